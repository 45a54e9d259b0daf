//! Shared helpers for the cross-crate tests.

use std::path::{Path, PathBuf};

use evpose_core::simdr::argmax;
use evpose_host::model::{self, quantize, AlignedBlob, FloatNet, Logits};
use evpose_host::parity;

/// The bundled fixtures folder (`tests/fixtures`).
pub fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

/// The shared reference folder beside the repository, if present (optional checks only).
pub fn shared() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared");
    p.is_dir().then_some(p)
}

/// Names of the bundled street windows: `street-00` … `street-09`.
pub fn street_windows() -> Vec<String> {
    (0..10).map(|i| format!("street-{i:02}")).collect()
}

/// The f32 parity rule against onnxruntime's outputs: max |Δ| ≤ 1e-4 · max|logit| per output and
/// identical argmax for every joint and axis. Panics naming `what` otherwise; returns the largest
/// max |Δ| / max|logit| of the two outputs.
pub fn assert_close(got: &Logits<f32>, want: &Logits<f32>, what: &str) -> f32 {
    let mut worst = 0f32;
    for (g, w, n, axis) in [
        (&got.x, &want.x, want.width(), "x"),
        (&got.y, &want.y, want.height(), "y"),
    ] {
        assert_eq!(g.len(), w.len(), "{what} {axis}: shape");
        let max_logit = w.iter().fold(0f32, |m, v| m.max(v.abs()));
        let max_diff = g
            .iter()
            .zip(w.iter())
            .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(
            max_diff <= 1e-4 * max_logit,
            "{what} {axis}: max|Δ| {max_diff} > 1e-4 · {max_logit}"
        );
        worst = worst.max(max_diff / max_logit);
        for j in 0..want.joints {
            let r = j * n..(j + 1) * n;
            assert_eq!(
                argmax(&g[r.clone()]),
                argmax(&w[r]),
                "{what} {axis}: argmax of joint {j}"
            );
        }
    }
    worst
}

/// Quantizes `net` calibrated on `calib`, then runs the core's int8 engine and tract on the
/// quantized ONNX graph over `inputs` and asserts identical int32 outputs (`==`) on every input.
/// Returns the joint axes whose int8 argmax lies within 1 px of the float one, and the total.
pub fn assert_int8_core_equals_tract(
    net: &FloatNet,
    calib: &[Vec<[f32; 5]>],
    inputs: &[Vec<[f32; 5]>],
    tag: &str,
) -> (usize, usize) {
    let q = quantize::calibrate(net, calib)
        .and_then(|ranges| quantize::quantize(net, &ranges))
        .unwrap_or_else(|e| panic!("{tag}: quantization failed: {e:#}"));
    let blob = AlignedBlob::new(&q.blob().unwrap());
    let file: String = tag
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .collect();
    let onnx = std::env::temp_dir().join(format!("evpose-{file}-{}.q.onnx", std::process::id()));
    std::fs::write(&onnx, q.onnx().unwrap()).unwrap();
    let float = AlignedBlob::new(&model::f32_blob(net).unwrap());
    let r = parity::report(&blob, &onnx, inputs, Some(&float));
    std::fs::remove_file(&onnx).ok();
    let r = r.unwrap_or_else(|e| panic!("{tag}: int8 parity run failed: {e:#}"));
    assert_eq!(r.mismatches, 0, "{tag}: core int8 != tract: {r:?}");
    assert_eq!(r.identical, inputs.len(), "{tag}: {r:?}");
    r.within_1px.unwrap()
}

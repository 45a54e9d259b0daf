//! The importer across PyTorch's ONNX exports of the paper's network family: opsets 11–18, fixed
//! and dynamic point counts, two joint/sensor sets (13 joints at 346×260, 5 at 64×48), two width
//! sets, fully connected layers with and without bias (MatMul or Gemm in the graph).
//!
//! The fixtures in `tests/fixtures/opsets/` are written by `scripts/make-opset-fixtures.py`
//! (seeded random weights and BatchNorm statistics; tiny widths), listed in its `manifest.json`.
//! For every listed model:
//! - the importer reads it, with the widths, joints, sensor size and point count it was made with;
//! - the core's f32 engine and tract match onnxruntime's outputs on the bundled input with the
//!   rule of `tests/inference.rs` (max |Δ| ≤ 1e-4 · max|logit|, identical argmax per joint and
//!   axis);
//! - quantized (calibrated on that input), the core's int8 engine and tract on the quantized ONNX
//!   give identical int32 outputs.
//!
//! A model that is missing or does not import fails the tests; every model is checked and every
//! failure reported (by name and opset) before the test fails.

use std::collections::BTreeSet;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;

use evpose_host::array;
use evpose_host::model::{self, AlignedBlob, FloatNet, Logits, TractModel};
use evpose_tests::{assert_close, assert_int8_core_equals_tract, fixtures};
use serde_json::Value;

/// One exported model, as the manifest lists it.
#[derive(Debug)]
struct Entry {
    name: String,
    opset: u64,
    dynamic: bool,
    points: usize,
    joints: usize,
    width: usize,
    height: usize,
    /// conv1..conv5, fc, head_dim.
    widths: [usize; 7],
    fc_bias: bool,
}

impl Entry {
    fn path(&self, suffix: &str) -> PathBuf {
        dir().join(format!("{}.{suffix}", self.name))
    }

    fn tag(&self) -> String {
        format!(
            "{} (opset {}, {} N)",
            self.name,
            self.opset,
            if self.dynamic { "dynamic" } else { "fixed" }
        )
    }

    fn import(&self) -> FloatNet {
        let path = self.path("onnx");
        assert!(
            path.is_file(),
            "{}: {} is missing",
            self.tag(),
            path.display()
        );
        model::import_onnx(&path).unwrap_or_else(|e| panic!("{}: import failed: {e:#}", self.tag()))
    }

    fn input(&self) -> Vec<[f32; 5]> {
        let points = model::read_points(&self.path("input.npy"))
            .unwrap_or_else(|e| panic!("{}: input: {e:#}", self.tag()));
        assert_eq!(points.len(), self.points, "{}: input points", self.tag());
        points
    }

    /// onnxruntime's outputs, `(1, J, W)` and `(1, J, H)`.
    fn reference(&self) -> Logits<f32> {
        let read = |axis: &str, n: usize| {
            let (shape, v) = array::read_exact::<f32>(&self.path(&format!("simdr_{axis}.npy")))
                .unwrap_or_else(|e| panic!("{}: simdr_{axis}: {e:#}", self.tag()));
            assert_eq!(
                shape,
                [1, self.joints as u64, n as u64],
                "{}: simdr_{axis} shape",
                self.tag()
            );
            v
        };
        Logits {
            joints: self.joints,
            x: read("x", self.width),
            y: read("y", self.height),
        }
    }
}

fn dir() -> PathBuf {
    fixtures().join("opsets")
}

fn manifest() -> Vec<Entry> {
    let path = dir().join("manifest.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (run scripts/make-opset-fixtures.py)",
            path.display()
        )
    });
    let json: Value = serde_json::from_str(&text).expect("manifest.json is not JSON");
    let num = |m: &Value, k: &str| {
        m[k].as_u64()
            .unwrap_or_else(|| panic!("manifest entry without integer '{k}': {m}"))
    };
    let flag = |m: &Value, k: &str| {
        m[k].as_bool()
            .unwrap_or_else(|| panic!("manifest entry without boolean '{k}': {m}"))
    };
    let models = json["models"].as_array().expect("manifest.json: no models");
    assert!(!models.is_empty(), "manifest.json lists no model");
    models
        .iter()
        .map(|m| {
            let w = &m["widths"];
            let widths = [
                "conv1", "conv2", "conv3", "conv4", "conv5", "fc", "head_dim",
            ]
            .map(|k| num(w, k) as usize);
            Entry {
                name: m["name"].as_str().expect("entry without name").to_string(),
                opset: num(m, "opset"),
                dynamic: flag(m, "dynamic"),
                points: num(m, "points") as usize,
                joints: num(m, "joints") as usize,
                width: num(m, "width") as usize,
                height: num(m, "height") as usize,
                widths,
                fc_bias: flag(m, "fc_bias"),
            }
        })
        .collect()
}

/// Runs `check` on every model, each to the end; then fails listing every model that failed.
fn for_every_model(what: &str, check: impl Fn(&Entry)) {
    let entries = manifest();
    let mut failed = Vec::new();
    for e in &entries {
        match catch_unwind(AssertUnwindSafe(|| check(e))) {
            Ok(()) => eprintln!("{what}: {} ok", e.tag()),
            Err(p) => {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                failed.push(if msg.starts_with(&e.name) {
                    msg
                } else {
                    format!("{}: {msg}", e.tag())
                });
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{what}: {} of {} models failed:\n{}",
        failed.len(),
        entries.len(),
        failed.join("\n")
    );
}

#[test]
fn manifest_covers_every_opset_fixed_and_dynamic_and_every_file() {
    let entries = manifest();
    let listed: BTreeSet<String> = entries.iter().map(|e| e.name.clone()).collect();
    assert_eq!(
        listed.len(),
        entries.len(),
        "duplicate names in the manifest"
    );
    for opset in 11..=18 {
        for dynamic in [false, true] {
            assert!(
                entries
                    .iter()
                    .any(|e| e.opset == opset && e.dynamic == dynamic),
                "no {} export at opset {opset}",
                if dynamic { "dynamic-N" } else { "fixed-N" }
            );
        }
    }
    let variety =
        |f: &dyn Fn(&Entry) -> String| entries.iter().map(f).collect::<BTreeSet<_>>().len() > 1;
    assert!(variety(&|e| format!(
        "{} {} {}",
        e.joints, e.width, e.height
    )));
    assert!(variety(&|e| format!("{:?}", e.widths)));
    assert!(variety(&|e| e.fc_bias.to_string()));
    for e in &entries {
        for suffix in ["onnx", "input.npy", "simdr_x.npy", "simdr_y.npy"] {
            assert!(e.path(suffix).is_file(), "{}: no {suffix}", e.tag());
        }
    }
    // Every bundled export is listed (none escapes the checks).
    for f in std::fs::read_dir(dir()).unwrap() {
        let f = f.unwrap().path();
        if f.extension().is_some_and(|x| x == "onnx") {
            let stem = f.file_stem().unwrap().to_string_lossy().to_string();
            assert!(
                listed.contains(&stem),
                "{} is not in manifest.json",
                f.display()
            );
        }
    }
}

#[test]
fn importer_reads_every_export_with_its_shape() {
    for_every_model("import", |e| {
        let net = e.import();
        let [a, b, c, d, conv5, fc, head] = e.widths;
        let point: Vec<_> = net
            .point
            .iter()
            .map(|l| (l.in_dim, l.out_dim, l.sources))
            .collect();
        assert_eq!(
            point,
            [
                (5, a, 1),
                (a, b, 2),
                (b, c, 4),
                (c, d, 8),
                (a + b + c + d, conv5, 0b11110)
            ],
            "{}: point layers",
            e.tag()
        );
        let fcs: Vec<_> = net.fc.iter().map(|l| (l.in_dim, l.out_dim)).collect();
        assert_eq!(
            fcs,
            [(2 * conv5, fc), (fc, e.joints * head)],
            "{}: FC layers",
            e.tag()
        );
        assert_eq!(
            (
                net.joints,
                net.head_dim(),
                net.head_x.out_dim,
                net.head_y.out_dim
            ),
            (e.joints, head, e.width, e.height),
            "{}: joints, head width, W, H",
            e.tag()
        );
        let want_points = (!e.dynamic).then_some(e.points);
        assert_eq!(net.points, want_points, "{}: point count", e.tag());
        assert!(
            net.point
                .iter()
                .chain(&net.fc)
                .all(|l| l.leaky == Some(0.01)),
            "{}: LeakyReLU(0.01) after every layer but the heads",
            e.tag()
        );
    });
}

#[test]
fn float_engines_match_onnxruntime_for_every_export() {
    for_every_model("f32", |e| {
        let net = e.import();
        let (input, want) = (e.input(), e.reference());
        let blob = AlignedBlob::new(&model::f32_blob(&net).unwrap());
        let core = model::run_core_f32(&blob, &input)
            .unwrap_or_else(|err| panic!("{}: core f32: {err:#}", e.tag()));
        let rc = assert_close(&core, &want, &format!("{}: core f32", e.tag()));
        let tract = TractModel::load(&e.path("onnx"))
            .and_then(|mut t| t.run(&input))
            .unwrap_or_else(|err| panic!("{}: tract: {err:#}", e.tag()));
        let rt = assert_close(&tract, &want, &format!("{}: tract", e.tag()));
        eprintln!(
            "{}: max|Δ| / max|logit|: core f32 {rc:.1e}, tract {rt:.1e}",
            e.tag()
        );
    });
}

#[test]
fn int8_core_equals_tract_for_every_export() {
    for_every_model("int8", |e| {
        let net = e.import();
        let input = vec![e.input()];
        let (close, total) = assert_int8_core_equals_tract(&net, &input, &input, &e.tag());
        eprintln!(
            "{}: int8 argmax within 1 px of float on {close}/{total} joint axes",
            e.tag()
        );
    });
}

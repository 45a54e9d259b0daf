//! Parity: the core's int8 engine against an independent engine (tract) on the quantized
//! graph, value for value, and how close int8 argmaxes stay to the float model's.

#[cfg(feature = "onnx")]
use std::path::Path;

#[cfg(feature = "onnx")]
use anyhow::{ensure, Context, Result};
use evpose_core::simdr::argmax;
#[cfg(feature = "onnx")]
use indicatif::ProgressBar;
use serde::Serialize;

use crate::model::Logits;
#[cfg(feature = "onnx")]
use crate::model::{AlignedBlob, CoreRunner, TractModel};

/// Result of a parity run.
#[derive(Clone, Debug, Serialize)]
pub struct ParityReport {
    /// Inputs compared.
    pub inputs: usize,
    /// Inputs whose int32 outputs are identical.
    pub identical: usize,
    /// Output values compared.
    pub values: usize,
    /// Output values that differ.
    pub mismatches: usize,
    /// Joint axes whose int8 argmax lies within 1 px of the float argmax (with `--float`).
    pub within_1px: Option<(usize, usize)>,
}

/// Compares the core's int8 engine with tract on the quantized graph, value for value
/// (feature `onnx`).
#[cfg(feature = "onnx")]
pub fn report(
    blob: &AlignedBlob,
    onnx: &Path,
    inputs: &[Vec<[f32; 5]>],
    float: Option<&AlignedBlob>,
) -> Result<ParityReport> {
    let mut tract = TractModel::load(onnx)?;
    let mut core = CoreRunner::new(blob).context("the int8 blob")?;
    let mut float = float
        .map(CoreRunner::new)
        .transpose()
        .context("the float model")?;
    let mut r = ParityReport {
        inputs: inputs.len(),
        identical: 0,
        values: 0,
        mismatches: 0,
        within_1px: float.as_ref().map(|_| (0, 0)),
    };
    let bar = ProgressBar::new(inputs.len() as u64);
    for pts in inputs {
        let reference = tract.run_i32(pts)?;
        let core = core.run_i8(pts)?;
        ensure!(
            core.x.len() == reference.x.len() && core.y.len() == reference.y.len(),
            "output shapes differ"
        );
        let diff = core
            .x
            .iter()
            .zip(&reference.x)
            .filter(|(a, b)| a != b)
            .count()
            + core
                .y
                .iter()
                .zip(&reference.y)
                .filter(|(a, b)| a != b)
                .count();
        r.values += core.x.len() + core.y.len();
        r.mismatches += diff;
        r.identical += usize::from(diff == 0);
        if let (Some(f), Some((close, total))) = (float.as_mut(), r.within_1px.as_mut()) {
            let fl = f.run_f32(pts)?;
            let (c, t) = argmax_agreement(&core, &fl);
            *close += c;
            *total += t;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(r)
}

/// Joint axes whose argmax differs by at most 1 px between two outputs, and the axes compared.
pub fn argmax_agreement(q: &Logits<i32>, f: &Logits<f32>) -> (usize, usize) {
    let mut close = 0;
    for j in 0..q.joints {
        for (qa, fa, n) in [(&q.x, &f.x, q.width()), (&q.y, &f.y, q.height())] {
            let a = argmax(&qa[j * n..(j + 1) * n]).unwrap_or(0);
            let b = argmax(&fa[j * n..(j + 1) * n]).unwrap_or(0);
            close += usize::from(a.abs_diff(b) <= 1);
        }
    }
    (close, 2 * q.joints)
}

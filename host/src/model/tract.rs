//! tract running an ONNX file: the independent reference engine (feature `onnx`).

use std::path::Path;

use anyhow::{anyhow, bail, ensure, Context, Result};
use tract_core::internal::DimLike;
use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;

use super::Logits;

/// An ONNX model prepared for tract, the independent reference engine. Clones share the
/// optimized plan.
#[derive(Clone)]
pub struct TractModel {
    /// The optimized plan and the point count it was made for.
    plan: Option<(usize, std::sync::Arc<TypedSimplePlan>)>,
    /// The loaded graph, for a dynamic export's plan at another point count.
    source: std::sync::Arc<InferenceModel>,
    fixed: Option<usize>,
    /// Whether the outputs are listed y first (by their names, [`super::heads_swapped`]).
    swapped: bool,
}

impl TractModel {
    /// Loads a model; a fixed-N export is optimized once, a dynamic one when the point count
    /// changes (the last plan is kept: a benchmark or a run at one N optimizes once).
    pub fn load(path: &Path) -> Result<Self> {
        let model = load_inference(path)?;
        let swapped = match model.output_outlets() {
            Ok([a, b]) => super::heads_swapped([model.outlet_label(*a), model.outlet_label(*b)]),
            _ => false,
        };
        let fixed = model
            .input_fact(0)
            .map_err(|e| anyhow!("{e}"))?
            .shape
            .dims()
            .nth(2)
            .and_then(|d| d.concretize())
            .and_then(|d| d.to_usize().ok());
        let plan = match fixed {
            Some(n) => Some((n, optimize(model.clone(), n)?)),
            None => None,
        };
        Ok(Self {
            plan,
            source: std::sync::Arc::new(model),
            fixed,
            swapped,
        })
    }

    /// The export's fixed point count, if any.
    pub fn fixed_points(&self) -> Option<usize> {
        self.fixed
    }

    /// Runs a float model on `points` rows `[x, y, t_avg, p_acc, cnt]` as they are.
    pub fn run(&mut self, points: &[[f32; 5]]) -> Result<Logits<f32>> {
        match self.run_any(points)? {
            TractOutput::F32(l) => Ok(l),
            TractOutput::I32(_) => bail!("the model's outputs are int32 (a quantized graph)"),
        }
    }

    /// Runs a quantized graph whose outputs are int32 accumulators.
    pub fn run_i32(&mut self, points: &[[f32; 5]]) -> Result<Logits<i32>> {
        match self.run_any(points)? {
            TractOutput::I32(l) => Ok(l),
            TractOutput::F32(_) => bail!("the model's outputs are float, not int32 accumulators"),
        }
    }

    /// Runs the model; outputs keep their element type.
    pub fn run_any(&mut self, points: &[[f32; 5]]) -> Result<TractOutput> {
        let n = points.len();
        ensure!(n > 0, "no input points");
        if let Some(f) = self.fixed {
            ensure!(n == f, "this model takes exactly {f} points, got {n}");
        }
        if self.plan.as_ref().is_none_or(|(at, _)| *at != n) {
            self.plan = Some((n, optimize((*self.source).clone(), n)?));
        }
        let (_, plan) = self.plan.as_ref().context("no plan")?;
        // (N, 5) → (1, 5, N)
        let mut input = vec![0f32; 5 * n];
        for (i, p) in points.iter().enumerate() {
            for (c, v) in p.iter().enumerate() {
                input[c * n + i] = *v;
            }
        }
        let t = tract_ndarray::Array3::from_shape_vec((1, 5, n), input)?;
        let out = plan
            .run(tvec!(Tensor::from(t).into()))
            .map_err(|e| anyhow!("tract: {e:?}"))?;
        ensure!(out.len() == 2, "expected two outputs");
        let (x, y) = if self.swapped {
            (&out[1], &out[0])
        } else {
            (&out[0], &out[1])
        };
        let joints = *x.shape().get(1).context("x output rank")?;
        Ok(if x.datum_type() == i32::datum_type() {
            TractOutput::I32(Logits {
                joints,
                x: values::<i32>(x)?,
                y: values::<i32>(y)?,
            })
        } else {
            TractOutput::F32(Logits {
                joints,
                x: values::<f32>(x)?,
                y: values::<f32>(y)?,
            })
        })
    }
}

/// Outputs of [`TractModel::run_any`].
#[derive(Clone, Debug, PartialEq)]
pub enum TractOutput {
    /// A float model's logits.
    F32(Logits<f32>),
    /// A quantized graph's int32 accumulators.
    I32(Logits<i32>),
}

fn values<T: Datum + Copy>(t: &TValue) -> Result<Vec<T>> {
    Ok(t.to_plain_array_view::<T>()
        .map_err(|e| anyhow!("{e}"))?
        .iter()
        .copied()
        .collect())
}

fn load_inference(path: &Path) -> Result<InferenceModel> {
    super::refuse_blob(path)?;
    tract_onnx::onnx()
        .model_for_path(path)
        .map_err(|e| anyhow!("{}: cannot load ONNX model: {e:?}", path.display()))
}

fn optimize(model: InferenceModel, n: usize) -> Result<std::sync::Arc<TypedSimplePlan>> {
    model
        .with_input_fact(0, f32::fact([1, 5, n]).into())
        .and_then(|m| m.into_optimized())
        .and_then(|m| m.into_runnable())
        .map_err(|e| anyhow!("tract cannot prepare the model for {n} points: {e:?}"))
}

//! Models on the host: ONNX import, the f32 blob, tract as the independent engine, and the
//! core engines run over owned blobs.

pub mod import;
pub mod net;
pub mod qonnx;
pub mod quant;

use std::path::Path;

use anyhow::{anyhow, bail, ensure, Context, Result};
use evpose_core::kernels::Kernels;
use evpose_core::{
    pack_point_layers, packed_bytes, run_f32_with, run_i8_packed, run_i8_with,
    scratch_words_for_block, DType, Model, PackedLayout,
};
use tract_core::internal::DimLike;
use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;

pub use import::import_onnx;
pub use net::{f32_blob, AlignedBlob, Dense, FloatNet};

/// SimDR outputs of one inference: `(J, W)` and `(J, H)` row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Logits<T> {
    /// Joints.
    pub joints: usize,
    /// x logits, `J × W`.
    pub x: Vec<T>,
    /// y logits, `J × H`.
    pub y: Vec<T>,
}

impl<T> Logits<T> {
    /// Width `W`.
    pub fn width(&self) -> usize {
        self.x.len() / self.joints.max(1)
    }
    /// Height `H`.
    pub fn height(&self) -> usize {
        self.y.len() / self.joints.max(1)
    }
}

/// An ONNX model prepared for tract, the independent reference engine.
pub struct TractModel {
    plan: Option<std::sync::Arc<TypedSimplePlan>>,
    path: std::path::PathBuf,
    fixed: Option<usize>,
}

impl TractModel {
    /// Loads a model; a fixed-N export is optimized once, a dynamic one per point count.
    pub fn load(path: &Path) -> Result<Self> {
        let model = load_inference(path)?;
        let fixed = model
            .input_fact(0)
            .map_err(|e| anyhow!("{e}"))?
            .shape
            .dims()
            .nth(2)
            .and_then(|d| d.concretize())
            .and_then(|d| d.to_usize().ok());
        let plan = match fixed {
            Some(n) => Some(optimize(model, n)?),
            None => None,
        };
        Ok(Self {
            plan,
            path: path.to_path_buf(),
            fixed,
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
        if let Some(f) = self.fixed {
            ensure!(n == f, "this model takes exactly {f} points, got {n}");
        }
        if self.plan.is_none() {
            self.plan = Some(optimize(load_inference(&self.path)?, n)?);
        }
        let plan = self.plan.as_ref().context("no plan")?;
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
        let joints = *out[0].shape().get(1).context("x output rank")?;
        let logits = if out[0].datum_type() == i32::datum_type() {
            TractOutput::I32(Logits {
                joints,
                x: values::<i32>(&out[0])?,
                y: values::<i32>(&out[1])?,
            })
        } else {
            TractOutput::F32(Logits {
                joints,
                x: values::<f32>(&out[0])?,
                y: values::<f32>(&out[1])?,
            })
        };
        if self.fixed.is_none() {
            self.plan = None; // the next call may have another N
        }
        Ok(logits)
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

/// A parsed model with its scratch memory, ready to run repeatedly (parsing checks the whole
/// blob's CRC, so it happens once, at load).
///
/// For an int8 model on a CPU with a native packed kernel ([`Kernels::has_packed`]), the point
/// layers' weights are also packed once, at load, as onnxruntime pre-packs at session creation;
/// [`CoreRunner::run_i8`] then uses them with such kernels.
pub struct CoreRunner<'b> {
    model: Model<'b>,
    scratch_f32: Vec<f32>,
    scratch_i32: Vec<i32>,
    packed: Option<(PackedLayout, Vec<u8>)>,
}

impl<'b> CoreRunner<'b> {
    /// Parses and validates a blob, and packs an int8 model's point layers if this CPU's
    /// kernels ([`kernels`]) have a packed kernel.
    pub fn new(blob: &'b AlignedBlob) -> Result<Self> {
        let model = Model::parse(blob.bytes()).map_err(|e| anyhow!("{e}"))?;
        let packed = if model.dtype() == DType::I8 && kernels().has_packed() {
            let mut buf = vec![0; packed_bytes(&model)];
            let layout = pack_point_layers(&model, &mut buf).map_err(|e| anyhow!("{e}"))?;
            Some((layout, buf))
        } else {
            None
        };
        // Scratch for the model's engine only, for its largest block of points.
        let words = scratch_words_for_block(&model, evpose_core::infer::MAX_BLOCK);
        let (f32_words, i32_words) = match model.dtype() {
            DType::F32 => (words, 0),
            DType::I8 => (0, words),
        };
        Ok(Self {
            scratch_f32: vec![0.0; f32_words],
            scratch_i32: vec![0; i32_words],
            model,
            packed,
        })
    }

    /// The parsed model.
    pub fn model(&self) -> &Model<'b> {
        &self.model
    }

    fn outputs<T: Default + Clone>(&self) -> Logits<T> {
        let (j, w, h) = (self.model.joints(), self.model.width(), self.model.height());
        Logits {
            joints: j,
            x: vec![T::default(); j * w],
            y: vec![T::default(); j * h],
        }
    }

    /// Runs the f32 engine.
    pub fn run_f32(&mut self, points: &[[f32; 5]]) -> Result<Logits<f32>> {
        let mut out = self.outputs();
        run_f32_with(
            kernels(),
            &self.model,
            points,
            &mut self.scratch_f32,
            &mut out.x,
            &mut out.y,
        )
        .map_err(|e| anyhow!("{e}"))?;
        Ok(out)
    }

    /// Runs the int8 engine with the given kernels (over the packed weights when they exist
    /// and `k` has a packed kernel); outputs are the heads' int32 accumulators.
    pub fn run_i8(&mut self, k: &Kernels, points: &[[f32; 5]]) -> Result<Logits<i32>> {
        let mut out = self.outputs();
        let (m, scratch) = (&self.model, &mut self.scratch_i32);
        match &self.packed {
            Some((layout, buf)) if k.has_packed() => {
                let packed = layout.weights(m, buf).map_err(|e| anyhow!("{e}"))?;
                run_i8_packed(k, m, &packed, points, scratch, &mut out.x, &mut out.y)
            }
            _ => run_i8_with(k, m, points, scratch, &mut out.x, &mut out.y),
        }
        .map_err(|e| anyhow!("{e}"))?;
        Ok(out)
    }

    /// Whether [`CoreRunner::run_i8`] with kernels that have a packed kernel uses packed
    /// weights.
    pub fn is_packed(&self) -> bool {
        self.packed.is_some()
    }
}

/// Runs the core's f32 engine once (parses the blob; use [`CoreRunner`] to run repeatedly).
pub fn run_core_f32(blob: &AlignedBlob, points: &[[f32; 5]]) -> Result<Logits<f32>> {
    CoreRunner::new(blob)?.run_f32(points)
}

/// The int8 kernels for this CPU (detected once).
pub fn kernels() -> &'static Kernels {
    static K: std::sync::OnceLock<Kernels> = std::sync::OnceLock::new();
    K.get_or_init(Kernels::detect)
}

/// Runs the core's int8 engine once with this CPU's kernels; outputs are the heads' int32
/// accumulators.
pub fn run_core_i8(blob: &AlignedBlob, points: &[[f32; 5]]) -> Result<Logits<i32>> {
    run_core_i8_with(kernels(), blob, points)
}

/// Runs the core's int8 engine once with the given kernels.
pub fn run_core_i8_with(
    k: &Kernels,
    blob: &AlignedBlob,
    points: &[[f32; 5]],
) -> Result<Logits<i32>> {
    CoreRunner::new(blob)?.run_i8(k, points)
}

/// Loads a model file: an ONNX export is imported into an f32 blob; a blob is read as is and
/// validated where it is parsed ([`CoreRunner::new`], `Model::parse`), once: its CRC covers
/// the whole file.
pub fn load_blob(path: &Path) -> Result<AlignedBlob> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    if bytes.starts_with(&evpose_core::model::MAGIC) {
        return Ok(AlignedBlob::new(&bytes));
    }
    if path.extension().is_some_and(|e| e == "onnx") {
        return Ok(AlignedBlob::new(&f32_blob(&import_onnx(path)?)?));
    }
    bail!(
        "{}: neither an evpose model blob nor an .onnx file",
        path.display()
    )
}

/// Reads an (N, 5) float32 point cloud.
pub fn read_points(path: &Path) -> Result<Vec<[f32; 5]>> {
    let (shape, v) = crate::npy::read_f64(path)?;
    ensure!(
        shape.len() == 2 && shape[1] == 5,
        "{}: expected an (N, 5) point cloud, got shape {shape:?}",
        path.display()
    );
    Ok(v.chunks_exact(5)
        .map(|r| std::array::from_fn(|i| r[i] as f32))
        .collect())
}

//! Models on the host: the f32 blob, int8 quantization and the core engines run over owned
//! blobs; with the `onnx` feature (on by default), ONNX import, the quantized model's ONNX twin
//! and tract as the independent engine.
//!
//! | module | what | feature |
//! |---|---|---|
//! | [`net`] | the float network as imported, the blob writer, [`AlignedBlob`] | |
//! | [`quantize`] | calibration and int8 quantization | |
//! | `import` | PyTorch ONNX exports → [`FloatNet`] (tract) | `onnx` |
//! | `qonnx` | the quantized network as a standard ONNX graph | `onnx` |
//! | `tract` | `TractModel`: tract running an ONNX file, the reference engine | `onnx` |

/// Whether a model's two outputs, named `labels`, are listed y head first: both names end in
/// `y` and `x` in that order (`simdr_y`, `simdr_x`). Otherwise the order is x, then y.
pub fn heads_swapped(labels: [Option<&str>; 2]) -> bool {
    let axis = |l: Option<&str>| {
        l.and_then(|l| l.trim().chars().last())
            .map(|c| c.to_ascii_lowercase())
    };
    (axis(labels[0]), axis(labels[1])) == (Some('y'), Some('x'))
}

#[cfg(feature = "onnx")]
pub mod import;
pub mod net;
#[cfg(feature = "onnx")]
pub mod qonnx;
pub mod quantize;
#[cfg(feature = "onnx")]
pub mod tract;

use std::path::Path;

use anyhow::{anyhow, bail, ensure, Context, Result};
use evpose_core::kernels::Kernels;
use evpose_core::{scratch_words_for_block, DType, Model, PackedWeights, Plan};
#[cfg(feature = "onnx")]
pub use import::import_onnx;
pub use net::{f32_blob, AlignedBlob, Dense, FloatNet};
#[cfg(feature = "onnx")]
pub use tract::{TractModel, TractOutput};

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

/// A parsed model with its kernels, packed weights and scratch memory, ready to run repeatedly
/// (parsing checks the whole blob's CRC, so it happens once, at load).
///
/// For an int8 model on a CPU with native packed kernels ([`Kernels::has_packed`]), the point
/// layers' weights (the int16 first layer's too) are packed once per blob ([`AlignedBlob::packed`]), as onnxruntime pre-packs
/// at session creation. [`CoreRunner::plan`] plans an inference over them (a few hundred
/// nanoseconds: a plan borrows the model and is rebuilt per call).
pub struct CoreRunner<'b> {
    model: Model<'b>,
    kernels: Kernels,
    packed: Option<PackedWeights<'b>>,
    words: usize,
    scratch_f32: Vec<f32>,
    scratch_i32: Vec<i32>,
}

impl<'b> CoreRunner<'b> {
    /// Parses and validates a blob, with this CPU's kernels ([`kernels`]).
    pub fn new(blob: &'b AlignedBlob) -> Result<Self> {
        Self::with_kernels(blob, kernels())
    }

    /// [`CoreRunner::new`] with a given kernel table (packed weights only where it has a
    /// packed kernel).
    pub fn with_kernels(blob: &'b AlignedBlob, k: &Kernels) -> Result<Self> {
        Self::build(blob, k, true)
    }

    /// [`CoreRunner::with_kernels`] over the blob's row-major weights even where `k` has a
    /// packed kernel: the same integers, to measure what packing gains (`evpose bench infer`).
    pub fn row_major(blob: &'b AlignedBlob, k: &Kernels) -> Result<Self> {
        Self::build(blob, k, false)
    }

    fn build(blob: &'b AlignedBlob, k: &Kernels, pack: bool) -> Result<Self> {
        let model = Model::parse(blob.bytes()).map_err(|e| anyhow!("{e}"))?;
        // Scratch for the model's engine only, for its largest block of points, and the words
        // that let its activation rows start at a cache line.
        let words = scratch_words_for_block(&model, evpose_core::infer::MAX_BLOCK)
            + evpose_core::infer::ALIGN_WORDS;
        let packed = match model.dtype() {
            DType::I8 if pack && k.has_packed() => blob.packed(&model)?,
            _ => None,
        };
        let (f32_words, i32_words) = match model.dtype() {
            DType::F32 => (words, 0),
            DType::I8 => (0, words),
        };
        let runner = Self {
            model,
            kernels: *k,
            packed,
            words,
            scratch_f32: vec![0.0; f32_words],
            scratch_i32: vec![0; i32_words],
        };
        runner.plan()?; // refuse what cannot run now, not at the first inference
        Ok(runner)
    }

    /// The parsed model.
    pub fn model(&self) -> &Model<'b> {
        &self.model
    }

    /// The inference plan over this runner's model, kernels, packed weights and scratch.
    pub fn plan(&self) -> Result<Plan<'_>> {
        match &self.packed {
            Some(p) => Plan::packed(&self.model, self.kernels, p, self.words),
            None => Plan::new(&self.model, self.kernels, self.words),
        }
        .map_err(|e| anyhow!("{e}"))
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
        let mut scratch = std::mem::take(&mut self.scratch_f32);
        let r = self
            .plan()?
            .run_f32(points, &mut scratch, &mut out.x, &mut out.y);
        self.scratch_f32 = scratch;
        r.map_err(|e| anyhow!("{e}"))?;
        Ok(out)
    }

    /// Runs the int8 engine; outputs are the heads' int32 accumulators.
    pub fn run_i8(&mut self, points: &[[f32; 5]]) -> Result<Logits<i32>> {
        let mut out = self.outputs();
        let mut scratch = std::mem::take(&mut self.scratch_i32);
        let r = self
            .plan()?
            .run_i8(points, &mut scratch, &mut out.x, &mut out.y);
        self.scratch_i32 = scratch;
        r.map_err(|e| anyhow!("{e}"))?;
        Ok(out)
    }

    /// Whether the int8 engine runs over packed weights.
    pub fn is_packed(&self) -> bool {
        self.packed.is_some()
    }
}

/// Runs the core's f32 engine once (parses the blob; use [`CoreRunner`] to run repeatedly).
pub fn run_core_f32(blob: &AlignedBlob, points: &[[f32; 5]]) -> Result<Logits<f32>> {
    CoreRunner::new(blob)?.run_f32(points)
}

/// The environment variable that picks a kernel family by name instead of the fastest this
/// CPU runs (`reference`, `avx2`, `avxvnni`, `avx512bw`, `avx512vnni`, `amx`): to measure or check
/// one family on a CPU that has several. Unset or empty: the fastest; a family this CPU lacks:
/// a warning on stderr, then the fastest (the kernel name every benchmark prints says which ran).
pub const KERNELS_ENV: &str = "EVPOSE_KERNELS";

/// The int8 kernels for this CPU (detected once), or the family [`KERNELS_ENV`] names.
pub fn kernels() -> &'static Kernels {
    static K: std::sync::OnceLock<Kernels> = std::sync::OnceLock::new();
    K.get_or_init(|| match std::env::var(KERNELS_ENV) {
        Err(std::env::VarError::NotPresent) => Kernels::detect(),
        Ok(name) if name.is_empty() => Kernels::detect(),
        named => {
            let named = named.map_err(|_| anyhow!("{KERNELS_ENV} is not UTF-8"));
            named.and_then(|n| kernels_named(&n)).unwrap_or_else(|e| {
                let k = Kernels::detect();
                eprintln!("warning: {e}; using {}", k.name());
                k
            })
        }
    })
}

/// The kernel family called `name`, if this build has it and this CPU runs it.
pub fn kernels_named(name: &str) -> Result<Kernels> {
    use evpose_core::kernels::Isa;
    Isa::ALL
        .iter()
        .find(|i| i.name() == name)
        .and_then(|i| i.kernels())
        .ok_or_else(|| {
            let here: Vec<&str> = Isa::ALL
                .iter()
                .filter(|i| i.is_supported_here())
                .map(|i| i.name())
                .collect();
            anyhow!(
                "{KERNELS_ENV}={name}: not a kernel family this CPU runs (it runs: {})",
                here.join(", ")
            )
        })
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
    CoreRunner::with_kernels(blob, k)?.run_i8(points)
}

/// Refuses an evpose blob where an ONNX export is wanted (tract, ONNX import), with what to
/// do instead: tract's own error would be a protobuf decoding failure.
#[cfg(feature = "onnx")]
fn refuse_blob(path: &Path) -> Result<()> {
    use std::io::Read as _;
    let mut head = [0u8; 4];
    let is_blob = std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut head))
        .is_ok_and(|()| head == evpose_core::model::MAGIC);
    if is_blob {
        bail!(
            "{} is an evpose model blob (.evq), not an ONNX export: tract and ONNX import need \
             the .onnx; run a blob with the core's engine (--engine i8, or f32 for an f32 blob)",
            path.display()
        );
    }
    Ok(())
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
        #[cfg(feature = "onnx")]
        return Ok(AlignedBlob::new(&f32_blob(&import_onnx(path)?)?));
        #[cfg(not(feature = "onnx"))]
        bail!(
            "{}: this evpose was built without ONNX import (cargo feature `onnx`)",
            path.display()
        );
    }
    bail!(
        "{}: neither an evpose model blob nor an .onnx file",
        path.display()
    )
}

/// Reads an (N, 5) float32 point cloud.
pub fn read_points(path: &Path) -> Result<Vec<[f32; 5]>> {
    let (shape, v) = crate::array::read_f64(path)?;
    ensure!(
        shape.len() == 2 && shape[1] == 5,
        "{}: expected an (N, 5) point cloud, got shape {shape:?}",
        path.display()
    );
    Ok(v.chunks_exact(5)
        .map(|r| std::array::from_fn(|i| r[i] as f32))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_families_are_picked_by_name() {
        assert_eq!(kernels_named("reference").unwrap().name(), "reference");
        let detected = Kernels::detect();
        assert_eq!(
            kernels_named(detected.name()).unwrap().isa(),
            detected.isa()
        );
        let err = kernels_named("avx1024").unwrap_err().to_string();
        assert!(
            err.contains("EVPOSE_KERNELS=avx1024") && err.contains("reference"),
            "{err}"
        );
        // A family this build has but this CPU (or target) cannot run is refused too.
        assert!(kernels_named("armdsp").is_err());
    }
}

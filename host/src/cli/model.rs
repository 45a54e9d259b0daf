//! `evpose infer`, `quantize`, `parity` and `bench infer` (feature `onnx`): arguments and
//! printing; the work is in [`crate::model`], [`crate::inputs`], [`crate::parity`] and
//! [`crate::bench`].

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};

use crate::model::{self, quantize, CoreRunner, Logits, TractModel, TractOutput};
use crate::{array, bench, inputs, parity};

/// Inference engines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Engine {
    /// tract-onnx running the `.onnx` file (float or quantized graph).
    Tract,
    /// The core's f32 engine (an `.onnx` is imported on the fly, or an f32 blob).
    F32,
    /// The core's int8 engine on a quantized `.evq` blob; outputs int32 accumulators.
    I8,
}

/// Arguments of `evpose infer`.
#[derive(Args, Debug)]
pub struct InferArgs {
    /// Model: `.onnx` (tract, f32) or a quantized `.evq` blob (i8).
    #[arg(long)]
    pub model: PathBuf,
    /// (N, 5) float32 point cloud `[x, y, t_avg, p_acc, cnt]`, fed as is.
    #[arg(long)]
    pub points: PathBuf,
    /// Engine.
    #[arg(long, value_enum)]
    pub engine: Engine,
    /// Output for the x logits, (J, W).
    #[arg(long)]
    pub out_x: PathBuf,
    /// Output for the y logits, (J, H).
    #[arg(long)]
    pub out_y: PathBuf,
    /// Run the same inference this many times after loading (timing from outside).
    #[arg(long, default_value_t = 1)]
    pub repeat: u32,
    /// Threads; every engine runs on one.
    #[arg(long, default_value_t = 1)]
    pub threads: u32,
}

/// Arguments of `evpose quantize`.
#[derive(Args, Debug)]
pub struct QuantizeArgs {
    /// The float model, a PyTorch ONNX export of the paper's family.
    #[arg(long)]
    pub model: PathBuf,
    /// Calibration data: event recordings (cut into windows, rasterized and sampled), (N, 5)
    /// point clouds or `evpose dataset` directories (`--max-windows` samples spread over each).
    #[arg(long, num_args = 1.., required = true)]
    pub calib: Vec<PathBuf>,
    /// Output int8 blob for the core.
    #[arg(long)]
    pub out: PathBuf,
    /// Output ONNX graph of the same integer computation (for an independent engine).
    #[arg(long)]
    pub onnx_out: Option<PathBuf>,
    /// Activation scales of the first point layer: one per channel (better for wide models
    /// whose conv1 channels differ in range: the paper-width model) or one for the layer (the
    /// narrow MCU model does better so).
    #[arg(long, value_enum, default_value_t = FirstLayerScales::Tensor)]
    pub first_layer_scales: FirstLayerScales,
    /// How inputs are sampled.
    #[command(flatten)]
    pub sampling: SamplingArgs,
}

/// `--first-layer-scales`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum FirstLayerScales {
    /// One activation scale for the layer.
    Tensor,
    /// One activation scale per output channel.
    Channel,
}

/// How event files become network inputs.
#[derive(Args, Debug, Clone)]
pub struct SamplingArgs {
    /// How to read the recordings.
    #[command(flatten)]
    pub input: super::InputArgs,
    /// Points per input (default: the model's fixed count, else 2048; 0 keeps all points).
    #[arg(long)]
    pub points: Option<usize>,
    /// Events per window when cutting event recordings.
    #[arg(long, default_value_t = evpose_core::raster::DEFAULT_WINDOW_EVENTS)]
    pub window_events: u32,
    /// Seed of the point sampler.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// At most this many windows per file (samples per dataset directory).
    #[arg(long, default_value_t = 16)]
    pub max_windows: usize,
}

impl SamplingArgs {
    /// The library's sampling settings.
    pub fn sampling(&self) -> inputs::Sampling {
        inputs::Sampling {
            points: self.points,
            window_events: self.window_events,
            seed: self.seed,
            max_windows: self.max_windows,
            open: self.input.options(),
        }
    }
}

/// Arguments of `evpose parity`.
#[derive(Args, Debug)]
pub struct ParityArgs {
    /// The quantized blob (`evpose quantize --out`).
    #[arg(long)]
    pub model: PathBuf,
    /// The quantized ONNX graph (`evpose quantize --onnx-out`).
    #[arg(long)]
    pub onnx: PathBuf,
    /// Inputs: event recordings or (N, 5) point clouds.
    #[arg(long, num_args = 1.., required = true)]
    pub inputs: Vec<PathBuf>,
    /// The float model, to report how often int8 argmaxes stay within 1 px of float ones.
    #[arg(long)]
    pub float: Option<PathBuf>,
    /// How inputs are sampled.
    #[command(flatten)]
    pub sampling: SamplingArgs,
}

/// Arguments of `evpose bench infer`.
#[derive(Args, Debug)]
pub struct BenchInferArgs {
    /// The float model (`.onnx`).
    #[arg(long)]
    pub model: PathBuf,
    /// Input points (default: a bundled street window, sampled to the model's point count).
    #[arg(long)]
    pub points: Option<PathBuf>,
    /// Timed runs per engine (after one warm-up run; at least 1).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..))]
    pub iterations: u32,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

fn write_logits<T: npyz::AutoSerialize + Copy>(l: &Logits<T>, x: &Path, y: &Path) -> Result<()> {
    array::write(x, &[l.joints as u64, l.width() as u64], &l.x)?;
    array::write(y, &[l.joints as u64, l.height() as u64], &l.y)
}

/// Runs `evpose infer`.
pub fn infer(a: &InferArgs) -> Result<()> {
    ensure!(
        a.threads == 1,
        "only --threads 1 is supported: every engine runs on one thread"
    );
    ensure!(a.repeat >= 1, "--repeat must be at least 1");
    let points = model::read_points(&a.points)?;
    match a.engine {
        Engine::Tract => {
            let mut m = TractModel::load(&a.model)?;
            let mut out = m.run_any(&points)?;
            for _ in 1..a.repeat {
                out = m.run_any(&points)?;
            }
            match out {
                TractOutput::F32(l) => write_logits(&l, &a.out_x, &a.out_y),
                TractOutput::I32(l) => write_logits(&l, &a.out_x, &a.out_y),
            }
        }
        Engine::F32 => {
            let blob = model::load_blob(&a.model)?;
            let mut runner = CoreRunner::new(&blob).context(a.model.display().to_string())?;
            warn_point_count(runner.model(), points.len());
            let l = repeat(a.repeat, || runner.run_f32(&points))?;
            write_logits(&l, &a.out_x, &a.out_y)
        }
        Engine::I8 => {
            let blob = model::load_blob(&a.model)?;
            let mut runner = CoreRunner::new(&blob).context(a.model.display().to_string())?;
            warn_point_count(runner.model(), points.len());
            let l = repeat(a.repeat, || runner.run_i8(&points))?;
            write_logits(&l, &a.out_x, &a.out_y)
        }
    }
}

/// The core engines run any point count (PointNet pools over them), but a model that records
/// its `N` was trained and calibrated at it: say so when the input differs.
fn warn_point_count(m: &evpose_core::Model<'_>, points: usize) {
    let n = m.preprocessing().points as usize;
    if n != 0 && n != points {
        eprintln!("warning: the model records {n} points per input; this input has {points}");
    }
}

fn repeat<T>(n: u32, mut f: impl FnMut() -> Result<T>) -> Result<T> {
    let mut out = f()?;
    for _ in 1..n {
        out = f()?;
    }
    Ok(out)
}

/// Runs `evpose quantize`.
pub fn quantize(a: &QuantizeArgs) -> Result<()> {
    let net = model::import_onnx(&a.model)?;
    let inputs = inputs::load(&a.calib, &a.sampling.sampling(), net.points)?;
    let bar = spinner(format!("calibrating on {} windows", inputs.len()));
    let mut ranges = quantize::calibrate(&net, &inputs)?;
    if a.first_layer_scales == FirstLayerScales::Tensor {
        ranges.per_tensor_first_layer();
    }
    bar.finish_and_clear();
    let mut q = quantize::quantize(&net, &ranges)?;
    // The preprocessing the calibration windows had travels with the model.
    // The point count the calibration asked for (0 with --points 0: any), not the first
    // window's, which with --points 0 is just that window's size.
    let points = a.sampling.sampling().points_for(net.points)?;
    q.preprocessing = evpose_core::model::Preprocessing {
        points: u32::try_from(points).context("too many points per input")?,
        window_events: a.sampling.window_events,
        slices: evpose_core::raster::DEFAULT_SLICES,
    };
    let blob = q.blob()?;
    std::fs::write(&a.out, &blob).with_context(|| format!("cannot write {}", a.out.display()))?;
    eprintln!(
        "wrote {} ({} bytes, calibrated on {} windows)",
        a.out.display(),
        blob.len(),
        inputs.len()
    );
    if let Some(path) = &a.onnx_out {
        std::fs::write(path, q.onnx()?)
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn spinner(msg: String) -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("valid template"),
    );
    bar.set_message(msg);
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// Runs `evpose parity`.
pub fn parity(a: &ParityArgs) -> Result<()> {
    let blob = model::load_blob(&a.model)?;
    let fixed = TractModel::load(&a.onnx)?.fixed_points();
    let inputs = inputs::load(&a.inputs, &a.sampling.sampling(), fixed)?;
    let float = a.float.as_deref().map(model::load_blob).transpose()?;
    let r = parity::report(&blob, &a.onnx, &inputs, float.as_ref())?;
    println!(
        "parity: {}/{} inputs identical, {} of {} int32 values differ",
        r.identical, r.inputs, r.mismatches, r.values
    );
    if let Some((c, t)) = r.within_1px {
        println!(
            "quantization: {c}/{t} joint axes ({:.1} %) within 1 px of the float argmax",
            100.0 * c as f64 / t as f64
        );
    }
    if r.mismatches > 0 {
        bail!("the core and tract disagree on {} values", r.mismatches);
    }
    Ok(())
}

/// Runs `evpose bench infer`.
pub fn bench_infer(a: &BenchInferArgs) -> Result<()> {
    let b = bench::infer(&a.model, a.points.as_deref(), a.iterations)?;
    let (n, macs) = (b.points, b.macs);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&b)?);
    } else {
        println!(
            "model {} ({} points, {:.3} GMAC per inference), one thread, median (fastest) of {}{}",
            a.model.display(),
            n,
            macs as f64 / 1e9,
            a.iterations,
            if b.cpu.is_empty() {
                String::new()
            } else {
                format!(" on {}", b.cpu)
            }
        );
        let [tract, f32, i8] = b.fastest_ms;
        println!("  tract f32 {:>9.2} ms ({tract:.2})", b.tract_f32_ms);
        println!("  core  f32 {:>9.2} ms ({f32:.2})", b.core_f32_ms);
        println!(
            "  core  i8  {:>9.2} ms ({i8:.2})  ({:.2} GMAC/s, kernels: {})",
            b.core_i8_ms, b.i8_gmacs, b.kernels
        );
        if let Some([ms, min]) = b.core_i8_row_major_ms {
            println!(
                "  core  i8  {ms:>9.2} ms ({min:.2})  over row-major weights: packed is {:.2}x \
                 ({:.2}x fastest)",
                ms / b.core_i8_ms,
                min / i8
            );
        }
        if let (Some(p), Some(f)) = (b.peak_gmacs, b.fraction_of_peak) {
            println!(
                "  int8 peak of this CPU, one thread: {p:.1} GMAC/s; core i8 runs at {:.1} %",
                100.0 * f
            );
        }
        println!(
            "  core i8 is {:.2}x tract f32 and {:.2}x core f32",
            b.speedup_i8_vs_tract, b.speedup_i8_vs_f32
        );
    }
    Ok(())
}

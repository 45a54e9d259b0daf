//! `evpose infer`, `quantize`, `parity` and `bench infer`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use clap::{Args, ValueEnum};
use evpose_core::sample::{rng_from_seed, sample_window};
use evpose_core::simdr::argmax;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use crate::model::{self, quant, AlignedBlob, CoreRunner, Logits, TractModel, TractOutput};
use crate::npy;
use crate::pipeline::{self, RasterOptions};

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
    /// Calibration data: event recordings (cut into windows, rasterized and sampled) or (N, 5)
    /// point clouds.
    #[arg(long, num_args = 1.., required = true)]
    pub calib: Vec<PathBuf>,
    /// Output int8 blob for the core.
    #[arg(long)]
    pub out: PathBuf,
    /// Output ONNX graph of the same integer computation (for an independent engine).
    #[arg(long)]
    pub onnx_out: Option<PathBuf>,
    /// How inputs are sampled.
    #[command(flatten)]
    pub sampling: SamplingArgs,
}

/// How event files become network inputs.
#[derive(Args, Debug, Clone)]
pub struct SamplingArgs {
    /// Points per input (default: the model's fixed count, else 2048; 0 keeps all points).
    #[arg(long)]
    pub points: Option<usize>,
    /// Events per window when cutting event recordings.
    #[arg(long, default_value_t = 7_500)]
    pub window_events: u32,
    /// Seed of the point sampler.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// At most this many windows per file.
    #[arg(long, default_value_t = 16)]
    pub max_windows: usize,
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
    /// Timed runs per engine (after one warm-up run).
    #[arg(long, default_value_t = 10)]
    pub iterations: u32,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

fn write_logits<T: npyz::AutoSerialize + Copy>(l: &Logits<T>, x: &Path, y: &Path) -> Result<()> {
    npy::write(x, &[l.joints as u64, l.width() as u64], &l.x)?;
    npy::write(y, &[l.joints as u64, l.height() as u64], &l.y)
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
            let l = repeat(a.repeat, || runner.run_f32(&points))?;
            write_logits(&l, &a.out_x, &a.out_y)
        }
        Engine::I8 => {
            let blob = model::load_blob(&a.model)?;
            let mut runner = CoreRunner::new(&blob).context(a.model.display().to_string())?;
            let l = repeat(a.repeat, || runner.run_i8(model::kernels(), &points))?;
            write_logits(&l, &a.out_x, &a.out_y)
        }
    }
}

fn repeat<T>(n: u32, mut f: impl FnMut() -> Result<T>) -> Result<T> {
    let mut out = f()?;
    for _ in 1..n {
        out = f()?;
    }
    Ok(out)
}

/// Network inputs from files: (N, 5) point clouds are sampled as they are; event recordings are
/// cut into windows, rasterized and sampled with the project's pipeline.
pub fn load_inputs(
    files: &[PathBuf],
    s: &SamplingArgs,
    model_points: Option<usize>,
) -> Result<Vec<Vec<[f32; 5]>>> {
    let n = s.points.or(model_points).unwrap_or(2048);
    if let Some(fixed) = model_points {
        ensure!(
            n == fixed,
            "the model takes exactly {fixed} points; --points {n} does not fit"
        );
    }
    let mut rng = rng_from_seed(s.seed);
    let mut out = Vec::new();
    for f in files {
        if let Ok(points) = model::read_points(f) {
            let mut idx = vec![0u32; points.len().max(n)];
            let picked = evpose_core::sample::sample_indices(points.len(), n, &mut rng, &mut idx)?;
            out.push(if picked.is_empty() {
                vec![[0.0; 5]; n]
            } else {
                picked.iter().map(|&i| points[i as usize]).collect()
            });
            continue;
        }
        let opts = RasterOptions {
            window_events: Some(s.window_events),
            ..RasterOptions::default()
        };
        let mut taken = 0;
        pipeline::rasterize(f, &opts, |_, w| {
            if taken >= s.max_windows || w.summary().events < s.window_events {
                return Ok(()); // a short tail window is not a full input
            }
            let len = evpose_core::sample::sample_len(w.len(), n).max(n);
            let mut idx = vec![0u32; len.max(w.len())];
            let mut rows = vec![[0f32; 5]; len];
            let rows = sample_window(w, n, &mut rng, &mut idx, &mut rows)?;
            out.push(rows.to_vec());
            taken += 1;
            Ok(())
        })
        .with_context(|| {
            format!(
                "{}: neither an (N, 5) point cloud nor a readable event file",
                f.display()
            )
        })?;
    }
    ensure!(!out.is_empty(), "no input windows in {files:?}");
    Ok(out)
}

/// Runs `evpose quantize`.
pub fn quantize(a: &QuantizeArgs) -> Result<()> {
    let net = model::import_onnx(&a.model)?;
    let inputs = load_inputs(&a.calib, &a.sampling, net.points)?;
    let bar = spinner(format!("calibrating on {} windows", inputs.len()));
    let ranges = quant::calibrate(&net, &inputs)?;
    bar.finish_and_clear();
    let q = quant::quantize(&net, &ranges)?;
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

/// Compares the core's int8 engine with tract on the quantized graph, value for value.
pub fn parity_report(
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
        let core = core.run_i8(model::kernels(), pts)?;
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

/// Runs `evpose parity`.
pub fn parity(a: &ParityArgs) -> Result<()> {
    let blob = model::load_blob(&a.model)?;
    let fixed = TractModel::load(&a.onnx)?.fixed_points();
    let inputs = load_inputs(&a.inputs, &a.sampling, fixed)?;
    let float = a.float.as_deref().map(model::load_blob).transpose()?;
    let r = parity_report(&blob, &a.onnx, &inputs, float.as_ref())?;
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

/// Result of `evpose bench infer`.
#[derive(Clone, Debug, Serialize)]
pub struct InferBench {
    /// Points per inference.
    pub points: usize,
    /// Multiply-accumulates per inference.
    pub macs: u64,
    /// Median latency per engine, ms: tract f32, core f32, core i8.
    pub tract_f32_ms: f64,
    /// Core f32 engine.
    pub core_f32_ms: f64,
    /// Core int8 engine.
    pub core_i8_ms: f64,
    /// tract f32 / core i8.
    pub speedup_i8_vs_tract: f64,
    /// core f32 / core i8.
    pub speedup_i8_vs_f32: f64,
    /// Core int8 MACs per second.
    pub i8_gmacs: f64,
    /// This CPU's one-thread int8 peak for that kernel family, GMAC/s (a loop of independent
    /// multiply-accumulate instructions, best of 5); absent for the reference kernels.
    pub peak_gmacs: Option<f64>,
    /// `i8_gmacs / peak_gmacs`.
    pub fraction_of_peak: Option<f64>,
    /// Kernel family the int8 engine used, and whether over packed weights.
    pub kernels: String,
}

fn median_ms(iters: u32, mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    f()?; // warm-up
    let mut t: Vec<f64> = Vec::new();
    for _ in 0..iters.max(1) {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

/// GMAC/s of [`evpose_core::kernels::peak_loop`] for `isa`, best of 5 runs of 120 M
/// instructions each (about 15 ms at two per cycle and 4 GHz: long against the timer and the
/// clock's ramp to its AVX-512 frequency).
fn peak_gmacs(isa: evpose_core::kernels::Isa) -> Option<f64> {
    let iters = 10_000_000;
    (0..5)
        .map(|_| {
            let t = Instant::now();
            let macs = evpose_core::kernels::peak_loop(isa, iters)?;
            Some(macs as f64 / t.elapsed().as_secs_f64() / 1e9)
        })
        .try_fold(0.0f64, |best, g| g.map(|g| best.max(g)))
}

/// Runs `evpose bench infer`.
pub fn bench_infer(a: &BenchInferArgs) -> Result<()> {
    let net = model::import_onnx(&a.model)?;
    let n = net.points.unwrap_or(2048);
    let samp = SamplingArgs {
        points: Some(n),
        window_events: 7_500,
        seed: 0,
        max_windows: 1,
    };
    let default = crate::cli::default_bench_events();
    let input = load_inputs(&[a.points.clone().unwrap_or(default)], &samp, net.points)?.remove(0);
    let fblob = AlignedBlob::new(&model::f32_blob(&net)?);
    let ranges = quant::calibrate(&net, std::slice::from_ref(&input))?;
    let qnet = quant::quantize(&net, &ranges)?;
    let qblob = AlignedBlob::new(&qnet.blob()?);
    let mut tract = TractModel::load(&a.model)?;
    // Each engine is loaded once, then timed (as onnxruntime's session is created once): the
    // core's blob checks and weight packing are not part of an inference.
    let mut core_f32 = CoreRunner::new(&fblob)?;
    let mut core_i8 = CoreRunner::new(&qblob)?;
    let model = core_f32.model();
    let macs = model.macs_per_point() * n as u64 + model.macs_after_pooling();
    let tract_ms = median_ms(a.iterations, || tract.run(&input).map(|_| ()))?;
    let f32_ms = median_ms(a.iterations, || core_f32.run_f32(&input).map(|_| ()))?;
    let i8_ms = median_ms(a.iterations, || {
        core_i8.run_i8(model::kernels(), &input).map(|_| ())
    })?;
    let peak = peak_gmacs(model::kernels().isa());
    let i8_gmacs = macs as f64 / (i8_ms * 1e-3) / 1e9;
    let b = InferBench {
        points: n,
        macs,
        tract_f32_ms: tract_ms,
        core_f32_ms: f32_ms,
        core_i8_ms: i8_ms,
        speedup_i8_vs_tract: tract_ms / i8_ms,
        speedup_i8_vs_f32: f32_ms / i8_ms,
        i8_gmacs,
        peak_gmacs: peak,
        fraction_of_peak: peak.map(|p| i8_gmacs / p),
        kernels: if core_i8.is_packed() && model::kernels().has_packed() {
            format!("{}, packed weights", model::kernels().name())
        } else {
            model::kernels().name().into()
        },
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&b)?);
    } else {
        println!(
            "model {} ({} points, {:.3} GMAC per inference), one thread, median of {}",
            a.model.display(),
            n,
            macs as f64 / 1e9,
            a.iterations
        );
        println!("  tract f32 {:>9.2} ms", b.tract_f32_ms);
        println!("  core  f32 {:>9.2} ms", b.core_f32_ms);
        println!(
            "  core  i8  {:>9.2} ms  ({:.2} GMAC/s, kernels: {})",
            b.core_i8_ms, b.i8_gmacs, b.kernels
        );
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

/// The bundled default model, embedded in the binary (so an installed `evpose` needs no
/// checkout): the small reference network, quantized, `assets/pointnet-small.evq`.
pub const DEFAULT_MODEL: &[u8] = include_bytes!("../../../assets/pointnet-small.evq");

/// [`DEFAULT_MODEL`], aligned (validated where it is parsed, as any blob).
pub fn default_blob() -> AlignedBlob {
    AlignedBlob::new(DEFAULT_MODEL)
}

/// Arguments of `evpose pose`.
#[derive(Args, Debug)]
pub struct PoseArgs {
    /// Event recording (any supported format).
    #[arg(long)]
    pub events: PathBuf,
    /// Model: an int8 `.evq` blob (i8 engine) or a float `.onnx` / f32 blob (f32 engine).
    /// Default: the bundled small model, quantized.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Camera to use in multi-camera recordings.
    #[arg(long, default_value_t = 0)]
    pub camera: u8,
    /// Count --window-events over the events of all cameras, using only --camera's, so that
    /// every camera gets the same windows (DHP19's evaluation: `--window-events 30000`); a
    /// window in which the camera has no event gives the joints of an all-zero input.
    #[arg(long)]
    pub all_camera_windows: bool,
    /// Print JSON lines (one object per window).
    #[arg(long)]
    pub json: bool,
    /// How windows are sampled.
    #[command(flatten)]
    pub sampling: SamplingArgs,
}

/// One window's pose.
#[derive(Clone, Debug, Serialize)]
pub struct WindowPose {
    /// Window index.
    pub window: usize,
    /// First and last timestamp, µs; `None` (JSON `null`) for a window without events.
    pub t_us: Option<(i64, i64)>,
    /// Points in the rasterized window.
    pub points: usize,
    /// Joints `(x, y)` in pixels, in the model's joint order.
    pub joints: Vec<(u16, u16)>,
}

/// Runs `evpose pose`: the whole pipeline on a recording.
pub fn pose(a: &PoseArgs) -> Result<()> {
    let blob = match &a.model {
        Some(path) => model::load_blob(path)?,
        None => default_blob(),
    };
    let mut runner = CoreRunner::new(&blob).with_context(|| match &a.model {
        Some(path) => path.display().to_string(),
        None => "the bundled model (assets/pointnet-small.evq)".into(),
    })?;
    let int8 = runner.model().dtype() == evpose_core::DType::I8;
    let n = a.sampling.points.unwrap_or(2048);
    let mut rng = rng_from_seed(a.sampling.seed);
    let opts = RasterOptions {
        window_events: Some(a.sampling.window_events),
        camera: a.camera,
        all_camera_windows: a.all_camera_windows,
        ..RasterOptions::default()
    };
    let mut idx = Vec::new();
    let mut rows = Vec::new();
    pipeline::rasterize(&a.events, &opts, |i, w| {
        let len = evpose_core::sample::sample_len(w.len(), n).max(n);
        idx.resize(len.max(w.len()), 0);
        rows.resize(len, [0f32; 5]);
        let input = sample_window(w, n, &mut rng, &mut idx, &mut rows)?;
        let mut joints = vec![evpose_core::Joint2d::default(); runner.model().joints()];
        let (width, height) = (runner.model().width(), runner.model().height());
        if int8 {
            let l = runner.run_i8(model::kernels(), input)?;
            evpose_core::decode(&l.x, &l.y, width, height, &mut joints)?;
        } else {
            let l = runner.run_f32(input)?;
            evpose_core::decode(&l.x, &l.y, width, height, &mut joints)?;
        }
        let s = w.summary();
        let p = WindowPose {
            window: i,
            t_us: (s.events > 0).then_some((s.t_min, s.t_max)),
            points: w.len(),
            joints: joints.iter().map(|j| (j.x, j.y)).collect(),
        };
        if a.json {
            println!("{}", serde_json::to_string(&p)?);
        } else {
            let js: Vec<String> = p.joints.iter().map(|(x, y)| format!("({x},{y})")).collect();
            println!(
                "window {:>3}  {} points  joints {}",
                p.window,
                p.points,
                js.join(" ")
            );
        }
        Ok(())
    })?;
    Ok(())
}

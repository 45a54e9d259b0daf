//! Benchmarks: rasterization throughput and inference latency of every engine in one run.
//! Figures are measured, never asserted (see the README's figures and the scripts that
//! produce them).

#[cfg(feature = "onnx")]
use std::path::Path;
use std::time::Instant;

use anyhow::Result;
use evpose_core::{RasterConfig, Rasterizer, WindowRule};
use serde::Serialize;

#[cfg(feature = "onnx")]
use crate::{
    inputs,
    model::{self, quantize, AlignedBlob, CoreRunner, TractModel},
};

/// Result of `evpose bench raster`.
#[derive(Clone, Debug, Serialize)]
pub struct RasterBench {
    /// Events pushed per pass.
    pub events: u64,
    /// Windows closed per pass.
    pub windows: u64,
    /// Points produced per pass.
    pub points: u64,
    /// Passes timed.
    pub iterations: u32,
    /// Wall time per pass, seconds.
    pub seconds_per_pass: f64,
    /// Throughput.
    pub events_per_second: f64,
}

/// Pushes `events` through a DAVIS346 rasterizer `iterations` times; returns the timing.
pub fn raster(
    events: &[evpose_core::Event],
    window_events: u32,
    iterations: u32,
) -> Result<RasterBench> {
    let config = RasterConfig {
        window: WindowRule::Events(window_events),
        ..RasterConfig::DAVIS346
    };
    let mut r = Rasterizer::new(
        config,
        crate::pipeline::vec_storage(window_events as usize, &config),
    )?;
    let mut run_once = || {
        let (mut windows, mut points) = (0u64, 0u64);
        let mut rest = events;
        while !rest.is_empty() {
            let (used, window) = r.extend(rest);
            if let Some(w) = window {
                windows += 1;
                points += w.len() as u64;
            }
            rest = &rest[used..];
        }
        if r.buffered() > 0 {
            points += r.flush().len() as u64;
            windows += 1;
        }
        (windows, points)
    };
    let (windows, points) = run_once(); // warm-up
    let start = Instant::now();
    for _ in 0..iterations {
        std::hint::black_box(run_once());
    }
    let secs = start.elapsed().as_secs_f64() / f64::from(iterations.max(1));
    Ok(RasterBench {
        events: events.len() as u64,
        windows,
        points,
        iterations,
        seconds_per_pass: secs,
        events_per_second: events.len() as f64 / secs,
    })
}

/// Result of `evpose bench infer`.
#[derive(Clone, Debug, Serialize)]
pub struct InferBench {
    /// The CPU, from `/proc/cpuinfo` (empty where it is not readable).
    pub cpu: String,
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
    /// Fastest run per engine, ms (tract f32, core f32, core i8): on a shared machine, the
    /// figure least disturbed by other work.
    pub fastest_ms: [f64; 3],
    /// tract f32 / core i8.
    pub speedup_i8_vs_tract: f64,
    /// core f32 / core i8.
    pub speedup_i8_vs_f32: f64,
    /// Core int8 MACs per second (median run).
    pub i8_gmacs: f64,
    /// This CPU's one-thread int8 peak for that kernel family, GMAC/s (a loop of independent
    /// multiply-accumulate instructions, best of 5); absent for the reference kernels.
    pub peak_gmacs: Option<f64>,
    /// `i8_gmacs / peak_gmacs`.
    pub fraction_of_peak: Option<f64>,
    /// Kernel family the int8 engine used, and whether over packed weights.
    pub kernels: String,
    /// Where the int8 engine ran over packed weights: the same engine and kernel family over
    /// the blob's row-major weights, `[median, fastest]` ms, timed right after it.
    pub core_i8_row_major_ms: Option<[f64; 2]>,
}

/// `(median, fastest)` ms of `iters` runs of `f`, after one warm-up run.
#[cfg(feature = "onnx")]
fn time_ms(iters: u32, mut f: impl FnMut() -> Result<()>) -> Result<(f64, f64)> {
    f()?; // warm-up
    let mut t: Vec<f64> = Vec::new();
    for _ in 0..iters.max(1) {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok((median(&t), t[0]))
}

/// The median of sorted times: the middle one, or the mean of the two middle ones for an
/// even count (0 for none).
fn median(sorted: &[f64]) -> f64 {
    match sorted.len() {
        0 => 0.0,
        n if n % 2 == 1 => sorted[n / 2],
        n => (sorted[n / 2 - 1] + sorted[n / 2]) / 2.0,
    }
}

/// GMAC/s of [`evpose_core::kernels::peak_loop`] for `isa`, best of 5 runs of 120 M
/// instructions each (about 15 ms at two per cycle and 4 GHz: long against the timer and the
/// clock's ramp to its AVX-512 frequency).
#[cfg(feature = "onnx")]
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

/// Times tract f32, the core's f32 engine and its int8 engine (the model quantized on the
/// input itself) on one input of `model`'s point count: `points` (an (N, 5) cloud or a
/// recording), or the bundled street window. Each engine is loaded once, then timed (as
/// onnxruntime's session is created once): blob checks and weight packing are not part of an
/// inference. Feature `onnx`.
#[cfg(feature = "onnx")]
pub fn infer(onnx: &Path, points: Option<&Path>, iterations: u32) -> Result<InferBench> {
    let net = model::import_onnx(onnx)?;
    let n = net.points.unwrap_or(evpose_core::pipeline::DEFAULT_POINTS);
    let sampling = inputs::Sampling {
        points: Some(n),
        window_events: evpose_core::raster::DEFAULT_WINDOW_EVENTS,
        seed: 0,
        max_windows: 1,
        open: Default::default(),
    };
    let input = match points {
        Some(p) => inputs::load(&[p.to_path_buf()], &sampling, net.points)?,
        None => {
            let mut rng = evpose_core::sample::rng_from_seed(0);
            inputs::from_reader(
                crate::assets::street_window()?.as_mut(),
                &sampling,
                n,
                &mut rng,
            )?
        }
    }
    .swap_remove(0);
    let fblob = AlignedBlob::new(&model::f32_blob(&net)?);
    let ranges = quantize::calibrate(&net, std::slice::from_ref(&input))?;
    let qblob = AlignedBlob::new(&quantize::quantize(&net, &ranges)?.blob()?);
    let mut tract = TractModel::load(onnx)?;
    let mut core_f32 = CoreRunner::new(&fblob)?;
    let mut core_i8 = CoreRunner::new(&qblob)?;
    let m = core_f32.model();
    let macs = m.macs_per_point() * n as u64 + m.macs_after_pooling();
    let (tract_ms, tract_min) = time_ms(iterations, || tract.run(&input).map(|_| ()))?;
    let (f32_ms, f32_min) = time_ms(iterations, || core_f32.run_f32(&input).map(|_| ()))?;
    let (i8_ms, i8_min) = time_ms(iterations, || core_i8.run_i8(&input).map(|_| ()))?;
    let k = model::kernels();
    let row_major = if core_i8.is_packed() {
        let mut runner = CoreRunner::row_major(&qblob, k)?;
        let (ms, min) = time_ms(iterations, || runner.run_i8(&input).map(|_| ()))?;
        Some([ms, min])
    } else {
        None
    };
    let peak = peak_gmacs(k.isa());
    let i8_gmacs = macs as f64 / (i8_ms * 1e-3) / 1e9;
    Ok(InferBench {
        cpu: cpu_model(),
        fastest_ms: [tract_min, f32_min, i8_min],
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
        kernels: if core_i8.is_packed() && k.has_packed() {
            format!("{}, packed weights", k.name())
        } else {
            k.name().into()
        },
        core_i8_row_major_ms: row_major,
    })
}

/// Result of `evpose bench pipeline`: the whole pipeline of `evpose run` (read → windows →
/// rasterize → sample → infer → decode → confidence → filter → triangulate) on a recording.
#[derive(Clone, Debug, Serialize)]
pub struct PipelineBench {
    /// The CPU, from `/proc/cpuinfo` (empty where it is not readable).
    pub cpu: String,
    /// What ran (recording, model, engine, window rule).
    pub run: crate::run::setup::Description,
    /// Events per pass over the recording (all cameras).
    pub events: u64,
    /// Windows per pass.
    pub windows: usize,
    /// Cameras estimated per window.
    pub cameras: usize,
    /// One thread: passes timed, and the median pass.
    pub passes: u32,
    /// One thread: median seconds per pass.
    pub seconds_per_pass: f64,
    /// One thread: events per second.
    pub events_per_second: f64,
    /// One thread: windows per second (each window estimated for every camera).
    pub windows_per_second: f64,
    /// One thread: milliseconds per window (all its cameras).
    pub ms_per_window: f64,
    /// One thread: seconds of the fastest pass (on a shared machine, the pass least disturbed
    /// by other work; the median moves with the machine's load).
    pub fastest_seconds_per_pass: f64,
    /// One thread: events per second in the fastest pass.
    pub fastest_events_per_second: f64,
    /// One thread: milliseconds per window in the fastest pass.
    pub fastest_ms_per_window: f64,
    /// Threads of the parallel run (recordings in parallel, one pass per task).
    pub threads: usize,
    /// All threads: events per second.
    pub parallel_events_per_second: f64,
    /// All threads: windows per second.
    pub parallel_windows_per_second: f64,
}

/// The CPU's model name (Linux), for the figures it qualifies.
///
/// With the family and model numbers when `/proc/cpuinfo` has them (a VM often names its CPU
/// only "Intel(R) Xeon(R) Processor"), e.g. `Intel(R) Xeon(R) Processor (family 6, model 207)`.
pub fn cpu_model() -> String {
    let Ok(info) = std::fs::read_to_string("/proc/cpuinfo") else {
        return String::new();
    };
    let field = |name: &str| {
        info.lines()
            .filter_map(|l| l.split_once(':'))
            .find(|(k, _)| k.trim() == name)
            .map(|(_, v)| v.trim().to_string())
    };
    let name = field("model name").unwrap_or_default();
    match (field("cpu family"), field("model")) {
        (Some(f), Some(m)) => format!("{name} (family {f}, model {m})"),
        _ => name,
    }
}

/// Runs `req` `passes` times on one thread (median pass) and `passes × threads` times on
/// `threads` threads (rayon; independent passes, as recordings in parallel).
pub fn pipeline(
    req: &crate::run::setup::Request,
    passes: u32,
    threads: usize,
) -> Result<PipelineBench> {
    use crate::run::setup::Plan;
    use rayon::prelude::*;
    // As `evpose run` without `--render`: the callback takes no events.
    let resolve = || -> Result<Plan> {
        let mut plan = Plan::resolve(req)?;
        plan.options.callback_events = false;
        Ok(plan)
    };
    let once = || -> Result<(f64, u64, usize)> {
        let plan = resolve()?;
        let start = Instant::now();
        let s = plan.run(|_, _, _| Ok(()))?;
        Ok((start.elapsed().as_secs_f64(), s.events, s.windows))
    };
    // The warm-up pass (page cache, allocations) also says what runs.
    let warm = resolve()?;
    let (run, cameras) = (warm.description.clone(), warm.options.cameras.len());
    warm.run(|_, _, _| Ok(()))?;
    let mut times = Vec::with_capacity(passes.max(1) as usize);
    let (mut events, mut windows) = (0, 0);
    for _ in 0..passes.max(1) {
        let (t, e, w) = once()?;
        (events, windows) = (e, w);
        times.push(t);
    }
    times.sort_by(f64::total_cmp);
    let median = median(&times);
    let fastest = times.first().copied().unwrap_or(median);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()?;
    let tasks = passes.max(1) as usize * threads.max(1);
    // Each pass resolved outside its timer, as on one thread (a plan does not move between
    // threads): the threads' busy time is the runs alone, and the slowest thread's total is
    // the wall time of the runs.
    let per_thread = pool.install(|| {
        (0..tasks)
            .into_par_iter()
            .map(|_| once().map(|(t, _, _)| (rayon::current_thread_index().unwrap_or(0), t)))
            .collect::<Result<Vec<(usize, f64)>>>()
    })?;
    let mut busy = vec![0f64; threads.max(1)];
    for (thread, t) in per_thread {
        if let Some(b) = busy.get_mut(thread) {
            *b += t;
        }
    }
    let wall = busy.iter().copied().fold(0.0, f64::max);
    Ok(PipelineBench {
        cpu: cpu_model(),
        run,
        events,
        windows,
        cameras,
        passes: passes.max(1),
        seconds_per_pass: median,
        events_per_second: events as f64 / median,
        windows_per_second: windows as f64 / median,
        ms_per_window: 1e3 * median / windows.max(1) as f64,
        fastest_seconds_per_pass: fastest,
        fastest_events_per_second: events as f64 / fastest,
        fastest_ms_per_window: 1e3 * fastest / windows.max(1) as f64,
        threads: threads.max(1),
        parallel_events_per_second: (events * tasks as u64) as f64 / wall,
        parallel_windows_per_second: (windows * tasks) as f64 / wall,
    })
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_median_of_an_even_count_is_the_mean_of_the_middle_two() {
        assert_eq!(super::median(&[1.0, 2.0, 3.0]), 2.0);
        assert_eq!(super::median(&[1.0, 2.0, 4.0, 10.0]), 3.0);
        assert_eq!(super::median(&[]), 0.0);
    }
}

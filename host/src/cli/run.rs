//! `evpose run`: arguments and printing; the run is [`crate::run`].

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use evpose_core::smooth::{Filter, LagParams, SmoothParams};

use crate::render::RunRenderer;
use crate::run::output::PoseWriter;
use crate::run::setup::{EngineKind, Plan, Request, DEFAULT_TIME_WINDOW_CAPACITY};
use crate::run::{
    RunSummary, RunWindow, NO_BODY_CONFIDENCE, NO_BODY_VIEWS_BASE, NO_BODY_VIEWS_SLOPE,
};

/// The temporal filter of `evpose run`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Smooth {
    /// A fixed-lag confidence-weighted mean over `--lag` windows each side: each window comes
    /// out `--lag` windows late, the most accurate (README, "Temporal filter").
    #[value(alias = "on")]
    FixedLag,
    /// A causal confidence-gated One-Euro filter: no latency, about half the gain.
    OneEuro,
    /// The network's joints as they are.
    Off,
}

/// What `evpose run` and `evpose bench pipeline` run: recording, model, engine, cameras.
#[derive(Args, Debug)]
pub struct SourceArgs {
    /// Event recording, any supported format (default: the bundled synthetic four-camera clip
    /// with ground truth).
    #[arg(long)]
    pub events: Option<PathBuf>,
    /// Model: an `.evq` blob (int8 or f32) or an `.onnx` file (default: the bundled MCU
    /// PointNet, int8).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Engine (default: i8 for int8 blobs, f32 for f32 blobs, tract for .onnx).
    #[arg(long, value_enum)]
    pub engine: Option<EngineKind>,
    /// Cameras to estimate, e.g. `2,3` (default: DHP19's front pair 2,3 for DHP19-layout
    /// recordings, else the recording's camera). Two or more calibrated cameras give 3-D.
    #[arg(long, value_delimiter = ',')]
    pub cameras: Option<Vec<u8>>,
    /// How to read the recording.
    #[command(flatten)]
    pub input: super::InputArgs,
}

impl SourceArgs {
    /// A request for these, everything else default.
    fn request(&self) -> Request {
        Request {
            events: self.events.clone(),
            open: self.input.options(),
            model: self.model.clone(),
            engine: self.engine,
            cameras: self.cameras.clone(),
            capacity: DEFAULT_TIME_WINDOW_CAPACITY,
            ..Request::default()
        }
    }
}

/// Arguments of `evpose run`.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// Recording, model, engine, cameras.
    #[command(flatten)]
    pub source: SourceArgs,
    /// Events per window, counted over all cameras of the recording (default: the model's
    /// window, 7,500, times the recording's cameras: 30,000 for DHP19's four).
    #[arg(long, conflicts_with = "window_ms")]
    pub window_events: Option<u32>,
    /// Window length in ms, instead of an event count.
    #[arg(long)]
    pub window_ms: Option<f64>,
    /// A window every this many events (or ms with --window-ms): sliding windows, for lower
    /// latency (default: the window, no overlap).
    #[arg(long)]
    pub stride: Option<f64>,
    /// Most events a time window holds (the oldest beyond it are dropped and counted), up to
    /// 2^32 − 1.
    #[arg(long, default_value_t = DEFAULT_TIME_WINDOW_CAPACITY,
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=u64::from(u32::MAX)))]
    pub max_window_events: usize,
    /// Points per network input (default: the model's).
    #[arg(long)]
    pub points: Option<usize>,
    /// Seed of the point samplers.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The temporal filter over windows, weighted by the joints' confidences.
    #[arg(long, value_enum, default_value_t = Smooth::FixedLag)]
    pub smooth: Smooth,
    /// Windows each side of the fixed-lag filter (its latency in windows; default: 3). Only
    /// with --smooth fixed-lag.
    #[arg(long, value_parser = super::lag_in_range)]
    pub lag: Option<usize>,
    /// Ground truth (`.gt.npy` of `evpose sim`, or DHP19's `.mat`; default: the one beside
    /// the recording, if any).
    #[arg(long)]
    pub gt: Option<PathBuf>,
    /// Calibration directory with DHP19's `P1..P4.npy` and `camera_positions.npy` (default:
    /// `calibration/` beside the recording, else DHP19's own for DHP19-layout recordings).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Write the poses: `.json` (an array of windows), `.jsonl` (a window per line) or `.csv`
    /// (a row per window, view and joint); repeat for several.
    #[arg(long)]
    pub out: Vec<PathBuf>,
    /// Draw each window (events, predicted and true skeletons, 3-D views) into an animated
    /// `.gif`, or numbered `.png` frames.
    #[arg(long)]
    pub render: Option<PathBuf>,
    /// Magnification of --render (default: 1).
    #[arg(long, requires = "render")]
    pub render_scale: Option<u32>,
    /// Print every window's line (text), or with --json every window as a JSON line.
    #[arg(long, short)]
    pub verbose: bool,
    /// Print JSON: the windows as lines with --verbose, then the summary.
    #[arg(long)]
    pub json: bool,
}

/// Runs `evpose run`.
pub fn run(a: &RunArgs) -> Result<()> {
    if a.source.events.is_none() && a.source.input != super::InputArgs::default() {
        bail!(
            "--format/--width/--height/--time-unit describe --events; the bundled clip needs none"
        );
    }
    if a.lag.is_some() && a.smooth != Smooth::FixedLag {
        bail!(
            "--lag sets the fixed-lag filter's window; --smooth {} has none",
            match a.smooth {
                Smooth::OneEuro => "one-euro",
                _ => "off",
            }
        );
    }
    let req = Request {
        window_events: a.window_events,
        window_ms: a.window_ms,
        stride: a.stride,
        points: a.points,
        seed: a.seed,
        filter: match a.smooth {
            Smooth::FixedLag => Filter::FixedLag(LagParams {
                lag: a.lag.unwrap_or(LagParams::DEFAULT.lag),
                ..LagParams::DEFAULT
            }),
            Smooth::OneEuro => Filter::OneEuro(SmoothParams::DEFAULT),
            Smooth::Off => Filter::Off,
        },
        gt: a.gt.clone(),
        calibration: a.calibration.clone(),
        capacity: a.max_window_events,
        ..a.source.request()
    };

    let mut plan = Plan::resolve(&req)?;
    // Only a rendering draws the events: without it, held windows need no copy of theirs.
    plan.options.callback_events = a.render.is_some();
    let d = plan.description.clone();
    if !a.json {
        eprintln!(
            "{}\n  model {} (engine {}, {} points), windows of {}{}\n  temporal filter: {}",
            d.events,
            d.model,
            d.engine,
            d.points,
            d.window,
            d.truth
                .as_ref()
                .map_or(String::new(), |t| format!(", ground truth {t}")),
            d.filter
        );
    }
    // The renderer first: its checks (extension, directory) fail before any output file
    // exists.
    let mut renderer = match &a.render {
        Some(path) => {
            let sizes: Vec<(u16, u16)> = plan
                .options
                .cameras
                .iter()
                .map(|c| c.rescale.sensor)
                .collect();
            Some(RunRenderer::create(
                path,
                &sizes,
                a.render_scale.unwrap_or(1),
                plan.triangulates(),
            )?)
        }
        None => None,
    };
    let mut writers = a
        .out
        .iter()
        .map(|p| PoseWriter::create(p))
        .collect::<Result<Vec<_>>>()?;
    let bar = indicatif::ProgressBar::new_spinner();
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} {pos} windows {msg} [{elapsed}]")
            .expect("a valid template"),
    );
    let summary = plan.run(|w, events, truth| {
        bar.inc(1);
        for out in &mut writers {
            out.write(w)?;
        }
        if let Some(r) = &mut renderer {
            r.add(w, events, truth)?;
        }
        if a.verbose {
            bar.suspend(|| print_window(w, a.json))?;
        }
        Ok(())
    });
    bar.finish_and_clear();
    // Whatever happened, the output files end well-formed (a JSON array closed) with the
    // windows done so far.
    let closed: Vec<Result<()>> = writers.into_iter().map(|out| out.finish()).collect();
    let summary = summary.map_err(|e| match a.out.as_slice() {
        [] => e,
        outs => {
            let names: Vec<String> = outs.iter().map(|p| p.display().to_string()).collect();
            e.context(format!(
                "the run stopped; {} keep the windows before the error",
                names.join(", ")
            ))
        }
    })?;
    closed.into_iter().collect::<Result<()>>()?;
    if a.json {
        let v = serde_json::json!({ "run": d, "summary": summary });
        println!("{}", serde_json::to_string(&v)?);
    } else {
        print_summary(&summary, d.synthetic);
    }
    if let (Some(path), Some(r)) = (&a.render, renderer) {
        let (frames, written) = (r.frames(), r.written());
        drop(r); // closes the GIF
        if frames == 0 {
            // A GIF without frames is not a valid file (and PNG frames were never written).
            if path.extension().is_some_and(|e| e == "gif") {
                std::fs::remove_file(path)
                    .with_context(|| format!("cannot remove {}", path.display()))?;
            }
            eprintln!("no windows: {} not written", path.display());
        } else {
            eprintln!("wrote {written} ({frames} frames)");
        }
    }
    for p in &a.out {
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}

fn print_window(w: &RunWindow, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(w)?);
        return Ok(());
    }
    let cams: Vec<String> = w
        .cameras
        .iter()
        .map(|c| {
            let conf = c
                .mean_confidence()
                .map_or(String::new(), |m| format!(" conf {m:.2}"));
            format!("cam {}: {} ev{conf}", c.camera, c.events)
        })
        .collect();
    let err = w.error.as_ref().map_or(String::new(), |e| {
        let d2: Vec<String> = e
            .mpjpe2d_px
            .iter()
            .map(|(_, v)| format!("{v:.1}"))
            .collect();
        format!(
            "  error 2-D {} px{}",
            d2.join("/"),
            e.mpjpe3d_mm
                .map_or(String::new(), |v| format!(", 3-D {v:.0} mm"))
        )
    });
    println!(
        "window {:>4}  t {:>8.3}-{:<8.3} s  {}{}{}",
        w.window,
        w.t_us[0] as f64 * 1e-6,
        w.t_us[1] as f64 * 1e-6,
        cams.join("  "),
        err,
        if w.no_body == Some(true) {
            "  no body"
        } else {
            ""
        }
    );
    Ok(())
}

fn print_summary(s: &RunSummary, synthetic: bool) {
    let cams: Vec<String> = s.cameras.iter().map(|c| c.to_string()).collect();
    println!(
        "{} windows, cameras {}, {} events{}",
        s.windows,
        cams.join(","),
        s.events,
        if s.dropped > 0 {
            format!(" ({} dropped from over-full windows)", s.dropped)
        } else {
            String::new()
        }
    );
    if s.empty_views > 0 {
        println!(
            "{} camera windows without events: left out of triangulation and of the no-body test",
            s.empty_views
        );
    }
    if s.skipped_windows > 0 {
        println!(
            "skipped {} empty windows over gaps longer than {} windows (a timestamp jump?)",
            s.skipped_windows,
            crate::run::windows::MAX_GAP_WINDOWS
        );
    }
    if let Some(c) = s.mean_confidence {
        println!(
            "mean joint confidence {c:.3}; {} of {} windows show no body ({})",
            s.no_body_windows,
            s.windows,
            no_body_rule(s)
        );
    }
    if let Some(e) = &s.errors {
        let f = |v: Option<f64>, unit: &str| v.map_or("-".to_owned(), |v| format!("{v:.2} {unit}"));
        println!(
            "against ground truth ({} windows{}): MPJPE2D {} (unfiltered {}), MPJPE3D {} (unfiltered {})",
            e.windows,
            if synthetic { ", synthetic data: not DHP19 figures" } else { "" },
            f(e.mpjpe2d_px, "px"),
            f(e.mpjpe2d_raw_px, "px"),
            f(e.mpjpe3d_mm, "mm"),
            f(e.mpjpe3d_raw_mm, "mm"),
        );
        if e.windows == 0 && s.windows > 0 {
            eprintln!(
                "warning: the ground truth covers none of the {} windows (another recording's, \
                 or another time base?)",
                s.windows
            );
        }
    }
    if s.no_body() {
        println!(
            "no body seen: {} of {} windows ({}); their joints are guesses",
            s.no_body_windows,
            s.windows,
            no_body_rule(s)
        );
    }
}

/// The no-body rule the run applied, in words ([`crate::run::no_body_seen`]).
fn no_body_rule(s: &RunSummary) -> String {
    let views = format!(
        "mean joint confidence below {NO_BODY_VIEWS_BASE} + {NO_BODY_VIEWS_SLOPE} ln(view \
         disagreement px)"
    );
    let one = format!("mean joint confidence below {NO_BODY_CONFIDENCE}");
    match s.views_compared {
        0 => one,
        n if n == s.windows => views,
        n => format!("{views} in {n} windows, {one} in the others"),
    }
}

/// Arguments of `evpose bench pipeline`.
#[derive(Args, Debug)]
pub struct BenchPipelineArgs {
    /// Recording (default: the bundled clip), model, engine, cameras, as `evpose run`.
    #[command(flatten)]
    pub source: SourceArgs,
    /// Timed passes on one thread (the median and the fastest are reported; at least 1); the
    /// parallel run makes this many per thread.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..))]
    pub passes: u32,
    /// Threads of the parallel run (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

/// Runs `evpose bench pipeline`.
pub fn bench_pipeline(a: &BenchPipelineArgs) -> Result<()> {
    let req = a.source.request();
    let threads = a
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let b = crate::bench::pipeline(&req, a.passes, threads)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&b)?);
        return Ok(());
    }
    println!("cpu: {}", b.cpu);
    println!(
        "{}: {} events, {} windows x {} camera(s) per pass; model {} (engine {}, {} points)",
        b.run.events, b.events, b.windows, b.cameras, b.run.model, b.run.engine, b.run.points
    );
    println!(
        "1 thread:   {:.2} M events/s, {:.0} windows/s, {:.3} ms per window (median of {} passes; real time: 36 ms)",
        b.events_per_second / 1e6,
        b.windows_per_second,
        b.ms_per_window,
        b.passes
    );
    println!(
        "            {:.2} M events/s, {:.3} ms per window in the fastest pass",
        b.fastest_events_per_second / 1e6,
        b.fastest_ms_per_window
    );
    println!(
        "{} threads: {:.2} M events/s, {:.0} windows/s (independent passes in parallel)",
        b.threads,
        b.parallel_events_per_second / 1e6,
        b.parallel_windows_per_second
    );
    Ok(())
}

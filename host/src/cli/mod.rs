//! The `evpose` command line: argument definitions, one function per command that calls the
//! library and prints. Nothing here is imported by tests or other modules; the work lives in
//! the library modules ([`crate::run`], [`crate::pipeline`], [`crate::convert`], …).

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use clap::{Args, Parser, Subcommand};

use crate::io::{self, Format};
use crate::pipeline::{self, RasterOptions};
use crate::summary::summarize_with;
use crate::{array, assets, bench, convert};

pub mod budget;
pub mod data;
#[cfg(feature = "onnx")]
pub mod model;
pub mod render;
pub mod run;
pub mod sim;
pub mod triangulate;

/// Human pose from event cameras: rasterization, inference and budgets for MCUs.
#[derive(Parser, Debug)]
#[command(name = "evpose", version, about)]
pub struct Cli {
    /// The command to run.
    #[command(subcommand)]
    pub command: Command,
}

/// `evpose` commands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Describe a recording: format, resolution, event counts, time span.
    Info(InfoArgs),
    /// Convert a recording to an (N, 4) float64 `.npy` array [x, y, t_us, p] (one camera), to
    /// AEDAT 4.0 (every camera; DV tools) or to a Prophesee RAW file (`.raw`, one camera; EVT
    /// 3.0, or EVT 2.0 / 2.1 with `--encoding`; Metavision / OpenEB tools).
    Convert(ConvertArgs),
    /// Rasterize events into event point clouds [x, y, t_avg, p_acc, cnt] (float32 .npy).
    Raster(RasterArgs),
    /// The main job: poses from a recording, per window and camera (2-D joints, confidences,
    /// the temporal filter, 3-D from calibrated cameras), errors against ground truth, pictures.
    /// Without arguments: the bundled model on the bundled clip.
    Run(run::RunArgs),
    /// Run a model on a point cloud: tract, the core's f32 engine or its int8 engine.
    #[cfg(feature = "onnx")]
    Infer(model::InferArgs),
    /// Calibrate and quantize a float ONNX model to an int8 blob and its ONNX twin.
    #[cfg(feature = "onnx")]
    Quantize(model::QuantizeArgs),
    /// Check that the core's int8 engine and tract on the quantized ONNX agree exactly.
    #[cfg(feature = "onnx")]
    Parity(model::ParityArgs),
    /// Per-layer MACs and bytes of a model, and a firmware image's flash and RAM.
    Budget(budget::BudgetArgs),
    /// Triangulate two DHP19 cameras' 2-D joints (one-camera `run --out` outputs) to 3-D joints in mm.
    Triangulate(triangulate::TriangulateArgs),
    /// Labelled windows (points, 2-D/3-D labels, masks) from recordings with ground truth.
    Dataset(data::DatasetArgs),
    /// MPJPE 2-D (px) and 3-D (mm) of a model, or of the mean-pose baseline, on a dataset.
    Eval(data::EvalArgs),
    /// Draw a simulated window's events with its ground truth (and a model's prediction).
    Render(render::RenderArgs),
    /// Simulate DHP19-style recordings (four cameras, ground truth, calibration) into a directory.
    Sim(sim::SimArgs),
    /// Measure throughput.
    #[command(subcommand)]
    Bench(BenchCommand),
}

/// Arguments of `evpose info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// Recording to describe.
    pub file: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// How to read the recording.
    #[command(flatten)]
    pub input: InputArgs,
}

/// Arguments of `evpose convert`.
#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// Recording to convert.
    pub file: PathBuf,
    /// Output: `.npy` ((N, 4) float64 `[x, y, t_us, p]`, one camera), `.aedat4` (one event
    /// stream per camera, LZ4, readable by DV tools) or `.raw` (Prophesee RAW, one camera,
    /// readable by Metavision / OpenEB tools; EVT 3.0 unless `--encoding` says otherwise).
    #[arg(long)]
    pub out: PathBuf,
    /// A `.raw` output's encoding: `evt3` (an IMX636's default), `evt21` (a GenX320's default,
    /// its byte order), `evt21-legacy` (EVT 2.1 as an IMX636 writes it) or `evt2`.
    #[arg(long, value_enum)]
    pub encoding: Option<RawEncoding>,
    /// Camera to export (default: camera 0 for `.npy` and `.raw`, every camera for `.aedat4`).
    #[arg(long)]
    pub camera: Option<u8>,
    /// How to read the recording.
    #[command(flatten)]
    pub input: InputArgs,
}

/// The encodings `convert --out F.raw` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RawEncoding {
    /// EVT 3.0 (16-bit words).
    Evt3,
    /// EVT 2.1, whole 64-bit words little-endian (a GenX320's order).
    Evt21,
    /// EVT 2.1, each word's upper half first (an IMX636's order).
    #[value(name = "evt21-legacy")]
    Evt21Legacy,
    /// EVT 2.0 (32-bit words, one event each).
    Evt2,
}

impl RawEncoding {
    /// The core's encoding.
    pub fn encoding(self) -> crate::io::evt::Encoding {
        use crate::io::evt::Encoding;
        match self {
            Self::Evt3 => Encoding::Evt3,
            Self::Evt21 => Encoding::Evt21,
            Self::Evt21Legacy => Encoding::Evt21Legacy,
            Self::Evt2 => Encoding::Evt2,
        }
    }

    /// How `convert` names it.
    fn label(self) -> &'static str {
        match self {
            Self::Evt3 => "EVT 3.0",
            Self::Evt21 => "EVT 2.1, a GenX320's byte order",
            Self::Evt21Legacy => "EVT 2.1, an IMX636's byte order",
            Self::Evt2 => "EVT 2.0",
        }
    }
}

/// The longest `--lag` the fixed-lag filter takes: 64 windows each side (each window waits
/// for 64 more, with its events held).
pub const MAX_LAG: usize = 64;

/// Parses `--lag`: windows each side, 0 to [`MAX_LAG`].
pub fn lag_in_range(s: &str) -> std::result::Result<usize, String> {
    let lag: usize = s.parse().map_err(|e| format!("{e}"))?;
    if lag > MAX_LAG {
        return Err(format!("at most {MAX_LAG} windows"));
    }
    Ok(lag)
}

/// How `info` and `convert` read a recording: the format, and what the file may not say.
#[derive(Args, Clone, Debug, Default, PartialEq, Eq)]
pub struct InputArgs {
    /// File format (default: detected from the header).
    #[arg(long, value_enum)]
    pub format: Option<Format>,
    /// Sensor width, for files that state no size (with --height).
    #[arg(long, requires = "height")]
    pub width: Option<u16>,
    /// Sensor height, for files that state no size (with --width).
    #[arg(long, requires = "width")]
    pub height: Option<u16>,
    /// Unit of text and `.npy` timestamps (default for text: seconds if a timestamp in the
    /// first lines has a fraction, else microseconds; for `.npy`: whole microseconds, a
    /// fraction refused).
    #[arg(long, value_enum)]
    pub time_unit: Option<io::TimeUnit>,
}

impl InputArgs {
    /// The reader options these arguments give.
    pub fn options(&self) -> io::OpenOptions {
        io::OpenOptions {
            format: self.format,
            size: self.width.zip(self.height),
            time_unit: self.time_unit,
        }
    }
}

/// Arguments of `evpose raster`.
#[derive(Args, Debug)]
pub struct RasterArgs {
    /// Recording to rasterize.
    #[arg(long)]
    pub events: PathBuf,
    /// Output `.npy`; with several windows, `OUT-000.npy`, `OUT-001.npy`, …
    #[arg(long)]
    pub out: PathBuf,
    /// Time slices K.
    #[arg(long, default_value_t = 4)]
    pub slices: u8,
    /// Events per window (default: the whole input as one window, unless an event lies more
    /// than 2^31 µs from its first: then the windows are numbered as with this option).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub window_events: Option<u32>,
    /// Camera to rasterize from multi-camera recordings.
    #[arg(long, default_value_t = 0)]
    pub camera: u8,
    /// Count --window-events over the events of all cameras, rasterizing only --camera's, so
    /// that every camera gets the same windows (DHP19's 30,000-event windows over its four
    /// cameras).
    #[arg(long, requires = "window_events")]
    pub all_camera_windows: bool,
    /// How to read the recording (format, sensor size, time unit).
    #[command(flatten)]
    pub input: InputArgs,
}

/// `evpose bench` targets.
#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Rasterization throughput on 7,500-event windows (events per second).
    Raster(BenchRasterArgs),
    /// Inference latency: tract f32, core f32 and core int8, one thread.
    #[cfg(feature = "onnx")]
    Infer(model::BenchInferArgs),
    /// The whole pipeline of `evpose run` on a recording: events/s and windows/s on one thread
    /// and on all, against the 36 ms real-time criterion.
    Pipeline(run::BenchPipelineArgs),
}

/// Arguments of `evpose bench raster`.
#[derive(Args, Debug)]
pub struct BenchRasterArgs {
    /// Events to rasterize, cut into windows (default: the bundled street windows).
    #[arg(long)]
    pub events: Option<PathBuf>,
    /// Events per window.
    #[arg(long, default_value_t = evpose_core::raster::DEFAULT_WINDOW_EVENTS)]
    pub window_events: u32,
    /// Passes over the events (at least 1).
    #[arg(long, default_value_t = 200, value_parser = clap::value_parser!(u32).range(1..))]
    pub iterations: u32,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// How to read --events.
    #[command(flatten)]
    pub input: InputArgs,
}

/// Ends the program quietly, with status 0, when its standard output or error is a pipe whose
/// reader has gone (`evpose info F | head -1`), as Unix tools do; `println!` otherwise panics
/// ("failed printing to stdout: Broken pipe") and exits with 101. Any other panic keeps the
/// default report. For a binary's `main`, before anything is printed.
pub fn quiet_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let msg = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.starts_with("failed printing to std") && msg.contains("Broken pipe") {
            std::process::exit(0);
        }
        default(info);
    }));
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Info(a) => info(&a),
        Command::Convert(a) => convert(&a),
        Command::Raster(a) => raster(&a),
        Command::Bench(BenchCommand::Raster(a)) => bench_raster(&a),
        Command::Bench(BenchCommand::Pipeline(a)) => run::bench_pipeline(&a),
        #[cfg(feature = "onnx")]
        Command::Bench(BenchCommand::Infer(a)) => model::bench_infer(&a),
        Command::Run(a) => run::run(&a),
        #[cfg(feature = "onnx")]
        Command::Infer(a) => model::infer(&a),
        #[cfg(feature = "onnx")]
        Command::Quantize(a) => model::quantize(&a),
        #[cfg(feature = "onnx")]
        Command::Parity(a) => model::parity(&a),
        Command::Budget(a) => budget::budget(&a),
        Command::Triangulate(a) => triangulate::triangulate(&a),
        Command::Sim(a) => sim::sim(&a),
        Command::Dataset(a) => data::dataset(&a),
        Command::Eval(a) => data::eval(&a),
        Command::Render(a) => render::render(&a),
    }
}

fn info(a: &InfoArgs) -> Result<()> {
    let s = summarize_with(&a.file, &a.input.options())?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    println!("file:       {}", s.file);
    println!("format:     {}", s.format.name());
    println!("events:     {}", s.events);
    for c in &s.cameras {
        let size = match (c.width, c.height) {
            (Some(w), Some(h)) => format!("{w}x{h}"),
            _ => "unknown".into(),
        };
        println!("camera {}:", c.camera);
        if let Some(name) = &c.name {
            println!("  name:       {name}");
        }
        println!("  resolution: {size}");
        println!("  events:     {} ({} on, {} off)", c.events, c.on, c.off);
        if let (Some(f), Some(l), Some(d)) = (c.first_t, c.last_t, c.duration_us) {
            println!("  first t:    {f} us");
            println!("  last t:     {l} us");
            println!("  duration:   {:.6} s", d as f64 / 1e6);
        }
    }
    let n = &s.notes;
    for (count, what) in [
        (n.skipped_records, "non-event records skipped"),
        (n.skipped_packets, "non-event packets skipped"),
        (
            n.dropped_events,
            "events dropped before the stream gave their time base",
        ),
        (n.timestamp_wraps, "timestamp counter wraps unwrapped"),
        (
            n.implied_time_highs,
            "EVT 3.0 time-low wraps without a time-high word, taken as the next period",
        ),
    ] {
        if count > 0 {
            println!("note:       {count} {what}");
        }
    }
    for a in &n.assumptions {
        println!("assumed:    {a}");
    }
    Ok(())
}

fn convert(a: &ConvertArgs) -> Result<()> {
    let ext = a
        .out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let opts = a.input.options();
    if a.encoding.is_some() && ext.as_deref() != Some("raw") {
        bail!("--encoding is for a Prophesee RAW output: name the output .raw");
    }
    let encoding = a.encoding.unwrap_or(RawEncoding::Evt3);
    let done = match ext.as_deref() {
        Some("npy") => convert::to_npy(&a.file, &opts, a.camera.unwrap_or(0), &a.out)?,
        Some("aedat4") => convert::to_aedat4(&a.file, &opts, a.camera, &a.out)?,
        Some("raw") => {
            let enc = encoding.encoding();
            convert::to_raw(&a.file, &opts, a.camera.unwrap_or(0), &a.out, enc)?
        }
        _ => bail!(
            "{}: unknown output format; name the output .npy, .aedat4 or .raw (Prophesee RAW)",
            a.out.display()
        ),
    };
    for w in &done.warnings {
        eprintln!("warning: {w}");
    }
    for a in &done.assumptions {
        eprintln!("assumed: {a}");
    }
    let ids: Vec<String> = done.cameras.iter().map(u8::to_string).collect();
    eprintln!(
        "wrote {} events of camera(s) {} to {}{}",
        done.events,
        ids.join(", "),
        a.out.display(),
        match ext.as_deref() {
            Some("aedat4") => " (AEDAT 4.0, LZ4; stream i holds the i-th of them)".to_string(),
            Some("raw") => format!(" (Prophesee RAW, {})", encoding.label()),
            _ => String::new(),
        }
    );
    Ok(())
}

/// Output path of window `index`: `OUT-000.npy`, `OUT-001.npy`, … (a run that makes one
/// window renames it back to `OUT`).
pub fn window_path(out: &Path, index: usize) -> PathBuf {
    let stem = out.file_stem().unwrap_or_default().to_string_lossy();
    out.with_file_name(format!("{stem}-{index:03}.npy"))
}

fn raster(a: &RasterArgs) -> Result<()> {
    let opts = RasterOptions {
        open: a.input.options(),
        slices: a.slices,
        window_events: a.window_events,
        camera: a.camera,
        all_camera_windows: a.all_camera_windows,
    };
    // Numbered files even without --window-events: a time jump can split the input into
    // windows (one file per window; a single one is renamed back below).
    let mut paths = Vec::new();
    let report = pipeline::rasterize(&a.events, &opts, |i, w| {
        let rows = pipeline::window_rows(w);
        let path = window_path(&a.out, i);
        array::write(&path, &[rows.len() as u64, 5], rows.as_flattened())?;
        paths.push(path);
        Ok(())
    })?;
    let size = report.size;
    // One window keeps the plain name.
    if paths.len() == 1 {
        std::fs::rename(&paths[0], &a.out)?;
        paths[0] = a.out.clone();
    }
    let s = report.stats;
    if s.accepted == 0 {
        // Nothing of the chosen camera: say which cameras the recording has.
        let info = crate::summary::summarize_with(&a.events, &a.input.options())?;
        if let Some(w) = info.no_events_warning(a.camera) {
            eprintln!("warning: {w}");
        }
    }
    eprintln!(
        "camera {}: {} window(s) from {} events ({}x{}, K={}); dropped {} out of range; wrote {}{}",
        a.camera,
        report.windows,
        s.accepted,
        size.0,
        size.1,
        a.slices,
        s.dropped_out_of_range,
        paths
            .first()
            .map(|p| p.display().to_string())
            .unwrap_or_default(),
        if paths.len() > 1 { " …" } else { "" }
    );
    Ok(())
}

fn bench_raster(a: &BenchRasterArgs) -> Result<()> {
    let mut reader = match &a.events {
        Some(path) => io::open_with(path, &a.input.options())?,
        None => assets::street_window()?,
    };
    let events = io::read_camera(reader.as_mut(), 0)?;
    let b = bench::raster(&events, a.window_events, a.iterations)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&b)?);
    } else {
        println!(
            "raster: {} events, {} windows, {} points per pass; {:.1} us per pass; {:.1} M events/s",
            b.events,
            b.windows,
            b.points,
            b.seconds_per_pass * 1e6,
            b.events_per_second / 1e6
        );
    }
    Ok(())
}

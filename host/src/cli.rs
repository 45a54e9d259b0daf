//! The `evpose` command line: argument definitions and one function per command.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use evpose_core::{RasterConfig, Rasterizer, WindowRule};
use serde::Serialize;

use crate::io::{self, Batch, CameraInfo, Format};

pub mod budget;
pub mod geometry;
pub mod inference;
use crate::npy;
use crate::pipeline::{self, RasterOptions, VecStorage};

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
    /// Convert a recording to an (N, 4) float64 `.npy` array [x, y, t_us, p].
    Convert(ConvertArgs),
    /// Rasterize events into event point clouds [x, y, t_avg, p_acc, cnt] (float32 .npy).
    Raster(RasterArgs),
    /// Estimate 2-D joints per event window: rasterize, sample, run the model, decode.
    Pose(inference::PoseArgs),
    /// Run a model on a point cloud: tract, the core's f32 engine or its int8 engine.
    Infer(inference::InferArgs),
    /// Calibrate and quantize a float ONNX model to an int8 blob and its ONNX twin.
    Quantize(inference::QuantizeArgs),
    /// Check that the core's int8 engine and tract on the quantized ONNX agree exactly.
    Parity(inference::ParityArgs),
    /// Per-layer MACs and bytes of a model, and a firmware image's flash and RAM.
    Budget(budget::BudgetArgs),
    /// Triangulate two DHP19 cameras' 2-D joints (`pose --json` outputs) to 3-D joints in mm.
    Triangulate(geometry::TriangulateArgs),
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
    /// Output: `.npy` ((N, 4) float64 `[x, y, t_us, p]`, one camera) or `.aedat4` (one event
    /// stream per camera, LZ4, readable by DV tools).
    #[arg(long)]
    pub out: PathBuf,
    /// Camera to export (default: camera 0 for `.npy`, every camera for `.aedat4`).
    #[arg(long)]
    pub camera: Option<u8>,
    /// How to read the recording.
    #[command(flatten)]
    pub input: InputArgs,
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
    /// Unit of text timestamps (default: seconds if the first lines have a decimal point,
    /// else microseconds).
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
    /// Events per window (default: the whole input as one window).
    #[arg(long)]
    pub window_events: Option<u32>,
    /// Sensor width (default: from the file).
    #[arg(long, requires = "height")]
    pub width: Option<u16>,
    /// Sensor height (default: from the file).
    #[arg(long, requires = "width")]
    pub height: Option<u16>,
    /// Camera to rasterize from multi-camera recordings.
    #[arg(long, default_value_t = 0)]
    pub camera: u8,
    /// Count --window-events over the events of all cameras, rasterizing only --camera's, so
    /// that every camera gets the same windows (DHP19's 30,000-event windows over its four
    /// cameras).
    #[arg(long, requires = "window_events")]
    pub all_camera_windows: bool,
    /// File format (default: detected from the header).
    #[arg(long, value_enum)]
    pub format: Option<Format>,
}

/// `evpose bench` targets.
#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Rasterization throughput on 7,500-event windows (events per second).
    Raster(BenchRasterArgs),
    /// Inference latency: tract f32, core f32 and core int8, one thread.
    Infer(inference::BenchInferArgs),
}

/// Arguments of `evpose bench raster`.
#[derive(Args, Debug)]
pub struct BenchRasterArgs {
    /// Events to rasterize, cut into windows (default: the bundled street windows).
    #[arg(long)]
    pub events: Option<PathBuf>,
    /// Events per window.
    #[arg(long, default_value_t = 7_500)]
    pub window_events: u32,
    /// Passes over the events.
    #[arg(long, default_value_t = 200)]
    pub iterations: u32,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Info(a) => info(&a),
        Command::Convert(a) => convert(&a),
        Command::Raster(a) => raster(&a),
        Command::Bench(BenchCommand::Raster(a)) => bench_raster(&a),
        Command::Bench(BenchCommand::Infer(a)) => inference::bench_infer(&a),
        Command::Pose(a) => inference::pose(&a),
        Command::Infer(a) => inference::infer(&a),
        Command::Quantize(a) => inference::quantize(&a),
        Command::Parity(a) => inference::parity(&a),
        Command::Budget(a) => budget::budget(&a),
        Command::Triangulate(a) => geometry::triangulate(&a),
    }
}

/// Per-camera statistics of a recording.
#[derive(Clone, Debug, Default, Serialize, PartialEq, Eq)]
pub struct CameraSummary {
    /// Camera id.
    pub camera: u8,
    /// Sensor width, if the file states it (or `--width` gives it).
    pub width: Option<u16>,
    /// Sensor height, if the file states it (or `--height` gives it).
    pub height: Option<u16>,
    /// Source name, if the file states one.
    pub name: Option<String>,
    /// Events of this camera.
    pub events: u64,
    /// ON events.
    pub on: u64,
    /// OFF events.
    pub off: u64,
    /// First timestamp in file order, µs.
    pub first_t: Option<i64>,
    /// Last timestamp in file order, µs.
    pub last_t: Option<i64>,
    /// `last_t - first_t`, µs.
    pub duration_us: Option<i64>,
}

/// What `evpose info` reports.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingSummary {
    /// The file.
    pub file: String,
    /// Its format, as the reader settled it (e.g. `aedat2-dhp19` for a detected `aedat2`).
    pub format: Format,
    /// All events, all cameras.
    pub events: u64,
    /// One entry per camera.
    pub cameras: Vec<CameraSummary>,
    /// What the reader skipped, repaired or assumed.
    pub notes: io::ReadNotes,
}

/// Streams a recording once and summarizes it.
pub fn summarize(path: &Path, format: Option<Format>) -> Result<RecordingSummary> {
    summarize_with(
        path,
        &io::OpenOptions {
            format,
            ..io::OpenOptions::default()
        },
    )
}

/// Streams a recording once and summarizes it, reading it with `opts`.
pub fn summarize_with(path: &Path, opts: &io::OpenOptions) -> Result<RecordingSummary> {
    let mut reader = io::open_with(path, opts)?;
    let mut cameras: Vec<CameraSummary> =
        reader.info().cameras.iter().map(camera_summary).collect();
    let mut batch = Batch::default();
    while reader
        .read_batch(&mut batch)
        .with_context(|| format!("{}", path.display()))?
    {
        for (e, &cam) in batch.events.iter().zip(&batch.cameras) {
            let s = match cameras.iter_mut().position(|c| c.camera == cam) {
                Some(i) => &mut cameras[i],
                None => {
                    cameras.push(CameraSummary {
                        camera: cam,
                        ..CameraSummary::default()
                    });
                    cameras.last_mut().expect("just pushed")
                }
            };
            s.events += 1;
            if e.on {
                s.on += 1;
            } else {
                s.off += 1;
            }
            s.first_t.get_or_insert(e.t);
            s.last_t = Some(e.t);
        }
    }
    // Cameras a reader declared while reading (AEDAT 3.1 sources) have their info now.
    let info = reader.info();
    for c in &mut cameras {
        if let Some(i) = info.cameras.iter().find(|i| i.id == c.camera) {
            c.width = c.width.or(i.width);
            c.height = c.height.or(i.height);
            c.name = c.name.take().or_else(|| i.name.clone());
        }
        c.duration_us = c.first_t.zip(c.last_t).map(|(a, b)| b - a);
    }
    cameras.sort_by_key(|c| c.camera);
    Ok(RecordingSummary {
        file: path.display().to_string(),
        format: info.format,
        events: cameras.iter().map(|c| c.events).sum(),
        cameras,
        notes: reader.notes(),
    })
}

fn camera_summary(c: &CameraInfo) -> CameraSummary {
    CameraSummary {
        camera: c.id,
        width: c.width,
        height: c.height,
        name: c.name.clone(),
        ..CameraSummary::default()
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
    match ext.as_deref() {
        Some("npy") => convert_npy(a),
        Some("aedat4") => convert_aedat4(a),
        _ => bail!(
            "{}: unknown output format; name the output .npy or .aedat4",
            a.out.display()
        ),
    }
}

fn convert_npy(a: &ConvertArgs) -> Result<()> {
    let opts = a.input.options();
    let camera = a.camera.unwrap_or(0);
    let summary = summarize_with(&a.file, &opts)?;
    let n = summary
        .cameras
        .iter()
        .find(|c| c.camera == camera)
        .map_or(0, |c| c.events);
    if n == 0 && summary.events > 0 {
        let ids: Vec<String> = summary
            .cameras
            .iter()
            .filter(|c| c.events > 0)
            .map(|c| c.camera.to_string())
            .collect();
        eprintln!(
            "warning: camera {camera} has no events (cameras with events: {}); pass --camera",
            ids.join(", ")
        );
    }
    let mut reader = io::open_with(&a.file, &opts)?;
    let file = std::fs::File::create(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    use npyz::WriterBuilder;
    let mut w = npyz::WriteOptions::<f64>::new()
        .default_dtype()
        .shape(&[n, 4])
        .writer(std::io::BufWriter::new(file))
        .begin_nd()?;
    let mut batch = Batch::default();
    let mut written = 0u64;
    while reader
        .read_batch(&mut batch)
        .with_context(|| format!("{}", a.file.display()))?
    {
        for (e, &cam) in batch.events.iter().zip(&batch.cameras) {
            if cam == camera {
                w.extend([
                    f64::from(e.x),
                    f64::from(e.y),
                    e.t as f64,
                    f64::from(u8::from(e.on)),
                ])?;
                written += 1;
            }
        }
    }
    if written != n {
        bail!("{} changed while converting", a.file.display());
    }
    w.finish()?;
    eprintln!("wrote {n} events of camera {camera} to {}", a.out.display());
    Ok(())
}

fn convert_aedat4(a: &ConvertArgs) -> Result<()> {
    use io::aedat4::{Aedat4Writer, Compression};
    let opts = a.input.options();
    let summary = summarize_with(&a.file, &opts)?;
    let mut cameras: Vec<CameraInfo> = summary
        .cameras
        .iter()
        .filter(|c| a.camera.is_none_or(|want| want == c.camera))
        .map(|c| CameraInfo {
            id: c.camera,
            width: c.width,
            height: c.height,
            name: c.name.clone(),
        })
        .collect();
    if cameras.is_empty() {
        let id = a.camera.unwrap_or(0);
        let (width, height) = (opts.size.map(|s| s.0), opts.size.map(|s| s.1));
        cameras.push(CameraInfo {
            id,
            width,
            height,
            name: None,
        });
    }
    if cameras.iter().any(|c| c.width.is_none()) {
        eprintln!(
            "warning: {} states no sensor size; DV tools expect one: pass --width and --height",
            a.file.display()
        );
    }
    let file = std::fs::File::create(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut w = Aedat4Writer::new(std::io::BufWriter::new(file), &cameras, Compression::Lz4)?;
    let mut reader = io::open_with(&a.file, &opts)?;
    let mut batch = Batch::default();
    let mut picked = Batch::default();
    let mut written = 0u64;
    while reader
        .read_batch(&mut batch)
        .with_context(|| format!("{}", a.file.display()))?
    {
        let part = match a.camera {
            None => &batch,
            Some(want) => {
                picked.clear();
                for (e, &cam) in batch.events.iter().zip(&batch.cameras) {
                    if cam == want {
                        picked.push(cam, *e);
                    }
                }
                &picked
            }
        };
        w.write(part)
            .with_context(|| format!("cannot write {}", a.out.display()))?;
        written += part.len() as u64;
    }
    w.finish()?;
    let ids: Vec<String> = cameras.iter().map(|c| c.id.to_string()).collect();
    eprintln!(
        "wrote {written} events of camera(s) {} to {} (AEDAT 4.0, LZ4; stream i holds the i-th of them)",
        ids.join(", "),
        a.out.display()
    );
    Ok(())
}

/// Output path of window `index` when a run produces `total` windows.
pub fn window_path(out: &Path, index: usize, several: bool) -> PathBuf {
    if !several {
        return out.to_path_buf();
    }
    let stem = out.file_stem().unwrap_or_default().to_string_lossy();
    out.with_file_name(format!("{stem}-{index:03}.npy"))
}

fn raster(a: &RasterArgs) -> Result<()> {
    let opts = RasterOptions {
        format: a.format,
        size: a.width.zip(a.height),
        slices: a.slices,
        window_events: a.window_events,
        camera: a.camera,
        all_camera_windows: a.all_camera_windows,
    };
    let several = a.window_events.is_some();
    let mut paths = Vec::new();
    let report = pipeline::rasterize(&a.events, &opts, |i, w| {
        let rows = pipeline::window_rows(w);
        let path = window_path(&a.out, i, several);
        npy::write(&path, &[rows.len() as u64, 5], rows.as_flattened())?;
        paths.push(path);
        Ok(())
    })?;
    // One window from a windowed run keeps the plain name, as if no window size were given.
    if several && paths.len() == 1 {
        std::fs::rename(&paths[0], &a.out)?;
        paths[0] = a.out.clone();
    }
    let s = report.stats;
    eprintln!(
        "{} window(s) from {} events ({}x{}, K={}); dropped {} out of range; wrote {}{}",
        report.windows,
        s.accepted,
        report.size.0,
        report.size.1,
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

/// Default events for the benchmark: the street windows bundled with the tests.
pub fn default_bench_events() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/street-00.events.npy")
}

/// Pushes `events` through a DAVIS346 rasterizer `iterations` times; returns the timing.
pub fn bench_raster_events(
    events: &[evpose_core::Event],
    window_events: u32,
    iterations: u32,
) -> Result<RasterBench> {
    let config = RasterConfig {
        window: WindowRule::Events(window_events),
        ..RasterConfig::DAVIS346
    };
    let mut r = Rasterizer::new(config, VecStorage::new(window_events as usize, &config))?;
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

/// Reads all events of camera 0 of a recording into memory.
pub fn load_events(path: &Path) -> Result<Vec<evpose_core::Event>> {
    let mut reader = io::open(path, None)?;
    let mut batch = Batch::default();
    let mut events = Vec::new();
    while reader.read_batch(&mut batch)? {
        events.extend(
            batch
                .events
                .iter()
                .zip(&batch.cameras)
                .filter(|(_, &c)| c == 0)
                .map(|(e, _)| *e),
        );
    }
    Ok(events)
}

fn bench_raster(a: &BenchRasterArgs) -> Result<()> {
    let path = a.events.clone().unwrap_or_else(default_bench_events);
    let events = load_events(&path)?;
    let b = bench_raster_events(&events, a.window_events, a.iterations)?;
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

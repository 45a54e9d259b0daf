//! Recordings through the core, window by window: events from any [`EventReader`] (a file,
//! the simulator, memory), one camera selected, windows cut per camera or over all cameras,
//! and each window handed to a core stage: the [`Rasterizer`] (`evpose raster`, datasets,
//! calibration inputs). `evpose run` cuts windows over several cameras at once
//! ([`crate::run::windows`]) and feeds each camera's core [`evpose_core::Session`].
//!
//! [`drive`] is the one loop over a reader's batches; a [`WindowSink`] is what it feeds.

use anyhow::{bail, Context, Result};
use evpose_core::raster::{RasterBuffers, MAX_HEIGHT, MAX_WIDTH};
use evpose_core::{
    Event, RasterConfig, RasterStats, RasterStorage, Rasterizer, Window, WindowRule,
};

use crate::io::{self, Batch, EventReader, OpenOptions, StreamInfo};

/// Heap-backed [`RasterStorage`] for windows of any size on the host: the core's
/// [`RasterBuffers`] over vectors ([`vec_storage`] makes one).
pub type VecStorage = RasterBuffers<Vec<u64>, Vec<u32>, Vec<u32>>;

/// Heap storage for windows of `capacity` events under `config`.
pub fn vec_storage(capacity: usize, config: &RasterConfig) -> VecStorage {
    RasterBuffers::from_parts(
        vec![0; capacity],
        vec![0; capacity],
        vec![0; usize::from(config.width)],
        vec![0; config.row_bins()],
    )
}

/// A rasterizer over heap storage for windows of `capacity` events of a `width × height`
/// sensor with `slices` time slices.
pub fn rasterizer(
    (width, height): (u16, u16),
    slices: u8,
    capacity: u32,
) -> Result<Rasterizer<VecStorage>> {
    let config = RasterConfig {
        width,
        height,
        slices,
        window: WindowRule::Events(capacity.max(1)),
    };
    Rasterizer::new(config, vec_storage(capacity.max(1) as usize, &config))
        .context("invalid rasterization settings")
}

/// Which events make a window.
#[derive(Clone, Copy, Debug, Default)]
pub struct Windowing {
    /// Camera whose events are used (multi-camera recordings); other cameras' are skipped.
    pub camera: u8,
    /// Count the window's events over every camera, using only `camera`'s: every camera gets
    /// the same windows (DHP19's "Mean Label" windows: 30,000 events over its four cameras). A
    /// window in which `camera` has no event is an empty window. `None`: windows of the
    /// rasterizer's own rule over `camera`'s events.
    pub shared_events: Option<u32>,
}

/// What a run over a reader did.
#[derive(Clone, Debug)]
pub struct RunReport {
    /// Windows produced.
    pub windows: usize,
    /// The rasterizer's counters.
    pub stats: RasterStats,
}

/// A core stage that turns events into windows and hands each closed window on: [`drive`]
/// feeds it. [`Rasterizing`] (point clouds) is the one.
pub trait WindowSink {
    /// Feeds events until one closes a window, which is handed on; returns how many events
    /// were used and whether a window closed.
    fn extend(&mut self, events: &[Event]) -> Result<(usize, bool)>;
    /// Closes the open window (possibly empty) and hands it on.
    fn flush(&mut self) -> Result<()>;
    /// Events in the open window.
    fn buffered(&self) -> usize;
    /// The rasterizer's counters.
    fn stats(&self) -> RasterStats;
}

/// A [`Rasterizer`] whose windows go to `on_window(index, window)`.
pub struct Rasterizing<S, F> {
    raster: Rasterizer<S>,
    on_window: F,
    windows: usize,
}

impl<S: RasterStorage, F: FnMut(usize, &Window<'_>) -> Result<()>> Rasterizing<S, F> {
    /// Hands `raster`'s windows to `on_window`.
    pub fn new(raster: Rasterizer<S>, on_window: F) -> Self {
        Self {
            raster,
            on_window,
            windows: 0,
        }
    }
}

impl<S: RasterStorage, F: FnMut(usize, &Window<'_>) -> Result<()>> WindowSink
    for Rasterizing<S, F>
{
    fn extend(&mut self, events: &[Event]) -> Result<(usize, bool)> {
        let (used, window) = self.raster.extend(events);
        let closed = window.is_some();
        if let Some(w) = window {
            (self.on_window)(self.windows, &w)?;
            self.windows += 1;
        }
        Ok((used, closed))
    }

    fn flush(&mut self) -> Result<()> {
        let w = self.raster.flush();
        (self.on_window)(self.windows, &w)?;
        self.windows += 1;
        Ok(())
    }

    fn buffered(&self) -> usize {
        self.raster.buffered()
    }

    fn stats(&self) -> RasterStats {
        *self.raster.stats()
    }
}

/// Sensor size for `camera`: the override, else the header's, else the largest supported.
pub fn sensor_size(info: &StreamInfo, camera: u8, size: Option<(u16, u16)>) -> (u16, u16) {
    size.or_else(|| {
        let c = info.cameras.iter().find(|c| c.id == camera)?;
        Some((c.width?, c.height?))
    })
    .unwrap_or((MAX_WIDTH, MAX_HEIGHT))
}

/// Counts the events of `camera` in a stream (reads it to the end).
pub fn count_events(reader: &mut dyn EventReader, camera: u8) -> Result<u64> {
    let mut batch = Batch::default();
    let mut n = 0u64;
    while reader.read_batch(&mut batch)? {
        n += batch.cameras.iter().filter(|&&c| c == camera).count() as u64;
    }
    Ok(n)
}

/// The loop over a reader: feeds `camera`'s events to `sink` batch by batch; the sink hands
/// each closed window on, in order. At the end of the input the open window is flushed if it
/// holds events; an input without any gives one empty window.
pub fn drive(
    reader: &mut dyn EventReader,
    windowing: Windowing,
    sink: &mut dyn WindowSink,
) -> Result<RunReport> {
    let mut batch = Batch::default();
    let mut selected = Vec::new();
    let mut windows = 0;
    let camera = windowing.camera;
    // With windows over all cameras: events of every camera in the open window, and whether
    // the camera's own window closed by count inside it.
    let shared = windowing.shared_events;
    let (mut in_window, mut closed_in_window) = (0u32, false);
    while reader.read_batch(&mut batch)? {
        let mut from = 0;
        while from < batch.events.len() {
            // The part of the batch inside the open window (all of it for per-camera windows).
            let to = match shared {
                Some(n) => batch.events.len().min(from + (n - in_window) as usize),
                None => batch.events.len(),
            };
            let (part, cams) = (&batch.events[from..to], &batch.cameras[from..to]);
            let events: &[Event] = if cams.iter().all(|&c| c == camera) {
                part
            } else {
                selected.clear();
                selected.extend(
                    part.iter()
                        .zip(cams)
                        .filter(|(_, &c)| c == camera)
                        .map(|(e, _)| *e),
                );
                &selected
            };
            let mut rest = events;
            while !rest.is_empty() {
                let (used, closed) = sink.extend(rest)?;
                if closed {
                    windows += 1;
                    closed_in_window = true;
                }
                rest = &rest[used..];
            }
            if let Some(n) = shared {
                in_window += (to - from) as u32;
                if in_window == n {
                    // The window ends with the n-th event of all cameras. If this camera had
                    // all n, its rasterizer closed it by count already; if it had none, the
                    // window is empty (and still a window, so that cameras stay aligned).
                    if !closed_in_window {
                        sink.flush()?;
                        windows += 1;
                    }
                    (in_window, closed_in_window) = (0, false);
                }
            }
            from = to;
        }
    }
    if sink.buffered() > 0 || windows == 0 || (in_window > 0 && !closed_in_window) {
        sink.flush()?;
        windows += 1;
    }
    Ok(RunReport {
        windows,
        stats: sink.stats(),
    })
}

/// Refuses a run in which every event fell outside the sensor (a wrong `--width/--height`, or
/// a file that states none).
pub fn check_in_sensor(report: &RunReport, (width, height): (u16, u16)) -> Result<()> {
    let s = report.stats;
    if s.dropped_out_of_range > 0 && s.accepted == 0 {
        bail!("every event lies outside the {width}×{height} sensor");
    }
    Ok(())
}

/// How `evpose raster` cuts and rasterizes a recording file.
#[derive(Clone, Debug)]
pub struct RasterOptions {
    /// How to read the file (format, fallback sensor size, text time unit). `open.size`, when
    /// given, is also the rasterizer's sensor size.
    pub open: OpenOptions,
    /// Time slices `K`.
    pub slices: u8,
    /// Events per window; `None` rasterizes the whole input as one window.
    pub window_events: Option<u32>,
    /// Camera to rasterize (multi-camera recordings).
    pub camera: u8,
    /// Count `window_events` over every camera's events ([`Windowing::shared_events`]).
    pub all_camera_windows: bool,
}

impl Default for RasterOptions {
    fn default() -> Self {
        Self {
            open: OpenOptions::default(),
            slices: evpose_core::raster::DEFAULT_SLICES,
            window_events: None,
            camera: 0,
            all_camera_windows: false,
        }
    }
}

/// What [`rasterize`] did.
#[derive(Clone, Debug)]
pub struct RasterReport {
    /// Windows produced.
    pub windows: usize,
    /// The rasterizer's counters.
    pub stats: RasterStats,
    /// The sensor size used.
    pub size: (u16, u16),
}

/// Rasterizes a recording file (`evpose raster`), calling `on_window(index, window)` for each
/// closed window in order: windows of `window_events` events (the last may be shorter), or the
/// whole input as one window (a counting pass first sizes it).
pub fn rasterize(
    path: &std::path::Path,
    opts: &RasterOptions,
    mut on_window: impl FnMut(usize, &Window<'_>) -> Result<()>,
) -> Result<RasterReport> {
    let mut reader = io::open_with(path, &opts.open)?;
    let size = sensor_size(reader.info(), opts.camera, opts.open.size);
    let capacity = match opts.window_events {
        Some(n) => n,
        None => {
            let info = reader.info();
            let n = match info.event_count {
                Some(n) if info.cameras.len() <= 1 => n,
                _ => count_events(io::open_with(path, &opts.open)?.as_mut(), opts.camera)
                    .with_context(|| path.display().to_string())?,
            };
            u32::try_from(n).context("too many events for one window; pass --window-events")?
        }
    };
    let mut sink = Rasterizing::new(rasterizer(size, opts.slices, capacity)?, |i, w| {
        on_window(i, w)
    });
    let windowing = Windowing {
        camera: opts.camera,
        shared_events: opts.window_events.filter(|_| opts.all_camera_windows),
    };
    let report =
        drive(reader.as_mut(), windowing, &mut sink).with_context(|| path.display().to_string())?;
    if opts.open.size.is_none() {
        check_in_sensor(&report, size)?;
    }
    Ok(RasterReport {
        windows: report.windows,
        stats: report.stats,
        size,
    })
}

/// A window's points as rows `[x, y, t_avg, p_acc, cnt]`.
pub fn window_rows(window: &Window<'_>) -> Vec<[f32; 5]> {
    window.iter().map(|p| p.features()).collect()
}

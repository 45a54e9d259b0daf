//! Whole recordings through the core: read, select a camera, rasterize window by window.
//!
//! The CLI's `raster` command and the parity tests both call [`rasterize`], so the tests check
//! the code path users run.

use std::path::Path;

use anyhow::{bail, Context, Result};
use evpose_core::raster::{RasterParts, MAX_HEIGHT, MAX_WIDTH};
use evpose_core::{RasterConfig, RasterStats, RasterStorage, Rasterizer, Window, WindowRule};

use crate::io::{self, Batch, Format, StreamInfo};

/// Heap-backed [`RasterStorage`] for windows of any size on the host.
pub struct VecStorage {
    a: Vec<u64>,
    b: Vec<u64>,
    hist_x: Vec<u32>,
    hist_rows: Vec<u32>,
}

impl VecStorage {
    /// Storage for windows of `capacity` events under `config`.
    pub fn new(capacity: usize, config: &RasterConfig) -> Self {
        Self {
            a: vec![0; capacity],
            b: vec![0; capacity],
            hist_x: vec![0; usize::from(config.width)],
            hist_rows: vec![0; config.row_bins()],
        }
    }
}

impl RasterStorage for VecStorage {
    fn parts(&mut self) -> RasterParts<'_> {
        RasterParts {
            a: &mut self.a,
            b: &mut self.b,
            hist_x: &mut self.hist_x,
            hist_rows: &mut self.hist_rows,
        }
    }

    fn words(&self) -> (&[u64], &[u64]) {
        (&self.a, &self.b)
    }
}

/// How to cut and rasterize a recording.
#[derive(Clone, Debug)]
pub struct RasterOptions {
    /// Force a file format instead of detecting it.
    pub format: Option<Format>,
    /// Sensor size; default: what the file states, else the largest supported size.
    pub size: Option<(u16, u16)>,
    /// Time slices `K`.
    pub slices: u8,
    /// Events per window; `None` rasterizes the whole input as one window.
    pub window_events: Option<u32>,
    /// Camera to rasterize (multi-camera recordings); events of other cameras are skipped.
    pub camera: u8,
    /// Count `window_events` over the events of every camera, rasterizing only `camera`'s
    /// events of each window, so that every camera gets the same windows (DHP19's "Mean
    /// Label" windows: 30,000 events over its four cameras). A window in which `camera` has no
    /// event is an empty window. Without `window_events`, no effect.
    pub all_camera_windows: bool,
}

impl Default for RasterOptions {
    fn default() -> Self {
        Self {
            format: None,
            size: None,
            slices: evpose_core::raster::DEFAULT_SLICES,
            window_events: None,
            camera: 0,
            all_camera_windows: false,
        }
    }
}

/// What a rasterization run did.
#[derive(Clone, Debug)]
pub struct RasterReport {
    /// The recording's header information.
    pub info: StreamInfo,
    /// The sensor size used.
    pub size: (u16, u16),
    /// Windows produced.
    pub windows: usize,
    /// The rasterizer's counters.
    pub stats: RasterStats,
}

/// Sensor size for `camera`: the override, else the header's, else the largest supported.
pub fn sensor_size(info: &StreamInfo, camera: u8, size: Option<(u16, u16)>) -> (u16, u16) {
    size.or_else(|| {
        let c = info.cameras.iter().find(|c| c.id == camera)?;
        Some((c.width?, c.height?))
    })
    .unwrap_or((MAX_WIDTH, MAX_HEIGHT))
}

/// Counts the events of `camera` in a recording (a streaming pass).
pub fn count_events(path: &Path, format: Option<Format>, camera: u8) -> Result<u64> {
    let mut reader = io::open(path, format)?;
    let mut batch = Batch::default();
    let mut n = 0u64;
    while reader
        .read_batch(&mut batch)
        .with_context(|| format!("{}", path.display()))?
    {
        n += batch.cameras.iter().filter(|&&c| c == camera).count() as u64;
    }
    Ok(n)
}

/// Rasterizes a recording, calling `on_window(index, window)` for each closed window in order.
///
/// Windows of `window_events` events (the last one may be shorter), or the whole input as one
/// window. An input without events gives one empty window.
pub fn rasterize(
    path: &Path,
    opts: &RasterOptions,
    mut on_window: impl FnMut(usize, &Window<'_>) -> Result<()>,
) -> Result<RasterReport> {
    let mut reader = io::open(path, opts.format)?;
    let info = reader.info().clone();
    let (width, height) = sensor_size(&info, opts.camera, opts.size);
    let capacity = match opts.window_events {
        Some(n) => n as usize,
        None => match info.event_count {
            Some(n) if info.cameras.len() <= 1 => n as usize,
            _ => count_events(path, opts.format, opts.camera)? as usize,
        },
    };
    let config = RasterConfig {
        width,
        height,
        slices: opts.slices,
        window: WindowRule::Events(capacity.max(1) as u32),
    };
    let mut raster = Rasterizer::new(config, VecStorage::new(capacity.max(1), &config))
        .context("invalid rasterization settings")?;
    let mut batch = Batch::default();
    let mut selected = Vec::new();
    let mut windows = 0;
    // With windows over all cameras: events of every camera in the open window, and the
    // window length in events of every camera.
    let shared = opts.window_events.filter(|_| opts.all_camera_windows);
    let (mut in_window, mut closed_in_window) = (0u32, false);
    while reader
        .read_batch(&mut batch)
        .with_context(|| format!("{}", path.display()))?
    {
        let mut from = 0;
        while from < batch.events.len() {
            // The part of the batch inside the open window (all of it for per-camera windows).
            let to = match shared {
                Some(n) => batch.events.len().min(from + (n - in_window) as usize),
                None => batch.events.len(),
            };
            let (part, cams) = (&batch.events[from..to], &batch.cameras[from..to]);
            let events: &[evpose_core::Event] = if cams.iter().all(|&c| c == opts.camera) {
                part
            } else {
                selected.clear();
                selected.extend(
                    part.iter()
                        .zip(cams)
                        .filter(|(_, &c)| c == opts.camera)
                        .map(|(e, _)| *e),
                );
                &selected
            };
            let mut rest = events;
            while !rest.is_empty() {
                let (used, window) = raster.extend(rest);
                if let Some(w) = window {
                    on_window(windows, &w)?;
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
                        on_window(windows, &raster.flush())?;
                        windows += 1;
                    }
                    (in_window, closed_in_window) = (0, false);
                }
            }
            from = to;
        }
    }
    if raster.buffered() > 0 || windows == 0 || (in_window > 0 && !closed_in_window) {
        on_window(windows, &raster.flush())?;
        windows += 1;
    }
    let stats = *raster.stats();
    if stats.dropped_out_of_range > 0 && opts.size.is_none() && windows == 1 && stats.accepted == 0
    {
        bail!("every event lies outside the {width}×{height} sensor");
    }
    Ok(RasterReport {
        info,
        size: (width, height),
        windows,
        stats,
    })
}

/// A window's points as rows `[x, y, t_avg, p_acc, cnt]`.
pub fn window_rows(window: &Window<'_>) -> Vec<[f32; 5]> {
    window.iter().map(|p| p.features()).collect()
}

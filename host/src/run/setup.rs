//! What `evpose run` runs: the recording (a file, or the bundled clip), the model and its
//! engine, the cameras, the window rule, the filter, ground truth and calibration, each from
//! what was asked or from the defaults, resolved before the run so that it can be described
//! (and pictures sized) first.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use evpose_core::smooth::Filter;
use evpose_core::DType;

use super::camera::{self, CameraEstimator, Rescale};
use super::truth::{self, Truth};
use super::windows::{WindowEvents, WindowRule};
use super::{CameraSetup, RunOptions, RunSummary, RunWindow, WindowTruth};
use crate::io::{self, EventReader, Format, OpenOptions};
use crate::model::{self, AlignedBlob, CoreRunner};
use crate::{assets, dhp19};

/// The engine that runs the network.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum EngineKind {
    /// tract on an ONNX file (any backbone: PointNet, DGCNN, Point Transformer).
    Tract,
    /// The core's f32 engine (an f32 blob, or a PointNet ONNX file imported).
    F32,
    /// The core's int8 engine (an `.evq` int8 blob): what the firmware runs.
    I8,
}

impl std::fmt::Display for EngineKind {
    /// The name `--engine` takes: `tract`, `f32` or `i8`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Tract => "tract",
            Self::F32 => "f32",
            Self::I8 => "i8",
        })
    }
}

/// What to run, as asked (every `None` takes the default).
#[derive(Clone, Debug, Default)]
pub struct Request {
    /// Recording; `None`: the bundled clip.
    pub events: Option<PathBuf>,
    /// How to read it.
    pub open: OpenOptions,
    /// Model; `None`: the bundled MCU model.
    pub model: Option<PathBuf>,
    /// Engine; `None`: by the model (int8 blob: i8, f32 blob: f32, ONNX: tract).
    pub engine: Option<EngineKind>,
    /// Cameras; `None`: DHP19's front pair (2, 3) for DHP19-layout recordings, else the first.
    pub cameras: Option<Vec<u8>>,
    /// Events per window over all cameras; `None`: the model's window × the cameras in the
    /// recording (7,500 × 4 = DHP19's 30,000).
    pub window_events: Option<u32>,
    /// Window length, ms (instead of events).
    pub window_ms: Option<f64>,
    /// Stride in the window's unit (events or ms); `None`: the window (no overlap).
    pub stride: Option<f64>,
    /// Points per network input; `None`: the model's.
    pub points: Option<usize>,
    /// Seed of the point samplers.
    pub seed: u64,
    /// The temporal filter.
    pub filter: Filter,
    /// Ground truth file; `None`: beside the recording, if any (the bundled clip's own).
    pub gt: Option<PathBuf>,
    /// Calibration directory; `None`: beside the recording, else DHP19's for DHP19 files.
    pub calibration: Option<PathBuf>,
    /// Most events of a time window.
    pub capacity: usize,
}

/// The most events a time window holds, by default.
pub const DEFAULT_TIME_WINDOW_CAPACITY: usize = 200_000;

enum Loaded {
    /// A blob for the core's engines (estimators borrow it, so they are made per run).
    Core(Box<AlignedBlob>),
    /// Estimators that own their model (tract).
    #[cfg_attr(not(feature = "onnx"), allow(dead_code))]
    Owned(Vec<Box<dyn CameraEstimator>>),
}

/// A resolved run, ready to go.
pub struct Plan {
    reader: Box<dyn EventReader>,
    loaded: Loaded,
    points: usize,
    seed: u64,
    /// The options the run uses.
    pub options: RunOptions,
    /// Ground truth, when found.
    pub truth: Option<Truth>,
    /// What runs, for people: source, model, engine, truth.
    pub description: Description,
}

/// A resolved run in words.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Description {
    /// The recording.
    pub events: String,
    /// The model.
    pub model: String,
    /// The engine.
    pub engine: EngineKind,
    /// Points per input.
    pub points: usize,
    /// The window rule.
    pub window: String,
    /// Where the ground truth comes from.
    pub truth: Option<String>,
    /// Whether the recording is synthetic (the bundled clip, or `evpose sim` output).
    pub synthetic: bool,
    /// The temporal filter, in words.
    pub filter: String,
}

impl Plan {
    /// Resolves a request.
    pub fn resolve(req: &Request) -> Result<Self> {
        let (reader, events_name) = match &req.events {
            Some(p) => (io::open_with(p, &req.open)?, p.display().to_string()),
            None => (assets::clip()?, assets::CLIP_NAME.to_owned()),
        };
        let info = reader.info().clone();
        let dhp19_layout = info.format == Format::Aedat2Dhp19;
        let ids: Vec<u8> = match &req.cameras {
            Some(c) if !c.is_empty() => c.clone(),
            _ if dhp19_layout => dhp19::FRONT_CHANNELS.to_vec(),
            _ => vec![info.cameras.first().map_or(0, |c| c.id)],
        };
        // A file that lists no camera has one, camera 0.
        let have: Vec<u8> = match info.cameras.len() {
            0 => vec![0],
            _ => info.cameras.iter().map(|c| c.id).collect(),
        };
        if let Some(bad) = ids.iter().find(|c| !have.contains(c)) {
            bail!("{events_name} has no camera {bad} (cameras {have:?})");
        }
        if let Some((_, c)) = ids.iter().enumerate().find(|(i, c)| ids[..*i].contains(c)) {
            bail!("camera {c} is listed twice in --cameras");
        }
        let recording_cameras = info.cameras.len().max(1) as u32;

        // The model and its engine.
        let name = req
            .model
            .as_ref()
            .map_or(assets::DEFAULT_MODEL_NAME.to_owned(), |p| {
                p.display().to_string()
            });
        let is_onnx = req
            .model
            .as_ref()
            .is_some_and(|p| p.extension().is_some_and(|e| e == "onnx"));
        let engine = req.engine.unwrap_or(if is_onnx {
            EngineKind::Tract
        } else {
            EngineKind::I8
        });
        let mut window_per_camera = evpose_core::raster::DEFAULT_WINDOW_EVENTS;
        let (loaded, points, model_size, engine) = match engine {
            EngineKind::Tract => {
                #[cfg(feature = "onnx")]
                {
                    let Some(path) = req.model.as_ref().filter(|_| is_onnx) else {
                        bail!("--engine tract runs an .onnx model (--model M.onnx)");
                    };
                    let capacity = capacity_for(req, window_per_camera * recording_cameras);
                    // One load (and tract optimization) for every camera: they share the plan.
                    let first = camera::TractCamera::load(path, req.points, capacity, req.seed)?;
                    let (size, points) = (first.1, first.0.points());
                    let mut estimators: Vec<Box<dyn CameraEstimator>> = Vec::new();
                    for i in 1..ids.len() {
                        let seed = req.seed.wrapping_add(i as u64);
                        estimators.push(Box::new(first.0.with_seed(seed)?));
                    }
                    estimators.insert(0, Box::new(first.0));
                    (Loaded::Owned(estimators), points, size, engine)
                }
                #[cfg(not(feature = "onnx"))]
                bail!("this evpose was built without tract (cargo feature `onnx`)");
            }
            EngineKind::F32 | EngineKind::I8 => {
                let blob = match &req.model {
                    Some(p) => model::load_blob(p)?,
                    None => assets::default_blob(),
                };
                let runner = CoreRunner::new(&blob).with_context(|| name.clone())?;
                let m = runner.model();
                let dtype = match engine {
                    EngineKind::I8 => DType::I8,
                    _ => DType::F32,
                };
                if m.dtype() != dtype {
                    bail!(
                        "{name} is an {} model; --engine {} needs {}",
                        m.dtype(),
                        if dtype == DType::I8 { "i8" } else { "f32" },
                        if dtype == DType::I8 {
                            "an int8 blob (evpose quantize makes one)"
                        } else {
                            "an f32 blob or an .onnx file"
                        }
                    );
                }
                let p = m.preprocessing();
                if p.window_events > 0 {
                    window_per_camera = p.window_events;
                }
                let points = req.points.unwrap_or(m.input_points());
                let size = (m.width() as u16, m.height() as u16);
                drop(runner);
                (Loaded::Core(Box::new(blob)), points, size, engine)
            }
        };

        // Windows.
        let (rule, window) = match (req.window_ms, req.window_events) {
            (Some(_), Some(_)) => bail!("give --window-events or --window-ms, not both"),
            (Some(ms), None) => {
                let size_us = (ms * 1e3).round() as i64;
                let stride_us = req.stride.map_or(size_us, |s| (s * 1e3).round() as i64);
                (
                    WindowRule::Time { size_us, stride_us },
                    format!("{ms} ms, every {} ms", stride_us as f64 / 1e3),
                )
            }
            (None, n) => {
                let size = n.unwrap_or(window_per_camera * recording_cameras);
                let stride = req.stride.map_or(size, |s| s.round() as u32);
                (
                    WindowRule::Events { size, stride },
                    format!(
                        "{size} events over {} camera(s), every {stride} events",
                        recording_cameras
                    ),
                )
            }
        };
        rule.check()?;

        // Cameras: sizes, calibration.
        let cal_dir = req
            .calibration
            .clone()
            .or_else(|| req.events.as_deref().and_then(truth::calibration_beside));
        let cameras = ids
            .iter()
            .map(|&id| {
                // The size the file states wins (as in every reader: `OpenOptions::size`), then
                // `--width/--height`; a file that states none (npy, text) without them is taken
                // to be at the model's resolution, events beyond it dropped by the rasterizer
                // and counted.
                let stated = info
                    .cameras
                    .iter()
                    .find(|c| c.id == id)
                    .and_then(|c| Some((c.width?, c.height?)));
                let sensor = stated.or(req.open.size).unwrap_or(model_size);
                Ok(CameraSetup {
                    id,
                    rescale: Rescale {
                        sensor,
                        model: model_size,
                    },
                    calibration: truth::calibration(cal_dir.as_deref(), &info, id)?,
                })
            })
            .collect::<Result<Vec<_>>>()?;

        // Ground truth.
        let (truth, truth_name) = match (&req.gt, &req.events) {
            (Some(p), _) => (Some(Truth::load(p)?), Some(p.display().to_string())),
            (None, Some(e)) => match Truth::beside(e) {
                Some(p) => (Some(Truth::load(&p)?), Some(p.display().to_string())),
                None => (None, None),
            },
            (None, None) => (
                Some(Truth::from_npy_bytes(assets::CLIP_GT)?),
                Some(format!("{} (bundled)", assets::CLIP_GT_NAME)),
            ),
        };
        let synthetic = req.events.is_none()
            || req.events.as_deref().is_some_and(|e| {
                e.parent()
                    .is_some_and(|d| d.join(crate::simulate::MANIFEST).is_file())
            });
        let capacity = capacity_for(req, window_per_camera * recording_cameras);
        Ok(Self {
            reader,
            loaded,
            points,
            seed: req.seed,
            options: RunOptions {
                cameras,
                rule,
                capacity,
                filter: req.filter,
                callback_events: true,
            },
            truth,
            description: Description {
                events: events_name,
                model: name,
                engine,
                points,
                window,
                truth: truth_name,
                synthetic,
                filter: describe_filter(&req.filter),
            },
        })
    }

    /// Whether the run gives 3-D joints (two or more calibrated cameras).
    pub fn triangulates(&self) -> bool {
        self.options
            .cameras
            .iter()
            .filter(|c| c.calibration.is_some())
            .count()
            >= 2
    }

    /// Runs it, calling `on_window` for each window in order.
    pub fn run(
        mut self,
        on_window: impl FnMut(&RunWindow, &WindowEvents<'_>, Option<&WindowTruth>) -> Result<()>,
    ) -> Result<RunSummary> {
        let capacity = self.options.capacity;
        let truth = self.truth.as_ref();
        match &mut self.loaded {
            Loaded::Core(blob) => {
                let runner = CoreRunner::new(blob)?;
                let mut estimators = camera::core_estimators(
                    &runner,
                    self.options.cameras.len(),
                    self.points,
                    capacity,
                    self.seed,
                )?;
                super::run(
                    self.reader.as_mut(),
                    &mut estimators,
                    &self.options,
                    truth,
                    on_window,
                )
            }
            Loaded::Owned(estimators) => super::run(
                self.reader.as_mut(),
                estimators,
                &self.options,
                truth,
                on_window,
            ),
        }
    }
}

/// The filter in words, for `evpose run`'s header.
pub fn describe_filter(f: &Filter) -> String {
    match f {
        Filter::Off => "off".into(),
        Filter::OneEuro(p) => format!(
            "causal One-Euro (min cut-off {} Hz, beta {}, full step at confidence {})",
            p.min_cutoff_hz, p.beta, p.full_confidence
        ),
        Filter::FixedLag(p) => format!(
            "fixed-lag confidence-weighted mean of {} windows (each window out {} windows later)",
            2 * p.lag + 1,
            p.lag
        ),
    }
}

fn capacity_for(req: &Request, events_window: u32) -> usize {
    match (req.window_ms, req.window_events) {
        (Some(_), _) => req.capacity.max(1),
        (None, Some(n)) => n as usize,
        (None, None) => events_window as usize,
    }
}

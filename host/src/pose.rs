//! Poses from a recording: any event source through the core's per-window [`Session`] with a
//! model, one [`WindowPose`] per window (the JSON schema `evpose pose --json` writes and
//! `evpose triangulate` reads, defined once here).

use anyhow::{Context, Result};
use evpose_core::pipeline::{Engine, Estimate, Workspace, F32, I8};
use evpose_core::raster::{DEFAULT_SLICES, DEFAULT_WINDOW_EVENTS};
use evpose_core::{DType, Estimator, Joint2d, Plan, Session};
use serde::{Deserialize, Serialize};

use crate::io::EventReader;
use crate::model::CoreRunner;
use crate::pipeline::{self, Estimating, RunReport, VecStorage, Windowing};

/// How a recording is cut, rasterized and sampled for a model.
#[derive(Clone, Copy, Debug)]
pub struct PoseOptions {
    /// Which camera, and windows per camera or over all cameras.
    pub windowing: Windowing,
    /// Events per window (of the camera, or of all cameras with `windowing.shared_events`).
    pub window_events: u32,
    /// Time slices `K`.
    pub slices: u8,
    /// Points per network input `N` (0 keeps every point).
    pub points: usize,
    /// Seed of the point sampler (one generator for the whole stream).
    pub seed: u64,
    /// Sensor size; `None`: what the reader states, else the largest supported.
    pub size: Option<(u16, u16)>,
}

impl PoseOptions {
    /// The preprocessing a model's blob records, with the defaults (2,048 points, 7,500 events,
    /// 4 slices) for what it does not state.
    pub fn for_model(model: &evpose_core::Model<'_>) -> Self {
        let p = model.preprocessing();
        let or = |v: u32, d: u32| if v == 0 { d } else { v };
        Self {
            windowing: Windowing::default(),
            window_events: or(p.window_events, DEFAULT_WINDOW_EVENTS),
            slices: if p.slices == 0 {
                DEFAULT_SLICES
            } else {
                p.slices
            },
            points: model.input_points(),
            seed: 0,
            size: None,
        }
    }
}

/// Below this mean joint confidence a window is reported as showing no body. Measured with
/// the bundled MCU model on the held-out synthetic set (camera 2): 12.6 % of the 1,027 windows
/// with a person fall below it, 86 % of the 14 person-free windows (bouncing balls, a spinning
/// stick) and all 11 windows of the real DAVIS346 street recording (cars).
pub const NO_BODY_CONFIDENCE: f32 = 0.40;

/// One window's pose: one JSON line of `evpose pose --json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WindowPose {
    /// Window index.
    #[serde(default)]
    pub window: usize,
    /// First and last timestamp, µs; `None` (JSON `null`) for a window without events.
    #[serde(default)]
    pub t_us: Option<(i64, i64)>,
    /// Points in the rasterized window.
    #[serde(default)]
    pub points: usize,
    /// Joints `(x, y)` in pixels, in the model's joint order.
    pub joints: Vec<(u16, u16)>,
    /// Confidence of each joint in [0, 1] ([`evpose_core::confidence`]); empty when the model
    /// carries no logit scales (int8 blobs before version 3).
    #[serde(default)]
    pub confidence: Vec<f32>,
}

impl WindowPose {
    /// The pose of an estimate; `scales` are the model's logit scales
    /// ([`evpose_core::Model::head_scales`]), `None` for no confidences.
    pub fn of(e: &Estimate<'_>, scales: Option<[f32; 2]>) -> Self {
        let s = e.window.summary();
        let mut confidence = vec![0f32; if scales.is_some() { e.joints.len() } else { 0 }];
        if let Some(scales) = scales {
            // The estimate's heads and joints agree in shape by construction.
            if e.confidence(scales, &mut confidence).is_err() {
                confidence.clear();
            }
        }
        Self {
            window: e.index as usize,
            t_us: (s.events > 0).then_some((s.t_min, s.t_max)),
            points: e.window.len(),
            joints: e.joints.iter().map(|j| (j.x, j.y)).collect(),
            confidence,
        }
    }

    /// Whether the window shows no body by [`NO_BODY_CONFIDENCE`] (`None` without
    /// confidences).
    pub fn no_body(&self) -> Option<bool> {
        self.mean_confidence().map(|c| c < NO_BODY_CONFIDENCE)
    }

    /// Mean joint confidence (`None` without confidences).
    pub fn mean_confidence(&self) -> Option<f32> {
        (!self.confidence.is_empty())
            .then(|| self.confidence.iter().sum::<f32>() / self.confidence.len() as f32)
    }
}

/// The heap buffers a host [`Workspace`] borrows, for engine `E`.
pub struct Buffers<E: Engine> {
    indices: Vec<u32>,
    rows: Vec<[f32; 5]>,
    scratch: Vec<E::Value>,
    x: Vec<E::Value>,
    y: Vec<E::Value>,
    joints: Vec<Joint2d>,
}

impl<E: Engine> Buffers<E> {
    /// Buffers for `plan` with `points` points per input, windows of up to `capacity` events
    /// (`points` 0 keeps every point: up to one per event).
    pub fn new(plan: &Plan<'_>, points: usize, capacity: usize) -> Self {
        let rows = if points == 0 { capacity.max(1) } else { points };
        Self {
            indices: vec![0; rows],
            rows: vec![[0.0; 5]; rows],
            scratch: vec![E::Value::default(); plan.scratch_words()],
            x: vec![E::Value::default(); plan.out_x_len()],
            y: vec![E::Value::default(); plan.out_y_len()],
            joints: vec![Joint2d::default(); plan.model().joints()],
        }
    }

    /// The workspace over these buffers.
    pub fn workspace(&mut self) -> Workspace<'_, E> {
        Workspace {
            indices: &mut self.indices,
            rows: &mut self.rows,
            scratch: &mut self.scratch,
            x: &mut self.x,
            y: &mut self.y,
            joints: &mut self.joints,
        }
    }
}

/// Runs a recording through the whole pipeline with `runner`'s model, calling `on_window`
/// with each window's estimate, in order.
pub fn estimate(
    reader: &mut dyn EventReader,
    runner: &CoreRunner<'_>,
    opts: &PoseOptions,
    mut on_window: impl FnMut(&Estimate<'_>) -> Result<()>,
) -> Result<RunReport> {
    let size = pipeline::sensor_size(reader.info(), opts.windowing.camera, opts.size);
    let raster = pipeline::rasterizer(size, opts.slices, opts.window_events)?;
    let plan = runner.plan()?;
    let session = Session::new(raster, Estimator::new(plan, opts.points, opts.seed));
    let report = match runner.model().dtype() {
        DType::I8 => run::<I8>(reader, session, opts, &mut on_window)?,
        DType::F32 => run::<F32>(reader, session, opts, &mut on_window)?,
    };
    if opts.size.is_none() {
        pipeline::check_in_sensor(&report, size)?;
    }
    Ok(report)
}

fn run<E: Engine>(
    reader: &mut dyn EventReader,
    session: Session<'_, VecStorage>,
    opts: &PoseOptions,
    on_window: &mut dyn FnMut(&Estimate<'_>) -> Result<()>,
) -> Result<RunReport> {
    let plan = *session.estimator().plan();
    let mut buffers = Buffers::<E>::new(&plan, opts.points, opts.window_events as usize);
    let mut sink = Estimating::new(session, buffers.workspace(), |e| on_window(e));
    pipeline::drive(reader, opts.windowing, &mut sink)
}

/// [`estimate`], giving each window's [`WindowPose`].
pub fn poses(
    reader: &mut dyn EventReader,
    runner: &CoreRunner<'_>,
    opts: &PoseOptions,
    mut on_pose: impl FnMut(WindowPose) -> Result<()>,
) -> Result<RunReport> {
    let scales = runner.model().head_scales();
    estimate(reader, runner, opts, |e| on_pose(WindowPose::of(e, scales)))
        .context("pose estimation")
}

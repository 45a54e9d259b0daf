//! `evpose run`, the main job: a recording in, per window and camera 2-D joints with their
//! confidences, the temporal filter over windows, and with two or more calibrated cameras 3-D
//! joints by confidence-weighted triangulation; errors against ground truth when the
//! recording has some.
//!
//! The stream is read once, in batches, and cut into windows over all cameras together
//! ([`windows::Cutter`]: by events or time, tumbling or sliding); each window's events of each
//! selected camera go through that camera's estimator ([`camera`]: the core's per-window
//! [`evpose_core::Session`], or tract); memory is one window of events plus the estimators
//! (with the fixed-lag filter, also the events of the windows waiting for their later ones).
//! Output goes to a callback as [`RunWindow`]s, the schema [`output`] writes.

pub mod camera;
pub mod output;
pub mod setup;
pub mod truth;
pub mod windows;

use anyhow::{bail, Context, Result};
use evpose_core::geometry::{triangulate_views, Camera};
use evpose_core::pipeline::{Engine, Workspace};
use evpose_core::smooth::{AxisState, Filter, FixedLag, Held, LagSlot, Smoother};
use evpose_core::{Event, Joint2d, Plan};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

use crate::dataset::JOINTS;
use crate::io::{Batch, EventReader};
use camera::{CameraEstimator, Raw, Rescale};
use truth::Truth;
use windows::{Cutter, WindowEvents, WindowRule};

/// Fewer than two calibrated cameras: below this mean joint confidence a window is reported as
/// showing no body. Chosen on two synthetic validation subjects (seed 600) and 20 person-free
/// recordings (seed 3500) with the bundled MCU model, which was trained with person-free
/// windows; measured on the held-out synthetic test subject, DHP19's windows: camera 2 alone,
/// 3.1 % of the 1,143 windows with a person fall below it and 88.5 % of the 1,321 person-free
/// ones (bouncing balls, a spinning stick); the mean over cameras 2 and 3, 2.2 % and 98 %; and
/// all 10 windows of the real DAVIS346 street recording (cars, one camera; mean 0.08).
pub const NO_BODY_CONFIDENCE: f32 = 0.32;

/// Two or more calibrated cameras: a window shows no body when its mean joint confidence is
/// below `NO_BODY_VIEWS_BASE + NO_BODY_VIEWS_SLOPE · ln(d)`, `d` its view disagreement in
/// pixels ([`view_disagreement_px`], at least 1): the more the views disagree, the surer the
/// network must be (the line crosses [`NO_BODY_CONFIDENCE`] at 7.4 px). A body is one 3-D
/// object that every camera sees, so the network's joints of it triangulate consistently; its
/// guesses on a scene without a person do not. Chosen with the bundled MCU model on DHP19's
/// front pair (cameras 2 and 3) of two synthetic validation subjects (seed 600) and 20
/// person-free recordings (seed 3500), the line (of a grid over base and slope) with the fewest
/// windows wrong on both sides together; on the held-out test subject it flags 1.7 % of the
/// windows with a person and 98.8 % of the person-free ones (README, "What the models do"). With more
/// cameras the per-view residual may differ: the line was not tuned for them.
pub const NO_BODY_VIEWS_BASE: f32 = 0.16;

/// The slope of the two-view no-body line per natural log of pixels ([`NO_BODY_VIEWS_BASE`]).
pub const NO_BODY_VIEWS_SLOPE: f32 = 0.08;

/// Whether a window shows no body, from its mean joint confidence over cameras and joints and,
/// with two or more calibrated cameras, its [`view_disagreement_px`]: below
/// [`NO_BODY_CONFIDENCE`] without one (or when it is not finite); below the line of
/// [`NO_BODY_VIEWS_BASE`] with one. A confidence that is not a number shows no body.
pub fn no_body_seen(mean_confidence: f32, view_disagreement_px: Option<f64>) -> bool {
    let needed = match view_disagreement_px {
        Some(d) if d.is_finite() => {
            let d = (d as f32).max(1.0);
            NO_BODY_VIEWS_BASE + NO_BODY_VIEWS_SLOPE * d.ln()
        }
        _ => NO_BODY_CONFIDENCE,
    };
    // A NaN confidence is no evidence of a body (a plain `<` would say it is).
    mean_confidence.is_nan() || mean_confidence < needed
}

/// The smallest weight a view gets in triangulation: a joint no camera is sure of is still
/// triangulated (from near-equal weights).
pub const MIN_VIEW_WEIGHT: f64 = 1e-3;

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
            // With the words that let the activation rows start at a cache line.
            scratch: vec![
                E::Value::default();
                plan.scratch_words() + evpose_core::infer::ALIGN_WORDS
            ],
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

/// One camera of a run.
#[derive(Clone, Debug)]
pub struct CameraSetup {
    /// Camera id in the recording.
    pub id: u8,
    /// Its sensor size and the model's resolution.
    pub rescale: Rescale,
    /// Its calibration, for 3-D and for projecting ground truth.
    pub calibration: Option<Camera>,
}

/// How a run cuts, filters and reports.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The cameras to estimate.
    pub cameras: Vec<CameraSetup>,
    /// How windows are cut (over the events of all cameras of the recording).
    pub rule: WindowRule,
    /// The most events a time window holds.
    pub capacity: usize,
    /// The temporal filter.
    pub filter: Filter,
    /// Whether the callback gets each window's events (to draw them). With the fixed-lag
    /// filter a window's events are copied while it waits for its later windows; without
    /// them, every window comes to the callback with an empty event list (its
    /// [`RunWindow::events`] still counts them).
    pub callback_events: bool,
}

/// One camera's pose in one window: a line of the output.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraPose {
    /// Camera id.
    pub camera: u8,
    /// The camera's events in the window.
    pub events: usize,
    /// Points of its rasterized window.
    pub points: usize,
    /// Joints `[x, y]` in the sensor's pixels (DHP19's `(u, v)`: column, row from the top
    /// left), model joint order; filtered when the filter is on.
    pub joints: Vec<[f32; 2]>,
    /// The network's joints before the filter (present when the filter is on).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub raw_joints: Option<Vec<[f32; 2]>>,
    /// Confidence of each joint in [0, 1] (empty when the model gives none).
    pub confidence: Vec<f32>,
}

impl CameraPose {
    /// Mean joint confidence (`None` without confidences).
    pub fn mean_confidence(&self) -> Option<f32> {
        (!self.confidence.is_empty())
            .then(|| self.confidence.iter().sum::<f32>() / self.confidence.len() as f32)
    }
}

/// Errors of one window against ground truth.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WindowError {
    /// Mean 2-D error of each camera's visible joints, pixels (camera id, error).
    pub mpjpe2d_px: Vec<(u8, f64)>,
    /// Mean 3-D error of the triangulated joints, mm.
    pub mpjpe3d_mm: Option<f64>,
}

/// One window's result: an object of `evpose run`'s output.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunWindow {
    /// Window index from 0.
    pub window: usize,
    /// Time span, µs ([`WindowEvents::t_us`]).
    pub t_us: [i64; 2],
    /// Events of every camera in the window.
    pub events: usize,
    /// Whether the window shows no body ([`no_body_seen`]: its mean confidence over cameras
    /// and joints and, with two or more calibrated cameras, how far their views disagree;
    /// `None` without confidences).
    pub no_body: Option<bool>,
    /// How far the views' joints (the network's, before the temporal filter) disagree, pixels
    /// ([`view_disagreement_px`]; absent with fewer than two calibrated cameras, or when no
    /// joint was triangulated).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_disagreement_px: Option<f64>,
    /// Each selected camera's pose.
    pub cameras: Vec<CameraPose>,
    /// 3-D joints `[x, y, z]`, mm in the calibration's world frame, from the (filtered)
    /// joints of every calibrated camera, weighted by confidence; `null` for a joint that could
    /// not be triangulated. Absent with fewer than two calibrated cameras.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joints3d: Option<Vec<Option<[f64; 3]>>>,
    /// Errors against ground truth (present when the recording has some).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<WindowError>,
}

/// Ground truth of one window, for pictures: the 3-D label and each camera's projection.
#[derive(Clone, Debug)]
pub struct WindowTruth {
    /// Mean 3-D pose over the window, mm.
    pub joints3d: [[f32; 3]; JOINTS],
    /// Per selected camera (in order): 2-D label (integer pixels) and visibility.
    pub cameras: Vec<([[f32; 2]; JOINTS], [u8; JOINTS])>,
}

/// Mean errors over a run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Errors {
    /// MPJPE2D of the reported (filtered) joints, pixels.
    pub mpjpe2d_px: Option<f64>,
    /// MPJPE2D of the network's joints before the filter.
    pub mpjpe2d_raw_px: Option<f64>,
    /// MPJPE3D of the reported 3-D joints, mm.
    pub mpjpe3d_mm: Option<f64>,
    /// MPJPE3D from the network's joints before the filter.
    pub mpjpe3d_raw_mm: Option<f64>,
    /// Windows with ground truth.
    pub windows: usize,
}

/// What a run did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RunSummary {
    /// Windows estimated.
    pub windows: usize,
    /// Cameras estimated.
    pub cameras: Vec<u8>,
    /// Events read (all cameras).
    pub events: u64,
    /// Events dropped from over-full time windows.
    pub dropped: u64,
    /// Empty time windows skipped over long gaps (beyond `windows::MAX_GAP_WINDOWS` in a row).
    pub skipped_windows: u64,
    /// Camera windows without events: guesses, left out of triangulation, of the views'
    /// disagreement, of the no-body test and of the mean confidence.
    pub empty_views: usize,
    /// Mean joint confidence over all windows and the cameras that saw events in them.
    pub mean_confidence: Option<f64>,
    /// Windows that show no body ([`no_body_seen`]).
    pub no_body_windows: usize,
    /// Windows judged with their views' disagreement (two or more calibrated cameras), not by
    /// confidence alone.
    pub views_compared: usize,
    /// Errors against ground truth, when there is some.
    pub errors: Option<Errors>,
}

impl RunSummary {
    /// Whether most windows show no body (`false` without confidences).
    pub fn no_body(&self) -> bool {
        self.windows > 0 && 2 * self.no_body_windows > self.windows
    }
}

#[derive(Default)]
struct Sums {
    d2: (f64, u64),
    d2_raw: (f64, u64),
    d3: (f64, u64),
    d3_raw: (f64, u64),
    windows: usize,
}

fn mean((s, n): (f64, u64)) -> Option<f64> {
    (n > 0).then(|| s / n as f64)
}

/// Triangulates each joint from the views of `cams` (`joints[i]` and `confidence[i]` of camera
/// `i`) that saw events (`seen[i]`: a camera without events in the window has only a guess);
/// `None` when fewer than two cameras are calibrated.
fn triangulate_window(
    cams: &[CameraSetup],
    joints: &[&[[f32; 2]]],
    confidence: &[&[f32]],
    seen: &[bool],
) -> Option<Vec<Option<[f64; 3]>>> {
    let calibrated: Vec<usize> = (0..cams.len())
        .filter(|&i| cams[i].calibration.is_some())
        .collect();
    if calibrated.len() < 2 {
        return None;
    }
    let n = joints.iter().map(|j| j.len()).min().unwrap_or(0);
    Some(
        (0..n)
            .map(|j| {
                let views: Vec<(&Camera, (f64, f64), f64)> = calibrated
                    .iter()
                    .filter_map(|&i| {
                        let cam = cams[i].calibration.as_ref()?;
                        let [u, v] = joints[i][j];
                        // Weight 0 leaves the view out.
                        let w = match confidence[i].get(j) {
                            _ if !seen.get(i).copied().unwrap_or(true) => 0.0,
                            Some(&c) => f64::from(c).max(MIN_VIEW_WEIGHT),
                            None => 1.0,
                        };
                        Some((cam, (f64::from(u), f64::from(v)), w))
                    })
                    .collect();
                triangulate_views(&views).ok()
            })
            .collect(),
    )
}

/// How far a window's views disagree: the mean distance, pixels, between each calibrated
/// camera's `joints` and the projection of the triangulated `joints3d` into it, over every
/// joint that was triangulated and projects and every camera that saw events (`seen`; all
/// when it is shorter); `None` without such views or 3-D joints.
/// Views of one body agree to a few pixels (median 3.2 px on the held-out synthetic test
/// subject, the network's joints before the filter); guesses on a scene without a person do
/// not (median 10.3 px). `evpose run` measures it on the network's joints before the temporal
/// filter, which holds an unsure joint where it was (and so would keep stale views agreeing
/// after a person left).
pub fn view_disagreement_px(
    cams: &[CameraSetup],
    joints: &[&[[f32; 2]]],
    joints3d: &[Option<[f64; 3]>],
    seen: &[bool],
) -> Option<f64> {
    let (mut sum, mut n) = (0f64, 0u32);
    for (i, (cam, joints)) in cams.iter().zip(joints).enumerate() {
        let Some(calibration) = &cam.calibration else {
            continue;
        };
        if !seen.get(i).copied().unwrap_or(true) {
            continue;
        }
        for (&[u, v], x) in joints.iter().zip(joints3d) {
            if let Some((pu, pv)) = x.and_then(|x| calibration.project(x)) {
                sum += (pu - f64::from(u)).hypot(pv - f64::from(v));
                n += 1;
            }
        }
    }
    (n > 0).then(|| sum / f64::from(n))
}

/// Mean 3-D distance of the triangulated joints to the label.
fn error3d(joints: &[Option<[f64; 3]>], label: &[[f32; 3]; JOINTS]) -> (f64, u64) {
    joints
        .iter()
        .zip(label)
        .filter_map(|(p, g)| {
            let p = (*p)?;
            Some(
                (0..3)
                    .map(|k| (p[k] - f64::from(g[k])).powi(2))
                    .sum::<f64>()
                    .sqrt(),
            )
        })
        .fold((0.0, 0), |(s, n), e| (s + e, n + 1))
}

/// Mean 2-D distance of the joints to the visible labels ([`crate::eval::joint_errors_2d`], the
/// evaluation's definition); nothing for a model with another joint count.
fn error2d(joints: &[[f32; 2]], (label, mask): &([[f32; 2]; JOINTS], [u8; JOINTS])) -> (f64, u64) {
    let Ok(pred) = <&[[f32; 2]; JOINTS]>::try_from(joints) else {
        return (0.0, 0);
    };
    crate::eval::joint_errors_2d(pred, label, mask)
        .iter()
        .flatten()
        .fold((0.0, 0), |(s, n), e| (s + e, n + 1))
}

fn add(acc: &mut (f64, u64), (s, n): (f64, u64)) {
    acc.0 += s;
    acc.1 += n;
}

/// One camera's estimate of one window, before the temporal filter.
struct Estimated {
    raw: Raw,
    /// The network's joints in the sensor's pixels.
    raw_joints: Vec<[f32; 2]>,
}

/// A window waiting for the fixed-lag filter's later windows.
struct Waiting {
    index: usize,
    t_us: (i64, i64),
    /// Its events and their cameras, for the callback (the cutter moves on); empty unless
    /// [`RunOptions::callback_events`].
    events: (Vec<u8>, Vec<Event>),
    /// How many events it had.
    count: usize,
    cameras: Vec<Estimated>,
}

/// Turns estimated (and filtered) windows into [`RunWindow`]s, keeps the run's sums, and hands
/// each window to the callback.
struct Reporter<'o, F> {
    opts: &'o RunOptions,
    truth: Option<&'o Truth>,
    on_window: F,
    summary: RunSummary,
    conf: (f64, u64),
    sums: Sums,
    first_t: Option<i64>,
}

impl<F> Reporter<'_, F>
where
    F: FnMut(&RunWindow, &WindowEvents<'_>, Option<&WindowTruth>) -> Result<()>,
{
    /// Reports window `w` (`count` events) from each camera's estimate and, with the filter on,
    /// its filtered joints (model pixels, per camera).
    fn window(
        &mut self,
        w: &WindowEvents<'_>,
        count: usize,
        cameras: Vec<Estimated>,
        filtered: Option<Vec<Vec<[f32; 2]>>>,
    ) -> Result<()> {
        let opts = self.opts;
        let label = self
            .truth
            .and_then(|t| t.label(w.t_us, self.first_t.unwrap_or(0)));
        let filter_on = filtered.is_some();
        let mut filtered = filtered.map(Vec::into_iter);
        let mut poses = Vec::with_capacity(cameras.len());
        let mut raws = Vec::with_capacity(cameras.len());
        for (est, cam) in cameras.into_iter().zip(&opts.cameras) {
            let joints = match filtered.as_mut().and_then(Iterator::next) {
                Some(f) => f.iter().map(|&p| cam.rescale.joint(p)).collect(),
                None => est.raw_joints.clone(),
            };
            poses.push(CameraPose {
                camera: cam.id,
                events: est.raw.events,
                points: est.raw.points,
                joints,
                raw_joints: filter_on.then(|| est.raw_joints.clone()),
                confidence: est.raw.confidence,
            });
            raws.push(est.raw_joints);
        }
        let confs: Vec<&[f32]> = poses.iter().map(|p| p.confidence.as_slice()).collect();
        let out_joints: Vec<&[[f32; 2]]> = poses.iter().map(|p| p.joints.as_slice()).collect();
        // A camera without events in the window has a guess, not a view: it is left out of the
        // triangulation, the views' disagreement and the no-body test.
        let seen: Vec<bool> = poses.iter().map(|p| p.events > 0).collect();
        self.summary.empty_views += seen.iter().filter(|&&s| !s).count();
        let joints3d = triangulate_window(&opts.cameras, &out_joints, &confs, &seen);
        let all: Vec<f32> = confs
            .iter()
            .zip(&seen)
            .filter(|(_, &s)| s)
            .flat_map(|(c, _)| c.iter().copied())
            .collect();
        let has_confidence = confs.iter().any(|c| !c.is_empty());
        // The network's own joints (before the filter) in 3-D, for the views' disagreement and
        // the unfiltered error.
        let raw_refs: Vec<&[[f32; 2]]> = raws.iter().map(|r| r.as_slice()).collect();
        let raw3d = if filter_on {
            triangulate_window(&opts.cameras, &raw_refs, &confs, &seen)
        } else {
            joints3d.clone()
        };
        let disagreement = raw3d
            .as_deref()
            .and_then(|j3| view_disagreement_px(&opts.cameras, &raw_refs, j3, &seen));
        // With confidences: judged on the cameras that saw events; no camera saw any, no body.
        let no_body = has_confidence.then(|| {
            if all.is_empty() {
                return true;
            }
            let m = all.iter().sum::<f32>() / all.len() as f32;
            self.conf.0 += all.iter().map(|&c| f64::from(c)).sum::<f64>();
            self.conf.1 += all.len() as u64;
            self.summary.views_compared += usize::from(disagreement.is_some_and(f64::is_finite));
            no_body_seen(m, disagreement)
        });
        self.summary.no_body_windows += usize::from(no_body == Some(true));
        let window_truth = label.map(|l| WindowTruth {
            joints3d: l,
            cameras: opts
                .cameras
                .iter()
                .map(|c| match &c.calibration {
                    Some(cal) => crate::dataset::project_label(cal, &l),
                    None => ([[0.0; 2]; JOINTS], [0; JOINTS]),
                })
                .collect(),
        });
        let sums = &mut self.sums;
        let error = window_truth.as_ref().map(|t| {
            sums.windows += 1;
            let mut e = WindowError::default();
            for (i, p) in poses.iter().enumerate() {
                let d = error2d(&p.joints, &t.cameras[i]);
                add(&mut sums.d2, d);
                add(&mut sums.d2_raw, error2d(&raws[i], &t.cameras[i]));
                if let Some(m) = mean(d) {
                    e.mpjpe2d_px.push((p.camera, m));
                }
            }
            if let Some(j3) = &joints3d {
                let d = error3d(j3, &t.joints3d);
                add(&mut sums.d3, d);
                e.mpjpe3d_mm = mean(d);
                if let Some(r3) = &raw3d {
                    add(&mut sums.d3_raw, error3d(r3, &t.joints3d));
                }
            }
            e
        });
        let result = RunWindow {
            window: w.index,
            t_us: [w.t_us.0, w.t_us.1],
            events: count,
            no_body,
            view_disagreement_px: disagreement,
            cameras: poses,
            joints3d,
            error,
        };
        (self.on_window)(&result, w, window_truth.as_ref())
    }

    /// Reports the fixed-lag filter's ready windows, oldest first.
    fn drain(
        &mut self,
        lagged: &mut [FixedLag<'_>],
        waiting: &mut VecDeque<Waiting>,
    ) -> Result<()> {
        loop {
            let mut filtered = Vec::with_capacity(lagged.len());
            let mut number = None;
            for (f, est) in lagged
                .iter_mut()
                .zip(waiting.front().map(|w| &w.cameras).into_iter().flatten())
            {
                let mut out = vec![[0f32; 2]; est.raw.joints.len()];
                // Every camera's filter saw the same windows at the same times: all are ready
                // together.
                number = f.pop(&mut out);
                if number.is_none() {
                    return Ok(());
                }
                filtered.push(out);
            }
            let Some(w) = number.and(waiting.pop_front()) else {
                return Ok(());
            };
            let events = WindowEvents {
                index: w.index,
                cameras: &w.events.0,
                events: &w.events.1,
                t_us: w.t_us,
            };
            self.window(&events, w.count, w.cameras, Some(filtered))?;
        }
    }
}

/// The confidences the fixed-lag filter weighs a camera's joints by: the model's, or 1 for
/// every joint of a model without them (a plain mean).
fn lag_weights(raw: &Raw) -> std::borrow::Cow<'_, [f32]> {
    if raw.confidence.len() == raw.joints.len() {
        std::borrow::Cow::Borrowed(&raw.confidence)
    } else {
        std::borrow::Cow::Owned(vec![1.0; raw.joints.len()])
    }
}

/// Runs a recording: reads `reader` to its end, estimating every window of `opts.rule` with
/// `estimators` (one per camera of `opts.cameras`, in order), and calls `on_window` with each
/// window's result, the window's events and, with `truth`, its ground truth. With the
/// fixed-lag filter, a window is reported once the filter's later windows have been estimated
/// (its events, with [`RunOptions::callback_events`], are held until then), and at the end of
/// the stream the last ones.
pub fn run(
    reader: &mut dyn EventReader,
    estimators: &mut [Box<dyn CameraEstimator + '_>],
    opts: &RunOptions,
    truth: Option<&Truth>,
    on_window: impl FnMut(&RunWindow, &WindowEvents<'_>, Option<&WindowTruth>) -> Result<()>,
) -> Result<RunSummary> {
    if estimators.len() != opts.cameras.len() {
        bail!(
            "{} estimators for {} cameras",
            estimators.len(),
            opts.cameras.len()
        );
    }
    if opts.cameras.is_empty() {
        bail!("no camera to estimate");
    }
    let mut cutter = Cutter::new(opts.rule, opts.capacity)?;
    let joints: Vec<usize> = estimators.iter().map(|e| e.joints()).collect();
    // The One-Euro filter's state: two coordinates per joint and camera.
    let mut euro_state: Vec<Vec<AxisState>> = joints
        .iter()
        .map(|&j| vec![AxisState::default(); 2 * j])
        .collect();
    let mut euros: Vec<Smoother<'_>> = match opts.filter {
        Filter::OneEuro(p) => euro_state
            .iter_mut()
            .map(|s| Smoother::new(p, s))
            .collect::<Result<_, _>>()?,
        _ => Vec::new(),
    };
    // The fixed-lag filter's: 2·lag + 1 windows per camera.
    let lag = match opts.filter {
        Filter::FixedLag(p) => Some(p),
        _ => None,
    };
    let slots = lag.map_or(0, |p| FixedLag::slots_for(p.lag));
    let mut lag_slots = vec![vec![LagSlot::default(); slots]; joints.len()];
    let mut lag_held: Vec<Vec<Held>> = joints
        .iter()
        .map(|&j| vec![Held::default(); slots * j])
        .collect();
    let mut lagged: Vec<FixedLag<'_>> = match lag {
        Some(p) => lag_slots
            .iter_mut()
            .zip(lag_held.iter_mut())
            .zip(&joints)
            .map(|((s, h), &j)| FixedLag::with_params(p, j, s, h))
            .collect::<Result<_, _>>()
            .map_err(|e| anyhow::anyhow!("{e}"))?,
        None => Vec::new(),
    };
    let mut waiting: VecDeque<Waiting> = VecDeque::new();
    let mut reporter = Reporter {
        opts,
        truth,
        on_window,
        summary: RunSummary {
            cameras: opts.cameras.iter().map(|c| c.id).collect(),
            ..RunSummary::default()
        },
        conf: (0.0, 0),
        sums: Sums::default(),
        first_t: None,
    };
    let mut events_buf: Vec<Event> = Vec::new();

    let mut emit = |w: &WindowEvents<'_>, reporter: &mut Reporter<'_, _>| -> Result<()> {
        let mut cameras = Vec::with_capacity(opts.cameras.len());
        for (cam, est) in opts.cameras.iter().zip(estimators.iter_mut()) {
            events_buf.clear();
            w.extend_camera(cam.id, &mut events_buf, |e| cam.rescale.event(e));
            let raw: Raw = est
                .estimate(&events_buf)
                .with_context(|| format!("window {} camera {}", w.index, cam.id))?;
            let raw_joints = raw
                .joints
                .iter()
                .map(|j| cam.rescale.joint([f32::from(j.x), f32::from(j.y)]))
                .collect();
            cameras.push(Estimated { raw, raw_joints });
        }
        // The callback's view of the window: its events, or none (see `callback_events`).
        let shown = if opts.callback_events {
            *w
        } else {
            WindowEvents {
                cameras: &[],
                events: &[],
                ..*w
            }
        };
        match opts.filter {
            Filter::Off => reporter.window(&shown, w.len(), cameras, None),
            Filter::OneEuro(_) => {
                let mut filtered = Vec::with_capacity(cameras.len());
                for (est, smoother) in cameras.iter().zip(euros.iter_mut()) {
                    let raw = &est.raw;
                    let mut out: Vec<[f32; 2]> = raw
                        .joints
                        .iter()
                        .map(|j| [f32::from(j.x), f32::from(j.y)])
                        .collect();
                    // A model without confidences is not filtered.
                    if raw.confidence.len() == raw.joints.len() {
                        smoother
                            .update(w.t_us.1, &raw.joints, &raw.confidence, &mut out)
                            .map_err(|e| anyhow::anyhow!("{e}"))?;
                    }
                    filtered.push(out);
                }
                reporter.window(&shown, w.len(), cameras, Some(filtered))
            }
            Filter::FixedLag(_) => {
                for (est, f) in cameras.iter().zip(lagged.iter_mut()) {
                    f.push(w.t_us.1, &est.raw.joints, &lag_weights(&est.raw))
                        .map_err(|e| anyhow::anyhow!("{e}"))?;
                }
                waiting.push_back(Waiting {
                    index: w.index,
                    t_us: w.t_us,
                    events: (shown.cameras.to_vec(), shown.events.to_vec()),
                    count: w.len(),
                    cameras,
                });
                reporter.drain(&mut lagged, &mut waiting)
            }
        }
    };

    let fed = (|| -> Result<()> {
        let mut batch = Batch::default();
        while reader.read_batch(&mut batch)? {
            reporter.summary.events += batch.events.len() as u64;
            if reporter.first_t.is_none() {
                reporter.first_t = batch.events.first().map(|e| e.t);
            }
            cutter.push_batch(&batch.cameras, &batch.events, &mut |w| {
                emit(w, &mut reporter)
            })?;
        }
        cutter.finish(&mut |w| emit(w, &mut reporter))
    })();
    // The fixed-lag filter's last windows, also when reading or estimating failed: every
    // window estimated is reported before the error.
    for f in &mut lagged {
        f.finish();
    }
    let drained = reporter.drain(&mut lagged, &mut waiting);
    fed?;
    drained?;
    let mut summary = reporter.summary;
    summary.windows = cutter.windows();
    summary.dropped = cutter.dropped();
    summary.skipped_windows = cutter.skipped();
    summary.mean_confidence =
        (reporter.conf.1 > 0).then(|| reporter.conf.0 / reporter.conf.1 as f64);
    if truth.is_some() {
        let sums = reporter.sums;
        summary.errors = Some(Errors {
            mpjpe2d_px: mean(sums.d2),
            mpjpe2d_raw_px: mean(sums.d2_raw),
            mpjpe3d_mm: mean(sums.d3),
            mpjpe3d_raw_mm: mean(sums.d3_raw),
            windows: sums.windows,
        });
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn setup(id: u8, calibrated: bool) -> CameraSetup {
        CameraSetup {
            id,
            rescale: Rescale {
                sensor: (346, 260),
                model: (346, 260),
            },
            calibration: calibrated.then(|| crate::dhp19::bundled_camera(id).unwrap()),
        }
    }

    #[test]
    fn views_of_one_point_agree_and_a_moved_view_disagrees() {
        let cams = [setup(2, true), setup(3, true), setup(1, false)];
        let points = [
            Some([100.0, 200.0, 900.0]),
            Some([-300.0, 50.0, 1200.0]),
            None,
        ];
        let view = |c: &CameraSetup| -> Vec<[f32; 2]> {
            points
                .iter()
                .map(|p| match (p, &c.calibration) {
                    (Some(p), Some(cal)) => {
                        let (u, v) = cal.project(*p).unwrap();
                        [u as f32, v as f32]
                    }
                    _ => [0.0, 0.0],
                })
                .collect()
        };
        let (a, mut b, c) = (view(&cams[0]), view(&cams[1]), vec![[5.0, 5.0]; 3]);
        let all = [true; 3];
        let d = view_disagreement_px(&cams, &[&a, &b, &c], &points, &all).unwrap();
        assert!(d < 1e-3, "{d}");
        // One joint of one view 10 px off: 10 px over the 4 projected joint views.
        b[0][0] += 10.0;
        let d = view_disagreement_px(&cams, &[&a, &b, &c], &points, &all).unwrap();
        assert!((d - 2.5).abs() < 1e-3, "{d}");
        // That view without events (a guess) is left out: the other one agrees.
        let seen = [true, false, true];
        let d = view_disagreement_px(&cams, &[&a, &b, &c], &points, &seen).unwrap();
        assert!(d < 1e-3, "{d}");
        // Nothing triangulated, or no calibration: nothing to compare.
        let none = [None; 3];
        assert_eq!(
            view_disagreement_px(&cams, &[&a, &b, &c], &none, &all),
            None
        );
        assert_eq!(view_disagreement_px(&cams[2..], &[&c], &points, &all), None);
    }

    #[test]
    fn the_no_body_line_rises_with_disagreement() {
        // One view: the confidence alone.
        assert!(no_body_seen(NO_BODY_CONFIDENCE - 0.01, None));
        assert!(!no_body_seen(NO_BODY_CONFIDENCE, None));
        // Views that agree to 3 px: a window of middling confidence shows a body; the same
        // confidence with views 20 px apart does not.
        assert!(!no_body_seen(0.35, Some(3.0)));
        assert!(no_body_seen(0.35, Some(20.0)));
        // The line: 0.16 + 0.08 ln d.
        let at_10 = NO_BODY_VIEWS_BASE + NO_BODY_VIEWS_SLOPE * 10f32.ln();
        assert!(no_body_seen(at_10 - 1e-4, Some(10.0)));
        assert!(!no_body_seen(at_10 + 1e-4, Some(10.0)));
        // Disagreement counts from 1 px; a NaN falls back to the one-view rule.
        assert!(no_body_seen(NO_BODY_VIEWS_BASE - 1e-4, Some(0.0)));
        assert!(!no_body_seen(NO_BODY_VIEWS_BASE + 1e-4, Some(0.2)));
        assert!(no_body_seen(NO_BODY_CONFIDENCE - 0.01, Some(f64::NAN)));
        assert!(!no_body_seen(
            NO_BODY_CONFIDENCE + 0.01,
            Some(f64::INFINITY)
        ));
        // A NaN confidence is no evidence of a body.
        assert!(no_body_seen(f32::NAN, None));
        assert!(no_body_seen(f32::NAN, Some(2.0)));
    }

    /// Without `callback_events`, the fixed-lag filter's held windows keep no events and the
    /// callback gets none, and nothing else about the run changes.
    #[test]
    fn callback_events_only_change_what_the_callback_sees() {
        let mut got = Vec::new();
        for keep in [true, false] {
            let mut plan = setup::Plan::resolve(&setup::Request::default()).unwrap();
            assert!(matches!(plan.options.filter, Filter::FixedLag(_)));
            plan.options.callback_events = keep;
            let mut windows = Vec::new();
            plan.run(|w, events, _| {
                windows.push((w.clone(), events.len()));
                Ok(())
            })
            .unwrap();
            got.push(windows);
        }
        let (kept, bare) = (&got[0], &got[1]);
        assert_eq!(kept.len(), 12, "the bundled clip's windows");
        for ((w, n), (w_bare, n_bare)) in kept.iter().zip(bare) {
            assert!(w.events > 0);
            assert_eq!(*n, w.events, "window {}: its events", w.window);
            assert_eq!(*n_bare, 0, "window {}: no events", w.window);
            assert_eq!(w, w_bare, "window {}: the same result", w.window);
        }
    }
}

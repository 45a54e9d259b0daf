//! Whole recordings: four cameras, ground truth at 100 Hz, deterministic per spec.
//!
//! Time advances in adaptive render steps: at most [`MAX_STEP_US`], shortened so that no joint
//! (or object point) moves more than [`MAX_STEP_PX`] pixel in any camera between two renders,
//! down to [`MIN_STEP_US`]. Edges are not anti-aliased, so a pixel crossed by an edge sees
//! a jump of several thresholds whatever the step; bounding the image motion per step instead
//! bounds the timestamp error of those events to the time an edge takes to cross one pixel.

use std::collections::VecDeque;

use evpose_core::geometry::Camera;
use evpose_core::Event;
use rayon::prelude::*;

use crate::body::{Capsule, Subject, JOINTS};
use crate::motion::{Motion, Movement, Stage};
use crate::pixel::{PixelModel, Sensor, SensorParams};
use crate::render::{Rect, Room, View};

/// Longest render step, µs.
pub const MAX_STEP_US: f64 = 4000.0;
/// Shortest render step, µs.
pub const MIN_STEP_US: f64 = 50.0;
/// Largest image motion of any joint between two renders, pixels.
pub const MAX_STEP_PX: f64 = 0.75;
/// With [`PixelModel::V1`], pixels keep being updated for this long after their image last
/// changed (photoreceptor settling), µs; [`PixelModel::V2`] updates them until they are at rest.
const SETTLE_US: f64 = 20_000.0;
/// Ground-truth rate, Hz.
pub const GT_HZ: f64 = 100.0;

/// What to simulate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecordingSpec {
    /// Seed of everything random.
    pub seed: u64,
    /// Subject index under the seed ([`Subject::from_seed`]).
    pub subject: u32,
    /// The movement.
    pub movement: Movement,
    /// Length, seconds.
    pub seconds: f64,
    /// The pixel model's version ([`PixelModel::V2`] unless reproducing data made with V1).
    pub pixel: PixelModel,
}

/// A simulated recording.
#[derive(Clone, Debug)]
pub struct Recording {
    /// The spec it came from.
    pub spec: RecordingSpec,
    /// Events of the four cameras `(channel, event)`, merged and sorted by time (then channel,
    /// row, column), µs from the start of the recording (`0 ≤ t < seconds · 10⁶`).
    pub events: Vec<(u8, Event)>,
    /// The 13 joints (DHP19 order, world mm) at 100 Hz: sample `k` is at `t = k · 10 ms`;
    /// empty for [`Movement::NoPerson`].
    pub gt_mm: Vec<[[f32; 3]; JOINTS]>,
    /// The subject (drawn also for `NoPerson`, where it does not appear).
    pub subject: Subject,
    /// The motion parameters.
    pub motion: Motion,
    /// Where the cameras look.
    pub stage: Stage,
    /// Room and lighting.
    pub room: Room,
    /// DVS parameters per camera channel.
    pub sensor: [SensorParams; 4],
    /// Render steps taken.
    pub steps: usize,
}

impl Recording {
    /// Events of one camera channel, in order.
    pub fn channel(&self, channel: u8) -> impl Iterator<Item = Event> + '_ {
        self.events
            .iter()
            .filter(move |(c, _)| *c == channel)
            .map(|&(_, e)| e)
    }
}

/// The scene's primitives at `t` seconds.
fn scene(subject: &Subject, motion: &Motion, t: f64) -> Vec<Capsule> {
    match motion.pose(t) {
        Some(p) => subject.capsules(&p),
        None => motion.objects(t),
    }
}

/// Points whose image motion bounds the render step.
fn key_points(subject: &Subject, motion: &Motion, t: f64) -> Vec<[f64; 3]> {
    match motion.pose(t) {
        Some(p) => subject.joints(&p).to_vec(),
        None => motion.objects(t).iter().flat_map(|c| [c.a, c.b]).collect(),
    }
}

/// Simulates one recording. Deterministic: the same spec and cameras give identical output,
/// whatever the thread pool. `cameras[i]` is camera channel `i` (DHP19 order).
pub fn simulate(spec: &RecordingSpec, cameras: &[Camera; 4]) -> Recording {
    let stage = Stage::from_cameras(cameras);
    let subject = Subject::from_seed(spec.seed, spec.subject);
    let stream = spec.movement.index() << 8;
    let motion = Motion::sample(spec.movement, spec.seed, spec.subject, &stage, spec.seconds);
    let room = Room::sample(spec.seed, spec.subject, stream, cameras);
    let sensor: [SensorParams; 4] =
        core::array::from_fn(|c| SensorParams::sample(spec.seed, spec.subject, stream | c as u16));
    let views: Vec<View> = cameras.par_iter().map(|c| View::new(c, &room)).collect();

    // Step times, µs.
    let t_end = (spec.seconds.max(0.0) * 1e6).round();
    let mut times = vec![0.0f64];
    let project_all = |pts: &[[f64; 3]]| -> Vec<Option<(f64, f64)>> {
        views
            .iter()
            .flat_map(|v| pts.iter().map(move |&p| v.project(p)))
            .collect()
    };
    let mut t = 0.0;
    let mut here = project_all(&key_points(&subject, &motion, 0.0));
    while t < t_end {
        let probe = (t + MAX_STEP_US).min(t_end);
        let there = project_all(&key_points(&subject, &motion, probe * 1e-6));
        let px = here
            .iter()
            .zip(&there)
            .filter_map(|(a, b)| {
                Some((a.as_ref()?.0 - b.as_ref()?.0).hypot(a.as_ref()?.1 - b.as_ref()?.1))
            })
            .fold(0.0f64, f64::max);
        let full = probe - t;
        let dt = if px > MAX_STEP_PX {
            (full * MAX_STEP_PX / px).max(MIN_STEP_US).min(full)
        } else {
            full
        };
        t = if t_end - (t + dt) < 1.0 {
            t_end
        } else {
            t + dt
        };
        times.push(t);
        here = if dt == full {
            there
        } else {
            project_all(&key_points(&subject, &motion, t * 1e-6))
        };
    }
    let scenes: Vec<Vec<Capsule>> = times
        .par_iter()
        .map(|&t| scene(&subject, &motion, t * 1e-6))
        .collect();

    let per_camera: Vec<Vec<Event>> = views
        .par_iter()
        .enumerate()
        .map(|(c, view)| {
            let mut frame = view.frame();
            view.render(&scenes[0], &mut frame);
            let mut px = Sensor::new(
                sensor[c],
                spec.pixel,
                &frame.intensity,
                view.width(),
                spec.seed,
                spec.subject,
                stream | c as u16,
            );
            let mut out = Vec::new();
            let mut recent: VecDeque<(f64, Rect)> = VecDeque::new();
            for k in 1..times.len() {
                let rect = view.render(&scenes[k], &mut frame);
                let active = match spec.pixel {
                    PixelModel::V1 => {
                        recent.push_back((times[k], rect));
                        while recent
                            .front()
                            .is_some_and(|&(tr, _)| tr < times[k] - SETTLE_US)
                        {
                            recent.pop_front();
                        }
                        recent.iter().fold(Rect::default(), |a, &(_, r)| a.union(r))
                    }
                    // The sensor keeps the pixels that are not at rest itself.
                    PixelModel::V2 => rect,
                };
                px.step(times[k - 1], times[k], &frame.intensity, active, &mut out);
            }
            px.finish(t_end, &mut out);
            out.retain(|e| (e.t as f64) < t_end.max(1.0));
            out
        })
        .collect();

    let mut events: Vec<(u8, Event)> = per_camera
        .into_iter()
        .enumerate()
        .flat_map(|(c, evs)| evs.into_iter().map(move |e| (c as u8, e)))
        .collect();
    events.par_sort_unstable_by_key(|&(c, e)| (e.t, c, e.y, e.x, e.on));

    let gt_mm = if spec.movement == Movement::NoPerson {
        Vec::new()
    } else {
        let n = (spec.seconds * GT_HZ - 1e-9).ceil().max(0.0) as usize;
        (0..n)
            .map(|k| {
                let pose = motion.pose(k as f64 / GT_HZ).expect("a person");
                subject.joints(&pose).map(|j| j.map(|v| v as f32))
            })
            .collect()
    };
    Recording {
        spec: *spec,
        events,
        gt_mm,
        subject,
        motion,
        stage,
        room,
        sensor,
        steps: times.len() - 1,
    }
}

/// Simulates many recordings in parallel (rayon), calling `on_done(index, &recording)` as each
/// finishes (in any order; each recording is dropped after its call). Each recording is the
/// same as [`simulate`] gives on its own.
pub fn simulate_many(
    specs: &[RecordingSpec],
    cameras: &[Camera; 4],
    on_done: impl Fn(usize, &Recording) + Sync,
) {
    specs.par_iter().enumerate().for_each(|(i, s)| {
        let r = simulate(s, cameras);
        on_done(i, &r);
    });
}

//! One camera's estimator: a window of that camera's events in (sensor pixels), its 2-D joints
//! and their confidences out. The core's [`Session`] runs `.evq` blobs (int8 or f32); tract runs
//! an ONNX file of any backbone after the core's rasterization and sampling.
//!
//! A sensor of another size than the model's SimDR resolution is rescaled to it, as the paper
//! resizes its inputs: event `x` becomes `⌊x · W / W_sensor⌋` (`y` likewise), and joints come back
//! as `(x + ½) · W_sensor / W − ½`, pixel centre to pixel centre.

use anyhow::Result;
#[cfg(feature = "onnx")]
use anyhow::{bail, Context};
use evpose_core::pipeline::{Engine, Estimate, F32, I8};
use evpose_core::{DType, Estimator, Event, Joint2d, Session};

use crate::model::CoreRunner;
use crate::pipeline::{self, VecStorage};

/// A window's raw estimate, in the model's pixels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Raw {
    /// Events of the camera in the window (after rescaling, all of them).
    pub events: usize,
    /// Points of the rasterized window.
    pub points: usize,
    /// Decoded joints, model pixels.
    pub joints: Vec<Joint2d>,
    /// Confidence per joint in [0, 1] (empty when the model carries no logit scales).
    pub confidence: Vec<f32>,
}

impl Raw {
    fn of(e: &Estimate<'_>, events: usize, scales: Option<[f32; 2]>) -> Self {
        let mut confidence = Vec::new();
        if let Some(scales) = scales {
            confidence = vec![0.0; e.joints.len()];
            // The estimate's heads and joints agree in shape by construction.
            if e.confidence(scales, &mut confidence).is_err() {
                confidence.clear();
            }
        }
        Self {
            events,
            points: e.window.len(),
            joints: e.joints.to_vec(),
            confidence,
        }
    }
}

/// The estimate of a window's largest part: a window the rasterizer had to split (at a
/// timestamp more than 2^31 µs from the window's first event) is represented by the part with
/// the most events.
#[derive(Default)]
struct Largest(Option<(u32, Raw)>);

impl Largest {
    /// Keeps `raw()` if a part of `events` events is larger than every part offered so far.
    fn offer(&mut self, events: u32, raw: impl FnOnce() -> Raw) {
        if self.0.as_ref().is_none_or(|(n, _)| events > *n) {
            self.0 = Some((events, raw()));
        }
    }

    fn is_empty(&self) -> bool {
        self.0.is_none()
    }

    /// The kept estimate (the default, empty one if none was offered).
    fn take(self) -> Raw {
        self.0.map(|(_, raw)| raw).unwrap_or_default()
    }
}

/// Maps a sensor's pixels to a model's resolution and back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rescale {
    /// Sensor size.
    pub sensor: (u16, u16),
    /// Model resolution (SimDR bins per axis).
    pub model: (u16, u16),
}

impl Rescale {
    /// Whether the sizes are equal (nothing to do).
    pub fn is_identity(&self) -> bool {
        self.sensor == self.model
    }

    /// An event's pixel in the model's resolution (`None` outside the sensor).
    pub fn event(&self, e: Event) -> Option<Event> {
        if self.is_identity() {
            return Some(e);
        }
        let (sw, sh) = (u32::from(self.sensor.0), u32::from(self.sensor.1));
        let (mw, mh) = (u32::from(self.model.0), u32::from(self.model.1));
        if u32::from(e.x) >= sw || u32::from(e.y) >= sh {
            return None;
        }
        Some(Event {
            x: (u32::from(e.x) * mw / sw) as u16,
            y: (u32::from(e.y) * mh / sh) as u16,
            ..e
        })
    }

    /// A model-pixel coordinate `[x, y]` in sensor pixels.
    pub fn joint(&self, [x, y]: [f32; 2]) -> [f32; 2] {
        if self.is_identity() {
            return [x, y];
        }
        let f = |v: f32, s: u16, m: u16| (v + 0.5) * f32::from(s) / f32::from(m) - 0.5;
        [
            f(x, self.sensor.0, self.model.0),
            f(y, self.sensor.1, self.model.1),
        ]
    }
}

/// One camera's estimator.
pub trait CameraEstimator {
    /// Estimates one window from the camera's events (model pixels).
    fn estimate(&mut self, events: &[Event]) -> Result<Raw>;

    /// Joints each estimate gives.
    fn joints(&self) -> usize;
}

/// A window's capacity as the rasterizer takes it (32 bits): larger is an error, not a
/// truncation.
fn window_capacity(capacity: usize) -> Result<u32> {
    u32::try_from(capacity)
        .map_err(|_| anyhow::anyhow!("windows of {capacity} events: at most 2^32 - 1"))
}

/// Time slices of the rasterization (the paper's K), per the model when it records them.
fn slices(recorded: u8) -> u8 {
    if recorded == 0 {
        evpose_core::raster::DEFAULT_SLICES
    } else {
        recorded
    }
}

/// The core engine: a [`Session`] over heap buffers.
struct CoreCamera<'m, E: Engine> {
    session: Session<'m, VecStorage>,
    buffers: crate::run::Buffers<E>,
    scales: Option<[f32; 2]>,
}

impl<E: Engine> CameraEstimator for CoreCamera<'_, E> {
    fn estimate(&mut self, events: &[Event]) -> Result<Raw> {
        let mut ws = self.buffers.workspace();
        let scales = self.scales;
        // The rasterizer holds a whole window, so it closes by count only at the last event;
        // it also closes early at an event more than 2^31 µs from the window's first (a
        // glitched timestamp). Then every part is estimated and the one with the most events
        // stands for the window ([`Largest`]), and nothing stays open to leak into the next.
        let mut best = Largest::default();
        let mut rest = events;
        while !rest.is_empty() {
            let (used, estimate) = self.session.extend(rest, &mut ws, &mut ())?;
            if let Some(e) = estimate {
                best.offer(e.window.summary().events, || {
                    Raw::of(&e, events.len(), scales)
                });
            }
            rest = &rest[used..];
        }
        if best.is_empty() || self.session.rasterizer().buffered() > 0 {
            let e = self.session.flush(&mut ws, &mut ())?;
            best.offer(e.window.summary().events, || {
                Raw::of(&e, events.len(), scales)
            });
        }
        Ok(best.take())
    }

    fn joints(&self) -> usize {
        self.buffers.joints.len()
    }
}

/// Core estimators over `runner`'s model for cameras that each see up to `capacity` events per
/// window; camera `i`'s sampler is seeded with `seed + i`.
pub fn core_estimators<'m>(
    runner: &'m CoreRunner<'_>,
    cameras: usize,
    points: usize,
    capacity: usize,
    seed: u64,
) -> Result<Vec<Box<dyn CameraEstimator + 'm>>> {
    let model = runner.model();
    let size = (model.width() as u16, model.height() as u16);
    let k = slices(model.preprocessing().slices);
    (0..cameras)
        .map(|i| -> Result<Box<dyn CameraEstimator + 'm>> {
            let raster = pipeline::rasterizer(size, k, window_capacity(capacity)?)?;
            let plan = runner.plan()?;
            let estimator = Estimator::new(plan, points, seed.wrapping_add(i as u64));
            let session = Session::new(raster, estimator);
            let scales = model.head_scales();
            Ok(match model.dtype() {
                DType::I8 => Box::new(CoreCamera::<I8> {
                    buffers: crate::run::Buffers::new(&plan, points, capacity),
                    session,
                    scales,
                }),
                DType::F32 => Box::new(CoreCamera::<F32> {
                    buffers: crate::run::Buffers::new(&plan, points, capacity),
                    session,
                    scales,
                }),
            })
        })
        .collect()
}

/// tract on an ONNX file, after the core's rasterization and sampling.
#[cfg(feature = "onnx")]
pub struct TractCamera {
    raster: evpose_core::Rasterizer<VecStorage>,
    rng: evpose_core::SampleRng,
    model: crate::model::TractModel,
    points: usize,
    capacity: usize,
    indices: Vec<u32>,
    rows: Vec<[f32; 5]>,
    joints: usize,
}

#[cfg(feature = "onnx")]
impl TractCamera {
    /// Loads `onnx` for windows of up to `capacity` events, `points` points per input (the
    /// export's fixed count when it has one); returns it with the model's resolution.
    pub fn load(
        onnx: &std::path::Path,
        points: Option<usize>,
        capacity: usize,
        seed: u64,
    ) -> Result<(Self, (u16, u16))> {
        let mut model = crate::model::TractModel::load(onnx)?;
        let points = match (points, model.fixed_points()) {
            (Some(p), Some(f)) if p != f => {
                bail!("{} takes exactly {f} points, not {p}", onnx.display())
            }
            (p, f) => p.or(f).unwrap_or(evpose_core::pipeline::DEFAULT_POINTS),
        };
        // The heads' lengths are the resolution: one run on an empty input gives them.
        let probe = model
            .run(&vec![[0.0; 5]; points.max(1)])
            .with_context(|| format!("{}: a trial inference", onnx.display()))?;
        let size = (probe.width() as u16, probe.height() as u16);
        let raster = pipeline::rasterizer(size, slices(0), window_capacity(capacity)?)?;
        Ok((
            Self {
                raster,
                rng: evpose_core::rng_from_seed(seed),
                model,
                points,
                capacity,
                indices: vec![0; points.max(capacity)],
                rows: vec![[0.0; 5]; points.max(capacity).max(1)],
                joints: probe.joints,
            },
            size,
        ))
    }

    /// Points per network input.
    pub fn points(&self) -> usize {
        self.points
    }

    /// Samples, infers and decodes the rasterizer's last closed window (part of a window of
    /// `events` events); returns the part's event count with the estimate.
    fn infer_last(&mut self, events: usize) -> Result<(u32, Raw)> {
        let window = self.raster.last_window().unwrap_or_default();
        let input = evpose_core::sample_window(
            &window,
            self.points,
            &mut self.rng,
            &mut self.indices,
            &mut self.rows,
        )?;
        let l = self.model.run(input)?;
        let (w, h) = (l.width(), l.height());
        let mut joints = vec![Joint2d::default(); l.joints];
        evpose_core::decode(&l.x, &l.y, w, h, &mut joints)?;
        let mut confidence = vec![0f32; l.joints];
        evpose_core::confidence::joints(&l.x, &l.y, w, h, [1.0; 2], &joints, &mut confidence)?;
        let raw = Raw {
            events,
            points: window.len(),
            joints,
            confidence,
        };
        Ok((window.summary().events, raw))
    }

    /// Another camera's estimator over the same loaded model (no second load or tract
    /// optimization), its sampler seeded with `seed`.
    pub fn with_seed(&self, seed: u64) -> Result<Self> {
        let c = *self.raster.config();
        let capacity = window_capacity(self.capacity)?;
        Ok(Self {
            raster: pipeline::rasterizer((c.width, c.height), c.slices, capacity)?,
            rng: evpose_core::rng_from_seed(seed),
            model: self.model.clone(),
            points: self.points,
            capacity: self.capacity,
            indices: vec![0; self.indices.len()],
            rows: vec![[0.0; 5]; self.rows.len()],
            joints: self.joints,
        })
    }
}

#[cfg(feature = "onnx")]
impl CameraEstimator for TractCamera {
    fn estimate(&mut self, events: &[Event]) -> Result<Raw> {
        // As the core camera: every part of a window the rasterizer split is estimated, the
        // largest stands for the window, and nothing stays open.
        let mut best = Largest::default();
        let mut rest = events;
        while !rest.is_empty() {
            let (used, closed) = self.raster.extend(rest);
            let closed = closed.is_some();
            if closed {
                let (n, raw) = self.infer_last(events.len())?;
                best.offer(n, || raw);
            }
            rest = &rest[used..];
        }
        if best.is_empty() || self.raster.buffered() > 0 {
            self.raster.flush();
            let (n, raw) = self.infer_last(events.len())?;
            best.offer(n, || raw);
        }
        Ok(best.take())
    }

    fn joints(&self) -> usize {
        self.joints
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 7,500 events over the sensor with a 50-minute jump after 5,000 (beyond the rasterizer's
    /// 2^31 µs per window), then a window whose events all sit on one pixel: that window has at
    /// most K = 4 points whatever came before.
    fn check_time_jump(cam: &mut dyn CameraEstimator) {
        let jump = 50 * 60 * 1_000_000;
        let first: Vec<Event> = (0..7_500u32)
            .map(|i| {
                let t = i64::from(i) + if i >= 5_000 { jump } else { 0 };
                Event::new((i % 300) as u16, (i / 300 % 250) as u16, t, i % 2 == 0)
            })
            .collect();
        let raw = cam.estimate(&first).unwrap();
        assert_eq!(raw.events, 7_500);
        // The larger part (5,000 events over 5,000 pixels) stands for the window.
        assert_eq!(raw.points, 5_000);
        let t0 = jump + 10_000;
        let second: Vec<Event> = (0..7_500)
            .map(|i| Event::new(7, 9, t0 + i64::from(i), true))
            .collect();
        let raw = cam.estimate(&second).unwrap();
        assert!(raw.points <= 4, "{} points", raw.points);
        assert_eq!(raw.events, 7_500);
    }

    #[test]
    fn a_workspace_too_small_for_a_window_is_refused_before_any_event_is_used() {
        use evpose_core::pipeline::{PipelineError, Workspace, F32};
        use evpose_core::sample::BufferTooSmall;
        use evpose_core::simdr::ShapeError;
        use evpose_core::InferError;
        let blob = crate::model::AlignedBlob::new(crate::assets::DEFAULT_MODEL);
        let runner = CoreRunner::new(&blob).unwrap();
        let plan = runner.plan().unwrap();
        // Every point of 100-event windows (N = 0): a window needs up to 100 rows.
        let raster = pipeline::rasterizer((346, 260), 4, 100).unwrap();
        let mut session = Session::new(raster, Estimator::new(plan, 0, 0));
        let mut buffers = crate::run::Buffers::<I8>::new(&plan, 0, 100);
        let events: Vec<Event> = (0..100)
            .map(|i| Event::new(i, 7, i64::from(i), true))
            .collect();
        // Each buffer one element short, in turn: refused, and no event taken.
        for short in 0..4 {
            let Workspace {
                indices,
                rows,
                scratch,
                x,
                y,
                joints,
            } = buffers.workspace();
            // One short of what a window needs, or the whole buffer.
            let cut =
                |len: usize, needed: usize, i: usize| if short == i { needed - 1 } else { len };
            let (nr, ns, nx, nj) = (
                cut(rows.len(), 100, 0),
                cut(scratch.len(), plan.scratch_words(), 1),
                cut(x.len(), plan.out_x_len(), 2),
                cut(joints.len(), plan.model().joints(), 3),
            );
            let mut small = Workspace::<I8> {
                indices,
                rows: &mut rows[..nr],
                scratch: &mut scratch[..ns],
                x: &mut x[..nx],
                y,
                joints: &mut joints[..nj],
            };
            let err = session.extend(&events, &mut small, &mut ()).unwrap_err();
            let want = match short {
                0 => PipelineError::Sample(BufferTooSmall {
                    needed: 100,
                    available: 99,
                }),
                1 => PipelineError::Infer(InferError::Scratch {
                    needed: ns + 1,
                    got: ns,
                }),
                2 => PipelineError::Infer(InferError::Output {
                    head: "x",
                    needed: nx + 1,
                    got: nx,
                }),
                _ => PipelineError::Decode(ShapeError::Length {
                    expected: nj + 1,
                    got: nj,
                }),
            };
            assert_eq!(err, want);
            assert_eq!(session.rasterizer().buffered(), 0);
            assert_eq!(session.rasterizer().stats().accepted, 0);
        }
        // An f32 workspace for the int8 plan.
        let mut f32_buffers = crate::run::Buffers::<F32>::new(&plan, 0, 100);
        let err = session
            .extend(&events, &mut f32_buffers.workspace(), &mut ())
            .unwrap_err();
        assert_eq!(err, PipelineError::Infer(InferError::DType));
        assert_eq!(session.rasterizer().buffered(), 0);
        // The same events again, with room: the whole window.
        let mut ws = buffers.workspace();
        let (used, estimate) = session.extend(&events, &mut ws, &mut ()).unwrap();
        assert_eq!(used, 100);
        assert_eq!(estimate.unwrap().window.len(), 100);
    }

    #[test]
    fn a_window_split_by_a_time_jump_leaves_nothing_for_the_next() {
        let blob = crate::model::AlignedBlob::new(crate::assets::DEFAULT_MODEL);
        let runner = CoreRunner::new(&blob).unwrap();
        let mut cams = core_estimators(&runner, 1, 256, 7_500, 0).unwrap();
        check_time_jump(cams[0].as_mut());
        #[cfg(feature = "onnx")]
        {
            let onnx = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/mcu.onnx");
            let (mut tract, _) = TractCamera::load(&onnx, None, 7_500, 0).unwrap();
            check_time_jump(&mut tract);
        }
    }

    #[test]
    fn rescaling_maps_pixels_and_joints() {
        let r = Rescale {
            sensor: (1280, 720),
            model: (346, 260),
        };
        let e = |x, y| Event::new(x, y, 0, true);
        assert_eq!(r.event(e(0, 0)), Some(e(0, 0)));
        assert_eq!(r.event(e(1279, 719)), Some(e(345, 259)));
        assert_eq!(r.event(e(640, 360)), Some(e(173, 130)));
        assert_eq!(r.event(e(1280, 0)), None);
        // Pixel centres map to pixel centres: model (0, 0) is the centre of the sensor's first
        // 3.7 × 2.77 pixels.
        let [x, y] = r.joint([0.0, 0.0]);
        assert!(
            (x - 1.3497).abs() < 1e-3 && (y - 0.8846).abs() < 1e-3,
            "{x} {y}"
        );
        let [x, y] = r.joint([345.0, 259.0]);
        assert!(
            (x - 1277.65).abs() < 1e-2 && (y - 718.115).abs() < 1e-2,
            "{x} {y}"
        );
        let same = Rescale {
            sensor: (346, 260),
            model: (346, 260),
        };
        assert_eq!(same.joint([12.0, 7.0]), [12.0, 7.0]);
        assert_eq!(same.event(e(400, 0)), Some(e(400, 0)));
    }
}

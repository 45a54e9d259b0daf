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
        let mut rest = events;
        let mut closed = None;
        // The rasterizer holds a whole window: it closes by count only at the last event.
        while !rest.is_empty() {
            let (used, estimate) = self.session.extend(rest, &mut ws, &mut ())?;
            if let Some(e) = estimate {
                closed = Some(Raw::of(&e, events.len(), scales));
            }
            rest = &rest[used..];
        }
        match closed {
            Some(raw) => Ok(raw),
            None => Ok(Raw::of(
                &self.session.flush(&mut ws, &mut ())?,
                events.len(),
                scales,
            )),
        }
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
            let raster = pipeline::rasterizer(size, k, capacity as u32)?;
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
        let raster = pipeline::rasterizer(size, slices(0), capacity as u32)?;
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

    /// Another camera's estimator over the same loaded model (no second load or tract
    /// optimization), its sampler seeded with `seed`.
    pub fn with_seed(&self, seed: u64) -> Result<Self> {
        let c = *self.raster.config();
        let capacity = self.capacity as u32;
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
        let closed = self.raster.extend(events).1.is_some();
        let window = if closed {
            self.raster.last_window().unwrap_or_default()
        } else {
            self.raster.flush()
        };
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
        Ok(Raw {
            events: events.len(),
            points: window.len(),
            joints,
            confidence,
        })
    }

    fn joints(&self) -> usize {
        self.joints
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

//! The per-window pipeline, written once: events → window → sampled points → inference →
//! joints.
//!
//! [`Session`] owns the streaming [`Rasterizer`] and an [`Estimator`] (the sampler's generator
//! and an inference [`Plan`]); the caller lends a [`Workspace`] (sampling indices, input rows,
//! inference scratch and outputs, joints) and feeds event batches. Each closed window comes
//! back as an [`Estimate`]: the window (its points, span and event count), the rasterizer's
//! counters, the network input, a view of the SimDR heads and the decoded joints, all borrowed
//! from the session and the workspace, so nothing is copied and nothing allocates.
//!
//! The host (`evpose run`), the Cortex-M7 firmware and the QEMU test all run windows through
//! [`Session::feed`] (or its parts [`Session::extend`] / [`Session::flush`]). The engine is a type
//! parameter of the [`Workspace`] ([`I8`] or [`F32`]), so an image links only the one it runs. A
//! [`Profiler`]
//! sees each stage begin and end (TensorFlow Lite Micro's profiler interface): the firmware
//! counts instructions with it; `()` profiles nothing.
//!
//! [`Digest`] defines the CRC-32 of a window's point cloud, network input and heads once, for
//! the firmware to print and the host to compare.
//!
//! ```
//! use evpose_core::pipeline::{Estimator, Session, Workspace, I8};
//! use evpose_core::{kernels::Kernels, Davis346Storage, Event, Model, Plan, RasterConfig, Rasterizer};
//! # fn demo(blob: &[u8]) -> Result<(), Box<dyn core::error::Error>> {
//! // `blob` starts at a 16-byte-aligned address (see `Model::parse`).
//! let model = Model::parse(blob)?;
//! // `Kernels::best()` on an MCU (what the build guarantees); `Kernels::detect()` on a host,
//! // whose default x86-64 build guarantees no SIMD (`best()` is then the scalar reference).
//! let plan = Plan::new(&model, Kernels::detect(), evpose_core::scratch_words(&model))?;
//! // The rasterization and point count the model was trained with: `model.preprocessing()`
//! // (the bundled models: DAVIS346's 7,500-event windows in K = 4 slices, N = 256 or 2,048).
//! let raster = Rasterizer::new(RasterConfig::DAVIS346, Davis346Storage::new())?;
//! let n = model.input_points();
//! let mut session = Session::new(raster, Estimator::new(plan, n, 0));
//! let (mut indices, mut rows) = (vec![0; n], vec![[0.0; 5]; n]);
//! let mut scratch = vec![0i32; plan.scratch_words()];
//! let (mut x, mut y) = (vec![0; plan.out_x_len()], vec![0; plan.out_y_len()]);
//! let mut joints = vec![Default::default(); model.joints()];
//! let mut ws = Workspace::<I8> {
//!     indices: &mut indices,
//!     rows: &mut rows,
//!     scratch: &mut scratch,
//!     x: &mut x,
//!     y: &mut y,
//!     joints: &mut joints,
//! };
//! let events = [Event::new(10, 20, 0, true); 7_500];
//! session.feed(&events, &mut ws, &mut (), |estimate| {
//!     // A filter's time for this window is its last event's: `window.summary().t_max`.
//!     assert_eq!(estimate.window.summary().events, 7_500);
//!     Ok::<(), evpose_core::pipeline::PipelineError>(())
//! })?;
//! # Ok(()) }
//! ```

use core::fmt;

use crate::infer::{InferError, Plan};
use crate::model::{DType, CRC, FEATURES};
use crate::raster::{RasterStats, RasterStorage, Rasterizer, Window};
use crate::sample::{rng_from_seed, sample_window, BufferTooSmall, SampleRng};
use crate::simdr::{decode, Joint2d, ShapeError};
use crate::Event;

/// Network input points per window: the paper's N.
pub const DEFAULT_POINTS: usize = 2048;

/// Why a window could not be estimated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PipelineError {
    /// The workspace's sampling buffers are too small.
    Sample(BufferTooSmall),
    /// Inference refused its buffers (or the workspace's engine is not the plan's).
    Infer(InferError),
    /// The heads could not be decoded into the workspace's joints.
    Decode(ShapeError),
}

impl fmt::Display for PipelineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Sample(e) => write!(f, "sampling: {e}"),
            Self::Infer(e) => write!(f, "inference: {e}"),
            Self::Decode(e) => write!(f, "decoding: {e}"),
        }
    }
}

impl core::error::Error for PipelineError {}

impl From<BufferTooSmall> for PipelineError {
    fn from(e: BufferTooSmall) -> Self {
        Self::Sample(e)
    }
}

impl From<InferError> for PipelineError {
    fn from(e: InferError) -> Self {
        Self::Infer(e)
    }
}

impl From<ShapeError> for PipelineError {
    fn from(e: ShapeError) -> Self {
        Self::Decode(e)
    }
}

/// A stage of the per-window pipeline, as a [`Profiler`] sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Step {
    /// Events into the rasterizer, up to the end of a window.
    Rasterize,
    /// The window's points sampled to the network input.
    Sample,
    /// The network.
    Infer,
    /// SimDR decoding to joints.
    Decode,
}

/// Sees each pipeline stage begin and end (TensorFlow Lite Micro's `MicroProfilerInterface`).
/// `()` is the profiler that does nothing.
pub trait Profiler {
    /// `step` begins.
    fn begin(&mut self, step: Step);
    /// `step` ends.
    fn end(&mut self, step: Step);
}

impl Profiler for () {
    #[inline(always)]
    fn begin(&mut self, _: Step) {}
    #[inline(always)]
    fn end(&mut self, _: Step) {}
}

/// An inference engine of a [`Plan`], chosen at compile time so that an image links only the
/// engine it runs: [`I8`] (int32 accumulators) or [`F32`] (logits).
pub trait Engine {
    /// The scratch and head-output element: `i32` for int8, `f32` for f32.
    type Value: Copy + PartialOrd + Default;
    /// The model type this engine runs.
    const DTYPE: DType;
    /// Runs `plan` with this engine.
    fn run(
        plan: &Plan<'_>,
        points: &[[f32; FEATURES]],
        scratch: &mut [Self::Value],
        x: &mut [Self::Value],
        y: &mut [Self::Value],
    ) -> Result<(), InferError>;
    /// The heads' view.
    fn heads<'a>(x: &'a [Self::Value], y: &'a [Self::Value]) -> Heads<'a>;
}

/// The int8 engine ([`Plan::run_i8`]).
#[derive(Clone, Copy, Debug)]
pub struct I8;

/// The f32 engine ([`Plan::run_f32`]).
#[derive(Clone, Copy, Debug)]
pub struct F32;

impl Engine for I8 {
    type Value = i32;
    const DTYPE: DType = DType::I8;
    fn run(
        plan: &Plan<'_>,
        points: &[[f32; FEATURES]],
        scratch: &mut [i32],
        x: &mut [i32],
        y: &mut [i32],
    ) -> Result<(), InferError> {
        plan.run_i8(points, scratch, x, y)
    }
    fn heads<'a>(x: &'a [i32], y: &'a [i32]) -> Heads<'a> {
        Heads::I8 { x, y }
    }
}

impl Engine for F32 {
    type Value = f32;
    const DTYPE: DType = DType::F32;
    fn run(
        plan: &Plan<'_>,
        points: &[[f32; FEATURES]],
        scratch: &mut [f32],
        x: &mut [f32],
        y: &mut [f32],
    ) -> Result<(), InferError> {
        plan.run_f32(points, scratch, x, y)
    }
    fn heads<'a>(x: &'a [f32], y: &'a [f32]) -> Heads<'a> {
        Heads::F32 { x, y }
    }
}

/// The memory a window's estimate runs in, lent by the caller (statics on an MCU, vectors on
/// a host), for engine `E`.
#[derive(Debug)]
pub struct Workspace<'w, E: Engine> {
    /// Sampling indices: at least the point count `N` (when `N` is 0, the most points a window
    /// can have: its event capacity).
    pub indices: &'w mut [u32],
    /// Network input rows: at least [`crate::sample::sample_len`]`(capacity, N)`: `N`, or when
    /// `N` is 0 the window's event capacity (a window has at most one point per event).
    pub rows: &'w mut [[f32; FEATURES]],
    /// Inference scratch: at least [`Plan::scratch_words`] (plus
    /// [`ALIGN_WORDS`](crate::infer::ALIGN_WORDS) on a host).
    pub scratch: &'w mut [E::Value],
    /// x head outputs: exactly [`Plan::out_x_len`] (`J × W`).
    pub x: &'w mut [E::Value],
    /// y head outputs: exactly [`Plan::out_y_len`] (`J × H`).
    pub y: &'w mut [E::Value],
    /// Decoded joints: the model's `J`.
    pub joints: &'w mut [Joint2d],
}

/// The SimDR heads of one estimate: f32 logits or the int8 engine's int32 accumulators, `J × W`
/// and `J × H` row-major.
#[derive(Clone, Copy, Debug)]
pub enum Heads<'a> {
    /// f32 logits.
    F32 {
        /// x logits.
        x: &'a [f32],
        /// y logits.
        y: &'a [f32],
    },
    /// int32 accumulators (bias included) of the int8 engine.
    I8 {
        /// x accumulators.
        x: &'a [i32],
        /// y accumulators.
        y: &'a [i32],
    },
}

/// One closed window's result.
#[derive(Clone, Copy, Debug)]
pub struct Estimate<'a> {
    /// Index of the window in the stream, from 0.
    pub index: u32,
    /// The window: its points, event count and time span.
    pub window: Window<'a>,
    /// The rasterizer's counters after this window (cumulative over the stream).
    pub stats: RasterStats,
    /// The network input: the sampled rows `[x, y, t_avg, p_acc, cnt]`.
    pub input: &'a [[f32; FEATURES]],
    /// The SimDR heads.
    pub heads: Heads<'a>,
    /// The decoded joints, in the model's joint order, pixels.
    pub joints: &'a [Joint2d],
}

impl Estimate<'_> {
    /// The confidence of each joint into `out`, exactly `J` long ([`crate::confidence::joints`];
    /// another length is a [`ShapeError`]), with the model's logit scales
    /// ([`crate::Model::head_scales`]; `None` for an int8 blob of format version 1 or 2, which
    /// predate them: such a blob has no confidences, re-quantize the model to get them).
    pub fn confidence(&self, scales: [f32; 2], out: &mut [f32]) -> Result<(), ShapeError> {
        let j = self.joints.len().max(1);
        match self.heads {
            Heads::I8 { x, y } => {
                crate::confidence::joints(x, y, x.len() / j, y.len() / j, scales, self.joints, out)
            }
            Heads::F32 { x, y } => {
                crate::confidence::joints(x, y, x.len() / j, y.len() / j, scales, self.joints, out)
            }
        }
    }

    /// CRC-32 digests of the window's point cloud, input and heads.
    pub fn digest(&self) -> Digest {
        Digest {
            points: Digest::points(&self.window),
            input: Digest::rows(self.input),
            heads: match self.heads {
                Heads::I8 { x, y } => Digest::heads_i32(x, y),
                Heads::F32 { x, y } => Digest::heads_f32(x, y),
            },
        }
    }
}

/// CRC-32 digests (ISO-HDLC, as the model blob's) of a window's stages, defined once so that
/// the firmware and the host compare the same bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Digest {
    /// [`Digest::points`] of the point cloud.
    pub points: u32,
    /// [`Digest::rows`] of the network input.
    pub input: u32,
    /// [`Digest::heads_i32`] (or `heads_f32`) of the heads.
    pub heads: u32,
}

impl Digest {
    /// The point cloud: per point, x u16, y u16, slice u8, t_avg f32 bits, p_acc i32, cnt u32,
    /// little-endian.
    pub fn points(w: &Window<'_>) -> u32 {
        let mut d = CRC.digest();
        for p in w.iter() {
            d.update(&p.x.to_le_bytes());
            d.update(&p.y.to_le_bytes());
            d.update(&[p.slice]);
            d.update(&p.t_avg.to_bits().to_le_bytes());
            d.update(&p.p_acc.to_le_bytes());
            d.update(&p.cnt.to_le_bytes());
        }
        d.finalize()
    }

    /// Network input rows: f32 bits, little-endian, row by row.
    pub fn rows(rows: &[[f32; FEATURES]]) -> u32 {
        let mut d = CRC.digest();
        for v in rows.iter().flatten() {
            d.update(&v.to_bits().to_le_bytes());
        }
        d.finalize()
    }

    /// int32 heads: all x values, then all y values, little-endian.
    pub fn heads_i32(x: &[i32], y: &[i32]) -> u32 {
        let mut d = CRC.digest();
        for v in x.iter().chain(y) {
            d.update(&v.to_le_bytes());
        }
        d.finalize()
    }

    /// f32 heads: all x values' bits, then all y values', little-endian.
    pub fn heads_f32(x: &[f32], y: &[f32]) -> u32 {
        let mut d = CRC.digest();
        for v in x.iter().chain(y) {
            d.update(&v.to_bits().to_le_bytes());
        }
        d.finalize()
    }
}

/// Sampling, inference and decoding of closed windows: the point count `N`, the sampler's
/// generator (one for the whole stream, seeded once) and the inference plan.
#[derive(Clone, Debug)]
pub struct Estimator<'m> {
    plan: Plan<'m>,
    rng: SampleRng,
    points: usize,
    windows: u32,
}

impl<'m> Estimator<'m> {
    /// Samples `points` points per window (0 keeps every point) with a generator seeded with
    /// `seed`, and runs `plan`.
    pub fn new(plan: Plan<'m>, points: usize, seed: u64) -> Self {
        Self {
            plan,
            rng: rng_from_seed(seed),
            points,
            windows: 0,
        }
    }

    /// The inference plan.
    pub fn plan(&self) -> &Plan<'m> {
        &self.plan
    }

    /// Points per window.
    pub fn points(&self) -> usize {
        self.points
    }

    /// Windows estimated so far.
    pub fn windows(&self) -> u32 {
        self.windows
    }

    /// Whether `ws` can hold the estimate of any window of up to `capacity` events: sampling
    /// buffers of [`crate::sample::sample_len`]`(capacity, N)` rows and indices, an engine of
    /// the plan's model type, head outputs of [`Plan::out_x_len`] and [`Plan::out_y_len`],
    /// [`Plan::scratch_words`] of scratch and room for the model's joints. What
    /// [`Estimator::estimate`] would refuse, told before a window is taken.
    pub fn check_workspace<E: Engine>(
        &self,
        ws: &Workspace<'_, E>,
        capacity: usize,
    ) -> Result<(), PipelineError> {
        let needed = crate::sample::sample_len(capacity, self.points);
        let available = ws.rows.len().min(ws.indices.len());
        if available < needed {
            return Err(PipelineError::Sample(BufferTooSmall { needed, available }));
        }
        let model = self.plan.model();
        if model.dtype() != E::DTYPE {
            return Err(PipelineError::Infer(InferError::DType));
        }
        self.plan
            .check(needed.max(1), ws.scratch.len(), (ws.x.len(), ws.y.len()))?;
        if ws.joints.len() < model.joints() {
            return Err(PipelineError::Decode(ShapeError::Length {
                expected: model.joints(),
                got: ws.joints.len(),
            }));
        }
        Ok(())
    }

    /// Samples, infers and decodes one closed window in `ws`.
    pub fn estimate<'a, E: Engine>(
        &mut self,
        window: Window<'a>,
        stats: RasterStats,
        ws: &'a mut Workspace<'_, E>,
        prof: &mut impl Profiler,
    ) -> Result<Estimate<'a>, PipelineError> {
        prof.begin(Step::Sample);
        let input = sample_window(&window, self.points, &mut self.rng, ws.indices, ws.rows)?;
        prof.end(Step::Sample);
        let model = self.plan.model();
        let (width, height) = (model.width(), model.height());
        let got = ws.joints.len();
        let joints = ws
            .joints
            .get_mut(..model.joints())
            .ok_or(ShapeError::Length {
                expected: model.joints(),
                got,
            })?;
        prof.begin(Step::Infer);
        E::run(&self.plan, input, ws.scratch, ws.x, ws.y)?;
        prof.end(Step::Infer);
        prof.begin(Step::Decode);
        decode(ws.x, ws.y, width, height, joints)?;
        prof.end(Step::Decode);
        let heads = E::heads(ws.x, ws.y);
        let index = self.windows;
        // Wrapping: 2^32 windows are a year at 133 windows/s, and a counter is no reason to
        // panic.
        self.windows = self.windows.wrapping_add(1);
        Ok(Estimate {
            index,
            window,
            stats,
            input,
            heads,
            joints,
        })
    }
}

/// A stream of events through the whole pipeline: the rasterizer and the estimator.
pub struct Session<'m, S> {
    raster: Rasterizer<S>,
    estimator: Estimator<'m>,
}

impl<'m, S: RasterStorage> Session<'m, S> {
    /// A session over a rasterizer (its configuration decides the windows) and an estimator.
    pub fn new(raster: Rasterizer<S>, estimator: Estimator<'m>) -> Self {
        Self { raster, estimator }
    }

    /// The rasterizer (its counters, the events buffered in the open window).
    pub fn rasterizer(&self) -> &Rasterizer<S> {
        &self.raster
    }

    /// The estimator (plan, point count, windows so far).
    pub fn estimator(&self) -> &Estimator<'m> {
        &self.estimator
    }

    /// Feeds events until one closes a window (as [`Rasterizer::extend`]); returns how many
    /// were used and, when a window closed, its estimate.
    ///
    /// A workspace that cannot hold a window's estimate ([`Estimator::check_workspace`]: its
    /// sampling buffers, engine, head outputs, scratch and joints) is refused before any event
    /// is used, so that the caller can feed the same events again with a workspace that fits.
    pub fn extend<'a, E: Engine>(
        &'a mut self,
        events: &[Event],
        ws: &'a mut Workspace<'_, E>,
        prof: &mut impl Profiler,
    ) -> Result<(usize, Option<Estimate<'a>>), PipelineError> {
        self.estimator.check_workspace(ws, self.raster.capacity())?;
        prof.begin(Step::Rasterize);
        let (used, closed) = {
            let (used, window) = self.raster.extend(events);
            (used, window.is_some())
        };
        prof.end(Step::Rasterize);
        let stats = *self.raster.stats();
        match self.raster.last_window().filter(|_| closed) {
            Some(w) => Ok((used, Some(self.estimator.estimate(w, stats, ws, prof)?))),
            None => Ok((used, None)),
        }
    }

    /// Closes the open window (possibly empty: sampling then gives `N` zero points) and
    /// estimates it. At the end of a stream whose last window already closed (a whole number
    /// of event-count windows), that is an empty window's estimate, with an index of its own:
    /// call it only when [`Rasterizer::buffered`] (through [`Session::rasterizer`]) is not 0. A workspace that cannot hold the estimate is refused first, as in
    /// [`Session::extend`], with the window still open.
    pub fn flush<'a, E: Engine>(
        &'a mut self,
        ws: &'a mut Workspace<'_, E>,
        prof: &mut impl Profiler,
    ) -> Result<Estimate<'a>, PipelineError> {
        self.estimator.check_workspace(ws, self.raster.capacity())?;
        self.raster.flush();
        let stats = *self.raster.stats();
        let w = self.raster.last_window().unwrap_or_default();
        self.estimator.estimate(w, stats, ws, prof)
    }

    /// Feeds a whole batch, calling `on_window` with each window it closes, in order: the
    /// per-window loop of every evpose pipeline (host and firmware).
    ///
    /// Always inlined: outlined on the Cortex-M7, the rasterizer's fill loop inside it spilled
    /// more and cost 140.2 instead of 133.3 instructions per event (QEMU, `firmware_qemu`,
    /// measured before the loop moved to i32 offsets).
    #[inline(always)]
    pub fn feed<E: Engine, Err: From<PipelineError>>(
        &mut self,
        events: &[Event],
        ws: &mut Workspace<'_, E>,
        prof: &mut impl Profiler,
        mut on_window: impl FnMut(Estimate<'_>) -> Result<(), Err>,
    ) -> Result<(), Err> {
        let mut rest = events;
        while !rest.is_empty() {
            let (used, estimate) = self.extend(rest, ws, prof)?;
            if let Some(e) = estimate {
                on_window(e)?;
            }
            // `extend` uses at most what it was given; `get` keeps a panic path out of firmware.
            rest = rest.get(used..).unwrap_or_default();
        }
        Ok(())
    }
}

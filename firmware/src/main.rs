//! evpose on a Cortex-M7, end to end: events → rasterization → sampling → int8 PointNet → SimDR.
//!
//! The image embeds an int8 model blob (`models/mcu.evq` at the repository root, the trained MCU
//! model and the default of `evpose run`) and 22,500 events of the DAVIS346 street recording
//! (`assets/street-00-02.evs`, three 7,500-event windows), and checks at boot that the core's
//! EVT decoder gives the first window's events from faery's EVT 3.0 words
//! (`assets/street-00.evt3`) and evutils's EVT 2.1 words in a GenX320's byte order
//! (`assets/street-00.evt21`), directly and through `input::EvtSource`. It streams the events through the
//! core's rasterizer in DMA-sized batches, samples each window to the blob's point count (256)
//! with a fixed seed, runs the int8 engine, decodes the joints, and prints per window, over defmt
//! (semihosting under QEMU): the joints, their confidences and the temporally filtered joints
//! (`core::smooth`; f32 bits), CRC-32 checksums of the
//! point cloud, of the network input and of the heads' int32 accumulators, and the instructions
//! of every stage.
//! The test suite (`tests/firmware_qemu.rs`) runs the same windows through the core on the
//! host and asserts identical joints and checksums.
//!
//! Every buffer is a `static` sized at compile time; there is no allocator (see `memory.x` for
//! the layout and the README's "Firmware (Cortex-M7)" section for the figures).
#![no_std]
#![no_main]
#![deny(unsafe_op_in_unsafe_fn)]
#![warn(clippy::undocumented_unsafe_blocks)]

mod clock;
mod fault;
mod input;
mod selftest;
mod stack;

use core::cell::Cell;
use cortex_m_rt::entry;
use defmt::println;
use defmt_semihosting as _;

use evpose_core::evt::Encoding;
use evpose_core::kernels::{self, Kernels};
use evpose_core::model::{DType, ModelError, FEATURES};
use evpose_core::pipeline::{Digest, Estimate, PipelineError, Profiler, Step, I8};
use evpose_core::raster::ConfigError;
use evpose_core::smooth::{
    AxisState, BadSmoothParams, FixedLag, Held, LagError, LagParams, LagSlot, SmoothParams,
    Smoother, StateTooSmall,
};
use evpose_core::{
    scratch_words_for_block, widen_point_layers, Davis346Storage, Estimator, Event, InferError,
    Joint2d, Model, Plan, RasterConfig, Rasterizer, Session, Workspace,
};
use static_cell::ConstStaticCell;

use crate::input::{EventSource, EvsReader, StreamError};

/// Seed of the point sampler: one generator for the whole stream, as `evpose` uses it.
const SEED: u64 = 0;
/// Events read from the source per batch (one DMA half-buffer on a board).
const BATCH: usize = 256;
// JOINTS, WIDTH, HEIGHT, SCRATCH_WORDS, POINTS and WIDENED_WORDS of the embedded model,
// computed by build.rs with `evpose_core::Model::parse`, `scratch_words_for_block` and
// `widened_words` (and checked again at boot).
include!(concat!(env!("OUT_DIR"), "/model_dims.rs"));

/// A model blob at a 16-byte-aligned address (`Model::parse` reads its arrays in place).
#[repr(C, align(16))]
struct Aligned<T>(T);

static MODEL: Aligned<[u8; include_bytes!("../../models/mcu.evq").len()]> =
    Aligned(*include_bytes!("../../models/mcu.evq"));
static EVENTS: [u8; include_bytes!("../assets/street-00-02.evs").len()] =
    *include_bytes!("../assets/street-00-02.evs");
/// The first window's events as EVT 3.0 words (what a Prophesee sensor streams), for the boot
/// check of the core's EVT decoder (`input::check_evt`).
static EVT3: [u8; include_bytes!("../assets/street-00.evt3").len()] =
    *include_bytes!("../assets/street-00.evt3");
/// The same events as EVT 2.1 words in a GenX320's byte order (its default encoding).
static EVT21: [u8; include_bytes!("../assets/street-00.evt21").len()] =
    *include_bytes!("../assets/street-00.evt21");

/// Every working buffer of the pipeline but the rasterizer's.
struct Buffers {
    events: [Event; BATCH],
    indices: [u32; POINTS],
    points: [[f32; FEATURES]; POINTS],
    scratch: [i32; SCRATCH_WORDS],
    out_x: [i32; JOINTS * WIDTH],
    out_y: [i32; JOINTS * HEIGHT],
    joints: [Joint2d; JOINTS],
}

impl Buffers {
    const fn new() -> Self {
        Self {
            events: [Event::new(0, 0, 0, false); BATCH],
            indices: [0; POINTS],
            points: [[0.0; FEATURES]; POINTS],
            scratch: [0; SCRATCH_WORDS],
            out_x: [0; JOINTS * WIDTH],
            out_y: [0; JOINTS * HEIGHT],
            joints: [Joint2d { x: 0, y: 0 }; JOINTS],
        }
    }
}

// Zero-initialized, so both land in .bss; `take()` hands out the one `&'static mut` (the
// rasterizer runs in the borrowed storage: a 122 KiB value must not pass through the stack).
static RASTER: ConstStaticCell<Davis346Storage> = ConstStaticCell::new(Davis346Storage::new());
static BUFFERS: ConstStaticCell<Buffers> = ConstStaticCell::new(Buffers::new());
/// The model's int8 point layers widened for the DSP block kernel (`widen_point_layers`):
/// twice their int8 bytes of RAM (38,400 for the bundled model), which save two `SXTB16` per
/// four weights and block of points.
static WIDENED: ConstStaticCell<[u32; WIDENED_WORDS]> = ConstStaticCell::new([0; WIDENED_WORDS]);

/// Why the pipeline stopped.
#[derive(defmt::Format)]
enum Error {
    Model(ModelError),
    /// The model does not fit the buffers this image was built with.
    ModelShape {
        joints: usize,
        width: usize,
        height: usize,
        scratch_words: usize,
    },
    Config(ConfigError),
    Stream(StreamError),
    Infer(InferError),
    Pipeline(PipelineError),
    /// The blob carries no logit scales for its int8 heads (a version 1 or 2 blob), which joint
    /// confidences need.
    NoHeadScales,
    /// The temporal filter's state does not hold the model's joints.
    Smooth(StateTooSmall),
    /// The One-Euro filter's parameters make no filter.
    SmoothParams(BadSmoothParams),
    /// The fixed-lag filter refused (its state, or a window's shape).
    Lag(LagError),
    /// A static buffer was taken twice (`run` takes each once).
    BuffersTaken,
}

macro_rules! from {
    ($($t:ty => $v:ident),*) => {
        $(impl From<$t> for Error {
            fn from(e: $t) -> Self {
                Self::$v(e)
            }
        })*
    };
}
from!(ModelError => Model, ConfigError => Config, StreamError => Stream,
      InferError => Infer, PipelineError => Pipeline);

#[entry]
fn main() -> ! {
    stack::paint();
    #[cfg(feature = "overflow-test")]
    fault::overflow();
    let Some(cp) = cortex_m::Peripherals::take() else {
        exit(2)
    };
    clock::start(cp.SYST);
    let per_tick = u64::from(clock::calibrate());
    println!("clock: instructions_per_tick={=u64}", per_tick);
    let kernels = evpose_core::kernels::Kernels::best();
    let check = selftest::kernels(&kernels);
    let (decoder_cases, decoder_mismatches) = input::check_decoder();
    println!(
        "selftest: kernels={=str} cases={=u32} mismatches={=u32} decoder_cases={=u32} decoder_mismatches={=u32}",
        kernels.name(),
        check.cases,
        check.mismatches,
        decoder_cases,
        decoder_mismatches
    );
    if decoder_mismatches > 0 {
        defmt::error!("the batch event decoder disagrees with the per-event one");
        exit(3)
    }
    // The assets hold the first window's events.
    let mut evt3 = input::check_evt(Encoding::Evt3, &EVENTS, &EVT3, 7_500);
    // A bad word in the stream: `EvtSource` reports it and reads on after it.
    evt3.mismatches += u32::from(!input::evt_source_recovers());
    println!(
        "evt3: events={=u32} mismatches={=u32} instructions={=u64}",
        evt3.events,
        evt3.mismatches,
        evt3.ticks * per_tick
    );
    let evt21 = input::check_evt(Encoding::Evt21, &EVENTS, &EVT21, 7_500);
    println!(
        "evt21: events={=u32} mismatches={=u32} instructions={=u64}",
        evt21.events,
        evt21.mismatches,
        evt21.ticks * per_tick
    );
    if evt3.mismatches > 0 || evt21.mismatches > 0 {
        defmt::error!("the core's EVT decoder disagrees with the EVS1 stream");
        exit(3)
    }
    if check.mismatches > 0 {
        // Wrong kernels give wrong joints: stop rather than report them.
        defmt::error!("the int8 kernels disagree with the reference");
        exit(3)
    }
    let code = match run(per_tick) {
        Ok(()) => 0,
        Err(e) => {
            defmt::error!("pipeline failed: {}", e);
            1
        }
    };
    println!(
        "stack: used={=usize} reserved={=usize}",
        stack::high_water(),
        stack::size()
    );
    exit(code)
}

fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

/// Instructions per pipeline stage, from SysTick ticks and the calibration: the core's
/// [`Profiler`] hook (shared, so that the per-window report can read it while the session runs).
struct StageClock {
    per_tick: u64,
    /// Tick at which the running stage began.
    started: Cell<u64>,
    /// Instructions per [`Step`] since the last report, and reading input.
    spent: [Cell<u64>; 5],
}

impl StageClock {
    const INPUT: usize = 4;

    fn new(per_tick: u64) -> Self {
        Self {
            per_tick,
            started: Cell::new(0),
            spent: Default::default(),
        }
    }

    fn slot(step: Step) -> usize {
        match step {
            Step::Rasterize => 0,
            Step::Sample => 1,
            Step::Infer => 2,
            Step::Decode => 3,
        }
    }

    /// Instructions since `start` (in ticks).
    fn since(&self, start: u64) -> u64 {
        (clock::ticks() - start) * self.per_tick
    }

    fn add(&self, slot: usize, instructions: u64) {
        self.spent[slot].set(self.spent[slot].get() + instructions);
    }

    /// The instructions per slot since the last call, and zero them.
    fn take(&self) -> [u64; 5] {
        core::array::from_fn(|i| self.spent[i].take())
    }
}

impl Profiler for &StageClock {
    fn begin(&mut self, _: Step) {
        self.started.set(clock::ticks());
    }

    fn end(&mut self, step: Step) {
        self.add(StageClock::slot(step), self.since(self.started.get()));
    }
}

fn run(per_tick: u64) -> Result<(), Error> {
    let clock = StageClock::new(per_tick);
    let t = clock::ticks();
    let model = Model::parse(&MODEL.0)?;
    let parse = clock.since(t);
    let scratch_needed = scratch_words_for_block(&model, kernels::arm::BLOCK_POINTS);
    if model.dtype() != DType::I8
        || (model.joints(), model.width(), model.height()) != (JOINTS, WIDTH, HEIGHT)
        || scratch_needed > SCRATCH_WORDS
    {
        return Err(Error::ModelShape {
            joints: model.joints(),
            width: model.width(),
            height: model.height(),
            scratch_words: scratch_needed,
        });
    }
    let scales = model.head_scales().ok_or(Error::NoHeadScales)?;
    let t = clock::ticks();
    let widened = WIDENED.try_take().ok_or(Error::BuffersTaken)?;
    let widened = widen_point_layers(&model, widened)?;
    let widen = clock.since(t);
    let t = clock::ticks();
    let plan = Plan::widened(&model, Kernels::best(), &widened, SCRATCH_WORDS)?;
    let prepare = clock.since(t);
    let Buffers {
        events,
        indices,
        points,
        scratch,
        out_x,
        out_y,
        joints,
    } = BUFFERS.try_take().ok_or(Error::BuffersTaken)?;
    // What does not scale with the point count (FC layers, heads, set-up): one inference on
    // one point. An inference's instructions do not depend on the values (no data-dependent
    // branches), so the difference to a window's inference is what its point layers cost.
    let t = clock::ticks();
    plan.run_i8(&[[0.0; FEATURES]], scratch, out_x, out_y)?;
    let one_point = clock.since(t);
    println!(
        "model: bytes={=usize} layers={=usize} point_layers={=usize} macs_per_point={=u64} macs_after_pooling={=u64} scratch_words={=usize} block={=usize} widened_words={=usize} parse_instructions={=u64} widen_instructions={=u64} plan_instructions={=u64} infer_one_point={=u64}",
        model.bytes().len(),
        model.layer_count(),
        model.point_layer_count(),
        model.macs_per_point(),
        model.macs_after_pooling(),
        plan.scratch_words(),
        plan.block(),
        WIDENED_WORDS,
        parse,
        widen,
        prepare,
        one_point
    );

    let storage = RASTER.try_take().ok_or(Error::BuffersTaken)?;
    let raster = Rasterizer::new(RasterConfig::DAVIS346, storage)?;
    let mut session = Session::new(raster, Estimator::new(plan, POINTS, SEED));
    let mut ws = Workspace::<I8> {
        indices,
        rows: points,
        scratch,
        x: out_x,
        y: out_y,
        joints,
    };
    // The causal One-Euro filter (`core::smooth::Smoother`, the parameters of `evpose run
    // --smooth one-euro`): 26 coordinates.
    let mut smooth_state = [AxisState::default(); 2 * JOINTS];
    let mut smoother =
        Smoother::new(SmoothParams::DEFAULT, &mut smooth_state).map_err(Error::SmoothParams)?;
    // The fixed-lag filter (`core::smooth::FixedLag`): lag 1 here, 3 on the host by default.
    // The bundled stream has three windows; with lag 3 each would be the mean of all three, and
    // the host comparison would show less. Each window comes out one window later, the last
    // at the end of the stream.
    const LAG: LagParams = LagParams {
        lag: 1,
        ..LagParams::DEFAULT
    };
    const LAG_SLOTS: usize = FixedLag::slots_for(LAG.lag);
    let mut lag_slots = [LagSlot::default(); LAG_SLOTS];
    let mut lag_held = [Held::default(); LAG_SLOTS * JOINTS];
    let mut lagged =
        FixedLag::with_params(LAG, JOINTS, &mut lag_slots, &mut lag_held).map_err(Error::Lag)?;
    // The host test recomputes the filter with these parameters.
    println!(
        "fixed_lag: lag={=usize} reset_after_us={=i64}",
        LAG.lag, LAG.reset_after_us
    );
    let mut source = EvsReader::new(&EVENTS[..])?;
    let h = *source.header();
    println!(
        "stream: width={=u16} height={=u16} events={=u32}",
        h.width, h.height, h.events
    );
    loop {
        let t = clock::ticks();
        let n = source.read_events(events)?;
        clock.add(StageClock::INPUT, clock.since(t));
        if n == 0 {
            break;
        }
        // The whole batch at once: the session rasterizes with `extend` (the same windows as
        // pushing event by event) and estimates every window the batch closes.
        // `read_events` returns at most the batch's length; `get` keeps a panic path out.
        let batch = events.get(..n).unwrap_or_default();
        session.feed(batch, &mut ws, &mut &clock, |e| {
            report(
                &e,
                &clock,
                one_point,
                &model,
                scales,
                &mut smoother,
                &mut lagged,
            )
        })?;
    }
    lagged.finish();
    print_lagged(&mut lagged, &clock);
    // The last window's input again, over the row-major weights (`Plan::new`: what a firmware
    // without the widened weights' RAM runs): its cost per point, and its heads' CRC, which
    // the test compares with the window's.
    {
        let row_major = Plan::new(&model, Kernels::best(), SCRATCH_WORDS)?;
        let t = clock::ticks();
        row_major.run_i8(ws.rows, ws.scratch, ws.x, ws.y)?;
        let per_point = clock.since(t).saturating_sub(one_point) / (POINTS as u64 - 1).max(1);
        println!(
            "row_major: per_point={=u64} per_point_layer_mac={=f32} crc_heads={=u32:#010x}",
            per_point,
            per_point as f32 / model.macs_per_point() as f32,
            Digest::heads_i32(ws.x, ws.y)
        );
    }
    let r = session.rasterizer();
    let s = r.stats();
    println!(
        "done: windows={=u32} accepted={=u64} dropped={=u64} out_of_order={=u64} tail={=usize}",
        session.estimator().windows(),
        s.accepted,
        s.dropped_out_of_range,
        s.out_of_order,
        r.buffered()
    );
    Ok(())
}

/// Prints one window's results, digests, joint confidences and filtered joints (their f32
/// bits, so that the host can compare them exactly) and instructions per stage.
fn report(
    e: &Estimate<'_>,
    clock: &StageClock,
    one_point: u64,
    model: &Model<'_>,
    scales: [f32; 2],
    smoother: &mut Smoother<'_>,
    lagged: &mut FixedLag<'_>,
) -> Result<(), Error> {
    let s = e.window.summary();
    let d = e.digest();
    println!(
        "window={=u32} events={=u32} points={=usize} t_min={=i64} t_max={=i64} crc_points={=u32:#010x} crc_input={=u32:#010x} crc_heads={=u32:#010x}",
        e.index,
        s.events,
        e.window.len(),
        s.t_min,
        s.t_max,
        d.points,
        d.input,
        d.heads
    );
    let mut xy = [0u16; 2 * JOINTS];
    for (pair, j) in xy.chunks_exact_mut(2).zip(e.joints.iter()) {
        pair.copy_from_slice(&[j.x, j.y]);
    }
    println!("window={=u32} joints={}", e.index, xy);
    let t = clock::ticks();
    let mut confidence = [0f32; JOINTS];
    e.confidence(scales, &mut confidence)
        .map_err(|d| Error::Pipeline(PipelineError::Decode(d)))?;
    let confidence_instructions = clock.since(t);
    println!(
        "window={=u32} confidence_bits={}",
        e.index,
        confidence.map(f32::to_bits)
    );
    // The confidence-gated filter, at the window's last event.
    let t = clock::ticks();
    let mut filtered = [[0f32; 2]; JOINTS];
    smoother
        .update(s.t_max, e.joints, &confidence, &mut filtered)
        .map_err(Error::Smooth)?;
    let filter_instructions = clock.since(t);
    let mut filtered_bits = [0u32; 2 * JOINTS];
    for (bits, v) in filtered_bits.iter_mut().zip(filtered.iter().flatten()) {
        *bits = v.to_bits();
    }
    println!("window={=u32} filtered_bits={}", e.index, filtered_bits);
    // The fixed-lag filter: this window in, the windows it completes out.
    let t = clock::ticks();
    lagged
        .push(s.t_max, e.joints, &confidence)
        .map_err(Error::Lag)?;
    let lag_instructions = clock.since(t) + print_lagged(lagged, clock);
    let [rasterize, sample, infer, decode, input] = clock.take();
    let n = e.input.len() as u64;
    let per_point = infer.saturating_sub(one_point) / (n - 1).max(1);
    let per_mac = per_point as f32 / model.macs_per_point() as f32;
    println!(
        "window={=u32} instructions input={=u64} rasterize={=u64} sample={=u64} infer={=u64} decode={=u64} confidence={=u64} filter={=u64} lag_filter={=u64} infer_one_point={=u64} per_point={=u64} per_point_layer_mac={=f32}",
        e.index, input, rasterize, sample, infer, decode, confidence_instructions, filter_instructions, lag_instructions, one_point, per_point, per_mac
    );
    Ok(())
}

/// Prints the fixed-lag filter's ready windows (`lagged: window=K instructions=N bits=[…]`:
/// the instructions of its `pop`, its joints as f32 bits) and returns the instructions the pops
/// took.
#[inline(never)]
fn print_lagged(lagged: &mut FixedLag<'_>, clock: &StageClock) -> u64 {
    let mut spent = 0;
    loop {
        let mut out = [[0f32; 2]; JOINTS];
        let t = clock::ticks();
        let popped = lagged.pop(&mut out);
        let took = clock.since(t);
        spent += took;
        let Some(k) = popped else {
            return spent;
        };
        let mut bits = [0u32; 2 * JOINTS];
        for (b, v) in bits.iter_mut().zip(out.iter().flatten()) {
            *b = v.to_bits();
        }
        println!(
            "lagged: window={=u64} instructions={=u64} bits={}",
            k, took, bits
        );
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    exit(4)
}

#[defmt::panic_handler]
fn defmt_panic() -> ! {
    exit(4)
}

//! evpose on a Cortex-M7, end to end: events → rasterization → sampling → int8 PointNet → SimDR.
//!
//! The image embeds an int8 model blob (`assets/pointnet-small.evq` at the repository root, the default model of `evpose pose`) and 22,500 events of the
//! DAVIS346 street recording (`assets/street-00-02.evs`, three 7,500-event windows). It streams
//! the events through the core's rasterizer in DMA-sized batches, samples each window to 2,048
//! points with a fixed seed, runs the int8 engine, decodes the joints, and prints per window,
//! over defmt (semihosting under QEMU): the joints, CRC-32 checksums of the point cloud, of the
//! network input and of the heads' int32 accumulators, and the instructions of every stage.
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
mod input;
mod selftest;
mod stack;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use defmt::println;
use defmt_semihosting as _;
use evpose_core::model::{DType, ModelError, FEATURES};
use evpose_core::raster::{ConfigError, Window};
use evpose_core::sample::{rng_from_seed, sample_window, BufferTooSmall, SampleRng};
use evpose_core::simdr::ShapeError;
use evpose_core::{
    decode, run_i8, scratch_words, Davis346Storage, Event, InferError, Joint2d, Model,
    RasterConfig, Rasterizer,
};
use static_cell::ConstStaticCell;

use crate::input::{EventSource, EvsReader, StreamError};

/// Network input points per window (the paper's N; `evpose quantize` samples the same).
const POINTS: usize = 2048;
/// Seed of the point sampler: one generator for the whole stream, as `evpose` uses it.
const SEED: u64 = 0;
/// Events read from the source per batch (one DMA half-buffer on a board).
const BATCH: usize = 256;
// JOINTS, WIDTH, HEIGHT and SCRATCH_WORDS of the embedded model, computed by build.rs with
// `evpose_core::Model::parse` and `scratch_words` (and checked again at boot).
include!(concat!(env!("OUT_DIR"), "/model_dims.rs"));

/// A model blob at a 16-byte-aligned address (`Model::parse` reads its arrays in place).
#[repr(C, align(16))]
struct Aligned<T>(T);

static MODEL: Aligned<[u8; include_bytes!("../../assets/pointnet-small.evq").len()]> =
    Aligned(*include_bytes!("../../assets/pointnet-small.evq"));
static EVENTS: [u8; include_bytes!("../assets/street-00-02.evs").len()] =
    *include_bytes!("../assets/street-00-02.evs");

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
    Sample(BufferTooSmall),
    Infer(InferError),
    Decode(ShapeError),
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
      BufferTooSmall => Sample, InferError => Infer, ShapeError => Decode);

#[entry]
fn main() -> ! {
    stack::paint();
    let Some(cp) = cortex_m::Peripherals::take() else {
        exit(2)
    };
    clock::start(cp.SYST);
    let per_tick = u64::from(clock::calibrate());
    println!("clock: instructions_per_tick={=u64}", per_tick);
    let kernels = evpose_core::kernels::Kernels::best();
    let check = selftest::kernels(&kernels);
    println!(
        "selftest: kernels={=str} cases={=u32} mismatches={=u32}",
        kernels.name(),
        check.cases,
        check.mismatches
    );
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

/// Instructions spent since `start` (in SysTick ticks), per the calibration.
struct Stopwatch {
    per_tick: u64,
}

impl Stopwatch {
    fn since(&self, start: u64) -> u64 {
        (clock::ticks() - start) * self.per_tick
    }
}

fn run(per_tick: u64) -> Result<(), Error> {
    let sw = Stopwatch { per_tick };
    let t = clock::ticks();
    let model = Model::parse(&MODEL.0)?;
    let parse = sw.since(t);
    let scratch = scratch_words(&model);
    if model.dtype() != DType::I8
        || (model.joints(), model.width(), model.height()) != (JOINTS, WIDTH, HEIGHT)
        || scratch > SCRATCH_WORDS
    {
        return Err(Error::ModelShape {
            joints: model.joints(),
            width: model.width(),
            height: model.height(),
            scratch_words: scratch,
        });
    }
    println!(
        "model: bytes={=usize} layers={=usize} point_layers={=usize} macs_per_point={=u64} macs_after_pooling={=u64} scratch_words={=usize} parse_instructions={=u64}",
        model.bytes().len(),
        model.layer_count(),
        model.point_layer_count(),
        model.macs_per_point(),
        model.macs_after_pooling(),
        scratch,
        parse
    );

    let Buffers {
        events,
        indices,
        points,
        scratch,
        out_x,
        out_y,
        joints,
    } = BUFFERS.take();
    let mut raster = Rasterizer::new(RasterConfig::DAVIS346, RASTER.take())?;
    let mut source = EvsReader::new(&EVENTS[..])?;
    let h = *source.header();
    println!(
        "stream: width={=u16} height={=u16} events={=u32}",
        h.width, h.height, h.events
    );
    let mut rng = rng_from_seed(SEED);
    let mut window = 0u32;
    let (mut input, mut rasterize) = (0u64, 0u64);
    loop {
        let t = clock::ticks();
        let n = source.read_events(events)?;
        input += sw.since(t);
        if n == 0 {
            break;
        }
        let mut t = clock::ticks();
        // The whole batch at once (`extend`: the same windows as pushing event by event, with
        // the per-event checks in registers); it stops after an event that closes a window.
        let mut rest = &events[..n];
        while !rest.is_empty() {
            let (used, closed) = raster.extend(rest);
            rest = &rest[used..];
            if let Some(w) = closed {
                rasterize += sw.since(t);
                let mut ctx = WindowRun {
                    sw: &sw,
                    model: &model,
                    rng: &mut rng,
                    indices,
                    points,
                    scratch,
                    out_x,
                    out_y,
                    joints,
                };
                ctx.process(window, &w, input, rasterize)?;
                window += 1;
                (input, rasterize) = (0, 0);
                t = clock::ticks();
            }
        }
        rasterize += sw.since(t);
    }
    let s = raster.stats();
    println!(
        "done: windows={=u32} accepted={=u64} dropped={=u64} out_of_order={=u64} tail={=usize}",
        window,
        s.accepted,
        s.dropped_out_of_range,
        s.out_of_order,
        raster.buffered()
    );
    Ok(())
}

/// What one window's processing borrows.
struct WindowRun<'a> {
    sw: &'a Stopwatch,
    model: &'a Model<'a>,
    rng: &'a mut SampleRng,
    indices: &'a mut [u32],
    points: &'a mut [[f32; FEATURES]],
    scratch: &'a mut [i32],
    out_x: &'a mut [i32],
    out_y: &'a mut [i32],
    joints: &'a mut [Joint2d],
}

impl WindowRun<'_> {
    /// Samples, infers and decodes one closed window; prints its results and instructions.
    fn process(
        &mut self,
        index: u32,
        w: &Window<'_>,
        input: u64,
        rasterize: u64,
    ) -> Result<(), Error> {
        let sw = self.sw;
        let t = clock::ticks();
        let rows = sample_window(w, POINTS, self.rng, self.indices, self.points)?;
        let sample = sw.since(t);
        let t = clock::ticks();
        run_i8(self.model, rows, self.scratch, self.out_x, self.out_y)?;
        let infer = sw.since(t);
        let t = clock::ticks();
        decode(self.out_x, self.out_y, WIDTH, HEIGHT, self.joints)?;
        let decode = sw.since(t);

        let s = w.summary();
        println!(
            "window={=u32} events={=u32} points={=usize} t_min={=i64} t_max={=i64} crc_points={=u32:#010x} crc_input={=u32:#010x} crc_heads={=u32:#010x}",
            index,
            s.events,
            w.len(),
            s.t_min,
            s.t_max,
            crc_points(w),
            crc_rows(rows),
            crc_heads(self.out_x, self.out_y)
        );
        let mut xy = [0u16; 2 * JOINTS];
        for (pair, j) in xy.chunks_exact_mut(2).zip(self.joints.iter()) {
            pair.copy_from_slice(&[j.x, j.y]);
        }
        println!("window={=u32} joints={}", index, xy);

        // The same inference on one point: what does not scale with the point count (FC
        // layers, heads, set-up). The difference is what the point layers cost per point.
        let n = rows.len() as u64;
        let t = clock::ticks();
        run_i8(self.model, &rows[..1], self.scratch, self.out_x, self.out_y)?;
        let one_point = sw.since(t);
        let per_point = infer.saturating_sub(one_point) / (n - 1).max(1);
        let per_mac = per_point as f32 / self.model.macs_per_point() as f32;
        println!(
            "window={=u32} instructions input={=u64} rasterize={=u64} sample={=u64} infer={=u64} decode={=u64} infer_one_point={=u64} per_point={=u64} per_point_layer_mac={=f32}",
            index, input, rasterize, sample, infer, decode, one_point, per_point, per_mac
        );
        Ok(())
    }
}

/// CRC-32 (ISO-HDLC, as the model blob's) of the point cloud: per point, x u16, y u16, slice
/// u8, t_avg f32 bits, p_acc i32, cnt u32, little-endian.
fn crc_points(w: &Window<'_>) -> u32 {
    let mut d = evpose_core::model::CRC.digest();
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

/// CRC-32 of the network input rows: f32 bits, little-endian, row by row.
fn crc_rows(rows: &[[f32; FEATURES]]) -> u32 {
    let mut d = evpose_core::model::CRC.digest();
    for v in rows.iter().flatten() {
        d.update(&v.to_bits().to_le_bytes());
    }
    d.finalize()
}

/// CRC-32 of the heads' int32 accumulators: all x values, then all y values, little-endian.
fn crc_heads(x: &[i32], y: &[i32]) -> u32 {
    let mut d = evpose_core::model::CRC.digest();
    for v in x.iter().chain(y) {
        d.update(&v.to_le_bytes());
    }
    d.finalize()
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    defmt::error!(
        "hard fault: pc={=u32:#010x} lr={=u32:#010x}",
        frame.pc(),
        frame.lr()
    );
    exit(3)
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

//! The kernels over pre-packed weights ([`crate::kernels::packed`]): int8 (`vpdpbusd`, four
//! inputs per lane) and int16 (`vpdpwssd`, two), on 512-bit registers (AVX-512 VNNI) and on
//! 256-bit ones (AVX-VNNI, for the CPUs that have it without AVX-512), and on AVX2 and
//! AVX-512BW, which have neither instruction. One loop for the VNNI widths and the int16 kernels
//! of AVX2 and AVX-512BW (`vpmaddwd` and an add in place of `vpdpwssd`), written once
//! ([`packed_loop!`]) and compiled per register width with that width's target features; the
//! int8 kernels of AVX2 and AVX-512BW ([`matmat_packed_i8_avx2`], [`matmat_packed_i8_avx512bw`])
//! are a second loop ([`widened_i8!`]), over inputs it widens first.
//!
//! A register tile is a slice of a row group (64 outputs) by up to [`TILE_POINTS`] points:
//!
//! | width | slice | accumulators | weight registers | per step of one slice |
//! |---|---|---|---|---|
//! | 512-bit | 64 rows, 4 registers of 16 lanes | 24 | 4 | 4 weight loads, 6 broadcasts, 24 `vpdpbusd` (1,536 MACs) |
//! | 256-bit | 16 rows, 2 registers of 8 lanes (16 registers in all) | 12 | 2 | 2 weight loads, 6 broadcasts, 12 `vpdpbusd` (384 MACs) |
//! | AVX2 int8 | 16 rows, 2 registers, 4 points | 8 | 4 (even and odd bytes) | 2 weight loads, 2 masks, 2 shifts, 8 broadcasts, 16 `vpmaddwd`, 16 adds (256 MACs) |
//! | AVX-512BW int8 | 64 rows, 4 registers, 5 points | 20 | 8 | 4 weight loads, 4 masks, 4 shifts, 10 broadcasts, 40 `vpmaddwd`, 40 adds (1,280 MACs) |
//!
//! (The MACs are int8's; an int16 `vpdpwssd` does half as many, two inputs per lane.) No
//! horizontal sums: lane `i` of accumulator `q` is output `LANES·q + i` of the slice, stored as
//! is. Each point's step of inputs (four bytes) is broadcast from memory.
//!
//! Row groups are the outer loop over a pass of up to [`SUPER`] tiles (24 points; the engine's
//! blocks hold up to four passes): each group's weights (32 KiB for the paper's conv5, whose 512 KiB live in L2) are
//! read from L2 once per pass and from L1 by the pass's other tiles, while the pass's inputs
//! (12 KiB for conv5) stay in L1, and `128·Σx` (the correction for the int8 weights' `+128`
//! offset) is computed once per point. With one tile per pass (the weights streamed from L2
//! once per six points), conv5 in blocks of 16 points ran at 495 GMAC/s on this project's Zen 5
//! VM (`benches/kernels.rs`, `packed/avx512vnni`), 94 % of the 524 GMAC/s
//! `kernels::peak_loop` measures, but at 52–55 % of the peak on an Intel Xeon (Emerald Rapids)
//! VM, where passes of four tiles ran 0–9 % faster in a conv5 timing loop (`docs/benchmarks.md`, "Stop 36");
//! a whole layer per row group (every tile of the call over each group's weights in L1, four-point
//! tiles) measured about 340 GMAC/s on the Zen 5 (a timing loop, on the same machine while it
//! was busy).
//!
//! The engine's last point layer can skip memory altogether: the pooled kernels
//! ([`matmat_packed_pool_i8_avx512vnni`], [`matmat_packed_pool_i8_avxvnni`], and for layers of
//! up to 512 inputs [`matmat_packed_pool_i8_avx2`], [`matmat_packed_pool_i8_avx512bw`])
//! requantize each register tile's sums and reduce them into the running max and sum, where
//! the plain kernels store int32 rows that the engine then requantizes to int8 rows and pools.
//!
//! On AVX2 and AVX-512BW the whole paper model runs 1.10–1.25× faster packed than row-major
//! (`docs/benchmarks.md`, "AVX2 and AVX-512BW packed kernels"). The AVX2 tile is four points: five, with
//! two registers each plus the four weight registers and two broadcasts, need 17 of the 16
//! registers, and the compiler then kept every accumulator in memory. Their tiles run in
//! passes of four too, slice by slice: a slice of a row group's weights (8 KiB of conv5's on
//! AVX2) is read from L2 or L3 once per pass of 16 points instead of once per tile (about 5 %
//! of the whole paper model on a Zen 3, `docs/benchmarks.md`, "Stop 37").

use core::arch::x86_64::*;

// The row-major kernels' `vpmaddwd` + add stand in for `vpdpwssd` (the same wrapping sums).
use super::{avx2_mac_i16, avx512bw_mac_i16, ld256_i8, ld256m_i32, ld512m_i32, vnni_corrections};
use crate::kernels::packed::{
    call_dims, pool_dims, Block, Lane, Packed, PackedI16, PackedI8, GROUP_ROWS,
};
use crate::quant::Requant;

/// Points per register tile.
pub const TILE_POINTS: usize = 6;

/// Steps (four inputs each) that the AVX2 and AVX-512BW int8 kernels widen at a time: 512
/// inputs (the paper's widest point layer, conv5), 1 KiB of stack per point of a pass. A layer
/// with more inputs is summed in chunks, its int32 sums written between them.
const WIDENED_CHUNK_STEPS: usize = 128;

/// Whether [`matmat_packed_pool_i8_avx2`] and [`matmat_packed_pool_i8_avx512bw`] run `w`
/// natively: at most 128 steps (512 inputs, one chunk of widened inputs), so that the sums stay
/// in registers until they are pooled.
pub fn widened_pool_takes(w: &PackedI8<'_>) -> bool {
    w.steps() <= WIDENED_CHUNK_STEPS
}

/// Tiles per pass over a row group: [`TILE_POINTS`] · 4 = 24 points (a quarter of the engine's
/// largest block, `infer::MAX_BLOCK`), whose inputs stay in L1 while each row group's weights
/// pass.
const SUPER: usize = 4;

/// What the loop needs to know of a weight type beyond its [`Lane`] layout.
trait Vnni: Lane {
    /// What to subtract from each point's sums, for `out.len()` points (rows `first..` of `x`,
    /// `x_stride` apart, `k` inputs each): `128·Σx` for int8 (the weights' offset), 0 for
    /// int16.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    unsafe fn corrections(x: &[Self], x_stride: usize, first: usize, k: usize, out: &mut [i32]);
}

impl Vnni for i8 {
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn corrections(x: &[i8], x_stride: usize, first: usize, k: usize, out: &mut [i32]) {
        vnni_corrections(x, x_stride, first, k, out)
    }
}

impl Vnni for i16 {
    unsafe fn corrections(_: &[i16], _: usize, _: usize, _: usize, out: &mut [i32]) {
        out.fill(0);
    }
}

/// A tile's points: `(x, x_stride, first point, corrections, epilogue)`.
type TileIo<'a, 'b, T, E> = (&'a [T], usize, usize, &'a [i32], &'b mut E);

/// One row group of one layer: what every tile of points multiplies by.
struct Tile<'a> {
    /// The group's blocks, one per step.
    blocks: &'a [Block],
    /// Inputs per point.
    k: usize,
    /// First row of the group.
    row0: usize,
    /// Rows of the group that are computed (1..=64).
    rows: usize,
    /// Bias from `row0` on.
    bias: &'a [i32],
}

/// Stamps the loop for one register width: a module `$m` with the int8 and int16 kernels
/// `$i8`/`$i16`, compiled with `$features`, on registers `$v` of `$lanes` i32 lanes, `$regs`
/// registers per slice of a row group, and the width's intrinsics (`$zero`, `$set1`, `$load`
/// of one register of a block, `$dpbusd`, `$dpwssd`, and `$store`, which stores the low
/// `min(len, $lanes)` lanes of `a + bias − c`). With `epilogue: $ep` (the module of the pooled
/// epilogue's steps for the width, [`ep512`] or [`ep256`]) it also stamps the pooled epilogue
/// `Pool`, and with `pool: $pool` (a VNNI width) the pooled int8 kernel `$pool` over it.
macro_rules! packed_loop {
    (
        $m:ident, $features:literal,
        $(i8: $i8:ident, dpbusd: $dpbusd:expr, $(pool: $pool:ident,)?)? i16: $i16:ident;
        $v:ty, $lanes:expr, $regs:expr,
        zero: $zero:expr, set1: $set1:expr, load: $load:expr,
        dpwssd: $dpwssd:expr, store: $store:expr
        $(, epilogue: $ep:ident)? $(,)?
    ) => {
        mod $m {
            use super::*;

            /// i32 lanes per register.
            const LANES: usize = $lanes;
            /// Registers per slice of a row group.
            const REGS: usize = $regs;
            /// Slices per row group.
            const SLICES: usize = GROUP_ROWS / (LANES * REGS);

            $(
            #[doc = concat!("[`crate::kernels::packed::matmat_packed_i8`], bit-exact, with `", $features, "`.")]
            ///
            /// # Safety
            #[doc = concat!("The CPU must support `", $features, "`.")]
            #[target_feature(enable = $features)]
            pub unsafe fn $i8(
                w: &PackedI8<'_>,
                x: &[i8],
                x_stride: usize,
                points: usize,
                bias: &[i32],
                out: &mut [i32],
                out_stride: usize,
            ) {
                let (points, rows) = call_dims(w, x, x_stride, points, bias, out, out_stride);
                let mut store = Store { out, stride: out_stride };
                tiles::<i8, _, 4>(w, x, x_stride, points, rows, bias, &mut store)
            }

            impl Mac for i8 {
                #[inline]
                #[target_feature(enable = $features)]
                unsafe fn mac(acc: &mut [$v; REGS], w: &[$v; REGS], inputs: i32) {
                    let v = $set1(inputs);
                    for (a, &w) in acc.iter_mut().zip(w) {
                        *a = $dpbusd(*a, w, v);
                    }
                }
            }

            $(
            #[doc = concat!("[`crate::kernels::packed::matmat_packed_pool_i8`], bit-exact, with `", $features, "`: ")]
            /// each register tile's sums requantized and pooled while they are in registers,
            /// never written to memory as int32 rows, nor as int8 ones.
            ///
            /// # Safety
            #[doc = concat!("The CPU must support `", $features, "`.")]
            #[allow(clippy::too_many_arguments)]
            #[target_feature(enable = $features)]
            pub unsafe fn $pool(
                w: &PackedI8<'_>,
                x: &[i8],
                x_stride: usize,
                points: usize,
                bias: &[i32],
                requant: Requant<'_>,
                max: &mut [i8],
                sum: &mut [i32],
            ) {
                let pooled = requant.scales.len().min(max.len()).min(sum.len());
                let (points, rows) = pool_dims(w, x.len(), x_stride, points, bias.len(), pooled);
                let mut pool = Pool::new(requant, max, sum);
                tiles::<i8, _, 4>(w, x, x_stride, points, rows, bias, &mut pool)
            }

            )?
            )?

            #[doc = concat!("[`crate::kernels::packed::matmat_packed_i16`], bit-exact, with `", $features, "`.")]
            ///
            /// # Safety
            #[doc = concat!("The CPU must support `", $features, "`.")]
            #[target_feature(enable = $features)]
            pub unsafe fn $i16(
                w: &PackedI16<'_>,
                x: &[i16],
                x_stride: usize,
                points: usize,
                bias: &[i32],
                out: &mut [i32],
                out_stride: usize,
            ) {
                let (points, rows) = call_dims(w, x, x_stride, points, bias, out, out_stride);
                let mut store = Store { out, stride: out_stride };
                tiles::<i16, _, 2>(w, x, x_stride, points, rows, bias, &mut store)
            }

            /// Every kernel: tiles of the first `points` points, each through every row
            /// group's first `rows` outputs (checked by the caller against `x`, `bias` and
            /// what `epilogue` takes), the sums handed to `epilogue`. `S` is `T::STEP`.
            #[allow(clippy::too_many_arguments)]
            #[inline]
            #[target_feature(enable = $features)]
            fn tiles<T: Mac, E: Epilogue, const S: usize>(
                w: &Packed<'_, T>,
                x: &[T],
                x_stride: usize,
                points: usize,
                rows: usize,
                bias: &[i32],
                epilogue: &mut E,
            ) {
                const { assert!(S == T::STEP) };
                let k = w.k();
                let mut first = 0;
                while first < points {
                    let sm = (points - first).min(SUPER * TILE_POINTS);
                    let mut corr = [0i32; SUPER * TILE_POINTS];
                    // SAFETY: every width's features include AVX2.
                    unsafe { T::corrections(x, x_stride, first, k, &mut corr[..sm]) };
                    for g in 0..rows.div_ceil(GROUP_ROWS) {
                        let row0 = g * GROUP_ROWS;
                        let tile = Tile {
                            blocks: w.group(g),
                            k,
                            row0,
                            rows: (rows - row0).min(GROUP_ROWS),
                            bias: &bias[row0..rows],
                        };
                        let mut t0 = 0;
                        while t0 < sm {
                            let m = (sm - t0).min(TILE_POINTS);
                            for slice in 0..SLICES {
                                if slice * REGS * LANES >= tile.rows {
                                    break;
                                }
                                let io = (x, x_stride, first + t0, &corr[t0..t0 + m], &mut *epilogue);
                                match m {
                                    1 => run::<1, S, T, E>(&tile, slice, io),
                                    2 => run::<2, S, T, E>(&tile, slice, io),
                                    3 => run::<3, S, T, E>(&tile, slice, io),
                                    4 => run::<4, S, T, E>(&tile, slice, io),
                                    5 => run::<5, S, T, E>(&tile, slice, io),
                                    _ => run::<6, S, T, E>(&tile, slice, io),
                                }
                            }
                            t0 += m;
                        }
                    }
                    first += sm;
                }
            }

            /// `NP` points (rows `p..p + NP` of `x`) through slice `slice` of the group, `S`
            /// inputs per step; `corr` holds what to subtract from each point's sums.
            #[inline]
            #[target_feature(enable = $features)]
            fn run<const NP: usize, const S: usize, T: Mac, E: Epilogue>(
                tile: &Tile<'_>,
                slice: usize,
                (x, x_stride, p, corr, epilogue): TileIo<'_, '_, T, E>,
            ) {
                let full = tile.k / S;
                // Plain loops, not `array::from_fn` (an out-of-line call that hides the
                // lengths): with every `steps[i]` sliced to `full`, the compiler keeps one
                // bounds check per step of the loop below instead of one per point.
                let mut rows: [&[T]; NP] = [&[]; NP];
                let mut steps: [&[[T; S]]; NP] = [&[]; NP];
                for (i, (row, st)) in rows.iter_mut().zip(&mut steps).enumerate() {
                    *row = &x[(p + i) * x_stride..][..tile.k];
                    *st = &row.as_chunks().0[..full];
                }
                let reg0 = slice * REGS;
                let (blocks, tail) = tile.blocks.split_at(full);
                let mut acc = [[$zero(); REGS]; NP];
                for (s, block) in blocks.iter().enumerate() {
                    let wv: [$v; REGS] = core::array::from_fn(|r| $load(block, reg0 + r));
                    for (a, xs) in acc.iter_mut().zip(&steps) {
                        // SAFETY: `run` is compiled with the features `T::mac` needs.
                        unsafe { T::mac(a, &wv, T::lane_bits(&xs[s])) };
                    }
                }
                if let Some(block) = tail.first() {
                    // K is not a multiple of the step: the missing inputs count as zero.
                    let wv: [$v; REGS] = core::array::from_fn(|r| $load(block, reg0 + r));
                    for (a, row) in acc.iter_mut().zip(&rows) {
                        // SAFETY: as above.
                        unsafe { T::mac(a, &wv, T::lane_bits(&row[full * S..])) };
                    }
                }
                // A copy for `finish` to read: `acc` itself then never lives in memory, so
                // that its zeros are register clears, not a `memset` of the whole tile.
                let sums = acc;
                // SAFETY: `run` is compiled with the features `finish` needs.
                unsafe { epilogue.finish(tile, reg0, p, &sums, corr) };
            }

            /// Where a register tile's sums go.
            pub(super) trait Epilogue {
                /// The sums `acc` of the `NP` points from `p` for the registers `reg0..` of
                /// `tile`'s slice (lane `i` of register `reg0 + r`: output
                /// `tile.row0 + LANES·(reg0 + r) + i`, those below `tile.rows`), before the
                /// bias and the corrections `corr` (one per point).
                ///
                /// # Safety
                #[doc = concat!("The CPU must support `", $features, "`.")]
                unsafe fn finish<const NP: usize>(
                    &mut self,
                    tile: &Tile<'_>,
                    reg0: usize,
                    p: usize,
                    acc: &[[$v; REGS]; NP],
                    corr: &[i32],
                );
            }

            /// The int32 outputs to `out`, point rows `stride` apart.
            pub(super) struct Store<'a> {
                pub(super) out: &'a mut [i32],
                pub(super) stride: usize,
            }

            impl Epilogue for Store<'_> {
                #[inline]
                #[target_feature(enable = $features)]
                unsafe fn finish<const NP: usize>(
                    &mut self,
                    tile: &Tile<'_>,
                    reg0: usize,
                    p: usize,
                    acc: &[[$v; REGS]; NP],
                    corr: &[i32],
                ) {
                    for (i, (a, &c)) in acc.iter().zip(corr).enumerate() {
                        let y = &mut self.out[(p + i) * self.stride + tile.row0..][..tile.rows];
                        for (r, &a) in a.iter().enumerate() {
                            let lo = (reg0 + r) * LANES;
                            if lo >= tile.rows {
                                break;
                            }
                            $store(&mut y[lo..], a, &tile.bias[lo..tile.rows], c);
                        }
                    }
                }
            }

            $(
            /// The outputs requantized to wide values ([`requantize_wide`], here on whole
            /// registers), reduced over the tile's points into a max and a sum per output in
            /// registers, then merged into the running `max` and `sum`. Max and sum of the wide
            /// values (all in `-128..=127`) are those of the int8 values.
            pub(super) struct Pool<'a> {
                scales: &'a [f32],
                alpha: f32,
                max: &'a mut [i8],
                sum: &'a mut [i32],
            }

            impl<'a> Pool<'a> {
                /// Pools into the running `max` and `sum` of `requant`'s outputs.
                pub(super) fn new(requant: Requant<'a>, max: &'a mut [i8], sum: &'a mut [i32]) -> Self {
                    Self { scales: requant.scales, alpha: requant.leaky.unwrap_or(1.0), max, sum }
                }
            }

            impl Epilogue for Pool<'_> {
                // Out of line: inlined, its constants were hoisted out of the tile loops and
                // held in registers through the multiply loop, which then kept five of its 24
                // accumulators in memory (a load and a store per `vpdpbusd`). The call stores
                // the accumulators once per slice instead.
                #[inline(never)]
                #[target_feature(enable = $features)]
                unsafe fn finish<const NP: usize>(
                    &mut self,
                    tile: &Tile<'_>,
                    reg0: usize,
                    _p: usize,
                    acc: &[[$v; REGS]; NP],
                    corr: &[i32],
                ) {
                    // Each point's correction broadcast once for the slice's registers.
                    let cs: [$v; NP] =
                        core::array::from_fn(|i| $set1(corr.get(i).copied().unwrap_or(0)));
                    let np = corr.len().min(NP);
                    let (lo0, alpha) = (reg0 * LANES, self.alpha);
                    let o0 = tile.row0 + lo0;
                    // A whole slice of `SLICE` outputs (64 at 512 bits, 16 at 256; every slice
                    // of a layer whose outputs are a multiple of 64): chunks of known length,
                    // so no masks and no checks.
                    if let (true, Some(bias), Some(scales), Some(max), Some(sum)) = (
                        tile.rows >= lo0 + SLICE,
                        tile.bias.get(lo0..).and_then(|b| b.first_chunk::<SLICE>()),
                        self.scales.get(o0..).and_then(|s| s.first_chunk::<SLICE>()),
                        self.max.get_mut(o0..).and_then(|m| m.first_chunk_mut::<SLICE>()),
                        self.sum.get_mut(o0..).and_then(|s| s.first_chunk_mut::<SLICE>()),
                    ) {
                        let (bias, _) = bias.as_chunks::<LANES>();
                        let (scales, _) = scales.as_chunks::<LANES>();
                        let (max, _) = max.as_chunks_mut::<LANES>();
                        let (sum, _) = sum.as_chunks_mut::<LANES>();
                        let chunks = bias.iter().zip(scales).zip(max).zip(sum);
                        for (r, (((b, s), m), t)) in chunks.enumerate() {
                            let outs = (&b[..], &s[..], &mut m[..], &mut t[..]);
                            pool_register(acc, &cs, np, r, outs, alpha, LANES);
                        }
                        return;
                    }
                    for r in 0..REGS {
                        let lo = (reg0 + r) * LANES;
                        if lo >= tile.rows {
                            break;
                        }
                        let (o, n) = (tile.row0 + lo, tile.rows - lo);
                        let outs = (
                            &tile.bias[lo..tile.rows],
                            self.scales.get(o..o + n).unwrap_or_default(),
                            self.max.get_mut(o..).unwrap_or_default(),
                            self.sum.get_mut(o..).unwrap_or_default(),
                        );
                        pool_register(acc, &cs, np, r, outs, alpha, n);
                    }
                }
            }

            /// Outputs per slice of a row group.
            const SLICE: usize = REGS * LANES;

            /// `(bias, scales, max, sum)` of a register's outputs.
            type Outs<'a> = (&'a [i32], &'a [f32], &'a mut [i8], &'a mut [i32]);

            /// Register `r` of the first `np` points' sums (`cs`: their corrections,
            /// broadcast) requantized and pooled into its `n` outputs. Lanes past `n` (bias and
            /// scale 0) requantize to 0 and are not merged.
            #[inline]
            #[target_feature(enable = $features)]
            fn pool_register<const NP: usize>(
                acc: &[[$v; REGS]; NP],
                cs: &[$v; NP],
                np: usize,
                r: usize,
                (bias, scales, max, sum): Outs<'_>,
                alpha: f32,
                n: usize,
            ) {
                let bias = $ep::load_i32(bias);
                let scale = $ep::cast_f32($ep::load_i32(bytemuck::cast_slice(scales)));
                // The max is taken before rounding, once per register: rounding is monotone,
                // so the rounded max is the max of the rounded values.
                let (mut mx, mut sm) = ($ep::set1_f32(-128.0), $zero());
                for (a, &c) in acc.iter().zip(cs).take(np) {
                    let v = $ep::sub($ep::add(a[r], bias), c);
                    let f = $ep::scaled(v, scale, alpha);
                    mx = $ep::max_f32(mx, f);
                    sm = $ep::add(sm, $ep::round(f));
                }
                $ep::merge(max, sum, $ep::round(mx), sm, n);
            }
            )?

            /// One point's step of inputs (the lane's four bytes), broadcast, times one
            /// slice of a block: `vpdpbusd` (int8) or `vpdpwssd` (int16) into each of the
            /// point's accumulators. A trait, so that a width without `vpdpbusd` (AVX2,
            /// AVX-512BW: their int8 kernels come from [`widened_i8!`]) stamps only the int16
            /// one.
            trait Mac: Vnni {
                /// # Safety
                #[doc = concat!("The CPU must support `", $features, "`.")]
                unsafe fn mac(acc: &mut [$v; REGS], w: &[$v; REGS], inputs: i32);
            }

            impl Mac for i16 {
                #[inline]
                #[target_feature(enable = $features)]
                unsafe fn mac(acc: &mut [$v; REGS], w: &[$v; REGS], inputs: i32) {
                    let v = $set1(inputs);
                    for (a, &w) in acc.iter_mut().zip(w) {
                        *a = $dpwssd(*a, w, v);
                    }
                }
            }
        }

        pub use $m::{$i16 $(, $i8 $(, $pool)?)?};
    };
}

packed_loop! {
    zmm, "avx2,avx512f,avx512bw,avx512vl,avx512vnni",
    i8: matmat_packed_i8_avx512vnni, dpbusd: _mm512_dpbusd_epi32,
    pool: matmat_packed_pool_i8_avx512vnni,
    i16: matmat_packed_i16_avx512vnni;
    __m512i, 16, 4,
    zero: _mm512_setzero_si512,
    set1: _mm512_set1_epi32,
    load: load512,
    dpwssd: _mm512_dpwssd_epi32,
    store: store512,
    epilogue: ep512,
}

packed_loop! {
    ymm, "avx2,avxvnni",
    i8: matmat_packed_i8_avxvnni, dpbusd: _mm256_dpbusd_avx_epi32,
    pool: matmat_packed_pool_i8_avxvnni,
    i16: matmat_packed_i16_avxvnni;
    __m256i, 8, 2,
    zero: _mm256_setzero_si256,
    set1: _mm256_set1_epi32,
    load: load256,
    dpwssd: _mm256_dpwssd_avx_epi32,
    store: store256,
    epilogue: ep256,
}

packed_loop! {
    avx2, "avx2",
    i16: matmat_packed_i16_avx2;
    __m256i, 8, 2,
    zero: _mm256_setzero_si256,
    set1: _mm256_set1_epi32,
    load: load256,
    dpwssd: avx2_mac_i16,
    store: store256,
    epilogue: ep256,
}

/// `y[..n] += a`'s low `n = min(y.len(), n, 8)` lanes, wrapping; nothing else of `y` is touched.
#[inline]
#[target_feature(enable = "avx2")]
fn add256(y: &mut [i32], a: __m256i, n: usize) {
    let mut lanes = [0i32; 8];
    // SAFETY: `lanes` is 8 i32; `storeu` has no alignment requirement.
    unsafe { _mm256_storeu_si256(lanes.as_mut_ptr().cast(), a) };
    for (y, &l) in y.iter_mut().zip(&lanes).take(n) {
        *y = y.wrapping_add(l);
    }
}

/// The int8 packed kernel on AVX2 and AVX-512BW, which have no `vpdpbusd`: two `vpmaddwd` per
/// step instead, on the packed bytes split into their even and odd bytes.
///
/// A lane's four weight bytes `(b0, b1, b2, b3)` (the unsigned `w + 128`) become the i16 pairs
/// `(b0, b2)` (a shift pair, which compiles to a mask) and `(b1, b3)` (a shift), once per step
/// of a slice, shared by the tile's points. Each point's inputs are sign-extended once per call
/// into the matching pairs, `(x0, x2)` and `(x1, x3)` of every step, in a small buffer of a
/// pass's four tiles, step-major per tile (128 steps at a time); the loop broadcasts them from
/// there. One step of
/// one point is then two broadcasts, two `vpmaddwd` and two adds for 32 MACs, where widening
/// the broadcast inputs in the loop would add three shifts, enough to make the shifts the limit.
/// Each i16 product is at most 255 · 128 in magnitude, so every pair sum and the sum of two
/// are exact in i32, as in `vpdpbusd`; the sums wrap modulo 2^32 like it.
///
/// The macro stamps this kernel for one width:
/// module `$m` with kernel `$i8` (and the pooled `$pool`, over the epilogues of the
/// [`packed_loop!`] module `$base` of the same width), compiled with `$features`, on registers `$v` of `$lanes` i32
/// lanes, `$regs` registers per slice, `$points` points per tile (at most 5), and the width's
/// intrinsics (`$slli8`/`$srli8`, shifts of each i16 by 8, `$madd` for `vpmaddwd`, `$add`;
/// `$store` as in [`packed_loop!`], `$accumulate` adding the low lanes to `y`).
macro_rules! widened_i8 {
    (
        $m:ident, $features:literal, $i8:ident $(, pool: $pool:ident)?; base: $base:ident;
        $v:ty, $lanes:expr, $regs:expr, $points:expr,
        zero: $zero:expr, set1: $set1:expr, load: $load:expr,
        slli8: $slli8:expr, srli8: $srli8:expr, madd: $madd:expr, add: $add:expr,
        store: $store:expr, accumulate: $accumulate:expr $(,)?
    ) => {
        mod $m {
            use super::*;
            use super::$base::{Epilogue, Store};

            /// Steps of a pass's points widened at a time.
            const CHUNK_STEPS: usize = WIDENED_CHUNK_STEPS;

            /// The buffer for layers of up to 128 inputs (every point layer of the MCU model,
            /// the paper's first ones): 256 bytes per point. A call zeroes its whole buffer,
            /// which the large one made a few per cent of a narrow layer.
            const SMALL_CHUNK_STEPS: usize = 32;

            /// Points per register tile.
            const POINTS: usize = $points;

            /// Tiles per pass: each slice of a row group's weights (8 KiB of conv5's on AVX2)
            /// is read from memory once per pass and from L1 by the pass's other tiles.
            const PASS: usize = 4;

            /// i32 lanes per register.
            const LANES: usize = $lanes;

            /// Registers per slice of a row group.
            const REGS: usize = $regs;

            /// Slices per row group.
            const SLICES: usize = GROUP_ROWS / (LANES * REGS);

            /// A pass's points' inputs, widened, tile by tile and step by step: `steps[t][s][i]`
            /// holds point `i` of tile `t`'s two i16 pairs of step `s`, `(x0, x2)` then
            /// `(x1, x3)` (each as the lane value, `x0` low). Step-major within a tile, so the
            /// loop walks the steps beside the weight blocks with no index checks. `C` steps.
            type Widened<const C: usize> = [[[[i32; 2]; POINTS]; C]; PASS];

            #[doc = concat!("[`crate::kernels::packed::matmat_packed_i8`], bit-exact, with `", $features, "`.")]
            ///
            /// # Safety
            #[doc = concat!("The CPU must support `", $features, "`.")]
            #[target_feature(enable = $features)]
            pub unsafe fn $i8(
                w: &PackedI8<'_>,
                x: &[i8],
                x_stride: usize,
                points: usize,
                bias: &[i32],
                out: &mut [i32],
                out_stride: usize,
            ) {
                let (points, rows) = call_dims(w, x, x_stride, points, bias, out, out_stride);
                let mut rows_out = Rows { out, stride: out_stride, add: false };
                let call = (x, x_stride, points, rows, bias);
                passes(w, call, &mut rows_out, |r, later| r.add = later);
            }

            $(
            #[doc = concat!("[`crate::kernels::packed::matmat_packed_pool_i8`], bit-exact, with `", $features, "`: ")]
            /// each register tile's sums requantized and pooled while they are in registers.
            /// Layers of more than 512 inputs (whose sums would be written between chunks)
            /// run the reference instead: [`widened_pool_takes`] says which layers this kernel
            /// is for.
            ///
            /// # Safety
            #[doc = concat!("The CPU must support `", $features, "`.")]
            #[allow(clippy::too_many_arguments)]
            #[target_feature(enable = $features)]
            pub unsafe fn $pool(
                w: &PackedI8<'_>,
                x: &[i8],
                x_stride: usize,
                points: usize,
                bias: &[i32],
                requant: Requant<'_>,
                max: &mut [i8],
                sum: &mut [i32],
            ) {
                if !widened_pool_takes(w) {
                    return crate::kernels::packed::matmat_packed_pool_i8(
                        w, x, x_stride, points, bias, requant, max, sum,
                    );
                }
                let pooled = requant.scales.len().min(max.len()).min(sum.len());
                let (points, rows) = pool_dims(w, x.len(), x_stride, points, bias.len(), pooled);
                let mut pool = super::$base::Pool::new(requant, max, sum);
                let call = (x, x_stride, points, rows, bias);
                // One chunk: `widened_pool_takes` bounds the steps.
                passes(w, call, &mut pool, |_, _| {});
            }
            )?

            /// `(x, x_stride, points, rows, bias)` of a checked call.
            type Call<'a> = (&'a [i8], usize, usize, usize, &'a [i32]);

            /// [`chunked`] over the small buffer where the layer fits it, else the large one.
            #[inline]
            #[target_feature(enable = $features)]
            fn passes<E: Epilogue>(
                w: &PackedI8<'_>,
                call: Call<'_>,
                epilogue: &mut E,
                later: fn(&mut E, bool),
            ) {
                if w.steps() <= SMALL_CHUNK_STEPS {
                    chunked::<SMALL_CHUNK_STEPS, E>(w, call, epilogue, later);
                } else {
                    chunked::<CHUNK_STEPS, E>(w, call, epilogue, later);
                }
            }

            /// Every kernel: the points in passes of up to `PASS` tiles, each pass's inputs
            /// widened `C` steps at a time into a buffer, then run slice by slice through
            /// every row group; `later(epilogue, true)` before every chunk but the first
            /// (whose sums are added to the first's instead of stored).
            #[inline]
            #[target_feature(enable = $features)]
            fn chunked<const C: usize, E: Epilogue>(
                w: &PackedI8<'_>,
                (x, x_stride, points, rows, bias): Call<'_>,
                epilogue: &mut E,
                later: fn(&mut E, bool),
            ) {
                let (k, steps) = (w.k(), w.steps());
                let mut buf: Widened<C> = [[[[0; 2]; POINTS]; C]; PASS];
                let mut first = 0;
                while first < points {
                    // A pass: up to `PASS` tiles of points.
                    let m = (points - first).min(POINTS * PASS);
                    let mut corr = [0i32; POINTS * PASS];
                    vnni_corrections(x, x_stride, first, k, &mut corr[..m]);
                    let mut s0 = 0;
                    while s0 < steps {
                        let n = (steps - s0).min(C);
                        for i in 0..m {
                            let row = &x[(first + i) * x_stride..][..k];
                            let chunk = row.get(s0 * 4..).unwrap_or(&[]);
                            widen(chunk, &mut buf[i / POINTS][..n], i % POINTS);
                        }
                        later(epilogue, s0 > 0);
                        for g in 0..rows.div_ceil(GROUP_ROWS) {
                            let row0 = g * GROUP_ROWS;
                            let tile = Tile {
                                blocks: w.group(g).get(s0..s0 + n).unwrap_or(&[]),
                                k,
                                row0,
                                rows: (rows - row0).min(GROUP_ROWS),
                                bias: &bias[row0..rows],
                            };
                            for slice in 0..SLICES {
                                if slice * REGS * LANES >= tile.rows {
                                    break;
                                }
                                for (t, xs) in buf.iter().enumerate() {
                                    let t0 = t * POINTS;
                                    if t0 >= m {
                                        break;
                                    }
                                    let np = (m - t0).min(POINTS);
                                    let io = (first + t0, &corr[t0..t0 + np], &mut *epilogue);
                                    let xs = &xs[..n];
                                    match np {
                                        1 => run::<1, E>(&tile, slice, xs, io),
                                        2 => run::<2, E>(&tile, slice, xs, io),
                                        3 => run::<3, E>(&tile, slice, xs, io),
                                        4 => run::<4, E>(&tile, slice, xs, io),
                                        // `np ≤ POINTS ≤ 5`.
                                        _ => run::<5, E>(&tile, slice, xs, io),
                                    }
                                }
                            }
                        }
                        s0 += n;
                    }
                    first += m;
                }
            }

            /// Sign-extends `x`'s steps into point `i`'s pairs of `steps` (as many steps as it
            /// holds; inputs past the end of `x` count as zero): 32 bytes, eight steps, per
            /// iteration.
            #[inline]
            #[target_feature(enable = $features)]
            fn widen(x: &[i8], steps: &mut [[[i32; 2]; POINTS]], i: usize) {
                for (s8, steps) in steps.chunks_mut(8).enumerate() {
                    let mut bytes = [0i8; 32];
                    let src = x.get(s8 * 32..).unwrap_or(&[]);
                    let n = src.len().min(32);
                    bytes[..n].copy_from_slice(&src[..n]);
                    let v = ld256_i8(&bytes);
                    let (mut even, mut odd) = ([0i32; 8], [0i32; 8]);
                    // SAFETY: `even` and `odd` are 32 writable bytes each; `storeu` has no
                    // alignment requirement.
                    unsafe {
                        let ev = _mm256_srai_epi16::<8>(_mm256_slli_epi16::<8>(v));
                        _mm256_storeu_si256(even.as_mut_ptr().cast(), ev);
                        _mm256_storeu_si256(odd.as_mut_ptr().cast(), _mm256_srai_epi16::<8>(v));
                    }
                    for ((step, &e), &o) in steps.iter_mut().zip(&even).zip(&odd) {
                        if let Some(pair) = step.get_mut(i) {
                            *pair = [e, o];
                        }
                    }
                }
            }

            /// `(first point, corrections, epilogue)` of a tile.
            type Io<'a, 'b, E> = (usize, &'a [i32], &'b mut E);

            /// `NP` points from `p` through slice `slice` of the group over this chunk's widened
            /// steps, the sums handed to `epilogue`.
            #[inline]
            #[target_feature(enable = $features)]
            fn run<const NP: usize, E: Epilogue>(
                tile: &Tile<'_>,
                slice: usize,
                steps: &[[[i32; 2]; POINTS]],
                (p, corr, epilogue): Io<'_, '_, E>,
            ) {
                let mut acc = [[$zero(); REGS]; NP];
                let reg0 = slice * REGS;
                for (block, xs) in tile.blocks.iter().zip(steps) {
                    let w: [[$v; 2]; REGS] = core::array::from_fn(|r| {
                        let wv = $load(block, reg0 + r);
                        [$srli8($slli8(wv)), $srli8(wv)]
                    });
                    for (a, &[e, o]) in acc.iter_mut().zip(xs) {
                        let (e, o) = ($set1(e), $set1(o));
                        for (a, [w_even, w_odd]) in a.iter_mut().zip(w) {
                            let lo = $madd(w_even, e);
                            let hi = $madd(w_odd, o);
                            *a = $add(*a, $add(lo, hi));
                        }
                    }
                }
                // A copy for the call: handed `&acc` itself, the compiler kept `acc` in memory
                // through the loop above, a store per accumulator and step, where the pooled
                // epilogue runs out of line.
                let sums = acc;
                // SAFETY: `run` is compiled with the features `finish` needs.
                unsafe { epilogue.finish(tile, reg0, p, &sums, corr) };
            }

            /// The int32 outputs of a chunk of steps: the first chunk's stored as the base
            /// width's [`Store`] stores them (`sums + bias − corr`), later chunks' added.
            struct Rows<'a> {
                out: &'a mut [i32],
                stride: usize,
                /// Whether the sums are added to what an earlier chunk stored.
                add: bool,
            }

            impl Epilogue for Rows<'_> {
                #[inline]
                #[target_feature(enable = $features)]
                unsafe fn finish<const NP: usize>(
                    &mut self,
                    tile: &Tile<'_>,
                    reg0: usize,
                    p: usize,
                    acc: &[[$v; REGS]; NP],
                    corr: &[i32],
                ) {
                    if !self.add {
                        let mut store = Store { out: &mut *self.out, stride: self.stride };
                        // SAFETY: compiled with the same features as `Store`'s width.
                        return unsafe { store.finish(tile, reg0, p, acc, corr) };
                    }
                    for (i, a) in acc.iter().enumerate().take(corr.len()) {
                        let y = &mut self.out[(p + i) * self.stride + tile.row0..][..tile.rows];
                        for (r, &a) in a.iter().enumerate() {
                            let lo = (reg0 + r) * LANES;
                            if lo >= tile.rows {
                                break;
                            }
                            $accumulate(&mut y[lo..], a, tile.rows - lo);
                        }
                    }
                }
            }
        }

        pub use $m::{$i8 $(, $pool)?};
    };
}

widened_i8! {
    avx2_i8, "avx2", matmat_packed_i8_avx2, pool: matmat_packed_pool_i8_avx2; base: avx2;
    __m256i, 8, 2, 4,
    zero: _mm256_setzero_si256, set1: _mm256_set1_epi32,
    load: load256, slli8: _mm256_slli_epi16::<8>, srli8: _mm256_srli_epi16::<8>,
    madd: _mm256_madd_epi16, add: _mm256_add_epi32,
    store: store256, accumulate: add256,
}

widened_i8! {
    avx512bw_i8, "avx2,avx512f,avx512bw,avx512vl", matmat_packed_i8_avx512bw,
    pool: matmat_packed_pool_i8_avx512bw; base: zmm_bw;
    __m512i, 16, 4, 5,
    zero: _mm512_setzero_si512, set1: _mm512_set1_epi32,
    load: load512, slli8: _mm512_slli_epi16::<8>, srli8: _mm512_srli_epi16::<8>,
    madd: _mm512_madd_epi16, add: _mm512_add_epi32,
    store: store512, accumulate: add512,
}

/// [`add256`] for 16 lanes, masked: only the low `min(y.len(), n, 16)` lanes are touched.
#[inline]
#[target_feature(enable = "avx512f")]
fn add512(y: &mut [i32], a: __m512i, n: usize) {
    let mask = super::low_mask(y.len().min(n)) as u16;
    // SAFETY: the mask selects lanes `0..min(y.len(), n, 16)`, inside `y`; the others are
    // neither read nor written.
    unsafe {
        let v = _mm512_add_epi32(a, _mm512_maskz_loadu_epi32(mask, y.as_ptr()));
        _mm512_mask_storeu_epi32(y.as_mut_ptr(), mask, v)
    }
}

packed_loop! {
    zmm_bw, "avx2,avx512f,avx512bw,avx512vl",
    i16: matmat_packed_i16_avx512bw;
    __m512i, 16, 4,
    zero: _mm512_setzero_si512,
    set1: _mm512_set1_epi32,
    load: load512,
    dpwssd: avx512bw_mac_i16,
    store: store512,
    epilogue: ep512,
}

/// Register `reg` (bytes `64·reg..`) of a block; `reg < 4`.
#[inline]
#[target_feature(enable = "avx512f")]
fn load512(block: &Block, reg: usize) -> __m512i {
    let (regs, _) = block.as_chunks::<64>();
    // SAFETY: the chunk is 64 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm512_loadu_si512(regs[reg].as_ptr().cast()) }
}

/// Register `reg` (bytes `32·reg..`) of a block; `reg < 8`.
#[inline]
#[target_feature(enable = "avx2")]
fn load256(block: &Block, reg: usize) -> __m256i {
    let (regs, _) = block.as_chunks::<32>();
    // SAFETY: the chunk is 32 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm256_loadu_si256(regs[reg].as_ptr().cast()) }
}

/// `y[..n] = a + bias[..n] − c` for the low `n = min(y.len(), bias.len(), 16)` lanes; nothing
/// else of `y` or `bias` is touched.
#[inline]
#[target_feature(enable = "avx512f")]
fn store512(y: &mut [i32], a: __m512i, bias: &[i32], c: i32) {
    let mask = super::low_mask(y.len().min(bias.len())) as u16;
    // SAFETY: the mask selects lanes `0..min(len, 16)`, inside both `bias` and `y`; the others
    // are neither read nor written.
    unsafe {
        let b = _mm512_maskz_loadu_epi32(mask, bias.as_ptr());
        let v = _mm512_sub_epi32(_mm512_add_epi32(a, b), _mm512_set1_epi32(c));
        _mm512_mask_storeu_epi32(y.as_mut_ptr(), mask, v)
    }
}

/// [`store512`] for 8 lanes: a full store when 8 fit, else lane by lane.
#[inline]
#[target_feature(enable = "avx2")]
fn store256(y: &mut [i32], a: __m256i, bias: &[i32], c: i32) {
    let n = y.len().min(bias.len());
    if let (Some(y), Some(b)) = (y.first_chunk_mut::<8>(), bias.first_chunk::<8>()) {
        // SAFETY: `b` and `y` are 8 i32 each; `loadu`/`storeu` have no alignment requirement.
        unsafe {
            let b = _mm256_loadu_si256(b.as_ptr().cast());
            let v = _mm256_sub_epi32(_mm256_add_epi32(a, b), _mm256_set1_epi32(c));
            _mm256_storeu_si256(y.as_mut_ptr().cast(), v)
        }
        return;
    }
    let mut lanes = [0i32; 8];
    // SAFETY: `lanes` is 8 i32; `storeu` has no alignment requirement.
    unsafe { _mm256_storeu_si256(lanes.as_mut_ptr().cast(), a) };
    for ((y, &l), &b) in y.iter_mut().zip(&lanes).zip(bias).take(n) {
        *y = l.wrapping_add(b).wrapping_sub(c);
    }
}

/// The pooled epilogue's steps on 512-bit registers, under the names [`packed_loop!`] uses.
mod ep512 {
    pub(super) use super::{
        ld512m_i32 as load_i32, merge512 as merge, round512 as round, scaled512 as scaled,
    };
    pub(super) use core::arch::x86_64::{
        _mm512_add_epi32 as add, _mm512_castsi512_ps as cast_f32, _mm512_max_ps as max_f32,
        _mm512_set1_ps as set1_f32, _mm512_sub_epi32 as sub,
    };
}

/// The pooled epilogue's steps on 256-bit registers, under the names [`packed_loop!`] uses.
mod ep256 {
    pub(super) use super::{
        ld256m_i32 as load_i32, merge256 as merge, round256 as round, scaled256 as scaled,
    };
    pub(super) use core::arch::x86_64::{
        _mm256_add_epi32 as add, _mm256_castsi256_ps as cast_f32, _mm256_max_ps as max_f32,
        _mm256_set1_ps as set1_f32, _mm256_sub_epi32 as sub,
    };
}

// The pooled epilogue's steps ([`crate::quant::requantize_wide`] on whole registers, and the
// merge into the running pool), for 16 and 8 lanes.
//
// `requantize_wide` clamps to `[-129, 128]`, rounds half to even and clamps the integer to
// `-128..=127`. Clamping to `[-128, 127]` before rounding gives the same integer for every
// input (rounding is monotone and the bounds are integers; a NaN gives the lower bound either
// way), and in that range the conversion instruction's rounding (to nearest, ties to even:
// embedded in the AVX-512 form, the default `MXCSR` mode Rust assumes in the AVX2 one) is the
// magic-number rounding of `quant::round_to_i32`.

/// [`crate::quant::requantize_wide`] of each lane of `acc` with its lane of `scale`, before
/// rounding: `acc · scale`, times `alpha` where negative, clamped to `[-128, 127]`.
#[inline]
#[target_feature(enable = "avx512f")]
fn scaled512(acc: __m512i, scale: __m512, alpha: f32) -> __m512 {
    let v = _mm512_mul_ps(_mm512_cvtepi32_ps(acc), scale);
    let neg = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(v, _mm512_setzero_ps());
    let v = _mm512_mask_mul_ps(v, neg, v, _mm512_set1_ps(alpha));
    _mm512_min_ps(
        _mm512_max_ps(v, _mm512_set1_ps(-128.0)),
        _mm512_set1_ps(127.0),
    )
}

/// [`scaled512`]'s values rounded half to even.
#[inline]
#[target_feature(enable = "avx512f")]
fn round512(v: __m512) -> __m512i {
    _mm512_cvt_roundps_epi32::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(v)
}

/// [`scaled512`] for 8 lanes.
#[inline]
#[target_feature(enable = "avx2")]
fn scaled256(acc: __m256i, scale: __m256, alpha: f32) -> __m256 {
    let v = _mm256_mul_ps(_mm256_cvtepi32_ps(acc), scale);
    let neg = _mm256_cmp_ps::<_CMP_LT_OQ>(v, _mm256_setzero_ps());
    let v = _mm256_blendv_ps(v, _mm256_mul_ps(v, _mm256_set1_ps(alpha)), neg);
    _mm256_min_ps(
        _mm256_max_ps(v, _mm256_set1_ps(-128.0)),
        _mm256_set1_ps(127.0),
    )
}

/// [`scaled256`]'s values rounded half to even (the default rounding mode).
#[inline]
#[target_feature(enable = "avx2")]
fn round256(v: __m256) -> __m256i {
    _mm256_cvtps_epi32(v)
}

/// Merges the low `min(n, max.len(), sum.len(), 16)` lanes of a max and a sum (lanes in
/// `-128..=127` for the max) into the running `max` and `sum`; nothing else is touched.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
fn merge512(max: &mut [i8], sum: &mut [i32], mx: __m512i, sm: __m512i, n: usize) {
    let mask = super::low_mask(n.min(max.len()).min(sum.len())) as u16;
    // SAFETY: the mask selects lanes inside `max` and `sum`; the others are neither read nor
    // written. The max's lanes fit in i8, so the truncating narrowing is exact.
    unsafe {
        let m = _mm512_cvtepi8_epi32(_mm_maskz_loadu_epi8(mask, max.as_ptr()));
        let m = _mm512_cvtepi32_epi8(_mm512_max_epi32(m, mx));
        _mm_mask_storeu_epi8(max.as_mut_ptr(), mask, m);
        let s = _mm512_add_epi32(_mm512_maskz_loadu_epi32(mask, sum.as_ptr()), sm);
        _mm512_mask_storeu_epi32(sum.as_mut_ptr(), mask, s);
    }
}

/// [`merge512`] for 8 lanes.
#[inline]
#[target_feature(enable = "avx2")]
fn merge256(max: &mut [i8], sum: &mut [i32], mx: __m256i, sm: __m256i, n: usize) {
    if let (true, Some(max), Some(sum)) = (
        n >= 8,
        max.first_chunk_mut::<8>(),
        sum.first_chunk_mut::<8>(),
    ) {
        // SAFETY: `max` is 8 bytes and `sum` 8 i32; unaligned loads and stores. The max's
        // lanes fit in i8, so the saturating packs are exact; `packs` works per 128-bit half,
        // so the halves' 4 bytes are joined with a lane permute.
        unsafe {
            let m = _mm256_cvtepi8_epi32(_mm_loadl_epi64(max.as_ptr().cast()));
            let m = _mm256_max_epi32(m, mx);
            let w = _mm256_packs_epi32(m, m); // i16: [a0..a3 a0..a3 | a4..a7 a4..a7]
            let w = _mm256_permute4x64_epi64::<0b1000>(w); // [a0..a3 a4..a7 | ..]
            let b = _mm_packs_epi16(_mm256_castsi256_si128(w), _mm256_castsi256_si128(w));
            _mm_storel_epi64(max.as_mut_ptr().cast(), b);
            let s = _mm256_add_epi32(_mm256_loadu_si256(sum.as_ptr().cast()), sm);
            _mm256_storeu_si256(sum.as_mut_ptr().cast(), s);
        }
        return;
    }
    let (mut m, mut t) = ([0i32; 8], [0i32; 8]);
    // SAFETY: `m` and `t` are 8 i32 each; `storeu` has no alignment requirement.
    unsafe {
        _mm256_storeu_si256(m.as_mut_ptr().cast(), mx);
        _mm256_storeu_si256(t.as_mut_ptr().cast(), sm);
    }
    for (((max, sum), &m), &t) in max.iter_mut().zip(sum).zip(&m).zip(&t).take(n) {
        // `m` is in -128..=127: the cast is exact.
        *max = (*max).max(m as i8);
        *sum = sum.wrapping_add(t);
    }
}

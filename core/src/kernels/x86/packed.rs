//! The AVX-512 VNNI kernels over pre-packed weights ([`crate::kernels::packed`]): int8
//! (`vpdpbusd`, four inputs per lane) and int16 (`vpdpwssd`, two), one loop for both.
//!
//! A register tile is one row group (64 outputs, four registers of 16 lanes) by up to
//! [`TILE_POINTS`] points: 24 accumulators, 4 weight registers, and each point's four input
//! bytes broadcast from memory. Per step of four inputs that is 4 weight loads and 6 broadcasts
//! for 24 `vpdpbusd` (1,536 MACs), with no horizontal sums: lane `i` of accumulator `q` is
//! output `16q + i` of the group, stored as is.
//!
//! Tiles are the outer loop: one tile's points run through every row group, so a layer's
//! weights stream through once per six points (from L2 for the paper's 512 KiB conv5) while
//! the points' inputs stay in L1, and `128·Σx` (the correction for the weights' `+128` offset)
//! is computed once per point. On this project's Zen 5 VM, conv5 in blocks of 16 points runs
//! at 495 GMAC/s this way (`benches/kernels.rs`, `packed/avx512vnni`), 94 % of the 524 GMAC/s
//! `kernels::peak_loop` measures; the other order, each row group's 32 KiB kept in L1 while
//! every tile passes over it, measured about 340 GMAC/s with four-point tiles (a timing loop,
//! on the same machine while it was busy).

use core::arch::x86_64::*;

use super::vnni_correction;
use crate::kernels::packed::{packed_dims, Block, Lane, Packed, PackedI16, PackedI8, GROUP_ROWS};

/// Points per register tile.
pub const TILE_POINTS: usize = 6;

/// Lanes per register (i32).
const LANES: usize = 16;

/// Registers per row group.
const REGS: usize = GROUP_ROWS / LANES;

/// [`crate::kernels::packed::matmat_packed_i8`], bit-exact, with `vpdpbusd` on 512-bit
/// registers.
///
/// # Safety
/// The CPU must support AVX2, AVX-512F/BW/VL and AVX-512 VNNI.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn matmat_packed_i8_avx512vnni(
    w: &PackedI8<'_>,
    x: &[i8],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    tiles::<i8, 4>(w, x, x_stride, points, bias, out, out_stride)
}

/// [`crate::kernels::packed::matmat_packed_i16`], bit-exact, with `vpdpwssd` on 512-bit
/// registers.
///
/// # Safety
/// The CPU must support AVX2, AVX-512F/BW/VL and AVX-512 VNNI.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn matmat_packed_i16_avx512vnni(
    w: &PackedI16<'_>,
    x: &[i16],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    tiles::<i16, 2>(w, x, x_stride, points, bias, out, out_stride)
}

/// What the loop needs to know of a weight type beyond its [`Lane`] layout.
trait Vnni: Lane {
    /// Whether a step is a pair of i16 (`vpdpwssd`) rather than four u8 × i8 (`vpdpbusd`).
    const WORDS: bool;
    /// What to subtract from each of a point's sums: `128·Σx` for int8 (the weights' offset),
    /// 0 for int16.
    fn correction(x: &[Self]) -> i32;
}

impl Vnni for i8 {
    const WORDS: bool = false;
    fn correction(x: &[i8]) -> i32 {
        vnni_correction(x)
    }
}

impl Vnni for i16 {
    const WORDS: bool = true;
    fn correction(_: &[i16]) -> i32 {
        0
    }
}

/// Both kernels: tiles of points, each through every row group. `S` is `T::STEP`.
#[allow(clippy::too_many_arguments)]
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn tiles<T: Vnni, const S: usize>(
    w: &Packed<'_, T>,
    x: &[T],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    let (points, rows) = packed_dims(
        w,
        x.len(),
        x_stride,
        points,
        bias.len(),
        out.len(),
        out_stride,
    );
    let k = w.k();
    let mut first = 0;
    while first < points {
        let m = (points - first).min(TILE_POINTS);
        let mut corr = [0i32; TILE_POINTS];
        for (c, p) in corr.iter_mut().zip(first..first + m) {
            *c = T::correction(&x[p * x_stride..][..k]);
        }
        for g in 0..rows.div_ceil(GROUP_ROWS) {
            let row0 = g * GROUP_ROWS;
            let tile = Tile {
                blocks: w.group(g),
                k,
                row0,
                rows: (rows - row0).min(GROUP_ROWS),
                bias: &bias[row0..rows],
            };
            let io = (x, x_stride, first, &corr[..m], &mut *out, out_stride);
            match m {
                1 => tile.run::<1, S, T>(io),
                2 => tile.run::<2, S, T>(io),
                3 => tile.run::<3, S, T>(io),
                4 => tile.run::<4, S, T>(io),
                5 => tile.run::<5, S, T>(io),
                _ => tile.run::<6, S, T>(io),
            }
        }
        first += m;
    }
}

/// One row group of one layer: what every tile of points multiplies by.
struct Tile<'a> {
    /// The group's blocks, one per step of four inputs.
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

/// A tile's points: `(x, x_stride, first point, corrections, out, out_stride)`.
type TileIo<'a, 'b, T> = (&'a [T], usize, usize, &'a [i32], &'b mut [i32], usize);

impl Tile<'_> {
    /// `NP` points (rows `p..p + NP` of `x`) through the group, `S` inputs per step; `corr`
    /// holds what to subtract from each point's sums.
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn run<const NP: usize, const S: usize, T: Vnni>(
        &self,
        (x, x_stride, p, corr, out, out_stride): TileIo<'_, '_, T>,
    ) {
        let full = self.k / S;
        // Plain loops, not `array::from_fn` (an out-of-line call that hides the lengths): with
        // every `steps[i]` sliced to `full`, the compiler keeps one bounds check per step of the
        // loop below instead of one per point.
        let mut rows: [&[T]; NP] = [&[]; NP];
        let mut steps: [&[[T; S]]; NP] = [&[]; NP];
        for (i, (row, st)) in rows.iter_mut().zip(&mut steps).enumerate() {
            *row = &x[(p + i) * x_stride..][..self.k];
            *st = &row.as_chunks().0[..full];
        }
        let (blocks, tail) = self.blocks.split_at(full);
        let mut acc = [[_mm512_setzero_si512(); REGS]; NP];
        for (s, block) in blocks.iter().enumerate() {
            let wv = load_block(block);
            for (a, xs) in acc.iter_mut().zip(&steps) {
                mac::<T>(a, &wv, T::lane_bits(&xs[s]));
            }
        }
        if let Some(block) = tail.first() {
            // K is not a multiple of the step: the last step's missing inputs count as zero.
            let wv = load_block(block);
            for (a, row) in acc.iter_mut().zip(&rows) {
                mac::<T>(a, &wv, T::lane_bits(&row[full * S..]));
            }
        }
        for (i, (a, &c)) in acc.iter().zip(corr).enumerate() {
            let y = &mut out[(p + i) * out_stride + self.row0..][..self.rows];
            let c = _mm512_set1_epi32(c);
            for (r, &a) in a.iter().enumerate() {
                let lo = r * LANES;
                if lo >= self.rows {
                    break;
                }
                let b = ld512m_i32(&self.bias[lo..self.rows]);
                st512m_i32(&mut y[lo..], _mm512_sub_epi32(_mm512_add_epi32(a, b), c));
            }
        }
    }
}

/// One point's step of inputs (the lane's four bytes), broadcast, times one block:
/// `vpdpbusd` (int8) or `vpdpwssd` (int16) into each of the point's four accumulators (16
/// outputs × one step each).
#[inline]
#[target_feature(enable = "avx512f,avx512vnni")]
fn mac<T: Vnni>(acc: &mut [__m512i; REGS], w: &[__m512i; REGS], inputs: i32) {
    let v = _mm512_set1_epi32(inputs);
    for (a, &w) in acc.iter_mut().zip(w) {
        *a = if T::WORDS {
            _mm512_dpwssd_epi32(*a, w, v)
        } else {
            _mm512_dpbusd_epi32(*a, w, v)
        };
    }
}

/// The four registers of one block.
#[inline]
#[target_feature(enable = "avx512f")]
fn load_block(block: &Block) -> [__m512i; REGS] {
    let (regs, _) = block.as_chunks::<64>();
    // SAFETY: each chunk is 64 readable bytes; `loadu` has no alignment requirement.
    core::array::from_fn(|q| unsafe { _mm512_loadu_si512(regs[q].as_ptr().cast()) })
}

/// The first `min(t.len(), 16)` values of `t`, zeros above.
#[inline]
#[target_feature(enable = "avx512f")]
fn ld512m_i32(t: &[i32]) -> __m512i {
    // SAFETY: the mask selects lanes `0..min(t.len(), 16)`, all inside `t`; others are not read.
    unsafe { _mm512_maskz_loadu_epi32(super::low_mask(t.len()) as u16, t.as_ptr()) }
}

/// Stores the low `min(t.len(), 16)` lanes of `v` into `t`.
#[inline]
#[target_feature(enable = "avx512f")]
fn st512m_i32(t: &mut [i32], v: __m512i) {
    // SAFETY: the mask selects lanes `0..min(t.len(), 16)`, all inside `t`; others are not
    // written.
    unsafe { _mm512_mask_storeu_epi32(t.as_mut_ptr(), super::low_mask(t.len()) as u16, v) }
}

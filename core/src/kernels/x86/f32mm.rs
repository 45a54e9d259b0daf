//! The f32 engine's point layers on AVX-512 and AVX2: a block of points through a tile of rows,
//! several rows and points per register tile, bit for bit
//! [`crate::kernels::reference::matmat_f32`].
//!
//! The reference sums each row and point in 16 partial sums (input `j` into sum `j mod 16`),
//! adds them by halves (lanes `i` and `i + 8`, then `i + 4`, `i + 2`, `i + 1`), then the tail's
//! dot product and the bias. One 512-bit register (two 256-bit ones) holds the 16 partial sums
//! of one row and point; a multiply and an add per step (never a fused multiply-add, which
//! rounds once where the reference rounds twice) keep every lane's operations those of the
//! reference, and the halving is done on the registers in the same order. On AVX-512 a tile is
//! four rows by four points: per step of 16 inputs it loads four weight vectors and four input
//! vectors for 16 products, where point by point
//! ([`crate::kernels::reference::matvec_f32`], four rows at a time) every weight vector is
//! loaded once per point and every output reduced alone.

use core::arch::x86_64::*;

use crate::kernels::reference::{finish_lanes, tail_dot, PointRows};

/// Partial sums per row and point (one 512-bit register, two 256-bit ones).
const LANES: usize = 16;

/// Some rows of a layer: their weights (`k` per row) and bias.
#[derive(Clone, Copy)]
struct WeightRows<'a> {
    w: &'a [f32],
    bias: &'a [f32],
    k: usize,
}

/// Stamps the block kernel for one register width: `$name` compiled with `$features`, the 16
/// partial sums of a row and point in a `$v`, register tiles of `$rt` rows by `$pt` points
/// (`$zero`, `$load`, `$madd` and `$halves` the width's steps; `$fast` a tile-wide finish
/// that returns whether it wrote the tile).
macro_rules! f32_tiles {
    (
        $m:ident, $name:ident, $features:literal, $v:ty, rows: $rt:expr, points: $pt:expr,
        zero: $zero:expr, load: $load:ident, madd: $madd:ident, halves: $halves:ident,
        fast: $fast:ident $(,)?
    ) => {
        mod $m {
            use super::*;

            /// Rows per register tile.
            const RT: usize = $rt;
            /// Points per register tile.
            const PT: usize = $pt;

            #[doc = concat!(
                "[`crate::kernels::reference::matmat_f32`], bit-exact, with `", $features, "`."
            )]
            ///
            /// # Safety
            #[doc = concat!("The CPU must support `", $features, "`.")]
            #[target_feature(enable = $features)]
            pub unsafe fn $name(w: &[f32], bias: &[f32], rows: &mut [f32], at: &PointRows) {
                let (k, o, points) = at.dims(w.len(), bias.len(), rows.len());
                if o == 0 {
                    return;
                }
                if k == 0 {
                    // `matvec_f32` gives the bias itself (not `0 + 0 + b`, which loses a
                    // -0.0).
                    for row in rows.chunks_mut(at.stride).take(points) {
                        row[at.out..][..o].copy_from_slice(&bias[..o]);
                    }
                    return;
                }
                let mut p0 = 0;
                while p0 < points {
                    let np = (points - p0).min(PT);
                    let mut o0 = 0;
                    while o0 < o {
                        let no = (o - o0).min(RT);
                        let l = WeightRows {
                            w: &w[o0 * k..(o0 + no) * k],
                            bias: &bias[o0..o0 + no],
                            k,
                        };
                        let (at0, n) = ((p0, o0), (no, np));
                        match n {
                            (RT, PT) => tile::<RT, PT>(l, rows, at, at0),
                            (RT, _) => tiles_of::<RT, 1>(l, rows, at, at0, n),
                            (_, PT) => tiles_of::<1, PT>(l, rows, at, at0, n),
                            _ => tiles_of::<1, 1>(l, rows, at, at0, n),
                        }
                        o0 += no;
                    }
                    p0 += np;
                }
            }

            /// Rows `o0..o0 + nr` by points `p0..p0 + np` as tiles of `R` rows by `P` points
            /// (`R` divides `nr`, `P` divides `np`): the edges of the block, where a whole
            /// tile does not fit.
            #[inline]
            #[target_feature(enable = $features)]
            fn tiles_of<const R: usize, const P: usize>(
                l: WeightRows<'_>,
                rows: &mut [f32],
                at: &PointRows,
                (p0, o0): (usize, usize),
                (nr, np): (usize, usize),
            ) {
                debug_assert!(nr.is_multiple_of(R) && np.is_multiple_of(P));
                let k = l.k;
                for r in (0..nr).step_by(R) {
                    let lr = WeightRows {
                        w: &l.w[r * k..(r + R) * k],
                        bias: &l.bias[r..r + R],
                        k,
                    };
                    for p in (p0..p0 + np).step_by(P) {
                        tile::<R, P>(lr, rows, at, (p, o0 + r));
                    }
                }
            }

            /// Rows `o0..o0 + R` (`l`: their weights and bias) for points `p0..p0 + P`, all
            /// of them inside `rows` ([`PointRows::dims`] checked it).
            #[inline]
            #[target_feature(enable = $features)]
            fn tile<const R: usize, const P: usize>(
                WeightRows { w, bias, k }: WeightRows<'_>,
                rows: &mut [f32],
                at: &PointRows,
                (p0, o0): (usize, usize),
            ) {
                let full = k / LANES;
                // Each row and point's tail dot product (0.0 without tails), taken while the
                // inputs are borrowed; the partial sums stay in registers for the finish.
                let mut tails = [[0.0f32; P]; R];
                let acc = {
                    // Every slice cut to `full` steps, so that the loop keeps few bounds
                    // checks.
                    let mut ws: [(&[[f32; LANES]], &[f32]); R] = [(&[], &[]); R];
                    for (r, ws) in ws.iter_mut().enumerate() {
                        let (lanes, tail) = w[r * k..(r + 1) * k].as_chunks::<LANES>();
                        *ws = (&lanes[..full], tail);
                    }
                    let mut xs: [(&[[f32; LANES]], &[f32]); P] = [(&[], &[]); P];
                    for (i, xs) in xs.iter_mut().enumerate() {
                        let x = &rows[(p0 + i) * at.stride + at.x.start..][..k];
                        let (lanes, tail) = x.as_chunks::<LANES>();
                        *xs = (&lanes[..full], tail);
                    }
                    let mut acc: [[$v; P]; R] = [[$zero; P]; R];
                    for s in 0..full {
                        // Each vector loaded once per step into a local, then shared.
                        let mut wv: [$v; R] = [$zero; R];
                        for (v, ws) in wv.iter_mut().zip(&ws) {
                            *v = $load(&ws.0[s]);
                        }
                        let mut xv: [$v; P] = [$zero; P];
                        for (v, xs) in xv.iter_mut().zip(&xs) {
                            *v = $load(&xs.0[s]);
                        }
                        for (acc, &wv) in acc.iter_mut().zip(&wv) {
                            for (a, &xv) in acc.iter_mut().zip(&xv) {
                                *a = $madd(*a, wv, xv);
                            }
                        }
                    }
                    if !k.is_multiple_of(LANES) {
                        for (tails, ws) in tails.iter_mut().zip(&ws) {
                            for (t, xs) in tails.iter_mut().zip(&xs) {
                                *t = tail_dot(ws.1, xs.1);
                            }
                        }
                    }
                    acc
                };
                if k.is_multiple_of(LANES) && $fast(&acc, bias, rows, at, (p0, o0)) {
                    return;
                }
                let mut sums = [[0.0f32; P]; R];
                for (((sums, acc), tails), &b) in sums.iter_mut().zip(&acc).zip(&tails).zip(bias) {
                    for ((s, &a), &t) in sums.iter_mut().zip(acc).zip(tails) {
                        *s = finish_lanes($halves(a), t, b);
                    }
                }
                for (i, p) in (p0..p0 + P).enumerate() {
                    let y = &mut rows[p * at.stride + at.out + o0..][..R];
                    for (y, s) in y.iter_mut().zip(&sums) {
                        *y = s[i];
                    }
                }
            }
        }

        pub use $m::$name;
    };
}

f32_tiles! {
    zmm, matmat_f32_avx512, "avx2,avx512f", __m512, rows: 4, points: 4,
    zero: _mm512_setzero_ps(), load: load512, madd: madd512, halves: halves, fast: fast512,
}

// One row by four points: four accumulators of two registers each (8 of 16), the weight
// vector's two, the inputs' as they are loaded. Measured on the paper model (AVX2 code on the
// Zen 5 VM, a timing loop of the f32 engine): 28.3 ms against 35.9 point by point; two rows by
// two points 31.8, three by two 46 (its 12 accumulator registers and the operands spilled),
// one by five or six 27.6–28.8.
f32_tiles! {
    ymm, matmat_f32_avx2, "avx2", [__m256; 2], rows: 1, points: 4,
    zero: [_mm256_setzero_ps(); 2], load: load256, madd: madd256, halves: halves2x256,
    fast: no_fast,
}

/// The AVX-512 tile's finish when the tile is four rows by four points (the caller calls it
/// only where no row has a tail): a row and point is `(Σ + 0.0) + b` (`finish_lanes` with
/// the empty tail's 0.0), four rows of a point at a time, the 16 sums from one transposing
/// tree ([`halves16`]).
#[inline]
#[target_feature(enable = "avx2,avx512f")]
fn fast512<const R: usize, const P: usize>(
    acc: &[[__m512; P]; R],
    bias: &[f32],
    rows: &mut [f32],
    at: &PointRows,
    (p0, o0): (usize, usize),
) -> bool {
    let (4, 4, Some(b)) = (R, P, bias.first_chunk::<4>()) else {
        return false;
    };
    let mut a = [[_mm512_setzero_ps(); 4]; 4];
    for (a, acc) in a.iter_mut().zip(acc) {
        for (a, &acc) in a.iter_mut().zip(acc) {
            *a = acc;
        }
    }
    let v = halves16(a);
    let b = load4(b);
    let lanes = [
        _mm512_extractf32x4_ps::<0>(v),
        _mm512_extractf32x4_ps::<1>(v),
        _mm512_extractf32x4_ps::<2>(v),
        _mm512_extractf32x4_ps::<3>(v),
    ];
    for (i, l) in lanes.into_iter().enumerate() {
        let mut y = [0.0f32; 4];
        store4(&mut y, _mm_add_ps(_mm_add_ps(l, _mm_setzero_ps()), b));
        // Inside `rows`, as in `tile` ([`PointRows::dims`] checked it).
        let at_y = (p0 + i) * at.stride + at.out + o0;
        rows[at_y..at_y + 4].copy_from_slice(&y);
    }
    true
}

/// 4 floats.
#[inline]
#[target_feature(enable = "avx2")]
fn load4(v: &[f32; 4]) -> __m128 {
    // SAFETY: `v` is 16 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm_loadu_ps(v.as_ptr()) }
}

/// 4 floats into `y`.
#[inline]
#[target_feature(enable = "avx2")]
fn store4(y: &mut [f32; 4], v: __m128) {
    // SAFETY: `y` is 16 writable bytes; `storeu` has no alignment requirement.
    unsafe { _mm_storeu_ps(y.as_mut_ptr(), v) }
}

/// 16 floats.
#[inline]
#[target_feature(enable = "avx512f")]
fn load512(v: &[f32; LANES]) -> __m512 {
    // SAFETY: `v` is 64 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm512_loadu_ps(v.as_ptr()) }
}

/// 16 floats, as two registers.
#[inline]
#[target_feature(enable = "avx2")]
fn load256(v: &[f32; LANES]) -> [__m256; 2] {
    // SAFETY: `v` is 64 readable bytes; `loadu` has no alignment requirement.
    unsafe {
        [
            _mm256_loadu_ps(v.as_ptr()),
            _mm256_loadu_ps(v.as_ptr().add(8)),
        ]
    }
}

/// `a + w · x` per lane, rounded twice (the reference's `acc + w * x`).
#[inline]
#[target_feature(enable = "avx512f")]
fn madd512(a: __m512, w: __m512, x: __m512) -> __m512 {
    _mm512_add_ps(a, _mm512_mul_ps(w, x))
}

/// [`madd512`] on two registers.
#[inline]
#[target_feature(enable = "avx2")]
fn madd256(a: [__m256; 2], w: [__m256; 2], x: [__m256; 2]) -> [__m256; 2] {
    [
        _mm256_add_ps(a[0], _mm256_mul_ps(w[0], x[0])),
        _mm256_add_ps(a[1], _mm256_mul_ps(w[1], x[1])),
    ]
}

/// AVX2 has no tile-wide finish: every output is finished alone.
#[inline]
#[target_feature(enable = "avx2")]
fn no_fast<const R: usize, const P: usize>(
    _: &[[[__m256; 2]; P]; R],
    _: &[f32],
    _: &mut [f32],
    _: &PointRows,
    _: (usize, usize),
) -> bool {
    false
}

/// The 16 lanes added as the reference's `sum_lanes` adds them: lane `i` and `i + 8`, then
/// `i + 4`, `i + 2`, `i + 1`.
#[inline]
#[target_feature(enable = "avx2,avx512f")]
fn halves(a: __m512) -> f32 {
    halves8(_mm256_add_ps(
        _mm512_castps512_ps256(a),
        _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(_mm512_castps_pd(a))),
    ))
}

/// [`halves`] on AVX2's two registers (lanes 0–7 and 8–15).
#[inline]
#[target_feature(enable = "avx2")]
fn halves2x256([lo, hi]: [__m256; 2]) -> f32 {
    halves8(_mm256_add_ps(lo, hi))
}

/// The last three halvings of [`halves`], from the eight sums of lanes `i` and `i + 8`.
#[inline]
#[target_feature(enable = "avx2")]
fn halves8(h8: __m256) -> f32 {
    let h4 = _mm_add_ps(_mm256_castps256_ps128(h8), _mm256_extractf128_ps::<1>(h8));
    let h2 = _mm_add_ps(h4, _mm_movehl_ps(h4, h4));
    let h1 = _mm_add_ss(h2, _mm_movehdup_ps(h2));
    _mm_cvtss_f32(h1)
}

/// [`halves`] of 16 registers at once, `a[r][p]`: 128-bit lane `p` of the result is
/// `[halves(a[0][p]), halves(a[1][p]), halves(a[2][p]), halves(a[3][p])]`, every lane added
/// to the same lane as in [`halves`] (a transposing tree: 45 shuffles and adds for 16 sums,
/// where [`halves`] takes eight instructions for one): the int8 kernels' tree
/// ([`super::tree16_512`]) with f32 adds.
#[inline]
#[target_feature(enable = "avx2,avx512f")]
fn halves16(a: [[__m512; 4]; 4]) -> __m512 {
    let mut bits = [[_mm512_setzero_si512(); 4]; 4];
    for (b, a) in bits.iter_mut().zip(&a) {
        for (b, &a) in b.iter_mut().zip(a) {
            *b = _mm512_castps_si512(a);
        }
    }
    _mm512_castsi512_ps(super::tree16_512::<super::AddF32>(bits))
}

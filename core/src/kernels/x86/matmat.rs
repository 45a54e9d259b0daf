//! Matrix-matrix kernels (a block of points sharing each weight load), per ISA: the loop
//! written once (`matmat_body!`), with the parent's steps and reductions.
#![allow(clippy::incompatible_msrv)]

use super::*;

/// Points per group: the VNNI corrections of a group live in a stack array, and the loops run
/// over a group's points inside each block of four weight rows, so the weights are read from
/// memory once per group (and `x`, `GROUP · K` bytes, stays in L1).
const GROUP: usize = 16;

/// The sums of 16 vectors, `a[r][q]` for four rows `r` and four points `q`: 128-bit lane `q` of
/// the result is `[Σa[0][q], Σa[1][q], Σa[2][q], Σa[3][q]]`.
///
/// A tree of 45 shuffles and adds ([`tree16_512`]), none of them multi-µop; four [`hsum4_512`]
/// take 52 instructions, 12 of them `vphaddd`. (Measured a few per cent faster at `P = 16`;
/// replacing one shuffle per pair by a blend measured no faster.)
#[inline]
#[target_feature(enable = "avx512f")]
fn hsum16_512(a: [[__m512i; 4]; 4]) -> __m512i {
    tree16_512::<AddI32>(a)
}

/// Four rows by `Q` points of 512-bit accumulators to `Q` vectors of four row sums.
#[inline]
#[target_feature(enable = "avx2,avx512f")]
fn reduce4_512<const Q: usize>(a: [[__m512i; Q]; 4]) -> [__m128i; Q] {
    // (Loops, not `array::from_fn`/`map`: their closures would not be inlined across the
    // target-feature boundary, and the vectors would go through memory.)
    let mut s = [_mm_setzero_si128(); Q];
    if Q == 4 {
        let mut b = [[_mm512_setzero_si512(); 4]; 4];
        for r in 0..4 {
            for q in 0..4 {
                b[r][q] = a[r][q];
            }
        }
        let v = hsum16_512(b);
        for (q, s) in s.iter_mut().enumerate() {
            *s = match q {
                0 => _mm512_extracti32x4_epi32::<0>(v),
                1 => _mm512_extracti32x4_epi32::<1>(v),
                2 => _mm512_extracti32x4_epi32::<2>(v),
                _ => _mm512_extracti32x4_epi32::<3>(v),
            };
        }
    } else {
        for (q, s) in s.iter_mut().enumerate() {
            *s = hsum4_512([a[0][q], a[1][q], a[2][q], a[3][q]]);
        }
    }
    s
}

/// Four rows by `Q` points of 256-bit accumulators to `Q` vectors of four row sums.
#[inline]
#[target_feature(enable = "avx2")]
fn reduce4_256<const Q: usize>(a: [[__m256i; Q]; 4]) -> [__m128i; Q] {
    let mut s = [_mm_setzero_si128(); Q];
    for (q, s) in s.iter_mut().enumerate() {
        *s = hsum4_256([a[0][q], a[1][q], a[2][q], a[3][q]]);
    }
    s
}

/// Calls `$f::<Q>` over the `$np` points of a group: blocks of `PB` points, then one block of
/// the 1 to 3 left. (Splitting `PB + 1` points as `PB − 1` and 2 rather than `PB` and 1
/// measured slower: the 4 × 1 block runs from L1.)
macro_rules! by_points {
    ($np:expr, |$p:ident| $f:ident($($arg:expr),*)) => {{
        let mut $p = 0;
        while $p + PB <= $np {
            $f::<PB>($($arg),*);
            $p += PB;
        }
        match $np - $p {
            0 => {}
            1 => $f::<1>($($arg),*),
            2 => $f::<2>($($arg),*),
            _ => $f::<3>($($arg),*),
        }
    }};
}

/// The matrix-matrix loop shared by the int8 kernels (see [`super::MatmatI8`]).
///
/// Points go in groups of [`GROUP`]; inside a group, for each block of four weight rows, the
/// points go `points` at a time (then the 1 to `points − 1` left over): one register block
/// holds `4 × points` accumulators, each weight vector loaded (and biased) once serves `points`
/// points and each `x` vector four rows. The four rows' weights (`4 · K` bytes) come from
/// memory for the first block of points and from L1 for the others. The rows left over after
/// the blocks of four go one at a time; a group of one point goes to the family's `matvec`
/// kernel. The other parameters are [`matvec_body`]'s; `corr(x_p)` is point `p`'s correction,
/// computed once per point per call.
///
/// The horizontal sums bound the speed: with row-major weights every output needs one (45
/// µops per 16 outputs for `hsum16_512`), against `K / 64` `vpdpbusd` per output. At
/// `K = 512` this kernel runs at about two thirds of the `vpdpbusd` peak.
macro_rules! matmat_body {
    (
        $w:ident, $k:ident, $x:ident, $bias:ident, $out:ident, $stride:ident;
        matvec: $matvec:ident, features: $feat:literal, vector: $v:ty, lanes: $lanes:expr,
        points: $pb:expr, zero: $zero:expr, load_w: $load_w:expr, load_x: $load_x:expr,
        mac: $mac:expr, reduce4: $reduce4:expr, hsum: $hsum:expr, corr: $corr:expr,
        tail: scalar $(,)?
    ) => {
        matmat_body!(@go $w, $k, $x, $bias, $out, $stride; $matvec, $feat, $v, $lanes, $pb,
            $zero, $load_w, $load_x, |_: &[i8]| $zero, |_: &[i8]| $zero, $mac, $reduce4, $hsum,
            $corr, true)
    };
    (
        $w:ident, $k:ident, $x:ident, $bias:ident, $out:ident, $stride:ident;
        matvec: $matvec:ident, features: $feat:literal, vector: $v:ty, lanes: $lanes:expr,
        points: $pb:expr, zero: $zero:expr, load_w: $load_w:expr, load_x: $load_x:expr,
        mac: $mac:expr, reduce4: $reduce4:expr, hsum: $hsum:expr, corr: $corr:expr,
        tail: masked($tail_w:expr, $tail_x:expr) $(,)?
    ) => {
        matmat_body!(@go $w, $k, $x, $bias, $out, $stride; $matvec, $feat, $v, $lanes, $pb,
            $zero, $load_w, $load_x, $tail_w, $tail_x, $mac, $reduce4, $hsum, $corr, false)
    };
    (
        @go $w:ident, $k:ident, $x:ident, $bias:ident, $out:ident, $stride:ident;
        $matvec:ident, $feat:literal, $v:ty, $lanes:expr, $pb:expr, $zero:expr,
        $load_w:expr, $load_x:expr, $tail_w:expr, $tail_x:expr, $mac:expr, $reduce4:expr,
        $hsum:expr, $corr:expr, $scalar_tail:expr
    ) => {{
        const L: usize = $lanes;
        const PB: usize = $pb;
        const SCALAR_TAIL: bool = $scalar_tail;
        const _: () = assert!(PB >= 1 && PB <= 4);

        /// `a[r][q] = Σ mac(w[r] chunk, x[q] chunk)` over the `K / L` full chunks, plus the
        /// masked tail chunk unless `SCALAR_TAIL`. Every row of `w` and `x` is `k` long.
        #[inline]
        #[target_feature(enable = $feat)]
        fn block<const R: usize, const Q: usize>(
            w: [&[i8]; R],
            x: [&[i8]; Q],
            k: usize,
        ) -> [[$v; Q]; R] {
            let n = k / L;
            // Re-sliced to `n` so that the indexing below needs no bounds checks.
            // (Loops, not `array::from_fn`/`map`: their closures would not be inlined across
            // the target-feature boundary.)
            let mut wc: [&[[i8; L]]; R] = [&[]; R];
            for r in 0..R {
                wc[r] = &w[r].as_chunks::<L>().0[..n];
            }
            let mut xc: [&[[i8; L]]; Q] = [&[]; Q];
            for q in 0..Q {
                xc[q] = &x[q].as_chunks::<L>().0[..n];
            }
            let mut a = [[$zero; Q]; R];
            let mut xv = [$zero; Q];
            for i in 0..n {
                for q in 0..Q {
                    xv[q] = $load_x(&xc[q][i]);
                }
                for r in 0..R {
                    let wv = $load_w(&wc[r][i]);
                    for q in 0..Q {
                        a[r][q] = $mac(a[r][q], wv, xv[q]);
                    }
                }
            }
            if !SCALAR_TAIL && k % L != 0 {
                for q in 0..Q {
                    xv[q] = $tail_x(&x[q][n * L..]);
                }
                for r in 0..R {
                    let wv = $tail_w(&w[r][n * L..]);
                    for q in 0..Q {
                        a[r][q] = $mac(a[r][q], wv, xv[q]);
                    }
                }
            }
            a
        }

        /// Rows `o..o + 4` (`w`, `bias`) for points `p..p + Q` of the group (`x`, `corr`,
        /// `out` from the group's first point).
        #[inline]
        #[target_feature(enable = $feat)]
        #[allow(clippy::too_many_arguments)]
        fn quad<const Q: usize>(
            w: [&[i8]; 4],
            bias: &[i32; 4],
            o: usize,
            x: &[i8],
            k: usize,
            p: usize,
            corr: &[i32; GROUP],
            out: &mut [i32],
            stride: usize,
        ) {
            let mut xs: [&[i8]; Q] = [&[]; Q];
            for (q, xs) in xs.iter_mut().enumerate() {
                *xs = &x[(p + q) * k..][..k];
            }
            let mut s: [__m128i; Q] = $reduce4(block::<4, Q>(w, xs, k));
            if SCALAR_TAIL && k % L != 0 {
                let t = k / L * L;
                for q in 0..Q {
                    let d = |r: usize| dot_tail(&w[r][t..], &xs[q][t..]);
                    s[q] = _mm_add_epi32(s[q], _mm_setr_epi32(d(0), d(1), d(2), d(3)));
                }
            }
            for q in 0..Q {
                let y = &mut out[(p + q) * stride + o..][..4];
                store4(bias, y.try_into().unwrap(), s[q], corr[p + q]);
            }
        }

        /// Row `o` for points `p..p + Q`, as [`quad`].
        #[inline]
        #[target_feature(enable = $feat)]
        #[allow(clippy::too_many_arguments)]
        fn single<const Q: usize>(
            w: &[i8],
            bias: i32,
            o: usize,
            x: &[i8],
            k: usize,
            p: usize,
            corr: &[i32; GROUP],
            out: &mut [i32],
            stride: usize,
        ) {
            let mut xs: [&[i8]; Q] = [&[]; Q];
            for (q, xs) in xs.iter_mut().enumerate() {
                *xs = &x[(p + q) * k..][..k];
            }
            let [a] = block::<1, Q>([w], xs, k);
            for q in 0..Q {
                let mut s = $hsum(a[q]);
                if SCALAR_TAIL {
                    let t = k / L * L;
                    s = s.wrapping_add(dot_tail(&w[t..], &xs[q][t..]));
                }
                out[(p + q) * stride + o] = bias.wrapping_add(s).wrapping_sub(corr[p + q]);
            }
        }

        let (k, stride) = ($k, $stride);
        let (points, n) =
            crate::kernels::matmat_dims(k, $w.len(), $x.len(), $bias.len(), $out.len(), stride);
        let mut g = 0;
        while g < points {
            let np = if points - g < GROUP { points - g } else { GROUP };
            let x = &$x[g * k..][..np * k];
            let out = &mut $out[g * stride..];
            if np == 1 {
                // One point (P = 1, or the last of P = 16n + 1): the same family's matvec
                // kernel, measured faster than the 4 × 1 block when the weights come from L2.
                // SAFETY: `$matvec` needs no more CPU features than the enclosing kernel, whose
                // caller guaranteed them.
                unsafe { $matvec($w, x, $bias, &mut out[..n]) };
                g += 1;
                continue;
            }
            let mut corr = [0i32; GROUP];
            if k > 0 {
                for (c, xp) in corr.iter_mut().zip(x.chunks_exact(k)) {
                    *c = $corr(xp);
                }
            }
            let mut o = 0;
            while o + 4 <= n {
                let mut w: [&[i8]; 4] = [&[]; 4];
                for (r, w) in w.iter_mut().enumerate() {
                    *w = &$w[(o + r) * k..][..k];
                }
                let b: &[i32; 4] = $bias[o..o + 4].try_into().unwrap();
                by_points!(np, |p| quad(w, b, o, x, k, p, &corr, out, stride));
                o += 4;
            }
            while o < n {
                let (w, b) = (&$w[o * k..][..k], $bias[o]);
                by_points!(np, |p| single(w, b, o, x, k, p, &corr, out, stride));
                o += 1;
            }
            g += np;
        }
    }};
}

/// int8 matrix-matrix product with AVX2 `vpmaddwd` on sign-extended i16, four rows by
/// two points per register block; same result as [`crate::kernels::reference::matmat_i8`].
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub unsafe fn matmat_i8_avx2(
    w: &[i8],
    k: usize,
    x: &[i8],
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    matmat_body!(w, k, x, bias, out, out_stride;
        matvec: matvec_i8_avx2, features: "avx2", vector: __m256i, lanes: 16, points: 2,
        zero: _mm256_setzero_si256(), load_w: avx2_ld_i8, load_x: avx2_ld_i8,
        mac: avx2_mac_i16, reduce4: reduce4_256, hsum: hsum_256, corr: |_: &[i8]| 0,
        tail: scalar)
}

/// int8 matrix-matrix product with AVX-VNNI `vpdpbusd` (256-bit) on `w + 128`, four rows by
/// two points per register block (three points: 12 accumulators, 3 `x` and a weight vector fill
/// all 16 registers, and measured 25 % slower); same result as
/// [`crate::kernels::reference::matmat_i8`].
///
/// # Safety
/// The CPU must support AVX2 and AVX-VNNI.
#[target_feature(enable = "avx2,avxvnni")]
pub unsafe fn matmat_i8_avxvnni(
    w: &[i8],
    k: usize,
    x: &[i8],
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    matmat_body!(w, k, x, bias, out, out_stride;
        matvec: matvec_i8_avxvnni, features: "avx2,avxvnni", vector: __m256i, lanes: 32,
        points: 2, zero: _mm256_setzero_si256(), load_w: avxvnni_ldw, load_x: ld256_i8,
        mac: avxvnni_mac, reduce4: reduce4_256, hsum: hsum_256,
        corr: |x: &[i8]| vnni_correction(&x[..x.len() / 32 * 32]), tail: scalar)
}

/// int8 matrix-matrix product with AVX-512BW `vpmaddwd` on sign-extended i16, four rows by
/// four points per register block; same result as [`crate::kernels::reference::matmat_i8`].
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW and AVX-512VL.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
pub unsafe fn matmat_i8_avx512bw(
    w: &[i8],
    k: usize,
    x: &[i8],
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    matmat_body!(w, k, x, bias, out, out_stride;
        matvec: matvec_i8_avx512bw, features: "avx2,avx512f,avx512bw,avx512vl",
        vector: __m512i, lanes: 32, points: 4,
        zero: _mm512_setzero_si512(), load_w: avx512bw_ld_i8, load_x: avx512bw_ld_i8,
        mac: avx512bw_mac_i16, reduce4: reduce4_512, hsum: hsum_512, corr: |_: &[i8]| 0,
        tail: masked(avx512bw_ldm_i8, avx512bw_ldm_i8))
}

/// int8 matrix-matrix product with AVX-512 VNNI `vpdpbusd` on `w + 128`, four rows by four
/// points per register block; same result as [`crate::kernels::reference::matmat_i8`].
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW, AVX-512VL and AVX-512 VNNI.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn matmat_i8_avx512vnni(
    w: &[i8],
    k: usize,
    x: &[i8],
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    matmat_body!(w, k, x, bias, out, out_stride;
        matvec: matvec_i8_avx512vnni, features: "avx2,avx512f,avx512bw,avx512vl,avx512vnni",
        vector: __m512i, lanes: 64, points: 4, zero: _mm512_setzero_si512(),
        load_w: avx512vnni_ldw, load_x: ld512_i8,
        mac: avx512vnni_mac, reduce4: reduce4_512, hsum: hsum_512, corr: vnni_correction,
        tail: masked(avx512vnni_ldwm, ld512m_i8))
}

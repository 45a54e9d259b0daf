//! Matrix-vector kernels (one input vector, `out = W x + b`), per ISA: the loop written once
//! (`matvec_body!`), each family's load and multiply-accumulate steps from the parent.
#![allow(clippy::incompatible_msrv)]

use super::*;

/// The matrix-vector loop shared by every kernel, four rows at a time:
/// `out[o] = bias[o] + hsum(Σ_chunks mac(w_chunk, x_chunk)) − corr`, wrapping.
///
/// `lanes` values per step; `load_w`/`load_x` load a full chunk (`&[T; lanes]`),
/// `mac(acc, w, x)` adds one step, `corr` is subtracted from every output (0 unless the weights
/// are fed biased). A row's last `K mod lanes` values are either one more vector step
/// (`tail: masked(load_w, load_x)`, loaders taking the tail slice and zeroing the lanes above
/// it) or summed by [`dot_tail`] (`tail: scalar`: cheaper than padding a copy when there are no
/// masked byte loads, as in AVX2).
macro_rules! matvec_body {
    (
        $w:ident, $x:ident, $bias:ident, $out:ident;
        lanes: $lanes:expr, zero: $zero:expr, load_w: $load_w:expr, load_x: $load_x:expr,
        mac: $mac:expr, hsum4: $hsum4:expr, hsum: $hsum:expr, corr: $corr:expr,
        tail: scalar $(,)?
    ) => {
        matvec_body!(@go $w, $x, $bias, $out; $lanes, $zero, $load_w, $load_x,
            |_| $zero, |_| $zero, $mac, $hsum4, $hsum, $corr, true)
    };
    (
        $w:ident, $x:ident, $bias:ident, $out:ident;
        lanes: $lanes:expr, zero: $zero:expr, load_w: $load_w:expr, load_x: $load_x:expr,
        mac: $mac:expr, hsum4: $hsum4:expr, hsum: $hsum:expr, corr: $corr:expr,
        tail: masked($tail_w:expr, $tail_x:expr) $(,)?
    ) => {
        matvec_body!(@go $w, $x, $bias, $out; $lanes, $zero, $load_w, $load_x,
            $tail_w, $tail_x, $mac, $hsum4, $hsum, $corr, false)
    };
    (
        @go $w:ident, $x:ident, $bias:ident, $out:ident; $lanes:expr, $zero:expr,
        $load_w:expr, $load_x:expr, $tail_w:expr, $tail_x:expr,
        $mac:expr, $hsum4:expr, $hsum:expr, $corr:expr, $scalar_tail:expr
    ) => {{
        const L: usize = $lanes;
        const SCALAR_TAIL: bool = $scalar_tail;
        let k = $x.len();
        let n = rows(k, $w.len(), $bias.len(), $out.len());
        let corr: i32 = $corr;
        let (xc, xt) = $x.as_chunks::<L>();
        if SCALAR_TAIL && xc.is_empty() {
            // Shorter than one chunk (the K = 5 first layer): nothing to vectorize along K.
            for (o, (y, &b)) in $out[..n].iter_mut().zip(&$bias[..n]).enumerate() {
                *y = b.wrapping_add(dot_tail(&$w[o * k..][..k], xt)).wrapping_sub(corr);
            }
            return;
        }
        let xtv = if SCALAR_TAIL { $zero } else { $tail_x(xt) };
        let row = |o: usize| $w[o * k..][..k].as_chunks::<L>();
        let mut o = 0;
        while o + 4 <= n {
            let [r0, r1, r2, r3] = [row(o), row(o + 1), row(o + 2), row(o + 3)];
            let mut a = [$zero; 4];
            for ((((xv, w0), w1), w2), w3) in xc.iter().zip(r0.0).zip(r1.0).zip(r2.0).zip(r3.0) {
                let xv = $load_x(xv);
                a[0] = $mac(a[0], $load_w(w0), xv);
                a[1] = $mac(a[1], $load_w(w1), xv);
                a[2] = $mac(a[2], $load_w(w2), xv);
                a[3] = $mac(a[3], $load_w(w3), xv);
            }
            let mut s = $hsum4(a);
            if SCALAR_TAIL {
                let t = [r0.1, r1.1, r2.1, r3.1].map(|w| dot_tail(w, xt));
                s = _mm_add_epi32(s, _mm_setr_epi32(t[0], t[1], t[2], t[3]));
            } else if !xt.is_empty() {
                let t = [r0.1, r1.1, r2.1, r3.1].map(|w| $mac($zero, $tail_w(w), xtv));
                s = _mm_add_epi32(s, $hsum4(t));
            }
            let (b, y) = (&$bias[o..o + 4], &mut $out[o..o + 4]);
            store4(b.try_into().unwrap(), y.try_into().unwrap(), s, corr);
            o += 4;
        }
        while o < n {
            let (wc, wt) = row(o);
            let mut a = $zero;
            for (xv, wv) in xc.iter().zip(wc) {
                a = $mac(a, $load_w(wv), $load_x(xv));
            }
            let mut s = $hsum(a);
            if SCALAR_TAIL {
                s = s.wrapping_add(dot_tail(wt, xt));
            } else if !xt.is_empty() {
                a = $mac($zero, $tail_w(wt), xtv);
                s = s.wrapping_add($hsum(a));
            }
            $out[o] = $bias[o].wrapping_add(s).wrapping_sub(corr);
            o += 1;
        }
    }};
}

/// int8 matrix-vector product with AVX2 `vpmaddwd` on sign-extended i16; same result as
/// [`crate::kernels::reference::matvec_i8`].
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub unsafe fn matvec_i8_avx2(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    matvec_body!(w, x, bias, out;
        lanes: 16, zero: _mm256_setzero_si256(),
        load_w: avx2_ld_i8, load_x: avx2_ld_i8,
        mac: avx2_mac_i16, hsum4: hsum4_256, hsum: hsum_256, corr: 0, tail: scalar)
}

/// int8 matrix-vector product with AVX-512BW `vpmaddwd` on sign-extended i16; same result as
/// [`crate::kernels::reference::matvec_i8`].
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW and AVX-512VL.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
pub unsafe fn matvec_i8_avx512bw(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    matvec_body!(w, x, bias, out;
        lanes: 32, zero: _mm512_setzero_si512(),
        load_w: avx512bw_ld_i8, load_x: avx512bw_ld_i8,
        mac: avx512bw_mac_i16, hsum4: hsum4_512, hsum: hsum_512, corr: 0,
        tail: masked(avx512bw_ldm_i8, avx512bw_ldm_i8))
}

/// int8 matrix-vector product with AVX-VNNI `vpdpbusd` (256-bit) on `w + 128`; same result as
/// [`crate::kernels::reference::matvec_i8`].
///
/// # Safety
/// The CPU must support AVX2 and AVX-VNNI.
#[target_feature(enable = "avx2,avxvnni")]
pub unsafe fn matvec_i8_avxvnni(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    matvec_body!(w, x, bias, out;
        lanes: 32, zero: _mm256_setzero_si256(),
        load_w: avxvnni_ldw, load_x: ld256_i8,
        mac: avxvnni_mac, hsum4: hsum4_256, hsum: hsum_256,
        corr: vnni_correction(&x[..x.len() / 32 * 32]), tail: scalar)
}

/// int8 matrix-vector product with AVX-512 VNNI `vpdpbusd` on `w + 128`; same result as
/// [`crate::kernels::reference::matvec_i8`].
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW, AVX-512VL and AVX-512 VNNI.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn matvec_i8_avx512vnni(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    matvec_body!(w, x, bias, out;
        lanes: 64, zero: _mm512_setzero_si512(),
        load_w: avx512vnni_ldw, load_x: ld512_i8,
        mac: avx512vnni_mac, hsum4: hsum4_512, hsum: hsum_512, corr: vnni_correction(x),
        tail: masked(avx512vnni_ldwm, ld512m_i8))
}

/// i16 matrix-vector product with AVX2 `vpmaddwd`; same result as
/// [`crate::kernels::reference::matvec_i16`].
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub unsafe fn matvec_i16_avx2(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn mac(a: __m256i, w: __m256i, x: __m256i) -> __m256i {
        _mm256_add_epi32(a, _mm256_madd_epi16(w, x))
    }
    matvec_body!(w, x, bias, out;
        lanes: 16, zero: _mm256_setzero_si256(),
        load_w: ld256_i16, load_x: ld256_i16,
        mac: mac, hsum4: hsum4_256, hsum: hsum_256, corr: 0, tail: scalar)
}

/// i16 matrix-vector product with AVX-VNNI `vpdpwssd` (256-bit); same result as
/// [`crate::kernels::reference::matvec_i16`].
///
/// # Safety
/// The CPU must support AVX2 and AVX-VNNI.
#[target_feature(enable = "avx2,avxvnni")]
pub unsafe fn matvec_i16_avxvnni(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    #[inline]
    #[target_feature(enable = "avx2,avxvnni")]
    fn mac(a: __m256i, w: __m256i, x: __m256i) -> __m256i {
        _mm256_dpwssd_avx_epi32(a, w, x)
    }
    matvec_body!(w, x, bias, out;
        lanes: 16, zero: _mm256_setzero_si256(),
        load_w: ld256_i16, load_x: ld256_i16,
        mac: mac, hsum4: hsum4_256, hsum: hsum_256, corr: 0, tail: scalar)
}

/// i16 matrix-vector product with AVX-512BW `vpmaddwd`; same result as
/// [`crate::kernels::reference::matvec_i16`].
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW and AVX-512VL.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
pub unsafe fn matvec_i16_avx512bw(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    #[inline]
    #[target_feature(enable = "avx512bw")]
    fn mac(a: __m512i, w: __m512i, x: __m512i) -> __m512i {
        _mm512_add_epi32(a, _mm512_madd_epi16(w, x))
    }
    matvec_body!(w, x, bias, out;
        lanes: 32, zero: _mm512_setzero_si512(),
        load_w: ld512_i16, load_x: ld512_i16,
        mac: mac, hsum4: hsum4_512, hsum: hsum_512, corr: 0,
        tail: masked(ld512m_i16, ld512m_i16))
}

/// i16 matrix-vector product with AVX-512 VNNI `vpdpwssd`; same result as
/// [`crate::kernels::reference::matvec_i16`].
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW, AVX-512VL and AVX-512 VNNI.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn matvec_i16_avx512vnni(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    #[inline]
    #[target_feature(enable = "avx512f,avx512vnni")]
    fn mac(a: __m512i, w: __m512i, x: __m512i) -> __m512i {
        _mm512_dpwssd_epi32(a, w, x)
    }
    matvec_body!(w, x, bias, out;
        lanes: 32, zero: _mm512_setzero_si512(),
        load_w: ld512_i16, load_x: ld512_i16,
        mac: mac, hsum4: hsum4_512, hsum: hsum_512, corr: 0,
        tail: masked(ld512m_i16, ld512m_i16))
}

// Matrix-matrix kernels.

//! x86_64 kernels: AVX2, AVX-VNNI, AVX-512BW and AVX-512 VNNI.
//!
//! Every kernel here returns the same integers as [`super::reference`], for any slice lengths:
//! it processes the same rows (see [`super::rows`]) and computes each dot product modulo 2^32,
//! the same residue the reference's `+` gives (wrapping in release builds; a debug build of the
//! reference panics instead, which needs sums no real layer produces).
//!
//! | kernel | int8 inner step | MACs per instruction |
//! |---|---|---|
//! | `avx2` | `vpmovsxbw` both operands, `vpmaddwd`, `vpaddd` | 16 |
//! | `avx512bw` | the same on 512-bit registers | 32 |
//! | `avxvnni` | `vpdpbusd` (u8 × s8 → i32), 256-bit | 32 |
//! | `avx512vnni` | `vpdpbusd`, 512-bit | 64 |
//!
//! `vpdpbusd` multiplies *unsigned* bytes by signed bytes. Both operands are signed here, so the
//! VNNI kernels feed the weights as `w + 128` (an XOR with `0x80`) and subtract `128 · Σ x`,
//! computed once per call because `x` is shared by every row:
//! `Σ w·x = Σ (w + 128)·x − 128·Σ x`. Each 4-byte group sums to at most 4 · 255 · 128 < 2^31,
//! and everything else is a wrapping i32 sum, so the identity holds exactly modulo 2^32.
//!
//! The i16 kernels use `vpmaddwd` (or `vpdpwssd`, its fused VNNI form): two i16 products summed
//! into i32. The only pair that leaves the i32 range is (−32768)·(−32768)·2 = 2^31, which both
//! instructions wrap to −2^31, again the residue modulo 2^32.
//!
//! Four rows are computed together so each chunk of `x` is loaded once for four rows and the four
//! horizontal sums share one shuffle tree. The AVX-512 kernels finish a row with masked loads (a
//! masked-off lane is never read); the 256-bit ones with a scalar loop.
//!
//! The `unsafe fn`s are public for callers that do their own feature checks; safe code gets them
//! through [`super::Kernels`], which hands out only kernels the CPU supports.
#![allow(unsafe_code)]
// This module needs Rust 1.89: the AVX-512 and AVX-VNNI intrinsics and target features are
// stable since 1.89, `slice::as_chunks` since 1.88. The workspace `rust-version` must say so.
#![allow(clippy::incompatible_msrv)]

use core::arch::x86_64::*;

use super::{rows, Isa, Kernels};

/// The x86 features the kernels use, as reported by `cpuid` and enabled by the OS (`xgetbv`).
///
/// Fields are private: a value can only come from [`Features::detect`] or
/// [`Features::compile_time`], so a `Features` never claims more than the CPU has.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Features {
    avx2: bool,
    avxvnni: bool,
    avx512bw: bool,
    avx512vnni: bool,
}

impl Features {
    /// Asks the CPU (`cpuid`) and the OS (`xgetbv`: are the YMM/ZMM registers saved on context
    /// switches?), as `std::is_x86_feature_detected!` does, but without `std`. Costs a few
    /// hundred cycles: call it once and keep the result.
    pub fn detect() -> Self {
        // SAFETY: `cpuid` exists on every x86_64 CPU (the intrinsic is a safe fn since Rust 1.94
        // and `unsafe` before, hence the `allow`).
        #[allow(unused_unsafe)]
        let (max_leaf, leaf1) = unsafe { (__cpuid(0).eax, __cpuid(1)) };
        if max_leaf < 7 {
            return Self::default();
        }
        // SAFETY: as above; leaf 7 exists since `max_leaf >= 7`.
        #[allow(unused_unsafe)]
        let leaf7 = unsafe { __cpuid_count(7, 0) };
        // SAFETY: as above; sub-leaf 1 of leaf 7 exists when leaf 7's EAX says so, else unused.
        #[allow(unused_unsafe)]
        let leaf7_1 = unsafe { __cpuid_count(7, 1) };
        let osxsave = leaf1.ecx & (1 << 27) != 0;
        let avx = leaf1.ecx & (1 << 28) != 0;
        let xcr0 = if osxsave {
            // SAFETY: CPUID.1:ECX.OSXSAVE says the OS enabled XSAVE, so `xgetbv` exists.
            unsafe { xcr0() }
        } else {
            0
        };
        let ymm = avx && xcr0 & 0b110 == 0b110; // SSE and AVX state
        let zmm = ymm && xcr0 & 0b1110_0000 == 0b1110_0000; // opmask, ZMM0-15 high, ZMM16-31
        let b = leaf7.ebx;
        let avx2 = ymm && b & (1 << 5) != 0;
        let avx512 = zmm && b & (1 << 16) != 0 && b & (1 << 30) != 0 && b & (1 << 31) != 0; // F BW VL
        Self {
            avx2,
            avxvnni: avx2 && leaf7.eax >= 1 && leaf7_1.eax & (1 << 4) != 0,
            avx512bw: avx2 && avx512,
            avx512vnni: avx2 && avx512 && leaf7.ecx & (1 << 11) != 0,
        }
    }

    /// The features this build may assume everywhere (`-C target-feature`/`target-cpu`).
    pub const fn compile_time() -> Self {
        Self {
            avx2: cfg!(target_feature = "avx2"),
            avxvnni: cfg!(all(target_feature = "avx2", target_feature = "avxvnni")),
            avx512bw: cfg!(all(
                target_feature = "avx2",
                target_feature = "avx512f",
                target_feature = "avx512bw",
                target_feature = "avx512vl"
            )),
            avx512vnni: cfg!(all(
                target_feature = "avx2",
                target_feature = "avx512f",
                target_feature = "avx512bw",
                target_feature = "avx512vl",
                target_feature = "avx512vnni"
            )),
        }
    }

    /// Whether the CPU has what `isa`'s kernels need.
    pub const fn supports(self, isa: Isa) -> bool {
        match isa {
            Isa::Reference => true,
            Isa::X86Avx2 => self.avx2,
            Isa::X86AvxVnni => self.avxvnni,
            Isa::X86Avx512Bw => self.avx512bw,
            Isa::X86Avx512Vnni => self.avx512vnni,
        }
    }

    /// AVX2.
    pub const fn avx2(self) -> bool {
        self.avx2
    }

    /// AVX2 and AVX-VNNI.
    pub const fn avxvnni(self) -> bool {
        self.avxvnni
    }

    /// AVX2, AVX-512F, AVX-512BW and AVX-512VL, with ZMM state enabled by the OS.
    pub const fn avx512bw(self) -> bool {
        self.avx512bw
    }

    /// [`Features::avx512bw`] and AVX-512 VNNI.
    pub const fn avx512vnni(self) -> bool {
        self.avx512vnni
    }
}

/// XCR0, the OS-enabled register state.
///
/// # Safety
/// The CPU must support `xgetbv` (CPUID.1:ECX.OSXSAVE).
#[target_feature(enable = "xsave")]
unsafe fn xcr0() -> u64 {
    // SAFETY: the caller checked OSXSAVE.
    unsafe { _xgetbv(0) }
}

/// The kernels of `isa` if `features` (from `detect` or `compile_time`) says the CPU runs them.
pub(super) const fn kernels(isa: Isa, features: Features) -> Option<Kernels> {
    if !features.supports(isa) {
        return None;
    }
    // Invariant: the private wrappers below are stored only here, after the check above.
    let (i8, i16): (super::MatvecI8, super::MatvecI16) = match isa {
        Isa::X86Avx2 => (avx2_i8, avx2_i16),
        Isa::X86AvxVnni => (avxvnni_i8, avxvnni_i16),
        Isa::X86Avx512Bw => (avx512bw_i8, avx512bw_i16),
        Isa::X86Avx512Vnni => (avx512vnni_i8, avx512vnni_i16),
        _ => return None,
    };
    Some(Kernels { isa, i8, i16 })
}

/// Safe wrappers with the reference's signature, for [`Kernels`]' function pointers.
macro_rules! checked {
    ($($name:ident => $kernel:ident($t:ty);)*) => {$(
        fn $name(w: &[$t], x: &[$t], bias: &[i32], out: &mut [i32]) {
            // SAFETY: this private fn is only reachable through a `Kernels` made by `kernels`
            // above, which checked that the CPU supports the kernel's features.
            unsafe { $kernel(w, x, bias, out) }
        }
    )*};
}

checked! {
    avx2_i8 => matvec_i8_avx2(i8);
    avx2_i16 => matvec_i16_avx2(i16);
    avxvnni_i8 => matvec_i8_avxvnni(i8);
    avxvnni_i16 => matvec_i16_avxvnni(i16);
    avx512bw_i8 => matvec_i8_avx512bw(i8);
    avx512bw_i16 => matvec_i16_avx512bw(i16);
    avx512vnni_i8 => matvec_i8_avx512vnni(i8);
    avx512vnni_i16 => matvec_i16_avx512vnni(i16);
}

// Loads and stores. The array types prove the bytes are there; the masked loads read only the
// lanes that exist (a masked-off lane is never accessed, so it cannot fault). Everything else in
// this file is safe code.

/// 16 bytes.
#[inline]
#[target_feature(enable = "avx2")]
fn ld128_i8(p: &[i8; 16]) -> __m128i {
    // SAFETY: `p` is 16 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm_loadu_si128(p.as_ptr().cast()) }
}

/// 32 bytes.
#[inline]
#[target_feature(enable = "avx2")]
fn ld256_i8(p: &[i8; 32]) -> __m256i {
    // SAFETY: `p` is 32 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm256_loadu_si256(p.as_ptr().cast()) }
}

/// 32 bytes.
#[inline]
#[target_feature(enable = "avx2")]
fn ld256_i16(p: &[i16; 16]) -> __m256i {
    // SAFETY: `p` is 32 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm256_loadu_si256(p.as_ptr().cast()) }
}

/// 64 bytes.
#[inline]
#[target_feature(enable = "avx512f")]
fn ld512_i8(p: &[i8; 64]) -> __m512i {
    // SAFETY: `p` is 64 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm512_loadu_si512(p.as_ptr().cast()) }
}

/// 64 bytes.
#[inline]
#[target_feature(enable = "avx512f")]
fn ld512_i16(p: &[i16; 32]) -> __m512i {
    // SAFETY: `p` is 64 readable bytes; `loadu` has no alignment requirement.
    unsafe { _mm512_loadu_si512(p.as_ptr().cast()) }
}

/// A mask of the low `min(n, 64)` lanes.
#[inline(always)]
const fn low_mask(n: usize) -> u64 {
    if n >= 64 {
        u64::MAX
    } else {
        (1 << n) - 1
    }
}

/// The first `min(t.len(), 32)` bytes of `t`, zeros above.
#[inline]
#[target_feature(enable = "avx512bw,avx512vl")]
fn ld256m_i8(t: &[i8]) -> __m256i {
    // SAFETY: the mask selects lanes `0..min(t.len(), 32)`, all inside `t`; others are not read.
    unsafe { _mm256_maskz_loadu_epi8(low_mask(t.len()) as u32, t.as_ptr()) }
}

/// The first `min(t.len(), 64)` bytes of `t`, zeros above.
#[inline]
#[target_feature(enable = "avx512bw")]
fn ld512m_i8(t: &[i8]) -> __m512i {
    // SAFETY: the mask selects lanes `0..min(t.len(), 64)`, all inside `t`; others are not read.
    unsafe { _mm512_maskz_loadu_epi8(low_mask(t.len()), t.as_ptr()) }
}

/// The first `min(t.len(), 32)` i16 of `t`, zeros above.
#[inline]
#[target_feature(enable = "avx512bw")]
fn ld512m_i16(t: &[i16]) -> __m512i {
    // SAFETY: the mask selects lanes `0..min(t.len(), 32)`, all inside `t`; others are not read.
    unsafe { _mm512_maskz_loadu_epi16(low_mask(t.len()) as u32, t.as_ptr()) }
}

/// `bias + s − corr` (lane-wise, wrapping) into `out`.
#[inline]
#[target_feature(enable = "avx2")]
fn store4(bias: &[i32; 4], out: &mut [i32; 4], s: __m128i, corr: i32) {
    // SAFETY: `bias` is 16 readable bytes; `loadu` has no alignment requirement.
    let b = unsafe { _mm_loadu_si128(bias.as_ptr().cast()) };
    let r = _mm_sub_epi32(_mm_add_epi32(b, s), _mm_set1_epi32(corr));
    // SAFETY: `out` is 16 writable bytes; `storeu` has no alignment requirement.
    unsafe { _mm_storeu_si128(out.as_mut_ptr().cast(), r) }
}

/// `Σ w·x` over a row's tail (fewer than one chunk), wrapping like the vector steps.
#[inline(always)]
fn dot_tail<T: Copy + Into<i32>>(w: &[T], x: &[T]) -> i32 {
    w.iter().zip(x).fold(0i32, |a, (&w, &x)| {
        a.wrapping_add(w.into().wrapping_mul(x.into()))
    })
}

// Horizontal sums.

/// `[Σa, Σb, Σc, Σd]`.
#[inline]
#[target_feature(enable = "avx2")]
fn hsum4_256([a, b, c, d]: [__m256i; 4]) -> __m128i {
    // [a01 a23 b01 b23 | a45 a67 b45 b67], then [a0-3 b0-3 c0-3 d0-3 | a4-7 b4-7 c4-7 d4-7].
    let abcd = _mm256_hadd_epi32(_mm256_hadd_epi32(a, b), _mm256_hadd_epi32(c, d));
    _mm_add_epi32(
        _mm256_castsi256_si128(abcd),
        _mm256_extracti128_si256::<1>(abcd),
    )
}

/// One vector's sum.
#[inline]
#[target_feature(enable = "avx2")]
fn hsum_256(a: __m256i) -> i32 {
    let s = _mm_add_epi32(_mm256_castsi256_si128(a), _mm256_extracti128_si256::<1>(a));
    let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b01_00_11_10>(s));
    let s = _mm_add_epi32(s, _mm_shuffle_epi32::<0b10_11_00_01>(s));
    _mm_cvtsi128_si32(s)
}

/// Lane `i` + lane `i + 8`.
#[inline]
#[target_feature(enable = "avx512f")]
fn fold_512(a: __m512i) -> __m256i {
    _mm256_add_epi32(_mm512_castsi512_si256(a), _mm512_extracti64x4_epi64::<1>(a))
}

/// `[Σa, Σb, Σc, Σd]`.
#[inline]
#[target_feature(enable = "avx2,avx512f")]
fn hsum4_512([a, b, c, d]: [__m512i; 4]) -> __m128i {
    hsum4_256([fold_512(a), fold_512(b), fold_512(c), fold_512(d)])
}

/// One vector's sum.
#[inline]
#[target_feature(enable = "avx2,avx512f")]
fn hsum_512(a: __m512i) -> i32 {
    hsum_256(fold_512(a))
}

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

/// `128 · Σ x`, wrapping: the correction for feeding `w + 128` to `vpdpbusd`.
#[inline(always)]
fn vnni_correction(x: &[i8]) -> i32 {
    x.iter()
        .fold(0i32, |s, &v| s.wrapping_add(i32::from(v)))
        .wrapping_mul(128)
}

/// int8 matrix-vector product with AVX2 `vpmaddwd` on sign-extended i16; same result as
/// [`super::reference::matvec_i8`].
///
/// # Safety
/// The CPU must support AVX2.
#[target_feature(enable = "avx2")]
pub unsafe fn matvec_i8_avx2(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn ld(p: &[i8; 16]) -> __m256i {
        _mm256_cvtepi8_epi16(ld128_i8(p))
    }
    #[inline]
    #[target_feature(enable = "avx2")]
    fn mac(a: __m256i, w: __m256i, x: __m256i) -> __m256i {
        _mm256_add_epi32(a, _mm256_madd_epi16(w, x))
    }
    matvec_body!(w, x, bias, out;
        lanes: 16, zero: _mm256_setzero_si256(),
        load_w: ld, load_x: ld,
        mac: mac, hsum4: hsum4_256, hsum: hsum_256, corr: 0, tail: scalar)
}

/// int8 matrix-vector product with AVX-512BW `vpmaddwd` on sign-extended i16; same result as
/// [`super::reference::matvec_i8`].
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW and AVX-512VL.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
pub unsafe fn matvec_i8_avx512bw(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
    fn ld(p: &[i8; 32]) -> __m512i {
        _mm512_cvtepi8_epi16(ld256_i8(p))
    }
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
    fn ldt(t: &[i8]) -> __m512i {
        _mm512_cvtepi8_epi16(ld256m_i8(t))
    }
    #[inline]
    #[target_feature(enable = "avx512bw")]
    fn mac(a: __m512i, w: __m512i, x: __m512i) -> __m512i {
        _mm512_add_epi32(a, _mm512_madd_epi16(w, x))
    }
    matvec_body!(w, x, bias, out;
        lanes: 32, zero: _mm512_setzero_si512(),
        load_w: ld, load_x: ld,
        mac: mac, hsum4: hsum4_512, hsum: hsum_512, corr: 0, tail: masked(ldt, ldt))
}

/// int8 matrix-vector product with AVX-VNNI `vpdpbusd` (256-bit) on `w + 128`; same result as
/// [`super::reference::matvec_i8`].
///
/// # Safety
/// The CPU must support AVX2 and AVX-VNNI.
#[target_feature(enable = "avx2,avxvnni")]
pub unsafe fn matvec_i8_avxvnni(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn ldw(p: &[i8; 32]) -> __m256i {
        _mm256_xor_si256(ld256_i8(p), _mm256_set1_epi8(i8::MIN))
    }
    #[inline]
    #[target_feature(enable = "avx2,avxvnni")]
    fn mac(a: __m256i, w: __m256i, x: __m256i) -> __m256i {
        _mm256_dpbusd_avx_epi32(a, w, x)
    }
    matvec_body!(w, x, bias, out;
        lanes: 32, zero: _mm256_setzero_si256(),
        load_w: ldw, load_x: ld256_i8,
        mac: mac, hsum4: hsum4_256, hsum: hsum_256, corr: vnni_correction(&x[..x.len() / 32 * 32]),
        tail: scalar)
}

/// int8 matrix-vector product with AVX-512 VNNI `vpdpbusd` on `w + 128`; same result as
/// [`super::reference::matvec_i8`].
///
/// # Safety
/// The CPU must support AVX2, AVX-512F, AVX-512BW, AVX-512VL and AVX-512 VNNI.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn matvec_i8_avx512vnni(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn ldw(p: &[i8; 64]) -> __m512i {
        _mm512_xor_si512(ld512_i8(p), _mm512_set1_epi8(i8::MIN))
    }
    #[inline]
    #[target_feature(enable = "avx512f,avx512bw")]
    fn ldwt(t: &[i8]) -> __m512i {
        // Lanes past the tail are 0 ^ 0x80 = 128, times x = 0 there.
        _mm512_xor_si512(ld512m_i8(t), _mm512_set1_epi8(i8::MIN))
    }
    #[inline]
    #[target_feature(enable = "avx512f,avx512vnni")]
    fn mac(a: __m512i, w: __m512i, x: __m512i) -> __m512i {
        _mm512_dpbusd_epi32(a, w, x)
    }
    matvec_body!(w, x, bias, out;
        lanes: 64, zero: _mm512_setzero_si512(),
        load_w: ldw, load_x: ld512_i8,
        mac: mac, hsum4: hsum4_512, hsum: hsum_512, corr: vnni_correction(x),
        tail: masked(ldwt, ld512m_i8))
}

/// i16 matrix-vector product with AVX2 `vpmaddwd`; same result as
/// [`super::reference::matvec_i16`].
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
/// [`super::reference::matvec_i16`].
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
/// [`super::reference::matvec_i16`].
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
/// [`super::reference::matvec_i16`].
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

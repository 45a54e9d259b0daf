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
//! The matrix-matrix kernels (`matmat_i8_*`, see [`super::MatmatI8`]) run the same inner step on
//! a register block of four rows by up to four points (two for the 256-bit kernels, which have
//! 16 registers), so that each weight vector loaded serves several points; the VNNI correction
//! is computed once per point. The 4 × 4 blocks of 512-bit sums are reduced by one shuffle tree
//! (`hsum16_512`).
//!
//! The packed kernel (`x86/packed.rs`, [`matmat_packed_i8_avx512vnni`]) needs neither the
//! shuffle tree nor the per-call correction of the weights: the weights are packed as `w + 128`
//! with 16 outputs across the lanes, the points' inputs are the signed operand, broadcast four
//! bytes at a time, and `128·Σx` is subtracted once per point.
//!
//! The `unsafe fn`s are public for callers that do their own feature checks; safe code gets them
//! through [`super::Kernels`], which hands out only kernels the CPU supports.
#![allow(unsafe_code)]
// This module needs Rust 1.89: the AVX-512 and AVX-VNNI intrinsics and target features are
// stable since 1.89, `slice::as_chunks` since 1.88. The workspace `rust-version` must say so.
#![allow(clippy::incompatible_msrv)]

use core::arch::x86_64::*;

use super::{rows, Isa, Kernels};

mod packed;
mod peak;

pub use packed::matmat_packed_i8_avx512vnni;
pub use peak::peak_loop;

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
            Isa::ArmDsp => false,
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
    let (i8, i16, i8mm): (super::MatvecI8, super::MatvecI16, super::MatmatI8) = match isa {
        Isa::X86Avx2 => (avx2_i8, avx2_i16, avx2_i8mm),
        Isa::X86AvxVnni => (avxvnni_i8, avxvnni_i16, avxvnni_i8mm),
        Isa::X86Avx512Bw => (avx512bw_i8, avx512bw_i16, avx512bw_i8mm),
        Isa::X86Avx512Vnni => (avx512vnni_i8, avx512vnni_i16, avx512vnni_i8mm),
        _ => return None,
    };
    let i8pk: Option<super::MatmatPackedI8> = match isa {
        Isa::X86Avx512Vnni => Some(avx512vnni_i8pk),
        _ => None,
    };
    let (requant, pool, f32): (super::RequantizeI8, super::PoolI8, super::MatvecF32) = match isa {
        Isa::X86Avx2 | Isa::X86AvxVnni => (avx2_requant, avx2_pool, avx2_f32),
        _ => (avx512_requant, avx512_pool, avx512_f32),
    };
    Some(Kernels {
        isa,
        i8,
        i16,
        i8mm,
        i8pk,
        requant,
        pool,
        f32,
    })
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

/// The same for the matrix-matrix kernels.
macro_rules! checked_mm {
    ($($name:ident => $kernel:ident;)*) => {$(
        fn $name(w: &[i8], k: usize, x: &[i8], bias: &[i32], out: &mut [i32], out_stride: usize) {
            // SAFETY: this private fn is only reachable through a `Kernels` made by `kernels`
            // above, which checked that the CPU supports the kernel's features.
            unsafe { $kernel(w, k, x, bias, out, out_stride) }
        }
    )*};
}

/// The reference requantization, pooling and f32 loops compiled for AVX2 or AVX-512 registers
/// (the same scalar code, vectorized by the compiler: the same IEEE operations per lane), with
/// the safe wrappers `kernels` stores.
macro_rules! widened {
    ($($name:ident / $safe:ident: $features:literal => $body:ident($($arg:ident: $t:ty),*);)*) => {$(
        /// [`super::reference`]'s loop of the same name, for wider registers.
        ///
        /// # Safety
        /// The CPU must support the enabled features.
        #[target_feature(enable = $features)]
        unsafe fn $name($($arg: $t),*) {
            super::reference::$body($($arg),*)
        }

        fn $safe($($arg: $t),*) {
            // SAFETY: as for `checked!`: only reachable through a `Kernels` whose ISA the CPU
            // supports (AVX2 for every x86 table, AVX-512F/BW/VL for the AVX-512 ones).
            unsafe { $name($($arg),*) }
        }
    )*};
}

widened! {
    requant_avx2 / avx2_requant: "avx2" => requantize_i8(
        acc: &[i32], scales: &[f32], leaky: Option<f32>, out: &mut [i8]);
    requant_avx512 / avx512_requant: "avx2,avx512f,avx512bw,avx512vl" => requantize_i8(
        acc: &[i32], scales: &[f32], leaky: Option<f32>, out: &mut [i8]);
    pool_avx2 / avx2_pool: "avx2" => pool_i8(max: &mut [i8], sum: &mut [i32], y: &[i8]);
    pool_avx512 / avx512_pool: "avx2,avx512f,avx512bw,avx512vl" => pool_i8(
        max: &mut [i8], sum: &mut [i32], y: &[i8]);
    f32_avx2 / avx2_f32: "avx2" => matvec_f32(w: &[f32], x: &[f32], bias: &[f32], out: &mut [f32]);
    f32_avx512 / avx512_f32: "avx2,avx512f,avx512bw,avx512vl" => matvec_f32(
        w: &[f32], x: &[f32], bias: &[f32], out: &mut [f32]);
}

/// The packed kernel behind the same kind of wrapper.
fn avx512vnni_i8pk(
    w: &super::PackedI8<'_>,
    x: &[i8],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    // SAFETY: as for `checked!`: only reachable through a `Kernels` whose ISA the CPU supports.
    unsafe { matmat_packed_i8_avx512vnni(w, x, x_stride, points, bias, out, out_stride) }
}

checked_mm! {
    avx2_i8mm => matmat_i8_avx2;
    avxvnni_i8mm => matmat_i8_avxvnni;
    avx512bw_i8mm => matmat_i8_avx512bw;
    avx512vnni_i8mm => matmat_i8_avx512vnni;
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

// The int8 steps of each kernel family, shared by the matvec and matmat kernels.

/// AVX2: 16 bytes sign-extended to i16.
#[inline]
#[target_feature(enable = "avx2")]
fn avx2_ld_i8(p: &[i8; 16]) -> __m256i {
    _mm256_cvtepi8_epi16(ld128_i8(p))
}

/// AVX2: `a + vpmaddwd(w, x)`.
#[inline]
#[target_feature(enable = "avx2")]
fn avx2_mac_i16(a: __m256i, w: __m256i, x: __m256i) -> __m256i {
    _mm256_add_epi32(a, _mm256_madd_epi16(w, x))
}

/// AVX-512BW: 32 bytes sign-extended to i16.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
fn avx512bw_ld_i8(p: &[i8; 32]) -> __m512i {
    _mm512_cvtepi8_epi16(ld256_i8(p))
}

/// AVX-512BW: the first `min(t.len(), 32)` bytes sign-extended to i16, zeros above.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
fn avx512bw_ldm_i8(t: &[i8]) -> __m512i {
    _mm512_cvtepi8_epi16(ld256m_i8(t))
}

/// AVX-512BW: `a + vpmaddwd(w, x)`.
#[inline]
#[target_feature(enable = "avx512bw")]
fn avx512bw_mac_i16(a: __m512i, w: __m512i, x: __m512i) -> __m512i {
    _mm512_add_epi32(a, _mm512_madd_epi16(w, x))
}

/// AVX-VNNI: 32 weights as `w + 128` (unsigned).
#[inline]
#[target_feature(enable = "avx2")]
fn avxvnni_ldw(p: &[i8; 32]) -> __m256i {
    _mm256_xor_si256(ld256_i8(p), _mm256_set1_epi8(i8::MIN))
}

/// AVX-VNNI: `vpdpbusd` (256-bit).
#[inline]
#[target_feature(enable = "avx2,avxvnni")]
fn avxvnni_mac(a: __m256i, w: __m256i, x: __m256i) -> __m256i {
    _mm256_dpbusd_avx_epi32(a, w, x)
}

/// AVX-512 VNNI: 64 weights as `w + 128` (unsigned).
#[inline]
#[target_feature(enable = "avx512f")]
fn avx512vnni_ldw(p: &[i8; 64]) -> __m512i {
    _mm512_xor_si512(ld512_i8(p), _mm512_set1_epi8(i8::MIN))
}

/// AVX-512 VNNI: the first `min(t.len(), 64)` weights as `w + 128`. Lanes past the tail are
/// 0 ^ 0x80 = 128, multiplied by the `x = 0` that the masked `x` load puts there.
#[inline]
#[target_feature(enable = "avx512f,avx512bw")]
fn avx512vnni_ldwm(t: &[i8]) -> __m512i {
    _mm512_xor_si512(ld512m_i8(t), _mm512_set1_epi8(i8::MIN))
}

/// AVX-512 VNNI: `vpdpbusd`.
#[inline]
#[target_feature(enable = "avx512f,avx512vnni")]
fn avx512vnni_mac(a: __m512i, w: __m512i, x: __m512i) -> __m512i {
    _mm512_dpbusd_epi32(a, w, x)
}

/// int8 matrix-vector product with AVX2 `vpmaddwd` on sign-extended i16; same result as
/// [`super::reference::matvec_i8`].
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
/// [`super::reference::matvec_i8`].
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
/// [`super::reference::matvec_i8`].
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
/// [`super::reference::matvec_i8`].
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

// Matrix-matrix kernels.

/// Points per group: the VNNI corrections of a group live in a stack array, and the loops run
/// over a group's points inside each block of four weight rows, so the weights are read from
/// memory once per group (and `x`, `GROUP · K` bytes, stays in L1).
const GROUP: usize = 16;

/// The sums of 16 vectors, `a[r][q]` for four rows `r` and four points `q`: 128-bit lane `q` of
/// the result is `[Σa[0][q], Σa[1][q], Σa[2][q], Σa[3][q]]`.
///
/// A tree of 45 shuffles and adds, none of them multi-µop; four [`hsum4_512`] take 52
/// instructions, 12 of them `vphaddd`. (Measured a few per cent faster at `P = 16`; replacing
/// one shuffle per pair by a blend measured no faster.)
#[inline]
#[target_feature(enable = "avx512f")]
fn hsum16_512(a: [[__m512i; 4]; 4]) -> __m512i {
    // [a.l0 + a.l2, a.l1 + a.l3, b.l0 + b.l2, b.l1 + b.l3] (128-bit lanes).
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn halve(a: __m512i, b: __m512i) -> __m512i {
        _mm512_add_epi32(
            _mm512_shuffle_i64x2::<0b01_00_01_00>(a, b),
            _mm512_shuffle_i64x2::<0b11_10_11_10>(a, b),
        )
    }
    // From [A0 A1 B0 B1] and [C0 C1 D0 D1]: [A0 + A1, B0 + B1, C0 + C1, D0 + D1].
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn quarter(c: __m512i, d: __m512i) -> __m512i {
        _mm512_add_epi32(
            _mm512_shuffle_i64x2::<0b10_00_10_00>(c, d),
            _mm512_shuffle_i64x2::<0b11_01_11_01>(c, d),
        )
    }
    // e[r], lane q: four partial sums of a[r][q].
    let mut e = [_mm512_setzero_si512(); 4];
    for r in 0..4 {
        e[r] = quarter(halve(a[r][0], a[r][1]), halve(a[r][2], a[r][3]));
    }
    // Per lane: [e0.0 + e0.2, e1.0 + e1.2, e0.1 + e0.3, e1.1 + e1.3], the same for e2, e3.
    let t01 = _mm512_add_epi32(
        _mm512_unpacklo_epi32(e[0], e[1]),
        _mm512_unpackhi_epi32(e[0], e[1]),
    );
    let t23 = _mm512_add_epi32(
        _mm512_unpacklo_epi32(e[2], e[3]),
        _mm512_unpackhi_epi32(e[2], e[3]),
    );
    _mm512_add_epi32(
        _mm512_unpacklo_epi64(t01, t23),
        _mm512_unpackhi_epi64(t01, t23),
    )
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
            super::matmat_dims(k, $w.len(), $x.len(), $bias.len(), $out.len(), stride);
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
                let mut p = 0;
                while p + PB <= np {
                    quad::<PB>(w, b, o, x, k, p, &corr, out, stride);
                    p += PB;
                }
                match np - p {
                    0 => {}
                    1 => quad::<1>(w, b, o, x, k, p, &corr, out, stride),
                    2 => quad::<2>(w, b, o, x, k, p, &corr, out, stride),
                    // (Splitting PB + 1 points as PB − 1 and 2 rather than PB and 1 measured
                    // slower: the 4 × 1 block runs from L1.)
                    _ => quad::<3>(w, b, o, x, k, p, &corr, out, stride),
                }
                o += 4;
            }
            while o < n {
                let (w, b) = (&$w[o * k..][..k], $bias[o]);
                let mut p = 0;
                while p + PB <= np {
                    single::<PB>(w, b, o, x, k, p, &corr, out, stride);
                    p += PB;
                }
                match np - p {
                    0 => {}
                    1 => single::<1>(w, b, o, x, k, p, &corr, out, stride),
                    2 => single::<2>(w, b, o, x, k, p, &corr, out, stride),
                    _ => single::<3>(w, b, o, x, k, p, &corr, out, stride),
                }
                o += 1;
            }
            g += np;
        }
    }};
}

/// int8 matrix-matrix product with AVX2 `vpmaddwd` on sign-extended i16, four rows by
/// two points per register block; same result as [`super::reference::matmat_i8`].
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
/// [`super::reference::matmat_i8`].
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
/// four points per register block; same result as [`super::reference::matmat_i8`].
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
/// points per register block; same result as [`super::reference::matmat_i8`].
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

//! x86_64 kernels: AVX2, AVX-VNNI, AVX-512BW, AVX-512 VNNI and AMX-INT8.
//!
//! Every kernel here returns the same integers as [`super::reference`], for any slice lengths:
//! it processes the same rows (see [`super::rows`]) and computes each dot product modulo 2^32,
//! the same residue the reference's wrapping sums give, in every build.
//!
//! | kernel | int8 inner step | MACs per instruction |
//! |---|---|---|
//! | `avx2` | `vpmovsxbw` both operands, `vpmaddwd`, `vpaddd` | 16 |
//! | `avx512bw` | the same on 512-bit registers | 32 |
//! | `avxvnni` | `vpdpbusd` (u8 × s8 → i32), 256-bit | 32 |
//! | `avx512vnni` | `vpdpbusd`, 512-bit | 64 |
//! | `amx` (packed int8 layers, `K` a multiple of 64 and ≥ 128 ([`AMX_MIN_K`]); else `avx512vnni`) | `tdpbsud` on 16 × 64-byte tiles | 16,384 |
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
//! The packed kernels (`x86/packed.rs`: [`matmat_packed_i8_avx512vnni`],
//! [`matmat_packed_i8_avxvnni`] and [`matmat_packed_i8_avx2`], and their int16 twins for the
//! first layer) need neither the shuffle tree nor the per-call correction of the weights: the
//! weights are packed as `w + 128` with 16 (or 8) outputs across the lanes, the points' inputs
//! are the signed operand, broadcast four bytes at a time (AVX2: as two i16 pairs, widened once
//! per call), and `128·Σx` is subtracted once per point. The AVX-512BW table (Skylake-SP's AVX-512,
//! without VNNI) runs AVX2's int8 loop on 512-bit registers.
//!
//! The AMX table (`x86/amx.rs`, [`matmat_packed_i8_amx`]) is the AVX-512 VNNI table with a
//! tile kernel for the packed int8 layers; [`Features::detect`] offers it only where Linux
//! granted this process the tile state ([`request_tile_data`]).
//!
//! The `unsafe fn`s are public for callers that do their own feature checks; safe code gets them
//! through [`super::Kernels`], which hands out only kernels the CPU supports.
#![allow(unsafe_code)]
// This module needs Rust 1.89: the AVX-512 and AVX-VNNI intrinsics and target features are
// stable since 1.89, `slice::as_chunks` since 1.88. The workspace `rust-version` must say so.
#![allow(clippy::incompatible_msrv)]

use core::arch::x86_64::*;

use super::{rows, Isa, Kernels, PointRows};

mod amx;
mod f32mm;
mod packed;
mod peak;

pub use amx::{
    matmat_packed_i8_amx, matmat_packed_pool_i8_amx, request_tile_data, MIN_K as AMX_MIN_K,
};

pub use f32mm::{matmat_f32_avx2, matmat_f32_avx512};
pub use packed::{
    matmat_packed_i16_avx2, matmat_packed_i16_avx512bw, matmat_packed_i16_avx512vnni,
    matmat_packed_i16_avxvnni, matmat_packed_i8_avx2, matmat_packed_i8_avx512bw,
    matmat_packed_i8_avx512vnni, matmat_packed_i8_avxvnni, matmat_packed_pool_i8_avx2,
    matmat_packed_pool_i8_avx512bw, matmat_packed_pool_i8_avx512vnni,
    matmat_packed_pool_i8_avxvnni, widened_pool_takes,
};
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
    amx: bool,
}

impl Features {
    /// Asks the CPU (`cpuid`) and the OS (`xgetbv`: are the YMM/ZMM registers saved on context
    /// switches?), as `std::is_x86_feature_detected!` does, but without `std`. Costs a few
    /// hundred cycles: call it once and keep the result.
    pub fn detect() -> Self {
        // Miri runs no `cpuid` and interprets only part of AVX-512: under it every table but
        // the reference is absent, so the portable (and the emulated Arm) kernels are what it
        // checks (`scripts/miri.sh`).
        if cfg!(miri) {
            return Self::default();
        }
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
        let avx512vnni = avx2 && avx512 && leaf7.ecx & (1 << 11) != 0;
        Self {
            avx2,
            avxvnni: avx2 && leaf7.eax >= 1 && leaf7_1.eax & (1 << 4) != 0,
            avx512bw: avx2 && avx512,
            avx512vnni,
            // Asked last, and only where the CPU has it: the request is a system call.
            amx: avx512vnni && amx::cpu_has_amx(leaf7.edx, xcr0) && request_tile_data(),
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
            // The OS's permission cannot be known at compile time.
            amx: false,
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
            Isa::X86Amx => self.amx,
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

    /// [`Features::avx512vnni`], AMX-TILE and AMX-INT8, with the tile state enabled by the OS
    /// (`XCR0`) and, on Linux, granted to this process ([`request_tile_data`], which `detect`
    /// calls); never at compile time.
    pub const fn amx(self) -> bool {
        self.amx
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
    // Invariant: the private wrappers below are stored only here, after the check above, and
    // `f32_kernel`/`packed_kernels` hand out theirs only for a table made here.
    let (i8, i16, i8mm): (super::MatvecI8, super::MatvecI16, super::MatmatI8) = match isa {
        Isa::X86Avx2 => (avx2_i8, avx2_i16, avx2_i8mm),
        Isa::X86AvxVnni => (avxvnni_i8, avxvnni_i16, avxvnni_i8mm),
        Isa::X86Avx512Bw => (avx512bw_i8, avx512bw_i16, avx512bw_i8mm),
        // AMX: the AVX-512 VNNI kernels, but for the packed int8 one (`packed_kernels`).
        Isa::X86Avx512Vnni | Isa::X86Amx => (avx512vnni_i8, avx512vnni_i16, avx512vnni_i8mm),
        _ => return None,
    };
    let (requant, pool): (super::RequantizeI8, super::PoolI8) = match isa {
        Isa::X86Avx2 | Isa::X86AvxVnni => (avx2_requant, avx2_pool),
        _ => (avx512_requant, avx512_pool),
    };
    Some(Kernels {
        isa,
        i8,
        i16,
        i8mm,
        requant,
        pool,
    })
}

/// The f32 kernel of an x86 table's ISA (`None` for other ISAs).
///
/// Takes the table, not an [`Isa`]: a table's ISA is one the CPU supports ([`kernels`] checked
/// it, and no other code sets an x86 ISA), so the wrappers' features are there.
pub(super) fn f32_kernel(k: &Kernels) -> Option<super::MatvecF32> {
    match k.isa() {
        Isa::X86Avx2 | Isa::X86AvxVnni => Some(avx2_f32),
        Isa::X86Avx512Bw | Isa::X86Avx512Vnni | Isa::X86Amx => Some(avx512_f32),
        _ => None,
    }
}

/// The native pooled packed kernel of an x86 table's ISA for `w`'s shape, if it has one (the
/// VNNI tables; the AMX table's runs on tiles where they take `w`, else AVX-512 VNNI's; AVX2
/// and AVX-512BW for layers of up to 512 inputs, [`widened_pool_takes`]); the same invariant
/// as [`f32_kernel`].
pub(super) fn packed_pool_kernel(
    k: &Kernels,
    w: &super::PackedI8<'_>,
) -> Option<super::MatmatPackedPoolI8> {
    match k.isa() {
        Isa::X86Amx if amx::takes(w) => Some(amx_pool),
        Isa::X86Amx | Isa::X86Avx512Vnni => Some(avx512vnni_pool),
        Isa::X86AvxVnni => Some(avxvnni_pool),
        Isa::X86Avx2 if widened_pool_takes(w) => Some(avx2_pool_i8pk),
        Isa::X86Avx512Bw if widened_pool_takes(w) => Some(avx512bw_pool_i8pk),
        _ => None,
    }
}

/// The native packed kernels (int8, int16) of an x86 table's ISA, if it has them; the same
/// invariant as [`f32_kernel`].
pub(super) fn packed_kernels(
    k: &Kernels,
) -> Option<(super::MatmatPackedI8, super::MatmatPackedI16)> {
    match k.isa() {
        Isa::X86Amx => Some((amx_i8pk, avx512vnni_i16pk)),
        Isa::X86Avx512Vnni => Some((avx512vnni_i8pk, avx512vnni_i16pk)),
        Isa::X86AvxVnni => Some((avxvnni_i8pk, avxvnni_i16pk)),
        Isa::X86Avx2 => Some((avx2_i8pk, avx2_i16pk)),
        Isa::X86Avx512Bw => Some((avx512bw_i8pk, avx512bw_i16pk)),
        _ => None,
    }
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

/// The f32 matrix-matrix kernel of an x86 table's ISA; the same invariant as [`f32_kernel`].
pub(super) fn f32_matmat_kernel(k: &Kernels) -> Option<super::MatmatF32> {
    match k.isa() {
        Isa::X86Avx2 | Isa::X86AvxVnni => Some(avx2_f32mm),
        Isa::X86Avx512Bw | Isa::X86Avx512Vnni | Isa::X86Amx => Some(avx512_f32mm),
        _ => None,
    }
}

fn avx2_f32mm(w: &[f32], bias: &[f32], rows: &mut [f32], at: &PointRows) {
    // SAFETY: as for `checked!`: only reachable through a `Kernels` whose ISA the CPU supports
    // (AVX2 for every x86 table).
    unsafe { matmat_f32_avx2(w, bias, rows, at) }
}

fn avx512_f32mm(w: &[f32], bias: &[f32], rows: &mut [f32], at: &PointRows) {
    // SAFETY: as for `checked!`: only reachable through a `Kernels` whose ISA the CPU supports
    // (AVX-512F for the tables `f32_matmat_kernel` gives it to).
    unsafe { matmat_f32_avx512(w, bias, rows, at) }
}

/// The packed kernels behind the same kind of wrapper.
macro_rules! checked_pk {
    ($($name:ident => $kernel:ident($t:ty, $w:ty);)*) => {$(
        fn $name(
            w: &$w,
            x: &[$t],
            x_stride: usize,
            points: usize,
            bias: &[i32],
            out: &mut [i32],
            out_stride: usize,
        ) {
            // SAFETY: as for `checked!`: only reachable through a `Kernels` whose ISA the CPU
            // supports.
            unsafe { $kernel(w, x, x_stride, points, bias, out, out_stride) }
        }
    )*};
}

checked_pk! {
    amx_i8pk => matmat_packed_i8_amx(i8, super::PackedI8<'_>);
    avx512vnni_i8pk => matmat_packed_i8_avx512vnni(i8, super::PackedI8<'_>);
    avx512vnni_i16pk => matmat_packed_i16_avx512vnni(i16, super::PackedI16<'_>);
    avxvnni_i8pk => matmat_packed_i8_avxvnni(i8, super::PackedI8<'_>);
    avxvnni_i16pk => matmat_packed_i16_avxvnni(i16, super::PackedI16<'_>);
    avx2_i8pk => matmat_packed_i8_avx2(i8, super::PackedI8<'_>);
    avx2_i16pk => matmat_packed_i16_avx2(i16, super::PackedI16<'_>);
    avx512bw_i8pk => matmat_packed_i8_avx512bw(i8, super::PackedI8<'_>);
    avx512bw_i16pk => matmat_packed_i16_avx512bw(i16, super::PackedI16<'_>);
}

/// The pooled packed kernels behind the same kind of wrapper.
macro_rules! checked_pool {
    ($($name:ident => $kernel:ident;)*) => {$(
        #[allow(clippy::too_many_arguments)]
        fn $name(
            w: &super::PackedI8<'_>,
            x: &[i8],
            x_stride: usize,
            points: usize,
            bias: &[i32],
            requant: crate::quant::Requant<'_>,
            max: &mut [i8],
            sum: &mut [i32],
        ) {
            // SAFETY: as for `checked!`: only reachable through a `Kernels`
            // (`packed_pool_kernel`) whose ISA the CPU supports.
            unsafe { $kernel(w, x, x_stride, points, bias, requant, max, sum) }
        }
    )*};
}

checked_pool! {
    amx_pool => matmat_packed_pool_i8_amx;
    avx512vnni_pool => matmat_packed_pool_i8_avx512vnni;
    avxvnni_pool => matmat_packed_pool_i8_avxvnni;
    avx2_pool_i8pk => matmat_packed_pool_i8_avx2;
    avx512bw_pool_i8pk => matmat_packed_pool_i8_avx512bw;
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

/// The first `min(t.len(), 16)` i32 of `t`, zeros above.
#[inline]
#[target_feature(enable = "avx512f")]
fn ld512m_i32(t: &[i32]) -> __m512i {
    // SAFETY: the mask selects lanes `0..min(t.len(), 16)`, all inside `t`; others are not read.
    unsafe { _mm512_maskz_loadu_epi32(low_mask(t.len()) as u16, t.as_ptr()) }
}

/// The first `min(t.len(), 8)` i32 of `t`, zeros above (AVX2's `vpmaskmovd`).
#[inline]
#[target_feature(enable = "avx2")]
fn ld256m_i32(t: &[i32]) -> __m256i {
    let n = t.len().min(8) as i32;
    // Lane i is loaded where i < n: its mask's sign bit is set.
    let mask = _mm256_cmpgt_epi32(
        _mm256_set1_epi32(n),
        _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
    );
    // SAFETY: the mask selects lanes `0..min(t.len(), 8)`, all inside `t`; masked-out lanes are
    // neither read nor able to fault.
    unsafe { _mm256_maskload_epi32(t.as_ptr(), mask) }
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

/// Lane-wise addition for [`tree16_512`]: i32 (wrapping) or f32, on the register's bits.
trait Add16 {
    /// `a + b` per 32-bit lane.
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    unsafe fn add(a: __m512i, b: __m512i) -> __m512i;
}

/// i32 lanes, wrapping (the int8 kernels' sums).
struct AddI32;

impl Add16 for AddI32 {
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn add(a: __m512i, b: __m512i) -> __m512i {
        _mm512_add_epi32(a, b)
    }
}

/// f32 lanes (the f32 kernel's partial sums).
struct AddF32;

impl Add16 for AddF32 {
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn add(a: __m512i, b: __m512i) -> __m512i {
        _mm512_castps_si512(_mm512_add_ps(
            _mm512_castsi512_ps(a),
            _mm512_castsi512_ps(b),
        ))
    }
}

/// The lane sums of 16 registers `a[r][q]` in one transposing tree: 128-bit lane `q` of the
/// result is `[Σa[0][q], Σa[1][q], Σa[2][q], Σa[3][q]]`, each sum taken as `sum_lanes` of the
/// f32 reference takes it (lanes `i` and `i + 8`, then `i + 4`, `i + 2`, `i + 1`): 30 shuffles
/// (on bits, the same for either lane type) and 15 adds of `A`.
#[inline]
#[target_feature(enable = "avx512f")]
fn tree16_512<A: Add16>(a: [[__m512i; 4]; 4]) -> __m512i {
    // Lanes `i` and `i + 8`: [a.l0 + a.l2, a.l1 + a.l3, b.l0 + b.l2, b.l1 + b.l3] (128-bit
    // lanes).
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn eighths<A: Add16>(a: __m512i, b: __m512i) -> __m512i {
        let (lo, hi) = (
            _mm512_shuffle_i64x2::<0b01_00_01_00>(a, b),
            _mm512_shuffle_i64x2::<0b11_10_11_10>(a, b),
        );
        // SAFETY: compiled with AVX-512F.
        unsafe { A::add(lo, hi) }
    }
    // Lanes `i` and `i + 4`: from [A0 A1 B0 B1] and [C0 C1 D0 D1], [A0 + A1, B0 + B1, C0 + C1,
    // D0 + D1].
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn fourths<A: Add16>(c: __m512i, d: __m512i) -> __m512i {
        let (even, odd) = (
            _mm512_shuffle_i64x2::<0b10_00_10_00>(c, d),
            _mm512_shuffle_i64x2::<0b11_01_11_01>(c, d),
        );
        // SAFETY: compiled with AVX-512F.
        unsafe { A::add(even, odd) }
    }
    // e[r], 128-bit lane q: the four partial sums of a[r][q] left after two halvings.
    let mut e = [_mm512_setzero_si512(); 4];
    for (e, a) in e.iter_mut().zip(&a) {
        *e = fourths::<A>(eighths::<A>(a[0], a[1]), eighths::<A>(a[2], a[3]));
    }
    // Lanes `i` and `i + 2`, per 128-bit lane: [e0.0 + e0.2, e1.0 + e1.2, e0.1 + e0.3,
    // e1.1 + e1.3], the same for e2 and e3; then lanes `i` and `i + 1`, the first pair of each
    // 128-bit lane of t01 and t23 against the second.
    // SAFETY: compiled with AVX-512F.
    unsafe {
        let t01 = A::add(
            _mm512_unpacklo_epi32(e[0], e[1]),
            _mm512_unpackhi_epi32(e[0], e[1]),
        );
        let t23 = A::add(
            _mm512_unpacklo_epi32(e[2], e[3]),
            _mm512_unpackhi_epi32(e[2], e[3]),
        );
        A::add(
            _mm512_unpacklo_epi64(t01, t23),
            _mm512_unpackhi_epi64(t01, t23),
        )
    }
}

/// `128 · Σ x`, wrapping: the correction for feeding `w + 128` to `vpdpbusd`.
#[inline(always)]
fn vnni_correction(x: &[i8]) -> i32 {
    x.iter()
        .fold(0i32, |s, &v| s.wrapping_add(i32::from(v)))
        .wrapping_mul(128)
}

/// [`vnni_correction`] of `out.len()` points: rows `first..` of `x`, `x_stride` apart, `k`
/// inputs each. Four rows at a time, 32 inputs per step: `Σ x = Σ (x ⊕ 0x80) − 128·n`, the
/// unsigned sums by `vpsadbw`, the four rows' vectors reduced together. Where
/// [`vnni_correction`] (sign-extended to i32 lanes, one reduction per point) took about 45
/// instructions per point at 64 inputs, 17 % of a 64 → 64 layer's kernel time (perf, Zen 5).
#[inline]
#[target_feature(enable = "avx2")]
fn vnni_corrections(x: &[i8], x_stride: usize, first: usize, k: usize, out: &mut [i32]) {
    let (flip, zero) = (_mm256_set1_epi8(i8::MIN), _mm256_setzero_si256());
    // `128 · n` of the vector steps' `n` inputs, wrapping (the truncation is modulo 2^32 too).
    let offset = ((k / 32 * 32) as i32).wrapping_mul(128);
    for (j, out) in out.chunks_mut(4).enumerate() {
        let (mut acc, mut tail) = ([zero; 4], [0i32; 4]);
        for (q, (a, t)) in acc.iter_mut().zip(&mut tail).enumerate().take(out.len()) {
            let row = &x[(first + 4 * j + q) * x_stride..][..k];
            let (steps, rest) = row.as_chunks::<32>();
            for s in steps {
                // Each i64 lane's sum of eight bytes (at most 2,040) sits in its low i32; i32
                // adds keep those sums modulo 2^32 and the high i32 at zero.
                let u = _mm256_xor_si256(ld256_i8(s), flip);
                *a = _mm256_add_epi32(*a, _mm256_sad_epu8(u, zero));
            }
            *t = rest.iter().fold(0i32, |s, &v| s.wrapping_add(i32::from(v)));
        }
        let mut sums = [0i32; 4];
        // SAFETY: `sums` is 16 writable bytes; `storeu` has no alignment requirement.
        unsafe { _mm_storeu_si128(sums.as_mut_ptr().cast(), hsum4_256(acc)) };
        for (o, (&s, &t)) in out.iter_mut().zip(sums.iter().zip(&tail)) {
            *o = s.wrapping_sub(offset).wrapping_add(t).wrapping_mul(128);
        }
    }
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

mod matmat;
mod matvec;

pub use matmat::*;
pub use matvec::*;

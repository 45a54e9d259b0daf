//! Matrix-vector kernels of the engines: `out[o] = bias[o] + Σ_k w[o·K + k] · x[k]`, and the
//! blocked int8 matrix-matrix kernel `out[p·S + o] = bias[o] + Σ_k w[o·K + k] · x[p·K + k]`
//! (several points per pass over the weights, [`Kernels::matmat_i8`]).
//!
//! [`reference`](mod@reference) is the specification: plain scalar loops. Optimized kernels must
//! give the same integers (`==`, no tolerance) and are tested against it
//! (`core/tests/kernels.rs`).
//!
//! # Dispatch
//!
//! As in tract-linalg, the portable table always exists and native kernels override it:
//!
//! - [`Kernels`] is a table for one [`Isa`]: int8 and i16 matvec, int8 matmat, and the
//!   requantization and pooling loops (the f32 and packed kernels are chosen from the ISA at the
//!   call, see below), with [`Kernels::reference`] (the portable fallback), [`Kernels::best`]
//!   (chosen at compile time from `cfg(target_feature)`) and [`Kernels::detect`] (chosen at run
//!   time: `cpuid` on x86_64, no `std` needed). A table can only be built for kernels the CPU
//!   runs, so calling through it is safe.
//! - The free functions [`matvec_i8`], [`matvec_i16`] and [`matmat_i8`] call `Kernels::best()`:
//!   a direct call, no indirection. A default `x86_64` build gets the reference kernels; a
//!   build with `RUSTFLAGS="-C target-cpu=native"` (or `-C target-feature=+avx2,...`) gets the
//!   best kernels that flag promises. Engines that want run-time selection take a `&Kernels`.
//! - [`Isa::ALL`] lists every kernel set, each with [`Isa::is_supported_here`] and
//!   [`Isa::kernels`], so tests and benchmarks run every kernel this CPU has.
//!
//! Kernel sets: [`reference`](mod@reference); on x86_64 (module `x86`) AVX2, AVX-VNNI,
//! AVX-512BW, AVX-512 VNNI and AMX-INT8 (the AVX-512 VNNI set with a tile kernel for the wide
//! packed int8 layers, where the OS grants the tile state); on Cortex-M with the `arm-dsp`
//! feature, [`arm`] (with its FPv5 requantization with `arm-fpv5`, else its FPv4 one on a core
//! with an FPU).
//!
//! # Cortex-M
//!
//! [`arm`] is CMSIS-NN's int8 step: `SXTB16` unpacks two int8 into two halfwords and `SMLAD`
//! does two MACs per instruction. Its instructions are inline assembly, built with the `arm-dsp`
//! cargo feature on `target_arch = "arm"` (stable Rust cannot see the DSP extension in
//! `cfg(target_feature)` and the intrinsics are unstable; thumbv6m/v7m/v8m.base lack the
//! instructions, so a firmware opts in), where [`Kernels::best`] picks it. Elsewhere the same
//! kernel runs on emulated instructions, so its blocking and tails are tested on any host; the
//! real instructions are tested on a Cortex-M7 and a Cortex-M4 under QEMU. The i16 first layer needs nothing:
//! LLVM's ARMParallelDSP pass already turns the reference i16 loop into `SMLAD`.
//!
//! # Contract
//!
//! Every kernel processes exactly the rows the reference does (see [`rows`]): with `K = x.len()`,
//! `min(out.len(), bias.len(), w.len() / K)` rows, leaving the rest of `out` untouched. The
//! dot products are exact modulo 2^32, which is what the reference's wrapping sums give in
//! every build (`wrapping_add`). `K = 0` gives `out[o] = bias[o]`, in the reference too.
//!
//! [`matmat_i8`] is [`reference::matmat_i8`]: the reference matvec once per point, on the
//! `points × rows` rectangle of [`matmat_dims`] (see [`MatmatI8`]). The x86 kernels compute it
//! four output rows by up to four points at a time, so each weight vector loaded is used for
//! several points and a layer's weights are streamed from memory once per block of points (up
//! to [`crate::infer::MAX_BLOCK`]) instead of once per point.
//!
//! # Packed weights
//!
//! Row-major weights cost the x86 kernels a horizontal sum per output. [`packed`] defines a
//! second layout, made once from the blob's rows into a buffer the caller owns, in which the
//! lanes of a register are 16 (or, on 256-bit registers, 8) outputs:
//! [`Kernels::matmat_packed_i8`] over it needs no
//! horizontal sums and reads each point's inputs in place; [`Kernels::matmat_packed_i16`] does
//! the same for the int16 first layer, whose five-input rows cost the row-major kernel more in
//! horizontal sums than in products. Every x86 table (AMX, AVX-512 VNNI, AVX-VNNI, AVX-512BW,
//! AVX2) has native packed kernels ([`Kernels::has_packed`]); every other table runs the packed
//! references, so the packed engine ([`crate::infer::Plan::packed`]) works, and is tested,
//! everywhere.
//!
//! The f32 and packed kernels are not stored in the table: [`Kernels::matvec_f32`],
//! [`Kernels::matmat_f32`] and the packed calls pick them from the table's [`Isa`] where they
//! are called. An image that never runs the f32 engine, or never plans packed weights (an int8
//! firmware), links neither.
//!
//! # Between the kernels
//!
//! The engine's requantization ([`reference::requantize_i8`]) and pooling
//! ([`reference::pool_i8`]) loops are in the table too, and the f32 engine's kernel
//! ([`reference::matvec_f32`], partial sums in a fixed order) is chosen by it: the x86 tables compile the same
//! scalar code with AVX2 or AVX-512 enabled, so the compiler vectorizes it for those registers (a
//! default `x86_64` build would otherwise get 128-bit SSE2 for them). IEEE arithmetic gives the
//! same result in every lane, and the tests compare them with `==` anyway. The f32 engine's
//! point layers that read earlier layers go through [`Kernels::matmat_f32`] instead, a block of
//! points at a time: on x86 register tiles written with intrinsics (several rows and points
//! sharing each load), the same partial sums in the same order, so the same bits.

pub mod arm;
pub mod packed;
pub mod reference;

#[cfg(target_arch = "x86_64")]
pub mod x86;

pub use packed::{MatmatPackedI16, MatmatPackedI8, MatmatPackedPoolI8, PackedI16, PackedI8};
pub use reference::PointRows;

/// The f32 kernel signature: `(w, x, bias, out)`, see [`reference::matvec_f32`].
pub type MatvecF32 = fn(&[f32], &[f32], &[f32], &mut [f32]);

/// The f32 matrix-matrix kernel signature: `(w, bias, rows, at)`, see
/// [`reference::matmat_f32`].
pub type MatmatF32 = fn(&[f32], &[f32], &mut [f32], &PointRows);

/// The int8 kernel signature: `(w, x, bias, out)`.
pub type MatvecI8 = fn(&[i8], &[i8], &[i32], &mut [i32]);

/// The i16 kernel signature: `(w, x, bias, out)`.
pub type MatvecI16 = fn(&[i16], &[i16], &[i32], &mut [i32]);

/// The blocked int8 kernel signature: `(w, k, x, bias, out, out_stride)`, computing
///
/// `out[p·S + o] = bias[o] + Σ_{j<K} w[o·K + j] · x[p·K + j]` for `p < P`, `o < O`
///
/// with `K = k`, `S = out_stride` and `(P, O) =` [`matmat_dims`]: `O` as many rows as
/// [`rows`] gives for a matvec whose `out` is one row of `S` (so `O ≤ S`: rows never overlap),
/// `P` as many points as `x` holds (`x.len() / K`, unbounded for `K = 0`) whose whole row of `O`
/// outputs fits in `out`. Exactly those `P · O` elements of `out` are written, each to the value
/// the reference matvec gives for that point (`bias` when `K = 0`, wrapping modulo 2^32 like
/// the matvec kernels); every other element, the gaps between rows included, is untouched.
/// Nothing panics: `K = 0`, `P = 0`, `O = 0`, `S = 0` and lengths that disagree all follow from
/// the rule above.
pub type MatmatI8 = fn(&[i8], usize, &[i8], &[i32], &mut [i32], usize);

/// The widened int8 block kernel signature: `(ww, w, k, x, bias, out, out_stride)`, see
/// [`arm::matmat_widened_i8`].
pub type MatmatWidenedI8 = fn(&[u32], &[i8], usize, &[i8], &[i32], &mut [i32], usize);

/// The requantization kernel signature: `(acc, scales, leaky, out)`, see
/// [`reference::requantize_i8`].
pub type RequantizeI8 = fn(&[i32], &[f32], Option<f32>, &mut [i8]);

/// The pooling kernel signature: `(max, sum, y)`, see [`reference::pool_i8`].
pub type PoolI8 = fn(&mut [i8], &mut [i32], &[i8]);

/// The rows every kernel computes for `K = x.len()`: those the reference's
/// `out.iter_mut().zip(w.chunks_exact(K)).zip(bias)` visits (for `K = 0`, `min(out, bias)`).
#[inline]
pub const fn rows(k: usize, w_len: usize, bias_len: usize, out_len: usize) -> usize {
    let n = if bias_len < out_len {
        bias_len
    } else {
        out_len
    };
    match w_len.checked_div(k) {
        Some(r) if r < n => r,
        _ => n,
    }
}

/// `(P, O)`, the points and rows a [`MatmatI8`] kernel computes: it writes
/// `out[p·out_stride + o]` for `p < P`, `o < O` and nothing else.
///
/// `O = rows(k, w_len, bias_len, out_stride)`; `P` is the number of points in `x`
/// (`x_len / k`, any number for `k = 0`) limited to those whose row ends inside `out`
/// (`p·out_stride + O ≤ out_len`). `(0, 0)` when either is 0: nothing is written.
#[inline]
pub const fn matmat_dims(
    k: usize,
    w_len: usize,
    x_len: usize,
    bias_len: usize,
    out_len: usize,
    out_stride: usize,
) -> (usize, usize) {
    let o = rows(k, w_len, bias_len, out_stride);
    if o == 0 || out_len < o {
        return (0, 0);
    }
    // o ≥ 1 implies out_stride ≥ 1 (a checked division all the same: no panic path in a
    // firmware image for the compiler's sake).
    let fit = match (out_len - o).checked_div(out_stride) {
        Some(f) => f + 1,
        None => return (0, 0),
    };
    let p = match x_len.checked_div(k) {
        Some(p) if p < fit => p,
        _ => fit,
    };
    (p, if p == 0 { 0 } else { o })
}

/// A family of kernels, named after the instructions it needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Isa {
    /// [`reference`](mod@reference): portable scalar Rust.
    Reference,
    /// x86_64 AVX2: `vpmaddwd` on i16 (int8 sign-extended), 256-bit.
    X86Avx2,
    /// x86_64 AVX-VNNI: `vpdpbusd`/`vpdpwssd`, 256-bit.
    X86AvxVnni,
    /// x86_64 AVX-512BW: `vpmaddwd`, 512-bit.
    X86Avx512Bw,
    /// x86_64 AVX-512 VNNI: `vpdpbusd`/`vpdpwssd`, 512-bit.
    X86Avx512Vnni,
    /// x86_64 Intel AMX-INT8 (`tdpbsud` on tiles) for the packed int8 layers whose `K` is a
    /// multiple of 64 and at least `x86::AMX_MIN_K` (128), and AVX-512 VNNI for everything
    /// else; needs the OS's permission for the tile state, which [`Kernels::detect`] asks for on
    /// Linux.
    X86Amx,
    /// Arm Cortex-M with the DSP extension: `SXTB16` + `SMLAD` ([`arm`]); built with the
    /// `arm-dsp` feature on `target_arch = "arm"` only.
    ArmDsp,
}

impl Isa {
    /// Every kernel family, on every target.
    pub const ALL: [Isa; 7] = [
        Isa::Reference,
        Isa::X86Avx2,
        Isa::X86AvxVnni,
        Isa::X86Avx512Bw,
        Isa::X86Avx512Vnni,
        Isa::X86Amx,
        Isa::ArmDsp,
    ];

    /// A short name: `reference`, `avx2`, `avxvnni`, `avx512bw`, `avx512vnni`, `amx`,
    /// `armdsp`.
    pub const fn name(self) -> &'static str {
        match self {
            Isa::Reference => "reference",
            Isa::X86Avx2 => "avx2",
            Isa::X86AvxVnni => "avxvnni",
            Isa::X86Avx512Bw => "avx512bw",
            Isa::X86Avx512Vnni => "avx512vnni",
            Isa::X86Amx => "amx",
            Isa::ArmDsp => "armdsp",
        }
    }

    /// Whether this build has the kernels and this CPU runs them (x86_64: asks `cpuid`).
    pub fn is_supported_here(self) -> bool {
        self.kernels().is_some()
    }

    /// The kernels, if this build has them and this CPU runs them.
    pub fn kernels(self) -> Option<Kernels> {
        match self {
            Isa::Reference => Some(Kernels::reference()),
            #[cfg(target_arch = "x86_64")]
            Isa::X86Avx2
            | Isa::X86AvxVnni
            | Isa::X86Avx512Bw
            | Isa::X86Avx512Vnni
            | Isa::X86Amx => x86::kernels(self, x86::Features::detect()),
            #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
            Isa::ArmDsp => Some(arm::kernels()),
            #[allow(unreachable_patterns)]
            _ => None,
        }
    }
}

/// The x86 kernel sets, fastest first (measured with `benches/kernels.rs`), for
/// [`Kernels::best`] and [`Kernels::detect`].
#[cfg(target_arch = "x86_64")]
const X86_FASTEST_FIRST: [Isa; 5] = [
    Isa::X86Amx,
    Isa::X86Avx512Vnni,
    Isa::X86Avx512Bw,
    Isa::X86AvxVnni,
    Isa::X86Avx2,
];

/// One int8 and one i16 matrix-vector kernel, one int8 matrix-matrix kernel, and the
/// requantization and pooling loops, every one bit-exact with [`reference`](mod@reference); the
/// packed kernels where the ISA has them and the f32 matrix-vector kernel are chosen from the
/// table's [`Isa`] when called (so an image links only those it calls).
///
/// Only kernels the CPU runs can be put in a table, and a table's ISA is one the CPU runs (the
/// fields are private; the constructors check), so the calls are safe. Pick once, keep the
/// table:
///
/// ```
/// use evpose_core::kernels::Kernels;
///
/// let k = Kernels::detect(); // e.g. "avx512vnni" on a Zen 4
/// let (w, x, bias) = ([1i8, 2, 3, 4, 5, 6], [1i8, -1, 2], [10, 20]);
/// let mut out = [0; 2];
/// k.matvec_i8(&w, &x, &bias, &mut out);
/// assert_eq!(out, [10 + 1 - 2 + 6, 20 + 4 - 5 + 12]);
///
/// // Two points (rows of x, K = 3) through the same weights, output rows 4 apart.
/// let x2 = [1i8, -1, 2, 0, 0, 1];
/// let mut out2 = [-1; 6];
/// k.matmat_i8(&w, 3, &x2, &bias, &mut out2, 4);
/// assert_eq!(out2, [10 + 1 - 2 + 6, 20 + 4 - 5 + 12, -1, -1, 10 + 3, 20 + 6]);
/// println!("{}", k.name());
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Kernels {
    isa: Isa,
    i8: MatvecI8,
    i16: MatvecI16,
    i8mm: MatmatI8,
    requant: RequantizeI8,
    pool: PoolI8,
}

impl Kernels {
    /// The portable [`reference`](mod@reference) kernels (with `K = 0` giving `out = bias`,
    /// not a panic).
    pub const fn reference() -> Self {
        Self {
            isa: Isa::Reference,
            i8: reference::matvec_i8,
            i16: reference::matvec_i16,
            i8mm: reference::matmat_i8,
            requant: reference_requantize,
            pool: reference_pool,
        }
    }

    /// The best kernels this build may use on any CPU it runs on, chosen from
    /// `cfg(target_feature)` (so by `-C target-cpu`/`-C target-feature`) and, on Arm, the
    /// `arm-dsp` feature; what [`matvec_i8`], [`matvec_i16`] and [`matmat_i8`] call. What a
    /// firmware wants; on a host built for plain x86-64 this is the scalar reference (the
    /// build guarantees no SIMD extension): a host asks the CPU with [`Kernels::detect`].
    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    pub const fn best() -> Self {
        arm::kernels()
    }

    /// The best kernels this build may use on any CPU it runs on, chosen from
    /// `cfg(target_feature)` (so by `-C target-cpu`/`-C target-feature`) and, on Arm, the
    /// `arm-dsp` feature; what [`matvec_i8`], [`matvec_i16`] and [`matmat_i8`] call. What a
    /// firmware wants; on a host built for plain x86-64 this is the scalar reference (the
    /// build guarantees no SIMD extension): a host asks the CPU with [`Kernels::detect`].
    #[cfg(not(all(target_arch = "arm", feature = "arm-dsp")))]
    pub const fn best() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let f = x86::Features::compile_time();
            let order = X86_FASTEST_FIRST;
            let mut i = 0;
            while i < order.len() {
                if let Some(k) = x86::kernels(order[i], f) {
                    return k;
                }
                i += 1;
            }
        }
        Self::reference()
    }

    /// The best kernels this CPU runs, asked at run time (`cpuid` on x86_64; elsewhere the same
    /// as [`Kernels::best`]). Costs a few hundred cycles: call it once.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let f = x86::Features::detect();
            for isa in X86_FASTEST_FIRST {
                if let Some(k) = x86::kernels(isa, f) {
                    return k;
                }
            }
        }
        Self::best()
    }

    /// The kernel family.
    pub const fn isa(&self) -> Isa {
        self.isa
    }

    /// The kernel family's name.
    pub const fn name(&self) -> &'static str {
        self.isa.name()
    }

    /// [`reference::matvec_i8`], bit-exact, with this table's kernel.
    #[inline]
    pub fn matvec_i8(&self, w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
        (self.i8)(w, x, bias, out)
    }

    /// [`reference::matvec_i16`], bit-exact, with this table's kernel.
    #[inline]
    pub fn matvec_i16(&self, w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
        (self.i16)(w, x, bias, out)
    }

    /// [`reference::matmat_i8`], bit-exact, with this table's kernel: the `x.len() / k` points
    /// (rows of `x`, `k` long) through the weights `w` (rows of `k`), point `p`'s outputs at
    /// `out[p·out_stride..][..O]`; see [`MatmatI8`] and [`matmat_dims`] for what is written.
    #[inline]
    pub fn matmat_i8(
        &self,
        w: &[i8],
        k: usize,
        x: &[i8],
        bias: &[i32],
        out: &mut [i32],
        out_stride: usize,
    ) {
        (self.i8mm)(w, k, x, bias, out, out_stride)
    }

    /// [`reference::requantize_i8`], bit-exact for finite scales (what
    /// [`Model::parse`](crate::model::Model::parse) accepts), compiled for this table's
    /// registers. With a NaN product (a NaN scale, or an infinite one times 0) the Cortex-M
    /// tables with an FPU (`arm-fpv5`, or an `eabihf` target) give 0 where the reference gives
    /// -128.
    #[inline]
    pub fn requantize_i8(&self, acc: &[i32], scales: &[f32], leaky: Option<f32>, out: &mut [i8]) {
        (self.requant)(acc, scales, leaky, out)
    }

    /// [`Kernels::requantize_i8`] with one layer's [`Requant`](crate::quant::Requant).
    #[inline]
    pub fn requantize(&self, acc: &[i32], r: crate::quant::Requant<'_>, out: &mut [i8]) {
        self.requantize_i8(acc, r.scales, r.leaky, out)
    }

    /// [`reference::pool_i8`], bit-exact, compiled for this table's registers.
    #[inline]
    pub fn pool_i8(&self, max: &mut [i8], sum: &mut [i32], y: &[i8]) {
        (self.pool)(max, sum, y)
    }

    /// [`reference::matvec_f32`], bit-exact, compiled for this table's registers (the f32
    /// engine's kernel).
    #[inline]
    pub fn matvec_f32(&self, w: &[f32], x: &[f32], bias: &[f32], out: &mut [f32]) {
        // Chosen here from the ISA, not stored in the table: an image that never runs the f32
        // engine (an int8 firmware) then links no f32 kernel.
        #[cfg(target_arch = "x86_64")]
        if let Some(f) = x86::f32_kernel(self) {
            return f(w, x, bias, out);
        }
        reference::matvec_f32(w, x, bias, out)
    }

    /// [`reference::matmat_f32`], bit-exact (so [`Kernels::matvec_f32`] for each point): the
    /// f32 engine's point layers, a block of points at a time. The x86 tables run register
    /// tiles (four rows by four points on AVX-512, `x86::matmat_f32_avx512`; one row by four
    /// points on AVX2, `x86::matmat_f32_avx2`); the others run [`Kernels::matvec_f32`] point
    /// by point.
    #[inline]
    pub fn matmat_f32(&self, w: &[f32], bias: &[f32], rows: &mut [f32], at: &PointRows) {
        #[cfg(target_arch = "x86_64")]
        if let Some(f) = x86::f32_matmat_kernel(self) {
            return f(w, bias, rows, at);
        }
        reference::matmat_f32_by(|w, x, b, y| self.matvec_f32(w, x, b, y), w, bias, rows, at)
    }

    /// Whether this table has native kernels for [packed](mod@packed) weights, int8 and int16
    /// (else [`Kernels::matmat_packed_i8`] and [`Kernels::matmat_packed_i16`] run the
    /// reference, and the row-major kernels are the faster choice).
    pub fn has_packed(&self) -> bool {
        #[cfg(target_arch = "x86_64")]
        if x86::packed_kernels(self).is_some() {
            return true;
        }
        false
    }

    /// The native packed kernels of this table's ISA. Chosen from the ISA at the call, not
    /// stored in the table, so that only an image that runs packed weights links them.
    fn packed_kernels(&self) -> Option<(MatmatPackedI8, MatmatPackedI16)> {
        #[cfg(target_arch = "x86_64")]
        if let Some(k) = x86::packed_kernels(self) {
            return Some(k);
        }
        None
    }

    /// [`packed::matmat_packed_i8`], bit-exact, with this table's packed kernel (the reference
    /// where it has none): the points `x[p·x_stride..][..K]` for `p < points` through the packed
    /// weights `w`, point `p`'s outputs at `out[p·out_stride..][..O]`; see [`MatmatPackedI8`]
    /// and [`packed::packed_dims`] for what is written.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn matmat_packed_i8(
        &self,
        w: &PackedI8<'_>,
        x: &[i8],
        x_stride: usize,
        points: usize,
        bias: &[i32],
        out: &mut [i32],
        out_stride: usize,
    ) {
        let kernel = self
            .packed_kernels()
            .map_or(packed::matmat_packed_i8 as MatmatPackedI8, |k| k.0);
        kernel(w, x, x_stride, points, bias, out, out_stride)
    }

    /// This table's native kernel that runs the packed int8 layer `w` straight into pooling
    /// ([`MatmatPackedPoolI8`], bit-exact with [`packed::matmat_packed_pool_i8`]), if it has
    /// one for `w`'s shape: the VNNI tables' (AVX-512 VNNI, AVX-VNNI) for every shape, the AMX
    /// table's on tiles where `K` is a multiple of 64 from `x86::AMX_MIN_K` and AVX-512 VNNI's
    /// otherwise, the AVX2 and AVX-512BW tables' for `K` up to 512 (one chunk of widened
    /// inputs, `x86::widened_pool_takes`). The engine runs its last point layer with it where
    /// there is one, and otherwise requantizes and pools [`Kernels::matmat_packed_i8`]'s int32
    /// rows.
    pub fn packed_pool_i8(&self, w: &PackedI8<'_>) -> Option<MatmatPackedPoolI8> {
        #[cfg(target_arch = "x86_64")]
        if let Some(k) = x86::packed_pool_kernel(self, w) {
            return Some(k);
        }
        let _ = w;
        None
    }

    /// [`packed::matmat_packed_i16`], bit-exact, with this table's packed kernel (the reference
    /// where it has none): [`Kernels::matmat_packed_i8`] for int16 weights and inputs (the
    /// engine's first layer).
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn matmat_packed_i16(
        &self,
        w: &PackedI16<'_>,
        x: &[i16],
        x_stride: usize,
        points: usize,
        bias: &[i32],
        out: &mut [i32],
        out_stride: usize,
    ) {
        let kernel = self
            .packed_kernels()
            .map_or(packed::matmat_packed_i16 as MatmatPackedI16, |k| k.1);
        kernel(w, x, x_stride, points, bias, out, out_stride)
    }
}

/// [`reference::requantize_i8`] as a function (the reference is `inline(always)`, for the
/// x86 tables to compile it for their registers).
fn reference_requantize(acc: &[i32], scales: &[f32], leaky: Option<f32>, out: &mut [i8]) {
    reference::requantize_i8(acc, scales, leaky, out)
}

/// [`reference::pool_i8`] as a function.
fn reference_pool(max: &mut [i8], sum: &mut [i32], y: &[i8]) {
    reference::pool_i8(max, sum, y)
}

/// Runs `iters` rounds of a loop of independent multiply-accumulate instructions of `isa`'s
/// widest int8 step and returns the MACs it did; timing it gives this CPU's one-thread int8
/// peak for that family (what benchmarks report a fraction of). `None` for the reference, for a
/// family the CPU lacks, and on other architectures.
pub fn peak_loop(isa: Isa, iters: u64) -> Option<u64> {
    #[cfg(target_arch = "x86_64")]
    {
        x86::peak_loop(isa, iters)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (isa, iters);
        None
    }
}

/// The kernels [`matvec_i8`], [`matvec_i16`] and [`matmat_i8`] use.
const BEST: Kernels = Kernels::best();

/// [`reference::matvec_f32`], bit-exact, with the compile-time best kernel ([`Kernels::best`]).
#[inline]
pub fn matvec_f32(w: &[f32], x: &[f32], bias: &[f32], out: &mut [f32]) {
    BEST.matvec_f32(w, x, bias, out)
}

/// [`reference::matvec_i8`], bit-exact, with the compile-time best kernel ([`Kernels::best`]).
#[inline]
pub fn matvec_i8(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    BEST.matvec_i8(w, x, bias, out)
}

/// [`reference::matvec_i16`], bit-exact, with the compile-time best kernel ([`Kernels::best`]).
#[inline]
pub fn matvec_i16(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    BEST.matvec_i16(w, x, bias, out)
}

/// [`reference::matmat_i8`], bit-exact, with the compile-time best kernel ([`Kernels::best`]).
#[inline]
pub fn matmat_i8(w: &[i8], k: usize, x: &[i8], bias: &[i32], out: &mut [i32], out_stride: usize) {
    BEST.matmat_i8(w, k, x, bias, out, out_stride)
}

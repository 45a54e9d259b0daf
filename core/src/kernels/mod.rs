//! Matrix-vector kernels of the engines: `out[o] = bias[o] + Σ_k w[o·K + k] · x[k]`.
//!
//! [`reference`](mod@reference) is the specification: plain scalar loops. Optimized kernels must
//! give the same integers (`==`, no tolerance) and are tested against it
//! (`core/tests/kernels.rs`).
//!
//! # Dispatch
//!
//! As in tract-linalg, the portable table always exists and native kernels override it:
//!
//! - [`Kernels`] is a table of one int8 and one i16 kernel for one [`Isa`], with
//!   [`Kernels::reference`] (the portable fallback), [`Kernels::best`] (chosen at compile time
//!   from `cfg(target_feature)`) and [`Kernels::detect`] (chosen at run time: `cpuid` on x86_64,
//!   no `std` needed). A table can only be built for kernels the CPU runs, so calling through it
//!   is safe.
//! - The free functions [`matvec_i8`] and [`matvec_i16`] call `Kernels::best()`: a direct call,
//!   no indirection. A default `x86_64` build gets the reference kernels; a build with
//!   `RUSTFLAGS="-C target-cpu=native"` (or `-C target-feature=+avx2,...`) gets the best
//!   kernels that flag promises. Engines that want run-time selection take a `&Kernels`.
//! - [`Isa::ALL`] lists every kernel set, each with [`Isa::is_supported_here`] and
//!   [`Isa::kernels`], so tests and benchmarks run every kernel this CPU has.
//!
//! Kernel sets: [`reference`](mod@reference); on x86_64 (module `x86`) AVX2, AVX-VNNI,
//! AVX-512BW and AVX-512 VNNI.
//!
//! # Cortex-M
//!
//! No Arm kernel yet; the reference is what the firmware runs. On `thumbv7em-none-eabihf`
//! LLVM's ARMParallelDSP pass already turns the reference i16 loop into `SMLAD` (two 16-bit
//! MACs per instruction). The int8 loop becomes `LDRSB`, `LDRSB`, `SMLABB` per MAC: `SMLAD`
//! for int8 needs `SXTB16`, which plain Rust does not produce and whose intrinsics
//! (`core::arch::arm::__sxtb16`, `__smlad`) are unstable; inline `asm!` would do, but stable
//! Rust cannot see the DSP extension in `cfg(target_feature)`, so such a kernel needs an opt-in
//! cargo feature (thumbv6m/v7m/v8m.base lack the instructions). Plain-Rust word loads with
//! shifts cost more instructions than the reference (14 against 12 per four MACs).
//!
//! # Contract
//!
//! Every kernel processes exactly the rows the reference does (see [`rows`]): with `K = x.len()`,
//! `min(out.len(), bias.len(), w.len() / K)` rows, leaving the rest of `out` untouched. The
//! dot products are exact modulo 2^32, which is what the reference's `+` gives in a release
//! build (a debug build panics on overflow instead). `K = 0` gives `out[o] = bias[o]`
//! (the reference itself panics there: `chunks_exact(0)`).

pub mod reference;

#[cfg(target_arch = "x86_64")]
pub mod x86;

pub use reference::matvec_f32;

/// The int8 kernel signature: `(w, x, bias, out)`.
pub type MatvecI8 = fn(&[i8], &[i8], &[i32], &mut [i32]);

/// The i16 kernel signature: `(w, x, bias, out)`.
pub type MatvecI16 = fn(&[i16], &[i16], &[i32], &mut [i32]);

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
}

impl Isa {
    /// Every kernel family, on every target.
    pub const ALL: [Isa; 5] = [
        Isa::Reference,
        Isa::X86Avx2,
        Isa::X86AvxVnni,
        Isa::X86Avx512Bw,
        Isa::X86Avx512Vnni,
    ];

    /// A short name: `reference`, `avx2`, `avxvnni`, `avx512bw`, `avx512vnni`.
    pub const fn name(self) -> &'static str {
        match self {
            Isa::Reference => "reference",
            Isa::X86Avx2 => "avx2",
            Isa::X86AvxVnni => "avxvnni",
            Isa::X86Avx512Bw => "avx512bw",
            Isa::X86Avx512Vnni => "avx512vnni",
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
            Isa::X86Avx2 | Isa::X86AvxVnni | Isa::X86Avx512Bw | Isa::X86Avx512Vnni => {
                x86::kernels(self, x86::Features::detect())
            }
            #[allow(unreachable_patterns)]
            _ => None,
        }
    }
}

/// One int8 and one i16 matrix-vector kernel, every one bit-exact with
/// [`reference`](mod@reference).
///
/// Only kernels the CPU runs can be put in a table (the fields are private), so the calls are
/// safe. Pick once, keep the table:
///
/// ```
/// use evpose_core::kernels::Kernels;
///
/// let k = Kernels::detect(); // e.g. "avx512vnni" on a Zen 4
/// let (w, x, bias) = ([1i8, 2, 3, 4, 5, 6], [1i8, -1, 2], [10, 20]);
/// let mut out = [0; 2];
/// k.matvec_i8(&w, &x, &bias, &mut out);
/// assert_eq!(out, [10 + 1 - 2 + 6, 20 + 4 - 5 + 12]);
/// println!("{}", k.name());
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Kernels {
    isa: Isa,
    i8: MatvecI8,
    i16: MatvecI16,
}

impl Kernels {
    /// The portable [`reference`](mod@reference) kernels (with `K = 0` giving `out = bias`,
    /// not a panic).
    pub const fn reference() -> Self {
        Self {
            isa: Isa::Reference,
            i8: reference_i8,
            i16: reference_i16,
        }
    }

    /// The best kernels this build may use on any CPU it runs on, chosen from
    /// `cfg(target_feature)` (so by `-C target-cpu`/`-C target-feature`); what [`matvec_i8`]
    /// and [`matvec_i16`] call.
    pub const fn best() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let f = x86::Features::compile_time();
            // Fastest first (measured on Zen 4, `benches/kernels.rs`).
            let order = [
                Isa::X86Avx512Vnni,
                Isa::X86Avx512Bw,
                Isa::X86AvxVnni,
                Isa::X86Avx2,
            ];
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
            for isa in [
                Isa::X86Avx512Vnni,
                Isa::X86Avx512Bw,
                Isa::X86AvxVnni,
                Isa::X86Avx2,
            ] {
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
}

/// [`reference::matvec_i8`], with `K = 0` defined as `out[o] = bias[o]` (the reference panics).
fn reference_i8(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    if x.is_empty() {
        let n = rows(0, w.len(), bias.len(), out.len());
        out[..n].copy_from_slice(&bias[..n]);
    } else {
        reference::matvec_i8(w, x, bias, out);
    }
}

/// [`reference::matvec_i16`], with `K = 0` defined as `out[o] = bias[o]` (the reference panics).
fn reference_i16(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    if x.is_empty() {
        let n = rows(0, w.len(), bias.len(), out.len());
        out[..n].copy_from_slice(&bias[..n]);
    } else {
        reference::matvec_i16(w, x, bias, out);
    }
}

/// The kernels [`matvec_i8`] and [`matvec_i16`] use.
const BEST: Kernels = Kernels::best();

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

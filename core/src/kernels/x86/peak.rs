//! The CPU's int8 multiply-accumulate peak for one thread, measured rather than looked up:
//! a loop of independent multiply-accumulate instructions of one kernel family, nothing else.
//! Benchmarks divide a kernel's MACs per second by this loop's to report a fraction of peak.

use core::arch::x86_64::*;
use core::hint::black_box;

use super::Features;
use crate::kernels::Isa;

/// Independent accumulators: more than latency × throughput of every instruction used (e.g.
/// `vpdpbusd`: 5 cycles × 2 per cycle on Zen 5), so the loop is throughput-bound.
const CHAINS: usize = 12;

/// Runs `iters` rounds of 12 (`CHAINS`) independent multiply-accumulate instructions of `isa`'s
/// widest int8 step and returns the MACs done (`iters × CHAINS × MACs per instruction`); time
/// it to get the peak. `None` for the reference, a family this CPU lacks, or a MAC count past
/// `u64` (checked before running).
///
/// | family | instruction | MACs |
/// |---|---|---|
/// | `avx512vnni` | `vpdpbusd` zmm | 64 |
/// | `avxvnni` | `vpdpbusd` ymm | 32 |
/// | `avx512bw` | `vpmaddwd` + `vpaddd` zmm (int8 widened to i16) | 32 |
/// | `avx2` | `vpmaddwd` + `vpaddd` ymm | 16 |
///
/// `amx` runs rounds of six independent `tdpbssd` (16 × 16 × 64 = 16,384 MACs each) instead.
pub fn peak_loop(isa: Isa, iters: u64) -> Option<u64> {
    if isa == Isa::X86Amx {
        let macs = iters.checked_mul(6 * super::amx::TILE_MACS)?;
        if !Features::detect().supports(isa) {
            return None;
        }
        // SAFETY: `detect` just confirmed AMX-INT8 and the tile-data permission.
        unsafe { super::amx::peak(iters) };
        return Some(macs);
    }
    let per_instruction = match isa {
        Isa::X86Avx512Vnni => 64,
        Isa::X86AvxVnni | Isa::X86Avx512Bw => 32,
        Isa::X86Avx2 => 16,
        _ => return None,
    };
    let macs = iters.checked_mul(CHAINS as u64 * per_instruction)?;
    if !Features::detect().supports(isa) {
        return None;
    }
    // SAFETY: `detect` just confirmed the CPU has the features each function enables.
    let sink = unsafe {
        match isa {
            Isa::X86Avx512Vnni => vnni512(iters),
            Isa::X86AvxVnni => vnni256(iters),
            Isa::X86Avx512Bw => madd512(iters),
            _ => madd256(iters),
        }
    };
    black_box(sink);
    Some(macs)
}

/// One loop per instruction, sums reduced to one lane so nothing is dead code. The
/// `vpmaddwd` loops multiply the accumulator itself, or the compiler would hoist the product of
/// two loop-invariant registers out of the loop.
macro_rules! peak_fn {
    ($name:ident, $features:literal, $t:ty, $set1:ident, $zero:ident, $step:expr, $fold:expr) => {
        #[target_feature(enable = $features)]
        unsafe fn $name(iters: u64) -> i32 {
            let (a, b) = ($set1(black_box(0x0101_0101)), $set1(black_box(0x0102_0304)));
            let mut acc: [$t; CHAINS] = [$zero(); CHAINS];
            for _ in 0..iters {
                for r in &mut acc {
                    *r = $step(*r, a, b);
                }
            }
            acc.iter().fold(0, |s, &v| s ^ $fold(v))
        }
    };
}

peak_fn!(
    vnni512,
    "avx512f,avx512vnni",
    __m512i,
    _mm512_set1_epi32,
    _mm512_setzero_si512,
    |r, a, b| _mm512_dpbusd_epi32(r, a, b),
    |v| _mm512_reduce_add_epi32(v)
);
peak_fn!(
    vnni256,
    "avx2,avxvnni",
    __m256i,
    _mm256_set1_epi32,
    _mm256_setzero_si256,
    |r, a, b| _mm256_dpbusd_avx_epi32(r, a, b),
    |v| _mm256_extract_epi32::<0>(v)
);
peak_fn!(
    madd512,
    "avx512f,avx512bw",
    __m512i,
    _mm512_set1_epi32,
    _mm512_setzero_si512,
    |r, _a, b| _mm512_add_epi32(r, _mm512_madd_epi16(r, b)),
    |v| _mm512_reduce_add_epi32(v)
);
peak_fn!(
    madd256,
    "avx2",
    __m256i,
    _mm256_set1_epi32,
    _mm256_setzero_si256,
    |r, _a, b| _mm256_add_epi32(r, _mm256_madd_epi16(r, b)),
    |v| _mm256_extract_epi32::<0>(v)
);

//! The Cortex-M int8 kernels with the DSP extension (Armv7E-M, Armv8-M Mainline with DSP):
//! `SXTB16` unpacks two int8 into two i16 halfwords, `SMLAD` multiplies two pairs of halfwords
//! and adds both products to an accumulator, two MACs per instruction.
//!
//! - [`matvec_i8`] is CMSIS-NN's fully-connected inner step (`arm_nn_vec_mat_mult_t_s8`): per
//!   four inputs of two rows, one word of `x` unpacked once (`SXTB16` and `SXTB16` of the word
//!   rotated by 8: bytes 0, 2 and 1, 3), one word of each row unpacked the same way, and four
//!   `SMLAD`.
//! - [`matmat_i8`] computes [`BLOCK_POINTS`] points per weight load (CMSIS-NN's 1×1
//!   convolution does two): the block's inputs are unpacked once, and all rows run over them
//!   in one inline-assembly loop (`LDR`, two `SXTB16`, four `LDRD`, eight `SMLAD` per 16 MACs).
//! - [`matmat_widened_i8`] does the same over weights [`widen_i8`] unpacked once at start-up
//!   (`LDRD` of two halfword-pair words instead of `LDR` and two `SXTB16`: 13 instructions per
//!   16 MACs), for twice the int8 weights' memory.
//! - [`pool_i8`] takes the maxima of four channels at once with `SSUB8` and `SEL`.
//! - [`matvec_i16`] runs `SMLAD` on the stored i16 weights and inputs (the 15-bit SimDR heads
//!   and the first layer), two rows at a time: an inline-assembly `LDRD` loop for word-aligned
//!   operands with `K` a multiple of four (the heads), else [`matvec_i8`]'s loop in Rust.
//! - [`requantize_i8`] does four outputs per pass: with the feature `arm-fpv5` (the Cortex-M7's
//!   double-precision FPv5 FPU) `VMAXNM` for the LeakyReLU and `VCVTN` for the rounding, on
//!   other cores with an FPU (`eabihf`: the M4's FPv4) a compare, a conditional `VMUL` and
//!   `VCVTR`.
//!
//! The instructions are inline assembly on `target_arch = "arm"` with the `arm-dsp`
//! cargo feature: stable Rust cannot see the DSP extension in `cfg(target_feature)`, and the
//! `core::arch::arm` intrinsics for it are unstable, so a firmware whose core has the extension
//! opts in (thumbv6m, thumbv7m and thumbv8m.base lack it). Everywhere else they are emulated in
//! Rust, bit for bit as the Armv7-M manual defines them, so the kernel's blocking, tails and
//! wrapping are tested on any host against the reference (`core/tests/kernels.rs`) and the
//! instructions themselves on a Cortex-M7 and a Cortex-M4 under QEMU (the firmware's boot self-test, asserted
//! by `tests/firmware_qemu.rs`).
//!
//! `SMLAD` adds exactly (the Q flag it may set does not change the result), so the sums wrap
//! modulo 2^32 like the reference's; the products of sign-extended bytes are at most 2^14.
#![allow(unsafe_code)]

use core::mem::MaybeUninit;

use super::rows;

/// Both halfwords of the word, sign-extended from bytes 0 and 2 of `x` (`SXTB16 r, x`).
#[inline(always)]
fn sxtb16(x: u32) -> u32 {
    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    {
        let r: u32;
        // SAFETY: SXTB16 reads and writes only the named registers, touches no memory and no
        // flags. It exists on cores with the DSP extension, which the `arm-dsp` feature
        // promises; on a target without it (thumbv6m, thumbv7m, thumbv8m.base) LLVM refuses
        // to assemble the instruction, so a wrong promise fails the build, not the run.
        unsafe {
            core::arch::asm!("sxtb16 {r}, {x}", r = lateout(reg) r, x = in(reg) x,
                options(pure, nomem, nostack, preserves_flags));
        }
        r
    }
    #[cfg(not(all(target_arch = "arm", feature = "arm-dsp")))]
    {
        let lo = x as u8 as i8 as i16 as u16;
        let hi = (x >> 16) as u8 as i8 as i16 as u16;
        u32::from(lo) | u32::from(hi) << 16
    }
}

/// The same for bytes 1 and 3 (`SXTB16 r, x, ROR #8`).
#[inline(always)]
fn sxtb16_ror8(x: u32) -> u32 {
    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    {
        let r: u32;
        // SAFETY: as in `sxtb16`.
        unsafe {
            core::arch::asm!("sxtb16 {r}, {x}, ror #8", r = lateout(reg) r, x = in(reg) x,
                options(pure, nomem, nostack, preserves_flags));
        }
        r
    }
    #[cfg(not(all(target_arch = "arm", feature = "arm-dsp")))]
    {
        sxtb16(x.rotate_right(8))
    }
}

/// `acc + a.lo · b.lo + a.hi · b.hi` on signed halfwords, wrapping (`SMLAD r, a, b, acc`).
#[inline(always)]
fn smlad(a: u32, b: u32, acc: i32) -> i32 {
    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    {
        let r: i32;
        // SAFETY: SMLAD reads and writes only the named registers and touches no memory; it may
        // set the Q flag (so no `preserves_flags`), which nothing here reads.
        unsafe {
            core::arch::asm!("smlad {r}, {a}, {b}, {acc}", r = lateout(reg) r, a = in(reg) a,
                b = in(reg) b, acc = in(reg) acc, options(pure, nomem, nostack));
        }
        r
    }
    #[cfg(not(all(target_arch = "arm", feature = "arm-dsp")))]
    {
        let half = |v: u32, s: u32| i32::from((v >> s) as u16 as i16);
        acc.wrapping_add(half(a, 0) * half(b, 0))
            .wrapping_add(half(a, 16) * half(b, 16))
    }
}

/// Four bytes as one little-endian word (one `LDR`; Cortex-M7 and M4 load unaligned words).
#[inline(always)]
fn word(b: &[i8; 4]) -> u32 {
    u32::from_le_bytes(b.map(|v| v as u8))
}

/// `acc + Σ w·x` over one step of four inputs, `x` already unpacked.
#[inline(always)]
fn step(acc: i32, w: &[i8; 4], (x02, x13): (u32, u32)) -> i32 {
    let w = word(w);
    smlad(sxtb16_ror8(w), x13, smlad(sxtb16(w), x02, acc))
}

/// `Σ w·x` over the inputs past the last whole step, wrapping.
#[inline(always)]
fn tail<T: Copy>(acc: i32, w: &[T], x: &[T]) -> i32
where
    i32: From<T>,
{
    w.iter().zip(x).fold(acc, |a, (&w, &x)| {
        a.wrapping_add(i32::from(w).wrapping_mul(i32::from(x)))
    })
}

/// `w[start..]`, empty when `start` is past its end.
#[inline(always)]
fn past<T>(w: &[T], start: usize) -> &[T] {
    w.get(start..).unwrap_or_default()
}

/// The matvec loop both DSP matvec kernels share: two rows at a time, so that each step of `S`
/// inputs of `x` is unpacked once (`unpack`) for both; `step(acc, w, u)` adds one step of a
/// row; an odd last row runs alone, and the inputs past the last whole step go through
/// [`tail`]. `K = 0` gives `out = bias`.
#[inline(always)]
fn matvec_two_rows<T: Copy, U: Copy, const S: usize>(
    w: &[T],
    x: &[T],
    bias: &[i32],
    out: &mut [i32],
    unpack: impl Fn(&[T; S]) -> U,
    step: impl Fn(i32, &[T; S], U) -> i32,
) where
    i32: From<T>,
{
    let k = x.len();
    let n = rows(k, w.len(), bias.len(), out.len());
    // Slices are cut with the checked methods (all in range by `rows`), so that a firmware
    // links no panic path here.
    let (Some(out), Some(bias)) = (out.get_mut(..n), bias.get(..n)) else {
        return;
    };
    if k == 0 {
        for (y, &b) in out.iter_mut().zip(bias) {
            *y = b;
        }
        return;
    }
    let (Some((pairs, last)), Some((outs, out_last)), Some(k2)) = (
        w.get(..n * k)
            .and_then(|w| w.split_at_checked(n / 2 * 2 * k)),
        out.split_at_mut_checked(n / 2 * 2),
        k.checked_mul(2).filter(|&v| v > 0),
    ) else {
        return;
    };
    let (xs, xt) = x.as_chunks::<S>();
    let full = xs.len() * S;
    let rest = |w| past(w, full);
    for ((ws, y), b) in pairs
        .chunks_exact(k2)
        .zip(outs.as_chunks_mut::<2>().0)
        .zip(bias.as_chunks::<2>().0)
    {
        let Some((w0, w1)) = ws.split_at_checked(k) else {
            return;
        };
        let (mut a0, mut a1) = (b[0], b[1]);
        for ((xv, w0v), w1v) in xs.iter().zip(w0.as_chunks().0).zip(w1.as_chunks().0) {
            let xu = unpack(xv);
            a0 = step(a0, w0v, xu);
            a1 = step(a1, w1v, xu);
        }
        *y = [tail(a0, rest(w0), xt), tail(a1, rest(w1), xt)];
    }
    if let ([y], Some(&b)) = (out_last, bias.last()) {
        // An odd row count: the last row alone.
        let acc = xs
            .iter()
            .zip(last.as_chunks().0)
            .fold(b, |a, (xv, wv)| step(a, wv, unpack(xv)));
        *y = tail(acc, rest(last), xt);
    }
}

/// [`super::reference::matvec_i8`], bit-exact, with `SXTB16` and `SMLAD`, two rows at a time
/// (each unpacked word of `x` serves both). `K = 0` gives `out = bias`.
pub fn matvec_i8(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    matvec_two_rows(
        w,
        x,
        bias,
        out,
        |xv: &[i8; 4]| {
            let xw = word(xv);
            (sxtb16(xw), sxtb16_ror8(xw))
        },
        step,
    );
}

/// Two i16 as one word, the first in the low halfword (one `LDR`; the Cortex-M4 and M7 load
/// unaligned words).
#[inline(always)]
fn halves([lo, hi]: [i16; 2]) -> u32 {
    u32::from(lo as u16) | u32::from(hi as u16) << 16
}

/// [`super::reference::matvec_i16`] (wrapping modulo 2^32), with `SMLAD` on the i16 weights
/// and inputs as they are stored: two MACs per instruction, four inputs per step, two rows at
/// a time. The 15-bit SimDR heads run here (3.1 instructions per MAC through the portable
/// kernel on the M7), and the first layer. `K = 0` gives `out = bias`.
///
/// On the DSP target, when `K` is a multiple of four and `w` and `x` start on 4-byte
/// boundaries (the heads: weights aligned in the blob, features in an aligned buffer), each
/// row pair runs one inline-assembly loop of `LDRD`s (which need word alignment) and `SMLAD`s:
/// 16 instructions per 16 MACs, unrolled twice. Anything else takes the Rust loop.
pub fn matvec_i16(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    if ldrd_shape(w, x) {
        // SAFETY: `ldrd_shape` is the function's contract.
        return unsafe { matvec_i16_aligned(w, x, bias, out) };
    }
    matvec_i16_rows(w, x, bias, out);
}

/// Whether [`matvec_i16`] may take the `LDRD` loop: `K` a positive multiple of four, `x` and
/// `w` on 4-byte boundaries.
#[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
#[inline(always)]
fn ldrd_shape(w: &[i16], x: &[i16]) -> bool {
    let aligned = |p: *const i16| (p as usize).is_multiple_of(4);
    let k = x.len();
    k > 0 && k.is_multiple_of(4) && aligned(x.as_ptr()) && aligned(w.as_ptr())
}

/// [`matvec_i16`]'s loop in Rust, for any shape and alignment.
#[inline(always)]
fn matvec_i16_rows(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    matvec_two_rows(
        w,
        x,
        bias,
        out,
        |&[a, b, c, d]: &[i16; 4]| (halves([a, b]), halves([c, d])),
        |acc, &[a, b, c, d]: &[i16; 4], (x01, x23)| {
            smlad(halves([c, d]), x23, smlad(halves([a, b]), x01, acc))
        },
    );
}

/// [`matvec_i16`] with the `LDRD` loop.
///
/// # Safety
///
/// [`ldrd_shape`] must hold: `K = x.len()` a positive multiple of four, `x` and `w` on 4-byte
/// boundaries (the assembly reads `K / 4` steps of 8 bytes from each row with `LDRD`). Checking
/// it again here cost the heads about 160 instructions per call under QEMU (spills around the
/// fallback), so the caller checks it once.
#[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
#[inline(never)]
unsafe fn matvec_i16_aligned(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    let k = x.len();
    let Some(k2) = k.checked_mul(2).filter(|&v| v > 0) else {
        return; // `K ≥ 4` by the contract
    };
    let n = rows(k, w.len(), bias.len(), out.len());
    let (Some(w), Some(bias), Some(out)) = (w.get(..n * k), bias.get(..n), out.get_mut(..n)) else {
        return; // `n` is within every length (`rows`)
    };
    let pairs = w.chunks_exact(k2).zip(bias.as_chunks::<2>().0);
    for ((ws, b), y) in pairs.zip(out.as_chunks_mut::<2>().0) {
        let Some((w0, w1)) = ws.split_at_checked(k) else {
            return; // `ws` is `2K` long
        };
        let [mut a0, mut a1] = *b;
        // One step: four inputs (one LDRD) against four weights of each row (one LDRD each),
        // four SMLAD.
        macro_rules! step {
            () => {
                concat!(
                    "ldrd {x0}, {x1}, [{px}], #8\n",
                    "ldrd {wa}, {wb}, [{p0}], #8\n",
                    "smlad {a0}, {wa}, {x0}, {a0}\n",
                    "smlad {a0}, {wb}, {x1}, {a0}\n",
                    "ldrd {wa}, {wb}, [{p1}], #8\n",
                    "smlad {a1}, {wa}, {x0}, {a1}\n",
                    "smlad {a1}, {wb}, {x1}, {a1}",
                )
            };
        }
        // SAFETY: the loop reads `K / 4` steps of 8 bytes from each of `x`, `w0` and `w1`
        // (each `K` i16 long, `K` a positive multiple of four: the function's contract), all
        // at 4-byte-aligned addresses (the contract; `w1` starts `2K` bytes, a multiple of 8,
        // after `w0`), as `LDRD` needs, and stops when the input pointer reaches `end`; it
        // writes only registers. SMLAD exists on cores with the DSP extension, which the
        // `arm-dsp` feature promises (see `sxtb16`).
        unsafe {
            core::arch::asm!(
                // Two steps per pass; an odd count (`end − px = 8·steps` bytes) enters at the
                // second.
                "sub {wa}, {end}, {px}",
                "tst {wa}, #8",
                "bne 3f",
                "2:",
                step!(),
                "3:",
                step!(),
                "cmp {px}, {end}",
                "bne 2b",
                px = inout(reg) x.as_ptr() => _,
                p0 = inout(reg) w0.as_ptr() => _,
                p1 = inout(reg) w1.as_ptr() => _,
                end = in(reg) x.as_ptr().wrapping_add(k),
                x0 = out(reg) _,
                x1 = out(reg) _,
                wa = out(reg) _,
                wb = out(reg) _,
                a0 = inout(reg) a0,
                a1 = inout(reg) a1,
                options(nostack, readonly),
            );
        }
        *y = [a0, a1];
    }
    if n % 2 == 1 {
        // An odd row count: the last row alone, through the Rust loop.
        let (Some(wl), Some(bl), Some(yl)) = (
            w.get((n - 1) * k..),
            bias.get(n - 1..),
            out.get_mut(n - 1..),
        ) else {
            return;
        };
        matvec_i16_rows(wl, x, bl, yl);
    }
}

/// Points the blocked [`matmat_i8`] computes per pass over a row of weights; an engine that
/// lends scratch for blocks of this many points ([`crate::scratch_words_for_block`]) gets it.
pub const BLOCK_POINTS: usize = 4;

/// Inputs of the block's unpacked `x` kept on the stack at a time (a multiple of four):
/// `2 × BLOCK_POINTS` words per four inputs, 1 KiB. A longer `K` runs in chunks, the
/// partial sums kept in `out` between them.
const CHUNK: usize = 128;

/// [`super::reference::matmat_i8`], bit-exact: four points at a time share each weight load
/// and each unpacking of it (CMSIS-NN's `arm_nn_mat_mult_kernel_s8_s16` does the same with two
/// columns); the rest of the points, fewer than four, go through [`matvec_i8`].
///
/// The block's inputs are unpacked once per chunk into the `SXTB16` halfword pairs (as
/// CMSIS-NN converts its columns to q15 first), so the inner step for four inputs of one row
/// and four points is one weight load, two `SXTB16`, four pairs of unpacked-input loads and
/// eight `SMLAD`: 16 MACs, one accumulator per point, in registers.
pub fn matmat_i8(w: &[i8], k: usize, x: &[i8], bias: &[i32], out: &mut [i32], out_stride: usize) {
    matmat_blocks(I8Rows { w, k }, w, k, x, bias, out, out_stride);
}

/// Words one row of `k` int8 weights takes widened ([`widen_i8`]): two per whole step of four
/// inputs. The last `k mod 4` weights of a row are not widened; the kernel reads them from the
/// row-major weights.
pub const fn widened_row_words(k: usize) -> usize {
    k / 4 * 2
}

/// Widens `rows` rows of `k` row-major int8 weights `w` for [`matmat_widened_i8`]: per row and
/// whole step of four inputs, the two words `SXTB16` makes of the step's weight word (bytes 0
/// and 2, then 1 and 3, as sign-extended halfwords), which the block kernel otherwise makes
/// for every block of points. Returns the words written to the front of `out`
/// (`rows · widened_row_words(k)`), `None` (nothing written) when `w` or `out` is too short.
pub fn widen_i8(w: &[i8], rows: usize, k: usize, out: &mut [u32]) -> Option<usize> {
    let per = widened_row_words(k);
    let (w, out) = (
        w.get(..rows.checked_mul(k)?)?,
        out.get_mut(..rows.checked_mul(per)?)?,
    );
    // Rows cut with `get` by index: `chunks_exact(k)` left a panic path for `k = 0` in the
    // firmware, which `per > 0` rules out but the compiler did not see.
    if per > 0 {
        for (r, o) in out.chunks_exact_mut(per).enumerate() {
            let row = w.get(r * k..r * k + k).unwrap_or_default();
            for (step, pair) in row.as_chunks::<4>().0.iter().zip(o.as_chunks_mut::<2>().0) {
                let wd = word(step);
                *pair = [sxtb16(wd), sxtb16_ror8(wd)];
            }
        }
    }
    Some(rows * per)
}

/// [`matmat_i8`] over weights also given widened (`ww`, from [`widen_i8`] of the same `w`,
/// `rows` and `k`): the inner step for four inputs of one row and four points loads the two
/// widened weight words with one `LDRD` instead of unpacking a weight word with two `SXTB16`
/// (13 instructions per 16 MACs instead of 15). The same integers as [`matmat_i8`]; with a
/// `ww` shorter than the rows computed need, it runs [`matmat_i8`] instead. Widened weights take twice
/// the memory of the int8 ones: a firmware trades RAM for this speed.
pub fn matmat_widened_i8(
    ww: &[u32],
    w: &[i8],
    k: usize,
    x: &[i8],
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    let (_, rows) = super::matmat_dims(k, w.len(), x.len(), bias.len(), out.len(), out_stride);
    let per = widened_row_words(k);
    match ww.get(..rows.saturating_mul(per)) {
        Some(ww) => matmat_blocks(WidenedRows { ww, per }, w, k, x, bias, out, out_stride),
        None => matmat_i8(w, k, x, bias, out, out_stride),
    }
}

/// Where the block kernel finds one row's weights for its whole steps of four inputs.
trait BlockRows: Copy {
    /// Row `r`'s weights for the steps of inputs `k0..full` (`k0` and `full − k0` multiples
    /// of four).
    type Row<'r>: Copy
    where
        Self: 'r;
    /// Row `r`'s steps `k0..full`, empty if out of range (never, by construction).
    fn row(&self, r: usize, k0: usize, full: usize) -> Self::Row<'_>;
    /// `acc[p] += Σ w·x` over those steps and the block's unpacked inputs `xu`.
    fn steps(acc: &mut [i32; BLOCK_POINTS], row: Self::Row<'_>, xu: &[[u32; 2 * BLOCK_POINTS]]);
    /// What [`rows_asm`] reads: the weights from input `k0` of row 0 on, as bytes; the bytes
    /// from one row to the next; whether they are widened.
    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    fn asm_weights(&self, k0: usize) -> (&[u8], usize, bool);
    /// Every row's steps `k0..full` at once in [`rows_asm`] (the DSP build): point `p`'s
    /// output of row `r` at `out[p·stride + r]`, starting from `bias[r]` when `k0 = 0`, else
    /// from that output. Returns whether it ran (else the caller runs [`BlockRows::steps`]
    /// row by row).
    #[inline(always)]
    fn all_rows(
        &self,
        k0: usize,
        full: usize,
        xu: &[[u32; 2 * BLOCK_POINTS]],
        bias: &[i32],
        out: &mut [i32],
        stride: usize,
    ) -> bool {
        #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
        {
            let (w, row_bytes, wide) = self.asm_weights(k0);
            let steps = (full - k0) / 4;
            // `wide` is a constant of the implementation: one monomorphized loop each.
            let run = if wide {
                rows_asm::<true>
            } else {
                rows_asm::<false>
            };
            run(w, row_bytes, steps, xu, bias, out, stride, k0 == 0)
        }
        #[cfg(not(all(target_arch = "arm", feature = "arm-dsp")))]
        {
            let _ = (k0, full, xu, bias, out, stride);
            false
        }
    }
}

/// Row-major int8 weights, rows of `k`: each step's weight word unpacked per block.
#[derive(Clone, Copy)]
struct I8Rows<'a> {
    w: &'a [i8],
    k: usize,
}

impl BlockRows for I8Rows<'_> {
    type Row<'r>
        = &'r [i8]
    where
        Self: 'r;

    #[inline(always)]
    fn row(&self, r: usize, k0: usize, full: usize) -> &[i8] {
        let at = r * self.k;
        self.w.get(at + k0..at + full).unwrap_or_default()
    }

    #[inline(always)]
    fn steps(acc: &mut [i32; BLOCK_POINTS], row: &[i8], xu: &[[u32; 2 * BLOCK_POINTS]]) {
        block_steps(acc, row, xu);
    }

    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    #[inline(always)]
    fn asm_weights(&self, k0: usize) -> (&[u8], usize, bool) {
        let w = self.w.get(k0..).unwrap_or_default();
        (bytemuck::cast_slice(w), self.k, false)
    }
}

/// Widened weights ([`widen_i8`]), rows of `per` words.
#[derive(Clone, Copy)]
struct WidenedRows<'a> {
    ww: &'a [u32],
    per: usize,
}

impl BlockRows for WidenedRows<'_> {
    type Row<'r>
        = &'r [u32]
    where
        Self: 'r;

    #[inline(always)]
    fn row(&self, r: usize, k0: usize, full: usize) -> &[u32] {
        // Two words per step of four inputs: inputs `k0..full` are words `k0/2..full/2`.
        let at = r * self.per;
        self.ww.get(at + k0 / 2..at + full / 2).unwrap_or_default()
    }

    #[inline(always)]
    fn steps(acc: &mut [i32; BLOCK_POINTS], row: &[u32], xu: &[[u32; 2 * BLOCK_POINTS]]) {
        widened_steps(acc, row, xu);
    }

    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    #[inline(always)]
    fn asm_weights(&self, k0: usize) -> (&[u8], usize, bool) {
        // Two words per step of four inputs: input `k0` starts word `k0/2`.
        let ww = self.ww.get(k0 / 2..).unwrap_or_default();
        (bytemuck::cast_slice(ww), 4 * self.per, true)
    }
}

/// Every row of one block and chunk in one inline-assembly loop: per row the accumulators from
/// `bias[r]` (`from_bias`) or from the outputs, `steps` steps of four inputs (four per pass; a
/// count that is not a multiple of four enters the pass at its second, third or fourth step),
/// and the four outputs stored at `out[p·stride + r]`. Row `r`'s weights for the steps start
/// `r · row_bytes` bytes into `w`, `step_bytes` per step: one word of four int8 weights
/// unpacked with two `SXTB16` ([`block_steps`]), or with `WIDE` two widened words loaded with one
/// `LDRD` ([`widened_steps`]). The loop keeps its own state in a small array in memory (the steps
/// need all 12 registers Rust's inline assembly leaves on Thumb), so a row costs about 25
/// instructions besides its steps, against about 45 for the same loop in Rust.
///
/// Returns false, doing nothing, where the shapes do not allow it (no steps, no rows, buffers
/// too short, or widened words not on a 4-byte boundary); the caller then runs the rows in Rust.
#[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn rows_asm<const WIDE: bool>(
    w: &[u8],
    row_bytes: usize,
    steps: usize,
    xu: &[[u32; 2 * BLOCK_POINTS]],
    bias: &[i32],
    out: &mut [i32],
    stride: usize,
    from_bias: bool,
) -> bool {
    let step_bytes = if WIDE { 8 } else { 4 };
    let rows = bias.len();
    // Bounds of everything the loop touches; all within `usize` by the checked arithmetic.
    let fits = steps > 0
        && rows > 0
        && steps <= xu.len()
        && step_bytes * steps <= row_bytes
        && (rows - 1)
            .checked_mul(row_bytes)
            .and_then(|v| v.checked_add(step_bytes * steps))
            .is_some_and(|v| v <= w.len())
        && stride
            .checked_mul(BLOCK_POINTS - 1)
            .and_then(|v| v.checked_add(rows))
            .is_some_and(|v| v <= out.len())
        && (!WIDE || (w.as_ptr() as usize).is_multiple_of(4));
    if !fits {
        return false;
    }
    let out = out.as_mut_ptr();
    // The loop's state: [xu, weight bytes of a row's steps, bytes from there to the next row,
    // output pointer (row r of point 0), output stride in bytes, bias pointer, output end].
    let mut ctx: [usize; 7] = [
        xu.as_ptr() as usize,
        step_bytes * steps,
        row_bytes - step_bytes * steps,
        out as usize,
        4 * stride,
        bias.as_ptr() as usize,
        out.wrapping_add(rows) as usize,
    ];
    // Three steps' and two steps' weight bytes (the pass's entry test).
    macro_rules! three_steps {
        (true) => {
            "24"
        };
        (false) => {
            "12"
        };
    }
    macro_rules! two_steps {
        (true) => {
            "16"
        };
        (false) => {
            "8"
        };
    }
    // One step's weights into `u` (inputs 0 and 2) and `t` (inputs 1 and 3).
    macro_rules! weights {
        (true) => {
            "ldrd {u}, {t}, [{pw}], #8\n"
        };
        (false) => {
            concat!(
                "ldr {t}, [{pw}], #4\n",
                "sxtb16 {u}, {t}\n",
                "sxtb16 {t}, {t}, ror #8\n",
            )
        };
    }
    // One step: the weights, then per point its two unpacked input words and two SMLAD.
    macro_rules! step {
        ($wide:tt) => {
            concat!(
                weights!($wide),
                "ldrd {xa}, {xb}, [{px}], #8\n",
                "smlad {a0}, {u}, {xa}, {a0}\n",
                "smlad {a0}, {t}, {xb}, {a0}\n",
                "ldrd {xa}, {xb}, [{px}], #8\n",
                "smlad {a1}, {u}, {xa}, {a1}\n",
                "smlad {a1}, {t}, {xb}, {a1}\n",
                "ldrd {xa}, {xb}, [{px}], #8\n",
                "smlad {a2}, {u}, {xa}, {a2}\n",
                "smlad {a2}, {t}, {xb}, {a2}\n",
                "ldrd {xa}, {xb}, [{px}], #8\n",
                "smlad {a3}, {u}, {xa}, {a3}\n",
                "smlad {a3}, {t}, {xb}, {a3}\n",
            )
        };
    }
    // The accumulators of a row: from its bias, or from its outputs.
    macro_rules! init {
        (bias) => {
            concat!(
                "ldr {xa}, [{ctx}, #20]\n",
                "ldr {a0}, [{xa}], #4\n",
                "str {xa}, [{ctx}, #20]\n",
                "mov {a1}, {a0}\n",
                "mov {a2}, {a0}\n",
                "mov {a3}, {a0}\n",
            )
        };
        (out) => {
            concat!(
                "ldr {xa}, [{ctx}, #12]\n",
                "ldr {xb}, [{ctx}, #16]\n",
                "ldr {a0}, [{xa}]\n",
                "ldr {a1}, [{xa}, {xb}]\n",
                "add {t}, {xa}, {xb}, lsl #1\n",
                "ldr {a2}, [{t}]\n",
                "ldr {a3}, [{t}, {xb}]\n",
            )
        };
    }
    // The whole loop: per row its accumulators, its steps, its outputs, the next row's
    // weights and the loop test; after it, the pass's entries for `steps mod 4` = 1, 2, 3.
    macro_rules! rows {
        ($init:tt, $wide:tt) => {
            // SAFETY: `fits` bounds every access: for each of the `rows` rows the loop reads
            // `steps · step_bytes` bytes of `w` from the row's start (`(rows − 1) · row_bytes +
            // steps · step_bytes ≤ w.len()`; `LDRD` needs 4-byte alignment, which `fits` checks
            // for the widened words; `LDR` takes any on Armv7E-M while CCR.UNALIGN_TRP is clear,
            // as it is out of reset, and as the row-major kernels before this one assumed),
            // `steps` entries of `xu` (`steps ≤ xu.len()`), `bias[r]` when `from_bias`
            // (`r < rows = bias.len()`), and
            // reads (when not `from_bias`) and writes `out[p·stride + r]` for `p < 4`
            // (`3·stride + rows ≤ out.len()`), with the alignment of `u32`, `i32` and `usize`.
            // It reads and writes `ctx` (its own state) and otherwise only registers; it stops
            // after `rows ≥ 1` rows (the output pointer reaches `out + rows`). SXTB16 and SMLAD
            // exist on cores with the DSP extension, which the `arm-dsp` feature promises (see
            // `sxtb16`).
            unsafe {
                core::arch::asm!(
                    "2:",
                    init!($init),
                    "ldr {px}, [{ctx}]",
                    "ldr {end}, [{ctx}, #4]",
                    concat!("tst {end}, #", three_steps!($wide)),
                    "add {end}, {end}, {pw}",
                    "bne 9f",
                    "4:",
                    step!($wide),
                    "7:",
                    step!($wide),
                    "6:",
                    step!($wide),
                    "8:",
                    step!($wide),
                    "cmp {pw}, {end}",
                    "bne 4b",
                    "ldr {xa}, [{ctx}, #12]",
                    "ldr {xb}, [{ctx}, #16]",
                    "str {a0}, [{xa}]",
                    "str {a1}, [{xa}, {xb}]",
                    "add {t}, {xa}, {xb}, lsl #1",
                    "str {a2}, [{t}]",
                    "str {a3}, [{t}, {xb}]",
                    "add {xa}, {xa}, #4",
                    "str {xa}, [{ctx}, #12]",
                    "ldr {xb}, [{ctx}, #8]",
                    "add {pw}, {pw}, {xb}",
                    "ldr {xb}, [{ctx}, #24]",
                    "cmp {xa}, {xb}",
                    "bne 2b",
                    "b 5f",
                    "9:",
                    "sub {t}, {end}, {pw}",
                    concat!("and {t}, {t}, #", three_steps!($wide)),
                    concat!("cmp {t}, #", two_steps!($wide)),
                    "beq 6b",
                    "bhi 7b",
                    "b 8b",
                    "5:",
                    pw = inout(reg) w.as_ptr() => _,
                    ctx = in(reg) ctx.as_mut_ptr(),
                    px = out(reg) _,
                    end = out(reg) _,
                    t = out(reg) _,
                    u = out(reg) _,
                    xa = out(reg) _,
                    xb = out(reg) _,
                    a0 = out(reg) _,
                    a1 = out(reg) _,
                    a2 = out(reg) _,
                    a3 = out(reg) _,
                    options(nostack),
                )
            }
        };
    }
    match (WIDE, from_bias) {
        (true, true) => rows!(bias, true),
        (true, false) => rows!(out, true),
        (false, true) => rows!(bias, false),
        (false, false) => rows!(out, false),
    }
    true
}

/// The blocked kernel over any row source: [`BLOCK_POINTS`] points at a time through chunks of
/// [`CHUNK`] inputs, the last points through [`matvec_i8`].
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn matmat_blocks<R: BlockRows>(
    src: R,
    w: &[i8],
    k: usize,
    x: &[i8],
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    let (points, rows) = super::matmat_dims(k, w.len(), x.len(), bias.len(), out.len(), out_stride);
    if k == 0 || rows == 0 {
        super::reference::matmat_by_rows(matvec_i8, w, k, x, bias, out, out_stride);
        return;
    }
    let (w, bias) = (
        w.get(..rows * k).unwrap_or_default(),
        bias.get(..rows).unwrap_or_default(),
    );
    let blocks = points / BLOCK_POINTS;
    // Both products are below the slice lengths when a block exists (`matmat_dims`), and
    // non-zero (`k ≥ 1`; `rows ≥ 1` implies `out_stride ≥ 1`). Without a block they may
    // overflow (one point and an `out_stride` of `usize::MAX`): then only the tail runs.
    if blocks > 0 {
        let (Some(xk), Some(os)) = (
            k.checked_mul(BLOCK_POINTS).filter(|&v| v > 0),
            out_stride.checked_mul(BLOCK_POINTS).filter(|&v| v > 0),
        ) else {
            return;
        };
        for (xb, ob) in x.chunks_exact(xk).zip(out.chunks_mut(os)).take(blocks) {
            let mut k0 = 0;
            while k0 < k {
                let kc = CHUNK.min(k - k0);
                block_chunk(src, w, k, k0, kc, xb, bias, ob, out_stride);
                k0 += kc;
            }
        }
    }
    let done = blocks * BLOCK_POINTS;
    if let (Some(x), Some(out)) = (
        x.get(done * k..points * k),
        out.get_mut(done * out_stride..),
    ) {
        super::reference::matmat_by_rows(matvec_i8, w, k, x, bias, out, out_stride);
    }
}

/// Inputs `k0..k0 + kc` of every row for one block of [`BLOCK_POINTS`] points (`xb`, rows of
/// `k`): starts from the bias on the first chunk and from the partial sums in `out` after it.
/// The whole steps of four inputs take the row source `src`, the last one to three inputs the
/// row-major `w`. Slices are cut with `get`, never indexed, so that the firmware links no panic
/// path here.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn block_chunk<R: BlockRows>(
    src: R,
    w: &[i8],
    k: usize,
    k0: usize,
    kc: usize,
    xb: &[i8],
    bias: &[i32],
    out: &mut [i32],
    stride: usize,
) {
    let full = k0 + kc / 4 * 4;
    let point = |p: usize, r: core::ops::Range<usize>| {
        xb.get(p * k + r.start..p * k + r.end).unwrap_or_default()
    };
    let steps = |p: usize| point(p, k0..full).as_chunks::<4>().0;
    // The block's inputs unpacked, per step of four and per point: bytes (0, 2) and (1, 3) as
    // halfwords. Only the entries written are read, so the buffer is not zeroed first (a
    // zeroed 1 KiB array was a `__aeabi_memclr4` call per block and layer in the QEMU profile).
    let mut buf = [MaybeUninit::<[u32; 2 * BLOCK_POINTS]>::uninit(); CHUNK / 4];
    let mut n = 0;
    for ((((slot, a), b), c), d) in buf
        .iter_mut()
        .zip(steps(0))
        .zip(steps(1))
        .zip(steps(2))
        .zip(steps(3))
    {
        let [a, b, c, d] = [a, b, c, d].map(word);
        slot.write([
            sxtb16(a),
            sxtb16_ror8(a),
            sxtb16(b),
            sxtb16_ror8(b),
            sxtb16(c),
            sxtb16_ror8(c),
            sxtb16(d),
            sxtb16_ror8(d),
        ]);
        n += 1;
    }
    // SAFETY: the loop above wrote `buf[..n]` (`n ≤ buf.len()`); `MaybeUninit<T>` has `T`'s
    // layout, so those entries read as `[u32; 8]`.
    let xu: &[[u32; 2 * BLOCK_POINTS]] =
        unsafe { core::slice::from_raw_parts(buf.as_ptr().cast(), n) };
    let done = src.all_rows(k0, full, xu, bias, out, stride);
    let mut ys = out.chunks_mut(stride);
    let (Some(y0), Some(y1), Some(y2), Some(y3)) = (ys.next(), ys.next(), ys.next(), ys.next())
    else {
        return; // ruled out by `matmat_dims`
    };
    // The four points' outputs of one row at a time.
    macro_rules! ys {
        () => {
            (y0.iter_mut().zip(y1.iter_mut())).zip(y2.iter_mut().zip(y3.iter_mut()))
        };
    }
    let rows = bias.iter().enumerate();
    // Two copies of the row loop, so that neither tests the chunk per row.
    if done {
        // Every row ran in `rows_asm`.
    } else if k0 == 0 {
        for ((r, &b), ((y0, y1), (y2, y3))) in rows.zip(ys!()) {
            let mut acc = [b; BLOCK_POINTS];
            R::steps(&mut acc, src.row(r, k0, full), xu);
            [*y0, *y1, *y2, *y3] = acc;
        }
    } else {
        for ((r, _), ((y0, y1), (y2, y3))) in rows.zip(ys!()) {
            let mut acc = [*y0, *y1, *y2, *y3];
            R::steps(&mut acc, src.row(r, k0, full), xu);
            [*y0, *y1, *y2, *y3] = acc;
        }
    }
    // The last one to three inputs when `K` is not a multiple of four, row by row.
    if full < k0 + kc {
        let tails = [0, 1, 2, 3].map(|p| point(p, full..k0 + kc));
        for (row, ((y0, y1), (y2, y3))) in w.chunks_exact(k).zip(ys!()) {
            let wt = row.get(full..k0 + kc).unwrap_or_default();
            for (y, t) in [y0, y1, y2, y3].into_iter().zip(tails) {
                *y = tail(*y, wt, t);
            }
        }
    }
}

/// `acc[p] += Σ w·x` over the steps of four inputs that `ws` (one row) and `xu` (the block's
/// unpacked inputs) share: per step one weight word, unpacked once, and two `SMLAD` per point.
/// The DSP build runs whole blocks of rows in [`rows_asm`] instead; this is the portable form
/// (and the DSP build's for a chunk without whole steps).
#[inline(always)]
fn block_steps(acc: &mut [i32; BLOCK_POINTS], row: &[i8], xu: &[[u32; 2 * BLOCK_POINTS]]) {
    for (u, wv) in xu.iter().zip(row.as_chunks::<4>().0) {
        let wd = word(wv);
        step_points(acc, [sxtb16(wd), sxtb16_ror8(wd)], u);
    }
}

/// [`block_steps`] over one row's widened words (`ww`, two per step: the unpacked weights).
#[inline(always)]
fn widened_steps(acc: &mut [i32; BLOCK_POINTS], ww: &[u32], xu: &[[u32; 2 * BLOCK_POINTS]]) {
    for (u, &w) in xu.iter().zip(ww.as_chunks::<2>().0) {
        step_points(acc, w, u);
    }
}

/// One step of four inputs for every point of a block: the step's unpacked weights `[w02, w13]`
/// against each point's two unpacked input words in `u`, two `SMLAD` per point.
#[inline(always)]
fn step_points(acc: &mut [i32; BLOCK_POINTS], [w02, w13]: [u32; 2], u: &[u32; 2 * BLOCK_POINTS]) {
    for (p, a) in acc.iter_mut().enumerate() {
        *a = smlad(w13, u[2 * p + 1], smlad(w02, u[2 * p], *a));
    }
}

/// Bytewise signed maximum of two words (`SSUB8` sets a GE flag per byte where `a ≥ b`, `SEL`
/// then picks that byte of `a`, else of `b`).
#[inline(always)]
fn max8(a: u32, b: u32) -> u32 {
    #[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
    {
        let r: u32;
        // SAFETY: SSUB8 and SEL read and write only the named registers (the scratch output
        // `_t` included) and the APSR.GE flags, touch no memory; both exist with the DSP
        // extension (see `sxtb16`).
        unsafe {
            core::arch::asm!("ssub8 {t}, {a}, {b}", "sel {r}, {a}, {b}", t = out(reg) _,
                r = lateout(reg) r, a = in(reg) a, b = in(reg) b, options(pure, nomem, nostack));
        }
        r
    }
    #[cfg(not(all(target_arch = "arm", feature = "arm-dsp")))]
    {
        u32::from_le_bytes(core::array::from_fn(|i| {
            let (x, y) = ((a >> (8 * i)) as u8 as i8, (b >> (8 * i)) as u8 as i8);
            x.max(y) as u8
        }))
    }
}

/// [`super::reference::pool_i8`], bit-exact, four channels per step: the maxima with `SSUB8`
/// and `SEL` on whole words, the sums from the sign-extended bytes.
pub fn pool_i8(max: &mut [i8], sum: &mut [i32], y: &[i8]) {
    let n = max.len().min(sum.len()).min(y.len());
    let (Some(max), Some(sum), Some(y)) = (max.get_mut(..n), sum.get_mut(..n), y.get(..n)) else {
        return; // `n` is the shortest length
    };
    let (m4, m_rest) = max.as_chunks_mut::<4>();
    let (s4, s_rest) = sum.as_chunks_mut::<4>();
    let (y4, y_rest) = y.as_chunks::<4>();
    for ((m, s), v) in m4.iter_mut().zip(s4).zip(y4) {
        let vw = word(v);
        *m = max8(vw, word(m)).to_le_bytes().map(|b| b as i8);
        for (s, &v) in s.iter_mut().zip(v) {
            *s = s.wrapping_add(i32::from(v));
        }
    }
    super::reference::pool_i8(m_rest, s_rest, y_rest);
}

/// Whether [`requantize_i8`] runs its FPv4 form (an FPU without FPv5's `VMAXNM`).
const FPV4_REQUANT: bool = cfg!(all(
    target_arch = "arm",
    feature = "arm-dsp",
    target_abi = "eabihf",
    not(feature = "arm-fpv5")
));

/// [`super::reference::requantize_i8`], bit-exact, four outputs per pass, in inline assembly
/// on a Cortex-M with the DSP extension (`arm-dsp`) and a hardware FPU (`target_abi =
/// "eabihf"`), everywhere else emulated.
///
/// With the `arm-fpv5` feature (the Cortex-M7's FPv5 FPU), per output: `VCVT` to f32, `VMUL`
/// by the scale, the LeakyReLU as `VMAXNM(v, α·v)`, then `VCVTN` (round to nearest, ties to
/// even, whatever the FPSCR's rounding mode; saturating) and `SSAT #8`: about 8.5 instructions
/// against about 18 for the reference's compare, select, float clamps and magic-number
/// rounding. The max form equals `v < 0 ? α·v : v` for slopes in `[0, 1]` (`α = 1` is no
/// LeakyReLU); a layer with another slope takes the reference.
///
/// Without it (the FPv4-SP of a Cortex-M4, which has neither `VMAXNM` nor `VCVTN`; the
/// single-precision FPv5 of an M33 has both, but Rust's inline assembly takes FPU operands
/// only on a double-precision FPU): the LeakyReLU is the reference's own compare and a
/// conditional `VMUL`, and the rounding `VCVTR`, which rounds in the FPSCR's mode: round to
/// nearest, ties to even, the default that Rust's floating point assumes everywhere (the
/// reference's magic-number rounding relies on it as well). About 10.5 instructions per output
/// against about 24 for the reference on the M4 (both counted in the M4 image's code). Slopes in `(0, 1]` only: an infinite `v`
/// times `α = 0` is NaN, which `VCVTR` would turn into 0 where the reference saturates it.
///
/// Both need finite scales, which [`crate::model::Model::parse`] checks: then `v` is never NaN
/// (but an infinite `v` times `α = 0`, which `VMAXNM` resolves to `v`), and rounding first and
/// saturating after gives the reference's clamp-then-round.
pub fn requantize_i8(acc: &[i32], scales: &[f32], leaky: Option<f32>, out: &mut [i8]) {
    let n = acc.len().min(scales.len()).min(out.len());
    let (Some(acc), Some(scales), Some(out)) = (acc.get(..n), scales.get(..n), out.get_mut(..n))
    else {
        return; // `n` is the shortest length
    };
    let alpha = match leaky {
        None => 1.0,
        Some(a) if (0.0..=1.0).contains(&a) && (a > 0.0 || !FPV4_REQUANT) => a,
        Some(_) => return super::reference::requantize_i8(acc, scales, leaky, out),
    };
    let (a4, a_rest) = acc.as_chunks::<4>();
    let (s4, s_rest) = scales.as_chunks::<4>();
    let (o4, o_rest) = out.as_chunks_mut::<4>();
    requantize_fours(a4, s4, alpha, o4);
    super::reference::requantize_i8(a_rest, s_rest, leaky, o_rest);
}

/// The requantization loop of [`requantize_fours`], four outputs per pass, written once for
/// both FPUs: `VLDMIA` of four accumulators into `s0–s3` and four scales into `s4–s7`, `VCVT`
/// and the scale's `VMUL`, then `$step` (the LeakyReLU and the rounding to integers in
/// `s0–s3`), two `VMOV`s of two results each, `SSAT #8` and `STRB`, until the accumulator
/// pointer reaches the end; nothing when `$n` is 0 (the loop tests its end only after a
/// pass). `$setup` runs once before the loop; `$operand`s are the slope's and any further
/// clobber.
#[cfg(all(
    target_arch = "arm",
    any(feature = "arm-fpv5", all(feature = "arm-dsp", target_abi = "eabihf"))
))]
macro_rules! requantize_loop {
    ($acc:expr, $scales:expr, $out:expr, $n:expr, [$($setup:literal),*], [$($step:literal),*],
     $($operand:tt)*) => {
        if $n > 0 {
            core::arch::asm!(
                $($setup,)*
                "2:",
                "vldmia {pa}!, {{s0-s3}}",
                "vldmia {ps}!, {{s4-s7}}",
                "vcvt.f32.s32 s0, s0",
                "vcvt.f32.s32 s1, s1",
                "vcvt.f32.s32 s2, s2",
                "vcvt.f32.s32 s3, s3",
                "vmul.f32 s0, s0, s4",
                "vmul.f32 s1, s1, s5",
                "vmul.f32 s2, s2, s6",
                "vmul.f32 s3, s3, s7",
                $($step,)*
                "vmov {r0}, {r1}, s0, s1",
                "vmov {r2}, {r3}, s2, s3",
                "ssat {r0}, #8, {r0}",
                "ssat {r1}, #8, {r1}",
                "ssat {r2}, #8, {r2}",
                "ssat {r3}, #8, {r3}",
                "strb {r0}, [{po}], #1",
                "strb {r1}, [{po}], #1",
                "strb {r2}, [{po}], #1",
                "strb {r3}, [{po}], #1",
                "cmp {pa}, {end}",
                "bne 2b",
                pa = inout(reg) $acc.as_ptr() => _,
                ps = inout(reg) $scales.as_ptr() => _,
                po = inout(reg) $out.as_mut_ptr() => _,
                end = in(reg) $acc.as_ptr().wrapping_add($n),
                r0 = out(reg) _,
                r1 = out(reg) _,
                r2 = out(reg) _,
                r3 = out(reg) _,
                out("s0") _,
                out("s1") _,
                out("s2") _,
                out("s3") _,
                out("s4") _,
                out("s5") _,
                out("s6") _,
                out("s7") _,
                $($operand)*
                options(nostack),
            )
        }
    };
}

/// [`requantize_i8`]'s four-output steps over the shortest of the three slices.
#[inline(always)]
fn requantize_fours(acc: &[[i32; 4]], scales: &[[f32; 4]], alpha: f32, out: &mut [[i8; 4]]) {
    let n = acc.len().min(scales.len()).min(out.len());
    #[cfg(all(target_arch = "arm", feature = "arm-fpv5"))]
    // Per output: the LeakyReLU as `VMAXNM(v, α·v)`, then `VCVTN`.
    // SAFETY: the loop (run only for `n > 0`) reads `n` steps of 16 bytes from `acc` and from
    // `scales` and writes `n` steps of 4 bytes to `out` (`n` is the shortest length; `VLDMIA`
    // needs the 4-byte alignment that `i32` and `f32` give, `STRB` none), stopping when the
    // accumulator pointer reaches `end`; it writes only the named registers, the flags (and
    // the FPSCR's cumulative exception bits) and `out`. `VMAXNM` and `VCVTN` exist on an FPv5
    // FPU, which the `arm-fpv5` feature promises (the `sreg` operand needs the
    // double-precision FPU's `vfp2` feature: without it the build fails).
    unsafe {
        requantize_loop!(
            acc,
            scales,
            out,
            n,
            [],
            [
                "vmul.f32 s4, s0, {al}",
                "vmul.f32 s5, s1, {al}",
                "vmul.f32 s6, s2, {al}",
                "vmul.f32 s7, s3, {al}",
                "vmaxnm.f32 s0, s0, s4",
                "vmaxnm.f32 s1, s1, s5",
                "vmaxnm.f32 s2, s2, s6",
                "vmaxnm.f32 s3, s3, s7",
                "vcvtn.s32.f32 s0, s0",
                "vcvtn.s32.f32 s1, s1",
                "vcvtn.s32.f32 s2, s2",
                "vcvtn.s32.f32 s3, s3"
            ],
            al = in(sreg) alpha,
        );
    }
    #[cfg(all(
        target_arch = "arm",
        feature = "arm-dsp",
        target_abi = "eabihf",
        not(feature = "arm-fpv5")
    ))]
    // Per output: the reference's `v < 0` compare (`VCMP`, `VMRS`) and a conditional `VMUL`
    // by α, then `VCVTR`. α travels in a core register: Rust's inline assembly takes FPU
    // operands only on a double-precision FPU, but single-precision registers may be named
    // as clobbers.
    // SAFETY: as the FPv5 loop: `n` steps of 16 bytes read from `acc` and `scales` (4-byte
    // aligned for `VLDMIA`), `n` steps of 4 bytes written to `out`, until the accumulator
    // pointer reaches `end`; only the named registers, the flags (and the FPSCR's cumulative
    // exception bits) and `out` are written.
    // Every instruction is VFPv2 (an `eabihf` target has such an FPU) or Armv7-M Thumb-2
    // (`SSAT`, `IT`).
    unsafe {
        requantize_loop!(
            acc,
            scales,
            out,
            n,
            ["vmov s8, {al}"],
            [
                "vcmp.f32 s0, #0",
                "vmrs APSR_nzcv, fpscr",
                "it mi",
                "vmulmi.f32 s0, s0, s8",
                "vcmp.f32 s1, #0",
                "vmrs APSR_nzcv, fpscr",
                "it mi",
                "vmulmi.f32 s1, s1, s8",
                "vcmp.f32 s2, #0",
                "vmrs APSR_nzcv, fpscr",
                "it mi",
                "vmulmi.f32 s2, s2, s8",
                "vcmp.f32 s3, #0",
                "vmrs APSR_nzcv, fpscr",
                "it mi",
                "vmulmi.f32 s3, s3, s8",
                "vcvtr.s32.f32 s0, s0",
                "vcvtr.s32.f32 s1, s1",
                "vcvtr.s32.f32 s2, s2",
                "vcvtr.s32.f32 s3, s3"
            ],
            al = in(reg) alpha.to_bits(),
            out("s8") _,
        );
    }
    #[cfg(not(all(
        target_arch = "arm",
        any(feature = "arm-fpv5", all(feature = "arm-dsp", target_abi = "eabihf"))
    )))]
    for ((a, s), o) in acc.iter().zip(scales).zip(out.iter_mut()).take(n) {
        for ((o, &a), &s) in o.iter_mut().zip(a).zip(s) {
            let v = a as f32 * s;
            // VMAXNM returns the number when one operand is NaN, as `f32::max` does; VCVTN
            // rounds to nearest even and saturates, NaN giving 0, as `rintf` and `as` do.
            let v = v.max(v * alpha);
            *o = (libm::rintf(v) as i32).clamp(-128, 127) as i8;
        }
    }
}

/// The DSP kernel table (see [`super::Kernels`]); only built where the instructions are real.
#[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
pub(super) const fn kernels() -> super::Kernels {
    let mut k = super::Kernels::reference();
    k.isa = super::Isa::ArmDsp;
    k.i8 = matvec_i8;
    k.i16 = matvec_i16;
    k.i8mm = matmat_i8;
    k.pool = pool_i8;
    // The FPv5 form with `arm-fpv5`, else the FPv4 form where there is an FPU.
    #[cfg(any(feature = "arm-fpv5", target_abi = "eabihf"))]
    {
        k.requant = requantize_i8;
    }
    k
}

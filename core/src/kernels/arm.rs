//! The Cortex-M int8 kernel with the DSP extension (Armv7E-M, Armv8-M Mainline with DSP):
//! `SXTB16` unpacks two int8 into two i16 halfwords, `SMLAD` multiplies two pairs of halfwords
//! and adds both products to an accumulator, two MACs per instruction. This is CMSIS-NN's
//! fully-connected inner step (`arm_nn_vec_mat_mult_t_s8`): per four inputs of two rows, one
//! word of `x` unpacked once (`SXTB16` and `SXTB16` of the word rotated by 8: bytes 0, 2 and
//! 1, 3), one word of each row unpacked the same way, and four `SMLAD`.
//!
//! The three instructions are inline assembly on `target_arch = "arm"` with the `arm-dsp`
//! cargo feature: stable Rust cannot see the DSP extension in `cfg(target_feature)`, and the
//! `core::arch::arm` intrinsics for it are unstable, so a firmware whose core has the extension
//! opts in (thumbv6m, thumbv7m and thumbv8m.base lack it). Everywhere else they are emulated in
//! Rust, bit for bit as the Armv7-M manual defines them, so the kernel's blocking, tails and
//! wrapping are tested on any host against the reference (`core/tests/kernels.rs`) and the
//! instructions themselves on a Cortex-M7 under QEMU (the firmware's boot self-test, asserted
//! by `tests/firmware_qemu.rs`).
//!
//! `SMLAD` adds exactly (the Q flag it may set does not change the result), so the sums wrap
//! modulo 2^32 like the reference's; the products of sign-extended bytes are at most 2^14.
#![allow(unsafe_code)]

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
fn tail(acc: i32, w: &[i8], x: &[i8]) -> i32 {
    w.iter().zip(x).fold(acc, |a, (&w, &x)| {
        a.wrapping_add(i32::from(w) * i32::from(x))
    })
}

/// [`super::reference::matvec_i8`], bit-exact, with `SXTB16` and `SMLAD`, two rows at a time
/// (each unpacked word of `x` serves both). `K = 0` gives `out = bias`.
pub fn matvec_i8(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    let k = x.len();
    let n = rows(k, w.len(), bias.len(), out.len());
    if k == 0 {
        out[..n].copy_from_slice(&bias[..n]);
        return;
    }
    let (xs, xt) = x.as_chunks::<4>();
    let full = xs.len() * 4;
    let (pairs, last) = w[..n * k].split_at(n / 2 * 2 * k);
    let (outs, out_last) = out[..n].split_at_mut(n / 2 * 2);
    for ((ws, y), b) in pairs
        .chunks_exact(2 * k)
        .zip(outs.as_chunks_mut::<2>().0)
        .zip(bias.as_chunks::<2>().0)
    {
        let (w0, w1) = ws.split_at(k);
        let (mut a0, mut a1) = (b[0], b[1]);
        for ((xv, w0v), w1v) in xs.iter().zip(w0.as_chunks().0).zip(w1.as_chunks().0) {
            let xw = word(xv);
            let xu = (sxtb16(xw), sxtb16_ror8(xw));
            a0 = step(a0, w0v, xu);
            a1 = step(a1, w1v, xu);
        }
        *y = [tail(a0, &w0[full..], xt), tail(a1, &w1[full..], xt)];
    }
    if let [y] = out_last {
        // An odd row count: the last row alone (`n ≥ 1` here, and `bias` holds `n` values).
        let acc = xs
            .iter()
            .zip(last.as_chunks().0)
            .fold(bias[n - 1], |a, (xv, wv)| {
                let xw = word(xv);
                step(a, wv, (sxtb16(xw), sxtb16_ror8(xw)))
            });
        *y = tail(acc, &last[full..], xt);
    }
}

/// [`super::reference::matmat_i8`] with [`matvec_i8`] per point (an MCU runs one point per
/// pass; there is no register room for more).
pub fn matmat_i8(w: &[i8], k: usize, x: &[i8], bias: &[i32], out: &mut [i32], out_stride: usize) {
    super::reference::matmat_by_rows(matvec_i8, w, k, x, bias, out, out_stride);
}

/// The DSP kernel table (see [`super::Kernels`]); only built where the instructions are real.
#[cfg(all(target_arch = "arm", feature = "arm-dsp"))]
pub(super) const fn kernels() -> super::Kernels {
    let mut k = super::Kernels::reference();
    k.isa = super::Isa::ArmDsp;
    k.i8 = matvec_i8;
    k.i8mm = matmat_i8;
    k
}

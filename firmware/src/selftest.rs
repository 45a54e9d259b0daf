//! Boot self-test of the int8 kernels the firmware runs ([`Kernels::best`]: with the `arm-dsp`
//! feature, `SXTB16` + `SMLAD` in inline assembly) against the portable reference, on the real
//! instructions. The host tests the same kernel code on emulated instructions; this is where
//! the instructions themselves are checked. `tests/firmware_qemu.rs` asserts the report.

use evpose_core::kernels::{self, reference, Kernels};

/// Widest `K` and most rows of the random cases.
const MAX_K: usize = 70;
const MAX_ROWS: usize = 9;

/// Most points of the matmat cases (row-major and widened weights): two blocks of
/// `BLOCK_POINTS` and a remainder.
const MAX_POINTS: usize = 2 * kernels::arm::BLOCK_POINTS + 1;
/// `K` of the matmat cases: below, at and across the blocked kernel's
/// 128-input chunk, with tails, and every count of steps of four modulo four.
const MM_K: [usize; 9] = [1, 4, 7, 10, 16, 127, 128, 131, 260];
/// The widest of them.
const MM_MAX_K: usize = 260;

/// An array on a 4-byte boundary.
#[repr(align(4))]
struct Words<T>(T);

/// What the self-test found.
pub struct Report {
    /// matvec (i8 and i16), matmat, pooling and requantization calls compared.
    pub cases: u32,
    /// Calls whose outputs differ from the reference's in any element.
    pub mismatches: u32,
}

/// xorshift32: deterministic values, no dependency.
struct Rng(u32);

impl Rng {
    // Not inlined: the array fills would otherwise be unrolled into tens of KiB of flash.
    #[inline(never)]
    fn next(&mut self) -> u32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 17;
        self.0 ^= self.0 << 5;
        self.0
    }
}

/// `s[..n]` without a panic path: every `n` here is within its array; the `min` lets the
/// compiler see that.
fn head<T>(s: &[T], n: usize) -> &[T] {
    &s[..n.min(s.len())]
}

/// `&mut s[..n]` without a panic path ([`head`]).
fn head_mut<T>(s: &mut [T], n: usize) -> &mut [T] {
    let n = n.min(s.len());
    &mut s[..n]
}

/// `&mut s[from..]` without a panic path ([`head`]).
fn tail_mut<T>(s: &mut [T], from: usize) -> &mut [T] {
    let from = from.min(s.len());
    &mut s[from..]
}

/// Compares `k.matvec_i8` with the reference on every `K` in `0..=70` (every tail of a
/// four-byte step) by every row count in `1..=9` (pairs and an odd row), random values with the
/// extremes -128 and 127 mixed in and biases near the i32 limits (sums that wrap; the release
/// build's reference wraps too), and then every one of the 256 × 256 int8 products.
pub fn kernels(k: &Kernels) -> Report {
    let mut rng = Rng(0x9E37_79B9);
    let mut report = Report {
        cases: 0,
        mismatches: 0,
    };
    let mut check = |w: &[i8], x: &[i8], bias: &[i32], rows: usize| {
        let (mut got, mut want) = ([0i32; 256], [0i32; 256]);
        k.matvec_i8(w, x, bias, head_mut(&mut got, rows));
        if x.is_empty() {
            for (o, &b) in want.iter_mut().zip(bias).take(rows) {
                *o = b;
            }
        } else {
            reference::matvec_i8(w, x, bias, head_mut(&mut want, rows));
        }
        report.cases += 1;
        if head(&got, rows) != head(&want, rows) {
            report.mismatches += 1;
        }
    };
    let value = |rng: &mut Rng| match rng.next() % 8 {
        0 => i8::MIN,
        1 => i8::MAX,
        _ => rng.next() as i8,
    };
    for kk in 0..=MAX_K {
        for rows in 1..=MAX_ROWS {
            let mut w = [0i8; MAX_K * MAX_ROWS];
            let mut x = [0i8; MAX_K];
            let mut bias = [0i32; MAX_ROWS];
            w.iter_mut().for_each(|v| *v = value(&mut rng));
            x.iter_mut().for_each(|v| *v = value(&mut rng));
            // Every third bias within 2^20 of an i32 limit, so that sums wrap (SMLAD's
            // overflow, which sets the Q flag, must still give the residue modulo 2^32).
            bias.iter_mut().for_each(|v| {
                let r = rng.next();
                *v = match r % 3 {
                    0 => i32::MAX - (r >> 12) as i32,
                    1 => i32::MIN + (r >> 12) as i32,
                    _ => r as i32,
                }
            });
            check(head(&w, rows * kk), head(&x, kk), head(&bias, rows), rows);
        }
    }
    // Every product: one row per weight value, K = 5 (a step and a tail), x one value at a time.
    let mut w = [0i8; 256 * 5];
    for (row, v) in w.chunks_exact_mut(5).zip(i8::MIN..=i8::MAX) {
        row.fill(v);
    }
    let bias = [0i32; 256];
    for v in i8::MIN..=i8::MAX {
        check(&w, &[v; 5], &bias, 256);
    }
    // The blocked matmat (four points per weight load): every point count up to two blocks and
    // a remainder, `K` across chunk boundaries, rows 1..=3, output rows 3 apart (gaps stay
    // untouched), against the reference matvec point by point.
    for &kk in &MM_K {
        for points in 1..=MAX_POINTS {
            for rows in 1..=3 {
                let stride = rows + 3;
                let mut w = [0i8; MM_MAX_K * 3];
                let mut x = [0i8; MM_MAX_K * MAX_POINTS];
                let mut bias = [0i32; 3];
                w.iter_mut().for_each(|v| *v = value(&mut rng));
                x.iter_mut().for_each(|v| *v = value(&mut rng));
                bias.iter_mut().for_each(|v| *v = rng.next() as i32);
                let (mut got, mut want) = (
                    [0x5A5A_5A5Ai32; 6 * MAX_POINTS],
                    [0x5A5A_5A5Ai32; 6 * MAX_POINTS],
                );
                let (w, x, bias) = (
                    head(&w, rows * kk),
                    head(&x, points * kk),
                    head(&bias, rows),
                );
                k.matmat_i8(w, kk, x, bias, &mut got, stride);
                for (p, xp) in x.chunks_exact(kk.max(1)).enumerate() {
                    reference::matvec_i8(
                        w,
                        xp,
                        bias,
                        head_mut(tail_mut(&mut want, p * stride), rows),
                    );
                }
                report.cases += 1;
                if got != want {
                    report.mismatches += 1;
                }
                // The same over the weights widened (`LDRD` of the halfword pairs).
                let mut ww = [0u32; MM_MAX_K / 2 * 3];
                let widened = kernels::arm::widen_i8(w, rows, kk, &mut ww).unwrap_or(0);
                let mut got = [0x5A5A_5A5Ai32; 6 * MAX_POINTS];
                kernels::arm::matmat_widened_i8(
                    head(&ww, widened),
                    w,
                    kk,
                    x,
                    bias,
                    &mut got,
                    stride,
                );
                report.cases += 1;
                if got != want || widened != rows * kernels::arm::widened_row_words(kk) {
                    report.mismatches += 1;
                }
            }
        }
    }
    // Max and sum pooling (four channels per SSUB8/SEL step): every length up to 9 and 128,
    // extremes mixed in, sums near the i32 limits.
    for len in (0..=9).chain([128]) {
        let (mut max, mut sum, mut y) = ([0i8; 128], [0i32; 128], [0i8; 128]);
        max.iter_mut().for_each(|v| *v = value(&mut rng));
        y.iter_mut().for_each(|v| *v = value(&mut rng));
        sum.iter_mut()
            .for_each(|v| *v = i32::MAX - (rng.next() % 256) as i32);
        let (mut m, mut s) = (max, sum);
        k.pool_i8(head_mut(&mut m, len), head_mut(&mut s, len), head(&y, len));
        reference::pool_i8(
            head_mut(&mut max, len),
            head_mut(&mut sum, len),
            head(&y, len),
        );
        report.cases += 1;
        if (m, s) != (max, sum) {
            report.mismatches += 1;
        }
    }
    // The reference table's kernels, called through its function pointers: inlined here,
    // the unrolled reference loops cost the image tens of KiB of flash.
    let reference = Kernels::reference();
    // The i16 matvec (SMLAD on the stored halfwords; the 15-bit heads and the first layer):
    // every `K` up to 70 (steps of four and their tails) by 1 to 9 rows, full-range values
    // (sums that wrap modulo 2^32; the release build's reference wraps too).
    for kk in 1..=MAX_K {
        for rows in 1..=MAX_ROWS {
            // Word-aligned, so that `K` a multiple of four takes the LDRD loop (the heads'
            // case) and every other `K` the Rust one.
            let (mut wa, mut xa) = (Words([0i16; MAX_K * MAX_ROWS]), Words([0i16; MAX_K]));
            let (w, x) = (&mut wa.0, &mut xa.0);
            let mut bias = [0i32; MAX_ROWS];
            let half = |rng: &mut Rng| match rng.next() % 8 {
                0 => i16::MIN,
                1 => i16::MAX,
                _ => rng.next() as i16,
            };
            w.iter_mut().for_each(|v| *v = half(&mut rng));
            x.iter_mut().for_each(|v| *v = half(&mut rng));
            bias.iter_mut().for_each(|v| *v = rng.next() as i32);
            let (w, x, bias) = (head(&w[..], rows * kk), head(&x[..], kk), head(&bias, rows));
            let (mut got, mut want) = ([0i32; MAX_ROWS], [0i32; MAX_ROWS]);
            k.matvec_i16(w, x, bias, head_mut(&mut got, rows));
            reference.matvec_i16(w, x, bias, head_mut(&mut want, rows));
            report.cases += 1;
            if got != want {
                report.mismatches += 1;
            }
        }
    }
    // Lengths that disagree (more weight rows than biases, fewer outputs, and the reverse):
    // the kernels compute the rows the reference visits, in the LDRD loop and in Rust.
    for kk in [8, 32, 6] {
        for (w_rows, b_len, o_len) in [(5, 4, 3), (4, 5, 4), (3, 3, 2), (6, 2, 5)] {
            let (mut wa, mut xa) = (Words([0i16; 32 * 6]), Words([0i16; 32]));
            wa.0.iter_mut().for_each(|v| *v = rng.next() as i16);
            xa.0.iter_mut().for_each(|v| *v = rng.next() as i16);
            let bias = [rng.next() as i32; 6];
            let (w, x, bias) = (
                head(&wa.0, w_rows * kk),
                head(&xa.0, kk),
                head(&bias, b_len),
            );
            let (mut got, mut want) = ([0x5A5A_5A5Ai32; 6], [0x5A5A_5A5Ai32; 6]);
            k.matvec_i16(w, x, bias, head_mut(&mut got, o_len));
            reference.matvec_i16(w, x, bias, head_mut(&mut want, o_len));
            report.cases += 1;
            if got != want {
                report.mismatches += 1;
            }
        }
    }
    // Requantization (VCVT, VMUL, then VMAXNM and VCVTN on the M7's FPv5, or VCMP, a
    // conditional VMUL and VCVTR on an M4's FPv4; SSAT): every accumulator in ±2^13 at eight
    // scales, and random ones over the whole i32 range at random scales, each with no
    // LeakyReLU, PyTorch's slope, the max form's edges 0 and 1, and a slope it leaves to the
    // reference (on FPv4 slope 0 too); lengths 1 to 4 and 37 (the four-output steps and their
    // tails).
    let mut check_requant = |acc: &[i32], scales: &[f32]| {
        for leaky in [None, Some(0.01f32), Some(0.0), Some(1.0), Some(1.5)] {
            let (mut got, mut want) = ([0i8; 64], [0i8; 64]);
            let n = acc.len();
            k.requantize_i8(acc, scales, leaky, head_mut(&mut got, n));
            reference.requantize_i8(acc, scales, leaky, head_mut(&mut want, n));
            report.cases += 1;
            if got != want {
                report.mismatches += 1;
            }
        }
    };
    // Scales where ties occur, then zero, negative and huge ones (products of ±inf, and
    // ±inf · 0 = NaN at slope 0, which VMAXNM must resolve to the number).
    for scale in [
        0.5f32,
        0.25,
        0.003_137_254_9,
        1.0,
        0.0,
        -0.5,
        f32::MAX,
        -f32::MAX,
    ] {
        let mut acc = [0i32; 64];
        let mut a = -(1 << 13);
        while a < (1 << 13) {
            acc.iter_mut()
                .enumerate()
                .for_each(|(i, v)| *v = a + i as i32);
            check_requant(&acc, &[scale; 64]);
            a += 64;
        }
    }
    for len in [1, 2, 3, 4, 37] {
        for _ in 0..8 {
            let (mut acc, mut scales) = ([0i32; 64], [0f32; 64]);
            acc.iter_mut()
                .for_each(|v| *v = rng.next() as i32 >> (rng.next() % 32));
            // Scales 2^-20..2^4 with random mantissas.
            scales
                .iter_mut()
                .for_each(|v| *v = f32::from_bits((107 + rng.next() % 24) << 23 | rng.next() >> 9));
            check_requant(head(&acc, len), head(&scales, len));
        }
    }
    report
}

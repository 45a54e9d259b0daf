//! Boot self-test of the int8 kernels the firmware runs ([`Kernels::best`]: with the `arm-dsp`
//! feature, `SXTB16` + `SMLAD` in inline assembly) against the portable reference, on the real
//! instructions. The host tests the same kernel code on emulated instructions; this is where
//! the instructions themselves are checked. `tests/firmware_qemu.rs` asserts the report.

use evpose_core::kernels::{reference, Kernels};

/// Widest `K` and most rows of the random cases.
const MAX_K: usize = 70;
const MAX_ROWS: usize = 9;

/// What the self-test found.
pub struct Report {
    /// matvec calls compared.
    pub cases: u32,
    /// Calls whose outputs differ from the reference's in any element.
    pub mismatches: u32,
}

/// xorshift32: deterministic values, no dependency.
struct Rng(u32);

impl Rng {
    fn next(&mut self) -> u32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 17;
        self.0 ^= self.0 << 5;
        self.0
    }
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
        k.matvec_i8(w, x, bias, &mut got[..rows]);
        if x.is_empty() {
            want[..rows].copy_from_slice(&bias[..rows]);
        } else {
            reference::matvec_i8(w, x, bias, &mut want[..rows]);
        }
        report.cases += 1;
        if got[..rows] != want[..rows] {
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
            check(&w[..rows * kk], &x[..kk], &bias[..rows], rows);
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
    report
}

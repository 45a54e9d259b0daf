//! Joint confidence from the SimDR distributions: how much of each axis' softmax mass lies near
//! its argmax.
//!
//! Per joint and axis, the logits `l` (f32 logits, or the int8 engine's accumulators times the
//! head's logit scale, [`crate::Model::head_scales`]) give a softmax `p`; the axis confidence is
//! the mass within [`RADIUS`] bins of the decoded coordinate `a`:
//! `c = Σ_{|i − a| ≤ R} p_i`. A network that learnt the task puts a label-shaped bump there
//! (σ = 8 bins, so about 0.68 for a perfect one), a network that sees no body spreads its mass
//! (a uniform softmax over 346 bins gives 17 / 346 ≈ 0.05). The joint's confidence is the
//! geometric mean of its two axes, in [0, 1].
//!
//! Fixed memory, no allocation; `f32` arithmetic alone (the exponential is [`exp`]), evaluated
//! in a fixed order, so the firmware and the host compute the same bits. For int8 heads the
//! differences to the peak are taken in integers (exact) before the one conversion to f32.

use crate::simdr::{Joint2d, ShapeError};

/// Half-width, in bins, of the window around the argmax whose softmax mass is the confidence:
/// the SimDR label's σ.
pub const RADIUS: usize = 8;

/// A head output type: f32 logits or int32 accumulators.
pub trait HeadValue: Copy + PartialOrd {
    /// `(self − peak) × scale` as f32 (≤ 0 when `peak` is the maximum).
    fn below(self, peak: Self, scale: f32) -> f32;

    /// [`HeadValue::below`] in straight-line code that a compiler can run on vectors, and
    /// whether that code may have differed from it (then the caller computes `below` again).
    #[inline(always)]
    fn below_fast(self, peak: Self, scale: f32) -> (f32, bool) {
        (self.below(peak, scale), false)
    }
}

impl HeadValue for f32 {
    #[inline(always)]
    fn below(self, peak: f32, scale: f32) -> f32 {
        (self - peak) * scale
    }
}

impl HeadValue for i32 {
    /// The difference in i32 and a flag where it overflowed (then `below` takes it in i64).
    #[inline(always)]
    fn below_fast(self, peak: i32, scale: f32) -> (f32, bool) {
        let d = self.wrapping_sub(peak);
        // Signed overflow: the operands' signs differ and the result's differs from `self`'s.
        let overflow = (self ^ peak) & (self ^ d) < 0;
        (d as f32 * scale, overflow)
    }

    #[inline]
    fn below(self, peak: i32, scale: f32) -> f32 {
        // The exact difference, converted once: in i32 where it fits (one `VCVT` on a
        // Cortex-M, where i64 → f32 is a library call), else in i64 (at most 2^32 in
        // magnitude). The same integer, so the same f32.
        match self.checked_sub(peak) {
            Some(d) => d as f32 * scale,
            None => (i64::from(self) - i64::from(peak)) as f32 * scale,
        }
    }
}

/// `ln(2^−126)`: below it [`exp`]'s `2^k` would not be a normal f32 (and `exp` gives 0).
const EXP_MIN_ARG: f32 = -87.336_54;

/// `e^x` in `f32` arithmetic alone, within 1 ulp of the correctly rounded result for every
/// normal result (`tests::exp_is_within_one_ulp`: every f32 above 88 and around each step of
/// `k`, and a grid over the rest). It replaced `libm::expf` (also within 1 ulp, with more
/// special cases): the firmware's confidences went from 0.75 M to 0.31 M instructions per
/// window on the Cortex-M7 (96 → 40 per logit).
///
/// `x = k·ln 2 + r` with `k` the integer nearest `x·log₂e` (the requantization's magic-number
/// rounding, [`crate::quant::round_to_i32`]) and `r = x − k·ln 2` in two steps (Cody–Waite: `ln 2`'s leading 9 bits make
/// `k·LN2_HI` exact for `|k| < 2^15`), so `|r| ≤ 0.35`; `e^r` is its Taylor polynomial of
/// degree 7 (truncation below `0.35^8 / 8! < 5.5·10^−9`, about a tenth of an ulp), and `2^k`
/// is built from its exponent bits (in two exact steps where `k = 128`). Results below the
/// smallest normal f32 (`x < −87.3365`, `e^x < 1.2·10^−38`) are 0: a softmax term that small is
/// nothing beside the peak's 1. NaN gives NaN; results are finite up to `x = 88.7228`. Not
/// monotone to the last ulp (the rounding errors of neighbouring arguments differ).
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    /// Above `ln(f32::MAX)` the result is infinite.
    const MAX_ARG: f32 = 88.722_84;
    if (EXP_MIN_ARG..=88.0).contains(&x) {
        let (p, k) = exp_parts(x);
        // `2^k`, exactly (k in [−126, 127]); the product is exact.
        return p * f32::from_bits(((k + 127) as u32) << 23);
    }
    if x.is_nan() || x > MAX_ARG {
        return x + f32::INFINITY; // NaN stays NaN
    }
    if x > 88.0 {
        // `k` is 127 or 128, and 2^128 is not a finite f32: `2^(k−1)`, then 2.
        let (p, k) = exp_parts(x);
        return p * f32::from_bits(((k + 126) as u32) << 23) * 2.0;
    }
    0.0
}

/// [`exp`] in straight-line code for `x ≤ 88` (the same operations on the same values, so the
/// same bits: [`exp`]'s first branch, or 0 below its range), and whether `x` lay outside that
/// (above 88, or NaN: then the caller takes [`exp`]). Without branches, a block of them runs
/// on vectors.
#[inline(always)]
fn exp_low(x: f32) -> (f32, bool) {
    // Clamped into the first branch's range, so that `2^k` is a normal f32 in every lane; a
    // lane below it is then set to 0, as `exp` gives.
    let c = crate::quant::at_most(crate::quant::at_least(x, EXP_MIN_ARG), 88.0);
    let (p, k) = exp_parts(c);
    let e = p * f32::from_bits(((k + 127) as u32) << 23);
    (
        if x >= EXP_MIN_ARG { e } else { 0.0 },
        x > 88.0 || x.is_nan(),
    )
}

/// Softmax terms per block: [`exp_low`] over [`HeadValue::below_fast`], with the exact path
/// taken again for a block where either said so.
const TERMS_BLOCK: usize = 32;

/// Whether [`add_terms`] computes its terms a block at a time: where the compiler has vectors
/// for them (x86-64, AArch64). A Cortex-M has none, and the block's stores and flags made its
/// confidences 46 % more instructions (311,800 → 455,240 per window on the M7): it computes one
/// term at a time, the same bits (the QEMU test compares the firmware's confidences with the
/// host's).
const BLOCKED_TERMS: bool = cfg!(any(target_arch = "x86_64", target_arch = "aarch64"));

/// `(all, near)` plus the softmax terms `exp(v.below(peak, scale))` of `values`, added one at a
/// time in order (`near` too, with `window`). With [`BLOCKED_TERMS`] the terms come a block at
/// a time from branch-free code (vectorized; the same bits, [`exp_low`]) before the in-order
/// sums (perf over `evpose bench pipeline`: 11.3 % of a run before, 4.4 % after).
#[inline(always)]
fn add_terms<T: HeadValue>(
    values: &[T],
    peak: T,
    scale: f32,
    (mut all, mut near): (f32, f32),
    window: bool,
) -> (f32, f32) {
    if !BLOCKED_TERMS {
        for &v in values {
            let t = exp(v.below(peak, scale));
            all += t;
            if window {
                near += t;
            }
        }
        return (all, near);
    }
    for block in values.chunks(TERMS_BLOCK) {
        let mut terms = [0f32; TERMS_BLOCK];
        let mut exact = false;
        for (t, &v) in terms.iter_mut().zip(block) {
            let (x, odd) = v.below_fast(peak, scale);
            let (e, out) = exp_low(x);
            *t = e;
            exact |= odd | out;
        }
        if exact {
            for (t, &v) in terms.iter_mut().zip(block) {
                *t = exp(v.below(peak, scale));
            }
        }
        for &t in terms.iter().take(block.len()) {
            all += t;
            if window {
                near += t;
            }
        }
    }
    (all, near)
}

/// `(p, k)` with `e^x ≈ p · 2^k`, `p = e^r` in `[0.70, 1.42]`, for `x` in `[MIN_ARG, MAX_ARG]`
/// (`k` in [−126, 128]).
#[inline(always)]
fn exp_parts(x: f32) -> (f32, i32) {
    /// `ln 2` to 9 significant bits (355/512) and the rest.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // The integer nearest `x·log₂e` (half to even; `|x·log₂e| ≤ 128`), as an i32 and as an
    // f32: both from the one sum with the magic number (the compiler computes it once).
    let y = x * core::f32::consts::LOG2_E;
    let (k, kf) = (
        crate::quant::round_to_i32(y),
        crate::quant::round_half_even(y),
    );
    let r = (x - kf * LN2_HI) - kf * LN2_LO;
    // 1 + r + r²/2! + … + r⁷/7!, by Horner.
    let mut p = 1.0 / 5040.0;
    for c in [
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        p = p * r + c;
    }
    (p, k)
}

/// Softmax mass of `logits` within [`RADIUS`] bins of `at` (an index of the maximum), with
/// logits scaled by `scale`.
pub fn axis<T: HeadValue>(logits: &[T], at: usize, scale: f32) -> f32 {
    let Some(&peak) = logits.get(at) else {
        return 0.0;
    };
    // The bins before the window, the window, the bins after it: one sum over all of them in
    // order, and the window's own.
    let lo = at.saturating_sub(RADIUS);
    let hi = (at + RADIUS + 1).min(logits.len());
    // `lo ≤ at < hi ≤ len`: both splits succeed (checked, so no panic path is linked).
    let Some((before, rest)) = logits.split_at_checked(lo) else {
        return 0.0;
    };
    let Some((window, after)) = rest.split_at_checked(hi - lo) else {
        return 0.0;
    };
    let sums = add_terms(before, peak, scale, (0.0, 0.0), false);
    let sums = add_terms(window, peak, scale, sums, true);
    let (all, near) = add_terms(after, peak, scale, sums, false);
    // `all` ≥ 1 (the peak's own term is exp(0) = 1), so the ratio is defined.
    near / all
}

/// Confidence of each decoded joint in `joints` (from `x`, `J × width`, and `y`, `J × height`,
/// row-major, as [`crate::decode`] reads them) into `out`, exactly `J` long; `scales` = `[x, y]`
/// logit scales ([`crate::Model::head_scales`]). Lengths that differ (or sizes whose product
/// does not fit a `usize`) are a [`ShapeError`].
pub fn joints<T: HeadValue>(
    x: &[T],
    y: &[T],
    width: usize,
    height: usize,
    scales: [f32; 2],
    joints: &[Joint2d],
    out: &mut [f32],
) -> Result<(), ShapeError> {
    let n = joints.len();
    if width == 0 || height == 0 {
        return Err(ShapeError::Axis(0));
    }
    let xs = n.checked_mul(width).ok_or(ShapeError::Axis(width))?;
    let ys = n.checked_mul(height).ok_or(ShapeError::Axis(height))?;
    for (got, want) in [(x.len(), xs), (y.len(), ys), (out.len(), n)] {
        if got != want {
            return Err(ShapeError::Length {
                expected: want,
                got,
            });
        }
    }
    for (((c, j), xs), ys) in out
        .iter_mut()
        .zip(joints)
        .zip(x.chunks_exact(width))
        .zip(y.chunks_exact(height))
    {
        let cx = axis(xs, usize::from(j.x), scales[0]);
        let cy = axis(ys, usize::from(j.y), scales[1]);
        *c = libm::sqrtf(cx * cy);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_whose_product_overflows_are_shape_errors() {
        let joints = [Joint2d::default(); 2];
        let mut out = [0f32; 2];
        let r = self::joints(
            &[0f32; 0],
            &[0f32; 2],
            1 << 63,
            1,
            [1.0; 2],
            &joints,
            &mut out,
        );
        assert_eq!(r, Err(ShapeError::Axis(1 << 63)));
    }

    /// Distance in ulp between `got` and the f32 nearest `want` (both finite and positive).
    fn ulps(got: f32, want: f64) -> u32 {
        got.to_bits().abs_diff((want as f32).to_bits())
    }

    #[test]
    fn exp_is_within_one_ulp() {
        // A grid over the whole normal range (every 2^-10 natively, fewer under Miri), every
        // f32 around each step of `k` (where |r| is largest) and around 0, and every f32
        // above 88 (the two-step scaling; 94,700 arguments natively).
        let (mut worst, mut at) = (0, 0.0);
        let mut check = |x: f32| {
            let u = ulps(exp(x), libm::exp(f64::from(x)));
            if u > worst {
                (worst, at) = (u, x);
            }
        };
        let step = if cfg!(miri) { 1.0 / 16.0 } else { 1.0 / 1024.0 };
        let mut x = -87.3f64;
        while x < 88.0 {
            check(x as f32);
            x += step;
        }
        let around = if cfg!(miri) { 16 } else { 4096 };
        for k in -126..=127 {
            let edge = ((f64::from(k) + 0.5) * core::f64::consts::LN_2) as f32;
            for d in -around..=around {
                check(f32::from_bits(edge.to_bits().wrapping_add_signed(d)));
            }
        }
        for d in 0..around as u32 {
            check(f32::from_bits(d));
            check(-f32::from_bits(d));
        }
        let top = if cfg!(miri) { 997 } else { 1 };
        let mut b = 88.0f32.to_bits() + 1;
        while f32::from_bits(b) <= 88.722_84 {
            check(f32::from_bits(b));
            b += top;
        }
        assert!(worst <= 1, "{worst} ulp at {at}");
    }

    #[test]
    fn exp_has_ieee_edges() {
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(-0.0), 1.0);
        assert_eq!(exp(f32::NEG_INFINITY), 0.0);
        assert_eq!(exp(-87.34), 0.0, "below the smallest normal result");
        assert!(exp(-87.33) > 0.0);
        assert_eq!(exp(88.73), f32::INFINITY);
        assert_eq!(exp(f32::INFINITY), f32::INFINITY);
        assert!(exp(f32::NAN).is_nan());
        // The top of the range (`k = 128`, scaled in two steps).
        let top = exp(88.72);
        assert!(
            top.is_finite() && ulps(top, libm::exp(88.72f32.into())) <= 1,
            "{top}"
        );
        // Monotone across a step of `k` and across the start of the two-step scaling.
        for x in [0.5 * core::f32::consts::LN_2, 88.0] {
            let b = x.to_bits();
            assert!(exp(f32::from_bits(b - 1)) <= exp(x) && exp(x) <= exp(f32::from_bits(b + 1)));
        }
    }

    #[test]
    fn a_label_shaped_bump_is_confident_and_a_flat_axis_is_not() {
        // A Gaussian bump of σ = 8 bins as log-probabilities: the 17 bins within σ hold 0.712
        // of the mass (0.683 for the continuous Gaussian, plus the endpoints).
        let bump: [f32; 346] = core::array::from_fn(|i| -((i as f32 - 100.0) / 8.0).powi(2) / 2.0);
        let g = |k: f64| libm::exp(-(k / 8.0) * (k / 8.0) / 2.0);
        let want = (-8..=8).map(|k| g(f64::from(k))).sum::<f64>()
            / (0..346).map(|i| g(f64::from(i) - 100.0)).sum::<f64>();
        let c = axis(&bump, 100, 1.0);
        assert!(
            (f64::from(c) - want).abs() < 1e-5 && (0.70..0.72).contains(&c),
            "{c}"
        );
        let flat = [0.5f32; 346];
        assert!((axis(&flat, 0, 1.0) - 9.0 / 346.0).abs() < 1e-6);
        assert!((axis(&flat, 100, 1.0) - 17.0 / 346.0).abs() < 1e-6);
        // A sharp peak: all the mass.
        let mut sharp = [0f32; 260];
        sharp[7] = 100.0;
        assert!((axis(&sharp, 7, 1.0) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn int8_accumulators_match_their_dequantized_logits() {
        let acc: [i32; 64] = core::array::from_fn(|i| (i as i32 - 20).pow(2) * -37 + 1000);
        let scale = 0.0123f32;
        let logits: [f32; 64] = core::array::from_fn(|i| acc[i] as f32 * scale);
        let (a, b) = (axis(&acc, 20, scale), axis(&logits, 20, 1.0));
        assert!((a - b).abs() < 1e-5, "{a} {b}");
    }

    #[test]
    fn the_blocked_exponential_is_exp_bit_for_bit() {
        // Every f32 from -128 to 128 in steps of 2^12 ulps, both neighbours of each edge of the
        // range, and the IEEE specials: where `exp_low` does not hand over to `exp`, the same
        // bits.
        let mut xs = vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            -f32::MAX,
        ];
        for edge in [EXP_MIN_ARG, 88.0, -88.0] {
            let b = edge.to_bits();
            xs.extend((b - 3..=b + 3).map(f32::from_bits));
        }
        let mut b = 0u32;
        while b < 0x4300_0000 {
            xs.extend([f32::from_bits(b), -f32::from_bits(b)]);
            b += 1 << 12;
        }
        let mut handed_over = 0;
        for x in xs {
            let (e, out) = exp_low(x);
            if out {
                handed_over += 1;
                assert!(x > 88.0 || x.is_nan(), "{x} handed over");
            } else {
                assert_eq!(e.to_bits(), exp(x).to_bits(), "exp({x})");
            }
        }
        assert!(handed_over > 0);
    }

    #[test]
    fn fast_differences_are_the_exact_ones_or_say_so() {
        let values = [
            i32::MIN,
            i32::MIN + 1,
            -70_000,
            -1,
            0,
            1,
            123_456,
            i32::MAX - 1,
            i32::MAX,
        ];
        for &v in &values {
            for &peak in &values {
                let (d, odd) = v.below_fast(peak, 0.37);
                let overflows = v.checked_sub(peak).is_none();
                assert_eq!(odd, overflows, "{v} - {peak}");
                if !odd {
                    assert_eq!(d.to_bits(), v.below(peak, 0.37).to_bits(), "{v} - {peak}");
                }
            }
        }
    }

    /// `axis` as it was before the blocked terms: one term at a time, in order.
    fn axis_one_by_one<T: HeadValue>(logits: &[T], at: usize, scale: f32) -> f32 {
        let peak = logits[at];
        let (lo, hi) = (
            at.saturating_sub(RADIUS),
            (at + RADIUS + 1).min(logits.len()),
        );
        let (mut all, mut near) = (0f32, 0f32);
        for (i, &v) in logits.iter().enumerate() {
            let e = exp(v.below(peak, scale));
            all += e;
            if (lo..hi).contains(&i) {
                near += e;
            }
        }
        near / all
    }

    #[test]
    fn blocked_terms_sum_like_one_by_one() {
        // Lengths across several blocks, peaks near either end and across block edges, logits
        // whose terms underflow, and int8 accumulators whose differences overflow i32 (the
        // exact path) or come close.
        use rand_core::RngCore;
        let mut rng = crate::sample::rng_from_seed(0x2545_F491_4F6C_DD1D);
        let mut next = move || rng.next_u64();
        for len in [1usize, 17, 31, 32, 33, 64, 100, 346] {
            for at in [0, len / 3, len / 2, len - 1] {
                let acc: Vec<i32> = (0..len)
                    .map(|_| match next() % 8 {
                        0 => i32::MIN + (next() % 5) as i32,
                        1 => i32::MAX - (next() % 5) as i32,
                        _ => (next() % 2_000_000) as i32 - 1_000_000,
                    })
                    .collect();
                for scale in [1e-5, 3e-4, 0.1] {
                    let (got, want) = (axis(&acc, at, scale), axis_one_by_one(&acc, at, scale));
                    assert_eq!(got.to_bits(), want.to_bits(), "len {len}, at {at}, {scale}");
                }
                let logits: Vec<f32> = acc.iter().map(|&a| a as f32 * 1e-4).collect();
                let (got, want) = (axis(&logits, at, 1.0), axis_one_by_one(&logits, at, 1.0));
                assert_eq!(got.to_bits(), want.to_bits(), "f32, len {len}, at {at}");
            }
        }
        // NaN logits take the exact path and give what it gives.
        let nan = [0.0, f32::NAN, 1.0];
        assert_eq!(
            axis(&nan, 2, 1.0).to_bits(),
            axis_one_by_one(&nan, 2, 1.0).to_bits()
        );
    }

    #[test]
    fn joints_checks_shapes_and_combines_the_axes() {
        let x = [0f32; 2 * 10];
        let y = [0f32; 2 * 5];
        let j = [Joint2d { x: 0, y: 0 }; 2];
        let mut out = [0f32; 2];
        joints(&x, &y, 10, 5, [1.0; 2], &j, &mut out).unwrap();
        // Flat axes: x keeps 9 of 10 bins (0..=8), y all 5: sqrt(0.9 × 1).
        assert!((out[0] - 0.9f32.sqrt()).abs() < 1e-6);
        let mut short = [0f32; 1];
        assert!(joints(&x, &y, 10, 5, [1.0; 2], &j, &mut short).is_err());
        assert!(joints(&x[..19], &y, 10, 5, [1.0; 2], &j, &mut out).is_err());
    }
}

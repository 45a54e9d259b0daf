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
//! Fixed memory, no allocation; `f32` with `libm::expf`, evaluated in a fixed order, so the
//! firmware and the host compute the same bits. For int8 heads the differences to the peak are
//! taken in integers (exact) before the one conversion to f32.

use crate::simdr::{Joint2d, ShapeError};

/// Half-width, in bins, of the window around the argmax whose softmax mass is the confidence:
/// the SimDR label's σ.
pub const RADIUS: usize = 8;

/// A head output type: f32 logits or int32 accumulators.
pub trait HeadValue: Copy + PartialOrd {
    /// `(self − peak) × scale` as f32 (≤ 0 when `peak` is the maximum).
    fn below(self, peak: Self, scale: f32) -> f32;
}

impl HeadValue for f32 {
    fn below(self, peak: f32, scale: f32) -> f32 {
        (self - peak) * scale
    }
}

impl HeadValue for i32 {
    fn below(self, peak: i32, scale: f32) -> f32 {
        // Exact in i64; the difference of two accumulators is at most 2^32 in magnitude.
        (i64::from(self) - i64::from(peak)) as f32 * scale
    }
}

/// Softmax mass of `logits` within [`RADIUS`] bins of `at` (an index of the maximum), with
/// logits scaled by `scale`.
pub fn axis<T: HeadValue>(logits: &[T], at: usize, scale: f32) -> f32 {
    let Some(&peak) = logits.get(at) else {
        return 0.0;
    };
    let (lo, hi) = (at.saturating_sub(RADIUS), at + RADIUS);
    let (mut near, mut all) = (0f32, 0f32);
    for (i, &v) in logits.iter().enumerate() {
        let e = libm::expf(v.below(peak, scale));
        all += e;
        if (lo..=hi).contains(&i) {
            near += e;
        }
    }
    // `all` ≥ 1 (the peak's own term is exp(0) = 1), so the ratio is defined.
    near / all
}

/// Confidence of each decoded joint in `joints` (from `x`, `J × width`, and `y`, `J × height`,
/// row-major, as [`crate::decode`] reads them) into `out[..J]`; `scales` = `[x, y]` logit
/// scales ([`crate::Model::head_scales`]).
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
    for (got, want) in [(x.len(), n * width), (y.len(), n * height), (out.len(), n)] {
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

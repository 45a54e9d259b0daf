//! SimDR: per-joint 1-D coordinate classification (Li et al., 2022), as used by the paper.
//!
//! Labels: a Gaussian over the pixel axis (σ = 8) centred at `int(coord + 0.5)`, min-max
//! normalized to `[0, 1]`; a joint whose `±3σ` box lies entirely outside the image has weight 0.
//! Decoding: the argmax of each joint's `x` vector (length W) and `y` vector (length H); the
//! first index wins ties.

use core::fmt;

/// The paper's label width in pixels.
pub const SIGMA: f32 = 8.0;

/// A decoded 2-D joint, in pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Joint2d {
    /// Column (argmax of the `x` vector).
    pub x: u16,
    /// Row (argmax of the `y` vector).
    pub y: u16,
}

/// Logit or output buffers whose lengths do not match the stated shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ShapeError {
    /// A buffer holds `got` values where `expected` were needed.
    Length {
        /// Values needed.
        expected: usize,
        /// Values present.
        got: usize,
    },
    /// An axis of length 0 or above `u16::MAX + 1` cannot be decoded.
    Axis(usize),
}

impl fmt::Display for ShapeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Length { expected, got } => {
                write!(f, "expected {expected} values, got {got}")
            }
            Self::Axis(n) => write!(f, "axis length {n} is not in 1..=65536"),
        }
    }
}

impl core::error::Error for ShapeError {}

/// Index of the largest value; the first one wins ties. `None` for an empty slice.
///
/// Values that compare false with everything (NaN) never win; an all-NaN slice gives 0.
pub fn argmax<T: PartialOrd + Copy>(values: &[T]) -> Option<usize> {
    let (mut best_i, mut best) = (0, *values.first()?);
    for (i, &v) in values.iter().enumerate().skip(1) {
        if v > best || (is_nan(best) && !is_nan(v)) {
            (best_i, best) = (i, v);
        }
    }
    Some(best_i)
}

/// Decodes `joints` joints from row-major logits `x` (`joints × width`) and `y`
/// (`joints × height`) into `out[..joints]`.
///
/// Works on f32 logits and on the int8 engine's i32 accumulators alike (the argmax of the
/// accumulators equals the argmax of the dequantized logits when the scale is positive).
pub fn decode<T: PartialOrd + Copy>(
    x: &[T],
    y: &[T],
    width: usize,
    height: usize,
    out: &mut [Joint2d],
) -> Result<(), ShapeError> {
    for axis in [width, height] {
        if axis == 0 || axis > usize::from(u16::MAX) + 1 {
            return Err(ShapeError::Axis(axis));
        }
    }
    let joints = out.len();
    // A product past usize (a 32-bit target) is a length no slice has.
    let len = |axis: usize| joints.checked_mul(axis).ok_or(ShapeError::Axis(axis));
    check_len(x.len(), len(width)?)?;
    check_len(y.len(), len(height)?)?;
    for ((joint, xs), ys) in out
        .iter_mut()
        .zip(x.chunks_exact(width))
        .zip(y.chunks_exact(height))
    {
        // Chunks are non-empty, so argmax is Some; indices are below 65536 (checked above).
        joint.x = argmax(xs).unwrap_or(0) as u16;
        joint.y = argmax(ys).unwrap_or(0) as u16;
    }
    Ok(())
}

/// True for values not equal to themselves (NaN).
#[allow(clippy::eq_op)]
fn is_nan<T: PartialOrd>(v: T) -> bool {
    v.partial_cmp(&v).is_none()
}

fn check_len(got: usize, expected: usize) -> Result<(), ShapeError> {
    if got == expected {
        Ok(())
    } else {
        Err(ShapeError::Length { expected, got })
    }
}

/// Whether a joint at `(x, y)` gets a label: false when its `±3σ` box lies entirely outside the
/// `width × height` image (the SimDR reference rule, with Python's truncating `int`), and for
/// a joint without a position (a NaN or infinite coordinate: DHP19's Vicon loses markers;
/// the reference's `int(nan)` raises instead of labelling pixel 0).
pub fn visible(x: f32, y: f32, width: usize, height: usize, sigma: f32) -> bool {
    if !(x.is_finite() && y.is_finite()) {
        return false;
    }
    let r = 3.0 * sigma;
    let (ul_x, ul_y) = ((x - r) as i64, (y - r) as i64);
    let (br_x, br_y) = ((x + r + 1.0) as i64, (y + r + 1.0) as i64);
    !(ul_x >= width as i64 || ul_y >= height as i64 || br_x < 0 || br_y < 0)
}

/// Writes the label vector of one axis: a Gaussian centred at `int(coord + 0.5)`, min-max
/// normalized to `[0, 1]` (1 at the centre when it lies inside the axis).
///
/// Accuracy: `libm::expf` (≤ 1 ulp), then one subtraction and one division in f32.
pub fn encode_axis(coord: f32, sigma: f32, out: &mut [f32]) {
    // Python's int() truncates toward zero.
    let centre = (coord + 0.5) as i64 as f32;
    let two_sigma_sq = 2.0 * sigma * sigma;
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for (i, v) in out.iter_mut().enumerate() {
        let d = i as f32 - centre;
        *v = libm::expf(-(d * d) / two_sigma_sq);
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    let range = hi - lo;
    for v in out.iter_mut() {
        *v = if range > 0.0 { (*v - lo) / range } else { 0.0 };
    }
}

/// Writes one joint's labels and returns its weight: 1 when visible, else 0 with zero vectors.
pub fn encode_joint(x: f32, y: f32, sigma: f32, out_x: &mut [f32], out_y: &mut [f32]) -> f32 {
    if !visible(x, y, out_x.len(), out_y.len(), sigma) {
        out_x.fill(0.0);
        out_y.fill(0.0);
        return 0.0;
    }
    encode_axis(x, sigma, out_x);
    encode_axis(y, sigma, out_y);
    1.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_joint_without_a_position_gets_no_label() {
        let (mut x, mut y) = ([1.0f32; 8], [1.0f32; 6]);
        for (u, v) in [
            (f32::NAN, 3.0),
            (3.0, f32::NAN),
            (f32::INFINITY, 2.0),
            (2.0, f32::NEG_INFINITY),
        ] {
            assert!(!visible(u, v, 8, 6, 2.0), "{u} {v}");
            assert_eq!(encode_joint(u, v, 2.0, &mut x, &mut y), 0.0, "{u} {v}");
            assert!(x.iter().chain(&y).all(|&l| l == 0.0));
        }
        assert_eq!(encode_joint(3.0, 2.0, 2.0, &mut x, &mut y), 1.0);
    }

    #[test]
    fn argmax_first_index_wins_ties() {
        assert_eq!(argmax(&[1, 5, 5, 2]), Some(1));
        assert_eq!(argmax(&[-3i32]), Some(0));
        assert_eq!(argmax::<i32>(&[]), None);
        assert_eq!(argmax(&[f32::NAN, 1.0, 0.5]), Some(1));
        assert_eq!(argmax(&[0.5, f32::NAN, 2.0]), Some(2));
        assert_eq!(argmax(&[f32::NAN, f32::NAN]), Some(0));
    }

    #[test]
    fn decode_picks_each_joint_row() {
        // 2 joints, width 4, height 3.
        let x = [0, 1, 9, 1, 7, 0, 0, 7];
        let y = [0, 1, 3, 2, 2, 1];
        let mut out = [Joint2d::default(); 2];
        decode(&x, &y, 4, 3, &mut out).unwrap();
        assert_eq!(out, [Joint2d { x: 2, y: 2 }, Joint2d { x: 0, y: 0 }]);
    }

    #[test]
    fn decode_rejects_bad_shapes() {
        let mut out = [Joint2d::default(); 2];
        assert_eq!(
            decode(&[0; 7], &[0; 6], 4, 3, &mut out),
            Err(ShapeError::Length {
                expected: 8,
                got: 7
            })
        );
        assert_eq!(
            decode(&[0; 0], &[0; 6], 0, 3, &mut out),
            Err(ShapeError::Axis(0))
        );
    }

    #[test]
    fn encode_matches_hand_computed_values() {
        // coord 3.4 -> centre int(3.9) = 3; width 8, sigma 2.
        // g(i) = exp(-(i-3)^2 / 8); min at i = 7: exp(-2); max 1 at i = 3.
        let mut v = [0f32; 8];
        encode_axis(3.4, 2.0, &mut v);
        let g = |d: f64| (-(d * d) / 8.0).exp();
        let lo = g(4.0);
        for (i, &got) in v.iter().enumerate() {
            let want = (g(i as f64 - 3.0) - lo) / (1.0 - lo);
            assert!(
                (f64::from(got) - want).abs() < 1e-6,
                "i={i}: {got} vs {want}"
            );
        }
        assert_eq!(v[3], 1.0);
        assert_eq!(v[7], 0.0);
        // Hand-computed: i=2 and i=4: (exp(-1/8) - exp(-2)) / (1 - exp(-2)) = 0.86410559...
        assert!((v[2] - 0.864_105_6).abs() < 1e-6);
        assert_eq!(v[2], v[4]);
        // The argmax of a label decodes back to the centre.
        assert_eq!(argmax(&v), Some(3));
    }

    #[test]
    fn centre_truncates_like_python_int() {
        let mut v = [0f32; 16];
        encode_axis(5.5, SIGMA, &mut v); // int(6.0) = 6
        assert_eq!(argmax(&v), Some(6));
        encode_axis(-0.7, SIGMA, &mut v); // int(-0.2) = 0
        assert_eq!(argmax(&v), Some(0));
    }

    #[test]
    fn visibility_rule() {
        // 3σ = 24: a joint at x = -24 still touches the image (br = int(-24 + 25) = 1 ≥ 0).
        assert!(visible(-24.0, 10.0, 346, 260, SIGMA));
        // At x = -25.5: br = int(-0.5) = 0, still ≥ 0. At x = -26: br = int(-1) = -1 < 0.
        assert!(visible(-25.5, 10.0, 346, 260, SIGMA));
        assert!(!visible(-26.0, 10.0, 346, 260, SIGMA));
        // Right edge: ul = int(x - 24) must be < 346.
        assert!(visible(369.9, 10.0, 346, 260, SIGMA));
        assert!(!visible(370.0, 10.0, 346, 260, SIGMA));
        let (mut vx, mut vy) = ([1f32; 346], [1f32; 260]);
        assert_eq!(encode_joint(500.0, 10.0, SIGMA, &mut vx, &mut vy), 0.0);
        assert!(vx.iter().chain(&vy).all(|&v| v == 0.0));
        assert_eq!(encode_joint(100.0, 10.0, SIGMA, &mut vx, &mut vy), 1.0);
        assert_eq!(argmax(&vx), Some(100));
    }
}

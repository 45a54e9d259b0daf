//! Integer arithmetic of the int8 engine, defined once.
//!
//! Every requantization in the int8 network is the same four IEEE-754 steps, chosen because an
//! independent ONNX engine computes them bit for bit (`shared/docs/quantization-notes.md`):
//!
//! ```text
//! v = f32(acc_i32)            int → float, round to nearest even (exact below 2^24)
//! v = v × scale_f32           one f32 multiply
//! v = v < 0 ? v × alpha : v   LeakyReLU in f32, before the single rounding (alpha = f32(0.01))
//! q = sat_i8(round_half_even(v))
//! ```
//!
//! In ONNX: `Cast(to=float) → Mul(scale) → LeakyRelu(alpha) → QuantizeLinear(scale=1, zp=0)`.
//! A scale of exactly 1 makes `QuantizeLinear` a plain round-half-even-and-saturate in every
//! engine (no reciprocal, no division).
//!
//! The first layer takes the point features as small integers instead of int8 (x and y reach
//! 345): [`InputCoding`] turns `[x, y, t_avg, p_acc, cnt]` into integers with per-feature
//! power-of-two scales, so the coding is exact, and the first layer's weights are kept within
//! ±1023 so that every partial sum stays below 2^24: exact in f32 in any order, hence equal to
//! the integer sum.

/// LeakyReLU slope of the paper's network, as the f32 that PyTorch exports.
pub const LEAKY_ALPHA: f32 = 0.01;

/// Rounds half to even. Exact for `|v| < 2^22`; callers clamp first.
///
/// Adding and subtracting 1.5 × 2^23 leaves the integer part in the mantissa, rounded by the
/// FPU's default mode (nearest, ties to even); no libm, no branches.
#[inline(always)]
pub fn round_half_even(v: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5 × 2^23
    (v + MAGIC) - MAGIC
}

/// Saturates to `[lo, hi]` and rounds half to even.
#[inline(always)]
pub fn round_clamp(v: f32, lo: f32, hi: f32) -> f32 {
    // Clamping first keeps the magic-number rounding in its exact range; values beyond the
    // bounds saturate either way. NaN cannot occur (finite integers times finite scales).
    // `at_least`/`at_most` rather than clamp: same values for every non-NaN input, and the
    // loops over layers vectorize (clamp's bound check and NaN rules keep them scalar).
    let v = at_most(at_least(v, lo - 1.0), hi + 1.0);
    at_most(at_least(round_half_even(v), lo), hi)
}

/// `v.max(c)` for a bound `c` that is not NaN (a NaN `v` gives `c`), as one compare and one
/// select: what x86's `maxps` computes (the requantization loop compiles to it), and on an FPU
/// without `VMAXNM` (the Cortex-M4's FPv4) a compare, a flag transfer and a conditional move,
/// where `f32::max` calls `fmaxf` (about 15 instructions and a call). Of +0.0 and −0.0 it
/// returns `c`, which `max` leaves open; the callers round to integers, where the two are the
/// same.
#[inline(always)]
pub fn at_least(v: f32, c: f32) -> f32 {
    if v > c {
        v
    } else {
        c
    }
}

/// `v.min(c)` for a bound `c` that is not NaN, as [`at_least`] is `max`.
#[inline(always)]
pub fn at_most(v: f32, c: f32) -> f32 {
    if v < c {
        v
    } else {
        c
    }
}

/// Rounds half to even straight to an integer: after adding 1.5 × 2^23 the rounded value sits
/// in the low mantissa bits, so subtracting the constant's bit pattern gives it as an i32.
/// Exact for `|v| < 2^22` (beyond, some integer, never a panic); integer SIMD only (no
/// float→int conversion), so loops vectorize.
#[inline(always)]
pub fn round_to_i32(v: f32) -> i32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5 × 2^23
    ((v + MAGIC).to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32)
}

/// Requantizes one int32 accumulator (bias included) to int8 with an optional LeakyReLU.
#[inline(always)]
pub fn requantize(acc: i32, scale: f32, leaky: Option<f32>) -> i8 {
    let mut v = acc as f32 * scale;
    if let Some(alpha) = leaky {
        if v < 0.0 {
            v *= alpha;
        }
    }
    // Same value as `round_clamp(v, -128.0, 127.0)`: clamp into the exact range, round,
    // saturate. [`at_least`]/[`at_most`]: one instruction each on x86 (`maxps`/`minps`), a
    // compare and a select on the M4's FPv4 (`f32::max` called `fmaxf` there); a NaN (an
    // infinite scale times 0) gives -129 and saturates to -128 instead of passing its bits on.
    // (`Model::parse` refuses non-finite scales; the Cortex-M kernels'
    // `kernels::arm::requantize_i8`, FPv5 and FPv4, rely on it.)
    saturate(v) as i8
}

/// [`requantize`]'s last step: `v` rounded half to even and saturated to `-128..=127`.
#[inline(always)]
fn saturate(v: f32) -> i32 {
    round_to_i32(at_most(at_least(v, -129.0), 128.0)).clamp(-128, 127)
}

/// [`requantize`] as an i32 (in `-128..=127`), with the LeakyReLU slope as a number: `alpha`
/// 1 for none (`v · 1 = v` exactly for every f32), so that
/// `requantize_wide(acc, scale, leaky.unwrap_or(1.0)) as i8 == requantize(acc, scale, leaky)`.
/// No branch on the option and no narrowing: the loop a pooled kernel keeps in registers.
#[inline(always)]
pub fn requantize_wide(acc: i32, scale: f32, alpha: f32) -> i32 {
    let v = acc as f32 * scale;
    saturate(if v < 0.0 { v * alpha } else { v })
}

/// One layer's requantization: per-output-channel multipliers and the optional LeakyReLU slope,
/// applied to each int32 accumulator by [`requantize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Requant<'a> {
    /// `[out]` multipliers (accumulator units → the next layer's int8 units).
    pub scales: &'a [f32],
    /// LeakyReLU slope, when the layer has one.
    pub leaky: Option<f32>,
}

/// Average pooling's single scaled rounding: `sat_i8(round(f32(sum) × (c / f32(n))))`.
///
/// `c` folds the input and output scales; the division by the point count is one IEEE division,
/// so a dynamic point count needs no precomputed table.
#[inline]
pub fn average(sum: i32, n: u32, c: f32) -> i8 {
    let m = c / n as f32;
    round_clamp(sum as f32 * m, -128.0, 127.0) as i8
}

/// Largest magnitude of a first-layer integer input.
pub const INPUT_LIMIT: i16 = 2047;
/// Largest magnitude of a first-layer weight: `5 × 2048 × 1023 + bias < 2^24`.
pub const FIRST_WEIGHT_LIMIT: i16 = 1023;
/// Largest magnitude of a first-layer bias, so that the sum stays below 2^24.
pub const FIRST_BIAS_LIMIT: i32 = (1 << 24) - 5 * 2048 * 1023 - 1;

/// Largest magnitude of an i16 head weight (blob version 3): 15 bits, so that the ONNX twin can
/// split each weight into two int8 halves (`w = 128·hi + lo`, `lo` in 0..=127).
pub const HEAD_WEIGHT_LIMIT: i16 = 16383;
/// Largest magnitude of an i16 head's bias: with [`MAX_I16_HEAD_DIM`] inputs of at most 128 in
/// magnitude, `256 × 16383 × 128 + 2^30 < 2^31`, so the i32 accumulators are exact.
pub const HEAD_BIAS_LIMIT: i32 = 1 << 30;
/// Largest head dim `D` of an i16 head.
pub const MAX_I16_HEAD_DIM: usize = 256;

/// Integer coding of the five point features for the first layer: `q = round(f × 2^shift)`,
/// saturated to `±INPUT_LIMIT`. Multiplying by a power of two is exact in f32, so the only
/// rounding is the final round-half-even; in ONNX: `Mul`, `Round` (half to even), `Clip`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InputCoding {
    /// Power-of-two exponent per feature `[x, y, t_avg, p_acc, cnt]`.
    pub shifts: [u8; 5],
}

impl InputCoding {
    /// The coding the quantizer uses: pixels and counts as they are, `t_avg` in units of 1/1024.
    pub const DEFAULT: Self = Self {
        shifts: [0, 0, 10, 0, 0],
    };

    /// Scale of feature `i`: `2^shift` (infinite from a shift of 128; 1 for `i` past the
    /// features), built from its f32 exponent bits: no shift that could overflow, and no
    /// integer conversion on the per-point path.
    pub fn factor(&self, i: usize) -> f32 {
        let s = self.shifts.get(i).map_or(0, |&s| u32::from(s));
        f32::from_bits((127 + s).min(255) << 23)
    }

    /// Codes one point.
    pub fn code(&self, features: &[f32; 5]) -> [i16; 5] {
        let lim = f32::from(INPUT_LIMIT);
        core::array::from_fn(|i| round_clamp(features[i] * self.factor(i), -lim, lim) as i16)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_and_rounding_never_panic_outside_their_ranges() {
        // Beyond ±2^22 the magic-number rounding gives some integer, not an overflow panic.
        let _ = round_to_i32(-12_582_913.0);
        let _ = round_to_i32(f32::MAX);
        let c = InputCoding {
            shifts: [0, 31, 32, 40, 200],
        };
        assert_eq!(c.factor(1), 2f32.powi(31));
        assert_eq!(c.factor(2), 2f32.powi(32));
        assert_eq!(c.factor(3), 2f32.powi(40));
        assert_eq!(c.factor(4), f32::INFINITY);
        assert_eq!(c.factor(5), 1.0);
    }

    /// `at_least`/`at_most` are `f32::max`/`min` with a bound that is not NaN, for every kind
    /// of value: NaN gives the bound, infinities, equal values, and ±0 against a non-zero
    /// bound (against a zero bound `max` may return either zero; both compare equal).
    #[test]
    fn at_least_and_at_most_are_max_and_min() {
        let values = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            0.0,
            -0.0,
            -129.0,
            128.0,
            127.5,
            -128.5,
            1e-40,
            -3.4e38,
            f32::MAX,
            f32::MIN,
            0.49999997,
        ];
        for c in [-129.0f32, 128.0, -2048.0, 2047.0, 0.0, -0.0] {
            for v in values
                .into_iter()
                .chain((0..200).map(|i| (i as f32 - 100.0) * 2.75))
            {
                let (lo, hi) = (at_least(v, c), at_most(v, c));
                assert!(lo == v.max(c) && !lo.is_nan(), "at_least({v}, {c}) = {lo}");
                assert!(hi == v.min(c) && !hi.is_nan(), "at_most({v}, {c}) = {hi}");
                if c != 0.0 {
                    assert_eq!(lo.to_bits(), v.max(c).to_bits(), "{v} {c}");
                    assert_eq!(hi.to_bits(), v.min(c).to_bits(), "{v} {c}");
                }
            }
        }
    }

    #[test]
    fn rounds_ties_to_even() {
        for (v, want) in [
            (0.5f32, 0.0f32),
            (1.5, 2.0),
            (2.5, 2.0),
            (-0.5, -0.0),
            (-1.5, -2.0),
            (-2.5, -2.0),
            (2.4999998, 2.0),
            (2.5000002, 3.0),
            (126.5, 126.0),
            (127.5, 128.0),
        ] {
            assert_eq!(round_half_even(v), want, "{v}");
        }
    }

    #[test]
    fn matches_std_on_a_dense_grid() {
        // Every quarter step in ±300 and a sweep of odd fractions.
        let mut v = -300.0f32;
        while v <= 300.0 {
            assert_eq!(round_half_even(v), v.round_ties_even(), "{v}");
            v += 0.25;
        }
        for i in -100_000..100_000 {
            let v = i as f32 * 0.001_3;
            assert_eq!(round_half_even(v), v.round_ties_even(), "{v}");
        }
    }

    #[test]
    fn integer_rounding_equals_float_rounding() {
        let mut v = -300.0f32;
        while v <= 300.0 {
            assert_eq!(round_to_i32(v) as f32, round_half_even(v), "{v}");
            v += 0.125;
        }
        for i in -200_000..200_000 {
            let v = i as f32 * 0.000_77;
            assert_eq!(round_to_i32(v) as f32, v.round_ties_even(), "{v}");
        }
    }

    #[test]
    fn requantize_wide_is_requantize() {
        // Accumulators across the i32 range and at rounding ties, scales of both signs
        // (a negative one flips which side the slope applies to), with and without the slope.
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut accs: Vec<i32> = vec![0, 1, -1, 250, -250, 350, -350, i32::MAX, i32::MIN];
        for _ in 0..20_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            accs.push((s >> 16) as i32 >> (s % 24));
        }
        for &scale in &[1.0, 0.5, 0.01, 3.7e-4, -0.02, 1e-9, 0.0] {
            for leaky in [None, Some(LEAKY_ALPHA), Some(0.2), Some(-0.5)] {
                for &a in &accs {
                    let wide = requantize_wide(a, scale, leaky.unwrap_or(1.0));
                    assert_eq!(
                        wide as i8,
                        requantize(a, scale, leaky),
                        "{a} {scale} {leaky:?}"
                    );
                    assert!((-128..=127).contains(&wide));
                }
            }
        }
    }

    #[test]
    fn requantize_saturates_and_applies_leaky_relu() {
        assert_eq!(requantize(1_000, 1.0, None), 127);
        assert_eq!(requantize(-1_000, 1.0, None), -128);
        assert_eq!(requantize(i32::MAX, 1.0, None), 127);
        assert_eq!(requantize(i32::MIN, 1.0, None), -128);
        // -250 × 0.01 = -2.5 → ties to even → -2.
        assert_eq!(requantize(-250, 1.0, Some(LEAKY_ALPHA)), -2);
        assert_eq!(requantize(-350, 1.0, Some(LEAKY_ALPHA)), -4); // -3.5 → -4
        assert_eq!(requantize(5, 0.5, Some(LEAKY_ALPHA)), 2); // 2.5 → 2
        assert_eq!(requantize(7, 0.5, None), 4); // 3.5 → 4
    }

    #[test]
    fn every_int8_product_rounds_like_the_spec() {
        // Exhaustive over accumulators -2^15..2^15 at an awkward scale, against an f64 model
        // of the same IEEE steps.
        let scale = 0.003_137_254_9f32;
        for acc in -(1 << 15)..(1 << 15) {
            let v = acc as f32 * scale;
            let v = if v < 0.0 { v * LEAKY_ALPHA } else { v };
            let want = v.round_ties_even().clamp(-128.0, 127.0) as i8;
            assert_eq!(requantize(acc, scale, Some(LEAKY_ALPHA)), want, "acc {acc}");
        }
    }

    #[test]
    fn average_is_one_scaled_rounding() {
        assert_eq!(average(300, 4, 1.0), 75);
        assert_eq!(average(10, 4, 1.0), 2); // 2.5 → 2
        assert_eq!(average(14, 4, 1.0), 4); // 3.5 → 4
        assert_eq!(average(-1_000_000, 3, 1.0), -128);
    }

    #[test]
    fn input_coding_is_exact_and_saturates() {
        let c = InputCoding::DEFAULT;
        assert_eq!(
            c.code(&[345.0, 259.0, 0.5, -3.0, 9.0]),
            [345, 259, 512, -3, 9]
        );
        assert_eq!(
            c.code(&[0.0, 0.0, 0.999_999, 5_000.0, 9_000.0]),
            [0, 0, 1024, 2047, 2047]
        );
        // t = 0.00048828125 × 1024 = 0.5 → ties to even → 0.
        assert_eq!(c.code(&[0.0, 0.0, 0.000_488_281_25, 0.0, 0.0])[2], 0);
    }
}

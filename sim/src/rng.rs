//! Seeded random streams and the few distributions the simulator needs.

use rand_core::RngCore;
use rand_pcg::Pcg64;

/// Stream tags: one independent random stream per purpose, so that adding a draw to one
/// purpose never changes another's numbers.
pub(crate) mod tag {
    pub const SUBJECT: u8 = 1;
    pub const MOTION: u8 = 2;
    pub const SENSOR: u8 = 3;
    pub const SCENE: u8 = 4;
    pub const NOISE: u8 = 5;
}

/// SplitMix64 finalizer: a bijective 64-bit mixer.
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A seeded random stream (PCG-XSL-RR 128/64).
#[derive(Clone, Debug)]
pub(crate) struct Rng(Pcg64);

impl Rng {
    /// The stream for `(seed, index, tag, sub)`. The PCG stream selector (bits: seed 56–119,
    /// index 24–55, sub 8–23, tag 0–7) is an injective function of all four, so distinct keys
    /// give distinct sequences.
    pub fn new(seed: u64, index: u32, tag: u8, sub: u16) -> Self {
        let stream = (u128::from(seed) << 56)
            | (u128::from(index) << 24)
            | (u128::from(sub) << 8)
            | u128::from(tag);
        let state = (u128::from(mix64(seed ^ 0x5851_f42d_4c95_7f2d)) << 64)
            | u128::from(mix64(
                u64::from(index) << 24 | u64::from(sub) << 8 | u64::from(tag),
            ));
        Self(Pcg64::new(state, stream))
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.0.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform integer in `0..n` (`n > 0`).
    pub fn below(&mut self, n: u64) -> u64 {
        ((u128::from(self.0.next_u64()) * u128::from(n)) >> 64) as u64
    }

    /// A fair coin.
    pub fn coin(&mut self) -> bool {
        self.0.next_u64() >> 63 == 1
    }

    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.unit(); // (0, 1]
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (core::f64::consts::TAU * u2).cos()
    }

    /// Exponential with rate `rate` (> 0).
    pub fn exponential(&mut self, rate: f64) -> f64 {
        -(1.0 - self.unit()).ln() / rate
    }

    /// Poisson with mean `lambda` (Knuth's product method below 30, a rounded normal
    /// approximation above).
    pub fn poisson(&mut self, lambda: f64) -> u64 {
        if lambda <= 0.0 {
            return 0;
        }
        if lambda < 30.0 {
            let limit = (-lambda).exp();
            let mut k = 0;
            let mut p = self.unit();
            while p > limit {
                k += 1;
                p *= self.unit();
            }
            k
        } else {
            (lambda + lambda.sqrt() * self.normal()).round().max(0.0) as u64
        }
    }
}

/// `3x² − 2x³` on `x` clamped to `[0, 1]`.
pub(crate) fn smoothstep(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distributions_have_the_right_moments() {
        let mut r = Rng::new(7, 0, 0, 0);
        let n = 20_000;
        let (mut s, mut s2, mut e, mut p) = (0.0, 0.0, 0.0, 0.0);
        for _ in 0..n {
            let x = r.normal();
            s += x;
            s2 += x * x;
            e += r.exponential(2.0);
            p += r.poisson(4.0) as f64;
        }
        let n = f64::from(n);
        assert!((s / n).abs() < 0.03);
        assert!((s2 / n - 1.0).abs() < 0.05);
        assert!((e / n - 0.5).abs() < 0.02);
        assert!((p / n - 4.0).abs() < 0.1);
        assert!((r.poisson(1000.0) as f64 - 1000.0).abs() < 200.0);
    }

    #[test]
    fn streams_differ_by_key() {
        let a = Rng::new(1, 0, 1, 0).unit();
        let b = Rng::new(1, 1, 1, 0).unit();
        let c = Rng::new(2, 0, 1, 0).unit();
        let d = Rng::new(1, 0, 2, 0).unit();
        assert!(a != b && a != c && a != d && b != c);
        assert_eq!(a, Rng::new(1, 0, 1, 0).unit());
    }
}

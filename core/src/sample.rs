//! Sampling a window's `M` points down (or up) to the network's `N` input points.
//!
//! Reference behaviour (paper, Sec. 3.2): when `M ≥ N`, `N` distinct indices drawn uniformly
//! without replacement; when `M < N`, `N` indices drawn with replacement; indices ascending, so
//! the points keep their (slice, y, x) order. `N = 0` keeps all points; an empty window gives `N`
//! all-zero points (one when `N = 0`: [`sample_len`]).
//!
//! The generator is PCG32 (`rand_pcg::Pcg32`, seeded with `seed_from_u64`); the mapping from its
//! `u32` outputs to indices is defined here (below) and is part of the contract, so a host and a
//! firmware with the same seed pick the same points.

use core::fmt;

use rand_core::{RngCore, SeedableRng};

use crate::raster::Window;

/// The seeded generator the pipeline uses.
pub type SampleRng = rand_pcg::Pcg32;

/// Creates the pipeline's generator from a 64-bit seed.
pub fn rng_from_seed(seed: u64) -> SampleRng {
    SampleRng::seed_from_u64(seed)
}

/// An output buffer too small for the requested sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BufferTooSmall {
    /// Entries needed.
    pub needed: usize,
    /// Entries available.
    pub available: usize,
}

impl fmt::Display for BufferTooSmall {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "sample needs {} entries but the buffer holds {}",
            self.needed, self.available
        )
    }
}

impl core::error::Error for BufferTooSmall {}

/// Number of points a sample of `n` from `m` has: `n`, or `m` when `n == 0` (keep all), and
/// then one for an empty window (`m == 0`): its all-zero point pools to what `N` all-zero
/// points do, so that an empty window gets the same guess in both modes instead of an input the
/// engine refuses.
pub const fn sample_len(m: usize, n: usize) -> usize {
    if n != 0 {
        n
    } else if m == 0 {
        1
    } else {
        m
    }
}

/// Uniform integer in `0..bound` (`bound > 0`, which its one caller guarantees; crate-private
/// so that no caller can pass 0) from 32-bit outputs, without bias (Lemire, "Fast Random
/// Integer Generation in an Interval", 2019).
pub(crate) fn below<R: RngCore>(rng: &mut R, bound: u32) -> u32 {
    debug_assert!(bound > 0);
    let mut m = u64::from(rng.next_u32()) * u64::from(bound);
    if (m as u32) < bound {
        let threshold = bound.wrapping_neg() % bound;
        while (m as u32) < threshold {
            m = u64::from(rng.next_u32()) * u64::from(bound);
        }
    }
    (m >> 32) as u32
}

/// Writes ascending indices of the points to keep into `out` and returns them.
///
/// - `n == 0`: all `m` indices.
/// - `m ≥ n`: `n` distinct indices, every subset equally likely (selection sampling, Knuth's
///   Algorithm S: one pass, no extra memory, output already sorted).
/// - `0 < m < n`: `n` indices drawn with replacement, then sorted.
/// - `m == 0`: no indices (the caller pads with zero points, see [`sample_window`]).
pub fn sample_indices<'o, R: RngCore>(
    m: usize,
    n: usize,
    rng: &mut R,
    out: &'o mut [u32],
) -> Result<&'o [u32], BufferTooSmall> {
    let len = if m == 0 { 0 } else { sample_len(m, n) };
    if out.len() < len {
        return Err(BufferTooSmall {
            needed: len,
            available: out.len(),
        });
    }
    // Indices are u32; a window never holds more than u32::MAX events.
    let m32 = u32::try_from(m).map_err(|_| BufferTooSmall {
        needed: m,
        available: u32::MAX as usize,
    })?;
    let out = &mut out[..len];
    if m == 0 {
        return Ok(out);
    }
    if n == 0 {
        for (slot, i) in out.iter_mut().zip(0..m32) {
            *slot = i;
        }
    } else if m >= n {
        // Selection sampling: each index is kept with probability needed / remaining, so
        // exactly `n` are kept; `out` holds `n` (an iterator, not indexing: no panic path).
        let mut slots = out.iter_mut();
        let mut needed = n as u32;
        for i in 0..m32 {
            if needed == 0 {
                break;
            }
            if below(rng, m32 - i) < needed {
                if let Some(slot) = slots.next() {
                    *slot = i;
                }
                needed -= 1;
            }
        }
    } else {
        for slot in out.iter_mut() {
            *slot = below(rng, m32);
        }
        out.sort_unstable();
    }
    Ok(out)
}

/// Samples a window into network input rows `[x, y, t_avg, p_acc, cnt]`.
///
/// `indices` is scratch for [`sample_indices`] (at least `sample_len(window.len(), n)` entries);
/// `out` receives `sample_len(window.len(), n)` rows, all zero for an empty window (`n` of them,
/// or one when `n == 0`).
/// Returns the filled rows.
pub fn sample_window<'o, R: RngCore>(
    window: &Window<'_>,
    n: usize,
    rng: &mut R,
    indices: &mut [u32],
    out: &'o mut [[f32; 5]],
) -> Result<&'o mut [[f32; 5]], BufferTooSmall> {
    let len = sample_len(window.len(), n);
    if out.len() < len {
        return Err(BufferTooSmall {
            needed: len,
            available: out.len(),
        });
    }
    let out = &mut out[..len];
    let picked = sample_indices(window.len(), n, rng, indices)?;
    if picked.is_empty() {
        out.fill([0.0; 5]);
    }
    for (row, &i) in out.iter_mut().zip(picked) {
        // Every index is below window.len(), so the point exists.
        *row = window.get(i as usize).map_or([0.0; 5], |p| p.features());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeping_every_point_of_an_empty_window_gives_one_zero_point() {
        assert_eq!(
            (sample_len(0, 0), sample_len(7, 0), sample_len(0, 5)),
            (1, 7, 5)
        );
        let mut storage = crate::raster::Davis346Storage::new();
        let config = crate::raster::RasterConfig::DAVIS346;
        let mut r = crate::raster::Rasterizer::new(config, &mut storage).unwrap();
        let window = r.flush();
        assert!(window.is_empty());
        let (mut idx, mut rows) = ([0u32; 4], [[1.0f32; 5]; 4]);
        let mut rng = rng_from_seed(1);
        let got = sample_window(&window, 0, &mut rng, &mut idx, &mut rows).unwrap();
        assert_eq!(got, &[[0.0; 5]]);
    }

    #[test]
    fn without_replacement_is_sorted_distinct_and_complete() {
        let mut rng = rng_from_seed(7);
        let mut buf = [0u32; 64];
        for m in [64usize, 65, 100, 1000] {
            let idx = sample_indices(m, 64, &mut rng, &mut buf).unwrap();
            assert_eq!(idx.len(), 64);
            assert!(idx.windows(2).all(|w| w[0] < w[1]), "m={m}: {idx:?}");
            assert!(idx.iter().all(|&i| (i as usize) < m));
        }
        // m == n keeps every point.
        let idx = sample_indices(64, 64, &mut rng, &mut buf).unwrap();
        assert!(idx.iter().copied().eq(0..64));
    }

    #[test]
    fn with_replacement_is_sorted_and_in_range() {
        let mut rng = rng_from_seed(1);
        let mut buf = [0u32; 50];
        let idx = sample_indices(3, 50, &mut rng, &mut buf).unwrap();
        assert_eq!(idx.len(), 50);
        assert!(idx.windows(2).all(|w| w[0] <= w[1]));
        assert!(idx.iter().all(|&i| i < 3));
        // With 50 draws from 3, every index appears (probability of a miss < 1e-8).
        assert!((0..3).all(|i| idx.contains(&i)));
    }

    #[test]
    fn zero_n_keeps_all_and_empty_input_gives_nothing() {
        let mut rng = rng_from_seed(0);
        let mut buf = [9u32; 8];
        assert!(sample_indices(5, 0, &mut rng, &mut buf)
            .unwrap()
            .iter()
            .copied()
            .eq(0..5));
        assert!(sample_indices(0, 8, &mut rng, &mut buf).unwrap().is_empty());
    }

    #[test]
    fn small_buffer_is_an_error() {
        let mut rng = rng_from_seed(0);
        let mut buf = [0u32; 3];
        assert_eq!(
            sample_indices(10, 4, &mut rng, &mut buf),
            Err(BufferTooSmall {
                needed: 4,
                available: 3
            })
        );
    }

    #[test]
    fn same_seed_same_sample() {
        let (mut a, mut b) = ([0u32; 32], [0u32; 32]);
        sample_indices(500, 32, &mut rng_from_seed(42), &mut a).unwrap();
        sample_indices(500, 32, &mut rng_from_seed(42), &mut b).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn selection_is_uniform() {
        // Each of m = 10 indices should be kept with probability n/m = 0.3.
        let mut rng = rng_from_seed(3);
        let mut hits = [0u32; 10];
        let mut buf = [0u32; 3];
        let trials = 20_000;
        for _ in 0..trials {
            for &i in sample_indices(10, 3, &mut rng, &mut buf).unwrap() {
                hits[i as usize] += 1;
            }
        }
        for h in hits {
            let p = f64::from(h) / f64::from(trials);
            assert!((p - 0.3).abs() < 0.02, "{hits:?}");
        }
    }

    #[test]
    fn below_stays_in_bounds() {
        let mut rng = rng_from_seed(9);
        for bound in [1u32, 2, 3, 7, 1 << 31, u32::MAX] {
            for _ in 0..1000 {
                assert!(below(&mut rng, bound) < bound);
            }
        }
    }
}

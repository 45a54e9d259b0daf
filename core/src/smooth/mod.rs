//! Temporal filtering of 2-D joints over windows, two ways:
//! - [`Smoother`]: causal (no latency), a One-Euro filter (Casiez, Roussel and Vogel, CHI 2012)
//!   per joint coordinate, gated by the joint's confidence;
//! - [`FixedLag`]: a fixed-lag smoother, each window the confidence-weighted mean of its
//!   neighbours `lag` windows either side, out `lag` windows late (the [`lag`] module).
//!
//! The One-Euro filter:
//!
//! Per coordinate, with `dt` the time between the two windows' last events:
//! `α(f) = 1 / (1 + 1 / (2π f dt))`; the derivative is low-passed at `d_cutoff_hz`, and the
//! value at `f = min_cutoff_hz + beta · |derivative|` (slow motion is smoothed hard, fast motion
//! passes). Confidence gating scales the step: `α' = α · min(1, c / full_confidence)`, so a joint
//! the network is unsure of (a limb that made no events in this window) mostly keeps its
//! filtered position, and a confident one follows the new estimate. The first window of a
//! sequence, any window after a gap longer than `reset_after_us` and any window that ends
//! before the previous one are taken as is; a window that ends when the previous one did
//! (`dt = 0`, every `α` 0) keeps the filtered joints.
//!
//! Fixed memory: the caller lends one [`AxisState`] per coordinate (`2 × J`); no allocation,
//! `f32` with `libm`, the same bits on the host and an MCU.

use crate::simdr::Joint2d;

pub mod lag;
pub use lag::{FixedLag, Held, LagError, LagParams, LagSlot};

/// A temporal filter and its parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Filter {
    /// None: the network's joints as they are.
    Off,
    /// The causal confidence-gated One-Euro filter ([`Smoother`]): no latency.
    OneEuro(SmoothParams),
    /// The fixed-lag confidence-weighted mean ([`FixedLag`]): `lag` windows late, more
    /// accurate.
    FixedLag(LagParams),
}

impl Filter {
    /// The default: the fixed-lag mean, three windows each side.
    pub const DEFAULT: Self = Self::FixedLag(LagParams::DEFAULT);
}

impl Default for Filter {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Filter parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SmoothParams {
    /// Cut-off at rest, Hz: lower smooths more.
    pub min_cutoff_hz: f32,
    /// Cut-off increase per pixel/second of motion.
    pub beta: f32,
    /// Cut-off of the derivative's low-pass, Hz.
    pub d_cutoff_hz: f32,
    /// Confidence at and above which a joint takes the full One-Euro step.
    pub full_confidence: f32,
    /// Restart after a gap longer than this between windows, µs.
    pub reset_after_us: i64,
}

impl SmoothParams {
    /// Defaults chosen on the synthetic validation set (`evpose eval --smooth`, README).
    pub const DEFAULT: Self = Self {
        min_cutoff_hz: 1.0,
        beta: 0.5,
        d_cutoff_hz: 1.0,
        full_confidence: 0.5,
        reset_after_us: 1_000_000,
    };
}

impl Default for SmoothParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl SmoothParams {
    /// Whether the parameters make a filter: every cut-off finite and positive, `beta` and
    /// `full_confidence` finite and not negative, `reset_after_us` not negative. Anything
    /// else turns the filter's state into NaN or infinity at the first step (`beta = inf`
    /// times a zero rate is NaN), which only a reset would clear.
    pub fn check(&self) -> Result<(), BadSmoothParams> {
        let positive = |v: f32| v.is_finite() && v > 0.0;
        let not_negative = |v: f32| v.is_finite() && v >= 0.0;
        let bad = if !positive(self.min_cutoff_hz) {
            Some("min_cutoff_hz")
        } else if !not_negative(self.beta) {
            Some("beta")
        } else if !positive(self.d_cutoff_hz) {
            Some("d_cutoff_hz")
        } else if !not_negative(self.full_confidence) {
            Some("full_confidence")
        } else if self.reset_after_us < 0 {
            Some("reset_after_us")
        } else {
            None
        };
        match bad {
            Some(field) => Err(BadSmoothParams { field }),
            None => Ok(()),
        }
    }
}

/// [`SmoothParams`] that make no filter ([`SmoothParams::check`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BadSmoothParams {
    /// The first offending field.
    pub field: &'static str,
}

impl core::fmt::Display for BadSmoothParams {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let want = match self.field {
            "min_cutoff_hz" | "d_cutoff_hz" => "finite and above 0",
            _ => "finite and not negative",
        };
        write!(f, "smoothing parameter {} must be {want}", self.field)
    }
}

impl core::error::Error for BadSmoothParams {}

/// One filtered coordinate.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisState {
    /// Filtered value, pixels.
    pub value: f32,
    /// Filtered derivative, pixels per second.
    pub rate: f32,
}

/// The lent state does not hold two coordinates per joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StateTooSmall {
    /// Coordinates needed (`2 × J`).
    pub needed: usize,
    /// Coordinates lent.
    pub got: usize,
}

impl core::fmt::Display for StateTooSmall {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "smoother state holds {} coordinates, {} needed",
            self.got, self.needed
        )
    }
}

impl core::error::Error for StateTooSmall {}

/// A confidence-gated One-Euro filter over a sequence of windows of one camera.
#[derive(Debug)]
pub struct Smoother<'s> {
    params: SmoothParams,
    state: &'s mut [AxisState],
    last_t_us: Option<i64>,
}

fn alpha(cutoff_hz: f32, dt_s: f32) -> f32 {
    let tau = 1.0 / (2.0 * core::f32::consts::PI * cutoff_hz);
    1.0 / (1.0 + tau / dt_s)
}

impl<'s> Smoother<'s> {
    /// A filter over the lent `state` (two coordinates per joint), or why `params` make none
    /// ([`SmoothParams::check`]).
    pub fn new(params: SmoothParams, state: &'s mut [AxisState]) -> Result<Self, BadSmoothParams> {
        params.check()?;
        Ok(Self {
            params,
            state,
            last_t_us: None,
        })
    }

    /// Forgets the sequence: the next window is taken as is.
    pub fn reset(&mut self) {
        self.last_t_us = None;
    }

    /// Filters the joints of the window that ended at `t_us` (its last event's time: an
    /// [`Estimate`](crate::pipeline::Estimate)'s `window.summary().t_max`) with their `confidence` into
    /// `out[j] = [x, y]` (pixels, sub-pixel): the first `min(joints, confidence, out)` joints
    /// (give the three the same length: a shorter `confidence` or `out` leaves the rest
    /// unfiltered and unwritten).
    pub fn update(
        &mut self,
        t_us: i64,
        joints: &[Joint2d],
        confidence: &[f32],
        out: &mut [[f32; 2]],
    ) -> Result<(), StateTooSmall> {
        let n = joints.len().min(confidence.len()).min(out.len());
        if self.state.len() < 2 * n {
            return Err(StateTooSmall {
                needed: 2 * n,
                got: self.state.len(),
            });
        }
        let p = self.params;
        // A step that does not fit an i64 (a glitched timestamp) restarts like any long gap.
        let dt_us = self.last_t_us.and_then(|last| t_us.checked_sub(last));
        // A window ending when the last did (dt = 0, where every α is 0) keeps the state and
        // outputs it; one ending before it (time went backwards) restarts.
        let (fresh, hold) = match dt_us {
            None => (true, false),
            Some(d) => (d < 0 || d > p.reset_after_us, d == 0),
        };
        self.last_t_us = Some(t_us);
        let dt = dt_us.map_or(0.0, |d| d as f32 * 1e-6);
        // Two state coordinates per joint, zipped (no indexing: no bounds check to panic).
        for (((joint, &c), o), state) in joints
            .iter()
            .zip(confidence)
            .zip(out.iter_mut())
            .zip(self.state.chunks_exact_mut(2))
        {
            // A NaN confidence (an f32 model's NaN logits) holds the joint, as 0 does, instead
            // of poisoning its state until the next reset.
            let gate = if c.is_nan() {
                0.0
            } else if p.full_confidence > 0.0 {
                (c / p.full_confidence).clamp(0.0, 1.0)
            } else {
                1.0
            };
            for ((s, raw), o) in state
                .iter_mut()
                .zip([f32::from(joint.x), f32::from(joint.y)])
                .zip(o.iter_mut())
            {
                if fresh {
                    *s = AxisState {
                        value: raw,
                        rate: 0.0,
                    };
                } else if !hold {
                    let rate = (raw - s.value) / dt;
                    let a_d = alpha(p.d_cutoff_hz, dt) * gate;
                    s.rate += a_d * (rate - s.rate);
                    let cutoff = p.min_cutoff_hz + p.beta * libm::fabsf(s.rate);
                    let a = alpha(cutoff, dt) * gate;
                    s.value += a * (raw - s.value);
                }
                *o = s.value;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(params: SmoothParams, seq: &[(i64, u16, f32)]) -> [f32; 8] {
        let mut state = [AxisState::default(); 2];
        let mut f = Smoother::new(params, &mut state).unwrap();
        let mut out = [0f32; 8];
        for (i, &(t, x, c)) in seq.iter().enumerate() {
            let mut o = [[0f32; 2]];
            f.update(t, &[Joint2d { x, y: 0 }], &[c], &mut o).unwrap();
            out[i] = o[0][0];
        }
        out
    }

    #[test]
    fn first_window_passes_and_steps_are_smoothed() {
        let p = SmoothParams::DEFAULT;
        let o = run(p, &[(0, 100, 1.0), (33_000, 110, 1.0), (66_000, 110, 1.0)]);
        assert_eq!(o[0], 100.0);
        assert!(o[1] > 100.0 && o[1] < 110.0, "{o:?}");
        assert!(o[2] > o[1] && o[2] < 110.0, "{o:?}");
    }

    #[test]
    fn confidence_gates_the_step() {
        let p = SmoothParams::DEFAULT;
        let sure = run(p, &[(0, 100, 1.0), (33_000, 140, 1.0)]);
        let unsure = run(p, &[(0, 100, 1.0), (33_000, 140, 0.1)]);
        let none = run(p, &[(0, 100, 1.0), (33_000, 140, 0.0)]);
        assert!(
            sure[1] > unsure[1] && unsure[1] > 100.0,
            "{sure:?} {unsure:?}"
        );
        assert_eq!(none[1], 100.0);
        // Timestamps whose difference does not fit an i64 restart the filter, no panic.
        let far = run(
            p,
            &[(1, 100, 1.0), (i64::MIN, 140, 1.0), (i64::MAX, 120, 1.0)],
        );
        assert_eq!(&far[..3], &[100.0, 140.0, 120.0]);
        // A NaN confidence holds the joint like 0, and the next window moves it again.
        let nan = run(
            p,
            &[(0, 100, 1.0), (33_000, 140, f32::NAN), (66_000, 140, 1.0)],
        );
        assert_eq!(nan[1], 100.0);
        assert!(nan[2] > 100.0 && nan[2] < 140.0, "{nan:?}");
    }

    #[test]
    fn fast_motion_follows_closer_than_slow() {
        // beta raises the cut-off with speed: a large jump is followed more closely (relative).
        let p = SmoothParams::DEFAULT;
        let slow = run(p, &[(0, 100, 1.0), (33_000, 102, 1.0)]);
        let fast = run(p, &[(0, 100, 1.0), (33_000, 200, 1.0)]);
        assert!(
            (fast[1] - 100.0) / 100.0 > (slow[1] - 100.0) / 2.0,
            "{slow:?} {fast:?}"
        );
    }

    #[test]
    fn gaps_and_time_going_back_restart() {
        let p = SmoothParams::DEFAULT;
        let gap = run(p, &[(0, 100, 1.0), (5_000_000, 140, 1.0)]);
        assert_eq!(gap[1], 140.0);
        let back = run(p, &[(10_000, 100, 1.0), (5_000, 140, 1.0)]);
        assert_eq!(back[1], 140.0);
    }

    #[test]
    fn a_window_at_the_same_time_holds_the_filtered_joints() {
        let p = SmoothParams::DEFAULT;
        // dt = 0: every α is 0, so neither a confident nor an unsure estimate moves the state
        // (it restarted before, and a 0-confidence joint jumped to the raw estimate).
        for c in [0.0, 1.0] {
            let same = run(p, &[(0, 100, 1.0), (33_000, 100, 1.0), (33_000, 200, c)]);
            assert_eq!(&same[..3], &[100.0, 100.0, 100.0], "confidence {c}");
        }
        // The next window filters on from the held state, with the real dt.
        let after = run(
            p,
            &[
                (0, 100, 1.0),
                (33_000, 100, 1.0),
                (33_000, 200, 1.0),
                (66_000, 110, 1.0),
            ],
        );
        let direct = run(p, &[(0, 100, 1.0), (33_000, 100, 1.0), (66_000, 110, 1.0)]);
        assert_eq!(after[3], direct[2]);
    }

    #[test]
    fn parameters_that_make_no_filter_are_refused() {
        let mut state = [AxisState::default(); 2];
        let d = SmoothParams::DEFAULT;
        let cases = [
            (
                SmoothParams {
                    beta: f32::INFINITY,
                    ..d
                },
                "beta",
            ),
            (SmoothParams { beta: -1.0, ..d }, "beta"),
            (
                SmoothParams {
                    min_cutoff_hz: f32::NAN,
                    ..d
                },
                "min_cutoff_hz",
            ),
            (
                SmoothParams {
                    min_cutoff_hz: -1.0,
                    ..d
                },
                "min_cutoff_hz",
            ),
            (
                SmoothParams {
                    min_cutoff_hz: 0.0,
                    ..d
                },
                "min_cutoff_hz",
            ),
            (
                SmoothParams {
                    d_cutoff_hz: 0.0,
                    ..d
                },
                "d_cutoff_hz",
            ),
            (
                SmoothParams {
                    full_confidence: f32::NAN,
                    ..d
                },
                "full_confidence",
            ),
            (
                SmoothParams {
                    reset_after_us: -1,
                    ..d
                },
                "reset_after_us",
            ),
        ];
        for (params, field) in cases {
            let err = Smoother::new(params, &mut state).unwrap_err();
            assert_eq!(err, BadSmoothParams { field }, "{params:?}");
        }
        // Zero beta (no speed term) and zero full confidence (no gating) are filters.
        let edge = SmoothParams {
            beta: 0.0,
            full_confidence: 0.0,
            ..d
        };
        let o = run(edge, &[(0, 100, 1.0), (33_000, 110, 1.0)]);
        assert!(o[1] > 100.0 && o[1] < 110.0, "{o:?}");
    }

    #[test]
    fn too_little_state_is_an_error() {
        let mut state = [AxisState::default(); 3];
        let mut f = Smoother::new(SmoothParams::DEFAULT, &mut state).unwrap();
        let j = [Joint2d::default(); 2];
        let mut o = [[0f32; 2]; 2];
        assert_eq!(
            f.update(0, &j, &[1.0; 2], &mut o),
            Err(StateTooSmall { needed: 4, got: 3 })
        );
    }
}

//! A fixed-lag smoother: each window's joints replaced by the confidence-weighted mean of the
//! windows up to `lag` before and `lag` after it, emitted once the `lag`-th later window has
//! been seen.
//!
//! Per joint coordinate of window `k`, over the windows `m` of `k − lag ..= k + lag` that exist
//! in `k`'s segment: `x̂_k = Σ w_m x_m / Σ w_m` with `w_m = c_m² + 10⁻⁶` (`c_m` the joint's
//! confidence in window `m`: a joint the network was unsure of counts little; with every
//! confidence 0 it is the plain mean). Sums run from the oldest window to the newest, in `f32`,
//! so an MCU and the host compute the same bits.
//!
//! It trades latency for accuracy: a window comes out `lag` windows after it went in (at the
//! end of a stream, [`FixedLag::finish`] releases the last ones). Where that latency is too
//! much, the causal [`super::Smoother`] (One-Euro) has none.
//!
//! A segment ends at a gap longer than `reset_after_us` between two windows' times, at time
//! going back and at [`FixedLag::finish`]; no window is averaged with another segment's. (Time
//! windows cut across a pause are windows too, one per stride, so they do not end a segment:
//! they hold the network's guesses on no events, which weigh little when its confidence is low.)
//!
//! Fixed memory: the caller lends `2 · lag + 1` [`LagSlot`]s and as many [`Held`] per joint.
//! ```
//! use evpose_core::smooth::{FixedLag, Held, LagSlot};
//! use evpose_core::Joint2d;
//!
//! let mut slots = [LagSlot::default(); 3]; // lag 1
//! let mut held = [Held::default(); 3];     // one joint
//! let mut f = FixedLag::new(1, 1, 1_000_000, &mut slots, &mut held).unwrap();
//! let mut out = [[0f32; 2]];
//! let mut got = Vec::new();
//! for (i, x) in [10u16, 20, 60].into_iter().enumerate() {
//!     f.push(i as i64 * 30_000, &[Joint2d { x, y: 0 }], &[1.0]).unwrap();
//!     // Pop what is ready after every push: window k once window k + 1 is in.
//!     while let Some(k) = f.pop(&mut out) {
//!         got.push((k, out[0][0]));
//!     }
//! }
//! // Window 0: the mean of windows 0 and 1; window 1: of 0, 1 and 2.
//! assert_eq!(got, [(0, 15.0), (1, 30.0)]);
//! f.finish(); // the end of the stream releases window 2: (20 + 60) / 2
//! assert_eq!(f.pop(&mut out), Some(2));
//! assert_eq!(out[0][0], 40.0);
//! ```

use crate::simdr::Joint2d;

/// What every window adds to each joint's weight: with all confidences 0 the mean is plain.
const WEIGHT_FLOOR: f32 = 1e-6;

/// Fixed-lag parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LagParams {
    /// Windows on each side of each window; the latency in windows.
    pub lag: usize,
    /// A segment ends at a gap longer than this between windows, µs.
    pub reset_after_us: i64,
}

impl LagParams {
    /// Three windows each side: chosen on the synthetic validation subjects (`evpose eval
    /// --smooth`, README), where 2–4 gave within half a point of each other.
    pub const DEFAULT: Self = Self {
        lag: 3,
        reset_after_us: 1_000_000,
    };
}

impl Default for LagParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One window held by [`FixedLag`]: the segment it belongs to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LagSlot {
    segment: u32,
}

/// One joint of one window held by [`FixedLag`]: its position and weight.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Held {
    x: f32,
    y: f32,
    weight: f32,
}

/// Why the fixed-lag smoother refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LagError {
    /// The lent slots or joints are too few for the lag and joint count.
    StateTooSmall {
        /// Slots (`2 · lag + 1`) or held joints (slots × joints) needed.
        needed: usize,
        /// Slots or held joints lent.
        got: usize,
    },
    /// A window's joints or confidences are not the configured joint count.
    Shape {
        /// Joints the smoother was made for.
        joints: usize,
        /// Joints given.
        got_joints: usize,
        /// Confidences given.
        got_confidence: usize,
    },
    /// A window is ready and was not popped: pushing would overwrite what it needs.
    NotPopped,
}

impl core::fmt::Display for LagError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Self::StateTooSmall { needed, got } => write!(
                f,
                "fixed-lag smoother state holds {got} entries, {needed} needed"
            ),
            Self::Shape {
                joints,
                got_joints,
                got_confidence,
            } => write!(
                f,
                "fixed-lag smoother for {joints} joints given {got_joints} joints and \
                 {got_confidence} confidences"
            ),
            Self::NotPopped => write!(f, "fixed-lag smoother: pop the ready windows first"),
        }
    }
}

impl core::error::Error for LagError {}

/// The fixed-lag smoother over the windows of one camera (see the [module docs](self)).
#[derive(Debug)]
pub struct FixedLag<'s> {
    lag: usize,
    joints: usize,
    reset_after_us: i64,
    slots: &'s mut [LagSlot],
    held: &'s mut [Held],
    /// Windows pushed so far (the next window's number).
    pushed: u64,
    /// The next window to emit.
    next_out: u64,
    /// Windows before this number belong to ended segments and are ready.
    ended_before: u64,
    segment: u32,
    last_t_us: Option<i64>,
}

impl<'s> FixedLag<'s> {
    /// Slots to lend for `lag`: `2 · lag + 1` (saturating: a lag no memory can hold asks for
    /// `usize::MAX`).
    pub const fn slots_for(lag: usize) -> usize {
        lag.saturating_mul(2).saturating_add(1)
    }

    /// A smoother with `lag` windows on each side for `joints` joints, restarting after gaps
    /// longer than `reset_after_us`, over [`FixedLag::slots_for`]`(lag)` lent `slots` and
    /// `slots × joints` lent `held` joints (longer slices are used in part).
    pub fn new(
        lag: usize,
        joints: usize,
        reset_after_us: i64,
        slots: &'s mut [LagSlot],
        held: &'s mut [Held],
    ) -> Result<Self, LagError> {
        // A lag no memory holds asks for `usize::MAX` slots, more than any slice has.
        let windows = Self::slots_for(lag);
        if slots.len() < windows {
            return Err(LagError::StateTooSmall {
                needed: windows,
                got: slots.len(),
            });
        }
        let needed = windows.saturating_mul(joints);
        if held.len() < needed {
            return Err(LagError::StateTooSmall {
                needed,
                got: held.len(),
            });
        }
        Ok(Self {
            lag,
            joints,
            reset_after_us,
            slots: &mut slots[..windows],
            held: &mut held[..needed],
            pushed: 0,
            next_out: 0,
            ended_before: 0,
            segment: 0,
            last_t_us: None,
        })
    }

    /// A smoother with `params` for `joints` joints over the lent `slots` and `held` joints.
    pub fn with_params(
        params: LagParams,
        joints: usize,
        slots: &'s mut [LagSlot],
        held: &'s mut [Held],
    ) -> Result<Self, LagError> {
        Self::new(params.lag, joints, params.reset_after_us, slots, held)
    }

    /// Windows on each side of each window.
    pub fn lag(&self) -> usize {
        self.lag
    }

    fn slot(&self, window: u64) -> usize {
        // The ring holds 2·lag + 1 ≥ 1 windows; the remainder is below that, a usize. (No
        // `%`: its divide-by-zero check would be a panic path in firmware.)
        window.checked_rem(self.slots.len() as u64).unwrap_or(0) as usize
    }

    /// Takes the window that ended at `t_us` (its last event's time: an
    /// [`Estimate`](crate::pipeline::Estimate)'s `window.summary().t_max`) with its `joints` and their `confidence`. Pop every
    /// ready window before the next push.
    pub fn push(
        &mut self,
        t_us: i64,
        joints: &[Joint2d],
        confidence: &[f32],
    ) -> Result<(), LagError> {
        if joints.len() != self.joints || confidence.len() != self.joints {
            return Err(LagError::Shape {
                joints: self.joints,
                got_joints: joints.len(),
                got_confidence: confidence.len(),
            });
        }
        // This window overwrites window `pushed − (2·lag + 1)`, the context of windows up to
        // `pushed − lag − 1`: those must be out.
        if self.pushed > self.next_out + self.lag as u64 {
            return Err(LagError::NotPopped);
        }
        // A step that does not fit an i64 (a glitched timestamp) is a gap like any other.
        let gap = self.last_t_us.map(|last| t_us.checked_sub(last));
        if gap.is_some_and(|d| d.is_none_or(|d| d < 0 || d > self.reset_after_us)) {
            self.end_segment();
        }
        self.last_t_us = Some(t_us);
        let slot = self.slot(self.pushed);
        let segment = self.segment;
        // In range by construction (`new` sized both); `get` keeps panics out of firmware.
        if let Some(s) = self.slots.get_mut(slot) {
            *s = LagSlot { segment };
        }
        let row = self
            .held
            .iter_mut()
            .skip(slot * self.joints)
            .take(self.joints);
        for ((h, j), &c) in row.zip(joints).zip(confidence) {
            // Confidences are in [0, 1]; NaN weighs nothing beyond the floor.
            let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
            *h = Held {
                x: f32::from(j.x),
                y: f32::from(j.y),
                weight: c * c + WEIGHT_FLOOR,
            };
        }
        self.pushed += 1;
        Ok(())
    }

    fn end_segment(&mut self) {
        if self.pushed > self.ended_before {
            self.segment = self.segment.wrapping_add(1);
            self.ended_before = self.pushed;
        }
        self.last_t_us = None;
    }

    /// Ends the stream: the windows still waiting for later ones become ready, and the next
    /// push starts a new segment.
    pub fn finish(&mut self) {
        self.end_segment();
    }

    /// Writes the next ready window's smoothed joints (`[x, y]`, model pixels) into `out` and
    /// returns its number (0 for the first window pushed), or `None` when no window is ready.
    /// `out` shorter than the joint count gets the first joints.
    pub fn pop(&mut self, out: &mut [[f32; 2]]) -> Option<u64> {
        let k = self.next_out;
        let lag = self.lag as u64;
        let ready = k < self.pushed && (k < self.ended_before || k + lag < self.pushed);
        if !ready {
            return None;
        }
        // Windows k − lag ..= k + lag that were pushed and are still held (a window older than
        // `pushed − (2·lag + 1)` has been overwritten), narrowed to k's segment (segments are
        // runs of window numbers), summed oldest first. Their slots follow each other round the
        // ring: one division for k's (a u64 remainder is a library call on a 32-bit MCU), then
        // steps.
        let ring = self.slots.len();
        let step = |slot: usize, forward: bool| match (forward, slot.checked_add(1)) {
            (true, Some(next)) if next < ring => next,
            (true, _) => 0,
            (false, _) => slot.checked_sub(1).unwrap_or(ring.saturating_sub(1)),
        };
        let segment_at = |slot: usize| self.slots.get(slot).map(|s| s.segment);
        let k_slot = self.slot(k);
        let segment = segment_at(k_slot);
        let oldest = self.pushed.saturating_sub(ring as u64);
        let (mut first, mut first_slot) = (k, k_slot);
        while first > oldest && first + lag > k && segment_at(step(first_slot, false)) == segment {
            first -= 1;
            first_slot = step(first_slot, false);
        }
        let (mut last, mut last_slot) = (k, k_slot);
        while last + 1 < self.pushed
            && last < k + lag
            && segment_at(step(last_slot, true)) == segment
        {
            last += 1;
            last_slot = step(last_slot, true);
        }
        for (j, o) in out.iter_mut().enumerate().take(self.joints) {
            let (mut sx, mut sy, mut sw) = (0f32, 0f32, 0f32);
            let mut slot = first_slot;
            for _ in first..=last {
                if let Some(h) = self.held.get(slot * self.joints + j) {
                    sx += h.weight * h.x;
                    sy += h.weight * h.y;
                    sw += h.weight;
                }
                slot = step(slot, true);
            }
            *o = [sx / sw, sy / sw];
        }
        self.next_out += 1;
        Some(k)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const J: usize = 2;

    fn joints(x: u16) -> [Joint2d; J] {
        [Joint2d { x, y: 2 * x }, Joint2d { x: 100, y: x }]
    }

    /// Pushes `(t, x, confidence)` windows with lag `lag`, popping after each push and at the
    /// end; returns (window number, joint 0's x) per output.
    fn run(lag: usize, seq: &[(i64, u16, f32)]) -> Vec<(u64, f32)> {
        let mut slots = [LagSlot::default(); 16];
        let mut held = [Held::default(); 16 * J];
        let mut f = FixedLag::new(lag, J, 1_000_000, &mut slots, &mut held).unwrap();
        let mut got = Vec::new();
        let mut out = [[0f32; 2]; J];
        for &(t, x, c) in seq {
            f.push(t, &joints(x), &[c, 1.0]).unwrap();
            while let Some(k) = f.pop(&mut out) {
                got.push((k, out[0][0]));
            }
        }
        f.finish();
        while let Some(k) = f.pop(&mut out) {
            got.push((k, out[0][0]));
        }
        got
    }

    fn even(n: usize) -> Vec<(i64, u16, f32)> {
        (0..n)
            .map(|i| (i as i64 * 30_000, 10 * i as u16, 1.0))
            .collect()
    }

    #[test]
    fn every_window_comes_out_once_in_order_after_lag_windows() {
        for lag in 0..4 {
            let got = run(lag, &even(9));
            let ks: Vec<u64> = got.iter().map(|g| g.0).collect();
            assert_eq!(ks, (0..9).collect::<Vec<_>>(), "lag {lag}");
        }
        // Latency: with lag 2, window 0 is out after window 2 went in, not before.
        let mut slots = [LagSlot::default(); 5];
        let mut held = [Held::default(); 5 * J];
        let mut f = FixedLag::new(2, J, 1_000_000, &mut slots, &mut held).unwrap();
        let mut out = [[0f32; 2]; J];
        for (i, x) in [0u16, 10, 20].into_iter().enumerate() {
            assert_eq!(f.pop(&mut out), None);
            f.push(i as i64, &joints(x), &[1.0; J]).unwrap();
        }
        assert_eq!(f.pop(&mut out), Some(0));
        assert_eq!(out, [[10.0, 20.0], [100.0, 10.0]]);
    }

    #[test]
    fn lag_zero_is_the_identity_and_a_ramp_is_kept_inside() {
        let got = run(0, &even(5));
        assert!(got.iter().all(|&(k, x)| x == 10.0 * k as f32), "{got:?}");
        // A linear ramp's centred mean is the ramp itself away from the ends (to f32 rounding:
        // each weight is 1 + 10⁻⁶).
        let got = run(3, &even(12));
        for &(k, x) in &got[3..9] {
            assert!((x - 10.0 * k as f32).abs() < 1e-3, "{got:?}");
        }
        // At the ends only one side exists: window 0 averages windows 0..=3.
        assert!((got[0].1 - 15.0).abs() < 1e-3, "{got:?}");
    }

    #[test]
    fn confidence_weights_and_zero_confidence_is_a_plain_mean() {
        // Confidences beyond [0, 1] are clamped: an infinite one weighs as 1.
        let inf = run(1, &[(0, 10, 1.0), (30_000, 90, f32::INFINITY)]);
        assert!(inf.iter().all(|g| g.1.is_finite()), "{inf:?}");
        // Window 1 is an outlier the network was unsure of.
        let got = run(1, &[(0, 10, 1.0), (30_000, 90, 0.1), (60_000, 10, 1.0)]);
        assert!(got[1].1 < 12.0, "{got:?}");
        let plain = run(1, &[(0, 10, 0.0), (30_000, 90, 0.0), (60_000, 10, 0.0)]);
        assert!((plain[1].1 - 110.0 / 3.0).abs() < 1e-3, "{plain:?}");
        let nan = run(
            1,
            &[(0, 10, 1.0), (30_000, 90, f32::NAN), (60_000, 10, 1.0)],
        );
        assert!(nan.iter().all(|g| g.1.is_finite()), "{nan:?}");
    }

    #[test]
    fn gaps_and_time_going_back_split_segments() {
        // A 5 s gap after window 1: windows 0 and 1 are never averaged with 2 and 3.
        let seq = [
            (0, 10, 1.0),
            (30_000, 20, 1.0),
            (5_030_000, 100, 1.0),
            (5_060_000, 200, 1.0),
        ];
        let got = run(3, &seq);
        assert_eq!(
            got,
            vec![(0, 15.0), (1, 15.0), (2, 150.0), (3, 150.0)],
            "{got:?}"
        );
        let back = run(2, &[(60_000, 10, 1.0), (30_000, 50, 1.0)]);
        assert_eq!(back, vec![(0, 10.0), (1, 50.0)]);
        // Two windows ending at the same time (sliding windows) stay in one segment.
        let same = run(1, &[(60_000, 10, 1.0), (60_000, 50, 1.0)]);
        assert!(same.iter().all(|g| (g.1 - 30.0).abs() < 1e-3), "{same:?}");
        // A step that does not fit an i64 splits like a gap (no overflow panic).
        let far = run(1, &[(1, 10, 1.0), (i64::MIN, 50, 1.0)]);
        assert_eq!(far, vec![(0, 10.0), (1, 50.0)]);
    }

    #[test]
    fn errors() {
        let mut slots = [LagSlot::default(); 4];
        let mut held = [Held::default(); 4 * J];
        assert_eq!(
            FixedLag::new(2, J, 1, &mut slots, &mut held).unwrap_err(),
            LagError::StateTooSmall { needed: 5, got: 4 }
        );
        assert_eq!(
            FixedLag::new(1, 3, 1, &mut slots, &mut held).unwrap_err(),
            LagError::StateTooSmall { needed: 9, got: 8 }
        );
        // A lag no memory holds is refused, not wrapped around.
        assert_eq!(
            FixedLag::new(usize::MAX / 2, J, 1, &mut slots, &mut held).unwrap_err(),
            LagError::StateTooSmall {
                needed: usize::MAX,
                got: 4
            }
        );
        let mut f = FixedLag::new(1, J, 1_000_000, &mut slots, &mut held).unwrap();
        assert!(matches!(
            f.push(0, &joints(1)[..1], &[1.0]),
            Err(LagError::Shape { joints: 2, .. })
        ));
        for t in 0..2 {
            f.push(t, &joints(1), &[1.0; J]).unwrap();
        }
        // Window 0 is ready and not popped: a third window would push on to where window 0's
        // neighbours are overwritten. Once it is out the window may go in.
        assert_eq!(f.push(2, &joints(1), &[1.0; J]), Err(LagError::NotPopped));
        let mut out = [[0f32; 2]; J];
        assert_eq!(f.pop(&mut out), Some(0));
        f.push(2, &joints(1), &[1.0; J]).unwrap();
        assert_eq!(f.push(3, &joints(1), &[1.0; J]), Err(LagError::NotPopped));
        assert_eq!(f.pop(&mut out), Some(1));
        f.push(3, &joints(1), &[1.0; J]).unwrap();
    }
}

//! Cutting a multi-camera event stream into windows: by event count or by time, tumbling or
//! sliding (a stride shorter than the window), over the events of every camera together (as
//! DHP19 counts its windows), in fixed memory (a ring of one window's events).

use std::collections::VecDeque;

use anyhow::{bail, Result};
use evpose_core::Event;

/// How windows are cut.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WindowRule {
    /// The last `size` events of all cameras, one window every `stride` events.
    Events {
        /// Events per window, over all cameras.
        size: u32,
        /// Events between the ends of consecutive windows (`size`: no overlap).
        stride: u32,
    },
    /// The events of `[end − size, end)`, one window every `stride` µs from the first event.
    Time {
        /// Window length, µs.
        size_us: i64,
        /// Time between the ends of consecutive windows, µs.
        stride_us: i64,
    },
}

impl WindowRule {
    /// Checks sizes and strides: positive, the stride no longer than the window.
    pub fn check(&self) -> Result<()> {
        let (size, stride) = match *self {
            Self::Events { size, stride } => (i64::from(size), i64::from(stride)),
            Self::Time { size_us, stride_us } => (size_us, stride_us),
        };
        if size <= 0 || stride <= 0 || stride > size {
            bail!("window {size} and stride {stride}: both must be positive, the stride at most the window");
        }
        Ok(())
    }
}

/// An event with its camera id.
pub type Tagged = (u8, Event);

/// One window: its events (every camera, in stream order) and its time span.
#[derive(Clone, Copy, Debug)]
pub struct WindowEvents<'a> {
    /// Index from 0.
    pub index: usize,
    /// Events with their camera, in two parts (the ring's halves).
    pub parts: (&'a [Tagged], &'a [Tagged]),
    /// Time span, µs: the first and last event's time for event windows, the nominal
    /// `[start, end)` as `(start, end − 1)` for time windows.
    pub t_us: (i64, i64),
}

impl WindowEvents<'_> {
    /// Events of all cameras.
    pub fn len(&self) -> usize {
        self.parts.0.len() + self.parts.1.len()
    }

    /// Whether the window holds no event.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The events of `camera`, in order.
    pub fn of_camera(&self, camera: u8) -> impl Iterator<Item = Event> + '_ {
        self.parts
            .0
            .iter()
            .chain(self.parts.1)
            .filter(move |(c, _)| *c == camera)
            .map(|&(_, e)| e)
    }
}

/// The window cutter: events go in one at a time, complete windows come out.
///
/// Event windows are complete when `size` events have arrived (then every `stride` events);
/// time windows when an event at or after their end arrives. The stream's tail, shorter than
/// one stride, makes no window, except that a stream too short for any window is one window.
/// Time windows hold at most `capacity` events: beyond it the oldest are dropped
/// ([`Cutter::dropped`]).
#[derive(Debug)]
pub struct Cutter {
    rule: WindowRule,
    ring: VecDeque<Tagged>,
    capacity: usize,
    seen: u64,
    emitted: usize,
    dropped: u64,
    /// Time windows: the end of the next window, µs (set by the first event).
    next_end: Option<i64>,
}

impl Cutter {
    /// A cutter for `rule`; `capacity` bounds a time window's events (event windows hold
    /// exactly their size).
    pub fn new(rule: WindowRule, capacity: usize) -> Result<Self> {
        rule.check()?;
        let capacity = match rule {
            WindowRule::Events { size, .. } => size as usize,
            WindowRule::Time { .. } => capacity.max(1),
        };
        Ok(Self {
            rule,
            ring: VecDeque::with_capacity(capacity),
            capacity,
            seen: 0,
            emitted: 0,
            dropped: 0,
            next_end: None,
        })
    }

    /// The most events one window can hold.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Events dropped from over-full time windows.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Windows emitted so far.
    pub fn windows(&self) -> usize {
        self.emitted
    }

    /// Adds one event of `camera`; calls `emit` for each window it completes.
    pub fn push(
        &mut self,
        camera: u8,
        event: Event,
        emit: &mut dyn FnMut(&WindowEvents<'_>) -> Result<()>,
    ) -> Result<()> {
        match self.rule {
            WindowRule::Events { size, stride } => {
                if self.ring.len() == self.capacity {
                    self.ring.pop_front();
                }
                self.ring.push_back((camera, event));
                self.seen += 1;
                let size = u64::from(size);
                if self.seen >= size && (self.seen - size).is_multiple_of(u64::from(stride)) {
                    let t0 = self.ring.front().map_or(event.t, |(_, e)| e.t);
                    self.emit((t0, event.t), emit)?;
                }
            }
            WindowRule::Time { size_us, stride_us } => {
                let mut end = *self.next_end.get_or_insert(event.t.saturating_add(size_us));
                while event.t >= end {
                    let start = end - size_us;
                    while self.ring.front().is_some_and(|(_, e)| e.t < start) {
                        self.ring.pop_front();
                    }
                    self.emit((start, end - 1), emit)?;
                    end = end.saturating_add(stride_us);
                    self.next_end = Some(end);
                }
                let start = end - size_us;
                while self.ring.front().is_some_and(|(_, e)| e.t < start) {
                    self.ring.pop_front();
                }
                if self.ring.len() == self.capacity {
                    self.ring.pop_front();
                    self.dropped += 1;
                }
                self.ring.push_back((camera, event));
                self.seen += 1;
            }
        }
        Ok(())
    }

    /// Ends the stream: a stream that gave no window and holds events gives them as one.
    pub fn finish(&mut self, emit: &mut dyn FnMut(&WindowEvents<'_>) -> Result<()>) -> Result<()> {
        if self.emitted == 0 && !self.ring.is_empty() {
            let t0 = self.ring.front().map_or(0, |(_, e)| e.t);
            let t1 = self.ring.back().map_or(0, |(_, e)| e.t);
            self.emit((t0, t1), emit)?;
        }
        Ok(())
    }

    fn emit(
        &mut self,
        t_us: (i64, i64),
        emit: &mut dyn FnMut(&WindowEvents<'_>) -> Result<()>,
    ) -> Result<()> {
        let w = WindowEvents {
            index: self.emitted,
            parts: self.ring.as_slices(),
            t_us,
        };
        emit(&w)?;
        self.emitted += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Windows of a stream of `(camera, t)` events: (index, events' times, span).
    fn cut(rule: WindowRule, capacity: usize, events: &[(u8, i64)]) -> Vec<(Vec<i64>, (i64, i64))> {
        let mut c = Cutter::new(rule, capacity).unwrap();
        let mut out = Vec::new();
        let mut emit = |w: &WindowEvents<'_>| {
            assert_eq!(w.index, out.len());
            let ts = w
                .parts
                .0
                .iter()
                .chain(w.parts.1)
                .map(|(_, e)| e.t)
                .collect();
            out.push((ts, w.t_us));
            Ok(())
        };
        for &(cam, t) in events {
            c.push(cam, Event::new(0, 0, t, true), &mut emit).unwrap();
        }
        c.finish(&mut emit).unwrap();
        out
    }

    fn stream(n: i64) -> Vec<(u8, i64)> {
        (0..n).map(|t| ((t % 4) as u8, 10 * t)).collect()
    }

    #[test]
    fn event_windows_tumble_and_slide() {
        let tumbling = cut(WindowRule::Events { size: 4, stride: 4 }, 0, &stream(10));
        assert_eq!(
            tumbling,
            vec![
                (vec![0, 10, 20, 30], (0, 30)),
                (vec![40, 50, 60, 70], (40, 70)),
            ],
            "the 2-event tail makes no window"
        );
        let sliding = cut(WindowRule::Events { size: 4, stride: 2 }, 0, &stream(9));
        let ends: Vec<_> = sliding.iter().map(|(_, s)| *s).collect();
        assert_eq!(ends, vec![(0, 30), (20, 50), (40, 70)]);
        // A stream shorter than a window is one window.
        assert_eq!(
            cut(WindowRule::Events { size: 4, stride: 4 }, 0, &stream(3)),
            vec![(vec![0, 10, 20], (0, 20))]
        );
        assert!(cut(WindowRule::Events { size: 4, stride: 4 }, 0, &[]).is_empty());
    }

    #[test]
    fn time_windows_cover_fixed_intervals() {
        // Events every 10 µs from t = 0; 25 µs windows every 25 µs: [0, 25), [25, 50), …
        let w = cut(
            WindowRule::Time {
                size_us: 25,
                stride_us: 25,
            },
            100,
            &stream(10),
        );
        assert_eq!(
            w,
            vec![
                (vec![0, 10, 20], (0, 24)),
                (vec![30, 40], (25, 49)),
                (vec![50, 60, 70], (50, 74)),
            ]
        );
        // Sliding by 10 µs over 30 µs windows.
        let w = cut(
            WindowRule::Time {
                size_us: 30,
                stride_us: 10,
            },
            100,
            &stream(6),
        );
        let got: Vec<_> = w.iter().map(|(ts, _)| ts.clone()).collect();
        assert_eq!(
            got,
            vec![vec![0, 10, 20], vec![10, 20, 30], vec![20, 30, 40]]
        );
        // A gap gives empty windows, so that windows keep their times.
        let w = cut(
            WindowRule::Time {
                size_us: 10,
                stride_us: 10,
            },
            100,
            &[(0, 0), (0, 5), (0, 35)],
        );
        assert_eq!(
            w,
            vec![(vec![0, 5], (0, 9)), (vec![], (10, 19)), (vec![], (20, 29))]
        );
        // Over capacity, the oldest events go and are counted.
        let mut c = Cutter::new(
            WindowRule::Time {
                size_us: 1000,
                stride_us: 1000,
            },
            3,
        )
        .unwrap();
        let mut n = 0;
        for t in 0..5 {
            c.push(0, Event::new(0, 0, t, true), &mut |_| Ok(()))
                .unwrap();
        }
        c.push(0, Event::new(0, 0, 1000, true), &mut |w| {
            n = w.len();
            Ok(())
        })
        .unwrap();
        assert_eq!((n, c.dropped()), (3, 2));
    }

    #[test]
    fn rules_are_checked() {
        assert!(Cutter::new(WindowRule::Events { size: 0, stride: 0 }, 0).is_err());
        assert!(Cutter::new(WindowRule::Events { size: 4, stride: 5 }, 0).is_err());
        assert!(Cutter::new(
            WindowRule::Time {
                size_us: 10,
                stride_us: -1
            },
            9
        )
        .is_err());
    }

    #[test]
    fn a_window_gives_each_camera_its_events() {
        let mut c = Cutter::new(WindowRule::Events { size: 8, stride: 8 }, 0).unwrap();
        let mut per_camera = Vec::new();
        for (cam, t) in stream(8) {
            c.push(cam, Event::new(0, 0, t, true), &mut |w| {
                per_camera = (0..4)
                    .map(|k| w.of_camera(k).map(|e| e.t).collect::<Vec<_>>())
                    .collect();
                Ok(())
            })
            .unwrap();
        }
        assert_eq!(per_camera[1], vec![10, 50]);
        assert_eq!(per_camera[3], vec![30, 70]);
    }
}

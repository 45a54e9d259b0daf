//! Cutting a multi-camera event stream into windows: by event count or by time, tumbling or
//! sliding (a stride shorter than the window), over the events of every camera together (as
//! DHP19 counts its windows), in bounded memory: a buffer of at most two windows' events,
//! cameras and events in separate arrays, so that a window is two contiguous slices and
//! events move by plain copies.

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
        let (size, stride, unit) = match *self {
            Self::Events { size, stride } => (i64::from(size), i64::from(stride), " events"),
            Self::Time { size_us, stride_us } => (size_us, stride_us, " µs"),
        };
        if size <= 0 || stride <= 0 || stride > size {
            bail!(
                "window {size}{unit} and stride {stride}{unit}: both must be positive, the stride \
                 at most the window"
            );
        }
        Ok(())
    }
}

/// One window: its events (every camera, in stream order) and its time span.
#[derive(Clone, Copy, Debug)]
pub struct WindowEvents<'a> {
    /// Index from 0.
    pub index: usize,
    /// The camera of each event (as long as `events`).
    pub cameras: &'a [u8],
    /// The events of every camera, in stream order.
    pub events: &'a [Event],
    /// Time span, µs: the first and last event's time for event windows, the nominal
    /// `[start, end)` as `(start, end − 1)` for time windows.
    pub t_us: (i64, i64),
}

impl WindowEvents<'_> {
    /// Events of all cameras.
    pub fn len(&self) -> usize {
        self.events.len()
    }

    /// Whether the window holds no event.
    pub fn is_empty(&self) -> bool {
        self.events.is_empty()
    }

    /// Appends the events of `camera`, in order, each through `map` (which may drop it), to
    /// `out` (`Some` keeps every event; `evpose run` rescales them to the model's sensor).
    pub fn extend_camera(
        &self,
        camera: u8,
        out: &mut Vec<Event>,
        mut map: impl FnMut(Event) -> Option<Event>,
    ) {
        // Two passes, the first without a branch on the camera: the cameras of a multi-camera
        // stream interleave at random, which makes such a branch hard to predict (1.05–1.17×
        // faster on the bundled clip this way). Each event is written at the cursor, which moves
        // on only for `camera`'s; then `map` runs over those in place.
        let base = out.len();
        out.resize(base + self.events.len(), Event::default());
        let dst = &mut out[base..];
        let mut kept = 0;
        for (&c, &e) in self.cameras.iter().zip(self.events) {
            if let Some(d) = dst.get_mut(kept) {
                *d = e;
            }
            kept += usize::from(c == camera);
        }
        out.truncate(base + kept);
        let mut w = base;
        for r in base..out.len() {
            if let Some(e) = map(out[r]) {
                out[w] = e;
                w += 1;
            }
        }
        out.truncate(w);
    }
}

/// The cutter's events: `cameras[start..]` and `events[start..]`, appended at the end and
/// dropped from the front, moved back to the start of their arrays once the dropped prefix is
/// as long as a window (so each event is copied at most twice, and the arrays hold at most
/// two windows' events).
#[derive(Debug, Default)]
struct Buffer {
    cameras: Vec<u8>,
    events: Vec<Event>,
    start: usize,
}

impl Buffer {
    fn len(&self) -> usize {
        self.events.len() - self.start
    }

    fn front(&self) -> Option<&Event> {
        self.events.get(self.start)
    }

    fn back(&self) -> Option<&Event> {
        self.events[self.start..].last()
    }

    /// Drops the `n` oldest events (all, if fewer).
    fn drop_front(&mut self, n: usize) {
        self.start += n.min(self.len());
    }

    /// Appends events, first moving the live ones to the front if `window` events were dropped.
    fn extend(&mut self, cameras: &[u8], events: &[Event], window: usize) {
        if self.start >= window {
            self.cameras.drain(..self.start);
            self.events.drain(..self.start);
            self.start = 0;
        }
        self.cameras.extend_from_slice(cameras);
        self.events.extend_from_slice(events);
    }

    fn view(&self, index: usize, t_us: (i64, i64)) -> WindowEvents<'_> {
        WindowEvents {
            index,
            cameras: &self.cameras[self.start..],
            events: &self.events[self.start..],
            t_us,
        }
    }
}

/// The most empty time windows a gap without events gives (see [`Cutter`]).
pub const MAX_GAP_WINDOWS: i64 = 10_000;

/// The window cutter: events go in (one at a time, or a reader's batch at once), complete windows
/// come out.
///
/// Event windows are complete when `size` events have arrived (then every `stride` events);
/// time windows when an event at or after their end arrives. The stream's tail, shorter than
/// one stride, makes no window, except that a stream too short for any window is one window.
/// Time windows hold at most `capacity` events: beyond it the oldest are dropped
/// ([`Cutter::dropped`]). A gap without events gives at most [`MAX_GAP_WINDOWS`] empty time
/// windows; those before them are skipped and counted ([`Cutter::skipped`]), so that a
/// timestamp jump (a glitch of hours) costs no billion empty estimates.
#[derive(Debug)]
pub struct Cutter {
    rule: WindowRule,
    buffer: Buffer,
    capacity: usize,
    emitted: usize,
    dropped: u64,
    skipped: u64,
    /// Time windows: the end of the next window, µs (set by the first event).
    next_end: Option<i64>,
    /// Event windows: events to take before the next window is complete.
    until_window: u64,
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
            buffer: Buffer::default(),
            capacity,
            emitted: 0,
            dropped: 0,
            skipped: 0,
            next_end: None,
            until_window: match rule {
                WindowRule::Events { size, .. } => u64::from(size),
                WindowRule::Time { .. } => 0,
            },
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

    /// Empty time windows skipped over gaps longer than [`MAX_GAP_WINDOWS`] windows.
    pub fn skipped(&self) -> u64 {
        self.skipped
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
        self.push_batch(&[camera], &[event], emit)
    }

    /// Adds events in order (`cameras[i]` is `events[i]`'s camera; the shorter slice bounds
    /// both); calls `emit` for each window they complete. The same windows as pushing them
    /// one by one; event windows take the events between two windows as one copy.
    pub fn push_batch(
        &mut self,
        cameras: &[u8],
        events: &[Event],
        emit: &mut dyn FnMut(&WindowEvents<'_>) -> Result<()>,
    ) -> Result<()> {
        let n = cameras.len().min(events.len());
        let (cameras, events) = (&cameras[..n], &events[..n]);
        match self.rule {
            WindowRule::Events { stride, .. } => {
                let mut at = 0;
                while at < n {
                    // Up to the event that completes the next window (at most `stride ≤
                    // size` events, so the buffer keeps them all).
                    let take = (n - at).min(usize::try_from(self.until_window).unwrap_or(n));
                    let b = &mut self.buffer;
                    b.drop_front((b.len() + take).saturating_sub(self.capacity));
                    let range = at..at + take;
                    b.extend(&cameras[range.clone()], &events[range], self.capacity);
                    at += take;
                    self.until_window -= take as u64;
                    if self.until_window == 0 {
                        let t0 = self.buffer.front().map_or(0, |e| e.t);
                        let t1 = self.buffer.back().map_or(0, |e| e.t);
                        self.emit((t0, t1), emit)?;
                        self.until_window = u64::from(stride);
                    }
                }
            }
            WindowRule::Time { size_us, stride_us } => {
                for (&camera, &event) in cameras.iter().zip(events) {
                    let mut end = *self.next_end.get_or_insert(event.t.saturating_add(size_us));
                    while event.t >= end {
                        let start = end - size_us;
                        self.drop_before(start);
                        if self.buffer.len() == 0 {
                            // Every window from here to `event`'s is empty: keep the last
                            // `MAX_GAP_WINDOWS` of them.
                            let empty = event.t.saturating_sub(end) / stride_us + 1;
                            let skip = empty - empty.min(MAX_GAP_WINDOWS);
                            if skip > 0 {
                                self.skipped += skip as u64;
                                end = end.saturating_add(skip.saturating_mul(stride_us));
                                self.next_end = Some(end);
                                continue;
                            }
                        }
                        self.emit((start, end - 1), emit)?;
                        end = end.saturating_add(stride_us);
                        self.next_end = Some(end);
                    }
                    self.drop_before(end - size_us);
                    if self.buffer.len() == self.capacity {
                        self.buffer.drop_front(1);
                        self.dropped += 1;
                    }
                    self.buffer.extend(&[camera], &[event], self.capacity);
                }
            }
        }
        Ok(())
    }

    /// Ends the stream: a stream that gave no window and holds events gives them as one.
    pub fn finish(&mut self, emit: &mut dyn FnMut(&WindowEvents<'_>) -> Result<()>) -> Result<()> {
        if self.emitted == 0 && self.buffer.len() > 0 {
            let t0 = self.buffer.front().map_or(0, |e| e.t);
            let t1 = self.buffer.back().map_or(0, |e| e.t);
            self.emit((t0, t1), emit)?;
        }
        Ok(())
    }

    /// Time windows: drops the oldest events while they lie before `start`.
    fn drop_before(&mut self, start: i64) {
        let live = &self.buffer.events[self.buffer.start..];
        // Events come in time order but for the odd one out of order: drop up to the first
        // event at or after `start`, as a queue would.
        let n = live.iter().position(|e| e.t >= start).unwrap_or(live.len());
        self.buffer.drop_front(n);
    }

    fn emit(
        &mut self,
        t_us: (i64, i64),
        emit: &mut dyn FnMut(&WindowEvents<'_>) -> Result<()>,
    ) -> Result<()> {
        emit(&self.buffer.view(self.emitted, t_us))?;
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
            let ts = w.events.iter().map(|e| e.t).collect();
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
        // A jump of a million windows (a glitched timestamp) gives only the last
        // `MAX_GAP_WINDOWS` empty ones, the rest counted as skipped, and so does a second gap
        // of three times that; windows keep their times. Sliding windows likewise.
        for (size_us, stride_us) in [(1_000, 1_000), (3_000, 1_000)] {
            let rule = WindowRule::Time { size_us, stride_us };
            let mut c = Cutter::new(rule, 100).unwrap();
            let mut got = Vec::new();
            let jump = 1_000_000_000 + 500;
            let last = jump + 3 * MAX_GAP_WINDOWS * stride_us;
            for t in [0, 10, jump, last] {
                c.push(0, Event::new(0, 0, t, true), &mut |w| {
                    got.push((w.len(), w.t_us));
                    Ok(())
                })
                .unwrap();
            }
            let empty = got.iter().filter(|(n, _)| *n == 0).count() as i64;
            assert_eq!(empty, 2 * MAX_GAP_WINDOWS, "{size_us}");
            // Every window that ends by the last event is emitted or skipped.
            let ends = (last - size_us) / stride_us + 1;
            assert_eq!(c.skipped() as i64 + c.windows() as i64, ends, "{size_us}");
            assert_eq!(c.windows(), got.len());
            // Times run on: the windows just before the jumped event end just before it.
            let before = got.iter().rev().find(|(_, (_, t1))| *t1 < jump).unwrap();
            assert!(jump - before.1 .1 <= stride_us, "{before:?}");
            assert!(got.windows(2).all(|w| w[1].1 .0 > w[0].1 .0));
        }
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

    /// Batches of any size give the windows that single events give, and the buffer never
    /// holds more than two windows' events.
    #[test]
    fn batches_cut_the_windows_of_single_events() {
        type Cut = (usize, Vec<u8>, Vec<Event>, (i64, i64));
        let events: Vec<(u8, Event)> = (0..2_000i64)
            .map(|i| {
                let t = 7 * i + (i * i) % 13; // in order, with repeated steps
                (
                    (i % 3) as u8,
                    Event::new((i % 17) as u16, (i % 11) as u16, t, i % 2 == 0),
                )
            })
            .collect();
        let rules = [
            (
                WindowRule::Events {
                    size: 64,
                    stride: 64,
                },
                0,
            ),
            (
                WindowRule::Events {
                    size: 100,
                    stride: 30,
                },
                0,
            ),
            (
                WindowRule::Events {
                    size: 5_000,
                    stride: 5_000,
                },
                0,
            ),
            (
                WindowRule::Time {
                    size_us: 300,
                    stride_us: 120,
                },
                40,
            ),
        ];
        let mut state = 12345u64;
        for (rule, capacity) in rules {
            let run = |sizes: &mut dyn FnMut() -> usize| -> Vec<Cut> {
                let mut c = Cutter::new(rule, capacity).unwrap();
                let mut out = Vec::new();
                let mut emit = |w: &WindowEvents<'_>| {
                    out.push((w.index, w.cameras.to_vec(), w.events.to_vec(), w.t_us));
                    Ok(())
                };
                let mut at = 0;
                while at < events.len() {
                    let n = sizes().min(events.len() - at);
                    let (cams, evs): (Vec<u8>, Vec<Event>) =
                        events[at..at + n].iter().copied().unzip();
                    c.push_batch(&cams, &evs, &mut emit).unwrap();
                    assert!(c.buffer.events.len() <= 2 * c.capacity, "{rule:?}");
                    at += n;
                }
                c.finish(&mut emit).unwrap();
                out
            };
            let single = run(&mut || 1);
            let batched = run(&mut || {
                state = state
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1);
                (state >> 33) as usize % 300
            });
            assert!(!single.is_empty());
            assert_eq!(single, batched, "{rule:?}");
        }
    }

    #[test]
    fn a_window_gives_each_camera_its_events() {
        let mut c = Cutter::new(WindowRule::Events { size: 8, stride: 8 }, 0).unwrap();
        let mut per_camera = Vec::new();
        for (cam, t) in stream(8) {
            c.push(cam, Event::new(0, 0, t, true), &mut |w| {
                per_camera = (0..4)
                    .map(|k| {
                        let mut evs = Vec::new();
                        w.extend_camera(k, &mut evs, Some);
                        evs.iter().map(|e| e.t).collect::<Vec<_>>()
                    })
                    .collect();
                Ok(())
            })
            .unwrap();
        }
        assert_eq!(per_camera[1], vec![10, 50]);
        assert_eq!(per_camera[3], vec![30, 70]);
    }

    #[test]
    fn extend_camera_appends_the_cameras_mapped_events_in_order() {
        // Cameras in a scrambled order, a map that drops some events and moves the rest, and
        // an `out` that already holds an event: the same as a plain filter and map.
        let mut c = Cutter::new(
            WindowRule::Events {
                size: 64,
                stride: 64,
            },
            0,
        )
        .unwrap();
        let mut state = 7u32;
        let mut seen = Vec::new();
        for i in 0..64 {
            state = state.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            let cam = (state >> 16) as u8 % 3;
            let e = Event::new(i % 7, i % 5, i64::from(i), i % 2 == 0);
            seen.push((cam, e));
            c.push(cam, e, &mut |w| {
                let map = |e: Event| (e.x != 3).then_some(Event { y: e.y + 1, ..e });
                for k in 0..4 {
                    let first = Event::new(9, 9, -1, true);
                    let mut got = vec![first];
                    w.extend_camera(k, &mut got, map);
                    let want: Vec<Event> = std::iter::once(first)
                        .chain(
                            seen.iter()
                                .filter(|(c, _)| *c == k)
                                .filter_map(|&(_, e)| map(e)),
                        )
                        .collect();
                    assert_eq!(got, want, "camera {k}");
                }
                Ok(())
            })
            .unwrap();
        }
    }
}

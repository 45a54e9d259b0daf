//! Rasterizer behaviour: against a naive dense-grid reference, and every odd input case.

use evpose_core::raster::{
    ConfigError, DropReason, InlineStorage, RasterStats, RasterStorage, WindowSummary,
};
use evpose_core::{Event, Point, Pushed, RasterConfig, Rasterizer, WindowRule};
use proptest::prelude::*;

type Small = InlineStorage<64, 16, 32>;

fn config(window: WindowRule) -> RasterConfig {
    RasterConfig {
        width: 16,
        height: 8,
        slices: 4,
        window,
    }
}

/// The reference algorithm, written the obvious way: a dense (K, H, W) grid, f64 slicing,
/// f32 accumulation in arrival order.
fn reference(events: &[Event], c: &RasterConfig) -> Vec<Point> {
    if events.is_empty() {
        return Vec::new();
    }
    let k = usize::from(c.slices);
    let (w, h) = (usize::from(c.width), usize::from(c.height));
    let t_min = events.iter().map(|e| e.t).min().unwrap() as f64;
    let t_max = events.iter().map(|e| e.t).max().unwrap() as f64;
    let mut grid = vec![(0u32, 0i32, 0f32); k * h * w];
    for e in events {
        let (slice, frac) = if t_max > t_min {
            let tn = (e.t as f64 - t_min) / (t_max - t_min) / 1.001 * k as f64;
            let s = tn.floor();
            (s as usize, (tn - s) as f32)
        } else {
            (0, 0.0)
        };
        let cell = &mut grid[(slice * h + usize::from(e.y)) * w + usize::from(e.x)];
        cell.0 += 1;
        cell.1 += if e.on { 1 } else { -1 };
        cell.2 += frac;
    }
    let mut out = Vec::new();
    for (i, &(cnt, p_acc, f_acc)) in grid.iter().enumerate() {
        if cnt > 0 {
            let slice = i / (h * w);
            out.push(Point {
                x: (i % w) as u16,
                y: (i / w % h) as u16,
                slice: slice as u8,
                t_avg: (f_acc / cnt as f32) / k as f32 + slice as f32 / k as f32,
                p_acc,
                cnt,
            });
        }
    }
    out
}

fn events_strategy(max: usize) -> impl Strategy<Value = Vec<Event>> {
    prop::collection::vec(
        (0u16..16, 0u16..8, -50i64..1_000, any::<bool>())
            .prop_map(|(x, y, t, on)| Event::new(x, y, t, on)),
        1..max,
    )
}

fn window_of<S: RasterStorage>(r: &mut Rasterizer<S>, events: &[Event]) -> Vec<Point> {
    for &e in events {
        assert!(matches!(r.push(e), Pushed::Buffered));
    }
    r.flush().iter().collect()
}

proptest! {
    /// Any event set (unordered timestamps, repeated cells, ties) rasterizes like the reference.
    /// Exact equality: with arrival order kept inside each cell, even the f32 sums match.
    #[test]
    fn matches_dense_reference(events in events_strategy(64)) {
        let c = config(WindowRule::Events(64));
        let mut r = Rasterizer::new(c, Small::new()).unwrap();
        prop_assert_eq!(window_of(&mut r, &events), reference(&events, &c));
    }

    /// A rasterizer in borrowed storage (`&mut S`, e.g. a `static` on an MCU) works as in owned
    /// storage, and the storage stays usable after it.
    #[test]
    fn borrowed_storage_rasterizes_like_owned(events in events_strategy(64)) {
        let c = config(WindowRule::Events(64));
        let mut storage = Small::new();
        let mut borrowed = Rasterizer::new(c, &mut storage).unwrap();
        for &e in &events {
            prop_assert!(matches!(borrowed.push(e), Pushed::Buffered));
        }
        let got: Vec<Point> = borrowed.flush().iter().collect();
        prop_assert_eq!(&got, &reference(&events, &c));
        let mut again = Rasterizer::new(c, &mut storage).unwrap();
        prop_assert_eq!(window_of(&mut again, &events), got);
    }

    /// Count windows cut the stream into consecutive chunks, each rasterized on its own.
    #[test]
    fn count_windows_are_consecutive_chunks(events in events_strategy(200), n in 1u32..40) {
        let c = config(WindowRule::Events(n));
        let mut r = Rasterizer::new(c, Small::new()).unwrap();
        let mut got = Vec::new();
        for &e in &events {
            if let Pushed::Window(w) = r.push(e) {
                got.push(w.iter().collect::<Vec<_>>());
            }
        }
        if r.buffered() > 0 {
            got.push(r.flush().iter().collect());
        }
        let want: Vec<_> = events.chunks(n as usize).map(|ch| reference(ch, &c)).collect();
        prop_assert_eq!(got, want);
    }
}

/// Everything a rasterizer produced: windows (points + summary) and final counters.
fn outcome_by_push(
    c: RasterConfig,
    events: &[Event],
) -> (
    Vec<(Vec<Point>, evpose_core::raster::WindowSummary)>,
    RasterStats,
) {
    let mut r = Rasterizer::new(c, Small::new()).unwrap();
    let mut out = Vec::new();
    for &e in events {
        if let Pushed::Window(w) = r.push(e) {
            out.push((w.iter().collect(), w.summary()));
        }
    }
    (out, *r.stats())
}

fn outcome_by_extend(
    c: RasterConfig,
    events: &[Event],
    chunk: usize,
) -> (
    Vec<(Vec<Point>, evpose_core::raster::WindowSummary)>,
    RasterStats,
) {
    let mut r = Rasterizer::new(c, Small::new()).unwrap();
    let mut out = Vec::new();
    for mut part in events.chunks(chunk) {
        while !part.is_empty() {
            let (used, w) = r.extend(part);
            if let Some(w) = w {
                out.push((w.iter().collect(), w.summary()));
            }
            part = &part[used..];
        }
    }
    (out, *r.stats())
}

proptest! {
    /// `extend` over buffers of any size is `push` event by event: same windows, same counters,
    /// with out-of-range pixels, backwards time, time jumps and both window rules.
    #[test]
    fn extend_equals_push(
        events in prop::collection::vec(
            (0u16..18, 0u16..9, prop_oneof![8 => -50i64..1_000, 1 => Just(i64::MAX), 1 => Just(i64::MIN)], any::<bool>())
                .prop_map(|(x, y, t, on)| Event::new(x, y, t, on)),
            0..300,
        ),
        rule in prop_oneof![(1u32..70).prop_map(WindowRule::Events), (1u32..400).prop_map(WindowRule::Duration)],
        chunk in 1usize..100,
    ) {
        let c = config(rule).clamp_events(64);
        prop_assert_eq!(outcome_by_extend(c, &events, chunk), outcome_by_push(c, &events));
    }
}

proptest! {
    /// In-order streams (the common case, whose window range the rasterizer takes from the
    /// first and last events instead of a pass over the window), through `extend` in buffers
    /// of any size: every count window rasterizes like the reference, and its summary spans
    /// its first to its last event. A stream sorted in pieces also puts a window's first event
    /// before the previous window's last.
    #[test]
    fn in_order_windows_match_reference(
        mut events in events_strategy(300),
        n in 1u32..64,
        chunk in 1usize..100,
        pieces in 1usize..4,
    ) {
        let len = events.len();
        for piece in events.chunks_mut(len.div_ceil(pieces)) {
            piece.sort_by_key(|e| e.t);
        }
        let c = config(WindowRule::Events(n));
        let (got, _) = outcome_by_extend(c, &events, chunk);
        let full = events.len() / n as usize;
        prop_assert_eq!(got.len(), full);
        for ((points, summary), ch) in got.iter().zip(events.chunks(n as usize)) {
            prop_assert_eq!(points, &reference(ch, &c));
            let (lo, hi) = (ch.iter().map(|e| e.t).min(), ch.iter().map(|e| e.t).max());
            prop_assert_eq!((Some(summary.t_min), Some(summary.t_max)), (lo, hi));
        }
    }
}

trait ClampEvents {
    fn clamp_events(self, cap: u32) -> Self;
}

impl ClampEvents for RasterConfig {
    fn clamp_events(mut self, cap: u32) -> Self {
        if let WindowRule::Events(n) = self.window {
            self.window = WindowRule::Events(n.min(cap));
        }
        self
    }
}

#[test]
fn out_of_range_pixels_are_dropped_and_counted() {
    let mut r = Rasterizer::new(config(WindowRule::Events(4)), Small::new()).unwrap();
    assert!(matches!(
        r.push(Event::new(16, 0, 0, true)),
        Pushed::Dropped(DropReason::OutOfRange)
    ));
    assert!(matches!(
        r.push(Event::new(0, 8, 0, true)),
        Pushed::Dropped(DropReason::OutOfRange)
    ));
    assert!(matches!(
        r.push(Event::new(15, 7, 0, true)),
        Pushed::Buffered
    ));
    assert_eq!(r.stats().dropped_out_of_range, 2);
    assert_eq!(r.stats().accepted, 1);
    assert_eq!(r.buffered(), 1);
}

#[test]
fn backwards_timestamps_are_accepted_counted_and_order_free() {
    let c = config(WindowRule::Events(8));
    let fwd = [0, 10, 20, 30].map(|t| Event::new(1, 1, t, true));
    let mut rev = fwd;
    rev.reverse();
    let mut r = Rasterizer::new(c, Small::new()).unwrap();
    let a = window_of(&mut r, &fwd);
    let b = window_of(&mut r, &rev);
    assert_eq!(a, b);
    // The second window starts at 30 after 30 (not backwards); 20, 10 and 0 go backwards.
    assert_eq!(r.stats().out_of_order, 3);
}

#[test]
fn one_timestamp_puts_everything_in_slice_zero() {
    let c = config(WindowRule::Events(8));
    let mut r = Rasterizer::new(c, Small::new()).unwrap();
    let pts = window_of(
        &mut r,
        &[
            Event::new(3, 2, 77, true),
            Event::new(3, 2, 77, false),
            Event::new(5, 2, 77, true),
        ],
    );
    assert_eq!(
        pts,
        vec![
            Point {
                x: 3,
                y: 2,
                slice: 0,
                t_avg: 0.0,
                p_acc: 0,
                cnt: 2
            },
            Point {
                x: 5,
                y: 2,
                slice: 0,
                t_avg: 0.0,
                p_acc: 1,
                cnt: 1
            },
        ]
    );
}

#[test]
fn empty_window_has_no_points() {
    let mut r = Rasterizer::new(config(WindowRule::Events(8)), Small::new()).unwrap();
    let w = r.flush();
    assert!(w.is_empty());
    assert_eq!(w.summary().events, 0);
    assert_eq!(r.stats().windows, 1);
    // After a window with events, an empty one still has no time extent (nothing stale).
    for i in 0..8 {
        r.push(Event::new(i, 0, 1_000 + i64::from(i), true));
    }
    assert_eq!(r.last_window().unwrap().summary().events, 8);
    assert_eq!(r.flush().summary(), WindowSummary::default());
}

#[test]
fn full_capacity_closes_the_window() {
    // Duration windows longer than the storage: the 64th event closes the window.
    let mut r = Rasterizer::new(config(WindowRule::Duration(1_000_000)), Small::new()).unwrap();
    let mut closed_at = None;
    for i in 0..100 {
        if let Pushed::Window(w) = r.push(Event::new(i % 16, 0, i64::from(i), true)) {
            assert_eq!(w.summary().events, 64);
            closed_at.get_or_insert(i);
        }
    }
    assert_eq!(closed_at, Some(63));
    assert_eq!(r.stats().windows_full, 1);
    assert_eq!(r.stats().accepted, 100);
    assert_eq!(r.buffered(), 36);
}

#[test]
fn duration_window_hands_the_closing_event_to_the_next_window() {
    let mut r = Rasterizer::new(config(WindowRule::Duration(100)), Small::new()).unwrap();
    assert!(matches!(
        r.push(Event::new(0, 0, 1_000, true)),
        Pushed::Buffered
    ));
    assert!(matches!(
        r.push(Event::new(1, 0, 1_099, true)),
        Pushed::Buffered
    ));
    // Older than the window start: still joins the open window.
    assert!(matches!(
        r.push(Event::new(2, 0, 990, false)),
        Pushed::Buffered
    ));
    match r.push(Event::new(3, 0, 1_100, true)) {
        Pushed::Window(w) => {
            assert_eq!(w.summary().events, 3);
            assert_eq!((w.summary().t_min, w.summary().t_max), (990, 1_099));
        }
        other => panic!("expected a window, got {other:?}"),
    }
    let next: Vec<_> = r.flush().iter().collect();
    assert_eq!(next.len(), 1);
    assert_eq!((next[0].x, next[0].t_avg), (3, 0.0));
    assert_eq!(r.stats().accepted, 4);
}

#[test]
fn a_time_jump_beyond_i32_microseconds_starts_a_new_window() {
    let mut r = Rasterizer::new(config(WindowRule::Events(8)), Small::new()).unwrap();
    assert!(matches!(
        r.push(Event::new(0, 0, 0, true)),
        Pushed::Buffered
    ));
    assert!(matches!(
        r.push(Event::new(1, 0, i64::MIN, true)),
        Pushed::Window(_)
    ));
    assert!(matches!(
        r.push(Event::new(2, 0, i64::MIN + 5, true)),
        Pushed::Buffered
    ));
    let w: Vec<_> = r.flush().iter().collect();
    assert_eq!(w.iter().map(|p| p.x).collect::<Vec<_>>(), vec![1, 2]);
    assert_eq!(r.stats().time_jumps, 1);
}

#[test]
fn single_event_windows_with_a_held_event() {
    // Events(1) with a pending event: each push closes exactly one window.
    let mut r = Rasterizer::new(config(WindowRule::Events(1)), Small::new()).unwrap();
    for t in [0, i64::MAX, 0, 5] {
        assert!(matches!(
            r.push(Event::new(1, 1, t, true)),
            Pushed::Window(_)
        ));
    }
    assert_eq!(r.stats().windows, 4);
}

#[test]
fn bad_configurations_are_typed_errors() {
    let err = |c: RasterConfig| Rasterizer::new(c, Small::new()).err();
    let ok = config(WindowRule::Events(8));
    assert_eq!(
        err(RasterConfig { width: 0, ..ok }),
        Some(ConfigError::Width(0))
    );
    assert_eq!(
        err(RasterConfig { height: 2000, ..ok }),
        Some(ConfigError::Height(2000))
    );
    assert_eq!(
        err(RasterConfig { slices: 9, ..ok }),
        Some(ConfigError::Slices(9))
    );
    assert_eq!(
        err(RasterConfig { width: 17, ..ok }),
        Some(ConfigError::Histogram {
            needed: 17,
            available: 16
        })
    );
    assert_eq!(
        err(RasterConfig { slices: 5, ..ok }),
        Some(ConfigError::Histogram {
            needed: 40,
            available: 32
        })
    );
    assert_eq!(
        err(config(WindowRule::Events(65))),
        Some(ConfigError::Capacity {
            needed: 65,
            available: 64
        })
    );
    assert_eq!(
        err(config(WindowRule::Duration(0))),
        Some(ConfigError::EmptyWindow)
    );
    // Offsets from a window's first event are i32: a longer duration could never be reached.
    let long = i32::MAX as u32 + 1;
    assert_eq!(
        err(config(WindowRule::Duration(long))),
        Some(ConfigError::Duration(long))
    );
    assert_eq!(err(config(WindowRule::Duration(long - 1))), None);
}

#[test]
fn stats_start_at_zero() {
    let r = Rasterizer::new(config(WindowRule::Events(8)), Small::new()).unwrap();
    assert_eq!(*r.stats(), RasterStats::default());
}

#[test]
fn memory_per_event_is_within_budget() {
    // 16 bytes per event of capacity (output included) + 4 bytes per histogram bin.
    let bytes = core::mem::size_of::<evpose_core::Davis346Storage>();
    assert_eq!(bytes, 16 * 7_500 + 4 * (346 + 1_040));
    assert!(bytes as f64 / 7_500.0 <= 20.0);
}

/// Storage for the in-order slice tests: up to 512 events on the 16 × 8 test sensor, K ≤ 8.
type Wide = InlineStorage<512, 16, 64>;

/// Rasterizes `events` (one window, in time order) with `slices` slices and compares with the
/// reference; `what` names the case.
fn assert_window_matches_reference(events: &[Event], slices: u8, what: &str) {
    let c = RasterConfig {
        slices,
        ..config(WindowRule::Events(512))
    };
    let mut r = Rasterizer::new(c, Wide::new()).unwrap();
    assert_eq!(window_of(&mut r, events), reference(events, &c), "{what}");
}

/// In-order windows take their slices from runs of arrival order whose ends are found by
/// bisection: for every slice count, every offset of small spans and the offsets on both sides
/// of every slice boundary of larger ones (the boundaries of `tn` fall between, and exactly on,
/// integer offsets), events rasterize like the reference.
#[test]
fn in_order_slice_runs_end_where_the_reference_slices_change() {
    let mut windows: Vec<(i64, Vec<i64>)> = (1..=300).map(|s| (s, (0..=s).collect())).collect();
    for span in [1_001i64, 4_004, 65_537, 999_999, 2_000_000_000] {
        windows.push((span, Vec::new()));
    }
    for slices in 1..=8u8 {
        for (span, offsets) in &windows {
            let mut offsets = offsets.clone();
            if offsets.is_empty() {
                offsets = vec![0, *span];
                for j in 1..i64::from(slices) {
                    let at = (j as f64 * *span as f64 * 1.001 / f64::from(slices)) as i64;
                    offsets.extend((at - 2..=at + 2).filter(|t| (0..=*span).contains(t)));
                }
                offsets.sort_unstable();
            }
            let events: Vec<Event> = offsets
                .iter()
                .enumerate()
                .map(|(i, &t)| {
                    Event::new((i % 16) as u16, (i / 3 % 8) as u16, 5_000 + t, i % 2 == 0)
                })
                .collect();
            assert_window_matches_reference(&events, slices, &format!("K = {slices}, span {span}"));
        }
    }
}

/// Slices of an in-order window longer than the 64 sorted words built at a time (full chunks,
/// a partial last one, empty slices between), on few cells so that cells sum many fractions.
#[test]
fn long_in_order_slices_match_reference() {
    for slices in [1u8, 2, 8] {
        for (first, last) in [(63usize, 65usize), (64, 129), (150, 1)] {
            let times = (0..first as i64)
                .map(|i| i / 7)
                .chain((0..last as i64).map(|i| 10_000 - i / 5));
            let mut times: Vec<i64> = times.collect();
            times.sort_unstable();
            let events: Vec<Event> = times
                .iter()
                .enumerate()
                .map(|(i, &t)| Event::new((i % 3) as u16, (i % 2) as u16, t, i % 5 != 0))
                .collect();
            let what = format!("K = {slices}, {first} + {last} events");
            assert_window_matches_reference(&events, slices, &what);
        }
    }
}

/// The word layouts at their limits: the widest and tallest sensor, eight slices, and the last
/// pixel (column 2,047, row 1,023, ON) in the last slice, whose row bin is the largest (8,191).
#[test]
fn largest_sensor_and_last_row_bin_match_reference() {
    type Largest = InlineStorage<8, 2048, 8192>;
    let c = RasterConfig {
        width: 2048,
        height: 1024,
        slices: 8,
        window: WindowRule::Events(8),
    };
    let events = [
        Event::new(0, 0, 0, false),
        Event::new(2047, 0, 10, true),
        Event::new(0, 1023, 500, true),
        Event::new(2047, 1023, 999, true),
        Event::new(2047, 1023, 1_000, true),
        Event::new(2047, 1023, 1_000, false),
    ];
    let mut storage = Box::new(Largest::new());
    let mut r = Rasterizer::new(c, &mut *storage).unwrap();
    let got = window_of(&mut r, &events);
    assert_eq!(got, reference(&events, &c));
    let last = got.last().unwrap();
    assert_eq!((last.x, last.y, last.slice, last.cnt), (2047, 1023, 7, 3));
}

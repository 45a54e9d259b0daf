//! Streaming rasterization of events into the paper's event point cloud (Sec. 3.2).
//!
//! Events are pushed one at a time into a window. When the window closes (after a fixed event
//! count, a fixed duration, or when its capacity is full) the rasterizer turns it into points
//! `[x, y, t_avg, p_acc, cnt]`, one per non-empty cell `(slice, y, x)`, ordered by slice, then
//! `y`, then `x`, with exactly the reference semantics (`shared/docs/paper-notes.md`):
//!
//! ```text
//! tn = (t - t_min) / (t_max - t_min) / 1.001 * K      (f64)
//! k  = floor(tn),  f = f32(tn - k)
//! per cell: cnt += 1, p_acc += 2p - 1, f_acc += f     (f32, in arrival order)
//! t_avg = (f_acc / cnt) / K + k / K                   (f32)
//! ```
//!
//! # Memory
//! No dense `K × H × W` grid (346 × 260 × 4 cells would not fit an MCU). A window of capacity
//! `C` uses two `u64` words per event (16 bytes, the output points included) plus one `u32`
//! histogram bin per column and per `(slice, row)`: for DAVIS346 and `K = 4`, 5.5 KiB whatever `C`.
//! The close also takes 512 bytes of stack (a chunk of 64 sorted words).
//!
//! # Algorithm
//! While a window fills, each event is packed into one word of buffer A and counted in a
//! per-column histogram; the window's time range is its first and last event's unless an event
//! came out of order (then the close finds it in one pass). On close, two stable counting-sort
//! passes put events in cell order while keeping arrival order inside a cell, so the f32
//! fraction sums add up in the same order as the reference: the first turns each word into its
//! slice and fraction, counts its `(slice, row)` bin and scatters it by column into buffer B
//! (the bin written into the word), the second scatters by bin back into A. A final pass merges
//! runs of equal cells into points, written over the consumed prefix of A and B; a point keeps
//! its row bin, split into slice and row when the point is read.
//!
//! In a window whose events came in time order (every real recording's), slices are runs of
//! arrival order: the close finds each run's end by bisection with the same f64 arithmetic and
//! gives its events their slice without computing one per event. On 32-bit Arm builds without
//! `arm-fpv5` (cores whose f64 is software: Cortex-M0, M4, M33) each fraction is first computed
//! in integers, exactly where an error bound proves it (`FixedFraction`), and in f64 otherwise.
//!
//! # Odd input, defined
//! - A pixel outside the configured sensor is dropped and counted ([`RasterStats::dropped_out_of_range`]).
//! - A timestamp going backwards is accepted: rasterization depends only on the window's
//!   `t_min`/`t_max`, never on order, exactly as in the reference. It is counted
//!   ([`RasterStats::out_of_order`]). With a duration rule, the window's span is measured from its
//!   first event, so an event older than that still joins the open window.
//! - An event more than `i32::MAX` µs (about 36 minutes) away from the window's first event
//!   closes the window and opens the next one ([`RasterStats::time_jumps`]).
//! - A full window is closed, never silently dropped from ([`RasterStats::windows_full`]).
//! - All events at one timestamp: every event goes to slice 0 with fraction 0.
//! - An empty window ([`Rasterizer::flush`] before any event) yields zero points.

use core::fmt;

use crate::event::Event;

/// Largest supported sensor width (the column is stored in 11 bits).
pub const MAX_WIDTH: u16 = 2048;
/// Largest supported sensor height (the row is stored in 10 bits).
pub const MAX_HEIGHT: u16 = 1024;
/// Largest supported number of time slices `K` (stored in 3 bits).
pub const MAX_SLICES: u8 = 8;
/// The paper's number of time slices.
pub const DEFAULT_SLICES: u8 = 4;
/// The paper's per-camera window: 7,500 events.
pub const DEFAULT_WINDOW_EVENTS: u32 = 7_500;

/// The normalization factor of the reference code: keeps the last event inside slice `K - 1`.
const SPAN_FACTOR: f64 = 1.001;

// Layout of a buffered event word (before close):   x:11 | (zero):4 | p:1 | y:10 | (zero):6 | t_off + 2^31:32 (u32)
// Layout of a sorted word (after the slice pass):   x:11 | (zero):4 | p:1 | row bin k·H + y:13 | (zero):3 | f32 bits:32
// Layout of a point, word A:                        x:11 | (zero):5 | row bin k·H + y:13 | (zero):3 | cnt:32
// Layout of a point, word B:                        f_acc f32 bits:32 | p_acc i32:32
//
// The row bin sits where the row was: a sorted word's low half is its buffered word's plus
// `k·H << RB_SHIFT`, and its bin is that half shifted down (bins stay below
// `MAX_SLICES · MAX_HEIGHT = 8,192`: 13 bits).
const X_MASK: u64 = (1 << 11) - 1;
const P_SHIFT: u32 = 15;
const RB_SHIFT: u32 = 16;
const RB_MASK: u64 = (1 << 13) - 1;

/// When a window closes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WindowRule {
    /// Close after this many accepted events (the paper: 7,500 per camera).
    Events(u32),
    /// Close when an event arrives at least this many µs after the window's first event; that
    /// event opens the next window.
    Duration(u32),
}

/// Runtime configuration of a [`Rasterizer`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RasterConfig {
    /// Sensor width in pixels, `1..=MAX_WIDTH`.
    pub width: u16,
    /// Sensor height in pixels, `1..=MAX_HEIGHT`.
    pub height: u16,
    /// Number of time slices `K`, `1..=MAX_SLICES`.
    pub slices: u8,
    /// When a window closes. A window also closes when the storage is full.
    pub window: WindowRule,
}

impl RasterConfig {
    /// The paper's configuration for a DAVIS346 camera: 346 × 260, `K = 4`, 7,500-event windows.
    pub const DAVIS346: Self = Self {
        width: 346,
        height: 260,
        slices: DEFAULT_SLICES,
        window: WindowRule::Events(DEFAULT_WINDOW_EVENTS),
    };

    /// Number of `(slice, row)` histogram bins this configuration needs.
    pub const fn row_bins(&self) -> usize {
        self.slices as usize * self.height as usize
    }
}

/// A configuration the rasterizer cannot run with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ConfigError {
    /// Width is 0 or above [`MAX_WIDTH`].
    Width(u16),
    /// Height is 0 or above [`MAX_HEIGHT`].
    Height(u16),
    /// Slice count is 0 or above [`MAX_SLICES`].
    Slices(u8),
    /// The window rule asks for 0 events or a 0 µs duration.
    EmptyWindow,
    /// The storage holds fewer events than a window of `Events(n)` needs, or none at all.
    Capacity {
        /// Events the configuration needs per window.
        needed: usize,
        /// Events the storage holds.
        available: usize,
    },
    /// The storage holds more events than a window can count (32 bits).
    StorageTooLarge {
        /// Events the storage holds.
        available: usize,
    },
    /// A window duration above `i32::MAX` µs: offsets from a window's first event are i32, so
    /// such a window would close at 2^31 µs anyway (as a time jump).
    Duration(u32),
    /// A histogram of the storage is shorter than the configuration needs.
    Histogram {
        /// Bins needed.
        needed: usize,
        /// Bins available.
        available: usize,
    },
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Width(w) => write!(f, "sensor width {w} is outside 1..={MAX_WIDTH}"),
            Self::Height(h) => write!(f, "sensor height {h} is outside 1..={MAX_HEIGHT}"),
            Self::Slices(k) => write!(f, "slice count {k} is outside 1..={MAX_SLICES}"),
            Self::EmptyWindow => write!(f, "a window must hold at least one event or microsecond"),
            Self::Capacity { needed, available } => write!(
                f,
                "window needs room for {needed} events but the storage holds {available}"
            ),
            Self::StorageTooLarge { available } => write!(
                f,
                "the storage holds {available} events; a window counts at most {} in 32 bits",
                u32::MAX
            ),
            Self::Duration(d) => write!(
                f,
                "window duration {d} µs is above {} µs (about 36 minutes)",
                i32::MAX
            ),
            Self::Histogram { needed, available } => write!(
                f,
                "histogram needs {needed} bins but the storage has {available}"
            ),
        }
    }
}

impl core::error::Error for ConfigError {}

/// The memory a [`Rasterizer`] works in: two equal event buffers and two histograms.
///
/// [`InlineStorage`] keeps everything inline with compile-time sizes (for a `static` on an MCU);
/// a host may implement this trait over heap buffers for windows of any size.
pub trait RasterStorage {
    /// Borrows all four buffers at once.
    fn parts(&mut self) -> RasterParts<'_>;
    /// Borrows the two event buffers for reading points.
    fn words(&self) -> (&[u64], &[u64]);
}

/// A borrowed storage is a storage: a rasterizer can run in a buffer that lives elsewhere (a
/// `static` handed out once on an MCU, a heap box on the host), as `embedded_io` and
/// `heapless` do for their traits.
impl<S: RasterStorage + ?Sized> RasterStorage for &mut S {
    fn parts(&mut self) -> RasterParts<'_> {
        (**self).parts()
    }
    fn words(&self) -> (&[u64], &[u64]) {
        (**self).words()
    }
}

/// Mutable views of a [`RasterStorage`].
pub struct RasterParts<'a> {
    /// Event buffer A: holds the window's events, then (with B) its points.
    pub a: &'a mut [u64],
    /// Event buffer B: scratch for sorting, then (with A) the points. Same length as `a`.
    pub b: &'a mut [u64],
    /// One bin per sensor column.
    pub hist_x: &'a mut [u32],
    /// One bin per `(slice, row)`.
    pub hist_rows: &'a mut [u32],
}

/// Rasterizer storage from four buffers: the event words `a` and `b` (one window's events
/// each) and the histograms `hist_x` (one bin per sensor column) and `hist_rows` (one per
/// `(slice, row)`). Arrays give fixed memory ([`InlineStorage`], a `static` on an MCU); a
/// host uses vectors (`evpose_host::pipeline::VecStorage`). One [`RasterStorage`]
/// implementation serves both.
pub struct RasterBuffers<A, X, R> {
    a: A,
    b: A,
    hist_x: X,
    hist_rows: R,
}

impl<A, X, R> RasterBuffers<A, X, R> {
    /// Storage over the given buffers (`a` and `b` of equal length: the window's capacity).
    pub const fn from_parts(a: A, b: A, hist_x: X, hist_rows: R) -> Self {
        Self {
            a,
            b,
            hist_x,
            hist_rows,
        }
    }
}

impl<A, X, R> RasterStorage for RasterBuffers<A, X, R>
where
    A: AsMut<[u64]> + AsRef<[u64]>,
    X: AsMut<[u32]>,
    R: AsMut<[u32]>,
{
    fn parts(&mut self) -> RasterParts<'_> {
        RasterParts {
            a: self.a.as_mut(),
            b: self.b.as_mut(),
            hist_x: self.hist_x.as_mut(),
            hist_rows: self.hist_rows.as_mut(),
        }
    }

    fn words(&self) -> (&[u64], &[u64]) {
        (self.a.as_ref(), self.b.as_ref())
    }
}

/// Inline, compile-time-sized storage: `CAP` events, `MAX_W` columns, `MAX_ROWS` `(slice, row)`
/// bins (`K × H`). Size: `16 × CAP + 4 × (MAX_W + MAX_ROWS)` bytes.
pub type InlineStorage<const CAP: usize, const MAX_W: usize, const MAX_ROWS: usize> =
    RasterBuffers<[u64; CAP], [u32; MAX_W], [u32; MAX_ROWS]>;

impl<const CAP: usize, const MAX_W: usize, const MAX_ROWS: usize>
    RasterBuffers<[u64; CAP], [u32; MAX_W], [u32; MAX_ROWS]>
{
    /// Zeroed storage; `const` so that it can initialize a `static`.
    pub const fn new() -> Self {
        const {
            assert!(CAP > 0, "a window must hold at least one event");
            assert!(
                CAP <= u32::MAX as usize,
                "event counts are stored in 32 bits"
            );
            assert!(
                MAX_W > 0 && MAX_W <= MAX_WIDTH as usize,
                "MAX_W must be in 1..=2048"
            );
            assert!(
                MAX_ROWS > 0 && MAX_ROWS <= MAX_SLICES as usize * MAX_HEIGHT as usize,
                "MAX_ROWS (slices × height) must be in 1..=8192"
            );
        }
        Self::from_parts([0; CAP], [0; CAP], [0; MAX_W], [0; MAX_ROWS])
    }
}

impl<const CAP: usize, const MAX_W: usize, const MAX_ROWS: usize> Default
    for RasterBuffers<[u64; CAP], [u32; MAX_W], [u32; MAX_ROWS]>
{
    fn default() -> Self {
        Self::new()
    }
}

/// Storage for the paper's DAVIS346 configuration: 7,500-event windows, up to 346 × 260, `K ≤ 4`.
/// 125,544 bytes (122.6 KiB).
pub type Davis346Storage = InlineStorage<7_500, 346, 1_040>;

/// Counters of everything the rasterizer did with its input; they only grow.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RasterStats {
    /// Events stored into a window.
    pub accepted: u64,
    /// Events dropped because the pixel lies outside the configured sensor.
    pub dropped_out_of_range: u64,
    /// Events whose timestamp is earlier than the previous accepted event's.
    pub out_of_order: u64,
    /// Windows closed early because an event lay more than `i32::MAX` µs from the window start.
    pub time_jumps: u64,
    /// Windows closed because the storage was full before the window rule closed them.
    pub windows_full: u64,
    /// Windows closed, by any cause (flushes of an empty window included).
    pub windows: u64,
}

/// Why [`Rasterizer::push`] dropped an event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum DropReason {
    /// The pixel lies outside the configured sensor.
    OutOfRange,
}

/// What [`Rasterizer::push`] did with an event.
#[derive(Debug)]
pub enum Pushed<'a> {
    /// The event is buffered in the open window.
    Buffered,
    /// The event was dropped and counted in [`RasterStats`].
    Dropped(DropReason),
    /// A window closed; its point cloud is borrowed until the next push. The event just pushed
    /// is either its last event or, when the window closed before it, held for the next window.
    Window(Window<'a>),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Filling,
    Closed { points: usize },
}

/// Streaming rasterizer over a [`RasterStorage`].
pub struct Rasterizer<S> {
    storage: S,
    config: RasterConfig,
    capacity: usize,
    phase: Phase,
    len: usize,
    t_first: i64,
    t_last: i64,
    /// Whether an event of the open window came earlier than the one before it; if none did,
    /// the window's time offsets run from 0 (its first event) to its last event's, and the
    /// close needs no pass to find them.
    disordered: bool,
    /// An event that closed the previous window and opens the next one.
    pending: Option<Event>,
    stats: RasterStats,
    summary: WindowSummary,
    /// Splits the points' row bins (the sensor height's reciprocal, computed once).
    rows: RowDecoder,
}

impl<S: RasterStorage> Rasterizer<S> {
    /// Creates a rasterizer, checking the configuration against the storage.
    pub fn new(config: RasterConfig, mut storage: S) -> Result<Self, ConfigError> {
        let (capacity, hx, hr) = {
            let parts = storage.parts();
            (
                parts.a.len().min(parts.b.len()),
                parts.hist_x.len(),
                parts.hist_rows.len(),
            )
        };
        check_config(&config, capacity, hx, hr)?;
        let mut r = Self {
            storage,
            config,
            capacity,
            phase: Phase::Filling,
            len: 0,
            t_first: 0,
            t_last: i64::MIN,
            disordered: false,
            pending: None,
            stats: RasterStats::default(),
            summary: WindowSummary::default(),
            rows: RowDecoder::new(config.height),
        };
        r.begin_window();
        Ok(r)
    }

    /// The configuration.
    pub fn config(&self) -> &RasterConfig {
        &self.config
    }

    /// Events one window can hold.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Events buffered in the open window.
    pub fn buffered(&self) -> usize {
        match self.phase {
            Phase::Filling => self.len,
            Phase::Closed { .. } => usize::from(self.pending.is_some()),
        }
    }

    /// Counters since creation.
    pub fn stats(&self) -> &RasterStats {
        &self.stats
    }

    /// Pushes one event. Never panics: bad events are dropped and counted, and a window that
    /// cannot take the event is closed first.
    pub fn push(&mut self, event: Event) -> Pushed<'_> {
        if event.x >= self.config.width || event.y >= self.config.height {
            self.stats.dropped_out_of_range += 1;
            return Pushed::Dropped(DropReason::OutOfRange);
        }
        if let Phase::Closed { .. } = self.phase {
            self.begin_window();
            if let Some(held) = self.pending.take() {
                if self.insert(held) {
                    self.pending = Some(event);
                    return Pushed::Window(self.window());
                }
            }
        }
        if self.insert(event) {
            Pushed::Window(self.window())
        } else {
            Pushed::Buffered
        }
    }

    /// Pushes events from a buffer (a DMA transfer, a decoded packet) until a window closes or
    /// the buffer ends. Returns how many events were consumed and the closed window, if any;
    /// call again with the rest. Exactly the same outcome as pushing the events one by one
    /// (windows, drops and counters; checked by a property test), with the per-event checks and
    /// counters kept in registers.
    pub fn extend(&mut self, events: &[Event]) -> (usize, Option<Window<'_>>) {
        let mut used = 0;
        // `get` rather than indexing: `used` stays within `events`, and no panic path is left
        // in firmware.
        while let Some(rest) = events.get(used..).filter(|r| !r.is_empty()) {
            if self.phase == Phase::Filling && self.len > 0 {
                used += self.fill(rest);
            }
            // Window boundaries, time jumps and the first event go through `push`.
            let Some(&e) = events.get(used) else {
                break;
            };
            let closed = matches!(self.push(e), Pushed::Window(_));
            used += 1;
            if closed {
                return (used, self.last_window());
            }
        }
        (used, None)
    }

    /// The fast path of [`Rasterizer::extend`]: stores events into a filling window that
    /// already has its first event, stopping before any event that would close the window.
    ///
    /// Written for few live values (`scripts/callgrind-raster.sh`): the buffer and the
    /// histogram are sliced to their bounds first, the batch is cut to the window's room (so
    /// the loop, [`Run::store`], needs no room test but the one bound of its zip over slots and
    /// events), drops are counted from the consumed count afterwards, the time test is one unsigned compare, and
    /// the window's time range is not tracked per event: an in-order window's range is its
    /// first and last offsets, and the close finds an out-of-order window's range itself.
    fn fill(&mut self, events: &[Event]) -> usize {
        let limit = match self.config.window {
            WindowRule::Events(n) => (n as usize).min(self.capacity),
            WindowRule::Duration(_) => self.capacity,
        };
        // Offsets `d = t − t_first` the window takes: i32, and below the duration.
        let end = match self.config.window {
            WindowRule::Duration(d) => i64::from(d).min(1 << 31),
            WindowRule::Events(_) => 1 << 31,
        };
        let span = (end - i64::from(i32::MIN)) as u64;
        let (width, height, t_first) = (self.config.width, self.config.height, self.t_first);
        // With |t_first| < 2^62, `t − t_first` wraps only for a true difference beyond ±2^62,
        // and a wrapped value is then still far outside the i32 offsets this loop accepts: the
        // wrapping subtraction decides like the exact one. Other windows take `push`.
        if t_first.unsigned_abs() >= 1 << 62 {
            return 0;
        }
        let start = self.len;
        // In the loop, times are offsets from `t_first` plus 2^31 in u32 (fewer live registers
        // on a 32-bit MCU, and they are what the words store), starting from the last stored
        // event's: with `len > 0` that event is in this window (`insert` and this loop store
        // only offsets that fit in i32), so it fits.
        let d_last = i32::try_from(self.t_last.wrapping_sub(t_first)).unwrap_or(i32::MIN);
        let mut u_last = biased(d_last);
        // `e.t − t_lo` is `d − i32::MIN` for `d = e.t − t_first`, wrapping the same way.
        let t_lo = t_first.wrapping_add(i64::from(i32::MIN));
        let mut backwards = 0usize;
        let parts = self.storage.parts();
        // The closing event (the `limit`-th) goes through push(): store up to `limit − 1`.
        // The storage holds `capacity` slots and `width` bins (checked at construction). The
        // check lets the compiler drop the slicing's panic paths (firmware); were the storage
        // short, `push` would take every event.
        let end = limit.saturating_sub(1).max(start);
        if end > parts.a.len() || usize::from(width) > parts.hist_x.len() {
            return 0;
        }
        let room = &mut parts.a[start..end];
        let hist_x = &mut parts.hist_x[..usize::from(width)];
        // Each event takes at most one slot: `room.len()` events cannot overflow it.
        let room_len = room.len();
        let batch = &events[..events.len().min(room_len)];
        let run = Run {
            rows_end: u32::from(height) << RB_SHIFT,
            t_lo,
            span,
        };
        // Runs of accepted events, each stored slot by slot; a dropped event (rare: a pixel
        // outside the sensor) ends a run and is skipped; a time jump or the end of a duration
        // window ends the loop.
        let (mut used, mut len) = (0, 0);
        while let (Some(rest), Some(slots)) = (batch.get(used..), room.get_mut(len..)) {
            let stored = run.store(rest, slots, hist_x, &mut u_last, &mut backwards);
            used += stored;
            len += stored;
            match rest.get(stored) {
                Some(e) if !(usize::from(e.x) < hist_x.len() && e.y < height) => used += 1,
                _ => break, // the batch's end, or an event for `push` to decide
            }
        }
        self.stats.accepted += len as u64;
        self.stats.dropped_out_of_range += (used - len) as u64;
        self.stats.out_of_order += backwards as u64;
        self.disordered |= backwards > 0;
        (self.len, self.t_last) = (start + len, t_first + i64::from(unbiased(u_last)));
        used
    }

    /// Closes the open window now (end of stream, or a timer on a quiet sensor) and returns it.
    /// An empty window gives zero points. If the last window closed with an event held for the
    /// next one, that event forms the new window.
    pub fn flush(&mut self) -> Window<'_> {
        if let Phase::Closed { .. } = self.phase {
            self.begin_window();
            if let Some(held) = self.pending.take() {
                // A window of one event cannot close by time; it may close by count.
                self.insert(held);
            }
        }
        if self.phase == Phase::Filling {
            self.close();
        }
        self.window()
    }

    /// The most recently closed window, if the rasterizer has not reopened since.
    pub fn last_window(&self) -> Option<Window<'_>> {
        match self.phase {
            Phase::Closed { .. } => Some(self.window()),
            Phase::Filling => None,
        }
    }

    fn window(&self) -> Window<'_> {
        let points = match self.phase {
            Phase::Closed { points } => points,
            Phase::Filling => 0,
        };
        let (a, b) = self.storage.words();
        // `points` ≤ capacity ≤ the storage's length (checked at construction); `get` keeps a
        // panic path out of firmware.
        Window {
            a: a.get(..points).unwrap_or_default(),
            b: b.get(..points).unwrap_or_default(),
            slices: self.config.slices,
            rows: self.rows,
            summary: self.summary,
        }
    }

    fn begin_window(&mut self) {
        let parts = self.storage.parts();
        // Sized at construction; `get` keeps panic paths out of firmware.
        let width = usize::from(self.config.width);
        if let Some(h) = parts.hist_x.get_mut(..width) {
            h.fill(0);
        }
        if let Some(h) = parts.hist_rows.get_mut(..self.config.row_bins()) {
            h.fill(0);
        }
        self.phase = Phase::Filling;
        self.len = 0;
    }

    /// Stores an accepted event in the filling window; returns whether the window closed.
    fn insert(&mut self, event: Event) -> bool {
        if self.len > 0 {
            let offset = event
                .t
                .checked_sub(self.t_first)
                .and_then(|d| i32::try_from(d).ok());
            let outside = match (offset, self.config.window) {
                (None, _) => {
                    self.stats.time_jumps += 1;
                    true
                }
                (Some(off), WindowRule::Duration(d)) => i64::from(off) >= i64::from(d),
                (Some(_), WindowRule::Events(_)) => false,
            };
            if outside {
                self.close();
                self.pending = Some(event);
                return true;
            }
        } else {
            self.t_first = event.t;
            self.disordered = false;
        }
        if event.t < self.t_last {
            self.stats.out_of_order += 1;
            // Only against an event of this window: the first may precede the last window's.
            self.disordered |= self.len > 0;
        }
        self.t_last = event.t;
        // In range: checked above against t_first, or 0 for the first event.
        let u = biased((event.t - self.t_first) as i32);
        let parts = self.storage.parts();
        // `len < capacity` (a full window closes) and `x < width` (checked by `push`).
        if let (Some(slot), Some(bin)) = (
            parts.a.get_mut(self.len),
            parts.hist_x.get_mut(usize::from(event.x)),
        ) {
            *slot = buffered_word(
                u32::from(event.x) | u32::from(event.y) << RB_SHIFT,
                event.on,
                u,
            );
            *bin += 1;
        }
        self.len += 1;
        self.stats.accepted += 1;
        let by_rule = matches!(self.config.window, WindowRule::Events(n) if self.len >= n as usize);
        if by_rule || self.len >= self.capacity {
            if !by_rule {
                self.stats.windows_full += 1;
            }
            self.close();
            return true;
        }
        false
    }

    fn close(&mut self) {
        let n = self.len;
        let parts = self.storage.parts();
        // The window's time offsets: from its first event (0) to its last, unless an event
        // came out of order (then one pass over the stored offsets).
        let (off_min, off_max) = if self.disordered {
            offset_range(parts.a.get(..n).unwrap_or_default())
        } else {
            (0, self.t_last.wrapping_sub(self.t_first) as i32)
        };
        // An empty window has no time extent (t_first and t_last belong to an earlier one).
        self.summary = if n == 0 {
            WindowSummary::default()
        } else {
            WindowSummary {
                events: n as u32,
                t_min: self.t_first + i64::from(off_min),
                t_max: self.t_first + i64::from(off_max),
            }
        };
        let in_order = !self.disordered;
        let points = rasterize(&self.config, parts, n, (off_min, off_max), in_order);
        self.phase = Phase::Closed { points };
        self.stats.windows += 1;
    }
}

fn check_config(
    c: &RasterConfig,
    capacity: usize,
    hist_x: usize,
    hist_rows: usize,
) -> Result<(), ConfigError> {
    if c.width == 0 || c.width > MAX_WIDTH {
        return Err(ConfigError::Width(c.width));
    }
    if c.height == 0 || c.height > MAX_HEIGHT {
        return Err(ConfigError::Height(c.height));
    }
    if c.slices == 0 || c.slices > MAX_SLICES {
        return Err(ConfigError::Slices(c.slices));
    }
    let needed = match c.window {
        WindowRule::Events(0) | WindowRule::Duration(0) => return Err(ConfigError::EmptyWindow),
        WindowRule::Events(n) => n as usize,
        WindowRule::Duration(d) if d > i32::MAX as u32 => return Err(ConfigError::Duration(d)),
        WindowRule::Duration(_) => 1,
    };
    if capacity > u32::MAX as usize {
        return Err(ConfigError::StorageTooLarge {
            available: capacity,
        });
    }
    if capacity < needed {
        return Err(ConfigError::Capacity {
            needed,
            available: capacity,
        });
    }
    if hist_x < usize::from(c.width) {
        return Err(ConfigError::Histogram {
            needed: usize::from(c.width),
            available: hist_x,
        });
    }
    if hist_rows < c.row_bins() {
        return Err(ConfigError::Histogram {
            needed: c.row_bins(),
            available: hist_rows,
        });
    }
    Ok(())
}

/// The per-event tests of [`Rasterizer::fill`]'s loop.
#[derive(Clone, Copy)]
struct Run {
    /// `H << RB_SHIFT`: an event's `x | y << RB_SHIFT` lies below it exactly when `y < H`.
    rows_end: u32,
    /// `t_first + i32::MIN`: `t − t_lo` is the offset from `t_first` plus 2^31.
    t_lo: i64,
    /// Offsets plus 2^31 the window takes lie below this (at most 2^32).
    span: u64,
}

impl Run {
    /// Stores events in order into `slots` while they are accepted (pixel on the sensor,
    /// offset inside the window); returns how many. One index walks both slices, and the
    /// column histogram (sliced to the sensor's width) bounds the column test, so no other
    /// bounds test is left in the loop. Not inlined: on its own the loop keeps every value in
    /// a register (`scripts/callgrind-raster.sh`).
    #[inline(never)]
    fn store(
        self,
        events: &[Event],
        slots: &mut [u64],
        hist_x: &mut [u32],
        u_last: &mut u32,
        backwards: &mut usize,
    ) -> usize {
        let (mut last, mut back) = (*u_last, *backwards);
        let mut stored = 0;
        for (slot, e) in slots.iter_mut().zip(events) {
            let Some(bin) = hist_x.get_mut(usize::from(e.x)) else {
                break;
            };
            let xy = u32::from(e.x) | u32::from(e.y) << RB_SHIFT;
            let u = e.t.wrapping_sub(self.t_lo) as u64;
            if xy >= self.rows_end || u >= self.span {
                break;
            }
            // `u < span ≤ 2^32`.
            let u = u as u32;
            back += usize::from(u < last);
            last = u;
            *slot = buffered_word(xy, e.on, u);
            *bin += 1;
            stored += 1;
        }
        (*u_last, *backwards) = (last, back);
        stored
    }
}

/// A buffered event word: `x | y << RB_SHIFT` (column and row, checked against the sensor), the
/// polarity and `u`, the time offset from the window's first event plus 2^31.
#[inline(always)]
fn buffered_word(xy: u32, on: bool, u: u32) -> u64 {
    u64::from(xy | u32::from(on) << P_SHIFT) | u64::from(u) << 32
}

/// The smallest and largest time offsets of buffered event words.
fn offset_range(words: &[u64]) -> (i32, i32) {
    words.iter().fold((i32::MAX, i32::MIN), |(lo, hi), &w| {
        let off = offset(w);
        (lo.min(off), hi.max(off))
    })
}

/// Turns the `n` buffered events of `parts.a` into points; returns the point count.
///
/// Three passes over the events: slices and the column sort in one (A → B), the
/// `(slice, row)` sort (B → A), and the merge of equal cells into points. Indexing goes
/// through `get`: every index is in range by construction (columns and rows were checked when
/// the events were stored, the prefix sums count exactly the events), and a firmware built
/// from this code links no panic path for them.
fn rasterize(
    c: &RasterConfig,
    p: RasterParts<'_>,
    n: usize,
    offsets: (i32, i32),
    in_order: bool,
) -> usize {
    let (Some(events), Some(sorted)) = (p.a.get_mut(..n), p.b.get_mut(..n)) else {
        return 0;
    };
    if n == 0 {
        return 0;
    }
    let (Some(hist_x), Some(hist_rows)) = (
        p.hist_x.get_mut(..usize::from(c.width)),
        p.hist_rows.get_mut(..c.row_bins()),
    ) else {
        return 0;
    };
    // Stable LSD counting sort: by column (while assigning slices), then by (slice, row).
    exclusive_prefix_sum(hist_x);
    let slices = Slices::new(c, offsets);
    let mut scatter = ColumnScatter {
        sorted,
        starts: hist_x,
        hist_rows,
        slice_step: u64::from(c.height) << RB_SHIFT,
    };
    if in_order && slices.span > 0.0 {
        // Offsets never decrease in arrival order, nor do slices: each slice is one run of
        // events, found by bisection, and its events need no slice index of their own.
        let mut rest: &[u64] = events;
        for k in 0..u32::from(c.slices) {
            let len = if k + 1 == u32::from(c.slices) {
                rest.len()
            } else {
                rest.partition_point(|&w| slices.position(offset(w)) < f64::from(k + 1))
            };
            let (run, tail) = rest.split_at_checked(len).unwrap_or((rest, &[]));
            scatter.run_slice(run, k, slices);
            rest = tail;
        }
    } else {
        for &w in events.iter() {
            let (k, frac) = slices.slice_and_fraction(offset(w));
            scatter.scatter(sorted_word(w, u64::from(k) * scatter.slice_step, frac));
        }
    }
    exclusive_prefix_sum(hist_rows);
    scatter_rows(sorted, hist_rows, events);
    merge_cells(p.a, p.b, n)
}

/// The second counting-sort pass: words sorted by column, scattered stably by their
/// `(slice, row)` bin (`starts`: the bins' exclusive prefix sums) into `out`.
#[inline(never)]
fn scatter_rows(sorted: &[u64], starts: &mut [u32], out: &mut [u64]) {
    for &w in sorted {
        let key = (w as u32 >> RB_SHIFT) as usize;
        if let Some(start) = starts.get_mut(key) {
            let at = *start as usize;
            *start += 1;
            if let Some(slot) = out.get_mut(at) {
                *slot = w;
            }
        }
    }
}

/// A buffered word's time offset from the window's first event.
#[inline(always)]
fn offset(w: u64) -> i32 {
    unbiased((w >> 32) as u32)
}

/// The stored form of a time offset `d` from the window's first event: `d + 2^31` as a u32,
/// in the same order as `d` (what [`Run::store`] computes as `t − t_lo`).
#[inline(always)]
fn biased(d: i32) -> u32 {
    d as u32 ^ 0x8000_0000
}

/// The offset `d` of a stored `d + 2^31` ([`biased`]'s inverse).
#[inline(always)]
fn unbiased(u: u32) -> i32 {
    (u ^ 0x8000_0000) as i32
}

/// Whether the in-order close computes fractions in integers first ([`FixedFraction`]): on
/// 32-bit Arm, whose cores mostly have no double-precision FPU (Cortex-M0, M4, M33), so that
/// f64 runs in software, unless the build enables `arm-fpv5` (the Cortex-M7 image, whose
/// FPU divides in f64). Elsewhere the f64 arithmetic is hardware and vectorized.
const FIXED_FRACTIONS: bool = cfg!(all(target_arch = "arm", not(feature = "arm-fpv5")));

/// The reference's slice arithmetic for one window's offsets.
#[derive(Clone, Copy)]
struct Slices {
    off_min: f64,
    span: f64,
    slices: f64,
    /// The same fractions in integer arithmetic, where they can be told exactly (only in the
    /// builds that use them, [`FIXED_FRACTIONS`]).
    fixed: Option<FixedFraction>,
}

impl Slices {
    fn new(c: &RasterConfig, (off_min, off_max): (i32, i32)) -> Self {
        let span = f64::from(off_max) - f64::from(off_min);
        let slices = f64::from(c.slices);
        Self {
            off_min: f64::from(off_min),
            span,
            slices,
            fixed: if FIXED_FRACTIONS {
                FixedFraction::new(off_min, span, slices)
            } else {
                None
            },
        }
    }

    /// `tn`: the same operations, in the same order, as the reference (float64). Monotone in
    /// `off` (each step is a correctly rounded operation with a positive constant), so a run of
    /// non-decreasing offsets is a run of non-decreasing slices.
    #[inline(always)]
    fn position(self, off: i32) -> f64 {
        (f64::from(off) - self.off_min) / self.span / SPAN_FACTOR * self.slices
    }

    /// The fraction of an offset known to lie in slice `k`.
    #[inline(always)]
    fn fraction_in(self, off: i32, k: u32) -> f32 {
        if FIXED_FRACTIONS {
            if let Some(f) = self.fixed.and_then(|x| x.fraction(off, k)) {
                return f;
            }
        }
        (self.position(off) - f64::from(k)) as f32
    }

    /// Slice and fraction of an offset (slice 0, fraction 0 when the window has no span).
    #[inline(always)]
    fn slice_and_fraction(self, off: i32) -> (u32, f32) {
        if self.span > 0.0 {
            let tn = self.position(off);
            // `off − off_min` is in [0, span] (the window's offsets lie between its
            // extremes), so the first quotient is in [0, 1], the second at most
            // f64(1 / 1.001) < 0.9991 and `tn` below 0.9991 · K: truncation is floor and
            // `k ≤ K − 1`, no clamp needed. (A u32 conversion, not u64: x86 has no direct
            // f64 → u64 instruction before AVX-512.)
            let k = tn as u32;
            (k, (tn - f64::from(k)) as f32)
        } else {
            (0, 0.0)
        }
    }
}

/// A slice's fraction `f32(tn − k)` without f64 division, where it can be told exactly.
///
/// `tn = ((a / S) / c) · K` in f64 (three rounded operations; `a = off − off_min`, `S` the
/// span, `c` the f64 nearest 1.001) lies within `X · 3 · 2^−53 < 2^−48` of the real
/// `X = a·K / (S·c)` (`X ≤ K / c < 8`). `R = K / (S · c)`, rounded twice in f64 once per
/// window, is within a relative `2^−52 · (1 + 2^−52)` of the real ratio, so `a · R` is within
/// `2^−49` of `X` (the 0.1 % that `X` stays below 8 absorbs the excess).
///
/// Positions are counted in units of `2^−U`, `U` per window: 49, or less where `R` is so large
/// (a span under about `K · 2^17`) that `M = ⌊R · 2^(U+32)⌋` would not fit 64 bits. Then
/// `x = ⌊a · M / 2^32⌋` is two 32 × 32-bit products (`UMULL`, `UMLAL` on a Cortex-M4) and lies
/// within 2 units below `a · R · 2^U` (one truncation in `M`, one in the product), so within
/// 5 units of `tn · 2^U` (2 + 1 + 1.5: `tn`'s three roundings are within `1.5 · 2^(U−49)`). Where it lies more than [`Self::ERROR`] units from every
/// f32 rounding midpoint (the midpoint below a power of two included, which is half as far),
/// `tn − k` (exact in f64) rounds to the same f32, built here from the bits. Otherwise (near a
/// midpoint, near the slice's ends, below `2^(27−U)` of a slice) the answer is `None` and the
/// caller takes the f64 path: in the tests none of 159,992 offsets spread over a long window
/// (but its first, fraction 0) and a few percent of all offsets of short spans.
///
/// The common case (the fraction at least `2^(32−U)`) runs in 32-bit words: a count of leading
/// zeros, three shifts into a normalized 32-bit head, one compare against the midpoint with a
/// tolerance scaled to the shift. About 30 instructions on a Cortex-M4, where the two f64
/// divisions in software cost several hundred.
#[derive(Clone, Copy, Debug)]
struct FixedFraction {
    /// `M`'s low 32 bits.
    m_lo: u32,
    /// `M`'s high 32 bits.
    m_hi: u32,
    /// `U`, in 33..=49.
    unit: u32,
    /// `2^(U−32)`: a unit count is below `2^U` where its high word is below this. (This and
    /// `exp` follow from `unit`; derived per event instead, the M4 build's rasterizer took 3
    /// instructions per event more: 156.5 against 153.5.)
    high_limit: u32,
    /// `189 − U`: a fraction whose leading bit lies `n` places below bit 63 of its unit count
    /// has the f32 encoding `(exp − n) << 23` plus its 24-bit significand (implicit bit
    /// included, which adds the missing 1 to the exponent field).
    exp: u32,
    off_min: i32,
}

impl FixedFraction {
    /// The finest unit, `2^−49`.
    const MAX_UNIT: u32 = 49;
    /// How far (units) the fixed-point position may lie from the reference's `tn` (under 5),
    /// plus one.
    const ERROR: u32 = 6;

    fn new(off_min: i32, span: f64, slices: f64) -> Option<Self> {
        // Spans are exact integers: a window without one has no fractions to compute.
        if span < 1.0 {
            return None;
        }
        // `R = m · 2^−s` with `m` its 53-bit significand; `R` lies in (2^−33, 8): span ≥ 1 and
        // span < 2^32, K ≤ 8.
        let bits = (slices / (span * SPAN_FACTOR)).to_bits();
        let s = 1075u32.checked_sub(((bits >> 52) & 0x7ff) as u32)?;
        let m = (bits & ((1 << 52) - 1)) | 1 << 52;
        // `R < 2^(53−s)`, so `R · 2^(U+32) < 2^64` for `U ≤ s − 21`. Below `U = 33` (spans of
        // about 2K and less) the common case would not exist: the f64 path takes them.
        let unit = s.checked_sub(21)?.min(Self::MAX_UNIT);
        if unit < 33 {
            return None;
        }
        // `M = m · 2^(U + 32 − s)`: exact where the exponent is not negative (`m` then moves
        // up at most 11 places), truncated otherwise.
        let up = unit + 32;
        let big = if up >= s {
            m << (up - s)
        } else {
            m.checked_shr(s - up)?
        };
        Some(Self {
            m_lo: big as u32,
            m_hi: (big >> 32) as u32,
            unit,
            high_limit: 1 << (unit - 32),
            exp: 189 - unit,
            off_min,
        })
    }

    /// `f32(tn − k)` for an offset of slice `k`, or `None` where this arithmetic cannot tell it.
    #[inline(always)]
    fn fraction(self, off: i32, k: u32) -> Option<f32> {
        const E: u32 = FixedFraction::ERROR;
        // `off − off_min` is in [0, 2^32).
        let a = u64::from(off.wrapping_sub(self.off_min) as u32);
        // ⌊a · M / 2^32⌋ (below 2^64, as `a < 2^32`), below 8 · 2^U for an offset inside the
        // window.
        let x = a * u64::from(self.m_hi) + ((a * u64::from(self.m_lo)) >> 32);
        // `f = x − k · 2^U`; `k · 2^U` has no low word (`U ≥ 33`, `k < 8`).
        let lo = x as u32;
        let hi = ((x >> 32) as u32).wrapping_sub(k << (self.unit - 32));
        if hi >= self.high_limit {
            return None; // `f ≥ 2^U`: outside slice `k`, or at its ends
        }
        // `n`: leading zeros of `f` as a u64; `head`: its 32 bits from the leading one down;
        // `rest`: the next 32 bits, where the rounding is decided (bit 31: the half);
        // `tol`: `E` units at the scale of `rest` (plus one for the bits below `rest`, in the
        // first case).
        let (n, head, rest, tol) = if hi != 0 {
            // `hi < 2^(U−32) ≤ 2^17`, so `n` is in 15..=31 and every shift below is in range.
            let n = hi.leading_zeros();
            let head = hi << n | lo.wrapping_shr(32 - n);
            let low = lo.wrapping_shl(n);
            (n, head, head << 24 | low >> 8, (E << (n - 8)) + 1)
        } else {
            // A fraction below `2^(32−U)` of a slice: 32 bits hold it exactly, and its
            // significand needs 24 of them and a few to round by.
            // With `z` leading zeros, `E` units lie `z + 24` places up in `rest`: beyond
            // `z = 4` the tolerance would reach the half itself.
            let z = lo.leading_zeros();
            if z > 4 {
                return None;
            }
            let head = lo << z;
            (32 + z, head, head << 24, E << (z + 24))
        };
        let m24 = head >> 8;
        let d = rest.wrapping_sub(1 << 31) as i32;
        let near_half = (d.wrapping_add(tol as i32) as u32) <= 2 * tol;
        if near_half || (m24 == 1 << 23 && rest <= tol) {
            return None;
        }
        // Rounding up carries into the exponent where the significand overflows, as IEEE's
        // encoding does.
        Some(f32::from_bits(
            ((self.exp - n) << 23) + m24 + u32::from(d > 0),
        ))
    }
}

// The small case's tolerance, `E · 2^28` at most, must stay below 2^31 (an i32, doubled in a
// u32).
const _: () = assert!(FixedFraction::ERROR <= 7);

/// The first counting-sort pass: sorted words (`x | p | row bin | fraction`, built from the
/// buffered words in arrival order by [`sorted_word`]) scattered into `sorted` by column,
/// stably (`starts`: the columns' exclusive prefix sums), with the `(slice, row)` bins counted.
struct ColumnScatter<'a> {
    sorted: &'a mut [u64],
    starts: &'a mut [u32],
    hist_rows: &'a mut [u32],
    /// One slice's step of the row field: `H << RB_SHIFT`.
    slice_step: u64,
}

impl ColumnScatter<'_> {
    /// Scatters the events of one slice `k` (a run of an in-order window). Sorted words are
    /// built a chunk at a time first: that loop has no stores but its own, and the compiler
    /// vectorizes it (fractions two at a time on SSE2).
    #[inline(never)]
    fn run_slice(&mut self, events: &[u64], k: u32, slices: Slices) {
        const CHUNK: usize = 64;
        let mut words = [0u64; CHUNK];
        let step = u64::from(k) * self.slice_step;
        for chunk in events.chunks(CHUNK) {
            for (s, &w) in words.iter_mut().zip(chunk) {
                *s = sorted_word(w, step, slices.fraction_in(offset(w), k));
            }
            for &s in words.get(..chunk.len()).unwrap_or_default() {
                self.scatter(s);
            }
        }
    }

    /// Counts a sorted word's row bin and scatters it by column.
    #[inline(always)]
    fn scatter(&mut self, s: u64) {
        if let Some(count) = self.hist_rows.get_mut((s as u32 >> RB_SHIFT) as usize) {
            *count += 1;
        }
        if let Some(start) = self.starts.get_mut((s & X_MASK) as usize) {
            let at = *start as usize;
            *start += 1;
            if let Some(slot) = self.sorted.get_mut(at) {
                *slot = s;
            }
        }
    }
}

/// A buffered word's sorted form: its row field moved by `step` (`k·H << RB_SHIFT`) to the row
/// bin `k·H + y`, and its fraction in place of the offset.
#[inline(always)]
fn sorted_word(w: u64, step: u64, frac: f32) -> u64 {
    ((w & 0xffff_ffff) + step) | u64::from(frac.to_bits()) << 32
}

fn exclusive_prefix_sum(bins: &mut [u32]) {
    let mut total = 0;
    for b in bins {
        let count = *b;
        *b = total;
        total += count;
    }
}

/// Merges runs of equal cells in the sorted `a[..n]` into points written to `(a[j], b[j])`.
///
/// Point `j` is written only after event `j` has been read (there are never more points than
/// events read so far), so the merge runs in place.
#[inline(never)]
fn merge_cells(a: &mut [u64], b: &mut [u64], n: usize) -> usize {
    // Column and row bin lie in the low 32 bits: kept in a machine word, so a 32-bit core
    // holds the cell in one register and compares it in one instruction (the Cortex-M7: 4.5
    // instructions per event fewer than with a u64), and x86-64 needs no zero-extension.
    const CELL_MASK: usize = (X_MASK | RB_MASK << RB_SHIFT) as usize;
    let Some(&first) = a.first() else {
        return 0;
    };
    let mut points = 0;
    let mut cell = first as usize & CELL_MASK;
    // ON events are counted; p_acc = ON − OFF = 2·ON − cnt at the end of each cell.
    let (mut cnt, mut on, mut f_acc) = (0u32, 0u32, 0f32);
    for i in 0..n.min(a.len()) {
        let w = a[i];
        if w as usize & CELL_MASK != cell {
            write_point(a, b, points, cell, cnt, on, f_acc);
            points += 1;
            cell = w as usize & CELL_MASK;
            (cnt, on, f_acc) = (0, 0, 0.0);
        }
        cnt += 1;
        on += ((w >> P_SHIFT) & 1) as u32;
        f_acc += f32::from_bits((w >> 32) as u32);
    }
    write_point(a, b, points, cell, cnt, on, f_acc);
    points + 1
}

/// Splits a point's row bin `k·H + y` into `(k, y)` when the point is read, with a multiply by
/// a reciprocal instead of a division: `k = ⌊bin · m / 2³²⌋`
/// with `m = ⌈2³² / H⌉` is exact for every bin below `8 · H ≤ 8,192` (the error
/// `bin · (m − 2³²/H) / 2³² < 2⁻¹⁹` never reaches the next integer, since the fraction of
/// `bin / H` is at most `1 − 1/H ≤ 1 − 2⁻¹⁰`; `core/src/raster.rs`'s tests check every `H`).
#[derive(Clone, Copy, Debug)]
struct RowDecoder {
    height: u64,
    reciprocal: u64,
}

impl RowDecoder {
    fn new(height: u16) -> Self {
        let height = u64::from(height.max(1));
        Self {
            height,
            reciprocal: (1u64 << 32).div_ceil(height),
        }
    }

    /// `(k, y)` of a row bin.
    #[inline(always)]
    fn split(self, bin: u64) -> (u64, u64) {
        let k = (bin * self.reciprocal) >> 32;
        (k, bin - k * self.height)
    }
}

fn write_point(a: &mut [u64], b: &mut [u64], j: usize, cell: usize, cnt: u32, on: u32, f_acc: f32) {
    // Wrapping: exact for cells of fewer than 2^31 events, and no overflow panic beyond.
    let p_acc = (on.wrapping_mul(2) as i32).wrapping_sub(cnt as i32);
    if let (Some(wa), Some(wb)) = (a.get_mut(j), b.get_mut(j)) {
        *wa = cell as u64 | u64::from(cnt) << 32;
        *wb = u64::from(f_acc.to_bits()) | u64::from(p_acc as u32) << 32;
    }
}

/// Time extent of a closed window.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WindowSummary {
    /// Events in the window.
    pub events: u32,
    /// Earliest timestamp, µs (0 in an empty window).
    pub t_min: i64,
    /// Latest timestamp, µs (0 in an empty window).
    pub t_max: i64,
}

/// A closed window's point cloud, borrowed from the rasterizer's storage.
#[derive(Clone, Copy, Debug)]
pub struct Window<'a> {
    a: &'a [u64],
    b: &'a [u64],
    slices: u8,
    rows: RowDecoder,
    summary: WindowSummary,
}

impl Default for Window<'_> {
    /// A window without points or events.
    fn default() -> Self {
        Self {
            a: &[],
            b: &[],
            slices: DEFAULT_SLICES,
            rows: RowDecoder::new(1),
            summary: WindowSummary::default(),
        }
    }
}

impl<'a> Window<'a> {
    /// Number of points (non-empty cells).
    pub fn len(&self) -> usize {
        self.a.len()
    }

    /// Whether the window has no points.
    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }

    /// Event count and time extent.
    pub fn summary(&self) -> WindowSummary {
        self.summary
    }

    /// Point `i` in (slice, y, x) order, or `None` past the end.
    pub fn get(&self, i: usize) -> Option<Point> {
        Some(decode_point(
            *self.a.get(i)?,
            *self.b.get(i)?,
            self.slices,
            self.rows,
        ))
    }

    /// The points in (slice, y, x) order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = Point> + 'a {
        let (slices, rows) = (self.slices, self.rows);
        self.a
            .iter()
            .zip(self.b)
            .map(move |(&wa, &wb)| decode_point(wa, wb, slices, rows))
    }
}

fn decode_point(wa: u64, wb: u64, slices: u8, rows: RowDecoder) -> Point {
    let (k, y) = rows.split((wa >> RB_SHIFT) & RB_MASK);
    // A row bin is below 8 · 1,024, so `k < 8` and `y < 1,024`.
    let (slice, y) = (k as u8, y as u16);
    let cnt = (wa >> 32) as u32;
    let f_acc = f32::from_bits(wb as u32);
    let k = f32::from(slices);
    Point {
        x: (wa & X_MASK) as u16,
        y,
        slice,
        // Same f32 operations as the reference: (f_acc / cnt) / K + k / K.
        t_avg: (f_acc / cnt as f32) / k + f32::from(slice) / k,
        p_acc: (wb >> 32) as u32 as i32,
        cnt,
    }
}

/// One point of the event point cloud: a non-empty `(slice, y, x)` cell.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Point {
    /// Column.
    pub x: u16,
    /// Row.
    pub y: u16,
    /// Time slice `k`, `0..K`.
    pub slice: u8,
    /// Mean normalized time in `[0, 1)`: `(mean fraction) / K + k / K`.
    pub t_avg: f32,
    /// ON events minus OFF events.
    pub p_acc: i32,
    /// Events in the cell.
    pub cnt: u32,
}

impl Point {
    /// The network's five input channels `[x, y, t_avg, p_acc, cnt]`, raw and unnormalized.
    pub fn features(&self) -> [f32; 5] {
        [
            f32::from(self.x),
            f32::from(self.y),
            self.t_avg,
            self.p_acc as f32,
            self.cnt as f32,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Checks [`FixedFraction`] against the f64 path for every offset of `span` in `offs`,
    /// for every `K`; returns (answered, asked).
    fn check_fixed(off_min: i32, span: u32, offs: impl Iterator<Item = u32> + Clone) -> (u64, u64) {
        let (mut hit, mut asked) = (0, 0);
        for slices in 1..=MAX_SLICES {
            let off_max = (i64::from(off_min) + i64::from(span)) as i32;
            let c = RasterConfig {
                slices,
                ..RasterConfig::DAVIS346
            };
            let s = Slices::new(&c, (off_min, off_max));
            let Some(fixed) = FixedFraction::new(off_min, s.span, s.slices) else {
                // Only spans of about 2K and less have no fixed fractions (`R ≥ 1/2`).
                assert!(span < 64, "no fixed fractions: span {span}, K {slices}");
                asked += offs.clone().count() as u64;
                continue;
            };
            for a in offs.clone() {
                let off = (i64::from(off_min) + i64::from(a)) as i32;
                let tn = s.position(off);
                let k = tn as u32;
                let want = (tn - f64::from(k)) as f32;
                asked += 1;
                if let Some(got) = fixed.fraction(off, k) {
                    hit += 1;
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "span {span}, a {a}, K {slices}"
                    );
                }
            }
        }
        (hit, asked)
    }

    /// The integer fractions of the Arm builds without a double-precision FPU are the f64
    /// path's, bit for bit, wherever they answer: every offset of spans 1–300 (1–30 under
    /// Miri) and, for large spans, offsets around every slice boundary and across the
    /// window; and they answer for nearly every event of a large span.
    #[test]
    fn fixed_fractions_are_the_f64_fractions() {
        // Under Miri (`scripts/miri.sh`, about 1,000 times slower) a tenth of the cases.
        let spans = if cfg!(miri) { 30 } else { 300 };
        let (mut sh, mut sn) = (0, 0);
        for span in 1..=spans {
            let (h, n) = check_fixed(0, span, 0..=span);
            sh += h;
            sn += n;
        }
        // Measured: 357,835 of 363,600 for spans 1–300, 3,205 of 3,960 for spans 1–30 (where
        // spans up to about 2K have no fixed fractions at all).
        let part = if cfg!(miri) { 75 } else { 98 };
        assert!(
            sh * 100 > sn * part,
            "{sh} of {sn} answered for small spans"
        );
        // Large spans: a linear congruential sequence of spans and offsets, the offsets
        // around each slice boundary, and a window far from 0 (the offset's subtraction).
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 32) as u32
        };
        let (mut hit, mut asked) = (0, 0);
        for round in 0..if cfg!(miri) { 2 } else { 300 } {
            // Offsets are i32: a window from 0 spans less than 2^31.
            let off_min = if round % 2 == 0 { 0 } else { i32::MIN };
            let span = if off_min == 0 { next() >> 1 } else { next() }.max(301);
            let random: [u32; 64] = core::array::from_fn(|_| next() % (span + 1));
            let edges = (0..=8u64).flat_map(|j| {
                let at = (u64::from(span) * j / 8) as u32;
                (0..9).map(move |d| at.saturating_add(d).saturating_sub(4).min(span))
            });
            let (h, n) = check_fixed(off_min, span, random.into_iter().chain(edges));
            hit += h;
            asked += n;
        }
        // The edges (81 of 145 offsets a window) are where the f64 path is most needed.
        // Measured: 326,459 of 348,000.
        assert!(hit * 10 > asked * 9, "{hit} of {asked} answered");
        let step = if cfg!(miri) { 100 } else { 1 };
        // (Offset 0, the window's first event, has fraction 0 and takes the f64 path.)
        let plain = (1..20_000u32)
            .step_by(step)
            .map(|i| i.wrapping_mul(107_371));
        let (h, n) = check_fixed(0, i32::MAX as u32, plain);
        assert_eq!(
            h, n,
            "every offset of a plain window but its first answered"
        );
    }

    /// The reciprocal split of a row bin into `(k, y)` is the division's, for every sensor
    /// height and every bin the histogram can hold (`K ≤ 8`); under Miri (`scripts/miri.sh`),
    /// which interprets about a thousand times slower, for a few heights.
    #[test]
    fn row_decoder_divides_exactly() {
        let under_miri = [1, 2, 3, 260, 1023];
        for height in (1..=MAX_HEIGHT).filter(|h| !cfg!(miri) || under_miri.contains(h)) {
            let d = RowDecoder::new(height);
            let h = u64::from(height);
            for bin in 0..u64::from(MAX_SLICES) * h {
                assert_eq!(d.split(bin), (bin / h, bin % h), "H = {height}, bin {bin}");
            }
        }
    }
}

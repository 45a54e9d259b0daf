//! Prophesee sensor words: EVT 2.0, EVT 2.1 and EVT 3.0 event streams decoded into [`Event`]s.
//!
//! Prophesee's sensors (the GenX320 beside a microcontroller, the IMX636 in the EVKs) stream
//! events in these encodings, and their RAW files store them after a text header. A decoder
//! here takes the words as little-endian bytes, as a DMA buffer or a file holds them, and
//! writes events through a closure or into a slice: no allocation, no unsafe code. It keeps the
//! stream's state across calls but no bytes: it uses whole words only and says how many bytes
//! it used ([`Progress::bytes`]), so a caller whose buffer ends inside a word hands that tail
//! back with the next bytes. The host's RAW reader runs it.
//!
//! EVT 2.0: u32 words, type in bits 28–31: `0x0`/`0x1` CD OFF/ON (t low 6 bits in 22–27, x in
//! 11–21, y in 0–10), `0x8` time high (bits 0–27 = t >> 6), `0xA`/`0xE`/`0xF` skipped.
//!
//! EVT 2.1 (the GenX320's default, the IMX636's other encoding beside EVT 3.0): u64 words,
//! type in bits 60–63; bits 32–63 are laid out as an EVT 2.0 word (CD OFF/ON with the time
//! low, x and y; time high; skipped types) and bits 0–31 of an event word are a mask: bit `i`
//! set, an event at x + i (lowest bit first; x need not be a multiple of 32). A GenX320 sends
//! each word little-endian as a whole ([`Encoding::Evt21`], OpenEB's `little`); an IMX636 sends
//! bits 32–63 first, then bits 0–31, each half little-endian ([`Encoding::Evt21Legacy`],
//! OpenEB's `legacy`).
//!
//! EVT 3.0: u16 words, type in bits 12–15: `0x0` y, `0x2` one event at x (polarity bit 11),
//! `0x3` vector base x and polarity, `0x4`/`0x5` 12- and 8-bit vectors of events from the base
//! (which then moves on by 12 or 8), `0x6`/`0x8` time low and time high (12 bits each: 24-bit
//! time), `0x7`/`0xA`/`0xE`/`0xF` skipped.
//!
//! Recoveries, each counted in [`EvtCounts`]: the time-high counter's wraps are unwrapped
//! ([`Unwrapper`]: a step back by more than half the counter's range; OpenEB's EVT 2.1 decoder
//! takes only the step from the largest value to 0, the same on any stream that does not jump
//! back hours); events before the first time-high word (EVT 3.0: or the first y) have no
//! time base and are dropped (an EVT 2.1 vector: all its events), as Prophesee's OpenEB does; a time-high word that changes the
//! period sets the EVT 3.0 time low to 0 (OpenEB); in an EVT 3.0 stream that has given one
//! time-high word so far, a time low more than 2,048 µs below the previous one with no
//! time-high word between starts the next period (expelliarmus writes such files; with more
//! time-high words, time lows are taken as given, as OpenEB takes them). Reserved word types,
//! pixels outside the sensor (without a sensor size: an x beyond 16 bits) and timestamps
//! beyond 64-bit microseconds are [`EvtError`]s.
//!
//! ```
//! use evpose_core::evt::{Encoding, EvtDecoder};
//! use evpose_core::Event;
//!
//! // EVT 3.0: time high 1, y = 7, time low 5, then an ON event at x = 3.
//! let words: [u16; 4] = [0x8001, 0x0007, 0x6005, 0x2803];
//! let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
//! let mut d = EvtDecoder::new(Encoding::Evt3, Some((320, 320)));
//! let mut out = [Event::default(); 16];
//! let p = d.decode(&bytes, &mut out).unwrap();
//! assert_eq!((p.bytes, p.events), (8, 1));
//! assert_eq!(out[0], Event::new(3, 7, (1 << 12) | 5, true));
//! ```

use crate::Event;

/// Unwraps a free-running counter of `bits` bits into a monotonic count.
///
/// A step back by more than half the period is a wrap. A step forward by more than half the
/// period right after a wrap is a late value from before the wrap (events of several cameras
/// or pixels are not always in strict order), and is placed in the previous period.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Unwrapper {
    bits: u32,
    last: Option<u64>,
    epoch: u64,
}

impl Unwrapper {
    /// An unwrapper for a `bits`-bit counter (`bits` is clamped to 1–63).
    pub const fn new(bits: u32) -> Self {
        Self {
            bits: if bits == 0 {
                1
            } else if bits > 63 {
                63
            } else {
                bits
            },
            last: None,
            epoch: 0,
        }
    }

    /// The counter's width in bits.
    pub const fn bits(&self) -> u32 {
        self.bits
    }

    /// Wraps seen so far (the current period).
    pub const fn wraps(&self) -> u64 {
        self.epoch
    }

    /// The last raw value taken, if any.
    pub const fn last(&self) -> Option<u64> {
        self.last
    }

    /// Takes `raw` as the last value, in the current period (a caller's fast path that
    /// unwrapped steps forward itself hands its last value back).
    pub fn set_last(&mut self, raw: u64) {
        self.last = Some(raw);
    }

    /// The unwrapped value of `raw`; `None` when it does not fit an `i64`.
    pub fn unwrap(&mut self, raw: u64) -> Option<i64> {
        let half = 1u64 << (self.bits - 1);
        let mut epoch = self.epoch;
        match self.last {
            Some(last) if raw < last && last - raw > half => {
                self.epoch += 1;
                epoch = self.epoch;
                self.last = Some(raw);
            }
            Some(last) if raw > last && raw - last > half && epoch > 0 => epoch -= 1,
            _ => self.last = Some(raw),
        }
        epoch
            .checked_mul(1u64 << self.bits)
            .and_then(|base| base.checked_add(raw))
            .and_then(|v| i64::try_from(v).ok())
    }
}

/// The word encoding of a stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Encoding {
    /// EVT 2.0: 32-bit words, one event each.
    Evt2,
    /// EVT 2.1 as a GenX320 sends it (OpenEB's `little` endianness): 64-bit words, each
    /// little-endian as a whole, up to 32 events each (vectors).
    Evt21,
    /// EVT 2.1 as an IMX636 sends it (OpenEB's `legacy` endianness): each 64-bit word as its
    /// upper 32 bits, then its lower 32 bits (the vector's mask), each little-endian.
    Evt21Legacy,
    /// EVT 3.0: 16-bit words, up to 12 events each (vectors).
    Evt3,
}

impl Encoding {
    /// Bytes per word.
    pub const fn word_bytes(self) -> usize {
        match self {
            Self::Evt2 => 4,
            Self::Evt21 | Self::Evt21Legacy => 8,
            Self::Evt3 => 2,
        }
    }

    /// The most events one word gives.
    pub const fn max_events_per_word(self) -> usize {
        match self {
            Self::Evt2 => 1,
            Self::Evt21 | Self::Evt21Legacy => 32,
            Self::Evt3 => 12,
        }
    }
}

/// Bad words: `at` is the byte index of the word in the slice given to [`EvtDecoder::decode`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EvtError {
    /// A word of a type the encoding reserves.
    ReservedType {
        /// Byte index of the word.
        at: usize,
        /// The word (an EVT 2.1 word as its 64 bits, the type in bits 60–63).
        word: u64,
    },
    /// An event outside the sensor size given to [`EvtDecoder::new`].
    OutsideSensor {
        /// Byte index of the word.
        at: usize,
        /// The event's column.
        x: u32,
        /// The event's row.
        y: u32,
        /// The sensor's width and height.
        size: (u16, u16),
    },
    /// With no sensor size given, an x beyond 16 bits (an EVT 3.0 vector run past 65535).
    WideX {
        /// Byte index of the word.
        at: usize,
        /// The column.
        x: u32,
    },
    /// A time-high word whose time does not fit 64-bit microseconds.
    TimeOverflow {
        /// Byte index of the word.
        at: usize,
    },
}

/// What a decoder recovered from, so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EvtCounts {
    /// Events before the stream gave their time base (EVT 3.0: or their row), dropped.
    pub dropped_events: u64,
    /// Words of the skipped types (triggers, "other", continuations).
    pub skipped_words: u64,
    /// Wraps of the time-high counter, unwrapped.
    pub timestamp_wraps: u64,
    /// EVT 3.0 time-low wraps taken as the next period with no time-high word (see the module
    /// documentation).
    pub implied_time_highs: u64,
}

/// How far one [`EvtDecoder::decode`] call went.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Progress {
    /// Bytes used: whole words. The rest (a cut word, or words left because the output was
    /// nearly full) goes to the next call.
    pub bytes: usize,
    /// Events written.
    pub events: usize,
}

/// A streaming EVT 2.0 / 2.1 / 3.0 decoder: a few words of state, no buffer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EvtDecoder {
    encoding: Encoding,
    size: Option<(u16, u16)>,
    /// Unwrapped time-high value, once one was seen.
    high: Option<i64>,
    high_counter: Unwrapper,
    /// EVT 3.0: time low, row, vector base and polarity.
    low: i64,
    /// EVT 3.0: a time-low word came since the last time-high word. Read only while the
    /// stream gave exactly one time-high word, and kept only then (the common path does not
    /// set it).
    low_seen: bool,
    /// EVT 3.0: time-high words so far.
    high_words: u64,
    y: Option<u16>,
    base_x: u32,
    on: bool,
    counts: EvtCounts,
}

impl EvtDecoder {
    /// A decoder at the start of a stream. With `size`, events outside it are errors; without,
    /// any x and y the words can hold are taken.
    pub const fn new(encoding: Encoding, size: Option<(u16, u16)>) -> Self {
        Self {
            encoding,
            size,
            high: None,
            high_counter: Unwrapper::new(match encoding {
                Encoding::Evt2 | Encoding::Evt21 | Encoding::Evt21Legacy => 28,
                Encoding::Evt3 => 12,
            }),
            low: 0,
            low_seen: false,
            high_words: 0,
            y: None,
            base_x: 0,
            on: false,
            counts: EvtCounts {
                dropped_events: 0,
                skipped_words: 0,
                timestamp_wraps: 0,
                implied_time_highs: 0,
            },
        }
    }

    /// The stream's encoding.
    pub const fn encoding(&self) -> Encoding {
        self.encoding
    }

    /// What the decoder recovered from so far.
    pub const fn counts(&self) -> EvtCounts {
        self.counts
    }

    /// Decodes whole words of `bytes` into `out` while a word's events still fit (one per
    /// EVT 2.0 word, up to 32 per EVT 2.1 word, up to 12 per EVT 3.0 word); returns the bytes
    /// used and events written.
    /// An `out` shorter than [`Encoding::max_events_per_word`] takes no word (`bytes: 0`).
    pub fn decode(&mut self, bytes: &[u8], out: &mut [Event]) -> Result<Progress, EvtError> {
        let room = out.len();
        let mut slots = out.iter_mut();
        self.decode_with(bytes, room, move |e| {
            // `room` keeps the events within `out`: every event has its slot.
            if let Some(slot) = slots.next() {
                *slot = e;
            }
        })
    }

    /// [`EvtDecoder::decode`] with a sink: `emit` takes each event; decoding stops before a
    /// word once fewer than [`Encoding::max_events_per_word`] of `room` events are left.
    pub fn decode_with(
        &mut self,
        bytes: &[u8],
        room: usize,
        emit: impl FnMut(Event),
    ) -> Result<Progress, EvtError> {
        match self.encoding {
            Encoding::Evt2 => self.evt2::<4, false>(bytes, room, emit),
            Encoding::Evt21 => self.evt2::<8, false>(bytes, room, emit),
            Encoding::Evt21Legacy => self.evt2::<8, true>(bytes, room, emit),
            Encoding::Evt3 => self.evt3(bytes, room, emit),
        }
    }

    /// The error of an event at `(x, y)` outside the sensor (without a size: an x beyond 16
    /// bits).
    #[cold]
    fn outside(&self, at: usize, x: u32, y: u32) -> EvtError {
        match self.size {
            Some(size) => EvtError::OutsideSensor { at, x, y, size },
            None => EvtError::WideX { at, x },
        }
    }

    /// EVT 2.0 (`W` = 4) and EVT 2.1 (`W` = 8) words. An EVT 2.1 word's upper 32 bits are an
    /// EVT 2.0 word (type, time low, x, y; or a time high), its lower 32 bits a mask of the
    /// events at x + 0 … x + 31; an EVT 2.0 event is a mask of one bit. `LEGACY`: the upper
    /// half comes first.
    ///
    /// The common case runs on locals ([`Evt2Fast`]): events of a known time inside the
    /// sensor, and time-high words that step forward by at most half the counter's range.
    /// Every other word goes through [`EvtDecoder::word2`] with the state written back first
    /// and read again after; none of those gives an event, so `emit` stays in registers.
    fn evt2<const W: usize, const LEGACY: bool>(
        &mut self,
        bytes: &[u8],
        room: usize,
        mut emit: impl FnMut(Event),
    ) -> Result<Progress, EvtError> {
        // `max_events_per_word`: a mask of one bit, or of 32; a word is taken while
        // `events ≤ last`.
        let max = if W == 8 { 32 } else { 1 };
        let Some(last) = room.checked_sub(max) else {
            return Ok(Progress {
                bytes: 0,
                events: 0,
            });
        };
        let mut events = 0;
        let mut s = Evt2Fast::load(self);
        let mut rest = bytes;
        'words: loop {
            if events > last {
                s.store(self);
                return Ok(Progress {
                    bytes: bytes.len() - rest.len(),
                    events,
                });
            }
            while let Some((b, tail)) = rest.split_first_chunk::<W>() {
                let (w, mask) = halves::<W, LEGACY>(b);
                let ty = w >> 28;
                // One test for both polarities (a branch on the polarity, which sensors
                // interleave at random, would be mispredicted half the time). `x_end` is 0
                // until the time base is known: no event is inside.
                if ty <= 0x1 && (w & 0x7FF) < s.height && s.x_end > 0 {
                    let (x0, y) = ((w >> 11) & 0x7FF, (w & 0x7FF) as u16);
                    let t = s.t_high | i64::from((w >> 22) & 0x3F);
                    let mut m = mask;
                    while m != 0 {
                        let x = x0 + m.trailing_zeros();
                        m &= m - 1;
                        if x >= s.x_end {
                            s.store(self);
                            let at = bytes.len() - rest.len();
                            return Err(self.outside(at, x, u32::from(y)));
                        }
                        emit(Event::new(x as u16, y, t, ty == 1));
                        events += 1;
                    }
                    if events > last {
                        rest = tail;
                        continue 'words;
                    }
                } else if !(ty == 0x8 && s.forward(w & 0x0FFF_FFFF)) {
                    break;
                }
                rest = tail;
            }
            let Some((b, tail)) = rest.split_first_chunk::<W>() else {
                break;
            };
            s.store(self);
            let (w, mask) = halves::<W, LEGACY>(b);
            let word = if W == 8 {
                u64::from(w) << 32 | u64::from(mask)
            } else {
                u64::from(w)
            };
            self.word2(bytes.len() - rest.len(), w, mask, word)?;
            s = Evt2Fast::load(self);
            rest = tail;
        }
        s.store(self);
        Ok(Progress {
            bytes: bytes.len() / W * W,
            events,
        })
    }

    /// An EVT 2.0 / 2.1 word outside [`EvtDecoder::evt2`]'s common case, at byte `at` (`w`: its
    /// upper half, `mask`: its events, `word`: the whole word): events before the time base
    /// (dropped) or outside the sensor (an error), a time-high word that does not step forward
    /// by at most half the range (a wrap, or the first), a skipped or reserved word. Gives no
    /// event.
    #[inline(never)]
    fn word2(&mut self, at: usize, w: u32, mask: u32, word: u64) -> Result<(), EvtError> {
        match w >> 28 {
            0x0 | 0x1 => {
                if self.high.is_none() {
                    self.counts.dropped_events += u64::from(mask.count_ones());
                } else if mask != 0 {
                    // `evt2` takes every event of a known time in a row inside the sensor: one
                    // here lies in a row outside it (`x`: the word's first event).
                    let x = ((w >> 11) & 0x7FF) + mask.trailing_zeros();
                    return Err(self.outside(at, x, w & 0x7FF));
                }
            }
            0x8 => {
                let high = self
                    .high_counter
                    .unwrap(u64::from(w & 0x0FFF_FFFF))
                    .filter(|&h| h < 1 << 57)
                    .ok_or(EvtError::TimeOverflow { at })?;
                self.high = Some(high);
                self.counts.timestamp_wraps = self.high_counter.wraps();
            }
            0xA | 0xE | 0xF => self.counts.skipped_words += 1,
            _ => return Err(EvtError::ReservedType { at, word }),
        }
        Ok(())
    }

    /// EVT 3.0 words, on [`Evt3Fast`] (the state in locals). An inner loop takes the words of
    /// a sparse stream (rows, time lows, single events of a known row and time inside the
    /// sensor) with few live values; the outer loop takes vector bases and vectors, and hands
    /// every other case to [`EvtDecoder::word3`] with the state written back first and read
    /// again after. No such case gives an event, so `emit` is never handed on and stays in
    /// registers. Out of line: its loop's registers are its own wherever `decode` is inlined.
    #[inline(never)]
    fn evt3(
        &mut self,
        bytes: &[u8],
        room: usize,
        mut emit: impl FnMut(Event),
    ) -> Result<Progress, EvtError> {
        // A word gives at most 12 events: one is taken while `events ≤ last`.
        let Some(last) = room.checked_sub(Encoding::Evt3.max_events_per_word()) else {
            return Ok(Progress {
                bytes: 0,
                events: 0,
            });
        };
        let mut events = 0;
        let mut s = Evt3Fast::load(self);
        let mut rest = bytes;
        // `events > last` changes only where an event is written: tested here, and after each
        // event of the inner loop (which then comes back here).
        'words: loop {
            if events > last {
                s.store(self);
                return Ok(Progress {
                    bytes: bytes.len() - rest.len(),
                    events,
                });
            }
            while let [b0, b1, tail @ ..] = rest {
                let w = u16::from_le_bytes([*b0, *b1]);
                match w >> 12 {
                    0x2 if u32::from(w & 0x7FF) < s.width && s.row < s.height => {
                        let x = w & 0x7FF;
                        emit(Event::new(x, s.row as u16, s.t, w & 0x800 != 0));
                        events += 1;
                        if events > last {
                            rest = tail;
                            continue 'words;
                        }
                    }
                    0x0 => s.row = u32::from(w & 0x7FF) | s.no_high,
                    // With exactly one time-high word so far a time low may imply the next
                    // period: `word3` tells.
                    0x6 if !s.one_high => s.t = (s.t & !0xFFF) | i64::from(w & 0xFFF),
                    _ => break,
                }
                rest = tail;
            }
            let [b0, b1, tail @ ..] = rest else {
                break;
            };
            let at = bytes.len() - rest.len();
            let w = u16::from_le_bytes([*b0, *b1]);
            let ty = w >> 12;
            match ty {
                0x3 => {
                    s.base_x = u32::from(w & 0x7FF);
                    s.on = w & 0x800 != 0;
                }
                0x4 | 0x5 if s.row < s.height => {
                    let (mut mask, width) = if ty == 0x4 {
                        (u32::from(w & 0xFFF), 12)
                    } else {
                        (u32::from(w & 0xFF), 8)
                    };
                    let base_x = s.base_x;
                    // Capped far above any sensor: `base_x + bit` cannot overflow.
                    s.base_x = (base_x + width).min(1 << 24);
                    while mask != 0 {
                        let x = base_x + mask.trailing_zeros();
                        mask &= mask - 1;
                        if x >= s.width {
                            s.store(self);
                            return Err(self.outside(at, x, s.row));
                        }
                        emit(Event::new(x as u16, s.row as u16, s.t, s.on));
                        events += 1;
                    }
                }
                _ => {
                    s.store(self);
                    self.word3(at, w)?;
                    s = Evt3Fast::load(self);
                }
            }
            rest = tail;
        }
        s.store(self);
        Ok(Progress {
            bytes: bytes.len() / 2 * 2,
            events,
        })
    }

    /// An EVT 3.0 word outside [`EvtDecoder::evt3`]'s common case, at byte `at`: an event
    /// (single or vector) of an unknown row or time, which is dropped, or outside the sensor,
    /// an error; a time low that wrapped; a time-high, skipped or reserved word. Gives no event.
    #[inline(never)]
    fn word3(&mut self, at: usize, w: u16) -> Result<(), EvtError> {
        let ty = w >> 12;
        match ty {
            0x0 => self.y = Some(w & 0x7FF),
            0x2 | 0x4 | 0x5 => {
                let (mask, x) = match ty {
                    0x2 => (1, u32::from(w & 0x7FF)),
                    _ => {
                        let (mask, width) = if ty == 0x4 {
                            (u32::from(w & 0xFFF), 12)
                        } else {
                            (u32::from(w & 0xFF), 8)
                        };
                        let base_x = self.base_x;
                        self.base_x = (base_x + width).min(1 << 24);
                        (mask, base_x + mask.trailing_zeros())
                    }
                };
                match (self.high, self.y) {
                    // `evt3` takes every event of a known row and time inside the sensor: one
                    // here lies outside it (`x` is the vector's first).
                    (Some(_), Some(y)) if mask != 0 => {
                        return Err(self.outside(at, x, u32::from(y)));
                    }
                    (Some(_), Some(_)) => {}
                    _ => self.counts.dropped_events += u64::from(mask.count_ones()),
                }
            }
            0x3 => {
                self.base_x = u32::from(w & 0x7FF);
                self.on = w & 0x800 != 0;
            }
            0x6 => {
                let low = i64::from(w & 0xFFF);
                // Time low back by more than half its range with no time-high word since
                // the last time low, in a stream that gave one time-high word so far: its
                // counter wrapped into the next period.
                let wrapped = self.low_seen && self.high_words == 1 && low + 0x800 < self.low;
                if let (true, Some(high)) = (wrapped, self.high) {
                    self.high = Some(
                        self.high_counter
                            .unwrap(((high + 1) & 0xFFF) as u64)
                            .filter(|&h| h < 1 << 50)
                            .ok_or(EvtError::TimeOverflow { at })?,
                    );
                    self.counts.timestamp_wraps = self.high_counter.wraps();
                    self.counts.implied_time_highs += 1;
                }
                self.low = low;
                self.low_seen = true;
            }
            0x8 => {
                let high = self
                    .high_counter
                    .unwrap(u64::from(w & 0xFFF))
                    .filter(|&h| h < 1 << 50)
                    .ok_or(EvtError::TimeOverflow { at })?;
                // A new time-high period starts at time low 0 (as OpenEB decodes it).
                if self.high != Some(high) {
                    self.low = 0;
                }
                self.high = Some(high);
                self.high_words += 1;
                self.low_seen = false;
                self.counts.timestamp_wraps = self.high_counter.wraps();
            }
            0x7 | 0xA | 0xE | 0xF => self.counts.skipped_words += 1,
            _ => {
                return Err(EvtError::ReservedType {
                    at,
                    word: u64::from(w),
                })
            }
        }
        Ok(())
    }
}

/// An EVT 3.0 decoder's state in the form its common words need (locals of
/// [`EvtDecoder::evt3`]'s loop): the readiness and sensor tests of an event folded into two
/// compares, the event time kept whole.
struct Evt3Fast {
    /// The row; [`Evt3Fast::NO_HIGH`] set while no time-high word came; `u32::MAX` before the
    /// first row. An event is in the common case when `row < height`.
    row: u32,
    /// `NO_HIGH` until a time-high word came, then 0.
    no_high: u32,
    /// `high << 12 | low` (the low 12 bits alone before the first time-high word).
    t: i64,
    /// Whether the stream gave exactly one time-high word so far (its time lows take
    /// [`EvtDecoder::word3`]).
    one_high: bool,
    base_x: u32,
    on: bool,
    /// The sensor's size; without one, the widest x and y the checks take, plus one.
    width: u32,
    height: u32,
}

impl Evt3Fast {
    /// Above every row: a row with this bit is never below the height.
    const NO_HIGH: u32 = 1 << 31;

    #[inline(always)]
    fn load(d: &EvtDecoder) -> Self {
        let no_high = if d.high.is_some() { 0 } else { Self::NO_HIGH };
        let one_high = d.high.is_some() && d.high_words == 1;
        let (width, height) = match d.size {
            Some((w, h)) => (u32::from(w), u32::from(h)),
            // `check`: without a size, an x up to 16 bits and any 11-bit row.
            None => (1 << 16, 1 << 11),
        };
        Self {
            row: d.y.map_or(u32::MAX, |y| u32::from(y) | no_high),
            no_high,
            t: (d.high.unwrap_or(0) << 12) | d.low,
            one_high,
            base_x: d.base_x,
            on: d.on,
            width,
            height,
        }
    }

    #[inline(always)]
    fn store(&self, d: &mut EvtDecoder) {
        d.y = (self.row != u32::MAX).then_some((self.row & 0x7FF) as u16);
        d.low = self.t & 0xFFF;
        d.base_x = self.base_x;
        d.on = self.on;
    }
}

/// An EVT 2.0 word (`W` = 4: the word and a mask of one event) or an EVT 2.1 word (`W` = 8: its
/// upper and lower halves; `LEGACY`, the upper half first).
#[inline(always)]
fn halves<const W: usize, const LEGACY: bool>(b: &[u8; W]) -> (u32, u32) {
    let first = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    match b.get(4..8) {
        Some(&[b4, b5, b6, b7]) => {
            let second = u32::from_le_bytes([b4, b5, b6, b7]);
            if LEGACY {
                (first, second)
            } else {
                (second, first)
            }
        }
        _ => (first, 1),
    }
}

/// An EVT 2.0 / 2.1 decoder's state in the form its common words need (locals of
/// [`EvtDecoder::evt2`]'s loop).
struct Evt2Fast {
    /// `high << 6`: an event's time less its low 6 bits; -1 while the time base is not known
    /// (times are never negative).
    t_high: i64,
    /// The sensor's width once the time base is known (without a size, the widest x the
    /// checks take, plus one); 0 before.
    x_end: u32,
    width: u32,
    /// The sensor's height (without a size, 2^11: any row).
    height: u32,
    /// The time-high counter's last value and its periods so far, `epoch · 2^28`; `None`
    /// before the first (or where the periods would not fit).
    counter: Option<(u32, i64)>,
}

impl Evt2Fast {
    #[inline(always)]
    fn load(d: &EvtDecoder) -> Self {
        let (width, height) = match d.size {
            Some((w, h)) => (u32::from(w), u32::from(h)),
            None => (1 << 16, 1 << 11),
        };
        // Periods from 2^57 µs on are `word2`'s (an overflow): `base + raw` stays in range.
        let counter = d.high_counter.last().and_then(|raw| {
            let base = i64::try_from(d.high_counter.wraps())
                .ok()?
                .checked_mul(1 << 28)?;
            (base < 1 << 57).then_some((raw as u32, base))
        });
        Self {
            t_high: d.high.map_or(-1, |h| h << 6),
            x_end: if d.high.is_some() { width } else { 0 },
            width,
            height,
            counter,
        }
    }

    #[inline(always)]
    fn store(&self, d: &mut EvtDecoder) {
        if self.t_high >= 0 {
            d.high = Some(self.t_high >> 6);
        }
        if let Some((raw, _)) = self.counter {
            d.high_counter.set_last(u64::from(raw));
        }
    }

    /// Takes a time-high value that steps forward from the last by at most half the counter's
    /// range, where [`Unwrapper::unwrap`] gives it the current period; false for any other.
    #[inline(always)]
    fn forward(&mut self, raw: u32) -> bool {
        let Some((last, base)) = self.counter else {
            return false;
        };
        let high = base + i64::from(raw);
        if raw < last || raw - last > 1 << 27 || high >= 1 << 57 {
            return false;
        }
        self.counter = Some((raw, base));
        self.t_high = high << 6;
        self.x_end = self.width;
        true
    }
}

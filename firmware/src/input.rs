//! Event input: a sensor-agnostic [`EventSource`] trait, the `EVS1` byte-stream decoder, and
//! [`EvtSource`], a Prophesee sensor's EVT words through the core's decoder.
//!
//! # Why a byte stream behind `embedded_io::Read`
//! Event sensors reach an MCU as a byte stream: a serial link (UART, SPI slave with DMA) or a
//! parallel port feeding a DMA ring. `embedded_io::Read` is the embedded-hal family's byte-stream
//! trait, and HAL UART drivers implement it (embassy's `BufferedUart`, for one). So
//! [`EvsReader`] decodes from any `R: embedded_io::Read`: on a board `R` is the driver; under
//! QEMU it is the recording in flash, a plain `&'static [u8]` (which implements `Read` too). The
//! pipeline sees only [`EventSource`], a batch interface shaped like a DMA half-buffer, so a
//! sensor with its own framing (a parallel port, an on-chip event decoder) only needs another
//! `EventSource` implementation, as [`EvtSource`] is for a Prophesee sensor's words.
//!
//! # The `EVS1` stream
//! Little-endian. A 24-byte header, then one `u32` word per event plus a `TIME` word where a time
//! step does not fit in an event word:
//!
//! ```text
//! header   0 magic "EVS1"   4 width u16   6 height u16   8 events u32   12 reserved u32 (0)
//!          16 t0 i64: the stream's start time, µs
//! EVENT    bit 31 = 0:  x = bits 0..=10, y = bits 11..=20, polarity = bit 21 (1 = ON),
//!                       dt = bits 22..=30: µs after the previous event (the first: after t0)
//! TIME     bit 31 = 1:  bits 0..=30 = a signed (two's complement, 31-bit) step in µs added to
//!                       the running time; the next EVENT word's dt adds to that
//! ```
//!
//! x and y have the core rasterizer's limits (11 and 10 bits). A step outside `0..512` µs,
//! backwards included, costs one `TIME` word; the street recording has none, so it takes
//! exactly 4 bytes per event. `events` counts EVENT words; the stream ends after the last.
//!
//! The encoder and an independent reference decoder live in the test suite
//! (`tests/firmware_qemu.rs`), which also checks that decoding `assets/street-00-02.evs` gives
//! exactly the events of the bundled `.npy` windows.

use embedded_io::{ErrorKind, Read, ReadExactError};
use evpose_core::evt::{Encoding, EvtDecoder, EvtError};
use evpose_core::Event;

/// Magic bytes of an `EVS1` stream.
pub const MAGIC: [u8; 4] = *b"EVS1";
/// Size of the stream header.
pub const HEADER_LEN: usize = 24;

const TIME_BIT: u32 = 1 << 31;
const X_MASK: u32 = (1 << 11) - 1;
const Y_SHIFT: u32 = 11;
const Y_MASK: u32 = (1 << 10) - 1;
const P_SHIFT: u32 = 21;
const DT_SHIFT: u32 = 22;
const DT_MASK: u32 = (1 << 9) - 1;

/// A producer of events, read in batches (one DMA buffer's worth at a time on a board).
pub trait EventSource {
    /// Why a read failed.
    type Error;

    /// Fills `out` from the front with the next events; returns how many. `Ok(0)` means the
    /// source has ended (a live sensor never ends: it blocks until events arrive).
    fn read_events(&mut self, out: &mut [Event]) -> Result<usize, Self::Error>;
}

/// Why an `EVS1` stream could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
#[non_exhaustive]
pub enum StreamError {
    /// The byte source failed.
    Read(ErrorKind),
    /// The source ended inside the header or before the stated number of events.
    UnexpectedEof,
    /// Not an `EVS1` stream.
    BadMagic,
    /// The running time left the `i64` range.
    TimeOverflow,
}

impl<E: embedded_io::Error> From<ReadExactError<E>> for StreamError {
    fn from(e: ReadExactError<E>) -> Self {
        match e {
            ReadExactError::UnexpectedEof => Self::UnexpectedEof,
            ReadExactError::Other(e) => Self::Read(e.kind()),
        }
    }
}

/// The header of an `EVS1` stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct Header {
    /// Sensor width in pixels.
    pub width: u16,
    /// Sensor height in pixels.
    pub height: u16,
    /// Number of events in the stream.
    pub events: u32,
    /// Start time, µs.
    pub t0: i64,
}

/// Decodes an `EVS1` stream from a byte source.
pub struct EvsReader<R> {
    source: R,
    header: Header,
    remaining: u32,
    time: i64,
    /// Bytes read from `source` and not yet decoded: `buf[start..end]`.
    buf: [u8; 256],
    start: usize,
    end: usize,
}

impl<R: Read> EvsReader<R> {
    /// Reads and checks the header.
    pub fn new(mut source: R) -> Result<Self, StreamError> {
        let mut h = [0u8; HEADER_LEN];
        source.read_exact(&mut h)?;
        if h[..4] != MAGIC {
            return Err(StreamError::BadMagic);
        }
        let u16_at = |o: usize| u16::from_le_bytes([h[o], h[o + 1]]);
        let u32_at = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
        let mut t0 = [0u8; 8];
        t0.copy_from_slice(&h[16..24]);
        let header = Header {
            width: u16_at(4),
            height: u16_at(6),
            events: u32_at(8),
            t0: i64::from_le_bytes(t0),
        };
        Ok(Self {
            source,
            header,
            remaining: header.events,
            time: header.t0,
            buf: [0; 256],
            start: 0,
            end: 0,
        })
    }

    /// The stream's header.
    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The next word, refilling the buffer from the source as needed (a source may return any
    /// number of bytes per read, so a word can straddle two reads).
    fn next_word(&mut self) -> Result<u32, StreamError> {
        // `get` and `first_chunk` rather than indexing: `start ≤ end ≤ 256` always holds, and
        // no panic path is left in the image.
        loop {
            if self.end >= self.start + 4 {
                if let Some(w) = self
                    .buf
                    .get(self.start..)
                    .and_then(|b| b.first_chunk::<4>())
                {
                    self.start += 4;
                    return Ok(u32::from_le_bytes(*w));
                }
            }
            self.refill()?;
        }
    }

    /// Moves the fewer than 4 bytes not yet decoded to the front of the buffer and reads more
    /// behind them.
    #[inline(never)]
    fn refill(&mut self) -> Result<(), StreamError> {
        let kept = carry_to_front::<4>(&mut self.buf, self.start, self.end);
        (self.start, self.end) = (0, kept);
        let n = self
            .source
            .read(self.buf.get_mut(kept..).unwrap_or_default())
            .map_err(|e| StreamError::Read(embedded_io::Error::kind(&e)))?;
        if n == 0 {
            return Err(StreamError::UnexpectedEof);
        }
        self.end += n;
        Ok(())
    }

    /// The next event, or `None` after the last one.
    pub fn next_event(&mut self) -> Result<Option<Event>, StreamError> {
        if self.remaining == 0 {
            return Ok(None);
        }
        loop {
            let w = self.next_word()?;
            self.time = self
                .time
                .checked_add(time_step(w))
                .ok_or(StreamError::TimeOverflow)?;
            if w & TIME_BIT == 0 {
                self.remaining -= 1;
                return Ok(Some(event_at(w, self.time)));
            }
        }
    }
}

impl<R: Read> EventSource for EvsReader<R> {
    type Error = StreamError;

    /// Decodes every whole word the buffer holds in one pass (the time in a register, no
    /// refill check per word), refilling between passes: the same events as [`next_event`]
    /// one by one (the boot check [`check_decoder`] compares them), in a fifth fewer
    /// instructions (43.0 against 53.8 per event on the Cortex-M7).
    ///
    /// [`next_event`]: EvsReader::next_event
    // Out of line: inlined into `main`, it took registers from the pipeline's own loops there
    // (the sampler measured 12–15 k more instructions per window).
    #[inline(never)]
    fn read_events(&mut self, out: &mut [Event]) -> Result<usize, StreamError> {
        let mut n = 0;
        while n < out.len() && self.remaining > 0 {
            if self.end < self.start + 4 {
                self.refill()?;
                continue;
            }
            n += self.decode_buffered(out.get_mut(n..).unwrap_or_default())?;
        }
        Ok(n)
    }
}

impl<R: Read> EvsReader<R> {
    /// Decodes the buffer's whole words into `out`, up to its length and the events left.
    fn decode_buffered(&mut self, out: &mut [Event]) -> Result<usize, StreamError> {
        let want = out.len().min(self.remaining as usize);
        let (words, _) = self
            .buf
            .get(self.start..self.end)
            .unwrap_or_default()
            .as_chunks::<4>();
        // A pass moves the time by less than 2^31 µs per word (an EVENT word's step is below
        // 2^9, a TIME word's at most 2^30 either way); far enough from both ends of the i64
        // range no step of this pass can overflow, and the loop need not check.
        let margin = (words.len() as i64) << 31;
        let (n, used, time) = if self.time.unsigned_abs() < (i64::MAX - margin) as u64 {
            decode_words::<false>(words, out.get_mut(..want).unwrap_or_default(), self.time)
        } else {
            decode_words::<true>(words, out.get_mut(..want).unwrap_or_default(), self.time)
        };
        self.start += used;
        let time = time.ok_or(StreamError::TimeOverflow)?;
        self.time = time;
        // `n ≤ want ≤ remaining`.
        self.remaining -= n as u32;
        Ok(n)
    }
}

/// The time step of a word: an EVENT word's `dt`, or a TIME word's signed 31-bit step.
#[inline(always)]
fn time_step(w: u32) -> i64 {
    if w & TIME_BIT != 0 {
        i64::from(((w << 1) as i32) >> 1)
    } else {
        i64::from(w >> DT_SHIFT & DT_MASK)
    }
}

/// The event of an EVENT word at `time` (after its step).
#[inline(always)]
fn event_at(w: u32, time: i64) -> Event {
    Event::new(
        (w & X_MASK) as u16,
        (w >> Y_SHIFT & Y_MASK) as u16,
        time,
        w >> P_SHIFT & 1 == 1,
    )
}

/// Decodes `words` into `out` until either runs out: (events written, bytes used, the time
/// after them, or `None` where a step overflowed it, `CHECKED` only).
#[inline(always)]
fn decode_words<const CHECKED: bool>(
    words: &[[u8; 4]],
    out: &mut [Event],
    mut time: i64,
) -> (usize, usize, Option<i64>) {
    let (mut n, mut used) = (0, 0);
    let mut words = words.iter();
    'events: for slot in out.iter_mut() {
        loop {
            let Some(&bytes) = words.next() else {
                break 'events;
            };
            let w = u32::from_le_bytes(bytes);
            used += 4;
            let step = time_step(w);
            time = if CHECKED {
                match time.checked_add(step) {
                    Some(t) => t,
                    None => return (n, used, None),
                }
            } else {
                time.wrapping_add(step)
            };
            if w & TIME_BIT == 0 {
                *slot = event_at(w, time);
                n += 1;
                break;
            }
        }
    }
    (n, used, Some(time))
}

/// Moves `buf[start..end]`, a cut word's bytes (at most `W`), to the front of `buf`; returns
/// how many. Copied through `get` and zips: no panic path in the image.
fn carry_to_front<const W: usize>(buf: &mut [u8], start: usize, end: usize) -> usize {
    let mut carry = [0u8; W];
    let pending = buf.get(start..end).unwrap_or_default();
    let kept = pending.len().min(W);
    for (c, &b) in carry.iter_mut().zip(pending) {
        *c = b;
    }
    for (b, &c) in buf.iter_mut().zip(&carry).take(kept) {
        *b = c;
    }
    kept
}

/// Why a Prophesee sensor's words could not be read ([`EvtSource`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
#[non_exhaustive]
pub enum EvtSourceError {
    /// The byte source failed.
    Read(ErrorKind),
    /// A word the core's decoder refused (a reserved type, a pixel outside the sensor, a time
    /// beyond 64-bit µs).
    Decode(EvtError),
    /// The byte source ended inside a word.
    CutWord,
    /// The output holds fewer events than one word can give
    /// ([`Encoding::max_events_per_word`]: 12 for EVT 3.0, 32 for EVT 2.1), or the buffer `N`
    /// fewer bytes than a word.
    OutputTooSmall,
}

/// A Prophesee sensor (a GenX320 beside the MCU, an IMX636) as an [`EventSource`]: its EVT 2.0,
/// 2.1 or 3.0 words from any `embedded_io::Read` (the sensor interface's DMA driver), decoded by
/// the core's [`EvtDecoder`] through an `N`-byte buffer (at least one word; a read may end
/// inside a word, whose bytes wait in the buffer for the rest). The boot check reads the first
/// window through it, 7 bytes per read ([`check_evt`]).
pub struct EvtSource<R, const N: usize> {
    source: R,
    decoder: EvtDecoder,
    /// Bytes read and not yet decoded: `buf[start..end]`.
    buf: [u8; N],
    start: usize,
    end: usize,
}

impl<R: Read, const N: usize> EvtSource<R, N> {
    /// A source of `encoding` words from `source`; events outside `size` (width, height) are
    /// errors, as the decoder's.
    pub const fn new(source: R, encoding: Encoding, size: Option<(u16, u16)>) -> Self {
        Self {
            source,
            decoder: EvtDecoder::new(encoding, size),
            buf: [0; N],
            start: 0,
            end: 0,
        }
    }

    /// The decoder (its counts of recoveries).
    pub fn decoder(&self) -> &EvtDecoder {
        &self.decoder
    }
}

impl<R: Read, const N: usize> EventSource for EvtSource<R, N> {
    type Error = EvtSourceError;

    /// Decodes the buffered words into `out`, refilling the buffer while they give no event;
    /// `Ok(0)` once the source ends on a word boundary. After a word the decoder refuses, the
    /// error; the next call goes on after that word (the events this call decoded before it
    /// are lost).
    fn read_events(&mut self, out: &mut [Event]) -> Result<usize, EvtSourceError> {
        let encoding = self.decoder.encoding();
        if out.len() < encoding.max_events_per_word() || N < encoding.word_bytes() {
            return Err(EvtSourceError::OutputTooSmall);
        }
        loop {
            let words = self.buf.get(self.start..self.end).unwrap_or_default();
            let p = match self.decoder.decode(words, out) {
                Ok(p) => p,
                Err(e) => {
                    // Go on after the bad word at the next call (a live sensor outlives one
                    // corrupted word); this call's events before it are lost.
                    self.start = (self.start + error_at(e) + encoding.word_bytes()).min(self.end);
                    return Err(EvtSourceError::Decode(e));
                }
            };
            self.start += p.bytes;
            if p.events > 0 {
                return Ok(p.events);
            }
            if p.bytes > 0 {
                continue; // words without events (time highs, rows): decode on
            }
            // Less than a word left (the output holds a word's events, so decoding stopped for
            // want of bytes): move it to the front and read behind it.
            let kept = carry_to_front::<8>(&mut self.buf, self.start, self.end);
            (self.start, self.end) = (0, kept);
            let n = self
                .source
                .read(self.buf.get_mut(kept..).unwrap_or_default())
                .map_err(|e| EvtSourceError::Read(embedded_io::Error::kind(&e)))?;
            if n == 0 {
                return if kept == 0 {
                    Ok(0)
                } else {
                    Err(EvtSourceError::CutWord)
                };
            }
            self.end += n;
        }
    }
}

/// Boot check of [`EvtSource`] after a bad word: EVT 3.0 words (time high, row, time low, an
/// event at x = 3, a reserved word, an event at x = 4) read 7 bytes at a time give the error,
/// then the event after the bad word, then the end (the event before it, decoded in the
/// failing call, is lost, as documented).
pub fn evt_source_recovers() -> bool {
    const WORDS: [u16; 6] = [0x8000, 0x0005, 0x6001, 0x2003, 0x1000, 0x2004];
    let mut bytes = [0u8; 12];
    for (b, w) in bytes.chunks_exact_mut(2).zip(WORDS) {
        b.copy_from_slice(&w.to_le_bytes());
    }
    let trickle = Trickle {
        data: &bytes,
        step: 7,
    };
    let mut source = EvtSource::<_, 16>::new(trickle, Encoding::Evt3, Some((346, 260)));
    let mut out = [Event::default(); 16];
    let first = source.read_events(&mut out);
    let bad = matches!(
        first,
        Err(EvtSourceError::Decode(EvtError::ReservedType {
            word: 0x1000,
            ..
        }))
    );
    let after =
        matches!(source.read_events(&mut out), Ok(1)) && out[0] == Event::new(4, 5, 1, false);
    bad && after && matches!(source.read_events(&mut out), Ok(0))
}

/// The byte index of the word an [`EvtError`] names.
fn error_at(e: EvtError) -> usize {
    match e {
        EvtError::ReservedType { at, .. }
        | EvtError::OutsideSensor { at, .. }
        | EvtError::WideX { at, .. }
        | EvtError::TimeOverflow { at } => at,
    }
}

/// A byte source that returns at most `step` bytes per read, so that words straddle reads.
struct Trickle<'a> {
    data: &'a [u8],
    step: usize,
}

impl embedded_io::ErrorType for Trickle<'_> {
    type Error = core::convert::Infallible;
}

impl Read for Trickle<'_> {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = self.step.min(buf.len()).min(self.data.len());
        let (head, rest) = self.data.split_at(n);
        for (b, &d) in buf.iter_mut().zip(head) {
            *b = d;
        }
        self.data = rest;
        Ok(n)
    }
}

/// The `EVS1` stream's events that [`check_evt`] compares decoded events with, times from
/// each stream's first event.
struct Expected {
    reader: EvsReader<&'static [u8]>,
    /// The first decoded event's time and the stream's.
    first: Option<(i64, i64)>,
}

impl Expected {
    fn new(evs: &'static [u8]) -> Option<Self> {
        Some(Self {
            reader: EvsReader::new(evs).ok()?,
            first: None,
        })
    }

    /// Compares `events` with the stream's next ones; returns the mismatches (an event the
    /// stream does not have counts as one).
    fn compare(&mut self, events: &[Event]) -> u32 {
        let mut mismatches = 0;
        for e in events {
            let Ok(Some(want)) = self.reader.next_event() else {
                mismatches += 1;
                continue;
            };
            let (t0, want_t0) = *self.first.get_or_insert((e.t, want.t));
            if e.t - t0 != want.t - want_t0 || (e.x, e.y, e.on) != (want.x, want.y, want.on) {
                mismatches += 1;
            }
        }
        mismatches
    }
}

/// What [`check_evt`] found.
pub struct EvtCheck {
    /// Events the words gave.
    pub events: u32,
    /// Events that differ from the `EVS1` stream's (and decoding errors).
    pub mismatches: u32,
    /// Clock ticks spent in the decoder.
    pub ticks: u64,
}

/// Bytes of sensor words handed to the decoder at a time (a DMA buffer's worth); odd, so that
/// pieces end inside words and the decoder's unused tail goes back with the next piece.
const EVT_PIECE: usize = 511;

/// Boot check of the core's EVT decoder (`evpose_core::evt`, what a Prophesee sensor streams)
/// on the real instructions: `words` are the recording's first events in `encoding`, written by
/// an independent encoder (EVT 3.0: faery, `scripts/third-party-formats.py --firmware-asset`;
/// EVT 2.1 in a GenX320's byte order: evutils, `scripts/evt21-engines.py --firmware-asset`),
/// decoded [`EVT_PIECE`] bytes at a time into batches of 64 (timed) and compared with the `EVS1`
/// stream `evs` event by event (times from each stream's first event); then read again through
/// [`EvtSource`] 7 bytes per read and compared again (not timed). Fewer or more than `expected`
/// events count as a mismatch too.
pub fn check_evt(
    encoding: Encoding,
    evs: &'static [u8],
    words: &'static [u8],
    expected: u32,
) -> EvtCheck {
    let mut check = EvtCheck {
        events: 0,
        mismatches: 0,
        ticks: 0,
    };
    let Some(mut want) = Expected::new(evs) else {
        check.mismatches += 1;
        return check;
    };
    let mut decoder = EvtDecoder::new(encoding, Some((346, 260)));
    let mut batch = [Event::default(); 64];
    let mut rest = words;
    while !rest.is_empty() {
        let piece = rest.get(..EVT_PIECE.min(rest.len())).unwrap_or_default();
        let start = crate::clock::ticks();
        let decoded = decoder.decode(piece, &mut batch);
        check.ticks += crate::clock::ticks() - start;
        let Ok(p) = decoded else {
            check.mismatches += 1;
            break;
        };
        rest = rest.get(p.bytes..).unwrap_or_default();
        check.events += p.events as u32;
        check.mismatches += want.compare(batch.get(..p.events).unwrap_or_default());
        if p.bytes == 0 {
            // A cut word at the end: the words ended inside one.
            check.mismatches += 1;
            break;
        }
    }
    if check.events != expected {
        check.mismatches += 1;
    }
    // The same words through the `EventSource` a firmware would run, 7 bytes per read (words
    // straddle reads; an EVT 2.1 word spans two): the same events again.
    let (Some(mut want), mut source) = (
        Expected::new(evs),
        EvtSource::<_, 64>::new(
            Trickle {
                data: words,
                step: 7,
            },
            encoding,
            Some((346, 260)),
        ),
    ) else {
        check.mismatches += 1;
        return check;
    };
    let mut seen = 0;
    loop {
        let n = match source.read_events(&mut batch) {
            Ok(0) => break,
            Ok(n) => n,
            Err(_) => {
                check.mismatches += 1;
                break;
            }
        };
        seen += n as u32;
        check.mismatches += want.compare(batch.get(..n).unwrap_or_default());
    }
    // Every word gave its events: none dropped for want of a time base or row.
    if seen != expected || source.decoder().counts().dropped_events > 0 {
        check.mismatches += 1;
    }
    check
}

/// Words of the boot check's streams.
const CHECK_WORDS: usize = 160;

/// Boot check of [`EvsReader::read_events`] against [`EvsReader::next_event`] on streams the
/// bundled recording does not exercise: `TIME` words among the events (backward and forward;
/// in the second stream forward only, from near the largest time, until the time overflows),
/// read 1, 3, 7 and 256 bytes at a time (words straddling reads) in batches of 1, 5 and 64
/// events. Returns (cases, mismatches); a case whose overflow did not happen is a mismatch.
pub fn check_decoder() -> (u32, u32) {
    let (mut cases, mut mismatches) = (0, 0);
    for overflow in [false, true] {
        let bytes = check_stream(overflow);
        for step in [1, 3, 7, 256] {
            for batch in [1, 5, 64] {
                cases += 1;
                if same_events(&bytes, step, batch) != Some(overflow) {
                    mismatches += 1;
                }
            }
        }
    }
    (cases, mismatches)
}

/// The boot check's stream: xorshift words, every seventh a `TIME` word of up to ±2^20 µs
/// (with `overflow`: forward only, from `i64::MAX − 2^22`).
fn check_stream(overflow: bool) -> [u8; HEADER_LEN + 4 * CHECK_WORDS] {
    let mut bytes = [0u8; HEADER_LEN + 4 * CHECK_WORDS];
    let mut state = 0x2545_F491u32;
    let mut events = 0u32;
    for (i, word) in bytes
        .get_mut(HEADER_LEN..)
        .unwrap_or_default()
        .as_chunks_mut::<4>()
        .0
        .iter_mut()
        .enumerate()
    {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let w = if i % 7 == 3 {
            let step = if overflow {
                (state % (1 << 20)) as i32
            } else {
                (state % (1 << 21)) as i32 - (1 << 20)
            };
            TIME_BIT | step as u32 & !TIME_BIT
        } else {
            events += 1;
            state & !TIME_BIT
        };
        *word = w.to_le_bytes();
    }
    let t0: i64 = if overflow {
        i64::MAX - (1 << 22)
    } else {
        1_589_163_147_368_868
    };
    let mut h = [0u8; HEADER_LEN];
    for (at, field) in [
        (0, &MAGIC[..]),
        (4, &2048u16.to_le_bytes()[..]),
        (6, &1024u16.to_le_bytes()[..]),
        (8, &events.to_le_bytes()[..]),
        (16, &t0.to_le_bytes()[..]),
    ] {
        for (b, &v) in h.iter_mut().skip(at).zip(field) {
            *b = v;
        }
    }
    for (b, &v) in bytes.iter_mut().zip(&h) {
        *b = v;
    }
    bytes
}

/// Whether batches of `batch` from [`EvsReader::read_events`] give the events and the end of
/// [`EvsReader::next_event`] one by one, both reading `step` bytes at a time: `Some(false)`
/// where both end cleanly, `Some(true)` where both fail with the same error after the same
/// events (a batch that fails returns none of its events), `None` where they differ.
fn same_events(bytes: &[u8], step: usize, batch: usize) -> Option<bool> {
    let mut one = EvsReader::new(Trickle { data: bytes, step }).ok()?;
    let mut many = EvsReader::new(Trickle { data: bytes, step }).ok()?;
    let mut out = [Event::default(); 64];
    loop {
        let got = match many.read_events(out.get_mut(..batch).unwrap_or_default()) {
            Ok(n) => out.get(..n).unwrap_or_default(),
            // The failing batch's events come first from `one`: fewer than a batch.
            Err(e) => {
                for _ in 0..batch {
                    match one.next_event() {
                        Ok(Some(_)) => {}
                        r => return (r == Err(e)).then_some(true),
                    }
                }
                return None;
            }
        };
        if got.is_empty() {
            return (one.next_event() == Ok(None)).then_some(false);
        }
        for e in got {
            if one.next_event() != Ok(Some(*e)) {
                return None;
            }
        }
    }
}

//! Event input: a sensor-agnostic [`EventSource`] trait and the `EVS1` byte-stream decoder.
//!
//! # Why a byte stream behind `embedded_io::Read`
//! Event sensors reach an MCU as a byte stream: a serial link (UART, SPI slave with DMA) or a
//! parallel port feeding a DMA ring. `embedded_io::Read` is the embedded-hal family's byte-stream
//! trait, and HAL UART drivers implement it (embassy's `BufferedUart`, for one). So
//! [`EvsReader`] decodes from any `R: embedded_io::Read`: on a board `R` is the driver; under
//! QEMU it is the recording in flash, a plain `&'static [u8]` (which implements `Read` too). The
//! pipeline sees only [`EventSource`], a batch interface shaped like a DMA half-buffer, so a
//! sensor with its own framing (a parallel port, an on-chip event decoder) only needs another
//! `EventSource` implementation.
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
        let pending = self.buf.get(self.start..self.end).unwrap_or_default();
        let mut carry = [0u8; 4];
        let kept = pending.len().min(carry.len());
        for (c, &b) in carry.iter_mut().zip(pending) {
            *c = b;
        }
        for (b, &c) in self.buf.iter_mut().zip(&carry).take(kept) {
            *b = c;
        }
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

    fn step(&mut self, dt: i64) -> Result<(), StreamError> {
        self.time = self.time.checked_add(dt).ok_or(StreamError::TimeOverflow)?;
        Ok(())
    }

    /// The next event, or `None` after the last one.
    pub fn next_event(&mut self) -> Result<Option<Event>, StreamError> {
        if self.remaining == 0 {
            return Ok(None);
        }
        loop {
            let w = self.next_word()?;
            if w & TIME_BIT != 0 {
                // Sign-extend the 31-bit step.
                self.step(i64::from(((w << 1) as i32) >> 1))?;
                continue;
            }
            self.step(i64::from(w >> DT_SHIFT & DT_MASK))?;
            self.remaining -= 1;
            return Ok(Some(Event::new(
                (w & X_MASK) as u16,
                (w >> Y_SHIFT & Y_MASK) as u16,
                self.time,
                w >> P_SHIFT & 1 == 1,
            )));
        }
    }
}

impl<R: Read> EventSource for EvsReader<R> {
    type Error = StreamError;

    fn read_events(&mut self, out: &mut [Event]) -> Result<usize, StreamError> {
        let mut n = 0;
        for slot in out.iter_mut() {
            match self.next_event()? {
                Some(e) => *slot = e,
                None => break,
            }
            n += 1;
        }
        Ok(n)
    }
}

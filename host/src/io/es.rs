//! Event Stream (`.es`, version 2): the format of Sepia, Tarsier, Command Line Tools and faery
//! (github.com/neuromorphic-paris/event_stream), DVS and ATIS streams.
//!
//! # Layout
//!
//! ```text
//! "Event Stream"                         12 bytes
//! u8 major, minor, patch                 version 2.x.y
//! u8 type                                1 DVS, 2 ATIS (0 generic, 3 display, 4 color: refused)
//! u16 LE width, u16 LE height
//! events: one byte of time and polarity, then u16 LE x and u16 LE y; times are differences
//! ```
//!
//! DVS byte 0: bits 1–7 the microseconds since the previous event, bit 0 `is_increase` (ON);
//! `0xFF` alone is an overflow (127 µs more before the next event), `0xFE` alone a reset byte
//! (skipped). ATIS byte 0: bits 2–7 the microseconds since the previous event, bit 1 the
//! polarity, bit 0 `is_tc`; a byte with bits 2–7 set is an overflow of 63 µs times its two low
//! bits (`0xFC`, zero, is the reset byte). ATIS threshold crossings (`is_tc`, half of an
//! exposure measurement) carry no polarity change: they are skipped and counted in
//! [`ReadNotes::skipped_records`]; their time differences still count. The first event's
//! difference is from time 0.
//!
//! Rows count from the bottom of the sensor (as Sepia and Tarsier draw them, and as faery
//! writes and reads them): the reader gives `y = height − 1 − y_file`, the top-left origin of
//! every other format here.
//! # Damage
//!
//! A version other than 2 and another stream type are `Unsupported` errors; a zero sensor
//! size, a pixel outside the sensor and a file that ends inside an event are errors naming
//! the byte offset.

use std::io::Read;

use evpose_core::Event;

use super::source::{out_of_sensor, Source};
use super::{Batch, CameraInfo, Format, ReadError, ReadNotes, StreamInfo, BATCH_EVENTS};

/// The file's first bytes.
pub const MAGIC: &[u8; 12] = b"Event Stream";

/// Bytes of the header: magic, version, type, width and height.
const HEADER_BYTES: usize = 20;

/// Bytes of one event.
const EVENT_BYTES: usize = 5;

/// The stream types read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Dvs,
    Atis,
}

/// Streaming Event Stream reader.
pub struct EsReader<R> {
    src: Source<R>,
    info: StreamInfo,
    kind: Kind,
    size: (u16, u16),
    /// Time of the last event (µs), overflows included.
    t: i64,
    notes: ReadNotes,
    finished: bool,
}

impl<R: Read> EsReader<R> {
    /// Parses the header (the file states its sensor size).
    pub fn new(inner: R) -> Result<Self, ReadError> {
        let mut src = Source::new(inner, 0);
        // The magic, version and type first: a generic stream has no size to read.
        let have = src.fill(HEADER_BYTES)?;
        if have < 16 {
            return Err(ReadError::Truncated {
                offset: 0,
                what: "the Event Stream header",
            });
        }
        let h = &src.data()[..have.min(HEADER_BYTES)];
        if &h[..12] != MAGIC {
            return Err(ReadError::Corrupt {
                offset: 0,
                message: "no `Event Stream` magic".into(),
            });
        }
        if h[12] != 2 {
            return Err(ReadError::Unsupported(format!(
                "Event Stream version {}.{}.{}; version 2 is read",
                h[12], h[13], h[14]
            )));
        }
        let kind = match h[15] {
            1 => Kind::Dvs,
            2 => Kind::Atis,
            t => {
                let name = match t {
                    0 => "generic",
                    3 => "display",
                    4 => "color",
                    _ => "unknown",
                };
                return Err(ReadError::Unsupported(format!(
                    "Event Stream of {name} events (type {t}); DVS (1) and ATIS (2) streams \
                     are read"
                )));
            }
        };
        if h.len() < HEADER_BYTES {
            return Err(ReadError::Truncated {
                offset: 16,
                what: "the Event Stream sensor size",
            });
        }
        let size = (
            u16::from_le_bytes([h[16], h[17]]),
            u16::from_le_bytes([h[18], h[19]]),
        );
        if size.0 == 0 || size.1 == 0 {
            return Err(ReadError::Corrupt {
                offset: 16,
                message: format!("sensor size {} x {}", size.0, size.1),
            });
        }
        src.consume(HEADER_BYTES);
        Ok(Self {
            src,
            info: StreamInfo {
                format: Format::Es,
                cameras: vec![CameraInfo {
                    id: 0,
                    width: Some(size.0),
                    height: Some(size.1),
                    name: None,
                }],
                event_count: None,
            },
            kind,
            size,
            t: 0,
            notes: ReadNotes::default(),
            finished: false,
        })
    }

    fn fill(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        while batch.len() < BATCH_EVENTS {
            let have = self.src.fill(EVENT_BYTES)?;
            if have == 0 {
                self.finished = true;
                return Ok(());
            }
            let base = self.src.offset();
            let used = self.decode(base, have, batch)?;
            if used == 0 {
                // Fewer bytes than an event, and no more to come (with five or more, an event
                // or an overflow byte is always used).
                return Err(ReadError::Truncated {
                    offset: base,
                    what: "an Event Stream event",
                });
            }
            self.src.consume(used);
        }
        Ok(())
    }

    /// Decodes the whole events among the first `have` buffered bytes (file offset `base`)
    /// until the batch is full; returns the bytes used.
    fn decode(&mut self, base: u64, have: usize, batch: &mut Batch) -> Result<usize, ReadError> {
        let data = &self.src.data()[..have];
        let (w, h) = self.size;
        let mut i = 0;
        while i < data.len() && batch.len() < BATCH_EVENTS {
            let b = data[i];
            // Overflow and reset bytes: (µs to add, whether the byte is one).
            let (step, alone) = match self.kind {
                Kind::Dvs => match b {
                    0xFF => (127, true),
                    0xFE => (0, true),
                    _ => (i64::from(b >> 1), false),
                },
                Kind::Atis if b & 0xFC == 0xFC => (63 * i64::from(b & 3), true),
                Kind::Atis => (i64::from(b >> 2), false),
            };
            if alone {
                self.t += step;
                i += 1;
                continue;
            }
            let Some(e) = data.get(i..i + EVENT_BYTES) else {
                break;
            };
            let x = u16::from_le_bytes([e[1], e[2]]);
            let y = u16::from_le_bytes([e[3], e[4]]);
            if x >= w || y >= h {
                return Err(out_of_sensor(base + i as u64, x.into(), y.into(), (w, h)));
            }
            self.t += step;
            // Event Stream rows count from the bottom.
            let y = h - 1 - y;
            match self.kind {
                Kind::Dvs => batch.push(0, Event::new(x, y, self.t, b & 1 == 1)),
                Kind::Atis if b & 1 == 1 => self.notes.skipped_records += 1,
                Kind::Atis => batch.push(0, Event::new(x, y, self.t, b & 2 == 2)),
            }
            i += EVENT_BYTES;
        }
        Ok(i)
    }
}

impl<R: Read> super::source::Fill for EsReader<R> {
    fn info(&self) -> &StreamInfo {
        &self.info
    }
    fn notes(&self) -> ReadNotes {
        self.notes.clone()
    }
    fn fill_batch(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        self.fill(batch)
    }
    fn finished(&mut self) -> &mut bool {
        &mut self.finished
    }
}

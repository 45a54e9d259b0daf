//! Prophesee `.dat` files of CD (change detection) events.
//!
//! # Layout
//!
//! ```text
//! "% …\n" header lines: "% Data file containing CD events.", "% Version 2", "% Date …",
//!                       "% Height 720", "% Width 1280", …
//! u8 event type (0x00 Event2D, 0x0C CD), u8 event size (8)     only when there is a header
//! 8-byte LE records: u32 t (µs), u32 with x = bits 0–13, y = bits 14–27, polarity = bits 28–31
//! ```
//!
//! `% Version 1` files (older ATIS sensors, up to 512 × 256) pack the second word as x = bits
//! 0–8, y = bits 9–16, polarity = bit 17 (bits 18–31 ignored, as Prophesee's `readATIS_td`
//! masks them; faery writes bits 17–20); version 2 and later, and files without a version
//! line, use the layout above.
//!
//! As Prophesee's `psee_loader` does, the header ends at the first line that does not start
//! with `%`, and a file without any header line has no type/size bytes either. The sensor size
//! comes from the `Width`/`Height` (or `geometry`) lines, else from `--width/--height`.
//!
//! # Damage and recovery
//!
//! Timestamps are a 32-bit counter: a step back by more than 2³¹ µs is a wrap, counted in
//! [`ReadNotes::timestamp_wraps`]. Errors: a file of other events (0x0E external triggers, …)
//! or other record sizes, `% Version 0` or a version that is not a number, a polarity other
//! than 0 or 1, a pixel outside a known sensor, and a file that ends inside a record, each
//! naming the offset.

use std::io::Read;

use evpose_core::Event;

use super::evt::PercentHeader;
use super::source::{out_of_sensor, time_overflow, Source, Unwrapper};
use super::{Batch, CameraInfo, Format, ReadError, ReadNotes, StreamInfo, BATCH_EVENTS};

/// Bytes per record.
pub const RECORD_BYTES: usize = 8;

/// Where a record's second word keeps x, y and the polarity.
#[derive(Clone, Copy)]
struct Layout {
    x_mask: u32,
    y_shift: u32,
    y_mask: u32,
    p_shift: u32,
    p_mask: u32,
}

impl Layout {
    /// `% Version 1`: 9-bit x, 8-bit y, polarity in bit 17.
    const V1: Self = Self {
        x_mask: 0x1FF,
        y_shift: 9,
        y_mask: 0xFF,
        p_shift: 17,
        p_mask: 1,
    };
    /// Version 2 and later: 14-bit x and y, polarity in the top four bits.
    const V2: Self = Self {
        x_mask: 0x3FFF,
        y_shift: 14,
        y_mask: 0x3FFF,
        p_shift: 28,
        p_mask: 0xF,
    };
}

/// Streaming `.dat` reader.
pub struct DatReader<R> {
    src: Source<R>,
    info: StreamInfo,
    size: Option<(u16, u16)>,
    layout: Layout,
    time: Unwrapper,
    notes: ReadNotes,
    finished: bool,
}

impl<R: Read> DatReader<R> {
    /// Parses the header and the event type; `size` is the fallback sensor size.
    pub fn new(inner: R, size: Option<(u16, u16)>) -> Result<Self, ReadError> {
        let mut src = Source::new(inner, 0);
        let header = PercentHeader::read(&mut src, false)?;
        let mut notes = ReadNotes::default();
        let layout = match header.get("version").map(|v| (v, v.parse::<u32>())) {
            None => Layout::V2,
            Some((_, Ok(1))) => Layout::V1,
            Some((_, Ok(v))) if v >= 2 => Layout::V2,
            Some((v, _)) => {
                return Err(ReadError::Unsupported(format!(
                    "DAT version {v:?}; versions 1 and later are read"
                )))
            }
        };
        if header.lines.is_empty() {
            notes
                .assumptions
                .push("no header: 8-byte CD records from the first byte".into());
        } else {
            let at = src.offset();
            if src.fill(2)? < 2 {
                return Err(ReadError::Truncated {
                    offset: at,
                    what: "the DAT event type and size",
                });
            }
            let (ty, bytes) = (src.data()[0], src.data()[1]);
            match ty {
                0x00 | 0x0C => {}
                0x0E => {
                    return Err(ReadError::Unsupported(
                        "DAT file of external-trigger events (type 0x0e); only CD events are read"
                            .into(),
                    ))
                }
                _ => {
                    return Err(ReadError::Unsupported(format!(
                        "DAT event type {ty:#04x}; only CD events (0x00, 0x0c) are read"
                    )))
                }
            }
            if usize::from(bytes) != RECORD_BYTES {
                return Err(ReadError::Corrupt {
                    offset: at + 1,
                    message: format!("DAT event size {bytes}; CD events are 8 bytes"),
                });
            }
            src.consume(2);
        }
        let size = match header.size() {
            Some(s) => Some(s),
            None => {
                if let Some((w, h)) = size {
                    notes
                        .assumptions
                        .push(format!("sensor size {w}x{h} from --width/--height"));
                }
                size
            }
        };
        Ok(Self {
            src,
            info: StreamInfo {
                format: Format::Dat,
                cameras: vec![CameraInfo {
                    id: 0,
                    width: size.map(|s| s.0),
                    height: size.map(|s| s.1),
                    name: None,
                }],
                event_count: None,
            },
            size,
            layout,
            time: Unwrapper::new(32),
            notes,
            finished: false,
        })
    }

    fn fill(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        while batch.len() < BATCH_EVENTS {
            let have = self.src.fill(RECORD_BYTES)?;
            if have < RECORD_BYTES {
                if have == 0 {
                    self.finished = true;
                    return Ok(());
                }
                return Err(ReadError::Truncated {
                    offset: self.src.offset(),
                    what: "a DAT event record",
                });
            }
            let n = (have / RECORD_BYTES).min(BATCH_EVENTS - batch.len());
            let base = self.src.offset();
            let records = &self.src.data()[..n * RECORD_BYTES];
            batch.events.reserve(n);
            batch.cameras.reserve(n);
            for (i, r) in records.chunks_exact(RECORD_BYTES).enumerate() {
                let ts = u32::from_le_bytes([r[0], r[1], r[2], r[3]]);
                let w = u32::from_le_bytes([r[4], r[5], r[6], r[7]]);
                let offset = base + (i * RECORD_BYTES) as u64;
                let l = self.layout;
                let x = w & l.x_mask;
                let y = (w >> l.y_shift) & l.y_mask;
                let p = (w >> l.p_shift) & l.p_mask;
                if p > 1 {
                    return Err(ReadError::Corrupt {
                        offset,
                        message: format!("polarity {p} (expected 0 or 1)"),
                    });
                }
                if let Some((sw, sh)) = self.size {
                    if x >= u32::from(sw) || y >= u32::from(sh) {
                        return Err(out_of_sensor(offset, x, y, (sw, sh)));
                    }
                }
                let t = self
                    .time
                    .unwrap(u64::from(ts))
                    .ok_or_else(|| time_overflow(offset))?;
                batch.push(0, Event::new(x as u16, y as u16, t, p == 1));
            }
            self.src.consume(n * RECORD_BYTES);
        }
        Ok(())
    }
}

impl<R: Read> super::source::Fill for DatReader<R> {
    fn info(&self) -> &StreamInfo {
        &self.info
    }
    fn notes(&self) -> ReadNotes {
        ReadNotes {
            timestamp_wraps: self.time.wraps(),
            ..self.notes.clone()
        }
    }
    fn fill_batch(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        self.fill(batch)
    }
    fn finished(&mut self) -> &mut bool {
        &mut self.finished
    }
}

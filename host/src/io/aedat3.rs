//! cAER / libcaer AEDAT 3.1: polarity events of one or more sources.
//!
//! # Layout
//!
//! ```text
//! "#!AER-DAT3.1\r\n"
//! "#Format: RAW\r\n", "#Source N: NAME\r\n" (one per source), "#Start-Time: …\r\n", …
//! "#!END-HEADER\r\n"
//! packets until EOF:
//!     28-byte LE header: i16 eventType, i16 eventSource, i32 eventSize, i32 eventTSOffset,
//!                        i32 eventTSOverflow, i32 eventCapacity, i32 eventNumber, i32 eventValid
//!     eventCapacity × eventSize bytes of events (the first eventNumber are used)
//! polarity event (type 1, 8 bytes): u32 LE data, i32 LE timestamp
//!     data: bit 0 valid, bit 1 polarity (1 = ON), y = bits 2–16, x = bits 17–31
//!     time (µs) = eventTSOverflow << 31 | timestamp
//! ```
//!
//! libcaer's origin is top-left, as [`Event`]'s; coordinates are kept as they are.
//!
//! # Cameras
//!
//! Each `#Source N: NAME` line declares a camera; camera ids are given in header order (the
//! first source is camera 0). A packet from an undeclared source declares a new camera. The
//! sensor size comes from the source name (DAVIS346, DAVIS240, DVS128, DVXplorer, …), else from
//! `--width/--height`, else is unknown.
//!
//! # Damage and recovery
//!
//! Packets of other event types (0–13: special, frame, IMU, …) are skipped whole and counted
//! ([`ReadNotes::skipped_packets`]); events whose valid bit is clear are skipped and counted
//! ([`ReadNotes::skipped_records`]). Errors, each naming the packet's (or event's) offset: an
//! unknown packet type (outside 0–13), a header field out of range (negative counts, more
//! events than capacity, a polarity packet whose events are not 8 bytes, a packet over
//! [`MAX_PACKET_BYTES`]), a negative timestamp, a pixel outside a known sensor, a header without
//! `#!END-HEADER`, and a file that ends inside a packet.

use std::io::Read;

use evpose_core::Event;

use super::source::{known_sensor_size, out_of_sensor, Source};
use super::{Batch, CameraInfo, Format, ReadError, ReadNotes, StreamInfo, BATCH_EVENTS};

/// Bytes of a packet header.
pub const PACKET_HEADER_BYTES: usize = 28;

/// Largest packet payload accepted (eventCapacity × eventSize), in bytes.
pub const MAX_PACKET_BYTES: u64 = 256 << 20;

/// Highest libcaer event type (`MATRIX4x4_EVENT`).
pub const MAX_EVENT_TYPE: i16 = 13;

/// libcaer's `POLARITY_EVENT` type.
pub const POLARITY_EVENT: i16 = 1;

/// Bytes of a polarity event.
const EVENT_BYTES: usize = 8;

/// The polarity packet being read.
struct Packet {
    start: u64,
    camera: u8,
    size: Option<(u16, u16)>,
    /// `eventTSOverflow << 31`.
    overflow: i64,
    /// Events of `eventNumber` not yet read.
    left: u64,
    /// Bytes after the used events (unused capacity).
    tail: u64,
}

/// Streaming AEDAT 3.1 reader.
pub struct Aedat3Reader<R> {
    src: Source<R>,
    info: StreamInfo,
    /// Source id of each camera.
    sources: Vec<i16>,
    fallback: Option<(u16, u16)>,
    packet: Option<Packet>,
    notes: ReadNotes,
    finished: bool,
}

impl<R: Read> Aedat3Reader<R> {
    /// Parses the header; `size` is the sensor size for sources whose name does not give one.
    pub fn new(inner: R, size: Option<(u16, u16)>) -> Result<Self, ReadError> {
        let mut src = Source::new(inner, 0);
        let declared = read_header(&mut src)?;
        let mut reader = Self {
            src,
            info: StreamInfo {
                format: Format::Aedat3,
                cameras: Vec::new(),
                event_count: None,
            },
            sources: Vec::new(),
            fallback: size,
            packet: None,
            notes: ReadNotes::default(),
            finished: false,
        };
        for (id, name) in declared {
            reader.add_camera(id, Some(name), 0)?;
        }
        Ok(reader)
    }

    fn add_camera(&mut self, source: i16, name: Option<String>, at: u64) -> Result<u8, ReadError> {
        let id = u8::try_from(self.sources.len()).map_err(|_| ReadError::Corrupt {
            offset: at,
            message: "more than 256 sources".into(),
        })?;
        let size = name
            .as_deref()
            .and_then(known_sensor_size)
            .or(self.fallback);
        self.sources.push(source);
        self.info.cameras.push(CameraInfo {
            id,
            width: size.map(|s| s.0),
            height: size.map(|s| s.1),
            name,
        });
        Ok(id)
    }

    /// Reads packet headers until a polarity packet; `false` at the end of the file.
    fn next_packet(&mut self) -> Result<bool, ReadError> {
        loop {
            let start = self.src.offset();
            let have = self.src.fill(PACKET_HEADER_BYTES)?;
            if have == 0 {
                return Ok(false);
            }
            if have < PACKET_HEADER_BYTES {
                return Err(ReadError::Truncated {
                    offset: start,
                    what: "an AEDAT 3.1 packet header",
                });
            }
            let h = PacketHeader::parse(&self.src.data()[..PACKET_HEADER_BYTES]);
            let payload = h.check(start)?;
            self.src.consume(PACKET_HEADER_BYTES);
            if h.event_type != POLARITY_EVENT {
                if self.src.skip(payload)? < payload {
                    return Err(ReadError::Truncated {
                        offset: start,
                        what: "an AEDAT 3.1 packet",
                    });
                }
                self.notes.skipped_packets += 1;
                continue;
            }
            if h.event_size != EVENT_BYTES as i32 || h.ts_offset != 4 {
                return Err(ReadError::Corrupt {
                    offset: start,
                    message: format!(
                        "polarity packet with eventSize {} and eventTSOffset {} (expected 8 and 4)",
                        h.event_size, h.ts_offset
                    ),
                });
            }
            let camera = match self.sources.iter().position(|&s| s == h.source) {
                Some(i) => i as u8,
                None => self.add_camera(h.source, None, start)?,
            };
            let info = &self.info.cameras[usize::from(camera)];
            self.packet = Some(Packet {
                start,
                camera,
                size: info.width.zip(info.height),
                overflow: i64::from(h.ts_overflow) << 31,
                left: h.number as u64,
                tail: (h.capacity - h.number) as u64 * EVENT_BYTES as u64,
            });
            return Ok(true);
        }
    }

    /// Moves events of the current packet into `batch`.
    fn drain(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        let Some(p) = self.packet.as_mut() else {
            return Ok(());
        };
        while p.left > 0 && batch.len() < BATCH_EVENTS {
            let have = self.src.fill(EVENT_BYTES)?;
            if have < EVENT_BYTES {
                return Err(ReadError::Truncated {
                    offset: p.start,
                    what: "an AEDAT 3.1 polarity packet",
                });
            }
            let n = (have / EVENT_BYTES)
                .min(usize::try_from(p.left).unwrap_or(usize::MAX))
                .min(BATCH_EVENTS - batch.len());
            let base = self.src.offset();
            let bytes = &self.src.data()[..n * EVENT_BYTES];
            for (i, e) in bytes.chunks_exact(EVENT_BYTES).enumerate() {
                let data = u32::from_le_bytes([e[0], e[1], e[2], e[3]]);
                let ts = i32::from_le_bytes([e[4], e[5], e[6], e[7]]);
                if data & 1 == 0 {
                    self.notes.skipped_records += 1;
                    continue;
                }
                let offset = base + (i * EVENT_BYTES) as u64;
                if ts < 0 {
                    return Err(ReadError::Corrupt {
                        offset,
                        message: format!("negative event timestamp {ts}"),
                    });
                }
                let x = data >> 17;
                let y = (data >> 2) & 0x7FFF;
                if let Some((w, h)) = p.size {
                    if x >= u32::from(w) || y >= u32::from(h) {
                        return Err(out_of_sensor(offset, x, y, (w, h)));
                    }
                }
                let t = p.overflow | i64::from(ts);
                batch.push(p.camera, Event::new(x as u16, y as u16, t, data & 2 != 0));
            }
            self.src.consume(n * EVENT_BYTES);
            p.left -= n as u64;
        }
        if p.left == 0 {
            if self.src.skip(p.tail)? < p.tail {
                return Err(ReadError::Truncated {
                    offset: p.start,
                    what: "an AEDAT 3.1 polarity packet",
                });
            }
            self.packet = None;
        }
        Ok(())
    }

    fn fill(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        while batch.len() < BATCH_EVENTS {
            if self.packet.is_some() {
                self.drain(batch)?;
            } else if !self.next_packet()? {
                self.finished = true;
                break;
            }
        }
        Ok(())
    }
}

/// The fields of a packet header.
struct PacketHeader {
    event_type: i16,
    source: i16,
    event_size: i32,
    ts_offset: i32,
    ts_overflow: i32,
    capacity: i32,
    number: i32,
    valid: i32,
}

impl PacketHeader {
    fn parse(b: &[u8]) -> Self {
        let i16_at = |i: usize| i16::from_le_bytes([b[i], b[i + 1]]);
        let i32_at = |i: usize| i32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        Self {
            event_type: i16_at(0),
            source: i16_at(2),
            event_size: i32_at(4),
            ts_offset: i32_at(8),
            ts_overflow: i32_at(12),
            capacity: i32_at(16),
            number: i32_at(20),
            valid: i32_at(24),
        }
    }

    /// Checks the fields; returns the payload size in bytes.
    fn check(&self, offset: u64) -> Result<u64, ReadError> {
        let bad = |message: String| Err(ReadError::Corrupt { offset, message });
        if !(0..=MAX_EVENT_TYPE).contains(&self.event_type) {
            return bad(format!("unknown packet type {}", self.event_type));
        }
        if self.source < 0 {
            return bad(format!("negative event source {}", self.source));
        }
        if self.event_size <= 0 || self.ts_offset < 0 || self.ts_offset > self.event_size - 4 {
            return bad(format!(
                "eventSize {} / eventTSOffset {} out of range",
                self.event_size, self.ts_offset
            ));
        }
        if self.ts_overflow < 0 {
            return bad(format!("negative eventTSOverflow {}", self.ts_overflow));
        }
        if self.capacity < 0
            || !(0..=self.capacity).contains(&self.number)
            || !(0..=self.number).contains(&self.valid)
        {
            return bad(format!(
                "event counts out of range (capacity {}, number {}, valid {})",
                self.capacity, self.number, self.valid
            ));
        }
        let payload = self.capacity as u64 * self.event_size as u64;
        if payload > MAX_PACKET_BYTES {
            return bad(format!(
                "packet of {payload} bytes exceeds {MAX_PACKET_BYTES}"
            ));
        }
        Ok(payload)
    }
}

/// Reads the header lines; returns the declared sources in order.
fn read_header<R: Read>(src: &mut Source<R>) -> Result<Vec<(i16, String)>, ReadError> {
    let Some(first) = src.header_line(0)? else {
        return Err(ReadError::Truncated {
            offset: 0,
            what: "the AEDAT 3.1 header",
        });
    };
    match first.strip_prefix("#!AER-DAT").map(str::trim) {
        Some("3.1") => {}
        Some(v) => {
            return Err(ReadError::Unsupported(format!(
                "AEDAT version {v:?} read as 3.1; use the format that matches the file"
            )))
        }
        None => {
            return Err(ReadError::Corrupt {
                offset: 0,
                message: "not an AEDAT 3.1 file: the first line is not #!AER-DAT3.1".into(),
            })
        }
    }
    let mut sources: Vec<(i16, String)> = Vec::new();
    loop {
        let at = src.offset();
        match src.peek()? {
            Some(b'#') => {}
            Some(_) => {
                return Err(ReadError::Corrupt {
                    offset: at,
                    message: "the header ends without #!END-HEADER".into(),
                })
            }
            None => {
                return Err(ReadError::Truncated {
                    offset: at,
                    what: "the AEDAT 3.1 header (no #!END-HEADER)",
                })
            }
        }
        let Some(line) = src.header_line(0)? else {
            continue;
        };
        let line = line.trim();
        if line == "#!END-HEADER" {
            return Ok(sources);
        }
        if let Some(format) = line.strip_prefix("#Format:") {
            let format = format.trim();
            if !format.eq_ignore_ascii_case("RAW") {
                return Err(ReadError::Unsupported(format!(
                    "AEDAT 3.1 data format {format:?}; only RAW is read"
                )));
            }
        } else if let Some(rest) = line.strip_prefix("#Source ") {
            let (id, name) = rest.split_once(':').ok_or_else(|| ReadError::Corrupt {
                offset: at,
                message: format!("malformed source line {line:?}"),
            })?;
            let id: i16 = id.trim().parse().map_err(|_| ReadError::Corrupt {
                offset: at,
                message: format!("malformed source id in {line:?}"),
            })?;
            if !sources.iter().any(|(s, _)| *s == id) {
                sources.push((id, name.trim().to_string()));
            }
        }
    }
}

impl<R: Read> super::source::Fill for Aedat3Reader<R> {
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

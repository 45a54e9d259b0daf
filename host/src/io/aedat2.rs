//! jAER AEDAT 2.0, including the DHP19 four-camera recordings.
//!
//! # Layout
//!
//! ```text
//! "#!AER-DAT2.0\r\n"
//! more "#…\r\n" header lines (comments, "# AEChip: <Java class>", often jAER's preferences XML),
//!     optionally ending with "#End Of ASCII Header\r\n"
//! 8-byte records until EOF: u32 BE address, u32 BE timestamp (µs)
//! ```
//!
//! The header ends after `#End Of ASCII Header`, or at the first line that does not start with
//! `#` (as jAER and its MATLAB and Python readers decide) or that holds control bytes (binary
//! records whose first address byte happens to be `#` = 0x23). Header parsing is bounded:
//! [`MAX_HEADER_BYTES`](super::MAX_HEADER_BYTES) in all, lines of at most
//! [`MAX_HEADER_LINE_BYTES`](super::MAX_HEADER_LINE_BYTES).
//!
//! # Which sensor
//!
//! The address layout depends on the sensor, which the file names only in its `# AEChip:` line
//! (a Java class such as `eu.seebetter.ini.chips.davis.DAVIS346B`; DHP19 files say
//! `MultiDavis346BCameraChip`). With `--format aedat2` (what detection gives) the reader takes
//! the sensor from that line, matching the class name case-insensitively:
//!
//! | class name contains | sensor |
//! |---|---|
//! | `multidavis346` | DHP19: four DAVIS346 cameras, [`Format::Aedat2Dhp19`] |
//! | `dvs128`, `tmpdiff128` | DVS128 layout, [`Format::Aedat2Dvs128`] |
//! | `davis346` / `davis240`, `sbret1x`/`sbret2x` | DAVIS layout, 346 × 260 / 240 × 180 |
//! | `davis128`, `davis208`, `davis640` | DAVIS layout, 128 × 128 / 208 × 192 / 640 × 480 |
//! | other `davis` | DAVIS layout; the size must come from `--width/--height` |
//!
//! A file without a recognisable `AEChip` line is refused (guessing the layout would misread
//! it silently); `--format aedat2-davis346|aedat2-davis240|aedat2-dvs128|aedat2-dhp19` states
//! the sensor and overrides the header (the disagreement is recorded in
//! [`ReadNotes::assumptions`]). With an explicit sensor a file may also lack the header.
//!
//! # Addresses
//!
//! * DAVIS (jAER `DavisBaseCamera`): bit 31 = 1 is an APS or IMU sample, bit 10 = 1 a special
//!   event; both clear is a polarity event with y_raw = bits 22–30, x_raw = bits 12–21, ON =
//!   bit 11. jAER decodes `x = width − 1 − x_raw` (`DavisEventExtractor`: `e.x = sx1 − …`) and
//!   keeps y from the bottom; this reader gives jAER's picture with [`Event`]'s top-left
//!   origin: `x = width − 1 − x_raw`, `y = height − 1 − y_raw`.
//! * DHP19: DAVIS layout, camera id = bits 0–3 (0–3; anything else is an error), x and y as
//!   for DAVIS. DHP19's frame generation (`extract_from_aedat.m`: `X = sx − x`, `y = sy −
//!   y_raw`) and its projection of the Vicon joints (P's `u`, and `v = H − v'`) use exactly
//!   this orientation, so labels projected with DHP19's P matrices land on the events.
//!   (Through stop 42 this reader kept x_raw, and on real DHP19 files the labels were mirrored
//!   left–right against the events; the simulator wrote the same mirror, so synthetic data did
//!   not show it.)
//! * DVS128 (jAER `Tmpdiff128`, libcaer `dvs128`): bits 15–31 set is a sync / special event;
//!   otherwise x = 127 − bits 1–7, and the event is ON when bit 0 is **0** (both jAER and
//!   libcaer invert the polarity bit). The row, bits 8–14, counts from the bottom as in every
//!   AEDAT 2.0 layout (iniVation's AEDAT 2.0 page: "(0, 0) in the lower left corner"; jAER keeps
//!   it so; libcaer's `dvs128.c` inverts it "to convert to CG format"): `y = 127 − row`, the
//!   top-left origin of [`Event`], as for DAVIS. (Through stop 41 this reader kept the row, and
//!   DVS128 recordings came out upside down against every other layout.)
//!
//! # Damage and recovery
//!
//! Non-polarity records are skipped and counted ([`ReadNotes::skipped_records`]). Timestamps
//! are a 32-bit counter: a step back by more than 2³¹ µs is a wrap (counted in
//! [`ReadNotes::timestamp_wraps`]) and later times get 2³² µs more each wrap. A pixel outside
//! the sensor, a DHP19 camera id above 3, and a file that ends inside a record are errors
//! naming the record's offset.

use std::io::Read;

use evpose_core::Event;

use super::source::{known_sensor_size, out_of_sensor, time_overflow, Source, Unwrapper};
use super::{Batch, CameraInfo, Format, ReadError, ReadNotes, StreamInfo, BATCH_EVENTS};

/// Bytes per record.
pub const RECORD_BYTES: usize = 8;

/// Cameras in a DHP19 recording.
pub const DHP19_CAMERAS: u8 = 4;

/// An address layout and sensor size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sensor {
    /// A DAVIS sensor of the given size (width, height).
    Davis(u16, u16),
    /// DHP19's four DAVIS346 cameras, camera id in address bits 0–3.
    Dhp19,
    /// DVS128 (128 × 128).
    Dvs128,
}

impl Sensor {
    /// Sensor size (width, height) of each camera.
    pub fn size(self) -> (u16, u16) {
        match self {
            Self::Davis(w, h) => (w, h),
            Self::Dhp19 => (346, 260),
            Self::Dvs128 => (128, 128),
        }
    }

    /// The most specific [`Format`] naming this sensor.
    pub fn format(self) -> Format {
        match self {
            Self::Davis(346, 260) => Format::Aedat2Davis346,
            Self::Davis(240, 180) => Format::Aedat2Davis240,
            Self::Davis(..) => Format::Aedat2,
            Self::Dhp19 => Format::Aedat2Dhp19,
            Self::Dvs128 => Format::Aedat2Dvs128,
        }
    }

    /// The sensor a `--format` value names, if it names one.
    pub fn of_format(format: Format) -> Option<Self> {
        match format {
            Format::Aedat2Davis346 => Some(Self::Davis(346, 260)),
            Format::Aedat2Davis240 => Some(Self::Davis(240, 180)),
            Format::Aedat2Dvs128 => Some(Self::Dvs128),
            Format::Aedat2Dhp19 => Some(Self::Dhp19),
            _ => None,
        }
    }

    /// The sensor of a jAER chip class name (the last component of the `AEChip` class).
    /// `Err` names a DAVIS whose size is unknown; `Ok(None)` is not a known sensor.
    fn of_chip_class(class: &str) -> Result<Option<Self>, ()> {
        let lower = class.to_ascii_lowercase();
        if lower.contains("multidavis346") {
            Ok(Some(Self::Dhp19))
        } else if lower.contains("dvs128") || lower.contains("tmpdiff128") {
            Ok(Some(Self::Dvs128))
        } else if lower.contains("davis") || lower.contains("sbret") {
            match known_sensor_size(&lower) {
                Some((w, h)) => Ok(Some(Self::Davis(w, h))),
                None => Err(()),
            }
        } else {
            Ok(None)
        }
    }
}

/// Streaming AEDAT 2.0 reader.
pub struct Aedat2Reader<R> {
    src: Source<R>,
    info: StreamInfo,
    sensor: Sensor,
    time: Unwrapper,
    notes: ReadNotes,
    finished: bool,
}

impl<R: Read> Aedat2Reader<R> {
    /// Parses the header. `format` is [`Format::Aedat2`] (sensor from the header) or one of
    /// the `Aedat2*` variants (sensor given); `size` is the fallback for a DAVIS of unknown
    /// size.
    pub fn new(inner: R, format: Format, size: Option<(u16, u16)>) -> Result<Self, ReadError> {
        let mut src = Source::new(inner, 0);
        let header = read_header(&mut src)?;
        let mut notes = ReadNotes::default();
        let given = Sensor::of_format(format);
        let from_header = header
            .chip
            .as_deref()
            .map(|c| (c, Sensor::of_chip_class(c)));
        let sensor = match (given, from_header) {
            (Some(s), found) => {
                notes
                    .assumptions
                    .push(format!("sensor from --format {}", format.name()));
                if let Some((class, Ok(Some(h)))) = found {
                    if h != s {
                        notes.assumptions.push(format!(
                            "the header names {class}, which --format {} overrides",
                            format.name()
                        ));
                    }
                }
                s
            }
            (None, Some((class, Ok(Some(s))))) => {
                notes
                    .assumptions
                    .push(format!("sensor from the header's AEChip line: {class}"));
                s
            }
            (None, Some((class, Err(())))) => match size {
                Some((w, h)) => {
                    notes.assumptions.push(format!(
                        "DAVIS address layout ({class}), size {w}x{h} from --width/--height"
                    ));
                    Sensor::Davis(w, h)
                }
                None => {
                    return Err(ReadError::Unsupported(format!(
                        "AEDAT 2.0 from {class}: a DAVIS of unknown size; pass --width and --height"
                    )))
                }
            },
            (None, found) => {
                let what = match found {
                    Some((class, _)) => format!("names chip {class:?}, not a known sensor"),
                    None if header.lines == 0 => "has no header".into(),
                    None => "names no sensor (no `# AEChip:` line)".into(),
                };
                return Err(ReadError::Unsupported(format!(
                    "this AEDAT 2.0 file {what}; state the address layout with --format \
                     aedat2-davis346, aedat2-davis240, aedat2-dvs128 or aedat2-dhp19"
                )));
            }
        };
        let (w, h) = sensor.size();
        let cameras = if sensor == Sensor::Dhp19 {
            (0..DHP19_CAMERAS)
                .map(|id| CameraInfo {
                    id,
                    width: Some(w),
                    height: Some(h),
                    name: Some(format!("DHP19 camera {id}")),
                })
                .collect()
        } else {
            vec![CameraInfo {
                id: 0,
                width: Some(w),
                height: Some(h),
                name: header.chip.clone(),
            }]
        };
        Ok(Self {
            src,
            info: StreamInfo {
                format: sensor.format(),
                cameras,
                event_count: None,
            },
            sensor,
            time: Unwrapper::new(32),
            notes,
            finished: false,
        })
    }

    /// The address layout in use.
    pub fn sensor(&self) -> Sensor {
        self.sensor
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
                    what: "an AEDAT 2.0 event record",
                });
            }
            let n = (have / RECORD_BYTES).min(BATCH_EVENTS - batch.len());
            let base = self.src.offset();
            let records = &self.src.data()[..n * RECORD_BYTES];
            let mut d = Decoder {
                time: &mut self.time,
                notes: &mut self.notes,
                batch,
                base,
                davis: !matches!(self.sensor, Sensor::Dvs128),
            };
            match self.sensor {
                Sensor::Davis(w, h) => d.davis::<false>(records, w, h)?,
                Sensor::Dhp19 => d.davis::<true>(records, 346, 260)?,
                Sensor::Dvs128 => d.dvs128(records)?,
            }
            self.src.consume(n * RECORD_BYTES);
        }
        Ok(())
    }
}

/// What the header says.
struct Header {
    /// Last component of the `AEChip` class.
    chip: Option<String>,
    /// Header lines read.
    lines: usize,
}

fn read_header<R: Read>(src: &mut Source<R>) -> Result<Header, ReadError> {
    let mut header = Header {
        chip: None,
        lines: 0,
    };
    if src.peek()? != Some(b'#') {
        return Ok(header);
    }
    while src.peek()? == Some(b'#') && (header.lines == 0 || src.line_is_text()?) {
        let at = src.offset();
        let Some(line) = src.header_line(0)? else {
            break;
        };
        if header.lines == 0 {
            check_version(&line)?;
        }
        header.lines += 1;
        let body = line[1..].trim();
        if body.eq_ignore_ascii_case("End Of ASCII Header") {
            break;
        }
        if let Some(class) = body.strip_prefix("AEChip:") {
            let class = class.trim();
            let base = class.rsplit('.').next().unwrap_or(class).trim();
            if base.is_empty() {
                return Err(ReadError::Corrupt {
                    offset: at,
                    message: "empty AEChip line".into(),
                });
            }
            header.chip = Some(base.to_string());
        }
    }
    Ok(header)
}

fn check_version(first: &str) -> Result<(), ReadError> {
    let Some(version) = first.strip_prefix("#!AER-DAT") else {
        return Err(ReadError::Corrupt {
            offset: 0,
            message: "not an AEDAT file: the first line is not #!AER-DAT…".into(),
        });
    };
    let version = version.trim();
    if version.starts_with("2.") {
        Ok(())
    } else if version.starts_with("1.") {
        Err(ReadError::Unsupported(
            "AEDAT 1.0 (6-byte records); only 2.0 is read here".into(),
        ))
    } else {
        Err(ReadError::Unsupported(format!(
            "AEDAT version {version:?} read as 2.0; use the format that matches the file"
        )))
    }
}

/// Decodes whole records into a batch.
struct Decoder<'a> {
    time: &'a mut Unwrapper,
    notes: &'a mut ReadNotes,
    batch: &'a mut Batch,
    /// File offset of the first record.
    base: u64,
    /// A DAVIS layout: its special events' times are kept ([`ReadNotes::special_times`]).
    davis: bool,
}

/// Why a record's address is refused.
enum Bad {
    /// `(x, y)` outside the sensor `(w, h)`.
    OutOfSensor(u32, u32, (u16, u16)),
    /// A DHP19 camera id above 3.
    Camera(u32),
}

impl Bad {
    /// The error, for the record at file offset `offset`.
    fn at(self, offset: u64) -> ReadError {
        match self {
            Bad::OutOfSensor(x, y, size) => out_of_sensor(offset, x, y, size),
            Bad::Camera(c) => ReadError::Corrupt {
                offset,
                message: format!("DHP19 camera id {c} (address bits 0-3) is above 3"),
            },
        }
    }
}

/// A record's address decoded: an event's `(camera, x, y, on)`, or `None` for a record that is
/// not a polarity event (skipped and counted).
type Address = Result<Option<(u8, u16, u16, bool)>, Bad>;

/// A DAVIS special (trigger) event: bit 31 (APS/IMU) clear, bit 10 set (DHP19's
/// `ImportAedatDataVersion1or2.m`: `~apsOrImuLogical & signalOrSpecialLogical`).
fn davis_special(addr: u32) -> bool {
    addr & 0x8000_0400 == 0x400
}

impl Decoder<'_> {
    /// DAVIS records (DHP19's with `DHP19`: address bits 0-3 carry the camera).
    fn davis<const DHP19: bool>(
        &mut self,
        records: &[u8],
        w: u16,
        h: u16,
    ) -> Result<(), ReadError> {
        self.records(records, |addr| {
            if addr & 0x8000_0400 != 0 {
                return Ok(None);
            }
            let x_raw = (addr >> 12) & 0x3FF;
            let y_raw = (addr >> 22) & 0x1FF;
            if x_raw >= u32::from(w) || y_raw >= u32::from(h) {
                return Err(Bad::OutOfSensor(x_raw, y_raw, (w, h)));
            }
            let camera = if DHP19 {
                let c = addr & 0xF;
                if c >= u32::from(DHP19_CAMERAS) {
                    return Err(Bad::Camera(c));
                }
                c as u8
            } else {
                0
            };
            // Both in range (checked above): jAER's picture, top-left origin.
            let (x, y) = (w - 1 - x_raw as u16, h - 1 - y_raw as u16);
            Ok(Some((camera, x, y, addr & 0x800 != 0)))
        })
    }

    /// DVS128 records.
    fn dvs128(&mut self, records: &[u8]) -> Result<(), ReadError> {
        self.records(records, |addr| {
            if addr & 0xFFFF_8000 != 0 {
                return Ok(None);
            }
            let x = 127 - ((addr >> 1) & 0x7F) as u16;
            let y = 127 - ((addr >> 8) & 0x7F) as u16;
            Ok(Some((0, x, y, addr & 1 == 0)))
        })
    }

    /// Whole records into the batch, each address through `address`, stopping at the first
    /// refused one (the events before it stay in the batch).
    ///
    /// The batch grows once by the records' count and the loop writes events by index (no
    /// length update per event), then the unused tail is cut off; the timestamps' common case
    /// (a step forward within the period) runs on a copy of the unwrapper's state in registers
    /// ([`super::source::Forward`]). 2.3× faster than a push per event and the unwrapper in
    /// memory (`cargo bench -p evpose-host --bench readers -- aedat2`: 10.1 → 4.5 ms per 2 M
    /// DAVIS346 events).
    #[inline(always)]
    fn records(
        &mut self,
        records: &[u8],
        address: impl Fn(u32) -> Address,
    ) -> Result<(), ReadError> {
        let (records, _) = records.as_chunks::<RECORD_BYTES>();
        let start = self.batch.len();
        self.batch
            .events
            .resize(start + records.len(), Event::default());
        self.batch.cameras.resize(start + records.len(), 0);
        let events = &mut self.batch.events[start..];
        let cameras = &mut self.batch.cameras[start..];
        let mut forward = super::source::forward(self.time);
        let (mut k, mut skipped) = (0, 0);
        let mut result = Ok(());
        for (i, r) in records.iter().enumerate() {
            let [a0, a1, a2, a3, t0, t1, t2, t3] = *r;
            let ts = u64::from(u32::from_be_bytes([t0, t1, t2, t3]));
            let offset = || self.base + (i * RECORD_BYTES) as u64;
            let addr = u32::from_be_bytes([a0, a1, a2, a3]);
            let (camera, x, y, on) = match address(addr) {
                Ok(Some(e)) => e,
                Ok(None) => {
                    // A DAVIS trigger's time, on the events' clock (DVS128 has no such bit).
                    if self.davis && davis_special(addr) {
                        if let Some(t) = forward.unwrap(self.time, ts) {
                            if self.notes.special_times.len() < super::MAX_SPECIAL_TIMES {
                                self.notes.special_times.push(t);
                            }
                        }
                    }
                    skipped += 1;
                    continue;
                }
                Err(bad) => {
                    result = Err(bad.at(offset()));
                    break;
                }
            };
            let Some(t) = forward.unwrap(self.time, ts) else {
                result = Err(time_overflow(offset()));
                break;
            };
            if let (Some(e), Some(c)) = (events.get_mut(k), cameras.get_mut(k)) {
                (*e, *c) = (Event::new(x, y, t, on), camera);
            }
            k += 1;
        }
        super::source::resume(self.time, &forward);
        self.notes.skipped_records += skipped;
        self.batch.events.truncate(start + k);
        self.batch.cameras.truncate(start + k);
        result
    }
}

impl<R: Read> super::source::Fill for Aedat2Reader<R> {
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

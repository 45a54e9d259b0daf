//! Event recording readers: one streaming interface, one module per format.
//!
//! Every reader yields events in batches of bounded size, so memory stays constant whatever the
//! file size. Damaged input gives a [`ReadError`] that names the byte offset, never a panic.
//!
//! | module | formats |
//! |---|---|
//! | [`npy`] | `.npy` (N, 4) `[x, y, t_us, p]` |
//! | [`aedat4`] | iniVation DV AEDAT 4.0 (reader and writer) |
//! | [`aedat2`] | jAER AEDAT 2.0: DAVIS346/240, DVS128, DHP19 (four cameras) |
//! | [`aedat3`] | cAER / libcaer AEDAT 3.1 |
//! | [`evt`] | Prophesee RAW, EVT 2.0, EVT 2.1 and EVT 3.0 (decoded by the core's `evt`; EVT 3.0, 2.0 and 2.1 written too) |
//! | [`dat`] | Prophesee `.dat` CD events |
//! | [`es`] | Event Stream `.es` (Sepia, Tarsier, faery): DVS and ATIS |
//! | [`text`] | text / CSV `t x y p` |
//!
//! Where a reader recovers instead of failing (records that are not polarity events, counter
//! wraps, events before a time base), it says so in [`EventReader::notes`]; every recovery is
//! documented in its module. Header parsing is bounded ([`MAX_HEADER_BYTES`],
//! [`MAX_HEADER_LINE_BYTES`]), and no size field in a file makes a reader allocate more than a
//! fixed bound.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use evpose_core::Event;

pub mod aedat2;
pub mod aedat3;
pub mod aedat4;
pub mod dat;
pub mod es;
pub mod evt;
pub mod npy;
mod source;
pub mod text;

pub use source::{MAX_HEADER_BYTES, MAX_HEADER_LINE_BYTES};

/// Events per batch that readers aim for.
pub const BATCH_EVENTS: usize = 65_536;

/// A batch of events, with the camera each came from (0 for single-camera formats).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Batch {
    /// Events in file order.
    pub events: Vec<Event>,
    /// Camera id of each event; same length as `events`.
    pub cameras: Vec<u8>,
}

impl Batch {
    /// Empties the batch, keeping its allocation.
    pub fn clear(&mut self) {
        self.events.clear();
        self.cameras.clear();
    }

    /// Appends one event.
    pub fn push(&mut self, camera: u8, event: Event) {
        self.cameras.push(camera);
        self.events.push(event);
    }

    /// Number of events.
    pub fn len(&self) -> usize {
        self.events.len()
    }

    /// Whether the batch is empty.
    pub fn is_empty(&self) -> bool {
        self.events.is_empty()
    }

    /// The events of `camera`, in order.
    pub fn of_camera(&self, camera: u8) -> impl Iterator<Item = Event> + '_ {
        self.events
            .iter()
            .zip(&self.cameras)
            .filter(move |&(_, &c)| c == camera)
            .map(|(e, _)| *e)
    }
}

/// File formats the readers understand.
///
/// [`Format::detect`] recognises every format from the first bytes of a file; the variants that
/// detection never returns (`aedat2-davis346`, `evt3`, …) exist so that `--format` can state
/// what a header leaves open or gets wrong. Readers report the format they settled on in
/// [`StreamInfo::format`] (for example `aedat2-davis346` for a file detected as `aedat2`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Format {
    /// NumPy `.npy`, an (N, 4) array `[x, y, t_us, p]`.
    Npy,
    /// iniVation DV AEDAT 4.0.
    Aedat4,
    /// jAER AEDAT 2.0, sensor named by the header's `# AEChip:` line.
    Aedat2,
    /// jAER AEDAT 2.0 from a DAVIS346 (346 × 260).
    #[value(name = "aedat2-davis346")]
    #[serde(rename = "aedat2-davis346")]
    Aedat2Davis346,
    /// jAER AEDAT 2.0 from a DAVIS240 (240 × 180).
    #[value(name = "aedat2-davis240")]
    #[serde(rename = "aedat2-davis240")]
    Aedat2Davis240,
    /// jAER AEDAT 2.0 from a DVS128 (128 × 128).
    #[value(name = "aedat2-dvs128")]
    #[serde(rename = "aedat2-dvs128")]
    Aedat2Dvs128,
    /// DHP19 raw data: AEDAT 2.0 with four DAVIS346 cameras, camera id in address bits 0–3.
    #[value(name = "aedat2-dhp19")]
    #[serde(rename = "aedat2-dhp19")]
    Aedat2Dhp19,
    /// cAER / libcaer AEDAT 3.1.
    Aedat3,
    /// Prophesee RAW, encoding named by the header (`% evt 2.0`, `% format EVT21`, …).
    Raw,
    /// Prophesee RAW, EVT 2.0 encoding.
    Evt2,
    /// Prophesee RAW, EVT 2.1 encoding, each 64-bit word little-endian (a GenX320's order).
    Evt21,
    /// Prophesee RAW, EVT 2.1 encoding, each word's upper half first (an IMX636's order,
    /// OpenEB's `legacy` endianness).
    #[value(name = "evt21-legacy")]
    #[serde(rename = "evt21-legacy")]
    Evt21Legacy,
    /// Prophesee RAW, EVT 3.0 encoding.
    Evt3,
    /// Prophesee `.dat` CD events.
    Dat,
    /// Event Stream `.es` (version 2; DVS and ATIS streams).
    #[value(alias = "event-stream")]
    Es,
    /// Text / CSV, one event per line: `t x y p` (or the columns a header row names).
    #[value(alias = "csv", alias = "txt")]
    Text,
}

impl Format {
    /// Every format, in declaration order.
    pub const ALL: [Self; 16] = [
        Self::Npy,
        Self::Aedat4,
        Self::Aedat2,
        Self::Aedat2Davis346,
        Self::Aedat2Davis240,
        Self::Aedat2Dvs128,
        Self::Aedat2Dhp19,
        Self::Aedat3,
        Self::Raw,
        Self::Evt2,
        Self::Evt21,
        Self::Evt21Legacy,
        Self::Evt3,
        Self::Dat,
        Self::Es,
        Self::Text,
    ];

    /// Guesses the format from the first bytes of a file (pass up to [`DETECT_BYTES`]).
    ///
    /// | first bytes | format |
    /// |---|---|
    /// | `\x93NUMPY` | `npy` |
    /// | `#!AER-DAT4` | `aedat4` |
    /// | `#!AER-DAT3` | `aedat3` |
    /// | `#!AER-DAT` (2.0; 1.0 is refused by the reader) | `aedat2` |
    /// | `%` lines with `% evt …` or `% format EVT…` | `raw` |
    /// | other `%` lines | `dat` (or `text` when printable text follows them) |
    /// | `Event Stream` | `es` |
    /// | printable text whose first data line has four numbers | `text` |
    pub fn detect(head: &[u8]) -> Option<Self> {
        if head.starts_with(b"\x93NUMPY") {
            Some(Self::Npy)
        } else if head.starts_with(b"#!AER-DAT4") {
            Some(Self::Aedat4)
        } else if head.starts_with(b"#!AER-DAT3") {
            Some(Self::Aedat3)
        } else if head.starts_with(b"#!AER-DAT") {
            Some(Self::Aedat2)
        } else if head.starts_with(b"%") {
            Some(evt::detect_percent_header(head))
        } else if head.starts_with(es::MAGIC) {
            Some(Self::Es)
        } else if text::looks_like_text(head) {
            Some(Self::Text)
        } else {
            None
        }
    }

    /// Human-readable name (the `--format` value).
    pub fn name(self) -> &'static str {
        match self {
            Self::Npy => "npy",
            Self::Aedat4 => "aedat4",
            Self::Aedat2 => "aedat2",
            Self::Aedat2Davis346 => "aedat2-davis346",
            Self::Aedat2Davis240 => "aedat2-davis240",
            Self::Aedat2Dvs128 => "aedat2-dvs128",
            Self::Aedat2Dhp19 => "aedat2-dhp19",
            Self::Aedat3 => "aedat3",
            Self::Raw => "raw",
            Self::Evt2 => "evt2",
            Self::Evt21 => "evt21",
            Self::Evt21Legacy => "evt21-legacy",
            Self::Evt3 => "evt3",
            Self::Dat => "dat",
            Self::Es => "es",
            Self::Text => "text",
        }
    }
}

/// Bytes [`open`] reads for [`Format::detect`].
pub const DETECT_BYTES: usize = 64 << 10;

/// Unit of text timestamps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum TimeUnit {
    /// Seconds (the RPG event-camera datasets).
    S,
    /// Milliseconds.
    Ms,
    /// Microseconds.
    Us,
    /// Nanoseconds (rounded to the nearest microsecond).
    Ns,
}

impl TimeUnit {
    /// Power of ten that turns a value in this unit into microseconds.
    pub fn exponent_to_us(self) -> i32 {
        match self {
            Self::S => 6,
            Self::Ms => 3,
            Self::Us => 0,
            Self::Ns => -3,
        }
    }

    /// Short name (`s`, `ms`, `us`, `ns`).
    pub fn name(self) -> &'static str {
        match self {
            Self::S => "s",
            Self::Ms => "ms",
            Self::Us => "us",
            Self::Ns => "ns",
        }
    }
}

/// What the caller knows that a file may not say; see [`open_with`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OpenOptions {
    /// The format; `None` detects it from the first bytes.
    pub format: Option<Format>,
    /// Sensor size (width, height) for files that state none. A size the file states wins.
    pub size: Option<(u16, u16)>,
    /// Unit of text and `.npy` timestamps; `None` detects it for text (see [`text`]) and takes
    /// whole microseconds for `.npy` (see [`npy`]).
    pub time_unit: Option<TimeUnit>,
}

/// Refuses a stream whose first events mostly go back in time: what a column order other
/// than the one a format without names assumes gives (`[t, x, y, p]` read as `[x, y, t, p]`
/// makes a pixel coordinate the time). Real recordings are in time order but for a few
/// events; a quarter of the first [`OrderCheck::EVENTS`] going backwards is no recording.
#[derive(Clone, Debug, Default)]
pub(crate) struct OrderCheck {
    seen: usize,
    backwards: usize,
    last: Option<i64>,
    /// The verdict is in (the first events counted, or the stream ended short of them).
    judged: bool,
}

impl OrderCheck {
    /// Events judged: the stream's first.
    pub(crate) const EVENTS: usize = 1_000;
    /// Fewest events a verdict needs.
    const MIN_EVENTS: usize = 16;

    /// Counts `events` (the stream's next ones) until the verdict; `columns` names the order
    /// the format assumes, for the message.
    pub(crate) fn check(&mut self, events: &[Event], columns: &str) -> Result<(), ReadError> {
        if self.judged {
            return Ok(());
        }
        for e in events.iter().take(Self::EVENTS - self.seen) {
            self.backwards += usize::from(self.last.is_some_and(|l| e.t < l));
            self.last = Some(e.t);
            self.seen += 1;
        }
        // A batch shorter than a reader fills is the stream's last.
        self.judged = self.seen >= Self::EVENTS || events.len() < BATCH_EVENTS;
        if self.judged && self.seen >= Self::MIN_EVENTS && 4 * self.backwards > self.seen {
            return Err(ReadError::Corrupt {
                offset: 0,
                message: format!(
                    "timestamps go backwards at {} of the first {} events: no recording is \
                     out of order like that. Are the columns in another order than {columns}?",
                    self.backwards, self.seen
                ),
            });
        }
        Ok(())
    }
}

/// What a reader repaired, skipped or assumed: the documented recoveries, with counts.
///
/// Each count only grows while reading; read it after the last batch for the whole file.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ReadNotes {
    /// Records that are not polarity events, skipped: APS samples, IMU samples, triggers and
    /// special events, invalid (filtered) AEDAT 3 events, EVT "other" words.
    pub skipped_records: u64,
    /// Whole packets skipped: AEDAT 3 packets of other event types, AEDAT 4 packets of
    /// non-event streams.
    pub skipped_packets: u64,
    /// Events dropped because the stream had not yet given their time base or row (EVT 2.0 /
    /// 3.0 events before the first time-high or y-address word, as Prophesee's decoders do).
    pub dropped_events: u64,
    /// Wraps of the file's timestamp counter that were unwrapped.
    pub timestamp_wraps: u64,
    /// EVT 3.0 time-low wraps with no time-high word before them, taken as the next time-high
    /// period (files written by expelliarmus; a conforming stream has none).
    pub implied_time_highs: u64,
    /// Decisions taken where the file is ambiguous (sensor model, time unit, …).
    pub assumptions: Vec<String>,
    /// Times (µs, on the events' clock) of the first [`MAX_SPECIAL_TIMES`] AEDAT 2.0 DAVIS
    /// special (trigger) events, in file order: DHP19 starts its Vicon clock at one of them
    /// (`dataset::dhp19_span`). Counted in [`ReadNotes::skipped_records`] too.
    pub special_times: Vec<i64>,
}

/// Most special-event times [`ReadNotes::special_times`] keeps (DHP19's files have 0 to 5).
pub const MAX_SPECIAL_TIMES: usize = 64;

/// What a recording says about one of its cameras.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct CameraInfo {
    /// Camera id as found in [`Batch::cameras`].
    pub id: u8,
    /// Sensor width, when the file states it.
    pub width: Option<u16>,
    /// Sensor height, when the file states it.
    pub height: Option<u16>,
    /// Source name, when the file states one (e.g. `DAVIS346_00000002`).
    pub name: Option<String>,
}

/// What a reader knows about its recording before reading any event.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct StreamInfo {
    /// The file's format.
    pub format: Format,
    /// Cameras known from the header (may be empty when the format states none).
    pub cameras: Vec<CameraInfo>,
    /// Event count, when the header states it (npy does).
    pub event_count: Option<u64>,
}

/// A damaged or unsupported recording.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The operating system failed to read.
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// The bytes at `offset` do not follow the format.
    #[error("at byte {offset}: {message}")]
    Corrupt {
        /// Byte offset in the file where the problem starts.
        offset: u64,
        /// What is wrong.
        message: String,
    },
    /// The file ends inside a record or header that started at `offset`.
    #[error("at byte {offset}: file ends inside {what}")]
    Truncated {
        /// Byte offset where the cut record starts.
        offset: u64,
        /// What was being read.
        what: &'static str,
    },
    /// The format is recognised but this variant is not supported.
    #[error("unsupported: {0}")]
    Unsupported(String),
}

/// A streaming reader of event batches.
pub trait EventReader {
    /// What the header says.
    fn info(&self) -> &StreamInfo;

    /// Clears `batch` and fills it with the next events. Returns `Ok(false)` at the end of the
    /// stream (with `batch` empty).
    fn read_batch(&mut self, batch: &mut Batch) -> Result<bool, ReadError>;

    /// What the reader skipped, repaired or assumed so far.
    fn notes(&self) -> ReadNotes {
        ReadNotes::default()
    }
}

/// Opens a recording, detecting its format from its first bytes unless `format` is given.
pub fn open(path: &Path, format: Option<Format>) -> anyhow::Result<Box<dyn EventReader>> {
    open_with(
        path,
        &OpenOptions {
            format,
            ..OpenOptions::default()
        },
    )
}

/// Opens a recording with [`OpenOptions`]: the format (detected from the first
/// [`DETECT_BYTES`] unless given), a fallback sensor size and the text time unit.
///
/// A detected `dat` whose file name ends in `.raw` is opened as `raw` (old Prophesee RAW files
/// may lack the `% evt` line; the RAW reader then asks for `--format evt2|evt21|evt21-legacy|evt3`).
pub fn open_with(path: &Path, opts: &OpenOptions) -> anyhow::Result<Box<dyn EventReader>> {
    use anyhow::Context;
    let file = BufReader::with_capacity(
        1 << 16,
        File::open(path).with_context(|| format!("cannot open {}", path.display()))?,
    );
    let raw_name = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("raw"));
    from_source(file, &path.display().to_string(), opts, raw_name)
}

/// Opens a recording held in memory (an embedded sample, a recording just simulated), as
/// [`open_with`] opens a file.
pub fn open_bytes(
    bytes: impl AsRef<[u8]> + Send + 'static,
    name: &str,
    opts: &OpenOptions,
) -> anyhow::Result<Box<dyn EventReader>> {
    from_source(std::io::Cursor::new(bytes), name, opts, false)
}

/// A reader over any byte source: the format is `opts.format`, or detected from the first
/// [`DETECT_BYTES`] (`raw_name`: a detected `dat` is read as `raw`). `name` names the source in
/// errors.
pub fn from_source<S: Read + Send + 'static>(
    mut source: S,
    name: &str,
    opts: &OpenOptions,
    raw_name: bool,
) -> anyhow::Result<Box<dyn EventReader>> {
    use anyhow::Context;
    let mut head = vec![
        0u8;
        if opts.format.is_some() {
            0
        } else {
            DETECT_BYTES
        }
    ];
    let n = read_up_to(&mut source, &mut head).with_context(|| format!("cannot read {name}"))?;
    head.truncate(n);
    let format = match opts.format {
        Some(f) => f,
        None => {
            let detected = Format::detect(&head).with_context(|| {
                format!(
                    "{name}: unknown event file format (first bytes {:02x?}); pass --format",
                    &head[..n.min(16)]
                )
            })?;
            if detected == Format::Dat && raw_name {
                Format::Raw
            } else {
                detected
            }
        }
    };
    // The bytes read for detection, then the rest of the source.
    let file = std::io::Cursor::new(head).chain(source);
    let size = opts.size;
    let reader: Box<dyn EventReader> = match format {
        Format::Npy => Box::new(WithSize::new(
            npy::NpyReader::new(file, opts.time_unit)?,
            size,
        )),
        Format::Aedat4 => Box::new(WithSize::new(aedat4::Aedat4Reader::new(file)?, size)),
        Format::Aedat2
        | Format::Aedat2Davis346
        | Format::Aedat2Davis240
        | Format::Aedat2Dvs128
        | Format::Aedat2Dhp19 => Box::new(aedat2::Aedat2Reader::new(file, format, size)?),
        Format::Aedat3 => Box::new(aedat3::Aedat3Reader::new(file, size)?),
        Format::Raw | Format::Evt2 | Format::Evt21 | Format::Evt21Legacy | Format::Evt3 => {
            Box::new(evt::EvtReader::new(file, format, size)?)
        }
        Format::Dat => Box::new(dat::DatReader::new(file, size)?),
        Format::Es => Box::new(es::EsReader::new(file)?),
        Format::Text => Box::new(text::TextReader::new(file, opts.time_unit, size)?),
    };
    Ok(reader)
}

/// Reads every event into memory, `(camera, event)` in the reader's order (file order; AEDAT 4
/// cameras merged by time).
pub fn read_all(reader: &mut dyn EventReader) -> Result<Vec<(u8, Event)>, ReadError> {
    let mut batch = Batch::default();
    let mut out = Vec::new();
    while reader.read_batch(&mut batch)? {
        out.extend(
            batch
                .cameras
                .iter()
                .copied()
                .zip(batch.events.iter().copied()),
        );
    }
    Ok(out)
}

/// Reads every event of `camera` into memory.
pub fn read_camera(reader: &mut dyn EventReader, camera: u8) -> Result<Vec<Event>, ReadError> {
    let mut batch = Batch::default();
    let mut events = Vec::new();
    while reader.read_batch(&mut batch)? {
        events.extend(batch.of_camera(camera));
    }
    Ok(events)
}

/// A reader whose header may lack the sensor size, with the caller's fallback filled in.
struct WithSize<R> {
    inner: R,
    info: StreamInfo,
}

impl<R: EventReader> WithSize<R> {
    fn new(inner: R, size: Option<(u16, u16)>) -> Self {
        let mut info = inner.info().clone();
        fill_size(&mut info, size);
        Self { inner, info }
    }
}

impl<R: EventReader> EventReader for WithSize<R> {
    fn info(&self) -> &StreamInfo {
        &self.info
    }

    fn read_batch(&mut self, batch: &mut Batch) -> Result<bool, ReadError> {
        self.inner.read_batch(batch)
    }

    fn notes(&self) -> ReadNotes {
        self.inner.notes()
    }
}

/// Gives every camera without a size the fallback `size`; with no camera at all, declares
/// camera 0 with it.
pub(crate) fn fill_size(info: &mut StreamInfo, size: Option<(u16, u16)>) {
    let Some((w, h)) = size else {
        return;
    };
    if info.cameras.is_empty() {
        info.cameras.push(CameraInfo {
            id: 0,
            width: None,
            height: None,
            name: None,
        });
    }
    for c in &mut info.cameras {
        if c.width.is_none() || c.height.is_none() {
            c.width = Some(w);
            c.height = Some(h);
        }
    }
}

/// Reads until `buf` is full or the input ends; returns the bytes read.
pub fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

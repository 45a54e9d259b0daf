//! Prophesee RAW files: EVT 2.0 and EVT 3.0 encodings.
//!
//! # Header
//!
//! `%` lines: `% evt 3.0`, `% format EVT3;height=720;width=1280`, `% geometry 1280x720`,
//! `% camera_integrator_name …`, `% serial_number …`, and in recent files a final `% end`. The
//! header ends after `% end` or at the first line that does not start with `%` (as Prophesee's
//! OpenEB decides) or that holds control bytes (event words whose first byte happens to be
//! `%` = 0x25). The encoding comes from `% format` or `% evt`; `--format evt2|evt3`
//! overrides it (recorded in [`ReadNotes::assumptions`]). EVT 2.1 is refused. The size comes
//! from `% format …;width=…;height=…` or `% geometry`; else, in files of Prophesee's own
//! cameras written before those lines existed, from `% system_ID` through OpenEB's table
//! (Gen3.0 and Gen3.1: 640 × 480; Gen4.0, Gen4.1 and IMX636: 1280 × 720) unless
//! `--width/--height` give one (expelliarmus writes a fixed header, `system_ID` 21 or 48,
//! whatever the events' sensor); else from `--width/--height`. In EVT 3.0 a time-high word that changes the period sets the time low
//! to 0 (OpenEB's decoder does the same).
//!
//! # EVT 2.0
//!
//! u32 LE words, type in bits 28–31:
//!
//! | type | word | meaning |
//! |---|---|---|
//! | 0x0 / 0x1 | CD_OFF / CD_ON | t low 6 bits in 22–27, x in 11–21, y in 0–10 |
//! | 0x8 | EVT_TIME_HIGH | bits 0–27 = t >> 6 |
//! | 0xA, 0xE, 0xF | EXT_TRIGGER, OTHERS, CONTINUED | skipped, counted |
//!
//! # EVT 3.0
//!
//! u16 LE words, type in bits 12–15:
//!
//! | type | word | meaning |
//! |---|---|---|
//! | 0x0 | EVT_ADDR_Y | y = bits 0–10 |
//! | 0x2 | EVT_ADDR_X | one event at x = bits 0–10, polarity bit 11 |
//! | 0x3 | VECT_BASE_X | base x = bits 0–10, polarity bit 11 |
//! | 0x4 / 0x5 | VECT_12 / VECT_8 | bit i set: event at base x + i; then base x += 12 / 8 |
//! | 0x6 / 0x8 | EVT_TIME_LOW / EVT_TIME_HIGH | 12 bits each: t = high << 12 \| low |
//! | 0x7, 0xA, 0xE, 0xF | CONTINUED_4, EXT_TRIGGER, OTHERS, CONTINUED_12 | skipped, counted |
//!
//! # Damage and recovery
//!
//! The time counters wrap (EVT 2.0 after 2³⁴ µs, EVT 3.0 after 2²⁴ µs ≈ 16.8 s): a time-high
//! word more than half the range below the previous one is a wrap, counted in
//! [`ReadNotes::timestamp_wraps`]. In an EVT 3.0 file that has given one time-high word so
//! far, a time-low word more than half its range (2,048 µs) below the previous one, with no
//! time-high word between them, starts the next time-high period: a conforming stream gives a
//! time-high word every period, but expelliarmus (a Python reader and writer) writes one per
//! file and lets the time low wrap; these are counted in [`ReadNotes::implied_time_highs`].
//! Once a second time-high word came, time lows are taken as given (as OpenEB does). Events before the first time-high word (or, in EVT 3.0,
//! before the first y address) have no time base and are dropped and counted in
//! [`ReadNotes::dropped_events`], as OpenEB does. Reserved word types, pixels outside a known
//! sensor (or x beyond 65535) and a file that ends inside a word are errors naming the word's
//! offset.

use std::io::Read;

use evpose_core::Event;

use super::source::{out_of_sensor, parse_geometry, time_overflow, Source, Unwrapper};
use super::{text, Batch, CameraInfo, Format, ReadError, ReadNotes, StreamInfo, BATCH_EVENTS};

/// The `%` header lines of a Prophesee file, as (lower-case key, value) pairs.
pub(crate) struct PercentHeader {
    /// Lines in file order (bounded by [`MAX_HEADER_BYTES`](super::MAX_HEADER_BYTES)).
    pub(crate) lines: Vec<(String, String)>,
}

impl PercentHeader {
    /// Reads `%` lines from the start of the file; stops after `% end` when `stop_at_end`.
    pub(crate) fn read<R: Read>(src: &mut Source<R>, stop_at_end: bool) -> Result<Self, ReadError> {
        let mut lines = Vec::new();
        while src.peek()? == Some(b'%') && src.line_is_text()? {
            let Some(line) = src.header_line(0)? else {
                break;
            };
            let body = line[1..].trim();
            let (key, value) = body.split_once(char::is_whitespace).unwrap_or((body, ""));
            let key = key.to_ascii_lowercase();
            let end = key == "end";
            lines.push((key, value.trim().to_string()));
            if end && stop_at_end {
                break;
            }
        }
        Ok(Self { lines })
    }

    /// The value of the first line with `key` (lower case).
    pub(crate) fn get(&self, key: &str) -> Option<&str> {
        self.lines
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// The sensor size: `% format …;width=W;height=H`, `% geometry WxH`, or `% Width` and
    /// `% Height` lines (as `.dat` files have).
    pub(crate) fn size(&self) -> Option<(u16, u16)> {
        let from_format = self.get("format").and_then(|f| {
            let mut w = None;
            let mut h = None;
            for opt in f.split(';').skip(1) {
                match opt.split_once('=') {
                    Some((k, v)) if k.trim().eq_ignore_ascii_case("width") => {
                        w = v.trim().parse().ok()
                    }
                    Some((k, v)) if k.trim().eq_ignore_ascii_case("height") => {
                        h = v.trim().parse().ok()
                    }
                    _ => {}
                }
            }
            w.zip(h)
        });
        let from_lines = || {
            let w = self.get("width")?.parse().ok()?;
            let h = self.get("height")?.parse().ok()?;
            Some((w, h))
        };
        from_format
            .or_else(|| self.get("geometry").and_then(parse_geometry))
            .or_else(from_lines)
            .filter(|&(w, h)| w > 0 && h > 0)
    }

    /// The sensor size that OpenEB gives a Prophesee camera's `% system_ID` when the header
    /// states none (files of Metavision before 2.2 or so), with the sensor's name; only for
    /// files whose integrator is Prophesee, as OpenEB decides (`psee_raw_file_header.cpp`).
    pub(crate) fn system_id_size(&self) -> Option<((u16, u16), &'static str)> {
        // OpenEB's `check_header`: the legacy `integrator_name` stands for both the camera's
        // and the plugin's integrator when neither is named; no integrator line at all means
        // Prophesee; the table applies only when both are Prophesee.
        let (camera, plugin) = match (
            self.get("camera_integrator_name"),
            self.get("plugin_integrator_name"),
        ) {
            (None, None) => {
                let legacy = self.get("integrator_name").unwrap_or("Prophesee");
                (Some(legacy), Some(legacy))
            }
            named => named,
        };
        if camera != Some("Prophesee") || plugin != Some("Prophesee") {
            return None;
        }
        let vga = (640, 480);
        let hd = (1280, 720);
        Some(match self.get("system_id")?.trim().parse::<u32>().ok()? {
            21 | 23 | 25 | 29 | 33 | 151 | 153 | 161 => (vga, "Gen3.0"),
            28 | 34 | 35 | 40 | 41 | 162 => (vga, "Gen3.1"),
            26 | 30 | 31 | 46 => (hd, "Gen4.0"),
            39 | 48 => (hd, "Gen4.1"),
            49 | 50 => (hd, "IMX636"),
            _ => return None,
        })
    }

    /// The encoding the header names, as written (`EVT3`, `3.0`, …), and what it means.
    fn encoding(&self) -> Option<(String, Option<Encoding>)> {
        if let Some(f) = self.get("format") {
            let name = f.split(';').next().unwrap_or("").trim().to_string();
            let enc = match name.to_ascii_uppercase().as_str() {
                "EVT2" => Some(Encoding::Evt2),
                "EVT3" => Some(Encoding::Evt3),
                _ => None,
            };
            return Some((format!("format {name}"), enc));
        }
        self.get("evt").map(|v| {
            let enc = match v {
                "2.0" | "2" => Some(Encoding::Evt2),
                "3.0" | "3" => Some(Encoding::Evt3),
                _ => None,
            };
            (format!("evt {v}"), enc)
        })
    }

    /// A camera name from the integrator, serial number or plugin lines.
    fn camera_name(&self) -> Option<String> {
        let integrator = self
            .get("camera_integrator_name")
            .or_else(|| self.get("integrator_name"));
        let serial = self.get("serial_number");
        match (integrator, serial) {
            (Some(i), Some(s)) => Some(format!("{i} {s}")),
            (Some(v), None) | (None, Some(v)) => Some(v.to_string()),
            (None, None) => self.get("plugin_name").map(str::to_string),
        }
    }
}

/// The format of a file that starts with `%`: `raw` when the header names an EVT encoding
/// (or ends with `% end`), `text` when printable text follows the header, else `dat`.
pub(crate) fn detect_percent_header(head: &[u8]) -> Format {
    let mut pos = 0;
    while head.get(pos) == Some(&b'%') {
        let Some(len) = head[pos..].iter().position(|&b| b == b'\n') else {
            // The header does not end within `head`.
            return Format::Dat;
        };
        let line = String::from_utf8_lossy(&head[pos + 1..pos + len]).to_ascii_lowercase();
        let mut words = line.split_whitespace();
        match (words.next(), words.next()) {
            (Some("evt"), _) | (Some("end"), None) => return Format::Raw,
            (Some("format"), Some(f)) if f.starts_with("evt") => return Format::Raw,
            _ => {}
        }
        pos += len + 1;
    }
    let rest = &head[pos.min(head.len())..];
    match rest {
        [0x00 | 0x0C | 0x0E, 8, ..] => Format::Dat,
        _ if !rest.is_empty() && text::looks_like_text(rest) => Format::Text,
        _ => Format::Dat,
    }
}

/// An EVT encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// EVT 2.0: 32-bit words.
    Evt2,
    /// EVT 3.0: 16-bit words.
    Evt3,
}

impl Encoding {
    fn format(self) -> Format {
        match self {
            Self::Evt2 => Format::Evt2,
            Self::Evt3 => Format::Evt3,
        }
    }

    fn word_bytes(self) -> usize {
        match self {
            Self::Evt2 => 4,
            Self::Evt3 => 2,
        }
    }
}

/// Decoder state carried across words.
struct State {
    /// Unwrapped time-high value, once one was seen.
    high: Option<i64>,
    high_counter: Unwrapper,
    /// EVT 3.0: time low, row, vector base and polarity.
    low: i64,
    /// EVT 3.0: a time-low word came since the last time-high word.
    low_seen: bool,
    /// EVT 3.0: time-high words so far.
    high_words: u64,
    y: Option<u16>,
    base_x: u32,
    on: bool,
}

/// Streaming Prophesee RAW reader (EVT 2.0 / 3.0).
pub struct EvtReader<R> {
    src: Source<R>,
    info: StreamInfo,
    encoding: Encoding,
    size: Option<(u16, u16)>,
    /// The size came from `% system_ID` (a guess that `--width/--height` can correct).
    size_from_id: bool,
    state: State,
    notes: ReadNotes,
    finished: bool,
}

impl<R: Read> EvtReader<R> {
    /// Parses the header. `format` is [`Format::Raw`] (encoding from the header),
    /// [`Format::Evt2`] or [`Format::Evt3`]; `size` is the fallback sensor size.
    pub fn new(inner: R, format: Format, size: Option<(u16, u16)>) -> Result<Self, ReadError> {
        let mut src = Source::new(inner, 0);
        let header = PercentHeader::read(&mut src, true)?;
        let mut notes = ReadNotes::default();
        let stated = header.encoding();
        let given = match format {
            Format::Evt2 => Some(Encoding::Evt2),
            Format::Evt3 => Some(Encoding::Evt3),
            _ => None,
        };
        let encoding = match (given, stated) {
            (Some(g), Some((name, e))) => {
                if e != Some(g) {
                    notes.assumptions.push(format!(
                        "the header says `{name}`, which --format {} overrides",
                        format.name()
                    ));
                }
                g
            }
            (Some(g), None) => g,
            (None, Some((_, Some(e)))) => e,
            (None, Some((name, None))) => {
                return Err(ReadError::Unsupported(format!(
                    "Prophesee RAW encoding `{name}`; only EVT 2.0 and EVT 3.0 are read"
                )))
            }
            (None, None) => {
                return Err(ReadError::Unsupported(
                    "the RAW header names no encoding (no `% evt` or `% format` line); pass \
                     --format evt2 or --format evt3"
                        .into(),
                ))
            }
        };
        let from_id = header.system_id_size().filter(|_| size.is_none());
        let size = match (header.size(), from_id) {
            (Some(s), _) => Some(s),
            (None, Some(((w, h), sensor))) => {
                notes.assumptions.push(format!(
                    "sensor size {w}x{h} from `% system_ID {}` (a {sensor} camera, as OpenEB \
                     reads a header without a size; --width/--height override it)",
                    header.get("system_id").unwrap_or_default()
                ));
                Some((w, h))
            }
            (None, None) => {
                if let Some((w, h)) = size {
                    notes
                        .assumptions
                        .push(format!("sensor size {w}x{h} from --width/--height"));
                }
                size
            }
        };
        let bits = match encoding {
            Encoding::Evt2 => 28,
            Encoding::Evt3 => 12,
        };
        Ok(Self {
            src,
            info: StreamInfo {
                format: encoding.format(),
                cameras: vec![CameraInfo {
                    id: 0,
                    width: size.map(|s| s.0),
                    height: size.map(|s| s.1),
                    name: header.camera_name(),
                }],
                event_count: None,
            },
            encoding,
            size,
            size_from_id: header.size().is_none() && from_id.is_some(),
            state: State {
                high: None,
                high_counter: Unwrapper::new(bits),
                low: 0,
                low_seen: false,
                high_words: 0,
                y: None,
                base_x: 0,
                on: false,
            },
            notes,
            finished: false,
        })
    }

    /// The encoding in use.
    pub fn encoding(&self) -> Encoding {
        self.encoding
    }

    fn fill(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        let word = self.encoding.word_bytes();
        // An EVT 3.0 word gives up to 12 events: stop while a whole vector still fits.
        let limit = BATCH_EVENTS - 12;
        while batch.len() < limit {
            let have = self.src.fill(word)?;
            if have < word {
                if have == 0 {
                    self.finished = true;
                    return Ok(());
                }
                return Err(ReadError::Truncated {
                    offset: self.src.offset(),
                    what: "an EVT word",
                });
            }
            let base = self.src.offset();
            let words = &self.src.data()[..have - have % word];
            let mut d = Decoder {
                state: &mut self.state,
                notes: &mut self.notes,
                size: self.size,
                size_from_id: self.size_from_id,
                batch,
                base,
                limit,
            };
            let used = match self.encoding {
                Encoding::Evt2 => d.evt2(words)?,
                Encoding::Evt3 => d.evt3(words)?,
            };
            self.src.consume(used * word);
        }
        Ok(())
    }
}

/// Decodes whole words into a batch.
struct Decoder<'a> {
    state: &'a mut State,
    notes: &'a mut ReadNotes,
    size: Option<(u16, u16)>,
    size_from_id: bool,
    batch: &'a mut Batch,
    /// File offset of the first word.
    base: u64,
    /// Decoding stops once the batch holds this many events.
    limit: usize,
}

impl Decoder<'_> {
    #[inline]
    fn check(&self, offset: u64, x: u32, y: u32) -> Result<(), ReadError> {
        match self.size {
            Some((w, h)) if x >= u32::from(w) || y >= u32::from(h) => {
                Err(self.outside(offset, x, y, (w, h)))
            }
            None if x > u32::from(u16::MAX) => Err(ReadError::Corrupt {
                offset,
                message: format!("x = {x} does not fit 16 bits"),
            }),
            _ => Ok(()),
        }
    }

    /// The error for a pixel outside the sensor (out of line: the decoding loops stay small).
    #[cold]
    #[inline(never)]
    fn outside(&self, offset: u64, x: u32, y: u32, size: (u16, u16)) -> ReadError {
        let mut e = out_of_sensor(offset, x, y, size);
        if let (true, ReadError::Corrupt { message, .. }) = (self.size_from_id, &mut e) {
            message.push_str(" (the size `system_ID` implies; pass --width/--height)");
        }
        e
    }

    /// Decodes EVT 2.0 words until the batch is full; returns the words used.
    fn evt2(&mut self, words: &[u8]) -> Result<usize, ReadError> {
        for (i, b) in words.chunks_exact(4).enumerate() {
            if self.batch.len() >= self.limit {
                return Ok(i);
            }
            let w = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            match w >> 28 {
                ty @ (0x0 | 0x1) => {
                    let Some(high) = self.state.high else {
                        self.notes.dropped_events += 1;
                        continue;
                    };
                    let x = (w >> 11) & 0x7FF;
                    let y = w & 0x7FF;
                    self.check(self.base + (i * 4) as u64, x, y)?;
                    let t = (high << 6) | i64::from((w >> 22) & 0x3F);
                    self.batch
                        .push(0, Event::new(x as u16, y as u16, t, ty == 1));
                }
                0x8 => {
                    let offset = self.base + (i * 4) as u64;
                    let high = self
                        .state
                        .high_counter
                        .unwrap(u64::from(w & 0x0FFF_FFFF))
                        .filter(|&h| h < 1 << 57)
                        .ok_or_else(|| time_overflow(offset))?;
                    self.state.high = Some(high);
                    self.notes.timestamp_wraps = self.state.high_counter.wraps();
                }
                0xA | 0xE | 0xF => self.notes.skipped_records += 1,
                ty => {
                    return Err(ReadError::Corrupt {
                        offset: self.base + (i * 4) as u64,
                        message: format!("EVT 2.0 word {w:#010x} has the reserved type {ty:#x}"),
                    })
                }
            }
        }
        Ok(words.len() / 4)
    }

    /// Decodes EVT 3.0 words until the batch is full; returns the words used.
    fn evt3(&mut self, words: &[u8]) -> Result<usize, ReadError> {
        for (i, b) in words.chunks_exact(2).enumerate() {
            if self.batch.len() >= self.limit {
                return Ok(i);
            }
            let w = u16::from_le_bytes([b[0], b[1]]);
            let s = &mut *self.state;
            match w >> 12 {
                0x0 => s.y = Some(w & 0x7FF),
                0x2 => {
                    let x = u32::from(w & 0x7FF);
                    let on = w & 0x800 != 0;
                    self.emit(i, x, on, 1)?;
                }
                0x3 => {
                    s.base_x = u32::from(w & 0x7FF);
                    s.on = w & 0x800 != 0;
                }
                0x4 => self.vector(i, u32::from(w & 0xFFF), 12)?,
                0x5 => self.vector(i, u32::from(w & 0xFF), 8)?,
                0x6 => {
                    let low = i64::from(w & 0xFFF);
                    // Time low back by more than half its range with no time-high word since
                    // the last time low, in a file that gave one time-high word so far: its
                    // counter wrapped into the next period (expelliarmus writes one time-high
                    // word per file; files with more follow OpenEB: the time low as given).
                    let wrapped = s.low_seen && s.high_words == 1 && low + 0x800 < s.low;
                    if let (true, Some(high)) = (wrapped, s.high) {
                        let offset = self.base + (i * 2) as u64;
                        s.high = Some(
                            s.high_counter
                                .unwrap(((high + 1) & 0xFFF) as u64)
                                .filter(|&h| h < 1 << 50)
                                .ok_or_else(|| time_overflow(offset))?,
                        );
                        self.notes.timestamp_wraps = s.high_counter.wraps();
                        self.notes.implied_time_highs += 1;
                    }
                    s.low = low;
                    s.low_seen = true;
                }
                0x8 => {
                    let offset = self.base + (i * 2) as u64;
                    let high = s
                        .high_counter
                        .unwrap(u64::from(w & 0xFFF))
                        .filter(|&h| h < 1 << 50)
                        .ok_or_else(|| time_overflow(offset))?;
                    // A new time-high period starts at time low 0 (as OpenEB decodes it).
                    if s.high != Some(high) {
                        s.low = 0;
                    }
                    s.high = Some(high);
                    s.high_words += 1;
                    s.low_seen = false;
                    self.notes.timestamp_wraps = s.high_counter.wraps();
                }
                0x7 | 0xA | 0xE | 0xF => self.notes.skipped_records += 1,
                ty => {
                    return Err(ReadError::Corrupt {
                        offset: self.base + (i * 2) as u64,
                        message: format!("EVT 3.0 word {w:#06x} has the reserved type {ty:#x}"),
                    })
                }
            }
        }
        Ok(words.len() / 2)
    }

    /// Events of a VECT_12 / VECT_8 word; moves the base x on by `width`.
    fn vector(&mut self, i: usize, mut mask: u32, width: u32) -> Result<(), ReadError> {
        let base_x = self.state.base_x;
        let on = self.state.on;
        self.state.base_x = base_x.saturating_add(width);
        if self.state.high.is_none() || self.state.y.is_none() {
            self.notes.dropped_events += u64::from(mask.count_ones());
            return Ok(());
        }
        while mask != 0 {
            let bit = mask.trailing_zeros();
            mask &= mask - 1;
            self.emit(i, base_x + bit, on, 0)?;
        }
        Ok(())
    }

    /// One EVT 3.0 event at `x` in the current row; `count_drop` is what to count as dropped
    /// when the time base or row is not known yet (vectors count their own).
    fn emit(&mut self, i: usize, x: u32, on: bool, count_drop: u64) -> Result<(), ReadError> {
        let (Some(high), Some(y)) = (self.state.high, self.state.y) else {
            self.notes.dropped_events += count_drop;
            return Ok(());
        };
        self.check(self.base + (i * 2) as u64, x, u32::from(y))?;
        let t = (high << 12) | self.state.low;
        self.batch.push(0, Event::new(x as u16, y, t, on));
        Ok(())
    }
}

impl<R: Read> super::source::Fill for EvtReader<R> {
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

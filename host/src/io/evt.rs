//! Prophesee RAW files: EVT 2.0, EVT 2.1 and EVT 3.0 encodings, read ([`EvtReader`]) and
//! written ([`Evt3Writer`] for EVT 3.0, [`Evt2Writer`] for EVT 2.0 and 2.1).
//!
//! # Header
//!
//! `%` lines: `% evt 3.0`, `% format EVT3;height=720;width=1280`, `% geometry 1280x720`,
//! `% camera_integrator_name …`, `% serial_number …`, and in recent files a final `% end`. The
//! header ends after `% end` or at the first line that does not start with `%` (as Prophesee's
//! OpenEB decides) or that holds control bytes (event words whose first byte happens to be
//! `%` = 0x25). The encoding comes from `% format` or `% evt`; `--format
//! evt2|evt21|evt21-legacy|evt3` overrides it (recorded in [`ReadNotes::assumptions`]). EVT
//! 2.1's byte order comes from the header as OpenEB decides it (below). The size comes
//! from `% format …;width=…;height=…` or `% geometry`; else, in files of Prophesee's own
//! cameras written before those lines existed, from `% system_ID` through OpenEB's table
//! (Gen3.0 and Gen3.1: 640 × 480; Gen4.0, Gen4.1 and IMX636: 1280 × 720) unless
//! `--width/--height` give one (expelliarmus writes a fixed header, `system_ID` 21 or 48,
//! whatever the events' sensor); else from `--width/--height`.
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
//! # EVT 2.1
//!
//! u64 words, type in bits 60–63 (the GenX320's default encoding; the IMX636's other one):
//!
//! | type | word | meaning |
//! |---|---|---|
//! | 0x0 / 0x1 | EVT_NEG / EVT_POS | t low 6 bits in 54–59, x in 43–53, y in 32–42; bit `i` of 0–31 set: an event at x + i |
//! | 0x8 | EVT_TIME_HIGH | bits 32–59 = t >> 6 |
//! | 0xA, 0xE, 0xF | EXT_TRIGGER, OTHERS, CONTINUED | skipped, counted |
//!
//! Byte order: a GenX320 writes each word little-endian as a whole (`evt21`); an IMX636 writes
//! bits 32–63 first, then bits 0–31, each half little-endian (`evt21-legacy`, OpenEB's
//! `legacy` endianness). The header says which in an `endianness=` option of `% format EVT21;…`
//! or an `% endianness` line (exactly `legacy`: upper half first; any other value: whole
//! words); without either, OpenEB reads `legacy` for a Prophesee camera whose `% system_ID` is
//! not 0 and below 0x37 (the IMX636 and Gen4 EVKs; a missing or unreadable one counts as -1)
//! and whole words otherwise, and so does this reader, with a note saying which. A header with
//! `% evt 2.1` but no `% format` line is read too (OpenEB takes `% evt` only for the old
//! systems it knows).
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
//! The words are decoded by the core's [`EvtDecoder`] (`evpose_core::evt`, the decoder a
//! microcontroller runs), whose documentation is the reference; in short: the time counters
//! wrap (EVT 2.0 and 2.1 after 2³⁴ µs, EVT 3.0 after 2²⁴ µs ≈ 16.8 s): a time-high word more than half
//! the range below the previous one is a wrap, counted in [`ReadNotes::timestamp_wraps`]. In an
//! EVT 3.0 file that has given one time-high word so far, a time-low word more than half its
//! range (2,048 µs) below the previous one, with no time-high word between them, starts the
//! next time-high period: a conforming stream gives a time-high word every period, but
//! expelliarmus (a Python reader and writer) writes one per file and lets the time low wrap;
//! these are counted in [`ReadNotes::implied_time_highs`]. Once a second time-high word came,
//! time lows are taken as given, and a time-high word that changes the period sets the time low
//! to 0 (as OpenEB does). Events before the first time-high word (or, in EVT 3.0, before the
//! first y address) have no time base and are dropped and counted in
//! [`ReadNotes::dropped_events`], as OpenEB does. Reserved word types, pixels outside a known
//! sensor (or x beyond 65535) and a file that ends inside a word are errors naming the word's
//! offset.

use std::io::Read;

pub use evpose_core::evt::Encoding;
use evpose_core::evt::{EvtDecoder, EvtError};
use evpose_core::Event;

use super::source::{out_of_sensor, parse_geometry, time_overflow, Source};
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
        if !self.prophesee_integrated() {
            return None;
        }
        let vga = (640, 480);
        let hd = (1280, 720);
        // The leading digits, as OpenEB's `get_system_id` reads them.
        Some(match leading_integer(self.get("system_id")?) {
            21 | 23 | 25 | 29 | 33 | 151 | 153 | 161 => (vga, "Gen3.0"),
            28 | 34 | 35 | 40 | 41 | 162 => (vga, "Gen3.1"),
            26 | 30 | 31 | 46 => (hd, "Gen4.0"),
            39 | 48 => (hd, "Gen4.1"),
            49 | 50 => (hd, "IMX636"),
            _ => return None,
        })
    }

    /// Whether the camera and the plugin are Prophesee's, as OpenEB's `check_header` decides:
    /// the legacy `integrator_name` stands for both when neither is named; no integrator line
    /// at all means Prophesee.
    fn prophesee_integrated(&self) -> bool {
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
        camera == Some("Prophesee") && plugin == Some("Prophesee")
    }

    /// The encoding the header names, as written (`EVT3`, `3.0`, …), and what it means; for
    /// EVT 2.1, with a note when the byte order was not stated.
    fn encoding(&self) -> Option<(String, Option<Encoding>, Option<String>)> {
        if let Some(f) = self.get("format") {
            let name = f.split(';').next().unwrap_or("").trim().to_string();
            let (enc, note) = match name.to_ascii_uppercase().as_str() {
                "EVT2" => (Some(Encoding::Evt2), None),
                "EVT21" => {
                    let (e, note) = self.evt21_order();
                    (Some(e), note)
                }
                "EVT3" => (Some(Encoding::Evt3), None),
                _ => (None, None),
            };
            return Some((format!("format {name}"), enc, note));
        }
        self.get("evt").map(|v| {
            let (enc, note) = match v {
                "2.0" | "2" => (Some(Encoding::Evt2), None),
                "2.1" => {
                    let (e, note) = self.evt21_order();
                    (Some(e), note)
                }
                "3.0" | "3" => (Some(Encoding::Evt3), None),
                _ => (None, None),
            };
            (format!("evt {v}"), enc, note)
        })
    }

    /// EVT 2.1's byte order as OpenEB decides it (`psee_raw_file_header.cpp`,
    /// `make_decoder.cpp`): the `endianness=` option of `% format` (the last one; without `=`,
    /// empty), else a non-empty `% endianness` line, else `legacy` for a Prophesee camera whose
    /// `% system_ID` is not 0 and below 0x37 (the IMX636 and Gen4 EVKs; read as C's `strtol`
    /// reads it, and -1 when missing or not a number), else whole words. Exactly `legacy` reads
    /// upper halves first; any other value, whole words. A note says which when the header did
    /// not state it.
    fn evt21_order(&self) -> (Encoding, Option<String>) {
        let option = self.get("format").and_then(|f| {
            f.split(';')
                .skip(1)
                .filter_map(|opt| {
                    let (k, v) = opt.split_once('=').unwrap_or((opt, ""));
                    (k.trim() == "endianness").then(|| v.trim().to_string())
                })
                .last()
        });
        let line = || {
            self.get("endianness")
                .map(str::trim)
                .filter(|v| !v.is_empty())
                .map(str::to_string)
        };
        if let Some(order) = option.or_else(line) {
            let enc = if order == "legacy" {
                Encoding::Evt21Legacy
            } else {
                Encoding::Evt21
            };
            return (enc, None);
        }
        let id = self.get("system_id").map_or(-1, leading_integer);
        if id != 0 && id < 0x37 && self.prophesee_integrated() {
            let why = match self.get("system_id") {
                Some(v) => format!("`% system_ID {v}`"),
                None => "a Prophesee header without a `% system_ID`".into(),
            };
            return (
                Encoding::Evt21Legacy,
                Some(format!(
                    "EVT 2.1 words read upper half first (an IMX636's order, OpenEB's `legacy`), \
                     as OpenEB reads {why} with no endianness stated; --format evt21 reads whole \
                     little-endian words"
                )),
            );
        }
        (
            Encoding::Evt21,
            Some(
                "EVT 2.1 words read little-endian whole (a GenX320's order; the header states no \
                 endianness); --format evt21-legacy reads an IMX636's"
                    .into(),
            ),
        )
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

/// The integer at the start of `v` as C's `strtol` reads it (leading spaces, a sign, decimal
/// digits; -1 where there are none, as OpenEB's `get_system_id` answers then).
fn leading_integer(v: &str) -> i64 {
    let v = v.trim_start();
    let (sign, digits) = match v.strip_prefix('-') {
        Some(rest) => (-1, rest),
        None => (1, v.strip_prefix('+').unwrap_or(v)),
    };
    let end = digits.bytes().take_while(u8::is_ascii_digit).count();
    digits[..end].parse::<i64>().map_or(-1, |n| sign * n)
}

/// The format an encoding reads as.
fn format_of(encoding: Encoding) -> Format {
    match encoding {
        Encoding::Evt2 => Format::Evt2,
        Encoding::Evt21 => Format::Evt21,
        Encoding::Evt21Legacy => Format::Evt21Legacy,
        Encoding::Evt3 => Format::Evt3,
    }
}

/// Streaming Prophesee RAW reader (EVT 2.0 / 2.1 / 3.0).
pub struct EvtReader<R> {
    src: Source<R>,
    info: StreamInfo,
    /// The words' decoder (the core's: the same one a microcontroller runs).
    decoder: EvtDecoder,
    /// The size came from `% system_ID` (a guess that `--width/--height` can correct).
    size_from_id: bool,
    /// EVT 2.1's byte order was not stated but assumed as OpenEB assumes it.
    order_assumed: bool,
    notes: ReadNotes,
    finished: bool,
}

impl<R: Read> EvtReader<R> {
    /// Parses the header. `format` is [`Format::Raw`] (encoding from the header),
    /// [`Format::Evt2`], [`Format::Evt21`], [`Format::Evt21Legacy`] or [`Format::Evt3`]; `size`
    /// is the fallback sensor size.
    pub fn new(inner: R, format: Format, size: Option<(u16, u16)>) -> Result<Self, ReadError> {
        let mut src = Source::new(inner, 0);
        let header = PercentHeader::read(&mut src, true)?;
        let mut notes = ReadNotes::default();
        let stated = header.encoding();
        let given = match format {
            Format::Evt2 => Some(Encoding::Evt2),
            Format::Evt21 => Some(Encoding::Evt21),
            Format::Evt21Legacy => Some(Encoding::Evt21Legacy),
            Format::Evt3 => Some(Encoding::Evt3),
            _ => None,
        };
        // EVT 2.1's byte order came from OpenEB's rule, not from the header (a reserved word
        // then hints at the other order).
        let mut order_assumed = false;
        let encoding = match (given, stated) {
            (Some(g), Some((name, e, _))) => {
                if e != Some(g) {
                    notes.assumptions.push(format!(
                        "the header says `{name}`{}, which --format {} overrides",
                        match e {
                            Some(e @ (Encoding::Evt21 | Encoding::Evt21Legacy)) =>
                                format!(" (its byte order: {})", format_of(e).name()),
                            _ => String::new(),
                        },
                        format.name()
                    ));
                }
                g
            }
            (Some(g), None) => g,
            (None, Some((_, Some(e), note))) => {
                order_assumed = note.is_some();
                notes.assumptions.extend(note);
                e
            }
            (None, Some((name, None, _))) => {
                return Err(ReadError::Unsupported(format!(
                    "Prophesee RAW encoding `{name}`; EVT 2.0, EVT 2.1 and EVT 3.0 are read"
                )))
            }
            (None, None) => {
                return Err(ReadError::Unsupported(
                    "the RAW header names no encoding (no `% evt` or `% format` line); pass \
                     --format evt2, evt21, evt21-legacy or evt3"
                        .into(),
                ))
            }
        };
        let from_id = header.system_id_size().filter(|_| size.is_none());
        // The size, and whether it is `% system_ID`'s guess.
        let (size, size_from_id) = match (header.size(), from_id) {
            (Some(s), _) => (Some(s), false),
            (None, Some(((w, h), sensor))) => {
                notes.assumptions.push(format!(
                    "sensor size {w}x{h} from `% system_ID {}` ({sensor} sensor, as OpenEB \
                     reads a header without a size; --width/--height override it)",
                    header.get("system_id").unwrap_or_default()
                ));
                (Some((w, h)), true)
            }
            (None, None) => {
                if let Some((w, h)) = size {
                    notes
                        .assumptions
                        .push(format!("sensor size {w}x{h} from --width/--height"));
                }
                (size, false)
            }
        };
        Ok(Self {
            src,
            info: StreamInfo {
                format: format_of(encoding),
                cameras: vec![CameraInfo {
                    id: 0,
                    width: size.map(|s| s.0),
                    height: size.map(|s| s.1),
                    name: header.camera_name(),
                }],
                event_count: None,
            },
            decoder: EvtDecoder::new(encoding, size),
            size_from_id,
            order_assumed,
            notes,
            finished: false,
        })
    }

    /// The encoding in use.
    pub fn encoding(&self) -> Encoding {
        self.decoder.encoding()
    }

    fn fill(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        let encoding = self.decoder.encoding();
        let word = encoding.word_bytes();
        // Stop while a whole word's events (a vector: 12 in EVT 3.0, 32 in EVT 2.1) still fit
        // the batch.
        while batch.len() + encoding.max_events_per_word() <= BATCH_EVENTS {
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
            let room = BATCH_EVENTS - batch.len();
            let p = self
                .decoder
                .decode_with(words, room, |e| batch.push(0, e))
                .map_err(|e| self.error(base, e))?;
            self.src.consume(p.bytes);
        }
        Ok(())
    }

    /// The reader's error for the decoder's, at file offset `base` + the word's index.
    #[cold]
    #[inline(never)]
    fn error(&self, base: u64, e: EvtError) -> ReadError {
        let corrupt = |at: usize, message: String| ReadError::Corrupt {
            offset: base + at as u64,
            message,
        };
        match e {
            EvtError::ReservedType { at, word } => corrupt(
                at,
                match self.decoder.encoding() {
                    Encoding::Evt2 => format!(
                        "EVT 2.0 word {word:#010x} has the reserved type {:#x}",
                        word >> 28
                    ),
                    e @ (Encoding::Evt21 | Encoding::Evt21Legacy) => format!(
                        "EVT 2.1 word {word:#018x} has the reserved type {:#x}{}",
                        word >> 60,
                        if self.order_assumed {
                            format!(
                                " (the header states no byte order and {} was assumed, as \
                                 OpenEB assumes it: try --format {})",
                                format_of(e).name(),
                                if e == Encoding::Evt21 {
                                    "evt21-legacy"
                                } else {
                                    "evt21"
                                }
                            )
                        } else {
                            String::new()
                        }
                    ),
                    Encoding::Evt3 => format!(
                        "EVT 3.0 word {word:#06x} has the reserved type {:#x}",
                        word >> 12
                    ),
                },
            ),
            EvtError::OutsideSensor { at, x, y, size } => {
                let mut e = out_of_sensor(base + at as u64, x, y, size);
                if let (true, ReadError::Corrupt { message, .. }) = (self.size_from_id, &mut e) {
                    message.push_str(" (the size `system_ID` implies; pass --width/--height)");
                }
                e
            }
            EvtError::WideX { at, x } => corrupt(at, format!("x = {x} does not fit 16 bits")),
            EvtError::TimeOverflow { at } => time_overflow(base + at as u64),
        }
    }
}

impl<R: Read> super::source::Fill for EvtReader<R> {
    fn info(&self) -> &StreamInfo {
        &self.info
    }
    fn notes(&self) -> ReadNotes {
        let c = self.decoder.counts();
        ReadNotes {
            skipped_records: c.skipped_words,
            dropped_events: c.dropped_events,
            timestamp_wraps: c.timestamp_wraps,
            implied_time_highs: c.implied_time_highs,
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

/// Whether EVT words hold a `width` × `height` sensor (11-bit addresses: up to 2,048), as
/// [`Evt3Writer::new`] and [`Evt2Writer::new`] check before they write anything.
pub fn check_raw_size(width: u16, height: u16) -> std::io::Result<()> {
    if !(1..=2048).contains(&width) || !(1..=2048).contains(&height) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "Prophesee EVT words hold sensors up to 2048 x 2048 (11-bit addresses), not \
                 {width} x {height}"
            ),
        ));
    }
    Ok(())
}

/// Time-high periods a time-high word may go back: less than half the 12-bit counter, so that
/// a reader does not take the step for a wrap ([`Unwrapper`](evpose_core::evt::Unwrapper)).
const WRITE_HIGH_STEP: i64 = 2047;

/// The longest gap [`Evt3Writer`] writes, in 4,096-µs periods (one word each): 2^24 periods,
/// about 19 hours and 32 MiB of words.
const MAX_WRITE_GAP_PERIODS: i64 = 1 << 24;

/// Writes events as a Prophesee RAW file in EVT 3.0: a `%` header that states the size
/// (`% format EVT3;height=H;width=W`, `% geometry`, `% end`), then per event the words that
/// changed (time high, time low, row) and one `EVT_ADDR_X` word. The time high is written twice
/// at the start (a reader then never takes a time-low step back for an unwritten period, see
/// the module documentation) and once per period, through gaps too (as a sensor writes it:
/// some readers take only the next period or the counter's wrap).
///
/// EVT 3.0 carries 24 bits of time from 0: every time is written less the 2^24-µs boundary at
/// or before the first event's ([`Evt3Writer::origin`]: 0 for a recording that starts below
/// 16.8 s; a DV recording's Unix times keep their low 24 bits). Refused: a time before that
/// origin, a step back of more than 2,047 periods (8.4 s) or across a 2^24-µs boundary
/// (readers that follow OpenEB take a time-high word below the one before as given, or as a
/// wrap forward), a gap of more than 2^24 periods (19 hours: one word per period), and a pixel
/// outside the stated sensor. Readers that keep time from going back (faery) read steps back
/// differently.
pub struct Evt3Writer<W: std::io::Write> {
    out: WordOut<W>,
    size: (u16, u16),
    origin: Option<i64>,
    high: Option<i64>,
    low: Option<i64>,
    y: Option<u16>,
}

impl<W: std::io::Write> Evt3Writer<W> {
    /// Writes the header of a `width` × `height` sensor (at most 2,048 × 2,048: 11-bit
    /// addresses).
    pub fn new(mut out: W, width: u16, height: u16) -> std::io::Result<Self> {
        check_raw_size(width, height)?;
        write!(
            out,
            "% evt 3.0\n% format EVT3;height={height};width={width}\n% geometry {width}x{height}\n\
             % integrator_name evpose\n% end\n"
        )?;
        Ok(Self {
            out: WordOut::new(out),
            size: (width, height),
            origin: None,
            high: None,
            low: None,
            y: None,
        })
    }

    /// Appends a word of type `ty` (its payload's low 12 bits).
    fn word(&mut self, ty: u16, payload: i64) -> std::io::Result<()> {
        let w = (ty << 12) | (payload & 0xFFF) as u16;
        self.out.push(&w.to_le_bytes())
    }

    /// Appends `events` in their order.
    pub fn write(&mut self, events: &[Event]) -> std::io::Result<()> {
        let invalid = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
        for e in events {
            // The 2^24-µs boundary at or before the first event: times keep their low 24 bits,
            // as a sensor's EVT 3.0 would hold them.
            let t = placed(e, self.size, &mut self.origin, |t| {
                t - t.rem_euclid(1 << 24)
            })?;
            let (high, low) = (t >> 12, t & 0xFFF);
            match self.high {
                None => {
                    self.word(0x8, high)?;
                    self.word(0x8, high)?;
                    self.low = None;
                }
                Some(mut at) if at != high => {
                    // Back: within 2,047 periods and the same 2^24-µs span (a reader that
                    // follows OpenEB takes a time-high word below the one before as a wrap
                    // only forward).
                    if high < at && (at - high > WRITE_HIGH_STEP || high >> 12 != at >> 12) {
                        return Err(invalid(format!(
                            "timestamp {} µs goes back past the 2^24-µs boundary of the time \
                             before, or more than {WRITE_HIGH_STEP} time-high periods: EVT 3.0 \
                             cannot hold that",
                            e.t
                        )));
                    }
                    if high - at > MAX_WRITE_GAP_PERIODS {
                        return Err(invalid(format!(
                            "timestamp {} µs comes {} s after the one before: EVT 3.0 writes a \
                             time-high word per 4,096 µs, and gaps over {} s are refused",
                            e.t,
                            ((high - at) << 12) / 1_000_000,
                            (MAX_WRITE_GAP_PERIODS << 12) / 1_000_000
                        )));
                    }
                    // Every period on the way, as a sensor writes them (faery's reader, for
                    // one, takes only the next period or the counter's wrap).
                    while high - at > 1 {
                        at += 1;
                        self.word(0x8, at)?;
                    }
                    self.word(0x8, high)?;
                    self.low = None;
                }
                Some(_) => {}
            }
            self.high = Some(high);
            if self.low != Some(low) {
                self.word(0x6, low)?;
                self.low = Some(low);
            }
            if self.y != Some(e.y) {
                self.word(0x0, i64::from(e.y))?;
                self.y = Some(e.y);
            }
            self.word(0x2, (i64::from(e.on) << 11) | i64::from(e.x))?;
        }
        Ok(())
    }

    /// The time (µs) subtracted from every event's: the 2^24-µs boundary at or before the first
    /// event's; `None` before the first event.
    pub fn origin(&self) -> Option<i64> {
        self.origin
    }

    /// Writes what is buffered and hands the output back.
    pub fn finish(self) -> std::io::Result<W> {
        self.out.finish()
    }
}

/// A RAW writer's words, collected and written to `out` 64 KiB at a time (faster than a
/// `BufWriter`'s call per 2- to 8-byte word: `convert` to EVT 3.0 of 8 M events took 103–119 ms
/// against 125–134 that way).
struct WordOut<W: std::io::Write> {
    out: W,
    words: Vec<u8>,
}

impl<W: std::io::Write> WordOut<W> {
    fn new(out: W) -> Self {
        Self {
            out,
            words: Vec::with_capacity(1 << 16),
        }
    }

    /// Appends a word's bytes; writes the buffer out when full.
    fn push(&mut self, word: &[u8]) -> std::io::Result<()> {
        self.words.extend_from_slice(word);
        if self.words.len() >= 1 << 16 {
            self.out.write_all(&self.words)?;
            self.words.clear();
        }
        Ok(())
    }

    /// Writes what is buffered, flushes, and hands the output back.
    fn finish(mut self) -> std::io::Result<W> {
        self.out.write_all(&self.words)?;
        self.out.flush()?;
        Ok(self.out)
    }
}

/// An event's time for a RAW writer, from `origin` (set by the first call to `first(t)` of the
/// first event's time); an error for a pixel outside `size` or a time before the origin or 2^62
/// µs after it.
fn placed(
    e: &Event,
    (w, h): (u16, u16),
    origin: &mut Option<i64>,
    first: impl FnOnce(i64) -> i64,
) -> std::io::Result<i64> {
    let invalid = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
    if e.x >= w || e.y >= h {
        return Err(invalid(format!(
            "event at x = {}, y = {} lies outside the {w}x{h} sensor",
            e.x, e.y
        )));
    }
    let origin = *origin.get_or_insert_with(|| first(e.t));
    e.t.checked_sub(origin)
        .filter(|t| (0..1 << 62).contains(t))
        .ok_or_else(|| {
            invalid(format!(
                "timestamp {} µs: the file holds times from {origin} µs (chosen from the first \
                 event's) to 2^62 µs after",
                e.t
            ))
        })
}

/// [`Evt2Writer`]'s origin for a first event at `t`: 0 where `t` lies in [0, 2^32) µs (times
/// are kept as they are: the counter wraps 3.6 hours or more later); else the 64-µs boundary at
/// or before [`EVT2_ORIGIN_LEAD`] before it (a Unix-time recording: times keep their low 6
/// bits, events up to that lead before the first are written), so that a recording shorter
/// than 4.8 hours less the lead never wraps the time-high counter (OpenEB's EVT 2.0 decoder
/// looks for a wrap only between read buffers, with a 10 ms threshold: it can miss one).
fn evt2_origin(t: i64) -> i64 {
    if (0..1 << 32).contains(&t) {
        return 0;
    }
    let lead = t.saturating_sub(EVT2_ORIGIN_LEAD);
    lead - lead.rem_euclid(64)
}

/// How far before the first event [`Evt2Writer`]'s origin lies: 2^20 µs (about a second), for
/// events a little out of order.
const EVT2_ORIGIN_LEAD: i64 = 1 << 20;

/// The widest step, in EVT 2.0 / 2.1 time-high periods (64 µs), that [`Evt2Writer`] writes as
/// one word: under half the 28-bit counter's range, so that a reader unwraps it forward.
const MAX_WRITE_STEP_PERIODS_2: i64 = (1 << 27) - 1;

/// Writes events as a Prophesee RAW file in EVT 2.0 or EVT 2.1 (either byte order,
/// [`Encoding::Evt21`] as a GenX320 writes it, [`Encoding::Evt21Legacy`] as an IMX636 does),
/// streaming: a header stating the size (and, for EVT 2.1, the byte order as OpenEB writes it:
/// `% format EVT21;endianness=…` and an `% endianness` line), a time-high word wherever an
/// event's `t >> 6` changes, and one event word per event; in EVT 2.1 an event joins the word
/// before when it has the same time, row and polarity, lies in the same 32 columns (the word's
/// x is a multiple of 32, as a sensor's) and to the right of the word's last event, so that
/// reading gives the events in their order.
///
/// Times are written as they are when the first lies in [0, 2^32) µs, else from the 64-µs
/// boundary at or before 2^20 µs (about a second) before the first event's: EVT 2.x holds 34
/// bits of time (4.8 hours), so a Unix-time recording shorter than that never wraps the
/// time-high counter; a longer one wraps it as a sensor's does, through its last value and
/// 0 (OpenEB's EVT 2.1 decoder takes only that step back as a wrap; its EVT 2.0 decoder looks
/// for wraps between read buffers and can miss one). Refused with an error: a step back across
/// a wrap of the counter or of 2^27 time-high periods (about 2^33 µs) or more, a step forward
/// of 2^27 periods or more (a reader could not tell either from the other), a time before the
/// origin, a pixel outside the stated sensor. Readers differ on steps back: evpose and OpenEB
/// take a small one as given (OpenEB logs it), evutils as a wrap, faery keeps time from going
/// back.
pub struct Evt2Writer<W: std::io::Write> {
    out: WordOut<W>,
    encoding: Encoding,
    size: (u16, u16),
    origin: Option<i64>,
    /// The last time-high value written (`t >> 6`, from the origin).
    high: Option<i64>,
    /// EVT 2.1: the word being filled (its upper half, mask, and the column of its last event).
    pending: Option<(u32, u32, u16)>,
}

impl<W: std::io::Write> Evt2Writer<W> {
    /// Writes the header of a `width` × `height` sensor (at most 2,048 × 2,048: 11-bit
    /// addresses) in `encoding` (EVT 2.0 or 2.1; EVT 3.0 is [`Evt3Writer`]'s).
    pub fn new(mut out: W, encoding: Encoding, width: u16, height: u16) -> std::io::Result<Self> {
        check_raw_size(width, height)?;
        let header = match encoding {
            Encoding::Evt2 => format!("% evt 2.0\n% format EVT2;height={height};width={width}\n"),
            Encoding::Evt21 | Encoding::Evt21Legacy => {
                let order = if encoding == Encoding::Evt21 {
                    "little"
                } else {
                    "legacy"
                };
                format!(
                    "% evt 2.1\n% format EVT21;endianness={order};height={height};\
                     width={width}\n% endianness {order}\n"
                )
            }
            Encoding::Evt3 => {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidInput,
                    "EVT 3.0 is written by Evt3Writer",
                ))
            }
        };
        write!(
            out,
            "{header}% geometry {width}x{height}\n% integrator_name evpose\n% end\n"
        )?;
        Ok(Self {
            out: WordOut::new(out),
            encoding,
            size: (width, height),
            origin: None,
            high: None,
            pending: None,
        })
    }

    /// Appends a word: its upper half (an EVT 2.0 word) and, in EVT 2.1, its mask.
    fn word(&mut self, upper: u32, mask: u32) -> std::io::Result<()> {
        match self.encoding {
            Encoding::Evt21 => self
                .out
                .push(&(u64::from(upper) << 32 | u64::from(mask)).to_le_bytes()),
            Encoding::Evt21Legacy => {
                let (u, m) = (upper.to_le_bytes(), mask.to_le_bytes());
                self.out
                    .push(&[u[0], u[1], u[2], u[3], m[0], m[1], m[2], m[3]])
            }
            _ => self.out.push(&upper.to_le_bytes()),
        }
    }

    /// Writes the EVT 2.1 word being filled, if any.
    fn flush_pending(&mut self) -> std::io::Result<()> {
        match self.pending.take() {
            Some((upper, mask, _)) => self.word(upper, mask),
            None => Ok(()),
        }
    }

    /// Appends `events` in their order.
    pub fn write(&mut self, events: &[Event]) -> std::io::Result<()> {
        let invalid = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
        for e in events {
            let t = placed(e, self.size, &mut self.origin, evt2_origin)?;
            let high = t >> 6;
            if self.high != Some(high) {
                self.flush_pending()?;
                if let Some(at) = self.high {
                    if high < at && high >> 28 != at >> 28 {
                        return Err(invalid(format!(
                            "timestamp {} µs goes back across a wrap of the 28-bit time-high \
                             counter (a 2^34-µs boundary from the origin): EVT 2.x cannot hold \
                             that",
                            e.t
                        )));
                    }
                    if (high - at).abs() > MAX_WRITE_STEP_PERIODS_2 {
                        return Err(invalid(format!(
                            "timestamp {} µs lies 2^27 time-high periods (about 2^33 µs) or more \
                             {} the one before: a reader could not tell that step from one the \
                             other way",
                            e.t,
                            if high > at { "after" } else { "before" }
                        )));
                    }
                    // Across the counter's wrap, its last value then 0, as a sensor's counter
                    // steps: OpenEB takes only that step back as a wrap.
                    if high >> 28 > at >> 28 {
                        if at & 0x0FFF_FFFF != 0x0FFF_FFFF {
                            self.word(0x8 << 28 | 0x0FFF_FFFF, 0)?;
                        }
                        if high & 0x0FFF_FFFF != 0 {
                            self.word(0x8 << 28, 0)?;
                        }
                    }
                }
                self.word(0x8 << 28 | (high & 0x0FFF_FFFF) as u32, 0)?;
                self.high = Some(high);
            }
            let upper = |x: u16| {
                u32::from(e.on) << 28
                    | ((t & 0x3F) as u32) << 22
                    | u32::from(x) << 11
                    | u32::from(e.y)
            };
            if self.encoding == Encoding::Evt2 {
                self.word(upper(e.x), 1)?;
                continue;
            }
            let base = e.x & !31;
            match &mut self.pending {
                Some((u, mask, last)) if *u == upper(base) && e.x > *last => {
                    *mask |= 1 << (e.x - base);
                    *last = e.x;
                }
                _ => {
                    self.flush_pending()?;
                    self.pending = Some((upper(base), 1 << (e.x - base), e.x));
                }
            }
        }
        Ok(())
    }

    /// The time (µs) subtracted from every event's: 0 when the first event's time lies in
    /// [0, 2^32) µs, else the 64-µs boundary at or before 2^20 µs before it; `None` before the
    /// first event.
    pub fn origin(&self) -> Option<i64> {
        self.origin
    }

    /// Writes what is buffered and hands the output back.
    pub fn finish(mut self) -> std::io::Result<W> {
        self.flush_pending()?;
        self.out.finish()
    }
}

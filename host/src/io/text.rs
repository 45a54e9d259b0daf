//! Text / CSV events, one per line: `t x y p` (the RPG event-camera datasets' layout).
//!
//! # Lines
//!
//! * Fields are separated by spaces or tabs (runs count as one) or by a comma or semicolon
//!   (with optional spaces around it); an empty field between two commas is an error, never a
//!   shifted column.
//! * Empty lines and lines starting with `#` or `%` are comments.
//! * Without a header row a line has exactly four fields, `t x y p`. A first non-comment line
//!   that is not all numbers is a header row naming the columns, in any order and among
//!   others: `t`/`ts`/`time`/`timestamp`, `x`, `y`, `p`/`pol`/`polarity`/`on`; a unit suffix
//!   on the time column (`t_us`, `timestamp[s]`, `time(ms)`) states the time unit, and
//!   `x@W`, `y@H` (faery's CSV: `t,x@346,y@260,on`) the sensor size. Every line then has
//!   as many fields as the header row. A comment line that names all four columns the same
//!   way (`# x y t p`, as NumPy's `savetxt(..., header="x y t p")` writes it) is that header.
//! * x and y are integers 0–65535 (`12.0` is accepted), p is 0/1, -1/1 or true/false (any
//!   case: pandas writes a boolean column as `True`/`False`).
//! * A first line of exactly two integers is the sensor size `W H` (the e2vid convention for
//!   RPG-style `events.txt`); it wins over `--width/--height`, like a size any format states.
//!
//! # Time unit
//!
//! In order: `--time-unit`, the header's unit suffix, else detection from the first
//! [`DETECT_BYTES`] after the header: seconds if a timestamp there has a fraction (a value,
//! not a spelling: `223.0` and `2.23e+02`, which NumPy's `savetxt` writes for whole
//! microseconds, are integers), microseconds otherwise. The decision is recorded in
//! [`ReadNotes::assumptions`]. When microseconds were detected, a later timestamp with a
//! fraction of a microsecond is an error (the detection was wrong; pass `--time-unit`), not a
//! silent rounding. Timestamps are converted exactly (decimal arithmetic, no float rounding)
//! and rounded half away from zero to whole microseconds.
//!
//! # Damage
//!
//! A malformed line (wrong field count, a field that is not a number, a coordinate or polarity
//! out of range, a pixel outside the `--width/--height` sensor, a timestamp beyond 64-bit
//! microseconds) is an error naming its line number and byte offset. Lines are limited to
//! [`MAX_LINE_BYTES`].

use std::io::Read;

use evpose_core::Event;

use super::source::Source;
use super::{
    Batch, CameraInfo, Format, ReadError, ReadNotes, StreamInfo, TimeUnit, BATCH_EVENTS,
    DETECT_BYTES,
};

/// Longest line accepted, in bytes.
pub const MAX_LINE_BYTES: usize = 4096;

/// Most fields a line may have.
pub const MAX_FIELDS: usize = 64;

/// Lines [`looks_like_text`] and the time-unit detection look at.
const DETECT_LINES: usize = 1000;

/// Which field holds what.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Columns {
    t: usize,
    x: usize,
    y: usize,
    p: usize,
    /// Fields every line must have.
    count: usize,
}

const T_X_Y_P: Columns = Columns {
    t: 0,
    x: 1,
    y: 2,
    p: 3,
    count: 4,
};

/// How lines are read, and where the reader is.
struct LineState {
    cols: Columns,
    /// Power of ten from the file's time unit to microseconds.
    exponent: i32,
    /// The unit was detected as microseconds: fractions are errors.
    strict: bool,
    size: Option<(u16, u16)>,
    /// 1-based number of the next line.
    line: u64,
}

/// Streaming text reader.
pub struct TextReader<R> {
    src: Source<R>,
    info: StreamInfo,
    state: LineState,
    notes: ReadNotes,
    order: super::OrderCheck,
    finished: bool,
}

impl<R: Read> TextReader<R> {
    /// Reads comments and the header row, and settles the time unit (`unit`, else from the
    /// header, else detected); `size` is the sensor size for the coordinate check.
    pub fn new(
        inner: R,
        unit: Option<TimeUnit>,
        size: Option<(u16, u16)>,
    ) -> Result<Self, ReadError> {
        let mut src = Source::new(inner, 0);
        src.fill(3)?;
        if src.data().starts_with(b"\xEF\xBB\xBF") {
            src.consume(3);
        }
        let mut line = 1u64;
        let mut notes = ReadNotes::default();
        let mut cols = T_X_Y_P;
        let mut header_unit = None;
        // A size in the header row's names (`x@W`, `y@H`).
        let mut header_size = None;
        // A first line of two integers is the sensor size (the e2vid / RPG `W H` convention).
        let mut stated_size = None;
        let mut first = true;
        // Comments, then either the header row or the first data line (left unread).
        loop {
            let at = src.offset();
            let have = src.fill(MAX_LINE_BYTES + 1)?;
            if have == 0 {
                break;
            }
            let data = src.data();
            let (body, len) = match data.iter().position(|&b| b == b'\n') {
                Some(i) => (&data[..i], i + 1),
                None if have > MAX_LINE_BYTES => return Err(long_line(at, line)),
                None => (data, have),
            };
            let body = trim(body);
            if is_comment(body) {
                // A comment that names every column is a header (NumPy's `savetxt(header=…)`
                // writes `# x y t p`); any other comment is skipped.
                let named = trim(body.get(1..).unwrap_or_default());
                let mut fields = [&[][..]; MAX_FIELDS];
                if let Ok(h) = split_fields(named, &mut fields)
                    .map_err(String::from)
                    .and_then(|n| header_columns(&fields[..n]))
                {
                    cols = h.cols;
                    header_unit = h.unit;
                    header_size = h.size.or(header_size);
                    notes.assumptions.extend(h.one_size);
                    notes.assumptions.push(format!(
                        "columns from the commented header row: {}",
                        String::from_utf8_lossy(body)
                    ));
                }
                src.consume(len);
                line += 1;
                continue;
            }
            let mut fields = [&[][..]; MAX_FIELDS];
            let n = split_fields(body, &mut fields).map_err(|m| bad_line(at, line, m))?;
            if let (true, Some(wh)) = (first, sensor_size(&fields[..n])) {
                stated_size = Some(wh);
                notes.assumptions.push(format!(
                    "sensor size {} x {} from the first line (the e2vid convention)",
                    wh.0, wh.1
                ));
                src.consume(len);
                line += 1;
                first = false;
                continue;
            }
            if fields[..n].iter().all(|f| is_value(f)) {
                break;
            }
            let h = header_columns(&fields[..n]).map_err(|m| bad_line(at, line, &m))?;
            cols = h.cols;
            header_unit = h.unit;
            header_size = h.size.or(header_size);
            notes.assumptions.extend(h.one_size);
            notes.assumptions.push(format!(
                "columns from the header row: {}",
                String::from_utf8_lossy(body)
            ));
            src.consume(len);
            line += 1;
            break;
        }
        let (unit, strict) = match (unit, header_unit) {
            (Some(u), _) => (u, false),
            (None, Some(u)) => {
                notes
                    .assumptions
                    .push(format!("timestamps in {} (header row)", u.name()));
                (u, false)
            }
            (None, None) => {
                src.fill(DETECT_BYTES)?;
                let seconds = has_fractional_time(src.data(), cols);
                let (u, why) = if seconds {
                    (TimeUnit::S, "a timestamp in the first lines has a fraction")
                } else {
                    (TimeUnit::Us, "the first lines have integer timestamps")
                };
                notes.assumptions.push(format!(
                    "timestamps in {} (detected: {why}; --time-unit overrides)",
                    u.name()
                ));
                (u, u == TimeUnit::Us)
            }
        };
        if let Some((w, h)) = header_size.filter(|_| stated_size.is_none()) {
            notes.assumptions.push(format!(
                "sensor size {w} x {h} from the header row (`x@{w}`, `y@{h}`)"
            ));
        }
        // A size the file states wins over the caller's (as for every format).
        let size = stated_size.or(header_size).or(size);
        Ok(Self {
            src,
            info: StreamInfo {
                format: Format::Text,
                cameras: vec![CameraInfo {
                    id: 0,
                    width: size.map(|s| s.0),
                    height: size.map(|s| s.1),
                    name: None,
                }],
                event_count: None,
            },
            state: LineState {
                cols,
                exponent: unit.exponent_to_us(),
                strict,
                size,
                line,
            },
            notes,
            order: super::OrderCheck::default(),
            finished: false,
        })
    }

    fn fill(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        let start = batch.len();
        self.fill_lines(batch)?;
        let columns = if self.state.cols == T_X_Y_P {
            "t x y p (a file without a header row; name the columns in one, e.g. `x y t p`)"
        } else {
            "the header row's"
        };
        self.order.check(&batch.events[start..], columns)
    }

    fn fill_lines(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        while batch.len() < BATCH_EVENTS {
            let have = self.src.fill(1)?;
            if have == 0 {
                self.finished = true;
                return Ok(());
            }
            let base = self.src.offset();
            let used = parse_lines(self.src.data(), base, &mut self.state, batch)?;
            if used > 0 {
                self.src.consume(used);
                continue;
            }
            // No whole line is buffered.
            if have > MAX_LINE_BYTES {
                return Err(long_line(base, self.state.line));
            }
            if self.src.fill(have + 1)? == have {
                // The last line has no line end.
                let data = self.src.data();
                parse_line(data, base, &mut self.state, batch)?;
                self.src.consume(have);
            }
        }
        Ok(())
    }
}

/// Parses the whole lines of `data` (at file offset `base`) until the batch is full; returns
/// the bytes used.
fn parse_lines(
    data: &[u8],
    base: u64,
    state: &mut LineState,
    batch: &mut Batch,
) -> Result<usize, ReadError> {
    let mut pos = 0;
    while batch.len() < BATCH_EVENTS {
        let Some(len) = data[pos..].iter().position(|&b| b == b'\n') else {
            break;
        };
        if len > MAX_LINE_BYTES {
            return Err(long_line(base + pos as u64, state.line));
        }
        parse_line(&data[pos..pos + len], base + pos as u64, state, batch)?;
        pos += len + 1;
    }
    Ok(pos)
}

/// Parses one line (without its `\n`) at file offset `at`.
fn parse_line(
    raw: &[u8],
    at: u64,
    state: &mut LineState,
    batch: &mut Batch,
) -> Result<(), ReadError> {
    let line = state.line;
    state.line += 1;
    let body = trim(raw);
    if is_comment(body) {
        return Ok(());
    }
    let mut fields = [&[][..]; MAX_FIELDS];
    let n = split_fields(body, &mut fields).map_err(|m| bad_line(at, line, m))?;
    let c = state.cols;
    if n != c.count {
        return Err(bad_line(
            at,
            line,
            &format!("{n} fields, expected {}", c.count),
        ));
    }
    let field = |i: usize| String::from_utf8_lossy(fields[i]).into_owned();
    let t_dec = parse_decimal(fields[c.t]);
    let t = t_dec
        .and_then(|d| d.scaled(state.exponent, state.strict))
        .ok_or_else(|| {
            let rounded = t_dec.and_then(|d| d.scaled(state.exponent, false));
            let why = if state.strict && rounded.is_some() {
                " (a fraction of a microsecond, but integer microseconds were detected; \
                 pass --time-unit)"
            } else {
                ""
            };
            bad_line(
                at,
                line,
                &format!("timestamp {:?} is not valid{why}", field(c.t)),
            )
        })?;
    let coord = |i: usize, what: &str| {
        whole_u16(fields[i])
            .ok_or_else(|| bad_line(at, line, &format!("{what} {:?} is not valid", field(i))))
    };
    let x = coord(c.x, "x")?;
    let y = coord(c.y, "y")?;
    let on = match parse_decimal(fields[c.p]).and_then(|d| d.scaled(0, true)) {
        Some(1) => true,
        Some(0 | -1) => false,
        _ => match boolean(fields[c.p]) {
            Some(on) => on,
            None => {
                return Err(bad_line(
                    at,
                    line,
                    &format!("polarity {:?} is not 0/1, -1/1 or true/false", field(c.p)),
                ))
            }
        },
    };
    if let Some((w, h)) = state.size {
        if x >= w || y >= h {
            return Err(bad_line(
                at,
                line,
                &format!("x = {x}, y = {y} lies outside the {w}x{h} sensor"),
            ));
        }
    }
    batch.push(0, Event::new(x, y, t, on));
    Ok(())
}

/// `true`/`false` in any case (Python's `True`/`False`, as pandas writes a boolean polarity).
fn boolean(field: &[u8]) -> Option<bool> {
    if field.eq_ignore_ascii_case(b"true") {
        Some(true)
    } else if field.eq_ignore_ascii_case(b"false") {
        Some(false)
    } else {
        None
    }
}

/// A data field: a number, or a boolean polarity.
fn is_value(field: &[u8]) -> bool {
    parse_decimal(field).is_some() || boolean(field).is_some()
}

/// A field holding a whole number 0..=65535 (`12.0` included): a coordinate.
fn whole_u16(field: &[u8]) -> Option<u16> {
    parse_decimal(field)
        .and_then(|d| d.scaled(0, true))
        .and_then(|v| u16::try_from(v).ok())
}

/// A line of exactly two integers 1..=65535: a sensor size `W H`.
fn sensor_size(fields: &[&[u8]]) -> Option<(u16, u16)> {
    let dim = |f: &[u8]| whole_u16(f).filter(|&v| v > 0);
    match fields {
        [w, h] => Some((dim(w)?, dim(h)?)),
        _ => None,
    }
}

fn bad_line(offset: u64, line: u64, message: &str) -> ReadError {
    ReadError::Corrupt {
        offset,
        message: format!("line {line}: {message}"),
    }
}

fn long_line(offset: u64, line: u64) -> ReadError {
    bad_line(
        offset,
        line,
        &format!("longer than {MAX_LINE_BYTES} bytes (not a text event file?)"),
    )
}

fn trim(mut s: &[u8]) -> &[u8] {
    while let [b' ' | b'\t' | b'\r', rest @ ..] = s {
        s = rest;
    }
    while let [rest @ .., b' ' | b'\t' | b'\r'] = s {
        s = rest;
    }
    s
}

fn is_comment(body: &[u8]) -> bool {
    matches!(body.first(), None | Some(b'#' | b'%'))
}

/// Splits a trimmed line into fields; returns how many.
fn split_fields<'a>(
    line: &'a [u8],
    out: &mut [&'a [u8]; MAX_FIELDS],
) -> Result<usize, &'static str> {
    let is_space = |b: u8| b == b' ' || b == b'\t';
    let is_sep = |b: u8| is_space(b) || b == b',' || b == b';';
    let mut i = 0;
    let mut n = 0;
    while i < line.len() {
        let start = i;
        while i < line.len() && !is_sep(line[i]) {
            i += 1;
        }
        if i == start {
            return Err("empty field");
        }
        if n == MAX_FIELDS {
            return Err("too many fields");
        }
        out[n] = &line[start..i];
        n += 1;
        while i < line.len() && is_space(line[i]) {
            i += 1;
        }
        if i < line.len() && (line[i] == b',' || line[i] == b';') {
            i += 1;
            while i < line.len() && is_space(line[i]) {
                i += 1;
            }
            if i == line.len() {
                return Err("empty last field");
            }
        }
    }
    Ok(n)
}

/// A decimal number: `(-1)^negative × digits × 10^exponent`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Decimal {
    negative: bool,
    digits: u64,
    exponent: i32,
}

/// Parses `[+-]digits[.digits][(e|E)[+-]digits]`; digits past the 19th significant one are
/// dropped (far below a microsecond for any timestamp).
fn parse_decimal(s: &[u8]) -> Option<Decimal> {
    let (negative, mut s) = match s {
        [b'-', rest @ ..] => (true, rest),
        [b'+', rest @ ..] => (false, rest),
        _ => (false, s),
    };
    let mut digits = 0u64;
    let mut exponent = 0i32;
    let mut seen = false;
    let mut significant = 0;
    let mut fraction = false;
    while let [c, rest @ ..] = s {
        match c {
            b'0'..=b'9' => {
                seen = true;
                if digits == 0 && *c == b'0' {
                    if fraction {
                        exponent -= 1;
                    }
                } else if significant < 19 {
                    digits = digits * 10 + u64::from(c - b'0');
                    significant += 1;
                    if fraction {
                        exponent -= 1;
                    }
                } else if !fraction {
                    exponent += 1;
                }
            }
            b'.' if !fraction => fraction = true,
            _ => break,
        }
        s = rest;
    }
    if !seen {
        return None;
    }
    if let [b'e' | b'E', rest @ ..] = s {
        let (neg, mut r) = match rest {
            [b'-', r @ ..] => (true, r),
            [b'+', r @ ..] => (false, r),
            _ => (false, rest),
        };
        let mut e = 0i32;
        let mut any = false;
        while let [c @ b'0'..=b'9', more @ ..] = r {
            e = (e * 10 + i32::from(c - b'0')).min(10_000);
            any = true;
            r = more;
        }
        if !any {
            return None;
        }
        exponent += if neg { -e } else { e };
        s = r;
    }
    s.is_empty().then_some(Decimal {
        negative,
        digits,
        exponent,
    })
}

impl Decimal {
    /// The value × 10^`shift` as an integer, rounded half away from zero; `None` when it
    /// overflows an `i64`, or when `exact` and rounding was needed.
    ///
    /// `digits` is below 10^19 (at most 19 significant digits are kept), so it and every power
    /// of ten up to 10^19 fit a `u64`: the product is one 64 × 64-bit multiply and the quotient
    /// one 64-bit division (a `u128` division is a library call: this function took 12.9 % of
    /// a text file's read with it); a power beyond that makes the value overflow or round to 0.
    fn scaled(self, shift: i32, exact: bool) -> Option<i64> {
        let e = self.exponent.checked_add(shift)?;
        let p = 10u64.checked_pow(e.unsigned_abs());
        let magnitude: u128 = if self.digits == 0 {
            0
        } else if e >= 0 {
            // `digits ≥ 1` times more than 10^19 overflows an i64.
            u128::from(self.digits) * u128::from(p?)
        } else if let Some(p) = p {
            let (q, r) = (self.digits / p, self.digits % p);
            if exact && r != 0 {
                return None;
            }
            u128::from(q) + u128::from(u128::from(r) * 2 >= u128::from(p))
        } else {
            // 10^k > 10^19 > digits: the value is below one half.
            if exact {
                return None;
            }
            0
        };
        let m = i128::try_from(magnitude).ok()?;
        i64::try_from(if self.negative { -m } else { m }).ok()
    }
}

/// What a header row names: the columns, the time unit and the sensor size.
struct Header {
    cols: Columns,
    unit: Option<TimeUnit>,
    /// From `x@W` and `y@H` column names (faery's CSV).
    size: Option<(u16, u16)>,
    /// A note when only one of `x@W`, `y@H` is given.
    one_size: Option<String>,
}

/// The columns, time unit and sensor size a header row names.
fn header_columns(names: &[&[u8]]) -> Result<Header, String> {
    let mut t = None;
    let mut x = None;
    let mut y = None;
    let mut p = None;
    let mut unit = None;
    let mut width = None;
    let mut height = None;
    for (i, raw) in names.iter().enumerate() {
        let mut name = String::from_utf8_lossy(raw)
            .trim_matches('"')
            .to_ascii_lowercase();
        // faery writes the sensor size into the coordinates' names: `x@346`, `y@260`.
        if let Some((axis @ ("x" | "y"), n)) = name.split_once('@').map(|(a, n)| (a.trim(), n)) {
            let n = n
                .trim()
                .parse::<u16>()
                .ok()
                .filter(|&n| n > 0)
                .ok_or_else(|| {
                    format!(
                        "header row names the column `{}`: a sensor size is 1 to 65535",
                        String::from_utf8_lossy(raw)
                    )
                })?;
            *(if axis == "x" { &mut width } else { &mut height }) = Some(n);
            name = axis.to_string();
        }
        let split = name.find(['_', '[', '(', ' ']).unwrap_or(name.len());
        let (base, rest) = name.split_at(split);
        let suffix = rest.trim_matches(|c| matches!(c, '_' | '[' | ']' | '(' | ')' | ' '));
        let slot = match base {
            "t" | "ts" | "time" | "timestamp" | "timestamps" => {
                let u = match suffix {
                    "" => None,
                    "us" | "µs" | "usec" | "microseconds" => Some(TimeUnit::Us),
                    "s" | "sec" | "seconds" => Some(TimeUnit::S),
                    "ms" | "msec" | "milliseconds" => Some(TimeUnit::Ms),
                    "ns" | "nsec" | "nanoseconds" => Some(TimeUnit::Ns),
                    _ => continue,
                };
                unit = u;
                &mut t
            }
            "x" if suffix.is_empty() => &mut x,
            "y" if suffix.is_empty() => &mut y,
            "p" | "pol" | "polarity" | "on" if suffix.is_empty() => &mut p,
            _ => continue,
        };
        if slot.replace(i).is_some() {
            return Err(format!("header row names column {base:?} twice"));
        }
    }
    match (t, x, y, p) {
        (Some(t), Some(x), Some(y), Some(p)) => Ok(Header {
            cols: Columns {
                t,
                x,
                y,
                p,
                count: names.len(),
            },
            unit,
            size: width.zip(height),
            one_size: (width.is_some() != height.is_some()).then(|| {
                format!(
                    "the header row gives only the sensor's {}: no size taken from it",
                    if width.is_some() { "width" } else { "height" }
                )
            }),
        }),
        _ => Err(format!(
            "neither four numbers nor a header row naming t, x, y and p columns: {}",
            names
                .iter()
                .map(|n| String::from_utf8_lossy(n).into_owned())
                .collect::<Vec<_>>()
                .join(" ")
        )),
    }
}

/// Whether a timestamp in the first whole lines of `data` has a fraction: its value is not a
/// whole number (however it is written: `223.0` and `2.23e+02` are whole).
fn has_fractional_time(data: &[u8], cols: Columns) -> bool {
    let mut fields = [&[][..]; MAX_FIELDS];
    data.split(|&b| b == b'\n')
        .take(DETECT_LINES)
        .map(trim)
        .filter(|l| !is_comment(l))
        .filter_map(|l| {
            let n = split_fields(l, &mut fields).ok()?;
            (n > cols.t)
                .then(|| parse_decimal(fields[cols.t]).is_some_and(|d| d.scaled(0, true).is_none()))
        })
        .any(|f| f)
}

/// Whether `head` (the start of a file) looks like a text event file: printable UTF-8 whose
/// first non-comment line is four numbers, or a header row naming t/x/y/p followed by a line
/// of numbers.
pub fn looks_like_text(head: &[u8]) -> bool {
    let head = head.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(head);
    // A cut last line is not judged.
    let whole = match head.iter().rposition(|&b| b == b'\n') {
        Some(i) if i + 1 < head.len() => &head[..i],
        _ => head,
    };
    // UTF-8 without control characters but tab and line ends (a header row may say `t[µs]`).
    let printable = std::str::from_utf8(whole).is_ok_and(|t| {
        t.chars()
            .all(|c| matches!(c, '\t' | '\n' | '\r') || !c.is_control())
    });
    if whole.is_empty() || !printable {
        return false;
    }
    let mut fields = [&[][..]; MAX_FIELDS];
    let mut cols = None;
    let mut first_seen = false;
    for line in whole.split(|&b| b == b'\n').take(DETECT_LINES).map(trim) {
        if is_comment(line) {
            continue;
        }
        let Ok(n) = split_fields(line, &mut fields) else {
            return false;
        };
        let numeric = fields[..n].iter().all(|f| is_value(f));
        if !first_seen && cols.is_none() && sensor_size(&fields[..n]).is_some() {
            first_seen = true;
            continue; // a `W H` first line
        }
        first_seen = true;
        return match cols {
            None if numeric => n == 4,
            None => match header_columns(&fields[..n]) {
                Ok(h) => {
                    cols = Some(h.cols);
                    continue;
                }
                Err(_) => false,
            },
            Some(c) => numeric && n == c.count,
        };
    }
    false
}

impl<R: Read> super::source::Fill for TextReader<R> {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn dec(s: &str) -> Option<Decimal> {
        parse_decimal(s.as_bytes())
    }

    #[test]
    fn decimals_scale_exactly() {
        let us = |s: &str| dec(s).and_then(|d| d.scaled(6, false));
        assert_eq!(us("1589163147.368868"), Some(1_589_163_147_368_868));
        assert_eq!(us("0.0000005"), Some(1), "half rounds away from zero");
        assert_eq!(us("-0.0000005"), Some(-1));
        assert_eq!(us("1e-6"), Some(1));
        assert_eq!(us("2.5E1"), Some(25_000_000));
        assert_eq!(us("00.000100"), Some(100));
        assert_eq!(us("9223372036854.775807"), Some(i64::MAX));
        assert_eq!(us("9223372036854.775808"), None);
        assert_eq!(dec("1.5").and_then(|d| d.scaled(0, true)), None);
        assert_eq!(dec("12.000").and_then(|d| d.scaled(0, true)), Some(12));
        for bad in [
            "", "-", ".", "1.2.3", "1e", "e5", "1x", "--1", "0x10", "nan", "inf",
        ] {
            assert_eq!(dec(bad), None, "{bad:?}");
        }
        assert_eq!(
            dec("123456789012345678901234").and_then(|d| d.scaled(0, false)),
            None
        );
    }

    /// [`Decimal::scaled`] as it was, in 128-bit arithmetic throughout.
    fn scaled_u128(d: Decimal, shift: i32, exact: bool) -> Option<i64> {
        let e = d.exponent.checked_add(shift)?;
        let magnitude: u128 = if d.digits == 0 {
            0
        } else if e >= 0 {
            let p = 10u128.checked_pow(u32::try_from(e).ok()?)?;
            u128::from(d.digits).checked_mul(p)?
        } else {
            let k = e.unsigned_abs();
            if k > 38 {
                if exact {
                    return None;
                }
                0
            } else {
                let p = 10u128.pow(k);
                let (q, r) = (u128::from(d.digits) / p, u128::from(d.digits) % p);
                if exact && r != 0 {
                    return None;
                }
                q + u128::from(2 * r >= p)
            }
        };
        let m = i128::try_from(magnitude).ok()?;
        i64::try_from(if d.negative { -m } else { m }).ok()
    }

    #[test]
    fn scaling_in_64_bits_matches_128() {
        // Digits of every length up to 19 (powers of ten, their neighbours, halves, random),
        // exponents from -45 to 45, both signs, exact or rounded.
        let mut next = crate::test_rng(0x9E37_79B9_7F4A_7C15);
        let mut digits = vec![0u64, 1, 5, 9_999_999_999_999_999_999];
        for k in 0..19 {
            let p = 10u64.pow(k);
            digits.extend([p, p - 1, p + 1, p / 2, 5 * p, 5 * p - 1]);
        }
        for _ in 0..500 {
            digits.push(next() % 10_000_000_000_000_000_000);
        }
        for &digits in &digits {
            for exponent in -45..=45 {
                for negative in [false, true] {
                    let d = Decimal {
                        negative,
                        digits,
                        exponent,
                    };
                    for (shift, exact) in
                        [(0, true), (0, false), (6, false), (6, true), (-3, false)]
                    {
                        assert_eq!(
                            d.scaled(shift, exact),
                            scaled_u128(d, shift, exact),
                            "{d:?} {shift}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn fields_split_on_spaces_commas_and_semicolons() {
        fn split(s: &str) -> Result<Vec<String>, &'static str> {
            let mut f = [&[][..]; MAX_FIELDS];
            let n = split_fields(s.as_bytes(), &mut f)?;
            Ok(f[..n]
                .iter()
                .map(|x| String::from_utf8_lossy(x).into_owned())
                .collect())
        }
        assert_eq!(split("1 2\t 3  4").unwrap(), ["1", "2", "3", "4"]);
        assert_eq!(split("1, 2 ,3;4").unwrap(), ["1", "2", "3", "4"]);
        assert!(split("1,,2,3").is_err());
        assert!(split("1,2,3,").is_err());
        assert_eq!(split("").unwrap(), Vec::<String>::new());
    }

    #[test]
    fn text_detection() {
        assert!(looks_like_text(b"0.1 1 2 1\n0.2 3 4 0\n"));
        assert!(looks_like_text(b"# comment\nt,x,y,p\n1,2,3,1\n"));
        assert!(looks_like_text(
            b"timestamp,x,y,polarity,extra\n1,2,3,1,9\n"
        ));
        assert!(!looks_like_text(b"hello, not events"));
        assert!(!looks_like_text(b"1 2 3\n"));
        assert!(!looks_like_text(b"1 2 3 4\x00\n"));
    }
}

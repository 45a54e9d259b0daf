//! iniVation DV AEDAT 4.0: a streaming reader and a writer.
//!
//! # Layout
//!
//! ```text
//! "#!AER-DAT4.0\r\n"                        14 bytes
//! u32 LE n, IOHeader flatbuffer            n bytes (the u32 is the flatbuffer's size prefix)
//! packets until EOF or the data table:
//!     i32 LE stream id, i32 LE size s,
//!     s bytes: a size-prefixed flatbuffer, compressed as the IOHeader says
//!     (LZ4 frame, zstd frame or none)
//! [FileDataTable at IOHeader.dataTablePosition; never read here]
//! ```
//!
//! The IOHeader (`IOHE`) holds the compression, the data table position (-1 when absent) and
//! `infoNode`, an XML document with one `<node name="ID">` per stream under
//! `<node name="outInfo">`; its `<attr key="typeIdentifier">` says what the stream carries
//! (`EVTS` events, `FRME` frames, `IMUS` IMU samples, `TRIG` triggers) and its child
//! `<node name="info">` gives `sizeX`, `sizeY` and `source`. An `EVTS` packet is an
//! `EventPacket` table whose only field is a vector of 16-byte structs
//! `{ t: i64 µs, x: i16, y: i16, on: bool, 3 bytes padding }`.
//!
//! Each `EVTS` stream is one camera; its id is its index among the `EVTS` streams in header
//! order. Packets of other streams are skipped without being decompressed.
//!
//! The flatbuffers are read by the small bounds-checked reader below, not generated code:
//! every offset is checked, so damaged input gives a [`ReadError`], never a panic, and no
//! allocation follows a size field beyond [`MAX_PACKET_BYTES`].

use std::io::{self, Read, Write};

use evpose_core::Event;

use super::{
    read_up_to, Batch, CameraInfo, Format, ReadError, ReadNotes, StreamInfo, BATCH_EVENTS,
};

/// The 14 bytes every AEDAT 4.0 file starts with.
pub const MAGIC: &[u8; 14] = b"#!AER-DAT4.0\r\n";

/// Largest IOHeader accepted, in bytes.
pub const MAX_HEADER_BYTES: u32 = 16 << 20;

/// Largest packet accepted, in bytes, before and after decompression.
pub const MAX_PACKET_BYTES: u64 = 256 << 20;

/// Events per packet that [`Aedat4Writer`] writes at most.
pub const WRITE_PACKET_EVENTS: usize = 4096;

/// File offset of the IOHeader flatbuffer (after the magic and its u32 size prefix).
const HEADER_OFFSET: u64 = MAGIC.len() as u64 + 4;

/// Bytes per event struct in an `EventPacket`.
const EVENT_BYTES: usize = 16;

/// Packet compression, as coded in the IOHeader.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Compression {
    /// Stored as is.
    None,
    /// LZ4 frame format.
    Lz4,
    /// LZ4 frame format, compressed harder (decoded like [`Compression::Lz4`]).
    Lz4High,
    /// Zstandard frame.
    Zstd,
    /// Zstandard frame, compressed harder (decoded like [`Compression::Zstd`]).
    ZstdHigh,
}

impl Compression {
    /// Every compression, in code order.
    pub const ALL: [Self; 5] = [
        Self::None,
        Self::Lz4,
        Self::Lz4High,
        Self::Zstd,
        Self::ZstdHigh,
    ];

    /// The IOHeader code (`CompressionType` enum).
    pub fn code(self) -> i32 {
        match self {
            Self::None => 0,
            Self::Lz4 => 1,
            Self::Lz4High => 2,
            Self::Zstd => 3,
            Self::ZstdHigh => 4,
        }
    }

    /// The compression of an IOHeader code, if known.
    pub fn from_code(code: i32) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.code() == code)
    }

    /// The name DV writes in the stream's `compression` attribute.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "NONE",
            Self::Lz4 => "LZ4",
            Self::Lz4High => "LZ4_HIGH",
            Self::Zstd => "ZSTD",
            Self::ZstdHigh => "ZSTD_HIGH",
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Bounds-checked flatbuffer access.

/// A flatbuffer in memory; `offset` is the file offset named in errors.
#[derive(Clone, Copy)]
struct Flatbuffer<'a> {
    buf: &'a [u8],
    offset: u64,
    what: &'static str,
}

impl<'a> Flatbuffer<'a> {
    fn corrupt(&self, message: String) -> ReadError {
        ReadError::Corrupt {
            offset: self.offset,
            message: format!("{}: {message}", self.what),
        }
    }

    fn bytes(&self, pos: usize, len: usize) -> Result<&'a [u8], ReadError> {
        pos.checked_add(len)
            .and_then(|end| self.buf.get(pos..end))
            .ok_or_else(|| {
                self.corrupt(format!(
                    "{len} bytes at {pos} are outside the {}-byte buffer",
                    self.buf.len()
                ))
            })
    }

    fn array<const N: usize>(&self, pos: usize) -> Result<[u8; N], ReadError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.bytes(pos, N)?);
        Ok(out)
    }

    fn u16(&self, pos: usize) -> Result<u16, ReadError> {
        self.array(pos).map(u16::from_le_bytes)
    }

    fn u32(&self, pos: usize) -> Result<u32, ReadError> {
        self.array(pos).map(u32::from_le_bytes)
    }

    fn i32(&self, pos: usize) -> Result<i32, ReadError> {
        self.array(pos).map(i32::from_le_bytes)
    }

    fn i64(&self, pos: usize) -> Result<i64, ReadError> {
        self.array(pos).map(i64::from_le_bytes)
    }

    /// The position `pos` plus the unsigned offset stored there.
    fn follow(&self, pos: usize) -> Result<usize, ReadError> {
        let target = usize::try_from(self.u32(pos)?)
            .ok()
            .and_then(|d| pos.checked_add(d))
            .filter(|&t| t < self.buf.len());
        target.ok_or_else(|| self.corrupt(format!("offset at {pos} points outside the buffer")))
    }

    /// Checks the 4-byte file identifier.
    fn expect_identifier(&self, id: &[u8; 4]) -> Result<(), ReadError> {
        let found = self.bytes(4, 4)?;
        if found == id {
            Ok(())
        } else {
            Err(self.corrupt(format!(
                "file identifier is {:?}, expected {:?}",
                String::from_utf8_lossy(found),
                String::from_utf8_lossy(id)
            )))
        }
    }

    fn root(&self) -> Result<Table<'a>, ReadError> {
        Table::at(*self, self.follow(0)?)
    }
}

/// A flatbuffer table with its vtable.
struct Table<'a> {
    fb: Flatbuffer<'a>,
    pos: usize,
    vtable: usize,
    vtable_len: usize,
    table_len: usize,
}

impl<'a> Table<'a> {
    fn at(fb: Flatbuffer<'a>, pos: usize) -> Result<Self, ReadError> {
        let soffset = i64::from(fb.i32(pos)?);
        let vtable = i64::try_from(pos)
            .ok()
            .map(|p| p - soffset)
            .and_then(|v| usize::try_from(v).ok())
            .ok_or_else(|| fb.corrupt(format!("vtable of the table at {pos} is out of range")))?;
        let vtable_len = usize::from(fb.u16(vtable)?);
        let table_len = usize::from(fb.u16(vtable + 2)?);
        if vtable_len < 4 || vtable_len % 2 != 0 || table_len < 4 {
            return Err(fb.corrupt(format!("vtable at {vtable} has bad sizes")));
        }
        fb.bytes(vtable, vtable_len)?;
        fb.bytes(pos, table_len)?;
        Ok(Self {
            fb,
            pos,
            vtable,
            vtable_len,
            table_len,
        })
    }

    /// Buffer position of field `index` (`size` bytes inline), or `None` when absent.
    fn field(&self, index: usize, size: usize) -> Result<Option<usize>, ReadError> {
        let entry = 4 + 2 * index;
        if entry + 2 > self.vtable_len {
            return Ok(None);
        }
        let at = usize::from(self.fb.u16(self.vtable + entry)?);
        if at == 0 {
            return Ok(None);
        }
        if at < 4 || at + size > self.table_len {
            return Err(self
                .fb
                .corrupt(format!("field {index} lies outside its table")));
        }
        Ok(Some(self.pos + at))
    }

    fn i32_or(&self, index: usize, default: i32) -> Result<i32, ReadError> {
        self.field(index, 4)?
            .map_or(Ok(default), |p| self.fb.i32(p))
    }

    fn i64_or(&self, index: usize, default: i64) -> Result<i64, ReadError> {
        self.field(index, 8)?
            .map_or(Ok(default), |p| self.fb.i64(p))
    }

    fn string(&self, index: usize) -> Result<Option<&'a str>, ReadError> {
        let Some(p) = self.field(index, 4)? else {
            return Ok(None);
        };
        let at = self.fb.follow(p)?;
        let len = self.fb.u32(at)? as usize;
        let bytes = self.fb.bytes(at + 4, len)?;
        std::str::from_utf8(bytes).map(Some).map_err(|e| {
            self.fb
                .corrupt(format!("string field {index} is not UTF-8: {e}"))
        })
    }

    /// Start and length of the vector in field `index` with `elem`-byte elements.
    fn vector(&self, index: usize, elem: usize) -> Result<Option<(usize, usize)>, ReadError> {
        let Some(p) = self.field(index, 4)? else {
            return Ok(None);
        };
        let at = self.fb.follow(p)?;
        let count = self.fb.u32(at)? as usize;
        let bytes = count.checked_mul(elem).ok_or_else(|| {
            self.fb
                .corrupt(format!("vector of {count} elements overflows"))
        })?;
        self.fb.bytes(at + 4, bytes)?;
        Ok(Some((at + 4, count)))
    }
}

// ---------------------------------------------------------------------------------------------
// The infoNode XML.

/// One stream declared in the header XML.
#[derive(Debug, Default)]
struct StreamDecl {
    id: i32,
    type_id: String,
    width: Option<u16>,
    height: Option<u16>,
    source: Option<String>,
}

/// A tag of an XML document; `attrs` is the raw attribute text.
enum Tag<'a> {
    Open {
        name: &'a str,
        attrs: &'a str,
        empty: bool,
    },
    Close(&'a str),
}

/// Splits XML into (text before, tag) pairs; skips comments, declarations and instructions.
struct Tags<'a> {
    s: &'a str,
    pos: usize,
}

impl<'a> Tags<'a> {
    fn next_tag(&mut self) -> Result<Option<(&'a str, Tag<'a>)>, String> {
        loop {
            let rest = &self.s[self.pos..];
            let Some(lt) = rest.find('<') else {
                return Ok(None);
            };
            let (text, tag, at) = (&rest[..lt], &rest[lt..], self.pos + lt);
            let skip_to = |end: &str| {
                tag.find(end)
                    .map(|i| i + end.len())
                    .ok_or_else(|| format!("unterminated markup at {at}"))
            };
            if tag.starts_with("<!--") {
                self.pos += lt + skip_to("-->")?;
            } else if tag.starts_with("<?") {
                self.pos += lt + skip_to("?>")?;
            } else if tag.starts_with("<!") {
                self.pos += lt + skip_to(">")?;
            } else {
                let end = tag_end(tag).ok_or_else(|| format!("unterminated tag at {at}"))?;
                self.pos += lt + end + 1;
                return Ok(Some((text, parse_tag(&tag[1..end]))));
            }
        }
    }
}

/// Index of the `>` that closes the tag starting `tag`, skipping quoted attribute values.
fn tag_end(tag: &str) -> Option<usize> {
    let mut quote = None;
    for (i, c) in tag.char_indices() {
        match (quote, c) {
            (None, '"' | '\'') => quote = Some(c),
            (Some(q), _) if c == q => quote = None,
            (None, '>') => return Some(i),
            _ => {}
        }
    }
    None
}

fn parse_tag(inner: &str) -> Tag<'_> {
    if let Some(name) = inner.strip_prefix('/') {
        return Tag::Close(name.trim());
    }
    let (inner, empty) = match inner.strip_suffix('/') {
        Some(s) => (s, true),
        None => (inner, false),
    };
    let split = inner.find(char::is_whitespace).unwrap_or(inner.len());
    Tag::Open {
        name: &inner[..split],
        attrs: &inner[split..],
        empty,
    }
}

/// The unescaped value of attribute `key` in raw attribute text.
fn xml_attr(attrs: &str, key: &str) -> Option<String> {
    let mut rest = attrs;
    loop {
        rest = rest.trim_start();
        let eq = rest.find('=')?;
        let name = rest[..eq].trim();
        let after = rest[eq + 1..].trim_start();
        let quote = after.chars().next().filter(|&c| c == '"' || c == '\'')?;
        let body = &after[1..];
        let close = body.find(quote)?;
        if name == key {
            return Some(unescape(&body[..close]));
        }
        rest = &body[close + 1..];
    }
}

/// Replaces the predefined and numeric XML entities; leaves unknown ones as they are.
fn unescape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(amp) = rest.find('&') {
        out.push_str(&rest[..amp]);
        rest = &rest[amp..];
        let decoded = rest.find(';').and_then(|semi| {
            let c = match &rest[1..semi] {
                "lt" => Some('<'),
                "gt" => Some('>'),
                "amp" => Some('&'),
                "quot" => Some('"'),
                "apos" => Some('\''),
                e => e
                    .strip_prefix("#x")
                    .map(|h| u32::from_str_radix(h, 16))
                    .or_else(|| e.strip_prefix('#').map(str::parse::<u32>))
                    .and_then(Result::ok)
                    .and_then(char::from_u32),
            };
            c.map(|c| (c, semi + 1))
        });
        match decoded {
            Some((c, len)) => {
                out.push(c);
                rest = &rest[len..];
            }
            None => {
                out.push('&');
                rest = &rest[1..];
            }
        }
    }
    out.push_str(rest);
    out
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&apos;")
}

/// The streams declared under `<node name="outInfo">`, in document order.
fn parse_streams(xml: &str) -> Result<Vec<StreamDecl>, String> {
    let mut tags = Tags { s: xml, pos: 0 };
    // Open elements: (tag name, `name` attribute).
    let mut stack: Vec<(&str, Option<String>)> = Vec::new();
    let mut streams: Vec<StreamDecl> = Vec::new();
    let mut attr_key: Option<String> = None;
    while let Some((text, tag)) = tags.next_tag()? {
        match tag {
            Tag::Open { name, attrs, empty } => {
                let out_info = stack
                    .iter()
                    .position(|(t, n)| *t == "node" && n.as_deref() == Some("outInfo"));
                if name == "node" && out_info.is_some_and(|i| stack.len() == i + 1) {
                    streams.push(stream_decl(attrs)?);
                }
                if name == "attr" {
                    attr_key = xml_attr(attrs, "key");
                    if empty {
                        attr_value(&stack, &mut streams, attr_key.take(), "");
                    }
                }
                if !empty {
                    stack.push((name, xml_attr(attrs, "name")));
                }
            }
            Tag::Close(name) => {
                if stack.pop().map(|(t, _)| t) != Some(name) {
                    return Err(format!("unexpected </{name}>"));
                }
                if name == "attr" {
                    attr_value(&stack, &mut streams, attr_key.take(), text);
                }
            }
        }
    }
    match stack.last() {
        Some((t, _)) => Err(format!("<{t}> is never closed")),
        None => Ok(streams),
    }
}

fn stream_decl(attrs: &str) -> Result<StreamDecl, String> {
    let name = xml_attr(attrs, "name").unwrap_or_default();
    let id = name
        .trim()
        .parse()
        .map_err(|_| format!("stream node name {name:?} is not an integer"))?;
    Ok(StreamDecl {
        id,
        ..StreamDecl::default()
    })
}

/// Records `<attr key="key">text</attr>` when it belongs to a stream or its `info` node.
fn attr_value(
    stack: &[(&str, Option<String>)],
    streams: &mut [StreamDecl],
    key: Option<String>,
    text: &str,
) {
    let (Some(key), Some(stream)) = (key, streams.last_mut()) else {
        return;
    };
    let Some(out_info) = stack
        .iter()
        .position(|(t, n)| *t == "node" && n.as_deref() == Some("outInfo"))
    else {
        return;
    };
    let value = unescape(text.trim());
    let inner = &stack[out_info + 1..];
    match inner {
        [("node", _)] if key == "typeIdentifier" => stream.type_id = value,
        [(_, _), ("node", Some(info))] if info == "info" => match key.as_str() {
            "sizeX" => stream.width = value.parse().ok(),
            "sizeY" => stream.height = value.parse().ok(),
            "source" => stream.source = Some(value),
            _ => {}
        },
        _ => {}
    }
}

// ---------------------------------------------------------------------------------------------
// Reader.

/// Stream id and handling of each declared stream.
type Routes = Vec<(i32, StreamKind)>;

/// What the reader does with a stream's packets.
#[derive(Clone, Copy)]
enum StreamKind {
    /// Events of the given camera.
    Events(u8),
    /// Anything else: skipped.
    Other,
}

/// The undelivered events of the current packet, as byte positions in the decompressed buffer.
#[derive(Default)]
struct Pending {
    camera: u8,
    next: usize,
    end: usize,
    index: usize,
    packet_offset: u64,
}

/// Streaming AEDAT 4.0 reader: one packet in memory at a time.
pub struct Aedat4Reader<R> {
    inner: R,
    info: StreamInfo,
    compression: Compression,
    streams: Routes,
    data_table: Option<u64>,
    pos: u64,
    raw: Vec<u8>,
    plain: Vec<u8>,
    pending: Pending,
    skipped: u64,
    finished: bool,
}

/// What the file header says.
struct Header {
    compression: Compression,
    data_table: Option<u64>,
    streams: Vec<StreamDecl>,
    end: u64,
}

fn read_header(r: &mut impl Read) -> Result<Header, ReadError> {
    let mut magic = [0u8; MAGIC.len()];
    let n = read_up_to(r, &mut magic)?;
    if magic[..n] != MAGIC[..n] {
        return Err(if magic.starts_with(b"#!AER-DAT") {
            ReadError::Unsupported(format!(
                "AEDAT version {:?}; only 4.0 is read",
                String::from_utf8_lossy(&magic[9..n.min(12)])
            ))
        } else {
            ReadError::Corrupt {
                offset: 0,
                message: "not an AEDAT 4.0 file (bad magic)".into(),
            }
        });
    }
    if n < MAGIC.len() {
        return Err(ReadError::Truncated {
            offset: 0,
            what: "magic",
        });
    }
    let mut size = [0u8; 4];
    if read_up_to(r, &mut size)? < 4 {
        return Err(ReadError::Truncated {
            offset: MAGIC.len() as u64,
            what: "IOHeader size",
        });
    }
    let size = u32::from_le_bytes(size);
    if size > MAX_HEADER_BYTES {
        return Err(ReadError::Corrupt {
            offset: MAGIC.len() as u64,
            message: format!("IOHeader size {size} exceeds {MAX_HEADER_BYTES}"),
        });
    }
    let mut buf = Vec::new();
    r.take(u64::from(size)).read_to_end(&mut buf)?;
    if buf.len() < size as usize {
        return Err(ReadError::Truncated {
            offset: HEADER_OFFSET,
            what: "IOHeader",
        });
    }
    let mut header = parse_io_header(&buf)?;
    header.end = HEADER_OFFSET + u64::from(size);
    if header.data_table.is_some_and(|t| t < header.end) {
        return Err(ReadError::Corrupt {
            offset: HEADER_OFFSET,
            message: "IOHeader: data table position lies inside the header".into(),
        });
    }
    Ok(header)
}

fn parse_io_header(buf: &[u8]) -> Result<Header, ReadError> {
    let fb = Flatbuffer {
        buf,
        offset: HEADER_OFFSET,
        what: "IOHeader",
    };
    fb.expect_identifier(b"IOHE")?;
    let root = fb.root()?;
    let code = root.i32_or(0, 0)?;
    let compression = Compression::from_code(code)
        .ok_or_else(|| ReadError::Unsupported(format!("AEDAT 4 compression type {code}")))?;
    let data_table = u64::try_from(root.i64_or(1, -1)?).ok();
    let xml = root
        .string(2)?
        .ok_or_else(|| fb.corrupt("no infoNode".into()))?;
    let streams = parse_streams(xml).map_err(|e| fb.corrupt(format!("infoNode XML: {e}")))?;
    Ok(Header {
        compression,
        data_table,
        streams,
        end: 0,
    })
}

/// Camera list and packet routing for the declared streams.
fn route_streams(decls: &[StreamDecl]) -> Result<(Vec<CameraInfo>, Routes), ReadError> {
    let mut cameras = Vec::new();
    let mut routes = Routes::new();
    for d in decls {
        if routes.iter().any(|(id, _)| *id == d.id) {
            return Err(ReadError::Corrupt {
                offset: HEADER_OFFSET,
                message: format!("IOHeader: stream {} is declared twice", d.id),
            });
        }
        let kind = if d.type_id == "EVTS" {
            let id = u8::try_from(cameras.len())
                .map_err(|_| ReadError::Unsupported("more than 256 event streams".into()))?;
            cameras.push(CameraInfo {
                id,
                width: d.width,
                height: d.height,
                name: d.source.clone(),
            });
            StreamKind::Events(id)
        } else {
            StreamKind::Other
        };
        routes.push((d.id, kind));
    }
    Ok((cameras, routes))
}

/// Decompresses `raw` into `plain` (both cleared or swapped as needed).
fn decompress(
    compression: Compression,
    raw: &mut Vec<u8>,
    plain: &mut Vec<u8>,
    offset: u64,
) -> Result<(), ReadError> {
    plain.clear();
    let limit = MAX_PACKET_BYTES + 1;
    let result = match compression {
        Compression::None => {
            std::mem::swap(raw, plain);
            Ok(plain.len())
        }
        Compression::Lz4 | Compression::Lz4High => lz4_flex::frame::FrameDecoder::new(&raw[..])
            .take(limit)
            .read_to_end(plain),
        Compression::Zstd | Compression::ZstdHigh => {
            zstd::stream::read::Decoder::with_buffer(&raw[..])
                .and_then(|d| d.take(limit).read_to_end(plain))
        }
    };
    let corrupt = |message: String| ReadError::Corrupt { offset, message };
    match result {
        Err(e) => Err(corrupt(format!(
            "{} decompression failed: {e}",
            compression.name()
        ))),
        Ok(_) if plain.len() as u64 > MAX_PACKET_BYTES => Err(corrupt(format!(
            "packet decompresses to more than {MAX_PACKET_BYTES} bytes"
        ))),
        Ok(_) => Ok(()),
    }
}

/// Start (in `plain`) and count of the event structs of a decompressed `EventPacket`.
fn event_vector(plain: &[u8], offset: u64) -> Result<(usize, usize), ReadError> {
    let fb = Flatbuffer {
        buf: plain,
        offset,
        what: "EventPacket",
    };
    // DV writes size-prefixed buffers; accept a bare one too.
    let prefixed =
        plain.len() >= 12 && &plain[8..12] == b"EVTS" && fb.u32(0)? as usize == plain.len() - 4;
    let skip = if prefixed { 4 } else { 0 };
    let body = Flatbuffer {
        buf: &plain[skip..],
        ..fb
    };
    body.expect_identifier(b"EVTS")?;
    let (start, count) = body.root()?.vector(0, EVENT_BYTES)?.unwrap_or((0, 0));
    Ok((start + skip, count))
}

impl<R: Read> Aedat4Reader<R> {
    /// Parses the magic and the IOHeader; events are read by [`EventReader::read_batch`].
    pub fn new(mut inner: R) -> Result<Self, ReadError> {
        let header = read_header(&mut inner)?;
        let (cameras, streams) = route_streams(&header.streams)?;
        Ok(Self {
            inner,
            info: StreamInfo {
                format: Format::Aedat4,
                cameras,
                event_count: None,
            },
            compression: header.compression,
            streams,
            data_table: header.data_table,
            pos: header.end,
            raw: Vec::new(),
            plain: Vec::new(),
            pending: Pending::default(),
            skipped: 0,
            finished: false,
        })
    }

    /// Packets of non-event streams (frames, IMU, triggers, …) skipped so far.
    pub fn skipped_packets(&self) -> u64 {
        self.skipped
    }

    /// The file's packet compression.
    pub fn compression(&self) -> Compression {
        self.compression
    }

    /// Gives back the underlying reader.
    pub fn into_inner(self) -> R {
        self.inner
    }

    /// Loads the next event packet into `pending`; `false` at the end of the packets.
    fn next_packet(&mut self) -> Result<bool, ReadError> {
        loop {
            let start = self.pos;
            if self.data_table == Some(start) {
                return Ok(false);
            }
            let mut head = [0u8; 8];
            match read_up_to(&mut self.inner, &mut head)? {
                0 if self.data_table.is_none() => return Ok(false),
                0 => {
                    return Err(ReadError::Truncated {
                        offset: start,
                        what: "packets (the file ends before its data table)",
                    })
                }
                8 => {}
                _ => {
                    return Err(ReadError::Truncated {
                        offset: start,
                        what: "packet header",
                    })
                }
            }
            let (stream, size) = self.packet_header(start, head)?;
            self.pos = start + 8 + size;
            match self.route(start, stream)? {
                StreamKind::Other => {
                    self.skip_payload(start, size)?;
                    self.skipped += 1;
                }
                StreamKind::Events(camera) => {
                    self.load_events(start, size, camera)?;
                    return Ok(true);
                }
            }
        }
    }

    /// Checks a packet header; returns the stream id and payload size.
    fn packet_header(&self, start: u64, head: [u8; 8]) -> Result<(i32, u64), ReadError> {
        let [a, b, c, d, e, f, g, h] = head;
        let stream = i32::from_le_bytes([a, b, c, d]);
        let size = i32::from_le_bytes([e, f, g, h]);
        let corrupt = |message: String| ReadError::Corrupt {
            offset: start,
            message,
        };
        let size = u64::try_from(size)
            .ok()
            .filter(|&s| s <= MAX_PACKET_BYTES)
            .ok_or_else(|| corrupt(format!("packet size {size} is out of range")))?;
        if let Some(table) = self.data_table {
            if start + 8 + size > table {
                return Err(corrupt(format!(
                    "packet runs past the data table at {table}"
                )));
            }
        }
        Ok((stream, size))
    }

    fn route(&self, start: u64, stream: i32) -> Result<StreamKind, ReadError> {
        self.streams
            .iter()
            .find(|(id, _)| *id == stream)
            .map(|&(_, kind)| kind)
            .ok_or_else(|| ReadError::Corrupt {
                offset: start,
                message: format!("packet of stream {stream}, which the header does not declare"),
            })
    }

    fn skip_payload(&mut self, start: u64, size: u64) -> Result<(), ReadError> {
        let copied = io::copy(&mut (&mut self.inner).take(size), &mut io::sink())?;
        if copied < size {
            return Err(ReadError::Truncated {
                offset: start,
                what: "packet",
            });
        }
        Ok(())
    }

    fn load_events(&mut self, start: u64, size: u64, camera: u8) -> Result<(), ReadError> {
        self.raw.clear();
        (&mut self.inner).take(size).read_to_end(&mut self.raw)?;
        if (self.raw.len() as u64) < size {
            return Err(ReadError::Truncated {
                offset: start,
                what: "event packet",
            });
        }
        decompress(self.compression, &mut self.raw, &mut self.plain, start)?;
        let (first, count) = event_vector(&self.plain, start)?;
        self.pending = Pending {
            camera,
            next: first,
            end: first + count * EVENT_BYTES,
            index: 0,
            packet_offset: start,
        };
        Ok(())
    }

    /// Moves pending events into `batch` until it holds `BATCH_EVENTS`.
    fn drain_pending(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        let p = &mut self.pending;
        let room = BATCH_EVENTS.saturating_sub(batch.len());
        let take = ((p.end - p.next) / EVENT_BYTES).min(room);
        batch.events.reserve(take);
        batch.cameras.reserve(take);
        for chunk in self.plain[p.next..p.next + take * EVENT_BYTES].chunks_exact(EVENT_BYTES) {
            let event = decode_event(chunk).ok_or_else(|| ReadError::Corrupt {
                offset: p.packet_offset,
                message: format!("event {} of the packet has a negative coordinate", p.index),
            })?;
            batch.push(p.camera, event);
            p.index += 1;
        }
        p.next += take * EVENT_BYTES;
        Ok(())
    }

    fn fill(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        while batch.len() < BATCH_EVENTS {
            if self.pending.next < self.pending.end {
                self.drain_pending(batch)?;
            } else if !self.next_packet()? {
                self.finished = true;
                break;
            }
        }
        Ok(())
    }
}

/// Decodes one 16-byte event struct; `None` for a negative coordinate.
fn decode_event(chunk: &[u8]) -> Option<Event> {
    let t = i64::from_le_bytes(chunk.get(0..8)?.try_into().ok()?);
    let x = i16::from_le_bytes(chunk.get(8..10)?.try_into().ok()?);
    let y = i16::from_le_bytes(chunk.get(10..12)?.try_into().ok()?);
    let on = *chunk.get(12)? != 0;
    Some(Event::new(
        u16::try_from(x).ok()?,
        u16::try_from(y).ok()?,
        t,
        on,
    ))
}

// ---------------------------------------------------------------------------------------------
// Writer.

/// The fixed first 32 bytes of a size-prefixed `EventPacket`, laid out as DV writes it:
/// size prefix, root offset, `EVTS`, padding, vtable, table, vector offset, vector length.
const PACKET_HEAD: [u8; 32] = [
    0, 0, 0, 0, // size prefix (filled in)
    16, 0, 0, 0, // root table at 4 + 16
    b'E', b'V', b'T', b'S', // file identifier
    0, 0, // padding
    6, 0, 8, 0, 4, 0, // vtable: 6 bytes, table 8 bytes, field 0 at +4
    6, 0, 0, 0, // table: vtable at -6
    4, 0, 0, 0, // field 0: vector at +4
    0, 0, 0, 0, // vector length (filled in)
];

/// Writes an AEDAT 4.0 file: one `EVTS` stream per camera, no data table.
///
/// Events are gathered into packets of at most [`WRITE_PACKET_EVENTS`] events of one camera,
/// in the order given. Call [`Aedat4Writer::finish`]: dropping the writer loses the last packet.
/// `Lz4High` is written like `Lz4` (the frames decode the same way).
pub struct Aedat4Writer<W: Write> {
    out: W,
    compression: Compression,
    /// Stream id of each camera id.
    streams: Vec<Option<i32>>,
    /// The `EventPacket` being filled, and its stream.
    packet: Vec<u8>,
    packet_stream: i32,
    packet_events: usize,
    compressed: Vec<u8>,
}

fn invalid(message: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, message)
}

impl<W: Write> Aedat4Writer<W> {
    /// Writes the magic and the IOHeader; stream `i` is `cameras[i]`, whose events are those
    /// with camera id `cameras[i].id` (ids must be distinct).
    pub fn new(mut out: W, cameras: &[CameraInfo], compression: Compression) -> io::Result<Self> {
        let mut streams = vec![None; 256];
        for (i, c) in cameras.iter().enumerate() {
            let slot = &mut streams[usize::from(c.id)];
            if slot.is_some() {
                return Err(invalid(format!("camera id {} appears twice", c.id)));
            }
            *slot = Some(i32::try_from(i).map_err(|_| invalid("too many cameras".into()))?);
        }
        out.write_all(MAGIC)?;
        out.write_all(&io_header(&info_xml(cameras, compression), compression))?;
        Ok(Self {
            out,
            compression,
            streams,
            packet: PACKET_HEAD.to_vec(),
            packet_stream: 0,
            packet_events: 0,
            compressed: Vec::new(),
        })
    }

    /// Appends the events of `batch`.
    pub fn write(&mut self, batch: &Batch) -> io::Result<()> {
        if batch.cameras.len() != batch.events.len() {
            return Err(invalid("batch has unequal event and camera counts".into()));
        }
        for (&camera, e) in batch.cameras.iter().zip(&batch.events) {
            let stream = self.streams[usize::from(camera)]
                .ok_or_else(|| invalid(format!("camera {camera} was not declared")))?;
            let x = i16::try_from(e.x).map_err(|_| invalid(format!("x = {} > 32767", e.x)))?;
            let y = i16::try_from(e.y).map_err(|_| invalid(format!("y = {} > 32767", e.y)))?;
            if self.packet_events > 0
                && (stream != self.packet_stream || self.packet_events >= WRITE_PACKET_EVENTS)
            {
                self.flush_packet()?;
            }
            self.packet_stream = stream;
            self.packet.extend_from_slice(&e.t.to_le_bytes());
            self.packet.extend_from_slice(&x.to_le_bytes());
            self.packet.extend_from_slice(&y.to_le_bytes());
            self.packet.extend_from_slice(&[u8::from(e.on), 0, 0, 0]);
            self.packet_events += 1;
        }
        Ok(())
    }

    /// Writes the last packet, flushes and returns the output.
    pub fn finish(mut self) -> io::Result<W> {
        if self.packet_events > 0 {
            self.flush_packet()?;
        }
        self.out.flush()?;
        Ok(self.out)
    }

    /// Compresses and writes the packet being filled, then starts a new one.
    fn flush_packet(&mut self) -> io::Result<()> {
        let len = self.packet.len();
        let prefix = u32::try_from(len - 4).map_err(|_| invalid("packet too large".into()))?;
        let count =
            u32::try_from(self.packet_events).map_err(|_| invalid("packet too large".into()))?;
        self.packet[0..4].copy_from_slice(&prefix.to_le_bytes());
        self.packet[28..32].copy_from_slice(&count.to_le_bytes());
        compress(self.compression, &self.packet, &mut self.compressed)?;
        let size = i32::try_from(self.compressed.len())
            .map_err(|_| invalid("compressed packet too large".into()))?;
        self.out.write_all(&self.packet_stream.to_le_bytes())?;
        self.out.write_all(&size.to_le_bytes())?;
        self.out.write_all(&self.compressed)?;
        self.packet.truncate(PACKET_HEAD.len());
        self.packet_events = 0;
        Ok(())
    }
}

/// Compresses `data` into `out` (cleared first).
fn compress(compression: Compression, data: &[u8], out: &mut Vec<u8>) -> io::Result<()> {
    out.clear();
    match compression {
        Compression::None => out.extend_from_slice(data),
        Compression::Lz4 | Compression::Lz4High => {
            let info = lz4_flex::frame::FrameInfo::new()
                .block_size(lz4_flex::frame::BlockSize::Max64KB)
                .block_mode(lz4_flex::frame::BlockMode::Linked);
            let mut enc = lz4_flex::frame::FrameEncoder::with_frame_info(info, out);
            enc.write_all(data)?;
            enc.finish().map_err(io::Error::other)?;
        }
        Compression::Zstd | Compression::ZstdHigh => {
            let level = if compression == Compression::Zstd {
                3
            } else {
                19
            };
            *out = zstd::bulk::compress(data, level)?;
        }
    }
    Ok(())
}

/// The size-prefixed IOHeader flatbuffer, laid out as DV writes it.
fn io_header(xml: &str, compression: Compression) -> Vec<u8> {
    let mut b = Vec::with_capacity(64 + xml.len());
    b.extend_from_slice(&[0; 4]); // size prefix (filled in)
    b.extend_from_slice(&24u32.to_le_bytes()); // root table at 4 + 24
    b.extend_from_slice(b"IOHE");
    b.extend_from_slice(&[0; 6]); // padding
    for v in [10u16, 24, 4, 12, 8] {
        b.extend_from_slice(&v.to_le_bytes()); // vtable: compression +4, table +12, info +8
    }
    b.extend_from_slice(&10i32.to_le_bytes()); // table: vtable at -10
    b.extend_from_slice(&compression.code().to_le_bytes());
    b.extend_from_slice(&16u32.to_le_bytes()); // infoNode at +16
    b.extend_from_slice(&(-1i64).to_le_bytes()); // dataTablePosition: none
    b.extend_from_slice(&[0; 4]); // padding
    b.extend_from_slice(&(xml.len() as u32).to_le_bytes());
    b.extend_from_slice(xml.as_bytes());
    b.push(0);
    b.resize(b.len().next_multiple_of(8), 0);
    let prefix = (b.len() - 4) as u32;
    b[0..4].copy_from_slice(&prefix.to_le_bytes());
    b
}

/// The infoNode XML declaring one `EVTS` stream per camera, in DV's layout.
fn info_xml(cameras: &[CameraInfo], compression: Compression) -> String {
    const ROOT: &str = "/mainloop/Recorder/outInfo/";
    let attr = |indent: usize, key: &str, ty: &str, value: &str| {
        format!(
            "{:indent$}<attr key=\"{key}\" type=\"{ty}\">{}</attr>\n",
            "",
            escape(value)
        )
    };
    let mut x = format!("<dv version=\"2.0\">\n    <node name=\"outInfo\" path=\"{ROOT}\">\n");
    for (i, cam) in cameras.iter().enumerate() {
        x += &format!("        <node name=\"{i}\" path=\"{ROOT}{i}/\">\n");
        x += &attr(12, "compression", "string", compression.name());
        x += &attr(12, "originalModuleName", "string", "evpose");
        let output = if i == 0 {
            "events".to_string()
        } else {
            format!("events_{i}")
        };
        x += &attr(12, "originalOutputName", "string", &output);
        x += &attr(
            12,
            "typeDescription",
            "string",
            "Array of events (polarity ON/OFF).",
        );
        x += &attr(12, "typeIdentifier", "string", "EVTS");
        x += &format!("            <node name=\"info\" path=\"{ROOT}{i}/info/\">\n");
        if let Some(w) = cam.width {
            x += &attr(16, "sizeX", "int", &w.to_string());
        }
        if let Some(h) = cam.height {
            x += &attr(16, "sizeY", "int", &h.to_string());
        }
        if let Some(name) = &cam.name {
            x += &attr(16, "source", "string", name);
        }
        x += &attr(16, "tsOffset", "long", "0");
        x += "            </node>\n        </node>\n";
    }
    x += "    </node>\n</dv>\n";
    x
}

impl<R: Read> super::source::Fill for Aedat4Reader<R> {
    fn info(&self) -> &StreamInfo {
        &self.info
    }
    fn notes(&self) -> ReadNotes {
        ReadNotes {
            skipped_packets: self.skipped,
            ..ReadNotes::default()
        }
    }
    fn fill_batch(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        self.fill(batch)
    }
    fn finished(&mut self) -> &mut bool {
        &mut self.finished
    }
}

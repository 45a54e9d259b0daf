//! The AEDAT 4.0 writer (`evpose convert --out X.aedat4`, synthetic data for DV tools).

use std::io::{self, Write};

use super::super::{Batch, CameraInfo};
use super::xml::*;
use super::*;

/// The fixed first 32 bytes of a size-prefixed `EventPacket`, laid out as DV writes it:
/// size prefix, root offset, `EVTS`, padding, vtable, table, vector offset, vector length.
pub(super) const PACKET_HEAD: [u8; 32] = [
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
/// Each camera fills a packet of its own, as DV records several cameras: a packet is written
/// when it holds [`WRITE_PACKET_EVENTS`] events, or once an event arrives [`WRITE_PACKET_SPAN_US`]
/// or more after its earliest one (whatever camera that event is of), and at
/// [`Aedat4Writer::finish`] (dropping the writer loses the open packets). So each camera's
/// events keep their order exactly, and a reader that takes packets in file order (as
/// [`super::Aedat4Reader`] does) sees events of time-ordered input out of order across cameras
/// by less than [`WRITE_PACKET_SPAN_US`]. `Lz4High` is written like `Lz4` (the frames decode
/// the same way).
pub struct Aedat4Writer<W: Write> {
    pub(super) out: W,
    pub(super) compression: Compression,
    /// Stream id of each camera id.
    pub(super) streams: Vec<Option<i32>>,
    /// The `EventPacket` being filled for each stream.
    pub(super) open: Vec<OpenPacket>,
    /// The earliest event time of the open packets (`i64::MAX` when none is open).
    pub(super) oldest: i64,
    pub(super) compressed: Vec<u8>,
}

/// A stream's packet being filled.
pub(super) struct OpenPacket {
    /// [`PACKET_HEAD`] and the events so far.
    bytes: Vec<u8>,
    events: usize,
    /// Time of its earliest event, µs.
    min_t: i64,
}

pub(super) fn invalid(message: String) -> io::Error {
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
        let open = cameras
            .iter()
            .map(|_| OpenPacket {
                bytes: PACKET_HEAD.to_vec(),
                events: 0,
                min_t: i64::MAX,
            })
            .collect();
        Ok(Self {
            out,
            compression,
            streams,
            open,
            oldest: i64::MAX,
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
            if e.t.saturating_sub(self.oldest) >= WRITE_PACKET_SPAN_US {
                self.flush_older(e.t.saturating_sub(WRITE_PACKET_SPAN_US))?;
            }
            let s = stream as usize; // ids are 0..cameras.len()
            if self.open[s].events >= WRITE_PACKET_EVENTS {
                self.flush_packet(s)?;
            }
            let p = &mut self.open[s];
            p.min_t = p.min_t.min(e.t);
            self.oldest = self.oldest.min(e.t);
            p.bytes.extend_from_slice(&e.t.to_le_bytes());
            p.bytes.extend_from_slice(&x.to_le_bytes());
            p.bytes.extend_from_slice(&y.to_le_bytes());
            p.bytes.extend_from_slice(&[u8::from(e.on), 0, 0, 0]);
            p.events += 1;
        }
        Ok(())
    }

    /// Writes the open packets, flushes and returns the output.
    pub fn finish(mut self) -> io::Result<W> {
        self.flush_older(i64::MAX)?;
        self.out.flush()?;
        Ok(self.out)
    }

    /// Writes every open packet whose earliest event is at or before `t`, oldest first.
    fn flush_older(&mut self, t: i64) -> io::Result<()> {
        let mut due: Vec<(i64, usize)> = (self.open.iter().enumerate())
            .filter(|(_, p)| p.events > 0 && p.min_t <= t)
            .map(|(s, p)| (p.min_t, s))
            .collect();
        due.sort_unstable();
        for (_, s) in due {
            self.flush_packet(s)?;
        }
        Ok(())
    }

    /// Compresses and writes stream `s`'s open packet, then starts a new one.
    fn flush_packet(&mut self, s: usize) -> io::Result<()> {
        let p = &mut self.open[s];
        let len = p.bytes.len();
        let prefix = u32::try_from(len - 4).map_err(|_| invalid("packet too large".into()))?;
        let count = u32::try_from(p.events).map_err(|_| invalid("packet too large".into()))?;
        p.bytes[0..4].copy_from_slice(&prefix.to_le_bytes());
        p.bytes[28..32].copy_from_slice(&count.to_le_bytes());
        compress(self.compression, &p.bytes, &mut self.compressed)?;
        let size = i32::try_from(self.compressed.len())
            .map_err(|_| invalid("compressed packet too large".into()))?;
        self.out.write_all(&(s as i32).to_le_bytes())?;
        self.out.write_all(&size.to_le_bytes())?;
        self.out.write_all(&self.compressed)?;
        p.bytes.truncate(PACKET_HEAD.len());
        p.events = 0;
        p.min_t = i64::MAX;
        self.oldest = (self.open.iter())
            .filter(|p| p.events > 0)
            .map(|p| p.min_t)
            .min()
            .unwrap_or(i64::MAX);
        Ok(())
    }
}

/// Compresses `data` into `out` (cleared first).
pub(super) fn compress(compression: Compression, data: &[u8], out: &mut Vec<u8>) -> io::Result<()> {
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
pub(super) fn io_header(xml: &str, compression: Compression) -> Vec<u8> {
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
/// The `source` of camera `i`'s stream: its name where the input gave it one no other camera
/// has, else that name (or `evpose`) with `_camera{id}`. dv-processing finds a camera's streams
/// by source, so every stream needs one and no two cameras may share it (without a source it
/// finds no stream at all: "does not contain any supported data streams").
fn source_name(cameras: &[CameraInfo], i: usize) -> String {
    let cam = &cameras[i];
    match &cam.name {
        Some(n)
            if cameras
                .iter()
                .filter(|c| c.name.as_ref() == Some(n))
                .count()
                == 1 =>
        {
            n.clone()
        }
        other => format!("{}_camera{}", other.as_deref().unwrap_or("evpose"), cam.id),
    }
}

pub(super) fn info_xml(cameras: &[CameraInfo], compression: Compression) -> String {
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
        // Every camera's stream is `events`, told apart by its `source` (below), as DV names
        // them: dv-processing's readers look a camera's events up under that name.
        x += &attr(12, "originalOutputName", "string", "events");
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
        x += &attr(16, "source", "string", &source_name(cameras, i));
        x += &attr(16, "tsOffset", "long", "0");
        x += "            </node>\n        </node>\n";
    }
    x += "    </node>\n</dv>\n";
    x
}

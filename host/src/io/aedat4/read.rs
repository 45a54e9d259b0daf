//! The streaming AEDAT 4.0 reader.

use std::collections::VecDeque;
use std::io::{self, Read};

use evpose_core::Event;

use super::super::{
    read_up_to, Batch, CameraInfo, Format, ReadError, ReadNotes, StreamInfo, BATCH_EVENTS,
};
use super::flatbuf::*;
use super::xml::*;
use super::*;

/// Stream id and handling of each declared stream.
pub(super) type Routes = Vec<(i32, StreamKind)>;

/// What the reader does with a stream's packets.
#[derive(Clone, Copy)]
pub(super) enum StreamKind {
    /// Events of the given camera.
    Events(u8),
    /// Anything else: skipped.
    Other,
}

/// The undelivered events of the current packet, as byte positions in the decompressed buffer.
#[derive(Default)]
pub(super) struct Pending {
    pub(super) camera: u8,
    pub(super) next: usize,
    pub(super) end: usize,
    pub(super) index: usize,
    pub(super) packet_offset: u64,
}

/// Streaming AEDAT 4.0 reader: one packet in memory at a time, or with several event streams
/// (cameras) a time merge of their packets.
///
/// A file of several cameras holds each camera's packets (DV's span up to 10 ms, as
/// [`super::Aedat4Writer`]'s do) in the order they were recorded, so packet order is time order
/// only to within a packet. The reader merges the cameras by time: it buffers decoded events
/// and gives the earliest camera's next event once the file has reached [`MERGE_SPAN_US`] past
/// it (the latest of the cameras' last decoded events), or more than [`MERGE_EVENTS`] events
/// are buffered, or the file ends; ties go to the lower camera id. Each camera's events keep
/// their file order exactly, so a camera's own time glitches stay where they are (one far
/// ahead of the events around it is due with the next). A damaged packet ends the read after the
/// events buffered before it. The merge looks at every camera's next event for each event it
/// gives (of 2 to 8 cameras, without a branch per camera), so its cost grows with their number
/// (`cargo bench -p evpose-host --bench readers`, on an Intel Xeon VM: four cameras 38 M
/// events/s, one 66 M; LZ4).
pub struct Aedat4Reader<R> {
    pub(super) inner: R,
    pub(super) info: StreamInfo,
    pub(super) compression: Compression,
    pub(super) streams: Routes,
    pub(super) data_table: Option<u64>,
    pub(super) pos: u64,
    pub(super) raw: Vec<u8>,
    pub(super) plain: Vec<u8>,
    pub(super) pending: Pending,
    pub(super) skipped: u64,
    pub(super) finished: bool,
    /// The time merge of a file with several cameras.
    pub(super) merge: Option<Merge>,
}

/// Buffered events of each camera of a several-camera file, merged by time.
pub(super) struct Merge {
    queues: Vec<VecDeque<Event>>,
    /// Events in `queues`.
    buffered: usize,
    /// Each camera's last decoded event time (`i64::MIN` before its first).
    last: Vec<i64>,
    /// Each camera's last given event time (`i64::MIN` before its first).
    given: Vec<i64>,
    /// When each camera's next event is due ([`Merge::refresh`]); `None` when none is buffered.
    due: Vec<Option<i64>>,
    /// No packet is left to read (the file ended, or `error`).
    eof: bool,
    /// The error that ended the packets, returned once the buffered events are given.
    error: Option<ReadError>,
}

impl Merge {
    /// Recomputes when camera `c`'s next event is due (after its queue's front changed). It
    /// is due at its own time, unless it lies more than [`MERGE_SPAN_US`] after both the
    /// camera's previous event and its next one (a timestamp glitch forward): then at the next
    /// one's, so that a glitch an hour ahead leaves with the events around it instead of
    /// holding its camera back.
    fn refresh(&mut self, c: usize) {
        let q = &self.queues[c];
        self.due[c] = q
            .front()
            .map(|e| due_time(e.t, q.get(1).map(|next| next.t), self.given[c]));
    }

    /// The camera whose next event is due first, if any is buffered, and when.
    fn earliest(&self) -> Option<(usize, i64)> {
        (self.due.iter().enumerate())
            .filter_map(|(c, due)| Some((c, (*due)?)))
            .min_by_key(|&(c, t)| (t, c))
    }

    /// The latest time the file has reached: the latest of each camera's last decoded event
    /// (not the latest event ever decoded, so that one glitch forward does not release every
    /// buffered event at once).
    fn latest(&self) -> i64 {
        self.last.iter().copied().max().unwrap_or(i64::MIN)
    }

    /// Moves the buffered events that are ready into `batch` in time order, until it holds
    /// [`BATCH_EVENTS`]: what [`Merge::give_one`] gives event by event (the earliest camera's
    /// next, while it is ready), mostly through [`Merge::give_plain`], which gives the same
    /// events in about half the time while no camera's next event is due beyond ±2^55 µs.
    fn give(&mut self, batch: &mut Batch) {
        let latest = self.latest();
        while batch.len() < BATCH_EVENTS {
            self.give_plain(latest, batch);
            if batch.len() >= BATCH_EVENTS {
                break;
            }
            // Where `give_plain` stopped: nothing ready, or a front it does not take.
            let Some((c, _)) = self.earliest().filter(|&(_, t)| self.ready(t, latest)) else {
                break;
            };
            self.give_one(c, batch);
        }
    }

    /// Gives camera `c`'s next event.
    fn give_one(&mut self, c: usize, batch: &mut Batch) {
        if let Some(e) = self.queues[c].pop_front() {
            // `c` < the camera count ≤ 256 (`route_streams`).
            batch.push(c as u8, e);
            self.given[c] = e.t;
            self.buffered -= 1;
            self.refresh(c);
        }
    }

    /// [`Merge::give_one`] repeated (`latest`: [`Merge::latest`]) for files of 2 to 8 cameras
    /// (more are merged event by event), while the earliest camera's next event is due
    /// ([`Merge::refresh`]) in `[−2^55, 2^55)` µs ([`front_key`]). Stops before any other event;
    /// the caller gives that one.
    fn give_plain(&mut self, latest: i64, batch: &mut Batch) {
        match self.queues.len() {
            2 => self.give_plain_n::<2>(latest, batch),
            3 => self.give_plain_n::<3>(latest, batch),
            4 => self.give_plain_n::<4>(latest, batch),
            5 => self.give_plain_n::<5>(latest, batch),
            6 => self.give_plain_n::<6>(latest, batch),
            7 => self.give_plain_n::<7>(latest, batch),
            8 => self.give_plain_n::<8>(latest, batch),
            _ => {}
        }
    }

    /// [`Merge::give_plain`] for `N` cameras: their next events' keys `due · 2^8 + camera`
    /// ([`front_key`]) side by side, the least one given, no queue touched until the end. The least key is taken
    /// with selects, not a branch per camera: the cameras of a recording interleave at random,
    /// so a branch on which is earlier is hard to predict (four cameras: 27 → 38 M events/s in `cargo
    /// bench -p evpose-host --bench readers`, against one event at a time through
    /// [`Merge::earliest`]).
    fn give_plain_n<const N: usize>(&mut self, latest: i64, batch: &mut Batch) {
        /// A key of no event: above every other.
        const NONE: i64 = i64::MAX;
        let Some(queues) = self.queues.get_mut(..N) else {
            return;
        };
        // Ready: the first `force` events whatever their time (while more than `MERGE_EVENTS`
        // are buffered; all at the end of the file), then those due by `thr`.
        let force = if self.eof {
            usize::MAX
        } else {
            self.buffered.saturating_sub(MERGE_EVENTS)
        };
        let thr = latest.saturating_sub(MERGE_SPAN_US);
        let room = BATCH_EVENTS.saturating_sub(batch.len());
        let mut slices: [&[Event]; N] = [&[]; N];
        // Each camera's next event's key, and whether the loop stops there ([`front_key`]).
        let (mut keys, mut stops) = ([NONE; N], [false; N]);
        for (c, q) in queues.iter_mut().enumerate() {
            slices[c] = q.make_contiguous();
            (keys[c], stops[c]) = front_key(slices[c], 0, self.given[c], c);
        }
        let mut next = [0usize; N];
        batch.events.reserve(room);
        batch.cameras.reserve(room);
        let mut n = 0;
        while n < room {
            let key = keys.iter().copied().fold(NONE, i64::min);
            let (c, t) = ((key & 0xff) as usize, key >> 8);
            if key == NONE || stops.get(c).is_none_or(|&s| s) || (n >= force && t > thr) {
                break;
            }
            let (Some(&q), Some(&i)) = (slices.get(c), next.get(c)) else {
                break; // (`c` is a camera's: keys hold their camera)
            };
            let Some(&e) = q.get(i) else {
                break; // (a key is only set for an event of its slice)
            };
            batch.push(c as u8, e);
            n += 1;
            (keys[c], stops[c]) = front_key(q, i + 1, e.t, c);
            next[c] = i + 1;
        }
        self.buffered -= n;
        for (c, (q, &taken)) in queues.iter_mut().zip(&next).enumerate() {
            if let Some(last) = taken.checked_sub(1).and_then(|i| q.get(i)) {
                self.given[c] = last.t;
                q.drain(..taken);
            }
        }
        for (c, &taken) in next.iter().enumerate() {
            if taken > 0 {
                self.refresh(c);
            }
        }
    }

    /// Whether an event due at `t` may be given: no later packet can hold an earlier one of
    /// another camera, as far as the merge looks ahead.
    fn ready(&self, t: i64, latest: i64) -> bool {
        self.eof || self.buffered > MERGE_EVENTS || t <= latest.saturating_sub(MERGE_SPAN_US)
    }
}

/// When a camera's next event, at `t`, is due ([`Merge::refresh`]), from the time of the event
/// after it (if buffered) and of the one before it (given).
fn due_time(t: i64, next: Option<i64>, prev: i64) -> i64 {
    let far = t.saturating_sub(MERGE_SPAN_US);
    match next {
        Some(next) if next < far && prev < far => next,
        _ => t,
    }
}

/// Where `q[i]`, camera `c`'s next event, goes in [`Merge::give_plain_n`]'s loop (`prev`: the
/// time of the camera's event before it): its key, and whether the loop stops when it is the
/// least. Past the end of `q`: `i64::MAX`, no event. An event due at `d` ([`Merge::refresh`]:
/// its own time, or its next event's for a glitch) in `[−2^55, 2^55)`: `d · 2^8 + c`, in the
/// merge's order. Due beyond that range: the range's end's or start's key, no later than its
/// place in the merge, and the loop stops there, so that [`Merge::give_one`] gives it (the loop
/// may then stop early, never late).
fn front_key(q: &[Event], i: usize, prev: i64, c: usize) -> (i64, bool) {
    const LIMIT: i64 = 1 << 55;
    let Some(e) = q.get(i) else {
        return (i64::MAX, false);
    };
    let due = due_time(e.t, q.get(i + 1).map(|next| next.t), prev);
    let key = if due >= LIMIT {
        (LIMIT - 1) << 8
    } else if due < -LIMIT {
        i64::MIN
    } else {
        due << 8
    } | c as i64;
    (key, !(-LIMIT..LIMIT).contains(&due))
}

/// What the file header says.
pub(super) struct Header {
    pub(super) compression: Compression,
    pub(super) data_table: Option<u64>,
    pub(super) streams: Vec<StreamDecl>,
    pub(super) end: u64,
}

pub(super) fn read_header(r: &mut impl Read) -> Result<Header, ReadError> {
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

pub(super) fn parse_io_header(buf: &[u8]) -> Result<Header, ReadError> {
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
pub(super) fn route_streams(decls: &[StreamDecl]) -> Result<(Vec<CameraInfo>, Routes), ReadError> {
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
pub(super) fn decompress(
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
pub(super) fn event_vector(plain: &[u8], offset: u64) -> Result<(usize, usize), ReadError> {
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
    /// Parses the magic and the IOHeader; events are read by [`EventReader::read_batch`](crate::io::EventReader::read_batch).
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
            merge: None,
        }
        .with_merge())
    }

    /// Sets up the time merge when the file has several cameras.
    fn with_merge(mut self) -> Self {
        let cameras = self.info.cameras.len();
        if cameras > 1 {
            self.merge = Some(Merge {
                queues: (0..cameras).map(|_| VecDeque::new()).collect(),
                buffered: 0,
                last: vec![i64::MIN; cameras],
                given: vec![i64::MIN; cameras],
                due: vec![None; cameras],
                eof: false,
                error: None,
            });
        }
        self
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
        if self.merge.is_some() {
            return self.fill_merged(batch);
        }
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

impl<R: Read> Aedat4Reader<R> {
    /// [`Aedat4Reader::fill`] for several cameras: the time merge ([`Aedat4Reader`]).
    fn fill_merged(&mut self, batch: &mut Batch) -> Result<(), ReadError> {
        loop {
            let Some(m) = self.merge.as_mut() else {
                return Ok(());
            };
            m.give(batch);
            // A camera's queue gives back what a burst made it grow to.
            for q in m.queues.iter_mut().filter(|q| q.is_empty()) {
                q.shrink_to(BATCH_EVENTS);
            }
            if batch.len() >= BATCH_EVENTS {
                return Ok(());
            }
            if m.eof {
                if m.buffered == 0 {
                    match m.error.take() {
                        // The buffered events first; the error at the next call.
                        Some(e) if !batch.is_empty() => m.error = Some(e),
                        Some(e) => return Err(e),
                        None => self.finished = true,
                    }
                }
                return Ok(());
            }
            let loaded = self.next_packet().and_then(|more| {
                if more {
                    self.queue_pending()?;
                }
                Ok(more)
            });
            if let Some(m) = self.merge.as_mut() {
                match loaded {
                    Ok(true) => {}
                    Ok(false) => m.eof = true,
                    Err(e) => (m.eof, m.error) = (true, Some(e)),
                }
            }
        }
    }

    /// Decodes the loaded packet's events into its camera's queue (those before a bad one,
    /// then the error).
    fn queue_pending(&mut self) -> Result<(), ReadError> {
        let (Some(m), p) = (self.merge.as_mut(), &mut self.pending) else {
            return Ok(());
        };
        let c = usize::from(p.camera);
        let Some(queue) = m.queues.get_mut(c) else {
            return Ok(());
        };
        let mut result = Ok(());
        for chunk in self.plain[p.next..p.end].chunks_exact(EVENT_BYTES) {
            let Some(event) = decode_event(chunk) else {
                result = Err(ReadError::Corrupt {
                    offset: p.packet_offset,
                    message: format!("event {} of the packet has a negative coordinate", p.index),
                });
                break;
            };
            queue.push_back(event);
            m.buffered += 1;
            p.index += 1;
            p.next += EVENT_BYTES;
        }
        if let Some(e) = queue.back() {
            m.last[c] = e.t;
        }
        m.refresh(c);
        result
    }
}

/// Decodes one 16-byte event struct; `None` for a negative coordinate.
pub(super) fn decode_event(chunk: &[u8]) -> Option<Event> {
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

impl<R: Read> super::super::source::Fill for Aedat4Reader<R> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A merge over `queues` (each camera's buffered events, in ring buffers that start
    /// `skew` slots in, so that longer ones wrap), as [`Aedat4Reader`] leaves it after loading
    /// them, its cameras' last given times `given`. With `unforced`, the count of buffered
    /// events is set `MERGE_EVENTS` higher (too many to buffer in a test) less `unforced`, so
    /// that all but the last `unforced` events given are ready whatever their time.
    fn merge(
        queues: &[Vec<Event>],
        given: &[i64],
        eof: bool,
        skew: usize,
        unforced: Option<usize>,
    ) -> Merge {
        let count = queues.iter().map(Vec::len).sum::<usize>();
        let n = queues.len();
        let ring = |q: &Vec<Event>| {
            let mut d = VecDeque::with_capacity(q.len() + skew);
            d.extend(std::iter::repeat_n(Event::default(), skew));
            d.drain(..skew);
            d.extend(q.iter().copied());
            d
        };
        let mut m = Merge {
            queues: queues.iter().map(ring).collect(),
            buffered: unforced.map_or(count, |u| MERGE_EVENTS + count.saturating_sub(u)),
            last: (queues.iter())
                .map(|q| q.last().map_or(i64::MIN, |e| e.t))
                .collect(),
            given: given.iter().copied().cycle().take(n).collect(),
            due: vec![None; n],
            eof,
            error: None,
        };
        (0..n).for_each(|c| m.refresh(c));
        m
    }

    /// The merge as first written: one event at a time, every camera looked at for each.
    fn give_one_by_one(m: &mut Merge, batch: &mut Batch) {
        let latest = m.latest();
        while batch.len() < BATCH_EVENTS {
            let Some((c, _)) = m.earliest().filter(|&(_, t)| m.ready(t, latest)) else {
                break;
            };
            m.give_one(c, batch);
        }
    }

    /// A camera's events: mostly rising times on a coarse grid (ties across cameras), some
    /// going back, some glitches far ahead, a few at and beyond the fast keys' range.
    fn camera() -> impl Strategy<Value = Vec<Event>> {
        const EDGES: [i64; 7] = [
            i64::MIN,
            -(1 << 55) - 1,
            -(1 << 55),
            (1 << 55) - 1,
            1 << 55,
            i64::MAX - 1,
            i64::MAX,
        ];
        let steps = (0u8..40, 0i64..40, any::<bool>());
        prop::collection::vec(steps, 0..300)
            .prop_map(|steps| {
                let mut t = 0;
                let at = |kind: u8, dt: i64, t: &mut i64| match kind {
                    0 | 1 => *t + 3 * MERGE_SPAN_US,   // a glitch ahead
                    2 => *t - dt * 1000,               // backwards
                    3 if dt < 7 => EDGES[dt as usize], // at the keys' range
                    _ => {
                        *t += dt * 1000;
                        *t
                    }
                };
                (steps.into_iter())
                    .map(|(kind, dt, on)| Event::new(dt as u16, 1, at(kind, dt, &mut t), on))
                    .collect::<Vec<_>>()
            })
            .prop_flat_map(|events| {
                // Often a last event at an edge: such fronts stay till the end, side by side.
                let tail = prop::option::weighted(0.3, 0..EDGES.len());
                (Just(events), tail).prop_map(|(mut events, tail)| {
                    events.extend(tail.map(|k| Event::new(0, 2, EDGES[k], true)));
                    events
                })
            })
    }

    proptest! {
        /// The merge gives exactly what one event at a time gives: the same events in the
        /// same order and the same state after, whatever the room left in the batch.
        #[test]
        fn the_merge_gives_what_single_events_give(
            queues in prop::collection::vec(camera(), 1..10),
            given in prop::collection::vec(prop_oneof![Just(i64::MIN), -400_000i64..400_000], 1..4),
            eof in any::<bool>(),
            room in 1usize..3000,
            skew in 0usize..400,
            unforced in prop::option::of(0usize..30),
        ) {
            let a = || merge(&queues, &given, eof, skew, unforced);
            let (mut a, mut b) = (a(), a());
            let full = Batch {
                events: vec![Event::new(0, 0, 0, false); BATCH_EVENTS - room],
                cameras: vec![0; BATCH_EVENTS - room],
            };
            let (mut got, mut want) = (full.clone(), full);
            a.give(&mut got);
            give_one_by_one(&mut b, &mut want);
            prop_assert_eq!(&got.events, &want.events);
            prop_assert_eq!(&got.cameras, &want.cameras);
            prop_assert_eq!(a.buffered, b.buffered);
            prop_assert_eq!(&a.given, &b.given);
            prop_assert_eq!(&a.due, &b.due);
            let left = |m: &Merge| m.queues.iter().map(|q| q.iter().copied().collect()).collect::<Vec<Vec<Event>>>();
            prop_assert_eq!(left(&a), left(&b));
        }
    }
}

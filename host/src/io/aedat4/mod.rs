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
//! order. Packets of other streams are skipped without being decompressed. Several cameras'
//! events are merged by time ([`Aedat4Reader`]).
//!
//! The flatbuffers are read by the small bounds-checked reader below, not generated code:
//! every offset is checked, so damaged input gives a [`ReadError`](crate::io::ReadError), never a panic, and no
//! allocation follows a size field beyond [`MAX_PACKET_BYTES`].

mod flatbuf;
mod read;
mod write;
mod xml;

pub use read::Aedat4Reader;
pub use write::Aedat4Writer;

/// The 14 bytes every AEDAT 4.0 file starts with.
pub const MAGIC: &[u8; 14] = b"#!AER-DAT4.0\r\n";

/// Largest IOHeader accepted, in bytes.
pub const MAX_HEADER_BYTES: u32 = 16 << 20;

/// Largest packet accepted, in bytes, before and after decompression.
pub const MAX_PACKET_BYTES: u64 = 256 << 20;

/// Events per packet that [`Aedat4Writer`] writes at most.
pub const WRITE_PACKET_EVENTS: usize = 4096;

/// Longest time from a packet's earliest event to an event that [`Aedat4Writer`] lets arrive
/// before it writes the packet, µs: how far a reader taking packets in file order can see
/// time-ordered events of different cameras out of order.
pub const WRITE_PACKET_SPAN_US: i64 = 10_000;

/// How far past an event the file must have reached before [`Aedat4Reader`] gives it, when
/// it merges several cameras by time, µs (ten of DV's 10-ms packets).
pub const MERGE_SPAN_US: i64 = 100_000;

/// Events [`Aedat4Reader`] buffers while it merges several cameras before it gives the
/// earliest ones whatever the file holds later (16 MiB): the buffer holds at most this many
/// plus the packet being read.
pub const MERGE_EVENTS: usize = 1 << 20;

/// File offset of the IOHeader flatbuffer (after the magic and its u32 size prefix).
pub(super) const HEADER_OFFSET: u64 = MAGIC.len() as u64 + 4;

/// Bytes per event struct in an `EventPacket`.
pub(super) const EVENT_BYTES: usize = 16;

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

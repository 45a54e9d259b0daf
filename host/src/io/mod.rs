//! Event recording readers: one streaming interface, one module per format.
//!
//! Every reader yields events in batches of bounded size, so memory stays constant whatever the
//! file size. Damaged input gives a [`ReadError`] that names the byte offset, never a panic.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use evpose_core::Event;

pub mod aedat4;
pub mod npy;

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
}

/// File formats the readers understand.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Format {
    /// NumPy `.npy`, an (N, 4) array `[x, y, t_us, p]`.
    Npy,
    /// iniVation DV AEDAT 4.0.
    Aedat4,
}

impl Format {
    /// Guesses the format from the first bytes of a file.
    pub fn detect(head: &[u8]) -> Option<Self> {
        if head.starts_with(b"\x93NUMPY") {
            Some(Self::Npy)
        } else if head.starts_with(b"#!AER-DAT4.0") {
            Some(Self::Aedat4)
        } else {
            None
        }
    }

    /// Human-readable name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Npy => "npy",
            Self::Aedat4 => "aedat4",
        }
    }
}

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
}

/// Opens a recording, detecting its format from its first bytes unless `format` is given.
pub fn open(path: &Path, format: Option<Format>) -> anyhow::Result<Box<dyn EventReader>> {
    use anyhow::Context;
    let format = match format {
        Some(f) => f,
        None => {
            let mut file =
                File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
            let mut head = [0u8; 16];
            let n = read_up_to(&mut file, &mut head)?;
            Format::detect(&head[..n]).with_context(|| {
                format!(
                    "{}: unknown event file format (first bytes {:02x?}); pass --format",
                    path.display(),
                    &head[..n]
                )
            })?
        }
    };
    let file = BufReader::with_capacity(
        1 << 16,
        File::open(path).with_context(|| format!("cannot open {}", path.display()))?,
    );
    let reader: Box<dyn EventReader> = match format {
        Format::Npy => Box::new(npy::NpyReader::new(file)?),
        Format::Aedat4 => Box::new(aedat4::Aedat4Reader::new(file)?),
    };
    Ok(reader)
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

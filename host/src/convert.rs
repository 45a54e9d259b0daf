//! `evpose convert`: a recording to an (N, 4) `.npy` array, to AEDAT 4.0 or to a Prophesee RAW
//! file (EVT 3.0, 2.0 or 2.1), streaming.

use std::path::Path;

use anyhow::{bail, Context, Result};
use npyz::WriterBuilder;

use crate::io::aedat4::{Aedat4Writer, Compression};
use crate::io::evt::Encoding;
use crate::io::{self, Batch, CameraInfo, OpenOptions};
use crate::summary::summarize_with;

/// What a conversion wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Converted {
    /// Events written.
    pub events: u64,
    /// Cameras written (the i-th AEDAT 4 stream holds the i-th).
    pub cameras: Vec<u8>,
    /// What the user should know (a camera without events, a missing sensor size).
    pub warnings: Vec<String>,
    /// What the reader assumed where the file is ambiguous (the time unit of a text file, the
    /// sensor of an AEDAT 2.0 file): [`io::ReadNotes::assumptions`].
    pub assumptions: Vec<String>,
}

/// Refuses to write over the recording being read (the output is created before the input has
/// been read to its end).
fn check_distinct(file: &Path, out: &Path) -> Result<()> {
    if let (Ok(a), Ok(b)) = (file.canonicalize(), out.canonicalize()) {
        if a == b {
            bail!(
                "{}: the output would overwrite the recording it reads",
                out.display()
            );
        }
    }
    Ok(())
}

/// Largest |t| (µs) that f64 holds exactly: 2^53.
const EXACT_IN_F64: i64 = 1 << 53;

/// Writes `camera`'s events of the recording `file` (read with `opts`) to `out` as an (N, 4)
/// float64 `.npy` array `[x, y, t_us, p]`. Two streaming passes (count, then write): memory
/// does not grow with the file. A timestamp beyond 2^53 µs (which f64 would round; e.g.
/// nanoseconds read as µs) is an error.
pub fn to_npy(file: &Path, opts: &OpenOptions, camera: u8, out: &Path) -> Result<Converted> {
    check_distinct(file, out)?;
    let summary = summarize_with(file, opts)?;
    let warnings: Vec<String> = summary.no_events_warning(camera).into_iter().collect();
    let n = summary
        .cameras
        .iter()
        .find(|c| c.camera == camera)
        .map_or(0, |c| c.events);
    let mut reader = io::open_with(file, opts)?;
    let path = file;
    let file =
        std::fs::File::create(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut w = npyz::WriteOptions::<f64>::new()
        .default_dtype()
        .shape(&[n, 4])
        .writer(std::io::BufWriter::new(file))
        .begin_nd()?;
    let mut batch = Batch::default();
    let mut written = 0u64;
    while reader
        .read_batch(&mut batch)
        .with_context(|| format!("{}", path.display()))?
    {
        for e in batch.of_camera(camera) {
            if e.t.unsigned_abs() > EXACT_IN_F64 as u64 {
                bail!(
                    "{}: timestamp {} µs does not fit a float64 exactly (beyond 2^53): \
                     nanoseconds read as µs? (--time-unit)",
                    path.display(),
                    e.t
                );
            }
            w.extend([
                f64::from(e.x),
                f64::from(e.y),
                e.t as f64,
                f64::from(u8::from(e.on)),
            ])?;
            written += 1;
        }
    }
    if written != n {
        bail!("{} changed while converting", path.display());
    }
    w.finish()?;
    Ok(Converted {
        events: written,
        cameras: vec![camera],
        warnings,
        assumptions: summary.notes.assumptions,
    })
}

/// A Prophesee RAW writer of either family: EVT 3.0, or EVT 2.0 / 2.1.
enum RawWriter<W: std::io::Write> {
    Evt3(io::evt::Evt3Writer<W>),
    Evt2(io::evt::Evt2Writer<W>),
}

impl<W: std::io::Write> RawWriter<W> {
    fn new(out: W, encoding: Encoding, (width, height): (u16, u16)) -> std::io::Result<Self> {
        Ok(match encoding {
            Encoding::Evt3 => Self::Evt3(io::evt::Evt3Writer::new(out, width, height)?),
            e => Self::Evt2(io::evt::Evt2Writer::new(out, e, width, height)?),
        })
    }
    fn write(&mut self, events: &[evpose_core::Event]) -> std::io::Result<()> {
        match self {
            Self::Evt3(w) => w.write(events),
            Self::Evt2(w) => w.write(events),
        }
    }
    fn origin(&self) -> Option<i64> {
        match self {
            Self::Evt3(w) => w.origin(),
            Self::Evt2(w) => w.origin(),
        }
    }
    fn finish(self) -> std::io::Result<W> {
        match self {
            Self::Evt3(w) => w.finish(),
            Self::Evt2(w) => w.finish(),
        }
    }
}

/// Writes `camera`'s events of the recording `file` (read with `opts`) to `out` as a Prophesee
/// RAW file in `encoding` (EVT 3.0: [`io::evt::Evt3Writer`]; EVT 2.0 and both EVT 2.1 byte
/// orders: [`io::evt::Evt2Writer`]), streaming. The sensor size is the one the file states, else
/// `--width/--height`; without either it is an error (a RAW header states it).
pub fn to_raw(
    file: &Path,
    opts: &OpenOptions,
    camera: u8,
    out: &Path,
    encoding: Encoding,
) -> Result<Converted> {
    check_distinct(file, out)?;
    let mut reader = io::open_with(file, opts)?;
    let info = reader.info().clone();
    let stated = info
        .cameras
        .iter()
        .find(|c| c.id == camera)
        .or(info.cameras.first())
        .and_then(|c| c.width.zip(c.height));
    let Some((width, height)) = stated.or(opts.size) else {
        bail!(
            "{} states no sensor size, which a Prophesee RAW header needs: pass --width and \
             --height",
            file.display()
        );
    };
    io::evt::check_raw_size(width, height)?;
    let path = file;
    let file =
        std::fs::File::create(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut w = RawWriter::new(std::io::BufWriter::new(file), encoding, (width, height))?;
    let mut copy = || -> Result<(u64, i64)> {
        let mut batch = Batch::default();
        let mut picked = Vec::new();
        let mut written = 0u64;
        while reader
            .read_batch(&mut batch)
            .with_context(|| format!("{}", path.display()))?
        {
            picked.clear();
            picked.extend(batch.of_camera(camera));
            w.write(&picked)
                .with_context(|| format!("cannot write {}", out.display()))?;
            written += picked.len() as u64;
        }
        Ok((written, w.origin().unwrap_or(0)))
    };
    // A refused event leaves no half-written file that would look like a whole one.
    let copied = copy().and_then(|done| Ok((done, w.finish()?)));
    let ((written, origin), _) = copied.inspect_err(|_| {
        let _ = std::fs::remove_file(out);
    })?;
    let mut warnings = Vec::new();
    if written == 0 {
        warnings.push(format!("{}: camera {camera} has no events", path.display()));
    }
    let mut assumptions = reader.notes().assumptions;
    if origin != 0 {
        assumptions.push(if encoding == Encoding::Evt3 {
            format!(
                "times written from {origin} µs, the 2^24-µs boundary at or before the first \
                 event's (EVT 3.0 holds 24 bits of time)"
            )
        } else {
            format!(
                "times written from {origin} µs, the 64-µs boundary about a second before the \
                 first event's (EVT 2.x holds 34 bits of time: 4.8 hours)"
            )
        });
    }
    Ok(Converted {
        events: written,
        cameras: vec![camera],
        warnings,
        assumptions,
    })
}

/// Writes the recording `file` (read with `opts`) to `out` as AEDAT 4.0 (LZ4, one event
/// stream per camera, readable by DV tools): every camera, or only `camera`.
pub fn to_aedat4(
    file: &Path,
    opts: &OpenOptions,
    camera: Option<u8>,
    out: &Path,
) -> Result<Converted> {
    check_distinct(file, out)?;
    let summary = summarize_with(file, opts)?;
    let mut warnings = Vec::new();
    let mut cameras: Vec<CameraInfo> = summary
        .cameras
        .iter()
        .filter(|c| camera.is_none_or(|want| want == c.camera))
        .map(|c| CameraInfo {
            id: c.camera,
            width: c.width,
            height: c.height,
            name: c.name.clone(),
        })
        .collect();
    if cameras.is_empty() {
        let id = camera.unwrap_or(0);
        // The recording has events, not of this camera: an empty stream is written.
        warnings.extend(summary.no_events_warning(id));
        // The size the file states for its cameras (they share the sensor), else the flags.
        let stated = summary.cameras.iter().find_map(|c| c.width.zip(c.height));
        let (width, height) = stated.or(opts.size).unzip();
        cameras.push(CameraInfo {
            id,
            width,
            height,
            name: None,
        });
    }
    if cameras.iter().any(|c| c.width.is_none()) {
        warnings.push(format!(
            "{} states no sensor size; DV tools expect one: pass --width and --height",
            file.display()
        ));
    }
    let path = file;
    let file =
        std::fs::File::create(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut w = Aedat4Writer::new(std::io::BufWriter::new(file), &cameras, Compression::Lz4)?;
    let mut reader = io::open_with(path, opts)?;
    let mut batch = Batch::default();
    let mut picked = Batch::default();
    let mut written = 0u64;
    while reader
        .read_batch(&mut batch)
        .with_context(|| format!("{}", path.display()))?
    {
        let part = match camera {
            None => &batch,
            Some(want) => {
                picked.clear();
                for e in batch.of_camera(want) {
                    picked.push(want, e);
                }
                &picked
            }
        };
        w.write(part)
            .with_context(|| format!("cannot write {}", out.display()))?;
        written += part.len() as u64;
    }
    w.finish()?;
    Ok(Converted {
        events: written,
        cameras: cameras.iter().map(|c| c.id).collect(),
        warnings,
        assumptions: summary.notes.assumptions,
    })
}

//! What `evpose info` reports: per-camera event counts, polarities and time spans of a
//! recording, in one streaming pass.

use std::path::Path;

use anyhow::{Context, Result};
use serde::Serialize;

use crate::io::{self, Batch, CameraInfo, EventReader, Format};

/// Per-camera statistics of a recording.
#[derive(Clone, Debug, Default, Serialize, PartialEq, Eq)]
pub struct CameraSummary {
    /// Camera id.
    pub camera: u8,
    /// Sensor width, if the file states it (or `--width` gives it).
    pub width: Option<u16>,
    /// Sensor height, if the file states it (or `--height` gives it).
    pub height: Option<u16>,
    /// Source name, if the file states one.
    pub name: Option<String>,
    /// Events of this camera.
    pub events: u64,
    /// ON events.
    pub on: u64,
    /// OFF events.
    pub off: u64,
    /// First timestamp in file order, µs.
    pub first_t: Option<i64>,
    /// Last timestamp in file order, µs.
    pub last_t: Option<i64>,
    /// Span from the earliest to the latest timestamp, µs (never negative, whatever the file
    /// order).
    pub duration_us: Option<i64>,
    /// Earliest and latest timestamps, µs (for the span).
    #[serde(skip)]
    t_range: Option<(i64, i64)>,
}

/// What `evpose info` reports.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingSummary {
    /// The file.
    pub file: String,
    /// Its format, as the reader settled it (e.g. `aedat2-dhp19` for a detected `aedat2`).
    pub format: Format,
    /// All events, all cameras.
    pub events: u64,
    /// One entry per camera.
    pub cameras: Vec<CameraSummary>,
    /// What the reader skipped, repaired or assumed.
    pub notes: io::ReadNotes,
}

impl RecordingSummary {
    /// A warning when `camera` has no events while the recording has some, naming the cameras
    /// that do (for the commands that take `--camera`).
    pub fn no_events_warning(&self, camera: u8) -> Option<String> {
        let mine = self.cameras.iter().find(|c| c.camera == camera);
        if mine.is_some_and(|c| c.events > 0) || self.events == 0 {
            return None;
        }
        let with: Vec<String> = self
            .cameras
            .iter()
            .filter(|c| c.events > 0)
            .map(|c| c.camera.to_string())
            .collect();
        Some(format!(
            "camera {camera} has no events (cameras with events: {}); pass --camera",
            with.join(", ")
        ))
    }
}

/// Streams a recording once and summarizes it.
pub fn summarize(path: &Path, format: Option<Format>) -> Result<RecordingSummary> {
    summarize_with(
        path,
        &io::OpenOptions {
            format,
            ..io::OpenOptions::default()
        },
    )
}

/// Streams a recording once and summarizes it, reading it with `opts`.
pub fn summarize_with(path: &Path, opts: &io::OpenOptions) -> Result<RecordingSummary> {
    let mut reader = io::open_with(path, opts)?;
    summarize_reader(reader.as_mut(), &path.display().to_string())
}

/// Summarizes a stream (read to its end); `name` names it in the summary and in errors.
pub fn summarize_reader(reader: &mut dyn EventReader, name: &str) -> Result<RecordingSummary> {
    let mut cameras: Vec<CameraSummary> =
        reader.info().cameras.iter().map(camera_summary).collect();
    let mut batch = Batch::default();
    while reader
        .read_batch(&mut batch)
        .with_context(|| name.to_owned())?
    {
        for (e, &cam) in batch.events.iter().zip(&batch.cameras) {
            let s = match cameras.iter_mut().position(|c| c.camera == cam) {
                Some(i) => &mut cameras[i],
                None => {
                    cameras.push(CameraSummary {
                        camera: cam,
                        ..CameraSummary::default()
                    });
                    cameras.last_mut().expect("just pushed")
                }
            };
            s.events += 1;
            if e.on {
                s.on += 1;
            } else {
                s.off += 1;
            }
            s.first_t.get_or_insert(e.t);
            s.last_t = Some(e.t);
            s.t_range = Some(
                s.t_range
                    .map_or((e.t, e.t), |(a, b)| (a.min(e.t), b.max(e.t))),
            );
        }
    }
    // Cameras a reader declared while reading (AEDAT 3.1 sources) have their info now.
    let info = reader.info();
    for c in &mut cameras {
        if let Some(i) = info.cameras.iter().find(|i| i.id == c.camera) {
            c.width = c.width.or(i.width);
            c.height = c.height.or(i.height);
            c.name = c.name.take().or_else(|| i.name.clone());
        }
        c.duration_us = c.t_range.map(|(a, b)| b - a);
    }
    cameras.sort_by_key(|c| c.camera);
    Ok(RecordingSummary {
        file: name.to_owned(),
        format: info.format,
        events: cameras.iter().map(|c| c.events).sum(),
        cameras,
        notes: reader.notes(),
    })
}

fn camera_summary(c: &CameraInfo) -> CameraSummary {
    CameraSummary {
        camera: c.id,
        width: c.width,
        height: c.height,
        name: c.name.clone(),
        ..CameraSummary::default()
    }
}

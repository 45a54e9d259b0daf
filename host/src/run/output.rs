//! `evpose run --out`: the poses as JSON (an array, one object per window), JSON lines (one
//! object per line) or CSV (one row per window, view and joint), streamed window by window.
//!
//! The object is [`RunWindow`] (schema in the README). CSV columns:
//! `window,t_start_us,t_end_us,view,joint,name,x,y,z,confidence`, where `view` is a camera id
//! with `x, y` in its pixels (`z` empty) or `3d` with `x, y, z` in mm (`confidence` the mean
//! of the views'); a joint that could not be triangulated has no `3d` row.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use evpose_core::skeleton::JOINT_NAMES;

use super::RunWindow;

/// An output format, from a file's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// `.json`: one array of window objects.
    Json,
    /// `.jsonl`: one window object per line.
    JsonLines,
    /// `.csv`: one row per window, view and joint.
    Csv,
}

impl Kind {
    /// The format of `path` by its extension.
    pub fn of(path: &Path) -> Result<Self> {
        match path.extension().and_then(|e| e.to_str()) {
            Some("json") => Ok(Self::Json),
            Some("jsonl") => Ok(Self::JsonLines),
            Some("csv") => Ok(Self::Csv),
            _ => bail!(
                "{}: the output format comes from the extension: .json, .jsonl or .csv",
                path.display()
            ),
        }
    }
}

/// The CSV header.
pub const CSV_HEADER: &str = "window,t_start_us,t_end_us,view,joint,name,x,y,z,confidence";

/// A streaming writer of one output file.
pub struct PoseWriter {
    kind: Kind,
    out: BufWriter<Box<dyn Write>>,
    path: PathBuf,
    written: usize,
}

impl PoseWriter {
    /// Creates `path` (format by extension).
    pub fn create(path: &Path) -> Result<Self> {
        let kind = Kind::of(path)?;
        let file =
            File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
        Self::new(kind, Box::new(file), path)
    }

    /// A writer of `kind` into any sink (`name` for messages).
    pub fn new(kind: Kind, sink: Box<dyn Write>, name: &Path) -> Result<Self> {
        let mut w = Self {
            kind,
            out: BufWriter::new(sink),
            path: name.to_path_buf(),
            written: 0,
        };
        match kind {
            Kind::Json => w.out.write_all(b"[\n"),
            Kind::Csv => writeln!(w.out, "{CSV_HEADER}"),
            Kind::JsonLines => Ok(()),
        }
        .with_context(|| w.path.display().to_string())?;
        Ok(w)
    }

    /// Appends one window.
    pub fn write(&mut self, w: &RunWindow) -> Result<()> {
        let path = self.path.display().to_string();
        match self.kind {
            Kind::Json => {
                if self.written > 0 {
                    self.out.write_all(b",\n").context(path.clone())?;
                }
                serde_json::to_writer(&mut self.out, w).context(path.clone())?;
            }
            Kind::JsonLines => {
                serde_json::to_writer(&mut self.out, w).context(path.clone())?;
                self.out.write_all(b"\n").context(path.clone())?;
            }
            Kind::Csv => write_csv(&mut self.out, w).context(path.clone())?,
        }
        self.written += 1;
        Ok(())
    }

    /// Closes the output (the JSON array's bracket) and flushes it.
    pub fn finish(mut self) -> Result<()> {
        if self.kind == Kind::Json {
            self.out.write_all(b"\n]\n")?;
        }
        self.out
            .flush()
            .with_context(|| format!("cannot write {}", self.path.display()))
    }
}

fn name(j: usize) -> &'static str {
    JOINT_NAMES.get(j).copied().unwrap_or("")
}

fn write_csv(out: &mut impl Write, w: &RunWindow) -> std::io::Result<()> {
    let [t0, t1] = w.t_us;
    for cam in &w.cameras {
        for (j, [x, y]) in cam.joints.iter().enumerate() {
            let c = cam
                .confidence
                .get(j)
                .map_or(String::new(), |c| c.to_string());
            writeln!(
                out,
                "{},{t0},{t1},{},{j},{},{x},{y},,{c}",
                w.window,
                cam.camera,
                name(j)
            )?;
        }
    }
    if let Some(j3) = &w.joints3d {
        for (j, p) in j3.iter().enumerate() {
            let Some([x, y, z]) = p else { continue };
            let confs: Vec<f32> = w
                .cameras
                .iter()
                .filter_map(|c| c.confidence.get(j).copied())
                .collect();
            let c = if confs.is_empty() {
                String::new()
            } else {
                (confs.iter().sum::<f32>() / confs.len() as f32).to_string()
            };
            writeln!(
                out,
                "{},{t0},{t1},3d,{j},{},{x},{y},{z},{c}",
                w.window,
                name(j)
            )?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::CameraPose;

    fn window(i: usize) -> RunWindow {
        RunWindow {
            window: i,
            t_us: [100, 200],
            events: 30,
            no_body: Some(false),
            view_disagreement_px: None,
            cameras: vec![CameraPose {
                camera: 2,
                events: 10,
                points: 9,
                joints: vec![[1.5, 2.0], [3.0, 4.0]],
                raw_joints: None,
                confidence: vec![0.5, 0.25],
            }],
            joints3d: Some(vec![Some([1.0, 2.0, 3.0]), None]),
            error: None,
        }
    }

    /// A sink the test can read back.
    #[derive(Clone, Default)]
    struct Shared(std::rc::Rc<std::cell::RefCell<Vec<u8>>>);
    impl Write for Shared {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.borrow_mut().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn written(kind: Kind, windows: usize) -> String {
        let sink = Shared::default();
        let mut w = PoseWriter::new(kind, Box::new(sink.clone()), Path::new("t")).unwrap();
        for i in 0..windows {
            w.write(&window(i)).unwrap();
        }
        w.finish().unwrap();
        let bytes = sink.0.borrow().clone();
        String::from_utf8(bytes).unwrap()
    }

    #[test]
    fn json_is_one_array_that_reads_back() {
        for n in [0, 1, 3] {
            let text = written(Kind::Json, n);
            let back: Vec<RunWindow> = serde_json::from_str(&text).unwrap();
            assert_eq!(back, (0..n).map(window).collect::<Vec<_>>());
        }
        let lines = written(Kind::JsonLines, 2);
        let back: Vec<RunWindow> = lines
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(back, vec![window(0), window(1)]);
    }

    #[test]
    fn csv_has_a_row_per_view_and_joint() {
        let text = written(Kind::Csv, 1);
        let rows: Vec<&str> = text.lines().collect();
        assert_eq!(
            rows,
            vec![
                CSV_HEADER,
                "0,100,200,2,0,head,1.5,2,,0.5",
                "0,100,200,2,1,shoulderR,3,4,,0.25",
                "0,100,200,3d,0,head,1,2,3,0.5",
            ]
        );
        assert!(Kind::of(Path::new("x.txt")).is_err());
        assert_eq!(Kind::of(Path::new("a/b.jsonl")).unwrap(), Kind::JsonLines);
    }
}

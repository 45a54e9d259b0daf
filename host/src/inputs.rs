//! Network inputs from files, for calibration, parity checks and benchmarks: (N, 5) point
//! clouds are sampled as they are; event recordings are cut into windows, rasterized and sampled
//! with the core's code (the preprocessing the firmware runs); an `evpose dataset` directory
//! gives samples spread evenly over it.

use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use evpose_core::raster::DEFAULT_SLICES;
use evpose_core::sample::{rng_from_seed, sample_indices, sample_len, sample_window, SampleRng};

use crate::io::{self, EventReader, OpenOptions};
use crate::model;
use crate::pipeline::{self, Rasterizing, Windowing};

/// How recordings become network inputs.
#[derive(Clone, Debug)]
pub struct Sampling {
    /// Points per input (default: the model's fixed count, else 2,048; 0 keeps all points).
    pub points: Option<usize>,
    /// Events per window when cutting event recordings.
    pub window_events: u32,
    /// Seed of the point sampler.
    pub seed: u64,
    /// At most this many windows per recording.
    pub max_windows: usize,
    /// How to read recordings.
    pub open: OpenOptions,
}

impl Sampling {
    /// The point count for a model with `model_points` fixed points (if any): the explicit
    /// count, else the model's, else [`evpose_core::pipeline::DEFAULT_POINTS`]; an explicit count
    /// that differs from a fixed one is an error.
    pub fn points_for(&self, model_points: Option<usize>) -> Result<usize> {
        let n = self
            .points
            .or(model_points)
            .unwrap_or(evpose_core::pipeline::DEFAULT_POINTS);
        if let Some(fixed) = model_points {
            ensure!(
                n == fixed,
                "the model takes exactly {fixed} points; --points {n} does not fit"
            );
        }
        Ok(n)
    }
}

/// Inputs from files: each an (N, 5) point cloud, an `evpose dataset` directory (at most
/// `max_windows` samples, evenly spaced over it) or an event recording (full windows only, at
/// most `max_windows` per file).
pub fn load(
    files: &[PathBuf],
    s: &Sampling,
    model_points: Option<usize>,
) -> Result<Vec<Vec<[f32; 5]>>> {
    let n = s.points_for(model_points)?;
    let mut rng = rng_from_seed(s.seed);
    let mut out = Vec::new();
    for f in files {
        if f.join("manifest.json").is_file() {
            out.extend(from_dataset(f, s.max_windows, n, &mut rng)?);
            continue;
        }
        if let Ok(points) = model::read_points(f) {
            out.push(sample_cloud(&points, n, &mut rng)?);
            continue;
        }
        let mut reader = io::open_with(f, &s.open).with_context(|| {
            format!(
                "{}: neither an (N, 5) point cloud nor a readable event file",
                f.display()
            )
        })?;
        out.extend(
            from_reader(reader.as_mut(), s, n, &mut rng)
                .with_context(|| f.display().to_string())?,
        );
    }
    ensure!(!out.is_empty(), "no input windows in {files:?}");
    Ok(out)
}

/// Up to `max` samples of the dataset in `dir`, evenly spaced over it (so that every movement
/// and camera of a sorted dataset is represented), each sampled to `n` points.
pub fn from_dataset(
    dir: &Path,
    max: usize,
    n: usize,
    rng: &mut SampleRng,
) -> Result<Vec<Vec<[f32; 5]>>> {
    let ds = crate::dataset::Dataset::open(dir)?;
    let take = max.min(ds.len());
    let mut out = Vec::with_capacity(take);
    for i in 0..take {
        let row = i * ds.len() / take;
        let cloud = ds.points_range(row, 1)?;
        out.push(sample_cloud(&cloud[0], n, rng)?);
    }
    Ok(out)
}

/// Samples `n` rows of a point cloud (`n` zero rows for an empty one).
pub fn sample_cloud(points: &[[f32; 5]], n: usize, rng: &mut SampleRng) -> Result<Vec<[f32; 5]>> {
    let mut idx = vec![0u32; points.len().max(n)];
    let picked = sample_indices(points.len(), n, rng, &mut idx)?;
    Ok(if picked.is_empty() {
        vec![[0.0; 5]; n]
    } else {
        picked.iter().map(|&i| points[i as usize]).collect()
    })
}

/// Inputs from a recording of camera 0: its full windows of `s.window_events`, sampled to `n`
/// points, at most `s.max_windows`.
pub fn from_reader(
    reader: &mut dyn EventReader,
    s: &Sampling,
    n: usize,
    rng: &mut SampleRng,
) -> Result<Vec<Vec<[f32; 5]>>> {
    let size = pipeline::sensor_size(reader.info(), 0, s.open.size);
    let raster = pipeline::rasterizer(size, DEFAULT_SLICES, s.window_events)?;
    let mut out = Vec::new();
    let mut sink = Rasterizing::new(raster, |_, w| {
        if out.len() >= s.max_windows || w.summary().events < s.window_events {
            return Ok(()); // a short tail window is not a full input
        }
        let len = sample_len(w.len(), n).max(n);
        let mut idx = vec![0u32; len.max(w.len())];
        let mut rows = vec![[0f32; 5]; len];
        let rows = sample_window(w, n, rng, &mut idx, &mut rows)?;
        out.push(rows.to_vec());
        Ok(())
    });
    pipeline::drive(reader, Windowing::default(), &mut sink)?;
    Ok(out)
}

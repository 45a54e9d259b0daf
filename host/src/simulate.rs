//! `evpose sim`: synthetic DHP19-style recordings on disk, from [`evpose_sim`].
//!
//! One recording per subject and movement, each T seconds, written into a directory:
//!
//! ```text
//! DIR/manifest.json                     what was generated (seed, subjects, split, pixel model,
//!                                       recordings)
//! DIR/calibration/P1..P4.npy, camera_positions.npy   DHP19's calibration (the rig simulated)
//! DIR/S<seed>-<subject>_<movement>.aedat   AEDAT 2.0 in DHP19's layout (camera id in address
//!                                          bits 0-3): the same readers as real DHP19 files
//! DIR/S<seed>-<subject>_<movement>.gt.npy  (T·100, 13, 3) float32: the 13 joints (DHP19
//!                                          order) in mm at 100 Hz, sample k at t = k·10 ms
//!                                          (absent for `no-person`)
//! ```
//!
//! Deterministic for a seed; subjects are drawn from `(seed, index)`, so two seeds never share
//! one. Recordings are simulated in parallel (rayon); memory holds one recording per thread.

use std::path::Path;
use std::sync::Mutex;

use anyhow::{bail, Context, Result};
use evpose_core::geometry::Camera;
use evpose_sim::{simulate_many, Movement, PixelModel, Recording, RecordingSpec};
use serde::{Deserialize, Serialize};

use crate::{array, dhp19};

/// Which side of the subject split a generated set is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// Training subjects.
    Train,
    /// Held-out test subjects.
    Test,
}

/// What to generate.
#[derive(Clone, Debug)]
pub struct SimOptions {
    /// Seed of everything random; selects the subjects.
    pub seed: u64,
    /// Subjects (indices `0..subjects` under the seed).
    pub subjects: u32,
    /// Seconds per recording.
    pub seconds: f64,
    /// Movements, each recorded once per subject.
    pub movements: Vec<Movement>,
    /// The split every recording of this set belongs to.
    pub split: Split,
    /// The simulator's pixel model (`evpose_sim::PixelModel`; V2 unless reproducing V1 data).
    pub pixel: PixelModel,
}

/// One generated recording, as listed in the manifest.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RecordingEntry {
    /// Event file, relative to the directory.
    pub file: String,
    /// Ground truth `.npy`, relative to the directory (`None` without a person).
    pub gt: Option<String>,
    /// Subject id: `seed · 1000 + index + 1` (unique across seeds below 1000 subjects).
    pub subject: u64,
    /// Movement name (`evpose_sim::Movement`, kebab-case).
    pub movement: String,
    /// Seconds.
    pub seconds: f64,
    /// Events per camera channel 0–3.
    pub events: [u64; 4],
    /// Subject height, m.
    pub height_m: f64,
}

/// The manifest of a generated set (`manifest.json`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SimManifest {
    /// `"evpose sim"`.
    pub generator: String,
    /// The seed.
    pub seed: u64,
    /// The split of every recording.
    pub split: Split,
    /// Calibration directory, relative.
    pub calibration: String,
    /// Ground-truth rate, Hz.
    pub gt_hz: f64,
    /// The pixel model's version (`v1`, `v2`); manifests written before V2 existed lack it and
    /// read as `v1`.
    #[serde(default = "pixel_v1")]
    pub pixel_model: String,
    /// The recordings, in generation order.
    pub recordings: Vec<RecordingEntry>,
}

fn pixel_v1() -> String {
    PixelModel::V1.name().into()
}

/// Name of the manifest file in a generated directory.
pub const MANIFEST: &str = "manifest.json";

/// The four DHP19 cameras in aedat channel order, from the bundled calibration.
pub fn dhp19_cameras() -> Result<[Camera; 4]> {
    Ok([
        dhp19::bundled_camera(0)?,
        dhp19::bundled_camera(1)?,
        dhp19::bundled_camera(2)?,
        dhp19::bundled_camera(3)?,
    ])
}

/// Subject id of `index` under `seed`, as the manifest and datasets record it.
pub fn subject_id(seed: u64, index: u32) -> u64 {
    seed * 1000 + u64::from(index) + 1
}

/// Generates the set into `out` (created if needed), calling `progress(done, total)` after
/// each recording.
pub fn generate(
    out: &Path,
    opts: &SimOptions,
    progress: impl Fn(usize, usize) + Sync,
) -> Result<SimManifest> {
    if opts.subjects == 0 || opts.subjects > 999 {
        bail!("--subjects must be in 1..=999");
    }
    if !(opts.seconds > 0.0 && opts.seconds <= 600.0) {
        bail!("--seconds must be in (0, 600]");
    }
    if opts.seed > u64::MAX / 1000 - 1 {
        bail!("--seed too large");
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    dhp19::write_calibration(&out.join("calibration"))?;
    let cameras = dhp19_cameras()?;
    let specs: Vec<RecordingSpec> = (0..opts.subjects)
        .flat_map(|subject| {
            opts.movements.iter().map(move |&movement| RecordingSpec {
                seed: opts.seed,
                subject,
                movement,
                seconds: opts.seconds,
                pixel: opts.pixel,
            })
        })
        .collect();
    let entries: Mutex<Vec<Option<Result<RecordingEntry>>>> =
        Mutex::new((0..specs.len()).map(|_| None).collect());
    let done = std::sync::atomic::AtomicUsize::new(0);
    simulate_many(&specs, &cameras, |i, rec| {
        let entry = write_recording(out, rec);
        entries.lock().expect("no panics while holding the lock")[i] = Some(entry);
        let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress(n, specs.len());
    });
    let recordings = entries
        .into_inner()
        .expect("no panics while holding the lock")
        .into_iter()
        .map(|e| e.unwrap_or_else(|| bail!("a recording was not simulated")))
        .collect::<Result<Vec<_>>>()?;
    let manifest = SimManifest {
        generator: "evpose sim".into(),
        seed: opts.seed,
        split: opts.split,
        calibration: "calibration".into(),
        gt_hz: evpose_sim::recording::GT_HZ,
        pixel_model: opts.pixel.name().into(),
        recordings,
    };
    let path = out.join(MANIFEST);
    std::fs::write(&path, serde_json::to_string_pretty(&manifest)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(manifest)
}

/// Base name of a recording's files.
pub fn recording_name(spec: &RecordingSpec) -> String {
    format!(
        "S{}-{:02}_{}",
        spec.seed,
        spec.subject,
        spec.movement.name()
    )
}

fn write_recording(out: &Path, rec: &Recording) -> Result<RecordingEntry> {
    let name = recording_name(&rec.spec);
    let file = format!("{name}.aedat");
    let path = out.join(&file);
    let f = std::fs::File::create(&path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    evpose_sim::write_dhp19(std::io::BufWriter::new(f), &rec.events)
        .with_context(|| format!("cannot write {}", path.display()))?;
    let gt = if rec.gt_mm.is_empty() {
        None
    } else {
        let gt = format!("{name}.gt.npy");
        let flat: Vec<f32> = rec.gt_mm.iter().flatten().flatten().copied().collect();
        let shape = [rec.gt_mm.len() as u64, evpose_sim::JOINTS as u64, 3];
        array::write(&out.join(&gt), &shape, &flat)?;
        Some(gt)
    };
    let mut events = [0u64; 4];
    for &(c, _) in &rec.events {
        events[usize::from(c & 3)] += 1;
    }
    Ok(RecordingEntry {
        file,
        gt,
        subject: subject_id(rec.spec.seed, rec.spec.subject),
        movement: rec.spec.movement.name().into(),
        seconds: rec.spec.seconds,
        events,
        height_m: rec.subject.height / 1000.0, // the body model's heights are in mm
    })
}

/// Reads a generated set's manifest.
pub fn read_manifest(dir: &Path) -> Result<SimManifest> {
    let path = dir.join(MANIFEST);
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{}: not an evpose sim manifest", path.display()))
}

/// Parses a movement list: `all`, or comma-separated names.
pub fn parse_movements(list: &str) -> Result<Vec<Movement>> {
    if list.trim() == "all" {
        return Ok(Movement::ALL.to_vec());
    }
    let list: Vec<Movement> = list
        .split(',')
        .map(|m| {
            // The error lists the movements; `all` is the one other word.
            m.trim()
                .parse::<Movement>()
                .map_err(|e| anyhow::anyhow!("{e} (or all)"))
        })
        .collect::<Result<_>>()?;
    // Each movement is one file per subject: listed twice, two jobs would write it at once.
    if let Some((_, m)) = list
        .iter()
        .enumerate()
        .find(|(i, m)| list[..*i].contains(m))
    {
        bail!("movement {} is listed twice", m.name());
    }
    Ok(list)
}

/// A generated recording's ground truth: `(T, 13, 3)` mm.
pub fn read_gt(path: &Path) -> Result<Vec<[[f32; 3]; evpose_sim::JOINTS]>> {
    let (shape, v) = array::read_f64(path)?;
    gt_from_array(&shape, &v).with_context(|| path.display().to_string())
}

/// Ground truth from a `(T, 13, 3)` array's shape and values (any numeric dtype).
pub fn gt_from_array(shape: &[u64], v: &[f64]) -> Result<Vec<[[f32; 3]; evpose_sim::JOINTS]>> {
    if shape.len() != 3 || shape[1] != evpose_sim::JOINTS as u64 || shape[2] != 3 {
        bail!("expected a (T, 13, 3) ground-truth array, got {shape:?}");
    }
    Ok(v.chunks_exact(3 * evpose_sim::JOINTS)
        .map(|s| std::array::from_fn(|j| std::array::from_fn(|a| s[3 * j + a] as f32)))
        .collect())
}

#[cfg(test)]
mod movement_tests {
    #[test]
    fn a_movement_listed_twice_is_refused() {
        assert_eq!(super::parse_movements("squats, hop-left").unwrap().len(), 2);
        let err = super::parse_movements("squats,squats").unwrap_err();
        assert_eq!(err.to_string(), "movement squats is listed twice");
    }
}

#[cfg(test)]
mod manifest_tests {
    use super::*;

    #[test]
    fn a_manifest_without_a_pixel_model_reads_as_v1() {
        let m = SimManifest {
            generator: "evpose sim".into(),
            seed: 1,
            split: Split::Train,
            calibration: "calibration".into(),
            gt_hz: 100.0,
            pixel_model: "v2".into(),
            recordings: Vec::new(),
        };
        let mut json: serde_json::Value = serde_json::to_value(&m).unwrap();
        assert_eq!(
            serde_json::from_value::<SimManifest>(json.clone()).unwrap(),
            m
        );
        json.as_object_mut().unwrap().remove("pixel_model");
        let old: SimManifest = serde_json::from_value(json).unwrap();
        assert_eq!(old.pixel_model, "v1");
    }
}

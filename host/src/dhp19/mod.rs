//! DHP19's camera calibration (Calabrese et al., CVPR Workshops 2019): the projection matrix and
//! centre of each of its four DAVIS346 cameras, by aedat camera channel.
//!
//! DHP19's files number the cameras differently from the recordings' channels; its evaluation
//! maps them as channel 0 → `P4.npy`, 1 → `P1.npy`, 2 → `P3.npy`, 3 → `P2.npy`, with the camera
//! centres (mm) in rows 3, 0, 2, 1 of `camera_positions.npy`. The two front cameras, used for
//! 3-D evaluation, are channels 2 and 3. The files are bundled in `assets/dhp19/` (float64).

pub mod mat;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use evpose_core::geometry::Camera;

use crate::array;

/// Image width of a DHP19 camera (DAVIS346), pixels.
pub const WIDTH: u16 = 346;
/// Image height of a DHP19 camera (DAVIS346), pixels.
pub const HEIGHT: u16 = 260;
/// The aedat channels of the two front cameras, the pair DHP19 triangulates.
pub const FRONT_CHANNELS: [u8; 2] = [2, 3];
/// Per aedat channel (the index): the projection matrix file and the row of its centre in
/// `camera_positions.npy`.
pub const CALIBRATION: [(&str, usize); 4] =
    [("P4.npy", 3), ("P1.npy", 0), ("P3.npy", 2), ("P2.npy", 1)];
/// The camera centres' file: a (4, 3) array, mm.
pub const POSITIONS: &str = "camera_positions.npy";

/// The bundled calibration directory in a checkout, `assets/dhp19/`.
pub fn default_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/dhp19")
}

/// The bundled calibration files, embedded in the binary so that an installed `evpose` needs
/// no checkout (the same bytes as in [`default_dir`]).
const BUNDLED: [(&str, &[u8]); 5] = [
    ("P1.npy", include_bytes!("../../../assets/dhp19/P1.npy")),
    ("P2.npy", include_bytes!("../../../assets/dhp19/P2.npy")),
    ("P3.npy", include_bytes!("../../../assets/dhp19/P3.npy")),
    ("P4.npy", include_bytes!("../../../assets/dhp19/P4.npy")),
    (
        POSITIONS,
        include_bytes!("../../../assets/dhp19/camera_positions.npy"),
    ),
];

/// Loads the camera of aedat channel `channel` (0–3) from a directory holding DHP19's
/// `P1..P4.npy` and `camera_positions.npy`.
pub fn camera(dir: &Path, channel: u8) -> Result<Camera> {
    camera_from(channel, |file| {
        let path = dir.join(file);
        let (shape, data) = array::read_f64(&path).with_context(|| {
            format!(
                "calibration directory {}: it needs DHP19's P1.npy .. P4.npy and \
                 camera_positions.npy (the bundled ones are used without --calibration)",
                dir.display()
            )
        })?;
        Ok((path.display().to_string(), shape, data))
    })
}

/// The camera of aedat channel `channel` (0–3) from the calibration embedded in the binary.
pub fn bundled_camera(channel: u8) -> Result<Camera> {
    camera_from(channel, |file| {
        let &(_, bytes) = BUNDLED
            .iter()
            .find(|(name, _)| *name == file)
            .context("not a bundled calibration file")?;
        let (shape, values) = array::stream_f64(bytes)?;
        let data = values.read_all()?;
        Ok((format!("bundled {file}"), shape, data))
    })
}

/// The 13 joints (DHP19's order, mm, f32) of every frame of a DHP19 Vicon file (`.mat`,
/// `XYZPOS`), at 100 Hz from the recording's first event.
pub fn vicon_poses(path: &Path) -> Result<Vec<[[f32; 3]; 13]>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let vicon = mat::read_xyzpos(&bytes).with_context(|| path.display().to_string())?;
    Ok(vicon
        .dhp19_frames()
        .with_context(|| path.display().to_string())?
        .iter()
        .map(|f| f.map(|j| j.map(|v| v as f32)))
        .collect())
}

/// Writes the bundled calibration files into `dir` (created if needed), as DHP19 ships them.
pub fn write_calibration(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for (name, bytes) in BUNDLED {
        let path = dir.join(name);
        std::fs::write(&path, bytes).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

/// One array, read by name: `(where it came from, shape, values)`.
type Array = (String, Vec<u64>, Vec<f64>);

fn camera_from(channel: u8, read: impl Fn(&str) -> Result<Array>) -> Result<Camera> {
    let Some(&(file, row)) = CALIBRATION.get(usize::from(channel)) else {
        bail!("DHP19 has camera channels 0–3, not {channel}");
    };
    let p = matrix::<3, 4>(read(file)?)?;
    let centres = matrix::<4, 3>(read(POSITIONS)?)?;
    Camera::new(p, centres[row], WIDTH, HEIGHT)
        .with_context(|| format!("DHP19 camera channel {channel} ({file}, centre row {row})"))
}

/// An `R × C` array of any numeric dtype, as f64.
fn matrix<const R: usize, const C: usize>((source, shape, data): Array) -> Result<[[f64; C]; R]> {
    if shape != [R as u64, C as u64] {
        bail!("{source}: expected a {R} × {C} array, found shape {shape:?}");
    }
    Ok(std::array::from_fn(|r| {
        std::array::from_fn(|c| data[r * C + c])
    }))
}

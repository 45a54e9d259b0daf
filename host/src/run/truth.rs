//! Ground truth and calibration for a run: 3-D joint positions at 100 Hz (an `evpose sim`
//! `.gt.npy`, or a DHP19 Vicon `.mat`), found beside the recording or named, and the cameras'
//! calibration (a directory of DHP19's files, else DHP19's own for a DHP19-layout recording).

use std::path::{Path, PathBuf};

use anyhow::Result;
use evpose_core::geometry::Camera;

use crate::dataset::{mean_label, JOINTS};
use crate::io::{Format, StreamInfo};

/// 3-D ground truth of a recording.
#[derive(Clone, Debug)]
pub struct Truth {
    /// Poses at 100 Hz, mm, DHP19's joint order.
    pub poses: Vec<[[f32; 3]; JOINTS]>,
    /// Time of sample 0, µs; `None`: the recording's first event (DHP19's Vicon files).
    pub t0_us: Option<i64>,
}

impl Truth {
    /// Reads an `evpose sim` `.gt.npy` (sample 0 at t = 0) or a DHP19 `.mat` (`XYZPOS`,
    /// sample 0 at the first event).
    pub fn load(path: &Path) -> Result<Self> {
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("mat"))
        {
            return Ok(Self {
                poses: crate::dhp19::vicon_poses(path)?,
                t0_us: None,
            });
        }
        Ok(Self {
            poses: crate::simulate::read_gt(path)?,
            t0_us: Some(0),
        })
    }

    /// Ground truth from `.gt.npy` bytes (sample 0 at t = 0).
    pub fn from_npy_bytes(bytes: &'static [u8]) -> Result<Self> {
        let (shape, values) = crate::array::stream_f64(bytes)?;
        let v = values.read_all()?;
        Ok(Self {
            poses: crate::simulate::gt_from_array(&shape, &v)?,
            t0_us: Some(0),
        })
    }

    /// The ground truth beside a recording, if any: `<stem>.gt.npy` (`evpose sim`) or
    /// `<stem>.mat` (DHP19).
    pub fn beside(events: &Path) -> Option<PathBuf> {
        let stem = events.file_stem()?.to_str()?;
        ["gt.npy", "mat"]
            .iter()
            .map(|ext| events.with_file_name(format!("{stem}.{ext}")))
            .find(|p| p.is_file())
    }

    /// The label of a window spanning `t_us`: the mean of the samples inside it (the nearest
    /// one when none is); `None` for a window the ground truth does not cover
    /// ([`crate::dataset::covers`]). `first_event_t` stands for the start of a `.mat`'s clock.
    pub fn label(&self, t_us: (i64, i64), first_event_t: i64) -> Option<[[f32; 3]; JOINTS]> {
        let t0 = self.t0_us.unwrap_or(first_event_t);
        if !crate::dataset::covers(self.poses.len(), t0, t_us) {
            return None;
        }
        mean_label(&self.poses, t0, t_us)
    }
}

/// The calibration of `camera`: from `dir` (DHP19's `P1..P4.npy` and `camera_positions.npy`),
/// else DHP19's own when the recording is in DHP19's layout (four DAVIS346 cameras), else none.
pub fn calibration(dir: Option<&Path>, info: &StreamInfo, camera: u8) -> Result<Option<Camera>> {
    if camera > 3 {
        return Ok(None);
    }
    match dir {
        Some(d) => crate::dhp19::camera(d, camera).map(Some),
        None if info.format == Format::Aedat2Dhp19 => {
            crate::dhp19::bundled_camera(camera).map(Some)
        }
        None => Ok(None),
    }
}

/// The calibration directory beside a recording: `calibration/` in its directory (as
/// `evpose sim` writes it), if present.
pub fn calibration_beside(events: &Path) -> Option<PathBuf> {
    let dir = events.parent()?.join("calibration");
    dir.join(crate::dhp19::POSITIONS).is_file().then_some(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_beyond_the_ground_truth_have_no_label() {
        // One second of ground truth (100 samples from t = 0) against windows over three.
        let truth = Truth {
            poses: vec![[[1.0; 3]; JOINTS]; 100],
            t0_us: Some(0),
        };
        assert!(truth.label((0, 99_999), 0).is_some());
        assert!(truth.label((950_000, 1_000_000), 0).is_some());
        // Half a period past the last sample (990 ms): still its label.
        assert!(truth.label((995_000, 1_000_000), 0).is_some());
        assert!(truth.label((1_000_000, 1_099_999), 0).is_none());
        assert!(truth.label((2_500_000, 2_600_000), 0).is_none());
        assert!(truth.label((-200_000, -100_000), 0).is_none());
        let none = Truth {
            poses: Vec::new(),
            t0_us: Some(0),
        };
        assert!(none.label((0, 10), 0).is_none());
    }
}

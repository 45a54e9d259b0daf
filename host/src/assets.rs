//! What ships inside the `evpose` binary, so that an installed tool needs no checkout: the
//! default model, the sample clip with its ground truth and a sample recording window.
//! (DHP19's calibration is embedded by [`crate::dhp19`].)

use crate::io::{self, EventReader, OpenOptions};
use crate::model::AlignedBlob;

/// The default model of `evpose run` and of the firmware: the trained MCU PointNet
/// (`models/mcu.evq`, int8, 256 points; `train/recipe.sh` makes it from synthetic data).
pub const DEFAULT_MODEL: &[u8] = include_bytes!("../../models/mcu.evq");

/// Where [`DEFAULT_MODEL`] comes from, for messages.
pub const DEFAULT_MODEL_NAME: &str = "the bundled model (models/mcu.evq)";

/// [`DEFAULT_MODEL`], aligned (validated where it is parsed, as any blob).
pub fn default_blob() -> AlignedBlob {
    AlignedBlob::new(DEFAULT_MODEL)
}

/// A real DAVIS346 window (7,500 events of a street scene, `tests/fixtures/street-00.events.npy`):
/// the default input of the benchmarks.
pub const STREET_WINDOW: &[u8] = include_bytes!("../../tests/fixtures/street-00.events.npy");

/// [`STREET_WINDOW`] as an event reader.
pub fn street_window() -> anyhow::Result<Box<dyn EventReader>> {
    io::open_bytes(
        STREET_WINDOW,
        "bundled street-00.events.npy",
        &OpenOptions::default(),
    )
}

/// The sample clip, `evpose run`'s default input: a synthetic DHP19-style recording (four
/// DAVIS346 cameras, AEDAT 2.0, 2 s, 368,884 events) of a held-out subject (`evpose sim --seed
/// 4242 --pixel-model v1`, never in training) kicking sideways (`side-kick`).
pub const CLIP: &[u8] = include_bytes!("../../assets/clip/S4242-00_side-kick.aedat");

/// Where [`CLIP`] comes from, for messages.
pub const CLIP_NAME: &str = "the bundled clip (assets/clip/S4242-00_side-kick.aedat)";

/// The clip's ground truth: 13 joints in mm at 100 Hz from t = 0 (`evpose sim`'s `.gt.npy`).
pub const CLIP_GT: &[u8] = include_bytes!("../../assets/clip/S4242-00_side-kick.gt.npy");

/// Where [`CLIP_GT`] comes from, for messages.
pub const CLIP_GT_NAME: &str = "assets/clip/S4242-00_side-kick.gt.npy";

/// [`CLIP`] as an event reader.
pub fn clip() -> anyhow::Result<Box<dyn EventReader>> {
    io::open_bytes(CLIP, "bundled clip", &OpenOptions::default())
}

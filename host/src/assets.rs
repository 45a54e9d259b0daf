//! What ships inside the `evpose` binary, so that an installed tool needs no checkout: the
//! default model and a sample recording window. (DHP19's calibration is embedded by
//! [`crate::dhp19`].)

use crate::io::{self, EventReader, OpenOptions};
use crate::model::AlignedBlob;

/// The default model of `evpose pose` and of the firmware: the trained MCU PointNet
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

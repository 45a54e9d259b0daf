//! Shared helpers for the cross-crate tests.

use std::path::{Path, PathBuf};

/// The bundled fixtures folder (`tests/fixtures`).
pub fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

/// The shared reference folder beside the repository, if present (optional checks only).
pub fn shared() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared");
    p.is_dir().then_some(p)
}

/// Names of the bundled street windows: `street-00` … `street-09`.
pub fn street_windows() -> Vec<String> {
    (0..10).map(|i| format!("street-{i:02}")).collect()
}

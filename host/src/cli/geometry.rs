//! `evpose triangulate`: 3-D joints (mm) from the 2-D joints of two DHP19 cameras.
//!
//! The 2-D joints come from two JSON-lines outputs of `evpose pose --json`, one per camera
//! (only each line's `joints`, `[[x, y], …]` in pixels, is read), paired window by window in
//! file order; or from two explicit lists. Pixels are taken as DHP19's `(u, v)` (column, row
//! from the top-left), as the reference evaluation takes its decoded joints; each joint pair is
//! triangulated with [`evpose_core::geometry::triangulate`].

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use evpose_core::geometry::{triangulate_joints, Camera, GeometryError};
use serde::{Deserialize, Serialize};

use crate::dhp19;

/// Arguments of `evpose triangulate`.
#[derive(Args, Debug)]
pub struct TriangulateArgs {
    /// Two outputs of `evpose pose --json` (JSON lines), one per camera, in the order of
    /// `--cameras`; windows are paired by their position in the files.
    #[arg(
        num_args = 2,
        value_names = ["POSES_A", "POSES_B"],
        required_unless_present = "joints_a",
        conflicts_with = "joints_a"
    )]
    pub poses: Vec<PathBuf>,
    /// Explicit 2-D joints seen by the first camera, `u,v` pairs separated by spaces or `;`
    /// (pixels), instead of pose files.
    #[arg(long, requires = "joints_b", allow_hyphen_values = true)]
    pub joints_a: Option<String>,
    /// Explicit 2-D joints seen by the second camera, as `--joints-a`.
    #[arg(long, requires = "joints_a", allow_hyphen_values = true)]
    pub joints_b: Option<String>,
    /// DHP19 camera channels (aedat channel ids, 0–3) of the two views, `A,B`; the default,
    /// the front pair, is DHP19's evaluation pair.
    #[arg(long, value_delimiter = ',', default_values_t = dhp19::FRONT_CHANNELS)]
    pub cameras: Vec<u8>,
    /// Directory with DHP19's `P1..P4.npy` and `camera_positions.npy` (default: the
    /// calibration bundled in the binary, `assets/dhp19`).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Print JSON lines instead of text.
    #[arg(long)]
    pub json: bool,
}

/// One window's 3-D pose.
#[derive(Clone, Debug, Serialize)]
pub struct WindowPose3d {
    /// Window index: the position of both input lines.
    pub window: usize,
    /// Joints `[x, y, z]` in mm (DHP19's world frame), in the input's joint order; `null` for a
    /// joint that could not be triangulated (the reason goes to stderr).
    pub joints: Vec<Option<[f64; 3]>>,
}

/// The part of an `evpose pose --json` line this command reads.
#[derive(Deserialize)]
struct PoseLine {
    joints: Vec<(f64, f64)>,
}

/// Runs `evpose triangulate`.
pub fn triangulate(a: &TriangulateArgs) -> Result<()> {
    let [ca, cb] = a.cameras[..] else {
        bail!("--cameras takes two channels, got {:?}", a.cameras);
    };
    let camera = |c| match &a.calibration {
        Some(dir) => dhp19::camera(dir, c),
        None => dhp19::bundled_camera(c),
    };
    let (cam_a, cam_b) = (camera(ca)?, camera(cb)?);
    let (views_a, views_b) = match (&a.joints_a, &a.joints_b, &a.poses[..]) {
        (Some(ja), Some(jb), _) => (
            vec![parse_joints(ja).context("--joints-a")?],
            vec![parse_joints(jb).context("--joints-b")?],
        ),
        (_, _, [pa, pb]) => (read_poses(pa)?, read_poses(pb)?),
        _ => bail!("give two pose files, or --joints-a and --joints-b"),
    };
    if views_a.len() != views_b.len() {
        eprintln!(
            "note: {} and {} windows; triangulating the first {}",
            views_a.len(),
            views_b.len(),
            views_a.len().min(views_b.len())
        );
    }
    for (window, (ja, jb)) in views_a.iter().zip(&views_b).enumerate() {
        let pose = triangulate_window(&cam_a, ja, &cam_b, jb, window)?;
        if a.json {
            println!("{}", serde_json::to_string(&pose)?);
        } else {
            print_text(&pose);
        }
    }
    Ok(())
}

/// Triangulates one window's joints; a joint that fails is `None`, reported on stderr.
pub fn triangulate_window(
    cam_a: &Camera,
    joints_a: &[(f64, f64)],
    cam_b: &Camera,
    joints_b: &[(f64, f64)],
    window: usize,
) -> Result<WindowPose3d> {
    let mut out = vec![Err(GeometryError::NonFinite); joints_a.len()];
    triangulate_joints(cam_a, joints_a, cam_b, joints_b, &mut out)
        .with_context(|| format!("window {window}"))?;
    let joints = out
        .into_iter()
        .enumerate()
        .map(|(j, r)| {
            r.inspect_err(|e| eprintln!("warning: window {window} joint {j}: {e}"))
                .ok()
        })
        .collect();
    Ok(WindowPose3d { window, joints })
}

fn print_text(p: &WindowPose3d) {
    let js: Vec<String> = p
        .joints
        .iter()
        .map(|j| match j {
            Some([x, y, z]) => format!("({x:.1},{y:.1},{z:.1})"),
            None => "-".to_owned(),
        })
        .collect();
    println!("window {:>3}  joints mm {}", p.window, js.join(" "));
}

/// Reads the `joints` of every line of an `evpose pose --json` output (blank lines skipped).
pub fn read_poses(path: &Path) -> Result<Vec<Vec<(f64, f64)>>> {
    let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut windows = Vec::new();
    for (i, line) in BufReader::new(file).lines().enumerate() {
        let line = line.with_context(|| format!("{}: reading line {}", path.display(), i + 1))?;
        if line.trim().is_empty() {
            continue;
        }
        let pose: PoseLine = serde_json::from_str(&line).with_context(|| {
            format!(
                "{} line {}: not an `evpose pose --json` line",
                path.display(),
                i + 1
            )
        })?;
        windows.push(pose.joints);
    }
    Ok(windows)
}

/// Parses `u,v` pairs separated by white space or `;`.
pub fn parse_joints(text: &str) -> Result<Vec<(f64, f64)>> {
    text.split(|c: char| c == ';' || c.is_whitespace())
        .filter(|s| !s.is_empty())
        .map(|pair| {
            let (u, v) = pair
                .split_once(',')
                .with_context(|| format!("`{pair}` is not a `u,v` pair"))?;
            let num = |s: &str| {
                s.trim()
                    .parse::<f64>()
                    .with_context(|| format!("`{s}` in `{pair}` is not a number"))
            };
            Ok((num(u)?, num(v)?))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_joint_lists() {
        assert_eq!(
            parse_joints("1,2 3.5,-4;5e1,6").unwrap(),
            vec![(1.0, 2.0), (3.5, -4.0), (50.0, 6.0)]
        );
        assert!(parse_joints("1,2 3").is_err());
        assert!(parse_joints("1,x").is_err());
        assert_eq!(parse_joints("  ").unwrap(), vec![]);
    }
}

//! `evpose triangulate`: 3-D joints (mm) from the 2-D joints of two DHP19 cameras.
//!
//! The 2-D joints come from two JSON-lines outputs of `evpose pose --json`, one per camera
//! (each line's `joints`, `[[x, y], …]` in pixels, and `t_us`, its first and last timestamp);
//! or from two explicit lists. Each camera's windows are cut from its own events, so window `i`
//! of one camera need not cover the same time as window `i` of the other: each window of the
//! first file is paired with the window of the second whose time span overlaps it most (by
//! position with `--by-position`, or when a window has no `t_us`: an empty window's is null). Pixels are taken as DHP19's `(u, v)` (column, row
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
    /// `--cameras`; each window of the first is paired with the window of the second whose
    /// time span (`t_us`) overlaps it most (by position in the files when `t_us` is absent).
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
    /// Pair windows by their position in the files instead of by time: for pose files made
    /// with `--all-camera-windows`, where window `i` is the same stretch of the recording for
    /// every camera.
    #[arg(long)]
    pub by_position: bool,
    /// Print JSON lines instead of text.
    #[arg(long)]
    pub json: bool,
}

/// One window's 3-D pose.
#[derive(Clone, Debug, Serialize)]
pub struct WindowPose3d {
    /// Window index: the position of the first camera's line.
    pub window: usize,
    /// The second camera's window paired with it (the position of its line).
    pub window_b: usize,
    /// Joints `[x, y, z]` in mm (DHP19's world frame), in the input's joint order; `null` for a
    /// joint that could not be triangulated (the reason goes to stderr).
    pub joints: Vec<Option<[f64; 3]>>,
}

/// The part of an `evpose pose --json` line this command reads.
#[derive(Deserialize)]
struct PoseLine {
    joints: Vec<(f64, f64)>,
    #[serde(default)]
    t_us: Option<(i64, i64)>,
}

/// One camera's window: its 2-D joints and, from a pose file, its first and last timestamp.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    /// Joints `(u, v)`, pixels.
    pub joints: Vec<(f64, f64)>,
    /// First and last event timestamp, µs.
    pub t_us: Option<(i64, i64)>,
}

/// Pairs each window of `a` with a window of `b`: the one whose time span overlaps it most
/// (ties: the first), none when no span overlaps; by position when asked or when either side
/// lacks times.
pub fn pair_windows(a: &[View], b: &[View], by_position: bool) -> Vec<(usize, Option<usize>)> {
    let timed = !by_position && a.iter().chain(b).all(|v| v.t_us.is_some());
    a.iter()
        .enumerate()
        .map(|(i, va)| {
            if !timed {
                return (i, (i < b.len()).then_some(i));
            }
            let (a0, a1) = va.t_us.unwrap_or_default();
            let overlap = |vb: &View| {
                let (b0, b1) = vb.t_us.unwrap_or_default();
                a1.min(b1) - a0.max(b0)
            };
            let best = b
                .iter()
                .enumerate()
                .filter(|(_, vb)| overlap(vb) >= 0)
                .fold(None, |best: Option<(usize, i64)>, (j, vb)| match best {
                    Some((_, o)) if o >= overlap(vb) => best,
                    _ => Some((j, overlap(vb))),
                });
            (i, best.map(|(j, _)| j))
        })
        .collect()
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
    let explicit = |text: &str, what: &str| -> Result<Vec<View>> {
        let joints = parse_joints(text).with_context(|| what.to_owned())?;
        Ok(vec![View { joints, t_us: None }])
    };
    let (views_a, views_b) = match (&a.joints_a, &a.joints_b, &a.poses[..]) {
        (Some(ja), Some(jb), _) => (explicit(ja, "--joints-a")?, explicit(jb, "--joints-b")?),
        (_, _, [pa, pb]) => (read_poses(pa)?, read_poses(pb)?),
        _ => bail!("give two pose files, or --joints-a and --joints-b"),
    };
    for (window, pair) in pair_windows(&views_a, &views_b, a.by_position) {
        let Some(window_b) = pair else {
            eprintln!("note: window {window} of the first camera has no partner; skipped");
            continue;
        };
        let (ja, jb) = (&views_a[window].joints, &views_b[window_b].joints);
        let pose = triangulate_window(&cam_a, ja, &cam_b, jb, (window, window_b))?;
        if a.json {
            println!("{}", serde_json::to_string(&pose)?);
        } else {
            print_text(&pose);
        }
    }
    Ok(())
}

/// Triangulates the joints of window `window` of the first camera and `window_b` of the
/// second; a joint that fails is `None`, reported on stderr.
pub fn triangulate_window(
    cam_a: &Camera,
    joints_a: &[(f64, f64)],
    cam_b: &Camera,
    joints_b: &[(f64, f64)],
    (window, window_b): (usize, usize),
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
    Ok(WindowPose3d {
        window,
        window_b,
        joints,
    })
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
    println!(
        "window {:>3} + {:>3}  joints mm {}",
        p.window,
        p.window_b,
        js.join(" ")
    );
}

/// Reads the `joints` and `t_us` of every line of an `evpose pose --json` output (blank lines
/// skipped).
pub fn read_poses(path: &Path) -> Result<Vec<View>> {
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
        windows.push(View {
            joints: pose.joints,
            t_us: pose.t_us,
        });
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
    fn windows_pair_by_time_overlap() {
        let v = |t: Option<(i64, i64)>| View {
            joints: vec![],
            t_us: t,
        };
        // Camera B's windows are cut at other times: A's 100–199 overlaps B's 130–260 most.
        let a = [v(Some((0, 99))), v(Some((100, 199))), v(Some((500, 600)))];
        let b = [v(Some((0, 40))), v(Some((41, 129))), v(Some((130, 260)))];
        assert_eq!(
            pair_windows(&a, &b, false),
            vec![(0, Some(1)), (1, Some(2)), (2, None)]
        );
        // By position when asked.
        assert_eq!(
            pair_windows(&a, &b, true),
            vec![(0, Some(0)), (1, Some(1)), (2, Some(2))]
        );
        // Touching spans overlap (inclusive timestamps); ties go to the first.
        let b = [v(Some((99, 99))), v(Some((99, 99)))];
        assert_eq!(pair_windows(&a[..1], &b, false), vec![(0, Some(0))]);
        // Without times, by position.
        let a = [v(None), v(None), v(None)];
        assert_eq!(
            pair_windows(&a, &b, false),
            vec![(0, Some(0)), (1, Some(1)), (2, None)]
        );
    }

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

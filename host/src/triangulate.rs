//! `evpose triangulate`: 3-D joints (mm) from the 2-D joints of two DHP19 cameras.
//!
//! The 2-D joints come from two outputs of `evpose run --out F.json|F.jsonl`, one camera each
//! (each window's `cameras[0].joints`, `[[x, y], …]` in pixels, and `t_us`, its time span);
//! or from two explicit lists. Each camera's windows are cut from its own events, so window `i`
//! of one camera need not cover the same time as window `i` of the other: each window of the
//! first file is paired with the window of the second whose time span overlaps it most (by
//! position with `--by-position`, and for explicit `--joints-a`/`--joints-b` lists, which carry
//! no times). Pixels are taken as DHP19's `(u, v)` (column, row
//! from the top-left), as the reference evaluation takes its decoded joints; each joint pair is
//! triangulated with [`evpose_core::geometry::triangulate`].

use std::path::Path;

use anyhow::{bail, Context, Result};
use evpose_core::geometry::{triangulate_joints, Camera, GeometryError};
use serde::Serialize;

use crate::run::RunWindow;

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

/// One camera's window: its 2-D joints and, from a pose file, its first and last timestamp.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    /// Joints `(u, v)`, pixels.
    pub joints: Vec<(f64, f64)>,
    /// First and last event timestamp, µs.
    pub t_us: Option<(i64, i64)>,
    /// The camera the joints are of, when the source says (an `evpose run` output does).
    pub camera: Option<u8>,
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

/// Reads the `joints` and `t_us` of every window of a one-camera `evpose run` output: a JSON
/// array (`.json`) or JSON lines (blank lines skipped).
pub fn read_poses(path: &Path) -> Result<Vec<View>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot open {}", path.display()))?;
    let windows: Vec<(usize, RunWindow)> = if text.trim_start().starts_with('[') {
        serde_json::from_str::<Vec<RunWindow>>(&text)
            .with_context(|| format!("{}: not an `evpose run` JSON output", path.display()))?
            .into_iter()
            .enumerate()
            .collect()
    } else {
        text.lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
            .map(|(i, line)| {
                let w: RunWindow = serde_json::from_str(line).with_context(|| {
                    format!(
                        "{} line {}: not an `evpose run` JSON line",
                        path.display(),
                        i + 1
                    )
                })?;
                Ok((i, w))
            })
            .collect::<Result<_>>()?
    };
    windows
        .into_iter()
        .map(|(i, w)| {
            let [cam] = &w.cameras[..] else {
                bail!(
                    "{} window {}: {} cameras; give one-camera outputs (`evpose run` \
                     triangulates several cameras itself)",
                    path.display(),
                    i,
                    w.cameras.len()
                );
            };
            Ok(View {
                joints: cam
                    .joints
                    .iter()
                    .map(|&[u, v]| (f64::from(u), f64::from(v)))
                    .collect(),
                t_us: Some((w.t_us[0], w.t_us[1])),
                camera: Some(cam.camera),
            })
        })
        .collect()
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
            camera: None,
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

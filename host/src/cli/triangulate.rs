//! `evpose triangulate`: arguments and printing; pairing and triangulation live in
//! [`crate::triangulate`].

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;

use crate::dhp19;
use crate::triangulate::{
    pair_windows, parse_joints, read_poses, triangulate_window, View, WindowPose3d,
};

/// Arguments of `evpose triangulate`.
#[derive(Args, Debug)]
pub struct TriangulateArgs {
    /// Two one-camera outputs of `evpose run --out F.json|F.jsonl`, in the order of
    /// `--cameras`; each window of the first is paired with the window of the second whose
    /// time span (`t_us`) overlaps it most.
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
    /// DHP19 camera channels (aedat channel ids, 0–3) of the two views, `A,B` (default: the
    /// cameras the pose files record, else DHP19's front pair, its evaluation pair). Pose files
    /// of other cameras than these are refused, but for two files of the same camera (the
    /// outputs of two one-camera recordings, both camera 0), which need this option.
    #[arg(long, value_delimiter = ',')]
    pub cameras: Option<Vec<u8>>,
    /// Directory with DHP19's `P1..P4.npy` and `camera_positions.npy` (default: the
    /// calibration bundled in the binary, `assets/dhp19`).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Pair windows by their position in the files instead of by time (for outputs whose
    /// window `i` is the same stretch of time for both cameras).
    #[arg(long)]
    pub by_position: bool,
    /// Print JSON lines instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs `evpose triangulate`.
pub fn triangulate(a: &TriangulateArgs) -> Result<()> {
    let explicit = |text: &str, what: &str| -> Result<Vec<View>> {
        let joints = parse_joints(text).with_context(|| what.to_owned())?;
        Ok(vec![View {
            joints,
            t_us: None,
            camera: None,
        }])
    };
    let (views_a, views_b) = match (&a.joints_a, &a.joints_b, &a.poses[..]) {
        (Some(ja), Some(jb), _) => (explicit(ja, "--joints-a")?, explicit(jb, "--joints-b")?),
        (_, _, [pa, pb]) => (read_poses(pa)?, read_poses(pb)?),
        _ => bail!("give two pose files, or --joints-a and --joints-b"),
    };
    // The cameras the pose files record (each file is one camera's: `read_poses` checks).
    let recorded = |views: &[View]| views.first().and_then(|v| v.camera);
    let files = recorded(&views_a)
        .zip(recorded(&views_b))
        .map(|(x, y)| vec![x, y]);
    // Both files of one camera id are one-camera recordings (whose poses record camera 0):
    // only --cameras can say which DHP19 cameras saw them.
    let same = files.as_ref().is_some_and(|f| f[0] == f[1]);
    let cameras = match (&a.cameras, files) {
        (Some(given), Some(_)) if same => given.clone(),
        (Some(given), Some(files)) if *given != files => bail!(
            "--cameras {} but the pose files are of cameras {} (in the order given)",
            join(given),
            join(&files)
        ),
        (Some(given), _) => given.clone(),
        (None, Some(files)) if same => bail!(
            "both pose files are of camera {} (as the poses of one-camera recordings are): \
             name the DHP19 cameras that recorded them with --cameras A,B (e.g. --cameras 2,3)",
            files[0]
        ),
        (None, Some(files)) => files,
        (None, None) => dhp19::FRONT_CHANNELS.to_vec(),
    };
    let [ca, cb] = cameras[..] else {
        bail!("--cameras takes two channels, got {cameras:?}");
    };
    let camera = |c| match &a.calibration {
        Some(dir) => dhp19::camera(dir, c),
        None => dhp19::bundled_camera(c),
    };
    let (cam_a, cam_b) = (camera(ca)?, camera(cb)?);
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

/// `a,b` for messages.
fn join(ids: &[u8]) -> String {
    ids.iter().map(u8::to_string).collect::<Vec<_>>().join(",")
}

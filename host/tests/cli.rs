//! The `evpose` binary, run as a user runs it.

use std::path::{Path, PathBuf};
use std::process::Command;

fn evpose(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_evpose"))
        .args(args)
        .output()
        .expect("run evpose");
    assert!(
        out.status.success(),
        "evpose {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn evpose_err(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_evpose"))
        .args(args)
        .output()
        .expect("run evpose");
    assert!(!out.status.success(), "evpose {args:?} should fail");
    String::from_utf8(out.stderr).unwrap()
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/fixtures")
        .join(name)
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("evpose-cli-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn info_json_on_an_npy_window() {
    let json = evpose(&["info", s(&fixture("street-00.events.npy")), "--json"]);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["format"], "npy");
    assert_eq!(v["events"], 7500);
    let cam = &v["cameras"][0];
    assert_eq!(
        cam["on"].as_u64().unwrap() + cam["off"].as_u64().unwrap(),
        7500
    );
    assert_eq!(cam["first_t"], 1_589_163_147_368_868i64);
    assert_eq!(cam["last_t"], 1_589_163_147_560_077i64);
    assert_eq!(cam["duration_us"], 191_209);
}

#[test]
fn convert_then_raster_reproduces_the_reference() {
    let converted = tmp("converted.npy");
    evpose(&[
        "convert",
        s(&fixture("street-03.events.npy")),
        "--out",
        s(&converted),
    ]);
    let (shape, a) = evpose_host::npy::read_exact::<f64>(&converted).unwrap();
    let (_, b) = evpose_host::npy::read_f64(&fixture("street-03.events.npy")).unwrap();
    assert_eq!(shape, vec![7500, 4]);
    assert_eq!(a, b);

    let points = tmp("points.npy");
    evpose(&[
        "raster",
        "--events",
        s(&converted),
        "--out",
        s(&points),
        "--width",
        "346",
        "--height",
        "260",
    ]);
    let (_, got) = evpose_host::npy::read_exact::<f32>(&points).unwrap();
    let (_, want) = evpose_host::npy::read_exact::<f32>(&fixture("street-03.points.npy")).unwrap();
    assert_eq!(got, want);
}

#[test]
fn raster_with_windows_writes_numbered_files() {
    let out = tmp("win.npy");
    evpose(&[
        "raster",
        "--events",
        s(&fixture("street-01.events.npy")),
        "--out",
        s(&out),
        "--window-events",
        "3000",
    ]);
    for i in 0..3 {
        let p = out.with_file_name(format!("win-{i:03}.npy"));
        let (shape, _) = evpose_host::npy::read_exact::<f32>(&p).unwrap();
        assert_eq!(shape[1], 5);
        assert!(shape[0] > 0);
    }
    assert!(!out.with_file_name("win-003.npy").exists());
}

#[test]
fn unknown_format_and_missing_file_are_clear_errors() {
    let junk = tmp("junk.bin");
    std::fs::write(&junk, b"hello, not events").unwrap();
    assert!(evpose_err(&["info", s(&junk)]).contains("unknown event file format"));
    assert!(evpose_err(&["info", "/nonexistent/x.npy"]).contains("cannot open"));
    let bad_shape = tmp("bad.npy");
    evpose_host::npy::write(&bad_shape, &[2, 3], &[0f64; 6]).unwrap();
    assert!(evpose_err(&["info", s(&bad_shape)]).contains("(N, 4)"));
}

#[test]
fn pose_runs_the_whole_pipeline_with_the_default_model() {
    let out = evpose(&[
        "pose",
        "--events",
        s(&fixture("street-00.events.npy")),
        "--json",
    ]);
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 1, "one 7,500-event window");
    assert_eq!(lines[0]["points"], 2912);
    let joints = lines[0]["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 13);
    for j in joints {
        assert!(j[0].as_u64().unwrap() < 346 && j[1].as_u64().unwrap() < 260);
    }
    // The same seed gives the same joints; the f32 model gives joints of the same shape.
    assert_eq!(
        evpose(&[
            "pose",
            "--events",
            s(&fixture("street-00.events.npy")),
            "--json"
        ]),
        out
    );
    let f = evpose(&[
        "pose",
        "--events",
        s(&fixture("street-00.events.npy")),
        "--model",
        s(&fixture("pointnet-small.onnx")),
        "--json",
    ]);
    assert_eq!(f.lines().count(), 1);
}

#[test]
fn infer_engines_write_their_outputs() {
    let pts = fixture("street-02.points.npy");
    for (engine, model) in [
        ("tract", fixture("pointnet-small.onnx")),
        ("f32", fixture("pointnet-small.onnx")),
    ] {
        let (x, y) = (
            tmp(&format!("{engine}-x.npy")),
            tmp(&format!("{engine}-y.npy")),
        );
        evpose(&[
            "infer",
            "--model",
            s(&model),
            "--points",
            s(&pts),
            "--engine",
            engine,
            "--out-x",
            s(&x),
            "--out-y",
            s(&y),
            "--repeat",
            "2",
        ]);
        let (shape, vx) = evpose_host::npy::read_exact::<f32>(&x).unwrap();
        assert_eq!(shape, vec![13, 346]);
        let (_, want) =
            evpose_host::npy::read_exact::<f32>(&fixture("street-02.small.simdr_x.npy")).unwrap();
        let max = want.iter().fold(0f32, |m, v| m.max(v.abs()));
        assert!(
            vx.iter()
                .zip(&want)
                .all(|(a, b)| (a - b).abs() <= 1e-4 * max),
            "{engine}"
        );
        assert_eq!(
            evpose_host::npy::read_exact::<f32>(&y).unwrap().0,
            vec![13, 260]
        );
    }
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/pointnet-small.evq");
    let (x, y) = (tmp("i8-x.npy"), tmp("i8-y.npy"));
    evpose(&[
        "infer",
        "--model",
        s(&model),
        "--points",
        s(&pts),
        "--engine",
        "i8",
        "--out-x",
        s(&x),
        "--out-y",
        s(&y),
    ]);
    assert_eq!(
        evpose_host::npy::read_exact::<i32>(&x).unwrap().0,
        vec![13, 346]
    );
    assert!(evpose_err(&[
        "infer",
        "--model",
        s(&model),
        "--points",
        s(&pts),
        "--engine",
        "i8",
        "--out-x",
        s(&x),
        "--out-y",
        s(&y),
        "--threads",
        "2"
    ])
    .contains("--threads 1"));
}

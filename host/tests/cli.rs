//! The `evpose` binary, run as a user runs it.

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "support/encoders.rs"]
mod encoders;

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

#[test]
fn a_reader_that_closes_the_pipe_ends_evpose_quietly() {
    use std::io::{BufRead, BufReader};
    // `evpose run -v | head -1`: the reader takes a line and goes while evpose still prints.
    let mut child = Command::new(env!("CARGO_BIN_EXE_evpose"))
        .args(["run", "-v"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run evpose");
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    assert!(!first.is_empty());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {stderr}", out.status);
    assert!(!stderr.contains("panicked"), "{stderr}");
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/fixtures")
        .join(name)
}

/// A path for a test's output file: in Cargo's scratch directory for integration tests
/// (`target/tmp`), so that each run overwrites the last one's files instead of leaving a new
/// directory in the system's temporary directory.
fn tmp(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("evpose-cli");
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
    let (shape, a) = evpose_host::array::read_exact::<f64>(&converted).unwrap();
    let (_, b) = evpose_host::array::read_f64(&fixture("street-03.events.npy")).unwrap();
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
    let (_, got) = evpose_host::array::read_exact::<f32>(&points).unwrap();
    let (_, want) =
        evpose_host::array::read_exact::<f32>(&fixture("street-03.points.npy")).unwrap();
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
        let (shape, _) = evpose_host::array::read_exact::<f32>(&p).unwrap();
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
    evpose_host::array::write(&bad_shape, &[2, 3], &[0f64; 6]).unwrap();
    assert!(evpose_err(&["info", s(&bad_shape)]).contains("(N, 4)"));
}

// ---------------------------------------------------------------------------------------------
// Event formats (issue 5): info per camera, convert from any format, fallbacks, damage.

fn json(args: &[&str]) -> serde_json::Value {
    serde_json::from_str(&evpose(args)).unwrap()
}

/// Reads every event of a recording with the library: (camera, event).
fn read_all(path: &Path) -> Vec<(u8, evpose_core::Event)> {
    let mut r = evpose_host::io::open(path, None).unwrap();
    let mut b = evpose_host::io::Batch::default();
    let mut out = Vec::new();
    while r.read_batch(&mut b).unwrap() {
        out.extend(b.cameras.iter().copied().zip(b.events.iter().copied()));
    }
    out
}

#[test]
fn info_json_per_camera_for_dhp19() {
    let events = encoders::synthetic(3000, 346, 260, 4, 5_000);
    let path = tmp("dhp19.aedat");
    std::fs::write(&path, encoders::aedat2_davis346(&events, true)).unwrap();
    let v = json(&["info", s(&path), "--json"]);
    assert_eq!(v["format"], "aedat2-dhp19");
    assert_eq!(v["events"], 3000);
    let cams = v["cameras"].as_array().unwrap();
    assert_eq!(cams.len(), 4);
    for (c, cam) in cams.iter().enumerate() {
        let mine: Vec<_> = events.iter().filter(|e| usize::from(e.cam) == c).collect();
        assert_eq!(cam["camera"], c);
        assert_eq!(cam["width"], 346);
        assert_eq!(cam["height"], 260);
        assert_eq!(cam["events"], mine.len());
        assert_eq!(cam["on"], mine.iter().filter(|e| e.on).count());
        assert_eq!(cam["off"], mine.iter().filter(|e| !e.on).count());
        assert_eq!(cam["first_t"], mine[0].t);
        assert_eq!(cam["last_t"], mine[mine.len() - 1].t);
    }
    assert!(v["notes"]["assumptions"][0]
        .as_str()
        .unwrap()
        .contains("MultiDavis346BCameraChip"));
}

#[test]
fn convert_dhp19_to_npy_per_camera_and_to_aedat4() {
    let events = encoders::synthetic(2000, 346, 260, 4, 1_000_000);
    let path = tmp("dhp19-convert.aedat");
    std::fs::write(&path, encoders::aedat2_davis346(&events, true)).unwrap();

    let c2 = tmp("dhp19-cam2.npy");
    evpose(&["convert", s(&path), "--out", s(&c2), "--camera", "2"]);
    let (shape, rows) = evpose_host::array::read_exact::<f64>(&c2).unwrap();
    let want: Vec<f64> = events
        .iter()
        .filter(|e| e.cam == 2)
        .flat_map(|e| {
            [
                f64::from(e.x),
                f64::from(e.y),
                e.t as f64,
                f64::from(u8::from(e.on)),
            ]
        })
        .collect();
    assert_eq!(shape, [want.len() as u64 / 4, 4]);
    assert_eq!(rows, want);

    // EVT 3.0: one camera, its events exactly (times below 2^24 µs are kept).
    let raw = tmp("dhp19-cam2.raw");
    evpose(&["convert", s(&path), "--out", s(&raw), "--camera", "2"]);
    let got = read_all(&raw);
    let want2: Vec<_> = events
        .iter()
        .filter(|e| e.cam == 2)
        .map(|e| (0, evpose_core::Event::new(e.x, e.y, e.t, e.on)))
        .collect();
    assert_eq!(got, want2);
    let v = json(&["info", s(&raw), "--json"]);
    assert_eq!(v["format"], "evt3");
    assert_eq!(v["cameras"][0]["width"], 346);
    // EVT 2.0 and EVT 2.1 in both byte orders (`--encoding`): the same events.
    for enc in ["evt2", "evt21", "evt21-legacy"] {
        let raw = tmp(&format!("dhp19-cam2-{enc}.raw"));
        evpose(&[
            "convert",
            s(&path),
            "--out",
            s(&raw),
            "--camera",
            "2",
            "--encoding",
            enc,
        ]);
        assert_eq!(read_all(&raw), want2, "{enc}");
        assert_eq!(json(&["info", s(&raw), "--json"])["format"], enc);
    }
    // A refused event (outside a stated 100 x 100 sensor) leaves no file behind.
    let street =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/street-00.events.npy");
    let refused = tmp("refused.raw");
    let msg = evpose_err(&[
        "convert",
        s(&street),
        "--width",
        "100",
        "--height",
        "100",
        "--out",
        s(&refused),
        "--encoding",
        "evt21",
    ]);
    assert!(msg.contains("outside") && !refused.exists(), "{msg}");
    let npy_out = tmp("x-enc.npy");
    let msg = evpose_err(&[
        "convert",
        s(&path),
        "--out",
        s(&npy_out),
        "--encoding",
        "evt21",
    ]);
    assert!(msg.contains(".raw"), "{msg}");

    // AEDAT 4: one stream per camera, in camera order, so the ids survive.
    let all = tmp("dhp19-all.aedat4");
    evpose(&["convert", s(&path), "--out", s(&all)]);
    let got = read_all(&all);
    let want: Vec<_> = events
        .iter()
        .map(|e| (e.cam, evpose_core::Event::new(e.x, e.y, e.t, e.on)))
        .collect();
    assert_eq!(got.len(), want.len());
    for cam in 0..4 {
        let a: Vec<_> = got.iter().filter(|(c, _)| *c == cam).collect();
        let b: Vec<_> = want.iter().filter(|(c, _)| *c == cam).collect();
        assert_eq!(a, b, "camera {cam}");
    }
    let v = json(&["info", s(&all), "--json"]);
    assert_eq!(v["format"], "aedat4");
    assert_eq!(v["cameras"].as_array().unwrap().len(), 4);
    assert_eq!(v["cameras"][3]["width"], 346);

    // One camera to AEDAT 4: a single stream.
    let one = tmp("dhp19-cam1.aedat4");
    evpose(&["convert", s(&path), "--out", s(&one), "--camera", "1"]);
    let got = read_all(&one);
    assert!(got.iter().all(|(c, _)| *c == 0));
    assert_eq!(got.len(), events.iter().filter(|e| e.cam == 1).count());

    assert!(evpose_err(&["convert", s(&path), "--out", s(&tmp("x.csv"))]).contains(".aedat4"));
}

#[test]
fn aedat4_round_trip_through_convert() {
    let real = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/aedat4/davis346-street-head.aedat4");
    let out = tmp("street-head-copy.aedat4");
    evpose(&["convert", s(&real), "--out", s(&out)]);
    let a = read_all(&real);
    assert!(!a.is_empty());
    assert_eq!(read_all(&out), a);
    let v = json(&["info", s(&out), "--json"]);
    assert_eq!(v["cameras"][0]["width"], 346);
    assert_eq!(
        v["cameras"][0]["name"],
        json(&["info", s(&real), "--json"])["cameras"][0]["name"]
    );
}

#[test]
fn text_and_raw_need_no_header_size_or_unit_with_flags() {
    // RPG text, seconds detected; converted to npy.
    let events = encoders::synthetic(500, 240, 180, 1, 7_000_000);
    let txt = tmp("events.txt");
    std::fs::write(&txt, encoders::text_seconds(&events)).unwrap();
    let npy = tmp("events-from-text.npy");
    evpose(&["convert", s(&txt), "--out", s(&npy)]);
    let (_, rows) = evpose_host::array::read_exact::<f64>(&npy).unwrap();
    assert_eq!(rows[2], events[0].t as f64);
    assert_eq!(rows[rows.len() - 2], events[499].t as f64);
    // Integer timestamps with --time-unit ms.
    let ms = tmp("ms.csv");
    std::fs::write(&ms, "t,x,y,p\n5,1,2,1\n6,3,4,0\n").unwrap();
    let v = json(&["info", s(&ms), "--json", "--time-unit", "ms"]);
    assert_eq!(v["format"], "text");
    assert_eq!(v["cameras"][0]["first_t"], 5000);
    assert_eq!(v["cameras"][0]["last_t"], 6000);
    // EVT 3.0 without a size: --width/--height fill it in and check the pixels.
    let mut raw = encoders::raw_header(&["evt 3.0", "end"]);
    raw.extend_from_slice(&encoders::evt3_body(&encoders::synthetic(
        300, 640, 480, 1, 0,
    )));
    let raw_path = tmp("nosize.raw");
    std::fs::write(&raw_path, &raw).unwrap();
    let v = json(&["info", s(&raw_path), "--json"]);
    assert_eq!(v["format"], "evt3");
    assert!(v["cameras"][0]["width"].is_null());
    let v = json(&[
        "info",
        s(&raw_path),
        "--json",
        "--width",
        "640",
        "--height",
        "480",
    ]);
    assert_eq!(v["cameras"][0]["width"], 640);
    assert_eq!(v["events"], 300);
    let small = evpose_err(&["info", s(&raw_path), "--width", "10", "--height", "10"]);
    assert!(small.contains("outside the 10x10 sensor"), "{small}");
}

#[test]
fn damaged_files_are_errors_naming_the_offset() {
    let events = encoders::synthetic(100, 346, 260, 4, 0);
    let bytes = encoders::aedat2_davis346(&events, true);
    let cut = tmp("cut.aedat");
    std::fs::write(&cut, &bytes[..bytes.len() - 3]).unwrap();
    let err = evpose_err(&["info", s(&cut)]);
    let last = bytes.len() - 8;
    assert!(
        err.contains(&format!(
            "at byte {last}: file ends inside an AEDAT 2.0 event record"
        )),
        "{err}"
    );
    // The AEDAT 2.0 sensor cannot be guessed: refused with the way out.
    let mut anon = encoders::aedat2_header(None, true);
    encoders::aedat2_record(&mut anon, encoders::davis_addr(1, 2, true, 346, 260), 5);
    let anon_path = tmp("anon.aedat");
    std::fs::write(&anon_path, &anon).unwrap();
    assert!(evpose_err(&["info", s(&anon_path)]).contains("--format aedat2-davis346"));
    let v = json(&[
        "info",
        s(&anon_path),
        "--json",
        "--format",
        "aedat2-davis346",
    ]);
    assert_eq!(v["cameras"][0]["first_t"], 5);
    // Text output lists the recoveries.
    let mut special = encoders::aedat2_header(Some("DAVIS240C"), true);
    encoders::aedat2_record(&mut special, 0x400, 1);
    encoders::aedat2_record(&mut special, encoders::davis_addr(1, 2, true, 240, 180), 2);
    let sp = tmp("special.aedat");
    std::fs::write(&sp, &special).unwrap();
    let text = evpose(&["info", s(&sp)]);
    assert!(text.contains("format:     aedat2-davis240"), "{text}");
    assert!(
        text.contains("note:       1 non-event records skipped"),
        "{text}"
    );
    assert!(
        text.contains("assumed:    sensor from the header"),
        "{text}"
    );
}

#[test]
fn run_estimates_a_recording_with_the_default_model() {
    let street = fixture("street-00.events.npy");
    let out = tmp("street.jsonl");
    let text = evpose(&["run", "--events", s(&street), "--out", s(&out)]);
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(&out)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 1, "one 7,500-event window");
    let cam = &lines[0]["cameras"][0];
    assert_eq!(lines[0]["events"], 7500);
    assert_eq!(cam["points"], 2912);
    let joints = cam["joints"].as_array().unwrap();
    assert_eq!(joints.len(), 13);
    for j in joints {
        assert!(j[0].as_f64().unwrap() < 346.0 && j[1].as_f64().unwrap() < 260.0);
    }
    // One camera, uncalibrated: no 3-D; no ground truth: no error.
    assert!(lines[0].get("joints3d").is_none() && lines[0].get("error").is_none());
    // The bundled model carries its logit scales: 13 confidences in [0, 1]. The window is a
    // street scene without a person; its mean confidence is below the no-body threshold, and
    // the user is told.
    let conf: Vec<f64> = cam["confidence"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_f64().unwrap())
        .collect();
    assert_eq!(conf.len(), 13);
    assert!(conf.iter().all(|c| (0.0..=1.0).contains(c)), "{conf:?}");
    let mean = conf.iter().sum::<f64>() / 13.0;
    assert!(
        mean < f64::from(evpose_host::run::NO_BODY_CONFIDENCE),
        "{mean}"
    );
    assert_eq!(lines[0]["no_body"], true);
    assert!(text.contains("no body seen: 1 of 1 windows"), "{text}");
    // The same seed gives the same joints; without the filter the raw joints are the joints;
    // the f32 model gives joints of the same shape.
    let again = tmp("street-again.jsonl");
    evpose(&["run", "--events", s(&street), "--out", s(&again)]);
    assert_eq!(
        std::fs::read_to_string(&again).unwrap(),
        std::fs::read_to_string(&out).unwrap()
    );
    let lines_off = evpose(&[
        "run",
        "--events",
        s(&street),
        "--smooth",
        "off",
        "--json",
        "-v",
    ]);
    let v: serde_json::Value = serde_json::from_str(lines_off.lines().next().unwrap()).unwrap();
    assert_eq!(v["cameras"][0]["joints"], *cam.get("raw_joints").unwrap());
    assert!(v["cameras"][0].get("raw_joints").is_none());
    let f = evpose(&[
        "run",
        "--events",
        s(&street),
        "--model",
        s(&fixture("pointnet-small.onnx")),
        "--engine",
        "f32",
        "--json",
    ]);
    let summary: serde_json::Value = serde_json::from_str(f.lines().last().unwrap()).unwrap();
    assert_eq!(summary["summary"]["windows"], 1);
    assert_eq!(summary["run"]["engine"], "f32");
    // Bad requests are refused with a reason.
    assert!(evpose_err(&["run", "--events", s(&street), "--cameras", "3"]).contains("no camera 3"));
    assert!(evpose_err(&["run", "--events", s(&street), "--stride", "9000"]).contains("stride"));
    assert!(evpose_err(&["run", "--events", s(&street), "--lag", "65"]).contains("at most 64"));
    assert!(evpose_err(&["run", "--events", s(&street), "--engine", "tract"]).contains(".onnx"));
    assert!(evpose_err(&["run", "--events", s(&street), "--out", "x.txt"]).contains(".jsonl"));
}

#[test]
fn run_on_the_bundled_clip_follows_its_ground_truth() {
    use evpose_host::dhp19;
    // No arguments: the bundled model on the bundled synthetic clip (four DHP19 cameras, 2 s,
    // a held-out subject kicking sideways), cameras 2 and 3, 3-D by triangulation.
    let out = tmp("clip.json");
    let text = evpose(&["run", "--out", s(&out)]);
    assert!(text.contains("synthetic data: not DHP19 figures"), "{text}");
    let windows: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(windows.len(), 12, "368,884 events in 30,000-event windows");
    // The default filter is the fixed-lag mean (lag 3): every window once, in order, and each
    // camera's joints the c²-weighted mean of the network's joints (`raw_joints`) of up to 3
    // windows either side, recomputed here in f64 (the core sums in f32: 1e-3 px).
    for (k, w) in windows.iter().enumerate() {
        assert_eq!(w["window"], k);
        for c in 0..2 {
            for j in 0..13 {
                for a in 0..2 {
                    let (mut sum, mut weights) = (0f64, 0f64);
                    let near = &windows[k.saturating_sub(3)..(k + 4).min(windows.len())];
                    for m in near {
                        let cam = &m["cameras"][c];
                        let conf = cam["confidence"][j].as_f64().unwrap();
                        let weight = f64::from((conf * conf) as f32 + 1e-6);
                        sum += weight * cam["raw_joints"][j][a].as_f64().unwrap();
                        weights += weight;
                    }
                    let got = w["cameras"][c]["joints"][j][a].as_f64().unwrap();
                    assert!(
                        (got - sum / weights).abs() < 1e-3,
                        "window {k} camera {c} joint {j}: {got} vs {}",
                        sum / weights
                    );
                }
            }
        }
    }
    // The clip's ground truth, read here with numpy's format alone: (200, 13, 3) mm at 100 Hz.
    let gt_path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/clip/S4242-00_side-kick.gt.npy");
    let (shape, gt) = evpose_host::array::read_f64(&gt_path).unwrap();
    assert_eq!(shape, vec![200, 13, 3]);
    let pose_at = |k: usize, j: usize| [0, 1, 2].map(|a| gt[(k * 13 + j) * 3 + a]);
    let cams = [2u8, 3].map(|c| dhp19::bundled_camera(c).unwrap());
    // The views' disagreement (the two-view no-body rule's input), recomputed: each camera's
    // joints before the filter against the projection of their 3-D joints. Without the filter
    // the JSON's joints and 3-D joints are those.
    let raw_out = tmp("clip-raw.json");
    evpose(&["run", "--smooth", "off", "--out", s(&raw_out)]);
    // The causal One-Euro filter: the first window passes as it is, later ones are filtered.
    let euro_out = tmp("clip-euro.json");
    evpose(&["run", "--smooth", "one-euro", "--out", s(&euro_out)]);
    let euro: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&euro_out).unwrap()).unwrap();
    assert_eq!(euro.len(), 12);
    assert_eq!(
        euro[0]["cameras"][0]["joints"],
        euro[0]["cameras"][0]["raw_joints"]
    );
    assert!(euro[1..]
        .iter()
        .any(|w| w["cameras"][0]["joints"] != w["cameras"][0]["raw_joints"]));
    let raw: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&raw_out).unwrap()).unwrap();
    for (w, f) in raw.iter().zip(&windows) {
        assert_eq!(w["view_disagreement_px"], f["view_disagreement_px"]);
        let (mut dsum, mut dn) = (0f64, 0u32);
        for (c, cam) in w["cameras"].as_array().unwrap().iter().zip(&cams) {
            for (p, x) in c["joints"]
                .as_array()
                .unwrap()
                .iter()
                .zip(w["joints3d"].as_array().unwrap())
            {
                let Some(x) = x.as_array() else { continue };
                let x = [0, 1, 2].map(|a| x[a].as_f64().unwrap());
                let (u, v) = cam.project(x).unwrap();
                dsum += (u - p[0].as_f64().unwrap()).hypot(v - p[1].as_f64().unwrap());
                dn += 1;
            }
        }
        let d = w["view_disagreement_px"].as_f64().unwrap();
        assert!((d - dsum / f64::from(dn)).abs() < 1e-4, "{d}");
    }
    let (mut sum2, mut n2, mut sum3, mut n3) = (0.0, 0, 0.0, 0);
    for w in &windows {
        let (t0, t1) = (
            w["t_us"][0].as_i64().unwrap(),
            w["t_us"][1].as_i64().unwrap(),
        );
        // The label: the mean of the 100 Hz samples inside the window's span.
        let ks: Vec<usize> = (0..200)
            .filter(|&k| (t0..=t1).contains(&(k as i64 * 10_000)))
            .collect();
        assert!(!ks.is_empty());
        let label = |j: usize| {
            let mut m = [0.0; 3];
            for &k in &ks {
                for (m, p) in m.iter_mut().zip(pose_at(k, j)) {
                    *m += p / ks.len() as f64;
                }
            }
            m
        };
        for (c, cam) in w["cameras"].as_array().unwrap().iter().zip(&cams) {
            for (j, p) in c["joints"].as_array().unwrap().iter().enumerate() {
                let Some((u, v)) = cam.project(label(j)) else {
                    continue;
                };
                if !cam.is_visible((u, v)) {
                    continue;
                }
                let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
                sum2 += ((x - u.trunc()).powi(2) + (y - v.trunc()).powi(2)).sqrt();
                n2 += 1;
            }
        }
        for (j, p) in w["joints3d"].as_array().unwrap().iter().enumerate() {
            let Some(p) = p.as_array() else { continue };
            let l = label(j);
            sum3 += (0..3)
                .map(|a| (p[a].as_f64().unwrap() - l[a]).powi(2))
                .sum::<f64>()
                .sqrt();
            n3 += 1;
        }
    }
    let (mpjpe2d, mpjpe3d) = (sum2 / f64::from(n2), sum3 / f64::from(n3));
    // Measured: 9.42 px and 85.3 mm (the mean-pose baseline on the held-out set: 22.9 px,
    // 273 mm). The bounds leave room for rounding across machines, not for a broken pipeline.
    assert!(n2 > 250 && n3 > 120, "{n2} {n3}");
    assert!(mpjpe2d < 12.0, "MPJPE2D {mpjpe2d:.2} px");
    assert!(mpjpe3d < 110.0, "MPJPE3D {mpjpe3d:.1} mm");
    // The run's own figures agree with this independent computation.
    let v = json(&["run", "--json"]);
    let e = &v["summary"]["errors"];
    assert!(
        (e["mpjpe2d_px"].as_f64().unwrap() - mpjpe2d).abs() < 1e-6,
        "{e}"
    );
    // (The run's 3-D label is stored as f32: 1e-3 mm.)
    assert!(
        (e["mpjpe3d_mm"].as_f64().unwrap() - mpjpe3d).abs() < 1e-3,
        "{e}"
    );
    assert_eq!(
        v["summary"]["no_body_windows"], 0,
        "a person in every window"
    );
    // Sliding windows: a window every 15,000 events gives 23.
    let v = json(&["run", "--stride", "15000", "--json"]);
    assert_eq!(v["summary"]["windows"], 23);
    // The render: one GIF frame per window.
    let gif = tmp("clip.gif");
    evpose(&["run", "--render", s(&gif)]);
    let bytes = std::fs::read(&gif).unwrap();
    assert!(bytes.starts_with(b"GIF89a"));
    let frames = image::codecs::gif::GifDecoder::new(std::io::Cursor::new(bytes)).unwrap();
    use image::AnimationDecoder;
    assert_eq!(frames.into_frames().count(), 12);
}

#[test]
fn budget_estimates_latency_per_target() {
    // An f32 model gets no estimate: the Cortex-M counts are the int8 engine's.
    let paper = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/paper.onnx");
    let v = json(&["budget", "--model", s(&paper), "--json"]);
    assert_eq!(v["latency"], serde_json::json!([]));
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/mcu.evq");
    let v = json(&[
        "budget",
        "--model",
        s(&model),
        "--target",
        "cortex-m7@480",
        "cortex-m4@168",
        "--json",
    ]);
    // The blob records its point count; the latency uses it.
    assert_eq!(v["model"]["points"], 256);
    let l = v["latency"].as_array().unwrap();
    assert_eq!(l.len(), 2);
    assert_eq!(l[0]["target"], "cortex-m7@480");
    let (m7, m4) = (l[0]["ms"].as_f64().unwrap(), l[1]["ms"].as_f64().unwrap());
    assert!(m4 > m7 * 480.0 / 168.0, "{m7} {m4}");
    // The M4 rasterizes with the M4 build's cost (f64 in software, integer fractions).
    let raster = |t: &serde_json::Value| t["rasterize"].as_f64().unwrap();
    assert!(
        raster(&l[1]) > raster(&l[0]),
        "{} {}",
        raster(&l[0]),
        raster(&l[1])
    );
    for t in l {
        let ms = t["ms"].as_f64().unwrap();
        assert_eq!(t["real_time"], ms <= 36.0);
        assert!(t["instructions"].as_f64().unwrap() > t["infer"].as_f64().unwrap());
        assert_eq!(t["weights"], "widened");
    }
    // The widened weights' RAM is reported; the row-major plan needs none and runs slower.
    assert_eq!(v["model"]["widened_bytes"], 38_400);
    let r = json(&[
        "budget",
        "--model",
        s(&model),
        "--weights",
        "row-major",
        "--json",
    ]);
    let rm = &r["latency"][0];
    assert_eq!(rm["weights"], "row-major");
    assert!(rm["infer"].as_f64().unwrap() > l[0]["infer"].as_f64().unwrap());
    assert_eq!(rm["rasterize"], l[0]["rasterize"]);
    // A Prophesee sensor's EVT 2.1 words cost more to read than the firmware's EVS1 words (the
    // QEMU counts of the boot check), and only the input stage changes.
    let e = json(&["budget", "--model", s(&model), "--input", "evt21", "--json"]);
    let e = &e["latency"][0];
    assert_eq!(e["input_stream"], "evt21");
    assert!(e["input"].as_f64().unwrap() > l[0]["input"].as_f64().unwrap());
    assert_eq!(e["rasterize"], l[0]["rasterize"]);
    assert_eq!(l[0]["input_stream"], "evs1");
    assert!(evpose_err(&[
        "budget",
        "--model",
        s(&model),
        "--target",
        "cortex-a53@1000"
    ])
    .contains("unknown core"));
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
        let (shape, vx) = evpose_host::array::read_exact::<f32>(&x).unwrap();
        assert_eq!(shape, vec![13, 346]);
        let (_, want) =
            evpose_host::array::read_exact::<f32>(&fixture("street-02.small.simdr_x.npy")).unwrap();
        let max = want.iter().fold(0f32, |m, v| m.max(v.abs()));
        assert!(
            vx.iter()
                .zip(&want)
                .all(|(a, b)| (a - b).abs() <= 1e-4 * max),
            "{engine}"
        );
        assert_eq!(
            evpose_host::array::read_exact::<f32>(&y).unwrap().0,
            vec![13, 260]
        );
    }
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/mcu.evq");
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
        evpose_host::array::read_exact::<i32>(&x).unwrap().0,
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

#[test]
fn triangulate_pairs_pose_windows_from_two_cameras() {
    use evpose_core::geometry::triangulate;
    use evpose_host::dhp19;
    let dir = dhp19::default_dir();
    let (a, b) = (
        dhp19::camera(&dir, 2).unwrap(),
        dhp19::camera(&dir, 3).unwrap(),
    );
    // Two windows of 13 joints near the capture volume's origin, as a one-camera
    // `evpose run --out F.jsonl` writes them (whole pixels here). Camera 3's windows are cut at other times: it has one more, earlier
    // window, so its window w + 1 is the one that covers camera 2's window w.
    let truth = |w: usize, j: usize| [40.0 * j as f64 - 240.0, 100.0 * w as f64, 120.0 * j as f64];
    let pixels = |cam: &evpose_core::geometry::Camera, w: usize| -> Vec<(u16, u16)> {
        (0..13)
            .map(|j| {
                let (u, v) = cam.project(truth(w, j)).unwrap();
                (u.round() as u16, v.round() as u16)
            })
            .collect()
    };
    let write = |name: &str, cam: &evpose_core::geometry::Camera, id: u8, first: i64| {
        let path = tmp(name);
        let lines: Vec<String> = (first..2)
            .enumerate()
            .map(|(i, w)| {
                serde_json::json!({
                    "window": i, "t_us": [w * 100 + 10, w * 100 + 90], "events": 30000,
                    "no_body": false,
                    "cameras": [{"camera": id, "events": 7000, "points": 256,
                        "joints": pixels(cam, w.max(0) as usize), "confidence": []}],
                })
                .to_string()
            })
            .collect();
        std::fs::write(&path, lines.join("\n") + "\n").unwrap();
        path
    };
    let (pa, pb) = (
        write("cam2.jsonl", &a, 2, 0),
        write("cam3.jsonl", &b, 3, -1),
    );
    let out = evpose(&["triangulate", s(&pa), s(&pb), "--json"]);
    // The files say which camera each is: given the other way round they triangulate the
    // same (the calibration follows the files), and a --cameras that contradicts them is
    // refused.
    let swapped = evpose(&["triangulate", s(&pb), s(&pa), "--json"]);
    let first: serde_json::Value = serde_json::from_str(swapped.lines().next().unwrap()).unwrap();
    let want = triangulate(
        &b,
        {
            let p = pixels(&b, 0);
            (f64::from(p[5].0), f64::from(p[5].1))
        },
        &a,
        {
            let p = pixels(&a, 0);
            (f64::from(p[5].0), f64::from(p[5].1))
        },
    )
    .unwrap();
    let got: [f64; 3] = serde_json::from_value(first["joints"][5].clone()).unwrap();
    assert!(
        (0..3).all(|i| (got[i] - want[i]).abs() < 1e-6),
        "{got:?} vs {want:?}"
    );
    let err = evpose_err(&["triangulate", s(&pb), s(&pa), "--cameras", "2,3"]);
    assert!(err.contains("the pose files are of cameras 3,2"), "{err}");
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2, "{out}");
    for (w, line) in lines.iter().enumerate() {
        assert_eq!(line["window"], w);
        assert_eq!(line["window_b"], w + 1, "paired by time, not by position");
        let joints = line["joints"].as_array().unwrap();
        assert_eq!(joints.len(), 13);
        let (ja, jb) = (pixels(&a, w), pixels(&b, w));
        for (j, got) in joints.iter().enumerate() {
            let got: [f64; 3] = serde_json::from_value(got.clone()).unwrap();
            let px = |p: (u16, u16)| (f64::from(p.0), f64::from(p.1));
            // The library's result (to 1e-9 mm: serde_json's default float parsing may be off
            // by an ulp) …
            let want = triangulate(&a, px(ja[j]), &b, px(jb[j])).unwrap();
            assert!(
                (0..3).all(|i| (got[i] - want[i]).abs() < 1e-9),
                "window {w} joint {j}: {got:?} vs {want:?}"
            );
            // … and within whole-pixel rounding of the true point (≤ 0.5 px ≈ a few mm).
            let t = truth(w, j);
            assert!(
                (0..3).all(|i| (got[i] - t[i]).abs() < 30.0),
                "{got:?} vs {t:?}"
            );
        }
    }
    // Two one-camera recordings' poses both say camera 0: refused without --cameras (with
    // the hint), and with it the same joints as the files that name their cameras.
    let (pa0, pb0) = (
        write("cam2-only.jsonl", &a, 0, 0),
        write("cam3-only.jsonl", &b, 0, -1),
    );
    let err = evpose_err(&["triangulate", s(&pa0), s(&pb0)]);
    assert!(
        err.contains("both pose files are of camera 0") && err.contains("--cameras A,B"),
        "{err}"
    );
    let named = evpose(&[
        "triangulate",
        s(&pa0),
        s(&pb0),
        "--cameras",
        "2,3",
        "--json",
    ]);
    assert_eq!(named, out);
    // Text output: one line per window; the default cameras are the front pair, 2 and 3.
    let text = evpose(&["triangulate", s(&pa), s(&pb), "--cameras", "2,3"]);
    assert_eq!(text.lines().count(), 2, "{text}");
    assert!(text.starts_with("window   0 +   1  joints mm ("), "{text}");

    // Explicit joints; one camera twice gives parallel rays: `null`, with the reason on stderr.
    let (ja, jb) = (pixels(&a, 0), pixels(&b, 0));
    let list = |js: &[(u16, u16)]| {
        js.iter()
            .map(|(u, v)| format!("{u},{v}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let one = evpose(&[
        "triangulate",
        "--joints-a",
        &list(&ja[..2]),
        "--joints-b",
        &list(&jb[..2]),
        "--json",
    ]);
    let one: serde_json::Value = serde_json::from_str(&one).unwrap();
    assert_eq!(one["window"], 0);
    assert_eq!(
        one["joints"].as_array().unwrap()[..],
        lines[0]["joints"].as_array().unwrap()[..2]
    );
    let same = Command::new(env!("CARGO_BIN_EXE_evpose"))
        .args(["triangulate", "--cameras", "2,2", "--json"])
        .args(["--joints-a", "100,100", "--joints-b", "100,100"])
        .output()
        .unwrap();
    assert!(same.status.success());
    assert_eq!(
        String::from_utf8_lossy(&same.stdout),
        "{\"window\":0,\"window_b\":0,\"joints\":[null]}\n"
    );
    assert!(String::from_utf8_lossy(&same.stderr).contains("parallel"));

    // Bad input: a line that is not a pose, a channel DHP19 does not have.
    let bad = tmp("bad.jsonl");
    let good = std::fs::read_to_string(&pa).unwrap();
    let first = good.lines().next().unwrap();
    std::fs::write(&bad, format!("{first}\n{{\"window\": 1}}\n")).unwrap();
    assert!(evpose_err(&["triangulate", s(&bad), s(&pb)]).contains("line 2"));
    let joints = ["--joints-a", "100,100", "--joints-b", "120,90"];
    let err = evpose_err(&[&["triangulate", "--cameras", "2,7"][..], &joints[..]].concat());
    assert!(err.contains("0–3"), "{err}");
}

#[test]
fn run_cuts_windows_over_all_cameras() {
    // 4,000 events of a DHP19 recording, the first 1,000 all from camera 0: with windows of
    // 1,000 events over all cameras, every camera gets 4 windows, camera 1's first one empty
    // (an all-zero input: still a pose, so that the windows stay aligned).
    let mut events = encoders::synthetic(4_000, 346, 260, 4, 1_000);
    for e in &mut events[..1_000] {
        e.cam = 0;
    }
    let path = tmp("dhp19-windows.aedat");
    std::fs::write(&path, encoders::aedat2_davis346(&events, true)).unwrap();
    let out = tmp("dhp19-windows.jsonl");
    let args = ["run", "--events", s(&path), "--cameras", "0,1,2,3"];
    evpose(&[&args[..], &["--window-events", "1000", "--out", s(&out)]].concat());
    let windows: Vec<serde_json::Value> = std::fs::read_to_string(&out)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(windows.len(), 4);
    for (w, win) in windows.iter().enumerate() {
        assert_eq!(win["events"], 1000);
        let cams = win["cameras"].as_array().unwrap();
        assert_eq!(cams.len(), 4);
        for (c, cam) in cams.iter().enumerate() {
            assert_eq!(cam["camera"], c);
            assert_eq!(
                cam["events"] == 0,
                w == 0 && c != 0,
                "window {w} camera {c}"
            );
        }
        // DHP19's four calibrated cameras: 3-D joints from all of them.
        assert_eq!(win["joints3d"].as_array().unwrap().len(), 13);
    }
    // Windows by time: 4,000 events over ~6 ms in 1 ms windows.
    let v = json(&[&args[..], &["--window-ms", "1", "--json"]].concat());
    assert!(v["summary"]["windows"].as_u64().unwrap() >= 4, "{v}");
}

#[test]
fn bench_pipeline_times_the_whole_run() {
    let v = json(&[
        "bench",
        "pipeline",
        "--passes",
        "2",
        "--threads",
        "2",
        "--json",
    ]);
    // The bundled clip: 368,884 events in 12 windows of cameras 2 and 3.
    assert_eq!(v["events"], 368_884);
    assert_eq!(v["windows"], 12);
    assert_eq!(v["cameras"], 2);
    assert_eq!(v["threads"], 2);
    for key in [
        "events_per_second",
        "windows_per_second",
        "parallel_events_per_second",
    ] {
        assert!(v[key].as_f64().unwrap() > 0.0, "{key}: {v}");
    }
    let per_window = v["ms_per_window"].as_f64().unwrap();
    let per_pass = v["seconds_per_pass"].as_f64().unwrap();
    assert!((per_window * 12.0 - per_pass * 1e3).abs() < 1e-6 * per_pass * 1e3);
    // Two passes: the median is their mean, the fastest the faster one.
    let fastest = v["fastest_seconds_per_pass"].as_f64().unwrap();
    assert!(fastest > 0.0 && fastest < per_pass, "{v}");
    let fastest_window = v["fastest_ms_per_window"].as_f64().unwrap();
    assert!((fastest_window * 12.0 - fastest * 1e3).abs() < 1e-6 * fastest * 1e3);
    let fastest_rate = v["fastest_events_per_second"].as_f64().unwrap();
    assert!((fastest_rate * fastest - 368_884.0).abs() < 1e-6 * 368_884.0);
}

/// A text recording: 300 events, a second without any, 300 more (`t x y p`, µs).
fn recording_with_a_gap() -> PathBuf {
    let path = tmp("gap.txt");
    let lines: String = (0..600u32)
        .map(|i| {
            let t = u64::from(i % 300) + if i >= 300 { 1_000_000 } else { 0 };
            format!("{t} {} {} 1\n", (i * 37) % 346, (i * 53) % 260)
        })
        .collect();
    std::fs::write(&path, lines).unwrap();
    path
}

#[test]
fn run_keeping_every_point_estimates_empty_windows_too() {
    // `--points 0` (every point of the window): a window without events gets the same guess
    // as with sampled points (one all-zero point pools as `N` do), not an inference error.
    let events = recording_with_a_gap();
    let mut outs = Vec::new();
    for points in ["0", "256"] {
        let out = tmp(&format!("gap-{points}.json"));
        evpose(&[
            "run",
            "--events",
            s(&events),
            "--window-ms",
            "100",
            "--points",
            points,
            "--smooth",
            "off",
            "--out",
            s(&out),
        ]);
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        let windows = v.as_array().unwrap().clone();
        assert_eq!(windows.len(), 10, "{points}");
        assert_eq!(windows[0]["cameras"][0]["events"], 300);
        assert_eq!(windows[5]["cameras"][0]["events"], 0);
        outs.push(windows);
    }
    assert_eq!(
        outs[0][5]["cameras"][0]["joints"],
        outs[1][5]["cameras"][0]["joints"]
    );
}

#[test]
fn run_errors_leave_well_formed_outputs() {
    // A recording damaged at its end: the run stops with the reader's error, and the JSON
    // output still parses, with the windows done before it.
    // (Long enough that the reader hands out batches before it meets the damage.)
    let events = encoders::synthetic(400_000, 346, 260, 4, 0);
    let bytes = encoders::aedat2_davis346(&events, true);
    let cut = tmp("cut-run.aedat");
    std::fs::write(&cut, &bytes[..bytes.len() - 3]).unwrap();
    let out = tmp("cut-run.json");
    let err = evpose_err(&["run", "--events", s(&cut), "--out", s(&out)]);
    assert!(err.contains("keep the windows before the error"), "{err}");
    assert!(
        err.contains("file ends inside an AEDAT 2.0 event record"),
        "{err}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert!(
        !v.as_array().unwrap().is_empty(),
        "no window before the error"
    );
    // Frames for a directory that does not exist: refused before any output file is made.
    let out = tmp("never-written.json");
    let _ = std::fs::remove_file(&out);
    let frames = tmp("no-such-dir").join("frame.png");
    let err = evpose_err(&[
        "run",
        "--events",
        s(&fixture("street-00.events.npy")),
        "--render",
        s(&frames),
        "--out",
        s(&out),
    ]);
    assert!(err.contains("no directory"), "{err}");
    assert!(!out.exists());
}

#[test]
fn run_keeps_the_sensor_size_the_file_states() {
    // The bundled clip's AEDAT 2.0 header states DHP19's 346 × 260: --width/--height, which
    // describe files that state no size, change nothing.
    let clip =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/clip/S4242-00_side-kick.aedat");
    let (plain, flagged) = (tmp("size-plain.json"), tmp("size-flagged.json"));
    evpose(&["run", "--events", s(&clip), "--out", s(&plain)]);
    evpose(&[
        "run",
        "--events",
        s(&clip),
        "--width",
        "640",
        "--height",
        "480",
        "--out",
        s(&flagged),
    ]);
    assert_eq!(
        std::fs::read(&plain).unwrap(),
        std::fs::read(&flagged).unwrap()
    );
}

#[test]
fn run_refuses_bad_or_ignored_arguments() {
    let clip =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/clip/S4242-00_side-kick.aedat");
    let err = evpose_err(&["run", "--events", s(&clip), "--cameras", "2,2"]);
    assert!(
        err.contains("camera 2 is listed twice in --cameras"),
        "{err}"
    );
    // 2^32 + 1 would have been truncated to windows of one event.
    let err = evpose_err(&["run", "--max-window-events", "4294967297"]);
    assert!(err.contains("4294967297 is not in 1..=4294967295"), "{err}");
    // Options that would be ignored are refused.
    let err = evpose_err(&["run", "--smooth", "off", "--lag", "2"]);
    assert!(err.contains("--smooth off has none"), "{err}");
    let err = evpose_err(&["run", "--render-scale", "2"]);
    assert!(err.contains("--render"), "{err}");
    // eval's filter options without --smooth, an engine for the baseline, render's cameras.
    let err = evpose_err(&["eval", "--data", "x", "--model", "m.evq", "--lag", "2"]);
    assert!(err.contains("--smooth"), "{err}");
    let err = evpose_err(&[
        "eval",
        "--data",
        "x",
        "--baseline",
        "t",
        "--engine",
        "tract",
    ]);
    assert!(err.contains("cannot be used with"), "{err}");
    let err = evpose_err(&[
        "render",
        "--recording",
        "r.aedat",
        "--camera",
        "7",
        "--out",
        "o.png",
    ]);
    assert!(err.contains("7 is not in 0..=3"), "{err}");
    // Benchmarks of zero passes would divide by nothing.
    let err = evpose_err(&["bench", "raster", "--iterations", "0"]);
    assert!(err.contains("0 is not in 1.."), "{err}");
    // Windows in ms are reported with their unit.
    let err = evpose_err(&["run", "--window-ms", "1", "--stride", "2"]);
    assert!(err.contains("window 1000 µs and stride 2000 µs"), "{err}");
}

#[test]
fn run_on_an_empty_recording_writes_no_empty_gif() {
    let empty = tmp("empty.txt");
    std::fs::write(&empty, "").unwrap();
    let gif = tmp("empty.gif");
    let _ = std::fs::remove_file(&gif);
    let out = Command::new(env!("CARGO_BIN_EXE_evpose"))
        .args([
            "run",
            "--events",
            s(&empty),
            "--format",
            "text",
            "--render",
            s(&gif),
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("no windows:") && err.contains("not written"),
        "{err}"
    );
    assert!(!gif.exists());
}

#[test]
fn quantize_records_the_point_count_it_was_asked_for() {
    // With --points 0 (every point of each calibration window) the blob records 0, "any";
    // it recorded the first window's point count, which `run` then resampled every window to.
    for (points, want) in [(Some("0"), 0), (Some("1024"), 1024), (None, 2048)] {
        let out = tmp(&format!("q-{}.evq", points.unwrap_or("default")));
        let model = fixture("pointnet-small.onnx");
        let calib = fixture("street-00.events.npy");
        let mut args = vec![
            "quantize",
            "--model",
            s(&model),
            "--calib",
            s(&calib),
            "--out",
            s(&out),
        ];
        if let Some(p) = points {
            args.extend(["--points", p]);
        }
        evpose(&args);
        let blob = evpose_host::model::AlignedBlob::new(&std::fs::read(&out).unwrap());
        let m = evpose_core::Model::parse(blob.bytes()).unwrap();
        assert_eq!(m.preprocessing().points, want, "{points:?}");
    }
}

#[test]
fn run_leaves_a_camera_without_events_out_of_3d_and_the_no_body_test() {
    // The bundled clip without camera 3's events: camera 2 alone sees the subject, so no
    // window has 3-D joints (one view) and none is judged empty of a body because of camera
    // 3's guesses; the summary says so.
    let clip = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/clip");
    let events: Vec<encoders::Ev> = read_all(&clip.join("S4242-00_side-kick.aedat"))
        .into_iter()
        .filter(|&(c, _)| c != 3)
        .map(|(c, e)| encoders::ev(c, e.x, e.y, e.t, e.on))
        .collect();
    let dir = tmp("dead-camera");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("S4242-00_side-kick.aedat");
    std::fs::write(&path, encoders::aedat2_davis346(&events, true)).unwrap();
    std::fs::copy(
        clip.join("S4242-00_side-kick.gt.npy"),
        dir.join("S4242-00_side-kick.gt.npy"),
    )
    .unwrap();
    let out = dir.join("dead.json");
    let text = evpose(&["run", "--events", s(&path), "--out", s(&out)]);
    let windows: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert!(
        text.contains(&format!(
            "{} camera windows without events: left out of triangulation",
            windows.len()
        )),
        "{text}"
    );
    for w in &windows {
        assert_eq!(w["cameras"][1]["events"], 0);
        assert!(
            w["joints3d"]
                .as_array()
                .unwrap()
                .iter()
                .all(|j| j.is_null()),
            "{w}"
        );
        assert_eq!(w["no_body"], false, "{}", w["window"]);
    }
}

#[test]
fn convert_raster_and_info_on_odd_input() {
    // convert never writes over the recording it reads.
    let src = tmp("self.npy");
    std::fs::copy(fixture("street-00.events.npy"), &src).unwrap();
    let before = std::fs::read(&src).unwrap();
    let err = evpose_err(&["convert", s(&src), "--out", s(&src)]);
    assert!(
        err.contains("would overwrite the recording it reads"),
        "{err}"
    );
    assert_eq!(std::fs::read(&src).unwrap(), before);
    // Nanoseconds read as µs do not fit f64 exactly: an error, not rounded times.
    let ns = tmp("ns.txt");
    std::fs::write(
        &ns,
        "1700000000123456789 1 2 1\n1700000000123457789 3 4 0\n",
    )
    .unwrap();
    let err = evpose_err(&["convert", s(&ns), "--out", s(&tmp("ns.npy"))]);
    assert!(err.contains("beyond 2^53"), "{err}");
    // info's span is never negative, whatever the file order.
    let back = tmp("back.txt");
    std::fs::write(&back, "100 1 1 1\n500 2 2 1\n50 3 3 1\n").unwrap();
    let v = json(&["info", s(&back), "--json"]);
    assert_eq!(v["cameras"][0]["duration_us"], 450);
    // A time jump splits raster's single window: one numbered file per window, none lost.
    let jump = tmp("jump.txt");
    std::fs::write(
        &jump,
        "0 1 1 1\n10 2 2 1\n3000000000 3 3 1\n3000000010 4 4 1\n3000000020 5 5 1\n",
    )
    .unwrap();
    let out = tmp("jump.npy");
    evpose(&["raster", "--events", s(&jump), "--out", s(&out)]);
    let (a, _) = evpose_host::array::read_f64(&tmp("jump-000.npy")).unwrap();
    let (b, _) = evpose_host::array::read_f64(&tmp("jump-001.npy")).unwrap();
    assert_eq!((a[0], b[0]), (2, 3));
    // convert to AEDAT 4 of a camera the recording lacks: said so (not "no sensor size").
    let dhp = tmp("four.aedat");
    let events = encoders::synthetic(400, 346, 260, 4, 0);
    std::fs::write(&dhp, encoders::aedat2_davis346(&events, true)).unwrap();
    let conv = Command::new(env!("CARGO_BIN_EXE_evpose"))
        .args([
            "convert",
            s(&dhp),
            "--out",
            s(&tmp("five.aedat4")),
            "--camera",
            "5",
        ])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&conv.stderr);
    assert!(
        said.contains("camera 5 has no events (cameras with events: 0, 1, 2, 3)"),
        "{said}"
    );
    assert!(!said.contains("states no sensor size"), "{said}");
    // A camera the recording does not have: said, with the cameras it has.
    let none = Command::new(env!("CARGO_BIN_EXE_evpose"))
        .args([
            "raster",
            "--events",
            s(&jump),
            "--out",
            s(&tmp("none.npy")),
            "--camera",
            "5",
        ])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&none.stderr);
    assert!(
        said.contains("camera 5 has no events (cameras with events: 0)"),
        "{said}"
    );
    let err = evpose_err(&[
        "raster",
        "--events",
        s(&jump),
        "--out",
        s(&out),
        "--window-events",
        "0",
    ]);
    assert!(err.contains("0 is not in 1.."), "{err}");
}

#[test]
fn ground_truth_of_another_recording_is_warned_about() {
    let street = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/aedat4/davis346-street-head.aedat4");
    let gt = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/clip/S4242-00_side-kick.gt.npy");
    let out = Command::new(env!("CARGO_BIN_EXE_evpose"))
        .args(["run", "--events", s(&street), "--gt", s(&gt)])
        .output()
        .unwrap();
    assert!(out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("warning: the ground truth covers none of the"),
        "{stderr}"
    );
}

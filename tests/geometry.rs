//! Two-view triangulation on DHP19's real calibration: round trips through the front cameras,
//! and agreement with an independent numpy implementation of the reference evaluation
//! (`scripts/make-triangulation-fixture.py`).
//!
//! Tolerances are f64 round-off, not method error: the DHP19 matrices have a condition number
//! of about 3.5 × 10⁵ (singular values ≈ 180 and 5 × 10⁻⁴), so back-projection through `P⁺`
//! loses about 5 of f64's 16 digits; at the capture volume's scale (10³ mm) that leaves errors
//! near 10⁻¹⁰ mm. Both checks allow 10⁻⁶ mm (10⁻⁹ of the scale), four orders of magnitude above
//! what is measured and far below anything a 2-D joint error (≈ 1 px ≈ 10 mm) could show.

use evpose_core::geometry::{triangulate, triangulate_joints, Camera, GeometryError};
use evpose_host::{array, dhp19};
use evpose_tests::fixtures;

/// Allowed 3-D error, mm (see the module docs).
const TOLERANCE_MM: f64 = 1e-6;

fn front() -> (Camera, Camera) {
    let dir = dhp19::default_dir();
    let [a, b] = dhp19::FRONT_CHANNELS;
    (
        dhp19::camera(&dir, a).unwrap(),
        dhp19::camera(&dir, b).unwrap(),
    )
}

fn max_abs_diff(x: [f64; 3], y: [f64; 3]) -> f64 {
    (0..3).map(|i| (x[i] - y[i]).abs()).fold(0.0, f64::max)
}

#[test]
fn channels_map_to_the_dhp19_calibration_files() {
    let dir = dhp19::default_dir();
    let (_, centres) = array::read_f64(&dir.join("camera_positions.npy")).unwrap();
    for (channel, file, row) in [(0, "P4", 3), (1, "P1", 0), (2, "P3", 2), (3, "P2", 1)] {
        let cam = dhp19::camera(&dir, channel).unwrap();
        let (shape, p) = array::read_f64(&dir.join(format!("{file}.npy"))).unwrap();
        assert_eq!(shape, [3, 4]);
        assert_eq!(cam.projection().concat(), p, "channel {channel}");
        assert_eq!(cam.centre()[..], centres[row * 3..row * 3 + 3]);
        assert_eq!((cam.width(), cam.height()), (346, 260));
        // Each centre is its P's null vector: P · [C, 1] vanishes up to round-off.
        let c = cam.centre();
        for (r, row) in cam.projection().iter().enumerate() {
            let terms = [row[0] * c[0], row[1] * c[1], row[2] * c[2], row[3]];
            let residual: f64 = terms.iter().sum();
            let scale: f64 = terms.iter().map(|t| t.abs()).sum();
            assert!(
                residual.abs() < 1e-9 * scale,
                "channel {channel} row {r}: P·[C, 1] = {residual:e} (scale {scale:e})"
            );
        }
    }
    let err = dhp19::camera(&dir, 4).unwrap_err();
    assert!(err.to_string().contains("0–3"), "{err}");
    // The calibration embedded in the binary is the same.
    for channel in 0..4 {
        assert_eq!(
            dhp19::bundled_camera(channel).unwrap(),
            dhp19::camera(&dir, channel).unwrap()
        );
    }
    assert!(dhp19::bundled_camera(4).is_err());
}

#[test]
fn front_cameras_round_trip_points_near_the_origin() {
    let (a, b) = front();
    // Where a standing subject's joints are (z up, the origin on the floor, mm): both front
    // cameras see them.
    for x in [
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 1000.0],
        [300.0, -300.0, 500.0],
        [-300.0, 300.0, 500.0],
        [200.0, 200.0, 1500.0],
    ] {
        assert!(
            a.is_visible(a.project(x).unwrap()),
            "{x:?} outside camera 2"
        );
        assert!(
            b.is_visible(b.project(x).unwrap()),
            "{x:?} outside camera 3"
        );
    }
    // A 250 mm grid over ±1,000 mm, the points both cameras see, as one batch of joints.
    let grid = (0..729).map(|n: i32| {
        let step = |d: i32| 250.0 * f64::from((n / d) % 9 - 4);
        [step(81), step(9), step(1)]
    });
    let (mut truth, mut ja, mut jb) = (Vec::new(), Vec::new(), Vec::new());
    for x in grid {
        let (pa, pb) = (a.project(x).unwrap(), b.project(x).unwrap());
        if a.is_visible(pa) && b.is_visible(pb) {
            truth.push(x);
            ja.push(pa);
            jb.push(pb);
        }
    }
    let mut out = vec![Err(GeometryError::NonFinite); truth.len()];
    triangulate_joints(&a, &ja, &b, &jb, &mut out).unwrap();
    let worst = out
        .iter()
        .zip(&truth)
        .map(|(got, x)| max_abs_diff(got.unwrap(), *x))
        .fold(0.0, f64::max);
    let seen = truth.len();
    eprintln!("round trip: {seen} points of 729 seen by both; worst error {worst:e} mm");
    assert!(seen >= 100, "only {seen} grid points visible in both views");
    assert!(worst < TOLERANCE_MM, "worst error {worst:e} mm");
}

#[test]
fn pseudo_inverses_match_numpy() {
    let dir = dhp19::default_dir();
    let (shape, pinv) = array::read_f64(&fixtures().join("dhp19-pinv.npy")).unwrap();
    assert_eq!(shape, [4, 4, 3]);
    let mut worst = 0.0f64;
    for channel in 0..4u8 {
        let ours = dhp19::camera(&dir, channel)
            .unwrap()
            .pseudo_inverse()
            .concat();
        let theirs = &pinv[usize::from(channel) * 12..][..12];
        let scale = theirs.iter().fold(0.0, |m: f64, v| m.max(v.abs()));
        for (o, t) in ours.iter().zip(theirs) {
            worst = worst.max((o - t).abs() / scale);
        }
    }
    eprintln!("pseudo-inverse: worst difference {worst:e} of the largest entry");
    // Two SVDs of a matrix with condition number 3.5e5: measured ~1e-12 relative.
    assert!(worst < 1e-9, "worst relative difference {worst:e}");
}

#[test]
fn triangulation_matches_the_numpy_reference() {
    let (a, b) = front();
    let (shape, rows) = array::read_f64(&fixtures().join("dhp19-triangulation.npy")).unwrap();
    assert_eq!(shape, [64, 7]);
    let mut worst = 0.0f64;
    for (i, r) in rows.chunks_exact(7).enumerate() {
        let got = triangulate(&a, (r[0], r[1]), &b, (r[2], r[3]))
            .unwrap_or_else(|e| panic!("row {i}: {e}"));
        let d = max_abs_diff(got, [r[4], r[5], r[6]]);
        assert!(d < TOLERANCE_MM, "row {i}: {got:?} vs numpy {:?}", &r[4..]);
        worst = worst.max(d);
    }
    eprintln!("numpy reference: worst difference {worst:e} mm over 64 noisy joint pairs");
}

#[test]
fn the_same_camera_twice_has_no_baseline() {
    // Two views through one calibration meet at its centre whatever they see (the point they
    // would give is the camera itself): refused, also beside a third view at that centre.
    let (a, b) = front();
    let (pa, qa) = (
        a.project([0.0, 0.0, 1000.0]).unwrap(),
        a.project([300.0, -300.0, 500.0]).unwrap(),
    );
    let err = evpose_core::geometry::triangulate_views(&[(&a, pa, 1.0), (&a, qa, 1.0)]);
    assert_eq!(err, Err(GeometryError::NoBaseline));
    assert_eq!(
        triangulate(&a, pa, &a.clone(), qa),
        Err(GeometryError::NoBaseline)
    );
    // With a second camera it triangulates.
    let x = [0.0, 0.0, 1000.0];
    let got = triangulate(&a, a.project(x).unwrap(), &b, b.project(x).unwrap()).unwrap();
    assert!(max_abs_diff(got, x) < TOLERANCE_MM);
}

//! The rasterizer, through the CLI's code path, against the reference rasterization of real
//! DAVIS346 windows: x, y, p_acc and cnt exactly; t_avg within 1e-6 (in practice bit-exact).

use evpose_host::array;
use evpose_host::io::OpenOptions;
use evpose_host::pipeline::{rasterize, window_rows, RasterOptions};
use evpose_tests::{fixtures, street_windows};

#[test]
fn street_windows_match_the_reference_rasterization() {
    let opts = RasterOptions {
        open: OpenOptions {
            size: Some((346, 260)),
            ..OpenOptions::default()
        },
        ..RasterOptions::default()
    };
    let mut t_exact = 0usize;
    let mut total = 0usize;
    for name in street_windows() {
        let events = fixtures().join(format!("{name}.events.npy"));
        let (shape, want) =
            array::read_exact::<f32>(&fixtures().join(format!("{name}.points.npy"))).unwrap();
        let mut got = Vec::new();
        let report = rasterize(&events, &opts, |_, w| {
            got = window_rows(w);
            Ok(())
        })
        .unwrap();
        assert_eq!(report.windows, 1, "{name}");
        assert_eq!(report.stats.accepted, 7_500, "{name}");
        assert_eq!(got.len() as u64, shape[0], "{name}: point count");
        for (i, (g, w)) in got.iter().zip(want.chunks_exact(5)).enumerate() {
            assert_eq!(
                [g[0], g[1], g[3], g[4]],
                [w[0], w[1], w[3], w[4]],
                "{name} point {i}"
            );
            assert!(
                (g[2] - w[2]).abs() <= 1e-6,
                "{name} point {i}: t_avg {} vs {}",
                g[2],
                w[2]
            );
            t_exact += usize::from(g[2] == w[2]);
        }
        total += got.len();
    }
    eprintln!("t_avg bit-exact on {t_exact} of {total} points");
}

#[test]
fn windowed_rasterization_of_the_concatenated_stream_gives_the_same_windows() {
    // All ten windows in one event file, cut back into 7,500-event windows by the CLI path.
    let dir = scratch_dir();
    let mut all = Vec::new();
    for name in street_windows() {
        let (_, v) = array::read_f64(&fixtures().join(format!("{name}.events.npy"))).unwrap();
        all.extend(v);
    }
    let joined = dir.join("joined.npy");
    array::write(&joined, &[(all.len() / 4) as u64, 4], &all).unwrap();
    let opts = RasterOptions {
        open: OpenOptions {
            size: Some((346, 260)),
            ..OpenOptions::default()
        },
        window_events: Some(7_500),
        ..RasterOptions::default()
    };
    let mut got = Vec::new();
    rasterize(&joined, &opts, |_, w| {
        got.push(window_rows(w));
        Ok(())
    })
    .unwrap();
    assert_eq!(got.len(), 10);
    for (name, rows) in street_windows().iter().zip(&got) {
        let (_, want) =
            array::read_exact::<f32>(&fixtures().join(format!("{name}.points.npy"))).unwrap();
        assert_eq!(rows.as_flattened(), &want[..], "{name}");
    }
}

/// Cargo's scratch directory for integration tests (`target/tmp`): each run overwrites the
/// last one's file.
fn scratch_dir() -> std::path::PathBuf {
    let d = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("evpose-parity");
    std::fs::create_dir_all(&d).unwrap();
    d
}

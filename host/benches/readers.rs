//! Reader throughput per event format: events per second, one core, through
//! `evpose_host::io::open` as `evpose info` reads (file on disk, page cache warm).
//!
//! Each format gets one synthetic file of [`EVENTS`] events, written by the spec encoders in
//! `tests/support/encoders.rs` (the AEDAT 4 writer and the npy writer for those two) into a
//! temporary directory. `cargo bench -p evpose-host --bench readers`.

#[path = "../tests/support/encoders.rs"]
mod encoders;

use std::path::{Path, PathBuf};
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use encoders::*;
use evpose_core::Event;
use evpose_host::io::aedat4::{Aedat4Writer, Compression};
use evpose_host::io::{open, Batch, CameraInfo};

/// Events per file.
const EVENTS: usize = 2_000_000;

/// Writes one file per format; returns (name, path).
fn files(dir: &Path) -> Vec<(&'static str, PathBuf)> {
    let davis = synthetic(EVENTS, 346, 260, 1, 1_000_000);
    let dhp19 = synthetic(EVENTS, 346, 260, 4, 1_000_000);
    let prophesee = synthetic(EVENTS, 1280, 720, 1, 1_000_000);
    let npy = dir.join("events.npy");
    let mut out = vec![("npy (f64)", npy.clone())];
    let mut put = |name: &'static str, file: &str, bytes: Vec<u8>| {
        let path = dir.join(file);
        std::fs::write(&path, bytes).expect("write bench file");
        out.push((name, path));
    };

    let rows: Vec<f64> = davis
        .iter()
        .flat_map(|e| {
            [
                f64::from(e.x),
                f64::from(e.y),
                e.t as f64,
                f64::from(u8::from(e.on)),
            ]
        })
        .collect();
    evpose_host::array::write(&npy, &[EVENTS as u64, 4], &rows).expect("write npy");

    for (name, file, compression) in [
        ("aedat4 (LZ4)", "lz4.aedat4", Compression::Lz4),
        ("aedat4 (zstd)", "zstd.aedat4", Compression::Zstd),
    ] {
        let cam = [CameraInfo {
            id: 0,
            width: Some(346),
            height: Some(260),
            name: None,
        }];
        let mut w = Aedat4Writer::new(Vec::new(), &cam, compression).expect("aedat4 header");
        let mut b = Batch::default();
        for e in &davis {
            b.push(0, Event::new(e.x, e.y, e.t, e.on));
        }
        w.write(&b).expect("aedat4 events");
        put(name, file, w.finish().expect("aedat4 finish"));
    }
    // Four cameras: the reader merges them by time.
    let cams: Vec<CameraInfo> = (0..4)
        .map(|id| CameraInfo {
            id,
            width: Some(346),
            height: Some(260),
            name: None,
        })
        .collect();
    let mut w = Aedat4Writer::new(Vec::new(), &cams, Compression::Lz4).expect("aedat4 header");
    let mut b = Batch::default();
    for e in &dhp19 {
        b.push(e.cam, Event::new(e.x, e.y, e.t, e.on));
    }
    w.write(&b).expect("aedat4 events");
    put(
        "aedat4 (LZ4, 4 cameras)",
        "dhp19.aedat4",
        w.finish().expect("aedat4 finish"),
    );
    put(
        "aedat2 (DAVIS346)",
        "davis.aedat",
        aedat2_davis346(&davis, false),
    );
    put(
        "aedat2 (DHP19, 4 cameras)",
        "dhp19.aedat",
        aedat2_davis346(&dhp19, true),
    );
    put(
        "aedat3 (polarity packets)",
        "davis.aedat3",
        aedat3_file(&davis, 1),
    );
    let mut evt2 = raw_header(&["evt 2.0", "format EVT2;height=720;width=1280", "end"]);
    evt2.extend_from_slice(&evt2_body(&prophesee));
    put("evt2", "evt2.raw", evt2);
    // Random events rarely share a row and time: one event per 64-bit word here.
    let mut evt21 = raw_header(&[
        "format EVT21;endianness=little;height=720;width=1280",
        "end",
    ]);
    evt21.extend_from_slice(&evt21_body(&prophesee));
    put("evt21", "evt21.raw", evt21);
    let mut evt3 = raw_header(&["evt 3.0", "format EVT3;height=720;width=1280", "end"]);
    evt3.extend_from_slice(&evt3_body(&prophesee));
    put("evt3", "evt3.raw", evt3);
    put("dat", "cd.dat", dat_file(&prophesee, 1280, 720));
    put("es (DVS)", "dvs.es", es_dvs_file(&prophesee, 1280, 720));
    put(
        "text (t x y p, seconds)",
        "events.txt",
        text_seconds(&davis),
    );
    out
}

fn read_all(path: &Path) -> u64 {
    let mut r = open(path, None).expect("open");
    let mut b = Batch::default();
    let mut n = 0;
    while r.read_batch(&mut b).expect("read") {
        n += b.len() as u64;
    }
    n
}

fn readers(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temp dir");
    let files = files(dir.path());
    let mut g = c.benchmark_group("read");
    g.throughput(Throughput::Elements(EVENTS as u64));
    g.sample_size(10);
    g.warm_up_time(Duration::from_secs(1));
    g.measurement_time(Duration::from_secs(4));
    for (name, path) in &files {
        assert_eq!(read_all(path), EVENTS as u64, "{name}");
        let bytes = std::fs::metadata(path).map_or(0, |m| m.len());
        eprintln!("{name}: {bytes} bytes");
        g.bench_function(*name, |b| b.iter(|| read_all(path)));
    }
    g.finish();
}

criterion_group!(benches, readers);
criterion_main!(benches);

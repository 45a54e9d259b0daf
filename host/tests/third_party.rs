//! Files written by other tools read as the events those tools were given: expelliarmus 1.1.12
//! (EVT 2.0, EVT 3.0, DAT) and faery 0.7.1 (EVT 2.0, EVT 3.0, DAT versions 1 and 2, AEDAT 4,
//! CSV, Event Stream) wrote
//! `fixtures/third-party/` from the arrays beside them (`scripts/third-party-formats.py
//! --write-fixtures`, which also runs the comparison the other way and on real camera files).

use std::path::{Path, PathBuf};

use evpose_core::Event;
use evpose_host::io::{open_with, read_all, EventReader, OpenOptions};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/third-party")
}

/// The events an engine was given: an (N, 4) int32 or int64 `[x, y, t_us, p]` array
/// (`stem` relative to the fixtures' folder).
fn expected(stem: &str) -> Vec<(u8, Event)> {
    let bytes = std::fs::read(dir().join(format!("{stem}.npy"))).unwrap();
    let npy = npyz::NpyFile::new(&bytes[..]).unwrap();
    let v: Vec<i64> = if npy.dtype() == npyz::DType::Plain("<i4".parse().unwrap()) {
        let v: Vec<i32> = npy.into_vec().unwrap();
        v.into_iter().map(i64::from).collect()
    } else {
        npy.into_vec().unwrap()
    };
    v.chunks_exact(4)
        .map(|r| (0, Event::new(r[0] as u16, r[1] as u16, r[2], r[3] == 1)))
        .collect()
}

fn open(path: &Path, size: Option<(u16, u16)>) -> Box<dyn EventReader> {
    let opts = OpenOptions {
        size,
        ..OpenOptions::default()
    };
    open_with(path, &opts).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()))
}

/// Every file of `stem` but its array, sorted.
fn files(stem: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with(&format!("{stem}.")) && !name.ends_with(".npy")
        })
        .collect();
    v.sort();
    v
}

#[test]
fn every_engine_file_reads_as_the_events_it_was_given() {
    let mut read = 0;
    // expelliarmus writes no size and a fixed `system_ID` (640 x 480 for EVT 2.0): the
    // 1280 x 720 sets pass their size, as a user would.
    for (stem, size, engines) in [
        ("street", None, 9),
        ("sparse", Some((1280, 720)), 8),
        ("rows", Some((1280, 720)), 9),
        // faery's DAT version 1 (9-bit x, 8-bit y) of a 304 x 240 sensor.
        ("atis", None, 1),
    ] {
        let want = expected(stem);
        let paths = files(stem);
        assert_eq!(paths.len(), engines, "{stem}: {paths:?}");
        for path in paths {
            let mut r = open(&path, size);
            let got = read_all(&mut *r).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!(got.len(), want.len(), "{}", path.display());
            if let Some(i) = (0..got.len()).find(|&i| got[i] != want[i]) {
                panic!(
                    "{}: event {i}: {:?} against {:?}",
                    path.display(),
                    got[i],
                    want[i]
                );
            }
            read += 1;
        }
    }
    assert_eq!(read, 27);
}

#[test]
fn expelliarmus_evt3_time_low_wraps_start_the_next_period() {
    // expelliarmus writes one time-high word per file: the 2,000 street events (50 ms) wrap the
    // 12-bit time low 12 times; faery writes the time-high words.
    for (file, implied) in [
        ("street.expelliarmus-evt3.raw", 12),
        ("street.faery-evt3.raw", 0),
    ] {
        let mut r = open(&dir().join(file), None);
        read_all(&mut *r).unwrap();
        assert_eq!(r.notes().implied_time_highs, implied, "{file}");
    }
}

#[test]
fn sizes_the_files_state_or_imply() {
    let size = |file: &str, given: Option<(u16, u16)>| {
        let r = open(&dir().join(file), given);
        let c = &r.info().cameras[0];
        (c.width.zip(c.height), r.notes().assumptions)
    };
    // faery states the size: in the RAW header, and as `x@W`, `y@H` in its CSV header row.
    assert_eq!(size("street.faery-evt3.raw", None).0, Some((346, 260)));
    let (csv, notes) = size("street.faery-csv.csv", None);
    assert_eq!(csv, Some((346, 260)));
    assert!(notes.iter().any(|n| n.contains("x@346")), "{notes:?}");
    // expelliarmus's EVT 3.0 header says `system_ID 48`, an EVK3 Gen4.1 (1280 x 720) to
    // OpenEB; --width/--height override it.
    let (implied, notes) = size("street.expelliarmus-evt3.raw", None);
    assert_eq!(implied, Some((1280, 720)));
    assert!(
        notes.iter().any(|n| n.contains("system_ID 48")),
        "{notes:?}"
    );
    assert_eq!(
        size("street.expelliarmus-evt3.raw", Some((346, 260))).0,
        Some((346, 260))
    );
    // Its EVT 2.0 header says `system_ID 21` (640 x 480) whatever the events: a 1280 x 720
    // set read without a size names where the size came from.
    let mut r = open(&dir().join("rows.expelliarmus-evt2.raw"), None);
    let err = read_all(&mut *r).unwrap_err().to_string();
    assert!(
        err.contains("640x480") && err.contains("system_ID") && err.contains("--width"),
        "{err}"
    );
}

/// EVT 2.1 in both byte orders (`fixtures/third-party/evt21`, `scripts/evt21-engines.py`):
/// evutils 0.3.18 wrote 2,000 street events in the IMX636's order (`legacy`), the same words with
/// their halves swapped are the GenX320's (evlib 0.13.2 reads them as the events given); and a
/// stream built from the format's description (vectors of random masks, triggers, OTHERS words,
/// a wrap of the time-high counter) in both orders, which evutils and evlib decode alike.
#[test]
fn evt21_files_read_as_evutils_and_evlib_read_them() {
    let dir = dir().join("evt21");
    for (stem, files) in [
        (
            "street-2000",
            ["street.evutils-evt21.raw", "street.evt21-little.raw"],
        ),
        (
            "vectors",
            ["vectors.evt21-legacy.raw", "vectors.evt21-little.raw"],
        ),
    ] {
        let want = expected(&format!("evt21/{stem}"));
        for (file, format) in files.iter().zip(["evt21-legacy", "evt21"]) {
            let mut r = open(&dir.join(file), None);
            assert_eq!(r.info().format.name(), format, "{file}");
            let got = read_all(&mut *r).unwrap_or_else(|e| panic!("{file}: {e}"));
            assert_eq!(got.len(), want.len(), "{file}");
            assert!(got == want, "{file}");
        }
    }
}

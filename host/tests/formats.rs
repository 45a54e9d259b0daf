//! The readers of AEDAT 2.0 (jAER, DHP19), AEDAT 3.1, Prophesee EVT 2.0 / 2.1 / 3.0 / `.dat` and
//! text: files built byte by byte from the format descriptions (`support/encoders.rs`),
//! damaged variants, detection, memory bounds, and proptest fuzzing of every decoder.

#[path = "support/encoders.rs"]
mod encoders;

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::Read;
use std::path::{Path, PathBuf};

use encoders::*;
use evpose_core::Event;
use evpose_host::io::aedat2::Aedat2Reader;
use evpose_host::io::aedat3::Aedat3Reader;
use evpose_host::io::aedat4::{Aedat4Reader, Aedat4Writer, Compression};
use evpose_host::io::dat::DatReader;
use evpose_host::io::es::EsReader;
use evpose_host::io::evt::EvtReader;
use evpose_host::io::text::TextReader;
use evpose_host::io::{
    open, open_with, Batch, CameraInfo, EventReader, Format, OpenOptions, ReadError, ReadNotes,
    TimeUnit, BATCH_EVENTS,
};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Allocation tracking: per thread, so that parallel tests do not disturb each other.

struct Counting;

thread_local! {
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn track(delta: isize) {
    let _ = LIVE.try_with(|live| {
        let v = live.get() + delta;
        live.set(v);
        let _ = PEAK.try_with(|p| p.set(p.get().max(v)));
    });
}

// SAFETY: forwards to the system allocator; the bookkeeping touches only thread-locals
// without destructors.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            track(l.size() as isize);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.alloc_zeroed(l) };
        if !p.is_null() {
            track(l.size() as isize);
        }
        p
    }

    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(p, l) };
        track(-(l.size() as isize));
    }

    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let q = unsafe { System.realloc(p, l, new) };
        if !q.is_null() {
            track(new as isize - l.size() as isize);
        }
        q
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Runs `f`; returns its result and the peak of this thread's live heap above the start.
fn peak_heap<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let start = LIVE.with(Cell::get);
    PEAK.with(|p| p.set(start));
    let out = f();
    let peak = PEAK.with(Cell::get) - start;
    (out, peak.max(0) as usize)
}

// ---------------------------------------------------------------------------------------------
// Helpers.

/// Every event with its camera, the batch sizes, and the notes at the end.
#[derive(Debug)]
struct Decoded {
    events: Vec<(u8, Event)>,
    batches: Vec<usize>,
    notes: ReadNotes,
}

fn drain(mut r: impl EventReader) -> Result<Decoded, ReadError> {
    let mut out = Decoded {
        events: Vec::new(),
        batches: Vec::new(),
        notes: ReadNotes::default(),
    };
    let mut batch = Batch::default();
    loop {
        match r.read_batch(&mut batch) {
            Ok(true) => {}
            Ok(false) => break,
            Err(e) => {
                assert!(batch.is_empty(), "a failed read leaves the batch empty");
                assert!(
                    !r.read_batch(&mut batch).unwrap(),
                    "finished after an error"
                );
                return Err(e);
            }
        }
        assert_eq!(batch.events.len(), batch.cameras.len());
        assert!(!batch.is_empty() && batch.len() <= BATCH_EVENTS);
        out.batches.push(batch.len());
        out.events.extend(
            batch
                .cameras
                .iter()
                .copied()
                .zip(batch.events.iter().copied()),
        );
    }
    assert!(!r.read_batch(&mut batch).unwrap(), "stays at the end");
    out.notes = r.notes();
    Ok(out)
}

/// The decoders under test, by name, over bytes.
#[derive(Clone, Copy, Debug)]
enum Dec {
    Aedat2,
    Aedat2Dhp19,
    Aedat3,
    Evt2,
    Evt21,
    Evt3,
    Dat,
    Text,
    Aedat4,
    Es,
}

const DECODERS: [Dec; 10] = [
    Dec::Aedat2,
    Dec::Aedat2Dhp19,
    Dec::Aedat3,
    Dec::Evt2,
    Dec::Evt21,
    Dec::Evt3,
    Dec::Dat,
    Dec::Text,
    Dec::Aedat4,
    Dec::Es,
];

fn decode(dec: Dec, bytes: &[u8]) -> Result<Decoded, ReadError> {
    decode_sized(dec, bytes, None)
}

fn decode_sized(dec: Dec, bytes: &[u8], size: Option<(u16, u16)>) -> Result<Decoded, ReadError> {
    match dec {
        Dec::Aedat2 => drain(Aedat2Reader::new(bytes, Format::Aedat2, size)?),
        Dec::Aedat2Dhp19 => drain(Aedat2Reader::new(bytes, Format::Aedat2Dhp19, size)?),
        Dec::Aedat3 => drain(Aedat3Reader::new(bytes, size)?),
        Dec::Evt2 => drain(EvtReader::new(bytes, Format::Evt2, size)?),
        Dec::Evt21 => drain(EvtReader::new(bytes, Format::Evt21, size)?),
        Dec::Evt3 => drain(EvtReader::new(bytes, Format::Evt3, size)?),
        Dec::Dat => drain(DatReader::new(bytes, size)?),
        Dec::Text => drain(TextReader::new(bytes, None, size)?),
        Dec::Aedat4 => drain(Aedat4Reader::new(bytes)?),
        Dec::Es => drain(EsReader::new(bytes)?),
    }
}

fn events_of(expected: &[Ev]) -> Vec<(u8, Event)> {
    expected
        .iter()
        .map(|e| (e.cam, Event::new(e.x, e.y, e.t, e.on)))
        .collect()
}

fn corrupt_offset(r: Result<Decoded, ReadError>) -> u64 {
    match r {
        Err(ReadError::Corrupt { offset, .. }) => offset,
        other => panic!("expected a Corrupt error, got {other:?}"),
    }
}

fn error_text(r: Result<Decoded, ReadError>) -> String {
    match r {
        Err(e) => e.to_string(),
        Ok(d) => panic!("expected an error, got {} events", d.events.len()),
    }
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/formats")
        .join(name)
}

// ---------------------------------------------------------------------------------------------
// AEDAT 2.0.

#[test]
fn aedat2_davis346_decodes_spec_bytes() {
    let mut f = aedat2_header(Some("eu.seebetter.ini.chips.davis.DAVIS346B"), true);
    let start = f.len() as u64;
    // Corners, both polarities: y_raw = 259 - y.
    aedat2_record(&mut f, davis_addr(0, 0, true, 346, 260), 100);
    aedat2_record(&mut f, davis_addr(345, 259, false, 346, 260), 101);
    // By hand: x_raw = 17 (x = 345 − 17 = 328, jAER's `sx1 − x_raw`), y_raw = 200 (y = 59), ON.
    aedat2_record(&mut f, (200 << 22) | (17 << 12) | (1 << 11), 102);
    // APS sample (bit 31), IMU sample (bits 31 and 11), special event (bit 10): skipped.
    aedat2_record(&mut f, 0x8000_0000 | (5 << 12), 103);
    aedat2_record(&mut f, 0x8000_0C00, 104);
    aedat2_record(&mut f, 0x0000_0400, 105);
    aedat2_record(&mut f, davis_addr(10, 20, false, 346, 260), 106);
    let d = decode(Dec::Aedat2, &f).unwrap();
    assert_eq!(
        d.events,
        events_of(&[
            ev(0, 0, 0, 100, true),
            ev(0, 345, 259, 101, false),
            ev(0, 328, 59, 102, true),
            ev(0, 10, 20, 106, false),
        ])
    );
    assert_eq!(d.notes.skipped_records, 3);
    assert!(d.notes.assumptions[0].contains("DAVIS346B"));
    let r = Aedat2Reader::new(&f[..], Format::Aedat2, None).unwrap();
    assert_eq!(r.info().format, Format::Aedat2Davis346);
    assert_eq!(r.info().cameras.len(), 1);
    assert_eq!(r.info().cameras[0].width, Some(346));
    assert_eq!(r.info().cameras[0].name.as_deref(), Some("DAVIS346B"));
    // x = 346 is outside the sensor: an error at that record.
    let mut bad = f.clone();
    aedat2_record(&mut bad, 346 << 12, 107);
    assert_eq!(
        corrupt_offset(decode(Dec::Aedat2, &bad)),
        start + 7 * 8,
        "offset of the 8th record"
    );
    // y_raw = 260 too.
    let mut bad = f.clone();
    aedat2_record(&mut bad, 260 << 22, 107);
    assert!(error_text(decode(Dec::Aedat2, &bad)).contains("outside the 346x260 sensor"));
}

#[test]
fn aedat2_sensor_choice() {
    let events = [ev(0, 239, 0, 5, true), ev(0, 0, 179, 6, false)];
    let mut f = aedat2_header(Some("eu.seebetter.ini.chips.davis.DAVIS240C"), false);
    for e in &events {
        aedat2_record(&mut f, davis_addr(e.x, e.y, e.on, 240, 180), e.t as u32);
    }
    // Header without the end marker: the data starts at the first byte that is not '#'.
    let d = decode(Dec::Aedat2, &f).unwrap();
    assert_eq!(d.events, events_of(&events));
    let r = Aedat2Reader::new(&f[..], Format::Aedat2, None).unwrap();
    assert_eq!(r.info().format, Format::Aedat2Davis240);

    // --format overrides the header, and says so.
    let r = Aedat2Reader::new(&f[..], Format::Aedat2Davis346, None).unwrap();
    let d = drain(r).unwrap();
    assert!(d.notes.assumptions.iter().any(|a| a.contains("overrides")));
    // y = 0 on the 180-row sensor is y_raw = 179, which a 260-row flip puts at 259 - 179.
    assert_eq!(d.events[0].1.y, 80, "flipped with the forced height");

    // No AEChip line: refused unless the sensor is given.
    let mut bare = aedat2_header(None, true);
    bare.extend_from_slice(
        &f[aedat2_header(Some("eu.seebetter.ini.chips.davis.DAVIS240C"), false).len()..],
    );
    let msg = error_text(decode(Dec::Aedat2, &bare));
    assert!(msg.contains("--format aedat2-davis346"), "{msg}");
    let d = drain(Aedat2Reader::new(&bare[..], Format::Aedat2Davis240, None).unwrap()).unwrap();
    assert_eq!(d.events, events_of(&events));

    // No header at all: only with a sensor given.
    let body = &bare[aedat2_header(None, true).len()..];
    assert!(decode(Dec::Aedat2, body).is_err());
    let d = drain(Aedat2Reader::new(body, Format::Aedat2Davis240, None).unwrap()).unwrap();
    assert_eq!(d.events, events_of(&events));

    // A DAVIS of unknown size needs --width/--height.
    let mut odd = aedat2_header(Some("eu.seebetter.ini.chips.davis.DavisFuture"), true);
    aedat2_record(&mut odd, davis_addr(3, 4, true, 200, 100), 9);
    assert!(error_text(decode(Dec::Aedat2, &odd)).contains("--width"));
    let d = decode_sized(Dec::Aedat2, &odd, Some((200, 100))).unwrap();
    assert_eq!(d.events, events_of(&[ev(0, 3, 4, 9, true)]));

    // Other versions.
    for (magic, what) in [("#!AER-DAT1.0\r\n", "1.0"), ("#!AER-DAT3.1\r\n", "3.1")] {
        let msg = error_text(decode(Dec::Aedat2, magic.as_bytes()));
        assert!(msg.contains(what), "{msg}");
    }
}

#[test]
fn data_starting_with_the_comment_byte_ends_the_header() {
    // AEDAT 2.0 without the end marker; the first address byte is '#' (0x23): y_raw = 140,
    // x_raw = 7.
    let mut f = aedat2_header(Some("DAVIS346B"), false);
    aedat2_record(&mut f, 0x2300_0000 | (7 << 12), 5);
    let d = decode(Dec::Aedat2, &f).unwrap();
    assert_eq!(d.events, events_of(&[ev(0, 345 - 7, 259 - 140, 5, false)]));
    // RAW without `% end`; the first word's first byte is '%' (0x25).
    let mut f = raw_header(&["evt 2.0"]);
    evt2_word(&mut f, 0x8000_0025);
    evt2_word(&mut f, evt2_cd(1, 2, true, 0));
    let d = decode(Dec::Evt2, &f).unwrap();
    assert_eq!(d.events, events_of(&[ev(0, 1, 2, 0x25 << 6, true)]));
}

#[test]
fn aedat2_dvs128_layout() {
    let mut f = aedat2_header(Some("ch.unizh.ini.jaer.chip.retina.Tmpdiff128"), true);
    // By hand: row 5 from the bottom (y = 122 from the top), x_raw = 0 (x = 127), polarity
    // bit 0 = 0 is ON.
    aedat2_record(&mut f, 5 << 8, 10);
    aedat2_record(&mut f, dvs128_addr(0, 127, false), 11);
    aedat2_record(&mut f, 0x8000, 12); // sync event: skipped
    let d = decode(Dec::Aedat2, &f).unwrap();
    assert_eq!(
        d.events,
        events_of(&[ev(0, 127, 122, 10, true), ev(0, 0, 127, 11, false)])
    );
    assert_eq!(d.notes.skipped_records, 1);
}

#[test]
fn aedat2_dhp19_four_cameras() {
    let events = synthetic(500, 346, 260, 4, 1_000);
    let f = aedat2_davis346(&events, true);
    let r = Aedat2Reader::new(&f[..], Format::Aedat2, None).unwrap();
    assert_eq!(r.info().format, Format::Aedat2Dhp19);
    let ids: Vec<u8> = r.info().cameras.iter().map(|c| c.id).collect();
    assert_eq!(ids, [0, 1, 2, 3]);
    assert!(r
        .info()
        .cameras
        .iter()
        .all(|c| c.width == Some(346) && c.height == Some(260)));
    assert_eq!(drain(r).unwrap().events, events_of(&events));
    // Camera id 4 is impossible.
    let mut bad = f.clone();
    aedat2_record(&mut bad, davis_addr(1, 1, true, 346, 260) | 4, 2_000);
    let msg = error_text(decode(Dec::Aedat2, &bad));
    assert!(msg.contains("camera id 4"), "{msg}");
}

/// DHP19's own decoding of its recordings (SensorsINI/DHP19, `generate_DHP19/
/// extract_from_aedat.m`: `X = (sx-x)+cam*sx; y = sy-y_raw;` with `sx = 346`, `sy = 260`,
/// 1-based, over the raw address fields of `ImportAedatDataVersion1or2.m`), jAER's
/// (`DavisEventExtractor`: `e.x = sx1 - x_raw`) and the projection of its labels
/// (`v = H - v'` on P's output) all place the raw pixel (c, r) at column 345 − c, row 259 − r
/// from the top-left: where this reader must put it for DHP19's P matrices to project the
/// labels onto the events. Through stop 42 it put it at column c: labels mirrored left–right
/// on real DHP19 files (the simulator wrote the same mirror, so synthetic data never showed
/// it).
#[test]
fn dhp19_addresses_decode_as_dhp19_and_jaer_decode_them() {
    let mut f = aedat2_header(
        Some("ch.unizh.ini.jaer.chip.multicamera.MultiDavis346BCameraChip"),
        true,
    );
    let raw: Vec<(u32, u32, u32)> = (0..40u32)
        .map(|i| ((i * 37) % 346, (i * 53) % 260, i % 4))
        .chain([(0, 0, 0), (345, 259, 3), (17, 200, 1)])
        .collect();
    for (i, &(c, r, cam)) in raw.iter().enumerate() {
        aedat2_record(&mut f, (r << 22) | (c << 12) | (1 << 11) | cam, i as u32);
    }
    let got = decode(Dec::Aedat2, &f).unwrap().events;
    let want: Vec<(u8, Event)> = raw
        .iter()
        .enumerate()
        .map(|(i, &(c, r, cam))| {
            // DHP19's 1-based (X, y) minus one: (346 − c) − 1, (260 − r) − 1.
            let (x, y) = (346 - c - 1, 260 - r - 1);
            (cam as u8, Event::new(x as u16, y as u16, i as i64, true))
        })
        .collect();
    assert_eq!(got, want);
}

/// DAVIS special (trigger) events are skipped as events but their times kept, on the events'
/// clock: DHP19 starts its Vicon clock at one of them.
#[test]
fn dhp19_trigger_times_are_kept() {
    let mut f = aedat2_header(
        Some("ch.unizh.ini.jaer.chip.multicamera.MultiDavis346BCameraChip"),
        true,
    );
    aedat2_record(&mut f, davis_addr(1, 1, true, 346, 260), 100);
    aedat2_record(&mut f, 0x400 | 2, 150); // a special event (bit 10), camera bits set
    aedat2_record(&mut f, davis_addr(2, 2, false, 346, 260) | 1, 200);
    aedat2_record(&mut f, 0x8000_0400, 250); // an APS/IMU sample with bit 10: not a trigger
    aedat2_record(&mut f, 0x400, 300);
    let d = decode(Dec::Aedat2, &f).unwrap();
    assert_eq!(d.events.len(), 2);
    assert_eq!(d.notes.special_times, [150, 300]);
    assert_eq!(d.notes.skipped_records, 3);
}

#[test]
fn aedat2_timestamps_unwrap() {
    let mut f = aedat2_header(Some("DAVIS346B"), true);
    let a = |f: &mut Vec<u8>, ts: u32| aedat2_record(f, davis_addr(1, 1, true, 346, 260), ts);
    a(&mut f, u32::MAX - 10);
    a(&mut f, 5); // wrapped
    a(&mut f, u32::MAX - 3); // late event from before the wrap
    a(&mut f, 20);
    a(&mut f, 0x8000_0000); // jAER's signed overflow (2^31) is no wrap of the u32
    let d = decode(Dec::Aedat2, &f).unwrap();
    let t: Vec<i64> = d.events.iter().map(|(_, e)| e.t).collect();
    let w = 1i64 << 32;
    assert_eq!(t, [w - 11, w + 5, w - 4, w + 20, w + (1 << 31)]);
    assert_eq!(d.notes.timestamp_wraps, 1);
}

#[test]
fn aedat2_header_is_bounded() {
    // A '#' line without an end is refused after 64 KiB, without reading on.
    let mut f = b"#!AER-DAT2.0\r\n#".to_vec();
    f.extend(std::iter::repeat_n(b'a', 100_000));
    let (r, peak) = peak_heap(|| decode(Dec::Aedat2Dhp19, &f));
    assert!(error_text(r).contains("header line is longer"));
    assert!(peak < 1 << 20, "peak {peak}");
    // More than 1 MiB of header lines is refused.
    let mut f = b"#!AER-DAT2.0\r\n".to_vec();
    for _ in 0..20_000 {
        f.extend_from_slice(
            b"# <entry key=\"some.preference\" value=\"a long preference value\"/>\r\n",
        );
    }
    assert!(error_text(decode(Dec::Aedat2Dhp19, &f)).contains("header is longer"));
}

// ---------------------------------------------------------------------------------------------
// AEDAT 3.1.

#[test]
fn aedat3_decodes_packets_and_sources() {
    let mut f = aedat3_header(&[(1, "DAVIS346B")]);
    // A special-event packet (type 0, 8-byte events): skipped.
    aedat3_packet_header(&mut f, 0, 1, 8, 4, 0, 2, 2, 2);
    f.extend_from_slice(&[0u8; 16]);
    // Polarity packet, overflow 1, capacity 4, number 3 (one invalid), one unused slot.
    aedat3_packet_header(&mut f, 1, 1, 8, 4, 1, 4, 3, 2);
    aedat3_polarity(&mut f, 345, 259, true, true, 7);
    aedat3_polarity(&mut f, 3, 4, true, false, 8);
    aedat3_polarity(&mut f, 0, 0, false, true, 0x7FFF_FFFF);
    f.extend_from_slice(&[0xEE; 8]); // unused capacity: never read
                                     // By hand: x = 2, y = 3, ON, valid: data = 2 << 17 | 3 << 2 | 2 | 1.
    aedat3_packet_header(&mut f, 1, 7, 8, 4, 0, 1, 1, 1);
    f.extend_from_slice(&((2u32 << 17) | (3 << 2) | 3).to_le_bytes());
    f.extend_from_slice(&9i32.to_le_bytes());
    let d = decode(Dec::Aedat3, &f).unwrap();
    let o = 1i64 << 31;
    assert_eq!(
        d.events,
        events_of(&[
            ev(0, 345, 259, o + 7, true),
            ev(0, 0, 0, o + 0x7FFF_FFFF, false),
            ev(1, 2, 3, 9, true),
        ])
    );
    assert_eq!(d.notes.skipped_packets, 1);
    assert_eq!(d.notes.skipped_records, 1);
    let r = Aedat3Reader::new(&f[..], None).unwrap();
    assert_eq!(
        r.info().cameras,
        [CameraInfo {
            id: 0,
            width: Some(346),
            height: Some(260),
            name: Some("DAVIS346B".into()),
        }]
    );
}

#[test]
fn aedat3_damage_is_typed_and_located() {
    let head = aedat3_header(&[(1, "DAVIS346B")]);
    let at = head.len() as u64;
    let packet = |f: &mut Vec<u8>, ty: i16, size: i32, off: i32, cap: i32, num: i32| {
        aedat3_packet_header(f, ty, 1, size, off, 0, cap, num, num);
    };
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("unknown packet type 14", {
            let mut f = head.clone();
            packet(&mut f, 14, 8, 4, 0, 0);
            f
        }),
        ("event counts out of range", {
            let mut f = head.clone();
            packet(&mut f, 1, 8, 4, 1, 2);
            f
        }),
        ("expected 8 and 4", {
            let mut f = head.clone();
            packet(&mut f, 1, 16, 4, 1, 1);
            f.extend_from_slice(&[1; 16]);
            f
        }),
        ("exceeds", {
            // 2^31 - 1 events of 8 bytes: refused before any allocation.
            let mut f = head.clone();
            packet(&mut f, 1, 8, 4, i32::MAX, 0);
            f
        }),
    ];
    for (what, f) in cases {
        let (r, peak) = peak_heap(|| decode(Dec::Aedat3, &f));
        match r {
            Err(ReadError::Corrupt { offset, message }) => {
                assert_eq!(offset, at, "{what}");
                assert!(message.contains(what), "{what}: {message}");
            }
            other => panic!("{what}: {other:?}"),
        }
        assert!(peak < 4 << 20, "{what}: peak {peak}");
    }
    let mut f = head.clone();
    packet(&mut f, 1, 8, 4, 1, 1);
    aedat3_polarity(&mut f, 1, 1, true, true, -5);
    assert!(error_text(decode(Dec::Aedat3, &f)).contains("negative event timestamp"));
    // Truncated inside a packet: names the packet.
    let mut f = head.clone();
    packet(&mut f, 1, 8, 4, 2, 2);
    aedat3_polarity(&mut f, 1, 1, true, true, 5);
    match decode(Dec::Aedat3, &f) {
        Err(ReadError::Truncated { offset, .. }) => assert_eq!(offset, at),
        other => panic!("{other:?}"),
    }
    // A header without its end line.
    let msg = error_text(decode(
        Dec::Aedat3,
        b"#!AER-DAT3.1\r\n#Format: RAW\r\n\x01\x00",
    ));
    assert!(msg.contains("#!END-HEADER"), "{msg}");
    let msg = error_text(decode(
        Dec::Aedat3,
        b"#!AER-DAT3.1\r\n#Format: SerializedTS\r\n",
    ));
    assert!(msg.contains("only RAW"), "{msg}");
}

// ---------------------------------------------------------------------------------------------
// Prophesee EVT 2.0 / 2.1 / 3.0.

#[test]
fn evt2_decodes_spec_words() {
    let mut f = raw_header(&[
        "camera_integrator_name Prophesee",
        "evt 2.0",
        "format EVT2;height=720;width=1280",
        "geometry 1280x720",
        "end",
    ]);
    let start = f.len() as u64;
    evt2_word(&mut f, evt2_cd(1, 1, true, 0)); // before any TIME_HIGH: dropped
    evt2_word(&mut f, evt2_time_high(1_000_000));
    evt2_word(&mut f, evt2_cd(1279, 719, true, 1_000_000 + 5));
    // By hand: CD_OFF, t low 63, x = 2, y = 3.
    evt2_word(&mut f, (63 << 22) | (2 << 11) | 3);
    evt2_word(&mut f, 0xA000_0001); // EXT_TRIGGER: skipped
                                    // Time high wraps (28 bits): 2^34 µs later the counter starts again.
    evt2_word(&mut f, evt2_time_high((1 << 34) - 64));
    evt2_word(&mut f, evt2_time_high(64));
    evt2_word(&mut f, evt2_cd(4, 5, false, 64 + 1));
    let d = decode(Dec::Evt2, &f).unwrap();
    let base = 1_000_000 / 64 * 64;
    assert_eq!(
        d.events,
        events_of(&[
            ev(0, 1279, 719, base + 5, true),
            ev(0, 2, 3, base + 63, false),
            ev(0, 4, 5, (1 << 34) + 64 + 1, false),
        ])
    );
    assert_eq!(d.notes.dropped_events, 1);
    assert_eq!(d.notes.skipped_records, 1);
    assert_eq!(d.notes.timestamp_wraps, 1);
    let r = EvtReader::new(&f[..], Format::Raw, None).unwrap();
    assert_eq!(r.info().format, Format::Evt2);
    assert_eq!(r.info().cameras[0].width, Some(1280));
    assert_eq!(r.info().cameras[0].height, Some(720));
    assert_eq!(r.info().cameras[0].name.as_deref(), Some("Prophesee"));

    // A reserved type, a pixel outside the sensor, half a word.
    let mut bad = f.clone();
    evt2_word(&mut bad, 0x3000_0000);
    assert_eq!(corrupt_offset(decode(Dec::Evt2, &bad)), start + 8 * 4);
    let mut bad = f.clone();
    evt2_word(&mut bad, evt2_cd(1280, 0, true, 0));
    assert!(error_text(decode(Dec::Evt2, &bad)).contains("outside the 1280x720 sensor"));
    let mut bad = f.clone();
    bad.extend_from_slice(&[1, 2]);
    match decode(Dec::Evt2, &bad) {
        Err(ReadError::Truncated { offset, .. }) => assert_eq!(offset, start + 8 * 4),
        other => panic!("{other:?}"),
    }
}

#[test]
fn evt3_decodes_spec_words() {
    let mut f = raw_header(&["evt 3.0", "format EVT3;height=720;width=1280", "end"]);
    let start = f.len() as u64;
    evt3_word(&mut f, 0x0, 7); // ADDR_Y before any time: sets y
    evt3_word(&mut f, 0x2, 9); // ADDR_X: no time base yet, dropped
    evt3_word(&mut f, 0x8, 0x123); // TIME_HIGH
    evt3_word(&mut f, 0x6, 0x456); // TIME_LOW: t = 0x123456
    evt3_word(&mut f, 0x2, (1 << 11) | 1279); // ON at x = 1279, y = 7
    evt3_word(&mut f, 0x0, 100); // y = 100
    evt3_word(&mut f, 0x3, 40); // VECT_BASE_X 40, OFF
    evt3_word(&mut f, 0x4, 0b1000_0000_0101); // x = 40, 42, 51
    evt3_word(&mut f, 0x5, 0b1000_0001); // base now 52: x = 52, 59
    evt3_word(&mut f, 0xA, 0); // EXT_TRIGGER
    evt3_word(&mut f, 0xE, 0); // OTHERS
    evt3_word(&mut f, 0x7, 0); // CONTINUED_4
    evt3_word(&mut f, 0x8, 0xFFF); // TIME_HIGH 4095
    evt3_word(&mut f, 0x8, 0x001); // wraps (12 bits): + 2^24
    evt3_word(&mut f, 0x6, 0x002);
    evt3_word(&mut f, 0x2, 3); // OFF at x = 3, y = 100
    let d = decode(Dec::Evt3, &f).unwrap();
    let t = 0x123456;
    let wrapped = (1 << 24) + 0x001002;
    assert_eq!(
        d.events,
        events_of(&[
            ev(0, 1279, 7, t, true),
            ev(0, 40, 100, t, false),
            ev(0, 42, 100, t, false),
            ev(0, 51, 100, t, false),
            ev(0, 52, 100, t, false),
            ev(0, 59, 100, t, false),
            ev(0, 3, 100, wrapped, false),
        ])
    );
    assert_eq!(d.notes.dropped_events, 1);
    assert_eq!(d.notes.skipped_records, 3);
    assert_eq!(d.notes.timestamp_wraps, 1);

    // Reserved type 0x1; a vector running past the sensor's edge.
    let mut bad = f.clone();
    evt3_word(&mut bad, 0x1, 0);
    assert_eq!(corrupt_offset(decode(Dec::Evt3, &bad)), start + 16 * 2);
    let mut bad = f.clone();
    evt3_word(&mut bad, 0x3, 1275);
    evt3_word(&mut bad, 0x4, 1 << 5);
    assert!(error_text(decode(Dec::Evt3, &bad)).contains("x = 1280"));
    // Without a size every x up to 65535 is taken; beyond is an error.
    let mut wide = raw_header(&["evt 3.0"]);
    evt3_word(&mut wide, 0x8, 0);
    evt3_word(&mut wide, 0x0, 0);
    evt3_word(&mut wide, 0x3, 2047);
    for _ in 0..5500 {
        evt3_word(&mut wide, 0x4, 0);
    }
    evt3_word(&mut wide, 0x4, 1);
    assert!(error_text(decode(Dec::Evt3, &wide)).contains("16 bits"));
}

/// EVT 3.0 time words as OpenEB decodes them, and the time-low wraps expelliarmus leaves
/// without a time-high word.
#[test]
fn evt3_time_words_follow_openeb() {
    let t = |high: i64, low: i64| (high << 12) | low;
    let times = |f: &[u8]| -> (Vec<i64>, ReadNotes) {
        let d = decode(Dec::Evt3, f).unwrap();
        (d.events.iter().map(|(_, e)| e.t).collect(), d.notes)
    };
    let mut f = raw_header(&["evt 3.0", "geometry 1280x720"]);
    evt3_word(&mut f, 0x8, 5);
    evt3_word(&mut f, 0x0, 1);
    evt3_word(&mut f, 0x6, 0x700);
    evt3_word(&mut f, 0x2, 1); // t = 5 << 12 | 0x700
    evt3_word(&mut f, 0x6, 0x6F5); // a time low below the one before is taken as given
    evt3_word(&mut f, 0x2, 2);
    evt3_word(&mut f, 0x8, 5); // the same time high again keeps the time low
    evt3_word(&mut f, 0x2, 3);
    evt3_word(&mut f, 0x8, 6); // a new period starts at time low 0
    evt3_word(&mut f, 0x2, 4);
    evt3_word(&mut f, 0x6, 0xFF0);
    evt3_word(&mut f, 0x2, 5);
    evt3_word(&mut f, 0x6, 0x010); // back by more than 0x800 after several time highs: as given
    evt3_word(&mut f, 0x2, 6);
    let (got, notes) = times(&f);
    let want = [
        t(5, 0x700),
        t(5, 0x6F5),
        t(5, 0x6F5),
        t(6, 0),
        t(6, 0xFF0),
        t(6, 0x010),
    ];
    assert_eq!(got, want);
    assert_eq!(notes.implied_time_highs, 0);

    // One time-high word in the file (expelliarmus): a time low back by more than 0x800
    // starts the next period, across the 12-bit time high's wrap too; a smaller step back is
    // taken as given; a later time-high word for the implied period keeps the time.
    let mut f = raw_header(&["evt 3.0", "geometry 1280x720"]);
    evt3_word(&mut f, 0x8, 0xFFE);
    evt3_word(&mut f, 0x0, 1);
    evt3_word(&mut f, 0x6, 0xFF0);
    evt3_word(&mut f, 0x2, 1);
    evt3_word(&mut f, 0x6, 0x010);
    evt3_word(&mut f, 0x2, 2);
    evt3_word(&mut f, 0x6, 0x7FF);
    evt3_word(&mut f, 0x6, 0x000); // back by 0x7FF only: as given
    evt3_word(&mut f, 0x2, 3);
    evt3_word(&mut f, 0x6, 0xF00);
    evt3_word(&mut f, 0x2, 4);
    evt3_word(&mut f, 0x6, 0x005); // the next period: time high 0x1000, wrapped
    evt3_word(&mut f, 0x2, 5);
    evt3_word(&mut f, 0x8, 0x000);
    evt3_word(&mut f, 0x2, 6);
    let (got, notes) = times(&f);
    let want = [
        t(0xFFE, 0xFF0),
        t(0xFFF, 0x010),
        t(0xFFF, 0),
        t(0xFFF, 0xF00),
        t(0x1000, 0x005),
        t(0x1000, 0x005),
    ];
    assert_eq!(got, want);
    assert_eq!(notes.implied_time_highs, 2);
    assert_eq!(notes.timestamp_wraps, 1);
}

/// The EVT 3.0 writer, read back: long gaps (more than half the time high's range, and its
/// wrap), small steps back, rows, both polarities, the corners; a late origin; what it refuses.
#[test]
fn evt3_writer_round_trips() {
    use evpose_host::io::evt::Evt3Writer;
    let mut events: Vec<Event> = synthetic(3000, 1280, 720, 1, 0)
        .iter()
        .map(|e| Event::new(e.x, e.y, e.t, e.on))
        .collect();
    // Gaps of 9 s and 40 s, a step back of 3 ms, the sensor's corners at one time.
    events[1000].t += 9_000_000;
    for e in &mut events[1001..] {
        e.t += 9_000_000;
    }
    for e in &mut events[2000..] {
        e.t += 40_000_000;
    }
    events[2500].t -= 3_000;
    let last = events[2999].t;
    events.push(Event::new(0, 0, last, true));
    events.push(Event::new(1279, 719, last, false));
    let write = |events: &[Event]| {
        let mut w = Evt3Writer::new(Vec::new(), 1280, 720).unwrap();
        w.write(events).map(|()| w.finish().unwrap())
    };
    let d = decode(Dec::Evt3, &write(&events).unwrap()).unwrap();
    let got: Vec<Event> = d.events.iter().map(|(_, e)| *e).collect();
    assert_eq!(got, events);
    assert_eq!(d.notes.implied_time_highs, 0);
    assert_eq!(d.notes.timestamp_wraps, 2);
    // A Unix-time recording keeps its times' low 24 bits (from the 2^24-µs boundary before its
    // first event), so an event a little before the first is written too.
    let unix = 1_589_163_147_368_868;
    let origin = unix - unix % (1 << 24);
    let late: Vec<Event> = [
        Event::new(1, 2, unix + 7, true),
        Event::new(3, 4, unix, false),
    ]
    .into_iter()
    .chain(
        events
            .iter()
            .map(|e| Event::new(e.x, e.y, e.t + unix, e.on)),
    )
    .collect();
    let mut w = Evt3Writer::new(Vec::new(), 1280, 720).unwrap();
    w.write(&late).unwrap();
    assert_eq!(w.origin(), Some(origin));
    let d = decode(Dec::Evt3, &w.finish().unwrap()).unwrap();
    let got: Vec<i64> = d.events.iter().map(|(_, e)| e.t + origin).collect();
    let want: Vec<i64> = late.iter().map(|e| e.t).collect();
    assert_eq!(got, want);
    // Refused: a pixel outside, a step back of more than 2,047 periods or across a 2^24-µs
    // boundary, a time before the origin, a gap of more than 2^24 periods.
    let bad = |e: &[Event]| write(e).unwrap_err().to_string();
    assert!(bad(&[Event::new(1280, 0, 0, true)]).contains("outside"));
    let back = [Event::new(0, 0, 9_000_000, true), Event::new(0, 0, 0, true)];
    assert!(bad(&back).contains("goes back"));
    let across = [
        Event::new(0, 0, 0, true),
        Event::new(0, 0, (1 << 24) + 100, true),
        Event::new(0, 0, (1 << 24) - 9, true),
    ];
    assert!(bad(&across).contains("goes back"));
    assert!(bad(&[Event::new(0, 0, 1 << 30, true), Event::new(0, 0, 0, true)]).contains("from"));
    let gap = [Event::new(0, 0, 0, true), Event::new(0, 0, 1 << 37, true)];
    assert!(bad(&gap).contains("gaps over"));
    assert!(Evt3Writer::new(Vec::new(), 4096, 10).is_err());
}

/// EVT 2.0 and EVT 2.1 (both byte orders) written by `Evt2Writer` read back as the events
/// given (times kept, the first lying in [0, 2^32) µs): gaps, a step back, rows of events
/// at one time (EVT 2.1 vectors), the counter's wrap on the way; and the refusals.
#[test]
fn evt2_and_evt21_writers_round_trip() {
    use evpose_host::io::evt::{Encoding, Evt2Writer};
    let mut events: Vec<Event> = synthetic(3000, 1280, 720, 1, 0)
        .iter()
        .map(|e| Event::new(e.x, e.y, e.t, e.on))
        .collect();
    // A gap of 9 s, a step back of 3 ms; a row of events at one time, left to right (one
    // vector word in EVT 2.1, 40 columns: two words), then a step left (a new word).
    for e in &mut events[1001..] {
        e.t += 9_000_000;
    }
    events[2500].t -= 3_000;
    let last = events[2999].t;
    events.extend((0..40).map(|i| Event::new(100 + i, 7, last, true)));
    events.push(Event::new(101, 7, last, true));
    // The polarity flips within the row; an event twice.
    events
        .extend([(102, false), (103, true), (103, true)].map(|(x, on)| Event::new(x, 7, last, on)));
    // Across the 2^34-µs wrap of the time-high counter, in steps under 2^33 µs.
    events.extend((1..4).map(|i| Event::new(9, 9, i << 32, true)));
    // The last events before the wrap lie 15 periods before it, the first after it 15 periods
    // into the next: the writer steps the counter through its last value and 0 on the way.
    let wrap = 1i64 << 34;
    let around = (0..50).map(|i| wrap - 1000 + if i < 25 { 4 * i } else { 2000 + 4 * i });
    events.extend(around.zip(0u16..).map(|(t, x)| Event::new(x, 3, t, false)));
    let write = |enc: Encoding, events: &[Event]| {
        let mut w = Evt2Writer::new(Vec::new(), enc, 1280, 720).unwrap();
        w.write(events).map(|()| w.finish().unwrap())
    };
    for (enc, format) in [
        (Encoding::Evt2, Format::Evt2),
        (Encoding::Evt21, Format::Evt21),
        (Encoding::Evt21Legacy, Format::Evt21Legacy),
    ] {
        let bytes = write(enc, &events).unwrap();
        let r = EvtReader::new(&bytes[..], Format::Raw, None).unwrap();
        assert_eq!(r.info().format, format);
        let d = drain(r).unwrap();
        let got: Vec<Event> = d.events.iter().map(|(_, e)| *e).collect();
        assert_eq!(got, events, "{enc:?}");
        assert_eq!(d.notes.timestamp_wraps, 1, "{enc:?}");
        assert!(d.notes.assumptions.is_empty(), "{:?}", d.notes.assumptions);
        // The wrap as a sensor's counter steps: its last value, then 0 (OpenEB counts only
        // that step back as a wrap).
        if enc == Encoding::Evt2 {
            let body = &bytes[bytes.windows(6).position(|w| w == b"% end\n").unwrap() + 6..];
            let highs: Vec<u32> = body
                .chunks_exact(4)
                .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
                .filter(|w| w >> 28 == 0x8)
                .collect();
            assert!(
                highs.windows(2).any(|w| w == [0x8FFF_FFFF, 0x8000_0000]),
                "no 0xFFFFFFF, 0 time highs"
            );
        }
    }
    // EVT 2.1 takes a row at one time in fewer words than EVT 2.0 (8 and 4 bytes a word).
    let row: Vec<Event> = (0..64).map(|i| Event::new(i, 5, 1_000, true)).collect();
    let (w2, w21) = (
        write(Encoding::Evt2, &row).unwrap(),
        write(Encoding::Evt21, &row).unwrap(),
    );
    let header = |b: &[u8]| b.windows(6).position(|w| w == b"% end\n").unwrap() + 6;
    assert_eq!(w2.len() - header(&w2), 4 * (1 + 64));
    assert_eq!(w21.len() - header(&w21), 8 * (1 + 2));
    // A Unix-time recording: times from the 64-µs boundary about a second before the first, so
    // that an event a little before it is written too, and the counter does not wrap.
    let unix = 1_589_163_147_368_868;
    let dv: Vec<Event> = [0, -500_000, 3_600_000_000]
        .map(|d| Event::new(1, 1, unix + d, true))
        .to_vec();
    let mut w = Evt2Writer::new(Vec::new(), Encoding::Evt2, 1280, 720).unwrap();
    w.write(&dv).unwrap();
    let origin = w.origin().unwrap();
    assert!(
        origin % 64 == 0 && (unix - origin - (1 << 20)).abs() < 64,
        "{origin}"
    );
    let d = decode(Dec::Evt2, &w.finish().unwrap()).unwrap();
    let got: Vec<i64> = d.events.iter().map(|(_, e)| e.t + origin).collect();
    assert_eq!(got, dv.iter().map(|e| e.t).collect::<Vec<_>>());
    assert_eq!(d.notes.timestamp_wraps, 0);
    // Refused: a pixel outside, a step back across the counter's wrap or of 2^27 periods, a
    // step forward of 2^27 periods, EVT 3.0, a sensor over 2048.
    let bad = |e: &[Event]| write(Encoding::Evt21, e).unwrap_err().to_string();
    assert!(bad(&[Event::new(1280, 0, 0, true)]).contains("outside"));
    let mut across: Vec<Event> = (0..4).map(|i| Event::new(0, 0, i << 32, true)).collect();
    across.extend([(1 << 34) + 5, (1 << 34) - 5].map(|t| Event::new(0, 0, t, true)));
    assert!(bad(&across).contains("goes back"));
    let far =
        [0, 1 << 32, (1 << 33) + (1 << 31), (1 << 31) - 1000].map(|t| Event::new(0, 0, t, true));
    assert!(bad(&far).contains("or more before"));
    let gap = [Event::new(0, 0, 0, true), Event::new(0, 0, 1 << 33, true)];
    assert!(bad(&gap).contains("2^33"));
    assert!(Evt2Writer::new(Vec::new(), Encoding::Evt3, 10, 10).is_err());
    let wide = Evt2Writer::new(Vec::new(), Encoding::Evt2, 4096, 10)
        .err()
        .unwrap();
    assert!(
        wide.to_string()
            .contains("EVT words hold sensors up to 2048"),
        "{wide}"
    );
}

/// The size a header without `% format` or `% geometry` implies through `% system_ID`, as
/// OpenEB's `check_header` decides whose table applies.
#[test]
fn raw_sizes_from_system_id_follow_openeb() {
    let size = |lines: &[&str]| {
        let mut f = raw_header(lines);
        evt3_word(&mut f, 0x8, 0);
        let r = EvtReader::new(&f[..], Format::Raw, None).unwrap();
        let c = &r.info().cameras[0];
        c.width.zip(c.height)
    };
    let hd = Some((1280, 720));
    let vga = Some((640, 480));
    assert_eq!(size(&["evt 3.0", "system_ID 48"]), hd); // no integrator: Prophesee
    assert_eq!(
        size(&["evt 2.0", "integrator_name Prophesee", "system_ID 21"]),
        vga
    );
    assert_eq!(
        size(&["evt 3.0", "integrator_name Foo", "system_ID 48"]),
        None
    );
    // The legacy name counts only when neither newer one is given.
    let both = [
        "camera_integrator_name Prophesee",
        "plugin_integrator_name Prophesee",
    ];
    assert_eq!(
        size(&[
            "evt 3.0",
            "integrator_name Foo",
            both[0],
            both[1],
            "system_ID 49"
        ]),
        hd
    );
    assert_eq!(size(&["evt 3.0", both[0], "system_ID 48"]), None);
    assert_eq!(size(&["evt 3.0", "system_ID 20"]), None); // not in the table
                                                          // A stated size wins; so do --width/--height.
    assert_eq!(
        size(&["evt 3.0", "geometry 320x320", "system_ID 48"]),
        Some((320, 320))
    );
    let mut f = raw_header(&["evt 3.0", "system_ID 48"]);
    evt3_word(&mut f, 0x8, 0);
    let r = EvtReader::new(&f[..], Format::Raw, Some((346, 260))).unwrap();
    assert_eq!(r.info().cameras[0].width, Some(346));
}

/// After a second time-high word, time lows are taken as given (OpenEB), not as implied
/// periods: a file with time-high words is not an expelliarmus file.
#[test]
fn evt3_implies_periods_only_before_a_second_time_high() {
    let mut f = raw_header(&["evt 3.0", "geometry 1280x720"]);
    evt3_word(&mut f, 0x8, 5);
    evt3_word(&mut f, 0x8, 5);
    evt3_word(&mut f, 0x0, 1);
    evt3_word(&mut f, 0x6, 3000);
    evt3_word(&mut f, 0x2, 1);
    evt3_word(&mut f, 0x6, 100);
    evt3_word(&mut f, 0x2, 2);
    let d = decode(Dec::Evt3, &f).unwrap();
    let times: Vec<i64> = d.events.iter().map(|(_, e)| e.t).collect();
    assert_eq!(times, [(5 << 12) + 3000, (5 << 12) + 100]);
    assert_eq!(d.notes.implied_time_highs, 0);
}

#[test]
fn evt_round_trips_and_batches() {
    let events = synthetic(200_000, 1280, 720, 1, 0);
    for (dec, body) in [
        (Dec::Evt2, evt2_body(&events)),
        (Dec::Evt21, evt21_body(&events)),
        (Dec::Evt3, evt3_body(&events)),
    ] {
        let mut f = raw_header(&["format EVT3;height=720;width=1280"]);
        f.extend_from_slice(&body);
        let d = decode(dec, &f).unwrap();
        assert_eq!(d.events, events_of(&events), "{dec:?}");
        assert!(d.batches.len() >= 3);
    }
}

#[test]
fn raw_header_encoding_and_size() {
    let mut f = raw_header(&["evt 2.0"]);
    evt2_word(&mut f, evt2_time_high(0));
    evt2_word(&mut f, evt2_cd(5, 6, true, 0));
    // No size in the header: the fallback is used, and checked.
    let r = EvtReader::new(&f[..], Format::Raw, Some((640, 480))).unwrap();
    assert_eq!(r.info().cameras[0].width, Some(640));
    assert!(drain(r).unwrap().notes.assumptions[0].contains("640x480"));
    assert!(decode_sized(Dec::Evt2, &f, Some((5, 5))).is_err());
    // No encoding named: RAW asks for --format; an unknown one is refused; --format overrides.
    let anon = [
        &raw_header(&["date 2020"])[..],
        &f[raw_header(&["evt 2.0"]).len()..],
    ]
    .concat();
    let msg = EvtReader::new(&anon[..], Format::Raw, None)
        .err()
        .unwrap()
        .to_string();
    assert!(msg.contains("--format evt2"), "{msg}");
    assert!(EvtReader::new(&raw_header(&["evt 4.0"])[..], Format::Raw, None).is_err());
    let d = drain(EvtReader::new(&f[..], Format::Evt3, None).unwrap());
    // EVT 2.0 words read as EVT 3.0 are garbage, but the override is on record (or it fails).
    if let Ok(d) = d {
        assert!(d.notes.assumptions[0].contains("overrides"));
    }
}

/// EVT 2.1's byte order from the header, as OpenEB decides it: the `endianness=` option of
/// `% format`, else an `% endianness` line, else `legacy` (upper halves first) for a Prophesee
/// camera whose `system_ID` is below 0x37, else whole little-endian words; a note says which
/// when the header did not.
#[test]
fn evt21_byte_order_follows_openeb() {
    let order = |lines: &[&str], format: Format| {
        let header = raw_header(lines);
        let r = EvtReader::new(&header[..], format, None).unwrap();
        let f = r.info().format;
        (f, drain(r).unwrap().notes.assumptions.join("; "))
    };
    let stated = order(
        &["format EVT21;endianness=legacy;height=720;width=1280"],
        Format::Raw,
    );
    assert_eq!(stated, (Format::Evt21Legacy, String::new()));
    let both = ["format EVT21;endianness=little", "endianness legacy"];
    assert_eq!(order(&both, Format::Raw).0, Format::Evt21);
    let line = ["format EVT21", "endianness legacy"];
    assert_eq!(order(&line, Format::Raw).0, Format::Evt21Legacy);
    // OpenEB's rule for a header that states none: IMX636 (system_ID 49) and no integrator
    // line (Prophesee) read `legacy`; another integrator, or a later system, whole words.
    let (f, n) = order(&["evt 2.1", "system_ID 49"], Format::Raw);
    assert_eq!(f, Format::Evt21Legacy);
    assert!(
        n.contains("system_ID 49") && n.contains("--format evt21"),
        "{n}"
    );
    let other = ["evt 2.1", "camera_integrator_name Foo", "system_ID 49"];
    let (f, n) = order(&other, Format::Raw);
    assert_eq!(f, Format::Evt21);
    assert!(
        n.contains("GenX320") && n.contains("--format evt21-legacy"),
        "{n}"
    );
    assert_eq!(
        order(&["format EVT21", "system_ID 64"], Format::Raw).0,
        Format::Evt21
    );
    // OpenEB's `get_system_id`: -1 when missing (legacy for a Prophesee header), the leading
    // digits of `49abc`, 0 for `0x31` (whole words).
    let (f, n) = order(&["format EVT21"], Format::Raw);
    assert_eq!(f, Format::Evt21Legacy);
    assert!(n.contains("without a `% system_ID`"), "{n}");
    assert_eq!(
        order(&["format EVT21", "system_ID 49abc"], Format::Raw).0,
        Format::Evt21Legacy
    );
    assert_eq!(
        order(&["format EVT21", "system_ID 0x31"], Format::Raw).0,
        Format::Evt21
    );
    // As OpenEB compares them: exactly `legacy`; the last option; an option without `=` is
    // empty (whole words); an empty `% endianness` line is no statement.
    assert_eq!(
        order(&["format EVT21;endianness=Legacy"], Format::Raw).0,
        Format::Evt21
    );
    let last = ["format EVT21;endianness=little;endianness=legacy"];
    assert_eq!(order(&last, Format::Raw).0, Format::Evt21Legacy);
    let bare = ["format EVT21;endianness", "system_ID 49"];
    let (f, n) = order(&bare, Format::Raw);
    assert!(f == Format::Evt21 && !n.contains("EVT 2.1"), "{n}");
    let empty = ["format EVT21", "endianness", "system_ID 49"];
    assert_eq!(order(&empty, Format::Raw).0, Format::Evt21Legacy);
    // --format overrides, on record.
    let (f, n) = order(&["format EVT21;endianness=legacy"], Format::Evt21);
    assert_eq!(f, Format::Evt21);
    assert!(n.contains("overrides") && n.contains("evt21-legacy"), "{n}");
    // A reserved type is an error that shows the whole word.
    let mut f = raw_header(&["format EVT21;endianness=little;width=64;height=64"]);
    let start = f.len() as u64;
    f.extend_from_slice(&(0x3000_0005_0000_00FFu64).to_le_bytes());
    let read = || drain(EvtReader::new(&f[..], Format::Raw, None).unwrap());
    assert_eq!(corrupt_offset(read()), start);
    let msg = error_text(read());
    assert!(
        msg.contains("0x30000005000000ff") && msg.contains("reserved type 0x3"),
        "{msg}"
    );
    // A GenX320's word read in the assumed IMX636 order (a Prophesee header without a byte
    // order or system_ID) has its mask's bits as type: the error names the other order.
    let mut f = raw_header(&["format EVT21;width=64;height=64"]);
    f.extend_from_slice(&(0x8000_0001_4000_0000u64).to_le_bytes());
    let msg = error_text(drain(EvtReader::new(&f[..], Format::Raw, None).unwrap()));
    assert!(msg.contains("try --format evt21"), "{msg}");
}

// ---------------------------------------------------------------------------------------------
// Prophesee .dat.

#[test]
fn dat_decodes_records() {
    let events = [ev(0, 1279, 719, 10, true), ev(0, 0, 0, 11, false)];
    let mut f = dat_file(&events, 1280, 720);
    let start = dat_file(&[], 1280, 720).len() as u64;
    // By hand: t = 12, x = 7, y = 8, polarity 1.
    dat_record(&mut f, 12, 7 | (8 << 14) | (1 << 28));
    // Wrap of the 32-bit time.
    dat_record(&mut f, u32::MAX, 0);
    dat_record(&mut f, 3, 0);
    let d = decode(Dec::Dat, &f).unwrap();
    let w = 1i64 << 32;
    assert_eq!(
        d.events,
        events_of(&[
            events[0],
            events[1],
            ev(0, 7, 8, 12, true),
            ev(0, 0, 0, w - 1, false),
            ev(0, 0, 0, w + 3, false)
        ])
    );
    assert_eq!(d.notes.timestamp_wraps, 1);
    let r = DatReader::new(&f[..], None).unwrap();
    assert_eq!(r.info().cameras[0].width, Some(1280));

    let mut bad = f.clone();
    dat_record(&mut bad, 13, 2 << 28);
    assert_eq!(corrupt_offset(decode(Dec::Dat, &bad)), start + 5 * 8);
    let mut bad = f.clone();
    dat_record(&mut bad, 13, 720 << 14);
    assert!(error_text(decode(Dec::Dat, &bad)).contains("outside"));
    let trig = [&f[..start as usize - 2], &[0x0E, 8][..]].concat();
    assert!(error_text(decode(Dec::Dat, &trig)).contains("external-trigger"));
    let size16 = [&f[..start as usize - 2], &[0x0C, 16][..]].concat();
    assert!(error_text(decode(Dec::Dat, &size16)).contains("event size 16"));
    let v0 = b"% Version 0\n\x00\x08".to_vec();
    assert!(error_text(decode(Dec::Dat, &v0)).contains("version"));
    // Version 1: 9-bit x, 8-bit y, polarity in bit 17 (bits 18-31 ignored, as Prophesee's
    // readATIS_td does).
    let mut v1 = b"% Version 1\n% Width 304\n% Height 240\n\x0c\x08".to_vec();
    dat_record(&mut v1, 5, 303 | (239 << 9) | (1 << 17) | (0x3FFF << 18));
    dat_record(&mut v1, 6, 2 | (3 << 9) | (1 << 18));
    let d = decode(Dec::Dat, &v1).unwrap();
    assert_eq!(
        d.events,
        events_of(&[ev(0, 303, 239, 5, true), ev(0, 2, 3, 6, false)])
    );
    dat_record(&mut v1, 7, 304);
    assert!(error_text(decode(Dec::Dat, &v1)).contains("outside"));
    // No header: records from the first byte.
    let body = &f[start as usize..];
    let d = decode(Dec::Dat, body).unwrap();
    assert_eq!(d.events.len(), 5);
    assert!(d.notes.assumptions[0].contains("no header"));
}

// ---------------------------------------------------------------------------------------------
// Event Stream.

#[test]
fn es_decodes_spec_bytes() {
    // DVS: reset bytes, overflows (127 us each), rows from the bottom.
    let mut f = es_dvs_file(&[], 320, 240);
    let start = f.len() as u64;
    f.extend_from_slice(&[0xFE, 0xFE]);
    f.extend_from_slice(&[(5 << 1) | 1, 7, 0, 0, 0]); // t = 5, x = 7, y_file = 0: ON, y = 239
    f.extend_from_slice(&[0xFF, 0xFF, 3 << 1, 63, 1, 239, 0]); // t = 5 + 254 + 3, x = 319, y = 0
    let d = decode(Dec::Es, &f).unwrap();
    assert_eq!(
        d.events,
        events_of(&[ev(0, 7, 239, 5, true), ev(0, 319, 0, 262, false)])
    );
    let r = EsReader::new(&f[..]).unwrap();
    assert_eq!(r.info().cameras[0].width, Some(320));
    assert_eq!(r.info().format, Format::Es);
    // A pixel outside; a cut event; other versions and stream types.
    let mut bad = f.clone();
    bad.extend_from_slice(&[0, 64, 1, 0, 0]);
    assert_eq!(corrupt_offset(decode(Dec::Es, &bad)), start + 14);
    assert!(error_text(decode(Dec::Es, &f[..f.len() - 1])).contains("Event Stream event"));
    let mut v1 = f.clone();
    v1[12] = 1;
    assert!(error_text(decode(Dec::Es, &v1)).contains("version 1.0.0"));
    let mut color = f.clone();
    color[15] = 4;
    assert!(error_text(decode(Dec::Es, &color)).contains("color"));
    let mut empty = f.clone();
    empty[16] = 0;
    empty[17] = 0;
    assert!(error_text(decode(Dec::Es, &empty)).contains("sensor size 0"));

    // ATIS (type 2): bits 2-7 time, bit 1 polarity, bit 0 threshold crossing (skipped);
    // overflow bytes add 63 us times their two low bits (0xFC resets).
    let mut a = f[..HEADER].to_vec();
    a[15] = 2;
    a.extend_from_slice(&[0xFC, (4 << 2) | 2, 1, 0, 2, 0]); // t = 4, ON, x = 1, y = 237
    a.extend_from_slice(&[0xFE, (1 << 2) | 1, 1, 0, 2, 0]); // t = 4 + 126 + 1: a crossing
    a.extend_from_slice(&[0xFD, 0, 9, 0, 0, 0]); // t = 131 + 63: OFF at x = 9, y = 239
    let d = decode(Dec::Es, &a).unwrap();
    assert_eq!(
        d.events,
        events_of(&[ev(0, 1, 237, 4, true), ev(0, 9, 239, 194, false)])
    );
    assert_eq!(d.notes.skipped_records, 1);
}

/// Bytes of an Event Stream header.
const HEADER: usize = 20;

// ---------------------------------------------------------------------------------------------
// Text.

fn text(bytes: &[u8], unit: Option<TimeUnit>) -> Result<Decoded, ReadError> {
    drain(TextReader::new(bytes, unit, None)?)
}

#[test]
fn text_layouts_and_units() {
    // RPG layout, seconds detected from the decimal point; comments; CRLF; no final newline.
    let rpg = b"# events.txt\r\n0.000000000 33 39 1\r\n\r\n1589163147.368868 1 2 0\r\n1e-6 3 4 -1";
    let d = text(rpg, None).unwrap();
    assert_eq!(
        d.events,
        events_of(&[
            ev(0, 33, 39, 0, true),
            ev(0, 1, 2, 1_589_163_147_368_868, false),
            ev(0, 3, 4, 1, false),
        ])
    );
    assert!(d.notes.assumptions[0].contains("timestamps in s"));
    // Integer timestamps: microseconds.
    let d = text(b"100 1 2 1\n101 3 4 0\n", None).unwrap();
    assert_eq!(d.events[1].1, Event::new(3, 4, 101, false));
    assert!(d.notes.assumptions[0].contains("timestamps in us"));
    // ... unless --time-unit says otherwise.
    let d = text(b"100 1 2 1\n", Some(TimeUnit::Ms)).unwrap();
    assert_eq!(d.events[0].1.t, 100_000);
    let d = text(b"1500 1 2 1\n", Some(TimeUnit::Ns)).unwrap();
    assert_eq!(d.events[0].1.t, 2, "rounded half away from zero");
    // A header row: any column order, extra columns, a unit suffix, CSV with a BOM.
    let csv = b"\xEF\xBB\xBFx,y,polarity,t_ms,extra\n5,6,1,2.5,x9\n7, 8 ,0,3,x\n";
    let d = text(csv, None).unwrap();
    assert_eq!(
        d.events,
        events_of(&[ev(0, 5, 6, 2_500, true), ev(0, 7, 8, 3_000, false)])
    );
    assert!(d.notes.assumptions.iter().any(|a| a.contains("header row")));
}

/// An (20, 4) npy of the layout events, one row each as `row` lays it out.
fn layout_npy(dir: &Path, name: &str, row: impl Fn(&LayoutEvent) -> [f64; 4]) -> PathBuf {
    let path = dir.join(name);
    let rows: Vec<f64> = layout_events().iter().flat_map(row).collect();
    evpose_host::array::write(&path, &[20, 4], &rows).unwrap();
    path
}

/// One event of the layout tests: x, y, t (µs), p.
type LayoutEvent = (u16, u16, i64, bool);

/// The twenty events the layout tests write: t increasing, x and y scattered.
fn layout_events() -> Vec<LayoutEvent> {
    (0..20)
        .map(|i| {
            (
                (113 + 211 * i) % 346,
                (155 + 101 * i) % 260,
                223 + 2_500 * i as i64,
                i % 3 == 0,
            )
        })
        .map(|(x, y, t, p)| (x as u16, y as u16, t, p))
        .collect()
}

fn layout_expected() -> Vec<(u8, Event)> {
    layout_events()
        .into_iter()
        .map(|(x, y, t, p)| (0, Event::new(x, y, t, p)))
        .collect()
}

/// Text as NumPy and pandas write it: whole microseconds written as floats are microseconds,
/// and NumPy's commented header row names the columns.
#[test]
fn text_written_by_numpy_and_pandas_reads_as_written() {
    let want = layout_expected();
    let lines = |f: &dyn Fn(&LayoutEvent) -> String| -> Vec<u8> {
        layout_events()
            .iter()
            .map(f)
            .collect::<String>()
            .into_bytes()
    };
    // np.savetxt's default format: "%.18e" for every value.
    let sci = lines(&|&(x, y, t, p)| {
        format!(
            "{:.18e} {:.18e} {:.18e} {:.18e}\n",
            t as f64,
            x as f64,
            y as f64,
            u8::from(p) as f64
        )
    });
    let d = text(&sci, None).unwrap();
    assert_eq!(d.events, want);
    assert!(
        d.notes.assumptions[0].contains("timestamps in us"),
        "{:?}",
        d.notes
    );
    // A float column of whole microseconds under a header row (pandas).
    let csv = [
        b"t,x,y,p\n".to_vec(),
        lines(&|&(x, y, t, p)| format!("{}.0,{x},{y},{}\n", t, u8::from(p))),
    ]
    .concat();
    assert_eq!(text(&csv, None).unwrap().events, want);
    // np.savetxt(header="x y t p") writes "# x y t p": a header, not a comment.
    let commented = [
        b"# x y t p\n".to_vec(),
        lines(&|&(x, y, t, p)| format!("{x} {y} {t} {}\n", u8::from(p))),
    ]
    .concat();
    let d = text(&commented, None).unwrap();
    assert_eq!(d.events, want);
    assert!(d
        .notes
        .assumptions
        .iter()
        .any(|a| a.contains("commented header row")));
    // A unit in UTF-8 in the header row is detected as text (it was refused as binary).
    let micro = "t[µs],x,y,p\n223,113,155,0\n".as_bytes();
    assert!(evpose_host::io::text::looks_like_text(micro));
    assert!(!evpose_host::io::text::looks_like_text(
        b"t,x,y,p\n223,113,\x01155,0\n"
    ));
    // e2vid's events.txt: a first line "W H" is the sensor size; pandas' boolean polarity.
    let e2vid = [
        b"346 260\n".to_vec(),
        lines(&|&(x, y, t, p)| {
            format!(
                "{:.6} {x} {y} {}\n",
                t as f64 * 1e-6,
                if p { "True" } else { "False" }
            )
        }),
    ]
    .concat();
    assert!(evpose_host::io::text::looks_like_text(&e2vid));
    let r = TextReader::new(&e2vid[..], None, None).unwrap();
    assert_eq!(r.info().cameras[0].width, Some(346));
    assert_eq!(r.info().cameras[0].height, Some(260));
    assert_eq!(drain(r).unwrap().events, want);
    // Seconds with fractions are still seconds.
    let seconds =
        lines(&|&(x, y, t, p)| format!("{:.6} {x} {y} {}\n", t as f64 * 1e-6, u8::from(p)));
    assert_eq!(text(&seconds, None).unwrap().events, want);
}

/// Columns in another order than the format assumes make a pixel coordinate the time, which
/// then mostly goes backwards: refused, where it was read.
#[test]
fn columns_in_another_order_are_refused_not_misread() {
    // Text without a header is `t x y p`; these lines are `x y t p`.
    let xytp: Vec<u8> = layout_events()
        .iter()
        .map(|&(x, y, t, p)| format!("{x} {y} {t} {}\n", u8::from(p)))
        .collect::<String>()
        .into_bytes();
    let msg = error_text(text(&xytp, None));
    assert!(
        msg.contains("timestamps go backwards") && msg.contains("t x y p"),
        "{msg}"
    );
    // An npy array is [x, y, t_us, p]; this one is [t, x, y, p] (every t below 65536).
    let dir = tempfile::tempdir().unwrap();
    let path = layout_npy(dir.path(), "txyp.npy", |&(x, y, t, p)| {
        [t as f64, f64::from(x), f64::from(y), f64::from(u8::from(p))]
    });
    let mut r = open(&path, None).unwrap();
    let msg = evpose_host::io::read_all(&mut *r).unwrap_err().to_string();
    assert!(
        msg.contains("timestamps go backwards") && msg.contains("[x, y, t_us, p]"),
        "{msg}"
    );
}

/// `.npy` times are whole microseconds unless `--time-unit` says otherwise: times in seconds
/// were rounded to 0 µs.
#[test]
fn npy_times_are_whole_microseconds_or_a_stated_unit() {
    let dir = tempfile::tempdir().unwrap();
    let path = layout_npy(dir.path(), "seconds.npy", |&(x, y, t, p)| {
        [
            f64::from(x),
            f64::from(y),
            t as f64 * 1e-6,
            f64::from(u8::from(p)),
        ]
    });
    let mut r = open(&path, None).unwrap();
    let msg = evpose_host::io::read_all(&mut *r).unwrap_err().to_string();
    assert!(
        msg.contains("not a whole number of microseconds") && msg.contains("--time-unit"),
        "{msg}"
    );
    let opts = OpenOptions {
        time_unit: Some(TimeUnit::S),
        ..OpenOptions::default()
    };
    let mut r = open_with(&path, &opts).unwrap();
    assert_eq!(
        evpose_host::io::read_all(&mut *r).unwrap(),
        layout_expected()
    );
}

/// faery's CSV header names the sensor size in the coordinates' columns.
#[test]
fn text_header_sizes() {
    let read = |bytes: &[u8]| drain(TextReader::new(bytes, None, None)?);
    let r = TextReader::new(&b"t,x@346,y@260,on\n5,345,259,1\n"[..], None, None).unwrap();
    assert_eq!(r.info().cameras[0].width, Some(346));
    assert_eq!(r.info().cameras[0].height, Some(260));
    let d = read(b"t,x@346,y@260,on\n5,345,259,1\n").unwrap();
    assert_eq!(d.events, events_of(&[ev(0, 345, 259, 5, true)]));
    assert!(error_text(read(b"t,x@346,y@260,on\n5,346,0,1\n")).contains("outside"));
    // A bad size is an error naming the column; one size alone is noted and not used.
    assert!(error_text(read(b"t,x@0,y@260,on\n5,1,2,1\n")).contains("`x@0`"));
    let d = read(b"t,x@346,y,on\n2,400,4,0\n").unwrap();
    assert_eq!(d.events, events_of(&[ev(0, 400, 4, 2, false)]));
    assert!(
        d.notes
            .assumptions
            .iter()
            .any(|n| n.contains("only the sensor's width")),
        "{:?}",
        d.notes.assumptions
    );
}

#[test]
fn text_damage_names_the_line() {
    // Integer microseconds detected from the first 1000 lines; a fraction after them.
    let late = [b"1 2 3 1\n".repeat(1000), b"2.5 3 4 1\n".to_vec()].concat();
    let msg = error_text(text(&late, None));
    assert!(
        msg.contains("line 1001") && msg.contains("fraction of a microsecond"),
        "{msg}"
    );
    let cases: [(&[u8], &str); 7] = [
        (b"1 2 3 1\n2 3 4\n", "line 2: 3 fields"),
        (b"1 2 3 1\n2 3 4 5\n", "line 2: polarity"),
        (b"1,2,,1\n", "empty field"),
        (b"1 -2 3 1\n", "x \"-2\""),
        (b"1 2 70000 1\n", "y \"70000\""),
        (b"99999999999999999999 2 3 1\n", "timestamp"),
        (b"t,x,y\n1,2,3\n", "t, x, y and p"),
    ];
    for (bytes, want) in cases {
        let msg = error_text(text(bytes, None));
        assert!(msg.contains(want), "{want}: {msg}");
    }
    // Offsets name the line start.
    match text(b"1 2 3 1\n2 3 4\n", None) {
        Err(ReadError::Corrupt { offset, .. }) => assert_eq!(offset, 8),
        other => panic!("{other:?}"),
    }
    // Overlong lines stop reading instead of buffering.
    let long = [b"1 2 3 1\n".to_vec(), vec![b'1'; 10_000]].concat();
    assert!(error_text(text(&long, None)).contains("longer than"));
    // A sensor size checks the coordinates.
    let r = TextReader::new(&b"1 400 3 1\n"[..], None, Some((346, 260))).unwrap();
    assert!(drain(r)
        .unwrap_err()
        .to_string()
        .contains("outside the 346x260"));
}

#[test]
fn text_round_trip_many_lines() {
    let events = synthetic(150_000, 346, 260, 1, 1_589_163_147_000_000);
    let d = text(&text_seconds(&events), None).unwrap();
    assert_eq!(d.events, events_of(&events));
    assert!(d.batches.len() >= 3);
}

// ---------------------------------------------------------------------------------------------
// Detection and `open`.

/// One small file per format, as the detection and fuzz seeds.
fn seeds() -> Vec<(&'static str, Dec, Format, Vec<u8>)> {
    let e = synthetic(40, 346, 260, 4, 1_000);
    let one: Vec<Ev> = e.iter().map(|e| Ev { cam: 0, ..*e }).collect();
    let mut evt2 = raw_header(&["evt 2.0", "format EVT2;height=260;width=346", "end"]);
    evt2.extend_from_slice(&evt2_body(&one));
    let mut evt3 = raw_header(&["evt 3.0", "format EVT3;height=260;width=346", "end"]);
    evt3.extend_from_slice(&evt3_body(&one));
    let mut evt21 = raw_header(&["format EVT21;endianness=little;height=260;width=346", "end"]);
    evt21.extend_from_slice(&evt21_body(&one));
    let cams = [
        CameraInfo {
            id: 0,
            width: Some(346),
            height: Some(260),
            name: Some("DAVIS346_00000001".into()),
        },
        CameraInfo {
            id: 1,
            width: Some(346),
            height: Some(260),
            name: None,
        },
    ];
    let mut w = Aedat4Writer::new(Vec::new(), &cams, Compression::Lz4).unwrap();
    let mut b = Batch::default();
    for x in &e {
        b.push(x.cam % 2, Event::new(x.x, x.y, x.t, x.on));
    }
    w.write(&b).unwrap();
    vec![
        (
            "dhp19.aedat",
            Dec::Aedat2,
            Format::Aedat2,
            aedat2_davis346(&e, true),
        ),
        (
            "davis346.aedat3",
            Dec::Aedat3,
            Format::Aedat3,
            aedat3_file(&e, 4),
        ),
        ("evt2.raw", Dec::Evt2, Format::Raw, evt2),
        ("evt3.raw", Dec::Evt3, Format::Raw, evt3),
        ("evt21.raw", Dec::Evt21, Format::Raw, evt21),
        ("cd.dat", Dec::Dat, Format::Dat, dat_file(&one, 346, 260)),
        ("rpg.txt", Dec::Text, Format::Text, text_seconds(&one)),
        (
            "two-cameras.aedat4",
            Dec::Aedat4,
            Format::Aedat4,
            w.finish().unwrap(),
        ),
        ("dvs.es", Dec::Es, Format::Es, es_dvs_file(&one, 346, 260)),
    ]
}

/// The seed files are committed (`tests/fixtures/formats/`, a few hundred bytes each) so that
/// external fuzzers can start from them; they must stay what the encoders build. Regenerate
/// with `EVPOSE_BLESS=1 cargo test -p evpose-host --test formats seed`.
#[test]
fn seed_fixtures_match_their_builders() {
    for (name, dec, _, bytes) in seeds() {
        let path = fixture(name);
        if std::env::var_os("EVPOSE_BLESS").is_some() {
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, &bytes).unwrap();
        }
        let stored = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!(stored, bytes, "{name} differs from its builder");
        assert!(bytes.len() < 4096, "{name}: seeds stay small");
        decode(dec, &bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
}

#[test]
fn detection_and_open_dispatch() {
    let dir = tempfile::tempdir().unwrap();
    for (name, _, format, bytes) in seeds() {
        assert_eq!(Format::detect(&bytes), Some(format), "{name}");
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).unwrap();
        let mut r = open(&path, None).unwrap();
        let mut b = Batch::default();
        assert!(r.read_batch(&mut b).unwrap(), "{name}");
    }
    assert_eq!(Format::detect(b"\x93NUMPY\x01\x00"), Some(Format::Npy));
    assert_eq!(Format::detect(b"#!AER-DAT4.0\r\n"), Some(Format::Aedat4));
    assert_eq!(
        Format::detect(b"% Height 10\n% Width 10\n\x0c\x08"),
        Some(Format::Dat)
    );
    assert_eq!(Format::detect(b"% end\n"), Some(Format::Raw));
    assert_eq!(
        Format::detect(b"% comment\n0.5 1 2 1\n"),
        Some(Format::Text)
    );
    assert_eq!(Format::detect(b"\x00\x01\x02"), None);
    // A `.raw` without `% evt`: opened as RAW, which asks for the encoding.
    let path = dir.path().join("old.raw");
    std::fs::write(&path, b"% date 2019\n\x00\x00\x00\x80").unwrap();
    let err = open(&path, None).err().unwrap().to_string();
    assert!(err.contains("--format evt2"), "{err}");
    let r = open(&path, Some(Format::Evt2)).unwrap();
    assert_eq!(r.info().format, Format::Evt2);
    // The size fallback reaches formats that state none, npy included.
    let npy = dir.path().join("e.npy");
    evpose_host::array::write(&npy, &[1, 4], &[1.0f64, 2.0, 3.0, 1.0]).unwrap();
    let opts = OpenOptions {
        size: Some((346, 260)),
        ..OpenOptions::default()
    };
    let r = open_with(&npy, &opts).unwrap();
    assert_eq!(r.info().cameras[0].width, Some(346));
}

#[test]
fn format_names_match_the_cli_and_json() {
    use clap::ValueEnum;
    for f in Format::ALL {
        let v = f.to_possible_value().unwrap();
        assert_eq!(v.get_name(), f.name());
        assert_eq!(serde_json::to_value(f).unwrap(), f.name());
        assert_eq!(Format::from_str(f.name(), false).unwrap(), f);
    }
    assert_eq!(Format::from_str("csv", false).unwrap(), Format::Text);
}

// ---------------------------------------------------------------------------------------------
// Memory: constant in the file size.

/// A header then `blocks` copies of `block`, produced on the fly.
struct Repeat {
    header: Vec<u8>,
    block: Vec<u8>,
    blocks: usize,
    pos: usize,
}

impl Read for Repeat {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let total = self.header.len() + self.block.len() * self.blocks;
        let mut n = 0;
        while n < buf.len() && self.pos < total {
            let (src, at) = if self.pos < self.header.len() {
                (&self.header, self.pos)
            } else {
                (
                    &self.block,
                    (self.pos - self.header.len()) % self.block.len(),
                )
            };
            let k = (src.len() - at).min(buf.len() - n);
            buf[n..n + k].copy_from_slice(&src[at..at + k]);
            n += k;
            self.pos += k;
        }
        Ok(n)
    }
}

/// (decoder, header, block of `events` events) for each streaming format.
fn repeatable() -> Vec<(Dec, Vec<u8>, Vec<u8>)> {
    let e = synthetic(4096, 346, 260, 1, 0);
    let mut evt_head = raw_header(&["format EVT3;height=260;width=346", "end"]);
    let aedat4 = {
        let cams = [CameraInfo {
            id: 0,
            width: Some(346),
            height: Some(260),
            name: None,
        }];
        let header = Aedat4Writer::new(Vec::new(), &cams, Compression::Lz4)
            .unwrap()
            .finish()
            .unwrap();
        let mut w = Aedat4Writer::new(Vec::new(), &cams, Compression::Lz4).unwrap();
        let mut b = Batch::default();
        for x in &e {
            b.push(0, Event::new(x.x, x.y, x.t, x.on));
        }
        w.write(&b).unwrap();
        let all = w.finish().unwrap();
        (header.clone(), all[header.len()..].to_vec())
    };
    let dat = dat_file(&e, 346, 260);
    let dat_head = dat_file(&[], 346, 260);
    let a2_head = aedat2_header(Some("DAVIS346B"), true);
    let mut a2 = Vec::new();
    for x in &e {
        aedat2_record(&mut a2, davis_addr(x.x, x.y, x.on, 346, 260), x.t as u32);
    }
    let a3_head = aedat3_header(&[(1, "DAVIS346B")]);
    let mut a3 = Vec::new();
    aedat3_polarity_packet(&mut a3, 1, 0, &e);
    evt_head.shrink_to_fit();
    vec![
        (Dec::Aedat2, a2_head, a2),
        (Dec::Aedat3, a3_head, a3),
        (Dec::Evt2, evt_head.clone(), evt2_body(&e)),
        (Dec::Evt21, evt_head.clone(), evt21_body(&e)),
        (Dec::Evt3, evt_head, evt3_body(&e)),
        (Dec::Dat, dat_head.clone(), dat[dat_head.len()..].to_vec()),
        (Dec::Text, Vec::new(), text_seconds(&e)),
        (Dec::Aedat4, aedat4.0, aedat4.1),
        (Dec::Es, es_dvs_file(&[], 346, 260), es_dvs_body(&e, 260, 0)),
    ]
}

fn stream_count(dec: Dec, header: &[u8], block: &[u8], blocks: usize) -> u64 {
    let src = Repeat {
        header: header.to_vec(),
        block: block.to_vec(),
        blocks,
        pos: 0,
    };
    let mut r: Box<dyn EventReader> = match dec {
        Dec::Aedat2 => Box::new(Aedat2Reader::new(src, Format::Aedat2, None).unwrap()),
        Dec::Aedat3 => Box::new(Aedat3Reader::new(src, None).unwrap()),
        Dec::Evt2 => Box::new(EvtReader::new(src, Format::Evt2, None).unwrap()),
        Dec::Evt21 => Box::new(EvtReader::new(src, Format::Evt21, None).unwrap()),
        Dec::Evt3 => Box::new(EvtReader::new(src, Format::Evt3, None).unwrap()),
        Dec::Dat => Box::new(DatReader::new(src, None).unwrap()),
        Dec::Text => Box::new(TextReader::new(src, Some(TimeUnit::S), None).unwrap()),
        Dec::Aedat4 => Box::new(Aedat4Reader::new(src).unwrap()),
        Dec::Es => Box::new(EsReader::new(src).unwrap()),
        Dec::Aedat2Dhp19 => unreachable!(),
    };
    let mut b = Batch::default();
    let mut n = 0;
    while r.read_batch(&mut b).unwrap() {
        n += b.len() as u64;
    }
    n
}

#[test]
fn memory_is_constant_in_the_file_size() {
    for (dec, header, block) in repeatable() {
        let (small, small_peak) = peak_heap(|| stream_count(dec, &header, &block, 16));
        let (large, large_peak) = peak_heap(|| stream_count(dec, &header, &block, 256));
        assert_eq!(large, small * 16, "{dec:?}");
        assert_eq!(large, 256 * 4096, "{dec:?}");
        // The stream's bytes (in Repeat) count too; they are the same for both.
        assert!(
            large_peak <= small_peak + (64 << 10),
            "{dec:?}: peak {large_peak} bytes for 256 blocks vs {small_peak} for 16"
        );
        assert!(large_peak < 4 << 20, "{dec:?}: peak {large_peak} bytes");
    }
}

// ---------------------------------------------------------------------------------------------
// Damage everywhere: truncation at every offset, and fuzzing.

/// Decodes without a panic escaping; the error's offset lies within the input.
fn decode_checked(dec: Dec, bytes: &[u8]) -> Result<Decoded, ReadError> {
    let (r, peak) = peak_heap(|| {
        std::panic::catch_unwind(|| decode(dec, bytes))
            .unwrap_or_else(|_| panic!("{dec:?} panicked on {bytes:02x?}"))
    });
    assert!(
        peak < 8 << 20,
        "{dec:?}: peak {peak} bytes on {} input bytes",
        bytes.len()
    );
    if let Err(ReadError::Corrupt { offset, .. } | ReadError::Truncated { offset, .. }) = &r {
        assert!(
            *offset <= bytes.len() as u64,
            "{dec:?}: offset {offset} past the end"
        );
    }
    r
}

#[test]
fn truncation_at_every_offset_is_a_prefix_or_an_error() {
    for (name, dec, _, bytes) in seeds() {
        let full = decode(dec, &bytes).unwrap().events;
        for cut in 0..bytes.len() {
            if let Ok(d) = decode_checked(dec, &bytes[..cut]) {
                if matches!(dec, Dec::Aedat4) {
                    // Its cameras are merged by time over what the file holds: each camera's
                    // events are a prefix of its own.
                    for c in 0..=u8::MAX {
                        let of = |v: &[(u8, Event)]| -> Vec<Event> {
                            v.iter().filter(|e| e.0 == c).map(|e| e.1).collect()
                        };
                        let (part, whole) = (of(&d.events), of(&full));
                        assert_eq!(part[..], whole[..part.len()], "{name} cut at {cut}");
                    }
                } else {
                    assert_eq!(d.events[..], full[..d.events.len()], "{name} cut at {cut}");
                }
            }
        }
    }
}

fn mutated() -> impl Strategy<Value = (usize, Vec<u8>)> {
    let n = seeds().len();
    (
        0..n,
        proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..4), 1..8),
    )
        .prop_map(|(i, edits)| {
            let mut bytes = seeds().swap_remove(i).3;
            for (pos, val, kind) in edits {
                let pos = usize::from(pos) % (bytes.len() + 1);
                match kind {
                    0 if pos < bytes.len() => bytes[pos] = val,
                    1 if pos < bytes.len() => bytes[pos] ^= 1 << (val % 8),
                    2 => bytes.insert(pos, val),
                    _ => bytes.truncate(pos),
                }
            }
            (i, bytes)
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(768))]

    /// Seed files with a few bytes overwritten, flipped, inserted or cut: every decoder
    /// returns events or a typed error, in bounded memory.
    #[test]
    fn mutated_seeds_never_panic((i, bytes) in mutated()) {
        let dec = seeds()[i].1;
        let _ = decode_checked(dec, &bytes);
    }

    /// Arbitrary bytes after a valid header, through every decoder.
    #[test]
    fn random_bodies_never_panic(body in proptest::collection::vec(any::<u8>(), 0..1024), which in 0usize..DECODERS.len()) {
        let dec = DECODERS[which];
        let header: Vec<u8> = match dec {
            Dec::Aedat2 => aedat2_header(Some("DAVIS346B"), true),
            Dec::Aedat2Dhp19 => aedat2_header(None, false),
            Dec::Aedat3 => aedat3_header(&[(1, "DVXplorer")]),
            Dec::Evt2 | Dec::Evt21 | Dec::Evt3 => raw_header(&["evt 3.0", "end"]),
            Dec::Dat => dat_file(&[], 64, 64),
            Dec::Text => b"t x y p\n".to_vec(),
            Dec::Aedat4 => aedat4_header(&[CameraInfo { id: 0, width: Some(64), height: Some(64), name: None }]),
            Dec::Es => es_dvs_file(&[], 64, 64),
        };
        let bytes = [header, body].concat();
        let _ = decode_checked(dec, &bytes);
    }

    /// Arbitrary bytes from the start.
    #[test]
    fn random_files_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512), which in 0usize..DECODERS.len()) {
        let _ = decode_checked(DECODERS[which], &bytes);
        let _ = Format::detect(&bytes);
    }

    /// Text made of digits, separators and line ends.
    #[test]
    fn random_text_never_panics(bytes in proptest::collection::vec(prop::sample::select(b"0123456789.,; -+eE\t\r\n#".to_vec()), 0..512)) {
        let _ = decode_checked(Dec::Text, &bytes);
    }
}

#[test]
fn all_camera_windows_give_every_camera_the_same_windows() {
    use evpose_core::{RasterConfig, Rasterizer, WindowRule};
    use evpose_host::pipeline::{rasterize, vec_storage, RasterOptions};
    // A DHP19 recording: the first 1,000 events all from camera 0 (camera 1 has an empty first
    // window, camera 0 a full one), then 5,500 over the four cameras; windows of 1,000 events
    // of all cameras (the last one 500).
    let n = 1_000;
    let mut events = synthetic(6_500, 346, 260, 4, 1_000);
    for e in &mut events[..n] {
        e.cam = 0;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dhp19.aedat");
    std::fs::write(&path, aedat2_davis346(&events, true)).unwrap();
    for cam in 0..4u8 {
        let opts = RasterOptions {
            window_events: Some(n as u32),
            camera: cam,
            all_camera_windows: true,
            ..RasterOptions::default()
        };
        let mut got = Vec::new();
        rasterize(&path, &opts, |i, w| {
            got.push((i, w.summary().events, w.iter().collect::<Vec<_>>()));
            Ok(())
        })
        .unwrap();
        // Each window: this camera's events of the same 1,000 events of all cameras, alone
        // through a rasterizer.
        let want: Vec<_> = events
            .chunks(n)
            .enumerate()
            .map(|(i, chunk)| {
                let mine: Vec<Event> = chunk
                    .iter()
                    .filter(|e| e.cam == cam)
                    .map(|e| Event::new(e.x, e.y, e.t, e.on))
                    .collect();
                let config = RasterConfig {
                    window: WindowRule::Events(n as u32),
                    ..RasterConfig::DAVIS346
                };
                let mut r = Rasterizer::new(config, vec_storage(n, &config)).unwrap();
                let (used, closed) = r.extend(&mine);
                assert_eq!(used, mine.len());
                // A camera with all 1,000 events closes the window by count.
                let closed = closed.map(|w| w.iter().collect::<Vec<_>>());
                let points = closed.unwrap_or_else(|| r.flush().iter().collect());
                (i, mine.len() as u32, points)
            })
            .collect();
        let counts = |v: &[(usize, u32, Vec<_>)]| -> Vec<(usize, u32, usize)> {
            v.iter().map(|(i, e, p)| (*i, *e, p.len())).collect()
        };
        assert_eq!(
            counts(&got),
            counts(&want),
            "camera {cam}: (window, events, points)"
        );
        for (g, w) in got.iter().zip(&want) {
            assert!(g.2 == w.2, "camera {cam} window {}: points differ", g.0);
        }
    }
}

/// Inputs the fuzz targets (`fuzz/`) found, kept as regression tests.
#[test]
fn inputs_found_by_the_fuzzer_are_errors() {
    // An npy header whose length field (version 3: 4 bytes) asks for 662 MB: the reader
    // allocated it before reading; now a header over NumPy's 10,000-byte limit is refused.
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/fuzz/npy-huge-header-length.npy");
    let bytes = std::fs::read(&path).unwrap();
    for format in [None, Some(Format::Npy)] {
        let opts = OpenOptions {
            format,
            ..OpenOptions::default()
        };
        let (r, peak) =
            peak_heap(|| evpose_host::io::open_bytes(bytes.clone(), "fuzz input", &opts));
        let err = r.err().expect("an error");
        assert!(format!("{err:#}").contains("npy header of"), "{err:#}");
        assert!(peak < 1 << 20, "{peak} bytes allocated");
    }
    // A header nesting 17 levels (16 `{`): the Python-literal parser backtracked for over 10 s (the fuzz
    // run's time-out); headers deeper than 6 levels are now refused before it runs.
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/fuzz/npy-deeply-nested-header.npy");
    let opts = OpenOptions::default();
    let err = evpose_host::io::open_bytes(std::fs::read(&path).unwrap(), "fuzz input", &opts)
        .err()
        .expect("an error");
    assert!(format!("{err:#}").contains("nests 17 levels"), "{err:#}");
}

//! AEDAT 4.0 reader and writer: a real DV recording, round trips, and damaged files.

use std::io::Read;
use std::path::{Path, PathBuf};

use evpose_core::Event;
use evpose_host::io::aedat4::{
    Aedat4Reader, Aedat4Writer, Compression, MERGE_EVENTS, WRITE_PACKET_EVENTS,
    WRITE_PACKET_SPAN_US,
};
use evpose_host::io::{open, Batch, CameraInfo, EventReader, Format, ReadError, BATCH_EVENTS};

/// The head of a DAVIS346 street recording made with DV (LZ4, streams EVTS 0, FRME 1, IMUS 2,
/// TRIG 3), cut by `fixtures/aedat4/make_head.py` from `shared/recordings/davis346-street.aedat4`:
/// header + the first 14 whole packets (bytes 0..112280), dataTablePosition set to -1.
fn head_fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/aedat4/davis346-street-head.aedat4")
}

/// The whole recording, present only where `../shared` sits beside the checkout.
fn full_recording() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/recordings/davis346-street.aedat4")
}

/// Everything a reader yields: the events with their camera, and the batch sizes.
struct Decoded {
    events: Vec<(u8, Event)>,
    batches: Vec<usize>,
    skipped: u64,
}

fn read_all_from(mut reader: Aedat4Reader<impl Read>) -> Result<Decoded, ReadError> {
    let mut out = Decoded {
        events: Vec::new(),
        batches: Vec::new(),
        skipped: 0,
    };
    let mut batch = Batch::default();
    while reader.read_batch(&mut batch)? {
        assert_eq!(batch.events.len(), batch.cameras.len());
        out.batches.push(batch.len());
        out.events.extend(
            batch
                .cameras
                .iter()
                .copied()
                .zip(batch.events.iter().copied()),
        );
    }
    assert!(batch.is_empty());
    assert!(!reader.read_batch(&mut batch).expect("read after the end"));
    out.skipped = reader.skipped_packets();
    Ok(out)
}

fn read_all(bytes: &[u8]) -> Result<Decoded, ReadError> {
    read_all_from(Aedat4Reader::new(bytes)?)
}

fn write_file(cameras: &[CameraInfo], compression: Compression, events: &[(u8, Event)]) -> Vec<u8> {
    let mut w = Aedat4Writer::new(Vec::new(), cameras, compression).expect("header");
    // Uneven batches, so that packets do not follow batch boundaries.
    for chunk in events.chunks(777) {
        let mut batch = Batch::default();
        for &(c, e) in chunk {
            batch.push(c, e);
        }
        w.write(&batch).expect("write");
    }
    w.finish().expect("finish")
}

fn camera(id: u8, width: u16, height: u16, name: &str) -> CameraInfo {
    CameraInfo {
        id,
        width: Some(width),
        height: Some(height),
        name: Some(name.into()),
    }
}

fn two_cameras() -> Vec<CameraInfo> {
    vec![
        camera(0, 346, 260, "DAVIS346_left"),
        camera(1, 640, 480, "DVXplorer <&\"right\">"),
    ]
}

/// Deterministic events of two cameras in runs of random length, with edge coordinates.
fn synthetic_events(n: usize) -> Vec<(u8, Event)> {
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut events = Vec::with_capacity(n);
    let (mut cam, mut run, mut t) = (0u8, 0u64, 1_589_163_147_368_868_i64);
    while events.len() < n {
        if run == 0 {
            cam ^= 1;
            run = 1 + next() % 3000;
        }
        run -= 1;
        t += (next() % 50) as i64;
        let (w, h) = if cam == 0 { (346, 260) } else { (640, 480) };
        let r = next();
        events.push((
            cam,
            Event::new((r % w) as u16, ((r >> 20) % h) as u16, t, r >> 63 == 1),
        ));
    }
    events.push((1, Event::new(32767, 0, t, false)));
    events.push((0, Event::new(0, 32767, t + 1, true)));
    events.push((0, Event::new(0, 0, -5, true)));
    events
}

/// What reading back the writer's file of `want` gives, `got`, must be: every camera's events in
/// their order, merged by time: the events of `want` that came in time order are read in
/// `(time, camera)` order (whatever order the packets are in).
fn assert_written_order(got: &[(u8, Event)], want: &[(u8, Event)]) {
    let by_camera = |v: &[(u8, Event)]| {
        let mut v = v.to_vec();
        v.sort_by_key(|&(c, _)| c); // stable: each camera's order stays
        v
    };
    assert_eq!(by_camera(got), by_camera(want));
    let in_order: std::collections::HashSet<(u8, Event)> = want
        .iter()
        .scan(i64::MIN, |latest, &(c, e)| {
            let kept = e.t >= *latest;
            *latest = (*latest).max(e.t);
            Some(kept.then_some((c, e)))
        })
        .flatten()
        .collect();
    let mut last = (i64::MIN, 0);
    for &(c, e) in got.iter().filter(|ev| in_order.contains(ev)) {
        assert!((e.t, c) >= last, "{c} {e:?} after {last:?}");
        last = (e.t, c);
    }
}

/// File offsets of the header end and of every packet end, by walking the packet headers.
fn packet_bounds(bytes: &[u8]) -> Vec<usize> {
    let le = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    let mut bounds = vec![18 + le(14)];
    while let Some(&pos) = bounds.last().filter(|&&p| p + 8 <= bytes.len()) {
        bounds.push(pos + 8 + le(pos + 4));
    }
    assert_eq!(bounds.last(), Some(&bytes.len()));
    bounds
}

/// Offset of a header-relative IOHeader field: dataTablePosition, for the DV layout.
const DATA_TABLE_AT: usize = 54;

// ---------------------------------------------------------------------------------------------
// A real recording.

/// Values from `python3 make_head.py …` (standard library only, its own LZ4 decoder):
/// 2000 events in 5 EVTS packets; 9 packets of other streams.
#[test]
fn head_of_real_recording_matches_independent_decode() {
    let file = std::fs::File::open(head_fixture()).expect("fixture");
    let reader = Aedat4Reader::new(std::io::BufReader::new(file)).expect("header");
    assert_eq!(reader.compression(), Compression::Lz4);
    let info = reader.info().clone();
    assert_eq!(info.format, Format::Aedat4);
    assert_eq!(info.event_count, None);
    assert_eq!(info.cameras, vec![camera(0, 346, 260, "DAVIS346_00000002")]);

    let got = read_all_from(reader).expect("read");
    assert_eq!(got.skipped, 9);
    let ev = &got.events;
    assert_eq!(ev.len(), 2000);
    assert!(ev.iter().all(|&(c, _)| c == 0));
    assert_eq!(
        ev[..3].iter().map(|&(_, e)| e).collect::<Vec<_>>(),
        [
            Event::new(215, 164, 1_589_163_147_368_868, true),
            Event::new(226, 160, 1_589_163_147_368_950, true),
            Event::new(40, 236, 1_589_163_147_368_974, true),
        ]
    );
    assert_eq!(ev[1999].1, Event::new(87, 226, 1_589_163_147_418_794, true));
    let t0 = ev[0].1.t;
    assert_eq!(ev.iter().map(|(_, e)| u64::from(e.x)).sum::<u64>(), 217_240);
    assert_eq!(ev.iter().map(|(_, e)| u64::from(e.y)).sum::<u64>(), 425_775);
    assert_eq!(ev.iter().filter(|(_, e)| e.on).count(), 1042);
    assert_eq!(ev.iter().map(|(_, e)| e.t - t0).sum::<i64>(), 50_346_981);
    assert!(ev.iter().all(|(_, e)| e.x < 346 && e.y < 260));
}

#[test]
fn open_detects_and_reads_aedat4() {
    let mut reader = open(&head_fixture(), None).expect("open");
    assert_eq!(reader.info().format, Format::Aedat4);
    let mut batch = Batch::default();
    let mut n = 0;
    while reader.read_batch(&mut batch).expect("read") {
        n += batch.len();
    }
    assert_eq!(n, 2000);
}

/// Optional: the whole 6 MB recording, when the shared folder is there. Expected values from
/// `python3 make_head.py … /dev/null 100000000` (reads up to the data table).
#[test]
fn full_real_recording_when_present() {
    let path = full_recording();
    if !path.exists() {
        eprintln!(
            "note: {} is missing; skipping the full-recording check",
            path.display()
        );
        return;
    }
    let file = std::fs::File::open(&path).expect("open");
    let got = read_all_from(Aedat4Reader::new(std::io::BufReader::new(file)).expect("header"))
        .expect("read");
    assert_eq!(got.events.len(), 78_830);
    assert_eq!(got.skipped, 472);
    assert!(got.batches.iter().all(|&b| b <= BATCH_EVENTS));
    let t0 = got.events[0].1.t;
    assert_eq!(
        got.events[78_829].1,
        Event::new(233, 205, 1_589_163_149_728_813, true)
    );
    assert_eq!(
        got.events.iter().map(|(_, e)| u64::from(e.x)).sum::<u64>(),
        14_861_513
    );
    assert_eq!(
        got.events.iter().map(|(_, e)| e.t - t0).sum::<i64>(),
        90_875_505_184
    );
}

/// The writer lays out an `EventPacket` byte for byte as DV does: compare with the first
/// EVTS packet of the real recording, decompressed.
#[test]
fn written_packet_is_byte_identical_to_dv() {
    let bytes = std::fs::read(head_fixture()).expect("fixture");
    let start = packet_bounds(&bytes)[0];
    let size = u32::from_le_bytes(bytes[start + 4..start + 8].try_into().unwrap()) as usize;
    assert_eq!(
        &bytes[start..start + 4],
        &[0, 0, 0, 0],
        "first packet is stream 0"
    );
    let mut dv = Vec::new();
    lz4_flex::frame::FrameDecoder::new(&bytes[start + 8..start + 8 + size])
        .read_to_end(&mut dv)
        .expect("lz4");

    let events = read_all(&bytes).expect("read").events;
    let first_packet = &events[..(dv.len() - 32) / 16];
    let ours = write_file(&[camera(0, 346, 260, "x")], Compression::None, first_packet);
    let ours_start = packet_bounds(&ours)[0];
    assert_eq!(&ours[ours_start + 8..], &dv[..]);
}

/// The writer's IOHeader flatbuffer (all but the XML) and LZ4 frame descriptor are those of DV.
#[test]
fn written_header_and_lz4_frame_match_dv() {
    let dv = std::fs::read(head_fixture()).expect("fixture");
    let events = [(0, Event::new(1, 2, 3, true))];
    let ours = write_file(&[camera(0, 346, 260, "x")], Compression::Lz4, &events);
    // File bytes 18..66: root offset, "IOHE", vtable, table (LZ4, infoNode offset,
    // dataTablePosition -1 as in the cut fixture, padding). 66..70 is the XML length.
    assert_eq!(&ours[..18 - 4], &dv[..18 - 4]);
    assert_eq!(&ours[18..66], &dv[18..66]);
    // Both sizes are 4 less than a multiple of 8, so that the buffer with its prefix is.
    let size = |b: &[u8]| u32::from_le_bytes(b[14..18].try_into().unwrap());
    assert_eq!(size(&dv) % 8, 4);
    assert_eq!(size(&ours) % 8, 4);
    // LZ4 frame magic, FLG (version 1, linked blocks, no checksums), BD (64 KiB), HC.
    let (d, o) = (packet_bounds(&dv)[0] + 8, packet_bounds(&ours)[0] + 8);
    assert_eq!(&ours[o..o + 7], &dv[d..d + 7]);
    assert_eq!(&dv[d + 4..d + 6], &[0x40, 0x40]);
}

// ---------------------------------------------------------------------------------------------
// Round trips.

#[test]
fn round_trip_two_cameras_every_compression() {
    let events = synthetic_events(20_000);
    let cameras = two_cameras();
    for compression in Compression::ALL {
        let bytes = write_file(&cameras, compression, &events);
        let reader = Aedat4Reader::new(&bytes[..]).expect("header");
        assert_eq!(reader.compression(), compression);
        assert_eq!(reader.info().cameras, cameras, "{compression:?}");
        let got = read_all_from(reader).expect("read");
        assert_written_order(&got.events, &events);
        assert_eq!(got.skipped, 0);
    }
}

#[test]
fn batches_are_bounded_and_span_packets() {
    let events = synthetic_events(3 * BATCH_EVENTS + 123);
    let bytes = write_file(&two_cameras(), Compression::Lz4, &events);
    let got = read_all(&bytes).expect("read");
    assert_written_order(&got.events, &events);
    assert!(got.batches.iter().all(|&b| b > 0 && b <= BATCH_EVENTS));
    assert!(got.batches.iter().filter(|&&b| b == BATCH_EVENTS).count() >= 3);
}

#[test]
fn empty_and_cameraless_files() {
    let bytes = write_file(&two_cameras(), Compression::Zstd, &[]);
    let got = read_all(&bytes).expect("read");
    assert!(got.events.is_empty() && got.batches.is_empty());
    let bytes = write_file(&[], Compression::None, &[]);
    let reader = Aedat4Reader::new(&bytes[..]).expect("header");
    assert!(reader.info().cameras.is_empty());
}

#[test]
fn camera_without_size_or_name_round_trips() {
    let cameras = [CameraInfo {
        id: 0,
        width: None,
        height: None,
        name: None,
    }];
    let events = [(0, Event::new(1, 2, 3, true))];
    let bytes = write_file(&cameras, Compression::Lz4High, &events);
    let reader = Aedat4Reader::new(&bytes[..]).expect("header");
    // A camera without a name gets a source of its own (dv-processing needs one).
    let named = [CameraInfo {
        name: Some("evpose_camera0".into()),
        ..cameras[0].clone()
    }];
    assert_eq!(reader.info().cameras, named);
    assert_eq!(read_all_from(reader).expect("read").events, events);
}

/// As DV writes them: every camera's stream is `events`, and the cameras differ by `source`
/// (dv-processing looks a camera's events up by both: a stream without a source, or named
/// otherwise, is one it cannot read through its default accessors).
#[test]
fn every_stream_is_events_of_a_source_of_its_own() {
    let cameras = [
        camera(0, 346, 260, "DAVIS346"),
        camera(1, 346, 260, "DAVIS346"),
        CameraInfo {
            id: 2,
            width: Some(346),
            height: Some(260),
            name: None,
        },
        camera(3, 346, 260, "DAVIS346_00000002"),
    ];
    let bytes = write_file(&cameras, Compression::None, &[]);
    let reader = Aedat4Reader::new(&bytes[..]).expect("header");
    let sources: Vec<String> = reader
        .info()
        .cameras
        .iter()
        .map(|c| c.name.clone().unwrap())
        .collect();
    assert_eq!(
        sources,
        [
            "DAVIS346_camera0",
            "DAVIS346_camera1",
            "evpose_camera2",
            "DAVIS346_00000002"
        ]
    );
    let text = String::from_utf8_lossy(&bytes);
    let outputs = text.matches(r#"<attr key="originalOutputName" type="string">events</attr>"#);
    assert_eq!(outputs.count(), 4, "{text}");
    assert!(!text.contains("events_"), "{text}");
}

#[test]
fn writer_rejects_what_aedat4_cannot_hold() {
    let mut w = Aedat4Writer::new(Vec::new(), &two_cameras(), Compression::None).expect("header");
    let mut batch = Batch::default();
    batch.push(0, Event::new(32768, 0, 0, true));
    assert!(w.write(&batch).is_err());
    batch.clear();
    batch.push(7, Event::new(0, 0, 0, true));
    assert!(w.write(&batch).is_err(), "undeclared camera");
    let twice = [camera(3, 1, 1, "a"), camera(3, 1, 1, "b")];
    assert!(Aedat4Writer::new(Vec::new(), &twice, Compression::None).is_err());
}

/// Packets hold one camera's events, at most `WRITE_PACKET_EVENTS`; the open ones are written
/// at the end oldest first.
#[test]
fn writer_packet_sizes() {
    let events: Vec<_> = (0..2 * WRITE_PACKET_EVENTS + 1)
        .map(|i| (0, Event::new(1, 1, i as i64, true)))
        .chain([(1, Event::new(2, 2, 0, false))])
        .collect();
    let bytes = write_file(&two_cameras(), Compression::None, &events);
    let bounds = packet_bounds(&bytes);
    let sizes: Vec<_> = bounds
        .windows(2)
        .map(|w| (w[1] - w[0] - 8 - 32) / 16)
        .collect();
    assert_eq!(sizes, [WRITE_PACKET_EVENTS, WRITE_PACKET_EVENTS, 1, 1]);
}

/// Cameras interleaved event by event share no packet but need not split them (they were
/// one-event packets), a packet is written once an event comes `WRITE_PACKET_SPAN_US` after its
/// earliest, whatever the event's camera, and the reader merges the cameras back by time.
#[test]
fn interleaved_cameras_fill_packets_of_their_own() {
    // 0.25 µs apart on average: 8,000 events over 2 ms, cameras alternating.
    let events: Vec<_> = (0..8000)
        .map(|i| ((i % 2) as u8, Event::new(1, 1, i / 4, i % 3 == 0)))
        .collect();
    let bytes = write_file(&two_cameras(), Compression::None, &events);
    let sizes = |b: &[u8]| {
        packet_bounds(b)
            .windows(2)
            .map(|w| (w[1] - w[0] - 8 - 32) / 16)
            .collect::<Vec<_>>()
    };
    assert_eq!(sizes(&bytes), [4000, 4000]);
    assert_written_order(&read_all(&bytes).unwrap().events, &events);

    // Camera 1 fires once at t = 0, camera 0 keeps going: camera 1's packet is written when
    // camera 0 reaches t = WRITE_PACKET_SPAN_US, before the events from then on.
    let span = WRITE_PACKET_SPAN_US;
    let events: Vec<_> = std::iter::once((1, Event::new(5, 5, 0, true)))
        .chain(
            (0..3 * span)
                .step_by(100)
                .map(|t| (0, Event::new(1, 1, t, true))),
        )
        .collect();
    let bytes = write_file(&two_cameras(), Compression::None, &events);
    // Packets of camera 0: [0, span), [span, 2 span), [2 span, 3 span); camera 1's second.
    assert_eq!(sizes(&bytes), [100, 1, 100, 100]);
    // Read back merged by time: camera 1's event after camera 0's at the same time.
    let got = read_all(&bytes).unwrap().events;
    let mut want = events.clone();
    want.sort_by_key(|&(c, e)| (e.t, c));
    assert_eq!(got, want);
}

/// One timestamp glitch an hour ahead neither holds its camera back nor lets the other
/// cameras' events out of time order (by more than the writer's packets allow).
#[test]
fn a_timestamp_glitch_does_not_stall_the_time_merge() {
    let mut events = synthetic_events(200_000);
    events.truncate(200_000); // time-ordered: without the three odd events at the end
    let glitch = (100_000..).find(|&i| events[i].0 == 0).unwrap();
    events[glitch].1.t += 3_600_000_000;
    let far = events[glitch].1.t;
    let bytes = write_file(&two_cameras(), Compression::Lz4, &events);
    let got = read_all(&bytes).expect("read").events;
    assert_eq!(got.len(), events.len());
    let mut latest = i64::MIN;
    let mut worst = 0;
    for (i, &(_, e)) in got.iter().enumerate() {
        if e.t == far {
            // The glitch leaves next to its neighbours in its camera's order.
            assert!(
                i.abs_diff(glitch) < 2 * WRITE_PACKET_EVENTS,
                "{i} vs {glitch}"
            );
            continue;
        }
        worst = worst.max(latest.saturating_sub(e.t));
        latest = latest.max(e.t);
    }
    assert!(worst < WRITE_PACKET_SPAN_US, "{worst} µs late");
}

/// The time merge buffers at most `MERGE_EVENTS` events: a file whose time stands still (no
/// event is ever `MERGE_SPAN_US` old) is still read as it goes, not whole.
#[test]
fn the_time_merge_buffers_a_bounded_number_of_events() {
    let n = MERGE_EVENTS + MERGE_EVENTS / 4;
    let events: Vec<_> = (0..n)
        .map(|i| ((i % 2) as u8, Event::new((i % 300) as u16, 7, 0, true)))
        .collect();
    let bytes = write_file(&two_cameras(), Compression::Lz4, &events);
    let mut reader = Aedat4Reader::new(&bytes[..]).expect("header");
    let mut batch = Batch::default();
    assert!(reader.read_batch(&mut batch).expect("read"));
    let rest = reader.into_inner().len();
    assert!(
        rest > bytes.len() / 10,
        "{rest} of {} bytes left",
        bytes.len()
    );
    let got = read_all(&bytes).expect("read").events;
    assert_written_order(&got, &events);
}

// ---------------------------------------------------------------------------------------------
// The data table.

#[test]
fn reading_stops_at_the_data_table() {
    let events = synthetic_events(5000);
    let mut bytes = write_file(&two_cameras(), Compression::Lz4, &events);
    let table = bytes.len() as i64;
    bytes[DATA_TABLE_AT..DATA_TABLE_AT + 8].copy_from_slice(&table.to_le_bytes());
    bytes.extend_from_slice(b"a FileDataTable that is never read \xff\xff\xff\xff");
    assert_eq!(read_all(&bytes).expect("read").events, events);

    // The table announced after the end of the file: truncated.
    let mut cut = bytes.clone();
    cut[DATA_TABLE_AT..DATA_TABLE_AT + 8].copy_from_slice(&(table + 100).to_le_bytes());
    cut.truncate(table as usize);
    assert!(matches!(read_all(&cut), Err(ReadError::Truncated { .. })));

    // The table announced inside a packet.
    let mid = packet_bounds(&cut)[1] as i64 - 3;
    cut[DATA_TABLE_AT..DATA_TABLE_AT + 8].copy_from_slice(&mid.to_le_bytes());
    assert!(matches!(read_all(&cut), Err(ReadError::Corrupt { .. })));

    // The table announced inside the header.
    cut[DATA_TABLE_AT..DATA_TABLE_AT + 8].copy_from_slice(&20i64.to_le_bytes());
    assert!(matches!(
        Aedat4Reader::new(&cut[..]),
        Err(ReadError::Corrupt { offset: 18, .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// Damaged files.

/// Small files: 2 cameras, a few packets, the four layouts that matter.
fn small_files() -> Vec<(Compression, Vec<u8>)> {
    let events = synthetic_events(300);
    [Compression::None, Compression::Lz4, Compression::Zstd]
        .into_iter()
        .map(|c| (c, write_file(&two_cameras(), c, &events)))
        .collect()
}

fn read_no_panic(bytes: &[u8], what: &str) -> Result<Decoded, ReadError> {
    std::panic::catch_unwind(|| read_all(bytes)).unwrap_or_else(|_| panic!("panic on {what}"))
}

#[test]
fn truncation_at_every_offset_is_an_error_or_a_clean_end() {
    for (compression, bytes) in small_files() {
        let full = read_all(&bytes).expect("read").events;
        let bounds = packet_bounds(&bytes);
        for cut in 0..bytes.len() {
            let what = format!("{compression:?} cut at {cut}");
            match read_no_panic(&bytes[..cut], &what) {
                Ok(got) => {
                    assert!(bounds.contains(&cut), "{what}: no error inside a record");
                    // The cameras are merged by time over what the file holds: each camera's
                    // events are a prefix of its own.
                    for c in 0..2 {
                        let of = |v: &[(u8, Event)]| -> Vec<Event> {
                            v.iter().filter(|e| e.0 == c).map(|e| e.1).collect()
                        };
                        let (part, whole) = (of(&got.events), of(&full));
                        assert_eq!(part[..], whole[..part.len()], "{what}");
                    }
                }
                Err(ReadError::Truncated { offset, .. }) => {
                    assert!(!bounds.contains(&cut), "{what}");
                    assert!(offset as usize <= cut, "{what}: offset {offset}");
                }
                Err(e) => panic!("{what}: {e}"),
            }
        }
    }
}

#[test]
fn truncated_real_recording_never_panics() {
    let bytes = std::fs::read(head_fixture()).expect("fixture");
    let bounds = packet_bounds(&bytes);
    for cut in (0..bytes.len()).step_by(61).chain(bounds.iter().copied()) {
        let result = read_no_panic(&bytes[..cut], &format!("cut at {cut}"));
        assert_eq!(result.is_ok(), bounds.contains(&cut), "cut at {cut}");
    }
}

#[test]
fn flipped_bytes_never_panic() {
    for (compression, bytes) in small_files() {
        for pos in 0..bytes.len() {
            // Every byte inverted; single-bit flips at every third byte (debug builds are slow).
            let masks: &[u8] = if pos % 3 == 0 {
                &[0xff, 0x01, 0x80]
            } else {
                &[0xff]
            };
            for &mask in masks {
                let mut bad = bytes.clone();
                bad[pos] ^= mask;
                let _ = read_no_panic(&bad, &format!("{compression:?} byte {pos} ^ {mask:#x}"));
            }
        }
    }
}

#[test]
fn flipped_bytes_in_real_recording_never_panic() {
    let bytes = std::fs::read(head_fixture()).expect("fixture");
    for pos in (0..bytes.len()).step_by(89) {
        let mut bad = bytes.clone();
        bad[pos] ^= 0xff;
        let _ = read_no_panic(&bad, &format!("real recording byte {pos}"));
    }
}

/// Random overwrites of 1 to 8 bytes, some in the header, with a fixed seed.
#[test]
fn random_mutations_never_panic() {
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state as usize
    };
    for (compression, bytes) in small_files() {
        for round in 0..MUTATION_ROUNDS {
            let mut bad = bytes.clone();
            for _ in 0..1 + next() % 8 {
                let pos = if next() % 4 == 0 {
                    next() % 80
                } else {
                    next() % bad.len()
                };
                bad[pos] = next() as u8;
            }
            let _ = read_no_panic(&bad, &format!("{compression:?} mutation round {round}"));
        }
    }
}

const MUTATION_ROUNDS: usize = 2000;

#[test]
fn flipped_structural_bytes_are_errors() {
    let (_, bytes) = small_files().remove(0); // Compression::None
    let header_end = packet_bounds(&bytes)[0];
    let flip = |pos: usize, mask: u8| {
        let mut bad = bytes.clone();
        bad[pos] ^= mask;
        read_all(&bad)
    };
    for pos in 0..14 {
        assert!(flip(pos, 0x20).is_err(), "magic byte {pos}");
    }
    for pos in [17, 18, 22, 23, 24, 25, 42, 46] {
        assert!(flip(pos, 0xff).is_err(), "IOHeader byte {pos}");
    }
    // Packet: stream id, size (sign bit), then the flatbuffer's prefix, root and identifier.
    for pos in [0, 7, 8, 16, 19] {
        match flip(header_end + pos, 0x80) {
            Err(ReadError::Corrupt { offset, .. }) => {
                assert_eq!(offset as usize, header_end, "packet byte {pos}")
            }
            other => panic!("packet byte {pos}: {:?}", other.map(|r| r.events.len())),
        }
    }
    // An event's x turned negative (event 5 of the first packet that has six).
    let bounds = packet_bounds(&bytes);
    let packet = (bounds.windows(2))
        .find(|w| w[1] - w[0] >= 8 + 32 + 16 * 6)
        .map(|w| w[0])
        .unwrap();
    match flip(packet + 8 + 32 + 16 * 5 + 9, 0x80) {
        Err(ReadError::Corrupt { offset, message }) => {
            assert_eq!(offset as usize, packet);
            assert!(message.contains("event 5"), "{message}");
        }
        other => panic!("negative x: {:?}", other.map(|r| r.events.len())),
    }
}

#[test]
fn bad_magic_and_other_versions() {
    assert!(matches!(
        read_all(b""),
        Err(ReadError::Truncated { offset: 0, .. })
    ));
    assert!(matches!(
        read_all(b"#!AER-DAT4"),
        Err(ReadError::Truncated { offset: 0, .. })
    ));
    assert!(matches!(
        read_all(b"\x93NUMPY\x01\x00"),
        Err(ReadError::Corrupt { offset: 0, .. })
    ));
    let v3 = b"#!AER-DAT3.1\r\n#!END-HEADER\r\n";
    assert!(matches!(read_all(v3), Err(ReadError::Unsupported(_))));
}

#[test]
fn lying_sizes_are_rejected_without_allocating() {
    let (_, bytes) = small_files().remove(0);
    let header_end = packet_bounds(&bytes)[0];
    // Header size 4 GiB - 1.
    let mut bad = bytes.clone();
    bad[14..18].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        read_all(&bad),
        Err(ReadError::Corrupt { offset: 14, .. })
    ));
    // Packet size 2 GiB - 1, and 200 MiB in a file that ends right away.
    for size in [i32::MAX, 200 << 20] {
        let mut bad = bytes[..header_end + 8].to_vec();
        bad[header_end + 4..].copy_from_slice(&size.to_le_bytes());
        assert!(read_all(&bad).is_err(), "size {size}");
    }
    // A vector length of 2^32 - 1 events in a 300-event packet.
    let mut bad = bytes.clone();
    bad[header_end + 8 + 28..header_end + 8 + 32].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(read_all(&bad), Err(ReadError::Corrupt { .. })));
}

#[test]
fn packet_of_undeclared_stream_is_corrupt() {
    let (_, mut bytes) = small_files().remove(0);
    let header_end = packet_bounds(&bytes)[0];
    bytes[header_end] = 9;
    assert!(matches!(read_all(&bytes), Err(ReadError::Corrupt { .. })));
}

/// A hand-built `EventPacket` in another valid layout: no size prefix, a vtable after its
/// table with an extra (absent) field, padding between table and vector.
#[test]
fn other_flatbuffer_layouts_are_read() {
    let mut fb = Vec::new();
    fb.extend_from_slice(&8u32.to_le_bytes()); // root table at 8
    fb.extend_from_slice(b"EVTS");
    fb.extend_from_slice(&(-8i32).to_le_bytes()); // table at 8: vtable at 16
    fb.extend_from_slice(&12u32.to_le_bytes()); // field 0 at 12: vector at 24
    fb.extend_from_slice(&[8, 0, 8, 0, 4, 0, 0, 0]); // vtable: 8 bytes, table 8, fields +4, none
    fb.extend_from_slice(&2u32.to_le_bytes()); // vector length at 24
    for (t, x, y, on) in [(10i64, 3i16, 4i16, 1u8), (11, 5, 6, 0)] {
        fb.extend_from_slice(&t.to_le_bytes());
        fb.extend_from_slice(&x.to_le_bytes());
        fb.extend_from_slice(&y.to_le_bytes());
        fb.extend_from_slice(&[on, 0xaa, 0xbb, 0xcc]);
    }
    let mut bytes = write_file(&two_cameras(), Compression::None, &[]);
    bytes.extend_from_slice(&1i32.to_le_bytes()); // stream 1: camera 1
    bytes.extend_from_slice(&(fb.len() as i32).to_le_bytes());
    bytes.extend_from_slice(&fb);
    let got = read_all(&bytes).expect("read").events;
    assert_eq!(
        got,
        [
            (1, Event::new(3, 4, 10, true)),
            (1, Event::new(5, 6, 11, false))
        ]
    );
}

/// Frames, IMU samples and triggers of unknown or known types are skipped, and cameras are
/// numbered by their order among the event streams.
#[test]
fn non_event_streams_are_skipped_and_cameras_numbered() {
    let events = [
        (0, Event::new(1, 2, 3, true)),
        (1, Event::new(4, 5, 6, false)),
    ];
    let written = write_file(&two_cameras(), Compression::None, &events);
    let bounds = packet_bounds(&written);
    let xml = r#"<?xml version="1.0"?><dv version="2.0"><!-- a comment -->
        <node name="outInfo" path="/x/">
          <node name="7"><attr key="typeIdentifier" type="string">FRME</attr>
            <node name="info"><attr key="sizeX" type="int">9</attr></node></node>
          <node name="3" path="a>b"><attr key="typeIdentifier" type="string">EVTS</attr>
            <node name="info"><attr key="sizeX" type="int">346</attr>
              <attr key="sizeY" type="int">260</attr>
              <attr key="source" type="string">cam &amp; &#65;</attr></node></node>
          <node name="5"><attr key="typeIdentifier" type="string">IMUS</attr></node>
          <node name="1"><attr key="typeIdentifier" type="string">EVTS</attr><attr key="x"/></node>
        </node></dv>"#;
    // Our own IOHeader with this XML: reuse the writer's layout by patching its size fields.
    let header = build_io_header(xml);
    let mut bytes = b"#!AER-DAT4.0\r\n".to_vec();
    bytes.extend_from_slice(&header);
    let packet = |stream: i32, body: &[u8]| {
        let mut p = stream.to_le_bytes().to_vec();
        p.extend_from_slice(&(body.len() as i32).to_le_bytes());
        p.extend_from_slice(body);
        p
    };
    let ev0 = &written[bounds[0] + 8..bounds[1]];
    let ev1 = &written[bounds[1] + 8..bounds[2]];
    bytes.extend(packet(7, b"frame bytes, never decoded"));
    bytes.extend(packet(1, ev0));
    bytes.extend(packet(5, b""));
    bytes.extend(packet(3, ev1));
    let reader = Aedat4Reader::new(&bytes[..]).expect("header");
    assert_eq!(
        reader.info().cameras,
        [
            camera(0, 346, 260, "cam & A"),
            CameraInfo {
                id: 1,
                width: None,
                height: None,
                name: None
            }
        ]
    );
    let got = read_all_from(reader).expect("read");
    assert_eq!(got.skipped, 2);
    assert_eq!(got.events, [(1, events[0].1), (0, events[1].1)]);
}

/// A size-prefixed IOHeader (no compression) around `xml`, built independently of the writer.
fn build_io_header(xml: &str) -> Vec<u8> {
    let mut fb = Vec::new();
    fb.extend_from_slice(&20u32.to_le_bytes()); // root table at 20
    fb.extend_from_slice(b"IOHE");
    // vtable at 8: 10 bytes, table 12 bytes; compression and dataTablePosition absent
    // (defaults NONE and -1), infoNode at +8.
    fb.extend_from_slice(&[10, 0, 12, 0, 0, 0, 0, 0, 8, 0, 0, 0]);
    fb.extend_from_slice(&12i32.to_le_bytes()); // table at 20: vtable at 8
    fb.extend_from_slice(&[0; 4]);
    fb.extend_from_slice(&4u32.to_le_bytes()); // infoNode at 28 + 4
    fb.extend_from_slice(&(xml.len() as u32).to_le_bytes());
    fb.extend_from_slice(xml.as_bytes());
    fb.push(0);
    let mut out = (fb.len() as u32).to_le_bytes().to_vec();
    out.extend_from_slice(&fb);
    out
}

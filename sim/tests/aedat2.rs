//! AEDAT 2.0 writer against an independent decoder of DHP19's layout.

use evpose_core::Event;
use evpose_sim::aedat2::{address, HEADER};
use evpose_sim::write_dhp19;

fn decode(bytes: &[u8]) -> (Vec<String>, Vec<(u8, Event)>) {
    let mut lines = Vec::new();
    let mut at = 0;
    while bytes[at] == b'#' {
        let end = bytes[at..].windows(2).position(|w| w == b"\r\n").unwrap() + at + 2;
        lines.push(String::from_utf8(bytes[at..end].to_vec()).unwrap());
        at = end;
        if lines.last().unwrap().starts_with("#End Of ASCII Header") {
            break;
        }
    }
    let events = bytes[at..]
        .chunks_exact(8)
        .map(|r| {
            let a = u32::from_be_bytes([r[0], r[1], r[2], r[3]]);
            let t = u32::from_be_bytes([r[4], r[5], r[6], r[7]]);
            assert_eq!(a & 0x8000_0400, 0, "APS/special bits set");
            let y_raw = (a >> 22) & 0x1FF;
            // jAER's and DHP19's decoding: x = 345 − x_raw, y = 259 − y_raw (top-left origin).
            let x = 345 - ((a >> 12) & 0x3FF);
            let on = a & 0x800 != 0;
            let cam = (a & 0xF) as u8;
            assert_eq!(a & 0x3F0, 0, "bits 4–9 unused");
            (
                cam,
                Event::new(x as u16, (260 - 1 - y_raw) as u16, i64::from(t), on),
            )
        })
        .collect();
    (lines, events)
}

#[test]
fn round_trip_through_the_dhp19_layout() {
    let mut events = Vec::new();
    for i in 0..2000u32 {
        let c = (i % 4) as u8;
        let e = Event::new(
            (i * 7 % 346) as u16,
            (i * 13 % 260) as u16,
            i64::from(i) * 997,
            i % 3 == 0,
        );
        events.push((c, e));
    }
    events.push((3, Event::new(345, 259, i64::from(u32::MAX), true)));
    events.push((0, Event::new(0, 0, 0, false)));
    let mut buf = Vec::new();
    write_dhp19(&mut buf, &events).unwrap();
    let (lines, back) = decode(&buf);
    assert_eq!(lines, HEADER);
    assert_eq!(lines[0], "#!AER-DAT2.0\r\n");
    assert_eq!(lines[1], "# This is a raw AE data file - do not edit\r\n");
    assert_eq!(
        lines[2],
        "# AEChip: ch.unizh.ini.jaer.chip.multicamera.MultiDavis346BCameraChip\r\n"
    );
    assert_eq!(back, events);
    assert_eq!(buf.len(), HEADER.concat().len() + 8 * events.len());
}

#[test]
fn address_bits_match_the_spec() {
    // x = 5 (x_raw = 345 − 5 = 340, as DHP19's `X = sx − x` and jAER's `sx1 − x_raw` read it
    // back), y = 0 (top row → y_raw = 259), ON, camera 2.
    let a = address(2, &Event::new(5, 0, 0, true)).unwrap();
    assert_eq!(a, 259 << 22 | 340 << 12 | 1 << 11 | 2);
}

#[test]
fn out_of_range_events_are_refused() {
    let mut buf = Vec::new();
    assert!(write_dhp19(&mut buf, &[(4, Event::new(0, 0, 0, true))]).is_err());
    assert!(write_dhp19(&mut buf, &[(0, Event::new(346, 0, 0, true))]).is_err());
    assert!(write_dhp19(&mut buf, &[(0, Event::new(0, 260, 0, true))]).is_err());
    assert!(write_dhp19(&mut buf, &[(0, Event::new(0, 0, -1, true))]).is_err());
    assert!(write_dhp19(&mut buf, &[(0, Event::new(0, 0, 1 << 32, true))]).is_err());
}

//! Byte-level encoders for the event formats, written from the format descriptions
//! (`shared/docs/formats.md`, libcaer, jAER, Prophesee's format pages), independently of the
//! readers in `evpose_host::io`. Shared by `tests/formats.rs`, `tests/cli.rs` and
//! `benches/readers.rs` (included with `#[path]`).
#![allow(dead_code)]

/// One event as the tests state it: camera, x, y (top-left origin), t (µs), ON.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ev {
    pub cam: u8,
    pub x: u16,
    pub y: u16,
    pub t: i64,
    pub on: bool,
}

pub const fn ev(cam: u8, x: u16, y: u16, t: i64, on: bool) -> Ev {
    Ev { cam, x, y, t, on }
}

/// `n` deterministic pseudo-random events on a `w` × `h` sensor over `cams` cameras, time
/// starting at `t0` and rising by 0–3 µs per event.
pub fn synthetic(n: usize, w: u16, h: u16, cams: u8, t0: i64) -> Vec<Ev> {
    let mut s = 0x2545_f491_4f6c_dd1d_u64;
    let mut t = t0;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            t += (s >> 60) as i64 % 4;
            ev(
                (s >> 8) as u8 % cams,
                (s >> 16) as u16 % w,
                (s >> 32) as u16 % h,
                t,
                s & 1 == 1,
            )
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// AEDAT 2.0 (jAER): "#" header lines, then big-endian u32 address, u32 timestamp.

/// A jAER header naming `chip` (a Java class), optionally ending with the end marker.
pub fn aedat2_header(chip: Option<&str>, end_marker: bool) -> Vec<u8> {
    let mut h = String::from("#!AER-DAT2.0\r\n");
    h += "# This is a raw AE data file - do not edit\r\n";
    h += "# Data format is int32 address, int32 timestamp (8 bytes total), repeated for each event\r\n";
    h += "# Timestamps tick is 1 us\r\n";
    h += "# created Thu Dec 20 10:00:00 CET 2018\r\n";
    if let Some(c) = chip {
        h += &format!("# AEChip: {c}\r\n");
    }
    if end_marker {
        h += "#End Of ASCII Header\r\n";
    }
    h.into_bytes()
}

/// DAVIS polarity address of the picture's pixel `(x, y_top)` (top-left origin, jAER's
/// orientation): y_raw = height − 1 − y_top (bottom origin) in bits 22–30, x_raw = width − 1 − x
/// in 12–21 (jAER decodes `x = sx1 − x_raw`), ON in bit 11.
pub fn davis_addr(x: u16, y_top: u16, on: bool, width: u16, height: u16) -> u32 {
    let (x_raw, y_raw) = (u32::from(width - 1 - x), u32::from(height - 1 - y_top));
    (y_raw << 22) | (x_raw << 12) | (u32::from(on) << 11)
}

/// DVS128 address (top-left `x`, `y_top`): x_raw = 127 - x in bits 1–7, the row from the
/// bottom (127 - y_top, AEDAT 2.0's lower-left origin) in bits 8–14, bit 0 = 0 for ON.
pub fn dvs128_addr(x: u16, y_top: u16, on: bool) -> u32 {
    (u32::from(127 - y_top) << 8) | (u32::from(127 - x) << 1) | u32::from(!on)
}

pub fn aedat2_record(out: &mut Vec<u8>, addr: u32, ts: u32) {
    out.extend_from_slice(&addr.to_be_bytes());
    out.extend_from_slice(&ts.to_be_bytes());
}

/// A DAVIS346 file (`dhp19`: camera id in address bits 0–3, MultiDavis346 chip).
pub fn aedat2_davis346(events: &[Ev], dhp19: bool) -> Vec<u8> {
    let chip = if dhp19 {
        "ch.unizh.ini.jaer.chip.multicamera.MultiDavis346BCameraChip"
    } else {
        "eu.seebetter.ini.chips.davis.DAVIS346B"
    };
    let mut out = aedat2_header(Some(chip), true);
    for e in events {
        let cam = if dhp19 { u32::from(e.cam) } else { 0 };
        aedat2_record(
            &mut out,
            davis_addr(e.x, e.y, e.on, 346, 260) | cam,
            e.t as u32,
        );
    }
    out
}

// ---------------------------------------------------------------------------------------------
// AEDAT 3.1 (libcaer): "#" header to "#!END-HEADER", then packets.

pub fn aedat3_header(sources: &[(i16, &str)]) -> Vec<u8> {
    let mut h = String::from("#!AER-DAT3.1\r\n#Format: RAW\r\n");
    for (id, name) in sources {
        h += &format!("#Source {id}: {name}\r\n");
    }
    h += "#Start-Time: 2017-06-12 10:00:00 (TZ+0200)\r\n#!END-HEADER\r\n";
    h.into_bytes()
}

#[allow(clippy::too_many_arguments)]
pub fn aedat3_packet_header(
    out: &mut Vec<u8>,
    ty: i16,
    source: i16,
    size: i32,
    ts_offset: i32,
    overflow: i32,
    capacity: i32,
    number: i32,
    valid: i32,
) {
    out.extend_from_slice(&ty.to_le_bytes());
    out.extend_from_slice(&source.to_le_bytes());
    for v in [size, ts_offset, overflow, capacity, number, valid] {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// libcaer polarity event: data = x << 17 | y << 2 | on << 1 | valid, then i32 timestamp.
pub fn aedat3_polarity(out: &mut Vec<u8>, x: u16, y: u16, on: bool, valid: bool, ts: i32) {
    let data = (u32::from(x) << 17) | (u32::from(y) << 2) | (u32::from(on) << 1) | u32::from(valid);
    out.extend_from_slice(&data.to_le_bytes());
    out.extend_from_slice(&ts.to_le_bytes());
}

/// A whole polarity packet of valid events (all from `source`, times < 2^31 · (overflow + 1)).
pub fn aedat3_polarity_packet(out: &mut Vec<u8>, source: i16, overflow: i32, events: &[Ev]) {
    let n = events.len() as i32;
    aedat3_packet_header(out, 1, source, 8, 4, overflow, n, n, n);
    for e in events {
        aedat3_polarity(out, e.x, e.y, e.on, true, (e.t & 0x7FFF_FFFF) as i32);
    }
}

/// A file with one source per camera (camera c is source c + 1), packets of up to 4096 events.
pub fn aedat3_file(events: &[Ev], cams: u8) -> Vec<u8> {
    let names: Vec<(i16, String)> = (0..cams)
        .map(|c| (i16::from(c) + 1, "DAVIS346B".to_string()))
        .collect();
    let refs: Vec<(i16, &str)> = names.iter().map(|(i, n)| (*i, n.as_str())).collect();
    let mut out = aedat3_header(&refs);
    for chunk in events.chunk_by(|a, b| a.cam == b.cam && a.t >> 31 == b.t >> 31) {
        for part in chunk.chunks(4096) {
            aedat3_polarity_packet(
                &mut out,
                i16::from(part[0].cam) + 1,
                (part[0].t >> 31) as i32,
                part,
            );
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Prophesee RAW and DAT.

pub fn raw_header(lines: &[&str]) -> Vec<u8> {
    let mut h = String::new();
    for l in lines {
        h += "% ";
        h += l;
        h += "\n";
    }
    h.into_bytes()
}

pub fn evt2_word(out: &mut Vec<u8>, w: u32) {
    out.extend_from_slice(&w.to_le_bytes());
}

/// EVT 2.0 CD word: type (0 OFF / 1 ON) << 28 | t low 6 bits << 22 | x << 11 | y.
pub fn evt2_cd(x: u16, y: u16, on: bool, t: i64) -> u32 {
    (u32::from(on) << 28) | (((t & 0x3F) as u32) << 22) | (u32::from(x) << 11) | u32::from(y)
}

/// EVT 2.0 TIME_HIGH word: 0x8 << 28 | (t >> 6) mod 2^28.
pub fn evt2_time_high(t: i64) -> u32 {
    (0x8 << 28) | (((t >> 6) as u32) & 0x0FFF_FFFF)
}

/// EVT 2.0 words for events (camera ignored): a TIME_HIGH whenever t >> 6 changes.
pub fn evt2_body(events: &[Ev]) -> Vec<u8> {
    let mut out = Vec::with_capacity(events.len() * 4 + 64);
    let mut high = None;
    for e in events {
        if high != Some(e.t >> 6) {
            high = Some(e.t >> 6);
            evt2_word(&mut out, evt2_time_high(e.t));
        }
        evt2_word(&mut out, evt2_cd(e.x, e.y, e.on, e.t));
    }
    out
}

/// EVT 2.1 words for events (camera ignored), whole words little-endian (a GenX320's order):
/// a TIME_HIGH whenever t >> 6 changes; events at one time, row and polarity with x ascending
/// within 32 of the first share a vector word (its upper half laid out as an EVT 2.0 word).
pub fn evt21_body(events: &[Ev]) -> Vec<u8> {
    let word = |out: &mut Vec<u8>, upper: u32, mask: u32| {
        out.extend_from_slice(&(u64::from(upper) << 32 | u64::from(mask)).to_le_bytes());
    };
    let mut out = Vec::new();
    let mut high = None;
    let mut i = 0;
    while let Some(e) = events.get(i) {
        if high != Some(e.t >> 6) {
            high = Some(e.t >> 6);
            word(&mut out, evt2_time_high(e.t), 0);
        }
        let mut mask = 1u32;
        i += 1;
        while let Some(f) = events.get(i) {
            let bit = u32::from(f.x.wrapping_sub(e.x));
            let next = (f.t, f.y, f.on) == (e.t, e.y, e.on) && f.x > e.x && bit < 32;
            if !next || bit <= 31 - mask.leading_zeros() {
                break;
            }
            mask |= 1 << bit;
            i += 1;
        }
        word(&mut out, evt2_cd(e.x, e.y, e.on, e.t), mask);
    }
    out
}

pub fn evt3_word(out: &mut Vec<u8>, ty: u16, payload: u16) {
    out.extend_from_slice(&((ty << 12) | (payload & 0xFFF)).to_le_bytes());
}

/// EVT 3.0 words for events: TIME_HIGH / TIME_LOW / ADDR_Y when they change; runs of events
/// with the same time, row and polarity and x within 12 of the run start become VECT_BASE_X +
/// VECT_12 words, single events EVT_ADDR_X.
pub fn evt3_body(events: &[Ev]) -> Vec<u8> {
    let mut out = Vec::with_capacity(events.len() * 2 + 64);
    let (mut high, mut low, mut row) = (None, None, None);
    let mut i = 0;
    while i < events.len() {
        let e = events[i];
        let h = (e.t >> 12) & 0xFFF;
        if high != Some(h) {
            high = Some(h);
            evt3_word(&mut out, 0x8, h as u16);
        }
        let l = e.t & 0xFFF;
        if low != Some(l) {
            low = Some(l);
            evt3_word(&mut out, 0x6, l as u16);
        }
        if row != Some(e.y) {
            row = Some(e.y);
            evt3_word(&mut out, 0x0, e.y);
        }
        // A vector gives its events in increasing x: only strictly increasing runs qualify.
        let mut j = i + 1;
        let mut mask = 1u16;
        let mut last_x = e.x;
        while j < events.len() {
            let f = events[j];
            if f.t != e.t || f.y != e.y || f.on != e.on || f.x <= last_x || f.x >= e.x + 12 {
                break;
            }
            mask |= 1 << (f.x - e.x);
            last_x = f.x;
            j += 1;
        }
        if j - i == 1 {
            evt3_word(&mut out, 0x2, (u16::from(e.on) << 11) | e.x);
        } else {
            evt3_word(&mut out, 0x3, (u16::from(e.on) << 11) | e.x);
            evt3_word(&mut out, 0x4, mask);
        }
        i = j;
    }
    out
}

/// A `.dat` file: header, type 0x0C size 8, records u32 t, u32 x | y << 14 | p << 28.
pub fn dat_file(events: &[Ev], width: u16, height: u16) -> Vec<u8> {
    let mut out = format!(
        "% Data file containing CD events.\n% Version 2\n% Date 2021-03-04 10:00:00\n% Height {height}\n% Width {width}\n"
    )
    .into_bytes();
    out.extend_from_slice(&[0x0C, 8]);
    for e in events {
        dat_record(
            &mut out,
            e.t as u32,
            u32::from(e.x) | (u32::from(e.y) << 14) | (u32::from(e.on) << 28),
        );
    }
    out
}

pub fn dat_record(out: &mut Vec<u8>, t: u32, w: u32) {
    out.extend_from_slice(&t.to_le_bytes());
    out.extend_from_slice(&w.to_le_bytes());
}

/// An Event Stream 2.0 DVS file (type 1): header, then per event the time difference (127-µs
/// overflow bytes first) with the polarity, u16 LE x and u16 LE y counted from the bottom row.
pub fn es_dvs_file(events: &[Ev], width: u16, height: u16) -> Vec<u8> {
    let mut out = b"Event Stream\x02\x00\x00\x01".to_vec();
    out.extend_from_slice(&width.to_le_bytes());
    out.extend_from_slice(&height.to_le_bytes());
    out.extend_from_slice(&es_dvs_body(events, height, 0));
    out
}

/// The events of an Event Stream DVS file, times from `t0`.
pub fn es_dvs_body(events: &[Ev], height: u16, t0: i64) -> Vec<u8> {
    let mut out = Vec::with_capacity(events.len() * 5);
    let mut prev = t0;
    for e in events {
        let mut dt = e.t - prev;
        prev = e.t;
        while dt >= 127 {
            out.push(0xFF);
            dt -= 127;
        }
        out.push(((dt as u8) << 1) | u8::from(e.on));
        out.extend_from_slice(&e.x.to_le_bytes());
        out.extend_from_slice(&(height - 1 - e.y).to_le_bytes());
    }
    out
}

/// Text lines `t x y p` with t in seconds (9 decimals: exact to the microsecond).
pub fn text_seconds(events: &[Ev]) -> Vec<u8> {
    let mut out = String::with_capacity(events.len() * 24);
    for e in events {
        use std::fmt::Write;
        let _ = writeln!(
            out,
            "{}.{:06}000 {} {} {}",
            e.t / 1_000_000,
            e.t % 1_000_000,
            e.x,
            e.y,
            u8::from(e.on)
        );
    }
    out.into_bytes()
}

/// An AEDAT 4.0 file holding only the header, for these cameras.
pub fn aedat4_header(cameras: &[evpose_host::io::CameraInfo]) -> Vec<u8> {
    use evpose_host::io::aedat4::{Aedat4Writer, Compression};
    Aedat4Writer::new(Vec::new(), cameras, Compression::Lz4)
        .and_then(|w| w.finish())
        .expect("in-memory header")
}

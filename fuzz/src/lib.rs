//! What the fuzz targets run, shared: each target is one line calling one of these.

use evpose_core::raster::{RasterConfig, WindowRule, MAX_HEIGHT, MAX_SLICES, MAX_WIDTH};
use evpose_core::{DType, Event, Rasterizer};
use evpose_host::io::{self, Batch, Format, OpenOptions};
use evpose_host::model::{AlignedBlob, CoreRunner};
use evpose_host::pipeline::vec_storage;

/// Reads every batch of `data` as `format` (`None`: detected). Errors end the read; the
/// batches must stay consistent (one camera per event).
pub fn read_all(data: &[u8], format: Option<Format>) {
    let opts = OpenOptions {
        format,
        ..OpenOptions::default()
    };
    let Ok(mut reader) = io::open_bytes(data.to_vec(), "fuzz input", &opts) else {
        return;
    };
    let mut batch = Batch::default();
    while let Ok(true) = reader.read_batch(&mut batch) {
        assert_eq!(batch.events.len(), batch.cameras.len());
    }
    let _ = reader.notes();
}

/// Parses `data` as a model blob, then the same bytes with the total length and CRC-32 made
/// right (so that mutations reach the structural checks behind the checksum); what parses runs
/// once on a fixed input.
pub fn blob(data: &[u8]) {
    parse_and_run(data);
    use evpose_core::model::{header, CRC};
    if data.len() >= header::CRC_FROM {
        let mut fixed = data.to_vec();
        let total = (fixed.len() as u32).to_le_bytes();
        fixed[header::TOTAL..header::TOTAL + 4].copy_from_slice(&total);
        let crc = CRC.checksum(&fixed[header::CRC_FROM..]).to_le_bytes();
        fixed[header::CRC..header::CRC + 4].copy_from_slice(&crc);
        parse_and_run(&fixed);
    }
}

fn parse_and_run(data: &[u8]) {
    let blob = AlignedBlob::new(data);
    let Ok(mut runner) = CoreRunner::new(&blob) else {
        return;
    };
    let n = match runner.model().input_points() {
        0 => 16,
        n => n.min(512),
    };
    let points: Vec<[f32; 5]> = (0..n)
        .map(|i| {
            let v = i as f32;
            [
                v % 346.0,
                v % 260.0,
                (v * 0.37) % 1.0,
                v % 3.0 - 1.0,
                1.0 + v % 4.0,
            ]
        })
        .collect();
    let _ = match runner.model().dtype() {
        DType::I8 => runner.run_i8(&points).map(|_| ()),
        DType::F32 => runner.run_f32(&points).map(|_| ()),
    };
}

/// A rasterizer whose configuration comes from the first 8 bytes and whose events come from
/// the rest (8 bytes each: x, y, a signed time step, polarity), fed in uneven batches; the
/// counters must add up.
pub fn raster(data: &[u8]) {
    let Some((head, rest)) = data.split_first_chunk::<8>() else {
        return;
    };
    let u16_at = |i: usize| u16::from_le_bytes([head[i], head[i + 1]]);
    let config = RasterConfig {
        width: u16_at(0) % (MAX_WIDTH + 2),
        height: u16_at(2) % (MAX_HEIGHT + 2),
        slices: head[4] % (MAX_SLICES + 2),
        window: if head[5] & 1 == 0 {
            WindowRule::Events(u32::from(u16_at(6) % 5000))
        } else {
            WindowRule::Duration(u32::from(u16_at(6)) * 37)
        },
    };
    let capacity = 1 + usize::from(u16_at(6) % 4096);
    let storage = vec_storage(capacity, &config);
    let Ok(mut raster) = Rasterizer::new(config, storage) else {
        return;
    };
    let mut t = 0i64;
    let events: Vec<Event> = rest
        .chunks_exact(8)
        .map(|c| {
            t += i64::from(i16::from_le_bytes([c[4], c[5]]));
            Event::new(
                u16::from_le_bytes([c[0], c[1]]) % (MAX_WIDTH + 16),
                u16::from_le_bytes([c[2], c[3]]) % (MAX_HEIGHT + 16),
                t,
                c[6] & 1 == 1,
            )
        })
        .collect();
    let mut fed = 0usize;
    let mut i = 0usize;
    while fed < events.len() {
        let step = 1 + (rest.get(i).copied().unwrap_or(7) as usize % 97);
        i += 1;
        let mut part = &events[fed..(fed + step).min(events.len())];
        while !part.is_empty() {
            let (used, window) = raster.extend(part);
            if let Some(w) = window {
                assert!(w.len() <= capacity);
            }
            assert!(used > 0 || part.is_empty(), "no progress");
            fed += used;
            part = &part[used..];
        }
    }
    let w = raster.flush();
    assert!(w.len() <= capacity);
    let s = *raster.stats();
    assert_eq!(
        s.accepted + s.dropped_out_of_range,
        events.len() as u64,
        "{s:?}"
    );
}

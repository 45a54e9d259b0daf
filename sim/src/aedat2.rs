//! jAER AEDAT 2.0 output in DHP19's four-camera layout.
//!
//! ```text
//! "#!AER-DAT2.0\r\n"
//! "# This is a raw AE data file - do not edit\r\n"
//! "# AEChip: ch.unizh.ini.jaer.chip.multicamera.MultiDavis346BCameraChip\r\n"
//! "#End Of ASCII Header\r\n"
//! records: u32 big-endian address, u32 big-endian timestamp (µs)
//! ```
//!
//! Address: `y_raw = 259 − y` in bits 22–30 (jAER's bottom-left origin), `x_raw = 345 − x` in
//! bits 12–21 (jAER decodes `x = 345 − x_raw`), ON in bit 11, the camera channel in bits 0–3;
//! bits 31 (APS/IMU) and 10 (special) clear. An event at `(x, y)` of the picture (top-left
//! origin) is where DHP19's and jAER's code put it, and where DHP19's P matrices project.

use std::io::{self, Write};

use evpose_core::Event;

/// The header lines, in order, each ending in CR LF.
pub const HEADER: [&str; 4] = [
    "#!AER-DAT2.0\r\n",
    "# This is a raw AE data file - do not edit\r\n",
    "# AEChip: ch.unizh.ini.jaer.chip.multicamera.MultiDavis346BCameraChip\r\n",
    "#End Of ASCII Header\r\n",
];

/// DAVIS346 width.
pub const WIDTH: u16 = 346;
/// DAVIS346 height.
pub const HEIGHT: u16 = 260;

/// The 32-bit address of `event` from camera `channel`.
///
/// # Errors
/// [`io::ErrorKind::InvalidInput`] for a channel above 3 or a pixel outside 346 × 260.
pub fn address(channel: u8, e: &Event) -> io::Result<u32> {
    if channel > 3 || e.x >= WIDTH || e.y >= HEIGHT {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("event {e:?} on channel {channel} does not fit DHP19's 4 × 346 × 260"),
        ));
    }
    let (x_raw, y_raw) = (u32::from(WIDTH - 1 - e.x), u32::from(HEIGHT - 1 - e.y));
    Ok(y_raw << 22 | x_raw << 12 | u32::from(e.on) << 11 | u32::from(channel))
}

/// Writes `events` as a DHP19 AEDAT 2.0 file. Timestamps are written as they are (µs), so they
/// must lie in `0..2³²`.
///
/// # Errors
/// I/O errors of `w`; [`io::ErrorKind::InvalidInput`] for an event that does not fit (see
/// [`address`]) or a timestamp outside `u32`.
pub fn write_dhp19<W: Write>(w: W, events: &[(u8, Event)]) -> io::Result<()> {
    let mut w = io::BufWriter::new(w);
    for line in HEADER {
        w.write_all(line.as_bytes())?;
    }
    for (c, e) in events {
        let t = u32::try_from(e.t).map_err(|_| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("timestamp {} µs does not fit u32", e.t),
            )
        })?;
        w.write_all(&address(*c, e)?.to_be_bytes())?;
        w.write_all(&t.to_be_bytes())?;
    }
    w.flush()
}

//! `.npy` event arrays: shape (N, 4), columns `[x, y, t_us, p]`, any numeric dtype.
//!
//! Times are microseconds: a time with a fraction of a microsecond is refused (times in
//! seconds or milliseconds would otherwise round to a handful of microseconds), unless
//! `--time-unit` ([`super::OpenOptions::time_unit`]) states the unit; the times are then
//! scaled to microseconds and rounded half away from zero. An array whose first events mostly
//! go back in time is refused too (`io::OrderCheck`): its columns are in another order.

use std::io::Read;

use evpose_core::Event;

use super::{
    Batch, EventReader, Format, OrderCheck, ReadError, StreamInfo, TimeUnit, BATCH_EVENTS,
};
use crate::array::{stream_f64, F64Values};

/// Streaming reader of an (N, 4) `.npy` event array.
pub struct NpyReader<R> {
    values: F64Values,
    _reader: std::marker::PhantomData<fn() -> R>,
    info: StreamInfo,
    rows_read: u64,
    rows: u64,
    /// A batch's rows, read in one block.
    rows_buf: Vec<[f64; 4]>,
    /// Microseconds per unit of the time column, when `--time-unit` states its unit (worked
    /// out once, not per row).
    scale: Option<f64>,
    order: OrderCheck,
}

impl<R: Read + Send + 'static> NpyReader<R> {
    /// Parses the header; rejects arrays that are not (N, 4). `unit`: the time column's unit,
    /// if stated (else microseconds, whole).
    pub fn new(inner: R, unit: Option<TimeUnit>) -> Result<Self, ReadError> {
        let (shape, values) = stream_f64(inner).map_err(|e| ReadError::Corrupt {
            offset: 0,
            message: format!("bad npy header: {e}"),
        })?;
        let rows = match shape[..] {
            [n, 4] => n,
            _ => {
                return Err(ReadError::Corrupt {
                    offset: 0,
                    message: format!(
                        "expected an (N, 4) array [x, y, t_us, p], got shape {shape:?}"
                    ),
                })
            }
        };
        Ok(Self {
            values,
            _reader: std::marker::PhantomData,
            info: StreamInfo {
                format: Format::Npy,
                cameras: Vec::new(),
                event_count: Some(rows),
            },
            rows_read: 0,
            rows,
            rows_buf: Vec::new(),
            scale: unit.map(|u| 10f64.powi(u.exponent_to_us())),
            order: OrderCheck::default(),
        })
    }
}

/// Converts one `[x, y, t, p]` row, rejecting values that are not event fields: `t` times
/// `scale` microseconds (rounded), or without a scale whole microseconds.
pub fn event_from_row(row: [f64; 4], index: u64, scale: Option<f64>) -> Result<Event, ReadError> {
    let [x, y, t, p] = row;
    // An integer in 0..=65535 exactly when the saturating conversion gives it back (NaN, a
    // fraction or a value out of range does not); no `trunc` call (a library call on x86-64
    // without SSE4.1).
    let coord = |v: f64| {
        let c = v as u16;
        (f64::from(c) == v).then_some(c)
    };
    let bad = |what: &str, v: f64| ReadError::Corrupt {
        offset: 0,
        message: format!("row {index}: {what} {v} is not valid"),
    };
    let x = coord(x).ok_or_else(|| bad("x", x))?;
    let y = coord(y).ok_or_else(|| bad("y", y))?;
    let t_us = scale.map_or(t, |s| t * s);
    // i64 µs; f64 holds integers exactly up to 2^53 µs (285 years).
    if !(t_us.is_finite() && t_us.abs() < 9.007_199_254_740_992e15) {
        return Err(bad("timestamp", t));
    }
    // Below 2^53 the truncation is exact: a fraction shows as a difference.
    if scale.is_none() && (t as i64) as f64 != t {
        return Err(ReadError::Corrupt {
            offset: 0,
            message: format!(
                "row {index}: timestamp {t} is not a whole number of microseconds: are the \
                 times in seconds or milliseconds? State the unit with --time-unit s|ms|us|ns \
                 (us rounds)"
            ),
        });
    }
    let on = if p == 1.0 {
        true
    } else if p == 0.0 || p == -1.0 {
        false
    } else {
        return Err(bad("polarity (expected 0/1 or -1/1)", p));
    };
    Ok(Event::new(x, y, round_half_away(t_us), on))
}

/// `t.round() as i64` for `|t| < 2^53`, without the library call that `round` is on x86-64: the
/// truncation and the fraction `t − trunc(t)` are exact there, and a fraction of at least one
/// half (in magnitude) rounds away from zero, as `f64::round` does.
fn round_half_away(t: f64) -> i64 {
    let r = t as i64;
    let f = t - r as f64;
    if f >= 0.5 {
        r + 1
    } else if f <= -0.5 {
        r - 1
    } else {
        r
    }
}

impl<R: Read + Send + 'static> EventReader for NpyReader<R> {
    fn info(&self) -> &StreamInfo {
        &self.info
    }

    fn read_batch(&mut self, batch: &mut Batch) -> Result<bool, ReadError> {
        batch.clear();
        // A batch's rows in one read (its values converted a block at a time), then each row
        // checked and converted to an event.
        let n = (self.rows - self.rows_read).min(BATCH_EVENTS as u64) as usize;
        self.rows_buf.resize(n, [0.0; 4]);
        match self.values.read(self.rows_buf.as_flattened_mut()) {
            Ok(got) if got == 4 * n => {}
            Err(e) if e.kind() != std::io::ErrorKind::UnexpectedEof => return Err(e.into()),
            _ => {
                return Err(ReadError::Truncated {
                    offset: 0,
                    what: "the npy data (fewer rows than the header states)",
                })
            }
        }
        batch.events.reserve(n);
        let mut result = Ok(());
        for &row in &self.rows_buf {
            match event_from_row(row, self.rows_read, self.scale) {
                Ok(e) => batch.events.push(e),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
            self.rows_read += 1;
        }
        batch.cameras.resize(batch.events.len(), 0);
        result?;
        self.order.check(&batch.events, "[x, y, t_us, p]")?;
        Ok(!batch.is_empty())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_convert_like_the_float_library() {
        // Coordinates: integers in range pass, anything else is refused, as with `fract` and a
        // range test; times: `round` (half away from zero) on both sides of every half.
        let coords = [
            0.0,
            -0.0,
            1.0,
            345.0,
            65_535.0,
            65_536.0,
            -1.0,
            0.5,
            2.25,
            f64::NAN,
            f64::INFINITY,
        ];
        for c in coords {
            let want = (c.fract() == 0.0 && (0.0..=65_535.0).contains(&c)).then_some(c as u16);
            let got = event_from_row([c, 1.0, 0.0, 1.0], 0, None)
                .ok()
                .map(|e| e.x);
            assert_eq!(got, want, "x = {c}");
        }
        let mut ts = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            0.49999999999999994,
            1e15 + 0.5,
        ];
        ts.extend((0..2_000).map(|i| (i as f64 - 1_000.0) * 0.25 + 1e9));
        ts.extend([9.007_199_254_740_99e15, -9.007_199_254_740_99e15]);
        for t in ts {
            assert_eq!(round_half_away(t), t.round() as i64, "t = {t}");
        }
    }
}

//! `.npy` event arrays: shape (N, 4), columns `[x, y, t_us, p]`, any numeric dtype.

use std::io::Read;

use evpose_core::Event;

use super::{Batch, EventReader, Format, ReadError, StreamInfo, BATCH_EVENTS};
use crate::array::{stream_f64, Values};

/// Streaming reader of an (N, 4) `.npy` event array.
pub struct NpyReader<R> {
    values: Values,
    _reader: std::marker::PhantomData<fn() -> R>,
    info: StreamInfo,
    rows_read: u64,
    rows: u64,
}

impl<R: Read + Send + 'static> NpyReader<R> {
    /// Parses the header; rejects arrays that are not (N, 4).
    pub fn new(inner: R) -> Result<Self, ReadError> {
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
        })
    }

    fn next_row(&mut self) -> Result<[f64; 4], ReadError> {
        let mut row = [0.0; 4];
        for v in &mut row {
            *v = match self.values.next() {
                Some(Ok(v)) => v,
                Some(Err(e)) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                    return Err(ReadError::Truncated {
                        offset: 0,
                        what: "the npy data (fewer rows than the header states)",
                    })
                }
                Some(Err(e)) => return Err(e.into()),
                None => {
                    return Err(ReadError::Truncated {
                        offset: 0,
                        what: "the npy data (fewer rows than the header states)",
                    })
                }
            };
        }
        Ok(row)
    }
}

/// Converts one `[x, y, t_us, p]` row, rejecting values that are not event fields.
pub fn event_from_row(row: [f64; 4], index: u64) -> Result<Event, ReadError> {
    let [x, y, t, p] = row;
    let coord =
        |v: f64| (v.fract() == 0.0 && (0.0..=f64::from(u16::MAX)).contains(&v)).then_some(v as u16);
    let bad = |what: &str, v: f64| ReadError::Corrupt {
        offset: 0,
        message: format!("row {index}: {what} {v} is not valid"),
    };
    let x = coord(x).ok_or_else(|| bad("x", x))?;
    let y = coord(y).ok_or_else(|| bad("y", y))?;
    // i64 µs; f64 holds integers exactly up to 2^53 µs (285 years).
    if !(t.is_finite() && t.abs() < 9.007_199_254_740_992e15) {
        return Err(bad("timestamp", t));
    }
    let on = if p == 1.0 {
        true
    } else if p == 0.0 || p == -1.0 {
        false
    } else {
        return Err(bad("polarity (expected 0/1 or -1/1)", p));
    };
    Ok(Event::new(x, y, t.round() as i64, on))
}

impl<R: Read + Send + 'static> EventReader for NpyReader<R> {
    fn info(&self) -> &StreamInfo {
        &self.info
    }

    fn read_batch(&mut self, batch: &mut Batch) -> Result<bool, ReadError> {
        batch.clear();
        while self.rows_read < self.rows && batch.len() < BATCH_EVENTS {
            let row = self.next_row()?;
            batch.push(0, event_from_row(row, self.rows_read)?);
            self.rows_read += 1;
        }
        Ok(!batch.is_empty())
    }
}

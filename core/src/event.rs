//! The event type every stage consumes.

/// One event-camera event: a brightness change at a pixel.
///
/// Pixels are 0-based with the origin at the top-left corner of the sensor; readers convert
/// formats with another origin (jAER's bottom-left) before events reach the core.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Event {
    /// Column, `0..width`.
    pub x: u16,
    /// Row, `0..height`.
    pub y: u16,
    /// Timestamp in microseconds. Absolute sensor clocks (DV stores Unix µs, about 2^51) fit.
    pub t: i64,
    /// Polarity: `true` for an ON (brightness increase) event.
    pub on: bool,
}

impl Event {
    /// Creates an event.
    pub const fn new(x: u16, y: u16, t: i64, on: bool) -> Self {
        Self { x, y, t, on }
    }
}

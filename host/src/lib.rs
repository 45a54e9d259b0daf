//! # evpose-host
//!
//! The std side of evpose: event file readers, `.npy` helpers, the rasterization pipeline over
//! whole recordings, benchmarks, and the `evpose` command-line tool (a thin binary over
//! [`cli`]).
#![deny(missing_docs)]

pub mod cli;
pub mod dhp19;
pub mod io;
pub mod model;
pub mod npy;
pub mod pipeline;

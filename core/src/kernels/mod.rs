//! Matrix-vector kernels of the engines: `out[o] = bias[o] + Σ_k w[o·K + k] · x[k]`.
//!
//! [`reference`] is the specification: plain scalar loops. Optimized kernels must give the same
//! integers (`==`, no tolerance) and are tested against it.

pub mod reference;

pub use reference::{matvec_f32, matvec_i16, matvec_i8};

//! # evpose-host
//!
//! The std side of evpose, a library with a thin command-line tool over it (`evpose`, in
//! [`cli`]): event file readers, the per-window pipeline over whole recordings, poses, model
//! import and quantization, parity with an independent engine, budgets and benchmarks.
//!
//! | stage | module |
//! |---|---|
//! | events in | [`io`] (every format, files or memory), [`summary`], [`convert`], [`simulate`] (synthetic DHP19-style recordings) |
//! | windows → estimates | [`pipeline`] (any reader through a core stage), [`run`] (the main job: multi-camera windows, confidences, filter, 3-D, ground truth; the output schema, once) |
//! | 3-D | [`dhp19`] (calibration), [`triangulate`] (window pairing, 3-D joints) |
//! | ground truth | [`dataset`] (labelled windows for training), [`eval`] (MPJPE 2-D and 3-D) |
//! | models | [`model`] (blobs, quantization; ONNX and tract with feature `onnx`), [`inputs`], [`parity`] |
//! | costs | [`budget`] (MACs, bytes, firmware images), [`latency`] (MCU latency from measured instruction counts), [`bench`](mod@bench) |
//! | pictures | [`render`] (event frames with skeletons) |
//! | files | [`array`](mod@array) (`.npy`), [`assets`] (what the binary embeds) |
//!
//! Feature `onnx` (default): ONNX import, the quantized ONNX twin and tract. Without it the
//! runtime builds without tract.
#![deny(missing_docs)]

pub mod array;
pub mod assets;
pub mod bench;
pub mod budget;
pub mod cli;
pub mod convert;
pub mod dataset;
pub mod dhp19;
pub mod eval;
pub mod inputs;
pub mod io;
pub mod latency;
pub mod model;
pub mod parity;
pub mod pipeline;
pub mod render;
pub mod run;
pub mod simulate;
pub mod summary;
pub mod triangulate;

/// A seeded xorshift64 stream of `u64`s, for unit tests' inputs.
#[cfg(test)]
pub(crate) fn test_rng(seed: u64) -> impl FnMut() -> u64 {
    let mut s = seed | 1;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    }
}

//! # evpose-core
//!
//! Human pose estimation from event cameras, after Chen et al., "Efficient Human Pose Estimation
//! via 3D Event Point Cloud" (3DV 2022), for microcontrollers: `no_std`, no allocator, every
//! buffer sized at compile time or borrowed from the caller.
//!
//! The pipeline, one module per stage:
//!
//! | stage | module | holds |
//! |---|---|---|
//! | events | [`event`] | the [`Event`] type |
//! | sensor words | [`evt`] | Prophesee EVT 2.0 / 2.1 / 3.0 streams decoded into events, state kept across buffers |
//! | rasterization | [`raster`] | streaming window → event point cloud `[x, y, t_avg, p_acc, cnt]` |
//! | sampling | [`sample`] | `M` points → `N` network inputs, seeded and reproducible |
//! | model | [`model`] | the `.evq` model blob, validated and read in place |
//! | quantization | [`quant`] | the int8 engine's rounding and requantization, defined once |
//! | inference | [`infer`] | the inference [`Plan`]: f32 and int8 PointNet engines, fused per point, fixed scratch |
//! | kernels | [`kernels`] | matrix kernels (row-major and packed weights), requantization, pooling: scalar reference and optimized versions |
//! | decoding | [`simdr`] | SimDR labels and argmax decoding to 2-D joints |
//! | confidence | [`confidence`] | per-joint confidence: softmax mass near each argmax |
//! | temporal filter | [`smooth`] | joints over windows: confidence-gated One-Euro (causal) or a confidence-weighted fixed-lag mean |
//! | per window | [`pipeline`] | one window of events in, one estimate out: the loop every pipeline runs |
//! | skeleton | [`skeleton`] | DHP19's 13 joints: order, names, lines |
//! | triangulation | `geometry` | projection and two-view triangulation of joints to 3-D (feature `geometry`; its docs: `cargo doc -p evpose-core --features geometry`) |
//!
//! Bad input never panics: it yields a typed error or a counted drop.
//!
//! ```
//! use evpose_core::{Davis346Storage, Event, Pushed, RasterConfig, Rasterizer};
//!
//! let mut r = Rasterizer::new(RasterConfig::DAVIS346, Davis346Storage::new()).unwrap();
//! for i in 0..7_500u16 {
//!     let e = Event::new(i % 346, i % 260, i64::from(i), i % 2 == 0);
//!     if let Pushed::Window(w) = r.push(e) {
//!         assert_eq!(w.summary().events, 7_500);
//!         assert!(w.len() > 0);
//!     }
//! }
//! ```
#![cfg_attr(not(test), no_std)]
#![deny(unsafe_code)]
#![deny(unsafe_op_in_unsafe_fn)]
#![warn(clippy::undocumented_unsafe_blocks)]
#![deny(missing_docs)]
#![warn(trivial_numeric_casts, unused_qualifications)]

pub mod confidence;
pub mod event;
pub mod evt;
#[cfg(feature = "geometry")]
pub mod geometry;
pub mod infer;
pub mod kernels;
pub mod model;
pub mod pipeline;
pub mod quant;
pub mod raster;
pub mod sample;
pub mod simdr;
pub mod skeleton;
pub mod smooth;

pub use event::Event;
pub use infer::{
    pack_layers, packed_bytes, scratch_words, scratch_words_for_block, widen_point_layers,
    widened_words, InferError, PackedLayout, PackedWeights, Plan, Stage, WidenedWeights,
};
pub use model::{DType, Model, ModelError};
pub use pipeline::{Estimate, Estimator, Session, Workspace};
pub use raster::{
    ConfigError, Davis346Storage, InlineStorage, Point, Pushed, RasterBuffers, RasterConfig,
    RasterStats, RasterStorage, Rasterizer, Window, WindowRule,
};
pub use sample::{rng_from_seed, sample_indices, sample_window, SampleRng};
pub use simdr::{decode, Joint2d};

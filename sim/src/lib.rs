//! # evpose-sim
//!
//! An event-camera simulator for training evpose on DHP19-like data: a randomized capsule
//! body performs one of DHP19's 33 movements in front of four calibrated DAVIS346 cameras, a
//! ray caster renders intensity, and a DVS pixel model with noise turns it into events; the
//! ground truth is the 13 joints at 100 Hz.
//!
//! | module | holds |
//! |---|---|
//! | [`body`] | 13-joint skeleton (DHP19 order), [`Subject`], capsule body, forward kinematics |
//! | [`motion`] | [`Movement`] (33 + `NoPerson`), per-recording [`motion::Motion`], [`motion::Stage`] |
//! | [`render`] | textured static room, ray-cast capsules, pixel convention |
//! | [`pixel`] | DVS pixel model and noise, randomized [`SensorParams`] |
//! | [`recording`] | [`simulate`] / [`simulate_many`]: events of 4 cameras + ground truth |
//! | [`aedat2`] | [`write_dhp19`]: jAER AEDAT 2.0 as DHP19 stores it |
//!
//! World frame: DHP19's Vicon frame, millimetres, +Z up, floor `z = 0`; the stage (where the
//! cameras' central rays meet) is derived from the cameras (see [`motion::Stage`]).
//!
//! ```
//! use evpose_core::geometry::Camera;
//! use evpose_sim::{simulate, Movement, PixelModel, RecordingSpec};
//!
//! // Four cameras 3 m from the origin, 2 m up, looking at (0, 0, 900) (f = 340 px).
//! let cam = |x: f64, y: f64| {
//!     let c = [x, y, 2000.0];
//!     let f = [-x, -y, -1100.0];
//!     let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
//!     let f = [f[0] / n, f[1] / n, f[2] / n];
//!     let r = { let r = [f[1], -f[0], 0.0]; let m = (r[0] * r[0] + r[1] * r[1]).sqrt(); [r[0] / m, r[1] / m, 0.0] };
//!     let u = [r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]];
//!     let row = |a: [f64; 3], k: f64, o: f64| {
//!         let v = [340.0 * a[0] + o * f[0], 340.0 * a[1] + o * f[1], 340.0 * a[2] + o * f[2]];
//!         [v[0], v[1], v[2], -(v[0] * c[0] + v[1] * c[1] + v[2] * c[2]) * k]
//!     };
//!     let p = [row(r, 1.0, 173.0), row(u, 1.0, 130.0), { let t = row([0.0; 3], 1.0, 1.0); [f[0], f[1], f[2], t[3]] }];
//!     Camera::new(p, c, 346, 260).unwrap()
//! };
//! let cameras = [cam(2500.0, 0.0), cam(-2500.0, 0.0), cam(-1800.0, -2000.0), cam(1800.0, -2000.0)];
//! let spec = RecordingSpec {
//!     seed: 1,
//!     subject: 0,
//!     movement: Movement::JumpingJacks,
//!     seconds: 0.3,
//!     pixel: PixelModel::V2,
//! };
//! let rec = simulate(&spec, &cameras);
//! assert_eq!(rec.gt_mm.len(), 30);
//! assert!(rec.events.windows(2).all(|w| w[0].1.t <= w[1].1.t));
//! let mut file = Vec::new();
//! evpose_sim::write_dhp19(&mut file, &rec.events).unwrap();
//! assert_eq!(file.len(), evpose_sim::aedat2::HEADER.concat().len() + 8 * rec.events.len());
//! ```
#![deny(missing_docs)]
#![deny(unsafe_code)]

pub mod aedat2;
pub mod body;
pub mod motion;
pub mod pixel;
pub mod recording;
pub mod render;
mod rng;
mod v3;

pub use aedat2::write_dhp19;
pub use body::{Subject, JOINTS, JOINT_NAMES};
pub use motion::Movement;
pub use pixel::{PixelModel, SensorParams};
pub use recording::{simulate, simulate_many, Recording, RecordingSpec};

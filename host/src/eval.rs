//! `evpose eval`: MPJPE of a model (or of the mean-pose baseline) on an `evpose dataset`.
//!
//! - **MPJPE2D** (pixels): per sample, the decoded joints (integer argmax of each SimDR axis)
//!   against the integer labels, Euclidean distance, averaged over the visible joints of all
//!   samples (masked joints excluded), as the paper's code computes it.
//! - **MPJPE3D** (mm): the predictions of the two front cameras (channels 2 and 3) for the same
//!   window are triangulated with DHP19's calibration ([`evpose_core::geometry`]) and compared
//!   with the window's 3-D label, averaged over the joints of all such windows (`--label mean`
//!   datasets only: a `--label last` dataset's samples of one window are no pair, and get no
//!   3-D figure).
//!
//! Both also per camera, per movement and per joint. Synthetic-data figures are not DHP19
//! figures; the report says which data it measured.

use std::collections::BTreeMap;

use anyhow::{bail, Result};
use evpose_core::geometry::{triangulate, triangulate_views, Camera};
use serde::Serialize;

use crate::dataset::{Dataset, JOINTS};

/// Predicted joints of one sample, pixels `(x, y)`.
pub type Joints2d = [[f32; 2]; JOINTS];

/// One sample's prediction: decoded joints and their confidences
/// ([`evpose_core::confidence`]; 1 where the model gives none).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prediction {
    /// Joints, pixels.
    pub joints: Joints2d,
    /// Confidence per joint, in [0, 1].
    pub confidence: [f32; JOINTS],
}

impl Prediction {
    /// The joints as the core's filters take them (whole model pixels, as decoded).
    pub fn core_joints(&self) -> [evpose_core::Joint2d; JOINTS] {
        self.joints.map(|[x, y]| evpose_core::Joint2d {
            x: x as u16,
            y: y as u16,
        })
    }

    /// Decodes the heads `x` (`J × width`) and `y` (`J × height`) with logit `scales`
    /// ([`evpose_core::Model::head_scales`]; `None`: confidence 1 for every joint).
    pub fn from_heads<T: evpose_core::confidence::HeadValue>(
        x: &[T],
        y: &[T],
        width: usize,
        height: usize,
        scales: Option<[f32; 2]>,
    ) -> Result<Self> {
        let mut joints = [evpose_core::Joint2d::default(); JOINTS];
        evpose_core::decode(x, y, width, height, &mut joints)?;
        let mut confidence = [1f32; JOINTS];
        if let Some(scales) = scales {
            evpose_core::confidence::joints(x, y, width, height, scales, &joints, &mut confidence)?;
        }
        Ok(Self {
            joints: joints.map(|p| [f32::from(p.x), f32::from(p.y)]),
            confidence,
        })
    }
}

/// Each recording's samples of one camera, in window order: the sequences a filter runs over.
/// An error for a dataset without window times (written before `span_us.npy` existed): the
/// filters' time steps come from them.
fn sequences(ds: &Dataset) -> Result<Vec<Vec<usize>>> {
    if !ds.span_us.is_empty() && ds.span_us.iter().all(|s| *s == [0, 0]) {
        bail!("the dataset has no window times (span_us.npy): rebuild it to filter over time");
    }
    let mut sequences: BTreeMap<(u32, u8), Vec<usize>> = BTreeMap::new();
    for i in 0..ds.len() {
        sequences
            .entry((ds.recording[i], ds.camera[i]))
            .or_default()
            .push(i);
    }
    Ok(sequences
        .into_values()
        .map(|mut rows| {
            rows.sort_by_key(|&i| ds.window[i]);
            rows
        })
        .collect())
}

/// The predictions after the confidence-gated temporal filter ([`evpose_core::smooth`]), run
/// over each recording's windows in order, camera by camera, with each window's last event
/// time as its time.
pub fn smooth(
    ds: &Dataset,
    predictions: &[Prediction],
    params: evpose_core::smooth::SmoothParams,
) -> Result<Vec<Joints2d>> {
    use evpose_core::smooth::{AxisState, Smoother};
    if predictions.len() != ds.len() {
        bail!("{} predictions for {} samples", predictions.len(), ds.len());
    }
    let mut out: Vec<Joints2d> = predictions.iter().map(|p| p.joints).collect();
    let mut state = [AxisState::default(); 2 * JOINTS];
    for rows in sequences(ds)? {
        let mut f = Smoother::new(params, &mut state)?;
        for &i in &rows {
            let p = &predictions[i];
            let joints = p.core_joints();
            f.update(ds.span_us[i][1], &joints, &p.confidence, &mut out[i])
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
    }
    Ok(out)
}

/// The predictions after the fixed-lag filter ([`evpose_core::smooth::FixedLag`]: each window
/// the confidence-weighted mean of `params.lag` windows either side), run over each recording's
/// windows in order, camera by camera, with each window's last event time as its time.
pub fn smooth_fixed_lag(
    ds: &Dataset,
    predictions: &[Prediction],
    params: evpose_core::smooth::LagParams,
) -> Result<Vec<Joints2d>> {
    use evpose_core::smooth::{FixedLag, Held, LagSlot};
    if predictions.len() != ds.len() {
        bail!("{} predictions for {} samples", predictions.len(), ds.len());
    }
    let mut out: Vec<Joints2d> = predictions.iter().map(|p| p.joints).collect();
    let mut slots = vec![LagSlot::default(); FixedLag::slots_for(params.lag)];
    let mut held = vec![Held::default(); slots.len() * JOINTS];
    let lag_err = |e: evpose_core::smooth::LagError| anyhow::anyhow!("{e}");
    for rows in sequences(ds)? {
        let mut f =
            FixedLag::with_params(params, JOINTS, &mut slots, &mut held).map_err(lag_err)?;
        // Window numbers count this sequence's pushes from 0: positions in `rows`.
        let pop = |f: &mut FixedLag<'_>, out: &mut [Joints2d]| {
            let mut buf = [[0f32; 2]; JOINTS];
            while let Some(k) = f.pop(&mut buf) {
                out[rows[k as usize]] = buf;
            }
        };
        for &i in &rows {
            let p = &predictions[i];
            let joints = p.core_joints();
            f.push(ds.span_us[i][1], &joints, &p.confidence)
                .map_err(lag_err)?;
            pop(&mut f, &mut out);
        }
        f.finish();
        pop(&mut f, &mut out);
    }
    Ok(out)
}

/// Errors of one group (a camera, a movement, a joint, or everything).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Mpjpe {
    /// MPJPE2D, pixels (`None` without a visible joint).
    pub mpjpe2d_px: Option<f64>,
    /// MPJPE3D, mm (`None` without a triangulated window).
    pub mpjpe3d_mm: Option<f64>,
    /// Joint errors summed into the 2-D figure.
    pub joints2d: u64,
    /// Joint errors summed into the 3-D figure.
    pub joints3d: u64,
}

#[derive(Clone, Copy, Debug, Default)]
struct Acc {
    sum2: f64,
    n2: u64,
    sum3: f64,
    n3: u64,
}

impl Acc {
    fn mpjpe(&self) -> Mpjpe {
        Mpjpe {
            mpjpe2d_px: (self.n2 > 0).then(|| self.sum2 / self.n2 as f64),
            mpjpe3d_mm: (self.n3 > 0).then(|| self.sum3 / self.n3 as f64),
            joints2d: self.n2,
            joints3d: self.n3,
        }
    }
}

/// What `evpose eval` reports.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    /// What was evaluated (model path and engine, or the baseline).
    pub predictor: String,
    /// Whether the data is synthetic (then these are not DHP19 figures).
    pub synthetic: bool,
    /// The simulator's pixel models of synthetic data (`evpose sim --pixel-model`), as the
    /// dataset's manifest records them (empty for real data and older datasets).
    pub pixel_models: Vec<String>,
    /// MPJPE2D over everything, pixels.
    pub mpjpe2d_px: Option<f64>,
    /// MPJPE3D over everything, mm.
    pub mpjpe3d_mm: Option<f64>,
    /// MPJPE3D with each view weighted by the joint's confidence in it
    /// ([`evpose_core::geometry::triangulate_views`], as `evpose run` triangulates), mm; `None`
    /// without confidences.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mpjpe3d_weighted_mm: Option<f64>,
    /// Samples (windows × cameras) evaluated.
    pub samples: usize,
    /// Windows triangulated for the 3-D figure.
    pub windows: usize,
    /// Per camera channel.
    pub per_camera: BTreeMap<u8, Mpjpe>,
    /// Per movement name.
    pub per_movement: BTreeMap<String, Mpjpe>,
    /// Per joint (DHP19 order).
    pub per_joint: Vec<Mpjpe>,
    /// Samples per second of the prediction (0 for the baseline).
    pub samples_per_second: f64,
    /// Mean joint confidence over all samples (`None` for the baseline).
    pub mean_confidence: Option<f64>,
    /// The same figures after the causal One-Euro filter (`evpose eval --smooth`, [`smooth`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub smoothed: Option<Box<EvalReport>>,
    /// The same figures after the fixed-lag filter (`evpose eval --smooth`,
    /// [`smooth_fixed_lag`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fixed_lag: Option<Box<EvalReport>>,
}

/// Euclidean 2-D error of each visible joint.
pub fn joint_errors_2d(
    pred: &Joints2d,
    label: &Joints2d,
    mask: &[u8; JOINTS],
) -> [Option<f64>; JOINTS] {
    std::array::from_fn(|j| {
        (mask[j] != 0).then(|| {
            let (dx, dy) = (
                f64::from(pred[j][0] - label[j][0]),
                f64::from(pred[j][1] - label[j][1]),
            );
            (dx * dx + dy * dy).sqrt()
        })
    })
}

/// Computes the report from one prediction per dataset sample. `cameras` maps the two
/// channels of the 3-D figure (DHP19: 2 and 3) to their calibration; with each sample's joint
/// `confidence`, the 3-D figure is also computed with confidence-weighted triangulation.
pub fn evaluate(
    ds: &Dataset,
    predictions: &[Joints2d],
    confidence: Option<&[[f32; JOINTS]]>,
    front: [(u8, &Camera); 2],
    predictor: String,
    samples_per_second: f64,
) -> Result<EvalReport> {
    if predictions.len() != ds.len() || confidence.is_some_and(|c| c.len() != ds.len()) {
        bail!("{} predictions for {} samples", predictions.len(), ds.len());
    }
    let mut weighted = (0f64, 0u64);
    let mut all = Acc::default();
    let mut per_camera: BTreeMap<u8, Acc> = BTreeMap::new();
    let mut per_movement: BTreeMap<u16, Acc> = BTreeMap::new();
    let mut per_joint = [Acc::default(); JOINTS];
    // Pairs of front-camera samples of one window: (recording, window) → rows. Only the mean
    // rule's windows are shared by the cameras; the last rule cuts each camera's events on
    // their own (its window 1 of one camera is another time than of the other), so it has no
    // 3-D figure.
    let mut pairs: BTreeMap<(u32, u32), [Option<usize>; 2]> = BTreeMap::new();
    let shared_windows = ds.manifest.label == crate::dataset::LabelRule::Mean;
    for (i, pred) in predictions.iter().enumerate() {
        let errs = joint_errors_2d(pred, &ds.label2d[i], &ds.mask[i]);
        for (j, e) in errs.iter().enumerate() {
            if let Some(e) = *e {
                for acc in [
                    &mut all,
                    per_camera.entry(ds.camera[i]).or_default(),
                    per_movement.entry(ds.movement[i]).or_default(),
                    &mut per_joint[j],
                ] {
                    acc.sum2 += e;
                    acc.n2 += 1;
                }
            }
        }
        // A person-free window has no 3-D label (and no visible joint for the 2-D error).
        if ds.person[i] == 0 {
            continue;
        }
        if let Some(side) = front.iter().position(|(c, _)| *c == ds.camera[i]) {
            if shared_windows {
                pairs.entry((ds.recording[i], ds.window[i])).or_default()[side] = Some(i);
            }
        }
    }
    let mut windows = 0;
    for rows in pairs.values() {
        let [Some(a), Some(b)] = *rows else { continue };
        windows += 1;
        for j in 0..JOINTS {
            let pa = (
                f64::from(predictions[a][j][0]),
                f64::from(predictions[a][j][1]),
            );
            let pb = (
                f64::from(predictions[b][j][0]),
                f64::from(predictions[b][j][1]),
            );
            let g = ds.gt3d[a][j];
            let dist = |x: [f64; 3]| {
                (0..3)
                    .map(|k| (x[k] - f64::from(g[k])).powi(2))
                    .sum::<f64>()
                    .sqrt()
            };
            if let Some(c) = confidence {
                let w = |i: usize| f64::from(c[i][j]).max(crate::run::MIN_VIEW_WEIGHT);
                let views = [(front[0].1, pa, w(a)), (front[1].1, pb, w(b))];
                if let Ok(x) = triangulate_views(&views) {
                    weighted.0 += dist(x);
                    weighted.1 += 1;
                }
            }
            let Ok(x) = triangulate(front[0].1, pa, front[1].1, pb) else {
                continue;
            };
            let e = dist(x);
            for acc in [
                &mut all,
                per_movement.entry(ds.movement[a]).or_default(),
                &mut per_joint[j],
            ] {
                acc.sum3 += e;
                acc.n3 += 1;
            }
        }
    }
    let total = all.mpjpe();
    Ok(EvalReport {
        predictor,
        synthetic: ds.manifest.synthetic,
        pixel_models: ds.manifest.pixel_models.clone(),
        mpjpe2d_px: total.mpjpe2d_px,
        mpjpe3d_mm: total.mpjpe3d_mm,
        mpjpe3d_weighted_mm: (weighted.1 > 0).then(|| weighted.0 / weighted.1 as f64),
        samples: ds.len(),
        windows,
        per_camera: per_camera
            .into_iter()
            .map(|(c, a)| (c, a.mpjpe()))
            .collect(),
        per_movement: per_movement
            .into_iter()
            .map(|(m, a)| {
                let name = ds
                    .manifest
                    .movements
                    .get(usize::from(m))
                    .cloned()
                    .unwrap_or_else(|| m.to_string());
                (name, a.mpjpe())
            })
            .collect(),
        per_joint: per_joint.iter().map(Acc::mpjpe).collect(),
        samples_per_second,
        mean_confidence: None,
        smoothed: None,
        fixed_lag: None,
    })
}

/// The mean-pose baseline: every sample of camera `c` is predicted as the mean visible 2-D
/// label of camera `c` in `train` (per joint). A model that does not beat it has learnt
/// nothing about the pose.
pub fn mean_pose(train: &Dataset, test: &Dataset) -> Result<Vec<Joints2d>> {
    let mut sums: BTreeMap<u8, [[f64; 3]; JOINTS]> = BTreeMap::new();
    for i in 0..train.len() {
        let s = sums.entry(train.camera[i]).or_insert([[0.0; 3]; JOINTS]);
        for (j, s) in s.iter_mut().enumerate() {
            if train.mask[i][j] != 0 {
                s[0] += f64::from(train.label2d[i][j][0]);
                s[1] += f64::from(train.label2d[i][j][1]);
                s[2] += 1.0;
            }
        }
    }
    (0..test.len())
        .map(|i| {
            let Some(s) = sums.get(&test.camera[i]) else {
                bail!(
                    "the training set has no sample of camera {}",
                    test.camera[i]
                );
            };
            // The integer pixel of the mean, as a decoded joint is an integer pixel.
            Ok(std::array::from_fn(|j| {
                let n = s[j][2].max(1.0);
                [(s[j][0] / n).round() as f32, (s[j][1] / n).round() as f32]
            }))
        })
        .collect()
}

/// Samples read and predicted per batch (bounds memory: a batch of 2,048-point samples is
/// 40 MiB).
const BATCH: usize = 1024;

/// Predictions for each sample with the core's engine on `blob` (int8 or f32), in parallel
/// (rayon, one runner per thread); `progress(done)` after each batch.
pub fn predict_core(
    ds: &Dataset,
    blob: &crate::model::AlignedBlob,
    progress: impl Fn(usize) + Sync,
) -> Result<Vec<Prediction>> {
    use rayon::prelude::*;
    let runner = crate::model::CoreRunner::new(blob)?;
    let (w, h, j) = (
        runner.model().width(),
        runner.model().height(),
        runner.model().joints(),
    );
    if j != JOINTS {
        bail!("the model has {j} joints; the dataset has {JOINTS}");
    }
    let int8 = runner.model().dtype() == evpose_core::DType::I8;
    let scales = runner.model().head_scales();
    predict_batches(ds, progress, |batch| {
        batch
            .par_iter()
            .map_init(
                || crate::model::CoreRunner::new(blob),
                |runner, points| {
                    let runner = runner.as_mut().map_err(|e| anyhow::anyhow!("{e:#}"))?;
                    if int8 {
                        let l = runner.run_i8(points)?;
                        Prediction::from_heads(&l.x, &l.y, w, h, scales)
                    } else {
                        let l = runner.run_f32(points)?;
                        Prediction::from_heads(&l.x, &l.y, w, h, scales)
                    }
                },
            )
            .collect()
    })
}

/// Predictions for each sample with tract running an ONNX file (any backbone of the family),
/// in parallel (one tract plan per thread). Feature `onnx`.
#[cfg(feature = "onnx")]
pub fn predict_tract(
    ds: &Dataset,
    onnx: &std::path::Path,
    progress: impl Fn(usize) + Sync,
) -> Result<Vec<Prediction>> {
    use rayon::prelude::*;
    predict_batches(ds, progress, |batch| {
        batch
            .par_iter()
            .map_init(
                || crate::model::TractModel::load(onnx),
                |model, points| {
                    let model = model.as_mut().map_err(|e| anyhow::anyhow!("{e:#}"))?;
                    let l = model.run(points)?;
                    let (w, h) = (l.width(), l.height());
                    if l.joints != JOINTS {
                        bail!(
                            "the model has {} joints; the dataset has {JOINTS}",
                            l.joints
                        );
                    }
                    Prediction::from_heads(&l.x, &l.y, w, h, Some([1.0; 2]))
                },
            )
            .collect()
    })
}

fn predict_batches(
    ds: &Dataset,
    progress: impl Fn(usize) + Sync,
    mut run: impl FnMut(&[Vec<[f32; 5]>]) -> Result<Vec<Prediction>>,
) -> Result<Vec<Prediction>> {
    let mut out = Vec::with_capacity(ds.len());
    for start in (0..ds.len()).step_by(BATCH) {
        let batch = ds.points_range(start, BATCH.min(ds.len() - start))?;
        out.extend(run(&batch)?);
        progress(out.len());
    }
    Ok(out)
}

/// The per-joint errors of a report as a PNG-ready bar chart: MPJPE2D (px) and MPJPE3D (mm).
pub fn per_joint_chart(r: &EvalReport) -> Result<image::RgbImage> {
    use crate::render::{bar_chart, Panel};
    let d2: Vec<Option<f64>> = r.per_joint.iter().map(|m| m.mpjpe2d_px).collect();
    let d3: Vec<Option<f64>> = r.per_joint.iter().map(|m| m.mpjpe3d_mm).collect();
    let title = format!(
        "{}{}",
        r.predictor,
        if r.synthetic { " (synthetic data)" } else { "" }
    );
    bar_chart(
        &title,
        &evpose_core::skeleton::JOINT_NAMES,
        &[
            Panel {
                title: "MPJPE2D per joint, px",
                values: &d2,
                colour: image::Rgb([70, 120, 200]),
            },
            Panel {
                title: "MPJPE3D per joint, mm",
                values: &d3,
                colour: image::Rgb([220, 120, 50]),
            },
        ],
    )
}

//! Post-training int8 quantization and its ONNX twin.
//!
//! Calibration runs the core's f32 engine over sampled event windows and records each layer's
//! largest activation. Scales are symmetric (zero point 0):
//! - activations: `max|y| / 127` per layer output; the first point layer's per channel when
//!   the calibrated ranges keep them apart ([`calibrate`] does, [`Ranges::per_tensor_first_layer`]
//!   merges them; `evpose quantize --first-layer-scales`);
//! - weights: one scale per output channel, after folding the input's per-channel scales into
//!   the weights (a layer reading a concatenation of layers with different scales, or the pooled
//!   `[max, mean]`, sees one int8 tensor with per-channel units);
//! - the first layer reads the integer-coded features (`x, y, p_acc, cnt` as is, `t_avg · 1024`)
//!   with i16 weights bounded by ±1023 so that it is exact in f32 (see `evpose_core::quant`);
//! - the heads use one weight scale for the whole tensor, so the int32 accumulators order the
//!   same way as the dequantized logits and feed the argmax directly; their weights keep 15 bits
//!   (i16, `±HEAD_WEIGHT_LIMIT`; int8 features), and the blob records the dequantization
//!   multiplier (`accumulator × scale = logit`) for joint confidences.
//!
//! The same integer computation is written as a standard ONNX graph ([`QuantNet::onnx`]) using
//! only ops that tract and onnxruntime compute exactly: `Round`, `Clip`, `Conv` on exact
//! integer-valued floats, `ConvInteger`, `MatMulInteger`, `Add` (int32), `Cast`, `Mul`,
//! `LeakyRelu`, `QuantizeLinear` with scale 1, `ReduceMax` (int8), `ReduceSum` (int32), `Div`.

use anyhow::{bail, ensure, Result};
use evpose_core::infer::MAX_BLOCK;
use evpose_core::model::{DType, LayerKind, Preprocessing, WeightType, FEATURES};
use evpose_core::quant::{
    InputCoding, FIRST_BIAS_LIMIT, FIRST_WEIGHT_LIMIT, HEAD_BIAS_LIMIT, HEAD_WEIGHT_LIMIT,
    MAX_I16_HEAD_DIM,
};
use evpose_core::{scratch_words_for_block, Model, Plan, Stage};

use super::net::{
    f32_blob, le_bytes, write_blob, AlignedBlob, BlobHeader, BlobLayer, Dense, FloatNet,
};

/// Largest activation magnitudes seen during calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct Ranges {
    /// Per point layer, per output channel.
    pub point: Vec<Vec<f32>>,
    /// The pooled mean half (`[max, mean]`: the max half takes the last point layer's range).
    pub mean: f32,
    /// Per FC layer.
    pub fc: Vec<f32>,
    /// Windows seen.
    pub windows: usize,
}

impl Ranges {
    /// One range for the first point layer's channels (their maximum): one activation scale
    /// for the layer, as every other point layer has.
    pub fn per_tensor_first_layer(&mut self) {
        if let Some(first) = self.point.first_mut() {
            let m = first.iter().fold(0f32, |a, &b| a.max(b));
            first.iter_mut().for_each(|r| *r = m);
        }
    }
}

/// Records activation ranges of `net` over calibration inputs (per channel for point layers).
pub fn calibrate(net: &FloatNet, inputs: &[Vec<[f32; 5]>]) -> Result<Ranges> {
    ensure!(
        !inputs.is_empty(),
        "calibration needs at least one input window"
    );
    // A NaN drops out of the running maxima and an infinity makes an infinite scale: either
    // would give a blob that looks fine and is not.
    for (w, points) in inputs.iter().enumerate() {
        if let Some(p) = points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
            bail!("calibration window {w}, point {p}: a non-finite feature");
        }
    }
    let blob = AlignedBlob::new(&f32_blob(net)?);
    let model = Model::parse(blob.bytes()).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut scratch = vec![0f32; scratch_words_for_block(&model, MAX_BLOCK)];
    let plan = Plan::new(&model, *super::kernels(), scratch.len())
        .map_err(|e| anyhow::anyhow!("calibration plan: {e}"))?;
    let mut x = vec![0f32; model.joints() * model.width()];
    let mut y = vec![0f32; model.joints() * model.height()];
    let pooled = net.pooled_width();
    let mut r = Ranges {
        point: net.point.iter().map(|l| vec![0.0; l.out_dim]).collect(),
        mean: 0.0,
        fc: vec![0.0; net.fc.len()],
        windows: inputs.len(),
    };
    let absmax = |v: &[f32]| v.iter().fold(0f32, |m, x| m.max(x.abs()));
    for points in inputs {
        plan.run_f32_observed(
            points,
            &mut scratch,
            &mut x,
            &mut y,
            |stage, v| match stage {
                Stage::Point(i) => {
                    for (m, x) in r.point[i].iter_mut().zip(v) {
                        *m = m.max(x.abs());
                    }
                }
                Stage::Pooled => r.mean = r.mean.max(absmax(&v[pooled..])),
                Stage::Fc(i) => r.fc[i] = r.fc[i].max(absmax(v)),
            },
        )
        .map_err(|e| anyhow::anyhow!("calibration inference: {e}"))?;
    }
    Ok(r)
}

/// Integer weights of one layer.
#[derive(Clone, Debug, PartialEq)]
pub enum QWeights {
    /// i16 (first layer).
    I16(Vec<i16>),
    /// i8.
    I8(Vec<i8>),
}

/// One quantized layer.
#[derive(Clone, Debug, PartialEq)]
pub struct QLayer {
    /// Role.
    pub kind: LayerKind,
    /// The float layer's shape, sources and activation.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// Sources bitmask (point layers).
    pub sources: u32,
    /// LeakyReLU slope.
    pub leaky: Option<f32>,
    /// `[out][in]` integer weights.
    pub w: QWeights,
    /// Bias in accumulator units.
    pub b: Vec<i32>,
    /// Requantization multipliers (empty for the heads).
    pub scales: Vec<f32>,
}

/// A quantized network: the int8 blob's content.
#[derive(Clone, Debug, PartialEq)]
pub struct QuantNet {
    /// Layers in blob order.
    pub layers: Vec<QLayer>,
    /// Number of point layers.
    pub point_layers: usize,
    /// Input coding.
    pub coding: InputCoding,
    /// Average-pool constant `c = s_last / s_mean`.
    pub avg_scale: f32,
    /// Joints.
    pub joints: usize,
    /// Head width `D`.
    pub head_dim: usize,
    /// Fixed point count of the source model.
    pub points: Option<usize>,
    /// The preprocessing recorded in the blob (points, window events, time slices).
    pub preprocessing: Preprocessing,
}

/// Activation scale from a range: `max|y| / 127` (1 for a layer that never fired).
fn act_scale(range: f32) -> f64 {
    if range > 0.0 {
        f64::from(range) / 127.0
    } else {
        1.0
    }
}

/// Quantized weights of a dense layer whose input has per-channel units `s_in`.
struct Folded {
    w: Vec<i32>,
    b: Vec<i32>,
    /// Weight scale per output channel (real value of one accumulator unit).
    sw: Vec<f64>,
}

/// Folds `l` into integers: each output's weight scale is the smallest that keeps its weights
/// within `±limit` and its bias within `±bias_limit` (a large bias beside small weights, e.g.
/// a BatchNorm with a tiny gamma folded in, widens the scale rather than being clipped; a row of
/// zero weights gets its scale from the bias alone), one scale for all outputs if `per_tensor`.
fn fold(l: &Dense, s_in: &[f64], limit: f64, per_tensor: bool, bias_limit: f64) -> Folded {
    let eff = |o: usize, k: usize| f64::from(l.w[o * l.in_dim + k]) * s_in[k];
    let row_max = |o: usize| (0..l.in_dim).fold(0f64, |m, k| m.max(eff(o, k).abs()));
    let bias = |o: usize| l.b.get(o).map_or(0.0, |&b| f64::from(b).abs());
    let mut sw: Vec<f64> = (0..l.out_dim)
        .map(|o| (row_max(o) / limit).max(bias(o) / bias_limit))
        .collect();
    if per_tensor {
        let m = sw.iter().fold(0f64, |a, &b| a.max(b));
        sw.iter_mut().for_each(|s| *s = m);
    }
    sw.iter_mut()
        .for_each(|s| *s = if *s > 0.0 { *s } else { 1.0 });
    let mut w = Vec::with_capacity(l.w.len());
    for (o, &s) in sw.iter().enumerate() {
        for k in 0..l.in_dim {
            w.push((eff(o, k) / s).round_ties_even().clamp(-limit, limit) as i32);
        }
    }
    let b =
        l.b.iter()
            .zip(&sw)
            .map(|(&b, &s)| {
                (f64::from(b) / s)
                    .round_ties_even()
                    .clamp(-bias_limit, bias_limit) as i32
            })
            .collect();
    Folded { w, b, sw }
}

/// The largest bias of an int8 layer with `k` inputs whose sums cannot leave i32: every
/// product is at most 127 · 128 in magnitude (weights within ±127, inputs within -128..=127).
fn i8_bias_limit(k: usize) -> f64 {
    (f64::from(i32::MAX) - k as f64 * 127.0 * 128.0).max(1.0)
}

/// Quantizes `net` with calibrated `ranges`.
pub fn quantize(net: &FloatNet, ranges: &Ranges) -> Result<QuantNet> {
    let coding = InputCoding::DEFAULT;
    // The first point layer's activation scales follow `ranges` (per channel unless
    // [`Ranges::per_tensor_first_layer`] merged them; its consumers fold per-input-channel scales
    // into their weights): a per-tensor scale there cost the paper-width model 1.2 px MPJPE2D in
    // a fake-quantization test, while per channel cost the MCU model 0.1 px. Every other point
    // layer has one scale (the pooled one must: the mean's constant `c` is one number).
    let n_point = ranges.point.len();
    let s_point: Vec<Vec<f64>> = ranges
        .point
        .iter()
        .enumerate()
        .map(|(i, ch)| {
            if i == 0 && n_point > 1 {
                // A channel that never fired takes the layer's smallest live scale, not 1.0:
                // its consumers fold its scale into their weights, and 1.0 beside small live
                // scales (a model on normalized inputs: 0.02) would set their rows' maxima
                // and crush the live channels' weights.
                let smallest = ch
                    .iter()
                    .filter(|&&r| r > 0.0)
                    .fold(f32::INFINITY, |a, &b| a.min(b));
                ch.iter()
                    .map(|&r| match r {
                        _ if r > 0.0 => act_scale(r),
                        _ => act_scale(if smallest.is_finite() { smallest } else { 0.0 }),
                    })
                    .collect()
            } else {
                let m = ch.iter().fold(0f32, |a, &b| a.max(b));
                vec![act_scale(m); ch.len()]
            }
        })
        .collect();
    let s_fc: Vec<f64> = ranges.fc.iter().map(|&r| act_scale(r)).collect();
    let s_mean = act_scale(ranges.mean);
    let mut layers = Vec::new();
    for (i, l) in net.point.iter().enumerate() {
        let (s_in, limit, bias_limit) = if l.sources == 1 {
            let s: Vec<f64> = (0..FEATURES)
                .map(|f| 1.0 / f64::from(coding.factor(f)))
                .collect();
            (
                s,
                f64::from(FIRST_WEIGHT_LIMIT),
                f64::from(FIRST_BIAS_LIMIT),
            )
        } else {
            let mut s = Vec::with_capacity(l.in_dim);
            for src in (1..=net.point.len()).filter(|b| l.sources >> b & 1 == 1) {
                s.extend_from_slice(&s_point[src - 1]);
            }
            (s, 127.0, i8_bias_limit(l.in_dim))
        };
        let f = fold(l, &s_in, limit, false, bias_limit);
        let w = if l.sources == 1 {
            QWeights::I16(f.w.iter().map(|&v| v as i16).collect())
        } else {
            QWeights::I8(f.w.iter().map(|&v| v as i8).collect())
        };
        layers.push(requant_layer(LayerKind::Point, l, w, f, &s_point[i]));
    }
    let last = s_point
        .last()
        .and_then(|s| s.first())
        .copied()
        .unwrap_or(1.0);
    let pooled = net.pooled_width();
    let mut s_in: Vec<f64> = std::iter::repeat_n(last, pooled)
        .chain(std::iter::repeat_n(s_mean, pooled))
        .collect();
    for (i, l) in net.fc.iter().enumerate() {
        let f = fold(l, &s_in, 127.0, false, i8_bias_limit(l.in_dim));
        let w = QWeights::I8(f.w.iter().map(|&v| v as i8).collect());
        layers.push(requant_layer(
            LayerKind::Fc,
            l,
            w,
            f,
            &vec![s_fc[i]; l.out_dim],
        ));
        s_in = vec![s_fc[i]; l.out_dim];
    }
    for (kind, h) in [
        (LayerKind::HeadX, &net.head_x),
        (LayerKind::HeadY, &net.head_y),
    ] {
        // 15-bit weights (blob version 3): int8 head weights cost 0.27 px MPJPE2D on the MCU
        // model (the argmax of a σ-8 SimDR bump is sensitive to rounding), i16 nothing
        // measurable, for ~0.1 % of the MACs.
        ensure!(
            h.in_dim <= MAX_I16_HEAD_DIM,
            "head dim {} above {MAX_I16_HEAD_DIM}",
            h.in_dim
        );
        let f = fold(
            h,
            &s_in[..h.in_dim],
            f64::from(HEAD_WEIGHT_LIMIT),
            true,
            f64::from(HEAD_BIAS_LIMIT),
        );
        layers.push(QLayer {
            kind,
            in_dim: h.in_dim,
            out_dim: h.out_dim,
            sources: 0,
            leaky: None,
            w: QWeights::I16(f.w.iter().map(|&v| v as i16).collect()),
            b: f.b,
            // One weight scale for the whole head: every output's dequantization multiplier is
            // the same (blob version 3: the logits' scale, for confidences).
            scales: f.sw.iter().map(|&s| s as f32).collect(),
        });
    }
    Ok(QuantNet {
        layers,
        point_layers: net.point.len(),
        coding,
        avg_scale: (last / s_mean) as f32,
        joints: net.joints,
        head_dim: net.head_dim(),
        points: net.points,
        preprocessing: Preprocessing {
            points: net.points.unwrap_or(0) as u32,
            ..Preprocessing::default()
        },
    })
}

/// A requantized layer; `s_out` is the output's activation scale per channel.
fn requant_layer(kind: LayerKind, l: &Dense, w: QWeights, f: Folded, s_out: &[f64]) -> QLayer {
    QLayer {
        kind,
        in_dim: l.in_dim,
        out_dim: l.out_dim,
        sources: l.sources,
        leaky: l.leaky,
        w,
        b: f.b,
        scales: f
            .sw
            .iter()
            .zip(s_out)
            .map(|(&s, &o)| (s / o) as f32)
            .collect(),
    }
}

impl QuantNet {
    /// The x and y heads.
    fn heads(&self) -> (&QLayer, &QLayer) {
        let n = self.layers.len();
        (&self.layers[n - 2], &self.layers[n - 1])
    }

    /// Serializes the int8 blob for the core.
    pub fn blob(&self) -> Result<Vec<u8>> {
        let (hx, hy) = self.heads();
        let layers: Vec<BlobLayer> = self
            .layers
            .iter()
            .map(|l| {
                let (weight_type, weights) = match &l.w {
                    QWeights::I16(w) => (WeightType::I16, le_bytes(w)),
                    QWeights::I8(w) => (WeightType::I8, le_bytes(w)),
                };
                BlobLayer {
                    kind: l.kind,
                    in_dim: l.in_dim,
                    out_dim: l.out_dim,
                    sources: l.sources,
                    leaky: l.leaky,
                    weight_type,
                    weights,
                    bias: le_bytes(&l.b),
                    scales: le_bytes(&l.scales),
                }
            })
            .collect();
        write_blob(
            &BlobHeader {
                dtype: DType::I8,
                joints: self.joints,
                width: hx.out_dim,
                height: hy.out_dim,
                head_dim: self.head_dim,
                point_layers: self.point_layers,
                input_shifts: self.coding.shifts,
                avg_scale: self.avg_scale,
                preprocessing: self.preprocessing,
            },
            &layers,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dense(in_dim: usize, w: Vec<f32>, b: Vec<f32>) -> Dense {
        Dense {
            in_dim,
            out_dim: b.len(),
            w,
            b,
            leaky: None,
            sources: 0,
        }
    }

    #[test]
    fn a_bias_beyond_its_limit_widens_the_scale_instead_of_being_clipped() {
        // Row 0: tiny weights beside a large bias (a folded BatchNorm with a tiny gamma); row
        // 1: zero weights and a bias; row 2: an ordinary row; row 3: nothing at all.
        let l = dense(
            4,
            [[1e-5f32; 4], [0.0; 4], [0.5, -0.25, 0.1, 0.0], [0.0; 4]].concat(),
            vec![0.1, 0.3, 0.01, 0.0],
        );
        let limit = 127.0;
        let bias_limit = 1e4;
        let f = fold(&l, &[1.0; 4], limit, false, bias_limit);
        for o in 0..4 {
            let back = f64::from(f.b[o]) * f.sw[o];
            assert!(
                (back - f64::from(l.b[o])).abs() <= f.sw[o] / 2.0,
                "row {o}: bias {} comes back as {back}",
                l.b[o]
            );
            assert!(f64::from(f.b[o].abs()) <= bias_limit);
            assert!(f.w[o * 4..][..4]
                .iter()
                .all(|w| f64::from(w.abs()) <= limit));
        }
        // The ordinary row keeps the weights' scale (its bias fits).
        assert_eq!(f.sw[2], 0.5 / 127.0);
        assert_eq!(f.w[8], 127);
        assert_eq!(f.sw[3], 1.0);
    }

    #[cfg(feature = "onnx")]
    #[test]
    fn a_first_layer_channel_that_never_fired_leaves_its_consumers_resolution() {
        // The small model calibrated per channel, then one conv1 channel made dead (range 0):
        // conv2's rows keep their other weights at full scale (±127 at each row's largest) as
        // often as with the channel alive.
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures");
        let net = super::super::import_onnx(&dir.join("pointnet-small.onnx")).unwrap();
        let input = super::super::read_points(&dir.join("street-00.points.npy")).unwrap();
        let mut ranges = calibrate(&net, &[input]).unwrap();
        // conv1's outputs a hundred times smaller, as in a model on normalized inputs (its
        // live scales then lie far below the 1.0 a dead channel used to get).
        ranges.point[0].iter_mut().for_each(|r| *r /= 100.0);
        // Rows of conv2 whose largest weight on the other channels is at full scale.
        let full = |ranges: &Ranges| {
            let q = quantize(&net, ranges).unwrap();
            let QWeights::I8(w) = &q.layers[1].w else {
                panic!("conv2 is int8")
            };
            w.chunks(q.layers[1].in_dim)
                .filter(|row| {
                    let others = row.iter().enumerate().filter(|&(j, _)| j != 3);
                    others.map(|(_, v)| v.unsigned_abs()).max() == Some(127)
                })
                .count()
        };
        let alive = full(&ranges);
        ranges.point[0][3] = 0.0;
        let dead = full(&ranges);
        assert!(
            dead >= alive,
            "{dead} rows at full scale, {alive} with the channel alive"
        );
    }

    #[test]
    fn int8_biases_leave_room_for_every_sum() {
        // A bias of 1 with weights of 1e-9: by the weights alone the integer bias would be
        // about 1.3e11, clipped at i32::MAX, and sums of K products on top would wrap.
        let k = 512;
        let l = dense(k, vec![1e-9; k], vec![1.0]);
        let f = fold(&l, &vec![1.0; k], 127.0, false, i8_bias_limit(k));
        let worst = i64::from(f.b[0]) + k as i64 * 127 * 128;
        assert!(worst <= i64::from(i32::MAX), "{worst}");
        assert!((f64::from(f.b[0]) * f.sw[0] - 1.0).abs() < 1e-6);
    }
}

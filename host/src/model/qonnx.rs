//! The int8 network written as a standard ONNX graph (opset 13), for an independent engine.
//!
//! Every step mirrors `evpose_core::quant` exactly (layouts `(1, C, N)` per point):
//! - input coding: `Clip(Round(Mul(points, 2^shift)), ±2047)`;
//! - first layer: float `Conv` with integer-valued weights and bias (exact: sums below 2^24);
//! - other point layers: `ConvInteger` (int8 × int8 → int32) + `Add` int32 bias, `Cast` to float;
//! - requantization: `Mul` (per-channel f32) → `LeakyRelu` → `QuantizeLinear(scale 1, zp 0)`;
//! - pooling: `ReduceMax` over int8; `ReduceSum` over int32, then `Mul(Cast(sum), Div(c, n))`
//!   with `n` read from the input's shape, then `QuantizeLinear(1, 0)`;
//! - FC layers: `MatMulInteger` + the same requantization; heads: `MatMulInteger` + `Add`,
//!   int32 outputs; 15-bit heads (the quantizer's default) as two `MatMulInteger`s over the
//!   weights' high and low parts, combined as `128·hi + lo`.

use anyhow::Result;
use prost::Message;
use tract_onnx::pb::{
    self, attribute_proto::AttributeType, tensor_proto::DataType, tensor_shape_proto::dimension,
    type_proto,
};

use super::quantize::{QLayer, QWeights, QuantNet};

const OPSET: i64 = 13;

#[derive(Default)]
struct Graph {
    nodes: Vec<pb::NodeProto>,
    inits: Vec<pb::TensorProto>,
    counter: usize,
}

enum Attr {
    Int(i64),
    Ints(Vec<i64>),
    Float(f32),
}

impl Graph {
    fn name(&mut self, stem: &str) -> String {
        self.counter += 1;
        format!("{stem}_{}", self.counter)
    }

    fn node(&mut self, op: &str, stem: &str, inputs: &[&str], attrs: &[(&str, Attr)]) -> String {
        let out = self.name(stem);
        self.node_as(op, out, inputs, attrs)
    }

    fn node_as(
        &mut self,
        op: &str,
        out: String,
        inputs: &[&str],
        attrs: &[(&str, Attr)],
    ) -> String {
        let attribute = attrs
            .iter()
            .map(|(n, a)| {
                let mut p = pb::AttributeProto {
                    name: n.to_string(),
                    ..Default::default()
                };
                match a {
                    Attr::Int(i) => {
                        p.r#type = AttributeType::Int as i32;
                        p.i = *i;
                    }
                    Attr::Ints(v) => {
                        p.r#type = AttributeType::Ints as i32;
                        p.ints = v.clone();
                    }
                    Attr::Float(f) => {
                        p.r#type = AttributeType::Float as i32;
                        p.f = *f;
                    }
                }
                p
            })
            .collect();
        self.nodes.push(pb::NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![out.clone()],
            name: out.clone(),
            op_type: op.into(),
            attribute,
            ..Default::default()
        });
        out
    }

    fn init(&mut self, stem: &str, dt: DataType, dims: &[usize], raw: Vec<u8>) -> String {
        let name = self.name(stem);
        self.inits.push(pb::TensorProto {
            name: name.clone(),
            data_type: dt as i32,
            dims: dims.iter().map(|&d| d as i64).collect(),
            raw_data: raw,
            ..Default::default()
        });
        name
    }

    fn f32s(&mut self, stem: &str, dims: &[usize], v: &[f32]) -> String {
        self.init(
            stem,
            DataType::Float,
            dims,
            bytemuck::cast_slice(v).to_vec(),
        )
    }
    fn i32s(&mut self, stem: &str, dims: &[usize], v: &[i32]) -> String {
        self.init(
            stem,
            DataType::Int32,
            dims,
            bytemuck::cast_slice(v).to_vec(),
        )
    }
    fn i64s(&mut self, stem: &str, dims: &[usize], v: &[i64]) -> String {
        self.init(
            stem,
            DataType::Int64,
            dims,
            bytemuck::cast_slice(v).to_vec(),
        )
    }
    fn i8s(&mut self, stem: &str, dims: &[usize], v: &[i8]) -> String {
        self.init(stem, DataType::Int8, dims, bytemuck::cast_slice(v).to_vec())
    }

    /// `QuantizeLinear(LeakyRelu(Mul(v, scale)))`: the single rounding of every layer.
    fn requantize(
        &mut self,
        v: &str,
        scale: &str,
        leaky: Option<f32>,
        one: &str,
        zero: &str,
    ) -> String {
        let mut y = self.node("Mul", "scaled", &[v, scale], &[]);
        if let Some(alpha) = leaky {
            y = self.node("LeakyRelu", "act", &[&y], &[("alpha", Attr::Float(alpha))]);
        }
        self.node("QuantizeLinear", "q", &[&y, one, zero], &[])
    }
}

/// Transposes `[out][in]` weights to ONNX MatMul's `[in][out]`.
fn transpose<T: Copy>(w: &[T], out: usize, inp: usize) -> Vec<T> {
    (0..inp * out)
        .map(|i| w[(i % out) * inp + i / out])
        .collect()
}

fn i8_weights(l: &QLayer) -> &[i8] {
    match &l.w {
        QWeights::I8(w) => w,
        QWeights::I16(_) => &[],
    }
}

fn value_info(name: &str, dt: DataType, dims: &[Option<usize>]) -> pb::ValueInfoProto {
    let dim = dims
        .iter()
        .map(|d| pb::tensor_shape_proto::Dimension {
            value: Some(match d {
                Some(v) => dimension::Value::DimValue(*v as i64),
                None => dimension::Value::DimParam("n".into()),
            }),
            ..Default::default()
        })
        .collect();
    pb::ValueInfoProto {
        name: name.into(),
        r#type: Some(pb::TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: dt as i32,
                shape: Some(pb::TensorShapeProto { dim }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

/// Builds the serialized ONNX model of a quantized network.
pub fn build(q: &QuantNet) -> Result<Vec<u8>> {
    let mut g = Graph::default();
    let one = g.f32s("one", &[], &[1.0]);
    let zero = g.i8s("zero", &[], &[0]);
    // Input coding.
    let factors: Vec<f32> = (0..5).map(|i| q.coding.factor(i)).collect();
    let factors = g.f32s("input_factors", &[1, 5, 1], &factors);
    let lim = f32::from(evpose_core::quant::INPUT_LIMIT);
    let (lo, hi) = (
        g.f32s("input_min", &[], &[-lim]),
        g.f32s("input_max", &[], &[lim]),
    );
    let scaled = g.node("Mul", "input_scaled", &["points", &factors], &[]);
    let rounded = g.node("Round", "input_rounded", &[&scaled], &[]);
    let coded = g.node("Clip", "input_coded", &[&rounded, &lo, &hi], &[]);
    // Point layers.
    let mut outs: Vec<String> = Vec::new();
    for l in &q.layers[..q.point_layers] {
        let c = l.out_dim;
        let scale = g.f32s("scale", &[1, c, 1], &l.scales);
        let kernel = ("kernel_shape", Attr::Ints(vec![1]));
        let acc = match &l.w {
            QWeights::I16(w) => {
                let wf: Vec<f32> = w.iter().map(|&v| f32::from(v)).collect();
                let bf: Vec<f32> = l.b.iter().map(|&v| v as f32).collect();
                let wn = g.f32s("w", &[c, l.in_dim, 1], &wf);
                let bn = g.f32s("b", &[c], &bf);
                g.node("Conv", "acc", &[&coded, &wn, &bn], &[kernel])
            }
            QWeights::I8(w) => {
                let srcs: Vec<&str> = (1..=outs.len())
                    .filter(|b| l.sources >> b & 1 == 1)
                    .map(|b| outs[b - 1].as_str())
                    .collect();
                let x = if srcs.len() == 1 {
                    srcs[0].to_string()
                } else {
                    g.node("Concat", "cat", &srcs, &[("axis", Attr::Int(1))])
                };
                let wn = g.i8s("w", &[c, l.in_dim, 1], w);
                let bn = g.i32s("b", &[1, c, 1], &l.b);
                let acc = g.node("ConvInteger", "acc_i", &[&x, &wn], &[kernel]);
                let acc = g.node("Add", "acc_b", &[&acc, &bn], &[]);
                g.node(
                    "Cast",
                    "acc",
                    &[&acc],
                    &[("to", Attr::Int(DataType::Float as i64))],
                )
            }
        };
        let q_out = g.requantize(&acc, &scale, l.leaky, &one, &zero);
        outs.push(q_out);
    }
    // Pooling.
    let last = outs.last().cloned().unwrap_or_default();
    let max = g.node(
        "ReduceMax",
        "pool_max",
        &[&last],
        &[("axes", Attr::Ints(vec![2])), ("keepdims", Attr::Int(0))],
    );
    let wide = g.node(
        "Cast",
        "pool_i32",
        &[&last],
        &[("to", Attr::Int(DataType::Int32 as i64))],
    );
    let axes = g.i64s("axes", &[1], &[2]);
    let sum = g.node(
        "ReduceSum",
        "pool_sum",
        &[&wide, &axes],
        &[("keepdims", Attr::Int(0))],
    );
    let shape = g.node("Shape", "shape", &["points"], &[]);
    let two = g.i64s("two", &[], &[2]);
    let n = g.node("Gather", "n", &[&shape, &two], &[("axis", Attr::Int(0))]);
    let nf = g.node(
        "Cast",
        "n_f",
        &[&n],
        &[("to", Attr::Int(DataType::Float as i64))],
    );
    let c = g.f32s("avg_c", &[], &[q.avg_scale]);
    let m = g.node("Div", "avg_m", &[&c, &nf], &[]);
    let sumf = g.node(
        "Cast",
        "sum_f",
        &[&sum],
        &[("to", Attr::Int(DataType::Float as i64))],
    );
    let avg = g.node("Mul", "avg", &[&sumf, &m], &[]);
    let avg = g.node("QuantizeLinear", "avg_q", &[&avg, &one, &zero], &[]);
    let mut x = g.node("Concat", "pooled", &[&max, &avg], &[("axis", Attr::Int(1))]);
    // FC layers.
    let heads = q.layers.len() - 2;
    for l in &q.layers[q.point_layers..heads] {
        let wn = g.i8s(
            "w",
            &[l.in_dim, l.out_dim],
            &transpose(i8_weights(l), l.out_dim, l.in_dim),
        );
        let bn = g.i32s("b", &[l.out_dim], &l.b);
        let scale = g.f32s("scale", &[l.out_dim], &l.scales);
        let acc = g.node("MatMulInteger", "fc_acc_i", &[&x, &wn], &[]);
        let acc = g.node("Add", "fc_acc_b", &[&acc, &bn], &[]);
        let acc = g.node(
            "Cast",
            "fc_acc",
            &[&acc],
            &[("to", Attr::Int(DataType::Float as i64))],
        );
        x = g.requantize(&acc, &scale, l.leaky, &one, &zero);
    }
    let shape = g.i64s(
        "joints_shape",
        &[3],
        &[1, q.joints as i64, q.head_dim as i64],
    );
    let joints = g.node("Reshape", "joints", &[&x, &shape], &[]);
    // Heads: int32 accumulators are the outputs.
    let mut outputs = Vec::new();
    for (l, name) in q.layers[heads..].iter().zip(["simdr_x", "simdr_y"]) {
        let bn = g.i32s("b", &[l.out_dim], &l.b);
        let acc = match &l.w {
            QWeights::I8(w) => {
                let wn = g.i8s(
                    "w",
                    &[l.in_dim, l.out_dim],
                    &transpose(w, l.out_dim, l.in_dim),
                );
                g.node("MatMulInteger", "head_acc", &[&joints, &wn], &[])
            }
            // 15-bit weights as two int8 halves, `w = 128·hi + lo` with lo in 0..=127: two exact
            // MatMulIntegers, the high one times 128 in int32.
            QWeights::I16(w) => {
                let hi: Vec<i8> = w.iter().map(|&v| (v >> 7) as i8).collect();
                let lo: Vec<i8> = w.iter().map(|&v| (v & 0x7f) as i8).collect();
                let hn = g.i8s(
                    "w_hi",
                    &[l.in_dim, l.out_dim],
                    &transpose(&hi, l.out_dim, l.in_dim),
                );
                let ln = g.i8s(
                    "w_lo",
                    &[l.in_dim, l.out_dim],
                    &transpose(&lo, l.out_dim, l.in_dim),
                );
                let k128 = g.i32s("k128", &[1], &[128]);
                let h = g.node("MatMulInteger", "head_hi", &[&joints, &hn], &[]);
                let h = g.node("Mul", "head_hi128", &[&h, &k128], &[]);
                let lo = g.node("MatMulInteger", "head_lo", &[&joints, &ln], &[]);
                g.node("Add", "head_acc", &[&h, &lo], &[])
            }
        };
        g.node_as("Add", name.into(), &[&acc, &bn], &[]);
        outputs.push(value_info(
            name,
            DataType::Int32,
            &[Some(1), Some(q.joints), Some(l.out_dim)],
        ));
    }
    let model = pb::ModelProto {
        ir_version: 7,
        opset_import: vec![pb::OperatorSetIdProto {
            domain: String::new(),
            version: OPSET,
        }],
        producer_name: "evpose".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        graph: Some(pb::GraphProto {
            name: "evpose_int8".into(),
            node: g.nodes,
            initializer: g.inits,
            input: vec![value_info(
                "points",
                DataType::Float,
                &[Some(1), Some(5), q.points],
            )],
            output: outputs,
            ..Default::default()
        }),
        ..Default::default()
    };
    Ok(model.encode_to_vec())
}

impl QuantNet {
    /// The same integer computation as a standard ONNX graph (opset 13) with int32 outputs
    /// `simdr_x` `(1, J, W)` and `simdr_y` `(1, J, H)`.
    pub fn onnx(&self) -> Result<Vec<u8>> {
        build(self)
    }
}

//! ONNX import: a PyTorch export of the paper's network family → [`FloatNet`].
//!
//! tract-onnx loads and types the graph (any opset it reads, 11–18 included); typing folds the
//! shape glue (`Shape`/`Gather`/`Unsqueeze`/`Concat` into constant reshapes) and turns each
//! `BatchNormalization` into a per-channel `Mul` + `Add`, which we fold into the preceding
//! layer. The typed graph is then interpreted symbolically, node by node in evaluation order:
//! every outlet is classified (constant, per-point features, a pending linear layer, a pooled
//! vector, …) and any node that does not fit the family is rejected with its name.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{anyhow, bail, ensure, Context, Result};
use tract_core::internal::DimLike;
use tract_core::ops::binary::TypedBinOp;
use tract_core::ops::cnn::{Conv, MaxPool};
use tract_core::ops::einsum::EinSum;
use tract_core::ops::element_wise::ElementWiseOp;
use tract_core::ops::konst::Const;
use tract_core::ops::nn::{LeakyRelu, Reduce, Reducer};
use tract_onnx::prelude::*;
use tract_onnx::tract_hir::infer::Factoid;

use super::net::{Dense, FloatNet};

/// Point count used to type a dynamic-N export (any value works; it must not be a common
/// width so that it cannot be confused with one).
const TYPING_POINTS: usize = 1031;

/// A symbolic value flowing along an outlet.
#[derive(Clone, Debug)]
enum Val {
    /// A constant tensor (f32 values).
    Const(Vec<f32>),
    /// Per-point features `(1, C, N)`: the concatenation of blocks (0 = input, i = point layer i).
    Feat(Vec<usize>),
    /// A linear layer's output before its activation.
    Lin(Pending),
    /// Max over points of point layer `l`.
    Max(usize),
    /// Sum over points of point layer `l`.
    Sum(usize),
    /// Mean over points of point layer `l`.
    Mean(usize),
    /// A vector after pooling: the pooled concatenation (`None`) or FC layer `i`'s output.
    Vector(Option<usize>),
    /// The last FC output viewed as `(1, J, D)`.
    Joints(usize),
    /// A head's output.
    Head(Box<Dense>),
}

#[derive(Clone, Debug, PartialEq)]
struct Pending {
    stage: Stage,
    layer: Dense,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Stage {
    Point,
    Fc,
    Head,
}

struct Importer {
    point: Vec<Dense>,
    fc: Vec<Dense>,
    points: usize,
    /// Pending layers already finalized without an activation, with what they became: a
    /// layer read twice (by a max and a mean) is one layer, not two.
    settled: Vec<(Pending, Val)>,
}

/// Imports an ONNX export of the paper's network family.
pub fn import_onnx(path: &Path) -> Result<FloatNet> {
    super::refuse_blob(path)?;
    let model = tract_onnx::onnx()
        .model_for_path(path)
        .map_err(|e| anyhow!("{}: cannot load ONNX model: {e:?}", path.display()))?;
    let fact = model
        .input_fact(0)
        .map_err(|e| anyhow!("{}: no input: {e}", path.display()))?;
    let fixed = fact
        .shape
        .dims()
        .nth(2)
        .and_then(|d| d.concretize())
        .and_then(|d| d.to_usize().ok());
    let n = fixed.unwrap_or(TYPING_POINTS);
    let typed = model
        .with_input_fact(0, f32::fact([1, 5, n]).into())
        .and_then(|m| m.into_typed())
        .map_err(|e| anyhow!("{}: cannot type the graph: {e:?}", path.display()))?;
    let mut net = Importer {
        point: Vec::new(),
        fc: Vec::new(),
        points: n,
        settled: Vec::new(),
    }
    .run(&typed)
    .with_context(|| {
        format!(
            "{}: not a PointNet-SimDR model of the family the core imports (tract runs any \
             ONNX export: --engine tract)",
            path.display()
        )
    })?;
    net.points = fixed;
    // A model whose training diverged has NaN or infinite weights: refuse it here, where the
    // layer can be named, not after quantization made plausible integers of it.
    for (i, (kind, l)) in net.layers().enumerate() {
        let bad = l.w.iter().chain(&l.b).find(|v| !v.is_finite());
        if let Some(v) = bad {
            bail!(
                "{}: layer {i} ({}) has a non-finite weight or bias ({v})",
                path.display(),
                evpose_core::infer::describe(kind)
            );
        }
    }
    Ok(net)
}

fn consts(v: &Val) -> Option<&[f32]> {
    match v {
        Val::Const(c) => Some(c),
        _ => None,
    }
}

impl Importer {
    fn run(mut self, model: &TypedModel) -> Result<FloatNet> {
        let mut vals: HashMap<OutletId, Val> = HashMap::new();
        for id in model.eval_order()? {
            let node = model.node(id);
            let inputs: Vec<&Val> = node
                .inputs
                .iter()
                .map(|o| {
                    vals.get(o)
                        .ok_or_else(|| anyhow!("input of '{}' unknown", node.name))
                })
                .collect::<Result<_>>()?;
            let out = self.eval(model, node, &inputs).with_context(|| {
                format!("unsupported node '{}' ({})", node.name, node.op.name())
            })?;
            vals.insert(OutletId::new(id, 0), out);
        }
        let outlets = model.output_outlets()?;
        let mut outputs: Vec<&Val> = outlets
            .iter()
            .map(|o| vals.get(o).ok_or_else(|| anyhow!("output not computed")))
            .collect::<Result<_>>()?;
        // The heads are taken in output order (x, then y) unless their names say otherwise.
        if let [a, b] = outlets {
            if super::heads_swapped([model.outlet_label(*a), model.outlet_label(*b)]) {
                outputs.swap(0, 1);
            }
        }
        let heads: Vec<Dense> = outputs
            .iter()
            .map(|v| match v {
                Val::Head(d) => Ok((**d).clone()),
                Val::Lin(p) if p.stage == Stage::Head => Ok(p.layer.clone()),
                _ => bail!("model outputs must be the two heads' logits"),
            })
            .collect::<Result<_>>()?;
        let [hx, hy] = &heads[..] else {
            bail!(
                "expected two outputs (simdr_x, simdr_y), found {}",
                heads.len()
            );
        };
        ensure!(
            !self.fc.is_empty(),
            "no fully connected layer after pooling"
        );
        let last = self.fc.last().map_or(0, |l| l.out_dim);
        ensure!(
            last.is_multiple_of(hx.in_dim),
            "last FC width {last} is not a multiple of the head width {}",
            hx.in_dim
        );
        Ok(FloatNet {
            joints: last / hx.in_dim,
            point: self.point,
            fc: self.fc,
            head_x: hx.clone(),
            head_y: hy.clone(),
            points: None,
        })
    }

    fn eval(&mut self, model: &TypedModel, node: &TypedNode, ins: &[&Val]) -> Result<Val> {
        let op = &node.op;
        if let Some(c) = op.downcast_ref::<Const>() {
            let t = c.val().cast_to::<f32>()?;
            return Ok(Val::Const(
                t.try_as_plain_ram()?.as_slice::<f32>()?.to_vec(),
            ));
        }
        if node.inputs.is_empty() {
            return Ok(Val::Feat(vec![0])); // the Source
        }
        // Typing does not fold every node on constants only: tract wires a Gemm's bias (how
        // PyTorch exports nn.Linear with its default bias on a 2-D input) as `Mul(beta, C)` of
        // two constants. Such nodes are evaluated, by the op itself.
        if ins.iter().all(|v| matches!(v, Val::Const(_))) {
            if let Some(v) = fold(model, node, ins)? {
                return Ok(v);
            }
        }
        if let Some(conv) = op.downcast_ref::<Conv>() {
            return self.conv(model, node, conv, ins);
        }
        if let Some(e) = op.downcast_ref::<ElementWiseOp>() {
            if let Some(l) = e.0.downcast_ref::<LeakyRelu>() {
                return self.activate(ins[0], Some(l.alpha));
            }
            bail!("element-wise op {} is not in the family", e.0.name());
        }
        if let Some(r) = op.downcast_ref::<Reduce>() {
            let l = self.single_layer(ins[0])?;
            ensure!(r.axes[..] == [2], "reduction must be over the points axis");
            return match r.reducer {
                Reducer::Max => Ok(Val::Max(l)),
                Reducer::Sum => Ok(Val::Sum(l)),
                _ => bail!("reducer {:?} is not in the family", r.reducer),
            };
        }
        if let Some(p) = op.downcast_ref::<MaxPool>() {
            let l = self.single_layer(ins[0])?;
            ensure!(
                p.pool_spec.kernel_shape[..] == [self.points],
                "MaxPool must span all points"
            );
            return Ok(Val::Max(l));
        }
        if let Some(e) = op.downcast_ref::<EinSum>() {
            return self.matmul(model, node, e, ins);
        }
        if let Some(b) = op.downcast_ref::<TypedBinOp>() {
            return self.binary(b.0.name(), ins);
        }
        match op.name().as_ref() {
            "Concat" => {
                let axis = op
                    .downcast_ref::<tract_core::ops::array::TypedConcat>()
                    .map(|c| c.axis);
                self.concat(axis, ins)
            }
            // Shape-only ops: the value is the same.
            "AddAxis" | "RmAxis" | "Reshape" | "Cast" | "Identity" => {
                self.reshape(model, node, ins[0])
            }
            other => bail!("op {other} is not in the family"),
        }
    }

    fn conv(
        &mut self,
        model: &TypedModel,
        node: &TypedNode,
        conv: &Conv,
        ins: &[&Val],
    ) -> Result<Val> {
        ensure!(conv.group == 1, "grouped convolution");
        ensure!(
            conv.pool_spec.kernel_shape[..] == [1],
            "only 1x1 convolutions (per-point layers)"
        );
        let Val::Feat(srcs) = ins[0] else {
            bail!("convolution input is not per-point features");
        };
        let w = consts(ins[1]).context("convolution weights are not constant")?;
        let wshape = model
            .outlet_fact(node.inputs[1])?
            .shape
            .as_concrete()
            .context("weight shape")?
            .to_vec();
        let (out_dim, in_dim) = (wshape[0], wshape[1]);
        ensure!(w.len() == out_dim * in_dim, "weights must be (out, in, 1)");
        let b = match ins.get(2) {
            Some(v) => consts(v)
                .context("convolution bias is not constant")?
                .to_vec(),
            None => vec![0.0; out_dim],
        };
        let b = broadcast(&b, out_dim)?;
        let sources = self.sources(srcs, in_dim)?;
        Ok(Val::Lin(Pending {
            stage: Stage::Point,
            layer: Dense {
                in_dim,
                out_dim,
                w: w.to_vec(),
                b,
                leaky: None,
                sources,
            },
        }))
    }

    /// Bitmask of a per-point input made of blocks; checks the width.
    fn sources(&self, srcs: &[usize], in_dim: usize) -> Result<u32> {
        let mut width = 0;
        let mut mask = 0u32;
        for (i, &s) in srcs.iter().enumerate() {
            ensure!(
                i == 0 || s == srcs[i - 1] + 1,
                "concatenated layers must be consecutive, in order"
            );
            width += if s == 0 { 5 } else { self.point[s - 1].out_dim };
            mask |= 1 << s;
        }
        ensure!(
            width == in_dim,
            "input width {width} does not match the weights ({in_dim})"
        );
        ensure!(
            mask == 1 || mask & 1 == 0,
            "the input features must feed a layer alone"
        );
        Ok(mask)
    }

    fn activate(&mut self, v: &Val, leaky: Option<f32>) -> Result<Val> {
        let Val::Lin(p) = v else {
            bail!("activation of something other than a linear layer");
        };
        let mut layer = p.layer.clone();
        layer.leaky = leaky;
        match p.stage {
            Stage::Point => {
                ensure!(
                    self.point.len() < evpose_core::model::MAX_POINT_LAYERS,
                    "too many point layers"
                );
                self.point.push(layer);
                Ok(Val::Feat(vec![self.point.len()]))
            }
            Stage::Fc => {
                self.fc.push(layer);
                Ok(Val::Vector(Some(self.fc.len() - 1)))
            }
            Stage::Head => bail!("activation after a head"),
        }
    }

    /// A per-point value that is one layer's output (what pooling reads).
    fn single_layer(&mut self, v: &Val) -> Result<usize> {
        let v = self.settle(v)?;
        match v {
            Val::Feat(s) if s.len() == 1 && s[0] > 0 => Ok(s[0]),
            _ => bail!("pooling must read one point layer's output"),
        }
    }

    /// Finalizes a pending layer used without activation (once: a second reader gets the same
    /// layer).
    fn settle(&mut self, v: &Val) -> Result<Val> {
        match v {
            Val::Lin(p) => {
                if let Some((_, done)) = self.settled.iter().find(|(q, _)| q == p) {
                    return Ok(done.clone());
                }
                let done = self.activate(v, None)?;
                self.settled.push((p.clone(), done.clone()));
                Ok(done)
            }
            other => Ok(other.clone()),
        }
    }

    /// A concatenation along `axis` (the op's, where tract says it).
    fn concat(&mut self, axis: Option<usize>, ins: &[&Val]) -> Result<Val> {
        let ins: Vec<Val> = ins.iter().map(|v| self.settle(v)).collect::<Result<_>>()?;
        // Per-point features `(1, C, N)` and pooled vectors `(1, C)` or `(1, C, 1)` join along
        // the channels; `[max, mean]` along another axis (e.g. `torch.cat(.., dim=2)` then a
        // flatten) interleaves them, which the blob's `[max…, mean…]` layout would misread.
        if ins.iter().any(|v| !matches!(v, Val::Const(_))) {
            ensure!(
                axis == Some(1),
                "concatenation must be along the channel axis (1), not {}",
                axis.map_or("an unknown one".to_string(), |a| a.to_string())
            );
        }
        match &ins[..] {
            [Val::Max(a), Val::Mean(b)] if a == b => {
                ensure!(
                    *a == self.point.len(),
                    "the pooled layer must be the last point layer"
                );
                Ok(Val::Vector(None))
            }
            [Val::Mean(_), Val::Max(_)] => bail!("pooling must be concatenated as [max, mean]"),
            feats if feats.iter().all(|v| matches!(v, Val::Feat(_))) => Ok(Val::Feat(
                feats
                    .iter()
                    .flat_map(|v| match v {
                        Val::Feat(s) => s.clone(),
                        _ => Vec::new(),
                    })
                    .collect(),
            )),
            _ => bail!("concatenation of values that are not per-point features or [max, mean]"),
        }
    }

    fn reshape(&mut self, model: &TypedModel, node: &TypedNode, v: &Val) -> Result<Val> {
        let shape = model
            .outlet_fact(OutletId::new(node.id, 0))?
            .shape
            .to_tvec();
        // A point or FC layer without an activation is final once reshaped (the last FC
        // viewed as joints); a head's output stays what it is.
        let settled;
        let v = match v {
            Val::Lin(p) if p.stage != Stage::Head => {
                settled = self.settle(v)?;
                &settled
            }
            other => other,
        };
        Ok(match v {
            Val::Vector(Some(i)) if shape.len() == 3 && *i + 1 == self.fc.len() => {
                let d = shape[2].to_usize()?;
                Val::Joints(d)
            }
            other => other.clone(),
        })
    }

    fn binary(&mut self, name: &str, ins: &[&Val]) -> Result<Val> {
        let (a, b) = (ins[0], ins[1]);
        let (lin, c) = match (a, b) {
            (Val::Lin(p), Val::Const(c)) | (Val::Const(c), Val::Lin(p)) => (p, c),
            (Val::Sum(l), Val::Const(c)) if c.len() == 1 => {
                let n = self.points as f32;
                return match name {
                    "Div" if c[0] == n => Ok(Val::Mean(*l)),
                    "Mul" if c[0] == 1.0 / n => Ok(Val::Mean(*l)),
                    _ => bail!("sum over points must be divided by the point count"),
                };
            }
            _ => bail!("{name} of values other than a linear layer and a constant"),
        };
        let out = lin.layer.out_dim;
        let c = broadcast(c, out)?;
        let mut p = lin.clone();
        match name {
            // BatchNorm slope (or any per-channel scale): W ← diag(c) W, b ← c b.
            "Mul" => {
                for (o, &s) in c.iter().enumerate() {
                    p.layer.w[o * p.layer.in_dim..(o + 1) * p.layer.in_dim]
                        .iter_mut()
                        .for_each(|w| *w *= s);
                    p.layer.b[o] *= s;
                }
            }
            "Add" => p.layer.b.iter_mut().zip(&c).for_each(|(b, c)| *b += c),
            "Sub" if matches!(a, Val::Lin(_)) => {
                p.layer.b.iter_mut().zip(&c).for_each(|(b, c)| *b -= c)
            }
            _ => bail!("{name} after a linear layer is not in the family"),
        }
        if p.stage == Stage::Head {
            return Ok(Val::Head(Box::new(p.layer)));
        }
        Ok(Val::Lin(p))
    }

    fn matmul(
        &mut self,
        model: &TypedModel,
        node: &TypedNode,
        e: &EinSum,
        ins: &[&Val],
    ) -> Result<Val> {
        ensure!(e.q_params.is_none(), "quantized matmul");
        let w = consts(ins[1]).context("matmul weights are not constant (second input)")?;
        let ws = model
            .outlet_fact(node.inputs[1])?
            .shape
            .as_concrete()
            .context("weight shape")?
            .to_vec();
        ensure!(ws.len() == 2, "matmul weights must be 2-D");
        // A Linear without bias (and any Linear on a 3-D input) is exported as MatMul, weights
        // stored (in, out). nn.Linear's default, with a bias, on a 2-D input is exported as
        // Gemm(transB=1) instead, which tract types as an EinSum over weights stored (out, in)
        // (`nk`) followed by an Add of the bias.
        let axes = e.axes.to_string();
        let transposed = match axes.as_str() {
            "mk,kn->mn" | "amk,kn->amn" | "k,kn->n" | "ak,kn->an" => false,
            "mk,nk->mn" | "amk,nk->amn" | "k,nk->n" | "ak,nk->an" => true,
            _ => bail!("matmul of form {axes} is not a vector-matrix product"),
        };
        let (in_dim, out_dim) = if transposed {
            (ws[1], ws[0])
        } else {
            (ws[0], ws[1])
        };
        // → [out][in]
        let wt = if transposed {
            w.to_vec()
        } else {
            let mut wt = vec![0.0; w.len()];
            for k in 0..in_dim {
                for o in 0..out_dim {
                    wt[o * in_dim + k] = w[k * out_dim + o];
                }
            }
            wt
        };
        let layer = Dense {
            in_dim,
            out_dim,
            w: wt,
            b: vec![0.0; out_dim],
            leaky: None,
            sources: 0,
        };
        let stage = match self.settle(ins[0])? {
            Val::Vector(v) => {
                let width = match v {
                    None => 2 * self.point.last().map_or(0, |l| l.out_dim),
                    Some(i) => self.fc[i].out_dim,
                };
                ensure!(
                    width == in_dim,
                    "matmul input width {width} does not match weights ({in_dim})"
                );
                Stage::Fc
            }
            Val::Joints(d) => {
                ensure!(
                    d == in_dim,
                    "head input width {d} does not match weights ({in_dim})"
                );
                Stage::Head
            }
            _ => bail!("matmul input is not a pooled vector or per-joint features"),
        };
        Ok(Val::Lin(Pending { stage, layer }))
    }
}

/// Evaluates a node whose inputs are all constants; `None` if the op cannot be evaluated alone.
fn fold(model: &TypedModel, node: &TypedNode, ins: &[&Val]) -> Result<Option<Val>> {
    let inputs = node
        .inputs
        .iter()
        .zip(ins)
        .map(|(o, v)| {
            let fact = model.outlet_fact(*o)?;
            let shape = fact
                .shape
                .as_concrete()
                .context("constant of unknown shape")?;
            let t = Tensor::from_shape(shape, consts(v).unwrap_or_default())?;
            Ok(t.cast_to_dt(fact.datum_type)?.into_owned().into_tvalue())
        })
        .collect::<Result<TVec<_>>>()?;
    let Some(out) = node.op.eval_out_of_plan(inputs)? else {
        return Ok(None);
    };
    let t = out[0].cast_to::<f32>()?;
    Ok(Some(Val::Const(
        t.try_as_plain_ram()?.as_slice::<f32>()?.to_vec(),
    )))
}

/// A per-channel constant of length `n`, or a scalar repeated.
fn broadcast(c: &[f32], n: usize) -> Result<Vec<f32>> {
    match c.len() {
        1 => Ok(vec![c[0]; n]),
        len if len == n => Ok(c.to_vec()),
        len => bail!("constant of {len} values does not match {n} channels"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The small fixture's protobuf.
    fn small_proto() -> tract_onnx::pb::ModelProto {
        use prost::Message;
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/pointnet-small.onnx");
        tract_onnx::pb::ModelProto::decode(&*std::fs::read(path).unwrap()).unwrap()
    }

    /// Imports `proto` (through a temporary file).
    fn import_proto(proto: &tract_onnx::pb::ModelProto, name: &str) -> Result<FloatNet> {
        use prost::Message;
        let path = std::env::temp_dir().join(format!("evpose-{name}-{}.onnx", std::process::id()));
        std::fs::write(&path, proto.encode_to_vec()).unwrap();
        let net = import_onnx(&path);
        std::fs::remove_file(&path).unwrap();
        net
    }

    #[test]
    fn layers_without_activation_read_twice_or_reshaped_import() {
        // conv5 without its LeakyReLU (read by both pools) and the last FC without its own
        // (reshaped into the joints' features): one layer each, without a slope.
        let mut proto = small_proto();
        let graph = proto.graph.as_mut().unwrap();
        for name in ["/conv5/conv5.2/LeakyRelu", "/out2/out2.2/LeakyRelu"] {
            let at = graph.node.iter().position(|n| n.name == name).unwrap();
            let node = graph.node.remove(at);
            let (x, y) = (&node.input[0], &node.output[0]);
            for input in graph.node.iter_mut().flat_map(|n| n.input.iter_mut()) {
                if input == y {
                    *input = x.clone();
                }
            }
        }
        let want = import_onnx(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/pointnet-small.onnx"),
        )
        .unwrap();
        let got = import_proto(&proto, "no-activation").unwrap();
        assert_eq!(
            (got.point.len(), got.fc.len()),
            (want.point.len(), want.fc.len())
        );
        assert_eq!(got.point[4].leaky, None);
        assert_eq!(got.fc[1].leaky, None);
        assert_eq!(got.point[4].w, want.point[4].w);
        assert_eq!(got.fc[1].w, want.fc[1].w);
    }

    #[test]
    fn heads_are_matched_by_their_output_names() {
        // The small fixture with its outputs listed as (simdr_y, simdr_x): the same heads, in
        // the import and in tract.
        use prost::Message;
        let original =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/pointnet-small.onnx");
        let want = import_onnx(&original).unwrap();
        let mut proto = small_proto();
        let graph = proto.graph.as_mut().unwrap();
        assert_eq!(graph.output[0].name, "simdr_x");
        graph.output.swap(0, 1);
        let got = import_proto(&proto, "swapped").unwrap();
        assert_eq!((got.head_x.out_dim, got.head_y.out_dim), (346, 260));
        assert_eq!(got, want);
        let swapped =
            std::env::temp_dir().join(format!("evpose-swapped-{}.onnx", std::process::id()));
        std::fs::write(&swapped, proto.encode_to_vec()).unwrap();
        let points: Vec<[f32; 5]> = (0..64)
            .map(|i| [i as f32 * 5.0, i as f32 * 3.0, 0.5, 1.0, 2.0])
            .collect();
        let run = |p: &Path| {
            super::super::TractModel::load(p)
                .unwrap()
                .run(&points)
                .unwrap()
        };
        let (a, b) = (run(&original), run(&swapped));
        std::fs::remove_file(&swapped).unwrap();
        assert_eq!(a.x.len(), 13 * 346);
        assert_eq!((a.x, a.y), (b.x, b.y));
    }

    #[test]
    fn tract_refuses_an_empty_point_cloud() {
        // (tract itself divides by the point count: a panic, where the core engines say why.)
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/pointnet-small.onnx");
        let mut t = super::super::TractModel::load(&path).unwrap();
        let err = t.run(&[]).unwrap_err().to_string();
        assert_eq!(err, "no input points");
    }

    #[test]
    fn concatenations_off_the_channel_axis_are_refused() {
        let layer = Dense {
            in_dim: 5,
            out_dim: 8,
            w: vec![0.0; 40],
            b: vec![0.0; 8],
            leaky: None,
            sources: 1,
        };
        let mut imp = Importer {
            point: vec![layer],
            fc: Vec::new(),
            points: 16,
            settled: Vec::new(),
        };
        // `[max, mean]` of the last point layer: along the channels it is the pooled vector;
        // along the points axis (`torch.cat(.., dim=2)` before a flatten) it is refused.
        let (max, mean) = (Val::Max(1), Val::Mean(1));
        assert!(matches!(
            imp.concat(Some(1), &[&max, &mean]),
            Ok(Val::Vector(None))
        ));
        for axis in [Some(0), Some(2), None] {
            let err = imp.concat(axis, &[&max, &mean]).unwrap_err().to_string();
            assert!(
                err.starts_with("concatenation must be along the channel axis (1)"),
                "{err}"
            );
        }
        // Per-point features likewise.
        let (a, b) = (Val::Feat(vec![0]), Val::Feat(vec![1]));
        assert!(matches!(imp.concat(Some(1), &[&a, &b]), Ok(Val::Feat(f)) if f == [0, 1]));
        assert!(imp.concat(Some(2), &[&a, &b]).is_err());
    }
}

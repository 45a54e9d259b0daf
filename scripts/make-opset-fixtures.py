#!/usr/bin/env python3
"""Writes the opset-matrix fixtures that `tests/opsets.rs` imports and checks.

The paper's PointNet-SimDR family (shared/docs/paper-notes.md, "Network"; the PyTorch definition
is train/models.py's `PointNet`, the one training uses), with tiny widths, exported with PyTorch's TorchScript exporter (`dynamo=False`, as the reference models
`pointnet-small.onnx` / `pointnet-paper.onnx` were) at every opset 11..18, with a fixed or a
dynamic point count, two (J, W, H) sets and two width sets:

- conv1..conv4: 1x1 Conv1d 5->a->b->c->d, no bias, BatchNorm1d, LeakyReLU(0.01);
- conv5: 1x1 Conv1d on concat(x1..x4), BatchNorm1d, LeakyReLU(0.01);
- max pooling (`adaptive_max_pool1d(x, 1)`: MaxPool over all N for a fixed N, GlobalMaxPool for
  a dynamic one) and mean pooling (`adaptive_avg_pool1d(x, 1)`: GlobalAveragePool) over the
  points, concatenated [max, mean];
- Linear -> BatchNorm1d -> LeakyReLU twice, the second to J * head_dim; reshape (J, head_dim);
- head_x Linear(head_dim -> W) and head_y Linear(head_dim -> H), shared by the joints, with bias.

Input `points` (1, 5, N) (dim 2 named "n" when dynamic), outputs `simdr_x` (1, J, W) and
`simdr_y` (1, J, H), like the reference exports. The fully connected layers have no bias, like
the reference models, except in the entries marked `fc_bias` (nn.Linear's default), which
PyTorch exports as Gemm instead of MatMul.

Weights, BatchNorm affine parameters and running statistics are random (seeded; eval mode), so
that every BatchNorm is non-trivial. Per model the script writes, to tests/fixtures/opsets/:
- `<name>.onnx`;
- `<name>.input.npy`: one seeded (64, 5) float32 point cloud of rows [x, y, t_avg, p_acc, cnt]
  (x < W and y < H integers, t_avg in [0, 1), p_acc small integers, cnt in 1..5);
- `<name>.simdr_x.npy`, `<name>.simdr_y.npy`: onnxruntime's outputs on that input (float32);
and `manifest.json` listing every model's opset, fixed/dynamic, J, W, H and widths.

Usage: python3 scripts/make-opset-fixtures.py  (with train/requirements.txt installed)
  (torch with the TorchScript ONNX exporter, onnx, onnxruntime, numpy; seeded: re-running gives
  the same outputs, and the same files with the same torch version)
"""

import json
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from torch import nn

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "train"))
import models  # noqa: E402  (train/models.py)

OUT = ROOT / "tests" / "fixtures" / "opsets"
POINTS = 64
SEED = 1118

# (a, b, c, d, conv5, fc, head_dim)
WIDTHS = {
    "w8": (8, 8, 16, 16, 32, 32, 8),
    "w12": (12, 16, 16, 24, 40, 24, 6),
}
# (J, W, H)
SENSORS = {
    13: (13, 346, 260),
    5: (5, 64, 48),
}

# (opset, dynamic N, joints, widths, FC bias): every opset both fixed and dynamic; the sensor,
# widths and FC bias alternate so that each opset sees two different networks.
MATRIX = [
    (11, False, 13, "w8", False),
    (11, True, 5, "w12", False),
    (12, False, 5, "w12", False),
    (12, True, 13, "w8", True),
    (13, False, 13, "w12", False),
    (13, True, 5, "w8", False),
    (14, False, 5, "w8", True),
    (14, True, 13, "w12", False),
    (15, False, 13, "w8", False),
    (15, True, 5, "w12", True),
    (16, False, 5, "w12", False),
    (16, True, 13, "w8", False),
    (17, False, 13, "w12", True),
    (17, True, 5, "w8", False),
    (18, False, 5, "w8", False),
    (18, True, 13, "w12", True),
]


def pointnet(widths, joints, width, height, fc_bias=False):
    """train/models.py's PointNet (the one definition of the family), optionally with biased
    fully connected layers."""
    model = models.PointNet(widths, joints=joints, width=width, height=height)
    if fc_bias:
        e, fc, head = widths[4:]
        for seq, cin, cout in [(model.head.out1, 2 * e, fc), (model.head.out2, fc, joints * head)]:
            seq[0] = nn.Linear(cin, cout, bias=True)
    return model


def randomize(model, gen):
    """Random weights and non-trivial BatchNorms (affine and running statistics)."""
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, (nn.Conv1d, nn.Linear)):
                fan_in = m.weight.shape[1]
                m.weight.copy_(torch.randn(m.weight.shape, generator=gen) / fan_in**0.5)
                if m.bias is not None:
                    m.bias.copy_(0.1 * torch.randn(m.bias.shape, generator=gen))
            elif isinstance(m, nn.BatchNorm1d):
                n = m.num_features
                m.weight.copy_(0.5 + torch.rand(n, generator=gen))
                m.bias.copy_(0.2 * torch.randn(n, generator=gen))
                m.running_mean.copy_(0.3 * torch.randn(n, generator=gen))
                m.running_var.copy_(0.5 + torch.rand(n, generator=gen))
    return model.eval()


def point_cloud(rng, width, height):
    """(POINTS, 5) rows [x, y, t_avg, p_acc, cnt] with realistic ranges."""
    x = rng.integers(0, width, POINTS)
    y = rng.integers(0, height, POINTS)
    t = rng.random(POINTS)
    p = rng.integers(-3, 4, POINTS)
    cnt = rng.integers(1, 6, POINTS)
    return np.stack([x, y, t, p, cnt], axis=1).astype(np.float32)


def export(model, path, opset, dynamic):
    kwargs = {}
    if dynamic:
        kwargs["dynamic_axes"] = {"points": {2: "n"}}
    torch.onnx.export(
        model,
        torch.zeros(1, 5, POINTS),
        str(path),
        opset_version=opset,
        input_names=["points"],
        output_names=["simdr_x", "simdr_y"],
        do_constant_folding=True,
        dynamo=False,
        **kwargs,
    )


def main():
    torch.manual_seed(SEED)
    OUT.mkdir(parents=True, exist_ok=True)
    manifest = []
    for i, (opset, dynamic, joints, wname, fc_bias) in enumerate(MATRIX):
        j, width, height = SENSORS[joints]
        widths = WIDTHS[wname]
        name = f"pn-o{opset}-{'dynamic' if dynamic else 'fixed'}-j{j}"
        gen = torch.Generator().manual_seed(SEED + i)
        model = randomize(pointnet(widths, j, width, height, fc_bias), gen)
        path = OUT / f"{name}.onnx"
        export(model, path, opset, dynamic)
        m = onnx.load(str(path))
        onnx.checker.check_model(m)
        got = [o.version for o in m.opset_import if o.domain in ("", "ai.onnx")]
        assert got == [opset], f"{name}: opset {got}"

        points = point_cloud(np.random.default_rng(SEED + i), width, height)
        sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        inp = points.T[None].copy()  # (N, 5) -> (1, 5, N)
        sx, sy = sess.run(["simdr_x", "simdr_y"], {"points": inp})
        with torch.no_grad():
            tx, ty = model(torch.from_numpy(inp))
        for o, t in [(sx, tx), (sy, ty)]:
            assert np.allclose(o, t.numpy(), rtol=1e-4, atol=1e-4), f"{name}: ort vs torch"
        assert sx.shape == (1, j, width) and sy.shape == (1, j, height), name
        np.save(OUT / f"{name}.input.npy", points)
        np.save(OUT / f"{name}.simdr_x.npy", sx.astype(np.float32))
        np.save(OUT / f"{name}.simdr_y.npy", sy.astype(np.float32))

        ops = sorted({n.op_type for n in m.graph.node})
        manifest.append({
            "name": name,
            "opset": opset,
            "dynamic": dynamic,
            "points": POINTS,
            "joints": j,
            "width": width,
            "height": height,
            "widths": dict(zip(["conv1", "conv2", "conv3", "conv4", "conv5", "fc", "head_dim"],
                               widths)),
            "fc_bias": fc_bias,
            "ops": ops,
        })
        print(f"{name}: {path.stat().st_size} bytes, ops {' '.join(ops)}")
    (OUT / "manifest.json").write_text(json.dumps({
        "torch": torch.__version__.split("+")[0],
        "onnxruntime": ort.__version__,
        "models": manifest,
    }, indent=1) + "\n")


if __name__ == "__main__":
    main()

"""The paper's three backbones, each ending in the same SimDR head.

Every model maps a point cloud `(B, 5, N)` of rows `[x, y, t_avg, p_acc, cnt]` (raw, as the
rasterizer writes them) to `simdr_x (B, J, W)` and `simdr_y (B, J, H)` logits.

- `PointNet`: the paper's variant (../shared/docs/paper-notes.md, "Network"): five 1x1
  convolutions without bias, BatchNorm and LeakyReLU(0.01), the fifth on the concatenation of
  the first four; max and mean pooling over the points. This is the form `evpose` imports into
  its core (f32 and int8); `PAPER_WIDTHS` are Table 4's.
- `DGCNN`: EdgeConv layers (Wang et al. 2019): per point the k nearest neighbours (in input
  space for the first layer, in feature space after), features `[x_j - x_i, x_i]`, a shared
  1x1 convolution and a max over the neighbours; the layer outputs are concatenated and
  embedded, then pooled like PointNet's.
- `PointTransformer`: vector self-attention over the k nearest neighbours in input space
  (Zhao et al. 2021): per neighbour `gamma(q_i - k_j + delta_ij)` weighs `v_j + delta_ij`
  channel by channel after a softmax over the neighbours, `delta = theta(p_i - p_j)` a learnt
  position encoding; residual blocks between linear layers, then the same pooling.

DGCNN and the Point Transformer run in `evpose` through tract (`evpose eval --engine tract`);
their k-NN exports as TopK and Gather.
"""

import torch
from torch import nn
import torch.nn.functional as F

#: DHP19: 13 joints, 346 x 260 sensor.
JOINTS, WIDTH, HEIGHT = 13, 346, 260

#: PointNet widths `(conv1, conv2, conv3, conv4, conv5, fc, head_dim)` of the paper (Table 4).
PAPER_WIDTHS = (64, 64, 128, 256, 1024, 1024, 128)

#: Scale that brings the raw input channels to about unit range for k-NN distances:
#: x / W, y / H, t_avg as is; polarity and count do not enter the neighbourhood.
KNN_SCALE = (1.0 / WIDTH, 1.0 / HEIGHT, 1.0, 0.0, 0.0)


def dense(conv, cin, cout):
    """A 1x1 convolution (per point) or a linear layer, without bias, then BN and LeakyReLU."""
    layer = nn.Conv1d(cin, cout, 1, bias=False) if conv else nn.Linear(cin, cout, bias=False)
    return nn.Sequential(layer, nn.BatchNorm1d(cout), nn.LeakyReLU(0.01))


class SimDRHead(nn.Module):
    """Pooled features `(B, C)` -> two FC layers -> `(B, J, D)` -> shared x and y heads."""

    def __init__(self, cin, fc, head_dim, joints=JOINTS, width=WIDTH, height=HEIGHT,
                 dropout=0.1):
        super().__init__()
        self.joints, self.head_dim = joints, head_dim
        self.out1 = nn.Sequential(*dense(False, cin, fc), nn.Dropout(dropout))
        self.out2 = nn.Sequential(*dense(False, fc, joints * head_dim), nn.Dropout(dropout))
        self.head_x = nn.Linear(head_dim, width)
        self.head_y = nn.Linear(head_dim, height)

    def forward(self, pooled):
        f = self.out2(self.out1(pooled)).view(pooled.size(0), self.joints, self.head_dim)
        return self.head_x(f), self.head_y(f)


def pool(x):
    """Max and mean over the points of `(B, C, N)`, concatenated: `(B, 2C)`.

    `adaptive_*_pool1d(x, 1)` exports as MaxPool (fixed N) / GlobalAveragePool, the form the
    `evpose` importer reads.
    """
    b = x.size(0)
    return torch.cat((F.adaptive_max_pool1d(x, 1).view(b, -1),
                      F.adaptive_avg_pool1d(x, 1).view(b, -1)), dim=1)


class PointNet(nn.Module):
    """The paper's PointNet-SimDR; `widths = (c1, c2, c3, c4, c5, fc, head_dim)`."""

    def __init__(self, widths=PAPER_WIDTHS, dropout=0.1, **sensor):
        super().__init__()
        a, b, c, d, e, fc, head = widths
        self.conv1 = dense(True, 5, a)
        self.conv2 = dense(True, a, b)
        self.conv3 = dense(True, b, c)
        self.conv4 = dense(True, c, d)
        self.conv5 = dense(True, a + b + c + d, e)
        self.head = SimDRHead(2 * e, fc, head, dropout=dropout, **sensor)

    def forward(self, x):
        x1 = self.conv1(x)
        x2 = self.conv2(x1)
        x3 = self.conv3(x2)
        x4 = self.conv4(x3)
        x5 = self.conv5(torch.cat((x1, x2, x3, x4), dim=1))
        return self.head(pool(x5))


def knn(p, k):
    """Indices `(B, N, k)` of the k nearest points of each point (itself included) in `p`
    `(B, C, N)`."""
    inner = torch.bmm(p.transpose(1, 2), p)  # (B, N, N)
    sq = (p * p).sum(dim=1, keepdim=True)  # (B, 1, N)
    neg = 2 * inner - sq - sq.transpose(1, 2)  # -|p_i - p_j|^2
    return neg.topk(k, dim=-1)[1]


def gather(x, idx):
    """Neighbour features `(B, C, N, k)` of `x (B, C, N)` at `idx (B, N, k)`."""
    b, c, n = x.shape
    k = idx.size(-1)
    base = torch.arange(b, device=x.device).view(b, 1, 1) * n
    flat = (idx + base).reshape(-1)
    rows = x.transpose(1, 2).reshape(b * n, c)[flat]  # (B*N*k, C)
    return rows.view(b, n, k, c).permute(0, 3, 1, 2)


def scaled(x):
    """The input channels weighted for neighbourhoods (`KNN_SCALE`)."""
    return x * x.new_tensor(KNN_SCALE).view(1, 5, 1)


class EdgeConv(nn.Module):
    def __init__(self, cin, cout, k):
        super().__init__()
        self.k = k
        self.conv = nn.Sequential(nn.Conv2d(2 * cin, cout, 1, bias=False),
                                  nn.BatchNorm2d(cout), nn.LeakyReLU(0.01))

    def forward(self, x, idx):
        nb = gather(x, idx)  # (B, C, N, k)
        centre = x.unsqueeze(-1).expand_as(nb)
        e = self.conv(torch.cat((nb - centre, centre), dim=1))
        return e.max(dim=-1)[0]


class DGCNN(nn.Module):
    """DGCNN: `widths = (e1, e2, e3, e4, emb, fc, head_dim)`, k neighbours."""

    def __init__(self, widths=(64, 64, 128, 256, 1024, 1024, 128), k=20, dropout=0.1,
                 **sensor):
        super().__init__()
        a, b, c, d, e, fc, head = widths
        self.k = k
        self.edges = nn.ModuleList([EdgeConv(5, a, k), EdgeConv(a, b, k), EdgeConv(b, c, k),
                                    EdgeConv(c, d, k)])
        self.embed = dense(True, a + b + c + d, e)
        self.head = SimDRHead(2 * e, fc, head, dropout=dropout, **sensor)

    def forward(self, x):
        outs = []
        h = x
        idx = knn(scaled(x), self.k)
        for i, edge in enumerate(self.edges):
            if i > 0:
                idx = knn(h, self.k)
            h = edge(h, idx)
            outs.append(h)
        return self.head(pool(self.embed(torch.cat(outs, dim=1))))


class VectorAttention(nn.Module):
    """One Point Transformer layer over the k nearest neighbours (indices given)."""

    def __init__(self, dim):
        super().__init__()
        self.q = nn.Conv1d(dim, dim, 1)
        self.kv = nn.Conv1d(dim, 2 * dim, 1)
        self.theta = nn.Sequential(nn.Conv2d(5, dim, 1), nn.BatchNorm2d(dim), nn.ReLU(),
                                   nn.Conv2d(dim, dim, 1))
        self.gamma = nn.Sequential(nn.Conv2d(dim, dim, 1), nn.BatchNorm2d(dim), nn.ReLU(),
                                   nn.Conv2d(dim, dim, 1))

    def forward(self, h, p, idx):
        q = self.q(h)
        k, v = self.kv(h).chunk(2, dim=1)
        delta = self.theta(p.unsqueeze(-1) - gather(p, idx))  # (B, C, N, k)
        w = self.gamma(q.unsqueeze(-1) - gather(k, idx) + delta).softmax(dim=-1)
        return (w * (gather(v, idx) + delta)).sum(dim=-1)


class TransformerBlock(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.pre = dense(True, dim, dim)
        self.attn = VectorAttention(dim)
        self.bn = nn.BatchNorm1d(dim)
        self.post = nn.Sequential(nn.Conv1d(dim, dim, 1, bias=False), nn.BatchNorm1d(dim))

    def forward(self, h, p, idx):
        y = F.leaky_relu(self.bn(self.attn(self.pre(h), p, idx)), 0.01)
        return F.leaky_relu(h + self.post(y), 0.01)


class PointTransformer(nn.Module):
    """Point Transformer: `widths = (d1, d2, d3, d4, emb, fc, head_dim)`; one vector-attention
    block per stage at full resolution (no down-sampling), stages joined by 1x1 convolutions."""

    def __init__(self, widths=(32, 64, 128, 256, 1024, 1024, 128), k=16, dropout=0.1,
                 **sensor):
        super().__init__()
        a, b, c, d, e, fc, head = widths
        self.k = k
        dims = (a, b, c, d)
        self.stem = dense(True, 5, a)
        self.blocks = nn.ModuleList(TransformerBlock(w) for w in dims)
        self.links = nn.ModuleList([nn.Identity()] + [dense(True, i, o)
                                                      for i, o in zip(dims, dims[1:])])
        self.embed = dense(True, sum(dims), e)
        self.head = SimDRHead(2 * e, fc, head, dropout=dropout, **sensor)

    def forward(self, x):
        p = scaled(x)
        idx = knn(p, self.k)
        h = self.stem(x)
        outs = []
        for link, block in zip(self.links, self.blocks):
            h = block(link(h), p, idx)
            outs.append(h)
        return self.head(pool(self.embed(torch.cat(outs, dim=1))))


BACKBONES = {"pointnet": PointNet, "dgcnn": DGCNN, "point-transformer": PointTransformer}


def build(backbone, widths=None, k=None, dropout=0.1):
    """A backbone by name, with optional widths (7 numbers) and k (k-NN backbones)."""
    cls = BACKBONES[backbone]
    kwargs = {"dropout": dropout}
    if widths is not None:
        kwargs["widths"] = tuple(widths)
    if k is not None and backbone != "pointnet":
        kwargs["k"] = k
    return cls(**kwargs)

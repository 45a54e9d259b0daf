"""Reading the arrays `evpose dataset` writes, SimDR labels, the loss and the metric."""

import json
from pathlib import Path

import numpy as np
import torch

#: SimDR label width (pixels), the paper's.
SIGMA = 8.0

#: DHP19's joint order mirrored left <-> right (head, shoulders, elbows, hips, hands, knees, feet).
MIRROR = [0, 2, 1, 4, 3, 6, 5, 8, 7, 10, 9, 12, 11]


class Dataset:
    """An `evpose dataset` directory in memory: `points (S, N, 5)`, `label2d (S, J, 2)`,
    `mask (S, J)`, `person (S,)` (1 = a person in the scene; all 1 without `person.npy`),
    `camera (S,)` and the manifest."""

    def __init__(self, path, limit=None):
        path = Path(path)
        self.manifest = json.loads((path / "manifest.json").read_text())
        load = lambda name: np.load(path / name, mmap_mode="r")
        n = len(load("camera.npy")) if limit is None else min(limit, len(load("camera.npy")))
        self.points = torch.from_numpy(np.array(load("points.npy")[:n]))
        self.label2d = torch.from_numpy(np.array(load("label2d.npy")[:n]))
        self.mask = torch.from_numpy(np.array(load("mask.npy")[:n])).float()
        self.person = (torch.from_numpy(np.array(load("person.npy")[:n])).float()
                       if (path / "person.npy").exists() else torch.ones(n))
        self.camera = np.asarray(load("camera.npy")[:n])

    def to(self, device):
        """Moves the arrays to `device` (e.g. the GPU, where batching then happens too: the
        random draws stay on the CPU generator, so a seed gives the same batches anywhere)."""
        for name in ("points", "label2d", "mask", "person"):
            setattr(self, name, getattr(self, name).to(device))
        return self

    @staticmethod
    def load(paths, limit=None):
        """The datasets at `paths` as one, or their first `limit` samples in all (in order)."""
        parts, left = [], limit
        for path in paths:
            if left is not None and left <= 0:
                break
            parts.append(Dataset(path, left))
            if left is not None:
                left -= len(parts[-1])
        return Dataset.concat(parts)

    @staticmethod
    def concat(parts):
        """One dataset of several (same point count)."""
        if len(parts) == 1:
            return parts[0]
        out = object.__new__(Dataset)
        out.manifest = parts[0].manifest
        out.points = torch.cat([p.points for p in parts])
        out.label2d = torch.cat([p.label2d for p in parts])
        out.mask = torch.cat([p.mask for p in parts])
        out.person = torch.cat([p.person for p in parts])
        out.camera = np.concatenate([p.camera for p in parts])
        return out

    def __len__(self):
        return len(self.camera)

    def batch(self, idx, points=None, generator=None, shift=0, flip=False,
              size=(346, 260)):
        """Inputs `(B, 5, points)`, labels, masks and person flags of rows `idx`. With fewer `points` than stored, a
        random subset per sample (the stored rows are already a uniform sample of the window,
        so a subset of them is one too). A window with fewer cells than stored rows was
        sampled with replacement (`core::sample`), its repeats adjacent (indices ascending):
        the subset takes distinct rows first, as `evpose` samples a window at inference (`N`
        distinct points whenever the window has `N`).

        Augmentation (training): `shift` moves each sample's points and labels by whole pixels
        drawn from [-shift, shift] per axis (joints that leave the sensor get weight 0);
        `flip` mirrors half the samples left-right (x -> W-1-x) and swaps the left and right
        joints, so that a left-arm movement teaches the right arm too."""
        dev = self.points.device
        idx = idx.to(dev)
        x = self.points[idx]
        lab, mask = self.label2d[idx].clone(), self.mask[idx].clone()
        if points is not None and points < x.size(1):
            # A row equal to the one before it is a repeat: sorted after every distinct row.
            repeat = torch.zeros(x.shape[:2], dtype=torch.bool)
            repeat[:, 1:] = (x[:, 1:] == x[:, :-1]).all(dim=-1).cpu()
            key = torch.rand(x.size(0), x.size(1), generator=generator) + repeat.float()
            order = key.argsort(dim=1)
            pick = order[:, :points].sort(dim=1)[0].to(dev)
            x = torch.gather(x, 1, pick.unsqueeze(-1).expand(-1, -1, 5))
        else:
            x = x.clone()
        b = x.size(0)
        if flip:
            m = (torch.rand(b, generator=generator) < 0.5).to(dev)
            x[m, :, 0] = (size[0] - 1) - x[m, :, 0]
            lab[m, :, 0] = (size[0] - 1) - lab[m, :, 0]
            lab[m] = lab[m][:, MIRROR]
            mask[m] = mask[m][:, MIRROR]
        if shift:
            d = torch.randint(-shift, shift + 1, (b, 1, 2), generator=generator).float().to(dev)
            x[:, :, :2] += d
            lab += d
            inside = ((lab[..., 0] >= 0) & (lab[..., 0] < size[0]) & (lab[..., 1] >= 0)
                      & (lab[..., 1] < size[1]))
            mask = mask * inside.float()
        return x.transpose(1, 2).contiguous(), lab, mask, self.person[idx].clone()


def simdr_target(coord, size, sigma=SIGMA):
    """Gaussian labels `(..., size)` centred on integer pixel `coord` `(...)`, min-max
    normalized to [0, 1] per vector (the paper's SimDR labels)."""
    grid = torch.arange(size, dtype=torch.float32, device=coord.device)
    g = torch.exp(-((grid - coord.unsqueeze(-1)) ** 2) / (2 * sigma**2))
    lo = g.min(dim=-1, keepdim=True)[0]
    hi = g.max(dim=-1, keepdim=True)[0]
    return (g - lo) / (hi - lo).clamp_min(1e-12)


def uniform_target(size, sigma=SIGMA):
    """The label of a scene without a person: a constant vector `(size,)` with the mass of a
    Gaussian label (about sigma * sqrt(2 pi)), so that its loss weighs like a joint's."""
    mass = simdr_target(torch.tensor([size // 2], dtype=torch.float32), size, sigma).sum()
    return torch.full((size,), float(mass) / size)


def simdr_loss(logits_x, logits_y, label2d, mask, person=None):
    """KL divergence between the softmax of each SimDR vector and its label, averaged over the
    bins, weighted by visibility and averaged over joints and samples.

    Rows whose `person` is 0 (person-free windows, `evpose dataset --person-free`) have no
    label: every joint of them is pulled towards the uniform distribution
    ([`uniform_target`]) with weight 1, which teaches the network to spread its mass, and so
    to lower its confidence, when it sees no body."""
    total = 0.0
    for logits, axis in ((logits_x, 0), (logits_y, 1)):
        t = simdr_target(label2d[..., axis], logits.size(-1))
        w = mask
        if person is not None:
            absent = person < 0.5
            t = torch.where(absent[:, None, None],
                            uniform_target(logits.size(-1)).to(t.device), t)
            w = torch.where(absent[:, None], torch.ones_like(mask), mask)
        logp = torch.log_softmax(logits, dim=-1)
        kl = (torch.xlogy(t, t) - t * logp).mean(dim=-1)
        total = total + (kl * w).mean()
    return total


def decode(logits_x, logits_y):
    """Argmax decoding `(B, J, 2)` (first index wins ties, like `evpose`)."""
    return torch.stack((logits_x.argmax(dim=-1), logits_y.argmax(dim=-1)), dim=-1).float()


def mpjpe2d(pred, label2d, mask):
    """Sum of visible joints' pixel errors and their count."""
    err = ((pred - label2d) ** 2).sum(dim=-1).sqrt()
    return float((err * mask).sum()), float(mask.sum())

#!/usr/bin/env python3
"""Writes the triangulation fixtures that `tests/geometry.rs` compares the core against.

An independent implementation of DHP19's reference evaluation in numpy: per camera, back-project
(u, H - v, 1) with numpy.linalg.pinv(P), dehomogenize, and take the ray from the camera centre
through that point; the 3-D joint is the least-squares intersection of the two rays (the normal
equations sum_i (I - n_i n_i^T) p = sum_i (I - n_i n_i^T) c_i, solved with numpy.linalg.lstsq).

Outputs, float64:
- tests/fixtures/dhp19-triangulation.npy, (N, 7): [u_a, v_a, u_b, v_b, X, Y, Z] for the front
  cameras a = channel 2, b = channel 3: 2-D joints of random points within +-1000 mm of the
  origin that both cameras see, moved by Gaussian noise (sigma 2 px; every other row then rounded
  to whole pixels, as `evpose pose` reports them), and numpy's triangulation of them (mm);
- tests/fixtures/dhp19-pinv.npy, (4, 4, 3): numpy.linalg.pinv of each channel's P.

Usage: python3 scripts/make-triangulation-fixture.py  (numpy >= 1.17; seeded, reproducible)
"""

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
ASSETS = ROOT / "assets" / "dhp19"
FIXTURES = ROOT / "tests" / "fixtures"
W, H = 346, 260
# aedat channel -> (projection matrix file, row of camera_positions.npy)
CALIBRATION = [("P4.npy", 3), ("P1.npy", 0), ("P3.npy", 2), ("P2.npy", 1)]
CAM_A, CAM_B = 2, 3
ROWS = 64
NOISE_PX = 2.0
SEED = 19


def camera(channel):
    name, row = CALIBRATION[channel]
    return np.load(ASSETS / name), np.load(ASSETS / "camera_positions.npy")[row]


def project(p, x):
    u, v, w = p @ np.append(x, 1.0)
    return np.array([u / w, H - v / w])


def back_project(p, uv):
    x = np.linalg.pinv(p) @ np.array([uv[0], H - uv[1], 1.0])
    return x[:3] / x[3]


def intersect(origins, through):
    n = through - origins
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    projectors = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
    r = projectors.sum(axis=0)
    q = (projectors @ origins[:, :, None]).sum(axis=0)
    return np.linalg.lstsq(r, q, rcond=None)[0][:, 0]


def visible(uv):
    return 0 < uv[0] <= W and 0 < uv[1] <= H


def main():
    (pa, ca), (pb, cb) = camera(CAM_A), camera(CAM_B)
    rng = np.random.default_rng(SEED)
    rows = []
    while len(rows) < ROWS:
        x = rng.uniform(-1000.0, 1000.0, 3)
        ja, jb = project(pa, x), project(pb, x)
        if not (visible(ja) and visible(jb)):
            continue
        ja = ja + rng.normal(0.0, NOISE_PX, 2)
        jb = jb + rng.normal(0.0, NOISE_PX, 2)
        if len(rows) % 2:
            ja, jb = np.round(ja), np.round(jb)
        origins = np.stack([ca, cb])
        through = np.stack([back_project(pa, ja), back_project(pb, jb)])
        rows.append(np.concatenate([ja, jb, intersect(origins, through)]))
    FIXTURES.mkdir(parents=True, exist_ok=True)
    np.save(FIXTURES / "dhp19-triangulation.npy", np.array(rows, dtype=np.float64))
    pinv = np.stack([np.linalg.pinv(camera(c)[0]) for c in range(4)])
    np.save(FIXTURES / "dhp19-pinv.npy", pinv.astype(np.float64))
    print(f"wrote {ROWS} rows and 4 pseudo-inverses to {FIXTURES}")


if __name__ == "__main__":
    main()

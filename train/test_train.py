"""`train/`'s own tests (pytest; needs torch, onnxruntime): each backbone trains for a few steps
on a tiny dataset in `evpose dataset`'s layout and its ONNX export matches PyTorch."""

import json

import numpy as np
import onnxruntime as ort
import pytest
import torch

import data
import models
import train

TINY = {
    "pointnet": ["--widths", "8", "8", "16", "16", "32", "32", "8"],
    "dgcnn": ["--widths", "8", "8", "16", "16", "32", "32", "8", "--k", "4"],
    "point-transformer": ["--widths", "8", "8", "16", "16", "32", "32", "8", "--k", "4"],
}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """24 samples of 64 points in the layout `evpose dataset` writes (random clouds, labels; one
    person-free)."""
    d = tmp_path_factory.mktemp("ds")
    rng = np.random.default_rng(7)
    s, n, j = 24, 64, models.JOINTS
    pts = np.stack([rng.integers(0, 346, (s, n)), rng.integers(0, 260, (s, n)),
                    rng.random((s, n)), rng.integers(-2, 3, (s, n)),
                    rng.integers(1, 4, (s, n))], axis=-1).astype(np.float32)
    np.save(d / "points.npy", pts)
    lab = np.stack([rng.integers(0, 346, (s, j)), rng.integers(0, 260, (s, j))], -1)
    np.save(d / "label2d.npy", lab.astype(np.float32))
    mask = np.ones((s, j), np.uint8)
    mask[0, 3] = 0
    np.save(d / "mask.npy", mask)
    np.save(d / "camera.npy", np.full(s, 2, np.uint8))
    person = np.ones(s, np.uint8)
    person[5] = 0  # a person-free window: trained towards uniform SimDR vectors
    np.save(d / "person.npy", person)
    (d / "manifest.json").write_text(json.dumps({"points": n, "samples": s}))
    return d


def test_simdr_target_is_the_papers_label():
    t = data.simdr_target(torch.tensor([100.0]), 346)[0]
    assert int(t.argmax()) == 100 and float(t.max()) == 1.0 and float(t.min()) == 0.0
    assert abs(float(t[108]) - np.exp(-0.5)) < 1e-6  # one sigma away


def test_loss_ignores_masked_joints():
    lx, ly = torch.randn(1, 13, 346), torch.randn(1, 13, 260)
    lab = torch.full((1, 13, 2), 50.0)
    mask = torch.ones(1, 13)
    base = data.simdr_loss(lx, ly, lab, mask)
    lab2 = lab.clone()
    lab2[0, 5] = 200.0
    mask[0, 5] = 0
    assert torch.isclose(data.simdr_loss(lx, ly, lab2, mask),
                         data.simdr_loss(lx, ly, lab, mask))
    assert not torch.isclose(base, data.simdr_loss(lx, ly, lab2, torch.ones(1, 13)))


def test_person_free_rows_are_pulled_to_uniform():
    """A person-free row's loss ignores its (zero) label and mask and is smallest at uniform
    logits; rows with a person are unaffected by the flag."""
    lab = torch.full((2, 13, 2), 50.0)
    mask = torch.zeros(2, 13)
    mask[0] = 1
    person = torch.tensor([1.0, 0.0])
    peaked_x, peaked_y = torch.randn(2, 13, 346), torch.randn(2, 13, 260)
    flat_x, flat_y = peaked_x.clone(), peaked_y.clone()
    flat_x[1], flat_y[1] = 0.0, 0.0
    # Row 0 (a person) alone decides the loss without the flag: row 1 is all masked.
    assert torch.isclose(data.simdr_loss(peaked_x, peaked_y, lab, mask),
                         data.simdr_loss(flat_x, flat_y, lab, mask))
    # With the flag, row 1 counts, and uniform logits beat random ones there.
    assert (data.simdr_loss(flat_x, flat_y, lab, mask, person)
            < data.simdr_loss(peaked_x, peaked_y, lab, mask, person))
    # The target's mass is a Gaussian label's, so a missing person weighs like a joint.
    u = data.uniform_target(346)
    g = data.simdr_target(torch.tensor([173.0]), 346)[0]
    assert torch.isclose(u.sum(), g.sum()) and bool((u == u[0]).all())


@pytest.mark.parametrize("backbone", sorted(TINY))
def test_backbone_trains_and_exports(backbone, tiny, tmp_path):
    out = tmp_path / f"{backbone}.onnx"
    args = train.parse(["--data", str(tiny), "--val", str(tiny), "--backbone", backbone,
                        "--points", "32", "--epochs", "3", "--batch", "8", "--lr", "3e-3",
                        "--lr-steps", "--out", str(out), "--quiet",
                        "--log", str(tmp_path / "log.json")] + TINY[backbone])
    model, log = train.train(args)
    assert len(log) == 3 and all(np.isfinite(e["loss"]) for e in log)
    assert log[-1]["loss"] < log[0]["loss"], log  # it learns something on 24 samples
    # The export matches PyTorch (float32 graph, different kernels: 1e-4 relative).
    x = data.Dataset(tiny).batch(torch.arange(1), 32)[0]
    with torch.no_grad():
        tx, ty = model.eval()(x)
    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    ox, oy = sess.run(["simdr_x", "simdr_y"], {"points": x.numpy()})
    assert ox.shape == (1, 13, 346) and oy.shape == (1, 13, 260)
    np.testing.assert_allclose(ox, tx.numpy(), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(oy, ty.numpy(), rtol=1e-4, atol=1e-4)
    assert out.with_suffix(".pt").exists()


def test_augmentation_moves_points_and_labels_together(tmp_path):
    """Each joint's label sits on a point of its own; after shifts and flips it still does,
    and a flip puts the right shoulder where the mirrored left one was."""
    s, j = 8, models.JOINTS
    rng = np.random.default_rng(3)
    lab = np.stack([rng.integers(30, 316, (s, j)), rng.integers(30, 230, (s, j))], -1)
    pts = np.zeros((s, j, 5), np.float32)
    pts[..., :2] = lab
    pts[..., 2] = np.arange(j) / j  # t_avg tags the joint each point was made for
    np.save(tmp_path / "points.npy", pts)
    np.save(tmp_path / "label2d.npy", lab.astype(np.float32))
    np.save(tmp_path / "mask.npy", np.ones((s, j), np.uint8))
    np.save(tmp_path / "camera.npy", np.full(s, 2, np.uint8))
    (tmp_path / "manifest.json").write_text(json.dumps({"points": j, "samples": s}))
    ds = data.Dataset(tmp_path)
    gen = torch.Generator().manual_seed(0)
    flipped = 0
    for _ in range(4):
        x, l2, mask, _ = ds.batch(torch.arange(s), None, gen, shift=20, flip=True)
        for b in range(s):
            for k in range(j):
                if mask[b, k] == 0:
                    continue
                # the point carrying this label's position
                hit = ((x[b, 0] == l2[b, k, 0]) & (x[b, 1] == l2[b, k, 1])).nonzero()
                assert len(hit) >= 1, (b, k)
                tag = int(round(float(x[b, 2, hit[0, 0]]) * j))
                assert tag in (k, data.MIRROR[k])
                flipped += tag != k
    assert flipped > 0  # some samples were mirrored


def test_fit_epochs_fills_the_budget_and_no_more():
    # 100 steps of 0.1 s: 10 s an epoch; 95 s hold 9 epochs, never more than asked, never 0.
    assert train.fit_epochs(0.1, 100, 95.0, 30) == 9
    assert train.fit_epochs(0.1, 100, 1000.0, 30) == 30
    assert train.fit_epochs(0.1, 100, 5.0, 30) == 1
    assert train.default_milestones(30) == [15, 20]


def test_fit_minutes_plans_the_epochs_it_trains(tiny, tmp_path):
    """`--fit-minutes` times the first epoch's steps, plans the epochs that fit (1.8 s cannot
    hold 100 epochs of 132 steps in eager PyTorch), trains exactly those, logs the plan after
    every epoch, and moves the rate steps to 1/2 and 2/3 of them."""
    log_path = tmp_path / "fit.json"
    args = train.parse(["--data"] + [str(tiny)] * 11 + [
        "--points", "16", "--epochs", "100", "--batch", "2", "--fit-minutes", "0.03",
        "--out", str(tmp_path / "fit.onnx"), "--quiet", "--log", str(log_path)]
        + TINY["pointnet"])
    _, log = train.train(args)
    planned = json.loads(log_path.read_text())["epochs_planned"]
    assert 1 <= planned < 100
    assert len(log) == planned
    first, second = train.default_milestones(planned)
    for e in log:
        # The rate logged after epoch e is the next epoch's; a milestone of 0 never fires.
        drops = sum(1 for m in (first, second) if 0 < m <= e["epoch"])
        assert e["lr"] == pytest.approx(1e-4 * 0.1 ** drops), (planned, log)


def test_limit_counts_the_samples_of_every_dataset_together(tiny):
    """`--limit N` keeps the first N samples of the --data sets together, not N of each."""
    assert len(data.Dataset.load([tiny, tiny])) == 48
    both = data.Dataset.load([tiny, tiny], 30)
    assert len(both) == 30
    one = data.Dataset(tiny)
    assert torch.equal(both.points[:24], one.points)
    assert torch.equal(both.points[24:], one.points[:6])
    assert len(data.Dataset.load([tiny, tiny], 10)) == 10


def test_a_subset_takes_distinct_points_before_repeats(tmp_path):
    """A window with fewer cells than stored rows was sampled with replacement (repeats
    adjacent): fewer training points take distinct rows, as inference would."""
    distinct = np.arange(40, dtype=np.float32)[:, None] * np.ones(5, np.float32)
    reps = np.array([3, 1, 1, 2] * 10)  # 40 cells in 70 rows, every fourth repeated
    rows = np.repeat(distinct, reps, axis=0)
    np.save(tmp_path / "points.npy", np.stack([rows[:64], rows[:64]]))
    np.save(tmp_path / "label2d.npy", np.zeros((2, models.JOINTS, 2), np.float32))
    np.save(tmp_path / "mask.npy", np.ones((2, models.JOINTS), np.uint8))
    np.save(tmp_path / "camera.npy", np.full(2, 2, np.uint8))
    (tmp_path / "manifest.json").write_text(json.dumps({"points": 64, "samples": 2}))
    ds = data.Dataset(tmp_path)
    cells = len(np.unique(rows[:64, 0]))
    gen = torch.Generator().manual_seed(0)
    for _ in range(20):
        for n in (8, cells):
            x, *_ = ds.batch(torch.arange(2), n, gen)
            for b in range(2):
                assert len(torch.unique(x[b, 0])) == n
        # More points than cells: every cell, then repeats.
        x, *_ = ds.batch(torch.arange(2), cells + 5, gen)
        assert all(len(torch.unique(x[b, 0])) == cells for b in range(2))

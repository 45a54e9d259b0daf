#!/usr/bin/env python3
"""Trains a backbone on an `evpose dataset` and exports it to ONNX for `evpose`.

    python train/train.py --data ds-train --val ds-val --backbone pointnet \
        --widths 64 64 128 256 1024 1024 128 --points 2048 --epochs 30 --out paper.onnx

The paper's setup is the default: SimDR labels (sigma 8), KL divergence weighted by visibility,
Adam at 1e-4 with x0.1 steps at epochs 15 and 20 (of 30), batch 16, dropout 0.1. Seeded (torch
and the sampler); logs the loss and the validation MPJPE2D per epoch (stdout and `--log`), with a
progress bar per epoch. `--minutes` stops cleanly after a wall-clock budget (the last finished
epoch is exported); `--fit-minutes` instead chooses, from the speed of the first epoch's steps,
how many epochs fit a budget, and scales the rate schedule to them (the log's `epochs_planned`;
`--epochs` with that number repeats the run). On CUDA the datasets live on the GPU and matrix
products use TF32. The export uses PyTorch's TorchScript exporter (`dynamo=False`) with a fixed
point count (`--export-points`, default `--points`): the form `evpose` imports (PointNet) and
tract runs (every backbone). A checkpoint (`.pt`, state dict + arguments) sits beside the ONNX.
"""

import argparse
import json
import math
import time
from collections import Counter
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

import data
import models


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", required=True, nargs="+", help="training datasets (evpose dataset)")
    p.add_argument("--val", help="validation dataset (MPJPE2D per epoch)")
    p.add_argument("--backbone", default="pointnet", choices=sorted(models.BACKBONES))
    p.add_argument("--widths", type=int, nargs=7, metavar="W",
                   help="c1 c2 c3 c4 c5 fc head_dim (default: the backbone's paper widths)")
    p.add_argument("--k", type=int, help="neighbours of the k-NN backbones")
    p.add_argument("--points", type=int, default=2048, help="points per training input")
    p.add_argument("--export-points", type=int, help="fixed N of the export (default --points)")
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--batch", type=int, default=16)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--lr-steps", type=int, nargs="*", default=None,
                   help="epochs at which the rate drops x0.1 (default: 1/2 and 2/3 of --epochs)")
    p.add_argument("--dropout", type=float, default=0.1)
    p.add_argument("--shift", type=int, default=0,
                   help="augmentation: random shift of points and labels by up to PX pixels")
    p.add_argument("--flip", action="store_true",
                   help="augmentation: mirror half the samples left-right, joints swapped")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--limit", type=int,
                   help="use only the first LIMIT training samples (of all --data sets, in order)")
    p.add_argument("--steps", type=int, help="stop after this many optimizer steps in all")
    p.add_argument("--minutes", type=float, help="stop after the epoch that passes this budget")
    p.add_argument("--fit-minutes", type=float,
                   help="train as many epochs (at most --epochs) as fit this wall-clock budget, "
                        "judged by the speed of the first epoch's steps; the rate steps at 1/2 "
                        "and 2/3 of them unless --lr-steps says otherwise")
    p.add_argument("--threads", type=int, help="torch CPU threads")
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--init", help="start from this checkpoint (.pt)")
    p.add_argument("--log", help="write the per-epoch log here (JSON)")
    p.add_argument("--out", required=True, help="ONNX file to write")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p.parse_args(argv)


#: Steps of the first epoch timed by `--fit-minutes` (after `FIT_WARMUP` untimed ones).
FIT_STEPS, FIT_WARMUP = 100, 20


def fit_epochs(step_seconds, steps_per_epoch, budget_seconds, max_epochs):
    """Whole epochs of `steps_per_epoch` steps at `step_seconds` each that fit in
    `budget_seconds` (at least 1, at most `max_epochs`)."""
    per_epoch = max(step_seconds * steps_per_epoch, 1e-9)
    return max(1, min(max_epochs, int(budget_seconds // per_epoch)))


def default_milestones(epochs):
    """The paper's schedule: the rate drops x0.1 after epochs `epochs // 2` and
    `epochs * 2 // 3` (15 and 20 of 30; 4 and 6 of 9; for 2 epochs both after the first,
    x0.01; for 1 never)."""
    return [epochs // 2, epochs * 2 // 3]


def evaluate(model, ds, points, device, batch=64):
    """MPJPE2D (px) of `model` on `ds` (inputs cut to `points` with a fixed seed)."""
    model.eval()
    gen = torch.Generator().manual_seed(0)
    total, count = 0.0, 0.0
    with torch.no_grad():
        for s in range(0, len(ds), batch):
            idx = torch.arange(s, min(s + batch, len(ds)))
            x, lab, mask, _ = ds.batch(idx, points, gen)
            lx, ly = model(x.to(device))
            e, n = data.mpjpe2d(data.decode(lx, ly).cpu(), lab.cpu(), mask.cpu())
            total, count = total + e, count + n
    return total / max(count, 1.0)


def export(model, path, points):
    """ONNX export in `evpose`'s form: input `points (1, 5, N)`, outputs `simdr_x`, `simdr_y`."""
    model = model.cpu().eval()
    torch.onnx.export(model, torch.zeros(1, 5, points), str(path), opset_version=13,
                      input_names=["points"], output_names=["simdr_x", "simdr_y"],
                      do_constant_folding=True, dynamo=False)


def train(args):
    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    ds = data.Dataset.load(args.data, args.limit)
    val = data.Dataset(args.val) if args.val else None
    if device.type == "cuda":
        # The arrays live on the GPU (a few GB at most) and batches are cut there; TF32
        # matrix products, as PyTorch's default for convolutions already is.
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        ds.to(device)
        if val is not None:
            val.to(device)
    model = models.build(args.backbone, args.widths, args.k, args.dropout).to(device)
    if args.init:
        model.load_state_dict(torch.load(args.init, map_location=device)["state"])
    params = sum(p.numel() for p in model.parameters())
    absent = int((ds.person < 0.5).sum())
    print(f"{args.backbone}: {params / 1e6:.3f} M parameters; {len(ds)} training samples "
          f"({absent} person-free), {args.points} points, device {device}", flush=True)
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    steps = args.lr_steps if args.lr_steps is not None else default_milestones(args.epochs)
    sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=steps, gamma=0.1)
    gen = torch.Generator().manual_seed(args.seed)
    log, done, start = [], 0, time.time()
    per_epoch = math.ceil(len(ds) / args.batch)
    epochs, timed_from, fitted = args.epochs, None, False
    if args.fit_minutes and per_epoch <= FIT_WARMUP + FIT_STEPS:
        raise SystemExit(f"--fit-minutes needs epochs of at least {FIT_WARMUP + FIT_STEPS} "
                         f"steps (this one has {per_epoch})")
    epoch = 0
    while epoch < epochs:
        model.train()
        order = torch.randperm(len(ds), generator=gen)
        bar = tqdm(range(per_epoch), desc=f"epoch {epoch + 1}/{epochs}",
                   disable=args.quiet, leave=False)
        # Summed on the device (in f64, as the Python float it replaced): reading it every step
        # would wait for the GPU each time.
        loss_sum, seen = torch.zeros((), dtype=torch.float64, device=device), 0
        for b in bar:
            idx = order[b * args.batch:(b + 1) * args.batch]
            if len(idx) < 2:  # BatchNorm needs two samples
                continue
            x, lab, mask, person = ds.batch(idx, args.points, gen, args.shift, args.flip)
            lx, ly = model(x.to(device))
            loss = data.simdr_loss(lx, ly, lab.to(device), mask.to(device), person.to(device))
            opt.zero_grad()
            loss.backward()
            opt.step()
            loss_sum, seen, done = loss_sum + loss.detach().double(), seen + 1, done + 1
            if not args.quiet and seen % 20 == 0:
                bar.set_postfix(loss=f"{float(loss_sum) / seen:.5f}")
            if args.fit_minutes and epoch == 0 and b in (FIT_WARMUP, FIT_WARMUP + FIT_STEPS):
                if device.type == "cuda":
                    torch.cuda.synchronize()
                if b == FIT_WARMUP:
                    timed_from = time.time()
                else:
                    step_s = (time.time() - timed_from) / FIT_STEPS
                    left = args.fit_minutes * 60 - (time.time() - start)
                    # 5 % for validation and checkpoints between epochs.
                    epochs = fit_epochs(step_s, per_epoch, 0.95 * (left + step_s * b),
                                        args.epochs)
                    fitted = True
                    if args.lr_steps is None:
                        sched.milestones = Counter(default_milestones(epochs))
                    print(f"fit: {step_s * 1e3:.2f} ms per step, {epochs} epochs of {per_epoch} "
                          f"steps in {args.fit_minutes} min", flush=True)
            if args.steps and done >= args.steps:
                break
        sched.step()
        entry = {"epoch": epoch + 1, "loss": float(loss_sum) / max(seen, 1), "steps": done,
                 "seconds": round(time.time() - start, 1), "lr": opt.param_groups[0]["lr"]}
        if val is not None:
            entry["val_mpjpe2d_px"] = evaluate(model, val, args.points, device)
        log.append(entry)
        print(json.dumps(entry), flush=True)
        out = Path(args.out)
        torch.save({"state": model.state_dict(), "args": vars(args)}, out.with_suffix(".pt"))
        if args.fit_minutes and epoch == 0 and not fitted:
            print(f"--fit-minutes: the first epoch ended before its {FIT_STEPS} timed steps; "
                  f"training for --epochs {args.epochs}", flush=True)
        if args.log:  # after every epoch: a run stopped from outside keeps its log
            write_log(args, epochs, log)
        epoch += 1
        if args.steps and done >= args.steps:
            break
        if args.minutes and time.time() - start > args.minutes * 60:
            print(f"time budget of {args.minutes} min reached after epoch {epoch}")
            break
    export(model, args.out, args.export_points or args.points)
    if args.log:
        write_log(args, epochs, log)
    return model, log


def write_log(args, epochs, log):
    """The run's arguments, the epochs it planned (`--fit-minutes`' choice) and its log."""
    Path(args.log).write_text(json.dumps({"args": vars(args), "epochs_planned": epochs,
                                          "epochs": log}, indent=1))


if __name__ == "__main__":
    train(parse())

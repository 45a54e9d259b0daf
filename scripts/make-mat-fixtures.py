#!/usr/bin/env python3
"""Writes the MAT-file fixtures of DHP19's Vicon ground truth that `host/tests/mat_scipy.rs`
reads (an independent writer: SciPy's `scipy.io.savemat`) and that seed the `read_mat` fuzz
target (fuzz/seeds/read_mat, the same files).

Each holds a struct `XYZPOS` with DHP19's 13 joint fields of shape (T, 3), value
`100 j + 10 r + a + 0.5` for joint j (DHP19 order), row r, axis a:
- xyzpos-v6.mat: T = 4, doubles, uncompressed (MATLAB `save -v6`);
- xyzpos-v7.mat: the same, zlib-compressed elements (`save -v7`, MATLAB's default);
- xyzpos-single-extra.mat: T = 3, single precision, integral values `100 j + 10 r + a`, a NaN
  at head row 1 axis 1, and variables of other classes beside it (a char array, a cell array,
  an int16 matrix) that the reader skips.

usage: python3 scripts/make-mat-fixtures.py   (needs scipy; rewrites both folders)
"""
import pathlib
import shutil

import numpy as np
import scipy.io as sio

JOINTS = "head shoulderR shoulderL elbowR elbowL hipR hipL handR handL kneeR kneeL footR footL".split()
root = pathlib.Path(__file__).resolve().parent.parent
out = root / "tests/fixtures/mat"
seeds = root / "fuzz/seeds/read_mat"
out.mkdir(parents=True, exist_ok=True)


def xyzpos(t, offset, dtype):
    r, a = np.meshgrid(np.arange(t), np.arange(3), indexing="ij")
    return {n: (100 * j + 10 * r + a + offset).astype(dtype) for j, n in enumerate(JOINTS)}


sio.savemat(out / "xyzpos-v6.mat", {"XYZPOS": xyzpos(4, 0.5, np.float64)}, do_compression=False)
sio.savemat(out / "xyzpos-v7.mat", {"XYZPOS": xyzpos(4, 0.5, np.float64)}, do_compression=True)
extra = xyzpos(3, 0.0, np.float32)
extra["head"][1, 1] = np.nan
cells = np.empty((1, 2), dtype=object)
cells[0, 0], cells[0, 1] = 1.0, "a"
sio.savemat(out / "xyzpos-single-extra.mat",
            {"note": "vicon", "XYZPOS": extra, "cells": cells, "k": np.int16([[3, -4]])},
            do_compression=False)
seeds.mkdir(parents=True, exist_ok=True)
for f in sorted(out.glob("*.mat")):
    shutil.copy(f, seeds / f.name)
    print(f.relative_to(root), f.stat().st_size, "bytes")

#!/usr/bin/env bash
# Inference latency, one thread, all engines in one run on this machine:
# tract f32, core f32, core int8 (evpose bench infer) and onnxruntime f32 / int8 (the peer),
# each as the median and the fastest of ITERATIONS runs (on a shared VM, the fastest run is the
# one least disturbed by other work; the medians move with it).
# EVPOSE_KERNELS=reference|avx2|avxvnni|avx512bw|avx512vnni|amx picks the core's kernel family.
# usage: scripts/bench-infer.sh [MODEL.onnx] [ITERATIONS]
set -euo pipefail
cd "$(dirname "$0")/.."
model=${1:-../shared/reference/pointnet-paper.onnx}
iters=${2:-20}
# The peer's version is part of every figure: pinned (the README's and the benchmark log's
# current figures are onnxruntime 1.32's).
# onnxruntime's quantizer imports ml_dtypes, which neither package installs.
python3 -c "import onnxruntime, onnx, ml_dtypes" 2>/dev/null ||
  python3 -m pip install -q "onnxruntime==1.32.0" "onnx==1.18.0" "ml_dtypes==0.7.0" "numpy<3"
python3 -c "import onnxruntime as o; v = o.__version__; print(f'onnxruntime {v}') if v.startswith('1.32') \
  else print(f'warning: onnxruntime {v}, not the 1.32 of the recorded figures')" >&2
cargo build --release -q -p evpose-host
evpose="${CARGO_TARGET_DIR:-target}/release/evpose"
points=$(mktemp --suffix=.npy)
# The same 2048-point input for every engine: the street-00 window sampled by our pipeline.
"$evpose" raster --events tests/fixtures/street-00.events.npy --width 346 --height 260 --out "$points.all.npy" 2>/dev/null
python3 - "$points.all.npy" "$points" <<'PY'
import sys, numpy as np
p = np.load(sys.argv[1]); rng = np.random.default_rng(0)
idx = np.sort(rng.choice(len(p), 2048, replace=len(p) < 2048))
np.save(sys.argv[2], p[idx].astype(np.float32))
PY
"$evpose" bench infer --model "$model" --points "$points" --iterations "$iters" --json > "$points.evpose.json"
python3 scripts/bench_ort.py "$model" "$points" "$iters" > "$points.ort.json"
python3 - "$points.evpose.json" "$points.ort.json" <<'PY'
import json, sys
e, o = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
t, f, i = e["fastest_ms"]
rows = [("tract f32", e["tract_f32_ms"], t), ("core f32", e["core_f32_ms"], f),
        (f"core int8 ({e['kernels']})", e["core_i8_ms"], i),
        *([("core int8, row-major weights", *e["core_i8_row_major_ms"])] if e.get("core_i8_row_major_ms") else []),
        ("onnxruntime f32", o["ort_f32_ms"], o["ort_f32_fastest_ms"]),
        ("onnxruntime int8 QDQ", o["ort_int8_qdq_ms"], o["ort_int8_qdq_fastest_ms"]),
        ("onnxruntime int8 QOperator", o["ort_int8_qoperator_ms"], o["ort_int8_qoperator_fastest_ms"])]
print(f"{e['cpu']}: {e['points']} points, {e['macs']/1e9:.3f} GMAC, one thread (onnxruntime {o['onnxruntime_version']})")
print(f"  {'engine':<42} {'median ms':>9} {'fastest ms':>10}   core int8 is ... faster (median; fastest)")
for name, ms, fastest in rows:
    print(f"  {name:<42} {ms:9.2f} {fastest:10.2f}   {ms / e['core_i8_ms']:.2f}x; {fastest / i:.2f}x")
if e.get("peak_gmacs"):
    best = e["macs"] / (i * 1e-3) / 1e9
    print(f"core int8: {e['i8_gmacs']:.1f} GMAC/s median, {best:.1f} fastest: {100 * e['fraction_of_peak']:.1f} % "
          f"and {100 * best / e['peak_gmacs']:.1f} % of this CPU's one-thread int8 peak ({e['peak_gmacs']:.1f} GMAC/s)")
PY
rm -f "$points" "$points".*

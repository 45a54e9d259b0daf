#!/usr/bin/env bash
# The paper's three backbones and the MCU PointNet trained side by side on one GPU, in a fixed wall-clock budget:
# the GPU steps of train/recipe.sh (paper, dgcnn, point-transformer) for a machine that is lent
# for minutes, with nothing but a Python that has torch, numpy, onnx and tqdm.
#
# Usage: bash train/gpu-session.sh EVPOSE WORKDIR OUTDIR MINUTES
#   EVPOSE   a release `evpose` binary (its `sim` and `dataset` make the training data here)
#   WORKDIR  scratch space (~4 GB)
#   OUTDIR   receives models.tar.part-* (the ONNX exports, checkpoints and logs, in pieces of
#            15 MiB: `cat models.tar.part-* | tar x` puts them back together)
#   MINUTES  training budget of each backbone (`train.py --fit-minutes`); 0: the smoke run only
#
# First a smoke run (every model, one short epoch on the validation set, exported) so that a
# broken setup fails in seconds instead of after the budget. Then the training data of
# train/recipe.sh's `data` step (same seeds), then the four trainings at once, each with
# `--fit-minutes MINUTES`: the number of epochs that fits is chosen from the speed of the first
# steps and written to its log (`epochs_planned`); train/recipe.sh repeats it with `--epochs`.
#
# Measured on an H200 with 16 Intel Xeon threads (2026-12-04, MINUTES 6, 519 s in all: smoke
# 15 s, data 111 s): the four trainings shared the GPU as plain processes (no CUDA MPS) and
# took 26-41 ms per step of 32 in their timed steps (the Point Transformer 45-48 ms over its
# whole run, which overran its budget by 3 %). Step time did not follow model size (the
# 0.13 M-parameter MCU PointNet 33 ms, the 4.5 M one 26 ms): sharing one GPU, or per-step host
# work (the 256-point models draw their point subsets on the CPU), bounded them, not
# arithmetic. A next run should try CUDA MPS, or one model at a time with the whole budget.
set -euo pipefail
evpose=$(realpath "${1:?usage: gpu-session.sh EVPOSE WORKDIR OUTDIR MINUTES}")
work=${2:?WORKDIR}
mkdir -p "${3:?OUTDIR}"
out=$(realpath "$3")
minutes=${4:?MINUTES}
shopt -s nullglob
repo=$(cd "$(dirname "$0")/.." && pwd)
py=${PYTHON:-python3}
# The simulator's pixel model (README, "evpose sim"): v1 made the shipped models' data;
# PIXEL_MODEL=v2 (the simulator's default) trains on the current one.
pixel="--pixel-model ${PIXEL_MODEL:-v1}"
mkdir -p "$work" "$out"
cd "$work"
t0=$SECONDS
stamp() { echo "[$((SECONDS - t0)) s] $*"; }

stamp "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2), $(nproc) threads"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
"$py" -c 'import torch, onnx; print("torch", torch.__version__, "cuda", torch.version.cuda,
"available", torch.cuda.is_available(), "onnx", onnx.__version__)'

# The validation subject first: the smoke run trains on it.
"$evpose" sim --out rec-val --seed 500 --subjects 1 --seconds 1 --movements all --split test $pixel
"$evpose" dataset --recordings rec-val --out ds-val --split test

trainpy() { "$py" "$repo/train/train.py" --quiet --threads 4 "$@"; }
# Each model's data, backbone and rate (batch 32 below); the MCU PointNet also sees the
# person-free scenes, as in train/recipe.sh (whose MCU run has its own schedule: 12 epochs).
backbone_args() {
  case $1 in
  mcu) echo --data ds-train ds-train2 ds-np --widths 16 16 32 64 128 128 32 --points 256 \
    --lr 1e-3 ;;
  paper) echo --data ds-train ds-train2 --widths 64 64 128 256 1024 1024 128 --points 2048 \
    --lr 5e-4 ;;
  dgcnn) echo --data ds-train ds-train2 --backbone dgcnn --widths 32 32 64 128 512 512 64 \
    --k 16 --points 256 --lr 1e-3 ;;
  point-transformer)
    echo --data ds-train ds-train2 --backbone point-transformer --widths 32 32 64 128 512 512 64 \
      --k 16 --points 256 --lr 1e-3 ;;
  esac
}
models="paper dgcnn point-transformer mcu"

stamp "smoke run"
mkdir -p smoke
pids=()
for m in $models; do
  # shellcheck disable=SC2046
  trainpy $(backbone_args "$m") --data ds-val --val ds-val --flip --shift 16 --epochs 1 \
    --batch 32 --out "smoke/$m.onnx" > "smoke/$m.log" 2>&1 &
  pids+=($!)
done
fail=0
for pid in "${pids[@]}"; do wait "$pid" || fail=1; done
tail -n 3 smoke/*.log
[ $fail = 0 ] || { stamp "smoke run failed"; cp smoke/*.log "$out/" 2>/dev/null; exit 3; }
if awk -v m="$minutes" 'BEGIN { exit !(m == 0) }'; then stamp "smoke run passed"; exit 0; fi

stamp "training data"
"$evpose" sim --out rec-train --seed 1 --subjects 6 --seconds 2 --movements all --split train $pixel
"$evpose" sim --out rec-train2 --seed 2 --subjects 12 --seconds 2 --movements all --split train $pixel
"$evpose" dataset --recordings rec-train --out ds-train --split train
"$evpose" dataset --recordings rec-train2 --out ds-train2 --split train
"$evpose" sim --out np-train --seed 4000 --subjects 24 --seconds 2 --movements no-person \
  --split train $pixel
"$evpose" dataset --recordings np-train --out ds-np --split train --person-free
rm -rf rec-train rec-train2 np-train

stamp "training, $minutes min each"
pids=()
for m in $models; do
  # Killed a little after the budget if an epoch runs long: its last checkpoint (.pt) and log
  # (.json), written after every epoch, stay.
  # shellcheck disable=SC2046
  timeout "$(awk -v m="$minutes" 'BEGIN { print int(m * 60 * 1.1 + 30) }')" \
    "$py" "$repo/train/train.py" --quiet --threads 4 $(backbone_args "$m") --val ds-val \
    --flip --shift 16 --epochs 30 --batch 32 --fit-minutes "$minutes" \
    --out "$m.onnx" --log "$m.json" > "$m.log" 2>&1 &
  pids+=($!)
done
set -- $models
for pid in "${pids[@]}"; do
  wait "$pid" || stamp "the $1 training exited with $?"
  shift
done
for m in $models; do echo "== $m"; { grep -E '^fit|"epoch"' "$m.log" || true; } | tail -n 4; done

stamp "packing"
tar cf - ./*.onnx ./*.pt ./*.json ./*.log | split -b 15M - "$out/models.tar.part-"
ls -l "$out"
stamp "done"

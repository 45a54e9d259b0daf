#!/usr/bin/env bash
# train/'s own tests: installs the pinned requirements into train/.venv (once; ~5 GB with
# PyTorch's CUDA libraries), then runs pytest (each backbone trains a few steps on a tiny
# dataset and its ONNX export is checked against PyTorch with onnxruntime). ~1 minute on 2 cores.
set -euo pipefail
cd "$(dirname "$0")"
if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
  .venv/bin/pip install --quiet -r requirements.txt
fi
exec .venv/bin/python -m pytest -q "$@"

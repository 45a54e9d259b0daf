#!/usr/bin/env bash
# Regenerates every firmware asset (firmware/assets/, and the model in assets/, shared with
# evpose pose):
#
#   pointnet-small.evq   the int8 model: `evpose quantize` of tests/fixtures/pointnet-small.onnx,
#                        calibrated on the windows street-00..02 (2,048 points per 7,500-event
#                        window, sampler seed 0: the tool's defaults)
#   street-00-02.evs     the first 22,500 events (three 7,500-event windows, which are the
#                        bundled street-00..02) of the DAVIS346 street recording, in the EVS1
#                        stream format (firmware/src/input.rs), written by the reference encoder
#                        in tests/firmware_qemu.rs
#
# Usage: scripts/make-firmware-assets.sh [RECORDING]
#        (default ../shared/recordings/davis346-street.aedat4)
# Then `cargo test --release --test firmware_qemu` checks the firmware against the host.
set -euo pipefail
cd "$(dirname "$0")/.."

recording=${1:-../shared/recordings/davis346-street.aedat4}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

evpose() { cargo run --quiet --release -p evpose-host --bin evpose -- "$@"; }

evpose quantize --model tests/fixtures/pointnet-small.onnx \
  --calib tests/fixtures/street-0{0,1,2}.events.npy \
  --out assets/pointnet-small.evq
evpose convert "$recording" --out "$tmp/events.npy"
EVPOSE_EVENTS_NPY="$tmp/events.npy" cargo test --quiet --release -p evpose-tests \
  --test firmware_qemu -- --ignored --exact regenerate_event_asset
ls -l firmware/assets assets/pointnet-small.evq

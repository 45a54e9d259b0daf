#!/usr/bin/env bash
# Regenerates the firmware's event asset (firmware/assets/). The model the firmware embeds is
# models/mcu.evq, shared with `evpose run`, made by train/recipe.sh (steps mcu, quantize):
#
#   street-00-02.evs     the first 22,500 events (three 7,500-event windows, which are the
#                        bundled street-00..02) of the DAVIS346 street recording, in the EVS1
#                        stream format (firmware/src/input.rs), written by the reference encoder
#                        in tests/firmware_qemu.rs
#   street-00.evt3       the first window's 7,500 events as EVT 3.0 words (no header), written
#                        by faery for the boot check of the core's EVT decoder: made by
#                        scripts/third-party-formats.py --firmware-asset (needs faery; see there)
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

evpose convert "$recording" --out "$tmp/events.npy"
EVPOSE_EVENTS_NPY="$tmp/events.npy" cargo test --quiet --release -p evpose-tests \
  --test firmware_qemu -- --ignored --exact regenerate_event_asset
ls -l firmware/assets

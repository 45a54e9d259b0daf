#!/usr/bin/env bash
# Checks evpose-core for the Cortex-M cores users deploy to, without and with its optional
# features (heapless's practice), so that a change that breaks a no_std target fails CI:
#   thumbv6m-none-eabi        Cortex-M0/M0+ (no DSP: `arm-dsp` does not apply)
#   thumbv7em-none-eabihf     Cortex-M4F/M7F (`arm-dsp` is built by the firmware test)
#   thumbv8m.main-none-eabihf Cortex-M33/M55; `arm-dsp` built with -C target-cpu=cortex-m33,
#                             since its inline assembly needs a core with the DSP extension
# `cargo check` (no code generation) keeps it to about a minute on two cores.
set -euo pipefail
cd "$(dirname "$0")/.."
rustup target add thumbv6m-none-eabi thumbv7em-none-eabihf thumbv8m.main-none-eabihf >/dev/null
for target in thumbv6m-none-eabi thumbv7em-none-eabihf thumbv8m.main-none-eabihf; do
  echo "evpose-core for $target: no features, then defmt + geometry + fast-crc"
  cargo check -q -p evpose-core --locked --target "$target" --no-default-features
  cargo check -q -p evpose-core --locked --target "$target" --features defmt,geometry,fast-crc
done
echo "evpose-core for thumbv8m.main-none-eabihf (Cortex-M33 with DSP): arm-dsp, built"
RUSTFLAGS="-C target-cpu=cortex-m33" cargo build -q -p evpose-core --locked \
  --target thumbv8m.main-none-eabihf --features arm-dsp --target-dir target/cortex-m33

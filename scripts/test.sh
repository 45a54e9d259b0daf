#!/usr/bin/env bash
# Installs what the test suite needs on a fresh Debian machine, then runs every check:
# formatting, clippy (warnings are errors) and the whole workspace's tests.
set -euo pipefail
cd "$(dirname "$0")/.."

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

# Rust components and the Cortex-M targets (firmware build, QEMU tests, core builds).
rustup component add rustfmt clippy >/dev/null 2>&1 || true
rustup target add thumbv6m-none-eabi thumbv7em-none-eabihf thumbv8m.main-none-eabihf

# QEMU for the firmware test.
if ! command -v qemu-system-arm >/dev/null 2>&1; then
  as_root apt-get update -qq
  DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq qemu-system-arm >/dev/null
fi

# A clean run writes about 3.5 GB (target/ 2.8 GB, firmware/target 0.69 GB with the M4 and the
# overflow-test builds; measured). Say so up front: a full disk otherwise surfaces as an obscure linker or rustc I/O
# error mid-build.
need_kb=$((3800 * 1024))
free_kb=$(df -Pk . | awk 'NR == 2 { print $4 }')
echo "scripts/test.sh: $((free_kb / 1024)) MiB free on $(df -P . | awk 'NR == 2 { print $6 }')"
if [ "${free_kb:-0}" -lt "$need_kb" ]; then
  echo "warning: a clean build needs about $((need_kb / 1024)) MiB; builds may fail with" \
    "'No space left on device'. Free space, or set CARGO_TARGET_DIR to a larger disk." >&2
fi

cargo fmt --all -- --check
# The firmware is its own workspace, built for thumbv7em-none-eabihf only: format and lint it
# too. Its build and its run under QEMU are the test `firmware_qemu`.
cargo fmt --manifest-path firmware/Cargo.toml -- --check
(cd firmware && cargo clippy --release -- -D warnings &&
  cargo clippy --release --features overflow-test -- -D warnings)
# The core's Cortex-M kernels as the firmware's Cortex-M4 build compiles them (arm-dsp without
# arm-fpv5: the FPv4 requantization), linted.
cargo clippy -p evpose-core --locked --target thumbv7em-none-eabihf --features arm-dsp -- -D warnings
cargo clippy --workspace --all-targets --locked -- -D warnings
# The runtime builds without tract (feature `onnx` off): readers, pose, rasterization, budgets.
cargo clippy -p evpose-host --no-default-features --all-targets --locked -- -D warnings
# The core on every Cortex-M target family, without and with its features (checked).
bash scripts/build-core-targets.sh
cargo test --workspace --locked

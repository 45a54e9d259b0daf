#!/usr/bin/env bash
# Installs what the test suite needs on a fresh Debian machine, then runs every check:
# formatting, clippy (warnings are errors) and the whole workspace's tests.
set -euo pipefail
cd "$(dirname "$0")/.."

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

# Rust components and the Cortex-M7 target (firmware build, QEMU tests).
rustup component add rustfmt clippy >/dev/null 2>&1 || true
rustup target add thumbv7em-none-eabihf

# QEMU for the firmware test.
if ! command -v qemu-system-arm >/dev/null 2>&1; then
  as_root apt-get update -qq
  DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq qemu-system-arm >/dev/null
fi

cargo fmt --all -- --check
# The firmware is its own workspace, built for thumbv7em-none-eabihf only: format and lint it
# too. Its build and its run under QEMU are the test `firmware_qemu`.
cargo fmt --manifest-path firmware/Cargo.toml -- --check
(cd firmware && cargo clippy --release -- -D warnings)
cargo clippy --workspace --all-targets --locked -- -D warnings
cargo test --workspace --locked

#!/usr/bin/env bash
# Runs a firmware image under QEMU (mps2-an500, Cortex-M7) and decodes its defmt output.
#
#   scripts/qemu-firmware.sh ELF          # decoded with defmt-print (cargo install defmt-print)
#   scripts/qemu-firmware.sh --raw ELF    # the raw defmt frames on stdout
#
# `cargo run --release` in firmware/ calls it (the runner in firmware/.cargo/config.toml).
# `-icount shift=0` makes virtual time advance 1 ns per instruction, so the firmware's SysTick
# counts instructions (deterministically); semihosting carries the defmt frames to stdout and
# the exit code back (0: the pipeline ran).
set -euo pipefail

raw=false
if [ "${1:-}" = "--raw" ]; then raw=true; shift; fi
elf=${1:?usage: $0 [--raw] ELF}

run_qemu() {
  qemu-system-arm -machine mps2-an500 -cpu cortex-m7 -nographic -monitor none -serial none \
    -semihosting-config enable=on,target=native -icount shift=0 -kernel "$elf"
}

if $raw; then
  run_qemu
elif command -v defmt-print >/dev/null 2>&1; then
  run_qemu | defmt-print -e "$elf"
else
  echo "defmt-print is not installed (cargo install defmt-print); or use --raw" >&2
  exit 1
fi

#!/usr/bin/env bash
# The core's tests under Miri: undefined behaviour, out-of-bounds and uninitialized reads,
# invalid pointer casts and aliasing violations in every path the tests reach, the `unsafe`
# blocks of the portable code included (the blocked Arm kernel's unpacked-input buffer, run on
# emulated instructions here). Miri has no `cpuid`, so the x86 SIMD tables are absent under it
# (`kernels::x86::Features::detect`) and the reference kernels run instead; the SIMD kernels are
# covered by the exact kernel tests on real CPUs and the Arm instructions by the QEMU self-test.
#
#   bash scripts/miri.sh                        # the default set (below)
#   bash scripts/miri.sh [CARGO TEST ARGS…]     # e.g. bash scripts/miri.sh --test raster
#
# Property tests run PROPTEST_CASES cases each (default 4: Miri interprets about 1,000× slower
# than native code); the kernel tests set 2 under Miri themselves. Needs the nightly toolchain with the miri and rust-src components
# (installed here if missing). Not part of scripts/test.sh: it takes about 19 minutes.
set -euo pipefail
cd "$(dirname "$0")/.."
rustup toolchain install nightly --profile minimal >/dev/null 2>&1 || true
rustup component add miri rust-src --toolchain nightly >/dev/null 2>&1 || true
export PROPTEST_CASES=${PROPTEST_CASES:-4}
# proptest persists failing cases to files and reads the clock: allow both.
export MIRIFLAGS=${MIRIFLAGS:-"-Zmiri-disable-isolation"}
# libm's x86 `sqrtf` is inline assembly, which Miri cannot run: its portable code instead (IEEE
# square roots are correctly rounded either way, so the values are the same).
miri() { cargo +nightly miri test -p evpose-core --features libm/force-soft-floats "$@"; }
if [ $# -gt 0 ]; then
  miri "$@"
  exit
fi
# The default set, about 19 minutes on two cores: the unit tests (6 min), the rasterizer's
# tests (3 min), and of the kernel tests the ones that reach the Arm kernels' and pooling's
# code (10 min; the rest of core/tests/kernels.rs checks x86 tables Miri does not have, and
# its property tests generate inputs too slowly interpreted to run them all).
miri --lib --test raster
miri --test kernels -- i8_matmat_kernels_match_reference_small_k pooling_matches i8_matmat_k_zero

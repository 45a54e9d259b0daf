#!/usr/bin/env bash
# Instructions per event of the core rasterizer, counted by callgrind (deterministic, unlike
# wall time). Prints the inclusive count of Rasterizer::extend (rasterization at window close
# included) divided by the events pushed.
set -euo pipefail
cd "$(dirname "$0")/.."
iters=${1:-10}
cargo build --release -q -p evpose-host
out=$(mktemp)
valgrind --tool=callgrind --callgrind-out-file="$out" \
  "${CARGO_TARGET_DIR:-target}/release/evpose" bench raster --iterations "$iters" >/dev/null 2>&1
events=$(( (iters + 1) * 7500 ))   # the benchmark runs one warm-up pass
callgrind_annotate --inclusive=yes "$out" >"$out.txt" 2>/dev/null
incl=$(awk '/Rasterizer<S>::extend/ { gsub(",", "", $1); print $1; exit }' "$out.txt")
if [ -z "$incl" ]; then
  echo "Rasterizer<S>::extend is not in the profile (renamed or inlined?): no figure" >&2
  exit 1
fi
echo "Rasterizer::extend, inclusive: $incl instructions for $events events"
awk -v i="$incl" -v e="$events" 'BEGIN { printf "%.1f instructions per event\n", i / e }'
rm -f "$out" "$out.txt"

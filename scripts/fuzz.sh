#!/usr/bin/env bash
# Fuzzes every target of fuzz/ (cargo-fuzz, libFuzzer, AddressSanitizer) for RUNS executions
# each (default 1,000,000), two at a time, with a 256 MiB RSS limit (a reader or the blob parser
# that allocates from an unchecked length field fails it) and a 10 s per-input timeout, and
# prints executions, crashes, out-of-memory, time-outs and peak RSS per target.
#
#   bash scripts/fuzz.sh [RUNS] [TARGET…]
#
# Needs a nightly toolchain and cargo-fuzz (installed here if missing). Corpora grow in
# fuzz/corpus/ (not committed), seeded from fuzz/seeds/; a failing input is saved in
# fuzz/artifacts/<target>/ and reproduces with `cargo +nightly fuzz run <target> <file>`.
set -euo pipefail
cd "$(dirname "$0")/../fuzz"
runs=${1:-1000000}
shift || true
rustup toolchain install nightly --profile minimal >/dev/null 2>&1 || true
command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz --locked
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <(cargo +nightly fuzz list)
fi
cargo +nightly fuzz build -O >/dev/null
mkdir -p logs
fuzz_one() {
  local t=$1
  mkdir -p "corpus/$t" "artifacts/$t"
  cp -n "seeds/$t"/* "corpus/$t"/ 2>/dev/null || true
  local start=$SECONDS
  touch "logs/$t.secs.start" # crash inputs saved after this one are this run's
  # -max_len: the largest seed, and at least 4 KiB.
  local max_len
  max_len=$(find "seeds/$t" -type f -printf '%s\n' | sort -n | tail -1)
  max_len=$(( max_len > 4096 ? max_len * 2 : 4096 ))
  cargo +nightly fuzz run -O "$t" "corpus/$t" -- -runs="$runs" -rss_limit_mb=256 \
    -timeout=10 -max_len="$max_len" -print_final_stats=1 >"logs/$t.log" 2>&1 || true
  echo $((SECONDS - start)) >"logs/$t.secs"
}
export -f fuzz_one
export runs
# AddressSanitizer keeps freed memory in a quarantine (256 MiB by default) that counts in the
# RSS: keep it small so that the RSS limit measures what the code under test holds.
export ASAN_OPTIONS="${ASAN_OPTIONS:-quarantine_size_mb=16}"
printf '%s\n' "${targets[@]}" | xargs -P 2 -I{} bash -c 'fuzz_one {}'
printf '%-20s %12s %8s %5s %9s %13s %8s\n' target executions crashes oom timeouts peak_rss_mb seconds
status=0
for t in "${targets[@]}"; do
  log="logs/$t.log"
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo 0)
  # One crash prints both a panic and libFuzzer's deadly signal: count the inputs saved.
  crash=$(find "artifacts/$t" -name 'crash-*' -newer "logs/$t.secs.start" 2>/dev/null | wc -l)
  oom=$(grep -c 'ERROR: libFuzzer: out-of-memory\|malloc(.*) exceeds limit' "$log" || true)
  tmo=$(grep -c 'ERROR: libFuzzer: timeout' "$log" || true)
  rss=$(grep -o 'stat::peak_rss_mb: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo '?')
  printf '%-20s %12s %8s %5s %9s %13s %8s\n' "$t" "${execs:-0}" "$crash" "$oom" "$tmo" "${rss:-?}" \
    "$(cat "logs/$t.secs")"
done
# A target that did not reach its executions without a finding (it did not build, or was
# killed) is a failure, not a clean row; so is any finding.
for t in "${targets[@]}"; do
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "logs/$t.log" | grep -o '[0-9]*$' || echo 0)
  findings=$(grep -c 'ERROR: AddressSanitizer\|ERROR: libFuzzer' "logs/$t.log" || true)
  if [ "${execs:-0}" -lt "$runs" ] || [ "$findings" -gt 0 ]; then
    echo "$t: ${execs:-0} of $runs executions, $findings finding(s): see logs/$t.log" >&2
    status=1
  fi
done
exit $status

#!/usr/bin/env bash
# Runs every fuzz target (build-fuzz/bin/fuzz_*) for SECONDS each on its seeds
# (scripts/fuzz-seeds.sh) and writes out/fuzz/report.md: executions, coverage (edges, features),
# corpus size and crashes per target. Crash, leak and timeout inputs are kept in
# out/fuzz/findings/<target>/. Exits 1 if any target found one.
#
# Targets run JOBS at a time (default: the number of cores). Each fuzzer is one process on one
# core, so every target still gets SECONDS of a core; the whole run takes SECONDS x targets / JOBS.
#
#   scripts/fuzz-run.sh [SECONDS] [BUILD_DIR] [JOBS]     (defaults: 60, build-fuzz, nproc)
set -uo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-60}
build=${2:-build-fuzz}
parallel=${3:-$(nproc)}
case "$seconds" in ''|*[!0-9]*) echo "fuzz-run: SECONDS is a whole number" >&2; exit 2 ;; esac
case "$parallel" in ''|0|*[!0-9]*) echo "fuzz-run: JOBS is a whole number, at least 1" >&2; exit 2 ;; esac
out=out/fuzz
mkdir -p "$out"
report="$out/report.md"
{
  echo "# Fuzzing report ($(date -u +%Y-%m-%dT%H:%MZ), $seconds s per target, $parallel at a time, $(nproc) cores)"
  echo
  echo "| target | executions | exec/s | edges (cov) | features (ft) | corpus | findings |"
  echo "| --- | --- | --- | --- | --- | --- | --- |"
} > "$report"
targets=("$build"/bin/fuzz_*)
[ -x "${targets[0]}" ] || { echo "fuzz-run: no fuzz targets in $build/bin; run make fuzz-build" >&2; exit 2; }

# fuzz_one TARGET: runs one target; its exit status goes to out/fuzz/TARGET.status.
fuzz_one() {
  local bin=$1 t corpus findings log
  t=$(basename "$bin")
  corpus="$out/corpus/$t"
  findings="$out/findings/$t"
  mkdir -p "$corpus" "$findings"
  [ -d "$out/seeds/$t" ] && cp -n "$out/seeds/$t"/* "$corpus"/ 2>/dev/null
  log="$out/$t.log"
  echo "fuzz-run: $t for $seconds s" >&2
  ASAN_OPTIONS=detect_leaks=1 "$bin" "$corpus" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=3072 \
      -max_len=1048576 -print_final_stats=1 -artifact_prefix="$findings/" > "$log" 2>&1
  echo $? > "$out/$t.status"
}
for bin in "${targets[@]}"; do
  rm -f "$out/$(basename "$bin").status"
  while [ "$(jobs -rp | wc -l)" -ge "$parallel" ]; do wait -n; done
  fuzz_one "$bin" &
done
wait

# The report, one row per target in name order.
failed=0
for bin in "${targets[@]}"; do
  t=$(basename "$bin")
  corpus="$out/corpus/$t"
  findings="$out/findings/$t"
  log="$out/$t.log"
  status=$(cat "$out/$t.status" 2>/dev/null || echo "no status")
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  ft=$(grep -o 'ft: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  files=$(ls "$corpus" | wc -l)
  found=$(ls "$findings" | wc -l)
  if [ "$status" != 0 ] || [ "$found" -gt 0 ]; then
    failed=1
    what=$(grep -m1 -E 'ERROR: (AddressSanitizer|LeakSanitizer|libFuzzer)|runtime error' "$log" | cut -c1-120)
    found="$found: ${what:-exit $status} (see $log)"
  fi
  echo "| $t | ${execs:-?} | ${rate:-?} | ${cov:-?} | ${ft:-?} | $files | $found |" >> "$report"
done
cat "$report"
exit $failed

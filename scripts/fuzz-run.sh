#!/usr/bin/env bash
# Runs every fuzz target (build-fuzz/bin/fuzz_*) for SECONDS each on its seeds
# (scripts/fuzz-seeds.sh) and writes out/fuzz/report.md: executions, coverage (edges, features),
# corpus size and crashes per target. Crash, leak and timeout inputs are kept in
# out/fuzz/findings/<target>/. Exits 1 if any target found one.
#
#   scripts/fuzz-run.sh [SECONDS] [BUILD_DIR]     (defaults: 60, build-fuzz)
set -uo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-60}
build=${2:-build-fuzz}
case "$seconds" in ''|*[!0-9]*) echo "fuzz-run: SECONDS is a whole number" >&2; exit 2 ;; esac
out=out/fuzz
mkdir -p "$out"
report="$out/report.md"
{
  echo "# Fuzzing report ($(date -u +%Y-%m-%dT%H:%MZ), $seconds s per target, $(nproc) cores)"
  echo
  echo "| target | executions | exec/s | edges (cov) | features (ft) | corpus | findings |"
  echo "| --- | --- | --- | --- | --- | --- | --- |"
} > "$report"
failed=0
for bin in "$build"/bin/fuzz_*; do
  t=$(basename "$bin")
  corpus="$out/corpus/$t"
  findings="$out/findings/$t"
  mkdir -p "$corpus" "$findings"
  [ -d "$out/seeds/$t" ] && cp -n "$out/seeds/$t"/* "$corpus"/ 2>/dev/null
  log="$out/$t.log"
  echo "fuzz-run: $t for $seconds s" >&2
  ASAN_OPTIONS=detect_leaks=1 "$bin" "$corpus" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=3072 \
      -max_len=1048576 -print_final_stats=1 -artifact_prefix="$findings/" > "$log" 2>&1
  status=$?
  execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
  cov=$(grep -o 'cov: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  ft=$(grep -o 'ft: [0-9]*' "$log" | tail -1 | grep -o '[0-9]*')
  files=$(ls "$corpus" | wc -l)
  found=$(ls "$findings" | wc -l)
  if [ "$status" -ne 0 ] || [ "$found" -gt 0 ]; then
    failed=1
    what=$(grep -m1 -E 'ERROR: (AddressSanitizer|LeakSanitizer|libFuzzer)|runtime error' "$log" | cut -c1-120)
    found="$found: ${what:-exit $status} (see $log)"
  fi
  echo "| $t | ${execs:-?} | ${rate:-?} | ${cov:-?} | ${ft:-?} | $files | $found |" >> "$report"
done
cat "$report"
exit $failed

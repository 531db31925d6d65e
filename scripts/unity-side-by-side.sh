#!/usr/bin/env bash
# Compile time with and without unity batches, side by side (BENCHMARKS.md, "CI time"): the objects
# of the program, the studies and cli_tests, deleted and compiled again with ninja -j 2 in a
# folder configured file by file (build-nounity) and then in one with unity batches
# (default: build). Needs both folders built once; prints the seconds of each.
set -euo pipefail
cd "$(dirname "$0")/.."
unity_dir=${1:-build}
cmake -S . -B build-nounity -G Ninja -DCMAKE_BUILD_TYPE=Release -DLFTRACK_WERROR=ON -DLFTRACK_UNITY_BUILD=OFF >/dev/null
for d in build-nounity "$unity_dir"; do
  mapfile -t objs < <(ninja -C "$d" -t targets all |
    grep -E '^(cli|studies|tests)/CMakeFiles/(lftrack|lftrack_studies|cli_tests)\.dir/.*\.o:' | cut -d: -f1)
  (cd "$d" && rm -f "${objs[@]}")
  start_ns=$(date +%s%N)
  ninja -C "$d" -j 2 "${objs[@]}" >/dev/null
  end_ns=$(date +%s%N)
  echo "$d: ${#objs[@]} objects in $(( (end_ns - start_ns) / 1000000000 )) s"
done

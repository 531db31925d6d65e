#!/usr/bin/env bash
# The shipped real-CT scenes on the real clock (issue 51's benchmark): each scene at its own rate
# (10 Hz) for CYCLES cycles with LOAD cores kept busy by stress-ng beside it, then the lumbar scene
# at 30 Hz (phantom-30hz's loop settings: a 33.3 ms period, a 20 ms registration budget, a 12 ms
# acquisition timeout, 24 cycles of prediction) on the lumbar scene's own light fields, and the
# built-in phantom at 30 Hz with clinical X-rays (scenes/phantom-clinical-30hz.yaml).
# Light fields are built first, unloaded and untimed (one cycle on the simulated clock). Writes
# out/exp/real-clock/<run>.json (the `sim --json` summary) and out/exp/real-clock/summary.md (one
# row per run); prints the table.
#
#   scripts/real-clock-scenes.sh [CYCLES] [LOAD] [LFTRACK]     (defaults: 3000, 1, build/bin/lftrack)
set -euo pipefail
cd "$(dirname "$0")/.."
cycles=${1:-3000}
load=${2:-1}
lftrack=${3:-build/bin/lftrack}
case "$cycles" in ''|0|*[!0-9]*) echo "real-clock-scenes: CYCLES is a whole number, at least 1" >&2; exit 2 ;; esac
case "$load" in ''|*[!0-9]*) echo "real-clock-scenes: LOAD is a whole number of cores (0: none)" >&2; exit 2 ;; esac
[ -x "$lftrack" ] || { echo "real-clock-scenes: $lftrack missing; run make first" >&2; exit 2; }
if [ "$load" -gt 0 ]; then
  command -v stress-ng >/dev/null || { echo "real-clock-scenes: stress-ng missing (make setup)" >&2; exit 2; }
fi
out=out/exp/real-clock
mkdir -p "$out"

# The 30 Hz variant of the lumbar scene, next to nothing in scenes/: its room file (which holds
# the loop's settings, docs/scenes.md "Room files") copied with the 30 Hz loop, and the scene
# naming that copy, with the CT's and the commissioning file's paths made absolute (the loop's
# period is not what the floors depend on).
data=$(cd scenes && realpath -m ../../shared/data)
lumbar30="$out/lumbar-ct-30hz.yaml"
room30="$out/oblique-pair-30hz.yaml"
commissioning=$(realpath scenes/commissioning)
room=$(sed -n 's|^room: \([^ ]*\).*|\1|p' scenes/lumbar-ct.yaml)
[ -n "$room" ] && [ -f "scenes/$room" ] ||
  { echo "real-clock-scenes: scenes/lumbar-ct.yaml names no room file; update the 30 Hz edit" >&2; exit 2; }
sed -e 's|^  period_ms: 100$|  period_ms: 33.333|' \
    -e 's|^  registration_budget_ms: 50$|  registration_budget_ms: 20|' \
    -e 's|^  acquire_timeout_ms: 40$|  acquire_timeout_ms: 12\n  prediction_cycles: 24|' \
    "scenes/$room" > "$room30"
sed -e "s|path: ../../shared/data|path: $data|" \
    -e "s|commissioning: commissioning/|commissioning: $commissioning/|" \
    -e "s|^room: [^ ]*|room: $(realpath "$room30")|" \
    -e 's|^name: .*|name: pancreas CT, lumbar vertebra, tracked at 30 Hz|' \
    scenes/lumbar-ct.yaml > "$lumbar30"
grep -q 'period_ms: 33.333' "$room30" && grep -q 'registration_budget_ms: 20' "$room30" &&
  grep -q 'prediction_cycles: 24' "$room30" && grep -q "room: $(realpath "$room30")" "$lumbar30" ||
  { echo "real-clock-scenes: scenes/$room's loop settings changed; update the 30 Hz edit" >&2; exit 2; }

# stress-ng beside a run; stopped when the run ends, or when this script is stopped.
stress_pid=
stop_stress() {
  if [ -n "$stress_pid" ]; then
    kill "$stress_pid" 2>/dev/null || true
    wait "$stress_pid" 2>/dev/null || true
    stress_pid=
  fi
}
trap 'stop_stress; exit 130' INT TERM
trap stop_stress EXIT

# run NAME SCENE [LF_DIR]: a run that fails is said so, and the others still run.
runs=()
run() {
  local name=$1 scene=$2 lf=${3:-}
  local lf_args=()
  [ -n "$lf" ] && lf_args=(--lf-dir "$lf")
  # One cycle on the simulated clock first builds whatever fields are missing (the registration's
  # and the simulator's), so the timed run below starts at once.
  echo "real-clock-scenes: $name: light fields" >&2
  if ! "$lftrack" -q sim --scene "$scene" --fast --cycles 1 "${lf_args[@]}" > /dev/null; then
    echo "real-clock-scenes: $name: the one-cycle warm-up failed; not run" >&2
    runs+=("$name")
    return 0
  fi
  if [ "$load" -gt 0 ]; then
    stress-ng --cpu "$load" --quiet &
    stress_pid=$!
  fi
  echo "real-clock-scenes: $name: $cycles cycles on the real clock beside stress-ng --cpu $load" >&2
  local status=0
  "$lftrack" -q sim --scene "$scene" --cycles "$cycles" --json "${lf_args[@]}" > "$out/$name.json" || status=$?
  stop_stress
  [ "$status" -eq 0 ] || echo "real-clock-scenes: $name: lftrack sim exited $status" >&2
  runs+=("$name")
}
run lumbar-ct scenes/lumbar-ct.yaml
run lumbar-ct-clinical scenes/lumbar-ct-clinical.yaml
run thoracic-ct scenes/thoracic-ct.yaml
run thoracic-ct-clinical scenes/thoracic-ct-clinical.yaml
run lumbar-ct-30hz "$lumbar30" out/lightfields/lumbar-ct
run phantom-clinical-30hz scenes/phantom-clinical-30hz.yaml out/lightfields/builtin-phantom

python3 - "$out" "$cycles" "$load" "${runs[@]}" <<'EOF' | tee "$out/summary.md"
import json, sys
out, cycles, load, runs = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
print(f"{cycles} cycles per run on the real clock, stress-ng --cpu {load} beside each\n")
print("| run | period ms | TRACK cycles | overruns | skipped periods | residual p95 mm (beam on: > 1 mm / > 2 mm) "
      "| cycle p99 ms | registration p95 ms | exposure to ack p50 / p99 ms | allocations per cycle |")
print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
for r in runs:
    try:
        d = json.load(open(f"{out}/{r}.json"))
    except (OSError, ValueError) as e:
        print(f"| {r} | no summary: {e} |")
        continue
    # A run that never tracked has none of some figures (null in the JSON): '-' for those.
    def fig(v, f):
        return "-" if v is None else format(v, f)
    t = d.get("target_residual") or {}
    on = t.get("beam_on") or {}
    lat = d.get("latency_exposure_to_ack_ms") or {}
    err = (t.get("error_3d_mm") or {}).get("p95")
    print(f"| {r} | {d['period_ms']:.1f} | {d['states'].get('TRACK', 0)} of {d['cycles']} | {d['overruns']} "
          f"| {d['skipped_periods']} | {fig(err, '.3f')} ({on.get('share_over_1mm', 0):.1%} / "
          f"{on.get('share_over_2mm', 0):.1%} of {on.get('cycles', 0)}) | {fig((d.get('cycle_ms') or {}).get('p99'), '.2f')} "
          f"| {fig((d.get('registration_ms') or {}).get('p95'), '.2f')} | {fig(lat.get('p50'), '.1f')} / {fig(lat.get('p99'), '.1f')} "
          f"| {d.get('allocations_per_cycle')} |")
EOF

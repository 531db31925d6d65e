#!/usr/bin/env bash
# The motion predictor with and without its rotations extrapolated (loop.predict_rotations), side
# by side on the same scenes, seeds and light fields, on the simulated clock (`sim --fast`: the
# same seed gives the same run whatever the host's load). For each scene a copy with
# `predict_rotations: true` is written next to it (next to its room file, for a scene whose loop
# settings are in one), so its relative paths still hold, and removed afterwards. Prints one row
# per scene and setting: TRACK cycles, holds, and over the beam-on cycles (tracking, after the
# set-up move) the target's true rotation (sd per axis, degrees), its 3D translation error p95
# (mm) and the share of those cycles beyond 1 mm. Journals and summaries: out/exp/predict-rotations.
#
#   scripts/predict-rotations-side-by-side.sh [CYCLES] [LFTRACK] [SCENE...]
#     (defaults: 300, build/bin/lftrack, the phantom at 30 Hz and the four real-CT scenes)
set -euo pipefail
cd "$(dirname "$0")/.."
cycles=${1:-300}
lftrack=${2:-build/bin/lftrack}
shift $(( $# > 2 ? 2 : $# ))
scenes=("$@")
[ ${#scenes[@]} -gt 0 ] || scenes=(scenes/phantom-30hz.yaml scenes/lumbar-ct.yaml scenes/lumbar-ct-clinical.yaml
                                 scenes/thoracic-ct.yaml scenes/thoracic-ct-clinical.yaml)
case "$cycles" in ''|0|*[!0-9]*) echo "predict-rotations: CYCLES is a whole number, at least 1" >&2; exit 2 ;; esac
[ -x "$lftrack" ] || { echo "predict-rotations: $lftrack missing; run make first" >&2; exit 2; }
out=out/exp/predict-rotations
mkdir -p "$out"
made=()
cleanup() { for f in "${made[@]}"; do rm -f "$f"; done; }
trap cleanup EXIT

# `loop:` in FILE gets `  predict_rotations: true` under it, into COPY; fails if FILE has no loop.
with_rotations() {
  grep -q '^loop:' "$1" || return 1
  sed 's|^loop:.*|&\n  predict_rotations: true|' "$1" > "$2"
}

printf '| scene | rotations | TRACK | holds | beam-on cycles | true rotation sd x / y / z (deg) | 3D error p95 (mm) | beyond 1 mm |\n'
printf '| --- | --- | --- | --- | --- | --- | --- | --- |\n'
for scene in "${scenes[@]}"; do
  [ -f "$scene" ] || { echo "predict-rotations: $scene missing" >&2; exit 2; }
  name=$(basename "$scene" .yaml)
  dir=$(dirname "$scene")
  copy="$dir/.predict-rotations-$name.yaml"
  if ! with_rotations "$scene" "$copy"; then
    room=$(sed -n 's|^room: *\([^ #]*\).*|\1|p' "$scene")
    [ -n "$room" ] && [ -f "$dir/$room" ] || { echo "predict-rotations: $scene has no loop section and no room file" >&2; exit 2; }
    room_copy="$(dirname "$dir/$room")/.predict-rotations-$(basename "$room")"
    with_rotations "$dir/$room" "$room_copy" || { echo "predict-rotations: $dir/$room has no loop section" >&2; exit 2; }
    made+=("$room_copy")
    sed "s|^room: *$room|room: $(dirname "$room")/$(basename "$room_copy")|" "$scene" > "$copy"
  fi
  made+=("$copy")
  for setting in extrapolated newest; do
    run=$scene
    [ "$setting" = extrapolated ] && run=$copy
    rm -f "$out/$name-$setting.lfj"
    "$lftrack" -q sim --scene "$run" --fast --cycles "$cycles" --journal "$out/$name-$setting.lfj" \
      --lf-dir "out/lightfields/$name" --json > "$out/$name-$setting.json"
    "$lftrack" -q journal export "$out/$name-$setting.lfj" > "$out/$name-$setting.jsonl"
    python3 - "$out/$name-$setting.json" "$out/$name-$setting.jsonl" "$name" "$setting" <<'EOF'
import json, math, sys
s = json.load(open(sys.argv[1]))
# The beam-on cycles (tracking, after the set-up move): the target's true rotation and 3D error.
on = [r for r in map(json.loads, open(sys.argv[2])) if r.get("beam_permit")]
rot = [r["true_target_residual"]["rotation_deg"] for r in on]
err = sorted(math.dist(r["true_target_residual"]["translation_mm"], (0, 0, 0)) for r in on)
def sd(v):
    m = sum(v) / len(v)
    return math.sqrt(sum((x - m) ** 2 for x in v) / len(v))
sds = [sd([r[a] for r in rot]) if rot else float("nan") for a in range(3)]
p95 = err[min(len(err) - 1, int(0.95 * len(err)))] if err else float("nan")
over = sum(e > 1.0 for e in err) / len(err) if err else float("nan")
print(f"| {sys.argv[3]} | {sys.argv[4]} | {s['states']['TRACK']} / {s['cycles']} | {s['holds']} | {len(on)} | "
      f"{sds[0]:.3f} / {sds[1]:.3f} / {sds[2]:.3f} | {p95:.3f} | {over:.3f} |")
EOF
  done
done

#!/usr/bin/env bash
# `lftrack register --sim` on every shipped real-CT scene at 9 gold poses across the pose envelope
# (10 mm / 5 degrees), two seeds each, a cold registration from the nominal pose (issue 51): one
# line per run with the verdict, its reason and the mean TRE. Exits 1 if any run was not ACCEPTED.
#
#   scripts/register-across-envelope.sh [LFTRACK]     (default build/bin/lftrack)
set -euo pipefail
cd "$(dirname "$0")/.."
lftrack=${1:-build/bin/lftrack}
[ -x "$lftrack" ] || { echo "register-across-envelope: $lftrack missing; run make first" >&2; exit 2; }
golds="0,0,0,0,0,0 8,0,0,0,0,0 0,-8,0,0,0,0 0,0,8,0,0,0 0,0,0,4,0,0 0,0,0,0,-4,0 0,0,0,0,0,4 5,-5,5,2.5,-2.5,2.5 -6,4,-3,-2,3,-1"
out=$(mktemp)
trap 'rm -f "$out"' EXIT
refused=0
for scene in lumbar-ct lumbar-ct-clinical thoracic-ct thoracic-ct-clinical; do
  for gold in $golds; do
    for seed in 1 2; do
      "$lftrack" -q register --scene "scenes/$scene.yaml" --sim --gold "$gold" --seed "$seed" --json > "$out" 2>&1 || true
      python3 - "$scene" "$gold" "$seed" "$out" <<'PY' || refused=1
import json, sys
scene, gold, seed, path = sys.argv[1:5]
text = open(path).read()
try:
    d = json.loads(text[text.index('{'):text.rindex('}') + 1])
except ValueError:
    print(f"{scene:22s} {gold:22s} {seed}  no result: {text.strip()[-200:]}")
    sys.exit(1)
v = d["verdict"]
print(f"{scene:22s} {gold:22s} {seed}  {'ACCEPTED' if v['ok'] else 'REJECTED'} ({v['reason']})  "
      f"mean TRE {d['tre_mm']['mean']:.3f} mm  {d['ms']:.0f} ms")
sys.exit(0 if v["ok"] else 1)
PY
    done
  done
done
exit $refused

#!/bin/bash
# Commissions the registration verdict of every shipped scene (issue 52): `lftrack commission`
# with 200 good and 1,000 bad cases each, the other CT's scene as the other patient, and the
# vertebral level of each spine. Writes scenes/commissioning/<scene>.yaml (the file the scene names,
# replacing the one there) and out/commission/<scene>/ (cases.csv, verdict.png), a log per scene in
# out/commission/.
# About 6-8 minutes a real-CT scene on two cores, 40 minutes in all. Run it again whenever a
# scene's CT, room, registration or imaging changes: the loop refuses a stale commissioning file.
#   scripts/commission-shipped-scenes.sh [LFTRACK] [SCENE...]
set -euo pipefail
cd "$(dirname "$0")/.."
lftrack=${1:-build/bin/lftrack}
shift || true
scenes=("$@")
[ ${#scenes[@]} -gt 0 ] || scenes=(lumbar-ct-clinical thoracic-ct-clinical lumbar-ct thoracic-ct phantom-clinical-30hz phantom-30hz)
mkdir -p out/commission
status=0
for scene in "${scenes[@]}"; do
  case $scene in  # the other patient (the same preset's other CT), and one vertebral level
    lumbar-ct) other=thoracic-ct level=35 ;;
    lumbar-ct-clinical) other=thoracic-ct-clinical level=35 ;;
    thoracic-ct) other=lumbar-ct level=25 ;;
    thoracic-ct-clinical) other=lumbar-ct-clinical level=25 ;;
    phantom-30hz) other=lumbar-ct level=30 ;;
    phantom-clinical-30hz) other=lumbar-ct-clinical level=30 ;;
    *) echo "unknown shipped scene: $scene" >&2; exit 2 ;;
  esac
  echo "== $scene"
  if "$lftrack" commission --scene "scenes/$scene.yaml" --good 200 --bad 1000 --seed 1 \
      --other-scene "scenes/$other.yaml" --level-mm "$level" --replace \
      --report "out/commission/$scene" > "out/commission/$scene.log" 2> "out/commission/$scene.err"; then
    grep -E "false accepts|held out|wrote" "out/commission/$scene.log"
  else
    echo "$scene: not commissioned (out/commission/$scene.log, .err)"; tail -3 "out/commission/$scene.err"; status=1
  fi
done
exit $status

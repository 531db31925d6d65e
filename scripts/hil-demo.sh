#!/usr/bin/env bash
# Hardware in the loop across processes, unattended: the built-in scene's room as three
# processes speaking the real protocols. Starts the couch (Modbus TCP) or robot (CAN bridge)
# server and the detector server (two GigE Vision cameras), runs `lftrack run --json` against
# them on the real clock, stops the servers, and prints the run's summary JSON (its `hil` block
# is the protocol's counters) with the detector server's truth (`served_frames`: the simulated
# patient's residual over the frames it served) on stdout. Progress goes to stderr.
#
#   scripts/hil-demo.sh [--cycles N] [--actuator modbus|can]
#
# Each GigE camera needs an IPv4 address of its own (GigE Vision's control port is fixed):
# 127.0.0.1 and the host's next address (or 127.0.0.2 where it was added to lo). The scene is
# copied to out/hil/ with those addresses. Light fields: out/lightfields/builtin-phantom (the
# built-in scene's; `make demo` builds them), built here if missing.
set -euo pipefail
cd "$(dirname "$0")/.."
cycles=300
actuator=modbus
while [ $# -gt 0 ]; do
  case "$1" in
    --cycles) cycles="$2"; shift 2 ;;
    --actuator) actuator="$2"; shift 2 ;;
    -h|--help) sed -n 2,14p "$0"; exit 0 ;;
    *) echo "hil-demo: unknown argument '$1' (--cycles N, --actuator modbus|can)" >&2; exit 2 ;;
  esac
done
case "$actuator" in modbus|can) ;; *) echo "hil-demo: --actuator is modbus or can" >&2; exit 2 ;; esac
case "$cycles" in ''|*[!0-9]*) echo "hil-demo: --cycles is a whole number" >&2; exit 2 ;; esac
[ "$cycles" -ge 1 ] || { echo "hil-demo: --cycles must be at least 1" >&2; exit 2; }

lftrack=build/bin/lftrack
[ -x "$lftrack" ] || { echo "hil-demo: $lftrack missing; run make first" >&2; exit 1; }
out=out/hil
mkdir -p "$out"
lf=out/lightfields/builtin-phantom

# The second camera's address: 127.0.0.2 if lo has it, else the host's next IPv4 address.
second=$(ip -4 -o addr show 2>/dev/null | awk '{print $4}' | cut -d/ -f1 | grep -v '^127\.0\.0\.1$' | head -1 || true)
[ -n "$second" ] || { echo "hil-demo: one IPv4 address only; add one (ip addr add 127.0.0.2/8 dev lo)" >&2; exit 1; }
scene="$out/gige-$actuator.yaml"
sed -e "s|camera: 127.0.0.2|camera: $second|" -e "s|\.\./\.\./out/hil/|$PWD/$out/|g" "scenes/room/gige-$actuator.yaml" > "$scene"

if [ ! -f "$lf/A.lf" ]; then
  echo "hil-demo: building the tracking light fields in $lf (minutes, once)" >&2
  "$lftrack" -q precompute --scene builtin:phantom -o "$lf" >&2
fi

pids=()
stop_servers() { for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; }
trap stop_servers EXIT
room="$out/room.link"
if [ "$actuator" = modbus ]; then
  "$lftrack" -q serve couch --modbus tcp:127.0.0.1:15020 --room "$room" --scene "$scene" --json > "$out/couch.out" &
else
  "$lftrack" -q serve robot --socket "$PWD/$out/robot.sock" --room "$room" --scene "$scene" --json > "$out/couch.out" &
fi
pids+=($!)
for _ in $(seq 50); do [ -s "$out/couch.out" ] && break; sleep 0.1; done
[ -s "$out/couch.out" ] || { echo "hil-demo: the $actuator server did not start" >&2; exit 1; }
# The detector server renders each pair when triggered (tens of ms on one core); on a two-core
# host it gets CPU 0 to itself, and the loop (the scene's loop.realtime.cpus) CPU 1.
taskset -c 0 "$lftrack" -q serve detectors --scene "$scene" --room "$room" --address 127.0.0.1 --address "$second" \
    --lf-dir "$lf" --json > "$out/detectors.out" &
detectors=$!
pids+=($detectors)
for _ in $(seq 600); do [ -s "$out/detectors.out" ] && break; sleep 0.1; done
[ -s "$out/detectors.out" ] || { echo "hil-demo: the detector server did not start" >&2; exit 1; }
echo "hil-demo: $(head -1 "$out/couch.out"); $(head -1 "$out/detectors.out")" >&2
set +e
"$lftrack" -q run --scene "$scene" --lf-dir "$lf" --cycles "$cycles" --rt ignore --json \
    --journal "$out/journal-$actuator.lfj" --overwrite > "$out/run.json"
status=$?
set -e
kill -TERM "$detectors"; wait "$detectors" 2>/dev/null || true
python3 - "$out/run.json" "$out/detectors.out" <<'PY'
import json, sys
run = json.load(open(sys.argv[1]))
served = [l for l in open(sys.argv[2]) if l.startswith("{")]
if served:
    run["served_frames"] = json.loads(served[-1])
print(json.dumps(run, indent=2))
PY
exit $status

#!/usr/bin/env bash
# Hardware in the loop across processes, unattended: the built-in scene's room as three
# processes speaking the real protocols. Starts the couch (Modbus TCP) or robot (CAN bridge)
# server and the detector server (two GigE Vision cameras), runs `lftrack run --json` against
# them on the real clock, stops the servers, and prints the run's summary JSON (its `hil` block
# is the protocol's counters) with the detector server's truth (`served_frames`: the simulated
# patient's residual over the frames it served) on stdout, always with `served_frames` (its
# `error` says why where the server gave none) and, where the run gave no summary, `run_error`.
# Progress goes to stderr.
#
#   scripts/hil-demo.sh [--cycles N] [--actuator modbus|can] [--scene FILE] [--lf-dir DIR] [--out DIR]
#
# Everything listens on loopback only: the couch on 127.0.0.1 at a free port (read back from
# the server), the two GigE cameras on 127.0.0.1 and 127.0.0.2 (GigE Vision's control port is
# fixed, so each camera needs an address of its own; every 127.x.y.z is this host's loopback).
# The scene (default scenes/room/gige-ACTUATOR.yaml) is copied to the output folder (default
# out/hil) with that port and the output folder's paths. Light fields (default
# out/lightfields/builtin-phantom, the built-in scene's; `make demo` builds them) are built here
# if missing. LFTRACK_BIN names the program (default build/bin/lftrack).
set -euo pipefail
cd "$(dirname "$0")/.."
cycles=300
actuator=modbus
scene_in=
lf=out/lightfields/builtin-phantom
out=out/hil
while [ $# -gt 0 ]; do
  case "$1" in
    --cycles) cycles="$2"; shift 2 ;;
    --actuator) actuator="$2"; shift 2 ;;
    --scene) scene_in="$2"; shift 2 ;;
    --lf-dir) lf="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    -h|--help) sed -n 2,19p "$0"; exit 0 ;;
    *) echo "hil-demo: unknown argument '$1' (--cycles N, --actuator modbus|can, --scene FILE, --lf-dir DIR, --out DIR)" >&2
       exit 2 ;;
  esac
done
case "$actuator" in modbus|can) ;; *) echo "hil-demo: --actuator is modbus or can" >&2; exit 2 ;; esac
case "$cycles" in ''|*[!0-9]*) echo "hil-demo: --cycles is a whole number" >&2; exit 2 ;; esac
[ "$cycles" -ge 1 ] || { echo "hil-demo: --cycles must be at least 1" >&2; exit 2; }
scene_in=${scene_in:-scenes/room/gige-$actuator.yaml}
[ -f "$scene_in" ] || { echo "hil-demo: no scene $scene_in" >&2; exit 2; }

lftrack=${LFTRACK_BIN:-build/bin/lftrack}
[ -x "$lftrack" ] || { echo "hil-demo: $lftrack missing; run make first" >&2; exit 1; }
mkdir -p "$out"
out=$(cd "$out" && pwd)

# The second camera's address. Linux answers the whole of 127.0.0.0/8 on lo; a host whose lo
# carries 127.0.0.1 alone cannot run the pair: GigE Vision's control port is fixed (3956), so the
# second camera cannot share 127.0.0.1 on another port, and an outside address is never used.
second=127.0.0.2
if ! python3 -c "import socket; socket.socket(socket.AF_INET, socket.SOCK_DGRAM).bind(('$second', 0))" 2>/dev/null; then
  echo "hil-demo: this host cannot bind $second (lo carries only 127.0.0.1?); the second GigE camera needs an" \
       "address of its own on loopback: sudo ip addr add $second/8 dev lo" >&2
  exit 1
fi
scene="$out/gige-$actuator.yaml"
sed -e "s|\.\./\.\./out/hil/|$out/|g" "$scene_in" > "$scene"

# Built once (minutes); afterwards precompute finds them up to date and builds nothing.
echo "hil-demo: the tracking light fields in $lf" >&2
"$lftrack" -q precompute --scene "$scene" -o "$lf" >&2

pids=()
stop_servers() { for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; }
trap stop_servers EXIT
# Waits (at most `tenths` tenths of a second) for the server `pid` to write its first line to
# `file`; gives up at once, with its exit status, if the server exits first.
wait_for_server() {
  local file=$1 pid=$2 what=$3 tenths=$4 status
  for _ in $(seq "$tenths"); do
    [ -s "$file" ] && return 0
    if ! kill -0 "$pid" 2>/dev/null; then
      status=0
      wait "$pid" || status=$?
      echo "hil-demo: the $what server exited (status $status) before it listened; its error is above" >&2
      exit 1
    fi
    sleep 0.1
  done
  echo "hil-demo: the $what server did not start in $((tenths / 10)) s" >&2
  exit 1
}
room="$out/room.link"
if [ "$actuator" = modbus ]; then
  "$lftrack" -q serve couch --modbus tcp:127.0.0.1:0 --room "$room" --scene "$scene" --json > "$out/couch.out" &
else
  "$lftrack" -q serve robot --socket "$out/robot.sock" --room "$room" --scene "$scene" --json > "$out/couch.out" &
fi
device=$!
pids+=("$device")
wait_for_server "$out/couch.out" "$device" "$actuator" 100
if [ "$actuator" = modbus ]; then
  # "lftrack serve couch: modbus tcp 127.0.0.1:PORT[; room link ...]": the port the kernel gave.
  port=$(head -1 "$out/couch.out" | sed -n 's|^lftrack serve couch: modbus tcp 127\.0\.0\.1:\([0-9][0-9]*\).*|\1|p')
  [ -n "$port" ] || { echo "hil-demo: no port in the couch server's first line: $(head -1 "$out/couch.out")" >&2; exit 1; }
  sed -i -e "s|port: [0-9][0-9]*}|port: $port}|" "$scene"
fi
# The detector server renders each pair when triggered (tens of ms on one core); on a two-core
# host it gets CPU 0 to itself, and the loop (the scene's loop.realtime.cpus) CPU 1.
taskset -c 0 "$lftrack" -q serve detectors --scene "$scene" --room "$room" --address 127.0.0.1 --address "$second" \
    --lf-dir "$lf" --json > "$out/detectors.out" &
detectors=$!
pids+=("$detectors")
# The first time, the server builds the simulator's frame fields (a minute or more on two cores).
wait_for_server "$out/detectors.out" "$detectors" detector 3000
echo "hil-demo: $(head -1 "$out/couch.out"); $(head -1 "$out/detectors.out")" >&2
set +e
"$lftrack" -q run --scene "$scene" --lf-dir "$lf" --cycles "$cycles" --rt ignore --json \
    --journal "$out/journal-$actuator.lfj" --overwrite > "$out/run.json"
status=$?
set -e
kill -TERM "$detectors" 2>/dev/null || true
wait "$detectors" 2>/dev/null || true
python3 - "$out/run.json" "$out/detectors.out" "$status" <<'PY'
import json, sys
try:
    run = json.load(open(sys.argv[1]))
except ValueError:
    run = {"run_error": "lftrack run gave no summary (exit status %s; its error is above)" % sys.argv[3]}
served = [l for l in open(sys.argv[2]) if l.startswith("{")]
run["served_frames"] = json.loads(served[-1]) if served else {"error": "the detector server gave no summary"}
print(json.dumps(run, indent=2))
PY
exit $status

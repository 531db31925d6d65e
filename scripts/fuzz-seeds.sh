#!/usr/bin/env bash
# Seed corpora for the fuzz targets (fuzz/), generated from valid files: scene files, a tiny
# archived run (index.csv, actuator.csv, frames, journal) and light fields made by lftrack
# itself, small NIfTI headers, one DICOM slice of the shared data (read in place), calibration
# files, operator commands. Nothing here is committed: the seeds go to out/fuzz/seeds/<target>.
#
#   scripts/fuzz-seeds.sh [LFTRACK]     (default build/bin/lftrack, the release build)
set -euo pipefail
cd "$(dirname "$0")/.."
lftrack=${1:-build/bin/lftrack}
[ -x "$lftrack" ] || { echo "fuzz-seeds: $lftrack missing; run make first" >&2; exit 1; }
seeds=out/fuzz/seeds
work=out/fuzz/work
rm -rf "$seeds" "$work"
mkdir -p "$work"
for t in fuzz_scene fuzz_calibration_files fuzz_light_field fuzz_images fuzz_sequence fuzz_journal fuzz_ct fuzz_commands \
    fuzz_modbus fuzz_v4l2 fuzz_rt_objects; do
  mkdir -p "$seeds/$t"
done
# prefix FILE BYTE OUT: OUT is BYTE (a selector, 0..255) followed by FILE.
prefix() { { printf "\\$(printf '%03o' "$2")"; cat "$1"; } > "$3"; }

# Scenes: every scene in the repository, and a small light-field scene for the runs below.
n=0
for s in scenes/*.yaml scenes/room/*.yaml; do cp "$s" "$seeds/fuzz_scene/scene-$((n++)).yaml"; done
small="$work/small.yaml"
sed -e 's|    resolution: \[16, 16, 128, 128\]|    resolution: [4, 4, 48, 48]\n    storage: fixed16|' scenes/phantom-shift.yaml > "$small" 2>/dev/null || true
cp "$small" "$seeds/fuzz_scene/small.yaml"

# A tiny run: light fields, a journal and an archive (frames, index, actuator read-backs).
"$lftrack" -q precompute --scene "$small" -o "$work/lf" >/dev/null 2>&1 || true
"$lftrack" -q sim --scene "$small" --lf-dir "$work/lf" --fast --cycles 6 --journal "$work/run.lfj" \
    --archive "$work/archive" >/dev/null 2>&1 || true
for f in "$work"/lf/*.lf; do [ -f "$f" ] && cp "$f" "$seeds/fuzz_light_field/"; done
[ -f "$work/run.lfj" ] && cp "$work/run.lfj" "$seeds/fuzz_journal/"
if [ -f "$work/archive/index.csv" ]; then
  cp "$work/archive/index.csv" "$seeds/fuzz_sequence/index-only.csv"
  if [ -f "$work/archive/actuator.csv" ]; then
    { cat "$work/archive/index.csv"; printf '\0'; cat "$work/archive/actuator.csv"; } > "$seeds/fuzz_sequence/with-actuator"
  fi
  first=$(ls "$work"/archive/frames/*.tif 2>/dev/null | head -1 || true)
  [ -n "$first" ] && prefix "$first" 0 "$seeds/fuzz_images/frame-tif"
fi
# Images of every kind lftrack writes.
"$lftrack" -q drr --scene "$small" --renderer siddon --bin 8 --image png --data pfm -o "$work/drr" >/dev/null 2>&1 || true
for f in "$work"/drr/*.png; do [ -f "$f" ] && prefix "$f" 1 "$seeds/fuzz_images/$(basename "$f")-png"; done
for f in "$work"/drr/*.pfm; do [ -f "$f" ] && prefix "$f" 2 "$seeds/fuzz_images/$(basename "$f")-pfm"; done

# Calibration files: a couch calibration, the built-in phantom as a file, a detector calibration
# made from the archived frames (dark: the frames; flood: the same frames brightened).
cat > "$work/couch.yaml" <<'YAML'
couch_calibration:
  rotation_deg: [0.5, -0.2, 1.0]
  centre_mm: [1, 2, 3]
  rms_mm: 0.05
  rotation_sd_deg: [0.01, 0.01, 0.01]
  centre_sd_mm: [0.1, 0.1, 0.1]
  centre_determined: true
  moves: 8
  source: fuzz seed
YAML
prefix "$work/couch.yaml" 0 "$seeds/fuzz_calibration_files/couch"
cat > "$work/phantom.yaml" <<'YAML'
name: seed
marker_diameter_mm: 2
body_size_mm: [100, 100, 100]
marker_mu_per_mm: 0.5
body_mu_per_mm: 0.02
markers_mm:
  - [0, 0, 0]
  - [30, 0, 0]
  - [0, 30, 0]
  - [0, 0, 30]
  - [20, 20, 10]
  - [-20, 10, 25]
YAML
prefix "$work/phantom.yaml" 2 "$seeds/fuzz_calibration_files/phantom"
for f in scenes/commissioning/*.yaml; do prefix "$f" 3 "$seeds/fuzz_calibration_files/commissioning-$(basename "$f" .yaml)"; done

# CT: small NIfTI-1 volumes (int16 and float32, with sform), and one real DICOM slice.
python3 - "$work" <<'PY'
import struct, sys
work = sys.argv[1]
def nifti(path, datatype, bitpix, fmt, values, dims=(4, 3, 2)):
    h = bytearray(348)
    struct.pack_into('<i', h, 0, 348)
    struct.pack_into('<8h', h, 40, 3, dims[0], dims[1], dims[2], 1, 1, 1, 1)
    struct.pack_into('<h', h, 70, datatype)
    struct.pack_into('<h', h, 72, bitpix)
    struct.pack_into('<8f', h, 76, 1, 1, 1, 1, 0, 0, 0, 0)
    struct.pack_into('<f', h, 108, 352)   # vox_offset
    struct.pack_into('<f', h, 112, 1.0)   # scl_slope
    struct.pack_into('<h', h, 254, 1)     # sform_code
    struct.pack_into('<4f', h, 280, 1, 0, 0, 0)
    struct.pack_into('<4f', h, 296, 0, 1, 0, 0)
    struct.pack_into('<4f', h, 312, 0, 0, 1, 0)
    h[344:348] = b'n+1\0'
    with open(path, 'wb') as f:
        f.write(b'\0')  # the target's selector: NIfTI
        f.write(bytes(h) + b'\0' * 4)
        f.write(struct.pack('<%d%s' % (len(values), fmt), *values))
nifti(work + '/int16', 4, 16, 'h', [-1000 + 10 * i for i in range(24)])
nifti(work + '/float32', 16, 32, 'f', [-1000.0 + 10 * i for i in range(24)])
PY
cp "$work/int16" "$seeds/fuzz_ct/nifti-int16"
cp "$work/float32" "$seeds/fuzz_ct/nifti-float32"
slice=$(find "${LFTRACK_DATA_DIR:-../shared/data}" -type f -iname '*.dcm' 2>/dev/null | sort | head -1 || true)
[ -n "$slice" ] && prefix "$slice" 1 "$seeds/fuzz_ct/dicom-slice"

# RT Plans and Structure Sets: Debian's python3-pydicom ships some (another patient's, as a user
# might hand them over).
pydicom=/usr/lib/python3/dist-packages/pydicom/data/test_files
[ -f "$pydicom/rtplan.dcm" ] && prefix "$pydicom/rtplan.dcm" 0 "$seeds/fuzz_rt_objects/rtplan"
[ -f "$pydicom/rtstruct.dcm" ] && prefix "$pydicom/rtstruct.dcm" 1 "$seeds/fuzz_rt_objects/rtstruct"

# Operator commands.
for c in "resume 417263" "stop" "reset 1" "status" "quit" "resume"; do printf '%s\n' "$c" > "$seeds/fuzz_commands/$(echo "$c" | tr ' ' _)"; done

# Modbus replies (fuzz/fuzz_modbus.cpp's script format): a couch that answers every request
# well, one that answers with an exception, one whose reply is cut short, one that goes silent.
python3 - "$seeds/fuzz_modbus" <<'PY'
import struct, sys
out = sys.argv[1]
def reply(pdu, flags=3, unit=1):
    adu = struct.pack('>HHHB', 0, 0, len(pdu) + 1, unit) + pdu
    return bytes([flags, len(adu)]) + adu
def inputs(status=8, ack=0, position=(1000, -2000, 500, 100, -50, 0), target=(1000, -2000, 500, 100, -50, 0)):
    regs = [status, ack, 0]
    for v in list(position) + list(target):
        b = struct.unpack('>HH', struct.pack('>i', v))
        regs += list(b)
    return reply(bytes([4, 2 * len(regs)]) + struct.pack('>%dH' % len(regs), *regs))
write_holding = reply(bytes([16, 0, 0, 0, 14]))
write_control = reply(bytes([6, 0, 13, 0, 2]))
# calls byte: read back, command, hold, read back = 0b11_10_01_00
calls = bytes([0b11100100])
seeds = {
    'good-couch': calls + inputs() + inputs() + write_holding + write_control + inputs(ack=1),
    'exception': calls + inputs() + inputs() + reply(bytes([0x90, 3])) + write_control + inputs(),
    'short-reply': calls + inputs() + inputs()[:20],
    'silent': calls + inputs() + bytes([8, 0]) + inputs(),
    'moving-fault': bytes([0]) + inputs() + inputs(status=3, ack=7, position=(2**31 - 1, -2**31, 0, 0, 0, 0)),
}
for name, data in seeds.items():
    open(out + '/' + name, 'wb').write(data)
PY

# V4L2 devices (fuzz/fuzz_v4l2.cpp reads its answers in call order): short seeds whose bytes
# mostly say "succeed"; the fuzzer grows them into devices that open and hand buffers over.
python3 - "$seeds/fuzz_v4l2" <<'PY'
import os, sys
out = sys.argv[1]
for n, size in enumerate([16, 64, 256, 1024]):
    open('%s/device-%d' % (out, n), 'wb').write(bytes((7 * i + n) % 200 for i in range(size)))
PY

for t in "$seeds"/*; do echo "$(basename "$t"): $(ls "$t" | wc -l) seeds" >&2; done

#!/usr/bin/env bash
# Installs every build, test and peer dependency of lftrack from Debian's packages.
# Non-interactive and idempotent: it asks apt only for what is missing, so a second run takes
# well under a second. Nothing is downloaded from anywhere but the Debian archive.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config
  libeigen3-dev libceres-dev            # geometry, least squares
  libdcmtk-dev                          # DICOM series (reader)
  libgdcm-dev                           # DICOM writing in tests
  libnifti2-dev                         # NIfTI-1/2 (nifti_clib)
  libyaml-cpp-dev libcli11-dev libspdlog-dev nlohmann-json3-dev
  libpng-dev libtiff-dev zlib1g-dev     # image output
  libmodbus-dev                         # couch driver (Modbus TCP/RTU)
  libaravis-dev                         # GigE Vision detectors and the fake GigE camera (Aravis 0.8)
  libusb-1.0-0-dev                      # aravis-0.8.pc requires libusb-1.0, which libaravis-dev does not pull in
  libgtest-dev libgmock-dev libbenchmark-dev
  plastimatch                           # independent reference DRR generator
  gnuplot-nox                           # plots of studies (PNG)
  stress-ng                             # a loaded core for the real-time loop benchmark
  slurmctld slurmd slurm-client munge   # a local Slurm cluster for job-array studies (scripts/slurm-local.sh)
  libcpp-httplib-dev                    # the monitor page's embedded HTTP server
  libopenigtlink-dev                    # OpenIGTLink server for navigation software (3D Slicer, PLUS)
  dicom3tools                           # dciodvfy: validates the exported DICOM registration and test RT objects
  python3-pydicom                       # its RT Plan / Structure Set test files: foreign input in tests
  chromium chromium-driver              # the monitor page tested in a real headless browser
  debhelper lintian help2man fakeroot   # `make deb`: the Debian package, its checks, its man pages
  systemd                               # systemd-analyze verify checks the package's units
  rt-tests                              # cyclictest, beside `lftrack rt-check` (BENCHMARKS.md)
)
# `scripts/setup.sh --fuzz` (make fuzz) adds clang with libFuzzer and its sanitizer runtimes.
if [ "${1:-}" = "--fuzz" ]; then
  packages+=(clang libclang-rt-dev)
fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ "${#missing[@]}" -eq 0 ]; then
  echo "setup: all ${#packages[@]} packages present"
  exit 0
fi

echo "setup: installing ${missing[*]}"
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "setup: not root and no sudo; install: ${missing[*]}" >&2; exit 1; }
  sudo_cmd=(sudo)
fi
export DEBIAN_FRONTEND=noninteractive
"${sudo_cmd[@]}" apt-get update -qq
"${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "setup: done"

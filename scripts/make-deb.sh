#!/usr/bin/env bash
# `make deb` (issue 59): lftrack_VERSION_amd64.deb from the Release build that `make check` built
# and tested, with debhelper (debian/rules), then checked by lintian. The package is assembled in
# OUT_DIR/src (a copy of debian/ and the scene the package installs as configuration), never in
# the source tree, so a test can make one beside other tests.
#   scripts/make-deb.sh [BUILD_DIR [OUT_DIR]]     defaults: build, out/deb
# Prints the .deb's path on its last line. Fails (exit 1) on a build, version or lintian problem.
set -euo pipefail
source_dir=$(cd "$(dirname "$0")/.." && pwd)
build_dir=$(realpath -m "${1:-$source_dir/build}")
out_dir=$(realpath -m "${2:-$source_dir/out/deb}")
fail() { echo "make-deb: $*" >&2; exit 1; }

for tool in dpkg-buildpackage dh lintian help2man fakeroot; do
  command -v "$tool" >/dev/null || fail "$tool is missing: run scripts/setup.sh (it installs debhelper, lintian, help2man)"
done
program="$build_dir/bin/lftrack"
[ -x "$program" ] || fail "no program at $program: build it first (make build)"
[ -f "$build_dir/cmake_install.cmake" ] ||
  fail "$build_dir is no CMake build folder (no cmake_install.cmake): configure and build it (make build)"
[ ! -e "$out_dir" ] || [ -d "$out_dir" ] || fail "$out_dir exists and is not a folder"
mkdir -p "$out_dir" 2>/dev/null && [ -w "$out_dir" ] || fail "$out_dir: cannot write the package there"

# The package's version is the changelog's; it must be the program's (CMakeLists.txt project()).
program_version=$("$program" --version | awk '{print $2}')
package_version=$(dpkg-parsechangelog -l "$source_dir/debian/changelog" -S Version)
[ "$program_version" = "$package_version" ] ||
  fail "debian/changelog says $package_version, the program says $program_version: add a changelog entry (dch -v $program_version)"

# A fresh assembly folder; the .deb and lintian's report of an earlier run are replaced.
work="$out_dir/src"
rm -rf "$work"
mkdir -p "$work"
cp -r "$source_dir/debian" "$work/debian"
rm -rf "$work/debian/lftrack" "$work/debian/.debhelper" "$work/debian/man" "$work/debian/files"
mkdir -p "$work/scenes"
cp "$source_dir/scenes/qa-phantom.yaml" "$work/scenes/"

echo "make-deb: packaging $program ($program_version) in $work"
(cd "$work" && LFTRACK_BUILD_DIR="$build_dir" LFTRACK_SOURCE_DIR="$source_dir" \
   dpkg-buildpackage -b -us -uc --no-pre-clean --no-post-clean -rfakeroot >"$out_dir/build.log" 2>&1) ||
  { tail -n 30 "$out_dir/build.log" >&2; fail "dpkg-buildpackage failed (whole log: $out_dir/build.log)"; }

deb="$out_dir/lftrack_${package_version}_amd64.deb"
[ -f "$deb" ] || fail "dpkg-buildpackage made no $deb (log: $out_dir/build.log)"

# Lintian: no error and no warning; an override (debian/lftrack.lintian-overrides) says why.
if ! lintian --fail-on error,warning --display-info "$deb" >"$out_dir/lintian.txt" 2>&1; then
  cat "$out_dir/lintian.txt" >&2
  fail "lintian found errors or warnings in $deb (report: $out_dir/lintian.txt)"
fi
echo "lintian $(lintian --version | awk '{print $2}'): no error or warning" >>"$out_dir/lintian.txt"
echo "make-deb: lintian: no error or warning; its notes in $out_dir/lintian.txt"
echo "$deb"

#!/usr/bin/env bash
# Man pages from the commands' own help (help2man): lftrack(1), and lftrack-COMMAND(1) for each
# command `lftrack --help` lists. Used by the Debian package (debian/rules); the help text is the
# one source, so the pages never disagree with the program.
#   scripts/make-man-pages.sh BIN OUT_DIR
set -euo pipefail
bin=${1:?usage: make-man-pages.sh BIN OUT_DIR}
out=${2:?usage: make-man-pages.sh BIN OUT_DIR}
[ -x "$bin" ] || { echo "make-man-pages: $bin is not an executable" >&2; exit 1; }
command -v help2man >/dev/null || { echo "make-man-pages: help2man is missing (scripts/setup.sh installs it)" >&2; exit 1; }
mkdir -p "$out"

# The commands and their one-line descriptions: the lines under "Subcommands:" in the help.
mapfile -t commands < <("$bin" --help | awk '/^Subcommands:/ {on = 1; next} on && /^  [a-z]/ {print $1}')
[ "${#commands[@]}" -gt 0 ] || { echo "make-man-pages: $bin --help lists no commands" >&2; exit 1; }

include=$(mktemp)
trap 'rm -f "$include"' EXIT
{
  echo '[SEE ALSO]'
  last=${commands[-1]}
  for c in "${commands[@]}"; do echo ".BR lftrack-$c (1)$([ "$c" = "$last" ] || echo ,)"; done
} >"$include"

help2man --no-info --section 1 --include "$include" \
  --name "real-time patient tracking for image-guided radiosurgery" "$bin" >"$out/lftrack.1"

for c in "${commands[@]}"; do
  # The description up to its first full stop or parenthesis, as a man page's NAME line.
  description=$("$bin" "$c" --help | head -n 1 | sed -e 's/ (.*//' -e 's/[.;:].*//')
  page="$out/lftrack-$c.1"
  printf '[SEE ALSO]\n.BR lftrack (1)\n' >"$include"
  help2man --no-info --section 1 --include "$include" --help-option "$c --help" --version-option --version \
    --name "$description" "$bin" >"$page"
  # help2man names the page after the program; this page is the command's.
  upper=$(echo "lftrack-$c" | tr '[:lower:]' '[:upper:]')
  sed -i -e "s/^\\.TH LFTRACK /.TH $upper /" -e "/^\\.SH NAME/{n;s/^lftrack /lftrack-$c /}" "$page"
done
echo "make-man-pages: $((${#commands[@]} + 1)) pages in $out"

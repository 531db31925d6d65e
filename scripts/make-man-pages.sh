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
# help2man runs the program through the shell, unquoted: it gets a name without spaces.
link_dir=$(mktemp -d)
trap 'rm -rf "$include" "$link_dir"' EXIT
ln -s "$(realpath "$bin")" "$link_dir/lftrack"
bin="$link_dir/lftrack"
{
  echo '[SEE ALSO]'
  last=${commands[-1]}
  for c in "${commands[@]}"; do echo ".BR lftrack-$c (1)$([ "$c" = "$last" ] || echo ,)"; done
} >"$include"

help2man --no-info --section 1 --include "$include" \
  --name "real-time patient tracking for image-guided radiosurgery" "$bin" >"$out/lftrack.1"

# One page: `lftrack WORDS --help` as lftrack-WORDS(1) (WORDS: a command, or a command and its
# subcommand, e.g. "qa daily" -> lftrack-qa-daily).
pages=1
page_of() {
  local words="$1" name="lftrack-${1// /-}" see="$2"
  local description page upper
  # The description up to its first full stop or parenthesis, as a man page's NAME line. sed reads
  # the whole help (no `head`): a reader that stops early makes a long help's writer die of SIGPIPE,
  # which pipefail turns into this script's failure (`sim --help` outgrew the pipe's first write).
  description=$("$bin" $words --help | sed -n -e '1{s/ (.*//' -e 's/[.;:].*//' -e 'p' -e '}')
  page="$out/$name.1"
  printf '[SEE ALSO]\n.BR %s (1)\n' "$see" >"$include"
  help2man --no-info --section 1 --include "$include" --help-option "$words --help" --version-option --version \
    --name "$description" "$bin" >"$page"
  # help2man names the page after the program; this page is the command's.
  upper=$(echo "$name" | tr '[:lower:]' '[:upper:]')
  sed -i -e "s/^\\.TH LFTRACK /.TH $upper /" -e "/^\\.SH NAME/{n;s/^lftrack /$name /}" "$page"
  pages=$((pages + 1))
}
for c in "${commands[@]}"; do
  page_of "$c" lftrack
  # A command with subcommands (qa daily, study trade, ...): a page for each, whose options the
  # command's own page does not list.
  mapfile -t subcommands < <("$bin" "$c" --help | awk '/^Subcommands:/ {on = 1; next} on && /^  [a-z]/ {print $1}')
  for sub in "${subcommands[@]}"; do page_of "$c $sub" "lftrack-$c"; done
done
echo "make-man-pages: $pages pages in $out"

#!/usr/bin/env bash
# The configuration reference in the docs is generated from the parameter
# table (server/sim/params.c) by build/gen-config-doc (scripts/gen-config-doc.c).
#
#   scripts/gen-config-doc.sh GEN            print the reference (Markdown)
#   scripts/gen-config-doc.sh --update GEN   rewrite it in the doc (make config-doc)
#   scripts/gen-config-doc.sh --check GEN    exit 1, with a diff, if the doc disagrees
#   scripts/gen-config-doc.sh --doc-path     print the doc's path (for tests)
#   ... --doc FILE                           use FILE as the doc (tests)
#   ... --daemon BIN                         add the daemon's own options, read
#                                            from `BIN --help` (its option table)
#
# The doc is docs/configuration.md (DOC below); everything between its markers
#   <!-- config-reference -->  ...  <!-- /config-reference -->
# is generated. The README links to it.
set -euo pipefail
cd "$(dirname "$0")/.."
DOC=docs/configuration.md
if [ "${1:-}" = --doc-path ]; then echo "$DOC"; exit 0; fi
mode=print doc= daemon=
while [ $# -gt 1 ]; do
  case $1 in
    --update|--check) mode=${1#--}; shift ;;
    --doc) doc=$2; shift 2 ;;
    --daemon) daemon=$2; shift 2 ;;
    *) break ;;
  esac
done
gen=${1:?usage: gen-config-doc.sh [--update|--check] [--doc FILE] path/to/gen-config-doc}
begin='<!-- config-reference -->'
end='<!-- /config-reference -->'

# The daemon's options, from the "Daemon options:" part of its --help:
#   "  --port (default "8080")" then "      TCP port ..." on the next line.
daemon_table() {
  echo
  echo "Daemon options (command line, or the same names with underscores in the \`--config\` JSON file):"
  echo
  echo "| option | default | description |"
  echo "|---|---|---|"
  "$daemon" --help | awk '
    /^Daemon options:/ { on = 1; next }
    on && /^$/ { on = 0 }
    on && /^  --/ {
      line = substr($0, 3); def = "–"
      if (match(line, / \(default ".*"\)$/)) {
        def = substr(line, RSTART + 11, RLENGTH - 13); line = substr(line, 1, RSTART - 1)
        def = (def == "") ? "(none)" : "`" def "`"
      }
      opt = line; next
    }
    on && /^      / && opt != "" {
      desc = $0; sub(/^ +/, "", desc); gsub(/\|/, "\\|", desc)
      printf "| `%s` | %s | %s |\n", opt, def, desc; opt = ""
    }'
}

want=$("$gen")
if [ -n "$daemon" ]; then want+=$'\n'$(daemon_table); fi
if [ "$mode" = print ]; then printf '%s\n' "$want"; exit 0; fi

[ -n "$doc" ] || doc=$DOC
if ! grep -qF -- "$begin" "$doc" || ! grep -qF -- "$end" "$doc"; then
  echo "gen-config-doc: $doc has no '$begin' ... '$end' markers" >&2
  exit 1
fi

# The lines strictly between the markers.
have=$(awk -v b="$begin" -v e="$end" 'index($0,e){inside=0} inside{print} index($0,b){inside=1}' "$doc")

if [ "$mode" = check ]; then
  if [ "$have" != "$want" ]; then
    echo "gen-config-doc: the configuration reference in $doc disagrees with the parameter table" >&2
    diff <(printf '%s\n' "$have") <(printf '%s\n' "$want") | head -40 >&2 || true
    echo "gen-config-doc: run 'make config-doc' to regenerate it" >&2
    exit 1
  fi
  echo "gen-config-doc: $doc agrees with the parameter table${daemon:+ and the daemon options}"
  exit 0
fi

tmp=$(mktemp "$doc.XXXXXX")
WANT=$want awk -v b="$begin" -v e="$end" 'BEGIN { want = ENVIRON["WANT"] }
  index($0,b) { print; print want; skip=1; next }
  index($0,e) { skip=0 }
  !skip { print }' "$doc" > "$tmp"
cat "$tmp" > "$doc" && rm -f "$tmp"
echo "gen-config-doc: updated $doc"

#!/usr/bin/env bash
# test-blender: the Blender add-on (tools/blender/oceand_bake.py) in Debian's
# Blender, headless, against a real oceand with its default 3 cascades (N = 128):
# ocean-tap bakes the summed sea, Blender installs the add-on through its add-on
# preferences (into a temporary user folder), imports the bake, and the evaluated
# vertices are compared with the daemon's exact surface (`query`) at each frame's
# sim time: within 25 mm rms. Then one step of Live.
# Usage: tests/blender/run.sh BUILD_DIR    (run by `make test-blender` from the repo root)
set -uo pipefail
BUILD=${1:-build}
tmp=$(mktemp -d)
DAEMON_LOG=$tmp/oceand.log
. tests/tap/lib.sh
trap 'stop_daemons; rm -rf "$tmp"' EXIT

command -v blender >/dev/null || fail "blender is not installed (make deps installs it: scripts/apt-packages.txt)"
port=$(free_port)
URL=ws://127.0.0.1:$port
# N = 128 at 10 ticks a second: the bake (6 fields lossless + 2 finer cascades) then
# stays inside the encode budget (samples per tick, measured at start-up) of a loaded
# machine, which refuses a subscription beyond it; a long query window keeps every bake
# frame's sim time answerable however long the machine takes between bake and check.
start_daemon "$port" --port "$port" --bind 127.0.0.1 --state-file "$tmp/state.json" \
  --web-root "$BUILD/web" --resolution 128 --cascades 3 --tick-rate 10 --query-window 60 \
  || fail "oceand did not start"

# The daemon plans its exact evaluator at the first query: not between the bake and its check.
"$BUILD/ocean-tap" "$URL" --query "0,0" >/dev/null || fail "warm-up query"
section "bake 4 frames of the whole sea (3 cascades summed), lossless"
# --intra: the temporal codec costs the server more per sample; a bake of six fields and
# the finer cascades would be served degraded on a loaded machine, stretching the bake.
"$BUILD/ocean-tap" "$URL" --frames 4 --bound 0 --intra --cascades all --format exr --out "$tmp/bake" \
  >"$tmp/tap.log" 2>&1 || fail "ocean-tap bake failed: $(cat "$tmp/tap.log")"
# Frozen from now on, so that every frame's sim time stays inside the query window.
"$BUILD/ocean-tap" "$URL" --set paused=true >/dev/null || fail "pause"
ls "$tmp"/bake/vdisp_0004.exr >/dev/null || fail "bake incomplete: $(ls "$tmp/bake")"
ok "$(ls "$tmp"/bake/*.exr | wc -l) EXR files"

section "Blender $(blender -b --factory-startup --version 2>/dev/null | head -n 1 | cut -d' ' -f2): add-on, import, compare with query"
BLENDER_USER_SCRIPTS=$tmp/user/scripts BLENDER_USER_CONFIG=$tmp/user/config \
  blender -b --factory-startup --python-exit-code 1 --python tests/blender/check_blender.py -- \
  tools/blender/oceand_bake.py "$tmp/bake" "$URL" "$tmp/result.json" >"$tmp/blender.log" 2>&1 \
  || fail "Blender check failed: $(tail -n 30 "$tmp/blender.log")"
/usr/bin/python3 - "$tmp/result.json" <<'PY' || fail "bad result: $(cat "$tmp/result.json")"
import json, sys
r = json.load(open(sys.argv[1]))
assert r["ok"], r
for k in ("frame_1", "frame_4"):
    print(f"  {k}: vertex height {r[k]['height_rms_mm']:.2f} mm rms (max {r[k]['height_max_mm']:.2f}), "
          f"horizontal {r[k]['source_rms_mm']:.2f} mm rms of query")
print(f"  live: {r['live']['height_rms_mm']:.2f} mm rms (1 mm bound on every cascade)")
PY
ok "the imported bake is the sea of query within 25 mm rms at frames 1 and 4; Live writes the sea"
finish_ok

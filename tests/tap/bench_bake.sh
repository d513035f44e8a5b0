#!/usr/bin/env bash
# bench-tap-bake: ocean-tap baking from the live stream (--format exr), N = 256,
# the default 3 cascades, 240 frames: one JSON line per configuration with wall
# frames per second, ocean-tap's CPU per frame, and the ticks it skipped (seq
# gaps: a bake's frames are the ticks it received). Exact-time bakes (--bake)
# need the server's render request; until then this measures the stream path.
# The daemon gets a fixed encode budget: the one it derives from its start-up
# measurement serves a loaded machine's bake degraded, and this measures ocean-tap.
# Usage: tests/tap/bench_bake.sh BUILD_DIR [FRAMES]
set -uo pipefail
BUILD=${1:-build}
FRAMES=${2:-240}
tmp=$(mktemp -d)
DAEMON_LOG=$tmp/oceand.log
. "$(dirname "$0")/lib.sh"
trap 'stop_daemons; rm -rf "$tmp"' EXIT
port=$(free_port)
start_daemon "$port" --port "$port" --bind 127.0.0.1 --state-file none --web-root "$BUILD/web" \
  --resolution 256 --cascades 3 --encode-budget 2000000 >&2 || fail "oceand did not start"
URL=ws://127.0.0.1:$port
bake() {   # bake NAME ARGS...
  local name=$1; shift
  rm -rf "$tmp/bake"
  /usr/bin/time -f '%e %U %S' -o "$tmp/time" "$BUILD/ocean-tap" "$URL" --frames "$FRAMES" --bound 0 --intra --timeout 30 \
    --format exr --out "$tmp/bake" "$@" >"$tmp/tap.log" 2>&1 || fail "$name: $(tail -n 3 "$tmp/tap.log")"
  /usr/bin/python3 - "$name" "$tmp/bake" "$tmp/time" "$*" <<'PY'
import glob, json, sys
name, d, tf, args = sys.argv[1:5]
wall, user, sys_ = map(float, open(tf).read().split())
m = [json.load(open(f)) for f in sorted(glob.glob(d + "/frame_*.json"))]
seqs = [x["seq"] for x in m]
skipped = sum(b - a - 1 for a, b in zip(seqs, seqs[1:]))
print(json.dumps({"bench": "tap_bake", "config": name, "args": args, "n": m[0]["n"], "side": m[0]["side"],
                  "cascades": m[0]["cascades"], "frames": len(m), "wall_s": wall, "fps": round(len(m) / wall, 2),
                  "cpu_ms_per_frame": round((user + sys_) * 1e3 / len(m), 2),
                  "ticks_skipped": skipped, "ticks_spanned": seqs[-1] - seqs[0] + 1,
                  "sim_s": round(m[-1]["sim_time"] - m[0]["sim_time"], 4)}))
PY
}
bake cascade0
bake summed --cascades all

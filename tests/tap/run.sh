#!/usr/bin/env bash
# test-tap: ocean-tap and the Python example against a real oceand.
# Usage: tests/tap/run.sh BUILD_DIR    (run by `make test-tap` from the repo root)
set -uo pipefail
BUILD=${1:-build}
PY=/usr/bin/python3
TAP=$BUILD/ocean-tap
EXAMPLE=proto/examples/ocean_stats.py
tmp=$(mktemp -d)
DAEMON_LOG=$tmp/oceand.log
. "$(dirname "$0")/lib.sh"
trap 'stop_daemons; rm -rf "$tmp"' EXIT

N=128
port=$(free_port)
URL=ws://127.0.0.1:$port
start_daemon "$port" --port "$port" --bind 127.0.0.1 --state-file "$tmp/state.json" \
  --web-root "$BUILD/web" --resolution $N || fail "oceand did not start"

# run EXPECTED_RC LABEL CMD... : run, keep stdout/stderr in $tmp/out, $tmp/err.
run() {
  local want=$1 label=$2; shift 2
  "$@" >"$tmp/out" 2>"$tmp/err"
  local rc=$?
  [ "$rc" -eq "$want" ] || fail "$label: exit $rc, expected $want
  command: $*
  stdout: $(head -c 600 "$tmp/out")
  stderr: $(head -c 600 "$tmp/err")"
}
# json_get FILE EXPR : evaluate a Python expression on the JSON document j.
json_get() { $PY -c 'import json,sys; j=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))' "$1" "$2"; }

section "command line and connection errors"
run 1 "no URL" "$TAP"
run 1 "bad --lod" "$TAP" "$URL" --lod 9
run 1 "bad --fields" "$TAP" "$URL" --fields height,nope
run 1 "bad --set" "$TAP" "$URL" --set wind_speed
run 0 "--help" "$TAP" --help
grep -q 'Exit codes' "$tmp/out" || fail "--help does not document the exit codes"
closed=$(free_port)
run 2 "nothing listening" "$TAP" "ws://127.0.0.1:$closed" --timeout 3
grep -q 'cannot connect' "$tmp/err" || fail "connect failure message missing: $(cat "$tmp/err")"
run 5 "unwritable --out" "$TAP" "$URL" --frames 1 --out /dev/null/x
ok "usage (1), connect (2) and output (5) errors"

section "hello"
run 0 "hello" "$TAP" "$URL"
cp "$tmp/out" "$tmp/hello.json"
[ "$(json_get "$tmp/hello.json" 'j["protocol"]')" = 1 ] || fail "hello.protocol is not 1"
[ "$(json_get "$tmp/hello.json" 'j["params"]["resolution"]')" = $N ] || fail "hello does not report resolution $N"
ok "ocean-tap prints the hello as JSON"

section "frames in every format"
run 0 "npy frames" "$TAP" "$URL" --frames 3 --fields height,dx,dz --lod 1 --bound 0.001 --out "$tmp/npy" --format npy
$PY - "$tmp/npy" $((N / 2)) <<'EOF' || fail "npy output is wrong"
import glob, os, sys
import numpy as np
d, side = sys.argv[1], int(sys.argv[2])
files = sorted(glob.glob(os.path.join(d, "*.npy")))
seqs = {os.path.basename(f).split("-")[1] for f in files}
assert len(seqs) == 3, f"expected 3 frames, got seqs {sorted(seqs)}"
for s in seqs:
    arrays = {}
    for field in ("height", "dx", "dz"):
        a = np.load(os.path.join(d, f"{field}-{s}"))
        assert a.dtype == np.float32 and a.shape == (side, side), (field, a.dtype, a.shape)
        assert np.isfinite(a).all(), f"{field} has non-finite samples"
        assert a.std() > 0, f"{field} is constant"
        arrays[field] = a
    assert not np.array_equal(arrays["height"], arrays["dx"]), "height and dx are the same data"
print(f"  {len(files)} files, {len(seqs)} frames of 3 fields, {side}x{side} float32")
EOF
run 0 "raw frame" "$TAP" "$URL" --frames 1 --fields height --bound 0 --out "$tmp/raw" --format raw
f32=$(ls "$tmp"/raw/height-*.f32) || fail "no raw file"
[ "$(stat -c %s "$f32")" -eq $((N * N * 4)) ] || fail "raw file has $(stat -c %s "$f32") bytes, expected $((N * N * 4))"
side=$(json_get "${f32%.f32}.json" 'j["shape"][0]')
seq=$(json_get "${f32%.f32}.json" 'j["seq"]')
[ "$side" = $N ] || fail "sidecar shape $side, expected $N"
[ "$(basename "$f32")" = "$(printf 'height-%08d.f32' "$seq")" ] || fail "sidecar seq $seq does not match $(basename "$f32")"
for fmt in pgm pgm8; do
  run 0 "$fmt frame" "$TAP" "$URL" --frames 1 --fields jacobian --lod 2 --max-rate 10 --out "$tmp/$fmt" --format $fmt
  pgm=$(ls "$tmp"/$fmt/jacobian-*.pgm) || fail "no $fmt file"
  maxval=$([ $fmt = pgm ] && echo 65535 || echo 255); bpp=$([ $fmt = pgm ] && echo 2 || echo 1)
  $PY - "$pgm" $((N / 4)) $maxval $bpp <<'EOF' || fail "$fmt output is wrong"
import sys
path, side, maxval, bpp = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
data = open(path, "rb").read()
lines = data.split(b"\n", 4)
assert lines[0] == b"P5" and lines[1].startswith(b"# min="), lines[:2]
assert lines[2] == f"{side} {side}".encode() and lines[3] == str(maxval).encode(), lines[2:4]
assert len(lines[4]) == side * side * bpp, len(lines[4])
px = [int.from_bytes(lines[4][k:k + bpp], "big") for k in range(0, len(lines[4]), bpp)]
assert min(px) == 0 and max(px) == maxval, (min(px), max(px))   # normalised min..max
EOF
done
ok "npy (3 frames x 3 fields, LOD 1), raw + sidecar, pgm 16-bit and 8-bit"

section "metadata of every format matches the frame headers"
# Headers recorded by an independent client (the Python example decoder) at
# the same time as ocean-tap writes every format; a set first makes
# params_version non-zero.
run 0 "set before the metadata check" "$TAP" "$URL" --set amplitude=1.1
$PY tests/tap/frame_headers.py "$URL" 6 "$tmp/headers.jsonl" &
rec_pid=$!
sleep 0.8
for fmt in npy raw pgm pgm8; do
  run 0 "$fmt metadata" "$TAP" "$URL" --frames 3 --fields height,dz --lod 2 --out "$tmp/meta-$fmt" --format $fmt
done
run 0 "exr metadata" "$TAP" "$URL" --frames 2 --lod 1 --out "$tmp/meta-exr" --format exr
wait $rec_pid || fail "frame_headers.py failed"
$PY tests/tap/check_meta.py "$tmp/headers.jsonl" "$BUILD/exr-read" "$tmp"/meta-{npy,raw,pgm,pgm8,exr} \
  || fail "ocean-tap's metadata disagrees with the frame headers"
ok "npy, raw, pgm, pgm8 sidecars, PGM comments and EXR attributes carry the frame's seq, sim_time, params_version"

section "EXR bake (Blender ocean modifier layout) round trip"
# Both clients at once, lossless: the npy run starts first and is stopped
# (SIGINT, exit 130) only after the bake is done. On a loaded machine both skip
# ticks, each its own, and may share no seq: the sea is paused, so that a bake
# frame can also be checked against an npy frame of the same sim_time.
run 0 "pause for the round trip" "$TAP" "$URL" --set paused=true
"$TAP" "$URL" --frames 600 --bound 0 --fields height,dx,dz,slope_x,slope_z,jacobian --out "$tmp/rt-npy" \
  >"$tmp/rt.out" 2>&1 &
rt_pid=$!
for _ in $(seq 100); do ls "$tmp"/rt-npy/jacobian-*.npy >/dev/null 2>&1 && break; sleep 0.1; done
run 0 "exr bake" "$TAP" "$URL" --frames 4 --bound 0 --out "$tmp/rt-exr" --format exr
sleep 0.3
kill -INT $rt_pid 2>/dev/null
rt_rc=0; wait $rt_pid || rt_rc=$?
[ $rt_rc = 130 ] || [ $rt_rc = 0 ] || fail "npy run for the round trip failed ($rt_rc): $(cat "$tmp/rt.out")"
ls "$tmp"/rt-exr/{disp,normal,foam}_0001.exr >/dev/null || fail "bake files missing: $(ls "$tmp/rt-exr")"
$PY tests/tap/check_exr.py "$tmp/rt-npy" "$tmp/rt-exr" "$BUILD/exr-read" || fail "EXR bake differs from the streamed fields"
run 0 "resume after the round trip" "$TAP" "$URL" --set paused=false
ok "disp/normal/foam_NNNN.exr read back with OpenEXR equal the streamed fields at the same seq (half precision)"

section "memory checks (valgrind)"
if command -v valgrind >/dev/null; then
  VG="valgrind -q --error-exitcode=99 --leak-check=full --errors-for-leak-kinds=definite,indirect"
  # One run through every code path that allocates: set, subscribe, frames, stats, files,
  # the finer cascades and their sum (FFTW).
  run 0 "ocean-tap under valgrind" $VG "$TAP" "$URL" --set amplitude=1 --frames 2 --fields height,jacobian \
    --lod 1 --bound 0.001 --out "$tmp/vg" --format raw --stats --cascades all --sum 48 --sum-area 3,4,50
  run 0 "ocean-tap --format exr under valgrind" $VG "$TAP" "$URL" --frames 2 --lod 2 --out "$tmp/vg-exr" --format exr
  ok "no memory errors or leaks in ocean-tap (set, frames, stats, raw output, EXR bake, cascades and their sum)"
else
  echo "  skip: valgrind not installed"
fi

section "--stats"
run 0 "stats" "$TAP" "$URL" --frames 5 --fields height --stats
line=$(grep '^frames=' "$tmp/out") || fail "no summary line: $(cat "$tmp/out")"
$PY - "$line" <<'EOF' || fail "bad stats line: $line"
import sys
kv = dict(p.split("=") for p in sys.argv[1].split())
assert int(kv["frames"]) == 5 and float(kv["fps"]) > 0 and int(kv["bytes"]) > 0, kv
for k in ("latency_ms_p50", "latency_ms_p95", "latency_ms_max", "mbit_per_s"):
    float(kv[k])
EOF
ok "$line"

section "--set and --watch"
"$TAP" "$URL" --watch >"$tmp/watch.out" 2>"$tmp/watch.err" &
watch_pid=$!
# The watcher has to be connected before the change; retry until it sees one.
seen=0
for i in 1 2 3 4 5 6 7 8 9 10; do
  run 0 "set choppiness" "$TAP" "$URL" --set choppiness=$((i % 2)).5   # alternates: always a change
  grep -q '"choppiness"' "$tmp/watch.out" && { seen=1; break; }
  sleep 0.3
done
[ $seen = 1 ] || fail "--watch printed no params broadcast: $(cat "$tmp/watch.out" "$tmp/watch.err")"
kill -INT $watch_pid; wait $watch_pid; rc=$?
[ $rc -eq 0 ] || fail "--watch exited $rc after Ctrl-C: $(cat "$tmp/watch.err")"
$PY - "$tmp/watch.out" <<'EOF' || fail "--watch output is not params JSON lines"
import json, sys
msgs = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
assert msgs and all(m["type"] == "params" for m in msgs), msgs
assert any("choppiness" in m["changed"] for m in msgs), msgs
EOF
run 0 "set two parameters" "$TAP" "$URL" --set wind_speed=20 --set spectrum=phillips
grep -Eq '^params_version=[0-9]+ changed=.*wind_speed' "$tmp/out" && grep -q 'spectrum' "$tmp/out" \
  || fail "set did not report both changes: $(cat "$tmp/out")"
run 0 "hello after set" "$TAP" "$URL"
[ "$(json_get "$tmp/out" 'j["params"]["wind_speed"]')" = 20 ] || fail "wind_speed is not 20 after set"
[ "$(json_get "$tmp/out" 'j["params"]["spectrum"]')" = phillips ] || fail "spectrum is not phillips after set"
run 4 "out of range" "$TAP" "$URL" --set wind_speed=1000
grep -q 'out_of_range' "$tmp/err" && grep -q 'wind_speed' "$tmp/err" || fail "no out_of_range/wind_speed in: $(cat "$tmp/err")"
run 4 "unknown parameter" "$TAP" "$URL" --set no_such_thing=1
grep -q 'unknown_param' "$tmp/err" || fail "no unknown_param in: $(cat "$tmp/err")"
run 4 "bad enum" "$TAP" "$URL" --set spectrum=bogus
run 4 "all or nothing" "$TAP" "$URL" --set wind_speed=5 --set no_such_thing=1
run 0 "hello after rejects" "$TAP" "$URL"
[ "$(json_get "$tmp/out" 'j["params"]["wind_speed"]')" = 20 ] || fail "a rejected set changed wind_speed"
ok "--watch sees changes; --set applies (0) and reports rejections with the server's code (4)"

section "Python example: its decoder against the shared test vectors"
$PY tests/tap/test_oceanproto.py proto/vectors || fail "the Python decoder disagrees with proto/vectors"

section "Python example decodes exactly what ocean-tap decodes"
run 0 "pause" "$TAP" "$URL" --set paused=true
# compare LOD BOUND : run both clients at once so they receive the same frames.
compare() {
  local lod=$1 bound=$2 a=$tmp/cmp-tap-$1-$2 b=$tmp/cmp-py-$1-$2
  # Python starts slower (numpy import): give it a head start for more common frames.
  # --max-rate 10: numpy keeps up, so neither client misses a tick of the shared stream and
  # resubscribes (that client's next tiles would be keyframes, not the other's predicted ones).
  $PY "$EXAMPLE" "$URL" --frames 8 --fields height,dx,dz,jacobian --lod "$lod" --bound "$bound" --max-rate 10 \
    --save "$b" >"$tmp/py.out" 2>&1 &
  local pp=$!
  sleep 0.3
  "$TAP" "$URL" --frames 8 --fields height,dx,dz,jacobian --lod "$lod" --bound "$bound" --max-rate 10 --out "$a" >"$tmp/tap.out" 2>&1
  local trc=$?
  wait $pp; local prc=$?
  [ $trc -eq 0 ] || fail "ocean-tap (lod $lod, bound $bound) exited $trc: $(cat "$tmp/tap.out")"
  [ $prc -eq 0 ] || fail "$EXAMPLE (lod $lod, bound $bound) exited $prc: $(cat "$tmp/py.out")"
  $PY - "$a" "$b" <<'EOF' || fail "Python and C decoders disagree (lod $lod, bound $bound)
  ocean-tap: $(tail -n 4 "$tmp/tap.out")
  Python: $(grep -v '^seq ' "$tmp/py.out" | tail -n 4)"
import glob, os, sys
import numpy as np
a, b = sys.argv[1], sys.argv[2]
ta = {os.path.basename(f) for f in glob.glob(a + "/*.npy")}
tb = {os.path.basename(f) for f in glob.glob(b + "/*.npy")}
common = sorted(ta & tb)
if not common:
    # The sea is paused, so every frame is the same: compare the last of each.
    last = lambda names, field: max(n for n in names if n.startswith(field + "-"))
    pairs = [(last(ta, f), last(tb, f)) for f in ("height", "dx", "dz", "jacobian")]
else:
    pairs = [(n, n) for n in common]
for na, nb in pairs:
    x, y = np.load(os.path.join(a, na)), np.load(os.path.join(b, nb))
    assert x.dtype == y.dtype == np.float32 and x.shape == y.shape, (na, x.dtype, x.shape, y.dtype, y.shape)
    if not np.array_equal(x.view(np.uint32), y.view(np.uint32)):
        diff = np.abs(x.astype(np.float64) - y)
        # Which rows and columns differ (tiles are square blocks of the grid), and every
        # field of that seq: a decoder bug shows in one codec path, a stream bug in tiles.
        rows, cols = np.nonzero(diff)
        others = [f"{f}: {np.count_nonzero(np.load(os.path.join(a, f + na[na.index('-'):])) != np.load(os.path.join(b, f + nb[nb.index('-'):])))}"
                  for f in ("height", "dx", "dz", "jacobian")
                  if os.path.exists(os.path.join(a, f + na[na.index('-'):])) and os.path.exists(os.path.join(b, f + nb[nb.index('-'):]))]
        sys.exit(f"{na}: {np.count_nonzero(diff)} samples differ, max {diff.max()}; rows {rows.min()}-{rows.max()}, "
                 f"columns {cols.min()}-{cols.max()} of {x.shape}; samples differing per field at this seq: {', '.join(others)}; "
                 f"seqs compared: {[p[0] for p in pairs]}")
print(f"  {len(pairs)} field arrays bit-identical ({len(pairs) // 4} frames with the same seq)" if common
      else f"  {len(pairs)} field arrays bit-identical (no common seq; same paused sea)")
EOF
}
compare 0 0
compare 1 0.001
compare 2 0.05
grep -q 'height' "$tmp/py.out" || fail "the example prints no statistics: $(cat "$tmp/py.out")"

# Lossy vs lossless of the same paused sea: the Python decoder honours the bound.
"$TAP" "$URL" --frames 1 --fields height --bound 0 --out "$tmp/exact" >/dev/null 2>&1 || fail "lossless frame"
$PY "$EXAMPLE" "$URL" --frames 1 --fields height --bound 0.005 --save "$tmp/lossy" >/dev/null 2>&1 || fail "example, bound 0.005"
$PY - "$tmp/exact" "$tmp/lossy" 0.005 <<'EOF' || fail "the Python decoder exceeds the error bound"
import glob, sys
import numpy as np
x = np.load(glob.glob(sys.argv[1] + "/height-*.npy")[0]).astype(np.float64)
y = np.load(glob.glob(sys.argv[2] + "/height-*.npy")[0]).astype(np.float64)
err = np.abs(x - y).max()
# bound, plus float32 rounding of the reconstruction
assert err <= float(sys.argv[3]) * (1 + 1e-6) + np.abs(x).max() * 2**-23, err
print(f"  max |lossy - lossless| = {err:.6f} <= 0.005")
EOF
# The finer cascades: per-cascade files, and their sum against the exact surface (query).
# This daemon runs N = 128 and the default 3 cascades; the sea is still paused.
run 0 "cascades + sum" "$TAP" "$URL" --frames 1 --bound 0 --cascades all --sum $N --fields height,dx,dz --out "$tmp/sum"
for f in height dx dz; do
  ls "$tmp"/sum/$f-c1-*.npy "$tmp"/sum/$f-c2-*.npy "$tmp"/sum/$f-sum-*.npy >/dev/null || fail "no $f cascade/sum files: $(ls "$tmp/sum")"
done
[ "$(json_get "$(ls "$tmp"/sum/height-c1-*.json)" 'j["cascade"]')" = 1 ] || fail "cascade 1's sidecar does not say cascade 1"
$PY tests/tap/check_sum.py "$URL" "$tmp/sum" 0.001 || fail "the summed grid is off query at its nodes"
run 0 "sum anywhere" "$TAP" "$URL" --frames 1 --bound 0 --cascades all --sum 150 --sum-area -37.3,12.1,100 \
  --fields height,dx,dz --out "$tmp/sum-area"
$PY tests/tap/check_sum.py "$URL" "$tmp/sum-area" 0.005 || fail "the summed grid is off query between nodes"
run 0 "sum bilinear" "$TAP" "$URL" --frames 1 --bound 0 --cascades all --sum 150 --sum-area -37.3,12.1,100 \
  --fields height,dx,dz --interp bilinear --out "$tmp/sum-bil"
$PY tests/tap/check_sum.py "$URL" "$tmp/sum-bil" 1 0.002 || fail "bilinear is not measurably off: the check is blind"
run 1 "--sum without --cascades" "$TAP" "$URL" --frames 1 --sum 64
ok "--cascades all: c1/c2 files; --sum on cascade 0's nodes and on another grid within 1 and 5 mm of query"
# ocean_stats.py --save writes ocean-tap's sidecar beside each .npy
f=$(ls "$tmp"/lossy/height-*.npy | head -n 1)
[ "$(json_get "${f%.npy}.json" 'j["seq"]')" = "$((10#$(basename "$f" .npy | cut -d- -f2)))" ] \
  || fail "ocean_stats.py --save: no sidecar with the seq of $f"
run 0 "ocean_stats.py --cascades" $PY "$EXAMPLE" "$URL" --frames 1 --fields height --lod 1 --bound 0.001 --cascades
grep -Eq 'sum of 3 cascades: height std [0-9.]+ \(cascade 0 off it by [0-9.]+ mm rms\)' "$tmp/out" \
  || fail "ocean_stats.py --cascades prints no summed sea: $(cat "$tmp/out")"
ok "ocean_stats.py --save writes the sidecar; --cascades sums the finer cascades"
run 0 "resume" "$TAP" "$URL" --set paused=false
ok "lossless and lossy (LOD 0/1/2) frames identical in both decoders; bound honoured"

section "--query and --probe"
run 1 "bad --query points" "$TAP" "$URL" --query "1;2"
run 1 "--query with frames" "$TAP" "$URL" --query "1,2" --frames 1
run 0 "query" "$TAP" "$URL" --query "1.5,-2;1e6,-3e6"
$PY - "$tmp/out" <<'EOF' || fail "--query output is not a query_result"
import json, math, sys
j = json.loads(open(sys.argv[1]).read())
assert j["type"] == "query_result" and len(j["points"]) == 2, j
for p in j["points"]:
    assert abs(math.hypot(*p["normal"]) - 1) < 1e-9 and abs(p["height"]) < 20, p
    for k in ("displacement", "vertical_velocity", "vertical_acceleration"):
        assert k in p, k
EOF
run 4 "query outside the window" "$TAP" "$URL" --query "1,2" --time -100
grep -q 'time_out_of_window' "$tmp/err" || fail "no time_out_of_window in: $(cat "$tmp/err")"
run 0 "probe json" "$TAP" "$URL" --probe "1.5,-2;40,7" --ticks 5
$PY - "$tmp/out" <<'EOF' || fail "--probe output is not one probe_data line per tick"
import json, sys
lines = [json.loads(l) for l in open(sys.argv[1])]
assert len(lines) == 5, len(lines)
seqs = [l["seq"] for l in lines]
assert all(b > a for a, b in zip(seqs, seqs[1:])), seqs
assert all(l["type"] == "probe_data" and len(l["points"]) == 2 and len(l["points"][0]) == 8 for l in lines)
EOF
run 0 "probe csv" "$TAP" "$URL" --probe "1.5,-2;40,7" --ticks 3 --csv
[ "$(head -n 1 "$tmp/out")" = "seq,sim_time,params_version,point,x,z,height,dx,dz,nx,ny,nz,vertical_velocity,vertical_acceleration" ] \
  || fail "--csv: no header row: $(head -n 1 "$tmp/out")"
[ "$(wc -l <"$tmp/out")" -eq 7 ] || fail "--csv: expected a header and 3 ticks x 2 points rows: $(cat "$tmp/out")"
[ "$(awk -F, '{print NF}' "$tmp/out" | sort -u)" = 14 ] || fail "--csv rows do not have 14 columns"
run 4 "probe over the limit" "$TAP" "$URL" --probe "$(for i in $(seq 1 17); do printf '%d,0;' $i; done | sed 's/;$//')"
grep -q 'too_many_points' "$tmp/err" || fail "no too_many_points in: $(cat "$tmp/err")"
ok "--query prints query_result (errors: 4 with the code), --probe one line per tick (JSON or CSV)"

section "Python examples: buoy (probes) and ship (a body on the shared sea)"
run 0 "buoy" timeout 60 $PY proto/examples/buoy.py "$URL" --seconds 3
$PY - "$tmp/out" <<'EOF' || fail "buoy.py output: $(cat "$tmp/out")"
import json, sys
j = json.loads(open(sys.argv[1]).read().strip().splitlines()[-1])
assert j["points"] == 9 and j["samples"] >= 60 and j["frames"] >= 5, j
assert 0.5 < j["ratio"] < 2 and j["hs_sea_m"] > 0, j
EOF
run 0 "ship --help" $PY proto/examples/ship.py --help
grep -q 'Ctrl-C (or the end of --seconds) removes the ship' "$tmp/out" || fail "ship.py --help is cut short: $(cat "$tmp/out")"
run 0 "ship" timeout 30 $PY proto/examples/ship.py "$URL" --seconds 2.5 --course 45 --key-file "$tmp/ship.key"
[ "$(grep -c '^ *[0-9]' "$tmp/out")" -ge 2 ] || fail "ship.py: expected 2+ motion lines: $(cat "$tmp/out")"
grep -q '^ship: removed body' "$tmp/out" || fail "ship.py did not remove its ship: $(cat "$tmp/out")"
ok "buoy.py compares its Hs with the sea's; ship.py sails a ship each second, removed at the end (test-tap-bodies: more)"

section "--bake: exact-time frames through the render request (oceand, and a stand-in server)"
run 1 "--bake without --fps" "$TAP" "$URL" --bake --start 0 --frames 2 --out "$tmp/bk"
run 4 "--bake over --render-max-units" "$TAP" "$URL" --bake --fps 24 --start 1 --frames 100000 --out "$tmp/bk"
grep -q 'render rejected: error bad_render' "$tmp/err" || fail "--bake refused: $(cat "$tmp/err")"
run 0 "--bake against oceand" "$TAP" "$URL" --bake --fps 24 --start 12.5 --frames 7 --bound 0 --cascades all \
  --format exr --out "$tmp/bake-oceand"
$PY - "$tmp/bake-oceand" <<'EOF2' || fail "--bake against oceand: output"
import glob, json, os, sys
d = sys.argv[1]
metas = sorted(glob.glob(os.path.join(d, "frame_*.json")))
assert len(metas) == 7, "%d frames written, asked for 7" % len(metas)
for k, f in enumerate(metas):
    m = json.load(open(f))
    assert m["frame"] == k + 1 and m["seq"] == k and abs(m["sim_time"] - (12.5 + k / 24)) <= 1e-6, m
    for kind in ("disp", "normal", "foam", "vdisp"):
        assert os.path.exists(os.path.join(d, "%s_%04d.exr" % (kind, k + 1))), (kind, k)
assert len(glob.glob(os.path.join(d, "*.exr"))) == 28, "EXR files: %d" % len(glob.glob(os.path.join(d, "*.exr")))
print("  7 frames at 12.5 + k/24 s, 4 EXR files each, nothing more")
EOF2
ok "--bake against oceand writes exactly K frames at T + k/F; a refused render exits 4"
fport=$(free_port)
$PY tests/tap/fake_render.py "$fport" "$tmp/render.json" &
fake_pid=$!
for _ in $(seq 50); do (exec 3<>/dev/tcp/127.0.0.1/$fport) 2>/dev/null && break; sleep 0.1; done
run 0 "--bake" "$TAP" "ws://127.0.0.1:$fport" --bake --fps 24 --start 100.5 --frames 5 --bound 0 \
  --cascades all --format exr --out "$tmp/bake-exact"
wait $fake_pid || fail "the stand-in server failed"
$PY - "$tmp/render.json" "$tmp/bake-exact" <<'EOF2' || fail "--bake output"
import json, os, sys
req, d = json.load(open(sys.argv[1])), sys.argv[2]
assert req["type"] == "render" and (req["start"], req["fps"], req["frames"]) == (100.5, 24, 5), req
assert len(req["cascades"]) == 2 and req["bound"] == 0 and "temporal" not in req, req
for k in range(5):
    m = json.load(open(os.path.join(d, f"frame_{k + 1:04d}.json")))
    assert m["seq"] == k and abs(m["sim_time"] - (100.5 + k / 24)) < 1e-9 and m["cascades"] == 3, m
    assert os.path.exists(os.path.join(d, f"vdisp_{k + 1:04d}.exr"))
assert not os.path.exists(os.path.join(d, "frame_0006.json")), "the live frame was written"
print("  5 frames at 100.5 + k/24 s, numbered 1..5; the live frame between them left out")
EOF2
ok "--bake sends render (start, fps, frames, fields, cascades), writes every rendered frame at its exact time"

section "control token, timeouts and a server that goes away"
silent=$(free_port)
# A TCP listener that accepts and never answers the WebSocket handshake.
$PY -c 'import socket, sys, time
s = socket.socket(); s.bind(("127.0.0.1", int(sys.argv[1]))); s.listen(1)
c, _ = s.accept(); time.sleep(5)' "$silent" &
silent_pid=$!
sleep 0.3
run 6 "silent server" "$TAP" "ws://127.0.0.1:$silent" --timeout 1
grep -q 'timed out' "$tmp/err" || fail "no timeout message: $(cat "$tmp/err")"
kill $silent_pid 2>/dev/null; wait $silent_pid 2>/dev/null
port2=$(free_port)
start_daemon "$port2" --port "$port2" --state-file none --resolution 64 --control-token s3cret \
  || fail "second oceand did not start"
run 4 "set without the control token" "$TAP" "ws://127.0.0.1:$port2" --set wind_speed=5
grep -q 'forbidden' "$tmp/err" || fail "no forbidden in: $(cat "$tmp/err")"
run 0 "set with --token" "$TAP" "ws://127.0.0.1:$port2" --token s3cret --set wind_speed=5
"$TAP" "ws://127.0.0.1:$port2" --frames 0 --fields height >"$tmp/out" 2>"$tmp/err" &
stream_pid=$!
sleep 0.5
kill "${DAEMON_PIDS[-1]}"
wait $stream_pid; rc=$?
[ $rc -eq 7 ] || fail "stream from a daemon that stopped: exit $rc, expected 7: $(cat "$tmp/err")"
ok "control token: without -> 4 forbidden, with --token -> 0; no answer -> 6, server gone mid-stream -> 7"

section "--frames N while the server serves the subscription at a coarser LOD"
# An encode budget of 4.5 N^2 samples: ocean-tap's 4 fields at lod 0 (4 N^2) are admitted;
# a second client's default subscription (3 fields, another bound: 3 N^2) is over it, and
# the plan serves the largest group, ocean-tap's, at lod 1. Its frames are incomplete at
# lod 0, so --frames 1000 gets nowhere: it must give up after --timeout and say why
# (it used to count any message as progress and wait until the server served it again).
port3=$(free_port)
start_daemon "$port3" --port "$port3" --bind 127.0.0.1 --state-file none --resolution 64 \
  --encode-budget $((64 * 64 * 9 / 2)) || fail "third oceand did not start"
"$TAP" "ws://127.0.0.1:$port3" --frames 1000 --fields height,dx,dz,slope_x --bound 0.001 --timeout 3 --stats \
  >"$tmp/out" 2>"$tmp/err" &
tap_pid=$!
# ocean-tap subscribed and writing frames (--stats reports each second) before the second client
for _ in $(seq 100); do grep -q ' frames, ' "$tmp/err" && break; sleep 0.1; done
grep -q ' frames, ' "$tmp/err" || fail "ocean-tap got no frames before the second client: $(cat "$tmp/err")"
PYTHONPATH=proto/examples $PY - "ws://127.0.0.1:$port3" <<'EOF2' &
import asyncio, sys, websockets, oceanproto
async def hold():   # the default subscription, held for 60 s (ocean-tap gives up long before)
    async with websockets.connect(sys.argv[1], subprotocols=[oceanproto.SUBPROTOCOL], max_size=None) as ws:
        end = asyncio.get_running_loop().time() + 60
        while asyncio.get_running_loop().time() < end:
            try:
                await asyncio.wait_for(ws.recv(), 0.5)
            except asyncio.TimeoutError:
                pass
asyncio.run(hold())
EOF2
hold_pid=$!
wait $tap_pid; rc=$?
kill $hold_pid 2>/dev/null; wait $hold_pid 2>/dev/null
[ $rc -eq 6 ] || fail "--frames while degraded: exit $rc, expected 6 (timeout): $(cat "$tmp/err")"
grep -q 'degraded (lod 1' "$tmp/err" || fail "no degraded notice: $(cat "$tmp/err")"
grep -q 'waiting for the next complete frame: the server serves this subscription at lod 1, not the lod 0' "$tmp/err" \
  || fail "the timeout does not say why: $(cat "$tmp/err")"
ok "--frames N at a coarser LOD: exit 6 after --timeout, naming the LOD served"

finish_ok

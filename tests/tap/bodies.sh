#!/usr/bin/env bash
# test-tap-bodies: floating bodies from ocean-tap (--launch/--body/--follow/--bodies,
# tools/tap_body.c) and proto/examples/ship.py against a real oceand (PROTOCOL.md §3.5, §7.6).
# Usage: tests/tap/bodies.sh BUILD_DIR    (run by `make test-tap-bodies` from the repo root)
set -uo pipefail
BUILD=${1:-build}
PY=/usr/bin/python3
TAP=$BUILD/ocean-tap
tmp=$(mktemp -d)
DAEMON_LOG=$tmp/oceand.log
. "$(dirname "$0")/lib.sh"
trap 'stop_daemons; rm -rf "$tmp"' EXIT

port=$(free_port)
URL=ws://127.0.0.1:$port
start_daemon "$port" --port "$port" --bind 127.0.0.1 --state-file "$tmp/state.json" \
  --web-root "$BUILD/web" --resolution 64 --wind-speed 5 || fail "oceand did not start"
# A moderate sea (wind 5 m/s): the bodies heave and roll, and the waves do not yaw a boat
# far off its heading in 5 s (at the default 10 m/s they may, by 15 degrees).

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
# body_listed ID : does --bodies list body ID? Prints its JSON line.
body_line() { "$TAP" "$URL" --bodies | $PY -c 'import json,sys
for l in sys.stdin:
    b = json.loads(l)
    if b["body"] == int(sys.argv[1]): print(l.strip())' "$1"; }

section "command line"
run 1 "--launch without --at" "$TAP" "$URL" --launch boat
run 1 "--throttle out of range" "$TAP" "$URL" --launch boat --at 0,0 --throttle 2
run 1 "--resume without --body" "$TAP" "$URL" --resume 00
run 1 "--follow alone" "$TAP" "$URL" --follow
run 0 "--help" "$TAP" --help
grep -q -- '--launch KIND' "$tmp/out" || fail "--help does not document --launch"
run 4 "unknown kind" "$TAP" "$URL" --launch zeppelin --at 0,0
grep -q unknown_kind "$tmp/err" || fail "unknown kind: no unknown_kind in: $(cat "$tmp/err")"
run 4 "launch outside the world" "$TAP" "$URL" --launch boat --at 1e6,0
grep -q out_of_range "$tmp/err" || fail "outside the world: no out_of_range in: $(cat "$tmp/err")"
run 0 "--bodies on an empty sea" "$TAP" "$URL" --bodies
[ ! -s "$tmp/out" ] || fail "--bodies on an empty sea printed: $(cat "$tmp/out")"
ok "usage errors (1), server refusals (4: unknown_kind, out_of_range), an empty list"

section "launch a boat and follow it under throttle"
"$TAP" "$URL" --launch boat --at 10,-20 --heading 90 --throttle 1 --follow --csv --ticks 150 \
  >"$tmp/follow.csv" 2>"$tmp/follow.err" &
tap_pid=$!
for _ in $(seq 50); do grep -q launched "$tmp/follow.err" && break; sleep 0.1; done
launched=$(grep -m1 '^{"launched"' "$tmp/follow.err") || fail "no launched line: $(cat "$tmp/follow.err")"
id=$(echo "$launched" | $PY -c 'import json,sys; print(json.load(sys.stdin)["launched"])')
owner=$(echo "$launched" | $PY -c 'import json,sys; print(json.load(sys.stdin)["owner"])')
[ -n "$owner" ] || fail "launched line without owner: $launched"
sleep 1
seen=$(body_line "$id")
[ -n "$seen" ] || fail "a second client's --bodies does not list body $id"
echo "$seen" | $PY -c 'import json,sys
b = json.load(sys.stdin)
assert b["kind"] == "boat" and b["owner"] == sys.argv[1] and not b["adrift"], b' "$owner" \
  || fail "the second client sees body $id as $seen, not a boat owned by $owner"
ok "a second client sees body $id, a boat owned by $owner"
wait "$tap_pid"; rc=$?
[ "$rc" -eq 0 ] || fail "follow exited $rc: $(cat "$tmp/follow.err")"
$PY - "$tmp/follow.csv" "$id" <<'EOF' || fail "the followed records are wrong"
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
assert len(rows) == 150, f"{len(rows)} rows, expected 150"
assert all(int(r["id"]) == int(sys.argv[2]) for r in rows), "rows of another body"
seqs = [int(r["seq"]) for r in rows]
assert all(b > a for a, b in zip(seqs, seqs[1:])), "seq not increasing"
v = [float(r["speed"]) for r in rows]
first, last = sum(v[:10]) / 10, sum(v[-10:]) / 10
assert last > first + 0.5 and last > 1.0, f"speed {first:.2f} -> {last:.2f} m/s: the throttle does not push"
hd = [float(r["heading"]) for r in rows]
off = max(abs((h - 90 + 180) % 360 - 180) for h in hd)
assert off < 15, f"heading wanders {off:.1f} degrees off 90 with the rudder amidships"
# Moving toward heading 90 = east = -x: x decreases, z less (the waves push it about).
dx = float(rows[-1]["x"]) - float(rows[0]["x"]); dz = float(rows[-1]["z"]) - float(rows[0]["z"])
assert dx < -1 and abs(dz) < abs(dx), f"moved dx={dx:.2f} dz={dz:.2f}: not east (-x)"
print(f"  ok  150 ticks: speed {first:.2f} -> {last:.2f} m/s, heading within {off:.1f} deg of 90, moved {dx:.1f} m in x")
EOF
[ -z "$(body_line "$id")" ] || fail "body $id is still listed after ocean-tap ended (no --keep)"
ok "the body is removed at the end"

section "ownership: steer another's body, claim with the resume key"
run 0 "launch --keep" "$TAP" "$URL" --launch dinghy --at -5,5 --keep
kid=$($PY -c 'import json,sys; print(json.load(open(sys.argv[1]))["launched"])' "$tmp/out")
key=$($PY -c 'import json,sys; print(json.load(open(sys.argv[1]))["resume"])' "$tmp/out")
[ -n "$(body_line "$kid")" ] || fail "--keep: body $kid is not listed after ocean-tap ended"
run 4 "steer another's body" "$TAP" "$URL" --body "$kid" --throttle 0.5
grep -q not_owner "$tmp/err" || fail "steer of another's body: no not_owner in: $(cat "$tmp/err")"
run 4 "claim with a wrong key" "$TAP" "$URL" --body "$kid" --resume 0123456789abcdef0123456789abcdef
grep -q not_owner "$tmp/err" || fail "wrong key: no not_owner in: $(cat "$tmp/err")"
[ -n "$(body_line "$kid")" ] || fail "a refused steer or claim removed body $kid"
run 4 "steer a body that is not there" "$TAP" "$URL" --body 999999 --throttle 0.5
grep -q no_such_body "$tmp/err" || fail "no such body: $(cat "$tmp/err")"
run 0 "claim with the key, steer, follow 10 ticks" "$TAP" "$URL" --body "$kid" --resume "$key" --throttle 0.3 --follow --ticks 10
[ "$(grep -c '"seq"' "$tmp/out")" -eq 10 ] || fail "claim + follow: expected 10 JSON lines: $(cat "$tmp/out")"
grep -q "\"claimed\":$kid" "$tmp/out" || fail "no claimed line: $(cat "$tmp/out")"
[ -z "$(body_line "$kid")" ] || fail "claimed body $kid is still listed after ocean-tap ended"
ok "steer of another's body: exit 4 not_owner; a wrong key: not_owner; the key claims it and it is removed at the end"

section "proto/examples/ship.py: a ship on the shared sea"
( cd "$tmp" && exec $PY "$OLDPWD/proto/examples/ship.py" "$URL" --kind dinghy --x 30 --z 40 --heading 0 \
    --course 90 --throttle 1 --seconds 8 --name shiptest ) >"$tmp/ship.out" 2>"$tmp/ship.err" &
ship_pid=$!
for _ in $(seq 60); do grep -q 'launched' "$tmp/ship.out" && break; sleep 0.1; done
sid=$(sed -n 's/^ship: launched dinghy body \([0-9]*\)$/\1/p' "$tmp/ship.out")
[ -n "$sid" ] || fail "ship.py did not launch: $(cat "$tmp/ship.out" "$tmp/ship.err")"
[ -f "$tmp/.ship-dinghy.key" ] || fail "ship.py kept no key file"
sleep 1.5
seen=$(body_line "$sid")
[ -n "$seen" ] || fail "another client does not see ship.py's body $sid"
echo "$seen" | grep -q '"name":"shiptest"' || fail "ship.py's body is not named shiptest: $seen"
wait "$ship_pid"; rc=$?
[ "$rc" -eq 0 ] || fail "ship.py exited $rc: $(cat "$tmp/ship.err")"
grep -q "ship: removed body $sid" "$tmp/ship.out" || fail "ship.py did not remove its body: $(cat "$tmp/ship.out")"
[ -z "$(body_line "$sid")" ] || fail "body $sid is still listed after ship.py ended"
[ ! -f "$tmp/.ship-dinghy.key" ] || fail "ship.py left its key file after removing the ship"
$PY - "$tmp/ship.out" <<'EOF' || fail "ship.py's lines are wrong: $(cat "$tmp/ship.out")"
import sys
rows = [l.split() for l in open(sys.argv[1]) if l.split() and l.split()[0].isdigit()]
assert len(rows) >= 5, f"{len(rows)} state lines in 8 s"
speed = [float(r[6]) for r in rows]
assert speed[-1] > speed[0] and speed[-1] > 0.5, f"speeds {speed}"
head = [float(r[7]) for r in rows]
rudder = [float(r[8]) for r in rows]
# Launched bow north, course 90 (east): the controller puts the rudder to starboard
# (+) and the bow turns clockwise toward the course (slowly while it gathers way: ~20 degrees in 8 s).
assert rudder[0] > 0.5, f"rudder {rudder[0]} at 90 degrees off course"
assert 10 < head[-1] < 135, f"headings {head}: the bow does not turn toward the course 90"
print(f"  ok  {len(rows)} lines: speed {speed[0]:.2f} -> {speed[-1]:.2f} m/s, heading {head[0]:.1f} -> {head[-1]:.1f} "
      f"(course 90, rudder {rudder[0]:+.2f})")
EOF
ok "ship.py's body $sid is seen by another client, named, and removed after"

section "Ctrl-C removes the body (ocean-tap --follow, ship.py)"
"$TAP" "$URL" --launch ball --at 1,2 --follow >"$tmp/int.out" 2>"$tmp/int.err" &
tap_pid=$!
for _ in $(seq 50); do grep -q '"seq"' "$tmp/int.out" && break; sleep 0.1; done
bid=$(sed -n 's/^{"launched":\([0-9]*\),.*/\1/p' "$tmp/int.out")
[ -n "$bid" ] && [ -n "$(body_line "$bid")" ] || fail "ocean-tap --follow: no body listed: $(cat "$tmp/int.out" "$tmp/int.err")"
kill -INT "$tap_pid"; wait "$tap_pid"; rc=$?
[ "$rc" -eq 0 ] || fail "Ctrl-C during --follow exited $rc: $(cat "$tmp/int.err")"
[ -z "$(body_line "$bid")" ] || fail "Ctrl-C: ocean-tap left body $bid on the sea"
( cd "$tmp" && exec $PY "$OLDPWD/proto/examples/ship.py" "$URL" --kind spar --seconds 60 ) >"$tmp/ship0.out" 2>&1 &
ship_pid=$!
for _ in $(seq 60); do grep -q '^ *[0-9]' "$tmp/ship0.out" && break; sleep 0.1; done
sid=$(sed -n 's/^ship: launched spar body \([0-9]*\)$/\1/p' "$tmp/ship0.out")
[ -n "$sid" ] || fail "ship.py did not launch: $(cat "$tmp/ship0.out")"
kill -INT "$ship_pid"; wait "$ship_pid"; rc=$?
[ "$rc" -eq 0 ] || fail "ship.py exited $rc on Ctrl-C: $(cat "$tmp/ship0.out")"
grep -q "ship: removed body $sid" "$tmp/ship0.out" || fail "ship.py did not remove body $sid on Ctrl-C: $(cat "$tmp/ship0.out")"
[ -z "$(body_line "$sid")" ] || fail "body $sid is still listed after ship.py's Ctrl-C"
ok "Ctrl-C: ocean-tap exits 0 and removes body $bid; ship.py removes body $sid"

section "ship.py claims its ship back after a restart"
( cd "$tmp" && exec $PY "$OLDPWD/proto/examples/ship.py" "$URL" --kind dinghy --seconds 60 ) \
  >"$tmp/ship1.out" 2>&1 &
ship_pid=$!
for _ in $(seq 60); do grep -q 'launched' "$tmp/ship1.out" && break; sleep 0.1; done
sid=$(sed -n 's/^ship: launched dinghy body \([0-9]*\)$/\1/p' "$tmp/ship1.out")
[ -n "$sid" ] || fail "ship.py did not launch: $(cat "$tmp/ship1.out")"
kill -9 "$ship_pid"; wait "$ship_pid" 2>/dev/null   # killed: no removal, the key file stays
[ -n "$(body_line "$sid")" ] || fail "body $sid gone after ship.py was killed (it should drift, claimable)"
( cd "$tmp" && exec $PY "$OLDPWD/proto/examples/ship.py" "$URL" --kind dinghy --seconds 2 ) >"$tmp/ship2.out" 2>&1 \
  || fail "the restarted ship.py: $(cat "$tmp/ship2.out")"
grep -q "ship: claimed body $sid back" "$tmp/ship2.out" || fail "no claim of body $sid: $(cat "$tmp/ship2.out")"
grep -q "ship: removed body $sid" "$tmp/ship2.out" || fail "the claimed body was not removed: $(cat "$tmp/ship2.out")"
[ -z "$(body_line "$sid")" ] || fail "body $sid is still listed"
ok "a restarted ship.py claims body $sid with its key file, and removes it at the end"
finish_ok

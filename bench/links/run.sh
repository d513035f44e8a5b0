#!/bin/bash
# The link lab: two network namespaces joined by bench/links/shaper (rate,
# one-way delay = RTT/2, loss, drop-tail queue); oceand runs in one, viewers
# (bench/links/viewer.py, the web client's subscription) in the other.
#
#   run.sh OCEAND SHAPER [LINK...]     one JSON object per line and link
# LINK = name:rate_kbit:rtt_ms:loss_pct[:flags], flags a comma list of
#   stall   a 3 s stall at second 10 of the measured window (timeline printed)
#   edge    the viewer connects to `oceand --role edge`, fed by `oceand --role
#           sim` over nats-server, all three in the server's namespace (the
#           sim and nats-server on its loopback); otherwise `--role all`.
# Each row says "role": "all" or "edge". Default: the five links of the
# bench and the stall, with --role all, then the same six through an edge
# (rows named NAME-edge). Needs root (namespaces, TUN), and nats-server for
# the edge rows; without root, prints {"skipped": ...} and exits 0.
# Env: SECONDS_PER_LINK (20), WARMUP (6), VIEWER_ARGS (extra viewer flags),
# OCEAND_ARGS (extra flags of every oceand: all, sim and edge),
# TCP_LOG=DIR (every 0.1 s, the server side's `ss -tin` of the viewer's
# connection, to DIR/NAME.ss: a look at cwnd, bytes in flight and unsent),
# PAGE_SHOT=FILE.png (instead of the viewer, the web page in headless
# chromium, tests/web/link_shot.mjs: a screenshot with the HUD after the
# measured window, and one JSON line; the daemon serves WEB_ROOT, build/web).
set -u
OCEAND=$(readlink -f "$1"); SHAPER=$(readlink -f "$2"); shift 2
HERE=$(dirname "$(readlink -f "$0")")
LINKS=("$@")
BASE=(50M:50000:20:0 10M:10000:50:0 4M:4000:80:1 2M:2000:150:0 1M:1000:300:2 10M-stall:10000:50:0:stall)
if [ ${#LINKS[@]} -eq 0 ]; then
  LINKS=("${BASE[@]}")
  for spec in "${BASE[@]}"; do
    IFS=: read -r name rest <<<"$spec"
    case "$rest" in *:*:*:*) LINKS+=("$name-edge:$rest,edge") ;; *) LINKS+=("$name-edge:$rest:edge") ;; esac
  done
fi
SECS=${SECONDS_PER_LINK:-20}
WARM=${WARMUP:-6}
NATS_BIN=$(command -v nats-server || echo /usr/sbin/nats-server)

if [ "$(id -u)" != 0 ] || ! ip netns add "lnkprobe$$" 2>/dev/null; then
  echo '{"skipped":"the link lab needs root and network namespaces"}'
  exit 0
fi
ip netns del "lnkprobe$$"

A=lnkA$$; B=lnkB$$; NET=10.201.$(( $$ % 200 + 20 ))
SH=; PROCS=(); TMP=$(mktemp -d)
stop_procs() { # the daemons (and nats-server), last started first
  local i
  for (( i=${#PROCS[@]}-1; i>=0; i-- )); do
    kill "${PROCS[i]}" 2>/dev/null && wait "${PROCS[i]}" 2>/dev/null
  done
  PROCS=()
}
cleanup() {
  stop_procs
  [ -n "$SH" ] && kill "$SH" 2>/dev/null && wait "$SH" 2>/dev/null
  ip netns del "$A" 2>/dev/null; ip netns del "$B" 2>/dev/null
  rm -rf "$TMP"
}
trap cleanup EXIT
trap 'exit 130' INT TERM   # (through the EXIT trap: stop everything, not the next link)
ip netns add "$A"; ip netns add "$B"
ip -n "$A" link set lo up; ip -n "$B" link set lo up

# wait_http URL [PYTHON-CONDITION on j, the /healthz JSON]: up to 20 s, from namespace A
wait_http() {
  local cond=${2:-True}
  for _ in $(seq 100); do
    ip netns exec "$A" /usr/bin/python3 -c "import json,sys,urllib.request
j=json.loads(urllib.request.urlopen('$1/healthz',timeout=1).read())
sys.exit(0 if $cond else 1)" 2>/dev/null && return 0
    sleep 0.2
  done
  return 1
}

# start_server ROLE: the daemon(s) the viewer connects to on $NET.1:8090
start_server() {
  local common=(--web-root "${WEB_ROOT:-$TMP/web}" --resolution 256 --plan-rigor 0 --wisdom-file none ${OCEAND_ARGS:-})
  if [ "$1" = all ]; then
    ip netns exec "$A" "$OCEAND" --bind "$NET.1" --port 8090 --state-file "$TMP/state.json" "${common[@]}" \
      >"$TMP/oceand.log" 2>&1 &
    PROCS+=($!)
    wait_http "http://$NET.1:8090"
    return
  fi
  [ -x "$NATS_BIN" ] || { echo "no nats-server" >"$TMP/oceand.log"; return 1; }
  ip netns exec "$A" "$NATS_BIN" -a 127.0.0.1 -p 4222 >"$TMP/nats.log" 2>&1 &
  PROCS+=($!)
  for _ in $(seq 100); do
    ip netns exec "$A" bash -c 'exec 3<>/dev/tcp/127.0.0.1/4222' 2>/dev/null && break
    sleep 0.1
  done
  ip netns exec "$A" "$OCEAND" --role sim --nats nats://127.0.0.1:4222 --bind 127.0.0.1 --port 8091 \
    --state-file "$TMP/state.json" "${common[@]}" >"$TMP/sim.log" 2>&1 &
  PROCS+=($!)
  wait_http "http://127.0.0.1:8091" || return 1
  ip netns exec "$A" "$OCEAND" --role edge --nats nats://127.0.0.1:4222 --bind "$NET.1" --port 8090 \
    --state-file none "${common[@]}" >"$TMP/oceand.log" 2>&1 &
  PROCS+=($!)
  wait_http "http://$NET.1:8090" "j.get('cluster') == 'ok'"
}

for spec in "${LINKS[@]}"; do
  IFS=: read -r name kbit rtt loss flags <<<"$spec"
  flags=",${flags:-},"
  role=all; [[ $flags == *,edge,* ]] && role=edge
  # A drop-tail queue of 100 ms at the link rate (at least 32 kB): a home
  # router's, neither bloated nor starved.
  q=$(( kbit * 1000 / 8 / 10 )); [ $q -lt 32768 ] && q=32768
  "$SHAPER" "$A" "$B" "$kbit" "$((rtt / 2))" "$loss" "$q" >"$TMP/shaper.out" 2>"$TMP/shaper.err" &
  SH=$!
  for _ in $(seq 50); do grep -q ready "$TMP/shaper.out" && break; sleep 0.1; done
  ip -n "$A" addr add "$NET.1" peer "$NET.2" dev lnk0; ip -n "$A" link set lnk0 up mtu 1500
  ip -n "$B" addr add "$NET.2" peer "$NET.1" dev lnk0; ip -n "$B" link set lnk0 up mtu 1500
  if ! start_server "$role"; then
    echo "{\"link\":\"$name\",\"role\":\"$role\",\"error\":\"the server did not start\"}"
    tail -5 "$TMP"/*.log >&2
  else
    extra=()
    bg=()
    if [[ $flags == *,stall,* ]]; then
      extra=(--timeline --rungs)
      ( sleep $((WARM + 10)); kill -USR1 "$SH"; sleep 3; kill -USR1 "$SH" ) &
      bg+=($!)
    fi
    if [ -n "${TCP_LOG:-}" ]; then
      mkdir -p "$TCP_LOG"
      ( end=$(( SECONDS + WARM + SECS + 5 ))
        while [ $SECONDS -lt $end ]; do
          echo "t $(date +%s.%N)"; ip netns exec "$A" ss -tinH state established "( sport = :8090 )"; sleep 0.1
        done ) >"$TCP_LOG/$name.ss" 2>/dev/null &
      bg+=($!)
    fi
    if [ -n "${PAGE_SHOT:-}" ]; then
      ip netns exec "$B" node "$HERE/../../tests/web/link_shot.mjs" --url "http://$NET.1:8090/" --out "$PAGE_SHOT" \
        --seconds "$SECS" || echo "{\"link\":\"$name\",\"role\":\"$role\",\"error\":\"page failed\"}"
    else
      # the set round trip's bound: RTT + 2 ticks (30 Hz) + 50 ms
      ip netns exec "$B" /usr/bin/python3 "$HERE/viewer.py" "ws://$NET.1:8090/" --name "$name" --role "$role" \
        --seconds "$SECS" --warmup "$WARM" --set-bound-ms $((rtt + 117)) "${extra[@]}" ${VIEWER_ARGS:-} ||
        echo "{\"link\":\"$name\",\"role\":\"$role\",\"error\":\"viewer failed\"}"
    fi
    for p in "${bg[@]}"; do kill "$p" 2>/dev/null; done
  fi
  stop_procs
  kill "$SH" 2>/dev/null; wait "$SH" 2>/dev/null; SH=
  wait 2>/dev/null
  rm -f "$TMP/state.json"
done

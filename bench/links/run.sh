#!/bin/bash
# The link lab: two network namespaces joined by bench/links/shaper (rate,
# one-way delay = RTT/2, loss, drop-tail queue); oceand runs in one, viewers
# (bench/links/viewer.py, the web client's subscription) in the other.
#
#   run.sh OCEAND SHAPER [LINK...]     one JSON object per line and link
# LINK = name:rate_kbit:rtt_ms:loss_pct[:stall] ("stall": a 3 s stall at
# second 10 of the measured window, timeline printed). Default: the five
# links of the bench plus the stall. Needs root (namespaces, TUN); without
# it, prints {"skipped": ...} and exits 0.
# Env: SECONDS_PER_LINK (20), WARMUP (6), VIEWER_ARGS (extra viewer flags),
# OCEAND_ARGS (extra daemon flags).
set -u
OCEAND=$(readlink -f "$1"); SHAPER=$(readlink -f "$2"); shift 2
HERE=$(dirname "$(readlink -f "$0")")
LINKS=("$@")
[ ${#LINKS[@]} -eq 0 ] && LINKS=(50M:50000:20:0 10M:10000:50:0 4M:4000:80:1 2M:2000:150:0 1M:1000:300:2 10M-stall:10000:50:0:stall)
SECS=${SECONDS_PER_LINK:-20}
WARM=${WARMUP:-6}

if [ "$(id -u)" != 0 ] || ! ip netns add "lnkprobe$$" 2>/dev/null; then
  echo '{"skipped":"the link lab needs root and network namespaces"}'
  exit 0
fi
ip netns del "lnkprobe$$"

A=lnkA$$; B=lnkB$$; NET=10.201.$(( $$ % 200 + 20 ))
SH=; OC=; TMP=$(mktemp -d)
cleanup() {
  [ -n "$OC" ] && kill "$OC" 2>/dev/null && wait "$OC" 2>/dev/null
  [ -n "$SH" ] && kill "$SH" 2>/dev/null && wait "$SH" 2>/dev/null
  ip netns del "$A" 2>/dev/null; ip netns del "$B" 2>/dev/null
  rm -rf "$TMP"
}
trap cleanup EXIT INT TERM
ip netns add "$A"; ip netns add "$B"
ip -n "$A" link set lo up; ip -n "$B" link set lo up

for spec in "${LINKS[@]}"; do
  IFS=: read -r name kbit rtt loss stall <<<"$spec"
  # A drop-tail queue of 100 ms at the link rate (at least 32 kB): a home
  # router's, neither bloated nor starved.
  q=$(( kbit * 1000 / 8 / 10 )); [ $q -lt 32768 ] && q=32768
  "$SHAPER" "$A" "$B" "$kbit" "$((rtt / 2))" "$loss" "$q" >"$TMP/shaper.out" 2>"$TMP/shaper.err" &
  SH=$!
  for _ in $(seq 50); do grep -q ready "$TMP/shaper.out" && break; sleep 0.1; done
  ip -n "$A" addr add "$NET.1" peer "$NET.2" dev lnk0; ip -n "$A" link set lnk0 up mtu 1500
  ip -n "$B" addr add "$NET.2" peer "$NET.1" dev lnk0; ip -n "$B" link set lnk0 up mtu 1500
  ip netns exec "$A" "$OCEAND" --bind "$NET.1" --port 8090 --state-file "$TMP/state.json" \
    --web-root "$TMP/web" --resolution 256 --plan-rigor 0 --wisdom-file none ${OCEAND_ARGS:-} >"$TMP/oceand.log" 2>&1 &
  OC=$!
  for _ in $(seq 100); do
    ip netns exec "$A" /usr/bin/python3 -c "import urllib.request;urllib.request.urlopen('http://$NET.1:8090/healthz',timeout=1)" 2>/dev/null && break
    sleep 0.2
  done
  extra=()
  if [ "${stall:-}" = stall ]; then
    extra=(--timeline --rungs)
    ( sleep $((WARM + 10)); kill -USR1 "$SH"; sleep 3; kill -USR1 "$SH" ) &
  fi
  ip netns exec "$B" /usr/bin/python3 "$HERE/viewer.py" "ws://$NET.1:8090/" --name "$name" --seconds "$SECS" \
    --warmup "$WARM" "${extra[@]}" ${VIEWER_ARGS:-} || echo "{\"link\":\"$name\",\"error\":\"viewer failed\"}"
  kill "$OC" 2>/dev/null; wait "$OC" 2>/dev/null; OC=
  kill "$SH" 2>/dev/null; wait "$SH" 2>/dev/null; SH=
  wait 2>/dev/null
done

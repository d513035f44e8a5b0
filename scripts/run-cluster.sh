#!/usr/bin/env bash
# run-cluster.sh — nats-server with JetStream (its file store in
# build/run-cluster/js, configured by build/run-cluster/nats.conf written
# here), two `oceand --role sim` (the first active, the second its hot
# standby: kill -9 the active one and the standby takes over) and two
# `--role edge` on loopback (docs/scaling.md); Ctrl-C stops them all.
# `make run-cluster` installs nats-server first if it is missing (scripts/deps.sh).
# Ports: NATS_PORT (4222), SIM_PORTS ("8090 8091"), EDGE_PORTS ("8081 8082");
# extra daemon flags in OCEAND_ARGS (e.g. "--resolution 512").
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${BUILD:-build}
NATS_PORT=${NATS_PORT:-4222}
SIM_PORTS=${SIM_PORTS:-"${SIM_PORT:-8090} 8091"}
EDGE_PORTS=${EDGE_PORTS:-"8081 8082"}
NATS_BIN=$(command -v nats-server || echo /usr/sbin/nats-server)
RUN=$BUILD/run-cluster
mkdir -p "$RUN"
pids=()
keep=()   # nats-server and the edges: the run ends when one of them exits (a sim may be killed and restarted)
cleanup() {
  trap - INT TERM EXIT
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  echo "run-cluster: stopped"
}
trap "cleanup; exit 0" INT TERM
trap cleanup EXIT
wait_http() {
  for _ in $(seq 200); do curl -fs "http://127.0.0.1:$1/healthz" >/dev/null 2>&1 && return 0; sleep 0.05; done
  echo "run-cluster: nothing answers on port $1 (see $RUN/*.log)" >&2; return 1
}

# JetStream keeps the active sim's lease and the sea's state (a KV bucket in a
# file store): what a standby takes over from, and what survives a kill -9.
cat >"$RUN/nats.conf" <<EOF
# written by scripts/run-cluster.sh
listen: 127.0.0.1:$NATS_PORT
jetstream {
  store_dir: "$PWD/$RUN/js"
}
EOF
"$NATS_BIN" -c "$RUN/nats.conf" >"$RUN/nats.log" 2>&1 & pids+=($!); keep+=($!)
for _ in $(seq 100); do (exec 3<>/dev/tcp/127.0.0.1/"$NATS_PORT") 2>/dev/null && break; sleep 0.05; done
URL=nats://127.0.0.1:$NATS_PORT
for p in $SIM_PORTS; do
  # shellcheck disable=SC2086
  "$BUILD/oceand" --role sim --nats "$URL" --port "$p" --state-file "$RUN/sim-$p-state.json" \
    --web-root "$BUILD/web" ${OCEAND_ARGS:-} >"$RUN/sim-$p.log" 2>&1 & pids+=($!)
  wait_http "$p"
done
for p in $EDGE_PORTS; do
  # shellcheck disable=SC2086
  "$BUILD/oceand" --role edge --nats "$URL" --port "$p" --state-file none --web-root "$BUILD/web" \
    ${OCEAND_ARGS:-} >"$RUN/edge-$p.log" 2>&1 & pids+=($!); keep+=($!)
done
for p in $EDGE_PORTS; do wait_http "$p"; done
echo "run-cluster: nats-server  nats://127.0.0.1:$NATS_PORT   (log $RUN/nats.log)"
for p in $SIM_PORTS; do
  echo "run-cluster: sim          http://127.0.0.1:$p/healthz  /metrics   (\"lease\": active or standby; log $RUN/sim-$p.log)"
done
for p in $EDGE_PORTS; do
  echo "run-cluster: edge         http://127.0.0.1:$p/   (web client; log $RUN/edge-$p.log)"
done
echo "run-cluster: Ctrl-C stops all"
wait -n "${keep[@]}" || true
echo "run-cluster: a process exited; stopping the rest" >&2

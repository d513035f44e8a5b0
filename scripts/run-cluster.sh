#!/usr/bin/env bash
# run-cluster.sh — nats-server, one `oceand --role sim` and two `--role edge`
# on loopback (docs/scaling.md); Ctrl-C stops them all. `make run-cluster`
# installs nats-server first if it is missing (scripts/deps.sh).
# Ports: NATS_PORT (4222), SIM_PORT (8090), EDGE_PORTS ("8081 8082"); extra
# daemon flags in OCEAND_ARGS (e.g. "--resolution 512").
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${BUILD:-build}
NATS_PORT=${NATS_PORT:-4222}
SIM_PORT=${SIM_PORT:-8090}
EDGE_PORTS=${EDGE_PORTS:-"8081 8082"}
NATS_BIN=$(command -v nats-server || echo /usr/sbin/nats-server)
RUN=$BUILD/run-cluster
mkdir -p "$RUN"
pids=()
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

"$NATS_BIN" -a 127.0.0.1 -p "$NATS_PORT" >"$RUN/nats.log" 2>&1 & pids+=($!)
for _ in $(seq 100); do (exec 3<>/dev/tcp/127.0.0.1/"$NATS_PORT") 2>/dev/null && break; sleep 0.05; done
URL=nats://127.0.0.1:$NATS_PORT
# shellcheck disable=SC2086
"$BUILD/oceand" --role sim --nats "$URL" --port "$SIM_PORT" --state-file "$RUN/sim-state.json" \
  --web-root "$BUILD/web" ${OCEAND_ARGS:-} >"$RUN/sim.log" 2>&1 & pids+=($!)
wait_http "$SIM_PORT"
for p in $EDGE_PORTS; do
  # shellcheck disable=SC2086
  "$BUILD/oceand" --role edge --nats "$URL" --port "$p" --state-file none --web-root "$BUILD/web" \
    ${OCEAND_ARGS:-} >"$RUN/edge-$p.log" 2>&1 & pids+=($!)
done
for p in $EDGE_PORTS; do wait_http "$p"; done
echo "run-cluster: nats-server  nats://127.0.0.1:$NATS_PORT   (log $RUN/nats.log)"
echo "run-cluster: sim          http://127.0.0.1:$SIM_PORT/healthz  /metrics   (log $RUN/sim.log)"
for p in $EDGE_PORTS; do
  echo "run-cluster: edge         http://127.0.0.1:$p/   (web client; log $RUN/edge-$p.log)"
done
echo "run-cluster: Ctrl-C stops all"
wait -n "${pids[@]}" || true
echo "run-cluster: a process exited; stopping the rest" >&2

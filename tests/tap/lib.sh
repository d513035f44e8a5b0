# tests/tap/lib.sh — helpers shared by tests/tap/*.sh (sourced; the caller
# sets $BUILD, and $DAEMON_LOG, the file that receives the daemon's output).
# Messages: "  ok  ..." per check, "FAIL: ..." and exit 1 on the first failure.

section() { echo "-- $* [${SECONDS}s]"; }
ok() { echo "  ok  $*"; }
fail() { echo "FAIL: $*" >&2; exit 1; }
finish_ok() { echo "PASS: $(basename "$0")"; exit 0; }

# A TCP port nobody listens on right now.
free_port() {
  /usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'
}

DAEMON_PIDS=()
# start_daemon PORT ARGS... : run $BUILD/oceand ARGS in the background and
# wait (up to 15 s) until /healthz answers on PORT. Returns 1, printing the
# daemon's log, if it exits or never answers.
start_daemon() {
  local port=$1; shift
  "$BUILD/oceand" "$@" >"${DAEMON_LOG:?}" 2>&1 &
  local pid=$!
  DAEMON_PIDS+=("$pid")
  for _ in $(seq 150); do
    if ! kill -0 "$pid" 2>/dev/null; then
      echo "oceand exited early; its log:" >&2; cat "$DAEMON_LOG" >&2; return 1
    fi
    curl -fsS -o /dev/null "http://127.0.0.1:$port/healthz" 2>/dev/null && return 0
    sleep 0.1
  done
  echo "oceand did not answer /healthz on port $port; its log:" >&2; cat "$DAEMON_LOG" >&2
  return 1
}

# Stop every daemon started by start_daemon (by pid) and wait for it.
stop_daemons() {
  local pid
  for pid in "${DAEMON_PIDS[@]}"; do
    kill "$pid" 2>/dev/null
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null
    wait "$pid" 2>/dev/null
  done
  DAEMON_PIDS=()
}

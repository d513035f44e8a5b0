#!/usr/bin/env bash
# test-python: the Python package proto/python, installed offline with pip into a
# venv (Debian's numpy, websockets, setuptools; nothing fetched), against a real
# oceand with its default 3 cascades at N = 256.
# Usage: tests/tap/package.sh BUILD_DIR    (run by `make test-python` from the repo root)
set -uo pipefail
BUILD=${1:-build}
PY=/usr/bin/python3
tmp=$(mktemp -d)
DAEMON_LOG=$tmp/oceand.log
. "$(dirname "$0")/lib.sh"
trap 'stop_daemons; rm -rf "$tmp"' EXIT

section "pip install ./proto/python, offline"
# A copy, so the build leaves nothing in the source tree. Plain `pip install` in a
# virtual environment that sees Debian's numpy and websockets, with no index at all.
cp -r proto/python "$tmp/src"
# --without-pip: Debian's pip, seen through the system site packages, installs into the
# venv (copying a pip into it would take longer than the rest of the suite).
$PY -m venv --system-site-packages --without-pip "$tmp/venv" >"$tmp/venv.log" 2>&1 \
  || fail "python3 -m venv: $(cat "$tmp/venv.log")"
"$tmp/venv/bin/python" -m pip install --no-index "$tmp/src" >"$tmp/pip.log" 2>&1 \
  || fail "pip install failed: $(tail -n 20 "$tmp/pip.log")"
site=$("$tmp/venv/bin/python" -c 'import oceand, os; print(os.path.dirname(os.path.dirname(oceand.__file__)))') \
  || fail "the venv cannot import oceand"
[ -f "$site/oceand/client.py" ] || fail "pip installed no oceand package into $site"
ok "pip install --no-index into a venv over Debian's numpy and websockets: $site"

# A long query window: a loaded machine may take seconds between a frame and its check.
# 10 ticks a second: 3 lossless fields of 3 cascades at N = 256 stay inside the encode
# budget (samples per tick, measured at start-up) of a loaded machine, which refuses more.
port=$(free_port)
start_daemon "$port" --port "$port" --bind 127.0.0.1 --state-file "$tmp/state.json" \
  --web-root "$BUILD/web" --resolution 256 --cascades 3 --tick-rate 10 --query-window 60 \
  || fail "oceand did not start"
section "the package against the daemon"
"$tmp/venv/bin/python" tests/tap/test_package.py "ws://127.0.0.1:$port" "$site" || fail "test_package.py"
finish_ok

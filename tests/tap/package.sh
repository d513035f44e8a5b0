#!/usr/bin/env bash
# test-python: the Python package proto/python, installed offline with pip
# (Debian's numpy, websockets, setuptools; nothing fetched), against a real
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
# A copy, so the build leaves nothing in the source tree.
cp -r proto/python "$tmp/src"
$PY -m pip install --no-deps --no-build-isolation --no-index --target "$tmp/site" "$tmp/src" \
  >"$tmp/pip.log" 2>&1 || fail "pip install failed: $(tail -n 20 "$tmp/pip.log")"
[ -f "$tmp/site/oceand/client.py" ] || fail "pip installed no oceand package: $(ls "$tmp/site")"
ok "installed into a fresh directory with --no-index"

port=$(free_port)
start_daemon "$port" --port "$port" --bind 127.0.0.1 --state-file "$tmp/state.json" \
  --web-root "$BUILD/web" --resolution 256 --cascades 3 || fail "oceand did not start"
section "the package against the daemon"
$PY tests/tap/test_package.py "ws://127.0.0.1:$port" "$tmp/site" || fail "test_package.py"
finish_ok

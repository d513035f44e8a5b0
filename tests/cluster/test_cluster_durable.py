#!/usr/bin/python3
"""Durability and versions across crashes (docs/scaling.md "Failure model").

No acknowledged `set` is lost by a kill -9 of any process; params_version never goes
back and is never reused; edges notice a restarted sim and tell their clients. Each
test starts its own nats-server (and daemons) on 127.0.0.1, as test_cluster_roles.py.
    /usr/bin/python3 tests/cluster/test_cluster_durable.py --oceand build/oceand [--cycles 3]
Prints "N passed, M failed" last.
"""
import argparse
import asyncio
import json
import os
import shutil
import signal
import sys
import tempfile
import time
import traceback

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "daemon"))
import test_cluster_roles as cr  # noqa: E402
import test_daemon as td  # noqa: E402
from test_cluster_roles import Cluster, Node, wait_for, expect_status  # noqa: E402
from test_daemon import TestFailure, check, connect, recv_json, recv_frame  # noqa: E402

ARGS = None
TESTS = []


def test(fn):
    TESTS.append(fn)
    return fn


def with_cluster(**kw):
    def deco(fn):
        def run():
            c = Cluster(**kw)
            ok = False
            try:
                fn(c)
                ok = True
            finally:
                c.close(failed=not ok)
        run.__name__ = fn.__name__
        return run
    return deco


def read_state(path):
    with open(path) as f:
        return json.load(f)


async def set_and_ack(ws, i, wind):
    """One set; its `params` (the ack) or error."""
    await ws.send(json.dumps({"type": "set", "id": i, "params": {"wind_speed": wind}}))
    return await recv_json(ws, lambda m: m["type"] in ("params", "error") and m.get("id") == i, timeout=10)


# ---------------------------------------------------------------- tests

@test
def test_role_all_kill9_right_after_an_acknowledged_set():
    """--role all: kill -9 as soon as the set's `params` arrives; the restarted daemon
    has the set in force, at the version acknowledged (the save happens before the ack)."""
    tmp = tempfile.mkdtemp(prefix="oceand-durable-")
    cr.ARGS = ARGS
    d = Node(tmp, "all")
    ok = False
    try:
        for k in range(ARGS.cycles):
            async def run():
                ws, h = await connect(d)
                p = await set_and_ack(ws, 1, 7.25 + k)
                check(p["type"] == "params", "set: %r" % p)
                d.proc.send_signal(signal.SIGKILL)   # no chance to save on the way out
                return p["params_version"]
            v = asyncio.run(run())
            d.kill()
            d.start()

            async def after():
                ws, h = await connect(d)
                check(h["params"]["wind_speed"] == 7.25 + k and h["params_version"] == v,
                      "after kill -9: wind %r version %r, acknowledged %r version %d"
                      % (h["params"]["wind_speed"], h["params_version"], 7.25 + k, v))
                fh, _ = await recv_frame(ws)
                check(fh["params_version"] == v, "frame version %r after restart, want %d" % (fh["params_version"], v))
                await ws.close()
            asyncio.run(after())
        ok = True
    finally:
        rc = d.kill(signal.SIGTERM)
        if not ok or rc != 0:
            print("--- log:\n%s" % d.read_log())
        shutil.rmtree(tmp, ignore_errors=True)
    check(rc == 0, "daemon exited %r" % rc)


@test
def test_a_set_that_cannot_be_saved_is_refused():
    """The state file cannot be written (its folder is gone): the set is answered
    `internal` (not saved), nothing changes, and the daemon keeps serving."""
    tmp = tempfile.mkdtemp(prefix="oceand-durable-")
    cr.ARGS = ARGS
    sub = os.path.join(tmp, "state")
    os.mkdir(sub)
    d = Node(tmp, "all", state_file=os.path.join(sub, "state.json"))
    ok = False
    try:
        async def run():
            ws, h = await connect(d)
            shutil.rmtree(sub)
            m = await set_and_ack(ws, 3, 9.5)
            check(m["type"] == "error" and m["code"] == "internal" and "not saved" in m["message"],
                  "unsaved set: %r" % m)
            ws2, h2 = await connect(d)
            check(h2["params"]["wind_speed"] == h["params"]["wind_speed"] and
                  h2["params_version"] == h["params_version"], "an unsaved set changed the sea: %r" % h2["params"])
            os.mkdir(sub)
            m = await set_and_ack(ws, 4, 9.5)
            check(m["type"] == "params" and m["params_version"] == h["params_version"] + 1, "set after: %r" % m)
            check(read_state(os.path.join(sub, "state.json"))["params"]["wind_speed"] == 9.5, "not saved")
            await ws.close()
            await ws2.close()
        asyncio.run(run())
        ok = True
    finally:
        rc = d.kill(signal.SIGTERM)
        if not ok or rc != 0:
            print("--- log:\n%s" % d.read_log())
        shutil.rmtree(tmp, ignore_errors=True)
    check(rc == 0, "daemon exited %r" % rc)


def main():
    global ARGS
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", required=True)
    ap.add_argument("--cycles", type=int, default=3)
    ap.add_argument("--recovery-s", type=float, default=2.0)
    ap.add_argument("-k", default="")
    ARGS = ap.parse_args()
    td.ARGS = cr.ARGS = ARGS
    if not os.path.exists(cr.NATS_BIN):
        print("nats-server not found (scripts/deps.sh installs it)")
        return 1
    passed = failed = 0
    for fn in TESTS:
        if ARGS.k and ARGS.k not in fn.__name__:
            continue
        t0 = time.time()
        try:
            fn()
            passed += 1
            print("PASS %s (%.1f s)" % (fn.__name__, time.time() - t0))
        except Exception:
            failed += 1
            print("FAIL %s" % fn.__name__)
            traceback.print_exc()
        sys.stdout.flush()
    print("%d passed, %d failed" % (passed, failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

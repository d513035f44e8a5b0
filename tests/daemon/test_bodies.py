#!/usr/bin/python3
"""Floating bodies against a real daemon (PROTOCOL.md §3.5, §7.6): launch, steer,
remove and claim; every error code refusing and changing nothing; two clients
reading the same body record on the same seq; a new client seeing every body
in its hello; ownership; the grace and the abandonment; a restart restoring the
bodies; /metrics.

    /usr/bin/python3 tests/daemon/test_bodies.py --oceand build/oceand
Each test starts its own daemon (test_daemon.Daemon) and stops it at the end;
prints "N passed, M failed" last.
"""
import argparse
import asyncio
import json
import os
import re
import struct
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import test_daemon as td  # noqa: E402
from test_daemon import check, connect, recv_json  # noqa: E402
from harness import running, run_tests  # noqa: E402

TESTS = []
SECTION = struct.Struct("<4sHH8x")           # tag, count, record_size, reserved
RECORD = struct.Struct("<IBBbb3f4f3f")       # 48 bytes: id, kind, flags, throttle, rudder, pos, quat, vel
HEX32 = re.compile(r"^[0-9a-f]{32}$")


def test(fn):
    TESTS.append(fn)
    return fn


def records(frame):
    """{body id: record dict} of a frame's BODY section ({} when it has none)."""
    hsize = struct.unpack_from("<H", frame, 6)[0]
    check(hsize >= 48 and hsize % 8 == 0, "header_size %d" % hsize)
    if hsize < 64 or frame[48:52] != b"BODY":
        return {}
    tag, count, rsize = SECTION.unpack_from(frame, 48)
    check(rsize == 48 and 64 + count * rsize <= hsize, "BODY section %d x %d in a header of %d" % (count, rsize, hsize))
    out = {}
    for i in range(count):
        raw = frame[64 + 48 * i:64 + 48 * (i + 1)]
        r = RECORD.unpack(raw)
        out[r[0]] = dict(kind=r[1], flags=r[2], throttle=r[3], rudder=r[4], pos=r[5:8], quat=r[8:12], vel=r[12:15],
                         raw=raw)
    return out


def seq_of(frame):
    return struct.unpack_from("<Q", frame, 8)[0]


async def frame_where(ws, pred, timeout=5.0):
    """The next frame whose records satisfy pred(records): (seq, records)."""
    deadline = time.time() + timeout
    while True:
        left = deadline - time.time()
        check(left > 0, "timed out waiting for a frame with the bodies expected")
        m = await asyncio.wait_for(ws.recv(), left)
        if isinstance(m, bytes):
            r = records(m)
            if pred(r):
                return seq_of(m), r


async def ask(ws, msg, timeout=5.0):
    """Send msg (it has an id) and return the reply carrying that id."""
    await ws.send(json.dumps(msg))
    return await recv_json(ws, lambda m: m.get("id") == msg["id"], timeout)


async def launch(ws, rid, kind="boat", x=10.0, z=-20.0, heading=90.0):
    m = await ask(ws, {"type": "launch", "id": rid, "kind": kind, "x": x, "z": z, "heading": heading})
    check(m["type"] == "launched", "launch refused: %r" % m)
    check(isinstance(m["body"], int) and m["body"] >= 1 and HEX32.match(m["resume"]), "launched %r" % m)
    return m["body"], m["resume"]


async def hello_bodies(d):
    ws, hello = await connect(d, url=d.url + "?frames=0")
    await ws.close()
    return {b["body"]: b for b in hello["bodies"]}


@test
def test_launch_steer_remove(d):
    async def run():
        a, hello = await connect(d)
        check([k["name"] for k in hello["body_kinds"]] == ["spar", "ball", "dinghy", "boat", "ship"],
              "body_kinds %r" % hello["body_kinds"])
        for k in hello["body_kinds"]:
            for member in ("name", "label", "description", "hull", "length", "beam", "height", "mass", "draft",
                           "powered", "top_speed", "turning_diameter"):
                check(member in k, "body_kinds row without %s: %r" % (member, k))
        check(hello["body_limits"] == {"per_session": 4, "max_bodies": 64, "launch_rate": 12, "grace": 60},
              "body_limits %r" % hello["body_limits"])
        check(hello["world_half_size"] == 2500 and hello["bodies"] == [], "hello %r" % hello["bodies"])
        boat = [k["name"] for k in hello["body_kinds"]].index("boat")
        body, _ = await launch(a, 1)
        lst = await recv_json(a, lambda m: m["type"] == "bodies")
        check([b["body"] for b in lst["bodies"]] == [body] and lst["bodies"][0]["kind"] == "boat" and
              lst["bodies"][0]["owner"] == hello["client_id"] and not lst["bodies"][0]["adrift"], "bodies %r" % lst)
        seq, r = await frame_where(a, lambda r: body in r)
        check(seq >= lst["seq"], "the body's first frame %d before its bodies message's seq %d" % (seq, lst["seq"]))
        rec = r[body]
        check(rec["kind"] == boat and rec["flags"] == 2 and rec["throttle"] == 0, "record %r" % rec)
        check(abs(rec["pos"][0] - 10) < 1 and abs(rec["pos"][2] + 20) < 1, "launched at %r" % (rec["pos"],))
        check(abs(sum(q * q for q in rec["quat"]) - 1) < 1e-3, "quaternion %r" % (rec["quat"],))
        # A steer without an id is not answered; with one it is.
        await a.send(json.dumps({"type": "steer", "body": body, "throttle": 0.5, "rudder": -0.2}))
        m = await ask(a, {"type": "steer", "id": 2, "body": body, "throttle": 0.5})
        check(m == {"type": "steered", "id": 2, "body": body}, "steered %r" % m)
        _, r = await frame_where(a, lambda r: body in r and r[body]["throttle"] == 64)
        check(r[body]["rudder"] == round(-0.2 * 127), "rudder %r" % r[body])
        m = await ask(a, {"type": "remove", "id": 3, "body": body})
        check(m == {"type": "removed", "id": 3, "body": body}, "removed %r" % m)
        lst = await recv_json(a, lambda m: m["type"] == "bodies")
        check(lst["bodies"] == [] and lst["removed"] == [{"body": body, "reason": "removed"}], "bodies %r" % lst)
        # With no body left, frames are as before: a 48-byte header.
        await frame_where(a, lambda r: not r)
        _, m = await frame_where(a, lambda r: True)
        check(m == {}, "a BODY section after the last body left")
        await a.close()
    asyncio.run(run())


@test
def test_errors_refuse_and_change_nothing():
    with running(td.Daemon, "--bodies-per-session", "2", "--max-bodies", "3", "--launch-rate", "2") as d:
        async def run():
            a, _ = await connect(d, url=d.url + "?frames=0")
            b, _ = await connect(d, url=d.url + "?frames=0")
            body, _ = await launch(a, 1)
            before = await hello_bodies(d)
            bad = [
                ({"type": "launch", "kind": "submarine", "x": 0, "z": 0}, "unknown_kind"),
                ({"type": "launch", "kind": 3, "x": 0, "z": 0}, "bad_type"),
                ({"type": "launch", "x": 0, "z": 0}, "bad_message"),
                ({"type": "launch", "kind": "boat", "z": 0}, "bad_message"),
                ({"type": "launch", "kind": "boat", "x": "10", "z": 0}, "bad_type"),
                ('{"type":"launch","kind":"boat","x":1e999,"z":0,"id":%d}', "bad_type"),
                ('{"type":"launch","kind":"boat","x":0,"z":0,"heading":-1e999,"id":%d}', "bad_type"),
                ({"type": "launch", "kind": "boat", "x": 2500.5, "z": 0}, "out_of_range"),
                ({"type": "launch", "kind": "boat", "x": 0, "z": -3000}, "out_of_range"),
                ({"type": "steer", "body": body, "throttle": 1.5}, "out_of_range"),
                ({"type": "steer", "body": body, "rudder": -1.01}, "out_of_range"),
                ('{"type":"steer","body":%d,"throttle":1e999,"id":%%d}' % body, "bad_type"),
                ({"type": "steer", "body": body, "throttle": "full"}, "bad_type"),
                ({"type": "steer", "throttle": 0.5}, "bad_message"),
                ({"type": "steer", "body": 1.5, "throttle": 0.5}, "bad_type"),
                ({"type": "steer", "body": 0, "throttle": 0.5}, "out_of_range"),
                ({"type": "steer", "body": 999, "throttle": 0.5}, "no_such_body"),
                ({"type": "remove", "body": 999}, "no_such_body"),
                ({"type": "remove"}, "bad_message"),
                ({"type": "claim", "body": body}, "bad_message"),
                ({"type": "claim", "body": body, "resume": "xyz"}, "bad_message"),
                ({"type": "claim", "body": body, "resume": "0" * 32}, "not_owner"),
                ({"type": "claim", "body": 999, "resume": "0" * 32}, "no_such_body"),
            ]
            for i, (msg, code) in enumerate(bad):
                if isinstance(msg, str):   # 1e999 is not a number Python's json writes
                    await a.send(msg % (100 + i))
                    e = await recv_json(a, lambda m, i=i: m.get("id") == 100 + i)
                else:
                    msg = dict(msg, id=100 + i)
                    e = await ask(a, msg)
                check(e["type"] == "error" and e["code"] == code, "%r -> %r (wanted %s)" % (msg, e, code))
            for msg in ({"type": "steer", "id": 200, "body": body, "throttle": 0.3},
                        {"type": "remove", "id": 201, "body": body}):
                e = await ask(b, msg)
                check(e["type"] == "error" and e["code"] == "not_owner", "%r by another -> %r" % (msg, e))
            # A steer without an id that fails is answered all the same (errors always are).
            await b.send(json.dumps({"type": "steer", "body": body, "throttle": 0.3}))
            e = await recv_json(b, lambda m: m["type"] == "error")
            check(e["code"] == "not_owner" and "id" not in e, "steer without id %r" % e)
            # Per session (2), then the world (3), then the launch rate (2 a minute: a launched twice).
            await launch(a, 2)
            e = await ask(a, {"type": "launch", "id": 3, "kind": "ball", "x": 0, "z": 0})
            check(e["type"] == "error" and e["code"] == "too_many_bodies", "third of a session %r" % e)
            await launch(b, 4)
            e = await ask(b, {"type": "launch", "id": 5, "kind": "ball", "x": 0, "z": 0})
            check(e["type"] == "error" and e["code"] == "too_many_bodies", "fourth in the world %r" % e)
            m = await ask(a, {"type": "remove", "id": 6, "body": body})
            check(m["type"] == "removed", "remove %r" % m)
            e = await ask(a, {"type": "launch", "id": 7, "kind": "ball", "x": 0, "z": 0})
            check(e["type"] == "error" and e["code"] == "rate_limited", "launch past --launch-rate %r" % e)
            after = await hello_bodies(d)
            check(len(after) == 2 and body not in after, "bodies after the refusals %r" % after)
            check(set(before) == {body}, "before %r" % before)
            check(d.metric("oceand_bodies") == 2, "oceand_bodies %r" % d.metric("oceand_bodies"))
            await a.close()
            await b.close()
        asyncio.run(run())
    with running(td.Daemon, "--control-token", "sesame") as d:
        async def run_token():
            v, hello = await connect(d, url=d.url + "?frames=0")
            check(hello["role"] == "viewer", "role %r" % hello["role"])
            e = await ask(v, {"type": "launch", "id": 1, "kind": "boat", "x": 0, "z": 0})
            check(e["type"] == "error" and e["code"] == "forbidden", "viewer launch %r" % e)
            e = await ask(v, {"type": "launch", "id": 2, "kind": "boat", "x": 0, "z": 0, "token": "wrong"})
            check(e["type"] == "error" and e["code"] == "forbidden", "wrong token %r" % e)
            check(await hello_bodies(d) == {}, "a refused launch left a body")
            body, _ = await launch_token(v)
            e = await ask(v, {"type": "steer", "id": 4, "body": body, "throttle": 1})
            check(e["type"] == "error" and e["code"] == "forbidden", "steer without the token %r" % e)
            m = await ask(v, {"type": "steer", "id": 5, "body": body, "throttle": 1, "token": "sesame"})
            check(m["type"] == "steered", "steer with the token %r" % m)
            await v.close()

        async def launch_token(v):
            m = await ask(v, {"type": "launch", "id": 3, "kind": "boat", "x": 0, "z": 0, "token": "sesame"})
            check(m["type"] == "launched", "launch with the token %r" % m)
            return m["body"], m["resume"]
        asyncio.run(run_token())


@test
def test_two_clients_same_record_same_seq(d):
    async def run():
        a, _ = await connect(d)
        b, _ = await connect(d)
        body, _ = await launch(a, 1, kind="dinghy", x=-5, z=7)
        await a.send(json.dumps({"type": "steer", "body": body, "throttle": 1, "rudder": 0.5}))
        seen = {}
        for ws, who in ((a, "a"), (b, "b")):
            t_end = time.time() + 2
            while time.time() < t_end:
                m = await asyncio.wait_for(ws.recv(), 5)
                if isinstance(m, bytes) and body in records(m):
                    seen.setdefault(seq_of(m), {})[who] = records(m)[body]["raw"]
        both = [s for s, v in seen.items() if len(v) == 2]
        check(len(both) >= 10, "only %d ticks seen by both clients" % len(both))
        for s in both:
            check(seen[s]["a"] == seen[s]["b"], "tick %d: the two clients got different records" % s)
        moving = {seen[s]["a"][8:20] for s in both}
        check(len(moving) > 1, "the powered dinghy did not move")
        await a.close()
        await b.close()
    asyncio.run(run())


@test
def test_new_client_sees_every_body_in_hello(d):
    async def run():
        a, _ = await connect(d, url=d.url + "?frames=0")
        await a.send(json.dumps({"type": "name", "id": 9, "name": "Ana"}))
        await recv_json(a, lambda m: m["type"] == "named")
        ids = [(await launch(a, i, kind=k, x=10 * i, z=0))[0] for i, k in enumerate(("spar", "ball", "ship"))]
        c, hello = await connect(d)
        got = {b["body"]: b for b in hello["bodies"]}
        check(sorted(got) == sorted(ids), "hello bodies %r, launched %r" % (got, ids))
        check(all(b["name"] == "Ana" and not b["adrift"] for b in got.values()), "hello bodies %r" % got)
        # Within a tick or so of the hello, its frames carry every one of them.
        seq, r = await frame_where(c, lambda r: True, timeout=2)
        check(sorted(r) == sorted(ids), "first frame's bodies %r" % sorted(r))
        # A new name is everyone's news.
        await a.send(json.dumps({"type": "name", "id": 10, "name": "Bea"}))
        lst = await recv_json(c, lambda m: m["type"] == "bodies")
        check(all(b["name"] == "Bea" for b in lst["bodies"]), "after the rename %r" % lst)
        await a.close()
        await c.close()
    asyncio.run(run())


@test
def test_grace_claim_and_abandonment():
    with running(td.Daemon, "--body-grace", "1.5") as d:
        async def run():
            a, _ = await connect(d, url=d.url + "?frames=0")
            w, _ = await connect(d)
            body, key = await launch(a, 1)
            await ask(a, {"type": "steer", "id": 2, "body": body, "throttle": 1})
            await a.close()
            lst = await recv_json(w, lambda m: m["type"] == "bodies" and m["bodies"] and m["bodies"][0]["adrift"])
            check(lst["bodies"][0]["body"] == body, "adrift %r" % lst)
            _, r = await frame_where(w, lambda r: body in r and r[body]["flags"] & 1)
            check(r[body]["throttle"] == 127, "within the grace it keeps its controls: %r" % r[body])
            # A reconnecting session takes it back with the key.
            b, _ = await connect(d, url=d.url + "?frames=0")
            e = await ask(b, {"type": "steer", "id": 3, "body": body, "throttle": 0.5})
            check(e["type"] == "error" and e["code"] == "not_owner", "steer before the claim %r" % e)
            m = await ask(b, {"type": "claim", "id": 4, "body": body, "resume": key})
            check(m == {"type": "claimed", "id": 4, "body": body}, "claim %r" % m)
            lst = await recv_json(w, lambda m: m["type"] == "bodies" and m["bodies"] and not m["bodies"][0]["adrift"])
            m = await ask(b, {"type": "steer", "id": 5, "body": body, "throttle": 0.5})
            check(m["type"] == "steered", "steer after the claim %r" % m)
            await b.close()
            # Gone for good: unpowered after the grace, removed after twice the grace.
            t0 = time.time()
            _, r = await frame_where(w, lambda r: body in r and r[body]["throttle"] == 0 and r[body]["flags"] & 1,
                                     timeout=4)
            check(time.time() - t0 > 1.0, "stopped %.1f s after the owner left (grace 1.5 s)" % (time.time() - t0))
            c, _ = await connect(d, url=d.url + "?frames=0")
            e = await ask(c, {"type": "claim", "id": 6, "body": body, "resume": key})
            check(e["type"] == "error" and e["code"] == "not_owner", "claim after the grace %r" % e)
            lst = await recv_json(w, lambda m: m["type"] == "bodies" and m["removed"], timeout=4)
            check(lst["removed"] == [{"body": body, "reason": "abandoned"}] and lst["bodies"] == [], "%r" % lst)
            check(time.time() - t0 > 2.5, "removed %.1f s after the owner left" % (time.time() - t0))
            check(d.metric('oceand_body_removals_total{reason="abandoned"}') == 1, "abandoned not counted")
            await c.close()
            await w.close()
        asyncio.run(run())


@test
def test_restart_restores_bodies():
    tmp = tempfile.mkdtemp(prefix="oceand-bodies-")
    state = os.path.join(tmp, "state.json")
    with running(td.Daemon, state_file=state, tmpdir=tmp, remove=False) as d:
        async def first():
            a, _ = await connect(d)
            ids = {}
            for i, k in enumerate(("ball", "boat")):
                ids[k] = await launch(a, i, kind=k, x=20.0 * i, z=5)
            gone, _ = await launch(a, 5, kind="spar")
            await ask(a, {"type": "remove", "id": 6, "body": gone})
            await ask(a, {"type": "steer", "id": 7, "body": ids["boat"][0], "throttle": 0.75})
            await asyncio.sleep(1.5)
            _, r = await frame_where(a, lambda r: len(r) == 2)
            await a.close()
            return ids, gone, r
        ids, gone, last = asyncio.run(first())
    saved = json.load(open(state))
    check(len(saved["bodies"]["list"]) == 2 and saved["bodies"]["next_id"] > gone, "state file %r" % saved["bodies"])
    with running(td.Daemon, state_file=state, tmpdir=tmp, remove=False) as d:
        async def second():
            c, hello = await connect(d)
            got = {b["body"]: b for b in hello["bodies"]}
            check(sorted(got) == sorted(v[0] for v in ids.values()), "after the restart %r" % got)
            check(all(b["adrift"] for b in got.values()), "restored bodies wait for a claim: %r" % got)
            _, r = await frame_where(c, lambda r: len(r) == 2)
            boat = ids["boat"][0]
            check(r[boat]["throttle"] == round(0.75 * 127), "the boat's throttle %r" % r[boat])
            ball = ids["ball"][0]
            dx = r[ball]["pos"][0] - last[ball]["pos"][0]
            check(abs(dx) < 5, "the ball moved %.1f m across the restart" % dx)
            m = await ask(c, {"type": "claim", "id": 1, "body": boat, "resume": ids["boat"][1]})
            check(m["type"] == "claimed", "claim after the restart %r" % m)
            new, _ = await launch(c, 2, kind="ball")
            check(new > gone, "id %d reused (removed before the restart: %d)" % (new, gone))
            await c.close()
        asyncio.run(second())
    # A bad body entry is refused whole: the daemon starts, without bodies.
    bad = json.load(open(state))
    bad["bodies"]["list"][0]["quat"] = [1, 1, 0, 0]
    bad["bodies"]["list"][1]["kind"] = "submarine"
    json.dump(bad, open(state, "w"))
    with running(td.Daemon, state_file=state, tmpdir=tmp) as d:
        check(asyncio.run(hello_bodies(d)) == {}, "bodies from a bad state file")
        check("bad_body" in d.read_log(), "the refusal is not logged with its code:\n%s" % d.read_log())


@test
def test_metrics_count_bodies(d):
    async def run():
        a, _ = await connect(d, url=d.url + "?frames=0")
        check(d.metric("oceand_bodies") == 0 and d.metric("oceand_body_launches_total") == 0, "metrics at start")
        x, _ = await launch(a, 1)
        y, _ = await launch(a, 2, kind="ball")
        await ask(a, {"type": "remove", "id": 3, "body": x})
        steps = lambda: d.metric("oceand_body_step_duration_seconds_count")

        async def until(cond, seconds=10.0):  # a count, not a rate: a busy machine only takes longer
            t_end = time.time() + seconds
            while not cond() and time.time() < t_end:
                await asyncio.sleep(0.1)
            return cond()
        check(await until(lambda: steps() > 5), "body steps not counted: %r" % steps())
        check(d.metric("oceand_bodies") == 1, "oceand_bodies %r" % d.metric("oceand_bodies"))
        check(d.metric("oceand_body_launches_total") == 2, "launches")
        check(d.metric('oceand_body_removals_total{reason="removed"}') == 1, "removals")
        # A tick with bodies and no frame subscriber still steps them.
        n0 = steps()
        check(await until(lambda: steps() >= n0 + 10), "bodies not stepped without viewers: %r after %r" % (steps(), n0))
        await a.close()
    asyncio.run(run())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--sanitized", action="store_true", help="sanitizer build: smaller N")
    ap.add_argument("-k", default="", help="run only tests whose name contains this")
    args = ap.parse_args()
    td.ARGS = argparse.Namespace(oceand=args.oceand, frame_check=None, sanitized=args.sanitized)
    if args.sanitized:
        td.BASE_N = 128
    t_all = time.time()
    passed, failed = run_tests(TESTS, args.k, td.Daemon)
    print("bodies tests took %.0f s" % (time.time() - t_all))
    print("%d passed, %d failed" % (passed, failed))
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()

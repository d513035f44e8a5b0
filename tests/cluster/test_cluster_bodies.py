#!/usr/bin/python3
"""Floating bodies through a cluster (PROTOCOL.md §3.5, §7.6 "Through an edge";
docs/scaling.md "Floating bodies"): a client of an edge launches, steers, removes
and claims; a viewer of another edge reads the same record on the same seq; nobody
steers another's body through an edge; an owner that leaves an edge leaves its body
adrift and claims it back through another edge; a standby that takes over puts
every body where it was, with its owner, and ids never go back. Each test starts
its own nats-server and daemons on 127.0.0.1, as test_cluster_roles.py.
    /usr/bin/python3 tests/cluster/test_cluster_bodies.py --oceand build/oceand
Prints "N passed, M failed" last.
"""
import argparse
import asyncio
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "daemon"))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "common"))
import oceand_proc  # noqa: E402
import test_bodies as tb  # noqa: E402
import test_cluster_durable as cd  # noqa: E402
import test_cluster_roles as cr  # noqa: E402
import test_daemon as td  # noqa: E402
from test_cluster_roles import wait_for  # noqa: E402
from test_daemon import check, connect  # noqa: E402

ARGS = None
TESTS = []


def test(fn):
    TESTS.append(fn)
    return fn


class Viewer:
    """A client whose messages are read all the time: JSON in order, and the BODY
    records of every frame by seq (tb.records)."""

    def __init__(self, ws, hello):
        self.ws, self.hello = ws, hello
        self.json, self.frames = [], {}
        self.task = asyncio.ensure_future(self.run())

    async def run(self):
        try:
            async for m in self.ws:
                if isinstance(m, bytes):
                    self.frames[tb.seq_of(m)] = tb.records(m)
                else:
                    self.json.append(json.loads(m))
        except Exception:   # noqa: BLE001: the socket closed
            pass

    async def wait_json(self, pred, what, timeout=10.0, start=0):
        deadline = time.time() + timeout
        while True:
            for m in self.json[start:]:
                if pred(m):
                    return m
            check(time.time() < deadline, "%s: timed out (got %r)" % (what, self.json[-5:]))
            await asyncio.sleep(0.02)

    async def ask(self, msg, timeout=10.0):
        n = len(self.json)
        await self.ws.send(json.dumps(msg))
        return await self.wait_json(lambda m: m.get("id") == msg["id"], "answer to %r" % msg, timeout, n)

    async def frame_where(self, pred, what, timeout=10.0, after=0):
        """(seq, records) of the newest frame after seq `after` whose records satisfy pred."""
        deadline = time.time() + timeout
        while True:
            for s in sorted(self.frames, reverse=True):
                if s > after and pred(self.frames[s]):
                    return s, self.frames[s]
            check(time.time() < deadline, "%s: timed out" % what)
            await asyncio.sleep(0.02)

    async def close(self):
        await self.ws.close()
        self.task.cancel()


async def viewer(node, **kw):
    ws, hello = await connect(node, **kw)
    return Viewer(ws, hello)


async def launch(v, rid, **kw):
    msg = {"type": "launch", "id": rid, "kind": "boat", "x": 10.0, "z": -20.0, "heading": 90.0}
    msg.update(kw)
    m = await v.ask(msg)
    check(m["type"] == "launched" and m["body"] >= 1 and tb.HEX32.match(m["resume"]), "launch: %r" % m)
    return m["body"], m["resume"]


def refused(m, code, what):
    check(m["type"] == "error" and m["code"] == code, "%s: %r, want error %s" % (what, m, code))


# ---------------------------------------------------------------- tests

@test
@cr.with_cluster(edges=2)
def test_bodies_through_edges(c):
    """A client of edge 0 launches and steers a boat; a viewer of edge 1 gets the
    `bodies` list and, on the same seq as the owner, byte for byte the same record;
    the viewer cannot steer, remove or claim it (not_owner), errors keep their codes;
    a rogue's broken sections and list on NATS change nothing a client gets;
    when the owner leaves, the body is adrift for everyone and its key claims it back
    through the other edge."""
    async def run():
        a = await viewer(c.edges[0])
        b = await viewer(c.edges[1])
        check(a.hello["body_limits"]["max_bodies"] == 64 and a.hello["bodies"] == [],
              "an edge's hello: %r %r" % (a.hello["body_limits"], a.hello["bodies"]))
        body, key = await launch(a, 1)
        for v in (a, b):
            lst = await v.wait_json(lambda m: m["type"] == "bodies" and m["bodies"], "bodies list")
            e = lst["bodies"][0]
            check(e["body"] == body and e["kind"] == "boat" and e["owner"] == a.hello["client_id"] and
                  not e["adrift"], "bodies on an edge: %r" % lst)
        # The same tick's record on both edges, byte for byte.
        seq, ra = await a.frame_where(lambda r: body in r, "the owner's frame with the body")
        _, rb = await b.frame_where(lambda r: body in r, "the other edge's frame with the body", after=seq - 1)
        both = sorted(set(s for s in a.frames if body in a.frames[s]) & set(s for s in b.frames if body in b.frames[s]))
        check(both, "no seq on which both edges carried the body")
        s = both[-1]
        check(a.frames[s][body]["raw"] == b.frames[s][body]["raw"], "seq %d: the records differ between edges" % s)
        # Every frame of either edge that has the body carries it (none lost between layers and section).
        m = await a.ask({"type": "steer", "id": 2, "body": body, "throttle": 1.0, "rudder": 0.25})
        check(m == {"type": "steered", "id": 2, "body": body}, "steered through an edge: %r" % m)
        _, r = await b.frame_where(lambda r: body in r and r[body]["throttle"] == 127, "the steer seen on edge 1")
        check(r[body]["rudder"] == round(0.25 * 127), "rudder %r" % r[body])
        n = len(a.json)
        await a.ws.send(json.dumps({"type": "steer", "body": body, "throttle": 0.5}))  # no id: no answer on success
        await b.frame_where(lambda r: body in r and r[body]["throttle"] == 64, "a steer without an id")
        check(not any(m.get("type") == "steered" for m in a.json[n:]), "a steer without an id was answered")
        # Hostile-ish: the other edge's client.
        refused(await b.ask({"type": "steer", "id": 3, "body": body, "throttle": -1}), "not_owner", "steer another's")
        refused(await b.ask({"type": "remove", "id": 4, "body": body}), "not_owner", "remove another's")
        refused(await b.ask({"type": "claim", "id": 5, "body": body, "resume": "0" * 32}), "not_owner", "wrong key")
        refused(await b.ask({"type": "steer", "id": 6, "body": body + 1000, "throttle": 0}), "no_such_body",
                "steer nothing")
        refused(await b.ask({"type": "launch", "id": 7, "kind": "kayak", "x": 0, "z": 0}), "unknown_kind", "kind")
        refused(await b.ask({"type": "launch", "id": 8, "kind": "boat", "x": 9999, "z": 0}), "out_of_range", "x")
        refused(await b.ask({"type": "steer", "id": 9, "body": body, "throttle": 2}), "out_of_range", "throttle")
        await asyncio.sleep(0.3)
        _, r = await b.frame_where(lambda r: body in r, "after the refusals")
        check(r[body]["throttle"] == 64, "a refused steer changed the throttle: %r" % r[body])
        # A rogue on NATS: sections that are not whole, one far ahead, a list with a bad entry.
        import struct
        import test_cluster_hostile as tch
        rogue = tch.RawNats(c.nats.url)
        try:
            good = s + 1
            bad_count = b"BODY" + struct.pack("<HH8x", 2, 48) + b"\0" * 48
            for body_ in (struct.pack("<Q", good) + bad_count, struct.pack("<Q", good) + b"BODX" + b"\0" * 60,
                          b"\1\2\3"):
                rogue.pub("oceand.bodies", tch.envelope(11, body_))
            rogue.pub("oceand.bodies", tch.envelope(10, json.dumps(
                {"type": "bodies", "seq": 1, "bodies": [{"body": 7, "kind": "kayak", "owner": "x", "name": "",
                                                         "adrift": False}], "removed": []}).encode()))
            rogue.sub("_INBOX.rogue-sync")   # its PONG: the server has every message above
        finally:
            rogue.close()
        await asyncio.sleep(0.5)
        seq_r, r = await b.frame_where(lambda r: True, "a frame after the rogue's messages")
        check(set(r) == {body} and r[body]["throttle"] == 64, "records after the rogue's messages: %r" % r)
        check(not any(m.get("type") == "bodies" and any(e["body"] == 7 for e in m["bodies"]) for m in b.json),
              "the rogue's list reached a client")
        check("that does not parse" in c.edges[1].read_log(), "the edge did not see (and drop) the rogue's list")
        # The owner leaves edge 0: adrift for everyone; its key claims it back on edge 1.
        n = len(b.json)
        await a.close()
        lst = await b.wait_json(lambda m: m["type"] == "bodies" and m["bodies"] and m["bodies"][0]["adrift"],
                                "adrift after its owner left", start=n)
        await b.frame_where(lambda r: body in r and r[body]["flags"] & 1, "the adrift flag on edge 1")
        a2 = await viewer(c.edges[1])
        check([e["body"] for e in a2.hello["bodies"]] == [body] and a2.hello["bodies"][0]["adrift"],
              "hello on edge 1: %r" % a2.hello["bodies"])
        m = await a2.ask({"type": "claim", "id": 10, "body": body, "resume": key})
        check(m == {"type": "claimed", "id": 10, "body": body}, "claim through the other edge: %r" % m)
        m = await a2.ask({"type": "steer", "id": 11, "body": body, "throttle": 0})
        check(m["type"] == "steered", "steer after the claim: %r" % m)
        refused(await b.ask({"type": "steer", "id": 12, "body": body, "throttle": 1}), "not_owner",
                "steer after another's claim")
        await b.wait_json(lambda m: m["type"] == "bodies" and m["bodies"] and not m["bodies"][0]["adrift"] and
                          m["bodies"][0]["owner"] == a2.hello["client_id"], "the new owner in bodies")
        # The limits are the sim's; a launch it refuses takes nothing from the edge's bucket (12 a minute).
        mine = [body] + [(await launch(a2, 20 + i, x=-50.0 * (i + 1)))[0] for i in range(3)]
        for i in range(10):
            refused(await a2.ask({"type": "launch", "id": 30 + i, "kind": "spar", "x": 0, "z": 0}), "too_many_bodies",
                    "a fifth body")
        m = await a2.ask({"type": "remove", "id": 40, "body": mine[-1]})
        check(m["type"] == "removed", "remove: %r" % m)
        await launch(a2, 41, x=60.0)   # the 4th of 12 launches: not rate_limited
        await a2.close()
        await b.close()
    asyncio.run(run())


@test
@cd.with_js_cluster(sims=2, edges=1)
def test_standby_takes_over_every_body(c):
    """Two sims on JetStream: a client of the edge launches two boats and runs one at
    full throttle; kill -9 of the active sim. The standby takes over with both bodies
    where they were (within the motion of the last record's age and the take-over),
    the owner steers them at once (it still owns them), and a new launch gets a
    larger id."""
    async def run():
        a = await viewer(c.edges[0])
        w = await viewer(c.edges[0])
        run_id, _ = await launch(a, 1)
        still, _ = await launch(a, 2, kind="spar", x=-30.0, z=40.0)
        m = await a.ask({"type": "steer", "id": 3, "body": run_id, "throttle": 1.0, "rudder": 0.0})
        check(m["type"] == "steered", "steer: %r" % m)
        await asyncio.sleep(3.5)   # some way from the launch point, at speed
        first = c.active()
        check(first is not None, "no active sim")
        seq0, r0 = await w.frame_where(lambda r: run_id in r and still in r, "both bodies before the kill")
        t_kill = time.time()
        first.kill()
        wait_for(lambda: c.active() not in (None, first), "the standby holds the lease", timeout=10)
        _, r1 = await w.frame_where(lambda r: run_id in r and still in r, "both bodies after the take-over",
                                       timeout=15, after=seq0)
        waited = time.time() - t_kill
        launch_pt = (10.0, r0[run_id]["pos"][1], -20.0)
        moved = math.dist(r0[run_id]["pos"], launch_pt)
        v0 = math.hypot(*r0[run_id]["vel"][::2])
        check(moved > 2 and v0 > 1, "the boat ran only %.1f m (%.1f m/s) before the kill" % (moved, v0))
        # The standby's copy is at most a replica period plus a renewal old; the boat
        # goes on from there at its speed (not from rest at the launch point).
        gap = math.dist(r0[run_id]["pos"], r1[run_id]["pos"])
        v1 = math.hypot(*r1[run_id]["vel"][::2])
        print("  boat: %.1f m run, %.2f m/s; after the take-over %.2f m away, %.2f m/s (%.2f s after the kill)"
              % (moved, v0, gap, v1, waited))
        speed = 1.5 * max(v0, v1)   # it is still accelerating
        check(gap < speed * (waited + 0.5) + 1, "the boat is %.1f m from where it was (%.2f s later)" % (gap, waited))
        check(math.dist(r1[run_id]["pos"], launch_pt) > moved - 1.5 and v1 > 0.5 * v0,
              "the boat started again: %.1f m from its launch point, %.2f m/s" % (
                  math.dist(r1[run_id]["pos"], launch_pt), v1))
        check(math.dist(r0[still]["pos"][::2], r1[still]["pos"][::2]) < 3, "the spar moved: %r -> %r"
              % (r0[still]["pos"], r1[still]["pos"]))
        check(r1[run_id]["throttle"] == 127 and not r1[run_id]["flags"] & 1, "the boat after the take-over: %r"
              % r1[run_id])
        # Its owner still owns it on the new sim.
        for k in range(50):
            m = await a.ask({"type": "steer", "id": 100 + k, "body": run_id, "throttle": -0.5})
            if m["type"] == "steered" or m.get("code") != "unavailable":
                break
            await asyncio.sleep(0.2)
        check(m["type"] == "steered", "the owner steers after the take-over: %r" % m)
        await w.frame_where(lambda r: run_id in r and r[run_id]["throttle"] == round(-0.5 * 127),
                            "the steer on the new sim")
        third, _ = await launch(a, 200, x=0.0, z=0.0)
        check(third > max(run_id, still), "an id went back: %d after %d, %d" % (third, run_id, still))
        h = await viewer(c.edges[0], url=c.edges[0].url + "?frames=0")
        owners = {e["body"]: e["owner"] for e in h.hello["bodies"]}
        check(owners.get(run_id) == a.hello["client_id"] and owners.get(still) == a.hello["client_id"],
              "owners after the take-over: %r" % h.hello["bodies"])
        for v in (a, w, h):
            await v.close()
    asyncio.run(run())


@test
@cd.with_js_cluster(sims=2, edges=1)
def test_an_older_record_brings_no_bodies_back(c):
    """A record older than the sims' state (a stale copy written into the bucket) with a
    body of its own: whichever sim takes the lease after it keeps the bodies it had or
    followed (the client's boat, its owner), never the old record's (no ship 4999 in any
    frame or list), and ids do not jump to the old record's next_id."""
    import test_cluster_hostile as tch
    async def run():
        a = await viewer(c.edges[0])
        for i in range(2):
            m = await a.ask({"type": "set", "id": 50 + i, "params": {"wind_speed": 9.5 + i}})
            check(m["type"] == "params", "set: %r" % m)
        v = m["params_version"]
        boat, _ = await launch(a, 1)
        wait_for(lambda: cd.metric_of(c.sims[1], "oceand_params_version") == v, "the standby follows version %d" % v)
        await asyncio.sleep(0.6)   # a renewal or two carry the boat
        ghost = {"id": 4999, "kind": "ship", "pos": [100, 0, 100], "quat": [1, 0, 0, 0], "vel": [0, 0, 0],
                 "omega": [0, 0, 0], "throttle": 0, "rudder": 0, "owner": "c1-rogue", "name": "",
                 "resume": "0" * 32, "origin": "edge-rogue"}
        old = {"holder": "rogue-1", "name": "rogue", "released": False, "params": {"wind_speed": 4.5},
               "params_version": v - 1, "sim_time": 100.0, "wall_us": int(time.time() * 1e6), "seq": 1,
               "tick_rate": 30, "bodies": {"next_id": 5000, "list": [ghost]}}
        rogue = tch.RawNats(c.nats.url)
        try:
            rogue.sub("_INBOX.rogue")
            rogue.pub("$KV.OCEAND_oceand.sim", json.dumps(old).encode(), reply="_INBOX.rogue")
            _, _, ack = rogue.next_msg(5)
            check(b'"stream"' in ack, "JetStream did not store the old record: %r" % ack)
        finally:
            rogue.close()
        seq0 = max(a.frames) if a.frames else 0
        await asyncio.sleep(4.0)   # the step-down, the lease's expiry, the take-over
        wait_for(lambda: c.active() is not None, "a sim holds the lease")
        _, r = await a.frame_where(lambda r: boat in r, "the boat after the old record", timeout=15,
                                   after=max(a.frames))
        ghosts = [s for s in a.frames if s > seq0 and 4999 in a.frames[s]]
        check(not ghosts, "the old record's body appeared on seqs %r" % ghosts[:5])
        check(not any(m.get("type") == "bodies" and any(e["body"] == 4999 for e in m["bodies"]) for m in a.json),
              "the old record's body in a bodies list")
        for k in range(50):
            m = await a.ask({"type": "steer", "id": 100 + k, "body": boat, "throttle": 0.5})
            if m["type"] == "steered" or m.get("code") != "unavailable":
                break
            await asyncio.sleep(0.2)
        check(m["type"] == "steered", "the owner steers after the old record: %r" % m)
        nxt, _ = await launch(a, 200, x=0.0, z=0.0)
        check(boat < nxt < 4999, "the next id %d (the boat's %d; the old record's next_id 5000)" % (nxt, boat))
        await a.close()
    asyncio.run(run())


def main():
    global ARGS
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", required=True)
    ap.add_argument("--cycles", type=int, default=1)
    ap.add_argument("-k", default="")
    ARGS = ap.parse_args()
    td.ARGS = cr.ARGS = cd.ARGS = ARGS
    if not os.path.exists(oceand_proc.NATS_BIN):
        print("nats-server not found (scripts/deps.sh installs it)")
        print("0 passed, 1 failed")
        return 1
    return cr.run_tests(TESTS, ARGS.k)


if __name__ == "__main__":
    sys.exit(main())

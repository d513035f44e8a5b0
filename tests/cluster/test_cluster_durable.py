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

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "daemon"))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "common"))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "proto", "python"))
import oceand_proc  # noqa: E402
import test_cluster_roles as cr  # noqa: E402
import test_daemon as td  # noqa: E402
from test_cluster_roles import Cluster, Node, wait_for  # noqa: E402
from test_daemon import TestFailure, check, connect, recv_json, recv_frame  # noqa: E402
from oceand import sea as oceansea  # noqa: E402

ARGS = None
TESTS = []


def test(fn):
    TESTS.append(fn)
    return fn


def read_state(path):
    with open(path) as f:
        return json.load(f)


async def set_and_ack(ws, i, wind):
    """One set; its `params` (the ack) or error."""
    await ws.send(json.dumps({"type": "set", "id": i, "params": {"wind_speed": wind}}))
    return await recv_json(ws, lambda m: m["type"] in ("params", "error") and m.get("id") == i, timeout=10)


async def set_until_acked(ws, i, wind, after):
    """A set, sent again while the cluster settles (a sim that just took over, JetStream
    recovering its store): refused or unanswered sets are never acknowledged. Its ack
    must name a version after `after` (a set that timed out at the edge may still have
    been applied: then the version moved by more than one, never back)."""
    deadline = time.time() + 15
    for k in range(200):
        m = await set_and_ack(ws, i + k, wind)
        if m["type"] == "params" or time.time() > deadline:
            break
        check(m["code"] in ("unavailable", "internal"), "set while the cluster settles: %r" % m)
        await asyncio.sleep(0.2)
    check(m["type"] == "params" and m["params_version"] > after and m["params"]["wind_speed"] == wind,
          "set after version %d: %r" % (after, m))
    return m


async def set_until_acked_params(ws, i, params, after):
    """A set of params, sent again while the cluster settles (as set_until_acked)."""
    deadline = time.time() + 15
    for k in range(200):
        await ws.send(json.dumps({"type": "set", "id": i + 1000 * k, "params": params}))
        m = await recv_json(ws, lambda x: x["type"] in ("params", "error") and x.get("id") == i + 1000 * k, timeout=10)
        if m["type"] == "params" or time.time() > deadline:
            break
        check(m["code"] in ("unavailable", "internal"), "set while the cluster settles: %r" % m)
        await asyncio.sleep(0.2)
    check(m["type"] == "params" and m["params_version"] > after, "set after version %d: %r" % (after, m))
    return m


class JsCluster(Cluster):
    """JetStream, sims sims (the first active, the others standbys) and edges edges."""

    def __init__(self, sims=2, edges=1, sim_extra=(), state=None):
        self.tmp = tempfile.mkdtemp(prefix="oceand-durable-")
        self.nodes = []
        if state is not None:   # the first sim's state file
            with open(os.path.join(self.tmp, "sim0-state.json"), "w") as f:
                json.dump(state, f)
        self.nats = oceand_proc.Nats(self.tmp, store=True, error=TestFailure)  # JetStream, its store in tmp
        try:
            self.sims = []
            for i in range(sims):
                n = self.node("sim%d" % i, "--role", "sim", "--nats", self.nats.url, *sim_extra)
                self.sims.append(n)
                wait_for(lambda n=n: n.health()["lease"] in ("active", "standby"), "sim%d has a lease state" % i)
                if i == 0:
                    wait_for(lambda n=n: n.health()["lease"] == "active", "the first sim holds the lease")
            self.sim = self.sims[0]
            self.edges = [self.node("edge%d" % i, "--role", "edge", "--nats", self.nats.url, "--state-file", "none")
                          for i in range(edges)]
            for e in self.edges:
                wait_for(lambda e=e: e.health()["cluster"] == "ok", "edge sees the sim")
        except BaseException:
            self.close()
            raise

    def active(self):
        for n in self.sims:
            if n.proc.poll() is None and n.health()["lease"] == "active":
                return n
        return None


def with_js_cluster(**kw):
    return cr.with_cluster(JsCluster, **kw)


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


def kill_and_restart(c):
    c.sim.kill()            # kill -9, then at once again (within the edges' 2 s detection)
    c.sim.start()


async def set_stream_then_kill(c, ws, watcher, kill_after, kill=kill_and_restart, settle=1.0):
    """Sets one after another (each waits for its ack) while kill(c) kills the
    sim after kill_after s. Returns (last acknowledged (wind, version), winds
    sent, (seq, sim_time, params_version) of the watcher's frames)."""
    acked, sent, versions, replies = None, [], [], []
    stop = asyncio.Event()
    t0 = time.time()

    async def watch():
        while not stop.is_set():
            try:
                h, _ = await recv_frame(watcher, timeout=0.5)
                versions.append((h["seq"], h["sim_time"], h["params_version"]))
            except (TestFailure, asyncio.TimeoutError):
                pass

    async def sets():
        nonlocal acked
        i = 0
        while not stop.is_set():
            i += 1
            wind = 5 + 0.125 * (i % 100)
            sent.append(wind)
            m = await set_and_ack(ws, i, wind)
            replies.append((round(time.time() - t0, 2), m["type"], m.get("code")))
            if m["type"] == "params":
                acked = (wind, m["params_version"])
            else:
                check(m["code"] == "unavailable", "set during the kill: %r" % m)
                await asyncio.sleep(0.05)

    w, t = asyncio.ensure_future(watch()), asyncio.ensure_future(sets())
    await asyncio.sleep(kill_after)
    # at least one set acknowledged first (a loaded machine may answer the first one late)
    await cr.await_for(lambda: acked is not None, "a set acknowledged before the kill (replies %r)" % replies)
    kill(c)   # on this thread: a daemon started from another one dies with it (PR_SET_PDEATHSIG)
    await asyncio.sleep(settle)
    stop.set()
    await asyncio.gather(w, t)
    check(acked is not None, "no set was acknowledged before the kill (at %.2f s): replies %r"
          % (kill_after, replies[:8]))
    return acked, sent, versions


@test
@cr.with_cluster(edges=1)
def test_sim_kill9_during_sets_keeps_the_last_acknowledged(c):
    """A stream of sets through an edge; kill -9 of the sim and an immediate restart
    (shorter than the edge's 2 s detection: it sees a new sim instance in the
    heartbeat and asks hello again). The restarted sim has the last acknowledged set in
    force (or a later one it saved but could not answer); the edge's hello says so; the
    frames' params_version never goes back; a new set gets a version never used."""
    async def run():
        # The edge serves clients as soon as it sees the sim's heartbeat; the sim's hello (and
        # its capacity) follows a request/reply later: on a busy machine, connect again until then.
        deadline = time.time() + 10
        while True:
            ws, h = await connect(c.edges[0])
            if isinstance(h.get("capacity"), dict) or time.time() > deadline:
                break
            await ws.close()
            await asyncio.sleep(0.2)
        check(isinstance(h.get("capacity"), dict) and h["capacity"].get("max_resolution"),
              "an edge's hello without the sim's capacity: %r" % h.get("capacity"))
        watcher, _ = await connect(c.edges[0])
        for cycle in range(ARGS.cycles):
            acked, sent, versions = await set_stream_then_kill(c, ws, watcher, 0.6 + 0.3 * cycle)
            check(acked is not None, "no set was acknowledged before the kill")
            wind, v = acked
            later = sent[sent.index(wind):] if wind in sent else [wind]
            st = read_state(c.sim.state_file)
            check(st["params_version"] >= v, "state file at version %r, %d acknowledged" % (st["params_version"], v))
            # The edge learns the new sim's sea (hello again) without a sim_down.
            def edge_hello():
                async def one():
                    x, hx = await connect(c.edges[0])
                    await x.close()
                    return hx
                return one()
            deadline = time.time() + 10
            while True:
                hx = await edge_hello()
                if hx["params_version"] == st["params_version"]:
                    break
                check(time.time() < deadline, "edge hello at version %r, the sim at %r"
                      % (hx["params_version"], st["params_version"]))
                await asyncio.sleep(0.2)
            check(hx["params"]["wind_speed"] in later, "after kill -9 wind %r; acknowledged %r (version %d)"
                  % (hx["params"]["wind_speed"], wind, v))
            check(hx["params_version"] >= v, "version %r < acknowledged %d" % (hx["params_version"], v))
            pv = [v[2] for v in versions]
            check(pv == sorted(pv), "frame versions went back: %r" % pv[-40:])
            await set_until_acked(ws, 10000 + 1000 * cycle, 21.5 + cycle, hx["params_version"])
        await ws.close()
        await watcher.close()
    asyncio.run(run())


async def edge_hello(edge):
    ws, h = await connect(edge)
    await ws.close()
    return h


async def hello_at(edge, version, what, timeout=10.0):
    """The edge's hello once it reached version (its cache follows the sim)."""
    deadline = time.time() + timeout
    while True:
        h = await edge_hello(edge)
        if h["params_version"] >= version:
            return h
        check(time.time() < deadline, "%s: edge hello at version %r, want %d" % (what, h["params_version"], version))
        await asyncio.sleep(0.1)


def one_active(c):
    """Exactly one live sim holds the lease; returns it."""
    leases = [(n.name, n.health()["lease"]) for n in c.sims if n.proc.poll() is None]
    act = [n for n in c.sims if n.proc.poll() is None and n.health()["lease"] == "active"]
    check(len(act) == 1, "leases: %r" % leases)
    return act[0]


def kill_active(c):
    act = c.active()
    check(act is not None, "no active sim to kill")
    act.kill()
    c.killed = act


@test
@with_js_cluster(sims=2, edges=1)
def test_measured_sea_reaches_the_edge_and_the_standby(c):
    """A `sea` sent through an edge: its sender and the edge's other clients get the
    summary, a new client of the edge has it in hello; the JetStream record carries the
    document, so after a kill -9 of the active sim the standby simulates the same sea
    (spectrum measured, the same summary) at the same version."""
    fixture = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "sea", "fixtures", "ndbc-rt",
                           "46026.data_spec")
    doc = oceansea.public(oceansea.read(fixture))

    async def run():
        ws, _ = await connect(c.edges[0], url=c.edges[0].url + "?frames=0")
        other, _ = await connect(c.edges[0], url=c.edges[0].url + "?frames=0")
        await ws.send(json.dumps({"type": "sea", "id": 1, "sea": doc}))
        m = await recv_json(ws, lambda x: x.get("id") == 1, timeout=15)
        check(m["type"] == "params" and m["params"]["spectrum"] == "measured" and m.get("sea"),
              "the edge's reply to a sea: %r" % {k: m.get(k) for k in ("type", "code", "message")})
        s, v = m["sea"], m["params_version"]
        check(s["source"] == doc["source"] and s["time"] == doc["time"] and s["version"] == v, "summary %r" % s)
        seen = await recv_json(other, lambda x: x["type"] == "params" and x.get("params_version") == v, timeout=10)
        check(seen.get("sea") == s, "the edge's other client got %r" % seen.get("sea"))
        h = await hello_at(c.edges[0], v, "after the sea")
        check(h["sea"] == s, "a new client of the edge: sea %r" % (h["sea"] and h["sea"]["source"]))
        bad = dict(doc, energy=[-1.0] + doc["energy"][1:])
        await ws.send(json.dumps({"type": "sea", "id": 2, "sea": bad}))
        m = await recv_json(ws, lambda x: x.get("id") == 2, timeout=10)
        check(m["type"] == "error" and m["code"] == "sea_negative", "a bad sea through the edge: %r" % m)
        first = one_active(c)
        kill_active(c)
        wait_for(lambda: c.active() not in (None, first), "the standby holds the lease", timeout=10)
        deadline = time.time() + 10
        while True:   # the edge learns the new sim's hello
            h = await hello_at(c.edges[0], v, "after the take-over")
            if h["sea"] and h["sea"]["source"] == s["source"] or time.time() > deadline:
                break
            await asyncio.sleep(0.2)
        check(h["params"]["spectrum"] == "measured" and h["params_version"] >= v, "after the take-over: %s v%d" %
              (h["params"]["spectrum"], h["params_version"]))
        # The new holder's own sea, not the edge's cache: a change of the grid under it makes
        # the holder summarise its sea again (a sim without one would refuse "measured").
        m = await set_until_acked_params(ws, 3, {"patch_size": 512}, h["params_version"])
        hs = m.get("sea")
        check(hs is not None and hs["version"] == m["params_version"] and
              all(hs[k] == s[k] for k in ("source", "time", "hs_m", "tp_s", "dir_from_deg", "polar")),
              "the standby's sea %r, the first sim's %r" % (hs and hs["source"], s["source"]))
        check(h["sea"] == s, "the edge's hello after the take-over: %r" % (h["sea"] and h["sea"]["source"]))
        await ws.close()
        await other.close()
    asyncio.run(run())


@test
@with_js_cluster(sims=2, edges=1)
def test_standby_takes_over_during_sets(c):
    """Two sims on JetStream: kill -9 of the active one during a stream of sets through
    an edge. The standby takes over with the same sea: the last acknowledged set (or a
    later one that was saved) is in force at the same version, sim time and seq go on
    forward, the edge's clients keep their sockets and get frames again; the killed sim
    comes back as the standby, and the next kill hands the lease back."""
    async def run():
        ws, h = await connect(c.edges[0])
        watcher, _ = await connect(c.edges[0])
        for cycle in range(ARGS.cycles):
            first = one_active(c)
            acked, sent, frames = await set_stream_then_kill(c, ws, watcher, 0.7 + 0.2 * cycle, kill=kill_active,
                                                             settle=0.5)
            check(acked is not None, "no set was acknowledged before the kill")
            wind, v = acked
            later = sent[sent.index(wind):]
            wait_for(lambda: c.active() not in (None, first), "the standby holds the lease", timeout=10)
            hx = await hello_at(c.edges[0], v, "after the take-over")
            check(hx["params"]["wind_speed"] in later and hx["params_version"] >= v,
                  "after the take-over: wind %r version %r; acknowledged %r at version %d"
                  % (hx["params"]["wind_speed"], hx["params_version"], wind, v))
            # Frames again on the same socket, continuing the sea forward.
            fh, _ = await recv_frame(watcher, pred=lambda h, b: h["params_version"] >= hx["params_version"], timeout=10)
            last = max(frames) if frames else None
            if last:
                check(fh["seq"] > last[0], "seq after the take-over %d, before %d" % (fh["seq"], last[0]))
                check(fh["sim_time"] >= last[1], "sim time went back: %r -> %r" % (last[1], fh["sim_time"]))
            pv = [f[2] for f in frames] + [fh["params_version"]]
            check(pv == sorted(pv), "frame versions went back: %r" % pv[-40:])
            await set_until_acked(ws, 20000 + 1000 * cycle, 22.5 + cycle, hx["params_version"])
            c.killed.start()   # back as the standby
            wait_for(lambda: c.killed.health()["lease"] == "standby", "the killed sim is a standby again")
            one_active(c)
        check(ws.open and watcher.open, "a client of the edge was disconnected")
        await ws.close()
        await watcher.close()
    asyncio.run(run())


class TemporalViewer:
    """A temporal viewer of an edge that decodes every frame it gets, in order, with one
    decoder state (oceanproto raises ProtocolError `reference` for a predicted tile whose
    references it lacks): per frame (seq, codecs); the first decoding error, if any."""

    def __init__(self, ws, oceanproto):
        self.ws, self.op = ws, oceanproto
        self.state = oceanproto.DecoderState()
        self.frames, self.error, self.stopped = [], None, False
        self.task = asyncio.ensure_future(self.run())

    async def run(self):
        while not self.stopped:   # (a cancel may be lost in wait_for when a frame arrives at once)
            try:
                h, b = await recv_frame(self.ws, timeout=30)
            except Exception:
                return
            try:
                f = self.op.decode_frame(b, self.state)
            except Exception as e:    # noqa: BLE001: kept for the check
                self.error = self.error or "seq %d: %r" % (h["seq"], e)
                continue
            self.frames.append((h["seq"], {t.codec for t in f.tiles}))

    def predicted_after(self, n):
        return sum(1 for _, c in self.frames[n:] if 3 in c)

    async def stop(self):
        self.stopped = True
        self.task.cancel()
        try:
            await self.task
        except asyncio.CancelledError:
            pass


@test
@with_js_cluster(sims=2, edges=1, sim_extra=("--tick-rate", "10"))
def test_temporal_viewer_across_take_overs(c):
    """A temporal viewer of an edge (the sim encodes its layers' stream once, the edge
    relays it) across a kill -9 of the active sim and then a SIGSTOP of the new one (the
    stalled holder runs again while the other acts): the new sim's chains are new, so the
    edge lets no viewer's references span two sim processes (oceand_cluster_new_chains_total)
    and the viewer takes keyframes first; it decodes every frame it gets in order with one
    decoder state, and gets predicted tiles again after each take-over. (10 Hz: the sims'
    plans keep the temporal codec on a loaded machine or under ASan.)"""
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "proto", "examples"))
    import oceanproto

    async def run():
        ws, _ = await connect(c.edges[0])
        await ws.send('{"type":"subscribe","id":1,"temporal":true,"adapt":false}')
        await recv_json(ws, lambda m: m["type"] in ("subscribed", "error"))
        v = TemporalViewer(ws, oceanproto)

        async def frames_on(what, n0, count=10, timeout=60):
            deadline = time.time() + timeout
            while len(v.frames) < n0 + count or not v.predicted_after(n0):
                check(v.error is None, "%s: %s" % (what, v.error))
                check(time.time() < deadline, "%s: %d frames, %d with predicted tiles"
                      % (what, len(v.frames) - n0, v.predicted_after(n0)))
                await asyncio.sleep(0.05)

        await frames_on("before", 0)
        chains0 = c.edges[0].metric("oceand_cluster_new_chains_total")
        first = one_active(c)
        n = len(v.frames)
        kill_active(c)
        wait_for(lambda: c.active() not in (None, first), "the standby holds the lease", timeout=10)
        await frames_on("after the take-over", n)
        check(c.edges[0].metric("oceand_cluster_new_chains_total") > chains0,
              "the edge did not start new chains for the other sim")
        c.killed.start()
        wait_for(lambda: c.killed.health()["lease"] == "standby", "the killed sim is a standby again")
        # the stalled holder: it runs again while the other one acts
        old = one_active(c)
        n = len(v.frames)
        old.proc.send_signal(signal.SIGSTOP)
        try:
            wait_for(lambda: any(x is not old and x.health()["lease"] == "active" for x in c.sims),
                     "the standby took over from the stalled one", timeout=10)
        finally:
            old.proc.send_signal(signal.SIGCONT)
        wait_for(lambda: old.health()["lease"] == "standby", "the stalled holder stepped down")
        await frames_on("after the stalled holder ran again", n)
        seqs = [sq for sq, _ in v.frames]
        check(seqs == sorted(seqs) and len(set(seqs)) == len(seqs), "seq went back or repeated at the viewer")
        check(v.error is None, "decoding: %s" % v.error)
        print("  %d frames, %d with predicted tiles, new chains at the edge: %d" % (
            len(v.frames), v.predicted_after(0), c.edges[0].metric("oceand_cluster_new_chains_total")))
        await v.stop()
        await ws.close()
    asyncio.run(run())


@test
@with_js_cluster(sims=2, edges=1)
def test_stalled_holder_steps_down(c):
    """The active sim stops (SIGSTOP) past its lease: the standby takes over; when the
    old one runs again its next write finds the record taken, and it steps down
    without answering or publishing: one active sim at a time, no version reused."""
    async def run():
        ws, h = await connect(c.edges[0])
        m = await set_and_ack(ws, 1, 14.5)
        check(m["type"] == "params", "set: %r" % m)
        old = one_active(c)
        old.proc.send_signal(signal.SIGSTOP)
        try:
            wait_for(lambda: any(n is not old and n.health()["lease"] == "active" for n in c.sims),
                     "the standby took over", timeout=10)
            m2 = await set_until_acked(ws, 100, 15.5, m["params_version"])
        finally:
            old.proc.send_signal(signal.SIGCONT)
        wait_for(lambda: old.health()["lease"] == "standby", "the stalled holder stepped down")
        one_active(c)
        m3 = await set_until_acked(ws, 300, 16.5, m2["params_version"])
        hx = await hello_at(c.edges[0], m3["params_version"], "after the step-down")
        check(hx["params"]["wind_speed"] == 16.5, "hello %r" % hx["params"])
        await ws.close()
    asyncio.run(run())


@test
@with_js_cluster(sims=1, edges=1)
def test_older_state_file_cannot_push_the_version_back(c):
    """The sim restarts with a state file older than what it acknowledged (a copy from
    before the last sets): the record in JetStream is newer and wins, so the version
    and the parameters are the last acknowledged ones, never the file's."""
    async def run():
        ws, h = await connect(c.edges[0])
        m = await set_and_ack(ws, 1, 8.5)
        check(m["type"] == "params", "set: %r" % m)
        shutil.copy(c.sim.state_file, c.sim.state_file + ".old")
        for i in range(3):
            m = await set_and_ack(ws, 2 + i, 9.5 + i)
            check(m["type"] == "params", "set: %r" % m)
        v = m["params_version"]
        c.sim.kill()
        shutil.copy(c.sim.state_file + ".old", c.sim.state_file)
        check(read_state(c.sim.state_file)["params_version"] == v - 3, "the old file")
        c.sim.start()
        wait_for(lambda: c.sim.health()["lease"] == "active", "the restarted sim holds the lease")
        hx = await hello_at(c.edges[0], v, "after the restart with an old file")
        check(hx["params_version"] == v and hx["params"]["wind_speed"] == 11.5,
              "restarted with an old state file: version %r wind %r, acknowledged %d wind 11.5"
              % (hx["params_version"], hx["params"]["wind_speed"], v))
        fh, _ = await recv_frame(ws, timeout=10)
        check(fh["params_version"] >= v, "a frame of version %r after the restart" % fh["params_version"])
        m = await set_and_ack(ws, 9, 12.5)
        check(m["type"] == "params" and m["params_version"] == v + 1, "next set: %r" % m)
        await ws.close()
    asyncio.run(run())


@test
@with_js_cluster(sims=2, edges=2)
def test_nats_and_edge_kill9_lose_no_acknowledged_set(c):
    """kill -9 of nats-server right after an acknowledged set, restart on the same port
    and store: the set is in force, one sim holds the lease, the next set gets the next
    version. Then kill -9 of an edge right after a set: the other edge's clients have
    it, and the restarted edge's hello too."""
    async def run():
        ws, h = await connect(c.edges[0])
        m = await set_and_ack(ws, 1, 17.25)
        check(m["type"] == "params", "set: %r" % m)
        await ws.close()
        c.nats.stop()
        time.sleep(0.5)
        c.nats.start()
        for e in c.edges:
            wait_for(lambda e=e: e.health()["cluster"] == "ok", "edge back after NATS", timeout=20)
        wait_for(lambda: c.active() is not None, "a sim holds the lease after NATS came back", timeout=20)
        one_active(c)
        hx = await hello_at(c.edges[0], m["params_version"], "after NATS")
        check(hx["params_version"] == m["params_version"] and hx["params"]["wind_speed"] == 17.25,
              "after kill -9 of NATS: %r at %r" % (hx["params"]["wind_speed"], hx["params_version"]))
        ws, _ = await connect(c.edges[0])
        other, _ = await connect(c.edges[1])
        # JetStream may still be recovering its store: a set it cannot save is refused
        # (or times out at the edge), never acknowledged; one is within a few seconds.
        m2 = await set_until_acked(ws, 2, 18.25, m["params_version"])
        c.edges[0].kill()
        p = await recv_json(other, lambda j: j["type"] == "params" and j["params_version"] == m2["params_version"])
        check(p["params"]["wind_speed"] == 18.25, "the other edge's params %r" % p)
        c.edges[0].start()
        hx = await hello_at(c.edges[0], m2["params_version"], "restarted edge")
        check(hx["params"]["wind_speed"] == 18.25, "restarted edge's hello %r" % hx["params"])
        await other.close()
    asyncio.run(run())


# ---------------------------------------------------------------- records ordered by version, clocks at their limit

TIME_MAX = 1e9   # OCEAN_TIME_MAX: the sea's clock stops there


def metric_of(node, name):
    return node.metric(name)


@test
@with_js_cluster(sims=2, edges=1, state={"params": {"time_scale": 16}, "params_version": 5,
                                         "sim_time": TIME_MAX - 1.5})
def test_standby_follows_a_holder_whose_clock_is_at_its_limit(c):
    """The holder's clock passed 1e9 s (999999998.5 at time_scale 16) and the standby's record
    parser, whose limit is 1e9, refused every record from then on: after a kill -9 of the
    holder it took over with its own older state, and the acknowledged set was lost. The
    clock stops at its limit now, the parser takes every record the holder can write, and
    the standby follows and takes over with the acknowledged set."""
    async def run():
        standby = c.sims[1]
        await asyncio.sleep(1.0)                     # the holder's clock is at its limit by now
        check(metric_of(c.sim, "oceand_sim_time_seconds") == TIME_MAX,
              "the holder's clock: %r" % metric_of(c.sim, "oceand_sim_time_seconds"))
        ws, h = await connect(c.edges[0])
        m = await set_and_ack(ws, 1, 13.5)
        check(m["type"] == "params", "set: %r" % m)
        v = m["params_version"]
        await ws.close()
        wait_for(lambda: metric_of(standby, "oceand_params_version") == v, "the standby follows version %d" % v)
        c.sim.kill()
        wait_for(lambda: standby.health()["lease"] == "active", "the standby takes over")
        hx = await hello_at(c.edges[0], v, "after the take-over")
        check(hx["params_version"] == v and hx["params"]["wind_speed"] == 13.5,
              "after the take-over: version %r wind %r, acknowledged %d wind 13.5"
              % (hx["params_version"], hx["params"]["wind_speed"], v))
        check(metric_of(standby, "oceand_sim_time_seconds") == TIME_MAX,
              "the new holder's clock: %r" % metric_of(standby, "oceand_sim_time_seconds"))
    asyncio.run(run())


@test
@with_js_cluster(sims=2, edges=1)
def test_an_older_record_never_takes_the_version_back(c):
    """A record of version 1 written into the bucket after version 3 was acknowledged (a
    stale copy, a restored bucket, anyone who may write it) was adopted by both sims, as
    any version other than their own: frames went from 3 back to 1 and later sets reused 2
    and 3. A sim adopts only a newer record; the holder that finds its lease taken by the
    older record steps down, and then the one that takes the lease keeps its own state."""
    import test_cluster_hostile as tch
    async def run():
        ws, h = await connect(c.edges[0])
        for i in range(3):
            m = await set_and_ack(ws, 1 + i, 9.5 + i)
            check(m["type"] == "params", "set: %r" % m)
        v = m["params_version"]
        wait_for(lambda: metric_of(c.sims[1], "oceand_params_version") == v, "the standby follows version %d" % v)
        # Frames made before the last set may still be queued to this client after its answer
        # (a frame shows the version it was computed with): read up to the first of version v,
        # so that what is judged below is what came after the old record, not before it.
        t_end = time.time() + 10.0
        while True:
            check(time.time() < t_end, "no frame of version %d within 10 s of its answer" % v)
            try:
                fh, _ = await recv_frame(ws, timeout=1.0)
            except (TestFailure, asyncio.TimeoutError):
                continue
            if fh["params_version"] >= v:
                break
        rogue = tch.RawNats(c.nats.url)
        try:
            old = {"holder": "rogue-1", "name": "rogue", "released": False, "params": {"wind_speed": 4.5},
                   "params_version": v - 2, "sim_time": 100.0, "wall_us": int(time.time() * 1e6), "seq": 1,
                   "tick_rate": 30}
            rogue.sub("_INBOX.rogue")
            rogue.pub("$KV.OCEAND_oceand.sim", json.dumps(old).encode(), reply="_INBOX.rogue")
            _, _, ack = rogue.next_msg(5)
            check(b'"stream"' in ack, "JetStream did not store the old record: %r" % ack)
        finally:
            rogue.close()
        versions = []
        t_end = time.time() + 4.0                    # the step-down, the lease's expiry, the take-over
        while time.time() < t_end:
            try:
                fh, _ = await recv_frame(ws, timeout=1.0)
                versions.append(fh["params_version"])
            except (TestFailure, asyncio.TimeoutError):
                pass
        check(versions and min(versions) >= v, "frames went back to version %r (acknowledged %d)"
              % (min(versions or [None]), v))
        wait_for(lambda: c.active() is not None, "a sim holds the lease")
        one_active(c)
        for n in c.sims:
            check(metric_of(n, "oceand_params_version") >= v, "%s went back to version %r"
                  % (n.name, metric_of(n, "oceand_params_version")))
        hx = await hello_at(c.edges[0], v, "after the old record")
        check(hx["params_version"] == v and hx["params"]["wind_speed"] == 11.5,
              "after the old record: version %r wind %r" % (hx["params_version"], hx["params"]["wind_speed"]))
        m = await set_until_acked(ws, 10, 12.5, v)
        check(m["params_version"] == v + 1, "the next set got version %r, want %d" % (m["params_version"], v + 1))
        await ws.close()
    asyncio.run(run())


def main():
    global ARGS
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", required=True)
    ap.add_argument("--cycles", type=int, default=3)
    ap.add_argument("--recovery-s", type=float, default=2.0)
    ap.add_argument("-k", default="")
    ARGS = ap.parse_args()
    td.ARGS = cr.ARGS = ARGS
    if not os.path.exists(oceand_proc.NATS_BIN):
        print("nats-server not found (scripts/deps.sh installs it)")
        return 1
    return cr.run_tests(TESTS, ARGS.k)


if __name__ == "__main__":
    sys.exit(main())

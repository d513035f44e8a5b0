#!/usr/bin/python3
"""A stream that fits the link (PROTOCOL.md §7.2 `link`, server/net/ladder.c),
over emulated links: two network namespaces joined by bench/links/shaper.

Behaviour, never timings: the ladder steps down on a slow link (a `link`
message, coarser tiles, the temporal codec reached); `adapt: false` pins a
subscription (no step, tiles as asked); after a stall a viewer gets back to
predicted tiles and every frame it received decodes in order (frame_check);
a reply overtakes the frames queued for a saturated link (at most the frame
in progress and what the short queue holds arrive before it). Without root
(no namespaces) the emulated part says so and the loopback part runs. One
case runs through an edge (`--role edge`, a sim and nats-server beside it).

    /usr/bin/python3 tests/links/test_links.py --oceand build/oceand --shaper build/shaper \\
        --frame-check build/frame_check [-k NAME]
"""
import argparse
import asyncio
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import urllib.request

import websockets

NATS_BIN = shutil.which("nats-server") or "/usr/sbin/nats-server"

ARGS = None
WEB_SUB = {"type": "subscribe", "id": "sub", "fields": ["height", "dx", "dz", "foam"], "field_lod": {"foam": 2},
           "cascades": [{"fields": ["height"], "lod": 1, "bound": 0.001}] * 3, "temporal": True}


class Failure(Exception):
    pass


def check(cond, msg):
    if not cond:
        raise Failure(msg)


def tiles(b):
    count, = struct.unpack_from("<H", b, 36)
    off, out = 48, []
    for _ in range(count):
        field, lod, codec, flags = b[off], b[off + 1], b[off + 2], b[off + 3]
        plen, = struct.unpack_from("<I", b, off + 32)
        out.append((field, lod, codec, flags & 3))
        off += 40 + plen
    return out


def seq_of(b):
    return struct.unpack_from("<Q", b, 8)[0]


def can_namespace():
    if os.geteuid() != 0 or not os.path.exists("/dev/net/tun"):
        return False
    name = "lnkprobe%d" % os.getpid()
    ok = subprocess.run(["ip", "netns", "add", name], capture_output=True).returncode == 0
    subprocess.run(["ip", "netns", "del", name], capture_output=True)
    return ok


def ip(*a):
    subprocess.run(["ip"] + list(a), check=True, capture_output=True)


class Lab:
    """oceand in namespace A behind the shaper; the clients run as this
    file's client mode in namespace B (client_in_b)."""

    def __init__(self, kbit, rtt_ms, loss=0, extra=(), role="all"):
        self.tmp = tempfile.mkdtemp(prefix="links-")
        self.log = open(os.path.join(self.tmp, "oceand.log"), "wb")
        self.procs, self.daemons = [], []   # started in this order, stopped in the other; the oceands
        self.shaper = None
        try:
            self.setup(kbit, rtt_ms, loss, extra, role)
        except BaseException:
            self.close()
            raise

    def setup(self, kbit, rtt_ms, loss, extra, role):
        pid = os.getpid()
        self.a, self.b = "lnkta%d" % pid, "lnktb%d" % pid
        self.net = "10.202.%d" % (pid % 200 + 20)
        ip("netns", "add", self.a)
        ip("netns", "add", self.b)
        ip("-n", self.a, "link", "set", "lo", "up")
        ip("-n", self.b, "link", "set", "lo", "up")
        q = max(32768, kbit * 1000 // 8 // 10)
        self.shaper = subprocess.Popen([ARGS.shaper, self.a, self.b, str(kbit), str(rtt_ms / 2), str(loss), str(q)],
                                       stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        check(self.shaper.stdout.readline().strip() == "ready", "shaper did not start")
        ip("-n", self.a, "addr", "add", self.net + ".1", "peer", self.net + ".2", "dev", "lnk0")
        ip("-n", self.a, "link", "set", "lnk0", "up")
        ip("-n", self.b, "addr", "add", self.net + ".2", "peer", self.net + ".1", "dev", "lnk0")
        ip("-n", self.b, "link", "set", "lnk0", "up")
        common = ["--web-root", os.path.join(self.tmp, "web"), "--resolution", "256", "--plan-rigor", "0",
                  "--wisdom-file", "none"] + list(extra)
        state = os.path.join(self.tmp, "state.json")
        self.url = "ws://%s.1:8091/" % self.net
        if role == "all":
            self.proc = self.start([ARGS.oceand, "--bind", self.net + ".1", "--port", "8091", "--state-file", state]
                                   + common, daemon=True)
            self.wait_health("http://%s.1:8091" % self.net, "True")
            return
        # an edge, fed by a sim over nats-server, all three in namespace A (the sim and NATS on its loopback)
        nats = self.start([NATS_BIN, "-a", "127.0.0.1", "-p", "4222"])
        deadline = time.time() + 10
        while self.in_a(["bash", "-c", "exec 3<>/dev/tcp/127.0.0.1/4222"]).returncode != 0:
            check(nats.poll() is None and time.time() < deadline, "nats-server did not listen")
            time.sleep(0.1)
        sim = self.start([ARGS.oceand, "--role", "sim", "--nats", "nats://127.0.0.1:4222", "--bind", "127.0.0.1",
                          "--port", "8092", "--state-file", state] + common, daemon=True)
        self.wait_health("http://127.0.0.1:8092", "True", sim)
        self.proc = self.start([ARGS.oceand, "--role", "edge", "--nats", "nats://127.0.0.1:4222", "--bind",
                                self.net + ".1", "--port", "8091", "--state-file", "none"] + common, daemon=True)
        self.wait_health("http://%s.1:8091" % self.net, "j.get('cluster') == 'ok'")

    def in_a(self, argv):
        return subprocess.run(["ip", "netns", "exec", self.a] + argv, capture_output=True)

    def start(self, argv, daemon=False):
        p = subprocess.Popen(["ip", "netns", "exec", self.a] + argv, stdout=self.log, stderr=self.log)
        self.procs.append(p)
        if daemon:
            self.daemons.append(p)
        return p

    def wait_health(self, base, cond, proc=None):
        """Until base/healthz answers and cond (Python, on its JSON j) holds."""
        proc = proc or self.proc
        deadline = time.time() + 30
        while self.in_a(["/usr/bin/python3", "-c", "import json,sys,urllib.request\n"
                         "j=json.loads(urllib.request.urlopen('%s/healthz',timeout=1).read())\n"
                         "sys.exit(0 if %s else 1)" % (base, cond)]).returncode != 0:
            check(proc.poll() is None, "oceand exited at start")
            check(time.time() < deadline, "oceand did not answer %s/healthz as expected" % base)
            time.sleep(0.2)

    def stall(self):
        self.shaper.send_signal(signal.SIGUSR1)  # toggles

    def close(self):
        """Stop the daemons (and nats-server), last started first; returns the first non-zero
        exit code of the oceands (0 when each exited 0) and their log."""
        for p in self.procs[::-1] + ([self.shaper] if self.shaper else []):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        rc = next((p.returncode for p in self.daemons if p.returncode != 0), 0)
        self.log.close()
        log = open(os.path.join(self.tmp, "oceand.log"), errors="replace").read()
        if getattr(self, "a", None):
            subprocess.run(["ip", "netns", "del", self.a], capture_output=True)
            subprocess.run(["ip", "netns", "del", self.b], capture_output=True)
        shutil.rmtree(self.tmp, ignore_errors=True)
        return rc, log


def client_in_b(lab, script_args):
    """Run this file's client mode in namespace B; returns its JSON result."""
    r = subprocess.run(["ip", "netns", "exec", lab.b, "/usr/bin/python3", os.path.abspath(__file__), "--client",
                        lab.url] + script_args, capture_output=True, text=True, timeout=120)
    check(r.returncode == 0, "client failed: %s" % r.stderr[-2000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------ client mode (in B)

async def client_main(url, mode, seconds, pinned, frames_dir):
    sub = dict(WEB_SUB)
    if frames_dir:  # frame_check recomputes cascade 0 from the params: not foam (a state), not the finer cascades
        sub["fields"] = ["height", "dx", "dz"]
        sub["cascades"] = []
        del sub["field_lod"]
    if pinned:
        sub["adapt"] = False
    if mode == "ping-parts":
        sub["parts"] = True
    out = {"links": [], "frames": 0, "codecs_after": {}, "lods": [], "pings": [], "messages": 0, "mid_tick_pongs": 0}
    in_tick = False   # the last binary message was a part with more to come (PROTOCOL.md §3.4)
    async with websockets.connect(url, subprotocols=["oceand.v1"], max_size=None, ping_interval=None,
                                  open_timeout=20) as ws:
        hello = json.loads(await ws.recv())
        out["params"] = hello["params"]
        await ws.send(json.dumps(sub))
        t0 = time.time()
        i = 0
        ping_at = {}
        next_ping = t0 + 4
        k = 0
        while time.time() - t0 < seconds:
            if mode.startswith("ping") and time.time() >= next_ping and k < 5:
                k += 1
                ping_at[k] = out["frames"]
                await ws.send(json.dumps({"type": "ping", "id": k}))
                next_ping = time.time() + 1.5
            try:
                m = await asyncio.wait_for(ws.recv(), 0.5)
            except asyncio.TimeoutError:
                continue
            if isinstance(m, bytes):
                out["messages"] += 1
                in_tick = bool(struct.unpack_from("<H", m, 38)[0] & 2)
                if in_tick:
                    continue
                out["frames"] += 1
                ts = tiles(m)
                out["lods"].append(sorted(set((c, l) for _, l, _, c in ts)))
                out.setdefault("codec_seq", []).append([seq_of(m), round(time.time() - t0, 2),
                                                        sum(1 for t in ts if t[2] == 3), len(ts)])
                if frames_dir:
                    with open(os.path.join(frames_dir, "f%06d.bin" % i), "wb") as f:
                        f.write(m)
                i += 1
                continue
            j = json.loads(m)
            if j.get("type") == "link":
                out["links"].append(dict(t=round(time.time() - t0, 2), rung=j["rung"], sub=j["subscription"],
                                         at_frame=out["frames"]))
            elif j.get("type") == "degraded":
                out["degraded"] = j.get("active", False) or out.get("degraded", False)
            elif j.get("type") == "subscribed":
                out["subscribed"] = j["subscription"]
            elif j.get("type") == "pong":
                out["pings"].append(out["frames"] - ping_at[j["id"]])
                out["mid_tick_pongs"] += in_tick
    print(json.dumps(out))


# ------------------------------------------------------------ tests

TESTS = []


def test(fn):
    TESTS.append(fn)
    return fn


def loopback_daemon(tmp):
    port = 8200 + os.getpid() % 500
    log = open(os.path.join(tmp, "oceand.log"), "wb")
    p = subprocess.Popen([ARGS.oceand, "--port", str(port), "--state-file", os.path.join(tmp, "s.json"),
                          "--web-root", os.path.join(tmp, "web"), "--resolution", "64", "--plan-rigor", "0",
                          "--wisdom-file", "none"], stdout=log, stderr=log)
    for _ in range(150):
        try:
            urllib.request.urlopen("http://127.0.0.1:%d/healthz" % port, timeout=1).read()
            break
        except OSError:
            time.sleep(0.1)
    return p, port, log


@test
def test_loopback_adapt_member():
    """adapt: false is accepted and echoed, a bad type is bad_subscription, a
    reading client on loopback stays on the first rung (no `link`)."""
    tmp = tempfile.mkdtemp(prefix="links-lo-")
    p, port, log = loopback_daemon(tmp)
    try:
        async def body():
            async with websockets.connect("ws://127.0.0.1:%d/" % port, subprotocols=["oceand.v1"],
                                          max_size=None) as ws:
                await ws.recv()
                await ws.send(json.dumps({"type": "subscribe", "id": 1, "adapt": "no"}))
                await ws.send(json.dumps({"type": "subscribe", "id": 2, "adapt": False, "temporal": True}))
                await ws.send(json.dumps({"type": "subscribe", "id": 3, "adapt": True}))
                got, links, frames = {}, 0, 0
                t0 = time.time()
                while time.time() - t0 < 3:
                    try:
                        m = await asyncio.wait_for(ws.recv(), 0.5)
                    except asyncio.TimeoutError:
                        continue
                    if isinstance(m, bytes):
                        frames += 1
                        continue
                    j = json.loads(m)
                    if j.get("id") in (1, 2, 3):
                        got[j["id"]] = j
                    links += j.get("type") == "link"
                return got, links, frames
        got, links, frames = asyncio.run(body())
        check(got[1]["type"] == "error" and got[1]["code"] == "bad_subscription", "adapt \"no\": %r" % got[1])
        check(got[2]["subscription"].get("adapt") is False, "adapt false not echoed: %r" % got[2])
        check("adapt" not in got[3]["subscription"], "adapt true is the default, not written: %r" % got[3])
        check(frames > 30 and links == 0, "loopback reader: %d frames, %d link messages" % (frames, links))
    finally:
        p.send_signal(signal.SIGTERM)
        p.wait(10)
        log.close()
        shutil.rmtree(tmp, ignore_errors=True)
    check(p.returncode == 0, "daemon exit %r" % p.returncode)


def lab_test(fn):
    fn.lab = True
    return test(fn)


def steps_down(role, seconds):
    lab = Lab(1000, 100, role=role)
    try:
        r = client_in_b(lab, ["--mode", "plain", "--seconds", str(seconds)])
    finally:
        rc, log = lab.close()
    check(rc == 0, "daemon exit %r: %s" % (rc, log[-2000:]))
    if not r["links"] and r.get("degraded"):
        # A daemon short of CPU (a sanitizer build) serves every group coarser
        # itself (`degraded`): the stream may then fit the link as it is.
        print("    served coarser by the encode plan (`degraded`): no step needed")
        return
    check(r["links"], "no `link` message on a 1 Mbit/s link")
    down = [x for x in r["links"] if x["rung"] > 0]
    check(down, "no step down: %r" % r["links"])
    sub = down[0]["sub"]
    coarser = (sub["lod"] > 0 or "cascades" not in sub or any(c["lod"] > 1 for c in sub["cascades"])
               or sub["bound"] > 0.01)
    check(coarser, "rung %d serves as asked: %r" % (down[0]["rung"], sub))
    # The frames on a lower rung: from the first step down until a step back to rung 0 (a later
    # step near the end of the window may leave no frame after it to look at).
    start = down[0]["at_frame"]
    ups = [x["at_frame"] for x in r["links"] if x["rung"] == 0 and x["at_frame"] > start]
    after = r["codec_seq"][start:ups[0] if ups else len(r["codec_seq"])]
    check(any(p == n and n > 0 for _, _, p, n in after),
          "no all-predicted frame on the lower rung (%d frames after the first step down; steps %r)"
          % (len(after), [(x["rung"], x["at_frame"]) for x in r["links"]]))


@lab_test
def test_slow_link_steps_down():
    """1 Mbit/s, 100 ms: the web client's subscription does not fit; the server
    steps down (`link`, rung > 0, a coarser subscription), the frames after it
    carry the coarser tiles, and predicted tiles arrive on the lower rung."""
    steps_down("all", 14)


@lab_test
def test_edge_slow_link_steps_down():
    """The same through an edge (`--role edge`, fed by `--role sim` over
    nats-server, all in the server's namespace): the edge's ladder steps down
    and predicted tiles arrive on the lower rung."""
    steps_down("edge", 12)


@lab_test
def test_pinned_skips_instead():
    """Same link, adapt: false: no step (no `link` with rung > 0), every tile at
    the LOD asked for."""
    lab = Lab(1000, 100)
    try:
        r = client_in_b(lab, ["--mode", "plain", "--seconds", "8", "--pinned"])
    finally:
        rc, log = lab.close()
    check(rc == 0, "daemon exit %r" % rc)
    check(not [x for x in r["links"] if x["rung"] > 0], "a pinned subscription stepped: %r" % r["links"])
    asked = {(0, 0), (0, 2), (1, 1), (2, 1), (3, 1)}
    late = [set(map(tuple, l)) for l in r["lods"][3:]]
    check(late, "no frames")
    if not r.get("degraded"):  # else the encode plan serves it coarser on purpose (`degraded`), not the ladder
        check(all(l <= asked for l in late), "pinned frames at other LODs: %r" % late[:3])


@lab_test
def test_stall_recovers_to_temporal():
    """10 Mbit/s, 50 ms, a 3 s stall: predicted tiles again after it, and every
    frame received decodes in order with one decoder."""
    lab = Lab(10000, 50)
    frames_dir = os.path.join(lab.tmp, "frames")
    os.makedirs(frames_dir)
    try:
        client = subprocess.Popen(["ip", "netns", "exec", lab.b, "/usr/bin/python3", os.path.abspath(__file__),
                                   "--client", lab.url, "--mode", "plain", "--seconds", "16",
                                   "--frames-dir", frames_dir], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True)
        time.sleep(7)
        lab.stall()
        time.sleep(3)
        lab.stall()
        out, err = client.communicate(timeout=60)
        check(client.returncode == 0, "client failed: %s" % err[-2000:])
        r = json.loads(out.strip().splitlines()[-1])
        files = sorted(os.listdir(frames_dir))
        pfile = os.path.join(lab.tmp, "params.json")
        with open(pfile, "w") as f:
            json.dump({"params": r["params"]}, f)
        fc = subprocess.run([ARGS.frame_check, pfile] + [os.path.join(frames_dir, x) for x in files],
                            capture_output=True, text=True, timeout=300)
    finally:
        rc, log = lab.close()
    check(rc == 0, "daemon exit %r" % rc)
    check(fc.returncode == 0, "frame_check failed:\n%s%s" % (fc.stdout[-1500:], fc.stderr[-1500:]))
    cs = r["codec_seq"]
    # the stall: the longest gap between arrivals; predicted tiles after it
    gaps = [(cs[i + 1][1] - cs[i][1], i + 1) for i in range(len(cs) - 1)]
    _, after = max(gaps)
    check(after < len(cs) - 10, "no frames after the stall")
    check(any(p == n and n > 0 for _, _, p, n in cs[after:]), "no all-predicted frame after the stall")


def pings_over_2mbit(mode):
    """The ping client (pinned at full detail) 13 s over 2 Mbit/s, 100 ms; the
    daemon must exit cleanly."""
    lab = Lab(2000, 100)
    try:
        r = client_in_b(lab, ["--mode", mode, "--seconds", "13", "--pinned"])
    finally:
        rc, _ = lab.close()
    check(rc == 0, "daemon exit %r" % rc)
    return r


@lab_test
def test_replies_overtake_frames():
    """2 Mbit/s, 100 ms, pinned at full detail (the link is saturated): a ping's
    answer waits behind the frame in progress and the short queue only, not
    behind a queue of frames: few frames arrive between ping and pong."""
    r = pings_over_2mbit("ping")
    check(len(r["pings"]) >= 3, "pongs: %r" % r["pings"])
    check(max(r["pings"]) <= 3, "frames received between ping and pong: %r" % r["pings"])


@lab_test
def test_replies_go_between_parts():
    """As above, with "parts": the frames (about 100 kB at full detail, intra: 0.4 s
    of the link each) come in parts of about a tick of the link, and a pong goes
    between two parts of one tick instead of after the whole frame."""
    r = pings_over_2mbit("ping-parts")
    print("    %d messages for %d ticks; pongs after %r ticks, %d of %d between two parts of one tick"
          % (r["messages"], r["frames"], r["pings"], r["mid_tick_pongs"], len(r["pings"])))
    check(r["messages"] >= 2 * r["frames"], "frames did not come in parts: %d messages, %d ticks"
          % (r["messages"], r["frames"]))
    check(len(r["pings"]) >= 3, "pongs: %r" % r["pings"])
    check(r["mid_tick_pongs"] >= 1, "no pong came between two parts of a tick")
    check(max(r["pings"]) <= 3, "ticks received between ping and pong: %r" % r["pings"])


def main():
    global ARGS
    p = argparse.ArgumentParser()
    p.add_argument("--oceand")
    p.add_argument("--shaper")
    p.add_argument("--frame-check")
    p.add_argument("-k", default="")
    p.add_argument("--client")
    p.add_argument("--mode", default="plain")
    p.add_argument("--seconds", type=float, default=10)
    p.add_argument("--pinned", action="store_true")
    p.add_argument("--frames-dir")
    ARGS = p.parse_args()
    if ARGS.client:
        asyncio.run(client_main(ARGS.client, ARGS.mode, ARGS.seconds, ARGS.pinned, ARGS.frames_dir))
        return 0
    lab_ok = can_namespace()
    if not lab_ok:
        print("test-links: no network namespaces (needs root and /dev/net/tun): emulated links skipped, "
              "loopback part only")
    passed = failed = skipped = 0
    for fn in TESTS:
        if ARGS.k and not any(k in fn.__name__ for k in ARGS.k.split(",")):
            continue
        if getattr(fn, "lab", False) and not lab_ok:
            skipped += 1
            continue
        t0 = time.time()
        try:
            fn()
            passed += 1
            print("PASS %s (%.1f s)" % (fn.__name__, time.time() - t0), flush=True)
        except Exception:
            failed += 1
            print("FAIL %s\n%s" % (fn.__name__, traceback.format_exc()), flush=True)
    print("%d passed, %d failed%s" % (passed, failed, ", %d skipped" % skipped if skipped else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

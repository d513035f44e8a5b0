#!/usr/bin/python3
"""Integration tests of exact-time renders (`render`, PROTOCOL.md §7.5)
against a real oceand, reusing test_daemon.py's harness.

    /usr/bin/python3 tests/daemon/test_render.py --oceand build/oceand --frame-check build/frame_check

- a render of 10 frames at 24 fps from T: `rendering`, then exactly 10 frames
  flagged rendered (frame header flags bit 0) with seq 0..9 and sim_time
  T + k/24 to 1e-6 s, no gap, then `rendered`; every frame decodes and its
  heights at grid nodes equal `query` at the frame's time (one cascade,
  choppiness 0: a node is its own source; float32 FFT vs double sum, 0.1 mm);
  a lossy render at the paused live sea's time equals the live lossless
  frame within its bound; three cascades: every cascade's layers are there;
- bad values get `bad_render` (or bad_message) with the id, and render nothing;
- `busy` when the render budget is spent (--render-max-units), and while the
  client's own render runs; render_cancel ends it with `rendered` "cancelled";
- a client that reads nothing holds the render at its window (the worker
  waits: it does not render ahead), and a client that goes away mid-render
  frees its render: the whole budget is available again.
"""
import argparse
import asyncio
import json
import os
import random
import socket
import struct
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "proto", "examples"))
import test_daemon as td  # noqa: E402
import oceanproto  # noqa: E402
from test_daemon import check, connect, recv_json  # noqa: E402
from harness import running, run_tests  # noqa: E402

TESTS = []
RENDERED = 1  # frame header flags bit 0


def test(fn):
    TESTS.append(fn)
    return fn


def flags(b):
    return struct.unpack_from("<H", b, 38)[0]


async def set_params(ws, params, rid):
    await ws.send(json.dumps({"type": "set", "id": rid, "params": params}))
    m = await recv_json(ws, lambda m: m.get("id") == rid, timeout=10)
    check(m["type"] == "params", "set refused: %r" % m)
    return m


async def quiet(ws, rid=90):
    """Live frames are not wanted: one tile of one field once a second."""
    await ws.send(json.dumps({"type": "subscribe", "id": rid, "fields": ["height"], "lod": 4,
                              "tiles": [[0, 0]], "max_rate": 1}))
    await recv_json(ws, lambda m: m.get("id") == rid)


async def render(ws, req, timeout=60):
    """Send a render; returns (rendering, [frames], rendered). Live frames in
    between are ignored; anything after `rendered` is not read."""
    await ws.send(json.dumps(dict(req, type="render")))
    first = await recv_json(ws, lambda m: m.get("id") == req["id"], timeout=10)
    check(first["type"] == "rendering", "render refused: %r" % first)
    frames, deadline = [], time.time() + timeout
    while True:
        left = deadline - time.time()
        check(left > 0, "render: %d frames, no `rendered` after %g s" % (len(frames), timeout))
        m = await asyncio.wait_for(ws.recv(), left)
        if isinstance(m, bytes):
            if flags(m) & RENDERED:
                frames.append(m)
            continue
        j = json.loads(m)
        if j.get("type") in ("rendered", "error") and j.get("id") == req["id"]:
            return first, frames, j


def grid_of(frame, field, cascade=0):
    f = oceanproto.decode_frame(frame)
    a = oceanproto.Assembler([field], min(t.lod for t in f.tiles if t.cascade == cascade), cascade)
    a.add(f)
    check(a.complete(), "frame does not hold the whole %s grid of cascade %d" % (field, cascade))
    return f, a.fields[field]


@test
def test_render_frames_at_exact_times(d):
    async def run():
        ws, hello = await connect(d)
        await quiet(ws)
        await set_params(ws, {"choppiness": 0, "cascades": 1}, 1)
        t0 = None
        for rid in range(30, 200):            # half a second of this sea (a query before it answers the old one)
            await ws.send(json.dumps({"type": "query", "id": rid, "points": [[0, 0]]}))
            t = (await recv_json(ws, lambda m: m.get("id") == rid, timeout=10))["sim_time"]
            t0 = t if t0 is None else t0
            if t >= t0 + 0.6:
                break
            await asyncio.sleep(0.1)
        p = await set_params(ws, {"paused": True}, 21)
        # the paused sea's time: the live frames stay there
        await ws.send(json.dumps({"type": "query", "id": 2, "points": [[0, 0]]}))
        now = (await recv_json(ws, lambda m: m.get("id") == 2, timeout=10))["sim_time"]
        T, F, K = now - 0.45, 24, 10          # inside the query window, before now
        first, frames, last = await render(ws, {"id": 3, "start": T, "fps": F, "frames": K,
                                                "fields": ["height", "dx", "dz"], "lod": 0, "bound": 0})
        check(first["frames"] == K and first["params_version"] == p["params_version"], "rendering: %r" % first)
        check(last["type"] == "rendered" and last["frames"] == K and "reason" not in last, "end: %r" % last)
        check(len(frames) == K, "%d rendered frames, asked for %d" % (len(frames), K))
        rnd = random.Random(7)
        worst = 0.0
        for k, b in enumerate(frames):
            h = td.parse_header(b)
            check(h["seq"] == k, "frame %d has seq %d" % (k, h["seq"]))
            check(abs(h["sim_time"] - (T + k / F)) <= 1e-6, "frame %d at %.9f, not T + k/F = %.9f"
                  % (k, h["sim_time"], T + k / F))
            check(h["params_version"] == p["params_version"], "frame %d: params_version %d" % (k, h["params_version"]))
            check(all(t["codec"] == 0 for t in td.tiles(b)), "a lossless render's tiles are codec 0")
            f, grid = grid_of(b, "height")
            n, L = f.n, f.patch_size
            nodes = [(rnd.randrange(n), rnd.randrange(n)) for _ in range(8)]
            pts = [[ix * L / n, iz * L / n] for ix, iz in nodes]
            await ws.send(json.dumps({"type": "query", "id": 100 + k, "points": pts, "time": h["sim_time"]}))
            r = await recv_json(ws, lambda m: m.get("id") == 100 + k, timeout=10)
            check(r["type"] == "query_result", "query refused: %r" % r)
            worst = max(worst, max(abs(q["height"] - float(grid[iz, ix])) for q, (ix, iz) in zip(r["points"], nodes)))
        check(worst < 1e-4, "rendered heights vs query at their times: %.2e m" % worst)
        print("    %d frames at T + k/%d, seq 0..%d; |render - query| <= %.2e m at grid nodes" % (K, F, K - 1, worst))

        # Lossy, at the live paused time: equal to the live lossless frame within the bound.
        await ws.send(json.dumps({"type": "subscribe", "id": 4, "fields": ["height", "dx", "dz"], "lod": 0,
                                  "bound": 0, "adapt": False, "tiles": "all", "max_rate": 30}))
        await recv_json(ws, lambda m: m.get("id") == 4)
        while True:
            live = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(live, bytes) and not flags(live) & RENDERED and td.parse_header(live)["sim_time"] == now \
                    and td.tiles(live)[0]["codec"] == 0 and td.tiles(live)[0]["lod"] == 0:
                break
        await quiet(ws, 5)
        _, frames2, last2 = await render(ws, {"id": 6, "start": now, "fps": 30, "frames": 2,
                                              "fields": ["height", "dx", "dz"], "lod": 0, "bound": 0.01})
        check(len(frames2) == 2 and last2["type"] == "rendered", "lossy render: %d frames, %r" % (len(frames2), last2))
        check(td.parse_header(frames2[0])["sim_time"] == now, "frame 0 is at start exactly")
        check(all(t["codec"] == 1 for t in td.tiles(frames2[0])), "a lossy render's tiles are codec 1")
        for field in ("height", "dx", "dz"):
            _, a = grid_of(frames2[0], field)
            _, b = grid_of(live, field)
            err = float(abs(a - b).max())
            check(err <= 0.01 + 1e-4, "%s: render vs live frame %.4f m > bound" % (field, err))
        print("    lossy render at the paused time = the live frame within 1 cm")
        await ws.close()
    asyncio.run(run())


@test
def test_render_cascades(d):
    async def run():
        ws, hello = await connect(d)
        await quiet(ws)
        p = await set_params(ws, {"cascades": 3}, 1)
        first, frames, last = await render(ws, {"id": 2, "start": 7.25, "fps": 50, "frames": 3,
                                                "fields": ["height", "jacobian", "foam"], "lod": 1, "bound": 0.001,
                                                "cascades": [{"fields": ["height"], "lod": 1},
                                                             {"fields": ["height", "dx"], "lod": 2}]})
        check(first["cascades"] == 3 and last["frames"] == 3 and len(frames) == 3, "%r %r" % (first, last))
        for k, b in enumerate(frames):
            h = td.parse_header(b)
            check(h["seq"] == k and abs(h["sim_time"] - (7.25 + k / 50)) <= 1e-6, "frame %d header %r" % (k, h))
            f = oceanproto.decode_frame(b)
            layers = sorted({(t.cascade, t.field, t.lod) for t in f.tiles})
            check(layers == [(0, "foam", 1), (0, "height", 1), (0, "jacobian", 1), (1, "height", 1), (2, "dx", 2),
                             (2, "height", 2)], "layers %r" % layers)
            check(h["params_version"] == p["params_version"], "version")
        await ws.close()
    asyncio.run(run())


@test
def test_bad_renders_change_nothing(d):
    base = {"start": 1, "fps": 24, "frames": 2, "fields": ["height"]}
    bad = [
        ({"start": None}, "bad_render"), ({"fps": 0}, "bad_render"), ({"fps": -24}, "bad_render"),
        ({"fps": "24"}, "bad_render"), ({"fps": 1e9}, "bad_render"), ({"frames": 0}, "bad_render"),
        ({"frames": 2.5}, "bad_render"), ({"frames": 10 ** 7}, "bad_render"), ({"start": -1}, "bad_render"),
        ({"start": 2e9}, "bad_render"), ({"fields": ["nope"]}, "bad_render"), ({"fields": []}, "bad_render"),
        ({"fields": None}, "bad_render"), ({"lod": 9}, "bad_render"), ({"bound": 0.002}, "bad_render"),
        ({"temporal": True}, "bad_render"), ({"max_rate": 5}, "bad_render"), ({"cascades": [1]}, "bad_render"),
        ({"cascades": [{"fields": ["foam"]}]}, "bad_render"), ({"tiles": [[99, 0]]}, "bad_render"),
        ({"frames": 100000, "fields": ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"]}, "bad_render"),
    ]

    async def run():
        ws, hello = await connect(d)
        for i, (change, code) in enumerate(bad):
            req = dict(base, type="render", id=10 + i, **change)
            req = {k: v for k, v in req.items() if v is not None}
            await ws.send(json.dumps(req))
            m = await recv_json(ws, lambda m: m.get("id") == 10 + i, timeout=10)
            check(m["type"] == "error" and m["code"] == code, "%r: %r" % (change, m))
        await ws.send('{"type":"render_cancel","id":1}')   # nothing to cancel: no answer, no harm
        await ws.send(json.dumps({"type": "ping", "id": 99}))
        m = await recv_json(ws, lambda m: m.get("id") in (1, 99), timeout=10)
        check(m["type"] == "pong", "after the refusals: %r" % m)
        check(d.metric("oceand_render_frames_total") == 0, "a refused render rendered frames")
        await ws.close()
    asyncio.run(run())


def busy_daemon():
    # 1 unit per frame (height, one cascade, N = 256); 10 units/s; 100 accepted at most
    return td.Daemon("--render-budget", "10", "--render-max-units", "100", "--cascades", "1")


@test
def test_render_busy_when_budget_spent_and_cancel():
    with running(busy_daemon) as d:
        async def run():
            a, _ = await connect(d)
            b, _ = await connect(d)
            await quiet(a)
            await quiet(b)
            n = td.BASE_N
            units = (n / 256) ** 2
            k = int(60 / units)   # 60 units: paced to >= 5.5 s, so it is still running below
            await a.send(json.dumps({"type": "render", "id": 1, "start": 0, "fps": 10, "frames": k,
                                     "fields": ["height"]}))
            m = await recv_json(a, lambda m: m.get("id") == 1, timeout=10)
            check(m["type"] == "rendering" and abs(m["units"] - 60) < 0.5, "first render: %r" % m)
            await b.send(json.dumps({"type": "render", "id": 2, "start": 0, "fps": 10, "frames": k,
                                     "fields": ["height"]}))
            m = await recv_json(b, lambda m: m.get("id") == 2, timeout=10)
            check(m["type"] == "error" and m["code"] == "busy", "over --render-max-units: %r" % m)
            await a.send(json.dumps({"type": "render", "id": 3, "start": 0, "fps": 10, "frames": 1,
                                     "fields": ["height"]}))
            m = await recv_json(a, lambda m: m.get("id") == 3, timeout=10)
            check(m["type"] == "error" and m["code"] == "busy", "a second render of one client: %r" % m)
            await a.send('{"type":"render_cancel"}')
            m = await recv_json(a, lambda m: m.get("id") == 1, timeout=10)
            check(m["type"] == "rendered" and m.get("reason") == "cancelled" and m["frames"] < k, "cancel: %r" % m)
            # the budget is free again, for either client
            await b.send(json.dumps({"type": "render", "id": 4, "start": 0, "fps": 10, "frames": 2,
                                     "fields": ["height"]}))
            m = await recv_json(b, lambda m: m.get("id") == 4 and m["type"] != "rendering", timeout=20)
            check(m["type"] == "rendered" and m["frames"] == 2, "after the cancel: %r" % m)
            check(d.metric("oceand_render_refused_total") == 2, "refusals counted")
            await a.close()
            await b.close()
        asyncio.run(run())


def ws_text(s, text):
    """One masked text frame from a raw socket."""
    data = text.encode()
    mask = os.urandom(4)
    hdr = bytes([0x81]) + (bytes([0x80 | len(data)]) if len(data) < 126 else
                           bytes([0x80 | 126]) + struct.pack(">H", len(data)))
    s.sendall(hdr + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))


def small_daemon():
    return td.Daemon("--render-max-units", "400", "--cascades", "1")


@test
def test_render_flow_control_and_client_gone():
    with running(small_daemon) as d:
        async def run():
            n = td.BASE_N
            frames = int(390 / ((n / 256) ** 2 * 3))      # 390 of the 400 units
            raw = td.raw_ws_socket(d.port, rcvbuf=4096)   # never reads
            raw.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
            ws_text(raw, '{"type":"subscribe","id":1,"fields":["height"],"lod":4,"tiles":[[0,0]],"max_rate":1}')
            ws_text(raw, json.dumps({"type": "render", "id": 2, "start": 5, "fps": 24, "frames": frames,
                                     "fields": ["height", "dx", "dz"], "bound": 0}))
            before = -1
            for _ in range(100):                            # until the worker stops for room
                await asyncio.sleep(0.3)
                now = d.metric("oceand_render_frames_total")
                if now == before and now > 0:
                    break
                before = now
            # A frame is 3 N^2 floats; the sockets hold ~1 MB: a worker that
            # did not wait would have rendered all `frames` by now.
            per_frame = 3 * n * n * 4
            cap = 4 + 1 + (2 << 20) // per_frame + 2
            check(0 < now <= cap, "a client that reads nothing got %d frames rendered (window and buffers: %d)"
                  % (now, cap))
            # another client cannot have the budget while this render holds it
            b, _ = await connect(d)
            await quiet(b)
            await b.send(json.dumps({"type": "render", "id": 3, "start": 0, "fps": 24, "frames": frames,
                                     "fields": ["height", "dx", "dz"]}))
            m = await recv_json(b, lambda m: m.get("id") == 3, timeout=10)
            check(m["type"] == "error" and m["code"] == "busy", "while the budget is held: %r" % m)
            raw.close()                                     # gone mid-render
            deadline = time.time() + 20
            rid = 4
            while True:
                await b.send(json.dumps({"type": "render", "id": rid, "start": 0, "fps": 24, "frames": frames,
                                         "fields": ["height", "dx", "dz"], "bound": 0.05, "lod": 2}))
                m = await recv_json(b, lambda m: m.get("id") == rid, timeout=10)
                if m["type"] == "rendering":
                    break
                check(m["code"] == "busy" and time.time() < deadline, "after the client left: %r" % m)
                rid += 1
                await asyncio.sleep(0.2)
            stopped = d.metric("oceand_render_frames_total")
            m = await recv_json(b, lambda m: m.get("id") == rid and m["type"] == "rendered", timeout=120)
            check(m["frames"] == frames, "the second render: %r" % m)
            print("    the reader-less client held the render at %d frames; after it left, another rendered %d"
                  % (now, d.metric("oceand_render_frames_total") - stopped))
            await b.close()
        asyncio.run(run())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--frame-check", default="build/frame_check")
    ap.add_argument("--sanitized", action="store_true", help="sanitizer build: smaller N")
    ap.add_argument("-k", default="", help="run only tests whose name contains this")
    args = ap.parse_args()
    td.ARGS = args
    if args.sanitized:
        td.BASE_N = 128
    t0 = time.time()
    passed, failed = run_tests(TESTS, args.k, td.Daemon)
    print("render tests took %.0f s" % (time.time() - t0))
    print("%d passed, %d failed" % (passed, failed))
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()

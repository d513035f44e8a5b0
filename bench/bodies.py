#!/usr/bin/python3
"""What floating bodies cost the tick: a real daemon at N = 256 (three cascades, the
defaults) with one viewer reading frames, measured without bodies, with 64 bodies
launched (every kind, the powered ones under way and turning), and without them
again, all in one run. Each phase is cut into 1 s windows; per window the mean
tick duration (deadline to the frame's publication), step duration and bodies
step duration come from /metrics' histogram sums; a phase reports the median of
its windows. Prints one JSON line per phase and a last line with the difference
and the ratio against the mean of the two phases without bodies.

    /usr/bin/python3 bench/bodies.py --oceand build/oceand      (make bench-bodies)
"""
import argparse
import asyncio
import json
import os
import re
import statistics
import sys
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "common"))
import oceand_proc  # noqa: E402

import websockets  # noqa: E402

KINDS = ["spar", "ball", "dinghy", "boat", "ship"]


def metrics(d):
    with urllib.request.urlopen(d.http + "/metrics", timeout=5) as r:
        text = r.read().decode()
    out = {}
    for line in text.splitlines():
        m = re.match(r"^([a-z_]+(?:\{[^}]*\})?) (\S+)$", line)
        if m:
            out[m.group(1)] = float(m.group(2))
    return out


def mean_ms(m0, m1, name):
    n = m1.get(name + "_count", 0) - m0.get(name + "_count", 0)
    return 1000 * (m1.get(name + "_sum", 0) - m0.get(name + "_sum", 0)) / n if n > 0 else 0.0


async def reader(ws, counts):
    """Read every frame (a viewer that keeps up), counting them."""
    try:
        async for m in ws:
            if isinstance(m, bytes):
                counts["frames"] += 1
    except websockets.ConnectionClosed:
        pass


async def phase(d, name, bodies, windows, counts):
    loop = asyncio.get_running_loop()
    rows = []
    f0 = counts["frames"]
    t0 = time.time()
    m_start = await loop.run_in_executor(None, metrics, d)
    prev = m_start
    for _ in range(windows):
        await asyncio.sleep(1.0)
        cur = await loop.run_in_executor(None, metrics, d)
        rows.append((mean_ms(prev, cur, "oceand_tick_duration_seconds"),
                     mean_ms(prev, cur, "oceand_step_duration_seconds"),
                     mean_ms(prev, cur, "oceand_body_step_duration_seconds")))
        prev = cur
    secs = time.time() - t0
    out = {"bench": "bodies", "phase": name, "bodies": bodies, "windows": windows,
           "tick_ms_median": round(statistics.median(r[0] for r in rows), 3),
           "step_ms_median": round(statistics.median(r[1] for r in rows), 3),
           "body_step_ms_median": round(statistics.median(r[2] for r in rows), 3),
           "overruns": int(prev["oceand_tick_overruns_total"] - m_start["oceand_tick_overruns_total"]),
           "viewer_fps": round((counts["frames"] - f0) / secs, 1)}
    print(json.dumps(out), flush=True)
    return out


async def run(args):
    d = oceand_proc.Oceand(args.oceand, "--resolution", "256", "--state-file", "none", *args.extra, "--bodies-per-session", "64",
                           "--max-bodies", "64", "--launch-rate", "600", "--control-rate", "1000",
                           "--control-burst", "1000")
    try:
        viewer = await websockets.connect(d.url, subprotocols=["oceand.v1"], max_size=None)
        counts = {"frames": 0}
        task = asyncio.ensure_future(reader(viewer, counts))
        ctl = await websockets.connect(d.url + "?frames=0", subprotocols=["oceand.v1"], max_size=None)
        hello = json.loads(await ctl.recv())
        powered = {k["name"]: k["powered"] for k in hello["body_kinds"]}
        await asyncio.sleep(args.warm)
        before = await phase(d, "none", 0, args.windows, counts)
        ids = []
        for i in range(args.bodies):
            kind = KINDS[i % len(KINDS)]
            await ctl.send(json.dumps({"type": "launch", "id": i, "kind": kind, "x": (i % 8) * 40.0 - 140,
                                       "z": (i // 8) * 40.0 - 140, "heading": (37 * i) % 360}))
        while len(ids) < args.bodies:
            m = json.loads(await asyncio.wait_for(ctl.recv(), 10))
            if m["type"] == "launched":
                ids.append((m["body"], KINDS[m["id"] % len(KINDS)]))
            elif m["type"] == "error":
                raise SystemExit("launch refused: %r" % m)
        for body, kind in ids:
            if powered[kind]:
                await ctl.send(json.dumps({"type": "steer", "body": body, "throttle": 0.8, "rudder": 0.3}))
        await asyncio.sleep(args.warm)
        with_bodies = await phase(d, "bodies", len(ids), args.windows, counts)
        for body, _ in ids:
            await ctl.send(json.dumps({"type": "remove", "body": body}))
        await asyncio.sleep(args.warm)
        after = await phase(d, "none_again", 0, args.windows, counts)
        base = (before["tick_ms_median"] + after["tick_ms_median"]) / 2
        print(json.dumps({"bench": "bodies", "summary": True, "N": 256, "bodies": len(ids),
                          "tick_ms_without": round(base, 3), "tick_ms_with": with_bodies["tick_ms_median"],
                          "added_ms": round(with_bodies["tick_ms_median"] - base, 3),
                          "ratio": round(with_bodies["tick_ms_median"] / base, 3) if base > 0 else None,
                          "body_step_ms": with_bodies["body_step_ms_median"],
                          "target_added_ms": 1.0}), flush=True)
        await ctl.close()
        await viewer.close()
        task.cancel()
    finally:
        d.stop()
        d.close()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--bodies", type=int, default=64)
    ap.add_argument("--windows", type=int, default=15, help="1 s windows per phase")
    ap.add_argument("--warm", type=float, default=2.0, help="s before each phase")
    ap.add_argument("extra", nargs="*", help="more daemon options, after --, e.g. -- --cascades 1")
    args = ap.parse_args()
    asyncio.run(run(args))


if __name__ == "__main__":
    main()

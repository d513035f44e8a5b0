#!/usr/bin/python3
"""Point query and probe benchmark for oceand (docs/query.md), part of `make bench-load`.
One JSON line per run:

  {"bench":"query","N":256,"points":16,"p50_ms":..,"p99_ms":..,"samples":..}
      round-trip latency of `query` (send -> query_result) for 1, 16 and 256 points,
      one client, one query at a time (the budget and rate limit are raised so that
      they do not refuse the benchmark's queries);
  {"bench":"probes","N":256,"clients":100,"points_per_client":16,"tick_ms_mean":..,
   "overruns":..,"probe_ticks_skipped":..,"probe_worker_ms_mean":..,"probe_msgs_per_s_min":..}
      100 clients probing 16 points each (and subscribed to almost no frames), over the
      window: the tick time and overruns (the tick must keep zero), the query worker's
      time per probe tick, probe ticks it skipped, and the slowest client's probe_data rate.

    /usr/bin/python3 bench/query_load.py [--ns 256,512] [--probe-clients 100] [--window 10]
"""
import argparse
import asyncio
import json
import os
import random
import sys
import tempfile
import time

import websockets

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "common"))
from load import metric  # noqa: E402
import oceand_proc  # noqa: E402


def start(args, n, extra=()):
    tmp = tempfile.mkdtemp(prefix="oceand-qbench-")
    return oceand_proc.Oceand(args.oceand, "--resolution", str(n), "--state-file", "none",
                              "--web-root", tmp, "--max-clients", "1000", "--log-level", "warn", *extra,
                              tmp=tmp, own_tmp=True)


def stop(d):
    d.stop(timeout=5)
    d.close()


QUIET = {"type": "subscribe", "fields": ["height"], "lod": 4, "tiles": [[0, 0]], "max_rate": 1}


async def connect(port):
    ws = await websockets.connect("ws://127.0.0.1:%d/" % port, subprotocols=["oceand.v1"], max_size=None,
                                  compression=None, max_queue=None)
    await ws.recv()  # hello
    await ws.send(json.dumps(QUIET))
    return ws


def pct(v, q):
    v = sorted(v)
    return v[min(len(v) - 1, int(q * (len(v) - 1) + 0.5))]


async def query_latency(port, n, points, samples):
    ws = await connect(port)
    rnd = random.Random(points)
    lat = []
    for i in range(samples + 2):
        pts = [[rnd.uniform(-1e4, 1e4), rnd.uniform(-1e4, 1e4)] for _ in range(points)]
        t0 = time.perf_counter()
        await ws.send(json.dumps({"type": "query", "id": i, "points": pts}))
        while True:
            m = await ws.recv()
            if isinstance(m, str):
                j = json.loads(m)
                if j.get("id") == i:
                    break
        if j["type"] != "query_result":
            raise RuntimeError("query refused: %r" % j)
        if i >= 2:  # the first two warm the caches
            lat.append((time.perf_counter() - t0) * 1e3)
    await ws.close()
    return lat


async def probe_clients(port, k, npts, window, warmup):
    socks = [await connect(port) for _ in range(k)]
    rnd = random.Random(1)
    for ws in socks if npts else []:
        await ws.send(json.dumps({"type": "probe", "id": 1,
                                  "points": [[rnd.uniform(-500, 500), rnd.uniform(-500, 500)] for _ in range(npts)]}))
    counts = [0] * k
    measuring = False

    async def reader(i, ws):
        while True:
            m = await ws.recv()
            if measuring and isinstance(m, str) and m.startswith('{"type":"probe_data"'):
                counts[i] += 1
    tasks = [asyncio.ensure_future(reader(i, ws)) for i, ws in enumerate(socks)]
    await asyncio.sleep(warmup)
    m0 = snapshot(port)
    measuring = True
    t0 = time.monotonic()
    await asyncio.sleep(window)
    measuring = False
    dt = time.monotonic() - t0
    m1 = snapshot(port)
    for t in tasks:
        t.cancel()
    for ws in socks:
        await ws.close()
    return [c / dt for c in counts], m0, m1


NAMES = ["oceand_tick_overruns_total", "oceand_tick_duration_seconds_sum", "oceand_tick_duration_seconds_count",
         "oceand_probe_tick_duration_seconds_sum", "oceand_probe_tick_duration_seconds_count",
         "oceand_probe_ticks_skipped_total", "oceand_probe_points"]


def snapshot(port):
    return {k: metric(port, k) for k in NAMES}


def bench(args):
    for n in (int(x) for x in args.ns.split(",")):
        d = start(args, n, ["--query-budget", "1000000", "--control-rate", "1000", "--control-budget", "1e7",
                            "--control-burst", "1000"] + args.oceand_args.split())
        port = d.port
        try:
            for pts in (1, 16, 256):
                samples = args.samples if pts < 256 else max(10, args.samples // 4)
                lat = asyncio.run(query_latency(port, n, pts, samples))
                print(json.dumps({"bench": "query", "N": n, "points": pts, "samples": len(lat),
                                  "p50_ms": round(pct(lat, 0.5), 2), "p99_ms": round(pct(lat, 0.99), 2),
                                  "ms_per_point_p50": round(pct(lat, 0.5) / pts, 3),
                                  "loadavg_1m": round(os.getloadavg()[0], 2)}), flush=True)
        finally:
            stop(d)
        if args.probe_clients:
            d = start(args, n, ["--probe-max-total", str(args.probe_clients * args.probe_points)]
                      + args.oceand_args.split())
            port = d.port
            try:
                # Baseline: the same clients connected, no probes; then with probes.
                _, b0, b1 = asyncio.run(probe_clients(port, args.probe_clients, 0, args.window, args.warmup))
                base = {k: b1[k] - b0[k] for k in NAMES}
                rates, m0, m1 = asyncio.run(probe_clients(port, args.probe_clients, args.probe_points,
                                                          args.window, args.warmup))
                dd = {k: m1[k] - m0[k] for k in NAMES}
                print(json.dumps({
                    "bench": "probes", "N": n, "clients": args.probe_clients, "points_per_client": args.probe_points,
                    "probe_points": int(m1["oceand_probe_points"]),
                    "tick_ms_mean": round(1e3 * dd["oceand_tick_duration_seconds_sum"]
                                          / max(1, dd["oceand_tick_duration_seconds_count"]), 2),
                    "overruns": int(dd["oceand_tick_overruns_total"]),
                    "tick_ms_mean_no_probes": round(1e3 * base["oceand_tick_duration_seconds_sum"]
                                                    / max(1, base["oceand_tick_duration_seconds_count"]), 2),
                    "overruns_no_probes": int(base["oceand_tick_overruns_total"]),
                    "probe_worker_ms_mean": round(1e3 * dd["oceand_probe_tick_duration_seconds_sum"]
                                                  / max(1, dd["oceand_probe_tick_duration_seconds_count"]), 2),
                    "probe_ticks": int(dd["oceand_probe_tick_duration_seconds_count"]),
                    "probe_ticks_skipped": int(dd["oceand_probe_ticks_skipped_total"]),
                    "probe_msgs_per_s_min": round(min(rates), 1),
                    "probe_msgs_per_s_median": round(sorted(rates)[len(rates) // 2], 1),
                    "window_s": args.window, "loadavg_1m": round(os.getloadavg()[0], 2)}), flush=True)
            finally:
                stop(d)


def add_args(ap):
    ap.add_argument("--query-ns", dest="ns", default="256,512", help="resolutions of the query/probe runs")
    ap.add_argument("--query-samples", dest="samples", type=int, default=60)
    ap.add_argument("--probe-clients", type=int, default=100)
    ap.add_argument("--probe-points", type=int, default=16)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--oceand-args", default="")
    ap.add_argument("--warmup", type=float, default=2)
    ap.add_argument("--window", type=float, default=10)
    add_args(ap)
    bench(ap.parse_args())


if __name__ == "__main__":
    main()

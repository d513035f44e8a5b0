#!/usr/bin/python3
"""buoy.py - a wave buoy: record the heave at a few points through `probe`
(PROTOCOL.md §7.4) and compare its significant wave height with the sea's.

    /usr/bin/python3 proto/examples/buoy.py ws://127.0.0.1:8080 --seconds 120
    /usr/bin/python3 proto/examples/buoy.py ws://127.0.0.1:8080 --at 10,20 --at 80,-40 --seconds 60

The buoy's Hs is 4 * std of its heave series (the spectral Hs, m0 = variance);
the sea's is 4 * std of the streamed height field over the same span (frames
decoded with the oceand package, proto/python). Also prints the peak period of the heave
spectrum. Seconds are of sim time (a server running with --time-scale 4
fills a minute of record in 15 s). Debian python3-websockets + python3-numpy.
"""
import argparse
import asyncio
import json
import os
import sys

import numpy as np
import websockets

try:
    import oceand as oceanproto
except ImportError:   # a checkout without `pip install ./proto/python`: the package beside this folder
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
    import oceand as oceanproto  # noqa: E402


def point(text):
    x, z = text.split(",")
    return [float(x), float(z)]


async def record(args):
    async with websockets.connect(args.url, subprotocols=[oceanproto.SUBPROTOCOL], max_size=None,
                                  compression=None, open_timeout=args.timeout, close_timeout=1) as ws:
        hello = json.loads(await asyncio.wait_for(ws.recv(), args.timeout))
        p = hello["params"]
        points = args.at or [[(i + 0.5) * p["patch_size"] / 3, (j + 0.5) * p["patch_size"] / 3]
                             for i in range(3) for j in range(3)]
        # The sea: a coarse lossless height field a few times a second is plenty for its variance.
        await ws.send(json.dumps({"type": "subscribe", "id": 1, "fields": ["height"], "lod": 2, "bound": 0,
                                  "max_rate": 5}))
        await ws.send(json.dumps({"type": "probe", "id": 2, "points": points}))
        heave, times, field = [], [], []
        t0 = None
        while True:
            msg = await asyncio.wait_for(ws.recv(), args.timeout)
            if isinstance(msg, bytes):
                if t0 is None:
                    continue
                f = oceanproto.decode_frame(msg)
                grid = oceanproto.Assembler(["height"], 2)
                grid.add(f)
                if grid.complete():
                    field.append(grid.fields["height"].astype(np.float64).ravel())
                continue
            m = json.loads(msg)
            if m.get("type") == "error":
                raise SystemExit(f"buoy: server refused: {m.get('code')}: {m.get('message')}")
            if m.get("type") != "probe_data":
                continue
            if t0 is None:
                t0 = m["sim_time"]
                print(f"recording {len(points)} point(s) for {args.seconds:g} s of sim time "
                      f"(N={p['resolution']}, wind {p['wind_speed']} m/s, {p['spectrum']})", flush=True)
            heave.append([q[0] for q in m["points"]])
            times.append(m["sim_time"])
            if m["sim_time"] - t0 >= args.seconds:
                return points, np.array(times), np.array(heave), np.array(field)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("url")
    ap.add_argument("--at", type=point, action="append", help="x,z of a probe (repeatable; default a 3x3 array)")
    ap.add_argument("--seconds", type=float, default=120.0, help="record length, s of sim time")
    ap.add_argument("--timeout", type=float, default=10.0)
    args = ap.parse_args()
    points, t, heave, field = asyncio.run(record(args))
    if len(t) < 8 or not len(field):
        raise SystemExit("buoy: record too short")
    hs_buoy = 4 * heave.std()
    hs_sea = 4 * field.std()
    # Peak period: mean periodogram of the heave, resampled on a uniform grid.
    dt = float(np.median(np.diff(t))) or 1 / 30
    tu = np.arange(t[0], t[-1], dt)
    hu = np.stack([np.interp(tu, t, heave[:, k]) for k in range(heave.shape[1])], axis=1)
    hu -= hu.mean(axis=0)
    spec = (np.abs(np.fft.rfft(hu * np.hanning(len(tu))[:, None], axis=0)) ** 2).mean(axis=1)
    freq = np.fft.rfftfreq(len(tu), dt)
    spec[0] = 0
    fp = freq[int(np.argmax(spec))]
    print(json.dumps({"points": len(points), "samples": len(t), "seconds": round(float(t[-1] - t[0]), 3),
                      "hs_buoy_m": round(float(hs_buoy), 4), "hs_sea_m": round(float(hs_sea), 4),
                      "ratio": round(float(hs_buoy / hs_sea), 4), "peak_period_s": round(1 / fp, 2) if fp else None,
                      "frames": len(field)}))


if __name__ == "__main__":
    main()

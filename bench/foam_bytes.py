#!/usr/bin/python3
"""Bytes per client that the foam field adds to the web client's subscription.
One oceand on loopback, one WebSocket client; for each wind speed, the default fields
(height, dx, dz) alone, with foam at the same LOD, and with foam at a coarser LOD
("field_lod", PROTOCOL.md §7.1). One JSON line per case:
  {"bench":"foam_bytes","wind":16,"case":"foam_lod2","kBps":...,"frames_per_s":...}

    /usr/bin/python3 bench/foam_bytes.py [--oceand build/oceand] [--seconds 4]
"""
import argparse
import asyncio
import json
import os
import sys
import tempfile
import time

import websockets

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "common"))
import oceand_proc  # noqa: E402

CASES = [
    ("default", {"fields": ["height", "dx", "dz"], "field_lod": {}}),
    ("foam_lod0", {"fields": ["height", "dx", "dz", "foam"], "field_lod": {}}),
    ("foam_lod2", {"fields": ["height", "dx", "dz", "foam"], "field_lod": {"foam": 2}}),
]


async def measure(port, wind, sub, seconds):
    async with websockets.connect("ws://127.0.0.1:%d/" % port, subprotocols=["oceand.v1"], max_size=None) as ws:
        await ws.recv()  # hello
        await ws.send(json.dumps({"type": "set", "id": 1, "params": {"wind_speed": wind}}))
        await ws.send(json.dumps({"type": "subscribe", "id": 2, **sub}))
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.5:  # settle: the new subscription and wind in every frame
            await ws.recv()
        frames = size = 0
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            m = await ws.recv()
            if isinstance(m, bytes):
                frames += 1
                size += len(m)
        return size / seconds / 1024, frames / seconds


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--seconds", type=float, default=4)
    ap.add_argument("--winds", default="8,16,25")
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="oceand-foam-")
    p = oceand_proc.Oceand(a.oceand, "--state-file", os.path.join(tmp, "state.json"), "--log-level", "warn",
                           tmp=tmp, own_tmp=True)
    port = p.port
    try:
        for wind in [float(w) for w in a.winds.split(",")]:
            for name, sub in CASES:
                kbps, fps = await measure(port, wind, sub, a.seconds)
                print(json.dumps({"bench": "foam_bytes", "wind": wind, "case": name,
                                  "kBps": round(kbps, 1), "frames_per_s": round(fps, 1)}), flush=True)
    finally:
        p.stop()
        p.close()


asyncio.run(main())

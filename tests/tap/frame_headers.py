#!/usr/bin/python3
"""frame_headers.py - record the header of every frame an oceand server sends.

    frame_headers.py URL SECONDS OUT.jsonl

Subscribes to the smallest stream there is (height, LOD 4) and writes one JSON
line per frame: {"seq", "sim_time", "params_version"}, decoded by the Python
example decoder (proto/examples/oceanproto.py), independently of ocean-tap.
Used by tests/tap/run.sh to check ocean-tap's metadata against the headers.
"""
import asyncio
import json
import os
import sys
import time

import websockets

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "proto", "examples"))
import oceanproto  # noqa: E402


async def record(url, seconds, out):
    async with websockets.connect(url, subprotocols=[oceanproto.SUBPROTOCOL], max_size=None,
                                  compression=None, open_timeout=10, close_timeout=1) as ws:
        await ws.recv()  # hello
        await ws.send(json.dumps({"type": "subscribe", "id": 1, "fields": ["height"], "lod": 4, "tiles": "all"}))
        seen = {}
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                msg = await asyncio.wait_for(ws.recv(), max(0.05, end - time.monotonic()))
            except asyncio.TimeoutError:
                break
            if isinstance(msg, bytes):
                f = oceanproto.decode_frame(msg)
                seen[f.seq] = {"seq": f.seq, "sim_time": f.sim_time, "params_version": f.params_version}
        with open(out, "w") as fo:
            for s in sorted(seen):
                fo.write(json.dumps(seen[s]) + "\n")


asyncio.run(record(sys.argv[1], float(sys.argv[2]), sys.argv[3]))

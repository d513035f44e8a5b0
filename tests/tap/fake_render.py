"""A stand-in server for ocean-tap --bake: speaks hello, subscribe and the draft
`render` request (exact-time frames), which oceand does not serve yet. Renders
K raw (codec 0) frames flagged as rendered (frame header flags bit 0, seq = k,
sim_time = start + k/fps) of every field and cascade asked for, with a live
frame (no flag) between them that ocean-tap must ignore. Writes the render
request it received to REQUEST_JSON. Serves one client, then exits.
Usage: /usr/bin/python3 tests/tap/fake_render.py PORT REQUEST_JSON"""
import asyncio
import json
import struct
import sys
import time

import numpy as np
import websockets

FIELDS = ("height", "dx", "dz", "slope_x", "slope_z", "jacobian", "foam")
FRAME = struct.Struct("<4sHHQdIHHfHHQ")
TILE = struct.Struct("<BBBBHHHHfddII")
N, L = 32, 256.0
SIZES = [L, L / 3.543, L / 3.543 ** 2]
port, out = int(sys.argv[1]), sys.argv[2]


def frame(seq, t, flags, layers):
    """layers: (cascade, field, lod); samples depend on t so that frames differ."""
    tiles = []
    for c, f, lod in layers:
        side = N >> lod
        jj, ii = np.mgrid[0:side, 0:side]
        a = (0.1 * np.sin(ii * 0.3 + jj * 0.2 + t) / (1 + c) + 0.01 * FIELDS.index(f)).astype("<f4")
        if f == "jacobian":
            a = (1 - a).astype("<f4")
        payload = a.tobytes()
        tiles.append(TILE.pack(FIELDS.index(f), lod, 0, c, 0, 0, side, side, 0.0, 0.0, 0.0, len(payload), 0) + payload)
    return FRAME.pack(b"OCNF", 1, 48, seq, t, 1, N, N, L, len(tiles), flags, int(time.time() * 1e6)) + b"".join(tiles)


async def serve(ws):
    await ws.send(json.dumps({"type": "hello", "protocol": 1, "server": "fake-render", "client_id": "c1",
                              "role": "controller", "params": {"resolution": N, "patch_size": L, "cascades": 3},
                              "params_version": 1, "cascade_patch_sizes": SIZES, "schema": [],
                              "tick_rate": 30, "tile_size": N}))
    async for text in ws:
        m = json.loads(text)
        if m["type"] == "subscribe":
            await ws.send(json.dumps({"type": "subscribed", "id": m.get("id"), "subscription": m}))
        elif m["type"] == "render":
            json.dump(m, open(out, "w"))
            await ws.send(json.dumps({"type": "rendering", "id": m["id"], "frames": m["frames"], "params_version": 1}))
            layers = [(0, f, m["lod"]) for f in m["fields"]]
            for c, sub in enumerate(m.get("cascades", []), start=1):
                layers += [(c, f, sub["lod"]) for f in sub["fields"]]
            for k in range(int(m["frames"])):
                await ws.send(frame(k, m["start"] + k / m["fps"], 1, layers))
                if k == 0:   # a live tick in between: not part of the render
                    await ws.send(frame(5000, 999.0, 0, layers))
            await ws.send(json.dumps({"type": "rendered", "id": m["id"], "frames": m["frames"]}))
            await asyncio.sleep(1)
            return


async def main():
    done = asyncio.get_running_loop().create_future()

    async def handler(ws, path=None):
        try:
            await serve(ws)
        finally:
            if not done.done():
                done.set_result(None)
    async with websockets.serve(handler, "127.0.0.1", port, subprotocols=["oceand.v1"]):
        await asyncio.wait_for(done, 30)

asyncio.run(main())

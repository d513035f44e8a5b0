#!/usr/bin/python3
"""One viewer of the link lab (bench/links/run.sh): subscribes like the web
client, reads every frame as it arrives, and prints one JSON object with
what it saw over the measured window:

  fps, ticks (share of the ticks in the window it received), latency p50/p95
  (arrival minus the frame's server_time_us: both clocks are this machine's),
  kB/frame, codec shares of its tiles, the rung (`link` messages), the
  round trip of a `set` (sent every second, like the web page on a control
  connection of its own, ?frames=0, and a copy under the same "once" key on
  the frame connection, unless --no-once or --one-connection; it moves
  time_scale by 1e-4 and back, which no frame shows; the reply is the first
  `params` of its version on either connection, as the page takes it; --noop-sets:
  sets that change nothing, answered on the control connection only:
  p50, p95, max and how many passed --set-bound-ms in the window; the warm-up's
  maximum apart), the role
  of the daemon it reads (--role, as run.sh started it) and the load average.

    viewer.py URL --seconds 20 --warmup 5 [--pinned] [--whole-frames] [--role edge]
    viewer.py URL --timeline ...   also a per-second list (fps, temporal share, rung)
"""
import argparse
import asyncio
import json
import os
import struct
import sys
import time

import websockets

WEB_SUB = {"type": "subscribe", "id": "sub", "fields": ["height", "dx", "dz", "foam"], "field_lod": {"foam": 2},
           "cascades": [{"fields": ["height"], "lod": 1, "bound": 0.001}] * 3, "temporal": True,
           "parts": True}
PART = 2  # frame header flags bit 1: more tiles of this tick follow (PROTOCOL.md §3.4)


def frame_info(b):
    seq, = struct.unpack_from("<Q", b, 8)
    tile_count, flags = struct.unpack_from("<HH", b, 36)
    server_us, = struct.unpack_from("<Q", b, 40)
    hsize, = struct.unpack_from("<H", b, 6)
    off = hsize
    codecs = {}
    lods = set()
    for _ in range(tile_count):
        codec = b[off + 2]
        lods.add(b[off + 1])
        plen, = struct.unpack_from("<I", b, off + 32)
        codecs[codec] = codecs.get(codec, 0) + 1
        off += 40 + plen
    return seq, server_us, codecs, lods, bool(flags & PART)


def pct(v, p):
    if not v:
        return None
    v = sorted(v)
    return v[min(len(v) - 1, int(p / 100 * len(v)))]


async def run(a):
    sub = dict(WEB_SUB)
    if a.pinned:
        sub["adapt"] = False
    if a.whole_frames:
        del sub["parts"]
    frames = []       # (t_arrival, seq, bytes, codecs, latency_ms)
    links = []        # (t, rung, msg)
    sets = []         # round trips (ms)
    pending = {}
    part = None       # (seq, bytes, codecs, lods) of the parts of a tick received so far
    t_start = time.time()
    first_seen = {}   # params_version -> when the first copy of it arrived (either connection)

    def replied(j, now):
        if j.get("type") == "params":
            now = first_seen.setdefault(j.get("params_version"), now)
        if j.get("type") == "error" and j.get("code") == "duplicate":
            return  # the copy on the other connection was applied
        if j.get("id") in pending and j.get("type") in ("params", "error"):
            t_sent = pending.pop(j["id"])
            sets.append(((now - t_sent) * 1000, t_sent - t_start))

    async def read_control(cws):
        async for m in cws:
            if isinstance(m, str):
                replied(json.loads(m), time.time())

    async with websockets.connect(a.url, subprotocols=["oceand.v1"], max_size=None, ping_interval=None,
                                  open_timeout=20) as ws:
        hello = json.loads(await ws.recv())
        scale = hello["params"]["time_scale"]
        await ws.send(json.dumps(sub))
        cws = reader = None
        if not a.one_connection:
            sep = "&" if "?" in a.url else "?"
            cws = await websockets.connect(a.url + sep + "frames=0", subprotocols=["oceand.v1"], ping_interval=None,
                                           open_timeout=20)
            json.loads(await cws.recv())  # its hello
            reader = asyncio.ensure_future(read_control(cws))
        next_set = time.time() + 1
        k = 0
        while time.time() - t_start < a.warmup + a.seconds:
            if a.sets and time.time() >= next_set:
                k += 1
                pending["s%d" % k] = time.time()
                value = scale if a.noop_sets or k % 2 == 0 else scale + 1e-4
                msg = {"type": "set", "id": "s%d" % k, "params": {"time_scale": value}}
                if cws and not a.no_once:  # like the page: on both connections, applied once
                    msg["once"] = os.urandom(12).hex()
                    await ws.send(json.dumps(msg))
                await (cws or ws).send(json.dumps(msg))
                next_set += 1
            try:
                m = await asyncio.wait_for(ws.recv(), 0.2)
            except asyncio.TimeoutError:
                continue
            now = time.time()
            if isinstance(m, bytes):
                seq, sus, codecs, lods, more = frame_info(m)
                size = len(m)
                if part and part[0] == seq:  # the earlier parts of this tick
                    size += part[1]
                    for c, cn in part[2].items():
                        codecs[c] = codecs.get(c, 0) + cn
                    lods |= part[3]
                part = (seq, size, codecs, lods) if more else None
                if not more:  # the tick is complete with its last part
                    frames.append((now, seq, size, codecs, (now * 1e6 - sus) / 1000, lods))
                continue
            j = json.loads(m)
            if j.get("type") == "link":
                links.append((now, j.get("rung"), j))
            else:
                replied(j, now)
        if cws:
            reader.cancel()
            await cws.close()
    t0 = t_start + a.warmup
    win = [f for f in frames if f[0] >= t0]
    out = {"link": a.name, "role": a.role}
    if len(win) >= 2:
        span = win[-1][0] - win[0][0]
        seqs = win[-1][1] - win[0][1] + 1
        tiles = {}
        for f in win:
            for c, n in f[3].items():
                tiles[c] = tiles.get(c, 0) + n
        nt = sum(tiles.values()) or 1
        lat = [f[4] for f in win]
        out.update(fps=round((len(win) - 1) / span, 1) if span > 0 else None,
                   ticks=round(len(win) / seqs, 3),
                   latency_p50_ms=round(pct(lat, 50), 1), latency_p95_ms=round(pct(lat, 95), 1),
                   kb_frame=round(sum(f[2] for f in win) / len(win) / 1000, 1),
                   codec_shares={str(c): round(n / nt, 3) for c, n in sorted(tiles.items())},
                   temporal=round(tiles.get(3, 0) / nt, 3),
                   lods=sorted(set().union(*[f[5] for f in win])))
    else:
        out.update(fps=0, ticks=0)
    out["rung"] = links[-1][1] if links else 0
    out["rung_changes"] = len(links)
    if links:
        out["link_kbps"] = links[-1][2].get("link_kbps")
    # The round trips of the sets sent in the measured window, like every figure
    # above; those of the warm-up (the ladder's first steps down) on their own.
    rtts = [r for r, t in sets if t >= a.warmup]
    start = [r for r, t in sets if t < a.warmup]
    out["set_rtt_p50_ms"] = round(pct(rtts, 50), 1) if rtts else None
    out["set_rtt_p95_ms"] = round(pct(rtts, 95), 1) if rtts else None
    out["set_rtt_max_ms"] = round(max(rtts), 1) if rtts else None
    out["set_rtt_warmup_max_ms"] = round(max(start), 1) if start else None
    if a.set_bound_ms:
        out["set_bound_ms"] = a.set_bound_ms
        out["sets_over_bound"] = "%d/%d" % (sum(r > a.set_bound_ms for r in rtts), len(rtts))
    if a.set_log:
        out["sets"] = [[round(t, 2), round(r, 1)] for r, t in sets]
    out["loadavg_1m"] = round(os.getloadavg()[0], 2)
    if a.timeline:
        tl = []
        for sec in range(int(a.warmup + a.seconds)):
            fs = [f for f in frames if t_start + sec <= f[0] < t_start + sec + 1]
            nt = sum(sum(f[3].values()) for f in fs) or 1
            rung = 0
            for lt, r, _ in links:
                if lt < t_start + sec + 1:
                    rung = r
            tl.append([sec, len(fs), round(sum(f[3].get(3, 0) for f in fs) / nt, 2), rung])
        out["timeline"] = tl
    if a.rungs:
        out["links"] = [dict(t=round(t - t_start, 2), rung=r, reason=j.get("reason")) for t, r, j in links]
    print(json.dumps(out), flush=True)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("url")
    p.add_argument("--name", default="")
    p.add_argument("--role", default="all", help="what serves it (all, edge): written in the row")
    p.add_argument("--seconds", type=float, default=20)
    p.add_argument("--warmup", type=float, default=5)
    p.add_argument("--pinned", action="store_true")
    p.add_argument("--whole-frames", action="store_true", help="subscribe without \"parts\" (one message a tick)")
    p.add_argument("--sets", type=int, default=1)
    p.add_argument("--noop-sets", action="store_true", help="sets that change nothing (the sender alone is answered)")
    p.add_argument("--no-once", action="store_true", help="sets on the control connection only, not also on the frame one")
    p.add_argument("--one-connection", action="store_true",
                   help="send the sets on the frame connection, not on a control connection (?frames=0)")
    p.add_argument("--timeline", action="store_true")
    p.add_argument("--rungs", action="store_true")
    p.add_argument("--set-log", action="store_true", help="every set: [seconds from start, round trip ms]")
    p.add_argument("--set-bound-ms", type=float, default=0, help="count the sets of the window over this round trip")
    a = p.parse_args()
    asyncio.run(run(a))


if __name__ == "__main__":
    sys.exit(main())

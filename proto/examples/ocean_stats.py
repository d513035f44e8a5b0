#!/usr/bin/python3
"""ocean_stats.py - subscribe to an oceand server and print statistics of each frame.

    /usr/bin/python3 proto/examples/ocean_stats.py ws://127.0.0.1:8080 --frames 30
    /usr/bin/python3 proto/examples/ocean_stats.py ws://127.0.0.1:8080 --fields height \\
        --lod 1 --bound 0.001 --frames 10 --save out      # also write out/height-<seq>.npy

Uses Debian's python3-websockets (10.x) and python3-numpy, and decodes the
binary frames with the oceand package (proto/python), its own implementation of
proto/PROTOCOL.md.
"""
import argparse
import asyncio
import json
import os
import sys
import time

import numpy as np
import websockets

try:
    import oceand as oceanproto
except ImportError:   # a checkout without `pip install ./proto/python`: the package beside this folder
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
    import oceand as oceanproto  # noqa: E402


def write_sidecar(path, name, frame, args, a):
    """The frame header beside each .npy, as ocean-tap writes it (docs/operations.md)."""
    side = a.shape[0]
    meta = {"field": name, "seq": frame.seq, "sim_time": frame.sim_time, "params_version": frame.params_version,
            "n": frame.n, "lod": args.lod, "patch_size": frame.patch_size, "spacing": frame.patch_size / side,
            "bound": args.bound, "server_time_us": frame.server_time_us, "format": "npy", "dtype": "float32",
            "shape": [side, side]}
    with open(path, "w") as f:
        json.dump(meta, f, indent=1)
        f.write("\n")


async def consume(args):
    async with websockets.connect(args.url, subprotocols=[oceanproto.SUBPROTOCOL],
                                  max_size=None, compression=None, open_timeout=args.timeout,
                                  close_timeout=1) as ws:
        hello = json.loads(await asyncio.wait_for(ws.recv(), args.timeout))
        if hello.get("type") != "hello" or hello.get("protocol") != oceanproto.VERSION:
            raise oceanproto.ProtocolError(f"unexpected first message: {str(hello)[:200]}")
        p = hello["params"]
        print(f"connected to {hello.get('server')}: N={p['resolution']} L={p['patch_size']} m "
              f"wind {p['wind_speed']} m/s, spectrum {p['spectrum']}, tick {hello.get('tick_rate')} Hz")

        # Ask for exactly what we want; wait for the server's normalised answer.
        # temporal: predicted frames (codec 3, ~2.5x fewer bytes; PROTOCOL.md §5.9), decoded
        # with a DecoderState that keeps the references; --intra: every frame alone.
        sub = {"type": "subscribe", "id": 1, "fields": args.fields, "lod": args.lod, "tiles": "all",
               "temporal": not args.intra}
        if args.bound is not None:
            sub["bound"] = args.bound
        if args.max_rate:
            sub["max_rate"] = args.max_rate
        # --cascades: the finer cascades' heights too (LOD 1 of a finer cascade loses nothing,
        # PROTOCOL.md §4.1), summed with cascade 0's on its grid: the whole sea.
        ncasc = min(int(p.get("cascades", 1)), 4) if args.cascades else 1
        if ncasc > 1:
            sub["cascades"] = [{"fields": ["height"], "lod": 1, "bound": 0 if args.bound == 0 else 0.001}] * (ncasc - 1)
        await ws.send(json.dumps(sub))
        while True:
            msg = await asyncio.wait_for(ws.recv(), args.timeout)
            if isinstance(msg, bytes):
                continue                       # a frame of the default subscription
            reply = json.loads(msg)
            if reply.get("type") == "error":
                raise oceanproto.ProtocolError(f"subscribe rejected: {reply.get('code')}: {reply.get('message')}")
            if reply.get("type") == "subscribed":
                break

        grid = oceanproto.Assembler(args.fields, args.lod)
        finer = [oceanproto.Assembler(["height"], 1, c) for c in range(1, ncasc)]
        state = oceanproto.DecoderState()
        resynced = -1.0
        done, nbytes, t0 = 0, 0, time.monotonic()
        while done < args.frames:
            msg = await asyncio.wait_for(ws.recv(), args.timeout)
            if not isinstance(msg, bytes):
                continue                       # params broadcasts etc.
            try:
                frame = oceanproto.decode_frame(msg, state)
            except oceanproto.ProtocolError as e:
                if e.code != "reference":
                    raise
                # A predicted frame whose references we lack: subscribing again makes the
                # server send keyframes next (at most once a second; frames on the way fail too).
                if time.monotonic() - resynced > 1:
                    resynced = time.monotonic()
                    await ws.send(json.dumps(sub))
                continue
            grid.add(frame)
            for a in finer:
                a.add(frame)
            if not grid.complete() or not all(a.complete() for a in finer):
                continue
            done += 1
            nbytes += len(msg)
            latency_ms = time.time() * 1e3 - frame.server_time_us / 1e3
            parts = []
            for name in args.fields:
                a = grid.fields[name]
                parts.append(f"{name}: min {a.min():.3f} max {a.max():.3f} mean {a.mean():.3f} std {a.std():.3f}")
                if args.save:
                    base = os.path.join(args.save, f"{name}-{frame.seq:08d}")
                    np.save(base + ".npy", a)
                    write_sidecar(base + ".json", name, frame, args, a)
            if finer and "height" in args.fields:
                grids = {0: {"height": grid.fields["height"]}}
                grids.update({a.cascade: {"height": a.fields["height"]} for a in finer})
                surface = oceanproto.Surface(frame.sim_time, frame.seq, frame.params_version,
                                             hello["cascade_patch_sizes"], grids)
                h = surface.grid("height", grid.fields["height"].shape[0])
                parts.append(f"sum of {ncasc} cascades: height std {h.std():.3f} "
                             f"(cascade 0 off it by {np.sqrt(np.mean((h - grid.fields['height']) ** 2)) * 1e3:.1f} mm rms)")
            print(f"seq {frame.seq}  t={frame.sim_time:.2f} s  " + "  ".join(parts) +
                  f"  {len(msg) / 1024:.1f} KiB  latency {latency_ms:.1f} ms", flush=True)
        dt = time.monotonic() - t0
        print(f"{done} frames in {dt:.2f} s: {done / dt:.1f} frames/s, "
              f"{nbytes / max(done, 1) / 1024:.1f} KiB/frame, {nbytes * 8 / dt / 1e6:.2f} Mbit/s")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("url", help="ws://host:port of an oceand server")
    ap.add_argument("--frames", type=int, default=10, help="complete frames to receive (default 10)")
    ap.add_argument("--fields", default="height,dx,dz", help="comma-separated field names")
    ap.add_argument("--lod", type=int, default=0, help="level of detail: (N/2^lod)^2 samples")
    ap.add_argument("--bound", type=float, help="max abs error; 0 = lossless (default: server's)")
    ap.add_argument("--save", metavar="DIR", help="write DIR/<field>-<seq>.npy and its .json sidecar for each frame")
    ap.add_argument("--timeout", type=float, default=10, help="seconds to wait for any message")
    ap.add_argument("--intra", action="store_true", help="intra-only frames (default: the temporal codec)")
    ap.add_argument("--max-rate", type=float, help="at most this many frames per second (default: every tick)")
    ap.add_argument("--cascades", action="store_true",
                    help="also the finer cascades' heights, summed with cascade 0's: the whole sea")
    args = ap.parse_args()
    args.fields = args.fields.split(",")
    unknown = set(args.fields) - set(oceanproto.FIELDS)
    if unknown:
        ap.error(f"unknown fields {sorted(unknown)}; known: {', '.join(oceanproto.FIELDS)}")
    if args.save:
        os.makedirs(args.save, exist_ok=True)
    try:
        asyncio.run(consume(args))
    except (oceanproto.ProtocolError, websockets.WebSocketException, OSError, asyncio.TimeoutError) as e:
        print(f"ocean_stats: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

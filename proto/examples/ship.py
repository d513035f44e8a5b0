#!/usr/bin/python3
"""ship.py - a small ship riding the sea: four hull probes (bow, stern, port,
starboard; PROTOCOL.md §7.4) give its heave, pitch and roll every tick.

    /usr/bin/python3 proto/examples/ship.py ws://127.0.0.1:8080 --length 40 --beam 10 \\
        --heading 30 --speed 5 --ticks 300

heave = mean of the four heights; pitch = atan((bow - stern) / length), bow
up positive; roll = atan((port - starboard) / beam), port up positive. The
ship sails at --speed m/s along --heading (degrees from +x towards +z): its
probes are moved once a second (a `probe` message replaces the set). Prints
one line per tick. Debian python3-websockets only.
"""
import argparse
import asyncio
import json
import math
import time

import websockets


def hull_points(x, z, heading, length, beam):
    c, s = math.cos(heading), math.sin(heading)
    ax, az = c * length / 2, s * length / 2          # along the keel
    px, pz = -s * beam / 2, c * beam / 2             # to port
    return [[x + ax, z + az], [x - ax, z - az], [x + px, z + pz], [x - px, z - pz]]


async def sail(args):
    heading = math.radians(args.heading)
    x, z = args.x, args.z
    async with websockets.connect(args.url, subprotocols=["oceand.v1"], max_size=None, compression=None,
                                  open_timeout=args.timeout, close_timeout=1) as ws:
        json.loads(await asyncio.wait_for(ws.recv(), args.timeout))      # hello
        # Frames are not needed: the smallest subscription there is.
        await ws.send(json.dumps({"type": "subscribe", "fields": ["height"], "lod": 4, "tiles": [[0, 0]],
                                  "max_rate": 1}))
        await ws.send(json.dumps({"type": "probe", "id": 1,
                                  "points": hull_points(x, z, heading, args.length, args.beam)}))
        last_move, t_prev, ticks = time.monotonic(), None, 0
        print("sim_time      x        z    heave_m  pitch_deg  roll_deg  heave_rate_m_s")
        while ticks < args.ticks or args.ticks == 0:
            msg = await asyncio.wait_for(ws.recv(), args.timeout)
            if isinstance(msg, bytes):
                continue
            m = json.loads(msg)
            if m.get("type") == "error":
                raise SystemExit(f"ship: server refused: {m.get('code')}: {m.get('message')}")
            if m.get("type") != "probe_data":
                continue
            bow, stern, port, star = m["points"]
            heave = (bow[0] + stern[0] + port[0] + star[0]) / 4
            rate = (bow[6] + stern[6] + port[6] + star[6]) / 4
            pitch = math.degrees(math.atan2(bow[0] - stern[0], args.length))
            roll = math.degrees(math.atan2(port[0] - star[0], args.beam))
            print(f"{m['sim_time']:9.3f} {x:8.2f} {z:8.2f} {heave:9.3f} {pitch:9.2f} {roll:9.2f} {rate:12.3f}",
                  flush=True)
            ticks += 1
            if t_prev is not None:
                dt = m["sim_time"] - t_prev
                x += args.speed * math.cos(heading) * dt
                z += args.speed * math.sin(heading) * dt
            t_prev = m["sim_time"]
            if args.speed and time.monotonic() - last_move >= 1.0:
                last_move = time.monotonic()
                await ws.send(json.dumps({"type": "probe",
                                          "points": hull_points(x, z, heading, args.length, args.beam)}))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("url")
    ap.add_argument("--x", type=float, default=0.0)
    ap.add_argument("--z", type=float, default=0.0)
    ap.add_argument("--length", type=float, default=40.0, help="m between the bow and stern probes")
    ap.add_argument("--beam", type=float, default=10.0, help="m between the port and starboard probes")
    ap.add_argument("--heading", type=float, default=0.0, help="degrees from +x towards +z")
    ap.add_argument("--speed", type=float, default=0.0, help="m/s")
    ap.add_argument("--ticks", type=int, default=0, help="stop after this many ticks (0 = until Ctrl-C)")
    ap.add_argument("--timeout", type=float, default=10.0)
    args = ap.parse_args()
    try:
        asyncio.run(sail(args))
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()

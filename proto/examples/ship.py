#!/usr/bin/python3
"""ship.py - a real ship on the shared sea (PROTOCOL.md §7.6): the server floats
it, every viewer sees it, and this script holds a course with its rudder.

    /usr/bin/python3 proto/examples/ship.py ws://127.0.0.1:8080 --kind ship \\
        --x 0 --z 0 --heading 0 --course 45 --throttle 0.8 [--seconds 60] [--name Ana]

Each second it prints the ship's heave (y), pitch, roll, speed and heading,
decoded from the records in the frame headers (§3.5). Frames: north = +z,
east = -x; body +z = bow, +y = up, +x = port. Heading: degrees clockwise from
north; pitch: bow up positive; roll: port side up positive.

The resume key goes to --key-file (default ./.ship-<kind>.key): restarted
within the server's grace, the script claims the same ship back instead of
launching a new one. Ctrl-C (or the end of --seconds) removes the ship.
"""
import argparse
import asyncio
import json
import math
import os
import signal
import sys

try:
    import oceand
except ImportError:   # a checkout without `pip install ./proto/python`
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
    import oceand  # noqa: E402


def attitude(q):
    """(heading, pitch, roll) in degrees from a body -> world quaternion (w, x, y, z)."""
    w, x, y, z = q
    bow = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))     # R * (0, 0, 1)
    port_y = 2 * (x * y + w * z)                                                 # (R * (1, 0, 0)).y
    up_y = 1 - 2 * (x * x + z * z)                                               # (R * (0, 1, 0)).y
    heading = math.degrees(math.atan2(-bow[0], bow[2])) % 360.0                  # east = -x, north = +z
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, bow[1]))))
    roll = math.degrees(math.atan2(port_y, up_y))
    return heading, pitch, roll


def rudder_for(course, heading, gain=1 / 30):
    """A proportional heading controller: full rudder beyond 30 degrees off course
    (rudder + is to starboard, which turns the bow clockwise)."""
    err = (course - heading + 180.0) % 360.0 - 180.0
    return max(-1.0, min(1.0, gain * err))


async def get_ship(sea, args):
    """Claim the ship of the key file back, or launch a new one (and save its key)."""
    try:
        with open(args.key_file) as f:
            saved = json.load(f)
        await sea.claim(saved["body"], saved["resume"])
        print(f"ship: claimed body {saved['body']} back", flush=True)
        return saved["body"]
    except (OSError, ValueError, KeyError, oceand.ServerError):
        pass
    m = await sea.launch(args.kind, args.x, args.z, heading=args.heading)
    with open(args.key_file, "w") as f:
        json.dump({"body": m["body"], "resume": m["resume"]}, f)
    print(f"ship: launched {args.kind} body {m['body']}", flush=True)
    return m["body"]


async def sail(args):
    sea = await oceand.AsyncClient.connect(args.url, args.timeout)
    body = None
    try:
        if args.name:
            await sea.ws.send(json.dumps({"type": "name", "name": args.name}))
        # Body records travel in frame headers: the smallest subscription that brings frames.
        await sea.subscribe(fields=["height"], lod=4, cascades=None, max_rate=10)
        body = await get_ship(sea, args)
        await sea.steer(body, throttle=args.throttle)
        print("     seq        x        z  heave_m pitch_deg roll_deg speed_m_s heading_deg rudder", flush=True)
        seq, start, last_print = None, None, -1.0
        while True:
            seq, records = await sea.bodies_now(newer_than=seq)
            me = next((b for b in records if b.id == body), None)
            if me is None:
                continue
            now = asyncio.get_running_loop().time()
            start = now if start is None else start
            heading, pitch, roll = attitude(me.quat)
            rudder = rudder_for(args.course, heading)
            await sea.steer(body, rudder=round(rudder, 3))
            if now - last_print >= 1.0:
                last_print = now
                x, y, z = me.pos
                speed = math.hypot(me.vel[0], me.vel[2])
                print(f"{seq:8d} {x:8.2f} {z:8.2f} {y:8.3f} {pitch:8.2f} {roll:8.2f} {speed:8.2f} "
                      f"{heading:10.1f} {rudder:+6.2f}", flush=True)
            if args.seconds and now - start >= args.seconds:
                break
    finally:
        if body is not None:
            try:
                await sea.remove(body)
                os.unlink(args.key_file)
                print(f"ship: removed body {body}", flush=True)
            except (oceand.ServerError, OSError, ConnectionError, asyncio.TimeoutError) as e:
                print(f"ship: could not remove body {body}: {e}", file=sys.stderr)
        await sea.close()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("url")
    ap.add_argument("--kind", default="ship", help="a name of hello's body_kinds (default ship)")
    ap.add_argument("--x", type=float, default=0.0, help="launch point, m (east = -x)")
    ap.add_argument("--z", type=float, default=0.0, help="launch point, m (north = +z)")
    ap.add_argument("--heading", type=float, default=0.0, help="the bow at launch, degrees clockwise from north")
    ap.add_argument("--course", type=float, default=0.0, help="degrees clockwise from north to steer to and hold")
    ap.add_argument("--throttle", type=float, default=0.5, help="-1 (astern) .. 1 (full ahead)")
    ap.add_argument("--name", default="", help="display name other viewers see")
    ap.add_argument("--seconds", type=float, default=0, help="stop (and remove the ship) after this many s")
    ap.add_argument("--key-file", help="where the resume key is kept (default ./.ship-KIND.key)")
    ap.add_argument("--timeout", type=float, default=10.0)
    args = ap.parse_args()
    args.key_file = args.key_file or f".ship-{args.kind}.key"
    for sig in (signal.SIGINT, signal.SIGTERM):   # Ctrl-C or kill: remove the ship, then exit
        signal.signal(sig, signal.default_int_handler)
    try:
        asyncio.run(sail(args))
    except KeyboardInterrupt:
        pass
    except oceand.ServerError as e:
        raise SystemExit(f"ship: server refused: {e}")


if __name__ == "__main__":
    main()

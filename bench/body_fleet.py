"""A fleet of floating bodies held open beside a synchronous benchmark (bench/load.py --bodies):
one control client (no frames) launches K bodies of every kind in turn on an 8-wide grid 40 m
apart, puts the powered ones under way and turning, as bench/bodies.py does, and keeps its
connection (so the bodies keep their owner) until stop(). Its own thread runs the asyncio
loop the websockets client needs."""
import asyncio
import json
import threading

import websockets

KINDS = ["spar", "ball", "dinghy", "boat", "ship"]
# What a daemon must allow for one client to launch a fleet at once.
DAEMON_ARGS = ["--bodies-per-session", "64", "--max-bodies", "64", "--launch-rate", "600",
               "--control-rate", "1000", "--control-burst", "1000"]


class Fleet:
    def __init__(self, url, count, timeout=20):
        self.url, self.count, self.timeout = url, count, timeout
        self.ready = threading.Event()
        self.error = None
        self.launched = 0
        self._loop = asyncio.new_event_loop()
        self._stop = None
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self):
        """Launch the fleet; returns once every body is launched and steered (raises on a refusal)."""
        self._thread.start()
        if not self.ready.wait(self.timeout + 5):
            raise RuntimeError("fleet: no answer in %d s" % self.timeout)
        if self.error:
            raise RuntimeError("fleet: %s" % self.error)
        return self

    def stop(self):
        if self._stop is not None:
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10)

    def _run(self):
        asyncio.set_event_loop(self._loop)
        try:
            self._loop.run_until_complete(self._main())
        except Exception as e:  # reported to start(); a fleet that fails must not hang the bench
            self.error = self.error or repr(e)
        finally:
            self.ready.set()
            self._loop.close()

    async def _main(self):
        self._stop = asyncio.Event()
        async with websockets.connect(self.url + "?frames=0", subprotocols=["oceand.v1"], max_size=None) as ws:
            hello = json.loads(await ws.recv())
            powered = {k["name"]: k["powered"] for k in hello["body_kinds"]}
            for i in range(self.count):
                await ws.send(json.dumps({"type": "launch", "id": i, "kind": KINDS[i % len(KINDS)],
                                          "x": (i % 8) * 40.0 - 140, "z": (i // 8) * 40.0 - 140,
                                          "heading": (37 * i) % 360}))
            ids = []
            while len(ids) < self.count:
                m = json.loads(await asyncio.wait_for(ws.recv(), self.timeout))
                if m.get("type") == "launched":
                    ids.append((m["body"], KINDS[m["id"] % len(KINDS)]))
                elif m.get("type") == "error":
                    self.error = "launch refused: %r" % m
                    return
            for body, kind in ids:
                if powered[kind]:
                    await ws.send(json.dumps({"type": "steer", "body": body, "throttle": 0.8, "rudder": 0.3}))
            self.launched = len(ids)
            self.ready.set()
            reader = asyncio.ensure_future(self._drain(ws))
            await self._stop.wait()
            reader.cancel()

    async def _drain(self, ws):
        """Read what the daemon sends (answers, `bodies`), so its queue to us never fills."""
        try:
            async for _ in ws:
                pass
        except websockets.ConnectionClosed:
            pass

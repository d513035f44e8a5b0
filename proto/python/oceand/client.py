"""oceand.client - a WebSocket client of oceand, async and sync.

    async with await AsyncClient.connect("ws://127.0.0.1:8080") as sea:
        await sea.subscribe(fields=["height", "dx", "dz"], bound=0, cascades="all")
        surface = await sea.surface()            # oceand.surface.Surface: every cascade of one frame
        h = surface.grid("height", 256)          # summed height on a 256 x 256 grid
        answer = await sea.query([[10, 20]])     # exact values (PROTOCOL.md §7.4)
        async for s in sea.render(start=100, fps=24, frames=240):   # exact times (§7.5)
            print(s.sim_time)                    # 100 + k/24, every k, in order

    with Client("ws://127.0.0.1:8080") as sea:   # the same calls, blocking
        sea.subscribe(cascades="all"); s = sea.surface(); sea.query([[0, 0]])

    A measured sea (§7.8), read by oceand.sea:  await sea.send_sea(oceand.sea.read("ndbc:46026"))
    A forecast as a timeline:  await sea.play_forecast(oceand.sea.read("forecast.spec"), speed=3600)
    sea.sea is the summary in force (hello's, then each params that brings one), or None.

One reader task takes every message off the socket: replies go to the request
that waits for them (by id), frames are decoded in order (predicted tiles need
every frame, §5.8) and the latest complete one is kept, probe_data is queued,
rendered frames (§7.5) wait in a short queue for render() (the reader waits when it
is full, so a slow consumer slows the render, never buffers it whole).
Uses Debian's python3-websockets (10.x) and python3-numpy only.
"""
import asyncio
import itertools
import json
import struct
import threading

import websockets

from . import frames as fr
from .surface import Surface


class ServerError(Exception):
    """The server answered a request with an `error` (§7.2): .code, .message, .reply."""

    def __init__(self, reply):
        self.reply, self.code, self.message = reply, reply.get("code"), reply.get("message", "")
        super().__init__(f"{self.code}: {self.message}")


RENDERED = 1   # frame header flags bit 0 (byte 38): a rendered frame (§7.5)


def _cascade_count(params):
    return int(params.get("cascades", 1))


class AsyncClient:
    """One connection. Create with `await AsyncClient.connect(url)`."""

    def __init__(self, ws, hello, timeout):
        self.ws, self.hello, self.timeout = ws, hello, timeout
        self.params = dict(hello.get("params", {}))
        self.params_version = hello.get("params_version")
        self.cascade_patch_sizes = list(hello.get("cascade_patch_sizes") or [self.params.get("patch_size")])
        self.subscription = hello.get("subscription", {})
        self._ids = itertools.count(1)
        self._waiting = {}                    # id -> Future of the reply
        self._state = fr.DecoderState()
        self._joiner = fr.FrameJoiner()
        self._assemblers = {}                 # cascade -> Assembler
        self._surface, self._surface_event = None, asyncio.Event()
        self._probe_queue = asyncio.Queue(maxsize=256)
        self._frame_error = None
        self._resub = None                    # the last subscribe, sent again to resync (§5.9)
        self._resync_t = -1.0
        self._temporal, self._latest = False, None
        self._render_q = asyncio.Queue(maxsize=4)   # rendered frames, then the render's end message
        self._render_id = None
        # Floating bodies (§7.6): the list (`bodies` messages), the keys that claim ours
        # back, and the newest frame's records.
        self.body_kinds = list(hello.get("body_kinds", []))
        self.bodies = {b["body"]: b for b in hello.get("bodies", [])}
        self.resume = {}                      # body -> resume key of the bodies this client launched
        self._bodies_now, self._bodies_event = None, asyncio.Event()
        self.sea = hello.get("sea")           # the measured sea's summary (§7.8), or None
        self._reader = asyncio.get_running_loop().create_task(self._read())

    @classmethod
    async def connect(cls, url, timeout=10.0):
        ws = await websockets.connect(url, subprotocols=[fr.SUBPROTOCOL], max_size=None, compression=None,
                                      open_timeout=timeout, close_timeout=1)
        hello = json.loads(await asyncio.wait_for(ws.recv(), timeout))
        if hello.get("type") != "hello" or hello.get("protocol") != fr.VERSION:
            await ws.close(1002)
            raise fr.ProtocolError("version", f"unexpected first message: {str(hello)[:200]}")
        return cls(ws, hello, timeout)

    async def __aenter__(self):
        return self

    async def __aexit__(self, *exc):
        await self.close()

    async def close(self):
        self._reader.cancel()
        try:
            await self._reader
        except (asyncio.CancelledError, Exception):
            pass
        await self.ws.close()

    # ---- the reader --------------------------------------------------------

    async def _read(self):
        try:
            async for msg in self.ws:
                if isinstance(msg, bytes):
                    if len(msg) >= 40 and msg[38] & RENDERED:
                        if self._render_id is not None:   # else a cancelled render's: dropped
                            await self._render_q.put(msg)  # waits for render() to take one
                    else:
                        try:
                            whole = self._joiner.push(msg)   # a tick may come in parts (§3.4)
                        except fr.ProtocolError:
                            whole = msg                      # the decoder says what is wrong
                        if whole is not None:
                            self._on_frame(whole)
                else:
                    m = json.loads(msg)
                    if self._render_id is not None and m.get("id") == self._render_id and \
                            m.get("type") in ("rendered", "error") and self._render_id not in self._waiting:
                        await self._render_q.put(m)
                    else:
                        self._on_text(m)
        except Exception as e:   # the connection ended: every waiting request learns it
            err = e
        else:
            err = ConnectionError("the server closed the connection")
        for f in self._waiting.values():
            if not f.done():
                f.set_exception(err)
        self._frame_error = err
        self._surface_event.set()
        if self._render_id is not None and not self._render_q.full():
            self._render_q.put_nowait(err)

    def _on_text(self, m):
        t = m.get("type")
        if t == "params":
            self.params.update(m.get("params", {}))
            self.params_version = m.get("params_version", self.params_version)
            if m.get("cascade_patch_sizes"):
                self.cascade_patch_sizes = list(m["cascade_patch_sizes"])
            if "sea" in m:
                self.sea = m["sea"]
        elif t == "bodies":
            self.bodies = {b["body"]: b for b in m.get("bodies", [])}
        elif t == "probe_data":
            if self._probe_queue.full():      # a reader that does not keep up loses the oldest
                self._probe_queue.get_nowait()
            self._probe_queue.put_nowait(m)
        f = self._waiting.pop(m.get("id"), None) if "id" in m else None
        if f is not None and not f.done():
            if t == "error":
                f.set_exception(ServerError(m))
            else:
                f.set_result(m)

    def _on_frame(self, data):
        try:   # the header alone: cheap, every frame
            self._bodies_now = (struct.unpack_from("<Q", data, 8)[0], fr.decode_bodies(data))
            self._bodies_event.set()
        except (fr.ProtocolError, struct.error):
            pass
        if not self._temporal:
            # Intra frames decode alone: keep the latest and decode it when asked, so
            # the reader never falls behind the replies (numpy decodes ~10 frames/s of
            # 3 fields x 3 cascades, the server sends 30).
            self._latest = data
            self._surface_event.set()
            return
        self._decode(data)

    def _decode(self, data):
        try:
            frame = fr.decode_frame(data, self._state if self._temporal else None)
        except fr.ProtocolError as e:
            if e.code != "reference":
                self._frame_error = e
                self._surface_event.set()
                return
            # Predicted tiles whose references we lack: subscribing again brings keyframes (§5.9).
            now = asyncio.get_running_loop().time()
            if self._resub is not None and now - self._resync_t > 1.0:
                self._resync_t = now
                asyncio.ensure_future(self.ws.send(json.dumps(self._resub)))
            return
        if not self._assemblers:
            return
        complete = True
        for a in self._assemblers.values():
            a.add(frame)
            complete = complete and a.complete()
        if complete:
            sizes = self.cascade_patch_sizes
            grids = {c: {k: v.copy() for k, v in a.fields.items()}
                     for c, a in self._assemblers.items() if c < len(sizes)}
            self._surface = Surface(frame.sim_time, frame.seq, frame.params_version, sizes, grids)
            self._surface_event.set()

    # ---- requests ----------------------------------------------------------

    async def request(self, msg):
        """Send a JSON request with a fresh id and wait for its reply (raises ServerError)."""
        msg = dict(msg, id=next(self._ids))
        fut = asyncio.get_running_loop().create_future()
        self._waiting[msg["id"]] = fut
        await self.ws.send(json.dumps(msg))
        try:
            return await asyncio.wait_for(fut, self.timeout)
        finally:
            self._waiting.pop(msg["id"], None)

    async def subscribe(self, fields=("height", "dx", "dz"), lod=0, bound=None, cascades="all",
                        max_rate=None, temporal=False, fine_lod=1, fine_bound=0.001):
        """Subscribe to `fields` of cascade 0 at `lod` and `bound` and, with cascades="all",
        the same fields of every finer cascade (3 entries: a 4th cascade is sent when
        it exists) at `fine_lod`, `fine_bound` (LOD 1 of a finer cascade loses nothing,
        §4.1); cascades=None: cascade 0 only; a list: the `cascades` member as is.
        temporal=True asks for predicted frames (codec 3, fewer bytes), which must all
        be decoded in order: only for a reader as fast as the stream."""
        # parts: replies (query, set) need not wait behind a whole frame on a slow link
        msg = {"type": "subscribe", "fields": list(fields), "lod": lod, "tiles": "all", "temporal": temporal,
               "parts": True}
        if bound is not None:
            msg["bound"] = bound
        if max_rate is not None:
            msg["max_rate"] = max_rate
        if cascades == "all":
            fb = fine_bound if bound != 0 else 0
            cascades = [{"fields": list(fields), "lod": fine_lod, "bound": fb}] * 3
        msg["cascades"] = list(cascades or [])
        reply = await self.request(msg)
        self.subscription = reply.get("subscription", {})
        self._resub = msg
        self._state.reset()
        n = min(_cascade_count(self.params), 1 + len(msg["cascades"]))
        self._assemblers = {0: fr.Assembler(fields, lod, 0)}
        for c, sub in enumerate(msg["cascades"][:n - 1], start=1):
            self._assemblers[c] = fr.Assembler(sub.get("fields", fields), sub.get("lod", lod), c)
        self._temporal, self._latest = temporal, None
        self._surface = None
        self._surface_event.clear()
        return self.subscription

    async def surface(self, newer_than=None):
        """The next complete frame of every subscribed cascade, as a Surface
        (newer than the Surface or seq given, else the next one to arrive)."""
        seq = getattr(newer_than, "seq", newer_than)
        if seq is None and self._surface is not None:
            seq = self._surface.seq
        while True:
            if self._frame_error is not None:
                raise self._frame_error
            if self._latest is not None:
                data, self._latest = self._latest, None
                self._decode(data)
            s = self._surface
            if s is not None and (seq is None or s.seq > seq):
                return s
            self._surface_event.clear()
            await asyncio.wait_for(self._surface_event.wait(), self.timeout)

    async def query(self, points, time=None):
        """Exact values at up to 256 world points (§7.4): the query_result message."""
        msg = {"type": "query", "points": [[float(x), float(z)] for x, z in points]}
        if time is not None:
            msg["time"] = float(time)
        return await self.request(msg)

    async def probe(self, points):
        """Probe these points every tick (§7.4); [] ends it. Read with probe_data()."""
        while not self._probe_queue.empty():
            self._probe_queue.get_nowait()
        return await self.request({"type": "probe", "points": [[float(x), float(z)] for x, z in points]})

    async def probe_data(self):
        """The next probe_data message (oldest first)."""
        return await asyncio.wait_for(self._probe_queue.get(), self.timeout)

    async def render(self, start, fps, frames, fields=("height", "dx", "dz"), lod=0, bound=None, cascades="all",
                     fine_lod=1, fine_bound=0.001):
        """Frames of the sea at exactly start + k/fps, k = 0 .. frames-1 (PROTOCOL.md §7.5),
        rendered by the server for the parameters in force: an async generator of one
        Surface per frame, every one, in order (.sim_time, .seq = k). Layers as in
        subscribe(); it does not change the subscription. Raises ServerError when the
        server refuses it (bad_render, busy) or ends it with an error. Closing the
        generator early (aclose(); the sync Client does it when its loop is left) cancels
        the render and waits for its end, so the next render may follow at once."""
        msg = {"type": "render", "id": next(self._ids), "start": float(start), "fps": float(fps),
               "frames": int(frames), "fields": list(fields), "lod": lod}
        if bound is not None:
            msg["bound"] = bound
        if cascades == "all":
            fb = fine_bound if bound != 0 else 0
            cascades = [{"fields": [f for f in fields if f != "foam"], "lod": fine_lod, "bound": fb}] * 3
        msg["cascades"] = list(cascades or [])
        fut = asyncio.get_running_loop().create_future()
        self._waiting[msg["id"]] = fut
        self._render_id = msg["id"]
        done, started, over = 0, False, False
        try:
            await self.ws.send(json.dumps(msg))
            try:
                reply = await asyncio.wait_for(fut, self.timeout)   # rendering, or ServerError
            finally:
                self._waiting.pop(msg["id"], None)
            started = True
            n = min(int(reply.get("cascades", 1)), 1 + len(msg["cascades"]))
            subs = [(fields, lod)] + [(c.get("fields", fields), c.get("lod", lod)) for c in msg["cascades"]]
            while True:
                item = await asyncio.wait_for(self._render_q.get(), max(self.timeout, 60.0))
                if isinstance(item, Exception):
                    over = True
                    raise item
                if isinstance(item, dict):
                    over = True
                    if item.get("type") == "error":
                        raise ServerError(item)
                    if item.get("frames", done) != done:
                        raise fr.ProtocolError("corrupt", f"render ended after {item.get('frames')} frames, "
                                                          f"{done} received")
                    return
                frame = fr.decode_frame(item)
                grids = {}
                for c in range(n):
                    a = fr.Assembler(subs[c][0], subs[c][1], c)
                    a.add(frame)
                    grids[c] = a.fields
                done += 1
                yield Surface(frame.sim_time, frame.seq, frame.params_version, self.cascade_patch_sizes, grids)
        finally:
            if started and not over and not self.ws.closed:
                # Left early: cancel, and wait for its `rendered`, after which the server takes the next.
                try:
                    await self.ws.send('{"type":"render_cancel"}')
                    while not isinstance(await asyncio.wait_for(self._render_q.get(), self.timeout),
                                         (dict, Exception)):
                        pass
                except Exception:
                    pass
            self._render_id = None
            while not self._render_q.empty():   # what was on its way: the reader drops the rest
                self._render_q.get_nowait()

    # ---- measured seas (§7.8) ---------------------------------------------

    async def send_sea(self, doc, token=None, tail=None):
        """Send one sea document (oceand.sea.read's, private members dropped): the
        `params` reply, whose "sea" is the summary (raises ServerError with the code)."""
        doc = {k: v for k, v in doc.items() if not k.startswith("_")}
        if tail is not None:
            doc["tail"] = tail
        msg = {"type": "sea", "sea": doc}
        if token:
            msg["token"] = token
        return await self.request(msg)

    async def play_forecast(self, docs, speed=1.0, token=None, tail=None, on_sent=None):
        """A forecast (documents in time order) as the sea's evolution: each document is
        sent when its time comes, the file's times scaled by 1/speed of wall-clock time
        (speed 3600: an hour of forecast a second); the server eases each change in.
        on_sent(doc, reply) is called after each. Returns the replies."""
        times = [_iso_seconds(d["time"]) for d in docs]
        t0, w0, out = times[0], asyncio.get_running_loop().time(), []
        for d, t in zip(docs, times):
            wait = w0 + (t - t0) / speed - asyncio.get_running_loop().time()
            if wait > 0:
                await asyncio.sleep(wait)
            r = await self.send_sea(d, token, tail)
            out.append(r)
            if on_sent:
                on_sent(d, r)
        return out

    # ---- floating bodies (§7.6) -------------------------------------------

    async def _body_request(self, msg, token):
        if token:
            msg["token"] = token
        return await self.request(msg)

    async def launch(self, kind, x, z, heading=0.0, token=None):
        """Launch a body of `kind` (a name of self.body_kinds) at world (x, z): the
        `launched` reply ({"body": id, "resume": key}); the key is kept in self.resume."""
        m = await self._body_request({"type": "launch", "kind": kind, "x": x, "z": z, "heading": heading}, token)
        self.resume[m["body"]] = m["resume"]
        return m

    async def steer(self, body, throttle=None, rudder=None, token=None):
        """Steer one of our bodies (-1..1 each; None keeps it): the `steered` reply."""
        msg = {"type": "steer", "body": body}
        if throttle is not None:
            msg["throttle"] = throttle
        if rudder is not None:
            msg["rudder"] = rudder
        return await self._body_request(msg, token)

    async def remove(self, body, token=None):
        """Remove one of our bodies: the `removed` reply."""
        m = await self._body_request({"type": "remove", "body": body}, token)
        self.resume.pop(body, None)
        return m

    async def claim(self, body, resume=None, token=None):
        """Take a body back with its resume key (after a reconnect, within the grace):
        the `claimed` reply. resume defaults to the key this client got at launch."""
        key = resume or self.resume[body]
        m = await self._body_request({"type": "claim", "body": body, "resume": key}, token)
        self.resume[body] = key
        return m

    async def bodies_now(self, newer_than=None):
        """(seq, [Body]) of the newest frame, or of the first one after seq newer_than
        (the client must receive frames: a ?frames=0 connection gets none)."""
        while self._bodies_now is None or (newer_than is not None and self._bodies_now[0] <= newer_than):
            if self._frame_error is not None and isinstance(self._frame_error, Exception) and \
                    not isinstance(self._frame_error, fr.ProtocolError):
                raise self._frame_error
            self._bodies_event.clear()
            await asyncio.wait_for(self._bodies_event.wait(), self.timeout)
        return self._bodies_now

    async def set(self, token=None, **params):
        """Change sea parameters (controller role): the `params` reply."""
        msg = {"type": "set", "params": params}
        if token:
            msg["token"] = token
        return await self.request(msg)


def _iso_seconds(text):
    """Seconds since 1970 of "YYYY-MM-DDThh:mm:ssZ" (the documents' times)."""
    import calendar
    import time as _time
    return calendar.timegm(_time.strptime(text, "%Y-%m-%dT%H:%M:%SZ"))


class Client:
    """The AsyncClient's calls, blocking: its event loop runs in a thread of its own
    (Debian 12's websockets 10 has no synchronous client)."""

    def __init__(self, url, timeout=10.0):
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="oceand-client", daemon=True)
        self._thread.start()
        self.timeout = timeout
        try:
            self._client = self._call(AsyncClient.connect(url, timeout))
        except BaseException:
            self._stop()
            raise

    def _call(self, coro):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(self.timeout + 5)

    def _stop(self):
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        self._loop.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self._loop.is_closed():
            return
        try:
            self._call(self._client.close())
        finally:
            self._stop()

    def render(self, *a, **k):
        """AsyncClient.render, as a plain generator of Surfaces."""
        gen = self._client.render(*a, **k)
        try:
            while True:
                try:
                    yield asyncio.run_coroutine_threadsafe(gen.__anext__(), self._loop).result(
                        max(self.timeout, 60.0) + 5)
                except StopAsyncIteration:
                    return
        finally:
            asyncio.run_coroutine_threadsafe(gen.aclose(), self._loop).result(self.timeout + 5)

    def play_forecast(self, *a, **k):
        """AsyncClient.play_forecast, blocking for as long as the timeline lasts."""
        return asyncio.run_coroutine_threadsafe(self._client.play_forecast(*a, **k), self._loop).result()

    def __getattr__(self, name):
        attr = getattr(self._client, name)
        if asyncio.iscoroutinefunction(attr):
            return lambda *a, **k: self._call(attr(*a, **k))
        return attr

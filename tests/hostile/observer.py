#!/usr/bin/python3
"""A well-behaved oceand client for the hostile battery, in its own process.

    observer.py ws://127.0.0.1:PORT/
Prints "ready <hello json>" once connected, then answers commands on stdin:
  mark   start a measurement window (prints {"ok":true})
  stats  frames received in the window, the seq span they cover, params
         messages seen, and whether the connection is still open (JSON line)
Exits when stdin closes. Frames are only counted (header seq), never decoded,
so the observer keeps up easily at small N.
"""
import asyncio
import json
import socket
import struct
import sys
import threading
import time

import websockets


class Window:
    def __init__(self):
        self.frames = 0
        self.first = None
        self.last = None
        self.params = 0
        self.texts = 0
        self.gaps = []          # (after_seq, missing, seconds into the window) for the first holes
        self.t0 = time.monotonic()


async def main(url):
    # A deep receive buffer and message queue: a hiccup in this process's own
    # scheduling (the machine is shared) must not look like the daemon's loss.
    host, port = url.split("//")[1].strip("/").split(":")
    sock = socket.socket()
    try:
        sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_RCVBUFFORCE", 33), 8 << 20)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.connect((host, int(port)))
    ws = await websockets.connect(url, sock=sock, subprotocols=["oceand.v1"], max_size=None, compression=None,
                                  max_queue=4096)
    hello = json.loads(await asyncio.wait_for(ws.recv(), 5))
    w = Window()
    state = {"closed": None}
    print("ready " + json.dumps(hello), flush=True)

    loop = asyncio.get_running_loop()
    cmds = asyncio.Queue()

    def stdin_reader():
        for line in sys.stdin:
            loop.call_soon_threadsafe(cmds.put_nowait, line.strip())
        loop.call_soon_threadsafe(cmds.put_nowait, None)

    threading.Thread(target=stdin_reader, daemon=True).start()

    async def receive():
        nonlocal w
        try:
            async for m in ws:
                if isinstance(m, bytes):
                    seq = struct.unpack_from("<Q", m, 8)[0]
                    if w.first is None:
                        w.first = seq
                    elif seq != w.last + 1 and len(w.gaps) < 20:
                        w.gaps.append((w.last, seq - w.last - 1, round(time.monotonic() - w.t0, 2)))
                    w.last = seq
                    w.frames += 1
                else:
                    w.texts += 1
                    if json.loads(m).get("type") == "params":
                        w.params += 1
        except websockets.exceptions.ConnectionClosed as e:
            state["closed"] = e.code if e.code is not None else -1
        if state["closed"] is None:
            state["closed"] = ws.close_code if ws.close_code is not None else -1

    rx = asyncio.create_task(receive())
    while True:
        c = await cmds.get()
        if c is None:
            break
        if c == "mark":
            w = Window()
            print(json.dumps({"ok": True}), flush=True)
        elif c == "stats":
            span = (w.last - w.first + 1) if w.first is not None else 0
            print(json.dumps({"frames": w.frames, "span": span, "params": w.params, "texts": w.texts, "gaps": w.gaps,
                              "closed": state["closed"]}), flush=True)
    rx.cancel()
    await ws.close()


if __name__ == "__main__":
    try:
        asyncio.run(main(sys.argv[1]))
    except Exception as e:  # the harness reads "not ready" and reports it
        print("error %r" % e, flush=True)
        sys.exit(1)

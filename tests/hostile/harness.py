"""Harness for the hostile-client battery: a real oceand on loopback, a raw
WebSocket client that controls every byte, and a well-behaved observer that
runs in its own process (so the attacker's CPU use in this process cannot
make it look slow).

Only 127.0.0.1 is ever used. Every loop is bounded by a count or a deadline.
"""
import fcntl
import json
import os
import resource
import select
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
PY = "/usr/bin/python3"

sys.path.insert(0, os.path.join(HERE, "..", "common"))
import oceand_proc  # noqa: E402


class CaseFailure(Exception):
    pass


def check(cond, msg):
    if not cond:
        raise CaseFailure(msg)


# ---------------------------------------------------------------- daemon

class Daemon(oceand_proc.Oceand):
    """One oceand with its own port, temp dir, state file and log."""

    def __init__(self, oceand, *extra, resolution=64, tick_rate=30, web=False, nofile=None, env=None,
                 log_pipe=False, fsize=None):
        tmp = tempfile.mkdtemp(prefix="oceand-hostile-")
        if web:   # a real web root (static file mount) instead of the placeholder page
            os.makedirs(os.path.join(tmp, "web"))
            with open(os.path.join(tmp, "web", "index.html"), "w") as f:
                f.write("<!doctype html><title>hostile test</title>")
        self.tick_rate = tick_rate
        self.pipe_r = self.pipe_w = None
        if log_pipe:   # stderr is a 4 KiB pipe that the test drains only when it chooses (drain_log)
            self.pipe_r, self.pipe_w = os.pipe()
            fcntl.fcntl(self.pipe_w, 1031, 4096)            # F_SETPIPE_SZ: one page
            os.set_blocking(self.pipe_r, False)

        def preexec():
            if nofile:   # a low descriptor limit (ulimit -n) for the daemon only
                resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))
            if fsize:    # a file size limit (ulimit -f, bytes): writes past it fail (or SIGXFSZ)
                resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
        super().__init__(oceand, "--bind", "127.0.0.1",
                         "--state-file", os.path.join(tmp, "state.json"),
                         "--web-root", os.path.join(tmp, "web"),
                         "--resolution", str(resolution), "--tick-rate", str(tick_rate),
                         "--log-level", "warn",
                         # the old fixed memory cap (the default now follows the machine's memory):
                         # cases that expect N = 2048 refused do not depend on this machine's memory
                         "--max-memory-mb", "256", *extra,
                         tmp=tmp, own_tmp=True, env=env, out=self.pipe_w,
                         preexec_fn=preexec if nofile or fsize else None, error=CaseFailure)

    def _spawned(self):
        if self.pipe_w is not None:   # the daemon holds the write end now
            os.close(self.pipe_w)
            self.pipe_w = None

    def drain_log(self):
        """Pipe mode: move what the daemon wrote to its stderr pipe into the log file."""
        while self.pipe_r is not None:
            try:
                data = os.read(self.pipe_r, 65536)
            except BlockingIOError:
                break
            if not data:
                break
            self.log.write(data)
        if not self.log.closed:
            self.log.flush()

    def read_log(self, tail=3000):
        if self.log is not None and not self.log.closed:
            self.drain_log()
        return super().read_log(tail)

    def sched(self):
        """(cpu_ms, runq_wait_ms) summed over the daemon's threads (/proc/PID/task/*/schedstat).
        Run-queue wait is time a thread was ready but the machine gave it no core."""
        cpu = wait = 0
        for t in os.listdir("/proc/%d/task" % self.proc.pid):
            try:
                with open("/proc/%d/task/%s/schedstat" % (self.proc.pid, t)) as f:
                    a = f.read().split()
                cpu += int(a[0])
                wait += int(a[1])
            except (OSError, IndexError, ValueError):
                pass
        return cpu / 1e6, wait / 1e6

    def fds(self):
        return len(os.listdir("/proc/%d/fd" % self.proc.pid))

    def get(self, path, timeout=5):
        with urllib.request.urlopen(self.http + path, timeout=timeout) as r:
            return r.read().decode()

    def metrics(self):
        out = {}
        for line in self.get("/metrics").splitlines():
            if line and not line.startswith("#"):
                k, _, v = line.rpartition(" ")
                out[k] = float(v)
        return out

    def metric(self, name):
        m = self.metrics()
        check(name in m, "metric %s missing" % name)
        return m[name]

    def health(self):
        return json.loads(self.get("/healthz"))

    def stop(self, timeout=10):
        """SIGTERM and wait; returns the exit code (None if it had to be killed)."""
        # pipe mode: never let our own pipe hold the daemon up
        rc, _ = super().stop(signal.SIGTERM, timeout, while_waiting=self.drain_log)
        self.kill()
        return rc

    def kill(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        if self.log is not None and not self.log.closed:
            self.drain_log()
        for fd in (self.pipe_r, self.pipe_w):
            if fd is not None:
                os.close(fd)
        self.pipe_r = self.pipe_w = None
        return super().kill()


def wait_until(pred, timeout, step=0.05):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if pred():
            return True
        time.sleep(step)
    return pred()


# ---------------------------------------------------------------- raw WebSocket

def handshake_request(port, extra_headers=""):
    return ("GET / HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
            "Sec-WebSocket-Protocol: oceand.v1\r\n%s\r\n" % (port, extra_headers)).encode()


def read_http_response(s, timeout=5):
    """Bytes up to the end of the HTTP response head, b'' if closed first."""
    s.settimeout(timeout)
    resp = b""
    try:
        while b"\r\n\r\n" not in resp and len(resp) < 16384:
            c = s.recv(1)
            if not c:
                break
            resp += c
    except (socket.timeout, ConnectionError):
        pass
    return resp


def raw_ws(port, rcvbuf=None, extra_headers="", timeout=5):
    """Handshake by hand; returns (socket, response head). Raises if refused."""
    s = socket.socket()
    if rcvbuf:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.settimeout(timeout)
    s.connect(("127.0.0.1", port))
    s.sendall(handshake_request(port, extra_headers))
    resp = read_http_response(s, timeout)
    if b" 101 " not in resp.split(b"\r\n")[0]:
        s.close()
        raise CaseFailure("handshake refused: %r" % resp[:120])
    return s, resp


def mask_bytes(payload, key):
    if key == b"\0\0\0\0" or not payload:
        return payload
    n = len(payload)
    k = (key * (n // 4 + 1))[:n]
    return (int.from_bytes(payload, "big") ^ int.from_bytes(k, "big")).to_bytes(n, "big")


def ws_header(opcode, length, fin=True, rsv1=False, key=b"\x11\x22\x33\x44"):
    b0 = (0x80 if fin else 0) | (0x40 if rsv1 else 0) | opcode
    if length < 126:
        h = struct.pack("!BB", b0, 0x80 | length)
    elif length < 65536:
        h = struct.pack("!BBH", b0, 0x80 | 126, length)
    else:
        h = struct.pack("!BBQ", b0, 0x80 | 127, length)
    return h + key


def ws_frame(opcode, payload, fin=True, rsv1=False, key=b"\x11\x22\x33\x44"):
    if isinstance(payload, str):
        payload = payload.encode()
    return ws_header(opcode, len(payload), fin, rsv1, key) + mask_bytes(payload, key)


OP_CONT, OP_TEXT, OP_BIN, OP_CLOSE, OP_PING, OP_PONG = 0, 1, 2, 8, 9, 10


class Reader:
    """Incremental parser of server->client frames on a raw socket."""

    def __init__(self, s):
        self.s = s
        self.buf = b""
        self.texts = []          # JSON objects received
        self.raw = []            # ...and their text as received (bytes): what json.loads would round
        self.bin_at = []         # self.binary when each of them arrived
        self.binary = 0          # binary frames (or final fragments) received
        self.close_code = None   # code from the server's close frame
        self.eof = False         # TCP closed (FIN or RST)
        self.reset = False

    def _parse(self):
        while True:
            b = self.buf
            if len(b) < 2:
                return
            op = b[0] & 0x0F
            n = b[1] & 0x7F
            off = 2
            if n == 126:
                if len(b) < 4:
                    return
                n = struct.unpack_from("!H", b, 2)[0]
                off = 4
            elif n == 127:
                if len(b) < 10:
                    return
                n = struct.unpack_from("!Q", b, 2)[0]
                off = 10
            if len(b) < off + n:
                return
            payload = b[off:off + n]
            self.buf = b[off + n:]
            if op == OP_TEXT:
                self.bin_at.append(self.binary)
                self.raw.append(payload)
                try:
                    self.texts.append(json.loads(payload))
                except ValueError:
                    self.texts.append({"unparseable": payload[:80].decode(errors="replace")})
            elif op in (OP_BIN, OP_CONT):
                if b[0] & 0x80:
                    self.binary += 1
            elif op == OP_CLOSE:
                self.close_code = struct.unpack("!H", payload[:2])[0] if len(payload) >= 2 else 1005
            elif op == OP_PING:
                pass                # deliberately never answered

    def pump(self, timeout=0.0):
        """Read what is available (waiting up to timeout for the first bytes)."""
        if self.eof:
            return
        r, _, _ = select.select([self.s], [], [], timeout)
        while r:
            try:
                data = self.s.recv(1 << 16, socket.MSG_DONTWAIT)
            except BlockingIOError:
                break
            except (ConnectionResetError, OSError):
                self.eof = self.reset = True
                break
            if not data:
                self.eof = True
                break
            self.buf += data
            self._parse()
            r, _, _ = select.select([self.s], [], [], 0)

    def until(self, pred, timeout):
        deadline = time.time() + timeout
        while not pred(self) and not self.eof and time.time() < deadline:
            self.pump(min(0.1, max(0.0, deadline - time.time())))
        return pred(self)

    def errors(self):
        return [t for t in self.texts if t.get("type") == "error"]


def send_quiet(s, data):
    """sendall that reports a closed peer instead of raising."""
    try:
        s.sendall(data)
        return True
    except (BrokenPipeError, ConnectionResetError, OSError):
        return False


def rst_close(s):
    s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    s.close()


# ---------------------------------------------------------------- observer

class Observer:
    """A well-behaved client in its own process (tests/hostile/observer.py)."""

    def __init__(self, url):
        self.p = subprocess.Popen([PY, os.path.join(HERE, "observer.py"), url],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        line = self._readline(15)
        check(line.startswith("ready"), "observer did not connect: %r" % line)
        self.hello = json.loads(line[len("ready "):])

    def _readline(self, timeout):
        r, _, _ = select.select([self.p.stdout], [], [], timeout)
        if not r:
            return ""
        return self.p.stdout.readline().strip()

    def _cmd(self, c):
        try:
            self.p.stdin.write(c + "\n")
            self.p.stdin.flush()
        except BrokenPipeError:
            return {"error": "observer gone"}
        line = self._readline(10)
        return json.loads(line) if line else {"error": "observer silent"}

    def mark(self):
        """Start a measurement window."""
        return self._cmd("mark")

    def stats(self):
        """Frames in the window: received, expected from seq span, params seen, closed?"""
        return self._cmd("stats")

    def close(self):
        try:
            self.p.stdin.close()
        except OSError:
            pass
        try:
            self.p.wait(5)
        except subprocess.TimeoutExpired:
            self.p.kill()
            self.p.wait()

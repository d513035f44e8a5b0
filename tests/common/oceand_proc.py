"""oceand_proc — the processes the Python suites and benches run against:
oceand, and nats-server for the cluster roles.

Each process gets a free 127.0.0.1 port and a log in a temporary folder, is
waited for until it serves (oceand: /healthz answers; nats-server: its port
accepts), and is stopped by its owner. Whatever is still running when this
process exits, or is stopped by SIGTERM (make's Ctrl-C, a CI timeout), is
killed and its own temporary folder removed, so that no daemon outlives its
test. Only loopback addresses are used.

Import with a path relative to the caller:
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "common"))
    import oceand_proc

    d = oceand_proc.Oceand("build/oceand", "--resolution", "64")   # started and ready
    d.url, d.http, d.port, d.tmp, d.read_log(), d.stop() -> (exit code, seconds)
    n = oceand_proc.Nats(store=True)                               # -js with its own store in n.tmp
"""
import atexit
import ctypes
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import urllib.error
import urllib.request

NATS_BIN = shutil.which("nats-server") or "/usr/sbin/nats-server"


class ProcError(Exception):
    """A process did not start or did not become ready (suites pass their own failure class as error=)."""


def free_port():
    """A TCP port on 127.0.0.1 that nothing listens on now (the kernel's pick)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def die_with_parent():
    """preexec_fn: SIGKILL the child when this process dies, even by SIGKILL (PR_SET_PDEATHSIG).
    Not for processes started from a thread that may end first: the signal follows the thread."""
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)


# ------------------------------------------------------------ clean-up of what is left

_live = []           # started and not closed: killed (and their own folders removed) at exit
_sigterm_hooked = False


def _cleanup():
    for p in list(_live):
        try:
            p.close()
        except Exception:   # clean-up goes on for the others
            pass


def _on_sigterm(signum, frame):
    _cleanup()
    # Then die of SIGTERM as if nothing had been caught: the parent sees the usual status.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    os.kill(os.getpid(), signal.SIGTERM)


def _track(p):
    global _sigterm_hooked
    if not _sigterm_hooked:
        _sigterm_hooked = True
        atexit.register(_cleanup)
        # A handler the program installed itself is left alone (it owns the policy).
        if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
            try:
                signal.signal(signal.SIGTERM, _on_sigterm)
            except ValueError:   # not the main thread: atexit still cleans up
                pass
    if p not in _live:
        _live.append(p)


def _untrack(p):
    if p in _live:
        _live.remove(p)


# ------------------------------------------------------------ one child process

class _Proc:
    """What oceand and nats-server share: a child with a log file in a folder."""

    name = "process"

    def __init__(self, tmp, prefix, port, log_name, error, own_tmp=None):
        # A folder made here is removed by close() (and at exit); own_tmp=True hands one over.
        self.own_tmp = tmp is None if own_tmp is None else own_tmp
        self.tmp = tmp or tempfile.mkdtemp(prefix=prefix)
        self.port = port or free_port()
        self.log_path = os.path.join(self.tmp, log_name)
        self.error = error
        self.proc = None
        self.log = None

    @property
    def pid(self):
        return self.proc.pid

    def alive(self):
        return self.proc is not None and self.proc.poll() is None

    def _spawn(self, args, out=None, env=None, preexec_fn=None):
        """Start args with stdout and stderr to out (default: the log file, appended to)."""
        if self.log is not None and not self.log.closed:   # a restart: the earlier run's handle
            self.log.close()
        self.log = open(self.log_path, "ab")
        _track(self)
        self.proc = subprocess.Popen(args, stdout=out if out is not None else self.log,
                                     stderr=out if out is not None else self.log,
                                     env=dict(os.environ, **env) if env else None, preexec_fn=preexec_fn)

    def read_log(self, tail=4000):
        """The last `tail` characters of the log."""
        try:
            with open(self.log_path, "rb") as f:
                return f.read().decode(errors="replace")[-tail:]
        except OSError:
            return ""

    def stop(self, sig=signal.SIGTERM, timeout=10, while_waiting=None):
        """Send sig and wait up to timeout s (calling while_waiting() every 50 ms if given);
        SIGKILL after that. Returns (exit code, seconds); the code is None when it had to be
        killed. OCEAND_TEST_GDB=1 prints every thread's stack before that kill."""
        if self.proc is None or self.proc.poll() is not None:
            return (self.proc.returncode if self.proc else None), 0.0
        t0 = time.time()
        self.proc.send_signal(sig)
        deadline = t0 + timeout
        while self.proc.poll() is None and time.time() < deadline:
            if while_waiting:
                while_waiting()
            try:
                self.proc.wait(0.05)
            except subprocess.TimeoutExpired:
                pass
        if self.proc.poll() is not None:
            return self.proc.returncode, time.time() - t0
        if os.environ.get("OCEAND_TEST_GDB"):
            subprocess.run(["gdb", "-p", str(self.proc.pid), "-batch", "-ex", "thread apply all bt"])
        self.proc.kill()
        self.proc.wait()
        return None, time.time() - t0

    def kill(self):
        """SIGKILL if still running, reap, close the log. Returns the exit code."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        if self.log is not None and not self.log.closed:
            self.log.close()
        return self.proc.returncode if self.proc is not None else None

    def close(self):
        """kill(), and remove the folder if this object made it."""
        self.kill()
        _untrack(self)
        if self.own_tmp:
            shutil.rmtree(self.tmp, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


# ------------------------------------------------------------ oceand

class Oceand(_Proc):
    """One oceand: `binary --port PORT *args`, started and ready when the constructor returns.

    tmp: the folder of its log (made, and removed by close(), when None; own_tmp=True: a
    folder made for it, removed the same way); name: the log's name (name.log) and the
    name in messages; env: variables added to this environment;
    tls_ctx: the client SSL context when it serves https/wss; ready(health): when given,
    also waits until it holds for the /healthz JSON (e.g. an edge that sees its sim);
    out: a file or descriptor for its stdout and stderr instead of the log; error: the
    exception class raised when it does not start."""

    def __init__(self, binary, *args, tmp=None, prefix="oceand-", port=None, name="oceand", env=None,
                 preexec_fn=None, tls_ctx=None, ready=None, ready_timeout=20.0, out=None, error=ProcError,
                 own_tmp=None):
        super().__init__(tmp, prefix, port, name + ".log", error, own_tmp)
        self.name = name
        self.binary = binary
        self.args = [str(a) for a in args]
        self.env, self.preexec_fn, self.out = env, preexec_fn, out
        self.tls_ctx = tls_ctx
        scheme = "s" if tls_ctx else ""
        self.url = "ws%s://127.0.0.1:%d/" % (scheme, self.port)
        self.http = "http%s://127.0.0.1:%d" % (scheme, self.port)
        self.ready, self.ready_timeout = ready, ready_timeout
        try:
            self.start()
        except BaseException:
            self.close()
            raise

    def start(self):
        """(Re)start on the same port, arguments and folder; wait until ready."""
        self._spawn([self.binary, "--port", str(self.port)] + self.args, self.out, self.env, self.preexec_fn)
        self._spawned()
        self.wait_ready()

    def _spawned(self):
        """Called right after the process is created (a subclass closes its end of a pipe here)."""

    def restart(self, sig=signal.SIGKILL):
        self.stop(sig)
        self.kill()
        self.start()

    def wait_ready(self):
        deadline = time.time() + self.ready_timeout
        while True:
            if self.proc.poll() is not None:
                raise self.error("%s exited at start with %s; log:\n%s" % (self.name, self.proc.returncode,
                                                                          self.read_log()))
            try:
                body = urllib.request.urlopen(self.http + "/healthz", timeout=1, context=self.tls_ctx).read()
                if self.ready is None or self.ready(json.loads(body)):
                    return
            except (urllib.error.URLError, ConnectionError, OSError, ValueError, KeyError):
                pass
            if time.time() > deadline:
                raise self.error("%s did not answer /healthz%s within %g s; log:\n%s"
                                 % (self.name, "" if self.ready is None else " as expected", self.ready_timeout,
                                    self.read_log()))
            time.sleep(0.05)

    def rss_kb(self):
        with open("/proc/%d/status" % self.proc.pid) as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
        return 0

    def cpu_s(self):
        """User + system CPU seconds it has used (/proc/PID/stat, all threads)."""
        with open("/proc/%d/stat" % self.proc.pid) as f:
            a = f.read().rsplit(")", 1)[1].split()
        return (int(a[11]) + int(a[12])) / os.sysconf("SC_CLK_TCK")


# ------------------------------------------------------------ nats-server

class Nats(_Proc):
    """A nats-server on 127.0.0.1, started and listening when the constructor returns.
    stop() kills it (SIGKILL: a crash) and start() brings it back on the same port.
    store=True: JetStream on, with its own store folder inside tmp."""

    name = "nats-server"

    def __init__(self, tmp=None, port=None, store=False, args=(), binary=None, log_name="nats.log",
                 pdeathsig=True, error=ProcError):
        super().__init__(tmp, "oceand-nats-", port, log_name, error)
        self.url = "nats://127.0.0.1:%d" % self.port
        self.binary = binary or NATS_BIN
        self.args = ["-a", "127.0.0.1", "-p", str(self.port)] + list(args)
        if store:
            self.store_dir = os.path.join(self.tmp, "nats-store")
            self.args += ["-js", "-sd", self.store_dir]
        self.pdeathsig = pdeathsig
        try:
            self.start()
        except BaseException:
            self.close()
            raise

    def start(self, timeout=10.0):
        self._spawn([self.binary] + self.args, preexec_fn=die_with_parent if self.pdeathsig else None)
        deadline = time.time() + timeout
        while True:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.5).close()
                return
            except OSError:
                if self.proc.poll() is not None:
                    raise self.error("nats-server exited at start with %s; log:\n%s"
                                     % (self.proc.returncode, self.read_log()))
                if time.time() > deadline:
                    raise self.error("nats-server did not listen on port %d" % self.port)
                time.sleep(0.05)

    def stop(self, sig=signal.SIGKILL, timeout=5, while_waiting=None):
        return super().stop(sig, timeout, while_waiting)


if __name__ == "__main__":
    # For shell scripts: `python3 tests/common/oceand_proc.py free-port` prints one.
    import sys
    if sys.argv[1:] != ["free-port"]:
        sys.exit("usage: oceand_proc.py free-port")
    print(free_port())

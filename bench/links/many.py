#!/usr/bin/python3
"""The link lab with many viewers (`make bench-links-load`): the daemon's encode cost with
200 viewers spread over the five links of bench-links, against the same 200 viewers all on
the fast path (loopback), in the same run.

Two network namespaces joined by bench/links/shaper in per-flow mode: oceand in A, the
viewers in B, 40 per link class, each class on its own address of B, and each viewer's TCP
connection with a link of its own (rate, one-way delay = RTT/2, loss, drop-tail queue of
100 ms at the rate, at least 32 kB): 40 viewers "on 2 Mbit/s" have 2 Mbit/s each. The
viewers are build/load_client (one process per class, 40 connections each), with the web
client's subscription (bench/links/viewer.py's WEB_SUB, temporal) and no `set`s.

Rows, per run (a fresh daemon each, the two alternating in order from run to run):
  loopback-200   the 200 viewers in A, on the daemon's loopback (5 processes of 40, as below)
  links-200      the 200 viewers in B, 40 per link: 50M/20ms, 10M/50ms, 4M/80ms/1%, 2M/150ms,
                 1M/300ms/2%
One JSON object per row and run; then one per row with the medians over the runs, and a
`ratio` row: links-200 / loopback-200 per run (encode ms per tick, CPU, layers per frame)
and their medians.

Daemon figures come from /proc (CPU) and /metrics, polled every 20 ms through the window:
an interval in which exactly one frame was published gives that frame's encode and tick
time exactly (oceand_encode_duration_seconds / oceand_tick_duration_seconds sums), hence
their medians per tick; layers and samples per frame from oceand_layers_encoded_total and
oceand_samples_encoded_total. The shaper runs SCHED_RR (--shaper-rt): one process carries all
200 links, and when it waited for a CPU its delays read as congestion to every viewer's ladder.
Each row also has the shaper's and the viewers' CPU, and the daemon's time runnable but
waiting for a CPU (/proc schedstat): this machine may be shared.

    many.py --oceand build/oceand --shaper build/shaper --load-client build/load_client
            [--runs 3] [--warmup 10] [--window 20] [--rows loopback-200,links-200]
Needs root (namespaces, TUN); without it prints {"skipped": ...} and exits 0.
"""
import argparse
import ctypes
import json
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from load import cpu_seconds, cpu_split, runq_wait_seconds  # noqa: E402 (bench/load.py: /proc readers)

WEB_SUB = {"type": "subscribe", "id": "sub", "fields": ["height", "dx", "dz", "foam"], "field_lod": {"foam": 2},
           "cascades": [{"fields": ["height"], "lod": 1, "bound": 0.001}] * 3, "temporal": True}
# (bench/links/viewer.py's without "parts": load_client counts every binary message as a frame)
# name, kbit/s, RTT ms, loss %: the five links of bench-links (bench/links/run.sh)
LINKS = [("50M", 50000, 20, 0), ("10M", 10000, 50, 0), ("4M", 4000, 80, 1), ("2M", 2000, 150, 0),
         ("1M", 1000, 300, 2)]
PORT = 8090
CLONE_NEWNET = 0x40000000


def sh(*cmd, check=True):
    return subprocess.run(cmd, check=check, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def stop(p, timeout):
    """Terminate a process; kill it if it is still there after `timeout` s."""
    if p and p.poll() is None:
        p.terminate()
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


METRIC_RE = re.compile(r"^(oceand_[a-z_]+(?:\{[^}]*\})?) (\S+)$", re.M)


class Lab:
    def __init__(self, a):
        self.a = a
        self.tag = os.getpid()
        self.ns_a, self.ns_b = "mlA%d" % self.tag, "mlB%d" % self.tag
        self.net = "10.202.%d" % (self.tag % 200 + 20)
        self.tmp = tempfile.mkdtemp(prefix="links-load-")
        self.procs = []        # (Popen, name): stopped at exit, last first
        self.shaper = None
        self.daemon = None

    def shaper_priority(self):
        """The shaper stands for the network: it should not wait for a CPU behind the daemon or other
        work (one process carries all 200 links, and its delays are every viewer's RTT). SCHED_RR at
        the lowest real-time priority (it sleeps in ppoll between packets; the kernel's real-time
        throttling still leaves 5 % to the rest), or only a niceness with --shaper-rt 0."""
        if self.a.shaper_rt:
            try:
                os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(1))
                return
            except OSError:
                pass
        os.nice(self.a.shaper_nice)

    # ---- set-up and clean-up
    def up(self):
        sh("ip", "netns", "add", self.ns_a)
        sh("ip", "netns", "add", self.ns_b)
        for ns in (self.ns_a, self.ns_b):
            sh("ip", "-n", ns, "link", "set", "lo", "up")
        flows = []
        for i, (_, kbit, rtt, loss) in enumerate(self.a.link_list):
            q = max(32768, kbit * 1000 // 8 // 10)      # 100 ms at the rate, at least 32 kB (run.sh)
            flows += ["--flow", "%s.%d:%d:%g:%g:%d" % (self.net, 2 + i, kbit, rtt / 2, loss, q)]
        # the shared link (anything else): fast, 0.1 ms
        self.shaper = subprocess.Popen([self.a.shaper, self.ns_a, self.ns_b, "10000000", "0.1", "0", "16777216", "1"]
                                       + flows, preexec_fn=self.shaper_priority, stdout=subprocess.PIPE, stderr=open(os.path.join(self.tmp, "shaper.err"), "w"),
                                       text=True)
        if self.shaper.stdout.readline().strip() != "ready":
            raise RuntimeError("the shaper did not start: " + open(os.path.join(self.tmp, "shaper.err")).read())
        sh("ip", "-n", self.ns_a, "addr", "add", self.net + ".1/24", "dev", "lnk0")
        # a long device queue: packets are dropped by the links' own queues, not before the shaper reads them
        sh("ip", "-n", self.ns_a, "link", "set", "lnk0", "up", "mtu", "1500", "txqueuelen", "10000")
        for i in range(len(self.a.link_list)):
            sh("ip", "-n", self.ns_b, "addr", "add", "%s.%d/24" % (self.net, 2 + i), "dev", "lnk0")
        sh("ip", "-n", self.ns_b, "link", "set", "lnk0", "up", "mtu", "1500", "txqueuelen", "10000")
        # This process joins A (its /metrics polls); `ip netns exec B` still reaches B.
        fd = os.open("/var/run/netns/" + self.ns_a, os.O_RDONLY)
        if ctypes.CDLL("libc.so.6", use_errno=True).setns(fd, CLONE_NEWNET) != 0:
            raise RuntimeError("setns failed")
        os.close(fd)

    def down(self):
        self.stop_daemon()
        for p, _ in reversed(self.procs):
            stop(p, 5)
        self.procs = []
        stop(self.shaper, 5)
        for ns in (self.ns_a, self.ns_b):
            sh("ip", "netns", "del", ns, check=False)
        shutil.rmtree(self.tmp, ignore_errors=True)

    # ---- the daemon
    def start_daemon(self):
        web = os.path.join(self.tmp, "web")
        os.makedirs(web, exist_ok=True)
        log = open(os.path.join(self.tmp, "oceand.log"), "w")
        self.daemon = subprocess.Popen([self.a.oceand, "--bind", self.net + ".1", "--port", str(PORT),
                                        "--state-file", "none", "--web-root", web, "--resolution", "256",
                                        "--plan-rigor", "0", "--wisdom-file", "none", "--max-clients", "400",
                                        "--log-level", "warn"] + self.a.oceand_args.split(),
                                       preexec_fn=(lambda: os.nice(self.a.daemon_nice)) if self.a.daemon_nice else None,
                                       stdout=log, stderr=log)
        for _ in range(200):
            try:
                urllib.request.urlopen("http://%s.1:%d/healthz" % (self.net, PORT), timeout=1).read()
                return
            except OSError:
                time.sleep(0.1)
        raise RuntimeError("the daemon did not start: " + open(os.path.join(self.tmp, "oceand.log")).read()[-500:])

    def stop_daemon(self):
        stop(self.daemon, 10)
        self.daemon = None

    def tun_dropped(self):
        """Packets the two TUN devices dropped before the shaper read them (its queue was full)."""
        n = 0
        for ns in (self.ns_a, self.ns_b):
            out = subprocess.run(["ip", "-n", ns, "-j", "-s", "link", "show", "lnk0"], capture_output=True, text=True).stdout
            try:
                n += json.loads(out)[0]["stats64"]["tx"]["dropped"]
            except (ValueError, LookupError):
                pass
        return n

    def metrics(self):
        text = urllib.request.urlopen("http://%s.1:%d/metrics" % (self.net, PORT), timeout=2).read().decode()
        return {k: float(v) for k, v in METRIC_RE.findall(text)}

    # ---- one row
    def row(self, name, run):
        self.start_daemon()
        try:
            return self.measure(name, run)
        finally:
            self.stop_daemon()

    def measure(self, name, run):
        a = self.a
        sub = json.dumps(WEB_SUB, separators=(",", ":"))
        clients = []
        for i, (lname, _, _, _) in enumerate(a.link_list):
            env = dict(os.environ, LOAD_HOST=self.net + ".1", LOAD_SET_INTERVAL_S="0", LOAD_PER_CLIENT="1")
            if a.link_log:   # every `link` message, per row, run and group
                os.makedirs(a.link_log, exist_ok=True)
                env["LOAD_LINK_LOG"] = os.path.join(a.link_log, "%s-%d-%d.log" % (name, run, i))
            cmd = [a.load_client, str(PORT), str(a.per_link), str(a.warmup), str(a.window), sub]
            if name.startswith("links"):
                env["LOAD_BIND"] = "%s.%d" % (self.net, 2 + i)
                cmd = ["ip", "netns", "exec", self.ns_b] + cmd
            p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            gname = lname if name.startswith("links") else "lo%d" % i
            if any(g == gname for g, _ in clients):
                gname += "-%d" % i
            clients.append((gname, p))
            self.procs.append((p, gname))
        # each process says "measuring" when its window starts (its clients connected + warm-up)
        starts = []
        for _, p in clients:
            line = p.stderr.readline()
            if "measuring" not in line:
                raise RuntimeError("load_client: " + line + p.stderr.read())
            starts.append(float(line.split()[1]))
        # the daemon's window: from the last client window's start to just before the first one's end
        t_end = min(starts) + a.window - 0.3
        pid = self.daemon.pid
        while time.monotonic() < max(starts):
            time.sleep(0.01)
        m0, c0, w0, t0 = self.metrics(), cpu_split(pid), runq_wait_seconds(pid), time.monotonic()
        td0 = self.tun_dropped()
        sc0, sw0 = cpu_seconds(self.shaper.pid), runq_wait_seconds(self.shaper.pid)
        cc0 = sum(cpu_seconds(p.pid) for _, p in clients)
        enc, tick = [], []
        prev = m0
        degraded, intra = [], []
        while time.monotonic() < t_end:
            time.sleep(0.02)
            m = self.metrics()
            dn = m["oceand_encode_duration_seconds_count"] - prev["oceand_encode_duration_seconds_count"]
            if dn == 1:   # exactly one frame published in this interval: its own times
                enc.append(1000 * (m["oceand_encode_duration_seconds_sum"] - prev["oceand_encode_duration_seconds_sum"]))
                tick.append(1000 * (m["oceand_tick_duration_seconds_sum"] - prev["oceand_tick_duration_seconds_sum"]))
            degraded.append(m.get("oceand_degraded_groups", 0))
            intra.append(m.get("oceand_intra_groups", 0))
            prev = m
        m1, c1, w1, t1 = prev, cpu_split(pid), runq_wait_seconds(pid), time.monotonic()
        td1 = self.tun_dropped()
        sc1, sw1 = cpu_seconds(self.shaper.pid), runq_wait_seconds(self.shaper.pid)
        cc1 = sum(cpu_seconds(p.pid) for _, p in clients)
        dt = t1 - t0

        def d(k):
            return m1.get(k, 0) - m0.get(k, 0)
        frames = d("oceand_encode_duration_seconds_count")
        groups = {}
        for gname, p in clients:
            out, err = p.communicate(timeout=60)
            if p.returncode != 0 or not out.strip():
                raise RuntimeError("load_client failed: " + err[-500:])
            r = json.loads(out)
            groups[gname] = {"connected": r["connected"], "fps_median": r["fps_median"], "fps_min": r["fps_min"],
                             "delivered_median": r["delivered_median"], "delivered_min": r["delivered"],
                             "lat_p50_ms": r["lat_p50_ms"], "kb_frame": round(r["frame_kb"] * 1.024, 1),
                             "mbytes_per_s": r["mbytes_per_s"],
                             "rung_end_median": r["rungs"]["end_median"], "rung_end_max": r["rungs"]["end_max"],
                             "rung_max_reached": r["rungs"]["max_reached"],
                             "steps_down": r["rungs"]["congestion"], "probes_up": r["rungs"]["probe"],
                             "rungs_at_end": sorted(set(r["client_rung"])),
                             "frames_per_viewer_median": round(statistics.median(r["client_fps"]) * a.window)}
        res = {"bench": "links-load", "row": name, "run": run, "viewers": sum(g["connected"] for g in groups.values()),
               "window_s": round(dt, 1),
               "daemon_cpu": round((sum(c1) - sum(c0)) / dt, 3),
               # user: the daemon's own code (encode, fanout); system: mostly TCP sends. Over the
               # links the kernel's TCP work partly runs in the shaper's writes (see shaper_cpu).
               "daemon_cpu_user": round((c1[0] - c0[0]) / dt, 3), "daemon_cpu_sys": round((c1[1] - c0[1]) / dt, 3),
               "daemon_runq_wait": round((w1 - w0) / dt, 3),
               "encode_ms_p50": round(statistics.median(enc), 2) if enc else None,
               "encode_ms_mean": round(1000 * d("oceand_encode_duration_seconds_sum") / max(1, frames), 2),
               "tick_ms_p50": round(statistics.median(tick), 2) if tick else None,
               "tick_samples": len(enc),
               "frames_per_s": round(frames / dt, 2),
               "overruns": int(d("oceand_tick_overruns_total")),
               "layers_per_frame": round(d('oceand_layers_encoded_total{kind="all"}') / max(1, frames), 2),
               "keyframe_layers_per_frame": round(d('oceand_layers_encoded_total{kind="keyframe"}') / max(1, frames), 2),
               "ksamples_per_frame": round(d('oceand_samples_encoded_total{kind="all"}') / max(1, frames) / 1000, 1),
               "keyframe_ksamples_per_frame": round(d('oceand_samples_encoded_total{kind="keyframe"}') / max(1, frames) / 1000, 1),
               "tiles_per_frame": {k: round(d('oceand_stream_tiles_total{kind="%s"}' % k) / max(1, frames), 1)
                                   for k in ("predicted", "key", "demand_key")},
               "degraded_groups_max": max(degraded or [0]), "intra_groups_max": max(intra or [0]),
               "mbytes_per_s": round(d("oceand_bytes_sent_total") / dt / 1e6, 2),
               "frames_sent_per_s": round(d("oceand_frames_sent_total") / dt, 1),
               "dropped_slow_per_s": round(d('oceand_frames_dropped_total{reason="slow_client"}') / dt, 1),
               "caught_up_per_s": round(d("oceand_frames_caught_up_total") / dt, 1),
               "waited_keyframe_per_s": round(d("oceand_frames_waited_keyframe_total") / dt, 1),
               "rung_changes": int(d("oceand_rung_changes_total")),
               "shaper_cpu": round((sc1 - sc0) / dt, 3),
               "shaper_runq_wait": round((sw1 - sw0) / dt, 3),
               "tun_dropped": td1 - td0,
               "clients_cpu": round((cc1 - cc0) / dt, 3),
               "loadavg_1m": round(os.getloadavg()[0], 2),
               "groups": groups}
        self.procs = []
        return res


def median_row(rows):
    out = {"bench": "links-load", "row": rows[0]["row"], "median_of": len(rows)}
    for k in ("daemon_cpu", "daemon_cpu_user", "daemon_cpu_sys", "daemon_runq_wait", "encode_ms_p50", "encode_ms_mean", "tick_ms_p50", "frames_per_s",
              "overruns", "layers_per_frame", "keyframe_layers_per_frame", "ksamples_per_frame",
              "keyframe_ksamples_per_frame", "mbytes_per_s", "shaper_cpu", "loadavg_1m"):
        v = [r[k] for r in rows if r.get(k) is not None]
        out[k] = round(statistics.median(v), 3) if v else None
    out["groups"] = {}
    for g in rows[0]["groups"]:
        gs = [r["groups"][g] for r in rows]
        out["groups"][g] = {k: round(statistics.median(x[k] for x in gs), 3)
                            for k in ("fps_median", "fps_min", "delivered_median", "frames_per_viewer_median",
                                      "rung_end_median", "rung_max_reached", "mbytes_per_s", "kb_frame", "lat_p50_ms")}
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--shaper", default="build/shaper")
    ap.add_argument("--load-client", default="build/load_client")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--warmup", type=float, default=10)
    ap.add_argument("--window", type=float, default=20)
    ap.add_argument("--per-link", type=int, default=40, help="viewers per link")
    ap.add_argument("--links", default=",".join(n for n, _, _, _ in LINKS),
                    help="the links' groups, by name (a name may repeat: e.g. 50M,50M,50M,50M,50M puts every group on 50M)")
    ap.add_argument("--rows", default="loopback-200,links-200")
    ap.add_argument("--oceand-args", default="")
    ap.add_argument("--shaper-rt", type=int, default=1, help="1: the shaper runs SCHED_RR (priority 1); 0: at --shaper-nice")
    ap.add_argument("--shaper-nice", type=int, default=-10,
                    help="the shaper's niceness: it stands for the network, so it should not queue for a CPU "
                         "behind the daemon or other work (one process carries all 200 links)")
    ap.add_argument("--daemon-nice", type=int, default=0, help="the daemon's niceness (a diagnostic: e.g. -10 on a busy machine)")
    ap.add_argument("--link-log", default="", help="a folder: the `link` messages each viewer got (load_client LOAD_LINK_LOG)")
    a = ap.parse_args()
    for k in ("oceand", "shaper", "load_client"):
        setattr(a, k, os.path.abspath(getattr(a, k)))
    if os.geteuid() != 0 or subprocess.run(["ip", "netns", "add", "mlprobe%d" % os.getpid()],
                                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode != 0:
        print(json.dumps({"skipped": "the link lab needs root and network namespaces"}), flush=True)
        return 0
    sh("ip", "netns", "del", "mlprobe%d" % os.getpid(), check=False)
    byname = {x[0]: x for x in LINKS}
    a.link_list = [byname[n] for n in a.links.split(",") if n]
    names = [r for r in a.rows.split(",") if r]
    total = len(a.link_list) * a.per_link
    if total != 200:
        names = [n.replace("-200", "-%d" % total) for n in names]
    lab = Lab(a)
    # SIGTERM / SIGINT: through the finally below (daemon, clients, shaper, namespaces)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(130))
    rows = {n: [] for n in names}
    try:
        lab.up()
        for run in range(1, a.runs + 1):
            order = names if run % 2 else list(reversed(names))
            for n in order:
                r = lab.row(n, run)
                rows[n].append(r)
                print(json.dumps(r), flush=True)
    except KeyboardInterrupt:
        return 130
    finally:
        lab.down()
    meds = {n: median_row(v) for n, v in rows.items() if v}
    for n in names:
        if n in meds:
            print(json.dumps(meds[n]), flush=True)
    if len(names) == 2 and all(rows[n] for n in names):
        lo, li = names[0], names[1]
        ratio = {"bench": "links-load", "row": "ratio", "of": "%s / %s" % (li, lo)}
        for k in ("encode_ms_p50", "encode_ms_mean", "tick_ms_p50", "daemon_cpu", "daemon_cpu_user", "layers_per_frame",
                  "ksamples_per_frame"):
            per = [round(b[k] / x[k], 3) for x, b in zip(rows[lo], rows[li]) if x.get(k) and b.get(k) is not None]
            ratio[k + "_runs"] = per
            ratio[k] = round(statistics.median(per), 3) if per else None
        print(json.dumps(ratio), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
"""Load benchmark for oceand: K WebSocket clients (build/load_client, libwebsockets)
on loopback. Prints one JSON line per run:
  {"bench":"load","N":256,"clients":200,"fps_median":..,"fps_min":..,"delivered":..,
   "lat_p50_ms":..,"lat_p99_ms":..,"set_latency_ticks_p99":..,"daemon_cpu":..,"rss_mb":..,"overruns":..}
delivered = share of the frames the daemon made in the window that reached the worst client.
Clients subscribe with "temporal": true (codec 3, as the web client does) unless --intra;
mbytes_per_s is all clients together, mbytes_per_s_per_client the mean per client.

    /usr/bin/python3 bench/load.py [--runs 256:200,512:100] [--window 10]
    /usr/bin/python3 bench/load.py --capacity      # the capacity rows (make bench-capacity)
    /usr/bin/python3 bench/load.py --runs 256:200 --bodies 64 --no-query   # make bench-load-bodies
--bodies K launches K floating bodies (bench/body_fleet.py) before the clients come; the line
then has "bodies" (floating at the end) and "body_step_ms_mean".
Client 0 sets the wind (11 <-> 12 m/s) every --set-interval s: 0.3 by default (someone
steering); 0 under --capacity (one viewer watching; pass --set-interval 0.3 to add steering).
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "common"))
import oceand_proc  # noqa: E402

import body_fleet  # noqa: E402


def metric(port, name):
    text = urllib.request.urlopen("http://127.0.0.1:%d/metrics" % port, timeout=5).read().decode()
    m = re.search(r"^%s (\S+)$" % re.escape(name), text, re.M)
    return float(m.group(1)) if m else float("nan")


def cpu_split(pid):
    """(user, system) CPU seconds of a process."""
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return int(fields[11]) / os.sysconf("SC_CLK_TCK"), int(fields[12]) / os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid):
    return sum(cpu_split(pid))


def runq_wait_seconds(pid):
    """Time the daemon's threads spent runnable but waiting for a CPU (schedstat)."""
    total = 0
    for tid in os.listdir("/proc/%d/task" % pid):
        try:
            with open("/proc/%d/task/%s/schedstat" % (pid, tid)) as f:
                total += int(f.read().split()[1])
        except OSError:
            pass
    return total / 1e9


def rss_mb(pid):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


def hist_p50_ms(port, name):
    """Median of a /metrics histogram, from its buckets (upper bound of the bucket holding it)."""
    text = urllib.request.urlopen("http://127.0.0.1:%d/metrics" % port, timeout=5).read().decode()
    rows = re.findall(r'^%s_bucket\{le="([^"]+)"\} (\d+)$' % re.escape(name), text, re.M)
    return [(float("inf") if le == "+Inf" else float(le) * 1000, int(c)) for le, c in rows]


def bucket_median(b0, b1):
    total = b1[-1][1] - b0[-1][1]
    if total <= 0:
        return float("nan")
    for (le, c1), (_, c0) in zip(b1, b0):
        if c1 - c0 >= total / 2:
            return le
    return float("inf")


def run(args, n, k, fields=None):
    tmp = tempfile.mkdtemp(prefix="oceand-bench-")
    # up to 2 min to be ready: the first start at a new N plans FFTW (then cached)
    d = oceand_proc.Oceand(args.oceand, "--resolution", str(n), "--state-file", "none",
                           "--web-root", tmp, "--max-clients", str(k + 16), "--log-level", "warn",
                           *(body_fleet.DAEMON_ARGS if args.bodies else []),
                           *args.oceand_args.split(), tmp=tmp, own_tmp=True, ready_timeout=120)
    port = d.port
    fleet = None
    try:
        if args.bodies:   # launched and under way before the clients come
            fleet = body_fleet.Fleet(d.url, args.bodies).start()
        sub = {"type": "subscribe", "temporal": not args.intra}   # temporal: as the web client does
        if fields:
            sub["fields"] = fields
        sub = [args.subscribe] if args.subscribe else [json.dumps(sub, separators=(",", ":"))]
        env = dict(os.environ, LOAD_SET_INTERVAL_S=str(args.set_interval))
        lc = subprocess.Popen([args.load_client, str(port), str(k), str(args.warmup), str(args.window)] + sub,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        line = lc.stderr.readline()          # "measuring": the window starts
        cpu0, t0, wait0 = cpu_seconds(d.pid), time.monotonic(), runq_wait_seconds(d.pid)
        over0 = metric(port, "oceand_tick_overruns_total")
        late0 = metric(port, "oceand_tick_late_total")
        tsum0, tcnt0 = metric(port, "oceand_tick_duration_seconds_sum"), metric(port, "oceand_tick_duration_seconds_count")
        esum0, ecnt0 = metric(port, "oceand_encode_duration_seconds_sum"), metric(port, "oceand_encode_duration_seconds_count")
        bsum0, bcnt0 = metric(port, "oceand_body_step_duration_seconds_sum"), metric(port, "oceand_body_step_duration_seconds_count")
        tb0 = hist_p50_ms(port, "oceand_tick_duration_seconds")
        rss = [rss_mb(d.pid)]
        while lc.poll() is None:
            time.sleep(0.5)
            rss.append(rss_mb(d.pid))
        cpu1, t1, wait1 = cpu_seconds(d.pid), time.monotonic(), runq_wait_seconds(d.pid)
        over1 = metric(port, "oceand_tick_overruns_total")
        late1 = metric(port, "oceand_tick_late_total")
        tsum1, tcnt1 = metric(port, "oceand_tick_duration_seconds_sum"), metric(port, "oceand_tick_duration_seconds_count")
        esum1, ecnt1 = metric(port, "oceand_encode_duration_seconds_sum"), metric(port, "oceand_encode_duration_seconds_count")
        bsum1, bcnt1 = metric(port, "oceand_body_step_duration_seconds_sum"), metric(port, "oceand_body_step_duration_seconds_count")
        bodies = metric(port, "oceand_bodies")
        tb1 = hist_p50_ms(port, "oceand_tick_duration_seconds")
        degraded = metric(port, "oceand_degraded_groups")
        intra_groups = metric(port, "oceand_intra_groups")   # the codec rung: temporal clients served intra at full detail
        out, err = lc.communicate()
        if lc.returncode != 0 or not out.strip():
            raise RuntimeError("load_client failed: %s %s" % (line, err))
        r = json.loads(out)
        res = {"bench": "load", "N": n, "clients": k, "temporal": not args.intra, "fields": fields or ["height", "dx", "dz"],
               "subscribe": args.subscribe, "oceand_args": args.oceand_args, "fps_median": r["fps_median"], "fps_min": r["fps_min"],
               "delivered": r["delivered"], "lat_p50_ms": r["lat_p50_ms"], "lat_p99_ms": r["lat_p99_ms"],
               "set_latency_ticks_p99": r["set_latency_ticks_p99"],
               "daemon_cpu": round((cpu1 - cpu0) / (t1 - t0), 2),
               "daemon_runq_wait": round((wait1 - wait0) / (t1 - t0), 2), "rss_mb": round(max(rss), 1),
               "rss_mb_start": round(rss[0], 1), "overruns": int(over1 - over0),
               "overruns_clock_late": int(late1 - late0) if late1 == late1 else None,  # of them: the tick thread not run in time
               "tick_ms_mean": round(1000 * (tsum1 - tsum0) / max(1, tcnt1 - tcnt0), 2),
               "tick_ms_p50_bucket": bucket_median(tb0, tb1),
               "encode_ms_mean": round(1000 * (esum1 - esum0) / max(1, ecnt1 - ecnt0), 2),  # wall, on the encode pool   # deadline -> frame published, histogram bucket
               "bodies": int(bodies) if bodies == bodies else 0,   # floating at the end (--bodies launched them)
               "body_step_ms_mean": round(1000 * (bsum1 - bsum0) / (bcnt1 - bcnt0), 3) if bcnt1 > bcnt0 else 0.0,
               "degraded_groups_at_end": int(degraded) if degraded == degraded else None,  # NaN: a daemon without the metric
               "intra_groups_at_end": int(intra_groups) if intra_groups == intra_groups else None,
               "connected": r["connected"], "frame_kb": r["frame_kb"], "mbytes_per_s": r["mbytes_per_s"],
               "mbytes_per_s_per_client": round(r["mbytes_per_s"] / max(1, r["connected"]), 3),
               "set_samples": r["set_samples"], "set_interval_s": args.set_interval, "window_s": args.window,
               "loadavg_1m": round(os.getloadavg()[0], 2)}   # this machine is shared: context for the numbers
        print(json.dumps(res), flush=True)
    finally:
        if fleet:
            fleet.stop()
        d.stop(timeout=5)
        d.close()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--load-client", default="build/load_client")
    ap.add_argument("--runs", default="256:1,256:50,256:200,512:100", help="N:clients,...")
    ap.add_argument("--oceand-args", default="", help="extra daemon flags, e.g. '--sim-nice -10'")
    ap.add_argument("--subscribe", default="", help="a subscribe message every client sends (JSON), e.g. the web client's")
    ap.add_argument("--warmup", type=float, default=2)
    ap.add_argument("--intra", action="store_true", help="clients do not ask for the temporal codec (codec 1 only)")
    ap.add_argument("--window", type=float, default=10)
    ap.add_argument("--bodies", type=int, default=0,
                    help="floating bodies launched (every kind, the powered ones under way) before the clients come")
    ap.add_argument("--no-query", action="store_true", help="skip the point query / probe runs (query_load.py)")
    import query_load
    query_load.add_args(ap)
    ap.add_argument("--capacity", action="store_true", help="the capacity rows (one viewer each: how far N and fields go), --repeat times each, "
                    "then one median line per row")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--base", default="",
                    help="--capacity: another oceand build to compare with; the two alternate run by run "
                         "(base first), each row gets a median line per build and a capacity_ab line (new/base)")
    ap.add_argument("--rows", default="", help="--capacity: only these rows, by name (e.g. 1024six,2048hdz)")
    ap.add_argument("--set-interval", type=float, default=None,
                    help="seconds between client 0's wind sets (default 0.3; --capacity: 0, the sea left alone)")
    args = ap.parse_args()
    if args.set_interval is None:   # capacity is one viewer watching; load has someone steering
        args.set_interval = 0.0 if args.capacity else 0.3
    if args.capacity:
        capacity(args)
        return
    for spec in args.runs.split(","):
        n, k = (int(x) for x in spec.split(":"))
        run(args, n, k)
    if not args.no_query:
        query_load.bench(args)   # query latency for 1/16/256 points, tick time with 100 probe clients


# The capacity rows and their targets: (N, clients, fields subscribed at 1 cm, LOD 0).
SIX = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"]
CAPACITY_ROWS = [
    (512, 1, SIX),
    (1024, 1, ["height", "dx", "dz"]),
    (1024, 1, SIX),
    (2048, 1, ["height"]),
    (2048, 1, ["height", "dx", "dz"]),
    (256, 200, None),
]


def row_name(n, k, fields):
    """Stable short names: 512six, 1024hdz, 1024six, 2048h, 2048hdz, 256x200."""
    if k > 1:
        return "%dx%d" % (n, k)
    return "%d%s" % (n, {6: "six", 3: "hdz", 1: "h"}[len(fields)])


def capacity_median(runs, args, n, k):
    import statistics
    med = {"bench": "capacity", "N": n, "clients": k, "fields": runs[0]["fields"], "runs": len(runs),
           "set_interval_s": args.set_interval}
    for key in ("fps_median", "fps_min", "delivered", "overruns", "overruns_clock_late", "tick_ms_mean", "tick_ms_p50_bucket",
                "encode_ms_mean",
                "lat_p50_ms", "daemon_cpu", "daemon_runq_wait", "rss_mb", "degraded_groups_at_end", "loadavg_1m"):
        med[key] = round(statistics.median(r[key] for r in runs), 3)
    for key in ("intra_groups_at_end",):   # None from a daemon without the metric
        vals = [r[key] for r in runs if r.get(key) is not None]
        med[key] = statistics.median(vals) if vals else None
    return med


def capacity(args):
    """Each row --repeat times and its median line. With --base, the base build and
    this one alternate run by run, so that both see the same moments of a shared
    machine (its speed drifts by tens of per cent over minutes): the ratio of their
    medians is the comparison, not either figure alone."""
    import contextlib
    import copy
    import io
    builds = [("new", args)]
    if args.base:
        base = copy.copy(args)
        base.oceand = args.base
        builds.insert(0, ("base", base))
    wanted = set(filter(None, args.rows.split(",")))
    for n, k, fields in CAPACITY_ROWS:
        name = row_name(n, k, fields or ["height", "dx", "dz"])
        if wanted and name not in wanted:
            continue
        runs = {label: [] for label, _ in builds}
        for _ in range(args.repeat):
            for label, a in builds:
                buf = io.StringIO()
                with contextlib.redirect_stdout(buf):
                    run(a, n, k, fields)
                line = buf.getvalue().strip()
                print(line, flush=True)
                runs[label].append(json.loads(line))
        meds = {}
        for label, a in builds:
            meds[label] = capacity_median(runs[label], args, n, k)
            meds[label]["row"] = name
            if args.base:
                meds[label]["build"] = label
                meds[label]["oceand"] = a.oceand
            print(json.dumps(meds[label]), flush=True)
        if args.base:
            ab = {"bench": "capacity_ab", "row": name, "runs": args.repeat}
            for key in ("tick_ms_mean", "encode_ms_mean", "fps_median", "daemon_cpu"):
                b, v = meds["base"][key], meds["new"][key]
                ab[key + "_base"], ab[key + "_new"] = b, v
                ab[key + "_ratio"] = round(v / b, 3) if b else None
            print(json.dumps(ab), flush=True)


if __name__ == "__main__":
    main()

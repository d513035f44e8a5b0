#!/usr/bin/python3
"""Control budget, before and after (docs/reliability.md): the attack of the
hostile case `control_budget` (50 clients x 20 subscribes/s listing all 1024
tiles, a controller's `set` every 0.5 s, an observer) against one or more
oceand builds, alternating, in the same run. One JSON line per run on stdout:
the service thread's CPU (the main thread: lws_service), the whole daemon's,
their run-queue wait, the observer's frames, the load average.

    /usr/bin/python3 bench/control_budget.py --oceand build/oceand [--before OLD_BUILD] [--rounds 3]
    make bench-control-budget [BEFORE=OLD_BUILD]

A build without --control-budget (before the change) is run with its
defaults; the others with theirs (budget 2000) and with --control-budget 300.
"""
import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "hostile"))
from harness import Daemon, Observer  # noqa: E402
import test_hostile  # noqa: E402


def thread_sched(pid, tid):
    with open("/proc/%d/task/%d/schedstat" % (pid, tid)) as f:
        a = f.read().split()
    return int(a[0]) / 1e6, int(a[1]) / 1e6


def has_budget(oceand):
    out = subprocess.run([oceand, "--help"], capture_output=True, text=True).stdout
    return "--control-budget" in out


def run(oceand, label, extra):
    d = Daemon(oceand, *extra, resolution=128)
    obs = Observer(d.url)
    try:
        time.sleep(0.5)
        obs.mark()
        svc0 = thread_sched(d.proc.pid, d.proc.pid)
        all0 = d.sched()
        load = os.getloadavg()[0]
        t0 = time.time()
        f = test_hostile.subscribe_flood(d)
        svc1 = thread_sched(d.proc.pid, d.proc.pid)
        all1 = d.sched()
        st = obs.stats()
        secs = time.time() - t0     # the window: connecting, the 5 s flood, the last answers
        m0, m1 = f["m0"], f["m1"]
        return dict(bench="control_budget", build=label, args=" ".join(extra), seconds=round(secs, 1),
                    service_cpu_ms_per_s=round((svc1[0] - svc0[0]) / secs), service_wait_ms_per_s=round(
                        (svc1[1] - svc0[1]) / secs), daemon_cpu_ms_per_s=round((all1[0] - all0[0]) / secs),
                    daemon_wait_ms_per_s=round((all1[1] - all0[1]) / secs),
                    observer_frames=st.get("frames"), observer_span=st.get("span"),
                    observer_share=round(st.get("frames", 0) / max(1, st.get("span", 0)), 3),
                    flood_seconds=round(f["elapsed"], 1), subscribes_sent=f["sent"],
                    subscribes_accepted=f["accepted"], errors=f["codes"],
                    sets_applied="%d/%d" % (len(f["sets"]) - len(f["late"]), len(f["sets"])),
                    overruns=m1.get("oceand_tick_overruns_total", 0) - m0.get("oceand_tick_overruns_total", 0),
                    load1_start=round(load, 1), load1_end=round(os.getloadavg()[0], 1))
    finally:
        obs.close()
        d.stop()
        d.close()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--before", default="", help="an older build to compare (run with its defaults)")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    test_hostile.OUT = sys.stderr
    variants = []
    if a.before:
        variants.append((a.before, "before", []))
    variants.append((a.oceand, "after", []))
    if has_budget(a.oceand):
        variants.append((a.oceand, "after", ["--control-budget", "300"]))
    for _ in range(a.rounds):
        for oceand, label, extra in variants:
            print(json.dumps(run(oceand, label, extra)), flush=True)


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""Standby take-over and durability figures (docs/scaling.md "Failure model").

nats-server with JetStream, two `oceand --role sim` (active + hot standby) and one
`--role edge`, all on this machine. A viewer on the edge receives frames; a controller
on the edge sends sets one after another (each waits for its ack). KILLS times: kill -9
of the active sim; gap = the longest wait between two frames at the viewer around the
kill (the take-over as a viewer sees it, socket kept); then the edge's hello is compared
with the last acknowledged set (lost = it is not in force); the killed sim restarts as
the standby. Prints one JSON line per kill and a summary line:
  {"bench":"cluster_failover","kills":K,"gap_median_s":..,"gap_max_s":..,"acked_sets":..,
   "acked_lost":0,"standby_cpu":..}
standby_cpu = cores the standby used over the last 5 s while following (no encode).

    /usr/bin/python3 bench/cluster_failover.py --oceand build/oceand [--kills 5]
"""
import argparse
import asyncio
import json
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "cluster"))
sys.path.insert(0, HERE)
import test_cluster_durable as t  # noqa: E402
from load import cpu_seconds  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--kills", type=int, default=5)
    args = ap.parse_args()
    t.ARGS = t.td.ARGS = t.cr.ARGS = argparse.Namespace(oceand=args.oceand, cycles=1, recovery_s=2.0, k="")
    c = t.JsCluster(sims=2, edges=1)
    gaps, lost, acked_total = [], 0, 0
    try:
        async def run():
            nonlocal lost, acked_total
            viewer, _ = await t.connect(c.edges[0])
            ctl, _ = await t.connect(c.edges[0])
            for k in range(args.kills):
                arrivals, stop = [], asyncio.Event()
                acked, i = None, 0

                async def watch():
                    while not stop.is_set():
                        try:
                            await t.recv_frame(viewer, timeout=0.5)
                            arrivals.append(time.monotonic())
                        except (t.TestFailure, asyncio.TimeoutError):
                            pass

                async def sets():
                    nonlocal acked, i
                    while not stop.is_set():
                        i += 1
                        wind = 5 + 0.125 * (i % 100)
                        m = await t.set_and_ack(ctl, 1000 * k + i, wind)
                        if m["type"] == "params":
                            acked = (wind, m["params_version"])
                        else:
                            await asyncio.sleep(0.05)

                w, s = asyncio.ensure_future(watch()), asyncio.ensure_future(sets())
                await asyncio.sleep(1.0)
                t_kill = time.monotonic()
                t.kill_active(c)
                await asyncio.sleep(4.0)
                stop.set()
                await asyncio.gather(w, s)
                around = [a for a in arrivals if a >= t_kill - 0.5]
                gap = max((b - a for a, b in zip(around, around[1:])), default=float("inf"))
                gaps.append(gap)
                wind, v = acked
                h = await t.hello_at(c.edges[0], v, "after the kill")
                ok = h["params_version"] >= v and (h["params_version"] > v or h["params"]["wind_speed"] == wind)
                lost += 0 if ok else 1
                acked_total += 1
                print(json.dumps({"bench": "cluster_failover_kill", "kill": k + 1, "gap_s": round(gap, 3),
                                  "acked_version": v, "version_after": h["params_version"], "lost": not ok}))
                sys.stdout.flush()
                c.killed.start()
                t.wait_for(lambda: c.killed.health()["lease"] == "standby", "standby again")
            standby = [n for n in c.sims if n.health()["lease"] == "standby"][0]
            c0, w0 = cpu_seconds(standby.proc.pid), time.time()
            await asyncio.sleep(5)
            cpu = (cpu_seconds(standby.proc.pid) - c0) / (time.time() - w0)
            print(json.dumps({"bench": "cluster_failover", "kills": args.kills,
                              "gap_median_s": round(statistics.median(gaps), 3), "gap_max_s": round(max(gaps), 3),
                              "acked_sets": acked_total, "acked_lost": lost, "standby_cpu": round(cpu, 3)}))
            await viewer.close()
            await ctl.close()
        asyncio.run(run())
    finally:
        c.close(failed=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())

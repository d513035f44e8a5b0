#!/usr/bin/python3
"""Many distinct layers against the encode budget, as a benchmark: N = 512, an observer, then 25
viewers asking together for every field x LOD x bound (25 subscription groups
of six fields, 150 layers). Prints one JSON line: what was admitted/refused,
and over a 5 s window the observer's frames/s, tick overruns, mean encode and
tick time, RSS. Works against a daemon without an encode budget too (then
everything is admitted): run it on two builds to compare.

    /usr/bin/python3 bench/layer_flood.py --oceand build/oceand     (make bench-layer-flood)
FLOOD_ARGS="..." adds daemon options (e.g. "--log-level info" to see the plan).
"""
import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "hostile"))
from harness import Daemon, Observer  # noqa: E402
import test_hostile as th  # noqa: E402  (attacker, ask)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--window", type=float, default=5.0)
    args = ap.parse_args()
    d = Daemon(args.oceand, *os.environ.get("FLOOD_ARGS", "").split(), "--max-clients", "64", "--control-rate", "10000", "--control-burst", "10000",
               resolution=args.resolution)
    obs = None
    try:
        obs = Observer(d.url)
        time.sleep(1.0)
        fields = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"]
        bounds = [0, 0.001, 0.005, 0.01, 0.05]
        rss0 = d.rss_kb()
        clients = [th.attacker(d) for _ in range(25)]
        admitted = refused = 0
        for k, (s, r) in enumerate(clients):
            m = th.ask(s, r, json.dumps({"type": "subscribe", "id": k, "fields": fields, "lod": k // 5,
                                         "bound": bounds[k % 5]}))
            if m and m.get("type") == "subscribed":
                admitted += 1
            else:
                refused += 1
        time.sleep(1.0)
        m0 = d.metrics()
        obs.mark()
        t0 = time.time()
        time.sleep(args.window)
        st = obs.stats()
        m1 = d.metrics()
        secs = time.time() - t0

        def mean_ms(name):
            n = m1[name + "_count"] - m0[name + "_count"]
            return round(1000 * (m1[name + "_sum"] - m0[name + "_sum"]) / max(1, n), 2)
        out = {"bench": "layer_flood", "N": args.resolution, "viewers": 25, "admitted": admitted, "refused": refused,
               "observer_fps": round(st.get("frames", 0) / secs, 1),
               "observer_share": round(st.get("frames", 0) / max(1, st.get("span", 1)), 3),
               "overruns": int(m1["oceand_tick_overruns_total"] - m0["oceand_tick_overruns_total"]),
               "window_s": round(secs, 1), "encode_ms_mean": mean_ms("oceand_encode_duration_seconds"),
               "tick_ms_mean": mean_ms("oceand_tick_duration_seconds"),
               "degraded_groups": m1.get("oceand_degraded_groups"),
               "rss_mb_before": round(rss0 / 1024, 1), "rss_mb": round(d.rss_kb() / 1024, 1),
               "loadavg_1m": round(os.getloadavg()[0], 2)}
        print(json.dumps(out), flush=True)
        for s, r in clients:
            s.close()
    finally:
        if obs:
            obs.close()
        d.stop()
        d.close()


if __name__ == "__main__":
    main()

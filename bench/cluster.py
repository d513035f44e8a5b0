#!/usr/bin/python3
"""Cluster benchmark (docs/scaling.md): one `oceand --role sim` and 1, 2, 3
`--role edge` daemons with a nats-server, all on this machine, K clients per edge
(build/load_client, one per edge), against `--role all` with the same K. One JSON line per run:
  {"bench":"cluster","mode":"cluster","edges":E,"clients_per_edge":K,"delivered_min":..,
   "lat_p50_ms":..,"lat_p99_ms":..,"sim_cpu":..,"edge_cpu_mean":..,"nats_cpu":..,
   "nats_bytes_per_tick":..,"nats_layers_per_tick":..,"edge_mbytes_per_s":..}
delivered_min = the worst client's share of the frames made in the window (load_client);
latency = tick (server_time_us, stamped by the sim) -> receipt by the client; the median
over the edges of each edge's p50 / p99. CPU in cores (user+sys / wall) over the window.

Then the web client's subscription with the temporal codec (WEB_SUB: cascade 0's height,
dx, dz at 1 cm, foam at LOD 2, cascades 1-3 height at LOD 1 and 1 mm; the sea left alone)
with --web-clients viewers (default 1: a web viewer), on `--role all` (mode "web_all") and on
each of 1, 2, 3 edges (mode "web_edge"), --web-runs times (default 3), then per number of
edges the medians (mode "web_edge_median"): frame_kb = bytes per frame received, the mean
over the viewers, and for an edge its ratio to --role all's in the same run (target <= 1.1,
docs/scaling.md); frame_kb_p50 the median frame (the shared frames a viewer that keeps up
takes: the ratio a loaded machine does not blur); sim_cpu shows the sim encodes each layer's stream once whatever the
number of edges.

    /usr/bin/python3 bench/cluster.py [--edges 1,2,3] [--clients 25,50,100] [--window 5]
                                      [--web-clients 1] [--web-runs 3] [--web-only | --no-web]
"""
import argparse
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "common"))
from load import cpu_seconds, metric  # noqa: E402
import oceand_proc  # noqa: E402


def stop(procs):
    """SIGTERM each (5 s each, then SIGKILL) and remove what they leave."""
    for p in procs:
        p.stop(signal.SIGTERM, 5)
        p.close()


# The web client's subscription (web/src/main.js; tests/cluster/test_cluster_roles.py WEB_SUB_T).
WEB_SUB = json.dumps({"type": "subscribe", "fields": ["height", "dx", "dz", "foam"], "field_lod": {"foam": 2},
                      "cascades": [{"fields": ["height"], "lod": 1, "bound": 0.001}] * 3, "temporal": True},
                     separators=(",", ":"))


def measure(args, ports, pids, k, sim_port, sub=None):
    """Run one load_client per port; sample CPU of pids over the measuring window."""
    env = dict(os.environ)
    if sub:
        env["LOAD_SET_INTERVAL_S"] = "0"   # the sea left alone: like for like between the two modes
    lcs = [subprocess.Popen([args.load_client, str(p), str(k), str(args.warmup), str(args.window)] +
                            ([sub] if sub else []), env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for p in ports]
    for lc in lcs:
        lc.stderr.readline()  # "measuring"
    cpu0 = {name: cpu_seconds(pid) for name, pid in pids.items()}
    t0 = time.monotonic()
    m0 = (metric(sim_port, "oceand_cluster_bytes_published_total"), metric(sim_port, "oceand_cluster_layers_published_total"),
          metric(sim_port, "oceand_ticks_total")) if sim_port else None
    outs = [lc.communicate() for lc in lcs]
    t1 = time.monotonic()
    cpu = {name: (cpu_seconds(pid) - cpu0[name]) / (t1 - t0) for name, pid in pids.items()}
    m1 = (metric(sim_port, "oceand_cluster_bytes_published_total"), metric(sim_port, "oceand_cluster_layers_published_total"),
          metric(sim_port, "oceand_ticks_total")) if sim_port else None
    res = []
    for lc, (out, err) in zip(lcs, outs):
        if lc.returncode != 0 or not out.strip():
            raise RuntimeError("load_client failed: %s" % err)
        res.append(json.loads(out))
    nat = None
    if m0:
        ticks = max(1.0, m1[2] - m0[2])
        nat = {"nats_bytes_per_tick": round((m1[0] - m0[0]) / ticks), "nats_layers_per_tick": round((m1[1] - m0[1]) / ticks, 2)}
    return res, cpu, nat


def run_all(args, k):
    tmp = tempfile.mkdtemp(prefix="oceand-bench-cluster-")
    d = oceand_proc.Oceand(args.oceand, "--state-file", "none", "--web-root", tmp, "--max-clients", str(k + 16),
                           "--log-level", "warn", "--resolution", str(args.n), tmp=tmp, own_tmp=True, name="all")
    try:
        res, cpu, _ = measure(args, [d.port], {"daemon": d.pid}, k, None)
        r = res[0]
        print(json.dumps({"bench": "cluster", "mode": "all", "edges": 0, "clients_per_edge": k, "N": args.n,
                          "delivered_min": r["delivered"], "lat_p50_ms": r["lat_p50_ms"], "lat_p99_ms": r["lat_p99_ms"],
                          "daemon_cpu": round(cpu["daemon"], 2), "mbytes_per_s": r["mbytes_per_s"],
                          "loadavg_1m": round(os.getloadavg()[0], 2)}), flush=True)
    finally:
        stop([d])


def start_cluster(args, tmp, procs, edges, k):
    """nats-server, a sim and `edges` edges (room for k clients each) in tmp, each appended to
    procs as it starts (the caller stops them); returns the sim, the edges and the pids by role."""
    nats = oceand_proc.Nats(tmp)
    procs.append(nats)
    sim = oceand_proc.Oceand(args.oceand, "--role", "sim", "--nats", nats.url, "--state-file", "none",
                             "--web-root", tmp, "--log-level", "warn", "--resolution", str(args.n),
                             tmp=tmp, name="sim")
    procs.append(sim)
    eprocs = []
    for i in range(edges):
        e = oceand_proc.Oceand(args.oceand, "--role", "edge", "--nats", nats.url, "--state-file", "none",
                               "--web-root", tmp, "--max-clients", str(k + 16), "--log-level", "warn",
                               tmp=tmp, name="edge%d" % i, ready=lambda j: j.get("cluster") == "ok")
        procs.append(e)
        eprocs.append(e)
    pids = {"sim": sim.pid, "nats": nats.pid}
    pids.update({"edge%d" % i: e.pid for i, e in enumerate(eprocs)})
    return sim, eprocs, pids


def run_cluster(args, edges, k):
    tmp = tempfile.mkdtemp(prefix="oceand-bench-cluster-")
    procs = []
    try:
        sim, eprocs, pids = start_cluster(args, tmp, procs, edges, k)
        res, cpu, nat = measure(args, [e.port for e in eprocs], pids, k, sim.port)
        out = {"bench": "cluster", "mode": "cluster", "edges": edges, "clients_per_edge": k, "N": args.n,
               "delivered_min": min(r["delivered"] for r in res),
               "lat_p50_ms": round(statistics.median(r["lat_p50_ms"] for r in res), 2),
               "lat_p99_ms": round(statistics.median(r["lat_p99_ms"] for r in res), 2),
               "sim_cpu": round(cpu["sim"], 2), "nats_cpu": round(cpu["nats"], 2),
               "edge_cpu_mean": round(statistics.mean(cpu["edge%d" % i] for i in range(edges)), 2),
               "edge_mbytes_per_s": round(statistics.mean(r["mbytes_per_s"] for r in res), 1),
               "loadavg_1m": round(os.getloadavg()[0], 2)}
        out.update(nat)
        print(json.dumps(out), flush=True)
    finally:
        stop(procs[::-1])
        shutil.rmtree(tmp, ignore_errors=True)


def run_web(args, edges_list):
    """The web client's temporal subscription, --web-runs times: --role all, then each
    number of edges; then per number of edges the median of the runs' ratios (a frame
    dropped by a starved client costs keyframe tiles for the next `need` frames, so one
    run on a shared machine is noisy)."""
    ratios = {e: [] for e in edges_list}
    p50_ratios = {e: [] for e in edges_list}
    kbs = {e: [] for e in edges_list}
    alls = []
    for run in range(args.web_runs):
        all_kb, rows = run_web_once(args, edges_list, run)
        alls.append(all_kb)
        for e in edges_list:
            kb, p50 = rows[e]
            kbs[e].append(kb)
            ratios[e].append(kb / all_kb if all_kb else float("nan"))
            p50_ratios[e].append(p50 / rows[0] if rows[0] else float("nan"))
    for e in edges_list:
        print(json.dumps({"bench": "cluster", "mode": "web_edge_median", "edges": e, "clients_per_edge": args.web_clients,
                          "N": args.n, "runs": args.web_runs, "frame_kb": round(statistics.median(kbs[e]), 1),
                          "frame_kb_all": round(statistics.median(alls), 1),
                          "ratio_to_all": round(statistics.median(ratios[e]), 3),
                          "ratio_p50_to_all": round(statistics.median(p50_ratios[e]), 3)}), flush=True)


def run_web_once(args, edges_list, run):
    k = args.web_clients
    rows = {}
    tmp = tempfile.mkdtemp(prefix="oceand-bench-cluster-")
    d = oceand_proc.Oceand(args.oceand, "--state-file", "none", "--web-root", tmp, "--max-clients", str(k + 16),
                           "--log-level", "warn", "--resolution", str(args.n), tmp=tmp, own_tmp=True, name="all")
    try:
        res, cpu, _ = measure(args, [d.port], {"daemon": d.pid}, k, None, WEB_SUB)
        all_kb = res[0]["frame_kb"]
        rows[0] = res[0]["frame_kb_p50"]
        print(json.dumps({"bench": "cluster", "mode": "web_all", "run": run, "edges": 0, "clients_per_edge": k,
                          "N": args.n, "frame_kb": all_kb, "frame_kb_p50": res[0]["frame_kb_p50"],
                          "delivered_min": res[0]["delivered"],
                          "daemon_cpu": round(cpu["daemon"], 2), "loadavg_1m": round(os.getloadavg()[0], 2)}),
              flush=True)
    finally:
        stop([d])
    for edges in edges_list:
        tmp = tempfile.mkdtemp(prefix="oceand-bench-cluster-")
        procs = []
        try:
            sim, eprocs, pids = start_cluster(args, tmp, procs, edges, k)
            res, cpu, nat = measure(args, [e.port for e in eprocs], pids, k, sim.port, WEB_SUB)
            kb = statistics.mean(r["frame_kb"] for r in res)
            p50 = statistics.mean(r["frame_kb_p50"] for r in res)
            rows[edges] = (kb, p50)
            out = {"bench": "cluster", "mode": "web_edge", "run": run, "edges": edges, "clients_per_edge": k, "N": args.n,
                   "frame_kb": round(kb, 1), "frame_kb_all": all_kb,
                   "ratio_to_all": round(kb / all_kb, 3) if all_kb else None,
                   "frame_kb_p50": round(p50, 1), "frame_kb_p50_all": rows[0],
                   "delivered_min": min(r["delivered"] for r in res),
                   "sim_cpu": round(cpu["sim"], 2), "nats_cpu": round(cpu["nats"], 2),
                   "edge_cpu_mean": round(statistics.mean(cpu["edge%d" % i] for i in range(edges)), 2),
                   "loadavg_1m": round(os.getloadavg()[0], 2)}
            out.update(nat)
            print(json.dumps(out), flush=True)
        finally:
            stop(procs[::-1])
            shutil.rmtree(tmp, ignore_errors=True)
    return all_kb, rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--load-client", default="build/load_client")
    ap.add_argument("--edges", default="1,2,3")
    ap.add_argument("--clients", default="25,50,100", help="clients per edge, each run")
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--warmup", type=float, default=2)
    ap.add_argument("--window", type=float, default=5)
    ap.add_argument("--web-clients", type=int, default=1, help="web viewers (temporal) per edge in the web rows")
    ap.add_argument("--web-runs", type=int, default=3, help="runs of the web rows (medians at the end)")
    ap.add_argument("--web-only", action="store_true", help="only the web rows")
    ap.add_argument("--no-web", action="store_true", help="no web rows")
    args = ap.parse_args()
    edges = [int(x) for x in args.edges.split(",")]
    if not args.web_only:
        for k in (int(x) for x in args.clients.split(",")):
            run_all(args, k)
            for e in edges:
                run_cluster(args, e, k)
    if not args.no_web:
        run_web(args, edges)


if __name__ == "__main__":
    main()

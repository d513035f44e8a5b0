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

    /usr/bin/python3 bench/cluster.py [--edges 1,2,3] [--clients 25,50,100] [--window 5]
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


def measure(args, ports, pids, k, sim_port):
    """Run one load_client per port; sample CPU of pids over the measuring window."""
    lcs = [subprocess.Popen([args.load_client, str(p), str(k), str(args.warmup), str(args.window)],
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


def run_cluster(args, edges, k):
    tmp = tempfile.mkdtemp(prefix="oceand-bench-cluster-")
    procs = []
    try:
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("--load-client", default="build/load_client")
    ap.add_argument("--edges", default="1,2,3")
    ap.add_argument("--clients", default="25,50,100", help="clients per edge, each run")
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--warmup", type=float, default=2)
    ap.add_argument("--window", type=float, default=5)
    args = ap.parse_args()
    for k in (int(x) for x in args.clients.split(",")):
        run_all(args, k)
        for e in (int(x) for x in args.edges.split(",")):
            run_cluster(args, e, k)


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""check_meta.py - ocean-tap's output metadata against the frame headers.

    check_meta.py HEADERS.jsonl EXR_READ DIR...

HEADERS.jsonl: one {"seq", "sim_time", "params_version"} per frame, recorded by
frame_headers.py from the same server at the same time. Every DIR holds one
ocean-tap output (--format npy, raw, pgm, pgm8 or exr); every file's metadata
(the .json sidecar, the PGM comment, the EXR attributes read back with the
OpenEXR library via EXR_READ, the bake's frame_NNNN.json) must agree with the
header of the frame with that seq: same sim_time (exactly) and params_version.
"""
import glob
import json
import os
import re
import subprocess
import sys

headers = {}
for line in open(sys.argv[1]):
    h = json.loads(line)
    headers[h["seq"]] = h
exr_read = sys.argv[2]
assert headers, "no frame headers recorded"
checked = missing = 0


def match(where, seq, sim_time, pv):
    global checked, missing
    h = headers.get(int(seq))
    if h is None:
        missing += 1  # the recorder missed this tick (it started later or skipped)
        return
    assert float(sim_time) == h["sim_time"], f"{where}: sim_time {sim_time} != header {h['sim_time']} (seq {seq})"
    assert int(pv) == h["params_version"], f"{where}: params_version {pv} != header {h['params_version']}"
    checked += 1


for d in sys.argv[3:]:
    files = [f for f in glob.glob(os.path.join(d, "*")) if not f.endswith(".json") and not f.endswith(".tmp.npy")]
    assert files, f"{d}: no output files"
    for f in sorted(files):
        base = os.path.basename(f)
        if f.endswith(".exr"):
            info = json.loads(subprocess.run([exr_read, f, f + ".tmp.npy"], check=True, capture_output=True,
                                             text=True).stdout)
            kind, frame = re.match(r"(disp|normal|foam|vdisp)_(\d{4})\.exr$", base).groups()
            assert info["oceand_field"] == kind, (base, info)
            side = json.load(open(os.path.join(d, f"frame_{frame}.json")))
            assert str(side["seq"]) == info["oceand_seq"] and float(info["oceand_sim_time"]) == side["sim_time"], \
                (base, info, side)
            match(base, info["oceand_seq"], info["oceand_sim_time"], info["oceand_params_version"])
            match(f"frame_{frame}.json", side["seq"], side["sim_time"], side["params_version"])
            continue
        meta = json.load(open(os.path.splitext(f)[0] + ".json"))
        assert meta["file"] == base, (meta["file"], base)
        seq = int(re.search(r"-(\d+)\.", base).group(1))
        assert meta["seq"] == seq, f"{base}: sidecar seq {meta['seq']}"
        match(base + " sidecar", meta["seq"], meta["sim_time"], meta["params_version"])
        if f.endswith(".pgm"):
            comment = open(f, "rb").read(200).split(b"\n")[1].decode()
            kv = dict(p.split("=") for p in comment[1:].split())
            assert int(kv["seq"]) == seq, comment
            match(base + " comment", kv["seq"], kv["sim_time"], kv["params_version"])
assert checked > 0 and missing <= checked, f"only {checked} files matched a recorded header, {missing} missing"
print(f"  {checked} metadata records agree with the frame headers ({missing} of ticks the recorder missed)")

#!/usr/bin/env python3
"""bench_table.py — turn `make bench-codec` JSON lines (stdin) into the
markdown tables of docs/codec.md.   make bench-codec | python3 proto/tools/bench_table.py"""
import json
import sys

rows = [json.loads(l) for l in sys.stdin if l.startswith("{")]
c = [r for r in rows if r.get("bench") == "codec"]
js = [r for r in rows if r.get("bench") == "codec_js_decode"]

print("| N | field | bound | oceand bits (64² tiles) | whole-field tile | zstd variant | zfp bits (tolerance) | zfp / oceand | oceand max_err | enc MB/s deflate / zstd | dec MB/s deflate / zstd | zfp enc / dec MB/s |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for r in c:
    if r["codec"] != "oceand" or r["tile"] != 64:
        continue
    key = lambda x: x["N"] == r["N"] and x["field"] == r["field"] and x["bound"] == r["bound"]
    whole = next(x for x in c if key(x) and x["codec"] == "oceand" and x["tile"] == r["N"])
    z = next(x for x in c if key(x) and x["codec"] == "oceand-zstd")
    zfp = next(x for x in c if key(x) and x["codec"] == "zfp")
    print(f"| {r['N']} | {r['field']} | {r['bound']} | **{r['bits']:.2f}** | {whole['bits']:.2f} | {z['bits']:.2f} "
          f"| {zfp['bits']:.2f} ({zfp['tolerance']:g}) | {zfp['bits'] / r['bits']:.2f}× | {r['max_err']:.6f} "
          f"| {r['enc_MBs']} / {z['enc_MBs']} | {r['dec_MBs']} / {z['dec_MBs']} | {zfp['enc_MBs']} / {zfp['dec_MBs']} |")
raw = [r for r in c if r["codec"] == "zstd-raw"]
if raw:
    print()
    print("Raw float32 + zstd-1 (lossless): " + ", ".join(
        f"N={r['N']} {r['field']} {r['bits']:.1f} bits" for r in raw if r["field"] in ("height", "jacobian")) + ".")
if js:
    print()
    print("| JS decode (node) N | field | bound | tile | MB/s wall (median) | MB/s CPU |")
    print("|---|---|---|---|---|---|")
    for r in js:
        if r["codec"] == 1:
            print(f"| {r['N']} | {r['field']} | {r['bound']} | {r['tile']} | {r['dec_MBs']} | {r['dec_MBs_cpu']} |")

# Temporal streams (codec 3): docs/codec.md's stream table.
st = [r for r in rows if r.get("bench") == "codec_stream"]
if st:
    print()
    print("| N | field | bound | bits/sample (intra, same fields) | max error (every sample of 300 frames) | encode MB/s (intra, same run) | decode MB/s |")
    print("|---|---|---|---|---|---|---|")
    for d in st:
        b = "1 mm" if d["bound"] == 0.001 else "1 cm" if d["bound"] == 0.01 else d["bound"]
        print(f"| {d['N']} | {d['field']} | {b} | **{d['bits']:.2f}** ({d['intra_bits']:.2f}) | {d['max_err']:.6f} "
              f"| {d['enc_MBs']} ({d['intra_enc_MBs']}) | {d['dec_MBs']} |")

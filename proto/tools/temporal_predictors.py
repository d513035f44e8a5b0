#!/usr/bin/env python3
"""temporal_predictors.py — the measurement behind codec 3's predictor (docs/codec.md).

Input: consecutive frames of the real simulation at 30 Hz, written by
    build/bench_codec --dump-fields N FRAMES FILE
Quantises every field on one fixed grid (step 2*bound, as the encoder's chains do), then for
each candidate predictor of the codes q_t from earlier frames codes the residuals per 128x128
tile with a Huffman-only raw DEFLATE block (zlib Z_HUFFMAN_ONLY: what codec 3's entropy stage
writes) and counts 56 bytes of tile header + prefix per tile and 2 bytes per escaped value.
Least-squares predictors are fitted per tile (coefficients rounded to 1/4096, as sent).
Prints one JSON line per field and bound: median bits/sample over the frames measured.

    /usr/bin/python3 proto/tools/temporal_predictors.py FILE N FRAMES [STRIDE]

Candidates: T1 = q1; T2 = 2 q1 - q2; T3 = 3 q1 - 3 q2 + q3; D3/D4/D5 = q1 + LS over the past
differences d1..d(D-1) (D reference frames); +lap = also the Laplacians L(d1), L(q1);
+lapall = L(d1), L(d2), L(d3), L(q1) (the codec's choice: D4+lapall P); suffix P = pair packing (two samples per byte when both zigzag
values are below 15), else one byte per sample.
"""
import json
import sys
import zlib

import numpy as np

FIELDS = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"]
TILE = 128


def huff(b):
    c = zlib.compressobj(9, zlib.DEFLATED, -15, 9, zlib.Z_HUFFMAN_ONLY)
    return len(c.compress(b.tobytes()) + c.flush())


def zigzag(r):
    r = r.astype(np.int64)
    return np.where(r >= 0, 2 * r, -2 * r - 1)


def tile_bytes(r, pairs):
    z = zigzag(r).ravel()
    if not pairs:
        return huff(np.minimum(z, 255).astype(np.uint8)) + 2 * int((z >= 255).sum())
    z1, z2 = z[0::2], z[1::2]
    ok = (z1 < 15) & (z2 < 15)
    esc = np.stack([z1[~ok], z2[~ok]], 1).ravel()
    b = np.concatenate([np.where(ok, 15 * z1 + z2, 255), np.minimum(esc, 255)]).astype(np.uint8)
    return huff(b) + 2 * int((esc >= 255).sum())


def bits(r, n, pairs):
    total = 0
    for tz in range(n // TILE):
        for tx in range(n // TILE):
            total += 56 + tile_bytes(r[tz * TILE:(tz + 1) * TILE, tx * TILE:(tx + 1) * TILE], pairs)
    return total * 8 / (n * n)


def lap(a):
    p = np.pad(a, 1, mode="edge")   # per field here; the codec clamps per tile (a few border samples differ)
    return p[1:-1, :-2] + p[1:-1, 2:] + p[:-2, 1:-1] + p[2:, 1:-1] - 4 * a


def ls_residual(target, feats, n):
    """target - floor((X c + 2048) / 4096) with c fitted per tile and rounded to 1/4096."""
    r = np.zeros((n, n), np.int64)
    for tz in range(n // TILE):
        for tx in range(n // TILE):
            sl = (slice(tz * TILE, (tz + 1) * TILE), slice(tx * TILE, (tx + 1) * TILE))
            X = np.stack([g[sl].ravel() for g in feats], 1).astype(np.float64)
            y = target[sl].ravel().astype(np.float64)
            c = np.round(np.linalg.lstsq(X, y, rcond=None)[0] * 4096)
            r[sl] = target[sl] - np.floor((X @ c + 2048) / 4096).astype(np.int64).reshape(TILE, TILE)
    return r


def main():
    path, n, frames = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    stride = int(sys.argv[4]) if len(sys.argv) > 4 else 3
    raw = np.fromfile(path, np.float32).reshape(frames, 6, n, n)
    for f, name in enumerate(FIELDS):
        for bound in (0.001, 0.01):
            v = raw[:, f].astype(np.float64)
            offset, scale = 0.5 * (v[0].max() + v[0].min()), 2 * bound * (1 - 2**-20)
            q = np.round((v - offset) / scale).astype(np.int64)
            acc = {}
            for t in range(6, frames, stride):
                d = [q[t - i] - q[t - i - 1] for i in range(5)]   # d[0] = the difference to predict
                cand = {"T1": d[0], "T2": d[0] - d[1], "T3": d[0] - 2 * d[1] + d[2]}
                for depth in (3, 4, 5):
                    cand[f"D{depth}"] = ls_residual(d[0], d[1:depth], n)
                for depth in (3, 4, 5):
                    cand[f"D{depth}+lap"] = ls_residual(d[0], d[1:depth] + [lap(d[1]), lap(q[t - 1])], n)
                # the codec's choice: every difference and its Laplacian, and L(q1)
                cand["D4+lapall"] = ls_residual(d[0], d[1:4] + [lap(x) for x in d[1:4]] + [lap(q[t - 1])], n)
                for k, r in cand.items():
                    acc.setdefault(k, []).append(bits(r, n, False))
                    if k.startswith("D"):
                        acc.setdefault(k + " P", []).append(bits(r, n, True))
            print(json.dumps({"bench": "temporal_predictors", "N": n, "field": name, "bound": bound,
                              **{k: round(float(np.median(x)), 3) for k, x in acc.items()}}), flush=True)


if __name__ == "__main__":
    main()

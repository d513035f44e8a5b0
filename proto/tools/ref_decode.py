#!/usr/bin/env python3
"""ref_decode.py — a third, independent decoder of oceand v1 frames, written
from proto/PROTOCOL.md alone with the Python standard library (zlib, struct).
Slow and simple on purpose: it shows what a client must do, and checks that
the document is enough.

  python3 proto/tools/ref_decode.py proto/vectors     # check every vector
  python3 proto/tools/ref_decode.py FRAME.bin         # print one frame

Codec 2 (zstd) tiles are skipped (no zstd in the standard library). Codec 3
(temporal, §5.6-5.8) is decoded against a `refs` dict that the caller keeps for a
stream (the `streams` of the manifest, frame by frame).
"""
import json
import os
import struct
import sys
import zlib


class FrameError(Exception):
    def __init__(self, code, msg):
        super().__init__(f"{code}: {msg}")
        self.code = code


FIELDS = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"]


def f32(x):
    """Round a float64 to the nearest float32 (ties to even), as §5.4 requires."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def wrap32(x):
    x &= 0xFFFFFFFF
    return x - (1 << 32) if x >= 1 << 31 else x


def decode_lossy(th, p):
    w, h = th["width"], th["height"]
    count = w * h
    if len(p) < 16:
        raise FrameError("corrupt", "lossy payload shorter than its prefix")
    esc_width, z1, z2, esc_count = struct.unpack_from("<BBHI", p, 0)
    coef = struct.unpack_from("<6b", p, 8)
    (z3,) = struct.unpack_from("<H", p, 14)
    if esc_width > 4 or z1 or z2 or z3 or esc_count > count or (esc_count == 0) != (esc_width == 0):
        raise FrameError("corrupt", "lossy prefix")
    if th["codec"] == 2:
        raise FrameError("unsupported", "zstd")
    d = zlib.decompressobj(-15)
    try:
        data = d.decompress(p[16:], count + esc_count * esc_width + 1)
    except zlib.error as e:
        raise FrameError("corrupt", str(e))
    if len(data) != count + esc_count * esc_width or not d.eof or d.unused_data:
        raise FrameError("corrupt", "deflate stream size")
    # §5.2 escapes and zigzag
    b, e, r = data[count:], 0, []
    for k in range(count):
        z = data[k]
        if z == 255:
            if e == esc_count:
                raise FrameError("corrupt", "too many escapes")
            z = 255 + sum(b[pl * esc_count + e] << (8 * pl) for pl in range(esc_width))
            e += 1
        r.append(wrap32((z >> 1) ^ -(z & 1)))
    if e != esc_count:
        raise FrameError("corrupt", "too few escapes")
    # §5.3 inverse prediction
    q = [0] * count
    for j in range(h):
        for i in range(w):
            k = j * w + i
            if j == 0:
                pred = q[k - 1] if i > 0 else 0
            elif i == 0:
                pred = q[k - w]
            elif j >= 2 and 2 <= i <= w - 2:
                s = (coef[0] * q[k - 1] + coef[1] * q[k - w] + coef[2] * q[k - w - 1] + coef[3] * q[k - w + 1]
                     + coef[4] * q[k - 2] + coef[5] * q[k - 2 * w])
                pred = max(-(1 << 31), min((1 << 31) - 1, (s + 32) // 64))
            else:
                pred = q[k - 1] + q[k - w] - q[k - w - 1]
            q[k] = wrap32(pred + r[k])
    # §5.4 reconstruction
    th["codes"] = q
    return [f32(th["offset"] + float(v) * th["scale"]) for v in q]


def unpack_escaped(data, count, esc_count, esc_width):
    """§5.2: count bytes (255 = escaped) then esc_count values of esc_width byte planes -> zigzag values."""
    b, e, z = data[count:], 0, []
    for k in range(count):
        v = data[k]
        if v == 255:
            if e == esc_count:
                raise FrameError("corrupt", "too many escapes")
            v = 255 + sum(b[pl * esc_count + e] << (8 * pl) for pl in range(esc_width))
            e += 1
        z.append(v)
    if e != esc_count:
        raise FrameError("corrupt", "too few escapes")
    return z


def lap(a, w, h, i, j):
    """§5.8: 5-point Laplacian, indices clamped into the tile."""
    at = lambda ii, jj: a[min(max(jj, 0), h - 1) * w + min(max(ii, 0), w - 1)]
    return at(i - 1, j) + at(i + 1, j) + at(i, j - 1) + at(i, j + 1) - 4 * at(i, j)


def decode_temporal(th, p, key, refs):
    """§5.6-5.8. refs: {key: [(seq, offset, scale, bound, codes)]} of earlier frames (None: no state)."""
    w, h = th["width"], th["height"]
    count, npairs = w * h, (w * h + 1) // 2
    if len(p) < 40:
        raise FrameError("corrupt", "temporal prefix")
    depth, packing, esc_width, z0, esc_count, pair_esc, z1, ref_seq = struct.unpack_from("<BBBBIIIQ", p, 0)
    coef = struct.unpack_from("<7h", p, 24)
    (z2,) = struct.unpack_from("<H", p, 38)
    allowed = {1: {6}, 2: {0, 3, 6}, 3: {0, 1, 3, 4, 6}, 4: set(range(7))}.get(depth)
    if (allowed is None or packing > 1 or esc_width > 4 or z0 or z1 or z2 or (esc_count == 0) != (esc_width == 0)
            or any(c and k not in allowed for k, c in enumerate(coef))):
        raise FrameError("corrupt", "temporal prefix")
    if packing == 0:
        if pair_esc or esc_count > count:
            raise FrameError("corrupt", "escape counts")
        size = count + esc_count * esc_width
    else:
        if pair_esc > npairs or esc_count > 2 * pair_esc:
            raise FrameError("corrupt", "escape counts")
        size = npairs + 2 * pair_esc + esc_count * esc_width
    q = []
    for i in range(depth):   # the references: ref_seq, ref_seq - 1, ... on this tile's grid
        hit = [c for (sq, o, sc, b, c) in (refs or {}).get(key, [])
               if sq == ref_seq - i and (o, sc, b) == (th["offset"], th["scale"], th["bound"])]
        if not hit:
            raise FrameError("reference", f"reference {ref_seq - i} missing")
        q.append(hit[0])
    d = zlib.decompressobj(-15)
    try:
        data = d.decompress(p[40:], size + 1)
    except zlib.error as e:
        raise FrameError("corrupt", str(e))
    if len(data) != size or not d.eof or d.unused_data:
        raise FrameError("corrupt", "deflate stream size")
    if packing == 0:
        z = unpack_escaped(data, count, esc_count, esc_width)
    else:
        y = unpack_escaped(data[npairs:], 2 * pair_esc, esc_count, esc_width)
        z, e = [], 0
        for pb in data[:npairs]:
            if pb < 225:
                z += [pb // 15, pb % 15]
            elif pb == 255 and e < pair_esc:
                z += y[2 * e:2 * e + 2]
                e += 1
            else:
                raise FrameError("corrupt", "pair byte")
        if e != pair_esc or (count % 2 and z[count] != 0):
            raise FrameError("corrupt", "pairs")
        z = z[:count]
    while len(q) < 4:   # terms the depth lacks are 0: stand-in references with zero coefficients
        q.append(q[0])
    codes = []
    for j in range(h):
        for i in range(w):
            k = j * w + i
            L = [lap(a, w, h, i, j) for a in q]
            S = (coef[0] * (q[0][k] - q[1][k]) + coef[1] * (q[1][k] - q[2][k]) + coef[2] * (q[2][k] - q[3][k])
                 + coef[3] * (L[0] - L[1]) + coef[4] * (L[1] - L[2]) + coef[5] * (L[2] - L[3]) + coef[6] * L[0])
            P = q[0][k] + (S + 2048) // 4096
            codes.append(wrap32(P + ((z[k] >> 1) ^ -(z[k] & 1))))
    return codes


def decode_frame(buf, refs=None):
    if len(buf) < 8:
        raise FrameError("truncated", "short header")
    if buf[:4] != b"OCNF":
        raise FrameError("magic", "not OCNF")
    version, header_size = struct.unpack_from("<HH", buf, 4)
    if version != 1:
        raise FrameError("version", f"version {version}")
    if header_size < 48 or header_size % 8:
        raise FrameError("corrupt", "header_size")
    if len(buf) < header_size:
        raise FrameError("truncated", "short header")
    seq, sim_time, pv, n, ts, patch, tc, flags, stu = struct.unpack_from("<QdIHHfHHQ", buf, 8)
    if n > 2048:
        raise FrameError("too_large", f"n {n}")
    pow2 = lambda v: v > 0 and v & (v - 1) == 0
    if not pow2(n) or not pow2(ts) or ts > n or not (patch > 0) or patch == float("inf") or sim_time != sim_time:
        raise FrameError("corrupt", "frame header")
    header = dict(seq=seq, simTime=sim_time, paramsVersion=pv, n=n, tileSize=ts, patchSize=patch,
                  tileCount=tc, flags=flags, serverTimeUs=stu)
    pos, tiles = header_size, []
    for _ in range(tc):
        if len(buf) - pos < 40:
            raise FrameError("truncated", "tile header")
        field, lod, codec, fl, tx, tz, w, h, bound, off, sc, plen, _res = struct.unpack_from("<BBBBHHHHfddII", buf, pos)
        side = ts >> lod if lod <= 4 else 0
        if field >= 6 or lod > 4 or side == 0 or w != side or h != side or tx >= n // ts or tz >= n // ts:
            raise FrameError("corrupt", "tile header")
        if codec not in (0, 1, 2, 3) or not (bound >= 0) or bound == float("inf"):
            raise FrameError("corrupt", "tile header")
        if codec and not (sc > 0 and sc != float("inf") and abs(off) != float("inf") and off == off):
            raise FrameError("corrupt", "offset/scale")
        pos += 40
        if plen > len(buf) - pos:
            raise FrameError("truncated", "payload")
        p = buf[pos:pos + plen]
        pos += plen
        th = dict(field=FIELDS[field], lod=lod, codec=codec, tileX=tx, tileZ=tz, width=w, height=h,
                  bound=bound, offset=off, scale=sc, cascade=fl & 3)   # flags bits 0-1: the cascade (§3.2)
        key = (field, lod, fl & 3, tx, tz, n, ts)
        if codec == 0:
            if plen != 4 * w * h:
                raise FrameError("corrupt", "raw size")
            th["samples"] = list(struct.unpack(f"<{w * h}f", p))
        elif codec == 3:
            codes = decode_temporal(th, p, key, refs)
            th["codes"], th["samples"] = codes, [f32(off + float(v) * sc) for v in codes]
        else:
            th["samples"] = decode_lossy(th, p)
        th["key"] = key
        tiles.append(th)
    if pos != len(buf):
        raise FrameError("corrupt", "bytes after the last tile")
    if refs is not None:   # §5.8: the whole frame decoded; keep the last 5 frames per tile
        for t in tiles:
            if "codes" in t:
                lst = refs.setdefault(t["key"], [])
                lst.append((seq, t["offset"], t["scale"], t["bound"], t["codes"]))
                del lst[:-5]
    return header, tiles


def check_vectors(vdir):
    with open(os.path.join(vdir, "manifest.json")) as f:
        m = json.load(f)
    ok = bad = skipped = 0
    for v in m["vectors"]:
        with open(os.path.join(vdir, v["file"]), "rb") as f:
            buf = f.read()
        with open(os.path.join(vdir, v["expected"]), "rb") as f:
            raw = f.read()
        expected = struct.unpack(f"<{len(raw) // 4}f", raw)
        try:
            header, tiles = decode_frame(buf)
        except FrameError as e:
            if e.code == "unsupported":
                skipped += 1
                continue
            print(f"FAIL {v['name']}: {e}")
            bad += 1
            continue
        good = all(header[k] == v["header"][k] for k in v["header"])
        for t, mt in zip(tiles, v["tiles"]):
            at = mt["sampleOffset"]
            good &= all(t[k] == mt[k] for k in ("field", "lod", "codec", "tileX", "tileZ", "offset", "scale"))
            good &= t["cascade"] == mt.get("cascade", 0)
            # identical float32 values (compared through their bits)
            good &= struct.pack(f"<{len(t['samples'])}f", *t["samples"]) == raw[4 * at:4 * (at + len(t["samples"]))]
        print(("ok   " if good else "FAIL ") + v["name"])
        ok += good
        bad += not good
    for b in m["bad"]:
        with open(os.path.join(vdir, b["file"]), "rb") as f:
            buf = f.read()
        try:
            decode_frame(buf)
            got = "accepted"
        except FrameError as e:
            got = e.code
        good = got == b["error"]
        print(("ok   " if good else "FAIL ") + f"{b['name']}: {got}")
        ok += good
        bad += not good
    for st in m.get("streams", []):
        refs, good = {}, True
        for f in st["frames"]:
            with open(os.path.join(vdir, f["file"]), "rb") as fh:
                buf = fh.read()
            try:
                _, tiles = decode_frame(buf, refs)
                got = None
            except FrameError as e:
                got, tiles = e.code, []
            if got != f.get("error"):
                good = False
            elif got is None:
                with open(os.path.join(vdir, f["expected"]), "rb") as fh:
                    raw = fh.read()
                samples = [x for t in tiles for x in t["samples"]]
                good &= struct.pack(f"<{len(samples)}f", *samples) == raw
        print(("ok   " if good else "FAIL ") + f"stream {st['name']}")
        ok += good
        bad += not good
    print(f"{ok} passed, {bad} failed, {skipped} skipped (zstd)")
    return bad == 0


def main():
    if len(sys.argv) != 2:
        print(__doc__)
        return 2
    arg = sys.argv[1]
    if os.path.isdir(arg):
        return 0 if check_vectors(arg) else 1
    with open(arg, "rb") as f:
        header, tiles = decode_frame(f.read())
    print(json.dumps(header))
    for t in tiles:
        s = t.pop("samples")
        print(json.dumps(t), f"{len(s)} samples, first {s[:4]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The Python package (proto/python, import name oceand) against a real daemon
with 3 cascades: per-cascade grids, the summed surface against `query`, the
sync and async clients, probes. Prints one "ok" line per check, exits 1 on the
first failure.

Usage: /usr/bin/python3 tests/tap/test_package.py URL [SITE_DIR]
SITE_DIR: where `pip install --target` put the package (else proto/python).
"""
import asyncio
import os
import struct
import sys

import numpy as np

here = os.path.dirname(os.path.abspath(__file__))
url = sys.argv[1]
sys.path.insert(0, os.path.abspath(sys.argv[2] if len(sys.argv) > 2 else os.path.join(here, "..", "..", "proto", "python")))
import oceand  # noqa: E402
from oceand import frames  # noqa: E402

# Targets (docs/query.md): summed grids against the exact surface.
NODE_MAX_M = 0.001      # at the nodes of cascade 0's grid
ANY_MAX_M = 0.005       # anywhere, spectral interpolation


def ok(msg):
    print(f"  ok  {msg}", flush=True)


def check(cond, msg):
    if not cond:
        print(f"FAIL: {msg}", file=sys.stderr)
        sys.exit(1)


def rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


# ---- where the package came from, and the Assembler keeps cascades apart ----
check(os.path.abspath(oceand.__file__).startswith(sys.path[0] + os.sep),
      f"oceand imported from {oceand.__file__}, not from {sys.path[0]}")
vec = open(os.path.join(here, "..", "..", "proto", "vectors", "v12_cascades.bin"), "rb").read()
f = oceand.decode_frame(vec)
by_cascade = {}
for t in f.tiles:
    by_cascade.setdefault(t.cascade, []).append(t)
check(len(by_cascade) >= 2, "v12_cascades.bin holds one cascade only")
for c, tiles in by_cascade.items():
    lod = tiles[0].lod
    a = oceand.Assembler(["height"], lod, cascade=c)
    a.add(f)
    t = next(t for t in tiles if t.field == "height")
    step = f.tile_size >> lod
    got = a.fields["height"][t.z * step:t.z * step + step, t.x * step:t.x * step + step]
    check(np.array_equal(got, t.samples), f"cascade {c}: the Assembler does not hold its tile")
    others = [u for u in f.tiles if u.cascade != c and u.field == "height" and u.lod == lod]
    for u in others:   # another cascade's tile at the same place must not have been written
        region = a.fields["height"][u.z * step:u.z * step + step, u.x * step:u.x * step + step]
        check(not np.array_equal(region, u.samples) or np.array_equal(u.samples, t.samples),
              f"cascade {c}'s Assembler took a tile of cascade {u.cascade}")
ok(f"Assembler(cascade=c) keeps only cascade c's tiles ({len(by_cascade)} cascades in v12_cascades.bin)")


# ---- FrameJoiner: a tick's parts (PROTOCOL.md §3.4) join to the whole frame ----
def split(buf, counts):
    """buf's tiles in messages of counts[i] tiles, flags bit 1 on all but the last."""
    ends, pos = [], 48
    for _ in range(struct.unpack_from("<H", buf, 36)[0]):
        pos += 40 + struct.unpack_from("<I", buf, pos + 32)[0]
        ends.append(pos)
    out, start, tile = [], 48, 0
    for i, k in enumerate(counts):
        end = ends[tile + k - 1]
        part = bytearray(buf[:48] + buf[start:end])
        struct.pack_into("<HH", part, 36, k, oceand.frames.FLAG_PART if i < len(counts) - 1 else 0)
        out.append(bytes(part))
        start, tile = end, tile + k
    return out


ntiles = struct.unpack_from("<H", vec, 36)[0]
for counts in ([1] * ntiles, [ntiles - 1, 1], [ntiles]):
    j = oceand.FrameJoiner()
    got = [j.push(p) for p in split(vec, counts)]
    check(all(g is None for g in got[:-1]) and got[-1] == vec, f"parts {counts} do not join to the whole frame")
other = split(vec, [1, ntiles - 1])
other = [o[:8] + struct.pack("<Q", 999) + o[16:] for o in other]
j = oceand.FrameJoiner()
j.push(split(vec, [1, ntiles - 1])[0])
j.push(other[0])
joined = j.push(other[1])
check(struct.unpack_from("<Q", joined, 8)[0] == 999 and struct.unpack_from("<H", joined, 36)[0] == ntiles,
      "a part of another tick did not drop the unfinished one")
ok(f"FrameJoiner joins parts to the whole frame ({ntiles} tiles, split 3 ways)")

# ---- the sync client: surface against query ----
with oceand.Client(url) as sea:
    ncasc = int(sea.params["cascades"])
    check(ncasc == 3, f"the daemon runs {ncasc} cascades, the test wants 3")
    sea.query([[0, 0]])   # the server plans its exact evaluator at the first query: not inside the window
    sea.subscribe(fields=["height", "dx", "dz"], bound=0, cascades="all")
    s = sea.surface()
    check(s.cascades == [0, 1, 2], f"surface cascades {s.cascades}")
    N = sea.params["resolution"]
    check(s.grids[0]["height"].shape == (N, N) and s.grids[1]["height"].shape == (N // 2, N // 2),
          f"grid shapes {[s.grids[c]['height'].shape for c in s.cascades]}")
    L0 = s.patch_sizes[0]
    rng = np.random.default_rng(7)
    # Nodes of cascade 0: the query point is where the node's surface point lands.
    ix, iz = rng.integers(0, N, 256), rng.integers(0, N, 256)
    x0, z0 = ix * L0 / N, iz * L0 / N
    g = s.grid("height", N)
    check(np.array_equal(g[iz, ix], s.sample("height", x0, z0).astype(np.float32)), "grid() and sample() disagree")
    px, pz = x0 + s.sample("dx", x0, z0), z0 + s.sample("dz", x0, z0)
    q = sea.query(np.stack([px, pz], 1), time=s.sim_time)
    check(abs(q["sim_time"] - s.sim_time) < 1e-9, f"query answered t={q['sim_time']}, asked {s.sim_time}")
    hq = np.array([p["height"] for p in q["points"]])
    src = np.array([p["source"] for p in q["points"]])
    check(np.abs(src - np.stack([x0, z0], 1)).max() < 0.01, "query's source is not the node")
    e_node = np.abs(g[iz, ix] - hq)
    e_c0 = np.abs(s.grids[0]["height"][iz, ix] - hq)
    check(e_node.max() <= NODE_MAX_M, f"summed grid at nodes: max {e_node.max() * 1e3:.3f} mm > 1 mm")
    # The comparison sees what is missing: cascade 0 alone is centimetres off.
    check(rms(e_c0) > 5 * NODE_MAX_M, f"cascade 0 alone is only {rms(e_c0) * 1e3:.2f} mm rms off: the check is blind")
    ok(f"summed grid at 256 nodes vs query: {rms(e_node) * 1e3:.3f} mm rms, {e_node.max() * 1e3:.3f} max "
       f"(cascade 0 alone: {rms(e_c0) * 1e3:.1f} mm rms)")

    # Anywhere: query's source point, the summed fields interpolated there.
    pts = rng.uniform(-1000, 1000, (256, 2))
    q = sea.query(pts, time=s.sim_time)
    hq = np.array([p["height"] for p in q["points"]])
    src = np.array([p["source"] for p in q["points"]])
    e_spec = np.abs(s.sample("height", src[:, 0], src[:, 1]) - hq)
    e_bil = np.abs(s.sample("height", src[:, 0], src[:, 1], "bilinear") - hq)
    hd, sx, sz = s.displaced_height(pts[:, 0], pts[:, 1])
    e_disp = np.abs(hd - hq)
    check(e_spec.max() <= ANY_MAX_M, f"spectral interpolation: max {e_spec.max() * 1e3:.3f} mm > 5 mm")
    check(e_disp.max() <= ANY_MAX_M, f"displaced_height: max {e_disp.max() * 1e3:.3f} mm > 5 mm")
    check(np.abs(np.stack([sx, sz], 1) - src).max() < 0.01, "displaced_height's source differs from query's")
    check(rms(e_bil) > rms(e_spec), "bilinear is no worse than spectral: the check is blind")
    ok(f"anywhere (256 points): spectral {rms(e_spec) * 1e3:.3f} mm rms, {e_spec.max() * 1e3:.3f} max; "
       f"displaced_height {rms(e_disp) * 1e3:.3f} rms; bilinear {rms(e_bil) * 1e3:.1f} rms, {e_bil.max() * 1e3:.1f} max")

    # Lossy finer cascades: the error stays within the bounds added up.
    sea.subscribe(fields=["height", "dx", "dz"], bound=0.001, cascades="all", max_rate=5)
    s2 = sea.surface()
    q = sea.query(pts[:64], time=s2.sim_time)
    hq = np.array([p["height"] for p in q["points"]])
    src = np.array([p["source"] for p in q["points"]])
    e = np.abs(s2.sample("height", src[:, 0], src[:, 1]) - hq)
    check(e.max() <= ANY_MAX_M, f"bound 0.001: max {e.max() * 1e3:.3f} mm")
    ok(f"bound 1 mm on every cascade: {rms(e) * 1e3:.3f} mm rms, {e.max() * 1e3:.3f} max")

    r = sea.probe([[0, 0], [10, 5]])
    check(r["type"] == "probing", f"probe answered {r}")
    d = sea.probe_data()
    check(d["type"] == "probe_data" and len(d["points"]) == 2 and len(d["points"][0]) == 8, f"probe_data {d}")
    try:
        sea.query([[0, 0]], time=-100)
        check(False, "a query outside the window was answered")
    except oceand.ServerError as e:
        check(e.code == "time_out_of_window", f"error code {e.code}")
    ok("probe / probe_data; a refused query raises ServerError(time_out_of_window)")

    # Exact-time renders (PROTOCOL.md §7.5): every frame, at start + k/fps, the summed sea of query.
    now = sea.query([[0, 0]])["sim_time"]
    T, F, K = max(0.0, now - 2.0), 10.0, 5
    got = list(sea.render(T, F, K, fields=["height", "dx", "dz"], bound=0))
    check([r.seq for r in got] == list(range(K)), f"render seqs {[r.seq for r in got]}")
    check(all(abs(r.sim_time - (T + k / F)) <= 1e-6 for k, r in enumerate(got)), "render times")
    r = got[-1]
    check(r.cascades == [0, 1, 2], f"render cascades {r.cascades}")
    g = r.grid("height", N)
    px, pz = x0 + r.sample("dx", x0, z0), z0 + r.sample("dz", x0, z0)
    q = sea.query(np.stack([px, pz], 1)[:64], time=r.sim_time)
    e = np.abs(g[iz, ix][:64] - np.array([p["height"] for p in q["points"]]))
    check(e.max() <= NODE_MAX_M, f"rendered sum at nodes vs query: max {e.max() * 1e3:.3f} mm")
    try:
        list(sea.render(0, 24, 10 ** 6))
        check(False, "a render of a million frames was accepted")
    except oceand.ServerError as err:
        check(err.code == "bad_render", f"error code {err.code}")
    ok(f"render: {K} frames at T + k/{F:g}, summed grid at nodes vs query {rms(e) * 1e3:.3f} mm rms; "
       f"a refused render raises ServerError(bad_render)")


# ---- the async client: two frames in order, one cascade ----
async def async_checks():
    async with await oceand.AsyncClient.connect(url) as sea:
        await sea.subscribe(fields=["height"], lod=1, bound=0.01, cascades=None)
        a = await sea.surface()
        b = await sea.surface(newer_than=a)
        check(b.seq > a.seq and a.cascades == [0], f"seqs {a.seq} {b.seq}, cascades {a.cascades}")
        check(a.grids[0]["height"].shape == (sea.params["resolution"] // 2,) * 2, "lod 1 shape")
        q, p = await asyncio.gather(sea.query([[1, 2]]), sea.query([[3, 4]]))
        check(q["points"] and p["points"] and q["id"] != p["id"], "concurrent queries")
        ok("AsyncClient: surfaces in seq order, concurrent queries matched by id")
        gen = sea.render(3.0, 30, 50, fields=["height"], lod=2, cascades=None)
        check((await gen.__anext__()).seq == 0, "first rendered frame")
        await gen.aclose()                 # cancels the render
        seqs = [r.seq async for r in sea.render(1.0, 24, 4, fields=["height"], lod=2, cascades=None)]
        check(seqs == [0, 1, 2, 3], f"a render after a cancelled one: seqs {seqs}")
    ok("AsyncClient.render: closing it early cancels; the next render follows")


async def control_only_checks():
    # A program that only sets, queries or probes: ?frames=0 (PROTOCOL.md §1.2), no frames.
    async with await oceand.AsyncClient.connect(url + "/?frames=0") as sea:
        check(sea.subscription.get("fields") == [], f"hello subscription {sea.subscription}")
        q = await sea.query([[5, 6]])
        await asyncio.sleep(0.5)           # 5 ticks at 10 Hz
        check(q["points"] and sea._latest is None, f"a frame reached the control-only client: {sea._latest is not None}")
    ok("AsyncClient on ?frames=0: queries answered, no frame")


# ---- floating bodies (PROTOCOL.md §3.5, §7.6) ----
import json  # noqa: E402
manifest = json.load(open(os.path.join(here, "..", "..", "proto", "vectors", "manifest.json")))
vb = next(v for v in manifest["vectors"] if v["name"] == "v13_bodies")
raw = open(os.path.join(here, "..", "..", "proto", "vectors", vb["file"]), "rb").read()
got = oceand.decode_bodies(raw)
check([b.id for b in got] == [b["id"] for b in vb["bodies"]], f"v13_bodies ids {[b.id for b in got]}")
for b, w in zip(got, vb["bodies"]):
    check(b.kind == w["kind"] and b.flags == w["flags"] and round(b.throttle * 127) == w["throttle"] and
          round(b.rudder * 127) == w["rudder"] and np.allclose(b.pos, w["pos"]) and np.allclose(b.quat, w["quat"]) and
          np.allclose(b.vel, w["vel"]), f"body {b.id}: {b} against {w}")
check(oceand.decode_frame(raw).bodies == got and oceand.decode_bodies(vec) == [], "bodies of a frame")
ok("decode_bodies: v13_bodies' three records exactly; a frame without a BODY section has none")


async def body_checks():
    async with await oceand.AsyncClient.connect(url) as sea:
        kinds = [k["name"] for k in sea.body_kinds]
        check("boat" in kinds and "ship" in kinds, f"body_kinds {kinds}")
        m = await sea.launch("boat", 10, -20, heading=90)
        body = m["body"]
        check(sea.resume.get(body) == m["resume"], "resume key not kept")
        await sea.steer(body, throttle=1.0, rudder=0.25)
        seq, now = await sea.bodies_now()
        seq2, now = await sea.bodies_now(newer_than=seq)
        while not any(b.id == body and b.throttle == 1.0 for b in now):
            seq2, now = await sea.bodies_now(newer_than=seq2)
        b = next(b for b in now if b.id == body)
        check(b.powered and not b.adrift and kinds[b.kind] == "boat", f"record {b}")
        await asyncio.sleep(0.3)
        check(body in sea.bodies and sea.bodies[body]["kind"] == "boat", f"bodies list {sea.bodies}")
        key = m["resume"]
    async with await oceand.AsyncClient.connect(url + "/?frames=0") as other:
        try:
            await other.steer(body, throttle=0)
            check(False, "another client steered the boat")
        except oceand.ServerError as e:
            check(e.reply["code"] == "not_owner", f"steer by another: {e.reply}")
        c = await other.claim(body, key)
        check(c["type"] == "claimed", f"claim {c}")
        r = await other.remove(body)
        check(r["type"] == "removed" and body not in other.resume, f"remove {r}")
    ok("AsyncClient: launch, steer, bodies_now (the frame's records), claim with the key, remove; not_owner")


asyncio.run(async_checks())
asyncio.run(control_only_checks())
asyncio.run(body_checks())
print("PASS: test_package.py")

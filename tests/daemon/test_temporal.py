#!/usr/bin/python3
"""Temporal codec (codec 3) against a real daemon (PROTOCOL.md §5.9, docs/codec.md).

Behaviour, not timing: every frame a temporal client receives decodes, in
order, with one decoder (build/frame_check, C) and lies within the bound of
the simulation (and of the lossless stream at equal seq, decoded by the
Python example decoder); a client that joins mid-stream decodes its first
frame alone; a client throttled by max_rate and a slow reader never get a
predicted frame without its references; intra-only clients never see codec 3.

    /usr/bin/python3 tests/daemon/test_temporal.py --oceand build/oceand --frame-check build/frame_check
Uses the harness of test_daemon.py (same flags: --sanitized, -k).
"""
import asyncio
import json
import os
import socket
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "proto", "examples"))
import test_daemon as td  # noqa: E402
from test_daemon import check, connect, recv_json, tiles, parse_header  # noqa: E402
import oceanproto  # noqa: E402
import numpy as np  # noqa: E402

TESTS = []
CODEC_TEMPORAL = 3


def test(fn):
    TESTS.append(fn)
    return fn


async def subscribe(ws, **sub):
    # Pinned (adapt: false) unless a test says otherwise: these tests judge the
    # codec's frames at the LOD asked for; on a loaded machine the ladder would
    # serve a slow reader coarser (PROTOCOL.md §7.2 `link`; tests/links judge that).
    sub.setdefault("adapt", False)
    await ws.send(json.dumps(dict(type="subscribe", id=9, **sub)))
    m = await recv_json(ws, lambda j: j.get("type") in ("subscribed", "error") and j.get("id") == 9)
    check(m["type"] == "subscribed", "subscribe refused: %r" % m)
    return m["subscription"]


async def collect(ws, seconds, limit=None):
    """Every binary frame received for `seconds` (after the caller's `subscribed`)."""
    out = []
    t0 = time.time()
    while time.time() - t0 < seconds and (limit is None or len(out) < limit):
        m = await asyncio.wait_for(ws.recv(), 5)
        if isinstance(m, bytes):
            out.append(m)
        elif '"degraded"' in m:
            print("    told:", m)
    return out


def full_detail(m, lod=0):
    """A frame whose tiles are all at the subscribed LOD. Short of encode time (a
    sanitizer build on a loaded machine), the daemon serves a group at a coarser LOD,
    and such layers go intra by design (docs/daemon.md, capacity): the checks of
    predicted tiles judge full-detail frames only."""
    return all(t["lod"] == lod for t in tiles(m))


def codecs(frames):
    c = {}
    for m in frames:
        for t in tiles(m):
            c[t["codec"]] = c.get(t["codec"], 0) + 1
    return c


def check_stream(d, params, frames, bound, what):
    """frame_check decodes the frames in order with ONE decoder (predicted tiles
    need their references) and compares every sample with the library."""
    res = td.frame_check(d, params, frames)
    check(len(res) == len(frames), "%s: frame_check gave %d lines for %d frames" % (what, len(res), len(frames)))
    worst = max(r["max_err"] for r in res)
    check(all(r["bad"] == 0 for r in res) and worst <= bound * (1 + 1e-6),
          "%s: samples outside the bound %g (max error %g)" % (what, bound, worst))
    return worst


@test
def test_temporal_stream_within_bound_of_lossless():
    """A long stream (60 s of sim time: 15 s at time_scale 4, so 450 ticks with
    four times the motion per tick; periodic keyframes every 60 ticks so every
    tile restarts its chain 7 times; the default K = 300 would give at most 1.5
    restarts in 60 s of ticks). Every temporal frame is within the bound of the
    lossless stream at equal seq and of the simulation."""
    d = td.Daemon("--keyframe-interval", "60", "--time-scale", "4")

    async def run():
        a, hello = await connect(d)
        b, _ = await connect(d)
        await subscribe(a, temporal=True, bound=0.01)
        await subscribe(b, bound=0, max_rate=5)      # lossless, a few frames a second
        ta = asyncio.ensure_future(collect(a, 15))
        tb = asyncio.ensure_future(collect(b, 15))
        fa, fb = await ta, await tb
        await a.close()
        await b.close()
        return hello, fa, fb
    try:
        hello, fa, fb = asyncio.run(run())
        c = codecs(fa)
        seqs = [parse_header(m)["seq"] for m in fa]
        gaps = sum(y - x - 1 for x, y in zip(seqs, seqs[1:]))
        print("    temporal: %d frames, %d skipped, tiles by codec %r, %.1f kB/frame; lossless: %d frames"
              % (len(fa), gaps, c, sum(map(len, fa)) / len(fa) / 1e3, len(fb)))
        check(len(fa) >= 200, "only %d temporal frames in 15 s" % len(fa))
        # A frame skipped under load (latest-frame-wins) sends that client keyframe tiles until it
        # has references again: judge the predictor on frames with no gap among the 4 before them.
        # Frames served at a coarser LOD on purpose (short of encode time) are intra: left out too.
        steady = [m for i, m in enumerate(fa) if i >= 4 and seqs[i] - seqs[i - 4] == 4 and
                  all(full_detail(x) for x in fa[i - 4:i + 1])]
        cs = codecs(steady)
        degraded = sum(not full_detail(m) for m in fa)
        if degraded > len(fa) / 2:
            print("    %d of %d frames degraded (short of encode time): predicted share not judged" % (degraded, len(fa)))
        else:
            check(len(steady) >= 100, "only %d frames without a recent gap" % len(steady))
            check(cs.get(CODEC_TEMPORAL, 0) > 0.8 * sum(cs.values()), "mostly predicted tiles expected: %r" % cs)
        check(CODEC_TEMPORAL not in {t["codec"] for t in tiles(fa[0])}, "the first frame must be keyframes")
        worst = check_stream(d, hello["params"], fa, 0.01, "temporal stream")
        # The same frames through the Python decoder, against the lossless stream at equal seq.
        state, lossless, compared, err = oceanproto.DecoderState(), {}, 0, 0.0
        for m in fb:
            f = oceanproto.decode_frame(m)
            lossless[f.seq] = {(t.field, t.x, t.z): t.samples for t in f.tiles}
        for m in fa:
            f = oceanproto.decode_frame(m, state)
            ref = lossless.get(f.seq)
            if ref is None:
                continue
            for t in f.tiles:
                # The server may send either layer at a coarser LOD when it is short of encode
                # time (capacity plan): a coarser LOD is plain subsampling (PROTOCOL.md §4).
                r, a = ref[(t.field, t.x, t.z)], t.samples
                if r.shape != a.shape:
                    sa, sr = a.shape[0] // min(a.shape[0], r.shape[0]), r.shape[0] // min(a.shape[0], r.shape[0])
                    a, r = a[::sa, ::sa], r[::sr, ::sr]
                e = float(np.max(np.abs(a.astype(np.float64) - r)))
                err = max(err, e)
            compared += 1
        print("    max error %.5f against the simulation, %.5f against the lossless stream (%d frames at equal seq)"
              % (worst, err, compared))
        check(compared >= 20, "only %d frames at equal seq with the lossless stream" % compared)
        check(err <= 0.01 * (1 + 1e-6), "temporal frames differ from the lossless ones by %g > bound" % err)
        check(d.metric('oceand_stream_tiles_total{kind="predicted"}') > 0, "no predicted tiles counted")
        rc, _ = d.stop()
        check(rc == 0, "exit code %r" % rc)
    finally:
        d.kill()


@test
def test_frames_same_on_any_encode_thread_count():
    """A layer's rows of tiles are encoded by whichever encode threads take
    them (server/frame.c): the bytes may not depend on it. Two paused daemons
    (t = 0, seed 1, N = 512: four rows of tiles a layer), one encode thread
    against three: the intra frames, the temporal client's first frame (the
    stream's keyframes) and its predicted tiles (the ref_seq in their prefix
    masked: the daemons' seq differ) are byte for byte the same."""
    # 5 ticks a second: a budget of 160 ms a frame, so that no frame is degraded (coarser, not
    # comparable) even under ASan on a loaded machine.
    ds = [td.Daemon("--paused", "true", "--resolution", "512", "--tick-rate", "5", "--encode-threads", str(k))
          for k in (1, 3)]

    async def grab(d):
        a, _ = await connect(d)
        b, _ = await connect(d)
        await subscribe(a, fields=["height", "dx", "slope_x"], bound=0.01)
        await subscribe(b, fields=["height", "dz", "jacobian"], temporal=True, bound=0.001)
        fa = await collect(a, 3, limit=3)
        # b is read after a: it catches up tick by tick (PROTOCOL.md §5.9), from a
        # first frame that may precede its stream; 8 frames reach depth 4 on both daemons.
        fb = await collect(b, 3, limit=8)
        await a.close()
        await b.close()
        return fa, fb

    def body(m):
        """The tiles, without the frame header and with each predicted tile's ref_seq zeroed."""
        b, off = bytearray(m), 48
        for _ in range(parse_header(m)["tile_count"]):
            f, lod, codec, fl, tx, tz, w, hh, bound, o, sc, plen, _r = td.TILE_HDR.unpack_from(b, off)
            if codec == CODEC_TEMPORAL:
                b[off + 40 + 16:off + 40 + 24] = bytes(8)
            off += 40 + plen
        return bytes(b[48:])
    try:
        got = [asyncio.run(grab(d)) for d in ds]
        (ia, ta), (ib, tb) = got
        check(len(ia) >= 2 and len(ib) >= 2 and len(ta) >= 4 and len(tb) >= 4,
              "too few frames: %d/%d intra, %d/%d temporal" % (len(ia), len(ib), len(ta), len(tb)))
        check(all(full_detail(m) for m in ia + ib + ta + tb), "a frame was degraded: cannot compare")
        print("    intra %d+%d frames, temporal %d+%d frames (codecs %r)" % (len(ia), len(ib), len(ta), len(tb), codecs(ta)))
        check(body(ia[0]) == body(ib[0]) and body(ia[-1]) == body(ib[-1]),
              "intra frames differ between 1 and 3 encode threads")
        check(body(ta[0]) == body(tb[0]), "the temporal stream's keyframes differ between 1 and 3 encode threads")
        pa = [body(m) for m in ta[1:] if CODEC_TEMPORAL in codecs([m])]
        pb = [body(m) for m in tb[1:] if CODEC_TEMPORAL in codecs([m])]
        check(pa and pb and pa[-1] == pb[-1], "predicted frames differ between 1 and 3 encode threads")
        for d in ds:
            rc, _ = d.stop()
            check(rc == 0, "exit code %r" % rc)
    finally:
        for d in ds:
            d.kill()


@test
def test_temporal_join_mid_stream(d):
    """A client that joins a running temporal stream decodes its first frame
    alone (keyframe tiles of that tick), then takes the shared predicted tiles."""
    async def run():
        a, hello = await connect(d)
        await subscribe(a, temporal=True)
        first_a = await collect(a, 1.0)
        b, _ = await connect(d)
        await subscribe(b, temporal=True)
        fb = await collect(b, 2.0)
        rest_a = await collect(a, 0.3)
        await a.close()
        await b.close()
        return hello, first_a + rest_a, fb
    hello, fa, fb = asyncio.run(run())
    check(len(fb) >= 10, "the joining client got only %d frames" % len(fb))
    print("    joiner: first frame codecs %r, all %r" % (codecs(fb[:1]), codecs(fb)))
    check(CODEC_TEMPORAL not in codecs(fb[:1]), "the joiner's first frame has predicted tiles")
    check_stream(d, hello["params"], fb[:1], 0.01, "first frame alone")
    check_stream(d, hello["params"], fb, 0.01, "joiner's stream")
    full = [m for m in fb[1:] if full_detail(m)]
    if len(full) < 5:
        print("    %d of %d frames at full detail (degraded, short of encode time): switch not judged" % (len(full), len(fb)))
    else:
        check(codecs(full[-5:]).get(CODEC_TEMPORAL, 0) > 0, "the joiner never switched to the shared predicted tiles")
    check_stream(d, hello["params"], fa, 0.01, "first client's stream")


@test
def test_temporal_finer_cascades(d):
    """The finer cascades are temporal too: a temporal client of cascades 0-2
    (the web client's kind of subscription, 3 cascades in force by default)
    gets predicted tiles of cascades 1 and 2, and every tile, decoded in order
    by one decoder keyed by cascade, is within its bound of the lossless stream
    at equal seq."""
    fine = [{"fields": ["height"], "lod": 1, "bound": 0.001}] * 2

    async def run():
        a, hello = await connect(d)
        b, _ = await connect(d)
        await subscribe(a, temporal=True, fields=["height", "dx"], bound=0.01, cascades=fine)
        await subscribe(b, fields=["height", "dx"], bound=0, max_rate=10,
                        cascades=[dict(c, bound=0) for c in fine])
        ta = asyncio.ensure_future(collect(a, 2))
        tb = asyncio.ensure_future(collect(b, 2))
        fa, fb = await ta, await tb
        await a.close()
        await b.close()
        return hello, fa, fb
    hello, fa, fb = asyncio.run(run())
    check(hello["params"]["cascades"] >= 3, "3 cascades in force expected: %r" % hello["params"]["cascades"])
    lossless = {}
    for m in fb:
        f = oceanproto.decode_frame(m)
        lossless[f.seq] = {(t.cascade, t.field, t.x, t.z): t.samples for t in f.tiles}
    state, predicted, compared, excess = oceanproto.DecoderState(), {}, 0, 0.0
    for m in fa:
        f = oceanproto.decode_frame(m, state)
        for t in f.tiles:
            predicted[(t.cascade, t.codec)] = predicted.get((t.cascade, t.codec), 0) + 1
        ref = lossless.get(f.seq)
        if ref is None:
            continue
        for t in f.tiles:
            r, s = ref[(t.cascade, t.field, t.x, t.z)], t.samples
            if r.shape != s.shape:   # a layer the capacity plan sent coarser: plain subsampling (§4)
                m_ = min(s.shape[0], r.shape[0])
                s, r = s[::s.shape[0] // m_, ::s.shape[0] // m_], r[::r.shape[0] // m_, ::r.shape[0] // m_]
            excess = max(excess, float(np.max(np.abs(s.astype(np.float64) - r))) / t.bound - 1)
        compared += 1
    print("    %d temporal frames, tiles by (cascade, codec) %r; %d at equal seq with the lossless stream, "
          "worst error %.3f x bound" % (len(fa), sorted(predicted.items()), compared, excess + 1))
    for c in (0, 1, 2):
        check(predicted.get((c, CODEC_TEMPORAL), 0) > 0, "no predicted (codec 3) tiles of cascade %d: %r" % (c, predicted))
    check(compared >= 10, "only %d frames at equal seq with the lossless stream" % compared)
    check(excess <= 1e-6, "temporal tiles differ from the lossless ones by %g x their bound" % (excess + 1))


@test
def test_temporal_throttled_client(d):
    """max_rate 10 at 30 Hz: every frame follows a gap, so every frame is keyframe
    tiles, all decodable in order by one decoder."""
    async def run():
        a, hello = await connect(d)
        fast, _ = await connect(d)
        await subscribe(fast, temporal=True)   # keeps the layer predicted for others
        await subscribe(a, temporal=True, max_rate=10)
        fa = await collect(a, 3.0)
        await a.close()
        await fast.close()
        return hello, fa
    hello, fa = asyncio.run(run())
    seqs = [parse_header(m)["seq"] for m in fa]
    print("    throttled: %d frames, seq steps %r, codecs %r" % (len(fa), sorted(set(y - x for x, y in zip(seqs, seqs[1:]))), codecs(fa)))
    check(len(fa) >= 15, "throttled client got only %d frames" % len(fa))
    check(CODEC_TEMPORAL not in codecs(fa), "a throttled client got predicted tiles")
    check_stream(d, hello["params"], fa, 0.01, "throttled stream")


@test
def test_temporal_slow_reader():
    """A client that reads slowly (small socket buffers, pauses) skips frames
    (latest frame wins); every frame it does get decodes in order. Pinned
    (adapt: false): the ladder would serve it coarser instead (tests/links)."""
    d = td.Daemon("--send-buffer-kb", "16")

    async def run():
        fast, hello = await connect(d)
        await subscribe(fast, temporal=True)
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 16384)
        sock.connect(("127.0.0.1", d.port))
        a, _ = await connect(d, max_queue=1, read_limit=1 << 14, sock=sock)
        await subscribe(a, temporal=True)
        frames = []
        t0 = time.time()
        while time.time() - t0 < 3:                  # slow: ~8 frames/s of 30
            m = await asyncio.wait_for(a.recv(), 10)
            if isinstance(m, bytes):
                frames.append(m)
            await asyncio.sleep(0.12)
        frames += await collect(a, 1.5)              # then read at full speed: predicted again
        await a.close()
        await fast.close()
        return hello, frames
    try:
        hello, frames = asyncio.run(run())
        seqs = [parse_header(m)["seq"] for m in frames]
        gaps = sum(y - x - 1 for x, y in zip(seqs, seqs[1:]))
        print("    slow reader: %d frames, %d skipped, codecs %r, waited for keyframes %d"
              % (len(frames), gaps, codecs(frames), d.metric("oceand_frames_waited_keyframe_total")))
        check(gaps >= 10, "the slow client skipped only %d frames: not slow enough to test" % gaps)
        check_stream(d, hello["params"], frames, 0.01, "slow reader's stream")
        check(codecs(frames[-5:]).get(CODEC_TEMPORAL, 0) > 0, "caught up, but no predicted tiles")
        rc, _ = d.stop()
        check(rc == 0, "exit code %r" % rc)
    finally:
        d.kill()


@test
def test_intra_only_and_resubscribe(d):
    """A client that does not ask for temporal never gets codec 3, even while
    another client streams the same layer predicted; a temporal client that
    changes its subscription (LOD) gets keyframes at once, decodable."""
    async def run():
        t, hello = await connect(d)
        i, _ = await connect(d)
        await subscribe(t, temporal=True)
        sub = await subscribe(i, fields=["height", "dx", "dz"])
        check(sub["temporal"] is False, "temporal is off unless asked for: %r" % sub)
        fi = await collect(i, 1.5)
        ft = await collect(t, 0.5)
        await subscribe(t, lod=1)                 # temporal stays on (omitted members keep their value)
        ft2 = await collect(t, 1.0)
        await t.close()
        await i.close()
        return hello, fi, ft, ft2
    hello, fi, ft, ft2 = asyncio.run(run())
    print("    intra client %r; temporal %r; after lod 1 %r" % (codecs(fi), codecs(ft), codecs(ft2)))
    check(CODEC_TEMPORAL not in codecs(fi), "an intra-only client got predicted tiles")
    check_stream(d, hello["params"], fi, 0.01, "intra stream")
    check(CODEC_TEMPORAL not in codecs(ft2[:1]) and {t["lod"] for t in tiles(ft2[0])} == {1},
          "first frame after resubscribing is not keyframes at the new LOD")
    check_stream(d, hello["params"], ft + ft2, 0.01, "temporal stream across a resubscribe")


@test
def test_temporal_across_resolution_change(d):
    """A change of N resets the streams: the first frame at the new N is all
    keyframes and the stream stays decodable in order."""
    async def run():
        a, hello = await connect(d)
        await subscribe(a, temporal=True)
        f1 = await collect(a, 0.7)
        await a.send(json.dumps({"type": "set", "params": {"resolution": td.BASE_N // 2}}))
        f2 = []
        t0 = time.time()
        while time.time() - t0 < 20 and sum(parse_header(m)["n"] == td.BASE_N // 2 for m in f2) < 15:
            f2 += await collect(a, 0.2)
        await a.close()
        return hello, f1, f2
    hello, f1, f2 = asyncio.run(run())
    old = [m for m in f1 + f2 if parse_header(m)["n"] == td.BASE_N]
    new = [m for m in f2 if parse_header(m)["n"] == td.BASE_N // 2]
    check(len(new) >= 15, "only %d frames at the new N" % len(new))
    check(CODEC_TEMPORAL not in codecs(new[:1]), "the first frame at the new N has predicted tiles")
    check(codecs(new[-5:]).get(CODEC_TEMPORAL, 0) > 0, "no predicted tiles at the new N")
    check_stream(d, hello["params"], old, 0.01, "stream before the change")
    check_stream(d, dict(hello["params"], resolution=td.BASE_N // 2), new, 0.01, "stream after the change")


def tile_grids(b):
    """Per tile (field, tx, tz): (codec, offset, scale, depth); depth = a codec 3 tile's reference count."""
    h = parse_header(b)
    off, out = 48, {}
    for _ in range(h["tile_count"]):
        f, lod, codec, fl, tx, tz, w, hh, bound, o, sc, plen, _r = td.TILE_HDR.unpack_from(b, off)
        depth = b[off + 40] if codec == CODEC_TEMPORAL else 0
        out[(f, tx, tz)] = (codec, o, sc, depth)
        off += 40 + plen
    return out


@test
def test_temporal_sea_changes():
    """Changes of the sea (PROTOCOL.md §5.9, docs/codec.md "Changes of the sea"): a
    wind change keeps the phases, so every tile's chain goes on (same grid) and the
    next tick predicts from the full depth at once; a seed change is a new sea: every
    tile starts a new chain (new grid, depth ramping from 1). One decoder takes the
    whole stream in order, within the bound of the lossless stream at equal seq."""
    d = td.Daemon("--keyframe-interval", "0")      # no periodic keyframes: each grid change is the policy's

    async def run():
        a, hello = await connect(d)
        b, _ = await connect(d)
        await subscribe(a, temporal=True, bound=0.01)
        await subscribe(b, bound=0, fields=["height"])          # lossless reference, height only
        ta = asyncio.ensure_future(collect(a, 2.4))
        tb = asyncio.ensure_future(collect(b, 2.4))
        await asyncio.sleep(0.8)
        await a.send(json.dumps({"type": "set", "params": {"wind_speed": 12}}))
        await asyncio.sleep(0.8)
        await a.send(json.dumps({"type": "set", "params": {"seed": 7}}))
        return hello, await ta, await tb
    try:
        hello, fa, fb = asyncio.run(run())
        versions = sorted({parse_header(m)["params_version"] for m in fa})
        check(len(versions) >= 3, "expected frames of three params versions, got %r" % versions)
        v0, v_wind, v_seed = versions[0], versions[1], versions[2]
        first = {}
        for i, m in enumerate(fa):
            first.setdefault(parse_header(m)["params_version"], i)
        iw, isd = first[v_wind], first[v_seed]
        check(iw > 0 and isd > iw + 1, "frames around the changes missing: %r" % first)
        before_w, at_w, before_s, at_s = (tile_grids(fa[i]) for i in (iw - 1, iw, isd - 1, isd))
        sizes = [len(m) for m in fa]
        print("    %d frames; wind change at frame %d (%.1f kB, before %.1f kB), seed change at %d (%.1f kB); codecs at "
              "the wind change %r, at the seed change %r" % (len(fa), iw, sizes[iw] / 1e3, sizes[iw - 1] / 1e3, isd,
                                                            sizes[isd] / 1e3, codecs(fa[iw:iw + 1]), codecs(fa[isd:isd + 1])))
        # wind: the same grid on every tile before and after (a chain that restarted has a new grid)
        same = [k for k in at_w if before_w.get(k, (0, None, None))[1:3] == at_w[k][1:3]]
        if not (full_detail(fa[iw - 1]) and full_detail(fa[iw])):
            print("    the wind change fell on degraded frames (short of encode time, intra): chains not judged")
        else:
            check(len(same) == len(at_w), "wind change: %d of %d tiles restarted their chain"
                  % (len(at_w) - len(same), len(at_w)))
        sw = [parse_header(m)["seq"] for m in fa]
        if iw + 1 < len(fa) and sw[iw + 1] == sw[iw] + 1 and sw[iw] == sw[iw - 1] + 1 and \
                all(full_detail(m) for m in fa[iw - 1:iw + 2]):
            depths = {v[3] for v in tile_grids(fa[iw + 1]).values()}
            check(depths == {4}, "the tick after a wind change predicts from depth %r, not 4" % depths)
        # seed: every tile a keyframe on a new grid
        check(all(v[0] != CODEC_TEMPORAL for v in at_s.values()), "seed change: predicted tiles %r" % codecs(fa[isd:isd + 1]))
        moved = [k for k in at_s if before_s.get(k, (0, None, None))[1:3] != at_s[k][1:3]]
        check(len(moved) == len(at_s), "seed change: %d of %d tiles kept their grid" % (len(at_s) - len(moved), len(at_s)))
        # every frame decodes in order, within the bound of the lossless stream
        state, lossless, compared, err = oceanproto.DecoderState(), {}, 0, 0.0
        for m in fb:
            f = oceanproto.decode_frame(m)
            lossless[f.seq] = {(t.x, t.z): t.samples for t in f.tiles}
        for m in fa:
            f = oceanproto.decode_frame(m, state)
            ref = lossless.get(f.seq)
            if ref is None:
                continue
            for t in f.tiles:
                if t.field == "height" and (t.x, t.z) in ref and ref[(t.x, t.z)].shape == t.samples.shape:
                    err = max(err, float(np.max(np.abs(t.samples.astype(np.float64) - ref[(t.x, t.z)]))))
            compared += 1
        print("    max error %.5f against the lossless stream (%d frames at equal seq)" % (err, compared))
        check(compared >= 20, "only %d frames at equal seq with the lossless stream" % compared)
        check(err <= 0.01 * (1 + 1e-6), "temporal frames differ from the lossless ones by %g > bound" % err)
        rc, _ = d.stop()
        check(rc == 0, "exit code %r" % rc)
    finally:
        d.kill()


@test
def test_temporal_group_served_intra_at_full_detail():
    """The plan's codec rung: a temporal group whose temporal encode
    does not fit, but whose intra encode does, is served intra at its own LOD
    and full rate, never coarser. Forced without timing by --temporal-budget
    (the temporal samples per tick; the default subscription, 3 n^2, over it
    at N, within it at N/2). The client is told (`degraded`, codec 1, its own
    lod, the full rate), gets decodable codec 1 tiles at lod 0 (a layer with no
    stream this tick: fanout.c sends the intra tiles), /metrics counts the
    group in oceand_intra_groups, not in oceand_degraded_groups. At N/2 the
    group goes back to the temporal codec (told, codec 3) and the frames decode
    in order across the switch; at N again, intra again."""
    n = td.BASE_N
    cap = 3 * (n // 2) ** 2
    d = td.Daemon("--temporal-budget", str(cap))

    async def run():
        a, hello = await connect(d)
        z = [z for z in hello["capacity"]["resolutions"] if z["n"] == n]
        check(z and z[0]["temporal_fields"] <= 2 and z[0]["temporal_fields"] <= z[0]["full_rate_fields"],
              "announced at N=%d with %d temporal samples at most: %r" % (n, cap, z))
        await subscribe(a, temporal=True, bound=0.01)
        g = await recv_json(a, lambda m: m["type"] == "degraded", timeout=10)
        rate = hello["tick_rate"]
        check(g["active"] is True and g["lod"] == 0 and g["subscribed_lod"] == 0 and g["codec"] == 1
              and g["rate"] == rate and g["reason"].startswith("intra codec"), "degraded message: %r" % g)
        fa = await collect(a, 1.5)
        c = codecs(fa)
        check(len(fa) >= 5 and set(c) == {1} and all(full_detail(m) for m in fa),
              "frames of the intra-served group: %d, codecs %r, lods %r" % (len(fa), c, {t["lod"] for m in fa for t in tiles(m)}))
        check(d.metric("oceand_intra_groups") == 1 and d.metric("oceand_degraded_groups") == 0,
              "metrics: intra_groups %r degraded_groups %r" % (d.metric("oceand_intra_groups"), d.metric("oceand_degraded_groups")))
        # N/2: the temporal samples fit; back to the temporal codec after the plan's hold (3 s)
        await a.send(json.dumps({"type": "set", "id": 1, "params": {"resolution": n // 2}}))
        p = await recv_json(a, lambda m: m["type"] == "params", timeout=10)
        half, told = [], None
        t0 = time.time()
        while time.time() - t0 < 25 and not (told and sum(1 for m in half if CODEC_TEMPORAL in codecs([m])) >= 10):
            m = await asyncio.wait_for(a.recv(), 5)
            if isinstance(m, bytes):
                if parse_header(m)["n"] == n // 2:
                    half.append(m)
            elif '"degraded"' in m:
                told = json.loads(m)
        check(told and told["active"] is False and told["codec"] == CODEC_TEMPORAL and told["lod"] == 0,
              "restore message at N/2: %r" % told)
        check(d.metric("oceand_intra_groups") == 0, "intra_groups after the restore")
        # N again: intra again
        await a.send(json.dumps({"type": "set", "id": 2, "params": {"resolution": n}}))
        g2 = await recv_json(a, lambda m: m["type"] == "degraded", timeout=10)
        check(g2["active"] is True and g2["codec"] == 1 and g2["lod"] == 0, "degraded at N again: %r" % g2)
        await a.close()
        return hello, p, fa, half
    try:
        hello, p, fa, half = asyncio.run(run())
        print("    N=%d: %d intra frames; N/2: %d frames, codecs %r" % (n, len(fa), len(half), codecs(half)))
        check_stream(d, hello["params"], fa, 0.01, "intra-served stream")
        check(CODEC_TEMPORAL in codecs(half), "no temporal tiles after the restore")
        check_stream(d, p["params"], half, 0.01, "stream across the switch back to temporal")
        rc, _ = d.stop()
        check(rc == 0, "exit code %r" % rc)
    finally:
        d.kill()


PART = 2  # frame header flags bit 1 (PROTOCOL.md §3.4)


def join_parts(messages):
    """The ticks of a stream of binary messages, the parts of each joined as §3.4
    says (written here from the text, not taken from a library): [(seq, frame)].
    Checks each part's shape on the way."""
    out, held = [], []
    for m in messages:
        h = parse_header(m)
        flags, = struct.unpack_from("<H", m, 38)
        if held:
            h0 = parse_header(held[0])
            check(h["seq"] == h0["seq"], "a part of seq %d follows an unfinished tick %d" % (h["seq"], h0["seq"]))
            check(m[:36] == held[0][:36] and m[40:48] == held[0][40:48],
                  "parts of one tick differ in more than tile_count and flags")
        if flags & PART:
            check(h["tile_count"] >= 1, "a part with no tile")
            held.append(m)
            continue
        parts = held + [m]
        held = []
        whole = bytearray(parts[0][:48])
        struct.pack_into("<HH", whole, 36, sum(parse_header(x)["tile_count"] for x in parts), flags)
        out.append((h["seq"], bytes(whole) + b"".join(x[48:] for x in parts), len(parts)))
    return out


@test
def test_parts_join_to_the_whole_frame(d):
    """subscribe "parts": a client gets a tick's frame in several messages (flags bit
    1 on all but the last, the same header but tile_count); joined, they are byte for
    byte the frame a client without parts gets at that seq (lossless: the same tiles
    for everyone). A temporal client's joined frames decode in order within the bound.
    "parts" must be a bool, and subscribed shows it."""
    async def run():
        a, hello = await connect(d)
        b, _ = await connect(d)
        c, _ = await connect(d)
        sa = await subscribe(a, fields=["height", "dx", "dz"], bound=0, parts=True)
        check(sa.get("parts") is True, "subscribed does not show parts: %r" % sa)
        sb = await subscribe(b, fields=["height", "dx", "dz"], bound=0)
        check("parts" not in sb, "subscribed shows parts to a client that did not ask: %r" % sb)
        await c.send(json.dumps({"type": "subscribe", "id": 4, "parts": 1}))
        e = await recv_json(c, lambda j: j.get("id") == 4)
        check(e["type"] == "error" and e["code"] == "bad_subscription", "parts: 1 accepted: %r" % e)
        await subscribe(c, temporal=True, parts=True)
        fa, fb, fc = await asyncio.gather(collect(a, 2.0), collect(b, 2.0), collect(c, 2.0))
        for w in (a, b, c):
            await w.close()
        return hello, fa, fb, fc
    hello, fa, fb, fc = asyncio.run(run())
    ja, jb = join_parts(fa), join_parts(fb)
    check(all(k == 1 for _, _, k in jb), "a client without parts got a part")
    multi = [k for _, _, k in ja if k > 1]
    check(multi, "no tick came in parts (%d messages, %d ticks)" % (len(fa), len(ja)))
    whole = {seq: f for seq, f, _ in jb}
    same = [(f, whole[seq]) for seq, f, _ in ja if seq in whole]
    print("    lossless: %d messages = %d ticks (up to %d parts), %d seqs in common" % (len(fa), len(ja), max(multi), len(same)))
    check(len(same) >= 3, "only %d ticks in common between the two clients" % len(same))
    check(all(x == y for x, y in same), "joined parts differ from the whole frame of the same tick")
    jc = join_parts(fc)
    check(len(jc) >= 10, "the temporal client with parts got %d ticks" % len(jc))
    check_stream(d, hello["params"], [f for _, f, _ in jc], 0.01, "temporal stream joined from parts")


if __name__ == "__main__":
    td.TESTS[:] = TESTS
    td.main()

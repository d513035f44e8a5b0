#!/usr/bin/python3
"""What a hostile publisher on the NATS prefix can do to an edge, and what it
must not: a sim and an edge on a nats-server of their own (test_cluster_roles'
Cluster), a viewer at the edge, and a rogue client speaking NATS's text
protocol by hand (no NATS package for Python here; the protocol is a few
lines) that republishes captured layers with other seqs, or publishes params
events and answers the viewers' sets itself.

    /usr/bin/python3 tests/cluster/test_cluster_hostile.py --oceand build/oceand [-k NAME]

Each case fails on a daemon without the defence it names. Prints
"N passed, M failed" last. Part of `make test-hostile`."""
import argparse
import asyncio
import json
import os
import socket
import struct
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import test_cluster_roles as tcr  # noqa: E402
from test_cluster_roles import check, connect, recv_frame, recv_json  # noqa: E402

PREFIX = "oceand"


class RawNats:
    """NATS's client protocol over a plain socket: CONNECT, SUB, PUB, MSG."""

    def __init__(self, url):
        host, port = url.replace("nats://", "").split(":")
        self.s = socket.create_connection((host, int(port)), timeout=5)
        self.buf = b""
        self._line()                                   # INFO {...}
        self.s.sendall(b'CONNECT {"verbose":false,"pedantic":false,"name":"rogue"}\r\nPING\r\n')
        while self._line() != b"PONG":
            pass
        self.sid = 0

    def _line(self):
        while b"\r\n" not in self.buf:
            chunk = self.s.recv(65536)
            if not chunk:
                raise ConnectionError("nats closed")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\r\n", 1)
        return line

    def _take(self, n):
        while len(self.buf) < n + 2:
            chunk = self.s.recv(65536)
            if not chunk:
                raise ConnectionError("nats closed")
            self.buf += chunk
        data, self.buf = self.buf[:n], self.buf[n + 2:]
        return data

    def sub(self, subject):
        """Subscribe, and wait until the server has it (PING answered after the SUB):
        otherwise a message published right after could pass by unseen."""
        self.sid += 1
        self.s.sendall(b"SUB %s %d\r\nPING\r\n" % (subject.encode(), self.sid))
        self.s.settimeout(5)
        while True:
            line = self._line()
            if line == b"PONG":
                return self.sid
            if line == b"PING":
                self.s.sendall(b"PONG\r\n")
            elif line.startswith(b"MSG "):
                self._take(int(line.split()[-1]))   # an earlier subscription's message: not wanted here

    def pub(self, subject, payload, reply=None):
        r = b" " + reply.encode() if reply else b""
        self.s.sendall(b"PUB %s%s %d\r\n%s\r\n" % (subject.encode(), r, len(payload), payload))

    def next_msg(self, timeout=5):
        """(subject, reply or None, payload); PINGs from the server are answered."""
        self.s.settimeout(timeout)
        while True:
            line = self._line()
            if line == b"PING":
                self.s.sendall(b"PONG\r\n")
                continue
            if not line.startswith(b"MSG "):
                continue
            parts = line.split()
            subject, n = parts[1].decode(), int(parts[-1])
            reply = parts[3].decode() if len(parts) == 5 else None
            return subject, reply, self._take(n)

    def close(self):
        self.s.close()


def envelope(kind, body, origin="rogue", by=""):
    """An OCNE envelope (server/cluster/cluster.h), version 2."""
    return (b"OCNE" + struct.pack("<BBBBI", 2, kind, len(origin), len(by), len(body)) + origin.encode()
            + by.encode() + body)


KIND_REPLY, KIND_PARAMS = 3, 4


def with_seq(part, seq):
    """A captured layer part (OCNL) with another seq (u64 at byte 8)."""
    return part[:8] + struct.pack("<Q", seq) + part[16:]


def seq_of(part):
    return struct.unpack_from("<Q", part, 8)[0]


def capture_frame(rogue, layers, timeout=5):
    """The parts of one complete tick of the given layer subjects: {subject: payload}."""
    got = {}
    t_end = time.time() + timeout
    while time.time() < t_end:
        subject, _, payload = rogue.next_msg(timeout)
        if subject not in layers or payload[:4] != b"OCNL":
            continue
        if got and seq_of(payload) != seq_of(next(iter(got.values()))):
            got = {}
        got[subject] = payload
        if len(got) == len(layers):
            return got
    raise tcr.TestFailure("no complete frame of %r captured" % layers)


async def frames_for(ws, seconds):
    """Headers of the frames a viewer gets for a while."""
    out = []
    t_end = time.time() + seconds
    while time.time() < t_end:
        try:
            h, _ = await recv_frame(ws, timeout=max(0.1, t_end - time.time()))
            out.append(h)
        except (asyncio.TimeoutError, tcr.TestFailure):
            break
    return out


WEB_LAYERS = ["%s.frame.0.%s.0.3" % (PREFIX, f) for f in ("height", "dx", "dz")]   # the default subscription


def check_stream_goes_on(frames, real_seq, what):
    check(len(frames) >= 20, "%s: the viewer got %d frames in 2 s" % (what, len(frames)))
    future = [h["seq"] for h in frames if h["seq"] > real_seq + 10 ** 6]
    check(not future, "%s: the viewer got frames from the future: %r" % (what, future[:3]))
    seqs = [h["seq"] for h in frames]
    check(seqs == sorted(seqs), "%s: seq went back at the viewer" % what)


TESTS = []


def test(fn):
    TESTS.append(fn)
    return fn


@test
@tcr.with_cluster(edges=1)
def rogue_future_layer(c):
    """One layer part republished with seq + 2e9 used to become the frame the
    edge collected: every real layer behind it was dropped as stale and no
    viewer got another frame. Then three complete future frames: every
    viewer that got one never took another (seq must grow)."""
    rogue = RawNats(c.nats.url)
    try:
        async def run():
            ws, _ = await connect(c.edges[0])
            await recv_frame(ws, timeout=10)
            rogue.sub("%s.frame.>" % PREFIX)
            parts = capture_frame(rogue, WEB_LAYERS)
            real = seq_of(next(iter(parts.values())))
            rogue.pub(WEB_LAYERS[0], with_seq(parts[WEB_LAYERS[0]], real + 2 * 10 ** 9))
            frames = await frames_for(ws, 2.0)
            check_stream_goes_on(frames, real, "one future layer")
            for k in range(3):                  # three complete future frames
                for subj in WEB_LAYERS:
                    rogue.pub(subj, with_seq(parts[subj], real + 2 * 10 ** 9 + 10 + k))
            frames = await frames_for(ws, 2.0)
            check_stream_goes_on(frames, real, "three complete future frames")
            ws2, _ = await connect(c.edges[0])      # and a viewer who joins afterwards
            h, _ = await recv_frame(ws2, timeout=5)
            check(h["seq"] < real + 10 ** 6, "a new viewer got a future frame: %r" % h["seq"])
            await ws.close()
            await ws2.close()
        asyncio.run(run())
        refused = c.edges[0].metric("oceand_cluster_layers_refused_total")
        check(refused >= 1, "the edge counted no refused layer (%r)" % refused)
    finally:
        rogue.close()


@test
@tcr.with_cluster(edges=1)
def rogue_text_to_viewers(c):
    """Text from NATS went to viewers unchecked: a params event whose by_name
    holds the bytes FF FE (a browser must fail a socket that receives a text
    frame that is not UTF-8), a rogue's answer to a viewer's set, and 600 KB
    params events that closed every viewer (1008). None reaches a viewer now;
    the viewer stays connected and gets `unavailable` for its set instead."""
    rogue = RawNats(c.nats.url)
    try:
        async def run():
            ws, _ = await connect(c.edges[0])
            await recv_frame(ws, timeout=10)
            bad = (b'{"type":"params","params_version":99,"params":{"wind_speed":12},"changed":["wind_speed"],'
                   b'"by":"c9","by_name":"\xff\xfe"}')
            rogue.pub("%s.params" % PREFIX, envelope(KIND_PARAMS, bad))
            big = json.dumps({"type": "params", "params_version": 98, "params": {"wind_speed": 11},
                              "changed": ["wind_speed"], "by": "c9", "pad": "x" * 600000}).encode()
            for _ in range(3):
                rogue.pub("%s.params" % PREFIX, envelope(KIND_PARAMS, big))
            # A rogue that answers every set (the sim answers too: the first answer wins).
            rogue.sub("%s.ctl" % PREFIX)
            await ws.send(json.dumps({"type": "set", "id": 7, "params": {"wind_speed": 9}}))
            t_end = time.time() + 5
            while time.time() < t_end:
                subject, reply, payload = rogue.next_msg(5)
                if subject == "%s.ctl" % PREFIX and reply:
                    rogue.pub(reply, envelope(KIND_REPLY, b"\xff\xfe not json <script>"))
                    break
            ans = await recv_json(ws, lambda m: m.get("id") == 7, timeout=10)
            check(ans["type"] in ("params", "error"), "answer to the set: %r" % ans)
            if ans["type"] == "error":
                check(ans["code"] == "unavailable", "a bad answer relayed as %r" % ans)
            frames = await frames_for(ws, 1.5)
            check(len(frames) >= 10, "the viewer got %d frames after the rogue's messages" % len(frames))
            check(ws.close_code is None, "the viewer was closed (%r)" % ws.close_code)
            await ws.close()
        asyncio.run(run())
    finally:
        rogue.close()


@test
@tcr.with_cluster(edges=1)
def edge_refused_set_keeps_no_name(c):
    """A set refused at the edge ({wind_speed: 99, name: "Refused"}, out of
    range) used to leave its name on the client, and the next valid set
    carried by_name "Refused". Neither changes when a set is refused."""
    async def run():
        ws, _ = await connect(c.edges[0])
        await ws.send(json.dumps({"type": "set", "id": 1, "params": {"wind_speed": 99}, "name": "Refused"}))
        e = await recv_json(ws, lambda m: m.get("id") == 1, timeout=10)
        check(e["type"] == "error" and e["code"] == "out_of_range", "refused set: %r" % e)
        await ws.send(json.dumps({"type": "set", "id": 2, "params": {"wind_speed": 11}}))
        p = await recv_json(ws, lambda m: m.get("id") == 2, timeout=10)
        check(p["type"] == "params", "valid set: %r" % p)
        check(p.get("by_name", "") != "Refused", "the refused set's name was kept: %r" % p.get("by_name"))
        await ws.close()
    asyncio.run(run())


KIND_DEMAND = 6
LAYER_HEADER = 200          # OCNL v3: 64 + 128-byte key bitmap + u64 epoch
SHARED, INTRA = 0x02, 0x04  # layer_flags (server/cluster/cluster.h, "Sections")


def with_byte(part, offset, value):
    return part[:offset] + bytes([value]) + part[offset + 1:]


def with_epoch(part, epoch):
    return part[:LAYER_HEADER - 8] + struct.pack("<Q", epoch) + part[LAYER_HEADER:]


@test
@tcr.with_cluster(edges=1)
def rogue_temporal_layers_and_demand(c):
    """The temporal stream through an edge against a rogue publisher: copies of the sim's
    temporal layer parts under another epoch (a second "sim") a few ticks ahead, parts
    with a need of 9, with the intra-section flag alone, with epoch 0; demand bodies with
    a streamed or wished-for layer outside the demanded keys, of a wrong length, and a
    rogue edge wishing for keyframes of the viewer's layers. The malformed ones are refused
    (counted); the viewer, temporal, keeps getting frames and decodes every one in order
    with one decoder state (never a predicted tile without its references), codec 3
    among them. (A copy under another epoch holds the real sim's tiles, so it cannot show
    a wrong decode: test_two_sims_never_mix_chains in test_cluster_roles.py does.)"""
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "proto", "examples"))
    import oceanproto
    rogue = RawNats(c.nats.url)
    try:
        async def run():
            ws, _ = await connect(c.edges[0])
            await ws.send('{"type":"subscribe","id":1,"temporal":true,"adapt":false}')
            await recv_json(ws, lambda m: m["type"] in ("subscribed", "error"))
            state = oceanproto.DecoderState()
            for _ in range(10):
                _, b = await recv_frame(ws, timeout=10)
                oceanproto.decode_frame(b, state)
            rogue.sub("%s.frame.>" % PREFIX)
            parts = capture_frame(rogue, WEB_LAYERS)
            check(all(p[41] & SHARED for p in parts.values()), "the sim publishes no shared tiles: flags %r"
                  % [p[41] for p in parts.values()])
            real = seq_of(next(iter(parts.values())))
            epoch = struct.unpack_from("<Q", next(iter(parts.values())), LAYER_HEADER - 8)[0]
            bad0 = c.edges[0].metric("oceand_cluster_bad_messages_total")
            for subj in WEB_LAYERS:
                p = parts[subj]
                rogue.pub(subj, with_byte(p, 63, 9))                          # need 9
                rogue.pub(subj, with_byte(with_byte(p, 41, INTRA), 63, 0))    # intra-section flag alone
                rogue.pub(subj, with_epoch(p, 0))                             # epoch 0
            for subj in WEB_LAYERS:                                           # a second "sim", ahead
                rogue.pub(subj, with_seq(with_epoch(parts[subj], epoch ^ 0x5a5a), real + 8))
            keys = bytearray(128)
            keys[0] = 0x01
            outside = bytearray(128)
            outside[1] = 0x01
            ttl = struct.pack("<I", 3000)
            rogue.pub("%s.demand" % PREFIX, envelope(KIND_DEMAND, ttl + bytes(keys) + bytes(outside) + bytes(128)))
            rogue.pub("%s.demand" % PREFIX, envelope(KIND_DEMAND, ttl + bytes(keys) + bytes(128) + bytes(outside)))
            rogue.pub("%s.demand" % PREFIX, envelope(KIND_DEMAND, ttl + bytes(keys) * 2))
            ours = bytearray(128)                                             # the viewer's 3 layers
            for k in (3, 28, 53):
                ours[k >> 3] |= 1 << (k & 7)
            rogue.pub("%s.demand" % PREFIX, envelope(KIND_DEMAND, ttl + bytes(ours) + bytes(128) + bytes(ours)))
            codecs, n, seqs = set(), 0, []
            t_end = time.time() + 4   # (decoding every frame in Python: a loaded machine reads fewer)
            while time.time() < t_end:
                h, b = await recv_frame(ws, timeout=5)
                f = oceanproto.decode_frame(b, state)   # raises ProtocolError `reference` on a bad chain
                codecs |= {t.codec for t in f.tiles}
                seqs.append(h["seq"])
                n += 1
            check(n >= 10, "the viewer got %d frames in 4 s" % n)
            check(seqs == sorted(seqs), "seq went back at the viewer")
            check(3 in codecs, "no predicted tile after the rogue's messages: %r" % codecs)
            bad = c.edges[0].metric("oceand_cluster_bad_messages_total") - bad0
            check(bad >= 9, "the edge refused %r of the 9 malformed parts" % bad)
            sbad = c.sim.metric("oceand_cluster_bad_messages_total")
            check(sbad >= 3, "the sim refused %r of the 3 malformed demands" % sbad)
            await ws.close()
        asyncio.run(run())
    finally:
        rogue.close()


@test
@tcr.with_cluster(edges=1)
def another_sims_frames_ahead(c):
    """Complete frames of another sim process (a sim of another sea on another prefix,
    its temporal layers captured at steady state: predicted tiles whose references are
    that sim's frames) republished on this prefix for the next 10 seqs of the real
    stream, so they reach the edge before the real sim's (and its catch-up ring); 5 times. The edge hands them out as
    another epoch: its temporal viewer's history is cleared, so it is never sent one of
    those predicted tiles against the real sim's frames, and it decodes every frame in
    order with one decoder state (an edge that kept the history across the epoch sends
    it one: the decoder meets `reference`)."""
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "proto", "examples"))
    import oceanproto
    other = "other"
    sf = os.path.join(c.tmp, "other-state.json")
    with open(sf, "w") as f:
        json.dump({"params": {"wind_speed": 21, "seed": 99}, "params_version": 1, "sim_time": 40}, f)
    c.node("other", "--role", "sim", "--nats", c.nats.url, "--nats-prefix", other, state_file=sf)
    rogue = RawNats(c.nats.url)
    try:
        async def run():
            # the other sim streams the viewer's 3 layers (a demand of its own, no keyframe wish)
            ours = bytearray(128)
            for k in (3, 28, 53):
                ours[k >> 3] |= 1 << (k & 7)
            demand = envelope(KIND_DEMAND, struct.pack("<I", 3000) + bytes(ours) + bytes(ours) + bytes(128),
                              origin="rogue-edge")
            rogue.sub("%s.frame.>" % other)
            other_layers = [s.replace(PREFIX + ".", other + ".", 1) for s in WEB_LAYERS]
            t_end = time.time() + 20
            parts = None
            while time.time() < t_end:
                rogue.pub("%s.demand" % other, demand)
                try:
                    got = capture_frame(rogue, other_layers, timeout=2)
                except (tcr.TestFailure, OSError):
                    continue
                if all(p[41] == SHARED and p[63] >= 1 for p in got.values()):   # predicted, no keyframe section
                    parts = got
                    break
            check(parts is not None, "no steady-state temporal frame captured from the other sim")
            ws, _ = await connect(c.edges[0])
            await ws.send('{"type":"subscribe","id":1,"temporal":true,"adapt":false}')
            await recv_json(ws, lambda m: m["type"] in ("subscribed", "error"))
            state = oceanproto.DecoderState()
            last = None
            for _ in range(200):   # until the viewer holds its chain (predicted tiles)
                h, b = await recv_frame(ws, timeout=10)
                f = oceanproto.decode_frame(b, state)
                last = h["seq"]
                if any(t.codec == 3 for t in f.tiles):
                    break
            check(last is not None, "no frame")
            rogue.sub("%s.frame.>" % PREFIX)          # where the real stream is now (the viewer may lag)
            chains0 = c.edges[0].metric("oceand_cluster_new_chains_total")
            n = 0
            for _ in range(5):   # 5 rounds: each meets the viewer holding a chain at some point of it
                real = seq_of(next(iter(capture_frame(rogue, WEB_LAYERS).values())))
                for k in range(1, 11):
                    for subj, osubj in zip(WEB_LAYERS, other_layers):
                        rogue.pub(subj, with_seq(parts[osubj], real + k))
                t_end = time.time() + 1.0
                while time.time() < t_end:
                    try:
                        _, b = await recv_frame(ws, timeout=max(0.1, t_end - time.time()))
                    except (asyncio.TimeoutError, tcr.TestFailure):
                        break
                    oceanproto.decode_frame(b, state)   # ProtocolError `reference`: the other sim's chain
                    n += 1
            check(n >= 10, "the viewer got %d frames in 5 s with the other sim's" % n)
            check(c.edges[0].metric("oceand_cluster_new_chains_total") > chains0,
                  "the edge did not take the other sim's frames as another epoch")
            await ws.close()
        asyncio.run(run())
    finally:
        rogue.close()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", required=True)
    ap.add_argument("-k", default="")
    args = ap.parse_args()
    tcr.ARGS = args
    tcr.td.ARGS = args
    return tcr.run_tests(TESTS, args.k)


if __name__ == "__main__":
    sys.exit(main())

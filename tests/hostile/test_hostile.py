#!/usr/bin/python3
"""Hostile-client battery and churn test for oceand (docs/reliability.md), against a real
daemon on 127.0.0.1.

    /usr/bin/python3 tests/hostile/test_hostile.py --oceand build/oceand [-k NAME] [--json]

Every case starts its own daemon (temp state file, free port, small N unless
the case needs real frames) and a well-behaved observer client in another
process, runs one attack with bounded loops, then checks:
  - the coded error / close code the attacker got (case specific),
  - the parameters are unchanged (or, for the set flood, only rate-limited sets applied),
  - the observer kept >= 99% of the frames of its window (by frame seq) and stayed connected,
  - the daemon is alive, its RSS is flat, and it exits 0 on SIGTERM afterwards.
Tick overruns (from /metrics) are reported, not asserted: the machine is shared.
With --json each case also prints its figures as one JSON line on stdout (the
human log then goes to stderr). Prints "N passed, M failed" last.
"""
import argparse
import json
import math
import os
import re
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import zlib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harness import (OP_BIN, OP_CONT, OP_TEXT, CaseFailure, Daemon, Observer, Reader, check,  # noqa: E402
                     handshake_request, raw_ws, read_http_response, rst_close, send_quiet, wait_until,
                     ws_frame, ws_header)

ARGS = None
OUT = sys.stdout           # human log (stderr under --json)
MIN_SHARE = 0.99           # observer frames kept during an attack
MIN_WINDOW = 4.0           # seconds: the shortest observer window
RSS_SLACK_KB = 2048        # "flat": RSS after the attack minus before
LIBERAL = ("--control-rate", "10000", "--control-burst", "10000", "--control-budget", "1e7")   # cases that send many messages


def log(*a):
    print(*a, file=OUT, flush=True)


# ---------------------------------------------------------------- helpers

def attacker(d, **kw):
    s, _ = raw_ws(d.port, **kw)
    r = Reader(s)
    check(r.until(lambda r: any(t.get("type") == "hello" for t in r.texts), 5), "attacker got no hello")
    return s, r


def ask(s, r, text, timeout=5):
    """Send one text message; return the next error/params/pong/subscribed reply (or None)."""
    n0 = len(r.texts)
    check(send_quiet(s, ws_frame(OP_TEXT, text)), "connection closed while sending %r" % text[:60])
    want = ("error", "params", "pong", "subscribed")
    r.until(lambda r: any(t.get("type") in want for t in r.texts[n0:]), timeout)
    for t in r.texts[n0:]:
        if t.get("type") in want:
            return t
    return None


def expect_errors(d, cases, **kw):
    """cases: [(text, code, param or None)]. One connection; every reply checked."""
    s, r = attacker(d, **kw)
    bad = []
    for text, code, param in cases:
        m = ask(s, r, text)
        shown = text if len(text) < 70 else text[:50] + "...(%d bytes)" % len(text)
        if m is None:
            bad.append("%s: no reply%s" % (shown, " (connection closed, code %r)" % r.close_code if r.eof else ""))
        elif m.get("type") != "error" or m.get("code") != code:
            bad.append("%s: got %s, want error %s" % (shown, json.dumps(m)[:160], code))
        elif param and m.get("param") != param:
            bad.append("%s: param %r, want %r" % (shown, m.get("param"), param))
    s.close()
    check(not bad, "; ".join(bad))
    return len(cases)


def fresh_hello(d):
    s, r = attacker(d)
    h = [t for t in r.texts if t.get("type") == "hello"][0]
    s.close()
    return h


def stream_message(s, r, total, opcode=OP_TEXT, chunk=16384, frag=None, deadline_s=15, byte=b"x"):
    """Send one message of `total` payload bytes (one frame, or fragments of
    `frag` bytes), pumping the reader between chunks. Returns payload bytes
    handed to the kernel when the server's close frame / EOF arrived (None if
    it never did), and the total sent."""
    s.setblocking(False)
    sent = 0
    at_close = None
    deadline = time.time() + deadline_s
    pending = b""

    def parts():
        if frag is None:
            yield ws_header(opcode, total, key=b"\0\0\0\0")
            left = total
            while left > 0:
                n = min(chunk, left)
                yield byte * n
                left -= n
        else:
            left, first = total, True
            while left > 0:
                n = min(frag, left)
                left -= n
                yield ws_header(opcode if first else OP_CONT, n, fin=left == 0, key=b"\0\0\0\0") + byte * n
                first = False

    it = parts()
    while time.time() < deadline:
        r.pump(0)
        if (r.close_code is not None or r.eof) and at_close is None:
            at_close = sent
            break
        if not pending:
            pending = next(it, b"")
            if not pending:
                break
        try:
            k = s.send(pending)
            sent += k
            pending = pending[k:]
        except BlockingIOError:
            r.pump(0.02)
        except (BrokenPipeError, ConnectionResetError, OSError):
            break               # the server hung up: what it sent before is still to be read
    s.setblocking(True)
    if at_close is None:
        r.until(lambda r: r.close_code is not None, 5)
        if r.close_code is not None or r.eof:
            at_close = sent
            r.eof = True
    return at_close, sent


# ---------------------------------------------------------------- cases

CASES = []


def case(resolution=64, args=(), changes_params=False, rss_slack_kb=RSS_SLACK_KB, settle_clients=True, web=False,
         nofile=None, log_pipe=False, fsize=None):
    def wrap(fn):
        fn.opts = dict(resolution=resolution, args=args, changes_params=changes_params,
                       rss_slack_kb=rss_slack_kb, settle_clients=settle_clients, web=web, nofile=nofile,
                       log_pipe=log_pipe, fsize=fsize)
        CASES.append(fn)
        return fn
    return wrap


@case(args=LIBERAL)
def malformed_json(d, fig):
    cases = [(t, "bad_json", None) for t in (
        "{", "}", '{"type":', '{"type":"set","params":{"wind_speed":20}', "not json at all", "",
        " ", "{'type':'set'}", '{"type":"set",,}', '{"type" "ping"}', "[1,2,3]", '"a string"', "42",
        "null", "true", '{"type":"ping",}', '{"type":"set","params":{"wind_speed":2O}}',
        '{"type":"set","params":{"wind_speed":0x14}}', '{"type":"set","params":{"wind_speed":+20}}')]
    fig["messages"] = expect_errors(d, cases)
    # Invalid UTF-8 in a text frame is a protocol error for WebSocket (close 1007).
    s, r = attacker(d)
    send_quiet(s, ws_frame(OP_TEXT, b'{"type":"ping","x":"\xff\xfe"}'))
    r.until(lambda r: r.close_code is not None, 5)
    fig["invalid_utf8_close"] = r.close_code
    s.close()
    check(r.close_code == 1007, "invalid UTF-8: close code %r, want 1007" % r.close_code)


@case(args=LIBERAL)
def json_leniency(d, fig):
    """Text that is not JSON (RFC 8259) but that a lenient parser accepts:
    trailing data, control bytes as whitespace, invalid \\u escapes, and a
    NUL inside a string (which would truncate names: "set\\u0000x" acting as
    "set"). Each must be rejected, and nothing applied. A \\u0000 anywhere is
    rejected as a whole (bad_json, D1 fix), before any name is looked at."""
    fig["messages"] = expect_errors(d, [
        ('{"type":"ping","id":1} trailing', "bad_json", None),
        ('{"type":"set","id":2,"params":{"wind_speed":21}}}', "bad_json", None),
        ('{"type":"set","id":3,"params":{"wind_speed":22}} {"type":"set"}', "bad_json", None),
        ('{"type":"ping"\x00,"id":4}', "bad_json", None),
        ('{"type":"ping","id":5,"x":"\\uZZZZ"}', "bad_json", None),
        ('{"type":"set\\u0000x","id":6,"params":{"wind_speed":23}}', "bad_json", None),
        ('{"type":"set","id":7,"params":{"spectrum":"phillips\\u0000junk"}}', "bad_json", None),
        ('{"type":"set","id":8,"params":{"wind_speed\\u0000x":13}}', "bad_json", None),
        ('{"type":"subscribe","id":9,"fields":["height\\u0000junk"]}', "bad_json", None),
    ])


@case(args=LIBERAL)
def nested_json(d, fig):
    n = 60000                 # fits under the 64 KiB message limit
    cases = [
        ("[" * n, "bad_json", None),
        ("{\"a\":" * (n // 5), "bad_json", None),
        ('{"type":"set","params":{"wind_speed":' + "[" * n, "bad_json", None),
        ('{"type":"set","params":{"wind_speed":' + "[" * 2000 + "]" * 2000 + "}}", "bad_json", None),
        ('{"type":"set","params":{"wind_speed":' + "[" * 500 + "1" + "]" * 500 + "}}", "bad_type", "wind_speed"),
        ('{"type":"ping","id":' + "{" * 20000 + "}", "bad_json", None),
    ]
    fig["messages"] = expect_errors(d, cases)
    # 100000 '[' is larger than the message limit: too_large and close 1009.
    s, r = attacker(d)
    send_quiet(s, ws_frame(OP_TEXT, "[" * 100000))
    r.until(lambda r: r.close_code is not None, 5)
    fig["nested_100k_close"] = r.close_code
    codes = [e.get("code") for e in r.errors()]
    s.close()
    check(r.close_code == 1009, "100000 '[': close code %r, want 1009" % r.close_code)
    check(codes in ([], ["too_large"]), "100000 '[': errors %r" % codes)


@case(args=LIBERAL)
def wrong_types(d, fig):
    S = '{"type":"set","id":%d,"params":{%s}}'
    sets = [("wind_speed", '"fast"'), ("wind_speed", "null"), ("wind_speed", "[]"), ("wind_speed", "{}"),
            ("wind_speed", "true"), ("wind_speed", "[20]"), ("spectrum", "3"), ("spectrum", "null"),
            ("spectrum", '["phillips"]'), ("paused", '"true"'), ("paused", "1"), ("paused", "null"),
            ("resolution", '"256"'), ("resolution", "128.5"), ("seed", "1.5"), ("seed", '"7"'),
            ("transform", "false")]
    cases = [(S % (i, '"%s":%s' % (p, v)), "bad_type", p) for i, (p, v) in enumerate(sets)]
    cases += [
        ('{"type":"set","id":100,"params":"wind_speed=20"}', "bad_message", None),
        ('{"type":"set","id":101,"params":null}', "bad_message", None),
        ('{"type":"set","id":102,"params":[["wind_speed",20]]}', "bad_message", None),
        ('{"type":5,"id":103}', "bad_message", None),
        ('{"type":null}', "bad_message", None),
        ('{"type":["set"],"params":{"wind_speed":20}}', "bad_message", None),
        ('{"type":"set","id":{"x":1},"params":{"wind_speed":20}}', "bad_message", None),
        ('{"type":"set","id":[1],"params":{"wind_speed":20}}', "bad_message", None),
        ('{"type":"set","id":105,"params":{"wind_speed":20,"amplitude":"big"}}', "bad_type", "amplitude"),
        ('{"type":"subscribe","id":106,"fields":"height"}', "bad_subscription", None),
        ('{"type":"subscribe","id":107,"fields":[1,2]}', "bad_subscription", None),
        ('{"type":"subscribe","id":108,"lod":"0"}', "bad_subscription", None),
        ('{"type":"subscribe","id":109,"lod":1.5}', "bad_subscription", None),
        ('{"type":"subscribe","id":110,"tiles":"some"}', "bad_subscription", None),
        ('{"type":"subscribe","id":111,"tiles":[[1]]}', "bad_subscription", None),
        ('{"type":"subscribe","id":112,"tiles":[[-1,0]]}', "bad_subscription", None),
        ('{"type":"subscribe","id":113,"tiles":[[70000,0]]}', "bad_subscription", None),
        ('{"type":"subscribe","id":114,"tiles":[]}', "bad_subscription", None),
        ('{"type":"subscribe","id":115,"max_rate":-1}', "bad_subscription", None),
        ('{"type":"subscribe","id":116,"max_rate":0}', "bad_subscription", None),
        ('{"type":"subscribe","id":117,"max_rate":"fast"}', "bad_subscription", None),
        ('{"type":"subscribe","id":118,"bound":"0.01"}', "bad_subscription", None),
    ]
    fig["messages"] = expect_errors(d, cases)


@case(args=LIBERAL)
def nan_inf_huge_numbers(d, fig):
    S = '{"type":"set","id":%d,"params":{%s}}'
    cases = [
        (S % (1, '"wind_speed":NaN'), "bad_json", None),
        (S % (2, '"wind_speed":Infinity'), "bad_json", None),
        (S % (3, '"wind_speed":-Infinity'), "bad_json", None),
        (S % (4, '"wind_speed":nan'), "bad_json", None),
        (S % (5, '"wind_speed":1e400'), "bad_type", "wind_speed"),
        (S % (6, '"wind_speed":-1e400'), "bad_type", "wind_speed"),
        (S % (7, '"wind_speed":1e308'), "out_of_range", "wind_speed"),
        (S % (8, '"seed":1e300'), "out_of_range", "seed"),
        (S % (9, '"seed":-1'), "out_of_range", "seed"),
        (S % (10, '"resolution":1e400'), "bad_type", "resolution"),
        (S % (11, '"time_scale":1e400'), "bad_type", "time_scale"),
        (S % (12, '"wind_speed":20,"amplitude":1e400'), "bad_type", "amplitude"),
        (S % (13, '"patch_size":' + "9" * 400), "bad_type", "patch_size"),
        (S % (14, '"loop_period":-1e400'), "bad_type", "loop_period"),
        ('{"type":"subscribe","id":15,"max_rate":1e400}', "bad_subscription", None),
        ('{"type":"subscribe","id":16,"lod":1e400}', "bad_subscription", None),
    ]
    fig["messages"] = expect_errors(d, cases)
    # A ping echoing a huge t must still produce valid JSON.
    s, r = attacker(d)
    m = ask(s, r, '{"type":"ping","id":1,"t":1e400}')
    s.close()
    check(m is not None and m.get("type") == "pong", "ping with t=1e400: reply %r" % (m,))


@case(args=LIBERAL)
def resolution_1m(d, fig):
    S = '{"type":"set","id":%d,"params":{"resolution":%s}}'
    rss0 = d.rss_kb()
    cases = [(S % (1, 1 << 20), "out_of_range", "resolution"), (S % (2, 1 << 31), "out_of_range", "resolution"),
             (S % (3, 1 << 63), "out_of_range", "resolution"), (S % (4, 4096), "out_of_range", "resolution"),
             (S % (5, 0), "out_of_range", "resolution"), (S % (6, -64), "out_of_range", "resolution"),
             (S % (7, 2048), "invalid", "resolution"),
             ('{"type":"set","id":8,"params":{"resolution":1048576,"transform":"dft"}}', "out_of_range", "resolution")]
    fig["messages"] = expect_errors(d, cases)
    fig["rss_jump_kb"] = d.rss_kb() - rss0


@case(args=LIBERAL)
def unknown_types(d, fig):
    types = ["fly", "", "SET", "Set", "set ", "__proto__", "constructor", "hello", "params", "error",
             "subscribed", "pong", "x" * 1000, "s\u00e9t"]
    cases = [(json.dumps({"type": t, "id": i, "params": {"wind_speed": 20}}), "unknown_type", None)
             for i, t in enumerate(types)]
    fig["messages"] = expect_errors(d, cases)


@case(args=LIBERAL)
def message_10mb(d, fig):
    """One 10 MB text message: close 1009 at the first overflow, not after 10 MB."""
    total = 10 << 20
    s, r = attacker(d)
    at_close, sent = stream_message(s, r, total)
    s.close()
    fig["close_code"] = r.close_code
    fig["sent_kb_at_close"] = None if at_close is None else at_close // 1024
    fig["too_large_error"] = [e.get("code") for e in r.errors()] == ["too_large"]
    log("    10 MB message: close %r after %s kB handed to the kernel (of %d kB)"
        % (r.close_code, fig["sent_kb_at_close"], total // 1024))
    fig["eof"], fig["reset"] = r.eof, r.reset
    check(r.close_code == 1009, "close code %r, want 1009 (connection ended: %s, by RST: %s, errors %r)"
          % (r.close_code, r.eof, r.reset, [e.get("code") for e in r.errors()]))
    check(at_close is not None and at_close < total // 2, "close only after %s of %d bytes" % (at_close, total))
    # Same size in 1 KiB fragments.
    s, r = attacker(d)
    at_close2, _ = stream_message(s, r, total, frag=1024)
    s.close()
    fig["fragmented_close_code"] = r.close_code
    fig["fragmented_sent_kb_at_close"] = None if at_close2 is None else at_close2 // 1024
    check(r.close_code == 1009, "fragmented: close code %r, want 1009" % r.close_code)
    check(at_close2 is not None and at_close2 < total // 2, "fragmented: close only after %s bytes" % at_close2)
    check(d.metric("oceand_closed_too_large_total") == 2, "closed_too_large metric")


@case(args=LIBERAL)
def deflate_bomb(d, fig):
    """permessage-deflate must be refused; a compressed (RSV1) message must not be inflated."""
    s = socket.create_connection(("127.0.0.1", d.port), timeout=5)
    s.sendall(handshake_request(d.port, "Sec-WebSocket-Extensions: permessage-deflate; client_max_window_bits\r\n"))
    resp = read_http_response(s)
    check(b" 101 " in resp.split(b"\r\n")[0], "handshake with a deflate offer refused: %r" % resp[:100])
    negotiated = b"sec-websocket-extensions" in resp.lower()
    fig["deflate_negotiated"] = negotiated
    check(not negotiated, "server accepted permessage-deflate: %r" % resp)
    # 64 MiB of JSON-ish text deflates to ~64 KiB; send it with RSV1 set anyway.
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    bomb = c.compress(b'{"type":"ping","pad":"') + c.compress(b"a" * (64 << 20)) + c.compress(b'"}')
    bomb += c.flush(zlib.Z_SYNC_FLUSH)[:-4]
    fig["bomb_bytes"] = len(bomb)
    r = Reader(s)
    r.until(lambda r: any(t.get("type") == "hello" for t in r.texts), 5)
    rss0 = d.rss_kb()
    send_quiet(s, ws_frame(OP_TEXT, bomb[:60000], rsv1=True))
    r.until(lambda r: r.close_code is not None, 5)
    fig["close_code"] = r.close_code
    fig["rss_jump_kb"] = d.rss_kb() - rss0
    s.close()
    log("    deflate offer refused; RSV1 bomb of %d bytes (64 MiB inflated): close %r, eof %s"
        % (len(bomb), r.close_code, r.eof))
    check(r.close_code is not None or r.eof, "RSV1 message without the extension did not end the connection")
    check(r.close_code in (None, 1002), "close code %r, want 1002 (protocol error)" % r.close_code)


@case(args=LIBERAL)
def binary_on_control(d, fig):
    s, r = attacker(d)
    for i in range(20):
        send_quiet(s, ws_frame(OP_BIN, bytes([i]) * (i * 100 + 1)))
    r.until(lambda r: len(r.errors()) >= 20, 5)
    codes = [e.get("code") for e in r.errors()]
    fig["errors_for_20"] = len(codes)
    check(len(codes) == 20 and set(codes) == {"bad_message"}, "20 binary messages: errors %r" % codes)
    # The connection is still usable for JSON afterwards.
    m = ask(s, r, '{"type":"ping","id":7}')
    check(m and m.get("type") == "pong", "ping after binary: %r" % (m,))
    s.close()
    # A 10 MB binary message: --max-message applies to binary data too (D2):
    # too_large and close 1009 at the first overflow, never buffered.
    total = 10 << 20
    for frag in (None, 1024):
        s, r = attacker(d)
        rss0 = d.rss_kb()
        at_close, sent = stream_message(s, r, total, opcode=OP_BIN, byte=b"\xa5", frag=frag)
        r.until(lambda r: len(r.errors()) >= 1, 3)
        key = "big_binary" if frag is None else "big_binary_fragmented"
        fig[key + "_close"] = r.close_code
        fig[key + "_sent_kb_at_close"] = None if at_close is None else at_close // 1024
        fig[key + "_rss_jump_kb"] = d.rss_kb() - rss0
        codes = [e.get("code") for e in r.errors()]
        s.close()
        log("    10 MB binary%s: errors %r, close %r after %s kB handed to the kernel, RSS +%d kB"
            % ("" if frag is None else " in 1 KiB fragments", codes, r.close_code, fig[key + "_sent_kb_at_close"],
               fig[key + "_rss_jump_kb"]))
        check("too_large" in codes and set(codes) <= {"bad_message", "too_large"}, "10 MB binary: errors %r" % codes)
        check(r.close_code == 1009, "10 MB binary: close code %r, want 1009" % r.close_code)
        check(at_close is not None and at_close < total // 2, "10 MB binary: close only after %s bytes" % at_close)
        check(fig[key + "_rss_jump_kb"] < 4096, "RSS grew %d kB on a 10 MB binary message" % fig[key + "_rss_jump_kb"])


@case()   # daemon defaults: 20 messages/s, burst 40
def binary_flood(d, fig):
    """200 binary messages at once with the default rate limit: each costs the
    daemon an error reply, so they should count against the control budget."""
    s, r = attacker(d)
    for i in range(200):
        send_quiet(s, ws_frame(OP_BIN, b"\x00" * 16))
    r.until(lambda r: len(r.errors()) >= 200 or r.eof, 5)
    codes = [e.get("code") for e in r.errors()]
    s.close()
    fig.update(sent=200, bad_message=codes.count("bad_message"), rate_limited=codes.count("rate_limited"),
               replies=len(codes))
    log("    200 binary messages at once: %d bad_message, %d rate_limited"
        % (codes.count("bad_message"), codes.count("rate_limited")))
    check(codes.count("bad_message") >= 1, "no bad_message for binary data")
    check(codes.count("bad_message") <= 40 + 5,
          "%d bad_message replies to 200 binary messages: binary data bypasses the control rate limit (burst 40)"
          % codes.count("bad_message"))
    check(codes.count("rate_limited") >= 1, "no rate_limited reply to 200 binary messages (burst 40)")


@case(args=LIBERAL)
def tile_amplification(d, fig):
    """One 8 KB subscribe listing tile [0,0] 1024 times, all 6 fields, lossless,
    then read as fast as possible: the subscription must be normalised (no
    duplicate tiles), not turned into ~100 MB frames."""
    s, r = attacker(d)
    sub = json.dumps({"type": "subscribe", "id": 1, "fields": ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"],
                      "bound": 0, "tiles": [[0, 0]] * 1024})
    m = ask(s, r, sub)
    check(m is not None, "no reply to the subscribe")
    tiles = (m.get("subscription") or {}).get("tiles")
    fig["reply"] = m.get("code") or m.get("type")
    fig["tiles_in_subscription"] = len(tiles) if isinstance(tiles, list) else tiles
    # Read greedily for 3 s (bounded), in a thread, and count what arrives.
    got = [0]
    stop = time.time() + 3

    def drain():
        s.settimeout(0.5)
        while time.time() < stop:
            try:
                k = len(s.recv(1 << 20))
            except socket.timeout:
                continue
            except OSError:
                break
            if not k:
                break
            got[0] += k
    m0 = d.metrics()
    t = threading.Thread(target=drain)
    t.start()
    t.join()
    m1 = d.metrics()
    s.close()
    sent_mb = (m1["oceand_bytes_sent_total"] - m0["oceand_bytes_sent_total"]) / 1e6
    fig.update(received_mb_3s=round(got[0] / 1e6, 1), daemon_sent_mb_3s=round(sent_mb, 1))
    log("    subscribe with 1024 copies of one tile: %s with %s tiles; the attacker received %.0f MB in 3 s"
        " (the daemon sent %.0f MB)" % (fig["reply"], fig["tiles_in_subscription"], got[0] / 1e6, sent_mb))
    if m.get("type") == "subscribed":
        check(isinstance(tiles, list) and len(tiles) == len({tuple(t) for t in tiles}),
              "duplicate tiles kept: %d entries for %d distinct tiles"
              % (len(tiles), len({tuple(t) for t in tiles})))
    else:
        check(m.get("code") == "bad_subscription", "reply %r" % m)


@case(changes_params=True)   # daemon defaults: 20 messages/s, burst 40
def set_flood(d, fig):
    """1000 `set`s in one second from one client: most get rate_limited."""
    s, r = attacker(d)
    changes0 = d.metric("oceand_param_changes_total")
    t0 = time.time()
    for i in range(1000):
        # 10.0, 10.5, ... distinct consecutive values, so every accepted set is a change
        send_quiet(s, ws_frame(OP_TEXT, '{"type":"set","id":%d,"params":{"wind_speed":%g}}' % (i, 10 + (i % 40) * 0.5)))
        r.pump(0)
        target = t0 + (i + 1) / 1000.0
        while time.time() < target:
            r.pump(max(0.0, target - time.time()))
    elapsed = time.time() - t0
    r.until(lambda r: sum(1 for t in r.texts if t.get("type") in ("params", "error")) >= 1000, 10)
    mine = [t for t in r.texts if t.get("type") == "params" and "id" in t]
    errs = [e.get("code") for e in r.errors()]
    limited = errs.count("rate_limited")
    s.close()
    time.sleep(0.3)
    changes = d.metric("oceand_param_changes_total") - changes0
    allowed = 40 + 20 * elapsed + 2
    fig.update(sent=1000, flood_seconds=round(elapsed, 2), accepted=len(mine), rate_limited=limited,
               other_errors=len(errs) - limited, applied=changes, allowed_max=round(allowed))
    log("    1000 sets in %.2f s: %d accepted, %d rate_limited, %d other errors, %d changes applied"
        % (elapsed, len(mine), limited, len(errs) - limited, changes))
    check(limited > 0, "no rate_limited error")
    check(len(mine) + limited + (len(errs) - limited) == 1000, "not every set was answered")
    check(len(errs) == limited, "unexpected errors %r" % sorted(set(errs)))
    check(len(mine) <= allowed, "%d sets accepted, bucket allows %d" % (len(mine), allowed))
    check(changes <= len(mine), "%d changes applied for %d accepted sets" % (changes, len(mine)))
    # The sea holds the last accepted value.
    last = max(mine, key=lambda t: t["params_version"]) if mine else None
    if last:
        h = fresh_hello(d)
        check(h["params"] == last["params"], "params after the flood differ from the last accepted set")


def burst(d, count, max_accept):
    """Open `count` connections at once and handshake on all; returns the sockets and the figures."""
    socks = []
    for _ in range(count):
        s = socket.socket()
        s.setblocking(False)
        s.connect_ex(("127.0.0.1", d.port))
        socks.append(s)
    req = handshake_request(d.port)
    pending = {s: b"" for s in socks}
    done = {}
    sent = set()
    deadline = time.time() + 20
    while pending and time.time() < deadline:
        # One blocking select for both directions: the attacker must not burn
        # a core of this 2-core machine spinning, or it measures itself.
        rl, w, _ = select.select(list(pending), [s for s in pending if s not in sent], [], 0.05)
        for s in w:
            try:
                if s.send(req) == len(req):
                    sent.add(s)
            except OSError:
                done[s] = pending.pop(s)
        for s in rl:
            if s not in pending:
                continue
            try:
                data = s.recv(4096)
            except (ConnectionError, OSError):
                data = b""
            pending[s] += data
            if not data or b"\r\n\r\n" in pending[s]:
                done[s] = pending.pop(s)
    accepted = sum(1 for resp in done.values() if b" 101 " in resp.split(b"\r\n")[0])
    return socks, dict(opened=count, accepted=accepted, refused=len(done) - accepted, unanswered=len(pending))


@case(args=("--max-clients", "100"), rss_slack_kb=8192)
def connections_500(d, fig):
    """500 connections at once against --max-clients 100 (the observer holds one slot), four times.
    A leak grows RSS on every burst; the allocator's warm-up grows it once, in whichever burst
    first needs it (seen: +1.3 MB in burst 1 on some runs, in burst 2 on a loaded CI machine).
    So the check is on the median growth between bursts, and a bound on the total."""
    rss = []
    for rnd in range(4):
        socks, f = burst(d, 500, 99)
        gauge = d.metric("oceand_clients")
        log("    burst %d: 500 at once: %d accepted, %d refused, %d unanswered; clients gauge %g"
            % (rnd + 1, f["accepted"], f["refused"], f["unanswered"], gauge))
        fig.update({"burst%d_%s" % (rnd + 1, k): v for k, v in f.items()})
        try:
            check(f["unanswered"] == 0, "%d connections got no handshake answer in 20 s" % f["unanswered"])
            check(f["accepted"] == 99, "%d accepted, want 99 (max 100, observer holds one)" % f["accepted"])
            check(gauge == 100, "clients gauge %g, want 100" % gauge)
            time.sleep(1.5)   # 99 connected clients that never read; the observer streams on
        finally:
            for s in socks:
                s.close()
        check(wait_until(lambda: d.metric("oceand_clients") == 1, 15),
              "clients not cleaned up: %g" % d.metric("oceand_clients"))
        time.sleep(0.3)
        rss.append(d.rss_kb())
        if rnd == 0:
            warmed_up(fig, rss[0])   # the first burst is the allocator's warm-up
    growth = [b - a for a, b in zip(rss, rss[1:])]
    fig["rss_growth_second_burst_kb"] = growth[0]
    fig["rss_growth_median_kb"] = sorted(growth)[1]
    log("    RSS after each burst: %s kB; growth between bursts %s kB" % (rss, growth))
    check(sorted(growth)[1] < 512,
          "RSS grew on most bursts (%s kB): a leak per connection, not the allocator's warm-up" % growth)
    check(rss[-1] - rss[0] < 2048, "RSS grew %d kB from the first burst to the fourth" % (rss[-1] - rss[0]))
    s, r = attacker(d)   # room again
    s.close()


@case(args=LIBERAL + ("--control-token", "s3cret-token"))
def viewer_without_token(d, fig):
    """With --control-token an anonymous client is a viewer: every way of steering is forbidden."""
    S = '{"type":"set","id":%d,"params":{"wind_speed":25}%s}'
    s, r = attacker(d)
    hello = [t for t in r.texts if t.get("type") == "hello"][0]
    s.close()
    fig["role"] = hello.get("role")
    check(hello.get("role") == "viewer", "role %r with a control token set, want viewer" % hello.get("role"))
    fig["messages"] = expect_errors(d, [
        (S % (1, ""), "forbidden", None),
        (S % (2, ',"token":"wrong"'), "forbidden", None),
        (S % (3, ',"token":""'), "forbidden", None),
        (S % (5, ',"token":"S3CRET-TOKEN"'), "forbidden", None),
        (S % (6, ',"token":"s3cret-toke"'), "forbidden", None),
        ('{"type":"pause","id":7}', "forbidden", None),
        ('{"type":"resume","id":8}', "forbidden", None),
        ('{"type":"set","id":9,"params":{"paused":true}}', "forbidden", None),
        ('{"type":"set","id":10,"params":{"resolution":1048576}}', "forbidden", None),
    ])
    # Viewers may still subscribe and ping.
    s, r = attacker(d)
    m = ask(s, r, '{"type":"subscribe","id":1,"fields":["height"]}')
    s.close()
    check(m and m.get("type") == "subscribed", "viewer subscribe: %r" % (m,))


def http_raw(port, request, limit=1 << 20, timeout=5):
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    try:
        s.sendall(request)
        out = b""
        while len(out) < limit:
            try:
                c = s.recv(65536)
            except (socket.timeout, ConnectionError):
                break
            if not c:
                break
            out += c
        return out
    finally:
        s.close()


@case(web=True)
def http_hostile(d, fig):
    """The HTTP side of the port: path traversal, oversized headers, a /metrics flood."""
    leaks = []
    for path in ("/../../../../../../etc/passwd", "/%2e%2e/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
                 "/..%2f..%2f..%2f..%2fetc%2fpasswd", "//etc/passwd", "/index.html/../../../../etc/passwd"):
        out = http_raw(d.port, ("GET %s HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n" % path).encode())
        status = out.split(b"\r\n", 1)[0].decode(errors="replace")
        if b"root:" in out:
            leaks.append(path)
        fig.setdefault("traversal_status", []).append(status[9:12])
    check(not leaks, "/etc/passwd served for %s" % leaks)
    big = http_raw(d.port, b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * (256 * 1024) + b"\r\n\r\n")
    fig["huge_header_reply"] = big.split(b"\r\n", 1)[0].decode(errors="replace")[:40] or "closed"
    n_ok = 0
    for _ in range(200):
        try:
            d.get("/metrics", timeout=5)
            n_ok += 1
        except Exception:
            pass
    fig["metrics_answered"] = n_ok
    log("    traversal statuses %s; 256 KiB header: %r; /metrics answered %d of 200"
        % (fig["traversal_status"], fig["huge_header_reply"], n_ok))
    check(n_ok == 200, "/metrics answered %d of 200" % n_ok)


@case(resolution=256, rss_slack_kb=4096)
def never_read(d, fig):
    """20 clients that connect and never read, at N=256 (real frames), for 6 s."""
    drops0 = d.metric('oceand_frames_dropped_total{reason="slow_client"}')
    stalled = [raw_ws(d.port, rcvbuf=4096)[0] for _ in range(20)]
    time.sleep(1.5)
    # RSS at three moments: queued frames would grow it in both halves; the allocator's
    # one-time step (~1.3 MB, seen failing connections_500 on CI) in one half at most.
    rss = [d.rss_kb()]
    for _ in range(2):
        time.sleep(2.25)
        rss.append(d.rss_kb())
    rss_a, rss_b = rss[0], rss[-1]
    halves = [rss[1] - rss[0], rss[2] - rss[1]]
    drops = d.metric('oceand_frames_dropped_total{reason="slow_client"}') - drops0
    fig.update(stalled=20, rss_during_growth_kb=rss_b - rss_a, frames_skipped=drops)
    log("    20 stalled clients: RSS %d -> %d kB over 4.5 s (halves %+d, %+d), %d frames skipped"
        % (rss_a, rss_b, halves[0], halves[1], drops))
    for s in stalled:
        s.close()
    check(min(halves) < 512, "RSS grew in both halves while clients were stalled: %+d, %+d kB" % tuple(halves))
    check(rss_b - rss_a < 2048, "RSS grew %d kB while clients were stalled" % (rss_b - rss_a))
    check(drops > 20 * 30, "stalled clients skipped only %d frames" % drops)


@case(args=("--ping-interval", "1", "--idle-timeout", "3"))
def half_open(d, fig):
    """TCP without handshake, half a handshake, and handshake-then-silence: all hung up."""
    bare = [socket.create_connection(("127.0.0.1", d.port), timeout=5) for _ in range(50)]
    partial = []
    for _ in range(20):
        s = socket.create_connection(("127.0.0.1", d.port), timeout=5)
        s.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n")
        partial.append(s)
    silent = [raw_ws(d.port)[0] for _ in range(10)]          # read, never send (no pong)
    mute = [raw_ws(d.port, rcvbuf=4096)[0] for _ in range(5)]  # neither read nor send
    t0 = time.time()
    try:
        half_open_watch(d, fig, t0, bare, partial, silent)
    finally:
        for s in bare + partial + silent + mute:
            s.close()


def half_open_watch(d, fig, t0, bare, partial, silent):
    check(d.metric("oceand_clients") == 16, "clients gauge %g, want 16" % d.metric("oceand_clients"))
    s2, _ = raw_ws(d.port)          # a new client still gets in meanwhile
    s2.close()
    readers = [Reader(s) for s in bare + partial + silent]
    closed_at = {}
    deadline = t0 + 25
    while time.time() < deadline and len(closed_at) < len(readers):
        for i, r in enumerate(readers):
            if i not in closed_at:
                r.pump(0)
                if r.eof:
                    closed_at[i] = time.time() - t0
        time.sleep(0.1)
    gauge_ok = wait_until(lambda: d.metric("oceand_clients") == 1, max(0.1, deadline - time.time()))

    def worst(lo, hi):
        t = [closed_at.get(i) for i in range(lo, hi)]
        return None if None in t else round(max(t), 1)
    fig.update(no_handshake_closed_s=worst(0, 50), partial_handshake_closed_s=worst(50, 70),
               silent_ws_closed_s=worst(70, 80), still_open=len(readers) - len(closed_at),
               gauge_after=d.metric("oceand_clients"))
    log("    hung up after: no handshake %s s, partial handshake %s s, silent WebSocket %s s; still open %d"
        % (fig["no_handshake_closed_s"], fig["partial_handshake_closed_s"], fig["silent_ws_closed_s"],
           fig["still_open"]))
    check(fig["no_handshake_closed_s"] is not None, "TCP connections without a handshake never hung up")
    check(fig["partial_handshake_closed_s"] is not None, "half-sent handshakes never hung up")
    check(fig["silent_ws_closed_s"] is not None, "silent WebSocket clients never hung up (idle timeout 3 s)")
    check(gauge_ok, "silent / non-reading clients still counted: %g" % d.metric("oceand_clients"))


@case(resolution=256)
def vanish_mid_frame(d, fig):
    """Clients that vanish (RST) mid outbound frame, mid inbound message, mid handshake."""
    for _ in range(10):
        s, _ = raw_ws(d.port)
        got = 0
        while got < 6000:
            got += len(s.recv(4096))
        rst_close(s)
    for _ in range(10):
        s, r = attacker(d)
        s.sendall(ws_header(OP_TEXT, 1000) + b"x" * 300)
        rst_close(s)
    for _ in range(10):
        s = socket.create_connection(("127.0.0.1", d.port), timeout=5)
        s.sendall(handshake_request(d.port)[:40])
        rst_close(s)
    ok = wait_until(lambda: d.metric("oceand_clients") == 1, 10)
    fig["gauge_after"] = d.metric("oceand_clients")
    check(ok, "vanished clients still counted: %g" % d.metric("oceand_clients"))


@case(resolution=256, args=("--send-buffer-kb", "16"))
def half_close_full_buffer(d, fig):
    """Clients that read nothing until the daemon's socket buffers are full (lws then keeps
    the unsent tail of a write) and then half-close (FIN, their socket kept open): each is
    hung up, and the lws thread goes on serving. lws 4.1 spun on such a connection for ever,
    reading its end again and again without polling (server/net/rx_guard.c): no frame, no
    answer, no shutdown (an edge of the cluster suite was killed by the 3 s alarm)."""
    socks = [raw_ws(d.port, rcvbuf=4096)[0] for _ in range(5)]
    time.sleep(1.5)                                   # frames fill both sides' buffers
    for s in socks:
        s.shutdown(socket.SHUT_WR)
    t0 = time.time()
    hung_up = []
    for s in socks:                                   # what the daemon still sends, then its close
        s.settimeout(max(0.1, t0 + 5 - time.time()))
        try:
            while s.recv(1 << 16):
                pass
            hung_up.append(round(time.time() - t0, 2))
        except OSError:                               # timeout, or a reset: not a clean close
            pass
        finally:
            s.close()
    gauge_ok = wait_until(lambda: d.metric("oceand_clients") == 1, 5)
    fig.update(half_closed=len(socks), hung_up=len(hung_up), hung_up_within_s=max(hung_up, default=None),
               gauge_after=d.metric("oceand_clients"))
    log("    %d half-closed clients with full buffers: %d hung up (within %s s); clients gauge %g"
        % (len(socks), len(hung_up), fig["hung_up_within_s"], fig["gauge_after"]))
    check(len(hung_up) == len(socks), "%d of %d half-closed clients never hung up" % (len(socks) - len(hung_up),
                                                                                      len(socks)))
    check(gauge_ok, "half-closed clients still counted: %g" % d.metric("oceand_clients"))


@case()   # RSS_SLACK_KB from after the warm-up: the total its rounds allow (2 MB), so both checks agree
def churn(d, fig):
    """1000 connect/subscribe/disconnect cycles in four rounds after a warm-up: a leak grows
    RSS every round (so at least two of the four rounds must grow < 256 kB: 1 kB a cycle),
    the allocator's one-time step one round at most (total < 2 MB)."""
    subs = ['{"type":"subscribe","id":1,"fields":["height"],"lod":1,"bound":0.05}',
            '{"type":"subscribe","id":1,"fields":["height","dx","dz","jacobian"],"bound":0}',
            '{"type":"subscribe","id":1,"fields":["slope_x","slope_z"],"lod":2,"tiles":[[0,0]],"max_rate":10}',
            '{"type":"subscribe","id":1,"bound":0.001}']
    errors = []

    def cycle(i):
        s, r = attacker(d)
        m = ask(s, r, subs[i % len(subs)])
        if not m or m.get("type") != "subscribed":
            errors.append("cycle %d: %r" % (i, m))
        if i % 3 == 0:
            send_quiet(s, ws_frame(8, b"\x03\xe8"))    # polite close
            s.close()
        elif i % 3 == 1:
            s.close()
        else:
            rst_close(s)

    def run(lo, hi, workers=4):
        def worker(k):
            for i in range(lo + k, hi, workers):
                if len(errors) < 5:
                    cycle(i)
        ts = [threading.Thread(target=worker, args=(k,)) for k in range(workers)]
        for t in ts:
            t.start()
        for t in ts:
            t.join()

    def settled_rss():
        wait_until(lambda: d.metric("oceand_clients") == 1, 10)
        time.sleep(0.5)
        return d.rss_kb()

    run(0, 100)                     # warm-up: allocator arenas, lws pools
    rss, fds_a = [settled_rss()], d.fds()
    warmed_up(fig, rss[0])
    secs = 0.0
    for k in range(4):
        t1 = time.time()
        run(100 + 250 * k, 350 + 250 * k)
        secs += time.time() - t1
        rss.append(settled_rss())
    fds_b = d.fds()
    rss_a, rss_b = rss[0], rss[-1]
    rounds = [b - a for a, b in zip(rss, rss[1:])]
    fig.update(cycles=1000, cycles_seconds=round(secs, 1), rss_after_warmup_kb=rss_a, rss_after_cycles_kb=rss_b,
               churn_rss_growth_kb=rss_b - rss_a, fd_growth=fds_b - fds_a)
    log("    1000 cycles in %.1f s: RSS %d -> %d kB (%+d; rounds of 250: %s), fds %+d"
        % (secs, rss_a, rss_b, rss_b - rss_a, rounds, fds_b - fds_a))
    check(not errors, "; ".join(errors[:3]))
    check(sorted(rounds)[1] < 256, "RSS grew on most rounds of 250 cycles (%s kB): a leak per cycle" % rounds)
    check(rss_b - rss_a < 2048, "RSS grew %d kB over 1000 cycles" % (rss_b - rss_a))
    check(fds_b - fds_a <= 0, "%d file descriptors leaked" % (fds_b - fds_a))


# ---------------------------------------------------------------- Host, handshake, reply bytes, descriptors, masking, web root

def http_status(port, request, timeout=5):
    """The status line's code of the answer to one raw request ('' if closed first)."""
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    try:
        s.sendall(request)
        head = read_http_response(s, timeout)
    finally:
        s.close()
    parts = head.split(b"\r\n", 1)[0].split()
    return parts[1].decode() if len(parts) > 1 else ""


def upgrade_status(port, host=None, origin=None, version="13", method="GET", extra=""):
    h = "%s / HTTP/1.1\r\nHost: %s\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n" \
        "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Protocol: oceand.v1\r\n" \
        % (method, host or "127.0.0.1:%d" % port)
    if version is not None:
        h += "Sec-WebSocket-Version: %s\r\n" % version
    if origin is not None:
        h += "Origin: %s\r\n" % origin
    return http_status(port, (h + extra + "\r\n").encode())


@case()
def dns_rebinding(d, fig):
    """Defect 1: a foreign name resolving to 127.0.0.1 (DNS rebinding) with a
    matching Origin must not get a WebSocket, nor HTTP answers; the names the
    daemon is bound to still work."""
    p = d.port
    evil = ["evil.example:%d" % p, "evil.example", "127.0.0.1.evil.example:%d" % p, "localhost.evil.example",
            "EVIL.example:%d" % p, "[::1]evil:%d" % p, "localhost:%d@evil.example" % p, "127.0.0.1:%dx" % p,
            "", "localhost:", ":%d" % p]
    got = {h: upgrade_status(p, host=h or " ", origin="http://%s" % h) for h in evil}
    got_http = {h: http_status(p, ("GET /healthz HTTP/1.1\r\nHost: %s\r\n\r\n" % h).encode()) for h in evil[:4]}
    ours = {h: upgrade_status(p, host=h, origin="http://%s" % h)
            for h in ("127.0.0.1:%d" % p, "localhost:%d" % p, "LOCALHOST:%d" % p, "localhost.:%d" % p, "[::1]:%d" % p)}
    ours_http = http_status(p, ("GET /healthz HTTP/1.1\r\nHost: localhost:%d\r\n\r\n" % p).encode())
    fig.update(foreign_upgrade=sorted(set(got.values())), foreign_http=sorted(set(got_http.values())),
               own_upgrade=sorted(set(ours.values())), own_http=ours_http)
    log("    foreign Host: upgrade %s, HTTP %s; our names: upgrade %s, HTTP %s"
        % (fig["foreign_upgrade"], fig["foreign_http"], fig["own_upgrade"], ours_http))
    check(all(v != "101" for v in got.values()), "foreign Host upgraded: %r" % {h: v for h, v in got.items() if v == "101"})
    check(all(v == "421" for k, v in got.items() if k), "foreign Host upgrade not 421: %r" % got)
    check(all(v == "421" for v in got_http.values()), "foreign Host HTTP not 421: %r" % got_http)
    check(all(v == "101" for v in ours.values()), "our own names refused: %r" % ours)
    check(ours_http == "200", "/healthz with Host localhost: %r" % ours_http)
    check(d.metric('oceand_clients_refused_total{reason="host"}') >= len(evil) - 1, "host refusals not counted")
    check(d.metric('oceand_http_refused_total{reason="host"}') >= 4, "HTTP host refusals not counted")


@case(args=("--server-name", "ocean.example.org,Other.Example"))
def server_name_option(d, fig):
    """Defect 1: --server-name adds names; anything else stays refused."""
    p = d.port
    got = {h: upgrade_status(p, host=h, origin="http://" + h)
           for h in ("ocean.example.org:%d" % p, "other.example", "ocean.example.org.evil:%d" % p, "example.org")}
    fig["statuses"] = got
    log("    --server-name: %r" % got)
    check(got["ocean.example.org:%d" % p] == "101" and got["other.example"] == "101", "listed names refused: %r" % got)
    check(got["ocean.example.org.evil:%d" % p] == "421" and got["example.org"] == "421", "unlisted names: %r" % got)


@case()
def handshake_rules(d, fig):
    """Minor: only GET with Sec-WebSocket-Version 13 opens a WebSocket (RFC 6455
    §4.2.2: 426 with the version we speak); an empty Origin is a foreign one."""
    p = d.port
    got = {"version 8": upgrade_status(p, version="8"), "version 99": upgrade_status(p, version="99"),
           "no version": upgrade_status(p, version=None), "version 13,8": upgrade_status(p, version="13, 8"),
           "POST": upgrade_status(p, method="POST", extra="Content-Length: 0\r\n"),
           "empty Origin": upgrade_status(p, origin=""), "good": upgrade_status(p)}
    fig["statuses"] = got
    log("    handshakes: %r" % got)
    check(got["version 8"] == "426" and got["version 99"] == "426" and got["version 13,8"] == "426",
          "other versions: %r" % got)
    check(got["no version"] == "400", "no version: %r" % got["no version"])
    check(got["POST"] == "405", "POST upgrade: %r" % got["POST"])
    check(got["empty Origin"] != "101", "empty Origin accepted")
    check(got["good"] == "101", "a good handshake refused: %r" % got["good"])
    # A refused upgrade is answered over HTTP (lws answers it as HTTP/1.0 and then
    # closes); what follows on the connection is never taken for WebSocket frames.
    unmasked0 = d.metric('oceand_clients_closed_total{reason="unmasked"}')
    s = socket.create_connection(("127.0.0.1", p), timeout=5)
    s.sendall(handshake_request(p).replace(b"Version: 13", b"Version: 8"))
    time.sleep(0.3)
    s.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    out = b""
    deadline = time.time() + 5
    closed = False
    while time.time() < deadline and b'"status":"ok"' not in out:
        try:
            c = s.recv(4096)
        except socket.timeout:
            break
        except OSError:
            c = b""
        if not c:
            closed = True
            break
        out += c
    s.close()
    fig["after_426"] = "healthz answered" if b'"status":"ok"' in out else "closed" if closed else "silent"
    check(out.startswith(b"HTTP/1.0 426") or out.startswith(b"HTTP/1.1 426"), "426 expected first: %r" % out[:60])
    check(fig["after_426"] != "silent", "connection neither answered nor closed after a 426: %r" % out[-200:])
    check(d.metric('oceand_clients_closed_total{reason="unmasked"}') == unmasked0,
          "an HTTP request after a refused upgrade was taken for an unmasked frame")


@case(resolution=64, rss_slack_kb=16384)
def reply_queue_bytes(d, fig):
    """Defect 3: 16 clients that never read, each sending 300 pings with a
    60 kB id (default limits): the replies they do not
    read are bounded in bytes per client (--output-limit-kb, 1 MiB)."""
    rss0 = d.rss_kb()
    big = '{"type":"ping","id":"%s"}' % ("i" * 60000)
    frame = ws_frame(OP_TEXT, big)
    socks = []
    for _ in range(16):
        s, _ = raw_ws(d.port, rcvbuf=4096)
        s.setblocking(False)
        socks.append([s, 300 * len(frame), 0])
    deadline = time.time() + 20
    while time.time() < deadline and any(x[2] < x[1] for x in socks):
        _, w, _ = select.select([], [x[0] for x in socks if x[2] < x[1]], [], 0.2)
        for x in socks:
            if x[0] in w:
                try:
                    off = x[2] % len(frame)
                    x[2] += x[0].send(frame[off:])
                except BlockingIOError:
                    pass
                except OSError:
                    x[2] = x[1]          # closed by the daemon
    time.sleep(1.0)
    rss1 = d.rss_kb()
    for x in socks:
        x[0].close()
    fig.update(clients=16, rss_growth_under_attack_kb=rss1 - rss0,
               closed_output_limit=d.metrics().get('oceand_clients_closed_total{reason="output_limit"}', 0))
    log("    16 non-reading clients x 300 pings with 60 kB ids: RSS %+d kB, %d closed at the output limit"
        % (rss1 - rss0, fig["closed_output_limit"]))
    # 16 x (1 MiB queue + 64 KiB message being read) plus slack; without the byte cap it grew by about +100 MB
    check(rss1 - rss0 < 16 * 1088 + 6144, "RSS grew %d kB with 16 non-reading clients" % (rss1 - rss0))


@case(args=LIBERAL + ("--output-limit-kb", "32", "--send-buffer-kb", "16"))
def output_limit_close(d, fig):
    """Defect 3: a client over --output-limit-kb of unread replies is closed
    with 1008 and counted in /metrics; the others are untouched."""
    socks = []
    for _ in range(8):
        s, r = attacker(d, rcvbuf=4096)
        socks.append((s, r))
    ping = ws_frame(OP_TEXT, '{"type":"ping","id":"%s"}' % ("p" * 200))
    for s, r in socks:
        s.setblocking(False)
        sent = 0
        for _ in range(1500):
            try:
                s.send(ping)
                sent += 1
            except (BlockingIOError, OSError):
                break
    # Read at once, all together: the close frame follows what is already in flight.
    deadline = time.time() + 15
    while time.time() < deadline and not all(r.close_code is not None or r.eof for _, r in socks):
        for s, r in socks:
            r.pump(0.02)
    codes = [r.close_code if r.close_code is not None else ("eof" if r.eof else None) for _, r in socks]
    for s, r in socks:
        s.close()
    ok = wait_until(lambda: d.metric('oceand_clients_closed_total{reason="output_limit"}') >= 8, 5)
    fig.update(closed_counted=d.metric('oceand_clients_closed_total{reason="output_limit"}'), close_codes=codes)
    log("    8 clients over a 32 KiB reply limit: counted %d, close codes %s"
        % (fig["closed_counted"], sorted(set(map(str, codes)))))
    check(ok, "clients over the output limit not closed/counted: %g" % fig["closed_counted"])
    check(all(c is not None for c in codes), "a client over the limit is still open")
    # The close frame (1008) is sent, but the kernel answers the client's still-unread
    # pings with a TCP reset that can overtake it: how many clients see 1008 rather than
    # EOF depends on timing (all, or none, on a loaded machine). What must hold: every
    # one is closed (above), counted by reason (above), and nothing else comes back.
    check(set(codes) <= {1008, "eof"}, "close codes %r, want 1008 or EOF" % codes)


@case(nofile=96, args=("--max-clients", "500"))
def fd_exhaustion(d, fig):
    """Defect 8: with `ulimit -n 96`, 150 TCP connections held open must not
    make the daemon spin on accept(2): its CPU time over the hold stays small,
    refusals are counted, and a client gets in again afterwards."""
    held = []
    for _ in range(150):
        s = socket.socket()
        s.setblocking(False)
        s.connect_ex(("127.0.0.1", d.port))
        held.append(s)
    time.sleep(0.5)
    cpu0, t0 = d.cpu_s(), time.time()
    time.sleep(3.0)
    cpu = d.cpu_s() - cpu0
    secs = time.time() - t0
    for s in held:
        s.close()
    # /metrics is an HTTP request: it gets a descriptor only after the release.
    check(wait_until(lambda: d.fds() < 60, 5), "descriptors not released: %d" % d.fds())
    refused = d.metrics().get("oceand_connections_refused_total", 0)
    fig.update(held=150, nofile=96, hold_s=round(secs, 1), daemon_cpu_s=round(cpu, 2), refused=refused)
    log("    150 connections held against ulimit -n 96: daemon used %.2f CPU s in %.1f s; %d refused at accept"
        % (cpu, secs, refused))
    check(cpu < 0.1 * secs, "daemon used %.2f CPU s in %.1f s while out of descriptors (accept loop?)" % (cpu, secs))
    check(refused > 0, "no refusal counted in oceand_connections_refused_total")
    s, r = attacker(d)
    s.close()


@case(args=LIBERAL)
def unmasked_frames(d, fig):
    """Defect 9: RFC 6455 §5.1, a client frame without a mask: close 1002,
    the message never handled. As the first frame, after good ones, with a
    16-bit length, as a control frame, and split across two TCP segments."""
    zero = b"\0\0\0\0"
    ping = b'{"type":"ping","id":1}'
    variants = {
        "first": [bytes([0x81, len(ping)]) + ping],
        "after_good": [ws_frame(OP_TEXT, '{"type":"ping","id":0}'), bytes([0x81, len(ping)]) + ping],
        "len16": [bytes([0x81, 126]) + struct.pack("!H", 300) + b'{"type":"ping","id":1,"x":"' + b"a" * 272 + b'"}'],
        "control": [bytes([0x89, 4]) + b"ping"],
        "split": [b"\x81", bytes([len(ping)]) + ping],
        "zero_key_ok": [ws_header(OP_TEXT, len(ping), key=zero) + ping],
    }
    out = {}
    for name, parts in variants.items():
        s, r = attacker(d)
        for part in parts:
            send_quiet(s, part)
            time.sleep(0.05)
        r.until(lambda r: r.close_code is not None or r.eof or any(t.get("type") == "pong" and t.get("id") == 1
                                                                    for t in r.texts), 3)
        pongs = [t.get("id") for t in r.texts if t.get("type") == "pong"]
        out[name] = {"close": r.close_code, "eof": r.eof, "pongs": pongs}
        s.close()
    fig["results"] = out
    log("    unmasked frames: %s" % json.dumps(out))
    for name in ("first", "after_good", "len16", "control", "split"):
        check(out[name]["close"] == 1002, "%s: close %r, want 1002" % (name, out[name]["close"]))
        check(1 not in out[name]["pongs"], "%s: the unmasked message was answered" % name)
    check(out["after_good"]["pongs"] == [0], "the masked ping before it: %r" % out["after_good"]["pongs"])
    check(out["zero_key_ok"]["close"] is None and out["zero_key_ok"]["pongs"] == [1],
          "a masked frame with an all-zero key must work: %r" % out["zero_key_ok"])
    check(d.metric('oceand_clients_closed_total{reason="unmasked"}') == 5, "unmasked closes not counted")


@case(web=True)
def symlink_web_root(d, fig):
    """Minor: a symlink inside the web root (to a file or a directory outside)
    is not followed; ordinary files still are."""
    web = os.path.join(d.tmp, "web")
    secret_dir = os.path.join(d.tmp, "secret")
    os.makedirs(secret_dir)
    with open(os.path.join(secret_dir, "key.txt"), "w") as f:
        f.write("TOP-SECRET-CONTENT")
    os.symlink(os.path.join(secret_dir, "key.txt"), os.path.join(web, "link.txt"))
    os.symlink(secret_dir, os.path.join(web, "dir"))
    os.makedirs(os.path.join(web, "sub"))
    os.symlink(os.path.join(secret_dir, "key.txt"), os.path.join(web, "sub", "index.html"))
    with open(os.path.join(web, "plain.txt"), "w") as f:
        f.write("plain")
    got = {}
    for path in ("/link.txt", "/dir/key.txt", "/sub/", "/plain.txt", "/"):
        out = http_raw(d.port, ("GET %s HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n" % path).encode())
        got[path] = (out.split(b"\r\n", 1)[0].split()[1:2] or [b""])[0].decode(), b"TOP-SECRET" in out
    fig["results"] = got
    log("    symlinks: %r" % got)
    leaks = [p for p, (_, leak) in got.items() if leak]
    check(not leaks, "files outside the web root served through symlinks: %s" % leaks)
    check(got["/plain.txt"][0] == "200" and got["/"][0] == "200", "ordinary files: %r" % got)
    check(d.metric('oceand_http_refused_total{reason="symlink"}') >= 3, "symlink refusals not counted")


# ---------------------------------------------------------------- pings, control frames, churn, pipelining, flapping

@case(args=LIBERAL)
def ws_ping_flood(d, fig):
    """20 000 WebSocket-level pings (opcode 9, 125-byte payloads) from a client
    that never reads: lws answers them below the JSON rate limit, so the
    answers must not pile up in memory."""
    s, r = attacker(d, rcvbuf=4096)
    s.setblocking(False)
    ping = ws_frame(9, b"p" * 125)
    rss0 = d.rss_kb()
    sent = 0
    deadline = time.time() + 8
    buf = ping * 100
    while sent < 20000 and time.time() < deadline:
        try:
            k = s.send(buf)
            sent += k // len(ping)
            if k < len(buf):
                time.sleep(0.01)
        except BlockingIOError:
            time.sleep(0.01)
        except OSError:
            break
    time.sleep(0.5)
    grow = d.rss_kb() - rss0
    s.close()
    fig.update(pings_sent=sent, rss_growth_during_kb=grow)
    log("    %d WebSocket pings from a client that never reads: RSS %+d kB" % (sent, grow))
    check(grow < 2048, "RSS grew %d kB under a ping flood" % grow)


@case(args=LIBERAL)
def interleaved_control(d, fig):
    """Framing corner cases: one JSON message in 2000 fragments with a ping
    between each (legal, one answer); then fragmented control frames, a
    control frame over 125 bytes, a continuation with nothing to continue and
    a new message inside an unfinished one (each a protocol error: 1002)."""
    s, r = attacker(d)
    msg = ('{"type":"ping","id":7,"pad":"%s"}' % ("z" * 31900)).encode()
    parts = [msg[i:i + 16] for i in range(0, len(msg), 16)]
    out = b""
    for i, p in enumerate(parts):
        out += ws_frame(OP_TEXT if i == 0 else OP_CONT, p, fin=i == len(parts) - 1) + ws_frame(9, b"x")
    send_quiet(s, out)
    r.until(lambda r: any(t.get("type") == "pong" for t in r.texts), 10)
    pongs = [t.get("id") for t in r.texts if t.get("type") == "pong"]
    s.close()
    fig["fragments"] = len(parts)
    check(pongs == [7], "fragmented ping with interleaved pings: answers %r" % pongs)
    bad = {
        "fragmented ping": ws_frame(9, b"ab", fin=False) + ws_frame(OP_CONT, b"cd"),
        "ping of 126 bytes": ws_header(9, 126) + b"\0" * 126,
        "lone continuation": ws_frame(OP_CONT, b'{"type":"ping"}'),
        "text inside text": ws_frame(OP_TEXT, b'{"type":', fin=False) + ws_frame(OP_TEXT, b'{"type":"ping"}'),
        "reserved opcode 3": ws_frame(3, b"xx"),
        "close with 1 byte": ws_frame(8, b"\x03"),
    }
    codes = {}
    for name, data in bad.items():
        s, r = attacker(d)
        send_quiet(s, data)
        r.until(lambda r: r.close_code is not None, 3)
        codes[name] = r.close_code if r.close_code is not None else ("eof" if r.eof else None)
        s.close()
    fig["close_codes"] = codes
    log("    %d fragments with interleaved pings: %r; protocol errors: %r" % (len(parts), pongs, codes))
    # lws 4.1 echoes a 1-byte close body as a close without status (1005): closed all the same.
    check(all(c in (1002, "eof") for n, c in codes.items() if n != "close with 1 byte"),
          "protocol errors not closed with 1002: %r" % codes)
    check(codes["close with 1 byte"] is not None, "a close frame with a 1-byte body left the connection open")


@case(args=LIBERAL, resolution=128)
def subscription_churn(d, fig):
    """4 clients each send 1500 subscribes cycling through fields x LOD x
    bound as fast as they can, then vanish: demand must come back to what the
    observer alone asks for (no layer encoded for nobody), memory flat (from
    the end of a warm-up that asks for each combination once)."""
    enc0 = d.metrics()
    time.sleep(1.5)
    enc0b = d.metrics()
    fields = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"]
    bounds = [0, 0.001, 0.01, 0.05]
    errors = []

    def churn(k, batches=15):
        s, r = attacker(d)
        for b in range(batches):   # batches of 100 (under the 256 unread replies a client may have)
            batch = b""
            for i in range(b * 100, b * 100 + 100):
                sub = {"type": "subscribe", "id": i, "fields": fields[:1 + (i + k) % 6], "lod": (i // 6) % 3,
                       "bound": bounds[(i // 18) % 4]}
                batch += ws_frame(OP_TEXT, json.dumps(sub))
            if not send_quiet(s, batch):
                errors.append("client %d closed by the daemon (close %r)" % (k, r.close_code))
                break
            n = b * 100 + 100
            if not r.until(lambda r: sum(1 for t in r.texts if t.get("type") == "subscribed") >= n, 10):
                errors.append("client %d: %d of %d subscribes answered" % (
                    k, sum(1 for t in r.texts if t.get("type") == "subscribed"), n))
                break
        rst_close(s)
    # Warm-up: the same 4 clients, one batch each (every (fields, LOD, bound) of the cycle, 4 at
    # once), so the one-time buffers are made before RSS is judged (it once went +2128 kB of 2048).
    ts = [threading.Thread(target=churn, args=(k, 1)) for k in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    wait_until(lambda: d.metric("oceand_clients") == 1, 10)
    time.sleep(1.0)
    warmed_up(fig, d.rss_kb())
    ts = [threading.Thread(target=churn, args=(k,)) for k in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    wait_until(lambda: d.metric("oceand_clients") == 1, 10)
    time.sleep(1.0)
    m1 = d.metrics()
    time.sleep(2.0)
    m2 = d.metrics()
    # encode time per tick now vs before the churn (only the observer's layer should be encoded)
    def per_tick(a, b):
        n = b["oceand_encode_duration_seconds_count"] - a["oceand_encode_duration_seconds_count"]
        return (b["oceand_encode_duration_seconds_sum"] - a["oceand_encode_duration_seconds_sum"]) / max(1, n)
    fig.update(subscribes=6000, encode_ms_per_tick_before=round(1000 * per_tick(enc0, enc0b), 3),
               encode_ms_per_tick_after=round(1000 * per_tick(m1, m2), 3),
               bytes_per_frame_after=round((m2["oceand_bytes_sent_total"] - m1["oceand_bytes_sent_total"])
                                           / max(1, m2["oceand_frames_sent_total"] - m1["oceand_frames_sent_total"])))
    s, r = attacker(d)
    m = ask(s, r, '{"type":"subscribe","id":1,"fields":["height"]}')
    s.close()
    log("    6000 subscribes from 4 vanishing clients; encode per tick %.3f ms before, %.3f ms after; %d bytes per frame"
        % (fig["encode_ms_per_tick_before"], fig["encode_ms_per_tick_after"], fig["bytes_per_frame_after"]))
    # (encode time per tick is reported, not asserted: timing is the benchmark's business)
    check(not errors, "; ".join(errors[:2]))
    check(m and m.get("type") == "subscribed", "subscribe after the churn: %r" % (m,))
    check(fig["bytes_per_frame_after"] < 2 * (enc0.get("oceand_bytes_sent_total", 1) /
                                              max(1, enc0.get("oceand_frames_sent_total", 1))) + 1024,
          "frames larger after the churn: demand left behind?")


# RSS: the admitted layers are real work (~6 M samples per tick at N = 512: a frame of
# several MB, up to three in flight, the encoders' row buffers), not a leak.
# The budget is fixed here (--encode-budget, 2 M samples per tick: a fifth of what
# the 25 viewers ask for) because the derived one follows the measured encode speed from
# tick to tick, so a check against the figure hello announced raced it on a loaded
# machine. The derived budget is announced and used by default (tests/daemon).
LAYER_FLOOD_BUDGET = 2000000


@case(args=LIBERAL + ("--max-clients", "64", "--encode-budget", str(LAYER_FLOOD_BUDGET)),
      resolution=512, rss_slack_kb=65536)
def layer_flood(d, fig):
    """Many distinct layers against the encode budget: 25 viewers together ask for every
    field x LOD x bound (25 groups of six fields, 150 layers, 10.5 M samples per
    tick) at N = 512. The subscriptions that would push the encode work past the
    budget the daemon announces (capacity.encode_budget) are refused with `busy`
    and change nothing; the admitted layers fit the budget; the observer keeps
    its frames."""
    fields = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"]
    bounds = [0, 0.001, 0.005, 0.01, 0.05]
    n = 512
    clients = [attacker(d) for _ in range(25)]
    hello = [t for t in clients[0][1].texts if t.get("type") == "hello"][0]
    budget = (hello.get("capacity") or {}).get("encode_budget")
    check(budget == LAYER_FLOOD_BUDGET, "hello announces encode budget %r, want %d" % (budget, LAYER_FLOOD_BUDGET))
    default = hello["subscription"]
    # What is encoded already: the observer's (and everyone's) default subscription.
    layers = {(f, default["lod"], default["bound"]) for f in default["fields"]}
    admitted, refused, other = 0, 0, []
    for k, (s, r) in enumerate(clients):
        lod, bound = k // 5, bounds[k % 5]
        m = ask(s, r, json.dumps({"type": "subscribe", "id": "L%d" % k, "fields": fields, "lod": lod, "bound": bound}))
        if m and m.get("type") == "subscribed":
            admitted += 1
            layers |= {(f, lod, bound) for f in fields}
        elif m and m.get("type") == "error" and m.get("code") == "busy" and m.get("id") == "L%d" % k:
            refused += 1
            # changing nothing: the client's subscription is still the default
            again = ask(s, r, json.dumps({"type": "subscribe", "id": "same"}))
            sub = (again or {}).get("subscription") or {}
            if (sub.get("lod"), sub.get("bound"), sub.get("fields")) != (default["lod"], default["bound"], default["fields"]):
                other.append("client %d: subscription changed by a refused subscribe: %r" % (k, sub))
        else:
            other.append("client %d: %r" % (k, m))
    samples = sum((n >> lod) ** 2 for (f, lod, b) in layers)
    time.sleep(2.0)   # the observer streams on while the admitted layers are encoded
    m = d.metrics()
    for s, r in clients:
        s.close()
    fig.update(budget_samples=int(budget), admitted=admitted, refused=refused, layers=len(layers),
               samples_per_tick=samples, refused_metric=m.get("oceand_subscriptions_refused_busy_total"))
    log("    25 viewers x 6 fields at every LOD x bound, N=512: %d admitted (%d layers, %d samples/tick), %d refused"
        " with busy; budget %d samples/tick" % (admitted, len(layers), samples, refused, budget))
    check(not other, "; ".join(other[:3]))
    check(refused > 0, "nothing refused: %d layers (%d samples per tick) admitted" % (len(layers), samples))
    check(samples <= budget, "admitted %d samples per tick, over the announced budget %d" % (samples, budget))
    check(m.get("oceand_subscriptions_refused_busy_total") == refused, "busy refusals in /metrics: %r, want %d"
          % (m.get("oceand_subscriptions_refused_busy_total"), refused))


@case()
def http_pipeline_flood(d, fig):
    """30 keep-alive connections each pipeline 400 GET /metrics and never read:
    one answer in flight per connection, memory flat, the stream unharmed."""
    req = b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 400
    socks = []
    rss0 = d.rss_kb()
    for _ in range(30):
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.connect(("127.0.0.1", d.port))
        s.setblocking(False)
        try:
            s.send(req)
        except (BlockingIOError, OSError):
            pass
        socks.append(s)
    time.sleep(3.0)
    grow = d.rss_kb() - rss0
    for s in socks:
        s.close()
    n_ok = sum(1 for _ in range(20) if d.get("/healthz"))
    fig.update(connections=30, requests=12000, rss_growth_during_kb=grow, healthz_after=n_ok)
    log("    30 connections x 400 pipelined /metrics, never read: RSS %+d kB; /healthz %d/20 after" % (grow, n_ok))
    check(grow < 4096, "RSS grew %d kB" % grow)


@case(resolution=64, changes_params=True, rss_slack_kb=8192)
def resolution_flapping(d, fig):
    """Minor: N 64 -> 512 -> 64, five times: once back at 64 the memory of the
    big grids goes back to the system (RSS near where it started)."""
    s, r = attacker(d)
    rss = [d.rss_kb()]
    for i in range(5):
        for n in (512, 64):
            m = ask(s, r, '{"type":"set","id":%d,"params":{"resolution":%d}}' % (i * 2 + (n == 64), n), timeout=15)
            check(m and m.get("type") == "params", "set resolution %d: %r" % (n, m))
            time.sleep(0.6)
        rss.append(d.rss_kb())
    s.close()
    time.sleep(1.0)
    rss.append(d.rss_kb())
    fig.update(rss_kb=rss, settled_growth_kb=rss[-1] - rss[0])
    log("    RSS at N=64 before and after each 64->512->64 round: %s kB" % rss)
    check(rss[-1] - rss[0] < 8192, "RSS settles %d kB above the start after flapping" % (rss[-1] - rss[0]))


# ---------------------------------------------------------------- logs, fan-out, state file, signals, paths, fragments, queries, names

def refusals(d, count, deadline_s=15):
    """`count` upgrades that the daemon refuses and logs: a foreign Origin
    (closed without an answer) and a foreign Host (421) in turn. Returns how
    many were dealt with, answered or closed; stops at the first left hanging
    (a daemon stuck on its log answers none after it)."""
    done = 0
    t_end = time.time() + deadline_s
    for i in range(count):
        if time.time() > t_end:
            break
        host = "127.0.0.1:%d" % d.port if i % 2 else "evil.example:%d" % d.port
        req = ("GET / HTTP/1.1\r\nHost: %s\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
               "Sec-WebSocket-Protocol: oceand.v1\r\nOrigin: http://evil.example\r\n\r\n" % host).encode()
        s = socket.create_connection(("127.0.0.1", d.port), timeout=3)
        try:
            s.sendall(req)
            c = s.recv(4096)             # the 421, or b"" when closed (Origin refused)
        except socket.timeout:
            break
        except OSError:
            c = b""
        finally:
            s.close()
        if c and not c.startswith(b"HTTP/1.1 421") and not c.startswith(b"HTTP/1.0 421"):
            raise CaseFailure("refusal %d answered %r" % (i, c[:40]))
        done += 1
    return done


@case(log_pipe=True)
def log_flood(d, fig):
    """Every refused upgrade logs a line (and lws adds one of its own). With
    stderr a pipe that is not drained fast enough (systemd, `| tee` on a slow
    disk) a full pipe blocked write(2) on the lws thread: 600 refusals stopped
    every client's frames. Lines are now rate-limited (10/s, burst 100) and
    dropped when stderr is full, both counted in /metrics. The test's pipe
    holds 4 KiB and is not read during the attack."""
    t0 = time.time()
    n = refusals(d, 3000)
    secs = time.time() - t0
    check(n == 3000, "only %d of 3000 refusals dealt with: the daemon stopped (blocked on its log?)" % n)
    m = d.metrics()
    rate = m.get('oceand_log_lines_dropped_total{reason="rate"}', 0)
    blocked = m.get('oceand_log_lines_dropped_total{reason="blocked"}', 0)
    d.drain_log()
    with open(d.log_path, "rb") as f:
        lines = f.read().count(b"\n")
    fig.update(refusals=3000, answered=n, attack_s=round(secs, 1), log_lines=lines, dropped_rate=rate,
               dropped_blocked=blocked)
    log("    %d of 3000 refused upgrades answered in %.1f s; log: %d lines written, %d over the rate, %d while "
        "stderr was full" % (n, secs, lines, rate, blocked))
    check(lines <= 100 + 10 * (time.time() - t0) + 20, "%d log lines for 3000 refusals in %.1f s" % (lines, secs))
    # each refusal logs at least one line; all but the burst and 10 a second are over the rate
    check(rate >= 3000 - (100 + 10 * (time.time() - t0) + 20),
          "log lines over the rate not dropped (or not counted): rate %d, blocked %d" % (rate, blocked))


@case(changes_params=True, rss_slack_kb=4096)   # daemon defaults: 20 messages/s, burst 40 per client
def params_fanout(d, fig):
    """40 controllers each send 20 sets a second (their rate limit) for 4 s,
    reading everything. Each applied set used to be broadcast as its own
    `params` to every client: K x 20 a second to each, so 100 such
    controllers cut a well-behaved client off (1008, reply queue full).
    Now the sets applied at one tick boundary go out as one `params`: a
    bystander gets at most one per tick, and stays connected."""
    K = 40
    ctl = []
    for _ in range(K):
        s, _ = raw_ws(d.port)
        s.setblocking(False)
        ctl.append(s)
    bs, br = attacker(d)            # the bystander: reads and counts
    # The 41 sessions' own buffers (each hello, with the schema and the kinds of bodies) are
    # allocated once: judge "flat" from here, so what is measured is the sets' fan-out.
    br.until(lambda r: False, 0.3)
    warmed_up(fig, d.rss_kb())
    ticks0 = d.metric("oceand_ticks_total")
    changes0 = d.metric("oceand_param_changes_total")
    t0 = time.time()
    i = 0
    nxt = t0
    while time.time() - t0 < 4.0:
        for s in ctl:
            i += 1
            send_quiet(s, ws_frame(OP_TEXT, '{"type":"set","params":{"wind_speed":%g}}' % (5 + (i % 61) * 0.5)))
        nxt += 0.05
        while time.time() < nxt:
            rl, _, _ = select.select(ctl + [bs], [], [], max(0.0, nxt - time.time()))
            for s in rl:
                if s is bs:
                    br.pump(0)
                    continue
                try:
                    s.recv(1 << 20)
                except OSError:
                    pass
    br.until(lambda r: False, 0.5)
    ticks = d.metric("oceand_ticks_total") - ticks0
    changes = d.metric("oceand_param_changes_total") - changes0
    got = sum(1 for t in br.texts if t.get("type") == "params")
    for s in ctl:
        s.close()
    bs.close()
    fig.update(controllers=K, sets_sent=i, sets_applied=changes, ticks=ticks, bystander_params=got,
               bystander_close=br.close_code, bystander_eof=br.eof)
    log("    %d controllers sent %d sets in 4 s (%d applied over %d ticks); the bystander got %d params, close %r"
        % (K, i, changes, ticks, got, br.close_code))
    check(br.close_code is None and not br.eof, "the bystander was disconnected (close %r)" % br.close_code)
    check(changes > 2 * ticks, "too few sets applied (%d over %d ticks) to test the fan-out" % (changes, ticks))
    check(1 <= got <= ticks + 2, "bystander got %d params for %d ticks (one per applied set: %d)" % (got, ticks, changes))


def read_state(d):
    try:
        with open(os.path.join(d.tmp, "state.json")) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


@case(changes_params=True)
def state_file_attacks(d, fig):
    """Whoever may write in the state file's folder plants a symlink at the
    temporary name the daemon saves through (state.json.tmp -> a file of the
    daemon's user): the save used to overwrite the link's target with the
    state. Then SIGUSR1 and SIGUSR2, whose default action ended the daemon
    without saving: they save now, like SIGHUP."""
    victim = os.path.join(d.tmp, "victim.txt")
    with open(victim, "w") as f:
        f.write("precious\n")
    os.symlink(victim, os.path.join(d.tmp, "state.json.tmp"))
    s, r = attacker(d)
    m = ask(s, r, '{"type":"set","id":1,"params":{"wind_speed":17.5}}')
    check(m and m.get("type") == "params", "set: %r" % (m,))
    saved = wait_until(lambda: (read_state(d) or {}).get("params", {}).get("wind_speed") == 17.5, 5)
    with open(victim) as f:
        victim_now = f.read()
    st_path = os.path.join(d.tmp, "state.json")
    fig.update(saved=saved, victim_intact=victim_now == "precious\n", state_is_link=os.path.islink(st_path))
    log("    symlink at state.json.tmp: state saved %s, victim %s, state.json a link: %s"
        % (saved, "intact" if victim_now == "precious\n" else "OVERWRITTEN (%r)" % victim_now[:30],
           os.path.islink(st_path)))
    check(victim_now == "precious\n", "the file behind a symlink at state.json.tmp was overwritten")
    check(saved and not os.path.islink(st_path), "state not saved as a file of its own")
    for i, sig in enumerate((signal.SIGUSR1, signal.SIGUSR2)):
        m = ask(s, r, '{"type":"set","id":%d,"params":{"wind_speed":%g}}' % (2 + i, 11.5 + i))
        check(m and m.get("type") == "params", "set: %r" % (m,))
        d.proc.send_signal(sig)
        ok = wait_until(lambda: (read_state(d) or {}).get("params", {}).get("wind_speed") == 11.5 + i, 3)
        fig[sig.name] = "saved" if ok and d.alive() else "exit %r" % d.proc.poll()
        check(d.alive(), "%s ended the daemon (exit %r)" % (sig.name, d.proc.poll()))
        check(ok, "%s did not save the state" % sig.name)
    s.close()


@case(changes_params=True, fsize=256)
def state_save_fsize(d, fig):
    """The disk is full, as far as the daemon can tell: `ulimit -f 1` (1 KiB;
    the state file is larger). A write past the limit raised SIGXFSZ, whose
    default action ended the daemon at its first save. It must fail like a
    full disk: a warning, nothing left behind, the daemon running. A set is
    saved before it is acknowledged, so the set that cannot be saved is
    refused (`internal`, not saved) and changes nothing."""
    s, r = attacker(d)
    m = ask(s, r, '{"type":"set","id":1,"params":{"wind_speed":18.5}}')
    check(m and m.get("type") == "error" and m.get("code") == "internal", "unsaved set: %r" % (m,))
    d.proc.send_signal(signal.SIGHUP)     # save now
    warned = wait_until(lambda: not d.alive() or b"File too large" in open(d.log_path, "rb").read(), 5)
    s.close()
    # The warning seen may be the set's save; the SIGHUP's may still be writing its
    # temporary file: what counts is what stays behind once the saves are over.
    state_files = lambda: sorted(f for f in os.listdir(d.tmp) if f.startswith("state"))
    wait_until(lambda: not state_files(), 3)
    left = state_files()
    fig.update(alive=d.alive(), exit=d.proc.poll(), warned=warned and d.alive(), files=left)
    log("    save under ulimit -f 256 bytes: daemon %s, warned %s, state files %s"
        % ("running" if d.alive() else "ended (%r)" % d.proc.poll(), warned, left))
    check(d.alive(), "the daemon ended at its save (exit %r: %s)" % (
        d.proc.poll(), "SIGXFSZ" if d.proc.poll() == -signal.SIGXFSZ else "?"))
    check(warned, "no warning about the failed save")
    check(not left, "files left behind by the failed save: %s" % left)


def run_oceand(args, env=None, timeout=8, stop_after=None):
    """Run oceand to its end (or SIGTERM it after stop_after s); (exit code, output)."""
    p = subprocess.Popen([ARGS.oceand, "--bind", "127.0.0.1", "--port", "0", "--wisdom-file", "none",
                          "--resolution", "64"] + args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         env=dict(os.environ, **(env or {})))
    try:
        out, _ = p.communicate(timeout=stop_after or timeout)
    except subprocess.TimeoutExpired:
        p.send_signal(signal.SIGTERM)
        try:
            out, _ = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            out, _ = p.communicate()
        if not stop_after:
            return None, out.decode(errors="replace")
    return p.returncode, out.decode(errors="replace")


@case()
def absurd_command_lines(d, fig):
    """Paths longer than the daemon's buffers were cut to fit, silently: a
    --state-file (or a config file's state_file) of 600 bytes became another
    path, which the daemon read and then wrote; so did a long $XDG_STATE_HOME
    (the default state folder). Now: a given path that does not fit is an
    error (exit 2); a derived one is not used (warning)."""
    base = os.path.join(d.tmp, "cl")
    os.makedirs(base)
    long_file = os.path.join(base, "d" * 560, "state.json")
    cfg = os.path.join(base, "c.json")
    with open(cfg, "w") as f:
        json.dump({"state_file": long_file}, f)
    got = {}
    for name, args in (("--state-file", ["--state-file", long_file]), ("config state_file", ["--config", cfg])):
        rc, out = run_oceand(args)
        got[name] = rc
        check(rc == 2 and "too long" in out, "%s of %d bytes: exit %r, %r" % (name, len(long_file), rc, out[-200:]))
    # $XDG_STATE_HOME whose oceand-state.json path would be cut inside the file name
    xdg = base
    while len(xdg) < 505:
        xdg = os.path.join(xdg, "x" * min(200, 504 - len(xdg)))
    os.makedirs(xdg)
    rc, out = run_oceand(["--log-level", "warn"], env={"XDG_STATE_HOME": xdg}, stop_after=1.5)
    written = os.listdir(xdg)
    got["XDG_STATE_HOME"] = written or rc
    fig["results"] = got
    log("    too-long paths: %r" % got)
    check(rc == 0, "with a long $XDG_STATE_HOME: exit %r, %r" % (rc, out[-200:]))
    check(not written, "state written to a cut path: %s" % written)
    check("XDG_STATE_HOME" in out, "no warning about the long $XDG_STATE_HOME: %r" % out[-200:])


@case(args=LIBERAL)
def fragment_floods(d, fig):
    """One 64 KiB message in 65 000 one-byte fragments, and 300 000 empty
    continuation frames inside one message: each is one answer, memory flat
    (the empty ones never grow the message, so --max-message never trips)."""
    s, r = attacker(d)
    msg = b'{"type":"ping","id":5,"pad":"' + b"a" * 65000 + b'"}'
    out = bytearray()
    for i in range(len(msg)):
        out += ws_frame(OP_TEXT if i == 0 else OP_CONT, msg[i:i + 1], fin=i == len(msg) - 1)
    rss0 = d.rss_kb()
    send_quiet(s, bytes(out))
    r.until(lambda r: any(t.get("type") == "pong" for t in r.texts), 15)
    one = [t.get("id") for t in r.texts if t.get("type") == "pong"]
    s.close()
    s, r = attacker(d)
    send_quiet(s, ws_frame(OP_TEXT, b"{", fin=False))
    empty = ws_frame(OP_CONT, b"", fin=False) * 10000
    for _ in range(30):
        if not send_quiet(s, empty):
            break
    send_quiet(s, ws_frame(OP_CONT, b'"type":"ping","id":6}'))
    r.until(lambda r: any(t.get("type") == "pong" for t in r.texts), 15)
    two = [t.get("id") for t in r.texts if t.get("type") == "pong"]
    s.close()
    fig.update(one_byte_fragments=len(msg), empty_fragments=300000, answers=[one, two], rss_jump_kb=d.rss_kb() - rss0)
    log("    %d one-byte fragments -> %r; 300 000 empty fragments -> %r; RSS %+d kB"
        % (len(msg), one, two, fig["rss_jump_kb"]))
    check(one == [5], "the message in one-byte fragments: answers %r" % one)
    check(two == [6], "the message with 300 000 empty fragments: answers %r" % two)


EXTREME = [1.7976931348623157e308, -1.7976931348623157e308, 1e308, 5e-324, -0.0, 1e20, 2.0 ** 53 + 1, -2.0 ** 63]


# LIBERAL: a 256-point query is 10 KB, 11 control units; the budgets under test here are the query ones.
@case(args=("--probe-max-total", "256") + LIBERAL, rss_slack_kb=4096)
def query_probe_abuse(d, fig):
    """Point queries and probes at absurd coordinates (+-DBL_MAX, 1e308,
    subnormals, 2^63) from 24 clients: probe sets changed with every message
    (over the total: busy), queries past the budget and the queue (busy),
    then every client vanishes with its queries still queued. Replies stay
    valid JSON with finite values, the refusals are coded, and once they are
    gone nothing is left probing."""
    pts = [[a, b] for a in EXTREME for b in EXTREME]
    socks = []
    codes = {}
    bad = []
    for k in range(24):
        s, r = attacker(d)
        socks.append((s, r))
        batch = b""
        for i in range(12):   # probe sets churned: a different set each message
            sub = pts[(k + i) % 48:(k + i) % 48 + 16]
            batch += ws_frame(OP_TEXT, json.dumps({"type": "probe", "id": i, "points": sub}))
        for i in range(12):
            batch += ws_frame(OP_TEXT, json.dumps({"type": "query", "id": 100 + i, "points": (pts * 4)[:256]}))
        send_quiet(s, batch)
    deadline = time.time() + 10
    for s, r in socks:
        r.until(lambda r: sum(1 for t in r.texts if t.get("type") in ("probing", "query_result", "error")) >= 24,
                max(0.1, deadline - time.time()))
        for t in r.texts:
            if t.get("type") == "error":
                codes[t.get("code")] = codes.get(t.get("code"), 0) + 1
            elif t.get("type") in ("probing", "query_result", "probe_data"):
                codes[t["type"]] = codes.get(t["type"], 0) + 1
            if "unparseable" in t:
                bad.append(t["unparseable"][:60])
            if t.get("type") == "query_result":
                for p in t["points"]:
                    vals = [p["height"], p["jacobian"], p["vertical_velocity"]] + p["displacement"] + p["normal"]
                    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
                        bad.append("query_result values %r" % vals[:4])
                        break
            if t.get("type") == "probe_data":
                if not all(math.isfinite(v) for p in t["points"] for v in p):
                    bad.append("probe_data %r" % t["points"][:1])
    # all vanish at once, with what they queued still queued
    for s, r in socks:
        rst_close(s)
    gone = wait_until(lambda: d.metric("oceand_clients") == 1 and d.metric("oceand_probe_points") == 0, 10)
    fig.update(replies=codes, bad=bad[:5], probe_points_after=d.metric("oceand_probe_points"))
    log("    24 clients x (12 probe sets + 12 queries of 256 points at absurd coordinates): %r" % codes)
    check(not bad, "replies not valid JSON or not finite: %r" % bad[:3])
    check(set(codes) <= {"probing", "query_result", "probe_data", "busy", "time_out_of_window"},
          "unexpected replies %r" % codes)
    check(codes.get("busy", 0) > 0 and codes.get("query_result", 0) > 0 and codes.get("probing", 0) > 0,
          "expected answers, and busy past the budget: %r" % codes)
    check(gone, "still probing after every client left: %g points" % d.metric("oceand_probe_points"))
    s, r = attacker(d)      # the service still answers
    send_quiet(s, ws_frame(OP_TEXT, json.dumps({"type": "query", "id": 1, "points": [[1.5, 2.5]]})))
    r.until(lambda r: any(t.get("type") in ("query_result", "error") for t in r.texts), 10)
    m = ([t for t in r.texts if t.get("type") in ("query_result", "error")] or [None])[0]
    s.close()
    check(m and m.get("type") in ("query_result", "error"), "a query afterwards: %r" % (m,))


@case(args=LIBERAL)
def name_abuse(d, fig):
    """`name` with markup, controls, bidi overrides, 33 characters: bad_name
    each (escaped lone surrogates: bad_json). Raw invalid UTF-8 inside a name (overlong,
    a surrogate, a 5-byte form) never reaches it: close 1007. And 10 clients
    renaming themselves 100 times each: a name goes to its owner only (no
    fan-out), so a bystander receives none of it."""
    fig["messages"] = expect_errors(d, [
        (json.dumps({"type": "name", "id": i, "name": n}), "bad_name", None) for i, n in enumerate([
            "<script>", "a&b", "\u202eevil", "tab\there", "x" * 33, " lead", "trail ", "\u200bzw", "\ufeffbom",
            "\x7f", "\u0085nel"])] + [
        ('{"type":"name","id":50,"name":"\\ud800"}', "bad_json", None),     # cJSON: a lone surrogate
        ('{"type":"name","id":51,"name":"\\udc00\\ud800"}', "bad_json", None),
        ('{"type":"name","id":52,"name":5}', "bad_name", None)])
    raw = {}
    for label, b in (("overlong", b"\xc0\xaf"), ("surrogate", b"\xed\xa0\x80"), ("5-byte", b"\xf8\x88\x80\x80\x80")):
        s, r = attacker(d)
        send_quiet(s, ws_frame(OP_TEXT, b'{"type":"name","id":1,"name":"a' + b + b'"}'))
        r.until(lambda r: r.close_code is not None or any(t.get("type") in ("named", "error") for t in r.texts), 3)
        raw[label] = r.close_code if r.close_code is not None else [t.get("type") for t in r.texts[1:]]
        s.close()
    bs, br = attacker(d)
    n0 = len(br.texts)
    flappers = [attacker(d) for _ in range(10)]
    for i in range(100):
        for k, (s, r) in enumerate(flappers):
            send_quiet(s, ws_frame(OP_TEXT, json.dumps({"type": "name", "name": "n%d-%d" % (k, i)})))
    ok = all(r.until(lambda r: sum(1 for t in r.texts if t.get("type") == "named") >= 100, 10) for s, r in flappers)
    br.until(lambda r: False, 0.5)
    leaked = [t.get("type") for t in br.texts[n0:]]
    for s, r in flappers:
        s.close()
    bs.close()
    fig.update(raw_utf8=raw, bystander_got=len(leaked))
    log("    raw invalid UTF-8 in a name: %r; 1000 renames: every one answered %s, bystander got %d messages"
        % (raw, ok, len(leaked)))
    check(all(v == 1007 for v in raw.values()), "raw invalid UTF-8 in a name: %r, want close 1007" % raw)
    check(ok, "not every rename was answered")
    check(not leaked, "renames reached a bystander: %r" % leaked[:5])


# ---------------------------------------------------------------- clients that do not read, memory given back

ALL_FIELDS = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian", "foam"]
FINE_FIELDS = ALL_FIELDS[:6]     # foam lives on cascade 0 only
HEAVY_SUB = json.dumps({"type": "subscribe", "id": "s", "fields": ALL_FIELDS, "lod": 0, "bound": 0,
                        "cascades": [{"fields": FINE_FIELDS, "lod": 0, "bound": 0}] * 2})
# The same in parts (PROTOCOL.md §3.4): a client stalled between two parts of a tick holds its frame alike.
HEAVY_SUB_PARTS = HEAVY_SUB[:-1] + ', "parts": true}'


@case(resolution=256, rss_slack_kb=80 * 1024)
def stalled_pinned_frames(d, fig):
    """150 clients with a 1 KiB receive window that never read, each subscribed
    to every field of three cascades at LOD 0, lossless (MBs a frame; half of
    them in parts, so they stall between two parts of a tick): each
    pinned a whole frame of its own (about 1 frame per client, RSS +300 MB).
    The frames held by clients that do not read are bounded now (48 MB, the
    oldest holders closed with 1008), and RSS stays within 64 MB of the start."""
    rss0 = d.rss_kb()
    socks = []
    for i in range(150):
        s, _ = raw_ws(d.port, rcvbuf=1024)
        send_quiet(s, ws_frame(OP_TEXT, HEAVY_SUB_PARTS if i % 2 else HEAVY_SUB))
        socks.append(s)
        time.sleep(0.03)       # one by one, so that each pins a different frame
    peak = rss0
    for _ in range(20):
        time.sleep(0.2)
        peak = max(peak, d.rss_kb())
    closed = d.metrics().get('oceand_clients_closed_total{reason="pinned"}', 0)
    fig.update(stalled=150, rss_start_kb=rss0, rss_peak_kb=peak, closed_pinned=closed)
    log("    150 stalled heavy clients: RSS %d -> peak %d kB (%+d MB), %d closed for pinning frames"
        % (rss0, peak, (peak - rss0) >> 10, closed))
    for s in socks:
        s.close()
    check(peak - rss0 <= 64 * 1024, "RSS grew %d MB with 150 stalled clients (at most 64)" % ((peak - rss0) >> 10))
    check(closed > 0, "no client was closed for pinning frames")


@case(resolution=128, args=("--ping-interval", "1", "--idle-timeout", "3"), rss_slack_kb=8192)
def pong_without_reading(d, fig):
    """A client that never reads but sends an unsolicited pong every second
    was never timed out (it looked alive). Reading is what counts now: no
    byte of its frame taken for --idle-timeout, and it is closed (1008)."""
    s, _ = raw_ws(d.port, rcvbuf=1024)
    send_quiet(s, ws_frame(OP_TEXT, HEAVY_SUB))
    t0 = time.time()
    closed_s = None
    while time.time() - t0 < 12:
        if not send_quiet(s, ws_frame(10, b"alive")):     # an unsolicited pong (opcode 10)
            closed_s = time.time() - t0
            break
        if d.metrics().get('oceand_clients_closed_total{reason="stalled"}', 0) >= 1:
            closed_s = time.time() - t0
            break
        time.sleep(1.0)
    s.close()
    fig.update(closed_after_s=None if closed_s is None else round(closed_s, 1))
    log("    a pong-sending client that never reads: closed after %s s" % fig["closed_after_s"])
    check(closed_s is not None and closed_s <= 8, "a client that never reads, sending pongs, held %s s" % closed_s)


@case(resolution=256, rss_slack_kb=20 * 1024)
def temporal_memory_returned(d, fig):
    """25 temporal viewers with distinct layers (each stream keeps ~40 bytes
    a sample) took RSS up by hundreds of MB, and it was never given back
    after they left. Within 5 s of the last one leaving, RSS is back within
    16 MB of the start."""
    rss0 = d.rss_kb()
    combos = [(f, lod, b) for f in ALL_FIELDS[:6] for lod in (0, 1) for b in (0.001, 0.005, 0.01)][:25]
    socks = []
    for f, lod, b in combos:
        s, _ = raw_ws(d.port)
        r = Reader(s)
        send_quiet(s, ws_frame(OP_TEXT, json.dumps({"type": "subscribe", "fields": [f], "lod": lod, "bound": b,
                                                     "temporal": True})))
        socks.append((s, r))
    t_end = time.time() + 4
    peak = rss0
    while time.time() < t_end:
        for s, r in socks:
            r.pump(0)
        peak = max(peak, d.rss_kb())
        time.sleep(0.05)
    for s, _ in socks:
        s.close()
    after = []
    for _ in range(10):
        time.sleep(0.5)
        after.append(d.rss_kb())
    fig.update(rss_start_kb=rss0, rss_peak_kb=peak, rss_after_kb=after[-1])
    log("    25 temporal viewers: RSS %d -> peak %d -> %d kB 5 s after they left" % (rss0, peak, after[-1]))
    check(peak - rss0 > 16 * 1024, "the viewers' streams took only %d kB: the case measures nothing" % (peak - rss0))
    check(after[-1] - rss0 <= 16 * 1024, "RSS %d MB above the start 5 s after the temporal viewers left"
          % ((after[-1] - rss0) >> 10))


@case(resolution=256, rss_slack_kb=8 * 1024)
def render_abuse(d, fig):
    """Exact-time renders (PROTOCOL.md §7.5) as an attacker would use them: 8
    clients that never read each ask for 600 lossless frames of every field of
    three cascades (megabytes a frame), more than the render budget admits, and
    a second render while their first runs; then all vanish mid-render. The
    live tick keeps its frames (the observer), the renders past the budget and
    the second ones are `busy`, each client holds at most its 4-frame window,
    and once they are gone nothing renders and the memory is given back."""
    rss0 = d.rss_kb()
    every = ALL_FIELDS[:6]
    finer = [f for f in ALL_FIELDS[:5]]   # the finer cascades: no Jacobian
    req = {"type": "render", "start": 50, "fps": 24, "frames": 600, "fields": every, "lod": 0, "bound": 0,
           "cascades": [{"fields": finer, "lod": 0, "bound": 0}, {"fields": finer, "lod": 0, "bound": 0}]}
    socks = []
    replies = {}
    for k in range(8):
        s, _ = raw_ws(d.port, rcvbuf=4096)
        r = Reader(s)
        send_quiet(s, ws_frame(OP_TEXT, json.dumps(dict(req, id=k))))
        socks.append((s, r))
    for k, (s, r) in enumerate(socks):
        r.until(lambda r, k=k: any(t.get("id") == k for t in r.texts), 5)
    for k, (s, r) in enumerate(socks):   # a second render while the first runs (or was refused)
        send_quiet(s, ws_frame(OP_TEXT, json.dumps(dict(req, id=100 + k, frames=2))))
    t_end = time.time() + 3
    peak = rss0
    while time.time() < t_end:
        for s, r in socks:
            r.pump(0)     # reads what fits in 4 KiB: the rest waits in the daemon's window
        peak = max(peak, d.rss_kb())
        time.sleep(0.05)
    for s, r in socks:
        r.until(lambda r: any(t.get("id", -1) >= 100 for t in r.texts), 3)
        for t in r.texts:
            if t.get("type") in ("error", "rendering", "rendered"):
                key = t.get("code") or t.get("type")
                replies[key] = replies.get(key, 0) + 1
    accepted = replies.get("rendering", 0)
    frames_rendered = d.metric("oceand_render_frames_total")
    for s, _ in socks:
        rst_close(s)
    left = wait_until(lambda: d.metric("oceand_clients") == 1, 10)
    time.sleep(0.5)       # a frame a worker was making when its client went is finished
    f0 = d.metric("oceand_render_frames_total")
    time.sleep(1.0)
    f1 = d.metric("oceand_render_frames_total")
    after = d.rss_kb()
    fig.update(clients=8, replies=replies, accepted=accepted, frames_rendered_while_held=frames_rendered,
               rendered_after_leaving=f1 - f0, rss_start_kb=rss0, rss_peak_kb=peak, rss_after_kb=after)
    log("    8 renders of 600 lossless frames x 16 layers, never read: %r; %d frames rendered while held; "
        "RSS %d -> peak %d -> %d kB" % (replies, frames_rendered, rss0, peak, after))
    check(left, "the render clients are still counted after they went")
    check(accepted >= 1 and replies.get("busy", 0) >= 8, "want some renders accepted and the rest, and every "
          "second render, busy: %r" % replies)
    check(frames_rendered <= 8 * accepted + 8, "%d frames rendered for %d clients that read nothing: the render "
          "does not wait at its window" % (frames_rendered, accepted))
    check(f1 - f0 == 0, "%d frames rendered after every client left" % (f1 - f0))
    check(set(replies) <= {"rendering", "busy"}, "unexpected replies %r" % replies)


@case(resolution=64, changes_params=True, rss_slack_kb=16 * 1024)
def resolution_flip_busy(d, fig):
    """One controller flips N between 64 and 512 as fast as its rate limit
    lets it, for 4 s. Each change of N rebuilt the grids while the next was
    queued behind it: the sea kept rebuilding and answers came late. Now a
    change of N while another is being built, or sooner after it than that
    one took to build, is answered `busy` at once; every set is answered."""
    s, r = attacker(d)
    sent = {}
    t_end = time.time() + 4
    i = 0
    while time.time() < t_end:
        i += 1
        n = 512 if i % 2 else 64
        send_quiet(s, ws_frame(OP_TEXT, '{"type":"set","id":%d,"params":{"resolution":%d}}' % (i, n)))
        sent[i] = time.time()
        r.pump(0)
        time.sleep(0.05)              # 20 a second: the client's rate limit
    r.until(lambda r: {t.get("id") for t in r.texts if t.get("type") in ("params", "error")} >= set(sent), 10)
    answers = {t.get("id"): t for t in r.texts if t.get("type") in ("params", "error") and t.get("id") in sent}
    busy = sum(1 for t in answers.values() if t.get("code") == "busy")
    applied = sum(1 for t in answers.values() if t.get("type") == "params")
    for k in range(50):               # back to N = 64 (the RSS check compares with the start)
        m = ask(s, r, '{"type":"set","id":"end%d","params":{"resolution":64}}' % k, timeout=10)
        if m and m.get("type") == "params":
            break
        time.sleep(0.2)
    s.close()
    fig.update(sets=len(sent), answered=len(answers), busy=busy, applied=applied)
    log("    %d sets flipping N: %d answered, %d applied, %d busy" % (len(sent), len(answers), applied, busy))
    check(len(answers) == len(sent), "%d of %d sets answered" % (len(answers), len(sent)))
    check(busy > 0, "no change of N was refused while another was being built")


# ---------------------------------------------------------------- runner

BUDGET = 300        # --control-budget of the control_budget case (units a second, all clients)


def subscribe_flood(d, K=50, per_s=20, secs=5.0, set_every=0.5):
    """K clients each send per_s subscribes a second listing all 1024 tiles
    (10 KB) for secs, reading everything; a well-behaved controller sends a
    `set` every set_every s. Also used by bench/control_budget.py."""
    tiles = [[x, z] for x in range(32) for z in range(32)]
    frame = ws_frame(OP_TEXT, json.dumps({"type": "subscribe", "fields": ["height"], "tiles": tiles}))
    att = []
    for _ in range(K):
        s, r = attacker(d)
        s.settimeout(2)             # blocking sends (a frame is never cut in half), bounded
        att.append((s, r))
    cs, cr = attacker(d)            # the controller (no token set: every client may)
    by_sock = {s: r for s, r in att}
    by_sock[cs] = cr
    m0 = d.metrics()
    sets = {}                       # id -> frames the controller had when it sent it
    t0 = time.time()
    nxt, next_set, k, sent = t0, t0 + set_every / 2, 0, 0
    while time.time() - t0 < secs:
        for s, _ in att:
            sent += send_quiet(s, frame)
        if time.time() >= next_set:
            k += 1
            sets[k] = cr.binary
            send_quiet(cs, ws_frame(OP_TEXT, '{"type":"set","id":%d,"params":{"wind_speed":%g}}' % (k, 5 + k * 0.5)))
            next_set = max(next_set + set_every, time.time() + set_every / 2)   # never two at once
        nxt += 1.0 / per_s
        while time.time() < nxt:
            rl, _, _ = select.select(list(by_sock), [], [], max(0.0, nxt - time.time()))
            for s in rl:
                by_sock[s].pump(0)
    elapsed = time.time() - t0
    for s, r in by_sock.items():
        r.until(lambda r: False, 0.05)
    cr.until(lambda r: sum(1 for t in r.texts if t.get("id") in sets) >= len(sets), 3)
    m1 = d.metrics()
    for s in by_sock:
        s.close()
    codes = {}
    accepted = 0
    for _, r in att:
        for t in r.texts:
            if t.get("type") == "subscribed":
                accepted += 1
            elif t.get("type") == "error":
                codes[t.get("code")] = codes.get(t.get("code"), 0) + 1
    answers = {t["id"]: t for t in cr.texts if t.get("id") in sets}
    late = ["set %d: %s" % (i, json.dumps(answers[i])[:120] if i in answers else "no answer")
            for i in sets if answers.get(i, {}).get("type") != "params"]
    # Frames the controller got between sending a set and its answer: ticks it waited (at least).
    waited = [cr.bin_at[cr.texts.index(answers[i])] - f for i, f in sets.items() if i in answers]
    return dict(frame=frame, elapsed=elapsed, sent=sent, accepted=accepted, codes=codes, sets=sets, late=late,
                waited=waited, controller_frames=cr.binary, m0=m0, m1=m1)


# RSS: 52 clients' 10 KB messages and echoes went through malloc (~5.7 MB kept by it afterwards);
# the controller's wind sets: the easing's second amplitude set per cascade and the query snapshots
# that carry both (+2.2 MB at N = 128, reached within 10 sets and flat from there to 200 sets,
# measured with 200 wind sets at N = 128: plateau 18.4 -> 20.6 MB; bounded, not a leak).
@case(args=("--control-budget", str(BUDGET)), changes_params=True, resolution=128, rss_slack_kb=10240)
def control_budget(d, fig):
    """50 clients each send 20 subscribes a second listing all 1024 tiles
    (10 KB: 0.5 ms of the service thread each), for 5 s, reading everything;
    a controller sends a `set` every 0.5 s. Each client was within its limit
    of 20 messages a second, and together they took the thread (the open
    finding of reliability.md). Now a message costs 1 unit + 1 per KiB (11
    here) against the client's own bucket (rate_limited) and against a budget
    of all clients (busy); a light client keeps its fair share of the budget.
    Checks: what was accepted fits the budget, the controller's every set is
    applied within a few ticks, and the observer keeps its frames."""
    K = 50
    f = subscribe_flood(d, K)
    frame, elapsed, sent, accepted, codes = f["frame"], f["elapsed"], f["sent"], f["accepted"], f["codes"]
    sets, late, waited, m0, m1 = f["sets"], f["late"], f["waited"], f["m0"], f["m1"]
    units = m1.get("oceand_control_units_total", float("nan")) - m0.get("oceand_control_units_total", 0)
    refused = {r: m1.get('oceand_control_refused_total{reason="%s"}' % r, 0)
               - m0.get('oceand_control_refused_total{reason="%s"}' % r, 0) for r in ("rate_limited", "busy")}
    # Accepted at most: the budget's refill, its 0.1 s burst, its debt (1 s of it), the fair shares
    # saved up (1 s of each, at least 4 units), one message of debt per client (K attackers, the
    # controller, the observer); a subscribe costs 11 units (1 + 10 KiB).
    cost = 1 + len(frame) // 1024
    n = K + 2
    allowed = (BUDGET * elapsed + 0.1 * BUDGET + BUDGET + max(BUDGET, 4 * n) + n * cost) / cost
    fig.update(clients=K, subscribes_sent=sent, subscribes_accepted=accepted, accepted_max=round(allowed),
               codes=codes, units=units, refused_rate_limited=refused["rate_limited"], refused_busy=refused["busy"],
               sets=len(sets), sets_applied=len(sets) - len(late), controller_frames=f["controller_frames"],
               set_frames_waited_max=max(waited) if waited else None)
    log("    %d clients sent %d subscribes of %d bytes in %.1f s: %d accepted (at most %d), errors %s; "
        "/metrics: %s units, refused %s; controller: %d of %d sets applied, waiting at most %s frames"
        % (K, sent, len(frame), elapsed, accepted, allowed, codes, units, refused, len(sets) - len(late), len(sets),
           fig["set_frames_waited_max"]))
    check(len(sets) >= 5, "only %d sets sent" % len(sets))
    check(not late, "the controller's sets were not all applied: " + "; ".join(late[:3]))
    # Answered before its next set (0.5 s, 15 ticks): frames the controller took meanwhile, a bound under load.
    check(f["controller_frames"] > 0 and max(waited) <= 15, "a set waited %s frames for its answer" % max(waited))
    check(accepted <= allowed, "%d subscribes accepted in %.1f s, the budget of %d units/s allows %d"
          % (accepted, elapsed, BUDGET, allowed))
    check(codes.get("busy", 0) > 0 and codes.get("rate_limited", 0) > 0,
          "want both rate_limited (own limit) and busy (budget) refusals, got %r" % codes)
    check(set(codes) <= {"busy", "rate_limited"}, "unexpected errors %r" % codes)
    check(refused["busy"] > 0, "busy refusals not counted in /metrics")


def run_case(fn, fig):
    """Run one case on its own daemon; figures go into fig (kept when the case fails)."""
    o = fn.opts
    fig["N"] = o["resolution"]
    d = Daemon(ARGS.oceand, *o["args"], resolution=o["resolution"], web=o["web"], nofile=o["nofile"],
               log_pipe=o["log_pipe"], fsize=o["fsize"])
    obs = None
    try:
        obs = Observer(d.url)
        params0, version0 = obs.hello["params"], obs.hello["params_version"]
        time.sleep(0.5)
        m0 = d.metrics()
        rss0 = d.rss_kb()
        obs.mark()
        cpu0, wait0 = d.sched()
        t0 = time.time()
        failure = None
        try:
            fn(d, fig)
        except CaseFailure as e:
            failure = str(e)
        except Exception as e:  # a harness error (socket, timeout): the case fails, with a trace
            failure = "%s: %s" % (type(e).__name__, e)
            traceback.print_exc(file=OUT)
        # Every window at least MIN_WINDOW long, so the share means something.
        while time.time() < t0 + MIN_WINDOW:
            time.sleep(0.05)
        secs = time.time() - t0
        # Liveness first: everything below needs the daemon.
        alive = d.alive()
        fig["daemon_alive"] = alive
        check(alive, (failure + "; " if failure else "") + "daemon died (exit %r); log tail:\n%s"
              % (d.proc.returncode, d.read_log()))
        st = obs.stats()
        cpu1, wait1 = d.sched()
        fig["daemon_cpu_ms"], fig["runq_wait_ms"] = round(cpu1 - cpu0), round(wait1 - wait0)
        m1 = d.metrics()
        if o["settle_clients"]:
            wait_until(lambda: d.metric("oceand_clients") == 1, 10)
        time.sleep(0.3)
        rss1 = d.rss_kb()
        # From the end of the case's own warm-up when it has one (warmed_up): its one-time growth is no leak.
        rss_base = fig.get("rss_warm_kb", rss0)
        share = st.get("frames", 0) / st["span"] if st.get("span") else 0.0
        fig.update(seconds=round(secs, 1), observer_frames=st.get("frames"), observer_span=st.get("span"),
                   observer_share=round(share, 4), observer_closed=st.get("closed"),
                   rss_before_kb=rss0, rss_after_kb=rss1, rss_growth_kb=rss1 - rss_base,
                   overruns=m1.get("oceand_tick_overruns_total", 0) - m0.get("oceand_tick_overruns_total", 0))
        problems = [failure] if failure else []
        if st.get("closed") is not None:
            problems.append("observer was disconnected (code %r)" % st.get("closed"))
        if st.get("frames", 0) < 0.5 * secs * d.tick_rate:
            problems.append("observer got %s frames in %.1f s (daemon stalled?)" % (st.get("frames"), secs))
        if share < MIN_SHARE:
            # The attack's doing or the shared machine's? A lost frame means the
            # daemon's threads were late by a tick period; if they spent at least
            # that long ready-but-not-running (run-queue wait), the scheduler can
            # explain the loss: reported as NOISE, not counted as a failure.
            lost = st["span"] - st["frames"]
            fig["observer_gaps"] = st.get("gaps")
            explained = fig["runq_wait_ms"] >= lost * 1000.0 / d.tick_rate
            if explained and not ARGS.strict:
                fig["noisy"] = True
                log("    NOISE: observer kept %.1f%% (%d lost, holes %s) while the daemon's threads waited %.0f ms"
                    " for a core (CPU used: %.0f ms): the machine's loss, not the attack's"
                    % (100 * share, lost, st.get("gaps"), fig["runq_wait_ms"], fig["daemon_cpu_ms"]))
            else:
                problems.append("observer kept %.1f%% of frames (%s of %s, holes %s), want >= %.0f%% "
                                "(daemon threads waited %.0f ms for a core, used %.0f ms)"
                                % (100 * share, st.get("frames"), st.get("span"), st.get("gaps"), 100 * MIN_SHARE,
                                   fig["runq_wait_ms"], fig["daemon_cpu_ms"]))
        if rss1 - rss_base >= o["rss_slack_kb"]:
            problems.append("RSS grew %d kB (%d -> %d%s), want < %d" % (rss1 - rss_base, rss_base, rss1,
                            " after the case's warm-up" if "rss_warm_kb" in fig else "", o["rss_slack_kb"]))
        if not o["changes_params"]:
            h = fresh_hello(d)
            if h["params"] != params0 or h["params_version"] != version0:
                changed = sorted(k for k in params0 if h["params"].get(k) != params0[k])
                problems.append("parameters changed: version %s -> %s, %s" % (version0, h["params_version"], changed))
            if st.get("params"):
                problems.append("observer saw %d params broadcasts" % st["params"])
        obs.close()
        obs = None
        rc = d.stop()
        fig["exit_code"] = rc
        if rc != 0:
            problems.append("exit code %r on SIGTERM after the attack; log tail:\n%s" % (rc, d.read_log()))
        check(not problems, "; ".join(problems))
    finally:
        if obs:
            obs.close()
        d.close()


# Cases that load the daemon (N > 64, hundreds of clients or sets, 10 MB messages) run alone
# under --jobs, after the light ones: they measure the observer against a busy daemon.
SOLO = {"connections_500", "churn", "resolution_flapping", "params_fanout", "message_10mb"}


def solo(fn):
    return fn.__name__ in SOLO or fn.opts["resolution"] > 64


def run_jobs(jobs):
    """Run the light cases as `jobs` shards in parallel processes (each case still has its own
    daemon and observer), then the solo() cases in one process alone; print each process's log
    whole, in order; one closing "N passed, M failed" line. Returns the exit code."""
    base = [sys.executable, os.path.abspath(__file__), "--oceand", ARGS.oceand, "-k", ARGS.k]
    base += ["--strict"] if ARGS.strict else []
    t_all = time.time()
    shards = ["%d/%d" % (i, jobs) for i in range(jobs)]
    files = [tempfile.TemporaryFile("w+") for _ in range(jobs + 1)]   # not pipes: a full one would stall its shard
    procs = [subprocess.Popen(base + ["--shard", sh], stdout=f, stderr=subprocess.STDOUT, text=True)
             for sh, f in zip(shards, files)]
    for p in procs:
        p.wait()
    procs.append(subprocess.Popen(base + ["--shard", "solo"], stdout=files[-1], stderr=subprocess.STDOUT, text=True))
    procs[-1].wait()
    outs = []
    for f in files:
        f.seek(0)
        outs.append(f.read())
        f.close()
    passed = failed = 0
    failed_names = []
    for i, (p, out) in enumerate(zip(procs, outs)):
        log("=== %s (exit %d)" % ("light cases, shard %s" % shards[i] if i < jobs else "solo cases", p.returncode))
        lines = out.splitlines()
        last = lines[-1] if lines else ""
        m = re.match(r"(\d+) passed, (\d+) failed$", last)
        log("\n".join(lines[:-1] if m else lines))
        if not m:
            failed += 1
            failed_names.append("shard-%d(no summary, exit %d)" % (i, p.returncode))
            continue
        passed += int(m.group(1))
        failed += int(m.group(2))
        failed_names += [l[len("failed: "):] for l in lines if l.startswith("failed: ")]
        if p.returncode != 0 and int(m.group(2)) == 0:
            failed += 1
            failed_names.append("shard-%d(exit %d)" % (i, p.returncode))
    log("hostile battery took %.0f s (%d processes)" % (time.time() - t_all, jobs))
    if failed_names:
        log("failed: " + " ".join(failed_names))
    log("%d passed, %d failed" % (passed, failed))
    return 0 if not failed else 1


def main():
    global ARGS, OUT
    ap = argparse.ArgumentParser()
    ap.add_argument("--oceand", default="build/oceand")
    ap.add_argument("-k", default="", help="run only cases whose name contains one of these (comma-separated)")
    ap.add_argument("--json", action="store_true", help="figures as JSON lines on stdout, log on stderr")
    ap.add_argument("--strict", action="store_true",
                    help="no noise allowance: < 99%% observer delivery fails even when the daemon waited for a core")
    ap.add_argument("--bench", action="store_true", help="like --json, and exit 0 even when a case fails")
    ap.add_argument("--jobs", type=int, default=1,
                    help="run the cases in this many processes at once (each case keeps its own daemon and "
                         "observer; the battery mostly waits on observer windows); logs printed in order")
    ap.add_argument("--shard", default="0/1", help=argparse.SUPPRESS)   # I/N: cases I, I+N, ... (--jobs uses it)
    ARGS = ap.parse_args()
    if ARGS.json or ARGS.bench:
        OUT = sys.stderr
        ARGS.jobs = 1          # figures are measured with the battery alone on the machine
    if ARGS.jobs > 1:
        sys.exit(run_jobs(ARGS.jobs))
    if ARGS.shard == "solo":
        cases = [fn for fn in CASES if solo(fn)]
    else:
        shard, shards = (int(x) for x in ARGS.shard.split("/"))
        cases = CASES if shards == 1 else [fn for fn in CASES if not solo(fn)][shard::shards]
    passed = failed = 0
    failed_names = []
    t_all = time.time()
    for fn in cases:
        if not any(k in fn.__name__ for k in ARGS.k.split(",")):
            continue
        log("--- %s" % fn.__name__)
        t0 = time.time()
        fig = {"bench": "hostile", "case": fn.__name__}
        try:
            run_case(fn, fig)
            fig["ok"] = True
            passed += 1
            log("ok   %s (%.1f s): observer %.1f%% of %s frames, RSS %+d kB, overruns %d"
                % (fn.__name__, time.time() - t0, 100 * fig["observer_share"], fig["observer_span"],
                   fig["rss_growth_kb"], fig["overruns"]))
        except Exception as e:
            fig.update(ok=False, error=str(e)[:300])
            failed += 1
            failed_names.append(fn.__name__)
            log("FAIL %s (%.1f s): %s" % (fn.__name__, time.time() - t0, e))
            if not isinstance(e, CaseFailure):
                traceback.print_exc(file=OUT)
        if ARGS.json or ARGS.bench:
            print(json.dumps(fig), flush=True)
    log("hostile battery took %.0f s" % (time.time() - t_all))
    if failed_names:
        log("failed: " + " ".join(failed_names))
    log("%d passed, %d failed" % (passed, failed))
    sys.exit(0 if ARGS.bench or not failed else 1)



# ---------------------------------------------------------------- outside battery: status pages, subscriptions, names, state

import urllib.error     # noqa: E402  (oceand_alone waits for /healthz)
import urllib.request   # noqa: E402

def http_exchange(s, request):
    """Send one request on a kept-alive socket; return (status line, headers dict, body) read by its
    Content-Length (none for HEAD). Reads nothing past the response it expects."""
    s.sendall(request.encode())
    head = read_http_response(s)
    check(head.endswith(b"\r\n\r\n"), "no complete response head to %r: %r" % (request.split("\r\n")[0], head[:200]))
    lines = head.decode(errors="replace").split("\r\n")
    hdrs = {}
    for line in lines[1:]:
        if ":" in line:
            k, _, v = line.partition(":")
            hdrs[k.strip().lower()] = v.strip()
    body = b""
    if not request.startswith("HEAD "):
        n = int(hdrs.get("content-length", "0"))
        s.settimeout(5)
        while len(body) < n:
            c = s.recv(n - len(body))
            if not c:
                break
            body += c
    return lines[0], hdrs, body


@case(web=True)
def head_requests(d, fig):
    """HEAD on /healthz, /metrics, a static file, / and missing paths, each on one kept-alive
    connection after a GET of the same path: the same status, type and Content-Length as the
    GET (RFC 9110 §9.3.2; the status pages' length may differ between the two, their content
    moves), no body: the next response on the connection starts with its status line. The
    daemon answered HEAD /healthz and /metrics with 404 and a 173-byte HTML body."""
    host = "Host: 127.0.0.1:%d\r\n" % d.port
    got = {}
    bad = []
    for path in ("/healthz", "/metrics", "/index.html", "/", "/missing", "/no/such/file.js"):
        s = socket.create_connection(("127.0.0.1", d.port), timeout=5)
        try:
            g_status, g_hdrs, _ = http_exchange(s, "GET %s HTTP/1.1\r\n%s\r\n" % (path, host))
            h_status, h_hdrs, _ = http_exchange(s, "HEAD %s HTTP/1.1\r\n%s\r\n" % (path, host))
            n_status, _, n_body = http_exchange(s, "GET /healthz HTTP/1.1\r\n%s\r\n" % host)
        finally:
            s.close()
        got[path] = h_status
        if h_status != g_status:
            bad.append("%s: HEAD %r, GET %r" % (path, h_status, g_status))
        if h_hdrs.get("content-type") != g_hdrs.get("content-type"):
            bad.append("%s: HEAD type %r, GET %r" % (path, h_hdrs.get("content-type"), g_hdrs.get("content-type")))
        if path not in ("/healthz", "/metrics") and h_hdrs.get("content-length") not in (None, g_hdrs.get("content-length")):
            bad.append("%s: HEAD length %r, GET %r" % (path, h_hdrs.get("content-length"), g_hdrs.get("content-length")))
        if not n_status.startswith("HTTP/1.1 200") or not n_body.startswith(b"{"):
            bad.append("%s: the request after HEAD got %r %r (a body was sent with the HEAD)" % (path, n_status, n_body[:40]))
    fig["head_status"] = got
    log("    HEAD: %s" % ", ".join("%s %s" % (k, v.split(" ", 1)[-1]) for k, v in got.items()))
    check(not bad, "; ".join(bad))


@case(args=LIBERAL)
def foam_finer_cascade(d, fig):
    """foam asked of a finer cascade: the frame builder makes foam for cascade 0 only and the
    fan-out sends a client no frame that lacks one of its layers, so such a subscription was
    accepted and then nothing arrived, not even cascade 0. Now named it is bad_subscription
    (the subscription in force unchanged, frames keep coming); inherited from the top level's
    fields it is left out, and frames arrive."""
    fig["messages"] = expect_errors(d, [
        ('{"type":"subscribe","id":1,"cascades":[{"fields":["foam"]}]}', "bad_subscription", None),
        ('{"type":"subscribe","id":2,"fields":["height","foam"],"cascades":[{"fields":["height","foam"]}]}',
         "bad_subscription", None),
        ('{"type":"subscribe","id":3,"cascades":[{"fields":["height"]},{"fields":["dx","foam"],"lod":1}]}',
         "bad_subscription", None),
        ('{"type":"subscribe","id":4,"fields":["foam"],"cascades":[{"lod":1}]}', "bad_subscription", None),
    ])
    s, r = attacker(d)
    m = ask(s, r, '{"type":"subscribe","id":5,"cascades":[{"fields":["foam","height"]}]}')
    check(m and m.get("code") == "bad_subscription", "foam in cascade 1: %r" % (m,))
    n0 = r.binary
    check(r.until(lambda r: r.binary >= n0 + 5, 5), "frames stopped after a refused subscribe")
    m = ask(s, r, '{"type":"subscribe","id":6,"fields":["height","foam"],"cascades":[{"lod":1}]}')
    check(m and m.get("type") == "subscribed", "foam inherited by cascade 1: %r" % (m,))
    casc = (m.get("subscription") or m).get("cascades")
    fig["inherited"] = casc
    check(casc and "foam" not in casc[0].get("fields", []), "cascade 1 inherited foam: %r" % (casc,))
    n1 = r.binary
    ok = r.until(lambda r: r.binary >= n1 + 5, 5)
    fig["frames_after"] = r.binary - n1
    s.close()
    check(ok, "no frames after subscribing height+foam with a finer cascade (%d)" % (r.binary - n1))


@case(args=LIBERAL)
def upgrade_header_whitespace(d, fig):
    """`Upgrade:` followed by 40 blanks before `websocket` (optional whitespace, RFC 9110
    §5.6.3): the frame guard kept 39 bytes of a header line, lost the value and closed
    a legal client. Also 200 blanks, and 50 blanks before a Content-Length (the guard must
    skip exactly that body). (A tab as that whitespace is refused by lws 4.1 itself, 403.)"""
    p = d.port
    variants = {
        "spaces40": "Upgrade:" + " " * 40 + "websocket",
        "spaces200": "Upgrade:" + " " * 200 + "websocket",
    }
    for name, line in variants.items():
        req = ("GET / HTTP/1.1\r\nHost: 127.0.0.1:%d\r\n%s\r\nConnection: Upgrade\r\n"
               "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
               "Sec-WebSocket-Protocol: oceand.v1\r\n\r\n" % (p, line))
        s = socket.create_connection(("127.0.0.1", p), timeout=5)
        s.sendall(req.encode())
        resp = read_http_response(s)
        check(b" 101 " in resp.split(b"\r\n")[0], "%s: handshake refused: %r" % (name, resp[:100]))
        r = Reader(s)
        check(r.until(lambda r: any(t.get("type") == "hello" for t in r.texts), 5), "%s: no hello" % name)
        m = ask(s, r, '{"type":"ping","id":1}')
        fig[name] = m.get("type") if m else ("closed %r" % r.close_code)
        s.close()
        check(m and m.get("type") == "pong", "%s: ping after the upgrade: %r (close %r)" % (name, m, r.close_code))
    # A POST with a body whose Content-Length has 50 blanks before it, then an upgrade: the guard
    # must skip exactly that body to read the upgrade's head.
    s = socket.create_connection(("127.0.0.1", p), timeout=5)
    body = "x" * 37
    s.sendall(("POST /nothing HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nContent-Length:%s%d\r\n\r\n%s"
               % (p, " " * 50, len(body), body)).encode())
    first = read_http_response(s)
    fig["post_status"] = first.split(b"\r\n")[0].decode(errors="replace")
    check(first.startswith(b"HTTP/1.1 "), "POST with a padded Content-Length: %r" % first[:80])
    n = int(re.search(rb"(?i)content-length: *(\d+)", first).group(1))
    while n > 0:
        n -= len(s.recv(n))
    s.sendall(handshake_request(p))
    resp = read_http_response(s)
    check(b" 101 " in resp.split(b"\r\n")[0], "upgrade after the POST: %r" % resp[:100])
    r = Reader(s)
    check(r.until(lambda r: any(t.get("type") == "hello" for t in r.texts), 5), "no hello after the POST")
    m = ask(s, r, '{"type":"ping","id":2}')
    s.close()
    check(m and m.get("type") == "pong", "ping after the POST and upgrade: %r (close %r)" % (m, r.close_code))


@case(args=LIBERAL)
def name_invisible_and_reserved(d, fig):
    """Display names with invisible format characters (general category Cf) that the older
    list missed: U+061C (Arabic letter mark, the one bidi control let through), tag characters
    U+E0001 and U+E0041, U+180E, U+0600, U+1D173; and names that read as the page's own words
    ("you" in any case, with spaces of other kinds around it; "the server"). Each bad_name;
    near misses are still names."""
    bad = ["a\u061cb", "x\U000E0001y", "\U000E0041", "m\u180en", "\u0600x", "d\U0001D173e", "x\u2066y",
           "you", "You", "YOU", "you\u00a0", "\u3000you", "the server", "The  Server", "the\u00a0server"]
    good = ["youth", "Yours", "you2", "the servers", "y o u", "\u00e9you"]
    s, r = attacker(d)
    wrong = []
    for i, n in enumerate(bad + good):
        n0 = len(r.texts)
        check(send_quiet(s, ws_frame(OP_TEXT, json.dumps({"type": "name", "id": i, "name": n}))), "connection closed")
        r.until(lambda r: any(t.get("id") == i for t in r.texts[n0:]), 5)
        m = next((t for t in r.texts[n0:] if t.get("id") == i), None)
        want = "bad_name" if n in bad else "named"
        if not m or (m.get("code") if m.get("type") == "error" else m.get("type")) != want:
            wrong.append("%r: %s, want %s" % (n, json.dumps(m)[:80] if m else "no reply", want))
    s.close()
    fig["names"] = len(bad) + len(good)
    check(not wrong, "; ".join(wrong))


def oceand_alone(args, wait_s=60):
    """An oceand on a free port with exactly these extra arguments (no --resolution, no
    --max-memory-mb unless given): (process, port, log path, temp dir), once /healthz answers,
    or (process, None, log, dir) if it exited first."""
    tmp = tempfile.mkdtemp(prefix="oceand-hostile-")
    port = free_port_local()
    logp = os.path.join(tmp, "oceand.log")
    with open(logp, "wb") as lf:
        p = subprocess.Popen([ARGS.oceand, "--bind", "127.0.0.1", "--port", str(port), "--wisdom-file", "none",
                              "--web-root", os.path.join(tmp, "web"), "--log-level", "info"] + list(args),
                             stdout=lf, stderr=lf)
    deadline = time.time() + wait_s
    while time.time() < deadline and p.poll() is None:
        try:   # /healthz answers once the service loop runs (after the start-up measurements)
            urllib.request.urlopen("http://127.0.0.1:%d/healthz" % port, timeout=1).read()
            return p, port, logp, tmp
        except (urllib.error.URLError, ConnectionError, OSError):
            time.sleep(0.1)
    return p, (port if p.poll() is None else None), logp, tmp


def free_port_local():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_alone(p, tmp):
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    shutil.rmtree(tmp, ignore_errors=True)


@case()
def state_over_memory_cap(d, fig):
    """A saved state that does not fit the memory cap, at start-up. (1) resolution 2048 with 3
    cascades under --max-memory-mb 160: the daemon starts at the largest N that fits with the
    saved cascades (512; a live `set` of 2048 is refused), and the log says so. (2) 4 saved
    cascades with --resolution 256 from the command line under --max-memory-mb 40 (256 x 4 does
    not fit, 256 x 3 does): the daemon used to refuse to start; now it drops to 3 cascades and
    says so. The first's peak RSS stays under its cap."""
    results, problems = {}, []
    for name, state, args, want in (
            ("saved_n", {"resolution": 2048, "cascades": 3}, ["--max-memory-mb", "160"], (512, 3)),
            ("saved_cascades", {"resolution": 256, "cascades": 4}, ["--max-memory-mb", "40", "--resolution", "256"],
             (256, 3))):
        tmpd = tempfile.mkdtemp(prefix="oceand-state-")
        sp = os.path.join(tmpd, "state.json")
        with open(sp, "w") as f:
            json.dump({"params": state, "params_version": 4, "sim_time": 1}, f)
        p, port, logp, tmp = oceand_alone(["--state-file", sp] + args)
        try:
            with open(logp, "rb") as f:
                text = f.read().decode(errors="replace")
            if port is None:
                problems.append("%s: the daemon did not start (exit %r): %s" % (name, p.poll(), text[-200:].strip()))
                continue
            s, _ = raw_ws(port)
            r = Reader(s)
            check(r.until(lambda r: any(t.get("type") == "hello" for t in r.texts), 10), "%s: no hello" % name)
            h = [t for t in r.texts if t.get("type") == "hello"][0]
            got = (h["params"]["resolution"], h["params"]["cascades"])
            m = ask(s, r, '{"type":"set","id":1,"params":{"resolution":2048,"cascades":3}}')
            s.close()
            with open("/proc/%d/status" % p.pid) as f:
                hwm_kb = next((int(l.split()[1]) for l in f if l.startswith("VmHWM:")), 0)
            with open(logp, "rb") as f:
                text = f.read().decode(errors="replace")
            warned = "saved" in text and "memory" in text
            cap_mb = int(args[1])
            results[name] = dict(got=got, peak_mb=round(hwm_kb / 1024), warned=warned,
                                 live_set=m.get("code") if m else None)
            if got != want:
                problems.append("%s: started with (N, cascades) %r, want the largest fit %r" % (name, got, want))
            if not warned:
                problems.append("%s: no log line about the saved state over the memory cap" % name)
            if not m or m.get("code") != "invalid":
                problems.append("%s: a live set of N 2048 x 3: %r" % (name, m))
            # The cap is the simulation's; the process adds ~25 MB of its own, so the peak is
            # compared with the larger cap only (88 MB of 160 here; 2048 x 3 took 1.7 GB).
            if cap_mb >= 100 and hwm_kb >= cap_mb * 1024:
                problems.append("%s: peak RSS %d MB over the cap of %d MB" % (name, hwm_kb // 1024, cap_mb))
        finally:
            stop_alone(p, tmp)
            shutil.rmtree(tmpd, ignore_errors=True)
    fig.update(results)
    log("    %s" % results)
    check(not problems, "; ".join(problems))


# ---------------------------------------------------------------- limits: what the daemon reaches, it restores
# Each case starts daemons of its own from a state file it writes.

VERSION_MAX = 2 ** 32 - 1       # params_version is a u32 in every frame header (PROTOCOL.md §7.7)
TIME_MAX = 1e9                  # OCEAN_TIME_MAX: the sea's clock stops there


def alone_from_state(state, *args):
    """oceand_alone at N = 64 from a state file holding `state`: (process, port, log, dir, state path)."""
    tmpd = tempfile.mkdtemp(prefix="oceand-limit-")
    sp = os.path.join(tmpd, "state.json")
    with open(sp, "w") as f:
        json.dump(state, f)
    p, port, logp, tmp = oceand_alone(["--state-file", sp, "--resolution", "64"] + list(args))
    return p, port, logp, tmp, tmpd, sp


def hello_of(port):
    s, _ = raw_ws(port)
    r = Reader(s)
    check(r.until(lambda r: any(t.get("type") == "hello" for t in r.texts), 10), "no hello")
    return s, r, [t for t in r.texts if t.get("type") == "hello"][0]


def query_height(s, r, i):
    """The height at (10, 20) now, by a query (PROTOCOL.md §7.4)."""
    n0 = len(r.texts)
    check(send_quiet(s, ws_frame(OP_TEXT, '{"type":"query","id":%d,"points":[[10,20]]}' % (100 + i))), "query not sent")
    r.until(lambda r: any(t.get("id") == 100 + i for t in r.texts[n0:]), 10)
    ans = [t for t in r.texts[n0:] if t.get("id") == 100 + i]
    check(ans and ans[0].get("type") == "query_result", "query: %r" % (ans[:1],))
    return ans[0]["points"][0]["height"]


@case()
def version_at_its_limit(d, fig):
    """A state file at params_version 2^32 - 2 was accepted, and the next three sets were
    acknowledged as 2^32 - 1, 0, 1 (frames too): a version used for two seas. Now the last
    number is used once, further changes get `version_limit` and change nothing, and a
    restart from the file the daemon saved there loads that version again (the loader's
    limit is the running daemon's)."""
    p, port, logp, tmp, tmpd, sp = alone_from_state(
        {"params": {"wind_speed": 10}, "params_version": VERSION_MAX - 1, "sim_time": 5})
    got = {}
    try:
        check(port is not None, "the daemon did not start from version %d" % (VERSION_MAX - 1))
        s, r, h = hello_of(port)
        check(h["params_version"] == VERSION_MAX - 1, "hello version %r" % h["params_version"])
        m = ask(s, r, '{"type":"set","id":1,"params":{"wind_speed":11}}')
        check(m and m.get("type") == "params" and m["params_version"] == VERSION_MAX, "last set: %r" % m)
        for i, text in enumerate(('{"type":"set","id":2,"params":{"wind_speed":12}}', '{"type":"pause","id":3}',
                                  '{"type":"set","id":4,"params":{"seed":9}}')):
            m = ask(s, r, text)
            got[text] = m.get("code") if m else None
            check(m and m.get("type") == "error" and m.get("code") == "version_limit",
                  "a change past the last version: %r" % m)
        m = ask(s, r, '{"type":"set","id":5,"params":{"wind_speed":11}}')   # changes nothing: needs no number
        check(m and m.get("type") == "params" and m["params_version"] == VERSION_MAX and m["changed"] == [],
              "a set that changes nothing: %r" % m)
        s.close()
        s, r, h = hello_of(port)
        s.close()
        check(h["params_version"] == VERSION_MAX and h["params"]["wind_speed"] == 11 and not h["params"]["paused"],
              "after the refused changes: version %r wind %r" % (h["params_version"], h["params"]["wind_speed"]))
        with open(sp) as f:
            saved = json.load(f)
        check(saved["params_version"] == VERSION_MAX, "state file version %r" % saved["params_version"])
        stop_alone(p, tmp)
        p, port, logp, tmp = oceand_alone(["--state-file", sp, "--resolution", "64"])
        check(port is not None, "the daemon did not start again from the file it saved")
        s, r, h = hello_of(port)
        got["restarted"] = h["params_version"]
        check(h["params_version"] == VERSION_MAX and h["params"]["wind_speed"] == 11,
              "restarted from the saved file: version %r wind %r" % (h["params_version"], h["params"]["wind_speed"]))
        m = ask(s, r, '{"type":"set","id":6,"params":{"wind_speed":13}}')
        check(m and m.get("code") == "version_limit", "a set after the restart: %r" % m)
        s.close()
    finally:
        stop_alone(p, tmp)
        shutil.rmtree(tmpd, ignore_errors=True)
    fig.update(got)
    log("    %s" % got)


@case()
def clock_at_its_limit(d, fig):
    """A valid state (sim_time 999999998.5, time_scale 16) passed the clock's limit of 1e9 s
    within a second; the daemon saved 1000000030.5 and the next start refused that file and
    began at t = 0. Now the clock stops at 1e9 s (frames keep coming, of a sea standing
    still), the daemon saves 1e9, and a restart goes on from there."""
    p, port, logp, tmp, tmpd, sp = alone_from_state(
        {"params": {"time_scale": 16}, "params_version": 3, "sim_time": TIME_MAX - 1.5})
    times = []
    try:
        check(port is not None, "the daemon did not start")
        metrics = lambda: urllib.request.urlopen("http://127.0.0.1:%d/metrics" % port, timeout=5).read().decode()

        def sim_time():
            line = [l for l in metrics().splitlines() if l.startswith("oceand_sim_time_seconds ")][0]
            return float(line.split()[1])
        s, r, h = hello_of(port)
        t_end = time.time() + 1.5
        while time.time() < t_end:
            times.append(sim_time())
            time.sleep(0.1)
        n0 = r.binary
        r.until(lambda r: r.binary >= n0 + 10, 5)
        fig["sim_time_max"] = max(times)
        check(max(times) <= TIME_MAX, "the clock ran past %g s: %r" % (TIME_MAX, max(times)))
        check(times[-1] == TIME_MAX, "the clock did not reach its limit: %r" % times[-1])
        check(r.binary >= n0 + 10, "frames stopped at the clock's limit (%d)" % (r.binary - n0))
        # A change of the waves' amplitudes eases in over sim time (8 ticks): with the clock
        # stopped it must apply at once, not stay 1/8 of the way for ever. The sea then is
        # the one a restart from the saved state shows (no easing at start).
        h_before = query_height(s, r, 1)
        m = ask(s, r, '{"type":"set","id":2,"params":{"wind_speed":20}}')
        check(m and m.get("type") == "params", "a set at the clock's limit: %r" % m)
        time.sleep(0.5)
        h_after = query_height(s, r, 3)
        s.close()
        check(abs(h_after - h_before) > 1e-4, "the wind change did not reach the sea: %r -> %r" % (h_before, h_after))
        p.send_signal(signal.SIGHUP)                     # save now
        check(wait_until(lambda: json.load(open(sp)).get("sim_time") == TIME_MAX, 5),
              "saved sim_time %r" % json.load(open(sp)).get("sim_time"))
        stop_alone(p, tmp)
        p, port, logp, tmp = oceand_alone(["--state-file", sp, "--resolution", "64"])
        check(port is not None, "the daemon did not start again from the file it saved")
        with open(logp, "rb") as f:
            text = f.read().decode(errors="replace")
        check("ignoring" not in text and "starting from 0" not in text, "the saved clock was refused: %s" % text[-300:])
        fig["restarted_at"] = sim_time()
        check(sim_time() == TIME_MAX, "restarted at sim time %r, saved %g" % (sim_time(), TIME_MAX))
        s, r, h = hello_of(port)
        h_restarted = query_height(s, r, 4)
        s.close()
        fig["heights"] = [h_before, h_after, h_restarted]
        check(abs(h_after - h_restarted) < 1e-6, "the eased sea at the limit %r is not the saved one's %r"
              % (h_after, h_restarted))
    finally:
        stop_alone(p, tmp)
        shutil.rmtree(tmpd, ignore_errors=True)
    log("    clock %.1f .. %.1f s; restarted at %r" % (min(times or [0]), max(times or [0]), fig.get("restarted_at")))


def nats_alone():
    """A nats-server on a free 127.0.0.1 port: (process, url), or (None, reason)."""
    exe = shutil.which("nats-server") or "/usr/sbin/nats-server"
    if not os.path.exists(exe):
        return None, "nats-server not installed"
    port = free_port_local()
    p = subprocess.Popen([exe, "-a", "127.0.0.1", "-p", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 10
    while time.time() < deadline and p.poll() is None:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return p, "nats://127.0.0.1:%d" % port
        except OSError:
            time.sleep(0.05)
    p.kill()
    p.wait()
    return None, "nats-server did not listen"


@case()
def healthz_many_layers(d, fig):
    """/healthz of a cluster edge (and its sim) while the edge's viewers want 100 distinct layers
    (4 viewers: 7 fields of cascade 0 and 6 of cascades 1..3, each viewer at its own LOD and
    bound). The layer list took /healthz past a fixed 1 KiB buffer and the answer ended
    mid-name (invalid JSON: every monitor that parses it broke). Now it parses, lists every
    layer, and the sim's lists them too once the edge's demand reaches it."""
    nats, url = nats_alone()
    check(nats is not None, url)
    sim = edge = None
    socks = []
    try:
        sim = Daemon(ARGS.oceand, "--role", "sim", "--nats", url)
        edge = Daemon(ARGS.oceand, "--role", "edge", "--nats", url)
        six = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian"]
        for i, (lod, bound) in enumerate(((0, 0.01), (1, 0.005), (2, 0.05), (3, 0.001))):
            s, r = attacker(edge)
            socks.append(s)
            msg = {"type": "subscribe", "id": i, "fields": six + ["foam"], "lod": lod, "bound": bound,
                   "cascades": [{"fields": six}] * 3}
            send_quiet(s, ws_frame(OP_TEXT, json.dumps(msg)))
        want = 4 * (7 + 3 * 6)

        def layers(dmn):
            text = dmn.get("/healthz")
            try:
                h = json.loads(text)
            except ValueError:
                raise CaseFailure("%s /healthz is not JSON (%d bytes, ends %r)" % (dmn.port, len(text), text[-30:]))
            return h.get("layers") or []
        ok = wait_until(lambda: len(layers(edge)) >= want, 10)
        fig["edge_layers"] = len(layers(edge))
        fig["edge_bytes"] = len(edge.get("/healthz"))
        check(ok, "edge /healthz lists %d layers, want %d" % (fig["edge_layers"], want))
        ok = wait_until(lambda: len(layers(sim)) >= want, 10)
        fig["sim_layers"] = len(layers(sim))
        log("    edge /healthz: %d layers in %d bytes; sim: %d layers" % (fig["edge_layers"], fig["edge_bytes"],
                                                                       fig["sim_layers"]))
        check(ok, "sim /healthz lists %d layers, want %d" % (fig["sim_layers"], want))
    finally:
        for s in socks:
            s.close()
        for dmn in (edge, sim):
            if dmn:
                dmn.stop()
                shutil.rmtree(dmn.tmp, ignore_errors=True)
        nats.kill()
        nats.wait()


# Both start daemons of their own (an N = 512 start-up with 3 cascades; a sim, an edge and a
# nats-server): alone, like the other cases that load the machine.
SOLO.update({"state_over_memory_cap", "healthz_many_layers"})


# ---------------------------------------------------------------- ids as sent, render counts, strict files, warm-ups

def warmed_up(fig, rss_kb):
    """A case's RSS after its own warm-up: run_case judges "flat" from here, not from before
    the case (the warm-up's one-time growth, allocator arenas and lws pools, is no leak: a
    churn run once went red at +1036 kB where its per-round check passed)."""
    fig["rss_warm_kb"] = rss_kb


EXACT_IDS = ["9007199254740993", "9223372036854775807", "18446744073709551615", "-9223372036854775809",
             "123456789012345678901234567890", "1e400", "-1e400", "1.0", "1E+2", "-0", "2.5e-3", "42"]


def reply_id_text(raw, member="id"):
    """The "id" (or another member) of a reply exactly as written (numbers as their own text,
    not rounded by a float parse), "" when it has none; None when the reply is not JSON."""
    try:
        m = json.loads(raw, parse_int=str, parse_float=str, parse_constant=str)
    except ValueError:
        return None
    if not isinstance(m, dict) or member not in m:
        return ""
    return m[member] if isinstance(m[member], str) else json.dumps(m[member])


# 12 renders and sea changes (each render makes and frees a simulation): up to 1.3 MB of allocator
# churn seen after the warm-up, no trend; the leak checks are churn's and render_abuse's.
@case(args=("--control-rate", "50", "--control-burst", "300", "--control-budget", "1e7"), changes_params=True,
      rss_slack_kb=4096)
def ids_as_sent(d, fig):
    """cJSON holds numbers as doubles: an id of 2^53 + 1 came back as 9.00719925474099e+15,
    2^63 - 1 as 9.2233720368547758e+18, 1e400 as null, on every reply (a client with 64-bit
    ids could not match its replies). Each request type with each of these ids: the reply
    carries the id's own text (PROTOCOL.md §7), the rate_limited refusal too; a number that
    is not JSON (cJSON takes "01") is refused with bad_json, not echoed."""
    s, r = attacker(d)
    sub = ask(s, r, '{"type":"subscribe","fields":[]}')    # control only: no live frames
    check(sub and sub.get("type") == "subscribed", "subscribe: %r" % (sub,))
    requests = [   # (message with %s for the id, the reply types it gets)
        ('{"type":"ping","id":%s,"t":TOKEN}', ["pong"]),     # t is echoed as sent too
        ('{"type":"set","id":%s,"params":{"wind_speed":75}}', ["error"]),
        ('{"type":"set","id":%s,"params":{"wind_speed":WIND}}', ["params"]),
        ('{"type":"pause","id":%s}', ["params"]),
        ('{"type":"resume","id":%s}', ["params"]),
        ('{"type":"subscribe","id":%s,"fields":[]}', ["subscribed"]),
        ('{"type":"name","id":%s,"name":"Ana"}', ["named"]),
        ('{"type":"query","id":%s,"points":[[1,2]]}', ["query_result"]),
        ('{"type":"query","id":%s,"points":[[1,2]],"time":-1e9}', ["error"]),
        ('{"type":"probe","id":%s,"points":[[0,0]]}', ["probing"]),
        ('{"type":"probe","id":%s,"points":[]}', ["probing"]),
        ('{"type":"render","id":%s,"start":1,"fps":10,"frames":1,"fields":["height"],"lod":3,"bound":0.05}',
         ["rendering", "rendered"]),
        ('{"type":"jump","id":%s}', ["error"]),
    ]
    bad, n = [], 0
    for k, token in enumerate(["1"] + EXACT_IDS):   # id 1 first: the warm-up (a render and a query worker's first job)
        if k == 1:
            time.sleep(0.5)
            warmed_up(fig, d.rss_kb())
        for req, types in requests:
            text = req.replace("WIND", "%g" % (10 + k % 5 + 0.5)).replace("TOKEN", token) % token
            n0 = len(r.raw)
            check(send_quiet(s, ws_frame(OP_TEXT, text)), "closed while sending %r" % text)
            n += 1

            def got(r):   # the replies of these types that came after the request
                return [x for x, t in zip(r.raw[n0:], r.texts[n0:]) if t.get("type") in types]
            r.until(lambda r: len(got(r)) >= len(types), 5)
            replies = got(r)
            if len(replies) < len(types):
                bad.append("%s: replies %s, want %s" % (text[:70], [t.get("type") for t in r.texts[n0:]], types))
            for x in replies:
                echoed = reply_id_text(x)
                if echoed != token:
                    bad.append("%s: id came back as %r" % (text[:70], echoed))
                if types == ["pong"] and reply_id_text(x, "t") != token:
                    bad.append("%s: t came back as %r" % (text[:70], reply_id_text(x, "t")))
    # Refused unread (rate_limited): the id is echoed from its text as well.
    token = EXACT_IDS[0]
    n0 = len(r.raw)
    for k in range(8):    # in batches, read between: more than 256 replies queued would close us (1008)
        for _ in range(50):
            send_quiet(s, ws_frame(OP_TEXT, '{"type":"ping","id":%s}' % token))
        r.until(lambda r: sum(1 for t in r.texts[n0:] if t.get("type") in ("pong", "error")) >= 50 * (k + 1), 10)
    limited = [x for x, t in zip(r.raw[n0:], r.texts[n0:]) if t.get("code") == "rate_limited"]
    wrong = [reply_id_text(x) for x in limited if reply_id_text(x) != token]
    # Numbers cJSON reads but JSON does not have: refused, never echoed as invalid JSON.
    time.sleep(1.5)   # the bucket refills
    refused = []
    for token in ("01", "-01", "1.", "1.e5"):
        m = ask(s, r, '{"type":"ping","id":%s}' % token)
        if not m or m.get("type") != "error" or m.get("code") != "bad_json" or "id" in m:
            refused.append("%s: %r" % (token, m))
    s.close()
    fig.update(ids=len(EXACT_IDS), requests=n, wrong=len(bad), rate_limited=len(limited))
    log("    %d requests with %d ids: %d wrong; %d rate_limited refusals, %d with a changed id"
        % (n, len(EXACT_IDS), len(bad), len(limited), len(wrong)))
    check(not bad, "; ".join(bad[:6]) + (" (%d in all)" % len(bad) if len(bad) > 6 else ""))
    check(limited, "400 pings at once: none refused rate_limited (the case measures nothing)")
    check(not wrong, "rate_limited echoed the id as %r, want %s" % (wrong[:3], EXACT_IDS[0]))
    check(not refused, "ids that are not JSON numbers: %s" % "; ".join(refused))


@case(resolution=256, rss_slack_kb=8 * 1024)
def render_count_delivered(d, fig):
    """`rendered.frames` said how many frames the render worker made, not how many reached
    the client: a client that stopped reading for 1 s and cancelled was told 5 where 2 arrived
    (the queued ones are dropped at the cancel). Renders of large lossless frames to a client
    with a 4 KiB receive buffer that stops reading for 0.2 .. 1 s, then cancels and reads on:
    `frames` equals the binary frames it received, every cycle; and once without a stall."""
    s, r = attacker(d, rcvbuf=4096)
    m = ask(s, r, '{"type":"subscribe","fields":[]}')    # no live frames: every binary one is the render's
    check(m and m.get("type") == "subscribed", "subscribe: %r" % (m,))
    req = {"type": "render", "start": 10, "fps": 30, "frames": 300, "fields": ["height", "dx", "dz"], "lod": 0,
           "bound": 0}
    cycles, bad = [], []
    for k, stall in enumerate((0.2, 1.0, 0.5, 1.0, 0.3, 0.8, 0.0)):
        b0, n0 = r.binary, len(r.texts)
        send_quiet(s, ws_frame(OP_TEXT, json.dumps(dict(req, id=k))))
        if stall:
            time.sleep(stall)                       # reads nothing: the daemon's window fills
        else:
            r.until(lambda r: r.binary - b0 >= 3, 10)
        send_quiet(s, ws_frame(OP_TEXT, '{"type":"render_cancel"}'))
        ok = r.until(lambda r: any(t.get("type") in ("rendered", "error") and t.get("id") == k
                                   for t in r.texts[n0:]), 20)
        end = [t for t in r.texts[n0:] if t.get("type") in ("rendered", "error") and t.get("id") == k]
        if not ok or end[0].get("type") != "rendered":
            bad.append("cycle %d: no rendered (%r)" % (k, end[:1]))
            break
        # the frames before `rendered` (it comes after its render's last frame)
        got = r.bin_at[n0 + r.texts[n0:].index(end[0])] - b0
        told = end[0].get("frames")
        cycles.append((stall, told, got))
        if told != got:
            bad.append("cycle %d (stalled %.1f s): told %r frames, %d arrived" % (k, stall, told, got))
        if end[0].get("reason") != "cancelled" or told >= req["frames"]:
            bad.append("cycle %d: not cancelled: %r" % (k, end[0]))
    s.close()
    fig.update(cycles=cycles)
    log("    (stall s, told, arrived): %s" % cycles)
    check(not bad, "; ".join(bad))
    check(any(got > 0 for _, _, got in cycles), "no render frame arrived at all: the case measures nothing")


NUL_TOKEN = "abcdefghijklmnopqrstuvwxyz0123456789"


@case()
def nul_in_files(d, fig):
    """A NUL in the config or state file cut strings: {"control_token":"abc\\u0000def..."}
    (or a raw NUL byte) left the token "abc", and a set carrying "abc" was applied; a saved
    "spectrum":"phillips\\u0000-not-a-spectrum" was applied as phillips. Every file loader
    now uses the control path's strict scan: such a config file stops the daemon at start
    with a message naming the NUL (exit 2); such a state file is ignored with that warning
    (docs/daemon.md: a corrupt state file is ignored), the sea starts from the defaults."""
    tmp = tempfile.mkdtemp(prefix="oceand-nul-")
    problems, results = [], {}
    try:
        cfg = os.path.join(tmp, "c.json")
        for name, body in (("escaped", b'{"control_token":"abc\\u0000' + NUL_TOKEN[3:].encode() + b'"}'),
                           ("raw", b'{"control_token":"abc\x00' + NUL_TOKEN[3:].encode() + b'"}')):
            with open(cfg, "wb") as f:
                f.write(body)
            rc, out = run_oceand(["--config", cfg, "--state-file", "none"], timeout=8)
            results["config_" + name] = rc
            if rc != 2 or "c.json" not in out or "bad_json" not in out or ("NUL" not in out and "0x00" not in out):
                problems.append("config with a %s NUL in the token: exit %r, %r" % (name, rc, out.strip()[-200:]))
        spath = os.path.join(tmp, "state.json")
        for name, spectrum in (("escaped", b'"phillips\\u0000-not-a-spectrum"'),
                               ("raw", b'"phillips\x00-not-a-spectrum"')):
            with open(spath, "wb") as f:
                f.write(b'{"params":{"spectrum":' + spectrum + b',"wind_speed":13},"params_version":5,"sim_time":3}')
            p, port, logp, ptmp = oceand_alone(["--state-file", spath, "--resolution", "64"])
            try:
                if port is None:
                    problems.append("state with a %s NUL: the daemon did not start (exit %r)" % (name, p.poll()))
                    continue
                hs, _ = raw_ws(port)
                hr = Reader(hs)
                hr.until(lambda r: any(t.get("type") == "hello" for t in r.texts), 10)
                hs.close()
                h = next(t for t in hr.texts if t.get("type") == "hello")
                with open(logp, "rb") as f:
                    text = f.read().decode(errors="replace")
                warned = "ignoring saved state" in text and "bad_json" in text
                got = (h["params"]["spectrum"], h["params"]["wind_speed"], h["params_version"])
                results["state_" + name] = dict(got=got, warned=warned)
                if got[0] == "phillips" or got[1] == 13 or got[2] == 5:
                    problems.append("state with a %s NUL applied: spectrum %r, wind %r, version %r" % ((name,) + got))
                if not warned:
                    problems.append("state with a %s NUL: no warning naming it (log %r)" % (name, text[-300:]))
            finally:
                stop_alone(p, ptmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    fig.update(results)
    log("    %s" % results)
    check(not problems, "; ".join(problems))


@case()
def ids_as_sent_through_an_edge(d, fig):
    """The same through a cluster: an edge forwards set, query and probe to the sim (a set with
    the client's display name added, re-printed), the sim answers, the edge relays the answer's
    text. The ids come back as sent on each, and on what the edge answers itself."""
    nats, url = nats_alone()
    check(nats is not None, url)
    sim = edge = None
    bad, n = [], 0
    try:
        sim = Daemon(ARGS.oceand, "--role", "sim", "--nats", url)
        edge = Daemon(ARGS.oceand, "--role", "edge", "--nats", url, *LIBERAL)
        s, r = attacker(edge)
        ask(s, r, '{"type":"name","name":"Ana"}')   # so the edge adds it to each forwarded set
        requests = [
            ('{"type":"ping","id":%s,"t":1}', "pong"),
            ('{"type":"set","id":%s,"params":{"wind_speed":75}}', "error"),       # refused at the edge
            ('{"type":"set","id":%s,"params":{"wind_speed":WIND}}', "params"),    # applied by the sim
            ('{"type":"query","id":%s,"points":[[1,2]]}', "query_result"),
            ('{"type":"probe","id":%s,"points":[[0,0]]}', "probing"),
            ('{"type":"probe","id":%s,"points":[]}', "probing"),
        ]
        for k, token in enumerate(EXACT_IDS[:7]):
            for req, want in requests:
                text = req.replace("WIND", "%g" % (11 + k % 3)) % token
                n0 = len(r.raw)
                send_quiet(s, ws_frame(OP_TEXT, text))
                n += 1
                r.until(lambda r: any(t.get("type") == want for t in r.texts[n0:]), 10)
                got = [x for x, t in zip(r.raw[n0:], r.texts[n0:]) if t.get("type") == want]
                if not got:
                    bad.append("%s: replies %s" % (text[:60], [t.get("type") for t in r.texts[n0:]]))
                elif reply_id_text(got[0]) != token:
                    bad.append("%s: id came back as %r" % (text[:60], reply_id_text(got[0])))
        s.close()
    finally:
        for dmn in (edge, sim):
            if dmn:
                dmn.stop()
                shutil.rmtree(dmn.tmp, ignore_errors=True)
        nats.kill()
        nats.wait()
    fig.update(requests=n, wrong=len(bad))
    log("    %d requests through an edge: %d wrong" % (n, len(bad)))
    check(not bad, "; ".join(bad[:6]) + (" (%d in all)" % len(bad) if len(bad) > 6 else ""))


SOLO.add("ids_as_sent_through_an_edge")   # a sim, an edge and a nats-server of its own


# ---------------------------------------------------------------- floating bodies (PROTOCOL.md §3.5, §7.6)

FRAME_MAGIC = b"OCNF"
BODY_REC = struct.Struct("<IBBbb3f4f3f")   # a BODY record's first 48 bytes (§3.5)


class BodyReader(Reader):
    """A Reader that keeps the BODY records of the latest frame header (§3.5) and every
    `bodies` message; raises nothing: a section that does not fit is kept as "corrupt"."""

    def __init__(self, s):
        super().__init__(s)
        self.records = None      # {id: record tuple} of the latest frame with a header, None before one
        self.frames_with = 0     # frames seen since the last reset (any header)
        self.corrupt = 0

    def _parse(self):
        while True:
            b = self.buf
            if len(b) < 2:
                return
            n = b[1] & 0x7F
            off = 2
            if n == 126:
                if len(b) < 4:
                    return
                n, off = struct.unpack_from("!H", b, 2)[0], 4
            elif n == 127:
                if len(b) < 10:
                    return
                n, off = struct.unpack_from("!Q", b, 2)[0], 10
            if len(b) < off + n:
                return
            if b[0] & 0x0F == OP_BIN and n >= 64:
                self._header(b[off:off + n])
            # the base class parses this one frame (texts, counts, close), then the rest
            self.buf, rest = b[:off + n], b[off + n:]
            Reader._parse(self)
            self.buf = rest

    def _header(self, p):
        if p[:4] != FRAME_MAGIC:
            return
        hs = struct.unpack_from("<H", p, 6)[0]
        if hs == 48:
            self.records, self.frames_with = {}, self.frames_with + 1
            return
        if hs < 64 or hs > len(p) or p[48:52] != b"BODY":
            return                                    # a later part (48-byte header) or another tag
        count, rsize = struct.unpack_from("<HH", p, 52)
        if rsize < 48 or 64 + count * rsize > hs:
            self.corrupt += 1
            return
        self.records = {}
        for i in range(count):
            r = BODY_REC.unpack_from(p, 64 + i * rsize)
            self.records[r[0]] = r
        self.frames_with += 1

    def fresh(self, timeout=3):
        """Records of a frame received after now."""
        self.pump(0)
        self.frames_with, self.records = 0, None
        self.until(lambda r: r.frames_with >= 2, timeout)
        return self.records

    def of_type(self, typ, n0=0):
        return [t for t in self.texts[n0:] if t.get("type") == typ]


def body_client(d, **kw):
    s, _ = raw_ws(d.port, **kw)
    r = BodyReader(s)
    check(r.until(lambda r: any(t.get("type") == "hello" for t in r.texts), 5), "body client got no hello")
    return s, r


def body_send_all(s, r, msgs, timeout=8):
    """Send every message (each with a distinct id) in one burst; return {id: [replies]} (replies with
    that id: launched/steered/removed/claimed/error), after every id has one reply or the timeout."""
    n0 = len(r.texts)
    check(send_quiet(s, b"".join(ws_frame(OP_TEXT, json.dumps(m) if isinstance(m, dict) else m) for m, _ in msgs)),
          "connection closed while sending")
    ids = [i for _, i in msgs]

    def replies():
        out = {i: [] for i in ids}
        for t in r.texts[n0:]:
            if t.get("type") in ("launched", "steered", "removed", "claimed", "error") and t.get("id") in out:
                out[t["id"]].append(t)
        return out
    r.until(lambda r: all(replies().values()), timeout)
    time.sleep(0.2)
    r.pump(0.05)
    return replies()


def one_reply(rep, i, what):
    got = rep.get(i, [])
    check(len(got) == 1, "%s (id %s): %d replies %s, want exactly one" % (what, i, len(got), [json.dumps(g)[:100] for g in got]))
    return got[0]


def coded(s, r, cases, base=100):
    """cases: [(text with %d for the id, codes, param)]. Texts that are not JSON (bad_json: the reply
    has no id) are asked one at a time; the rest in bursts of 20, matched by id. Returns what was wrong."""
    bad = []
    for text, codes, param in cases:
        if codes == ("bad_json",):
            m = ask(s, r, text % 0 if "%d" in text else text)
            if not m or code_of(m) != "bad_json":
                bad.append("%s: %r, want bad_json" % (text[:80], m))
    rest = [(t % (base + i), i + base, codes, param) for i, (t, codes, param) in enumerate(cases) if codes != ("bad_json",)]
    for k in range(0, len(rest), 20):
        chunk = rest[k:k + 20]
        rep = body_send_all(s, r, [(text, i) for text, i, _, _ in chunk])
        for text, i, codes, param in chunk:
            got = rep.get(i, [])
            if len(got) != 1:
                bad.append("%s: %d replies" % (text[:80], len(got)))
            elif code_of(got[0]) not in codes:
                bad.append("%s: %s, want %s" % (text[:80], code_of(got[0]), "/".join(codes)))
            elif param and got[0].get("param") != param:
                bad.append("%s: param %r, want %r" % (text[:80], got[0].get("param"), param))
    return bad


def code_of(m):
    return m["code"] if m.get("type") == "error" else m.get("type")


def launch_one(s, r, kind="boat", x=0.0, z=0.0, heading=0.0, i=900):
    rep = body_send_all(s, r, [({"type": "launch", "id": i, "kind": kind, "x": x, "z": z, "heading": heading}, i)])
    m = one_reply(rep, i, "launch %s at (%g, %g)" % (kind, x, z))
    check(m.get("type") == "launched", "launch %s at (%g, %g): %r" % (kind, x, z, m))
    return m["body"], m["resume"]


def world_bodies(d):
    """The world's bodies as a fresh hello lists them: {body: entry}."""
    h = fresh_hello(d)
    return {b["body"]: b for b in h.get("bodies", [])}


def records_finite(recs):
    return all(all(math.isfinite(v) for v in rec[5:]) for rec in recs.values())


@case(args=LIBERAL + ("--launch-rate", "6", "--bodies-per-session", "3", "--max-bodies", "8"))
def bodies_launch_storm(d, fig):
    """One client over --bodies-per-session (3) and, after removing its bodies, over --launch-rate
    (a bucket of 6); then six clients at once at --max-bodies (8). Every launch is answered once:
    `launched` exactly as the limits allow, every refusal with its own code; the world holds what
    was accepted, nothing else changed."""
    s, r = body_client(d)
    rep = body_send_all(s, r, [({"type": "launch", "id": i, "kind": "ball", "x": 10 * i, "z": 0}, i) for i in range(1, 11)])
    codes = [code_of(one_reply(rep, i, "launch")) for i in range(1, 11)]
    check(codes == ["launched"] * 3 + ["too_many_bodies"] * 7, "per-session storm: %s" % codes)
    mine = [one_reply(rep, i, "launch")["body"] for i in range(1, 4)]
    rep = body_send_all(s, r, [({"type": "remove", "id": 20 + k, "body": b}, 20 + k) for k, b in enumerate(mine)])
    check(all(code_of(one_reply(rep, 20 + k, "remove")) == "removed" for k in range(3)), "removes: %s" % rep)
    # 3 of the bucket's 6 spent: 3 more launched (the session limit again), then...
    rep = body_send_all(s, r, [({"type": "launch", "id": i, "kind": "ball", "x": 10 * i, "z": 5}, i) for i in range(30, 33)])
    codes2 = [code_of(one_reply(rep, i, "launch")) for i in range(30, 33)]
    mine2 = [one_reply(rep, i, "launch")["body"] for i in range(30, 33) if codes2[i - 30] == "launched"]
    rep = body_send_all(s, r, [({"type": "remove", "id": 40 + k, "body": b}, 40 + k) for k, b in enumerate(mine2)])
    # ...the bucket is empty (the refill is 6 a minute: at most one more within these seconds)
    rep = body_send_all(s, r, [({"type": "launch", "id": i, "kind": "ball", "x": 10 * i, "z": 9}, i) for i in range(50, 56)])
    codes3 = [code_of(one_reply(rep, i, "launch")) for i in range(50, 56)]
    fig.update(session_codes=codes, rate_codes=codes2 + codes3)
    check(codes2 == ["launched"] * 3, "after the removes: %s, want 3 launched" % codes2)
    check(codes3.count("launched") <= 1 and codes3.count("rate_limited") >= 5
          and set(codes3) <= {"launched", "rate_limited"}, "bucket empty: %s, want rate_limited" % codes3)
    kept = [one_reply(rep, i, "launch")["body"] for i in range(50, 56) if codes3[i - 50] == "launched"]
    # many clients at --max-bodies
    others = [body_client(d) for _ in range(6)]
    for k, (so, _) in enumerate(others):
        send_quiet(so, b"".join(ws_frame(OP_TEXT, json.dumps({"type": "launch", "id": j, "kind": "ball", "x": -100 * k - j,
                                                                     "z": 50})) for j in range(1, 4)))
    want = 8 - len(kept)
    got = {"launched": 0}
    for so, ro in others:
        ro.until(lambda ro: len([t for t in ro.texts if t.get("id") in (1, 2, 3)
                                 and t.get("type") in ("launched", "error")]) >= 3, 8)
        for t in ro.texts:
            if t.get("id") in (1, 2, 3) and t.get("type") in ("launched", "error"):
                got[code_of(t)] = got.get(code_of(t), 0) + 1
    fig.update(world_codes=got)
    log("    per session %s; bucket %s; world %s" % (codes, codes2 + codes3, got))
    check(sum(got.values()) == 18, "18 launches from 6 clients: %d answers %s" % (sum(got.values()), got))
    check(got["launched"] == want and got.get("too_many_bodies", 0) == 18 - want and len(got) == 2,
          "world storm: %s, want %d launched and the rest too_many_bodies" % (got, want))
    world = world_bodies(d)
    check(len(world) == 8, "the world holds %d bodies, want 8 (%s)" % (len(world), sorted(world)))
    recs = r.fresh()
    check(recs is not None and set(recs) == set(world), "frame records %s, bodies list %s" % (sorted(recs or {}), sorted(world)))
    for so, _ in others:
        so.close()
    s.close()


BAD_KEYS = ['"9F86D081884C7D659A2FEAA0C55AD015"', '"9f86d081884c7d659a2feaa0c55ad01"', '"9f86d081884c7d659a2feaa0c55ad0150"',
            '"9f86d081884c7d659a2feaa0c55ad01g"', '""', '123', 'null', '["9f86d081884c7d659a2feaa0c55ad015"]',
            '"9f86d081884c7d659a2feaa0c55ad01\\u0000"']


@case(args=LIBERAL + ("--body-grace", "2"))
def bodies_not_owner(d, fig):
    """A client steers, removes and claims another's body (wrong, malformed and missing resume keys),
    then claims it with the right key after the grace. not_owner / bad_message each, and the body's
    record (frame header) keeps its throttle, rudder and owner."""
    a, ra = body_client(d)
    body, key = launch_one(a, ra, "boat", 30, 40, 0)
    rep = body_send_all(a, ra, [({"type": "steer", "id": 2, "body": body, "throttle": 0.5, "rudder": 0.25}, 2)])
    check(code_of(one_reply(rep, 2, "own steer")) == "steered", "own steer: %s" % rep)
    time.sleep(0.3)
    rec0 = ra.fresh()
    check(rec0 and body in rec0, "no record of body %d in the frames" % body)
    check(rec0[body][3] == 64 and rec0[body][4] == 32, "own steer not in force: throttle %d rudder %d"
          % (rec0[body][3], rec0[body][4]))
    b, rb = body_client(d)
    wrong = "0" * 32 if key != "0" * 32 else "1" * 32
    msgs = [('{"type":"steer","id":1,"body":%d,"throttle":-1,"rudder":1}' % body, 1),
            ('{"type":"steer","id":2,"body":%d,"throttle":0}' % body, 2),
            ('{"type":"remove","id":3,"body":%d}' % body, 3),
            ('{"type":"claim","id":4,"body":%d,"resume":"%s"}' % (body, wrong), 4),
            ('{"type":"claim","id":5,"body":%d,"resume":"%s"}' % (body, key[:31] + ("0" if key[31] != "0" else "1")), 5),
            ('{"type":"claim","id":6,"body":%d}' % body, 6)]
    want = {1: "not_owner", 2: "not_owner", 3: "not_owner", 4: "not_owner", 5: "not_owner", 6: "bad_message"}
    for k, bad in enumerate(BAD_KEYS):
        msgs.append(('{"type":"claim","id":%d,"body":%d,"resume":%s}' % (10 + k, body, bad), 10 + k))
        want[10 + k] = "bad_json" if "u0000" in bad else "bad_message"
    wrongs = coded(b, rb, [(m.replace('"id":%d,' % i, '"id":%d,'), (want[i],), None) for m, i in msgs])
    check(not wrongs, "refusals: " + "; ".join(wrongs))
    check(not rb.of_type("claimed") and not rb.of_type("removed"), "the other client got an answer of success")
    rec1 = rb.fresh()
    check(rec1 and body in rec1 and rec1[body][3] == 64 and rec1[body][4] == 32 and not rec1[body][2] & 1,
          "body %d changed after the refusals: %r" % (body, rec1 and rec1.get(body)))
    owner = world_bodies(d)[body]
    check(not owner["adrift"] and owner["owner"] == [t for t in ra.texts if t.get("type") == "hello"][0]["client_id"],
          "owner changed: %r" % owner)
    # after the grace: the right key is refused, the body drifts unpowered and is then removed
    a.close()
    check(wait_until(lambda: world_bodies(d).get(body, {}).get("adrift"), 3), "body not adrift after its owner left")
    time.sleep(2.4)
    rep = body_send_all(b, rb, [('{"type":"claim","id":50,"body":%d,"resume":"%s"}' % (body, key), 50)])
    late = code_of(one_reply(rep, 50, "late claim"))
    fig.update(refusals=len(msgs), late_claim=late)
    log("    %d refusals as coded; claim after the grace: %s" % (len(msgs), late))
    check(late in ("not_owner", "no_such_body"), "claim after the grace: %s, want not_owner" % late)
    check(not rb.of_type("claimed"), "claimed after the grace")
    check(wait_until(lambda: body not in world_bodies(d), 4), "abandoned body %d not removed" % body)
    b.close()


HOSTILE_VALUES = [("NaN", ("bad_json",)), ("Infinity", ("bad_json",)), ("-Infinity", ("bad_json",)),
                  ("1e999", ("bad_type",)), ("-1e999", ("bad_type",)), ('"1"', ("bad_type",)), ("null", ("bad_type",)),
                  ("true", ("bad_type",)), ("[1]", ("bad_type",)), ("{}", ("bad_type",))]


@case(args=LIBERAL)
def bodies_hostile_numbers(d, fig):
    """NaN, Infinity, 1e999, huge, negative, fractional and string values in every member of launch,
    steer, remove and claim: a coded error each (with its param), nothing launched, steered,
    removed or claimed: the world's list and the body's record unchanged."""
    s, r = body_client(d)
    body, key = launch_one(s, r, "boat", 0, 0, 0)
    rep = body_send_all(s, r, [({"type": "steer", "id": 2, "body": body, "throttle": 0.25, "rudder": -0.5}, 2)])
    check(code_of(one_reply(rep, 2, "steer")) == "steered", "steer: %s" % rep)
    time.sleep(0.3)
    rec0, world0 = r.fresh(), world_bodies(d)
    cases = []   # (text, codes, param)
    L = '{"type":"launch","id":%d,"kind":"ball","x":X,"z":Z,"heading":H}'
    for v, codes in HOSTILE_VALUES + [("1e300", ("out_of_range",)), ("-2500.001", ("out_of_range",)),
                                      ("2501", ("out_of_range",)), ("-1e308", ("out_of_range",))]:
        for m in "XZ":
            cases.append((L.replace(m, v).replace("X", "1").replace("Z", "2").replace("H", "0"), codes, m.lower()))
    for v, codes in HOSTILE_VALUES:
        cases.append((L.replace("H", v).replace("X", "1").replace("Z", "2"), codes, "heading"))
    for v in ('"boat"', "", '"BOAT"', '"__proto__"', '"boat\\u0000"', "1", "null"):
        k = ('"kind":%s,' % v) if v else ""
        codes = ("bad_message",) if not v else ("bad_json",) if "u0000" in v else \
            ("bad_type",) if not v.startswith('"') else ("unknown_kind",)
        if v == '"boat"':
            continue
        cases.append(('{"type":"launch","id":%%d,%s"x":1,"z":2}' % k, codes, "kind"))
    cases.append(('{"type":"launch","id":%d,"kind":"ball","z":2}', ("bad_message",), "x"))
    ids = [("0", ("out_of_range",)), ("-1", ("out_of_range",)), ("1.5", ("bad_type",)), ("4294967296", ("out_of_range",)),
           ("1e300", ("out_of_range",)), ("%d.000001" % body, ("bad_type",)), ('"%d"' % body, ("bad_type",))] + HOSTILE_VALUES
    for v, codes in ids:
        cases.append(('{"type":"steer","id":%%d,"body":%s,"throttle":1}' % v, codes, "body"))
        cases.append(('{"type":"remove","id":%%d,"body":%s}' % v, codes, "body"))
        cases.append(('{"type":"claim","id":%%d,"body":%s,"resume":"%s"}' % (v, key), codes, "body"))
    for v, codes in HOSTILE_VALUES + [("1.0001", ("out_of_range",)), ("-1.5", ("out_of_range",)), ("127", ("out_of_range",)),
                                      ("1e300", ("out_of_range",)), ("-1e308", ("out_of_range",))]:
        for m in ("throttle", "rudder"):
            cases.append(('{"type":"steer","id":%%d,"body":%d,"%s":%s}' % (body, m, v), codes, m))
            # one member good, the other hostile: nothing of it applies
            other = "rudder" if m == "throttle" else "throttle"
            cases.append(('{"type":"steer","id":%%d,"body":%d,"%s":1,"%s":%s}' % (body, other, m, v), codes, m))
    cases.append(('{"type":"remove","id":%d}', ("bad_message",), "body"))
    cases.append(('{"type":"steer","id":%d,"throttle":1}', ("bad_message",), "body"))
    bad = coded(s, r, cases)
    fig.update(messages=len(cases), wrong=len(bad))
    log("    %d hostile body requests: %d wrong" % (len(cases), len(bad)))
    check(not bad, "; ".join(bad[:6]) + (" (%d in all)" % len(bad) if len(bad) > 6 else ""))
    check(not r.of_type("launched")[1:] and not r.of_type("removed") and not r.of_type("claimed"),
          "a hostile request succeeded: %s" % [t for t in r.texts if t.get("type") in ("launched", "removed", "claimed")][1:])
    rec1, world1 = r.fresh(), world_bodies(d)
    check(world1 == world0, "bodies list changed: %s -> %s" % (world0, world1))
    check(rec1 and set(rec1) == set(rec0) and rec1[body][3:5] == rec0[body][3:5] and records_finite(rec1),
          "record changed: %r -> %r" % (rec0.get(body), rec1 and rec1.get(body)))
    s.close()


@case(args=LIBERAL)
def bodies_removal_races(d, fig):
    """Remove and steer the same body in one burst; remove it twice; claim it while it is being
    removed; close the connection with a remove in flight. No crash, each request answered once
    (removed once, the rest no_such_body or, for a steer that reached the sim first, steered), and
    the `bodies` lists every client gets agree with the frames' records."""
    w, rw = body_client(d)        # a bystander: follows the bodies messages
    s, r = body_client(d)
    b1, k1 = launch_one(s, r, "dinghy", 0, 0, 0, i=1)
    b2, k2 = launch_one(s, r, "dinghy", 20, 0, 0, i=2)
    b3, k3 = launch_one(s, r, "ball", 40, 0, 0, i=3)
    rep = body_send_all(s, r, [({"type": "remove", "id": 10, "body": b1}, 10),
                               ({"type": "steer", "id": 11, "body": b1, "throttle": 1}, 11),
                               ({"type": "remove", "id": 12, "body": b1}, 12),
                               ({"type": "claim", "id": 13, "body": b1, "resume": k1}, 13),
                               ({"type": "steer", "id": 14, "body": b1, "rudder": 1}, 14),
                               ({"type": "remove", "id": 15, "body": b1}, 15)])
    codes = {i: code_of(one_reply(rep, i, "race")) for i in (10, 11, 12, 13, 14, 15)}
    fig["race_codes"] = codes
    log("    burst on body %d: %s" % (b1, codes))
    check(codes[10] == "removed", "first remove: %s" % codes[10])
    check(all(codes[i] == "no_such_body" for i in (12, 13, 15)), "remove twice / claim while removing: %s" % codes)
    check(all(codes[i] in ("no_such_body", "steered") for i in (11, 14)), "steer of a removed body: %s" % codes)
    check(len(r.of_type("removed")) == 1, "removed answered %d times" % len(r.of_type("removed")))
    # a second client claims b2 (it holds the key) while the owner removes it, in one burst each
    c, rc = body_client(d)
    send_quiet(s, ws_frame(OP_TEXT, json.dumps({"type": "remove", "id": 20, "body": b2})))
    send_quiet(c, ws_frame(OP_TEXT, json.dumps({"type": "claim", "id": 21, "body": b2, "resume": k2})))
    r.until(lambda r: any(t.get("id") == 20 for t in r.texts), 5)
    rc.until(lambda r: any(t.get("id") == 21 for t in r.texts), 5)
    a20 = [code_of(t) for t in r.texts if t.get("id") == 20]
    a21 = [code_of(t) for t in rc.texts if t.get("id") == 21]
    fig.update(remove_vs_claim=[a20, a21])
    check(len(a20) == 1 and len(a21) == 1, "remove vs claim: answers %s / %s, want one each" % (a20, a21))
    check((a20, a21) in ((["removed"], ["no_such_body"]), (["not_owner"], ["claimed"])),
          "remove vs claim: %s / %s" % (a20, a21))
    if a21 == ["claimed"]:     # the claim came first: its new owner removes it
        send_quiet(c, ws_frame(OP_TEXT, json.dumps({"type": "remove", "id": 22, "body": b2})))
        rc.until(lambda r: any(t.get("id") == 22 for t in r.texts), 5)
    # close with a remove in flight (RST right after it)
    send_quiet(s, ws_frame(OP_TEXT, json.dumps({"type": "remove", "id": 30, "body": b3})))
    rst_close(s)
    check(wait_until(lambda: b1 not in world_bodies(d) and b2 not in world_bodies(d), 5), "removed bodies still listed")
    time.sleep(0.5)
    world = world_bodies(d)
    check(set(world) <= {b3} and all(e["adrift"] for e in world.values()),
          "after the RST: %s (want nothing, or body %d adrift)" % (world, b3))
    rw.until(lambda rw: rw.of_type("bodies") and {e["body"] for e in rw.of_type("bodies")[-1]["bodies"]} == set(world), 3)
    check(rw.of_type("bodies"), "the bystander got no bodies message")
    last = rw.of_type("bodies")[-1]
    check({e["body"] for e in last["bodies"]} == set(world), "bystander's last bodies %s, world %s" % (last, world))
    gone = [g["body"] for m in rw.of_type("bodies") for g in m["removed"]]
    check(gone.count(b1) == 1 and gone.count(b2) == 1 and gone.count(b3) <= 1,
          "removed announced %s (each once)" % gone)
    recs = rw.fresh()
    check(set(recs or {}) == set(world), "frame records %s, list %s" % (sorted(recs or {}), sorted(world)))
    for x in (w, c):
        x.close()


@case(args=LIBERAL + ("--body-grace", "0.1", "--max-bodies", "1000"),
      rss_slack_kb=2048)
def bodies_launch_leave_1000(d, fig):
    """1000 cycles of connect → launch → close (4 threads), --body-grace 0.1: each body is abandoned
    (adrift, then removed) after its owner left. Rounds of 250 after a warm-up of 100: the world
    empties after each, every launch got a new id (ids only grow, never reused), and RSS after each
    round is within 2 MB of the end of the warm-up, and most rounds grow it by < 512 kB over the
    round before: memory comes back."""
    lock = threading.Lock()
    ids, errors = [], []

    def cycle(k):
        try:
            s, _ = raw_ws(d.port)
            r = Reader(s)
            send_quiet(s, ws_frame(OP_TEXT, '{"type":"launch","id":1,"kind":"ball","x":%d,"z":%d}' % (k % 2000 - 1000, k % 7)))
            r.until(lambda r: any(t.get("id") == 1 for t in r.texts), 5)
            got = [t for t in r.texts if t.get("id") == 1]
            with lock:
                if got and got[0].get("type") == "launched":
                    ids.append(got[0]["body"])
                else:
                    errors.append(got[0] if got else "no answer")
            if k % 3 == 2:
                rst_close(s)
            else:
                s.close()
        except (CaseFailure, OSError) as e:
            with lock:
                errors.append(str(e))

    def run(n, start):
        threads = [threading.Thread(target=lambda t=t: [cycle(start + j) for j in range(t, n, 4)]) for t in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()

    def empty():
        return wait_until(lambda: not world_bodies(d), 10)

    run(100, 0)
    check(empty(), "the world did not empty after the warm-up")
    time.sleep(0.3)
    warm = d.rss_kb()
    warmed_up(fig, warm)
    rss, rounds, done = [], [], len(ids)
    for k in range(4):
        run(250, 100 + 250 * k)
        check(empty(), "the world did not empty after round %d: %s" % (k + 1, sorted(world_bodies(d))[:10]))
        time.sleep(0.3)
        rss.append(d.rss_kb() - warm)
        rounds.append(ids[done:])
        done = len(ids)
    grew = [k for k in range(1, len(rounds)) if rounds[k] and rounds[k - 1] and min(rounds[k]) <= max(rounds[k - 1])]
    fig.update(launched=len(ids), errors=len(errors), rss_rounds_kb=rss)
    log("    %d launched, %d errors; RSS per round from the warm-up: %s kB" % (len(ids), len(errors), rss))
    check(not grew, "ids of round %s not above the round before's (an id reused?)" % grew)
    check(not errors, "launch errors: %s" % errors[:5])
    check(len(ids) == 1100 and len(set(ids)) == 1100, "%d ids, %d distinct, want 1100" % (len(ids), len(set(ids))))
    h = fresh_hello(d)
    s, r = body_client(d)
    nb, _ = launch_one(s, r, "ball", 0, 0, 0)
    s.close()
    check(nb > max(ids), "a new body got id %d, not above the largest %d" % (nb, max(ids)))
    check(not h.get("bodies"), "bodies left: %s" % h.get("bodies"))
    # between rounds: a leak grows every round (4 kB a body: +1.1 MB a round); a healthy daemon's
    # allocator settles (seen: +108, +72, +48, 0 kB)
    steps = [b - a for a, b in zip([0] + rss, rss)]
    fig["rss_steps_kb"] = steps
    check(max(rss) < 2048 and sum(x < 512 for x in steps) >= 3,
          "RSS per round %s kB (steps %s), want all < 2048 from the warm-up and most steps < 512" % (rss, steps))


SOLO.add("bodies_launch_leave_1000")   # 1000 connections and launches on 4 threads


@case(args=LIBERAL + ("--bodies-per-session", "16"))
def bodies_at_bounds(d, fig):
    """Bodies launched exactly at the world's bounds (±world_half_size, the four corners, heading
    1e300), just past them (refused, out_of_range), and a boat and a ship at full throttle driven
    straight into them: every record stays finite, within ±world_half_size, the bodies stay."""
    s, r = body_client(d)
    h = [t for t in r.texts if t.get("type") == "hello"][0]
    W = h["world_half_size"]
    placed = []
    for k, (x, z) in enumerate([(W, W), (-W, -W), (W, -W), (-W, W), (0, W), (-W, 0)]):
        placed.append(launch_one(s, r, "ball" if k % 2 else "spar", x, z, 1e300 if k == 0 else 0, i=10 + k)[0])
    # east is -x (§3.5): heading 90 drives a boat at x = -W + 5 into the west... east bound; heading 0 into +z
    drivers = [launch_one(s, r, "boat", -W + 5, 0, 90, i=20)[0], launch_one(s, r, "ship", 0, W - 30, 0, i=21)[0]]
    rep = body_send_all(s, r, [({"type": "steer", "id": 30 + k, "body": b, "throttle": 1}, 30 + k) for k, b in enumerate(drivers)])
    check(all(code_of(one_reply(rep, 30 + k, "steer")) == "steered" for k in range(2)), "steers: %s" % rep)
    s2, r2 = body_client(d)
    ms = [('{"type":"launch","id":%d,"kind":"ball","x":%r,"z":0}' % (40 + k, v), 40 + k)
          for k, v in enumerate([W + 0.001, -W - 0.001, math.nextafter(W, 1e9)])]
    ms.append(('{"type":"launch","id":43,"kind":"ball","x":0,"z":%r}' % math.nextafter(-W, -1e9), 43))
    rep = body_send_all(s2, r2, ms)
    over = [code_of(one_reply(rep, i, m)) for m, i in ms]
    check(over == ["out_of_range"] * 4, "launches past the bounds: %s" % over)
    s2.close()
    worst, frames, bad = 0.0, 0, []
    deadline = time.time() + 5
    r.frames_with = 0
    while time.time() < deadline and not bad:
        r.pump(0.1)
        if r.records is None:
            continue
        frames += 1
        for rec in r.records.values():
            if not all(math.isfinite(v) for v in rec[5:]):
                bad.append("body %d: %r" % (rec[0], rec))
            elif abs(rec[5]) > W or abs(rec[7]) > W:
                bad.append("body %d out of the world at (%g, %g)" % (rec[0], rec[5], rec[7]))
            else:
                worst = max(worst, abs(rec[5]), abs(rec[7]))
        r.records = None
    world = world_bodies(d)
    fig.update(frames=frames, largest_coordinate=worst)
    log("    %d frames: largest |x|,|z| %.3f of %g; bodies %s" % (frames, worst, W, sorted(world)))
    check(not bad, "; ".join(bad[:4]))     # (the watch stops at the first bad record)
    check(frames > 30 and r.frames_with > 30, "only %d frames with records (connection closed: %s, close code %r)"
          % (frames, r.eof, r.close_code))
    check(set(world) == set(placed + drivers), "bodies lost at the bounds: %s, want %s" % (sorted(world), sorted(placed + drivers)))
    s.close()


if __name__ == "__main__":
    main()

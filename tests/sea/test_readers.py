#!/usr/bin/env python3
"""test-sea-readers: the readers of measured seas, in C (`ocean-tap sea`) and in Python
(`oceand.sea`), on the fixtures of tests/sea/gen_fixtures.py (its known sea is in
fixtures/truth.json).

  1. every reader on every good fixture gives back the sea's Hs (4 sqrt(m0)) within 1 %,
     its peak in the band the generator says, the direction at the peak within 2 deg,
     and the right time (the newest in all five NDBC files, or --time);
  2. every broken fixture gives its coded error, naming the file, the line and the band,
     and prints no document;
  3. the same fixtures fetched over HTTP from a server this test starts on 127.0.0.1
     (and stops) give the same documents; a missing URL is an io error;
  4. the C and the Python readers give the same documents (numbers to 1e-12), and on 200
     damaged copies of the fixtures the same document or the same error;
  5. reading a realtime set of 45 days (the size NDBC serves) is timed and printed.
The checks must be able to fail: the decoy rows (another sea at the other times) are
read with --time and must be off by more than the tolerance.
Usage: tests/sea/test_readers.py BUILD_DIR   (make test-sea-readers)"""
import functools
import http.server
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
FIX = os.path.join(HERE, "fixtures")
sys.path.insert(0, os.path.join(ROOT, "proto", "python"))
from oceand import sea  # noqa: E402

BUILD = sys.argv[1] if len(sys.argv) > 1 else "build"
TAP = os.path.join(BUILD, "ocean-tap")
TRUTH = json.load(open(os.path.join(FIX, "truth.json")))
failures = []


def check(cond, what):
    if not cond:
        failures.append(what)
        print(f"  FAIL {what}")
    return cond


def tap(*args):
    p = subprocess.run([TAP, "sea", *args], capture_output=True, text=True, timeout=60)
    return p.returncode, p.stdout, p.stderr


def c_read(source, *extra):
    rc, out, err = tap(source, "--print", *extra)
    if rc != 0:
        raise RuntimeError(f"ocean-tap sea {source} exited {rc}: {err.strip()}")
    return json.loads(out), err


def py_read(source, **kw):
    got = sea.read(source, **kw)
    return [sea.public(d) for d in got] if isinstance(got, list) else sea.public(got)


def angle_diff(a, b):
    return abs((a - b + 180) % 360 - 180)


def against_truth(label, doc, t, hs=None):
    st = sea.stats(doc)
    want_hs = hs if hs is not None else t["hs"]
    ok = check(abs(st["hs"] / want_hs - 1) < 0.01, f"{label}: Hs {st['hs']:.4f}, the sea's {want_hs:.4f} (1 %)")
    if hs is None:
        ok &= check(t["peak_band_low"] - 1e-9 <= st["fp"] <= t["peak_band_high"] + 1e-9,
                    f"{label}: peak {st['fp']:.4f} Hz outside the band {t['peak_band_low']:.4f}..{t['peak_band_high']:.4f}")
        ok &= check(angle_diff(st["direction_at_peak"], t["direction_at_peak"]) < 2,
                    f"{label}: from {st['direction_at_peak']:.2f} deg at the peak, the sea's {t['direction_at_peak']:.2f}")
    ok &= check(doc["time"] == t["time"], f"{label}: time {doc['time']}, expected {t['time']}")
    return st, ok


def same(a, b, path=""):
    """Where documents a and b differ (numbers to 1e-12 relative), or None."""
    if isinstance(a, list) or isinstance(b, list):
        if not (isinstance(a, list) and isinstance(b, list)) or len(a) != len(b):
            return f"{path}: lengths differ"
        for i, (x, y) in enumerate(zip(a, b)):
            d = same(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    if isinstance(a, dict) or isinstance(b, dict):
        if not (isinstance(a, dict) and isinstance(b, dict)) or list(a) != list(b):
            return f"{path}: members differ: {list(a) if isinstance(a, dict) else a} / {list(b) if isinstance(b, dict) else b}"
        for k in a:
            d = same(a[k], b[k], f"{path}.{k}")
            if d:
                return d
        return None
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return None if abs(a - b) <= 1e-12 * max(abs(a), abs(b)) else f"{path}: {a!r} != {b!r}"
    return None if a == b else f"{path}: {a!r} != {b!r}"


GOOD = [("ndbc realtime", "ndbc-rt/46026.data_spec", "ndbc-rt"),
        ("ndbc realtime (named by .swr2)", "ndbc-rt/46026.swr2", "ndbc-rt"),
        ("ndbc historical 2025", "ndbc-hist/46026w2025.txt", "ndbc-hist-2025"),
        ("ndbc historical 1998 (.gz, no minutes, r x100)", "ndbc-hist/46026k1998.txt.gz", "ndbc-hist-1998"),
        ("cdip", "cdip/100p1_rt.ascii", "cdip")]


def part1_and_4(base=FIX, tag=""):
    print(f"-- good fixtures{tag}: Hs, peak band, direction, time; C and Python agree")
    results = {}
    for label, rel, key in GOOD + [("ww3", "ww3/storm.spec", "ww3")]:
        src = os.path.join(base, rel) if not base.startswith("http") else f"{base}/{rel}"
        c_doc, summary = c_read(src)
        p_doc = py_read(src)
        results[rel] = c_doc
        d = same(c_doc, p_doc)
        check(d is None, f"{label}{tag}: C and Python differ: {d}")
        if key == "ww3":
            check(isinstance(c_doc, list) and len(c_doc) == 3, f"ww3{tag}: {len(c_doc)} documents, expected 3")
            times = [x["time"] for x in c_doc]
            check(times == sorted(times), f"ww3{tag}: times not in order: {times}")
            for k, (doc, t) in enumerate(zip(c_doc, TRUTH["ww3"])):
                st, _ = against_truth(f"ww3 time {k}{tag}", doc, t)
                check(doc["form"] == "spectrum2d" and doc["depth"] == 52, f"ww3{tag}: form/depth {doc['form']} {doc['depth']}")
                print(f"  ok  ww3 {doc['time']}: Hs {st['hs']:.4f} (sea {t['hs']:.4f}, {100 * (st['hs'] / t['hs'] - 1):+.2f} %), "
                      f"peak {st['fp']:.4f} Hz, from {st['direction_at_peak']:.2f} (sea {t['direction_at_peak']:.2f})")
        else:
            t = TRUTH[key]
            st, _ = against_truth(f"{label}{tag}", c_doc, t)
            check(c_doc["form"] == "moments", f"{label}: form {c_doc['form']}")
            check(summary.count("\n") == 1 and "Hs " in summary and " from " in summary, f"{label}: summary {summary!r}")
            print(f"  ok  {label}: Hs {st['hs']:.4f} (sea {t['hs']:.4f}, {100 * (st['hs'] / t['hs'] - 1):+.2f} %), "
                  f"peak {st['fp']:.4f} Hz, from {st['direction_at_peak']:.2f} (sea {t['direction_at_peak']:.2f}), {c_doc['time']}")
    return results


def part1_time():
    print("-- --time, and the checks can fail (the decoy rows hold another sea)")
    t = TRUTH["ndbc-hist-2025-first"]
    for who, doc in (("C", c_read(os.path.join(FIX, "ndbc-hist/46026d2025.txt"), "--time", t["time"])[0]),
                     ("Python", py_read(os.path.join(FIX, "ndbc-hist/46026d2025.txt"), when=t["time"]))):
        st = sea.stats(doc)
        check(doc["time"] == t["time"] and abs(st["hs"] / t["hs"] - 1) < 0.01,
              f"{who} --time {t['time']}: {doc['time']} Hs {st['hs']:.3f}, expected {t['hs']:.3f}")
        check(abs(st["hs"] / TRUTH["ndbc-hist-2025"]["hs"] - 1) > 0.01, f"{who}: the decoy row is within 1 % of the sea")
    decoy, _ = c_read(os.path.join(FIX, "ndbc-rt/46026.data_spec"), "--time", "2026-12-01T18:40Z")
    st = sea.stats(decoy)
    check(abs(st["hs"] / TRUTH["ndbc-rt"]["hs"] - 1) > 0.01
          and angle_diff(st["direction_at_peak"], TRUTH["ndbc-rt"]["direction_at_peak"]) > 2,
          "the realtime decoy row (18:40) passes the checks: they cannot tell seas apart")
    rc, out, err = tap(os.path.join(FIX, "ndbc-rt/46026.data_spec"), "--print", "--time", "2026-12-01T21:40Z")
    check(rc == 8 and "error no_time" in err and not out, f"a time not in the files: {rc} {err.strip()}")
    one, _ = c_read(os.path.join(FIX, "ww3/storm.spec"), "--time", "2026-12-02T06:00Z")
    check(len(one) == 1 and one[0]["time"] == "2026-12-02T06:00:00Z", "ww3 --time: one document of that time")
    print(f"  ok  --time reads the row asked for (historical, realtime, WW3); the decoy rows are off by "
          f"{100 * (st['hs'] / TRUTH['ndbc-rt']['hs'] - 1):+.0f} % and "
          f"{angle_diff(st['direction_at_peak'], TRUTH['ndbc-rt']['direction_at_peak']):.0f} deg")


def part2():
    print("-- broken fixtures: the coded error, the file, the line, the band; no document")
    cases = json.load(open(os.path.join(FIX, "broken", "expected.json")))
    for c in cases:
        src = os.path.join(FIX, c["source"])
        rc, out, err = tap(src, "--print")
        where = f"{c['file']}:{c['line']}: " + (f"band {c['band']}: " if c["band"] else "")
        check(rc == 8 and not out and f"error {c['code']}: {where}" in err,
              f"{c['name']} (C): exit {rc}, stdout {len(out)} bytes, stderr {err.strip()!r}; expected "
              f"\"error {c['code']}: {where}\"")
        try:
            sea.read(src)
            check(False, f"{c['name']} (Python): no error")
        except sea.SeaError as e:
            check((e.code, e.file, e.line, e.band) == (c["code"], c["file"], c["line"], c["band"]),
                  f"{c['name']} (Python): {e}; expected {c['code']} {c['file']}:{c['line']} band {c['band']}")
        print(f"  ok  {c['name']}: {err.strip().split(': ', 1)[1]}")
    rc, out, err = tap(os.path.join(FIX, "no-such-file.data_spec"), "--print")
    check(rc == 8 and "error io: " in err and "no-such-file.data_spec: cannot open" in err and not out,
          f"a missing file: {rc} {err.strip()}")
    rc, out, err = tap("--print")
    check(rc == 1, f"no SOURCE: exit {rc}")
    rc, out, err = tap(os.path.join(FIX, "ww3/storm.spec"), "ws://127.0.0.1:9")
    check(rc == 2 and "cannot connect" in err, f"sending to no daemon: exit {rc}: {err.strip()}")
    rc, out, err = tap(os.path.join(FIX, "ww3/storm.spec"), "ws://127.0.0.1:9", "--print")
    check(rc == 1 and "one of them" in err, f"--print and a URL: exit {rc}: {err.strip()}")
    rc, out, err = tap(os.path.join(FIX, "truth.json"), "--print")
    check(rc == 8 and "error bad_header" in err, f"an unknown format: {rc} {err.strip()}")
    print(f"  ok  {len(cases)} broken fixtures; a missing file (io), no SOURCE (1), no daemon at the URL (2), "
          f"--print with a URL (1), an unknown format (bad_header)")


def part3(from_files):
    print("-- over HTTP from a server on 127.0.0.1 (started and stopped here)")
    # The served folder: the fixtures, and NDBC's historical layout (a folder per kind)
    root = tempfile.mkdtemp()
    os.symlink(FIX, os.path.join(root, "f"))
    for folder, letter in zip(("swden", "swdir", "swdir2", "swr1", "swr2"), "wdijk"):
        os.makedirs(os.path.join(root, "historical", folder))
        shutil.copy(os.path.join(FIX, "ndbc-hist", f"46026{letter}1998.txt.gz"), os.path.join(root, "historical", folder))
    handler = functools.partial(QuietHandler, directory=root)
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    th = threading.Thread(target=srv.serve_forever, daemon=True)
    th.start()
    try:
        host = f"http://127.0.0.1:{srv.server_address[1]}"
        base = f"{host}/f"
        # The shortcuts, pointed at this server: ndbc:46026 reads ndbc-rt/46026.*; cdip:100 asks for the
        # dataset's size (a .dds written here) and then its newest record (the server ignores the query)
        with open(os.path.join(root, "100p1_rt.nc.dds"), "w") as fh:
            fh.write("Dataset {\n    Int32 waveTime[waveTime = 2];\n    Float32 waveFrequency[waveFrequency = 64];\n}\n")
        shutil.copy(os.path.join(FIX, "cdip", "100p1_rt.ascii"), os.path.join(root, "100p1_rt.nc.ascii"))
        os.environ["OCEAND_SEA_NDBC"] = f"{base}/ndbc-rt/"
        os.environ["OCEAND_SEA_CDIP"] = f"{host}/"
        try:
            for short, rel in (("ndbc:46026", "ndbc-rt/46026.data_spec"), ("cdip:100", "cdip/100p1_rt.ascii")):
                for who, doc in (("C", c_read(short)[0]), ("Python", py_read(short))):
                    want = dict(from_files[rel], source="CDIP 100") if short.startswith("cdip") else from_files[rel]
                    check(same(doc, want) is None, f"{who} {short}: {same(doc, want)}")
        finally:
            del os.environ["OCEAND_SEA_NDBC"], os.environ["OCEAND_SEA_CDIP"]
        url = f"{host}/historical/swdir2/46026i1998.txt.gz"
        for who, doc in (("C", c_read(url)[0]), ("Python", py_read(url))):
            check(same(doc, from_files["ndbc-hist/46026k1998.txt.gz"]) is None,
                  f"{who}: NDBC's historical layout (a folder per kind) read other files")
        got = part1_and_4(base, " (http)")
        for rel, doc in from_files.items():
            d = same(doc, got[rel])
            check(d is None, f"{rel}: the URL's document differs from the file's: {d}")
        rc, out, err = tap(f"{base}/ndbc-rt/nothing.data_spec", "--print")
        check(rc == 8 and "error io" in err and "404" in err, f"a missing URL (C): {rc} {err.strip()}")
        try:
            sea.read(f"{base}/ndbc-rt/nothing.data_spec")
            check(False, "a missing URL (Python): no error")
        except sea.SeaError as e:
            check(e.code == "io", f"a missing URL (Python): {e}")
        print(f"  ok  {len(from_files)} sources over HTTP equal to the files, and NDBC's historical folders; ndbc:46026 and cdip:100 (pointed at this server); 404 -> io; {QuietHandler.requests} requests served")
        memory(base)
    finally:
        srv.shutdown()
        srv.server_close()
        th.join(5)
        shutil.rmtree(root)


def memory(base):
    """Every reader's paths that allocate, good and refused, a file, a .gz and a URL, under valgrind."""
    if not shutil.which("valgrind"):
        print("  skip: valgrind not installed")
        return
    vg = ["valgrind", "-q", "--error-exitcode=99", "--leak-check=full", "--errors-for-leak-kinds=definite,indirect"]
    runs = [os.path.join(FIX, s) for s in ("ndbc-rt/46026.data_spec", "ndbc-hist/46026k1998.txt.gz", "ww3/storm.spec",
                                           "cdip/100p1_rt.ascii", "broken/rt-999/46026.swdir",
                                           "broken/ww3-truncated/storm.spec", "broken/cdip-fill/100p1_rt.ascii")]
    runs.append(f"{base}/ndbc-rt/46026.swdir")
    for src in runs:
        p = subprocess.run(vg + [TAP, "sea", src, "--print"], capture_output=True, text=True, timeout=120)
        check(p.returncode in (0, 8), f"valgrind: ocean-tap sea {src}: exit {p.returncode}: {p.stderr[-800:]}")
    print(f"  ok  no memory errors or leaks in ocean-tap sea ({len(runs)} sources: each reader, refused ones, a URL)")


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    requests = 0

    def log_message(self, *a):
        QuietHandler.requests += 1


def part5():
    print("-- time to read a realtime set of NDBC's size (45 days, 24 rows a day, five files)")
    with tempfile.TemporaryDirectory() as d:
        subprocess.run(["/usr/bin/python3", os.path.join(HERE, "gen_fixtures.py"), "--realtime-days", "45", "--out", d],
                       check=True)
        src = os.path.join(d, "46026.data_spec")
        size = sum(os.path.getsize(os.path.join(d, f)) for f in os.listdir(d))
        t0 = time.perf_counter()
        doc, _ = c_read(src)
        t_c = time.perf_counter() - t0
        t0 = time.perf_counter()
        pdoc = py_read(src)
        t_py = time.perf_counter() - t0
        against_truth("45-day realtime set", doc, dict(TRUTH["ndbc-rt"], time="2026-12-01T20:40:00Z"))
        check(same(doc, pdoc) is None, "45-day set: C and Python differ")
        print(f"  ok  {size / 1e6:.1f} MB in five files: ocean-tap sea (the whole process) {1000 * t_c:.0f} ms, "
              f"oceand.sea.read {1000 * t_py:.0f} ms (not asserted; the target is well under 1 s)")


def mutations(count=200, seed=7):
    """C and Python on the same damaged files: the same document, or the same error (code, file,
    line, band). Deterministic: the same damage every run."""
    import random
    import re
    print(f"-- C and Python on {count} damaged copies of the fixtures (seed {seed})")
    rnd = random.Random(seed)
    sets = [("ndbc-rt", [f"46026.{e}" for e in ("data_spec", "swdir", "swdir2", "swr1", "swr2")]),
            ("ndbc-hist", [f"46026{c}2025.txt" for c in "wdijk"]), ("ww3", ["storm.spec"]), ("cdip", ["100p1_rt.ascii"])]
    toks = ["MM", "999.0", "-999", "x", "", "(0.1)", "1e400", "nan", "0x1p3", "0.5", "\n", " ", "[0], ", "'", "-1", "99",
            "\t", "+", "\u00e9", "0"]
    refused, before = 0, len(failures)
    for _ in range(count):
        kind, files = rnd.choice(sets)
        with tempfile.TemporaryDirectory() as d:
            for f in files:
                shutil.copy(os.path.join(FIX, kind, f), d)
            p = os.path.join(d, rnd.choice(files))
            s = open(p).read()
            for _ in range(rnd.randint(1, 3)):
                i = rnd.randrange(len(s))
                s = s[:i] + rnd.choice(toks) + s[min(len(s), i + rnd.randint(0, 8)):]
            open(p, "w").write(s)
            src = os.path.join(d, files[0])
            rc, out, err = tap(src, "--print")
            try:
                got, perr = py_read(src), None
            except sea.SeaError as e:
                got, perr = None, e
            if rc == 0:
                check(perr is None and same(json.loads(out), got) is None,
                      f"{kind}: C read a document, Python {perr or same(json.loads(out), got)}")
                continue
            refused += 1
            m = re.search(r"error (\w+): (?:(\S+?):(\d+): |(\S+): )?(?:band (\d+): )?", err)
            c_err = (m.group(1), m.group(2) or m.group(4) or "", int(m.group(3) or 0), int(m.group(5) or 0)) if m else err
            p_err = (perr.code, perr.file, perr.line, perr.band) if perr else None
            check(c_err == p_err, f"{kind}: C {err.strip()[:160]!r}, Python {str(perr)[:160]!r}")
    if len(failures) == before:
        print(f"  ok  the same verdict on all {count}: {refused} refused with the same code, file, line and band, "
              f"{count - refused} read to the same document")


def regenerated():
    print("-- the committed fixtures are the generator's")
    import filecmp
    with tempfile.TemporaryDirectory() as d:
        subprocess.run(["/usr/bin/python3", os.path.join(HERE, "gen_fixtures.py"), "--fixtures", d], check=True,
                       stdout=subprocess.DEVNULL)
        bad = []
        def walk(cmp, rel=""):
            bad.extend(os.path.join(rel, n) for n in cmp.left_only + cmp.right_only + cmp.diff_files + cmp.funny_files)
            for n, sub in cmp.subdirs.items():
                walk(sub, os.path.join(rel, n))
        filecmp.clear_cache()
        cmp = filecmp.dircmp(FIX, d)
        walk(cmp)
        # dircmp compares by size and time first: compare every file's bytes as well
        for dp, _, fs in os.walk(d):
            for f in fs:
                rel = os.path.relpath(os.path.join(dp, f), d)
                a = os.path.join(FIX, rel)
                if os.path.exists(a) and open(a, "rb").read() != open(os.path.join(dp, f), "rb").read():
                    bad.append(rel)
        if check(not bad, f"fixtures differ from what gen_fixtures.py writes: {sorted(set(bad))[:8]}"):
            print("  ok  tests/sea/fixtures is what tests/sea/gen_fixtures.py writes, byte for byte")


def main():
    if not os.access(TAP, os.X_OK):
        sys.exit(f"{TAP} is not built")
    regenerated()
    files = part1_and_4()
    part1_time()
    part2()
    part3(files)
    mutations()
    part5()
    if failures:
        print(f"FAIL: {len(failures)} checks failed")
        return 1
    print("PASS: test_readers.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())

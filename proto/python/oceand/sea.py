"""Measured seas: NDBC, WAVEWATCH III and CDIP files read into the sea document.

    from oceand import sea
    doc = sea.read("ndbc:46026")                  # or a file, an http(s):// URL
    docs = sea.read("forecast.spec")              # WAVEWATCH III: a list, one per time
    print(sea.summary(doc))                       # "NDBC 46026 ...: Hs 2.31 m, Tp ..., from 271.3 deg ..."

    /usr/bin/python3 -m oceand.sea SOURCE [--time T] [--point NAME]

The same readers as `ocean-tap sea` (tools/sea_*.c), written again from the same
description (docs/operations.md, "Measured seas"): the same document, the same error
codes naming the same file, line and band (SeaError), numbers equal to the C readers'
(a test compares them). Every direction in a document is where waves come FROM, degrees
clockwise from true north. Pure Python (and numpy for the statistics); gzip for
historical .gz files, urllib for URLs."""
import gzip
import json
import math
import os
import re
import sys
import urllib.parse
import urllib.request
from datetime import datetime, timezone

import numpy as np

MAX_FREQ = 128
MAX_DIR = 72
MAX_M0 = 100.0
MAX_TIMES = 512
MAX_BYTES = 64 << 20
EXIT_SEA = 8

NDBC_RT = "https://www.ndbc.noaa.gov/data/realtime2/"
CDIP_RT = "https://thredds.cdip.ucsd.edu/thredds/dodsC/cdip/realtime/"
RT_EXT = (".data_spec", ".swdir", ".swdir2", ".swr1", ".swr2")
HIST_LETTERS = "wdijk"
_NUM = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_INT = re.compile(r"[0-9]+")


class SeaError(Exception):
    """A source that cannot be read or is not a valid sea: code, file, line (1-based, 0 =
    the file as a whole), band (1-based, 0 = none), message."""

    def __init__(self, code, file, line, band, msg):
        super().__init__(msg)
        self.code, self.file, self.line, self.band, self.msg = code, file, line, band, msg

    def __str__(self):
        where = f"{self.file}:{self.line}: " if self.file and self.line > 0 else f"{self.file}: " if self.file else ""
        band = f"band {self.band}: " if self.band > 0 else ""
        return f"error {self.code}: {where}{band}{self.msg}"


def _alpha(c):
    """C's isalpha in the C locale: ASCII letters only."""
    return ("a" <= c <= "z") or ("A" <= c <= "Z")


def _num(tok):
    """A number token (all of it), or None."""
    if _NUM.fullmatch(tok) is None:
        return None
    v = float(tok)
    return v if math.isfinite(v) else None


def time_canon(text):
    m = re.fullmatch(r"([0-9]{4})-([0-9]{1,2})-([0-9]{1,2})T([0-9]{1,2}):([0-9]{1,2})(?::([0-9]{1,2}))?Z?", text)
    if not m:
        return None
    y, mo, d, h, mi = (int(g) for g in m.groups()[:5])
    s = int(m.group(6) or 0)
    if not (1 <= mo <= 12 and 1 <= d <= 31 and h <= 23 and mi <= 59 and s <= 60 and 1900 <= y <= 9999):
        return None
    return f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}:{s:02d}Z"


def _want(when):
    if when is None:
        return None
    c = time_canon(when)
    if c is None:
        raise SeaError("no_time", "", 0, 0, f"--time {when[:40]} is not YYYY-MM-DDThh:mm[:ss]Z")
    return c


def bandwidth_from_centres(f):
    n = len(f)
    if n == 1:
        return [f[0] * 0.1]
    out = []
    for i in range(n):
        lo = (f[i] - f[i - 1]) / 2 if i > 0 else (f[1] - f[0]) / 2
        hi = (f[i + 1] - f[i]) / 2 if i < n - 1 else (f[n - 1] - f[n - 2]) / 2
        out.append(lo + hi)
    return out


# ---- the document -------------------------------------------------------------

def _dir_widths(dirs):
    n = len(dirs)
    if n == 1:
        return [2 * math.pi]
    w = []
    for j in range(n):
        lo = math.fmod(dirs[j] - dirs[(j - 1) % n] + 360.0, 360.0)
        hi = math.fmod(dirs[(j + 1) % n] - dirs[j] + 360.0, 360.0)
        w.append((lo + hi) / 2 * math.pi / 180)
    return w


def stats(doc):
    """m0, Hs = 4 sqrt(m0), Tp, the peak frequency and the direction (from) at the peak band."""
    f, bw = doc["frequency"], doc["bandwidth"]
    if doc["form"] == "moments":
        s = list(doc["energy"])
    else:
        w = _dir_widths(doc["direction"])
        s = [sum(e * wj for e, wj in zip(row, w)) for row in doc["energy"]]
    m0 = 0.0
    peak, best = 0, -1.0
    for i in range(len(f)):
        m0 += s[i] * bw[i]
        if s[i] > best:
            best, peak = s[i], i
    if doc["form"] == "moments":
        sx, sy = doc["a1"][peak], doc["b1"][peak]
    else:
        sx = sy = 0.0
        for e, wj, d in zip(doc["energy"][peak], w, doc["direction"]):
            sx += e * wj * math.cos(d * math.pi / 180)
            sy += e * wj * math.sin(d * math.pi / 180)
    fp = f[peak]
    return {"m0": m0, "hs": 4 * math.sqrt(m0), "fp": fp, "tp": 1 / fp if fp > 0 else 0.0, "peak": peak,
            "direction_at_peak": math.fmod(math.atan2(sy, sx) * 180 / math.pi + 360.0, 360.0)}


def summary(doc):
    st = stats(doc)
    hs = f" (the file says {doc['_file_hs']:.2f} m)" if doc.get("_file_hs") is not None else ""
    return (f"{doc['source']} {doc['time']}: Hs {st['hs']:.2f} m{hs}, Tp {st['tp']:.2f} s, from "
            f"{st['direction_at_peak']:.1f} deg at the peak ({st['fp']:.4f} Hz)")


def check(doc, file):
    """The document's limits; raises SeaError as the C readers do (sea_doc_check)."""
    f, bw = doc["frequency"], doc["bandwidth"]
    if not 1 <= len(f) <= MAX_FREQ:
        raise SeaError("too_many_bands", file, 0, 0, f"{len(f)} frequencies (1..{MAX_FREQ})")
    twod = doc["form"] == "spectrum2d"
    if twod and not 1 <= len(doc["direction"]) <= MAX_DIR:
        raise SeaError("too_many_bands", file, 0, 0, f"{len(doc['direction'])} directions (1..{MAX_DIR})")
    for i in range(len(f)):
        if not math.isfinite(f[i]) or f[i] <= 0 or (i > 0 and not f[i] > f[i - 1]):
            raise SeaError("out_of_range", file, 0, i + 1, f"frequency {f[i]:g} Hz: bands must increase from > 0")
        if not math.isfinite(bw[i]) or bw[i] <= 0:
            raise SeaError("out_of_range", file, 0, i + 1, f"band width {bw[i]:g} Hz")
        if not twod:
            e = doc["energy"][i]
            if not math.isfinite(e) or e < 0:
                raise SeaError("out_of_range", file, 0, i + 1, f"energy {e:g} m^2/Hz")
            for k in ("a1", "b1", "a2", "b2"):
                v = doc[k][i]
                if not math.isfinite(v) or abs(v) > 1 + 1e-9:
                    raise SeaError("out_of_range", file, 0, i + 1, f"{k} = {v:g}: |.| <= 1")
        else:
            for e, d in zip(doc["energy"][i], doc["direction"]):
                if not math.isfinite(e) or e < 0:
                    raise SeaError("out_of_range", file, 0, i + 1, f"energy {e:g} at direction {d:g}")
    if twod:
        dirs = doc["direction"]
        for j, d in enumerate(dirs):
            if not math.isfinite(d) or d < 0 or d >= 360 or (j > 0 and not d > dirs[j - 1]):
                raise SeaError("out_of_range", file, 0, 0, f"direction {j + 1} ({d:g} deg): distinct, in [0, 360)")
    st = stats(doc)
    if not st["m0"] <= MAX_M0:
        raise SeaError("out_of_range", file, 0, 0, f"m0 = {st['m0']:g} m^2 (Hs {st['hs']:.1f} m): at most {MAX_M0:g} m^2")
    fh = doc.get("_file_hs")
    if fh is not None and fh > 0 and abs(st["hs"] - fh) > 0.1 * fh:
        raise SeaError("hs_mismatch", file, 0, 0, f"the file's Hs {fh:.3f} m, its bands give 4 sqrt(m0) = {st['hs']:.3f} m")
    return doc


def public(doc):
    """The document without the reader's private members (_file_hs)."""
    return {k: v for k, v in doc.items() if not k.startswith("_")}


# ---- NDBC ----------------------------------------------------------------------

LINE_MAX = 16383    # the C reader's line buffer: a longer line is refused, not read in part


def _lines(text, name):
    """(line number, tokens) of every non-empty line."""
    for no, line in enumerate(text.split("\n"), 1):
        toks = [t for t in re.split(r"[ \t\r]+", line) if t]
        if toks:
            if len(line) > LINE_MAX:
                raise SeaError("bad_number", name, no, 0, f"a line of more than {LINE_MAX} bytes")
            yield no, toks


def _row_time(no, toks, ntime, file):
    if len(toks) < ntime:
        raise SeaError("truncated", file, no, 0, "the row ends in its time columns")
    v = [0] * 5
    for k in range(ntime):
        t = toks[k]
        if _INT.fullmatch(t) is None or int(t) > 99999:
            raise SeaError("bad_number", file, no, 0, f'time column {k + 1} is "{t[:40]}", not a whole number')
        v[k] = int(t)
    if v[0] < 100:
        v[0] += 1900        # the oldest files write two-digit years, all 19xx
    if not (1 <= v[1] <= 12 and 1 <= v[2] <= 31 and v[3] <= 23 and v[4] <= 59):
        raise SeaError("out_of_range", file, no, 0, f"no such time: {v[0]} {v[1]} {v[2]} {v[3]} {v[4]}")
    return f"{v[0] % 10000:04d}-{v[1]:02d}-{v[2]:02d}T{v[3]:02d}:{v[4]:02d}:00Z"


def _value(tok, miss99):
    """(missing, value); None if not a number."""
    if tok == "MM":
        return True, 0.0
    v = _num(tok)
    if v is None:
        return None
    if v >= 999 or (miss99 and v == 99):
        return True, v
    return False, v


def _scan_times(text, name, ntime):
    rows = {}
    order = []
    for no, toks in _lines(text, name):
        if toks[0][0] == "#" or _alpha(toks[0][0]):
            continue
        t = _row_time(no, toks, ntime, name)
        if t not in rows:       # the first row of a time, as the C reader finds it
            rows[t] = (no, toks)
        order.append(t)
    if not order:       # named at the file's last line, as the C reader counts them
        last = text.count("\n") + (0 if not text or text.endswith("\n") else 1)
        raise SeaError("truncated", name, last, 0, "no data rows")
    return rows, order


def _choose(names, rows, orders, want):
    if want is not None:
        for k in range(5):
            if want not in rows[k]:
                raise SeaError("no_time", names[k], 0, 0, f"no row at {want}")
        return want
    common = [t for t in orders[0] if all(t in rows[k] for k in range(1, 5))]
    if not common:
        raise SeaError("no_time", names[0], 0, 0, "no time is in all five files")
    return max(common)


def _rt_pairs(no, toks, first, name):
    f, v, miss = [], [], []
    k = first
    while k < len(toks):
        band = len(f) + 1
        if len(f) == MAX_FREQ:
            raise SeaError("too_many_bands", name, no, band, f"more than {MAX_FREQ} bands")
        if k + 1 >= len(toks):
            raise SeaError("truncated", name, no, band, f'the row ends after the value "{toks[k][:40]}", before its frequency')
        ft = toks[k + 1]
        if len(ft) < 3 or len(ft) >= 64 or ft[0] != "(" or ft[-1] != ")":
            raise SeaError("bad_number", name, no, band, f'"{ft[:40]}" is not a frequency "(0.033)"')
        fv = _num(ft[1:-1])
        if fv is None:
            raise SeaError("bad_number", name, no, band, f'frequency "{ft[:40]}" is not a number')
        r = _value(toks[k], False)
        if r is None:
            raise SeaError("bad_number", name, no, band, f'"{toks[k][:40]}" is not a number')
        f.append(fv)
        miss.append(r[0])
        v.append(r[1])
        k += 2
    return {"file": name, "line": no, "f": f, "v": v, "miss": miss}


def _combine(r, hist, station, when):
    what = ("C11", "alpha1", "alpha2", "r1", "r2")
    n = len(r[0]["f"])
    if n < 1:
        raise SeaError("truncated", r[0]["file"], r[0]["line"], 0, "the row has no bands")
    for k in range(1, 5):
        nk = len(r[k]["f"])
        if nk < n:
            raise SeaError("truncated", r[k]["file"], r[k]["line"], nk + 1, f"the row has {nk} bands, {r[0]['file']} has {n}")
        if nk > n:
            raise SeaError("bands_mismatch", r[k]["file"], r[k]["line"], n + 1,
                           f"the row has {nk} bands, {r[0]['file']} has {n}")
        for i in range(n):
            if abs(r[k]["f"][i] - r[0]["f"][i]) > 5e-5:
                raise SeaError("bands_mismatch", r[k]["file"], r[k]["line"], i + 1,
                               f"frequency {r[k]['f'][i]:g} Hz, {r[0]['file']} has {r[0]['f'][i]:g} Hz")
    scale = [1.0] * 5
    if hist:
        for k in (3, 4):
            mx = max([v for v, m in zip(r[k]["v"], r[k]["miss"]) if not m] + [0.0])
            if mx > 1:
                scale[k] = 0.01     # this year stores r x 100
    doc = {"form": "moments", "source": f"NDBC {station}", "time": when, "depth": None,
           "frequency": list(r[0]["f"]), "bandwidth": None, "energy": [], "a1": [], "b1": [], "a2": [], "b2": []}
    for i in range(n):
        if r[0]["miss"][i]:
            raise SeaError("missing", r[0]["file"], r[0]["line"], i + 1, f"C11 at {r[0]['f'][i]:g} Hz is missing")
        e = r[0]["v"][i]
        if e < 0:
            raise SeaError("out_of_range", r[0]["file"], r[0]["line"], i + 1, f"C11 {e:g} < 0")
        doc["energy"].append(e)
        x = [0.0] * 5
        for k in range(1, 5):
            x[k] = r[k]["v"][i] * scale[k]
            if r[k]["miss"][i] and e != 0:
                raise SeaError("missing", r[k]["file"], r[k]["line"], i + 1,
                               f"{what[k]} at {r[k]['f'][i]:g} Hz is missing and the band has energy {e:g} m^2/Hz")
            if r[k]["miss"][i]:
                continue
            bad = (x[k] < 0 or x[k] > 360) if k <= 2 else (x[k] < 0 or x[k] > 1)
            if bad:
                rng = "0..360" if k <= 2 else "0..1 (or 0..100)" if hist else "0..1"
                raise SeaError("out_of_range", r[k]["file"], r[k]["line"], i + 1,
                               f"{what[k]} = {r[k]['v'][i]:g} is outside {rng}")
        if any(r[k]["miss"][i] for k in range(1, 5)):
            for c in ("a1", "b1", "a2", "b2"):
                doc[c].append(0.0)      # a band without energy
            continue
        a1r, a2r = x[1] * math.pi / 180, x[2] * math.pi / 180
        doc["a1"].append(x[3] * math.cos(a1r))
        doc["b1"].append(x[3] * math.sin(a1r))
        doc["a2"].append(x[4] * math.cos(2 * a2r))
        doc["b2"].append(x[4] * math.sin(2 * a2r))
    doc["bandwidth"] = bandwidth_from_centres(doc["frequency"])
    return check(doc, r[0]["file"])


def ndbc_realtime(texts, names, station, when=None):
    """texts, names: the .data_spec, .swdir, .swdir2, .swr1, .swr2 files (this order)."""
    want = _want(when)
    scans = [_scan_times(texts[k], names[k], 5) for k in range(5)]
    t = _choose(names, [s[0] for s in scans], [s[1] for s in scans], want)
    rows = []
    for k in range(5):
        no, toks = scans[k][0][t]
        first = 5
        if k == 0:      # SepFreq: the wind sea/swell separation, not a band
            if len(toks) < 6:
                raise SeaError("truncated", names[k], no, 0, "the row ends before SepFreq")
            if _num(toks[5]) is None:
                raise SeaError("bad_number", names[k], no, 0, f'SepFreq "{toks[5][:40]}" is not a number')
            first = 6
        rows.append(_rt_pairs(no, toks, first, names[k]))
    return _combine(rows, False, station, t)


def _hist_header(text, name):
    for no, toks in _lines(text, name):
        k = 0
        while k < len(toks) and _num(toks[k]) is None:
            k += 1
        lab = toks[0][1:] if toks[0][0] == "#" else toks[0]
        if k < 4 or k > 5 or lab not in ("YY", "YYYY"):
            raise SeaError("bad_header", name, no, 0,
                           f'expected "#YY MM DD hh [mm] .0200 .0325 ...", got "{toks[0][:60]}"')
        freq = []
        for tok in toks[k:]:
            if len(freq) == MAX_FREQ:
                raise SeaError("too_many_bands", name, no, len(freq) + 1, f"more than {MAX_FREQ} bands")
            v = _num(tok)
            if v is None:
                raise SeaError("bad_header", name, no, len(freq) + 1, f'band centre "{tok[:40]}" is not a number')
            freq.append(v)
        if not freq:
            raise SeaError("bad_header", name, no, 0, "the header names no bands")
        return k, freq
    raise SeaError("bad_header", name, 1, 0, "the file is empty")


def ndbc_historical(texts, names, station, when=None):
    """texts, names: the w (swden), d (swdir), i (swdir2), j (swr1), k (swr2) files."""
    want = _want(when)
    heads, scans = [], []
    for k in range(5):
        heads.append(_hist_header(texts[k], names[k]))
        scans.append(_scan_times(texts[k], names[k], heads[k][0]))
    t = _choose(names, [s[0] for s in scans], [s[1] for s in scans], want)
    rows = []
    for k in range(5):
        ntime, freq = heads[k]
        no, toks = scans[k][0][t]
        have = len(toks) - ntime
        if have < len(freq):
            raise SeaError("truncated", names[k], no, have + 1, f"the row has {have} values, the header {len(freq)} bands")
        if have > len(freq):
            raise SeaError("bands_mismatch", names[k], no, len(freq) + 1,
                           f"the row has {have} values, the header {len(freq)} bands")
        v, miss = [], []
        for i, tok in enumerate(toks[ntime:]):
            r = _value(tok, k >= 3)
            if r is None:
                raise SeaError("bad_number", names[k], no, i + 1, f'"{tok[:40]}" is not a number')
            miss.append(r[0])
            v.append(r[1])
        rows.append({"file": names[k], "line": no, "f": freq, "v": v, "miss": miss})
    for k in range(1, 5):
        for i in range(min(len(rows[k]["f"]), len(rows[0]["f"]))):
            if abs(rows[k]["f"][i] - rows[0]["f"][i]) > 5e-5:
                raise SeaError("bands_mismatch", names[k], 1, i + 1,
                               f"band centre {rows[k]['f'][i]:g} Hz, {names[0]} has {rows[0]['f'][i]:g} Hz")
    for k in range(1, 5):
        if len(rows[k]["f"]) != len(rows[0]["f"]):
            raise SeaError("bands_mismatch", names[k], 1, 0, f"{len(rows[k]['f'])} bands, {names[0]} has {len(rows[0]['f'])}")
    return _combine(rows, True, station, t)


# ---- WAVEWATCH III ---------------------------------------------------------------

class _Cursor:
    """Numbers one after the other, as Fortran's columns may join them ("37.75-122.83")."""
    _ANY = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")

    def __init__(self, text, name):
        self.t, self.name, self.pos, self.line, self.last = text, name, 0, 1, 1

    def skip_ws(self):
        t, n = self.t, len(self.t)
        while self.pos < n and t[self.pos] in " \t\r\n\f\v":
            if t[self.pos] == "\n":
                self.line += 1
            self.pos += 1

    def num(self, band):
        """The next number, or None at the end of the file."""
        self.skip_ws()
        if self.pos >= len(self.t):
            return None
        m = self._ANY.match(self.t, self.pos)
        end = m.end() if m else self.pos
        nxt = self.t[end] if end < len(self.t) else ""
        if not m or (nxt and nxt not in " \t\r\n\f\v+-") or not math.isfinite(float(m.group())):
            tok = re.match(r"[^ \t\r\n\f\v]{0,40}", self.t[self.pos:]).group()
            raise SeaError("bad_number", self.name, self.line, band, f'"{tok}" is not a number')
        self.pos = end
        self.last = self.line
        return float(m.group())

    def rest_of_line(self):
        self.skip_ws()
        if self.pos >= len(self.t):
            return None
        nl = self.t.find("\n", self.pos)
        end = len(self.t) if nl < 0 else nl
        s = self.t[self.pos:end]
        self.pos = end
        return s[:511]


def _quoted(s):
    """('name' without its padding, the rest), or None."""
    if not s.startswith("'"):
        return None
    q = s.find("'", 1)
    if q < 0:
        return None
    return s[1:q].rstrip(" "), s[q + 1:]


def ww3(text, name, point=None):
    """Every time of one point (the first, or `point`): a list of spectrum2d documents."""
    c = _Cursor(text, name)
    head = c.rest_of_line()
    if head is None:
        raise SeaError("bad_header", name, 1, 0, "the file is empty")
    q = _quoted(head)
    if q is None or q[0] != "WAVEWATCH III SPECTRA":
        raise SeaError("bad_header", name, 1, 0, "not a WAVEWATCH III spectrum file (no 'WAVEWATCH III SPECTRA' at its start)")
    m = re.match(r"[ \t\r\n\f\v]*([+-]?[0-9]+)[ \t\r\n\f\v]+([+-]?[0-9]+)[ \t\r\n\f\v]+([+-]?[0-9]+)[ \t\r\n\f\v]*", q[1])
    if not m or _quoted(q[1][m.end():]) is None:
        raise SeaError("bad_header", name, 1, 0, "expected NF ND NP 'grid' after the title")
    nf, nd, np_ = (int(g) for g in m.groups())
    if not (1 <= nf <= MAX_FREQ and 1 <= nd <= MAX_DIR):
        raise SeaError("too_many_bands", name, 1, 0,
                       f"{nf} frequencies and {nd} directions (at most {MAX_FREQ} and {MAX_DIR})")
    if not 1 <= np_ <= 100000:
        raise SeaError("bad_header", name, 1, 0, f"{np_} points")
    freq, dirs = [], []
    for i in range(nf + nd):
        v = c.num(i + 1 if i < nf else 0)
        if v is None:
            raise SeaError("truncated", name, c.last, i + 1 if i < nf else 0,
                           f"the file ends in its {'frequencies' if i < nf else 'directions'}")
        if i < nf:
            if not v > 0 or (freq and not v > freq[-1]):
                raise SeaError("out_of_range", name, c.line, i + 1, f"frequency {v:g} Hz: bands must increase from > 0")
            freq.append(v)
            continue
        if v < 0 or v > 2 * math.pi + 1e-6:
            raise SeaError("out_of_range", name, c.line, 0, f"direction {i - nf + 1} is {v:g} rad, outside 0..2 pi")
        frm = math.fmod(v * 180 / math.pi + 180, 360)
        if frm >= 360 - 1e-9:
            frm = 0.0
        dirs.append((frm, i - nf))
    dirs.sort(key=lambda d: d[0])
    for j in range(1, nd):
        if dirs[j][0] - dirs[j - 1][0] < 1e-6:
            raise SeaError("out_of_range", name, 0, 0, f"two directions are the same ({dirs[j][0]:g} deg from)")
    ratio = (freq[-1] / freq[0]) ** (1.0 / (nf - 1)) if nf > 1 else 1.1
    if all(abs(freq[i] / freq[i - 1] / ratio - 1) < 5e-3 for i in range(1, nf)):
        bw = [fi * (ratio - 1 / ratio) / 2 for fi in freq]
    else:
        bw = bandwidth_from_centres(freq)
    col = [0] * nd
    for j, (_, k) in enumerate(dirs):
        col[k] = j
    docs = []
    while True:
        c.skip_ws()
        tline = c.line
        line = c.rest_of_line()
        if line is None:
            break
        m = re.fullmatch(r"[ \t\r\n\f\v]*([+-]?[0-9]{1,8})[ \t\r\n\f\v]*([+-]?[0-9]{1,6})", line)
        if not m:
            raise SeaError("bad_header", name, tline, 0, f'expected a time "YYYYMMDD HHMMSS", got "{line[:40]}"')
        ymd, hms = int(m.group(1)), int(m.group(2))
        when = time_canon(f"{ymd // 10000:04d}-{ymd // 100 % 100:02d}-{ymd % 100:02d}T"
                          f"{hms // 10000:02d}:{hms // 100 % 100:02d}:{hms % 100:02d}Z")
        if when is None:
            raise SeaError("out_of_range", name, tline, 0, f"no such time: {ymd:08d} {hms:06d}")
        found = False
        for ip in range(np_):
            c.skip_ws()
            pline = c.line
            line = c.rest_of_line()
            if line is None:
                raise SeaError("truncated", name, pline, 0, f"the file ends before point {ip + 1} of {when}")
            q = _quoted(line)
            nums, at = [], 0
            while q and len(nums) < 3:      # lat lon depth, one after the other (as sscanf reads them)
                m = re.compile(r"[ \t\r\n\f\v]*([+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)").match(q[1], at)
                if not m:
                    break
                nums.append(m.group(1))
                at = m.end()
            if q is None or len(nums) < 3:
                raise SeaError("bad_header", name, pline, 0, f"expected 'NAME' lat lon depth ..., got \"{line[:40]}\"")
            mine = not found and (point is None or point == q[0])
            doc = None
            if mine:
                if len(docs) == MAX_TIMES:
                    raise SeaError("too_many_bands", name, tline, 0, f"more than {MAX_TIMES} times")
                depth = float(nums[2])
                doc = {"form": "spectrum2d", "source": f"WW3 {q[0]}", "time": when,
                       "depth": depth if 0 < depth < 20000 else None, "frequency": list(freq), "bandwidth": list(bw),
                       "direction": [d[0] for d in dirs], "energy": [[0.0] * nd for _ in range(nf)]}
                found = True
            for v in range(nf * nd):
                x = c.num(v % nf + 1)
                if x is None:
                    raise SeaError("truncated", name, c.last, v % nf + 1,
                                   f"the file ends after {v} of the {nf * nd} values of {q[0]} at {when}")
                if doc is not None:
                    doc["energy"][v % nf][col[v // nf]] = x
            if doc is not None:
                try:
                    check(doc, name)
                except SeaError as err:
                    err.line = pline
                    raise
                docs.append(doc)
        if not found:
            raise SeaError("bad_header", name, tline, 0, f'no point named "{point}" at {when}')
    if not docs:
        raise SeaError("truncated", name, c.line, 0, "no time in the file")
    return docs


# ---- CDIP ---------------------------------------------------------------------------

_CDIP = ("waveTime", "waveFrequency", "waveBandwidth", "waveEnergyDensity", "waveA1Value", "waveB1Value",
         "waveA2Value", "waveB2Value", "waveHs", "waveFlagPrimary", "metaWaterDepth")


def _cdip_values(s, var, no, name):
    while s.startswith("["):
        q = s.find("]")
        if q < 0:
            raise SeaError("bad_number", name, no, 0, f'unclosed row index "{s[:40]}"')
        s = s[q + 1:].lstrip(" ,")
    parts = s.split(",")
    for idx, part in enumerate(parts):
        p = part.strip(" \t\r")
        if not p and idx == len(parts) - 1:
            break           # a trailing comma, or an empty row
        m = re.fullmatch(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|nan|NaN|inf|Inf", p)
        if not m:
            raise SeaError("bad_number", name, no, len(var) + 1, f'"{p[:40]}" is not a number')
        var.append((float(p), no))


def cdip(text, name, station, when=None):
    want = _want(when)
    v = {k: [] for k in _CDIP}
    lines = text.split("\n")
    body = seen_dds = False
    cur = None
    for no, raw in enumerate(lines, 1):
        if len(raw) >= 65536:
            raise SeaError("bad_number", name, no, 0, "a line of more than 65536 bytes")
        t = raw.lstrip(" \t").rstrip("\r ")
        if not body:
            if t.startswith("Dataset"):
                seen_dds = True
            if len(t) >= 8 and set(t) == {"-"}:
                body = True
                continue
            if seen_dds:
                continue
            body = True
        if not t:
            cur = None
            continue
        if _alpha(t[0]):
            head = re.split(r"[\[,]", t, 1)[0]
            vn = head.split(".", 1)[1] if "." in head else head
            cur = vn if vn in v and not v[vn] else None
            if cur and "," in t and "[" not in t:
                _cdip_values(t[t.index(",") + 1:], v[cur], no, name)
                cur = None
            continue
        if cur:
            _cdip_values(t, v[cur], no, name)
    if not body:
        last = text.count("\n") + (0 if not text or text.endswith("\n") else 1)   # as the C reader counts
        raise SeaError("bad_header", name, last, 0, "no values after the dataset description")
    for k in _CDIP[:8]:
        if not v[k]:
            raise SeaError("bad_header", name, 0, 0, f"no {k} in the answer")
    nt, nf = len(v["waveTime"]), len(v["waveFrequency"])
    if nf > MAX_FREQ:
        raise SeaError("too_many_bands", name, v["waveFrequency"][0][1], MAX_FREQ + 1, f"{nf} bands (at most {MAX_FREQ})")
    b = v["waveBandwidth"]
    if len(b) != nf:
        raise SeaError("truncated" if len(b) < nf else "bands_mismatch", name, b[-1][1], 0, f"{len(b)} band widths for {nf} bands")
    for k in _CDIP[3:8]:
        x = v[k]
        if len(x) != nt * nf:
            raise SeaError("truncated" if len(x) < nt * nf else "bands_mismatch", name, x[-1][1],
                           len(x) % nf + 1 if len(x) % nf else 0,
                           f"{k} has {len(x)} values, {nt} times x {nf} bands need {nt * nf}")
    t, stamp = -1, ""
    for k, (s, no) in enumerate(v["waveTime"]):
        if not -1e11 < s < 1e11:
            raise SeaError("out_of_range", name, no, 0, f"waveTime {s:g}")
        w = datetime.fromtimestamp(round(s), timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
        if (w == want) if want else (t < 0 or s > v["waveTime"][t][0]):
            t, stamp = k, w
    if t < 0:
        raise SeaError("no_time", name, 0, 0, f"no record at {want}")
    fl = v["waveFlagPrimary"]
    if len(fl) == nt and fl[t][0] != 1:
        raise SeaError("flagged", name, fl[t][1], 0, f"waveFlagPrimary is {fl[t][0]:g} at {stamp} (1 = good)")
    depth = v["metaWaterDepth"][0][0] if v["metaWaterDepth"] else None
    hs = v["waveHs"][t][0] if len(v["waveHs"]) == nt else None
    doc = {"form": "moments", "source": f"CDIP {station}", "time": stamp,
           "depth": depth if depth is not None and 0 < depth < 20000 else None}
    if hs is not None and (not math.isfinite(hs) or hs <= -999):
        hs = None
    keys = {"waveFrequency": "frequency", "waveBandwidth": "bandwidth", "waveEnergyDensity": "energy",
            "waveA1Value": "a1", "waveB1Value": "b1", "waveA2Value": "a2", "waveB2Value": "b2"}
    for k in _CDIP[1:8]:
        out = []
        for i in range(nf):
            x, no = v[k][i if k in ("waveFrequency", "waveBandwidth") else t * nf + i]
            if not math.isfinite(x) or x <= -999:
                raise SeaError("missing", name, no, i + 1, f"{k} is missing ({x:g}) at {stamp}")
            out.append(x)
        doc[keys[k]] = out
    doc["_file_hs"] = hs
    check(doc, name)
    return doc


# ---- sources ---------------------------------------------------------------------------

def load(source):
    """The text of a file or an http(s):// URL, gunzipped when the name ends in .gz."""
    try:
        if source.startswith(("http://", "https://")):
            with urllib.request.urlopen(source, timeout=30) as r:
                data = r.read(MAX_BYTES + 1)
        else:
            with open(source, "rb") as fh:
                data = fh.read(MAX_BYTES + 1)
    except OSError as e:
        raise SeaError("io", source, 0, 0, f"cannot read: {getattr(e, 'reason', None) or e.strerror or e}") from None
    if len(data) > MAX_BYTES:
        raise SeaError("io", source, 0, 0, "larger than 64 MiB")
    if source.endswith(".gz"):
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, ValueError):
            raise SeaError("io", source, 0, 0, "not a whole gzip stream") from None
    if b"\0" in data:
        raise SeaError("bad_header", source, 0, 0, "a NUL byte: not text")
    # latin-1: one character per byte, as the C readers see them (line lengths, what is a letter)
    return data.decode("latin-1")


def _base(s):
    path = s.split("?", 1)[0]
    return path.rsplit("/", 1)[-1]


def _hist_at(name):
    b = _base(name)
    m = re.fullmatch(r"(.{5})([wdijk])([0-9]{4})\.txt(\.gz)?", b)
    return len(name.split("?", 1)[0]) - len(b) + 5 if m else -1


def cdip_url(station):
    """The URL of a CDIP station's newest record (its size asked first, the dataset's .dds)."""
    base = os.environ.get("OCEAND_SEA_CDIP") or CDIP_RT     # another server (a mirror, the tests' own)
    dds = load(f"{base}{station}p1_rt.nc.dds")
    nt = re.search(r"\[waveTime = ([0-9]+)\]", dds)
    nf = re.search(r"\[waveFrequency = ([0-9]+)\]", dds)
    if not nt or not nf or not 1 <= int(nf.group(1)) <= MAX_FREQ:
        raise SeaError("bad_header", f"{base}{station}p1_rt.nc.dds", 0, 0,
                       f"no waveTime and waveFrequency dimensions (1..{MAX_FREQ} bands) in the dataset's description")
    t, f = int(nt.group(1)) - 1, int(nf.group(1)) - 1
    ix, ixf = f"[{t}]", f"[{t}][0:1:{f}]"
    q = (f"waveTime{ix},waveFrequency,waveBandwidth,waveEnergyDensity{ixf},waveA1Value{ixf},waveB1Value{ixf},"
         f"waveA2Value{ixf},waveB2Value{ixf},waveHs{ix},waveFlagPrimary{ix},metaWaterDepth")
    return f"{base}{station}p1_rt.nc.ascii?{q}"


def read(source, when=None, point=None):
    """A document (NDBC, CDIP) or a list of them (WAVEWATCH III), from a file, a URL or ndbc:ID / cdip:ID.
    Raises SeaError."""
    station = ""
    one = source
    kind = None
    if source.startswith("ndbc:"):
        station = source[5:65]
        one = f"{os.environ.get('OCEAND_SEA_NDBC') or NDBC_RT}{station}.data_spec"
    elif source.startswith("cdip:"):
        station = source[5:65]
        one = cdip_url(station)
        kind = "cdip"
    if kind is None:
        for ext in RT_EXT:
            if one.endswith(ext):
                stem = one[:-len(ext)]
                names = [stem + e for e in RT_EXT]
                station = station or _base(one)[:-len(ext)]
                texts = [load(n) for n in names]
                return ndbc_realtime(texts, [_base(n) for n in names], station, when)
        at = _hist_at(one)
        if at >= 0:
            # NDBC's own server keeps each kind in a folder of its own (.../swden/46026w2023.txt.gz)
            folders = ("/swden/", "/swdir/", "/swdir2/", "/swr1/", "/swr2/")
            mine = folders[HIST_LETTERS.index(one[at])]
            head, tail = one[:at - 5], one[at - 5:]
            if head.endswith(mine):
                names = [head[:-len(mine)] + fo + tail[:5] + c + tail[6:] for fo, c in zip(folders, HIST_LETTERS)]
            else:
                names = [one[:at] + c + one[at + 1:] for c in HIST_LETTERS]
            texts = [load(n) for n in names]
            return ndbc_historical(texts, [_base(n) for n in names], one[at - 5:at], when)
    text = load(one)
    name = _base(one)
    if kind is None:
        kind = "ww3" if text.startswith("'WAVEWATCH III SPECTRA'") else "cdip" if "waveEnergyDensity" in text else None
    if kind == "ww3":
        docs = ww3(text, name, point)
        if when is not None:
            w = _want(when)
            keep = [d for d in docs if d["time"] == w]
            if not keep:
                raise SeaError("no_time", name, 0, 0, f"no time {w} in the file")
            docs = keep[-1:]
        return docs
    if kind == "cdip":
        return cdip(text, name, station or re.split(r"[_.?]", name, 1)[0], when)
    raise SeaError("bad_header", name, 1, 0, "not a sea this reader knows (NDBC files are recognised by their names, "
                   "WAVEWATCH III and CDIP by their text)")


def main(argv=None):
    import argparse
    ap = argparse.ArgumentParser(prog="python -m oceand.sea",
                                 description="Read a measured sea and print its sea document (JSON, one line) on "
                                             "stdout, a summary per time on stderr.")
    ap.add_argument("source", help="a file, an http(s):// URL, ndbc:ID or cdip:ID")
    ap.add_argument("--time", help="the record at this time (YYYY-MM-DDThh:mm[:ss]Z) instead of the newest")
    ap.add_argument("--point", help="the WAVEWATCH III output point (default: the first)")
    ap.add_argument("--send", metavar="URL", help="send it to the daemon at this ws:// URL (PROTOCOL.md §7.8) "
                                                   "instead of printing it; a forecast plays as a timeline")
    ap.add_argument("--speed", type=float, default=3600.0,
                    help="--send of a forecast: forecast seconds per wall-clock second (default 3600)")
    ap.add_argument("--token", help="--send: the daemon's control token")
    ap.add_argument("--tail", choices=("f-4", "f-5", "none", "wind"), help="--send: what lies above the last band")
    a = ap.parse_args(argv)
    if a.speed <= 0:
        ap.error("--speed must be > 0")
    if a.time is not None and time_canon(a.time) is None:
        ap.error("--time needs YYYY-MM-DDThh:mm[:ss]Z")
    try:
        got = read(a.source, a.time, a.point)
    except SeaError as e:
        print(f"python -m oceand.sea: {e}", file=sys.stderr)
        return EXIT_SEA
    docs = got if isinstance(got, list) else [got]
    for d in docs:
        print(summary(d), file=sys.stderr)
    if a.send:
        return _send(a, [public(d) for d in docs])
    out = [public(d) for d in docs] if isinstance(got, list) else public(got)
    print(json.dumps(out, separators=(",", ":")))
    return 0


def _send(a, docs):
    """--send: the documents to a daemon, at their times (a forecast) or at once (one)."""
    import asyncio
    from .client import AsyncClient, ServerError

    def said(d, r):
        s = r.get("sea") or {}
        print(f"sent {d.get('source', '')} {d.get('time', '')}: params_version {r.get('params_version')}, "
              f"the grid holds {s.get('captured')}" + (f" ({s['fit_note']})" if s.get("fit_note") else ""),
              file=sys.stderr)

    async def run():
        async with await AsyncClient.connect(a.send) as c:
            await c.play_forecast(docs, a.speed, a.token, a.tail, said)
    try:
        asyncio.run(run())
    except ServerError as e:
        print(f"python -m oceand.sea: the daemon refused the sea: {e}", file=sys.stderr)
        return EXIT_SEA
    except (OSError, ConnectionError) as e:
        print(f"python -m oceand.sea: {a.send}: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

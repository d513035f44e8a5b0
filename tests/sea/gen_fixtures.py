#!/usr/bin/env python3
"""Writes the sea readers' fixtures (tests/sea/fixtures/) from one known sea.

The sea ("the known sea"):
  - a wind sea: JONSWAP, Hs 2.0 m, Tp 7 s, gamma 3.3, coming from 225 deg (SW),
    spreading cos^2s((theta - 225)/2) with s = 8;
  - a swell: Gaussian in frequency, Hs 1.5 m, peak 1/13.5 Hz (Tp 13.5 s), sigma 0.008 Hz,
    coming from 270 deg (W), s = 20.
  Hs of the whole sea = 4 sqrt(m0_wind + m0_swell) = 2.5 m; its peak is the swell's
  (from 270 deg). The exact figures of every fixture (Hs, the band the peak falls in, the
  mean direction at the peak band from the model's a1, b1) are in fixtures/truth.json.

Files, as the real services write them (sea.h and docs/operations.md describe the formats):
  ndbc-rt/46026.{data_spec,swdir,swdir2,swr1,swr2}   realtime, newest row first, 3 times;
      .swr2 lacks the newest (20:40) row, so the newest time in all five is 19:40, which
      holds the known sea; 20:40 and 18:40 hold a different one (Hs x1.5, swell from 300)
  ndbc-hist/46026{w,d,i,j,k}2025.txt                 historical, minute column, r in 0..1;
      the last row (the newest) the known sea, the first (2025-06-01 00:40) the other one
  ndbc-hist/46026{w,d,i,j,k}1998.txt.gz              historical, gzipped, "YY MM DD hh"
      (two-digit year, no minute column), 38 bands 0.03..0.40 Hz, r1 and r2 x 100
  ww3/storm.spec                                      WAVEWATCH III, 29 frequencies (x1.1),
      24 directions, 3 times six hours apart: a storm's wind sea arriving over the swell
  cdip/100p1_rt.ascii                                 CDIP's OPeNDAP text, 64 bands, 2
      records (the newest the known sea), with waveHs, waveFlagPrimary, metaWaterDepth
  broken/...                                          one fault each (BROKEN below), with
      the error each reader must give in broken/expected.json

Run with /usr/bin/python3 (numpy); `--fixtures DIR` writes them elsewhere (the test does, and
wants the committed ones byte for byte). `--realtime-days D --out DIR` writes a realtime set of D
days (24 rows a day) into DIR instead, for timing the readers on a file of real size."""
import argparse
import functools
import gzip
import json
import math
import os
import shutil
import sys
from decimal import ROUND_HALF_UP, Decimal

import numpy as np

G = 9.81
HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "fixtures")


# ---- the sea ---------------------------------------------------------------

def jonswap(f, hs, tp, gamma=3.3):
    """JONSWAP density (m^2/Hz) scaled to Hs exactly (numerically, over 0.001..5 Hz)."""
    f = np.asarray(f, float)
    fp = 1.0 / tp
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        sig = np.where(f <= fp, 0.07, 0.09)
        shape = f ** -5.0 * np.exp(-1.25 * (fp / f) ** 4) * gamma ** np.exp(-((f - fp) ** 2) / (2 * sig ** 2 * fp ** 2))
        shape = np.where(f > 0, shape, 0.0)
    return shape * (hs / 4) ** 2 / _jonswap_m0(tp, gamma)


@functools.lru_cache(maxsize=None)
def _jonswap_m0(tp, gamma):
    fp = 1.0 / tp
    fine = np.linspace(0.001, 5.0, 200000)
    sig_f = np.where(fine <= fp, 0.07, 0.09)
    ref = fine ** -5.0 * np.exp(-1.25 * (fp / fine) ** 4) * gamma ** np.exp(-((fine - fp) ** 2) / (2 * sig_f ** 2 * fp ** 2))
    return float(np.trapz(ref, fine))


def gauss(f, hs, fp, sigma):
    f = np.asarray(f, float)
    return (hs / 4) ** 2 * np.exp(-((f - fp) ** 2) / (2 * sigma ** 2)) / (sigma * math.sqrt(2 * math.pi))


def r1_of(s):
    return s / (s + 1)


def r2_of(s):
    return s * (s - 1) / ((s + 1) * (s + 2))


class Sea:
    """Components (density function, from-direction deg, spreading s)."""

    def __init__(self, comps):
        self.comps = comps

    def density(self, f):
        return sum(c[0](f) for c in self.comps)

    def moments(self, f):
        """C11 and a1, b1, a2, b2 (from-frame) at band centres f."""
        f = np.asarray(f, float)
        e = np.zeros_like(f)
        a1 = np.zeros_like(f); b1 = np.zeros_like(f); a2 = np.zeros_like(f); b2 = np.zeros_like(f)
        for dens, frm, s in self.comps:
            ec = dens(f)
            th = math.radians(frm)
            e += ec
            a1 += ec * r1_of(s) * math.cos(th); b1 += ec * r1_of(s) * math.sin(th)
            a2 += ec * r2_of(s) * math.cos(2 * th); b2 += ec * r2_of(s) * math.sin(2 * th)
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.where(e > 0, 1 / np.where(e > 0, e, 1), 0)
        return e, a1 * k, b1 * k, a2 * k, b2 * k

    def spectrum2d(self, f, dirs_from):
        """E(f, theta) (m^2/(Hz rad)) with each component's spreading normalised on the grid."""
        f = np.asarray(f, float)
        dth = 2 * math.pi / len(dirs_from)
        out = np.zeros((len(f), len(dirs_from)))
        for dens, frm, s in self.comps:
            d = np.cos(np.radians(np.asarray(dirs_from) - frm) / 2) ** (2 * s)
            d /= d.sum() * dth
            out += np.outer(dens(f), d)
        return out

    def hs(self):
        fine = np.linspace(0.0005, 5.0, 400000)
        return 4 * math.sqrt(np.trapz(self.density(fine), fine))


def known_sea():
    return Sea([(lambda f: jonswap(f, 2.0, 7.0), 225.0, 8.0), (lambda f: gauss(f, 1.5, 1 / 13.5, 0.008), 270.0, 20.0)])


def other_sea():
    """The decoy at the other times: a wrong row chosen shows in Hs and direction."""
    return Sea([(lambda f: jonswap(f, 3.0, 7.0), 225.0, 8.0), (lambda f: gauss(f, 2.25, 1 / 13.5, 0.008), 300.0, 20.0)])


def storm(k):
    """WW3 time k = 0, 1, 2: the swell, then a wind sea from 225 growing over it."""
    ws = [(0.3, 4.0), (2.0, 7.0), (3.5, 9.0)][k]
    return Sea([(lambda f: jonswap(f, ws[0], ws[1]), 225.0, 8.0), (lambda f: gauss(f, 1.5, 1 / 13.5, 0.008), 270.0, 20.0)])


def truth(sea, freq, bw, e, a1, b1, label):
    """What a reader must give back: Hs of the sea, the peak band, the direction there."""
    p = int(np.argmax(e))
    second = np.sort(e)[-2]
    assert e[p] > 1.03 * second, f"{label}: the peak band is not clear ({e[p]} vs {second})"
    discrete = 4 * math.sqrt(float(np.sum(e * bw)))
    hs = sea.hs()
    assert abs(discrete / hs - 1) < 0.008, f"{label}: the bands hold Hs {discrete:.4f}, the sea {hs:.4f}"
    direction = math.degrees(math.atan2(b1[p], a1[p])) % 360
    return {"hs": round(hs, 6), "hs_of_the_bands": round(discrete, 6), "peak_frequency": float(freq[p]),
            "peak_band_low": float(freq[p] - bw[p] / 2), "peak_band_high": float(freq[p] + bw[p] / 2),
            "tp": round(1 / freq[p], 6), "direction_at_peak": round(direction, 4)}


def widths(f):
    """Band widths from neighbouring centres: what the NDBC readers derive."""
    f = np.asarray(f, float)
    lo = np.r_[f[1] - f[0], np.diff(f)] / 2
    hi = np.r_[np.diff(f), f[-1] - f[-2]] / 2
    return lo + hi


# ---- NDBC ------------------------------------------------------------------

NDBC_BANDS = [round(0.0325 + 0.005 * k, 4) for k in range(13)] + [round(0.10 + 0.01 * k, 4) for k in range(26)] \
    + [round(0.365 + 0.02 * k, 4) for k in range(7)]
NDBC_HIST_BANDS = [0.02] + NDBC_BANDS
OLD_BANDS = [round(0.03 + 0.01 * k, 4) for k in range(38)]


def half_up(x, places):
    return str(Decimal(repr(float(x))).quantize(Decimal(1).scaleb(-places), rounding=ROUND_HALF_UP))


def ndbc_values(sea, freq):
    """Per band: C11, alpha1, alpha2, r1, r2 as NDBC stores them (alpha from, degrees)."""
    e, a1, b1, a2, b2 = sea.moments(freq)
    al1 = np.degrees(np.arctan2(b1, a1)) % 360
    al2 = (np.degrees(np.arctan2(b2, a2)) / 2) % 360
    return e, al1, al2, np.hypot(a1, b1), np.hypot(a2, b2)


def rt_rows(sea, stamp):
    """The five realtime rows of one time."""
    e, al1, al2, r1, r2 = ndbc_values(sea, NDBC_BANDS)
    rows = []
    tag = stamp.strftime("%Y %m %d %H %M")
    fq = [half_up(f, 3) for f in NDBC_BANDS]
    c11 = [half_up(x, 3) for x in e]
    none = [c == "0.000" for c in c11]     # no energy: NDBC writes 999 for the direction
    rows.append(tag + " 0.110 " + " ".join(f"{c} ({q})" for c, q in zip(c11, fq)))
    for vals, places, miss in ((al1, 1, "999.0"), (al2, 1, "999.0"), (r1, 3, "999.00"), (r2, 3, "999.00")):
        rows.append(tag + " " + " ".join(f"{miss if n else half_up(v, places)} ({q})" for v, n, q in zip(vals, none, fq)))
    return rows


RT_HEADERS = ["#YY  MM DD hh mm Sep_Freq  < spec_1 (freq_1) spec_2 (freq_2) spec_3 (freq_3) ... >",
              "#YY  MM DD hh mm alpha1_1 (freq_1) alpha1_2 (freq_2) ...",
              "#YY  MM DD hh mm alpha2_1 (freq_1) alpha2_2 (freq_2) ...",
              "#YY  MM DD hh mm R1_1 (freq_1) R1_2 (freq_2) ...",
              "#YY  MM DD hh mm R2_1 (freq_1) R2_2 (freq_2) ..."]
RT_EXT = ["data_spec", "swdir", "swdir2", "swr1", "swr2"]


def write(path, text, gz=False):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    data = text.encode()
    if gz:
        data = gzip.compress(data, mtime=0)     # the same bytes every run
    with open(path, "wb") as fh:
        fh.write(data)


def realtime(outdir, stamps, seas, skip=None):
    """Rows newest first; skip = {(file index, stamp)} rows left out."""
    files = [[RT_HEADERS[k]] for k in range(5)]
    for st, sea in zip(stamps, seas):
        rows = rt_rows(sea, st)
        for k in range(5):
            if skip and (k, st) in skip:
                continue
            files[k].append(rows[k])
    for k in range(5):
        write(os.path.join(outdir, f"46026.{RT_EXT[k]}"), "\n".join(files[k]) + "\n")


def hist_rows(sea, stamp, bands, old):
    e, al1, al2, r1, r2 = ndbc_values(sea, bands)
    tag = stamp.strftime("%y %m %d %H") if old else stamp.strftime("%Y %m %d %H %M")
    c11 = [half_up(x, 2) for x in e]
    none = [c == "0.00" for c in c11]
    scale = 100 if old else 1
    rp = 0 if old else 2
    return [tag + " " + " ".join(f"{c:>6}" for c in c11),
            tag + " " + " ".join(f"{'999' if n else half_up(v, 0):>6}" for v, n in zip(al1, none)),
            tag + " " + " ".join(f"{'999' if n else half_up(v, 0):>6}" for v, n in zip(al2, none)),
            tag + " " + " ".join(f"{'999.00' if n else half_up(v * scale, rp):>6}" for v, n in zip(r1, none)),
            tag + " " + " ".join(f"{'999.00' if n else half_up(v * scale, rp):>6}" for v, n in zip(r2, none))]


def historical(outdir, year, stamps, seas, old):
    bands = OLD_BANDS if old else NDBC_HIST_BANDS
    head = ("YY  MM DD hh " if old else "#YY  MM DD hh mm ") + " ".join(f"{f:.4f}".lstrip("0") for f in bands)
    files = [[head] for _ in range(5)]
    for st, sea in zip(stamps, seas):
        for k, row in enumerate(hist_rows(sea, st, bands, old)):
            files[k].append(row)
    for k, letter in enumerate("wdijk"):
        name = f"46026{letter}{year}.txt" + (".gz" if old else "")
        write(os.path.join(outdir, name), "\n".join(files[k]) + "\n", gz=old)


# ---- WAVEWATCH III -----------------------------------------------------------

WW3_NF, WW3_ND = 29, 24


def fortran_e(x, width=11, digits=3):
    """Fortran's Ew.d: 0.ddddE+xx."""
    if x == 0:
        m, ex = 0.0, 0
    else:
        ex = math.floor(math.log10(abs(x))) + 1
        m = x / 10 ** ex
        if round(abs(m), digits) >= 1:
            m /= 10
            ex += 1
    s = f"{m:.{digits}f}".replace("0.", ".", 1) if False else f"{m:.{digits}f}"
    return f"{s}E{ex:+03d}".rjust(width)


def ww3(path):
    freq = [0.035 * 1.1 ** n for n in range(WW3_NF)]
    cart = [2 * math.pi * j / WW3_ND for j in range(WW3_ND)]                   # going to, counterclockwise from east
    stored = [math.fmod(2.5 * math.pi - t, 2 * math.pi) for t in cart]        # as WW3 writes them
    frm = [(math.degrees(d) + 180) % 360 for d in stored]                      # the document's "from"
    lines = [f"'WAVEWATCH III SPECTRA'     {WW3_NF:2d}    {WW3_ND:2d}     1 'spectral resolution for points'"]
    fq = [fortran_e(f, 10) for f in freq]
    lines += ["".join(fq[i:i + 8]) for i in range(0, WW3_NF, 8)]
    dv = [f"{d:7.3f}" for d in stored]
    lines += ["".join(dv[i:i + 10]) for i in range(0, WW3_ND, 10)]
    freq_w = [float(v) for v in fq]
    ratio = (freq_w[-1] / freq_w[0]) ** (1 / (WW3_NF - 1))
    bw = np.array(freq_w) * (ratio - 1 / ratio) / 2
    truths = []
    times = ["20261202 000000", "20261202 060000", "20261202 120000"]
    for k, stamp in enumerate(times):
        sea = storm(k)
        e2 = sea.spectrum2d(freq_w, frm)
        lines.append(stamp)
        lines.append("'46026     '  37.75-122.83      52.0   8.20 225.0   0.00 270.0")
        vals = [fortran_e(e2[i, j]) for j in range(WW3_ND) for i in range(WW3_NF)]   # frequency fastest
        lines += ["".join(vals[i:i + 7]) for i in range(0, len(vals), 7)]
        # the truth from what the file holds (3 digits), as the readers see it
        held = np.array([float(v) for v in vals]).reshape(WW3_ND, WW3_NF).T
        dth = 2 * math.pi / WW3_ND
        s1 = held.sum(axis=1) * dth
        th = np.radians(frm)
        a1 = (held * np.cos(th)).sum(axis=1) * dth / np.where(s1 > 0, s1, 1)
        b1 = (held * np.sin(th)).sum(axis=1) * dth / np.where(s1 > 0, s1, 1)
        t = truth(sea, np.array(freq_w), bw, s1, a1, b1, f"ww3 {stamp}")
        t["time"] = f"{stamp[:4]}-{stamp[4:6]}-{stamp[6:8]}T{stamp[9:11]}:{stamp[11:13]}:{stamp[13:15]}Z"
        truths.append(t)
    write(path, "\n".join(lines) + "\n")
    return truths


# ---- CDIP --------------------------------------------------------------------

CDIP_F = [round(0.025 + 0.005 * k, 4) for k in range(16)] + [round(0.11 + 0.01 * k, 4) for k in range(48)]
CDIP_BW = [0.005] * 15 + [0.0075] + [0.01] * 48


def cdip(path, seas, times):
    f = np.array(CDIP_F)
    bw = np.array(CDIP_BW)
    rows = {n: [] for n in ("e", "a1", "b1", "a2", "b2")}
    hs = []
    for sea in seas:
        e, a1, b1, a2, b2 = sea.moments(f)
        for n, v in zip(("e", "a1", "b1", "a2", "b2"), (e, a1, b1, a2, b2)):
            rows[n].append([float(f"{x:.6g}") for x in v])
        hs.append(4 * math.sqrt(sum(x * w for x, w in zip(rows["e"][-1], bw))))
    nt, nf = len(seas), len(f)
    fmt = lambda v: ", ".join(f"{x:.6g}" for x in v)
    out = ["Dataset {", f"    Int32 waveTime[waveTime = {nt}];", f"    Float32 waveFrequency[waveFrequency = {nf}];",
           f"    Float32 waveBandwidth[waveFrequency = {nf}];"]
    for n in ("waveEnergyDensity", "waveA1Value", "waveB1Value", "waveA2Value", "waveB2Value"):
        out += ["    Grid {", "     ARRAY:", f"        Float32 {n}[waveTime = {nt}][waveFrequency = {nf}];", "     MAPS:",
                f"        Int32 waveTime[waveTime = {nt}];", f"        Float32 waveFrequency[waveFrequency = {nf}];",
                f"    }} {n};"]
    out += [f"    Float32 waveHs[waveTime = {nt}];", f"    Byte waveFlagPrimary[waveTime = {nt}];",
            "    Float32 metaWaterDepth;", "} cdip/realtime/100p1_rt.nc;",
            "---------------------------------------------",
            f"waveTime[{nt}]", ", ".join(str(t) for t in times), "",
            f"waveFrequency[{nf}]", fmt(f), "", f"waveBandwidth[{nf}]", fmt(bw), ""]
    for n, key in (("waveEnergyDensity", "e"), ("waveA1Value", "a1"), ("waveB1Value", "b1"), ("waveA2Value", "a2"),
                   ("waveB2Value", "b2")):
        out.append(f"{n}.{n}[{nt}][{nf}]")
        out += [f"[{i}], " + fmt(r) for i, r in enumerate(rows[key])]
        out += ["", f"{n}.waveTime[{nt}]", ", ".join(str(t) for t in times), "", f"{n}.waveFrequency[{nf}]", fmt(f), ""]
    out += [f"waveHs[{nt}]", fmt(hs), "", f"waveFlagPrimary[{nt}]", ", ".join("1" for _ in seas), "",
            "metaWaterDepth, 52.0", ""]
    write(path, "\n".join(out))
    return rows, f, bw


# ---- broken fixtures ---------------------------------------------------------

def edit_line(path, lineno, fn):
    lines = open(path).read().split("\n")
    lines[lineno - 1] = fn(lines[lineno - 1])
    open(path, "w").write("\n".join(lines))


def replace_pair(band, new_value=None, new_freq=None):
    """A realtime row with band `band` (1-based) changed."""
    def fn(line):
        t = line.split()
        first = 6 if "(" not in t[5] and "(" in t[7] else 5
        k = first + 2 * (band - 1)
        if new_value is not None:
            t[k] = new_value
        if new_freq is not None:
            t[k + 1] = new_freq
        return " ".join(t)
    return fn


def broken(outdir, good_rt, good_hist, good_ww3, good_cdip):
    """Each a copy of a good fixture with one fault; expected.json says what each reader must say."""
    cases = []

    def rt_case(name, ext, line, fn, code, band):
        d = os.path.join(outdir, name)
        shutil.copytree(good_rt, d)
        edit_line(os.path.join(d, f"46026.{ext}"), line, fn)
        cases.append({"name": name, "source": f"broken/{name}/46026.data_spec", "code": code,
                      "file": f"46026.{ext}", "line": line, "band": band})

    # line 3 is the 19:40 row of each file but .swr2 (which lacks 20:40: its line 2)
    rt_case("rt-mm", "data_spec", 3, replace_pair(20, new_value="MM"), "missing", 20)
    rt_case("rt-999", "swdir", 3, replace_pair(12, new_value="999.0"), "missing", 12)
    # the row cut after band 22's value (0.180 Hz), before its frequency
    rt_case("rt-truncated", "swr1", 3, lambda l: l[:l.index(" (0.180)") - 1].rsplit(" ", 1)[0] + " 0.8",
            "truncated", NDBC_BANDS.index(0.18) + 1)
    rt_case("rt-mismatch", "swdir2", 3, replace_pair(30, new_freq="(0.295)"), "bands_mismatch", 30)
    rt_case("rt-nonnumeric", "swr2", 2, replace_pair(7, new_value="0.8x1"), "bad_number", 7)

    def one_case(name, src_dir, fname, line, fn, code, band, source=None):
        d = os.path.join(outdir, name)
        shutil.copytree(src_dir, d)
        edit_line(os.path.join(d, fname), line, fn)
        cases.append({"name": name, "source": source or f"broken/{name}/{fname}", "code": code, "file": fname,
                      "line": line, "band": band})

    one_case("rt-toomany", good_rt, "46026.data_spec", 3,
             lambda l: l + "".join(f" 0.000 ({0.5 + 0.001 * k:.3f})" for k in range(90)), "too_many_bands", 129)
    # historical 2025 (plain text): a bad header, an MM in the spectral density
    hist = os.path.join(outdir, "_hist")
    os.makedirs(hist)
    for n in os.listdir(good_hist):
        if "2025" in n:
            shutil.copy(os.path.join(good_hist, n), hist)
    one_case("hist-badheader", hist, "46026w2025.txt", 1, lambda l: l.replace(".1100", ".11O0"), "bad_header",
             NDBC_HIST_BANDS.index(0.11) + 1,
             source="broken/hist-badheader/46026w2025.txt")
    one_case("hist-mm", hist, "46026w2025.txt", 4,
             lambda l: " ".join(t if i != 5 + 17 else "MM" for i, t in enumerate(l.split())), "missing", 18,
             source="broken/hist-mm/46026w2025.txt")
    one_case("hist-mismatch", hist, "46026j2025.txt", 1, lambda l: l.replace(".1200", ".1250"), "bands_mismatch",
             NDBC_HIST_BANDS.index(0.12) + 1,
             source="broken/hist-mismatch/46026w2025.txt")
    shutil.rmtree(hist)
    # WAVEWATCH III: the file cut in the last time's values; a header without its sizes
    d = os.path.join(outdir, "ww3-truncated")
    os.makedirs(d)
    lines = open(good_ww3).read().split("\n")
    cut = lines[:-20]
    open(os.path.join(d, "storm.spec"), "w").write("\n".join(cut) + "\n")
    nvals = sum(len(l.split()) for l in cut[cut.index("20261202 120000") + 2:])
    cases.append({"name": "ww3-truncated", "source": "broken/ww3-truncated/storm.spec", "code": "truncated",
                  "file": "storm.spec", "line": len(cut), "band": nvals % WW3_NF + 1})
    d = os.path.join(outdir, "ww3-badheader")
    os.makedirs(d)
    open(os.path.join(d, "storm.spec"), "w").write("\n".join(["'WAVEWATCH III SPECTRA'  29 'no sizes'"] + lines[1:]))
    cases.append({"name": "ww3-badheader", "source": "broken/ww3-badheader/storm.spec", "code": "bad_header",
                  "file": "storm.spec", "line": 1, "band": 0})
    # CDIP: a fill value in the newest record's energy
    d = os.path.join(outdir, "cdip-fill")
    os.makedirs(d)
    text = open(good_cdip).read().split("\n")
    at = text.index("waveEnergyDensity.waveEnergyDensity[2][64]") + 2
    vals = text[at].split(", ")
    vals[9 + 1] = "-999.0"     # band 10 (the first token is the row index)
    text[at] = ", ".join(vals)
    open(os.path.join(d, "100p1_rt.ascii"), "w").write("\n".join(text))
    cases.append({"name": "cdip-fill", "source": "broken/cdip-fill/100p1_rt.ascii", "code": "missing",
                  "file": "100p1_rt.ascii", "line": at + 1, "band": 10})
    with open(os.path.join(outdir, "expected.json"), "w") as fh:
        json.dump(cases, fh, indent=1)
        fh.write("\n")
    return cases


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--realtime-days", type=int, help="write a realtime set of this many days to --out instead")
    ap.add_argument("--out", help="the folder for --realtime-days")
    ap.add_argument("--fixtures", default=OUT, help="where to write the fixtures (default: tests/sea/fixtures; "
                    "the test writes them elsewhere and compares)")
    a = ap.parse_args()
    out = a.fixtures
    from datetime import datetime, timedelta
    if a.realtime_days:
        newest = datetime(2026, 12, 1, 20, 40)
        stamps = [newest - timedelta(hours=h) for h in range(24 * a.realtime_days)]
        seas = [known_sea() if h == 0 else other_sea() for h in range(len(stamps))]
        realtime(a.out, stamps, seas)
        return
    if os.path.isdir(out):
        shutil.rmtree(out)
    sea, other = known_sea(), other_sea()
    t = {"sea": {"wind_sea": {"spectrum": "jonswap", "hs": 2.0, "tp": 7.0, "gamma": 3.3, "from": 225, "s": 8},
                 "swell": {"spectrum": "gauss", "hs": 1.5, "tp": 13.5, "sigma_hz": 0.008, "from": 270, "s": 20},
                 "hs": round(sea.hs(), 6)}}
    # realtime
    s0 = datetime(2026, 12, 1, 20, 40)
    stamps = [s0, s0 - timedelta(hours=1), s0 - timedelta(hours=2)]
    realtime(os.path.join(out, "ndbc-rt"), stamps, [other, sea, other], skip={(4, s0)})
    fr = np.array([float(half_up(f, 3)) for f in NDBC_BANDS])
    e, al1, al2, r1, r2 = ndbc_values(sea, NDBC_BANDS)
    e = np.array([float(half_up(x, 3)) for x in e])
    a1 = np.cos(np.radians(al1)) * r1
    b1 = np.sin(np.radians(al1)) * r1
    t["ndbc-rt"] = dict(truth(sea, fr, widths(fr), e, a1, b1, "ndbc-rt"), time="2026-12-01T19:40:00Z")
    # historical
    h = os.path.join(out, "ndbc-hist")
    last = datetime(2025, 12, 31, 23, 40)
    historical(h, 2025, [datetime(2025, 6, 1, 0, 40), datetime(2025, 12, 31, 22, 40), last], [other, other, sea], False)
    fb = np.array(NDBC_HIST_BANDS)
    e, al1, al2, r1, r2 = ndbc_values(sea, NDBC_HIST_BANDS)
    e = np.array([float(half_up(x, 2)) for x in e])
    t["ndbc-hist-2025"] = dict(truth(sea, fb, widths(fb), e, np.cos(np.radians(al1)) * r1,
                                     np.sin(np.radians(al1)) * r1, "hist 2025"), time="2025-12-31T23:40:00Z")
    t["ndbc-hist-2025-first"] = {"time": "2025-06-01T00:40:00Z", "hs": round(other.hs(), 6)}
    historical(h, 1998, [datetime(1998, 3, 1, 0), datetime(1998, 3, 1, 1)], [other, sea], True)
    fo = np.array(OLD_BANDS)
    e, al1, al2, r1, r2 = ndbc_values(sea, OLD_BANDS)
    e = np.array([float(half_up(x, 2)) for x in e])
    t["ndbc-hist-1998"] = dict(truth(sea, fo, widths(fo), e, np.cos(np.radians(al1)) * r1,
                                     np.sin(np.radians(al1)) * r1, "hist 1998"), time="1998-03-01T01:00:00Z")
    # WW3
    t["ww3"] = ww3(os.path.join(out, "ww3", "storm.spec"))
    # CDIP: the newest record (the second) is the known sea
    times = [1764619200, 1764621000]     # 2025-12-01 20:00 and 20:30 UTC
    rows, f, bw = cdip(os.path.join(out, "cdip", "100p1_rt.ascii"), [other, sea], times)
    t["cdip"] = dict(truth(sea, f, bw, np.array(rows["e"][1]), np.array(rows["a1"][1]), np.array(rows["b1"][1]),
                           "cdip"), time="2025-12-01T20:30:00Z")
    cases = broken(os.path.join(out, "broken"), os.path.join(out, "ndbc-rt"), h, os.path.join(out, "ww3", "storm.spec"),
                   os.path.join(out, "cdip", "100p1_rt.ascii"))
    with open(os.path.join(out, "truth.json"), "w") as fh:
        json.dump(t, fh, indent=1)
        fh.write("\n")
    print(f"fixtures in {out}: the known sea Hs {sea.hs():.4f} m; {len(cases)} broken cases")
    for k in ("ndbc-rt", "ndbc-hist-2025", "ndbc-hist-1998", "cdip"):
        print(f"  {k:16s} Hs of the bands {t[k]['hs_of_the_bands']:.4f}  peak {t[k]['peak_frequency']:.4f} Hz  "
              f"from {t[k]['direction_at_peak']:.2f}")
    for w in t["ww3"]:
        print(f"  ww3 {w['time']} Hs {w['hs']:.4f} (bands {w['hs_of_the_bands']:.4f})  peak {w['peak_frequency']:.4f} Hz"
              f"  from {w['direction_at_peak']:.2f}")


if __name__ == "__main__":
    sys.exit(main())

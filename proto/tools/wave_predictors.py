#!/usr/bin/env python3
"""wave_predictors.py — does a predictor that knows the dispersion relation beat codec 3's?

Input: consecutive frames of the real simulation at 30 Hz (defaults, t = 10 s), written by
    build/bench_codec --dump-fields N FRAMES FILE
One field of cascade 0 (FIELD: 0 height, 1 dx, 2 dz, 3 slope_x, 4 slope_z, 5 jacobian). Every
candidate runs the codec's closed loop on the refined grid, as the daemon's chains do
(scale = 2 * bound / r, r = 3; a sample whose prediction is a valid code takes it, else its
rounded code), so each predictor works on the codes a decoder would hold. Per predicted frame
and 128 x 128 tile, bits per sample, medians over the frames after WARM intra frames:
  coded  the residuals in codec 3's packing (pairs when both zigzag values are below 15)
         through a Huffman-only raw DEFLATE block, + 56 bytes of tile header and prefix;
  quad   four samples per byte (base 3) when all four zigzag values are below 3, else an
         escape and codec 3's pairs (a packing whose floor is 1/4 bit, not 1/2);
  H0     the residuals' order-0 entropy.
The first line checks the model: the recurrence h(t+1) = F^-1[2 cos(w dt) F(h(t))] - h(t-1)
on the simulation's own floats (w^2 = g k tanh kD, the defaults' patch and depth).

    /usr/bin/python3 proto/tools/wave_predictors.py FILE N FRAMES [WARM [CANDIDATES [FIELD]]]

Candidates (q_j = the reconstructed codes j ticks back, d_j = q_j - q_(j+1), L = 5-point
Laplacian clamped per tile, B = L(L(.)); LS = least squares per tile on the current frame's
rounded codes, coefficients rounded to 1/4096 and sent, as codec 3 does):
  c3        codec 3: q1 + LS[d1 d2 d3 L(d1) L(d2) L(d3) L(q1)]
  c3+B      codec 3 + B(d1), B(q1) (a closer local fit of w^2 = g|k|)
  c3+BB     codec 3 + B(d1), B(d2), B(d3), B(q1), L(B(q1))
  wave2     2 q1 - q2 + LS[L(q1) B(q1)] (the wave equation with integer stencils)
  specT     whole field in float64: F^-1[sum_j c_j(w) F(q_j)], j = 1..T, c(w) per mode the
            smallest-norm T taps exact for both e^(+-i w t) (spec2 = 2 cos(w dt) q1 - q2),
            i.e. the references' rounding noise averaged over T ticks
  specT/f32 the same in float32 with the taps rounded to 2^-14 (the precision it needs)
  intT      specT in int64: codes with 12 fractional bits, a radix-2 FFT with twiddles and
            taps rounded to 2^-24, one rounding rule (rnd), every product below 2^62 (what
            any decoder can reproduce bit for bit)
  firS      spec8's taps as space-time kernels truncated to S x S samples (a local filter)
  oracle    the true floats of the last two ticks advanced by the recurrence: the floor
"""
import json
import sys
import zlib

import numpy as np

TILE = 128
FIELDS = ["height", "dx", "dz", "slope_x", "slope_z", "jacobian", "foam"]
DEFAULT = ["c3", "c3+B", "c3+BB", "wave2", "spec2", "spec4", "spec8", "spec12", "spec8/f32", "fir17", "fir33", "oracle"]
R = 3
G = 9.81
L_PATCH = 256.0
DEPTH = 1000.0
DT = 1.0 / 30


def huff(b):
    c = zlib.compressobj(9, zlib.DEFLATED, -15, 9, zlib.Z_HUFFMAN_ONLY)
    return len(c.compress(b.tobytes()) + c.flush())


def zigzag(r):
    return np.where(r >= 0, 2 * r, -2 * r - 1)


def tile_bytes(r):
    z = zigzag(r.astype(np.int64)).ravel()
    z1, z2 = z[0::2], z[1::2]
    ok = (z1 < 15) & (z2 < 15)
    esc = np.stack([z1[~ok], z2[~ok]], 1).ravel()
    b = np.concatenate([np.where(ok, 15 * z1 + z2, 255), np.minimum(esc, 255)]).astype(np.uint8)
    return huff(b) + 2 * int((esc >= 255).sum())


def quad_bytes(r):
    """Four samples per byte (base 3) when all four zigzag values are below 3, else an
    escape byte and the four in codec 3's pair packing: a packing with a floor of 1/4 bit."""
    z = zigzag(r.astype(np.int64)).ravel().reshape(-1, 4)
    ok = (z < 3).all(1)
    sym = np.where(ok, ((z[:, 0] * 3 + z[:, 1]) * 3 + z[:, 2]) * 3 + z[:, 3], 255)
    e = z[~ok]
    pr = np.where((e[:, 0::2] < 15) & (e[:, 1::2] < 15), 15 * e[:, 0::2] + e[:, 1::2], 255).ravel()
    return huff(sym.astype(np.uint8)) + huff(np.minimum(pr, 255).astype(np.uint8)) + 2 * int((e >= 15).sum())


def h0(r):
    _, c = np.unique(r, return_counts=True)
    p = c / c.sum()
    return float(-(p * np.log2(p)).sum())


def tiles(n):
    for tz in range(n // TILE):
        for tx in range(n // TILE):
            yield (slice(tz * TILE, (tz + 1) * TILE), slice(tx * TILE, (tx + 1) * TILE))


def lap(a):
    out = np.empty_like(a)
    for sl in tiles(a.shape[0]):   # clamped per tile, as codec 3
        t = a[sl]
        p = np.pad(t, 1, mode="edge")
        out[sl] = p[1:-1, :-2] + p[1:-1, 2:] + p[:-2, 1:-1] + p[2:, 1:-1] - 4 * t
    return out


def ls_pred(base, feats, fit, n):
    """base + floor((X c + 2048) / 4096) per tile, c the least squares of fit = (Xf, yf) x 4096."""
    Xf, yf = fit
    out = np.empty((n, n), np.float64)
    for sl in tiles(n):
        A = np.stack([g[sl].ravel() for g in Xf], 1).astype(np.float64)
        c = np.round(np.linalg.lstsq(A, yf[sl].ravel().astype(np.float64), rcond=None)[0] * 4096)
        X = np.stack([g[sl].ravel() for g in feats], 1).astype(np.float64)
        out[sl] = base[sl] + np.floor((X @ c + 2048) / 4096).reshape(TILE, TILE)
    return out


def omega_grid(n):
    m = np.fft.fftfreq(n, 1.0 / n)
    kx, kz = np.meshgrid(m, m)
    k = 2 * np.pi / L_PATCH * np.sqrt(kx ** 2 + kz ** 2)
    return np.sqrt(G * k * np.tanh(k * DEPTH))


def spec_coeffs(w, taps):
    """Per mode: c (taps on q1..q_taps) minimising |c|^2 with sum_j c_j e^(-+i w j dt) = 1."""
    j = np.arange(1, taps + 1)
    cs = np.empty(w.shape + (taps,))
    uw, inv = np.unique(np.round(w, 12), return_inverse=True)
    for idx, wi in enumerate(uw):
        A = np.stack([np.cos(wi * j * DT), np.sin(wi * j * DT)])       # real form of both exponentials
        if wi == 0:
            A = A[:1]
            b = np.array([1.0])
        else:
            b = np.array([1.0, 0.0])
        cs.reshape(-1, taps)[inv.ravel() == idx] = A.T @ np.linalg.solve(A @ A.T, b)
    return cs


TW = 24   # fixed-point twiddles and taps: integers of 2^24
FB = 12   # fractional bits of the codes inside the FFT


def rnd(x, s):
    """floor((x + 2^(s-1)) / 2^s): the one rounding of the integer FFT (exact in int64, in
    Python ints, and in JavaScript doubles while |x| < 2^53)."""
    return (x + (1 << (s - 1))) >> s


def ifft_int_1d(re, im, axis, inverse):
    """Radix-2 decimation in time along axis on int64 arrays; twiddles round(2^TW cos/sin);
    every product rounded by rnd(., TW); each direction halves (rnd(., 1)) at every other
    stage, so forward and inverse together divide by n per axis and values stay small."""
    n = re.shape[axis]
    bits = n.bit_length() - 1
    rev = np.array([int(format(i, f"0{bits}b")[::-1], 2) for i in range(n)])
    re, im = np.take(re, rev, axis), np.take(im, rev, axis)
    re, im = np.moveaxis(re, axis, -1).copy(), np.moveaxis(im, axis, -1).copy()
    sign = 1 if inverse else -1
    size, stage = 2, 0
    while size <= n:
        h = size // 2
        k = np.arange(h)
        wr = np.round(np.cos(2 * np.pi * k / size) * (1 << TW)).astype(np.int64)
        wi = np.round(sign * np.sin(2 * np.pi * k / size) * (1 << TW)).astype(np.int64)
        a_r = re.reshape(re.shape[:-1] + (n // size, size))
        a_i = im.reshape(im.shape[:-1] + (n // size, size))
        br, bi = a_r[..., h:], a_i[..., h:]
        tr, ti = rnd(br * wr - bi * wi, TW), rnd(br * wi + bi * wr, TW)
        ur, ui = a_r[..., :h].copy(), a_i[..., :h].copy()
        if stage % 2 == (1 if inverse or bits % 2 == 0 else 0):   # bits halvings in all
            a_r[..., :h], a_i[..., :h] = rnd(ur + tr, 1), rnd(ui + ti, 1)
            a_r[..., h:], a_i[..., h:] = rnd(ur - tr, 1), rnd(ui - ti, 1)
        else:
            a_r[..., :h], a_i[..., :h] = ur + tr, ui + ti
            a_r[..., h:], a_i[..., h:] = ur - tr, ui - ti
        size, stage = size * 2, stage + 1
    return np.moveaxis(re, -1, axis), np.moveaxis(im, -1, axis)


def fft2_int(re, im, inverse=False):
    re, im = ifft_int_1d(re, im, 1, inverse)
    return ifft_int_1d(re, im, 0, inverse)


def main():
    path, n, frames = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    warm = int(sys.argv[4]) if len(sys.argv) > 4 else 12
    cands = sys.argv[5].split(",") if len(sys.argv) > 5 else DEFAULT
    field = int(sys.argv[6]) if len(sys.argv) > 6 else 0
    raw = np.fromfile(path, np.float32).reshape(frames, -1, n, n)[:, field].astype(np.float64)
    w = omega_grid(n)
    twoc = 2 * np.cos(w * DT)
    coef = {}
    # the model's check: the recurrence on the true floats
    rec = np.real(np.fft.ifft2(twoc * np.fft.fft2(raw[10]))) - raw[9]
    print(json.dumps({"check": "recurrence on true height", "rms_err_m": float(np.sqrt(((rec - raw[11]) ** 2).mean())),
                      "rms_step_m": float(np.sqrt(((raw[11] - raw[10]) ** 2).mean()))}), flush=True)
    for bound in (0.001, 0.01):
        scale = 2 * bound / R
        offset = 0.5 * (raw[0].max() + raw[0].min())
        u = (raw - offset) / scale                       # exact position on the grid
        half = bound / scale * (1 - 1e-6)               # valid codes: |q - u| <= half
        names = cands
        res = {k: {"coded": [], "quad": [], "H0": []} for k in names}
        for name in names:
            q = [np.round(u[t]) for t in range(12)]     # keyframes (intra, not counted)
            spec = {}                                   # intT: each reference's spectrum, kept
            for t in range(12, frames):
                q1, q2, q3, q4 = q[t - 1], q[t - 2], q[t - 3], q[t - 4]
                d1, d2, d3 = q1 - q2, q2 - q3, q3 - q4
                if name.startswith("c3"):
                    feats = [d1, d2, d3, lap(d1), lap(d2), lap(d3), lap(q1)]
                    if name == "c3+B":
                        feats += [lap(lap(d1)), lap(lap(q1))]
                    if name == "c3+BB":
                        feats += [lap(lap(d1)), lap(lap(d2)), lap(lap(d3)), lap(lap(q1)), lap(lap(lap(q1)))]
                    # the encoder fits on this frame's rounded codes (it has the truth)
                    P = ls_pred(q1, feats, (feats, np.round(u[t]) - q1), n)
                elif name == "wave2":
                    feats = [lap(q1), lap(lap(q1))]
                    P = ls_pred(2 * q1 - q2, feats, (feats, np.round(u[t]) - (2 * q1 - q2)), n)
                elif name == "spec2":
                    P = np.round(np.real(np.fft.ifft2(twoc * np.fft.fft2(q1))) - q2)
                elif name.startswith("int"):
                    # specT in integers: forward FFT of each reference (kept by a decoder),
                    # taps rounded to 2^-TW, products rounded, inverse FFT halving per stage
                    taps = int(name[3:])
                    if taps not in coef:
                        coef[taps] = spec_coeffs(w, taps)
                    key = ("int", taps)
                    if key not in coef:
                        coef[key] = np.round(coef[taps] * (1 << TW)).astype(np.int64)
                    ci = coef[key]
                    sr = si = 0
                    for j in range(taps):
                        if t - 1 - j not in spec:
                            qi = q[t - 1 - j].astype(np.int64) << FB
                            spec[t - 1 - j] = fft2_int(qi, np.zeros_like(qi))
                        fr, fi = spec[t - 1 - j]
                        sr = sr + rnd(fr * ci[..., j], TW)
                        si = si + rnd(fi * ci[..., j], TW)
                    assert max(np.abs(sr).max(), np.abs(si).max()) < 2 ** 38   # products < 2^62
                    P = rnd(fft2_int(sr, si, inverse=True)[0], FB).astype(np.float64)
                elif name.startswith("spec"):
                    taps = int(name[4:].split("/")[0])
                    if taps not in coef:
                        coef[taps] = spec_coeffs(w, taps)
                    cc = coef[taps]
                    if name.endswith("/f32"):   # single precision throughout, coefficients to 2^-14
                        cc = (np.round(cc * 16384) / 16384).astype(np.float32)
                        F = sum(cc[..., j] * np.fft.fft2(q[t - 1 - j].astype(np.float32)).astype(np.complex64)
                                for j in range(taps))
                        P = np.round(np.real(np.fft.ifft2(F).astype(np.complex64)).astype(np.float64))
                    else:
                        F = sum(cc[..., j] * np.fft.fft2(q[t - 1 - j]) for j in range(taps))
                        P = np.round(np.real(np.fft.ifft2(F)))
                elif name.startswith("fir"):
                    # spec8's predictor as space-time FIR kernels truncated to (2h+1)^2 (periodic)
                    h = int(name[3:]) // 2
                    if name not in coef:
                        if 8 not in coef:
                            coef[8] = spec_coeffs(w, 8)
                        ker = np.real(np.fft.ifft2(np.moveaxis(coef[8], -1, 0)))
                        idx = np.minimum(np.arange(n), n - np.arange(n))
                        win = (idx[:, None] <= h) & (idx[None, :] <= h)
                        coef[name] = np.fft.fft2(ker * win)
                    cc = coef[name]
                    F = sum(cc[j] * np.fft.fft2(q[t - 1 - j]) for j in range(8))
                    P = np.round(np.real(np.fft.ifft2(F)))
                else:   # oracle: true floats advanced one tick
                    P = np.round(np.real(np.fft.ifft2(twoc * np.fft.fft2(u[t - 1]))) - u[t - 2])
                P = np.round(P)
                qt = np.where(np.abs(P - u[t]) <= half, P, np.round(u[t]))
                q.append(qt)
                if t >= warm:
                    r = (qt - P).astype(np.int64)
                    res[name]["coded"].append(sum(56 + tile_bytes(r[sl]) for sl in tiles(n)) * 8 / (n * n))
                    res[name]["quad"].append(sum(56 + quad_bytes(r[sl]) for sl in tiles(n)) * 8 / (n * n))
                    res[name]["H0"].append(h0(r))
            assert np.abs(np.array(q[4:]) * scale + offset - raw[4:]).max() <= bound * (1 + 1e-5)
        print(json.dumps({"bench": "wave_predictors", "N": n, "field": FIELDS[field], "bound": bound,
                          **{k: {m: round(float(np.median(v[m])), 3) for m in v} for k, v in res.items()}}),
              flush=True)


if __name__ == "__main__":
    main()

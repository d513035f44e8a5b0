#!/usr/bin/python3
"""check_exr.py - ocean-tap's Blender bake against the streamed fields.

    check_exr.py NPY_DIR EXR_DIR EXR_READ

NPY_DIR: ocean-tap --format npy --bound 0 of all six fields; EXR_DIR: ocean-tap
--format exr --bound 0 run at the same time. For every bake frame whose seq is
also in NPY_DIR (or, when the npy run skipped it, whose sim_time and
params_version are those of a frame in NPY_DIR: a paused sea), the three EXR files, read back with the OpenEXR library
(EXR_READ), must hold the streamed fields within half-float rounding:
disp = (dx, height, dz), normal = (-slope_x, 1, -slope_z)/|.|,
foam = clamp(1 - jacobian, 0, 1), alpha 1; the first scanline is the last
grid row (Blender's bottom-up images); header: RGBA half, ZIP.
"""
import glob
import json
import os
import subprocess
import sys

import numpy as np

npy_dir, exr_dir, exr_read = sys.argv[1:4]


def read_exr(path):
    info = json.loads(subprocess.run([exr_read, path, path + ".npy"], check=True, capture_output=True,
                                     text=True).stdout)
    img = np.load(path + ".npy")
    os.remove(path + ".npy")
    assert info["compression"] == "zip", info
    assert sorted(info["channels"]) == [["A", "half"], ["B", "half"], ["G", "half"], ["R", "half"]], info
    return img[::-1]  # back to grid rows: row 0 = z = 0


def close(name, got, want):
    want = want.astype(np.float32)
    err = np.abs(got.astype(np.float64) - want)
    tol = np.abs(want) * 2.0 ** -11 + 2.0 ** -24  # round to nearest half
    bad = np.count_nonzero(err > tol)
    assert bad == 0, f"{name}: {bad} samples beyond half precision, worst {err.max():.3g}"
    return err.max()


frames = sorted(glob.glob(os.path.join(exr_dir, "frame_*.json")))
assert frames, "no bake frames"
numbers = [int(os.path.basename(f)[6:10]) for f in frames]
assert numbers == list(range(1, len(frames) + 1)), f"bake frames are not numbered 1..n: {numbers}"
compared, worst = 0, 0.0
same_sea = {}
for sj in glob.glob(os.path.join(npy_dir, "jacobian-*.json")):
    m = json.load(open(sj))
    same_sea[(m["sim_time"], m["params_version"])] = m["seq"]
for fj in frames:
    meta = json.load(open(fj))
    fr, seq = meta["frame"], meta["seq"]
    # The streamed frame of the same seq; or, when the npy run missed it (a loaded machine
    # skips ticks), one of the same sim_time and params_version: the same sea (paused).
    if not os.path.exists(os.path.join(npy_dir, f"jacobian-{seq:08d}.npy")):
        seq = same_sea.get((meta["sim_time"], meta["params_version"]), seq)
    fields = {}
    for f in ("height", "dx", "dz", "slope_x", "slope_z", "jacobian"):
        p = os.path.join(npy_dir, f"{f}-{seq:08d}.npy")
        if os.path.exists(p):
            fields[f] = np.load(p)
    if len(fields) < 6:
        continue
    disp = read_exr(os.path.join(exr_dir, f"disp_{fr:04d}.exr"))
    normal = read_exr(os.path.join(exr_dir, f"normal_{fr:04d}.exr"))
    foam = read_exr(os.path.join(exr_dir, f"foam_{fr:04d}.exr"))
    vdisp = read_exr(os.path.join(exr_dir, f"vdisp_{fr:04d}.exr"))
    assert disp.shape == (meta["side"], meta["side"], 4), disp.shape
    worst = max(worst, close("disp R = dx", disp[..., 0], fields["dx"]),
                close("disp G = height", disp[..., 1], fields["height"]),
                close("disp B = dz", disp[..., 2], fields["dz"]))
    # vdisp: Blender's axes for a Displace modifier (RGB to XYZ): X = dx, Y = dz, Z = height
    close("vdisp R = dx", vdisp[..., 0], fields["dx"])
    close("vdisp G = dz", vdisp[..., 1], fields["dz"])
    close("vdisp B = height", vdisp[..., 2], fields["height"])
    sx, sz = fields["slope_x"].astype(np.float64), fields["slope_z"].astype(np.float64)
    length = np.sqrt(sx * sx + 1 + sz * sz)
    close("normal R", normal[..., 0], -sx / length)
    close("normal G", normal[..., 1], 1 / length)
    close("normal B", normal[..., 2], -sz / length)
    close("foam", foam[..., 0], np.clip(np.float32(1) - fields["jacobian"], 0, 1))
    for img in (disp, normal, foam, vdisp):
        assert (img[..., 3] == 1).all(), "alpha is not 1"
    assert (foam[..., 0] == foam[..., 1]).all() and (foam[..., 0] == foam[..., 2]).all()
    compared += 1
assert compared > 0, "no bake frame has the same seq as a streamed frame"
print(f"  {compared} of {len(frames)} bake frames equal the streamed fields at the same seq "
      f"(worst displacement difference {worst:.2g} m, half precision)")

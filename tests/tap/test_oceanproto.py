"""The Python example's decoder (proto/examples/oceanproto.py) against the
shared test vectors (proto/vectors/): every good vector decodes to exactly the
expected float32 samples, every bad vector is rejected with the error code of the manifest.
Usage: /usr/bin/python3 tests/tap/test_oceanproto.py [proto/vectors]"""
import json
import os
import sys

import numpy as np

here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(here, "..", "..", "proto", "examples"))
import oceanproto  # noqa: E402

vdir = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "..", "..", "proto", "vectors")
manifest = json.load(open(os.path.join(vdir, "manifest.json")))
failures = 0
good = 0
for v in manifest["vectors"]:
    data = open(os.path.join(vdir, v["file"]), "rb").read()
    expected = np.fromfile(os.path.join(vdir, v["expected"]), "<f4")
    try:
        frame = oceanproto.decode_frame(data)
    except oceanproto.ProtocolError as e:
        print(f"FAIL {v['name']}: rejected: {e}")
        failures += 1
        continue
    got = np.concatenate([t.samples.ravel() for t in frame.tiles]) if frame.tiles else np.zeros(0, np.float32)
    h = v["header"]
    if (frame.seq, frame.n, frame.tile_size, len(frame.tiles)) != (h["seq"], h["n"], h["tileSize"], h["tileCount"]):
        print(f"FAIL {v['name']}: header {frame.seq, frame.n, frame.tile_size, len(frame.tiles)}")
        failures += 1
    elif got.shape != expected.shape or not np.array_equal(got.view(np.uint32), expected.view(np.uint32)):
        n = np.count_nonzero(got != expected) if got.shape == expected.shape else "shape"
        print(f"FAIL {v['name']}: samples differ ({n})")
        failures += 1
    else:
        good += 1
bad = 0
for b in manifest.get("bad", []):
    try:
        oceanproto.decode_frame(open(os.path.join(vdir, b["file"]), "rb").read())
        print(f"FAIL {b['name']}: accepted")
        failures += 1
    except oceanproto.ProtocolError as e:
        if e.code != b["error"]:
            print(f"FAIL {b['name']}: error {e.code}, expected {b['error']} ({e})")
            failures += 1
        else:
            bad += 1
# Temporal streams (codec 3): one DecoderState per stream, frames in order.
streams = 0
for st in manifest.get("streams", []):
    state = oceanproto.DecoderState()
    for i, f in enumerate(st["frames"]):
        data = open(os.path.join(vdir, f["file"]), "rb").read()
        try:
            frame = oceanproto.decode_frame(data, state)
        except oceanproto.ProtocolError as e:
            if e.code != f.get("error"):
                print(f"FAIL {st['name']} frame {i}: {e}")
                failures += 1
            continue
        if "error" in f:
            print(f"FAIL {st['name']} frame {i}: accepted, expected {f['error']}")
            failures += 1
            continue
        expected = np.fromfile(os.path.join(vdir, f["expected"]), "<f4")
        got = np.concatenate([t.samples.ravel() for t in frame.tiles])
        if frame.seq != f["seq"] or got.shape != expected.shape or not np.array_equal(got.view(np.uint32), expected.view(np.uint32)):
            print(f"FAIL {st['name']} frame {i}: samples differ")
            failures += 1
    streams += 1
# Assembler: a frame is complete only when it carries every tile of the wanted fields at
# the wanted LOD. A frame served at a coarser LOD (the server degraded it, §7.2) is not,
# though the grid still holds the frame before (which used to be saved under the new seq).
from types import SimpleNamespace as NS  # noqa: E402


def synth(seq, lod, value, n=64, ts=32):
    side = ts >> lod
    return NS(seq=seq, n=n, tile_size=ts, tiles=[NS(field="height", lod=lod, cascade=0, x=x, z=z,
                                                   samples=np.full((side, side), value, np.float32))
                                                for z in range(n // ts) for x in range(n // ts)])


asm = oceanproto.Assembler(["height"], 1)
asm.add(synth(1, 1, 1.0))
first = asm.complete() and (asm.fields["height"] == 1.0).all()
asm.add(synth(2, 2, 2.0))                 # degraded: coarser tiles only
degraded = asm.complete()
part = synth(3, 1, 3.0)
part.tiles = part.tiles[1:]               # one tile missing
asm.add(part)
partial = asm.complete()
asm.add(synth(4, 1, 4.0))
if not first or degraded or partial or not asm.complete():
    print(f"FAIL Assembler: complete after a full frame {first}, after a coarser one {degraded} (want False), "
          f"after a partial one {partial} (want False), after the next full one {asm.complete()}")
    failures += 1

if failures or not good or not bad:
    print(f"FAIL: {failures} failures ({good} good vectors decoded, {bad} bad vectors rejected)")
    sys.exit(1)
print(f"  ok  Python decoder: {good} vectors bit-exact, {bad} malformed frames rejected with the right error, "
      f"{streams} temporal streams frame by frame")

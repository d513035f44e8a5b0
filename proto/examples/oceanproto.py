"""oceanproto.py - the frame decoder of the oceand Python package, for scripts
that run from a checkout without installing it (`pip install ./proto/python`
installs the same code as the package `oceand`).

    import oceanproto
    frame = oceanproto.decode_frame(message_bytes, oceanproto.DecoderState())
    grid = oceanproto.Assembler(["height"], lod=1, cascade=0); grid.add(frame)
"""
import os
import sys

try:
    from oceand import frames as _frames
except ImportError:   # not installed: the package beside this folder
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
    from oceand import frames as _frames

globals().update({k: v for k, v in vars(_frames).items() if not k.startswith("__")})

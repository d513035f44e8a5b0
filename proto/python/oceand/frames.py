"""oceand.frames - a decoder of oceand binary frames (protocol v1).

Written from proto/PROTOCOL.md alone (section numbers below refer to it), as a
second implementation next to the C (proto/c) and JavaScript (proto/js) ones.
Needs only numpy and the standard library; zstd-coded tiles (codec 2) use the
system libzstd through ctypes, since Debian 12 has no python3 zstd module.

    frame = decode_frame(message_bytes)       # -> Frame, or raises ProtocolError
    state = DecoderState(); frame = decode_frame(message_bytes, state)   # a stream with codec 3 tiles
    frame.seq, frame.sim_time, frame.n, ...
    for tile in frame.tiles: tile.field, tile.lod, tile.cascade, tile.x, tile.z, tile.samples
    grid = Assembler(["height"], lod=1, cascade=0); grid.add(frame); grid.fields["height"]
"""
import ctypes
import ctypes.util
import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

MAGIC = b"OCNF"
VERSION = 1
SUBPROTOCOL = "oceand.v1"
FIELDS = ("height", "dx", "dz", "slope_x", "slope_z", "jacobian", "foam")   # ids 0..6 (§3.2)
MAX_N, MAX_LOD = 2048, 4

# §3.1, §3.2: all little-endian, no padding.
FRAME_HEADER = struct.Struct("<4sHHQdIHHfHHQ")   # 48 bytes
TILE_HEADER = struct.Struct("<BBBBHHHHfddII")    # 40 bytes
LOSSY_PREFIX = struct.Struct("<BBHI6bH")         # 16 bytes (§5.1)
assert (FRAME_HEADER.size, TILE_HEADER.size, LOSSY_PREFIX.size) == (48, 40, 16)

CODEC_RAW_F32, CODEC_DEFLATE, CODEC_ZSTD, CODEC_TEMPORAL = 0, 1, 2, 3   # §5
TEMPORAL_PREFIX = struct.Struct("<BBBBIIIQ7hH")   # 40 bytes (§5.6)
assert TEMPORAL_PREFIX.size == 40
COEF_MASK = (0, 0x40, 0x49, 0x5B, 0x7F)   # coefficients allowed per depth (§5.6)
MAX_DEPTH, PAIR_LIMIT = 4, 15


class ProtocolError(ValueError):
    """Not a valid v1 frame. code is one of the names of §6.1:
    truncated, magic, version, corrupt, too_large, reference (a predicted tile
    whose reference frames this DecoderState does not hold)."""

    def __init__(self, code, message):
        super().__init__(f"{code}: {message}")
        self.code = code


@dataclass
class Tile:
    field: str
    lod: int
    codec: int
    x: int               # tile_x, tile_z: tile column and row (§4)
    z: int
    bound: float
    samples: np.ndarray  # (height, width) float32, row j along z, column i along x
    cascade: int = 0     # tile header flags bits 0-1 (§3.2): which cascade's patch (§4.1)


BODY_SECTION = struct.Struct("<4sHH8x")            # 16 bytes: tag, count, record_size (§3.5)
BODY_RECORD = struct.Struct("<IBBbb3f4f3f")         # 48 bytes
BODY_ADRIFT, BODY_POWERED = 1, 2                    # record flags


@dataclass
class Body:
    """One floating body's record of a tick (§3.5)."""
    id: int
    kind: int            # index into hello["body_kinds"]
    flags: int
    throttle: float      # -1..1 (the byte / 127)
    rudder: float
    pos: tuple           # (x, y, z) m, world, centre of mass
    quat: tuple          # (w, x, y, z), body -> world
    vel: tuple           # (vx, vy, vz) m/s

    @property
    def adrift(self):
        return bool(self.flags & BODY_ADRIFT)

    @property
    def powered(self):
        return bool(self.flags & BODY_POWERED)


def decode_bodies(data):
    """The floating bodies in a frame's header (§3.5): a list of Body in ascending
    id, [] for a frame without a BODY section. Raises ProtocolError on a bad header
    or a section that does not fit it."""
    data = memoryview(data)
    if len(data) < FRAME_HEADER.size:
        raise ProtocolError("truncated", "shorter than a frame header")
    magic, version, header_size = struct.unpack_from("<4sHH", data, 0)
    if magic != MAGIC:
        raise ProtocolError("magic", f"magic {bytes(magic)!r}")
    if version != VERSION:
        raise ProtocolError("version", f"frame version {version}")
    if header_size < FRAME_HEADER.size or header_size % 8:
        raise ProtocolError("corrupt", f"header_size {header_size}")
    if header_size > len(data):
        raise ProtocolError("truncated", "shorter than its header_size")
    room = header_size - FRAME_HEADER.size
    if room < BODY_SECTION.size or bytes(data[48:52]) != b"BODY":
        return []
    _tag, count, rsize = BODY_SECTION.unpack_from(data, 48)
    if rsize < BODY_RECORD.size or rsize % 8 or count * rsize > room - BODY_SECTION.size:
        raise ProtocolError("corrupt", f"BODY section of {count} x {rsize} bytes in a header of {header_size}")
    out = []
    for i in range(count):
        r = BODY_RECORD.unpack_from(data, 64 + i * rsize)
        out.append(Body(r[0], r[1], r[2], r[3] / 127.0, r[4] / 127.0, r[5:8], r[8:12], r[12:15]))
    return out


@dataclass
class Frame:
    seq: int
    sim_time: float
    params_version: int
    n: int
    tile_size: int
    patch_size: float
    server_time_us: int
    tiles: list = field(default_factory=list)
    bodies: list = field(default_factory=list)   # the tick's floating bodies (Body, §3.5)


def _pow2(v):
    return v > 0 and v & (v - 1) == 0


# ---- entropy coders (§5.1: exactly `size` bytes, stream consumed entirely) ----

def _inflate(data, size):
    d = zlib.decompressobj(wbits=-15)          # raw DEFLATE, no zlib header
    try:
        out = d.decompress(data, size + 1)
    except zlib.error as e:
        raise ProtocolError("corrupt", f"bad DEFLATE stream: {e}") from None
    if len(out) != size or not d.eof or d.unused_data or d.unconsumed_tail:
        raise ProtocolError("corrupt", f"DEFLATE stream does not give exactly {size} bytes")
    return out


_zstd = None


def _unzstd(data, size):
    global _zstd
    if _zstd is None:
        _zstd = ctypes.CDLL(ctypes.util.find_library("zstd") or "libzstd.so.1")
        _zstd.ZSTD_decompress.restype = ctypes.c_size_t
        _zstd.ZSTD_decompress.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p, ctypes.c_size_t]
        _zstd.ZSTD_isError.restype = ctypes.c_uint
        _zstd.ZSTD_isError.argtypes = [ctypes.c_size_t]
    out = ctypes.create_string_buffer(size + 1)
    r = _zstd.ZSTD_decompress(out, size + 1, data, len(data))
    if _zstd.ZSTD_isError(r) or r != size:
        raise ProtocolError("corrupt", f"zstd stream does not give exactly {size} bytes")
    return out.raw[:size]


# ---- codecs 1 and 2, undone --------------------------------------------------------

def _residuals(payload, codec, count):
    """§5.1-5.2: prefix, entropy stream, escapes, zigzag -> (int64 residuals, coef)."""
    if len(payload) < LOSSY_PREFIX.size:
        raise ProtocolError("corrupt", "lossy payload shorter than its prefix")
    esc_width, zero1, zero2, esc_count, *rest = LOSSY_PREFIX.unpack_from(payload, 0)
    coef, zero3 = rest[:6], rest[6]
    if esc_width > 4 or zero1 or zero2 or zero3 or esc_count > count or (esc_width == 0) != (esc_count == 0):
        raise ProtocolError("corrupt", "bad lossy prefix")
    size = count + esc_count * esc_width
    body = payload[LOSSY_PREFIX.size:]
    raw = _inflate(body, size) if codec == CODEC_DEFLATE else _unzstd(body, size)
    z = _escaped_values(raw, count, esc_count, esc_width)
    # zigzag: 0, 1, 2, 3, 4 ... -> 0, -1, 1, -2, 2 ...
    r = (z >> np.uint64(1)).astype(np.int64) ^ -(z & np.uint64(1)).astype(np.int64)
    return r, np.array(coef, np.int64)


def _wrap32(v):
    """Reduce int64 values modulo 2^32 into the int32 range."""
    return ((v + 2**31) & 0xFFFFFFFF) - 2**31


_wavefronts = {}


def _wavefront_plan(h, w):
    """The samples of a tile grouped so that each group only depends on earlier
    ones: sample (j, i) needs W, WW (same row, left), N, NN, NW and NE (rows
    above, NE one column right), all on an earlier anti-diagonal t = 2j + i.
    Per group: rows, columns and which rule of the §5.3 table applies."""
    key = (h, w)
    if key not in _wavefronts:
        plan = []
        for t in range(2 * (h - 1) + (w - 1) + 1):
            j = np.arange(max(0, -(-(t - (w - 1)) // 2)), min(h - 1, t // 2) + 1)
            i = t - 2 * j
            rule = np.full(len(j), 4)                                 # 4: Lorenzo W + N - NW
            rule[(j >= 2) & (i >= 2) & (i <= w - 2)] = 3              # 3: interior predictor
            rule[(j > 0) & (i == 0)] = 2                              # 2: N
            rule[(j == 0) & (i > 0)] = 1                              # 1: W
            rule[(j == 0) & (i == 0)] = 0                             # 0: zero
            plan.append((j, i, rule))
        _wavefronts[key] = plan
    return _wavefronts[key]


def _unpredict(r, coef):
    """§5.3 for a batch of same-sized tiles. r: (T, h, w) int64 residuals,
    coef: (T, 6) coefficients c_W, c_N, c_NW, c_NE, c_WW, c_NN. Returns int64
    codes in the int32 range. Works on whole anti-diagonals with numpy."""
    T, h, w = r.shape
    # Codes with a margin of zeros (2 rows above, 2 columns left, 1 right) so the
    # six neighbours can always be read; the rules never use the margin's values.
    q = np.zeros((T, h + 2, w + 3), np.int64)
    c = [coef[:, k, None] for k in range(6)]
    for j, i, rule in _wavefront_plan(h, w):
        J, I = j + 2, i + 2
        W, N, NW = q[:, J, I - 1], q[:, J - 1, I], q[:, J - 1, I - 1]
        NE, WW, NN = q[:, J - 1, I + 1], q[:, J, I - 2], q[:, J - 2, I]
        s = c[0] * W + c[1] * N + c[2] * NW + c[3] * NE + c[4] * WW + c[5] * NN   # exact, |s| < 2^41
        interior = np.clip((s + 32) // 64, -2**31, 2**31 - 1)                     # // floors toward -inf
        P = np.select([rule == 0, rule == 1, rule == 2, rule == 3],
                      [0, W, N, interior], W + N - NW)
        q[:, J, I] = _wrap32(P + r[:, j, i])
    return q[:, 2:, 2:w + 2]


# ---- codec 3: temporal prediction (§5.6-5.8) -----------------------------------------

class DecoderState:
    """The references of predicted tiles: the codes of the last frames of every tile.
    One per stream; decode its frames in order. A frame that fails changes nothing."""

    def __init__(self):
        self.tiles = {}   # (field, lod, cascade, x, z, n, tile_size) -> list of (seq, offset, scale, bound, codes)

    def reset(self):
        self.tiles.clear()


def _escaped_values(raw, count, esc_count, esc_width):
    """§5.2: count bytes (stream A, 255 = escaped) + byte planes (stream B, least significant
    first) -> uint64 zigzag values."""
    a = np.frombuffer(raw, np.uint8, count)
    z = a.astype(np.uint64)
    escaped = np.flatnonzero(a == 255)
    if len(escaped) != esc_count:
        raise ProtocolError("corrupt", f"{len(escaped)} escapes, prefix says {esc_count}")
    if esc_count:
        planes = np.frombuffer(raw, np.uint8, esc_count * esc_width, count).reshape(esc_width, esc_count)
        x = np.zeros(esc_count, np.uint64)
        for p in range(esc_width):
            x |= planes[p].astype(np.uint64) << np.uint64(8 * p)
        if (x > 2**32 - 256).any():
            raise ProtocolError("corrupt", "escaped residual out of range")
        z[escaped] = 255 + x
    return z


def _lap(a):
    """5-point Laplacian inside the tile, neighbours clamped to the tile (edge samples repeat)."""
    p = np.pad(a, 1, mode="edge")
    return p[1:-1, :-2] + p[1:-1, 2:] + p[:-2, 1:-1] + p[2:, 1:-1] - 4 * a


def _temporal(payload, key, offset, scale, bound, height, width, state):
    """A codec 3 payload -> int64 codes (height, width), checked in the order of §5.6."""
    count, npairs = width * height, (width * height + 1) // 2
    if len(payload) < TEMPORAL_PREFIX.size:
        raise ProtocolError("corrupt", "temporal payload shorter than its prefix")
    depth, packing, esc_width, zero1, esc_count, pair_esc, zero2, ref_seq, *coef = TEMPORAL_PREFIX.unpack_from(payload, 0)
    coef, zero3 = coef[:7], coef[7]
    if (not 1 <= depth <= MAX_DEPTH or packing > 1 or esc_width > 4 or zero1 or zero2 or zero3
            or (esc_count == 0) != (esc_width == 0)
            or any(c and not COEF_MASK[depth] >> k & 1 for k, c in enumerate(coef))):
        raise ProtocolError("corrupt", "bad temporal prefix")
    if packing == 0:
        if pair_esc or esc_count > count:
            raise ProtocolError("corrupt", "bad escape counts")
        size = count + esc_count * esc_width
    else:
        if pair_esc > npairs or esc_count > 2 * pair_esc:
            raise ProtocolError("corrupt", "bad escape counts")
        size = npairs + 2 * pair_esc + esc_count * esc_width
    if state is None:
        raise ProtocolError("reference", "a predicted tile (codec 3) needs a DecoderState")
    refs = []
    for i in range(depth):
        found = [s for s in state.tiles.get(key, []) if s[0] == ref_seq - i and s[1:4] == (offset, scale, bound)
                 and s[4].shape == (height, width)]
        if not found:
            raise ProtocolError("reference", f"tile {key}: reference frame {ref_seq - i} missing or on another grid")
        refs.append(found[0][4])
    raw = _inflate(payload[TEMPORAL_PREFIX.size:], size)
    if packing == 0:
        z = _escaped_values(raw, count, esc_count, esc_width)
    else:
        a = np.frombuffer(raw, np.uint8, npairs)
        if ((a >= PAIR_LIMIT * PAIR_LIMIT) & (a != 255)).any() or np.count_nonzero(a == 255) != pair_esc:
            raise ProtocolError("corrupt", "bad pair bytes")
        y = _escaped_values(raw[npairs:], 2 * pair_esc, esc_count, esc_width)
        z = np.zeros(2 * npairs, np.uint64)
        z[0::2], z[1::2] = a // PAIR_LIMIT, a % PAIR_LIMIT
        esc = np.flatnonzero(a == 255)
        z[2 * esc], z[2 * esc + 1] = y[0::2], y[1::2]
        if count % 2 and z[count]:
            raise ProtocolError("corrupt", "padding value of an odd tile is not 0")
        z = z[:count]
    r = (z >> np.uint64(1)).astype(np.int64) ^ -(z & np.uint64(1)).astype(np.int64)
    # Missing references (depth < 4) stand in as q1: their coefficients are 0.
    q = [refs[i] if i < depth else refs[0] for i in range(4)]
    lap = [_lap(a) for a in q]
    c = coef
    s = (c[0] * (q[0] - q[1]) + c[1] * (q[1] - q[2]) + c[2] * (q[2] - q[3]) + c[3] * (lap[0] - lap[1])
         + c[4] * (lap[1] - lap[2]) + c[5] * (lap[2] - lap[3]) + c[6] * lap[0])   # exact in int64, |s| < 2^52
    return _wrap32(q[0] + (s + 2048) // 4096 + r.reshape(height, width))


# ---- parts (§3.4) ---------------------------------------------------------------------

FLAG_RENDERED = 1   # frame header flags bit 0: a rendered frame (§7.5)
FLAG_PART = 2       # bit 1: more tiles of this tick follow in the next message (§3.4)


class FrameJoiner:
    """Joins the parts of a tick's frame (subscribe "parts": true). push() every
    binary message: it returns the whole frame (the first part's header with the
    tiles of all the parts counted and bit 1 cleared, then their tiles in order)
    once the last part is in, a message that is not a part as it is, and None while
    parts are held. A part of another seq than the held ones drops them."""

    def __init__(self):
        self.parts, self.seq = [], None

    def push(self, data):
        if len(data) < FRAME_HEADER.size:
            raise ProtocolError("truncated", "shorter than a frame header")
        header_size, seq = struct.unpack_from("<HQ", data, 6)
        tile_count, flags = struct.unpack_from("<HH", data, 36)
        if header_size < FRAME_HEADER.size or header_size % 8 or header_size > len(data):
            raise ProtocolError("corrupt", f"header_size {header_size}")
        if self.parts and seq != self.seq:
            self.parts = []
        if flags & FLAG_PART:
            self.seq = seq
            self.parts.append((bytes(data), header_size, tile_count))
            return None
        if not self.parts:
            return data
        parts, self.parts = self.parts + [(bytes(data), header_size, tile_count)], []
        tiles = sum(p[2] for p in parts)
        if tiles > 0xFFFF:
            raise ProtocolError("corrupt", f"{tiles} tiles in the parts of one frame")
        first, first_size, _ = parts[0]
        head = bytearray(first[:first_size])
        struct.pack_into("<HH", head, 36, tiles, flags & ~FLAG_PART)
        return bytes(head) + b"".join(p[0][p[1]:] for p in parts)


# ---- frames (§3) -------------------------------------------------------------------

def decode_frame(data, state=None):
    """Decode one binary WebSocket message into a Frame, checking every length
    and field in the order of §6.1 before using it. state: a DecoderState,
    needed for predicted tiles (codec 3); it keeps this frame's codes as references."""
    data = memoryview(data)
    if len(data) < FRAME_HEADER.size:
        raise ProtocolError("truncated", "shorter than a frame header")
    (magic, version, header_size, seq, sim_time, params_version, n, tile_size,
     patch_size, tile_count, _flags, server_time_us) = FRAME_HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise ProtocolError("magic", f"magic {bytes(magic)!r}")
    if version != VERSION:
        raise ProtocolError("version", f"frame version {version}, this decoder speaks {VERSION}")
    if header_size < FRAME_HEADER.size or header_size % 8:
        raise ProtocolError("corrupt", f"header_size {header_size}")
    if header_size > len(data):
        raise ProtocolError("truncated", "shorter than its header_size")
    if n > MAX_N:
        raise ProtocolError("too_large", f"n = {n}")
    if not (_pow2(n) and _pow2(tile_size) and tile_size <= n and math.isfinite(sim_time)
            and math.isfinite(patch_size) and patch_size > 0):
        raise ProtocolError("corrupt", f"bad frame header (n={n}, tile_size={tile_size})")
    frame = Frame(seq, sim_time, params_version, n, tile_size, patch_size, server_time_us)
    frame.bodies = decode_bodies(data)
    grid_tiles = n // tile_size

    # Pass 1: headers, raw tiles, and the residuals of lossy tiles.
    pos, decoded, lossy, codes = header_size, [], {}, {}
    for index in range(tile_count):
        if len(data) - pos < TILE_HEADER.size:
            raise ProtocolError("truncated", f"tile {index}: truncated tile header")
        (fid, lod, codec, tflags, tx, tz, width, height, bound, offset, scale,
         payload_len, _reserved) = TILE_HEADER.unpack_from(data, pos)
        pos += TILE_HEADER.size
        if payload_len > len(data) - pos:
            raise ProtocolError("truncated", f"tile {index}: payload_len past the end")
        side = tile_size >> lod if lod <= MAX_LOD else 0
        if (fid >= len(FIELDS) or lod > MAX_LOD or codec > CODEC_TEMPORAL or tx >= grid_tiles
                or tz >= grid_tiles or side < 1 or width != side or height != side
                or not (math.isfinite(bound) and bound >= 0)):
            raise ProtocolError("corrupt", f"tile {index}: bad tile header")
        payload = bytes(data[pos:pos + payload_len])
        pos += payload_len
        count = width * height
        if codec == CODEC_RAW_F32:
            if payload_len != 4 * count:
                raise ProtocolError("corrupt", f"tile {index}: raw payload of {payload_len} bytes")
            samples = np.frombuffer(payload, "<f4").reshape(height, width).astype(np.float32)
        elif codec == CODEC_TEMPORAL:
            if not (math.isfinite(offset) and math.isfinite(scale) and scale > 0):
                raise ProtocolError("corrupt", f"tile {index}: bad offset/scale")
            key = (fid, lod, tflags & 3, tx, tz, n, tile_size)
            q = _temporal(payload, key, offset, scale, bound, height, width, state)
            codes[index] = (key, offset, scale, bound, q)
            samples = (offset + q.astype(np.float64) * scale).astype(np.float32)
        else:
            if not (math.isfinite(offset) and math.isfinite(scale) and scale > 0):
                raise ProtocolError("corrupt", f"tile {index}: bad offset/scale")
            r, coef = _residuals(payload, codec, count)
            lossy.setdefault((height, width), []).append((index, r.reshape(height, width), coef, offset, scale))
            samples = None
        decoded.append(Tile(FIELDS[fid], lod, codec, tx, tz, bound, samples, tflags & 3))
    if pos != len(data):
        raise ProtocolError("corrupt", f"{len(data) - pos} bytes after the last tile")

    # Pass 2: inverse prediction, all lossy tiles of a size at once, then §5.4:
    # value = float32(offset + q*scale) in float64 (numpy does not fuse the multiply-add).
    for (height, width), group in lossy.items():
        q = _unpredict(np.stack([g[1] for g in group]), np.stack([g[2] for g in group]))
        for (index, _r, _c, offset, scale), qt in zip(group, q):
            decoded[index].samples = (offset + qt.astype(np.float64) * scale).astype(np.float32)
            t = decoded[index]
            key = (FIELDS.index(t.field), t.lod, t.cascade, t.x, t.z, n, tile_size)
            codes[index] = (key, offset, scale, t.bound, qt)
    frame.tiles = decoded
    if state is not None:   # the whole frame decoded: its codes become references (5 per tile, oldest out)
        for key, offset, scale, bound, qt in codes.values():
            slots = state.tiles.setdefault(key, [])
            if len(slots) > MAX_DEPTH:
                slots.remove(min(slots, key=lambda s: s[0]))
            slots.append((seq, offset, scale, bound, qt))
    return frame


class Assembler:
    """Puts the tiles of one cascade (§4.1) together into whole (N >> lod)^2
    fields. complete() is true when the last frame added carried every tile of
    every wanted field at this LOD: a frame the server sends at a coarser LOD
    while it is degraded (§7.2) does not, and the fields then still hold an
    earlier frame's samples. Tiles of other cascades are left out: each cascade
    is its own grid over its own patch, and they only add up as surfaces."""

    def __init__(self, fields, lod, cascade=0):
        self.wanted, self.lod, self.cascade = set(fields), lod, cascade
        self.fields, self._seen, self._shape = {}, {}, None

    def add(self, frame):
        if self._shape != (frame.n, frame.tile_size):   # new resolution: start again
            self._shape = (frame.n, frame.tile_size)
            side = frame.n >> self.lod
            self.fields = {f: np.zeros((side, side), np.float32) for f in self.wanted}
        tiles = frame.n // frame.tile_size
        self._seen = {f: np.zeros((tiles, tiles), bool) for f in self.wanted}   # this frame's tiles
        step = frame.tile_size >> self.lod
        for t in frame.tiles:
            if t.field not in self.wanted or t.lod != self.lod or t.cascade != self.cascade:
                continue   # sent before our subscription took effect, at a coarser LOD (degraded), or another cascade
            h, w = t.samples.shape
            self.fields[t.field][t.z * step:t.z * step + h, t.x * step:t.x * step + w] = t.samples
            self._seen[t.field][t.z, t.x] = True

    def complete(self):
        return bool(self._seen) and all(s.all() for s in self._seen.values())

// oc_decode.js — decoder for oceand protocol v1 binary frames (proto/PROTOCOL.md).
// ES module for browsers and node >= 20, no imports (bundlers and the in-browser
// test inline it as is). Codec 1 (the default) is raw DEFLATE, inflated by:
//   - node's zlib when running under node (process.getBuiltinModule, no import);
//   - else DecompressionStream('deflate-raw'), all tiles of a frame concurrently;
//   - and, when a synchronous inflater is installed with setInflateRaw() (e.g.
//     fflate's inflateSync, as the web client's worker does), that one for tiles
//     below 128x128 samples, where a stream's set-up cost dominates
//     (STREAM_MIN_SAMPLES, measured).
// Codec 2 (zstd) is optional: call setZstdDecompressor(fzstd.decompress) to
// enable it. Codec 3 (temporal, predicted from the previous frames) needs a
// DecoderState that lives as long as the stream: decodeFrame(buf, { state }). Every length is checked before it is read; bad input throws an
// Error whose `code` is 'truncated' | 'magic' | 'version' | 'corrupt' |
// 'too_large' | 'unsupported' | 'reference' (a predicted tile whose reference
// frames this state has not decoded: wait for the keyframe the server sends next).

export const PROTO_VERSION = 1;
export const SUBPROTOCOL = 'oceand.v1';
export const FIELD_NAMES = Object.freeze(['height', 'dx', 'dz', 'slope_x', 'slope_z', 'jacobian', 'foam']);
export const CODEC_RAW_F32 = 0;
export const CODEC_QUANT_LORENZO = 1;       // deflate-raw entropy coder (default)
export const CODEC_QUANT_LORENZO_ZSTD = 2;  // zstd entropy coder
export const CODEC_TEMPORAL = 3;            // predicted from the previous 1..4 frames, deflate-raw
export const FRAME_HEADER_SIZE = 48;
export const TILE_HEADER_SIZE = 40;
export const MAX_N = 2048;
export const MAX_LOD = 4;
const LOSSY_PREFIX = 16;
const TEMPORAL_PREFIX = 40;
const MAX_DEPTH = 4;
const HISTORY_SLOTS = MAX_DEPTH + 1;
const PAIR_LIMIT = 15;
const nodeZlib = globalThis.process?.getBuiltinModule?.('node:zlib') ?? null;

let zstdDecompress = null;
/** Enable codec 2: fn(Uint8Array compressed, Uint8Array out) -> Uint8Array (e.g. fzstd's decompress). */
export function setZstdDecompressor(fn) { zstdDecompress = fn; }

let inflateRawSync = null;
/**
 * Install a synchronous raw-DEFLATE inflater for codec 1 (null removes it):
 * fn(Uint8Array compressed, Uint8Array out) -> Uint8Array of the inflated bytes (a view of
 * `out` or a new array), throwing on a bad stream. `out` has room for one byte more than the
 * expected size, so a stream that runs long shows up as a longer result. With fflate:
 * setInflateRaw((src, out) => inflateSync(src, { out })).
 * Used for tiles below STREAM_MIN_SAMPLES (all tiles where DecompressionStream is missing);
 * under node only with options.useNodeZlib = false.
 */
export function setInflateRaw(fn, options = {}) { inflateRawSync = fn; inflateAll = !!(fn && options.allTiles); }
// options.allTiles: the installed inflater takes every tile, large ones too (the WebAssembly one,
// faster than a DecompressionStream at any tile size).
let inflateAll = false;

let temporalKernel = null;
/**
 * Install a codec 3 prediction kernel (null removes it): fn(refs, depth, zz, w, h, coef, q, dst, offset, scale, pairs)
 * (zz: the zigzag residuals, or with pairs = true stream A of pair packing without escaped pairs) -> true when it wrote the tile's codes to q (Int32Array) and its samples to dst ({array, offset, stride,
 * rowStride}), false to leave the tile to this module's JavaScript (bit-identical). The WebAssembly one:
 * proto/js/oc_wasm.js's loadKernels(bytes).temporal.
 */
export function setTemporalKernel(fn) { temporalKernel = fn; }

/** Error thrown for bad input; `code` says which kind. */
export class FrameError extends Error {
  constructor(code, message) {
    super(`oceand frame: ${message}`);
    this.name = 'FrameError';
    this.code = code;
  }
}
const fail = (code, message) => new FrameError(code, message);

function asBytes(buf) {
  if (buf instanceof ArrayBuffer) return new Uint8Array(buf);
  if (ArrayBuffer.isView(buf)) return new Uint8Array(buf.buffer, buf.byteOffset, buf.byteLength);
  throw fail('corrupt', 'input is not an ArrayBuffer or typed array');
}

const isPow2 = (v) => v > 0 && (v & (v - 1)) === 0;

function readFrameHeader(bytes) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes.length < 8) throw fail('truncated', `${bytes.length} bytes, need ${FRAME_HEADER_SIZE}`);
  if (bytes[0] !== 0x4f || bytes[1] !== 0x43 || bytes[2] !== 0x4e || bytes[3] !== 0x46)
    throw fail('magic', 'magic is not "OCNF"');
  const version = dv.getUint16(4, true);
  if (version !== PROTO_VERSION) throw fail('version', `protocol version ${version}, this decoder speaks ${PROTO_VERSION}`);
  const headerSize = dv.getUint16(6, true);
  if (headerSize < FRAME_HEADER_SIZE || headerSize % 8) throw fail('corrupt', `header_size ${headerSize}`);
  if (bytes.length < headerSize) throw fail('truncated', `${bytes.length} bytes, header_size ${headerSize}`);
  const h = {
    seq: Number(dv.getBigUint64(8, true)),
    simTime: dv.getFloat64(16, true),
    paramsVersion: dv.getUint32(24, true),
    n: dv.getUint16(28, true),
    tileSize: dv.getUint16(30, true),
    patchSize: dv.getFloat32(32, true),
    tileCount: dv.getUint16(36, true),
    flags: dv.getUint16(38, true),
    serverTimeUs: Number(dv.getBigUint64(40, true)),
    headerSize,
  };
  if (h.n > MAX_N) throw fail('too_large', `n ${h.n} > ${MAX_N}`);
  if (!isPow2(h.n) || !isPow2(h.tileSize) || h.tileSize > h.n) throw fail('corrupt', `n ${h.n}, tile_size ${h.tileSize}`);
  if (!Number.isFinite(h.simTime) || !(h.patchSize > 0) || !Number.isFinite(h.patchSize))
    throw fail('corrupt', 'sim_time or patch_size not finite');
  h.bodies = readBodies(bytes, dv, headerSize);
  return h;
}

/** Body record flags (PROTOCOL.md §3.5). */
export const BODY_ADRIFT = 1;
export const BODY_POWERED = 2;

/* The floating bodies of the frame's tick: the BODY section of the header
 * (PROTOCOL.md §3.5), [] when there is none. Each: { id, kind (index into
 * hello.body_kinds), flags, adrift, powered, throttle, rudder (-1..1),
 * pos [x, y, z], quat [w, x, y, z], vel [vx, vy, vz] }. */
function readBodies(bytes, dv, headerSize) {
  const room = headerSize - FRAME_HEADER_SIZE;
  if (room < 16 || bytes[48] !== 0x42 || bytes[49] !== 0x4f || bytes[50] !== 0x44 || bytes[51] !== 0x59) return [];
  const count = dv.getUint16(52, true), rsize = dv.getUint16(54, true);
  if (rsize < 48 || rsize % 8 || count * rsize > room - 16)
    throw fail('corrupt', `BODY section of ${count} x ${rsize} bytes in a header of ${headerSize}`);
  const out = [];
  for (let i = 0, p = 64; i < count; i++, p += rsize) {
    const f = (k) => dv.getFloat32(p + k, true);
    const flags = bytes[p + 5];
    out.push({
      id: dv.getUint32(p, true), kind: bytes[p + 4], flags,
      adrift: (flags & BODY_ADRIFT) !== 0, powered: (flags & BODY_POWERED) !== 0,
      throttle: dv.getInt8(p + 6) / 127, rudder: dv.getInt8(p + 7) / 127,
      pos: [f(8), f(12), f(16)], quat: [f(20), f(24), f(28), f(32)], vel: [f(36), f(40), f(44)],
    });
  }
  return out;
}

/** Parse and validate the frame header only (synchronous): the 48 bytes, and `bodies` from its BODY section (§3.5). */
export function parseFrameHeader(arrayBuffer) {
  return readFrameHeader(asBytes(arrayBuffer));
}

function readTileHeader(bytes, dv, pos, fh) {
  if (bytes.length - pos < TILE_HEADER_SIZE) throw fail('truncated', `tile header at ${pos}`);
  const t = {
    field: bytes[pos], lod: bytes[pos + 1], codec: bytes[pos + 2], flags: bytes[pos + 3],
    tileX: dv.getUint16(pos + 4, true), tileZ: dv.getUint16(pos + 6, true),
    width: dv.getUint16(pos + 8, true), height: dv.getUint16(pos + 10, true),
    bound: dv.getFloat32(pos + 12, true),
    offset: dv.getFloat64(pos + 16, true), scale: dv.getFloat64(pos + 24, true),
    payloadLen: dv.getUint32(pos + 32, true),
  };
  if (t.field >= FIELD_NAMES.length) throw fail('corrupt', `field ${t.field}`);
  if (t.lod > MAX_LOD) throw fail('corrupt', `lod ${t.lod}`);
  const side = fh.tileSize >> t.lod;
  if (side === 0 || t.width !== side || t.height !== side) throw fail('corrupt', `tile ${t.width}x${t.height} at lod ${t.lod}`);
  const grid = fh.n / fh.tileSize;
  if (t.tileX >= grid || t.tileZ >= grid) throw fail('corrupt', `tile (${t.tileX},${t.tileZ}) outside ${grid}x${grid}`);
  if (!Number.isFinite(t.bound) || t.bound < 0) throw fail('corrupt', `bound ${t.bound}`);
  if (t.codec === CODEC_QUANT_LORENZO || t.codec === CODEC_QUANT_LORENZO_ZSTD || t.codec === CODEC_TEMPORAL) {
    if (!Number.isFinite(t.offset) || !Number.isFinite(t.scale) || !(t.scale > 0)) throw fail('corrupt', 'offset/scale');
  } else if (t.codec !== CODEC_RAW_F32) {
    throw fail('corrupt', `codec ${t.codec}`);
  }
  if (t.payloadLen > bytes.length - pos - TILE_HEADER_SIZE) throw fail('truncated', `payload of ${t.payloadLen} bytes`);
  return t;
}

// Synchronous inflaters: node's zlib, or the one installed with setInflateRaw().
function inflateRawNode(src, n) {
  let res;
  try {
    res = nodeZlib.inflateRawSync(src, { info: true, maxOutputLength: Math.max(n, 1) });
  } catch (e) {
    throw fail('corrupt', `deflate: ${e.message}`);
  }
  if (res.buffer.length !== n) throw fail('corrupt', `deflate stream gave ${res.buffer.length} bytes, expected ${n}`);
  if (res.engine.bytesWritten !== src.length) throw fail('corrupt', 'bytes after the end of the deflate stream');
  return new Uint8Array(res.buffer.buffer, res.buffer.byteOffset, n);
}

let inflateOut = new Uint8Array(4097); // reused: its bytes are consumed by reconstruct() before the next tile
function inflateRawInstalled(src, n) {
  if (inflateOut.length < n + 1) inflateOut = new Uint8Array(n + 1);
  let res;
  try {
    res = inflateRawSync(src, inflateOut.subarray(0, n + 1));
  } catch (e) {
    throw fail('corrupt', `deflate: ${e && e.message}`);
  }
  if (!(res instanceof Uint8Array) || res.length !== n) throw fail('corrupt', `deflate stream gave ${res && res.length} bytes, expected ${n}`);
  return res;
}

// Which inflater for a codec 1 tile when both a setInflateRaw() one and DecompressionStream
// exist: a stream costs ~0.1 ms to set up but then inflates natively, ~1.6x faster than
// fflate, so it wins on large tiles. Measured in headless Chromium on the 2-core dev machine
// (docs/web.md), inflating one N=256 height+dx+dz frame: 48 tiles of 64x64 samples,
// fflate 2.5 ms, streams 4.7 ms; 12 tiles of 128x128, fflate 2.4 ms, streams 1.6 ms.
const STREAM_MIN_SAMPLES = 128 * 128;
const haveStreams = typeof DecompressionStream === 'function';
// Codec 3 tiles inflate to half as many bytes (pair packing) from a quarter of the input, so
// the stream's set-up dominates: they take the synchronous inflater whenever one is installed
// (node, CPU per N=256 frame of height+dx+dz: 4.2-5.3 ms with fflate, 5.5-6.5 with streams).
const preferStream = (t) => !inflateAll && t.codec === CODEC_QUANT_LORENZO && t.width * t.height >= STREAM_MIN_SAMPLES;

// One DecompressionStream per tile (async; decodeFrame runs them concurrently).
async function inflateRawStream(src, n) {
  if (!haveStreams) throw fail('unsupported', 'codec 1 needs DecompressionStream or setInflateRaw()');
  const ds = new DecompressionStream('deflate-raw');
  const writer = ds.writable.getWriter();
  const written = writer.write(src).then(() => writer.close()).catch(() => {}); // errors surface on the reader
  const reader = ds.readable.getReader();
  const out = new Uint8Array(n);
  let pos = 0;
  try {
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      if (value.length > n - pos) {
        reader.cancel().catch(() => {});
        throw fail('corrupt', 'deflate stream longer than expected');
      }
      out.set(value, pos);
      pos += value.length;
    }
  } catch (e) {
    if (e instanceof FrameError) throw e;
    throw fail('corrupt', `deflate: ${e.message}`);
  }
  await written;
  if (pos !== n) throw fail('corrupt', `deflate stream gave ${pos} bytes, expected ${n}`);
  return out;
}

function unzstd(src, n) {
  if (!zstdDecompress) throw fail('unsupported', 'codec 2 (zstd) needs setZstdDecompressor()');
  let out;
  try {
    out = zstdDecompress(src, new Uint8Array(n));
  } catch (e) {
    throw fail('corrupt', `zstd: ${e.message}`);
  }
  if (out.length !== n) throw fail('corrupt', `zstd stream gave ${out.length} bytes, expected ${n}`);
  return out;
}

// Streams A + B -> zigzag residuals -> prediction inverse (int32 wrap-around)
// -> float32(offset + q*scale). Mirrors proto/c/oc_transform.c exactly.
// Scratch arrays are reused: reconstruct() never awaits, so tiles cannot interleave here.
let scratch = new Int32Array(4096);   // the codes q
let zzScratch = new Int32Array(4096); // zigzag values when the tile has escapes

// Tiles with escapes: stream A + stream B -> one zigzag value per sample (u32 bit pattern).
function unpackEscapes(zz, packed, count, escCount, escWidth) {
  // One byte per sample; 255 = take the next escaped value from stream B (byte planes).
  let e = 0;
  for (let k = 0; k < count; k++) {
    let z = packed[k];
    if (z === 255) {
      if (e === escCount) throw fail('corrupt', 'more escapes than esc_count');
      let x = 0;
      for (let p = 0; p < escWidth; p++) x += packed[count + p * escCount + e] * 2 ** (8 * p);
      if (x > 0xffffffff - 255) throw fail('corrupt', 'escaped residual out of range');
      z = (x + 255) | 0;
      e++;
    }
    zz[k] = z;
  }
  if (e !== escCount) throw fail('corrupt', 'fewer escapes than esc_count');
}

// The interior prediction when its sum is outside int32 (never for real data): the same sum
// in float64 (exact, |s| < 2^41), floor(s / 64), clamped to int32.
function predictWide(c, W, N, NW, NE, WW, NN) {
  const s = c[0] * W + c[1] * N + c[2] * NW + c[3] * NE + c[4] * WW + c[5] * NN + 32;
  return Math.max(-2147483648, Math.min(2147483647, Math.floor(s / 64)));
}

// One pass over the tile, row by row: zigzag-decode the residual, add the prediction, store
// the code (for the rows below) and its float. The last decoded neighbours stay in locals
// (wv = W, ww = WW, n = N, nw = NW) rather than being re-read. Every sum is exact (|x| < 2^53)
// before `| 0` wraps it to int32, as the C decoder's uint32 arithmetic does.
// z = src[k] is a zigzag value (a stream A byte, or from unpackEscapes); its residual is
// (z >>> 1) ^ -(z & 1).
function reconstruct(t, packed, escCount, escWidth, coef, dst) {
  const w = t.width, h = t.height, count = w * h;
  if (scratch.length < count) scratch = new Int32Array(count);
  const q = scratch;
  let src = packed; // no escapes (the usual case): read stream A directly
  if (escCount !== 0) {
    if (zzScratch.length < count) zzScratch = new Int32Array(count);
    src = zzScratch;
    unpackEscapes(src, packed, count, escCount, escWidth);
  }
  const out = dst.array; // the store rounds to float32, as the C cast does
  const os = dst.stride, ors = dst.rowStride;
  const off = t.offset, sc = t.scale;
  let z = src[0], o = dst.offset;
  let wv = (z >>> 1) ^ -(z & 1); // (0, 0): P = 0
  q[0] = wv; out[o] = off + wv * sc;
  for (let i = 1; i < w; i++) { // row 0: P = W
    z = src[i];
    wv = (((z >>> 1) ^ -(z & 1)) + wv) | 0;
    o += os;
    q[i] = wv; out[o] = off + wv * sc;
  }
  const cW = coef[0], cN = coef[1], cNW = coef[2], cNE = coef[3], cWW = coef[4], cNN = coef[5];
  const hasInterior = w >= 4 && h >= 3;
  for (let j = 1; j < h; j++) {
    const r = j * w, u = r - w;
    o = dst.offset + j * ors;
    z = src[r];
    wv = (((z >>> 1) ^ -(z & 1)) + q[u]) | 0; // column 0: P = N
    q[r] = wv; out[o] = off + wv * sc;
    let nw = q[u];
    if (j < 2 || !hasInterior) { // Lorenzo across the row
      for (let i = 1; i < w; i++) {
        const n = q[u + i];
        z = src[r + i];
        wv = (((z >>> 1) ^ -(z & 1)) + wv + n - nw) | 0;
        o += os;
        q[r + i] = wv; out[o] = off + wv * sc;
        nw = n;
      }
      continue;
    }
    const u2 = u - w;
    let ww = wv, n = q[u + 1];
    z = src[r + 1];
    wv = (((z >>> 1) ^ -(z & 1)) + wv + n - nw) | 0; // i = 1: Lorenzo
    o += os;
    q[r + 1] = wv; out[o] = off + wv * sc;
    nw = n; n = q[u + 2];
    for (let i = 2; i < w - 1; i++) { // interior: the 6-neighbour predictor
      const ne = q[u + i + 1], nn = q[u2 + i];
      z = src[r + i];
      const res = (z >>> 1) ^ -(z & 1);
      // 32 first (so no product's -0 reaches the JIT as a possible result: it keeps int32
      // arithmetic) and the W term last (the only one that depends on the previous sample).
      // s is only compared and shifted, so it stays an int32; the rare sum outside int32 is
      // recomputed in float64.
      const s = (32 + cN * n + cNW * nw + cNE * ne + cWW * ww + cNN * nn) + cW * wv;
      const p = s >= -2147483648 && s <= 2147483647 ? s >> 6 : predictWide(coef, wv, n, nw, ne, ww, nn);
      ww = wv;
      wv = (res + p) | 0;
      o += os;
      q[r + i] = wv; out[o] = off + wv * sc;
      nw = n; n = ne;
    }
    z = src[r + w - 1];
    wv = (((z >>> 1) ^ -(z & 1)) + wv + n - nw) | 0; // i = w - 1: Lorenzo
    o += os;
    q[r + w - 1] = wv; out[o] = off + wv * sc;
  }
}

function decodeRaw(t, bytes, start, dst) {
  const w = t.width, h = t.height;
  if (t.payloadLen !== w * h * 4) throw fail('corrupt', `raw payload ${t.payloadLen} bytes for ${w * h} samples`);
  const out = dst.array, os = dst.stride;
  if (os === 1 && dst.rowStride === w && new Uint8Array(new Uint16Array([1]).buffer)[0] === 1) { // little-endian, contiguous
    new Uint8Array(out.buffer, out.byteOffset + 4 * dst.offset, w * h * 4).set(bytes.subarray(start, start + t.payloadLen));
    return;
  }
  // Strided or big-endian: as 32-bit patterns (a float round trip could change a NaN's bits).
  const dv = new DataView(bytes.buffer, bytes.byteOffset + start, t.payloadLen);
  const bits = new Uint32Array(out.buffer, out.byteOffset, out.length);
  for (let j = 0, k = 0; j < h; j++) {
    for (let i = 0, o = dst.offset + j * dst.rowStride; i < w; i++, k++, o += os) bits[o] = dv.getUint32(4 * k, true);
  }
}

// The 16-byte prefix of a lossy payload (§5.1), validated; src = the entropy-coded stream.
function readLossyPrefix(t, bytes, start) {
  const count = t.width * t.height;
  if (t.payloadLen < LOSSY_PREFIX) throw fail('corrupt', 'lossy payload shorter than its prefix');
  const dv = new DataView(bytes.buffer, bytes.byteOffset + start, LOSSY_PREFIX);
  const escWidth = bytes[start];
  const escCount = dv.getUint32(4, true);
  if (escWidth > 4 || bytes[start + 1] || dv.getUint16(2, true) || dv.getUint16(14, true)) throw fail('corrupt', 'lossy prefix');
  if (escCount > count || (escCount === 0) !== (escWidth === 0)) throw fail('corrupt', 'esc_count/esc_width');
  const coef = new Int8Array(6);
  for (let i = 0; i < 6; i++) coef[i] = dv.getInt8(8 + i);
  const src = bytes.subarray(start + LOSSY_PREFIX, start + t.payloadLen);
  return { escWidth, escCount, coef, src, n: count + escCount * escWidth };
}

// ---- parts: one tick's frame in several messages (PROTOCOL.md §3.4) ----

export const FRAME_FLAG_RENDERED = 1;
export const FRAME_FLAG_PART = 2;

/**
 * Joins the parts of a tick's frame (subscribe "parts": true): push() every binary
 * message; it returns the whole frame (the first part's header with the tiles of all
 * the parts counted and bit 1 cleared, then their tiles in order) once the last part
 * is in, a message that is not a part as it is, and null while parts are held. A
 * part of another seq than the held ones drops them (a server never sends that).
 */
export class FrameJoiner {
  constructor() { this.parts = []; this.seq = 0n; this.joined = 0; /* frames that came in 2 or more parts */ }
  push(arrayBuffer) {
    const bytes = asBytes(arrayBuffer);
    const h = readFrameHeader(bytes);
    const seq = new DataView(bytes.buffer, bytes.byteOffset).getBigUint64(8, true);
    if (this.parts.length && seq !== this.seq) this.parts = [];
    if (h.flags & FRAME_FLAG_PART) {
      this.seq = seq;
      this.parts.push({ bytes, h });
      return null;
    }
    if (!this.parts.length) return arrayBuffer;
    const parts = [...this.parts, { bytes, h }];
    this.parts = [];
    this.joined++;
    const first = parts[0];
    const tiles = parts.reduce((n, p) => n + p.h.tileCount, 0);
    if (tiles > 0xffff) throw fail('corrupt', `${tiles} tiles in the parts of one frame`);
    const size = first.h.headerSize + parts.reduce((n, p) => n + p.bytes.length - p.h.headerSize, 0);
    const out = new Uint8Array(size);
    out.set(first.bytes.subarray(0, first.h.headerSize));
    let at = first.h.headerSize;
    for (const p of parts) { out.set(p.bytes.subarray(p.h.headerSize), at); at += p.bytes.length - p.h.headerSize; }
    const dv = new DataView(out.buffer);
    dv.setUint16(36, tiles, true);
    dv.setUint16(38, first.h.flags & ~FRAME_FLAG_PART, true);
    return out.buffer;
  }
}

// ---- codec 3: temporal prediction (PROTOCOL.md §5.6-5.8) ----

/** The references of predicted tiles: the codes of the last frames of every tile. One per stream. */
export class DecoderState {
  constructor() { this.tiles = new Map(); this.spare = []; }
  /** Forget every reference (e.g. after resubscribing); predicted tiles then fail until the next keyframe. */
  reset() { this.tiles.clear(); this.spare.length = 0; }
}
// Code arrays of references that left the history, reused for the next tiles' codes: no
// allocation per tile and frame in a steady stream (decodes of one state never overlap).
function takeCodes(state, count) {
  const spare = state && state.spare;
  while (spare && spare.length) {
    const c = spare.pop();
    if (c.length === count) return c;
  }
  return new Int32Array(count);
}
// A tile's identity for references: cascade (tile flags bits 0-1, PROTOCOL.md §3.2) included.
const tileKey = (h, t) => `${t.field}/${t.lod}/${t.flags & 3}/${t.tileX}/${t.tileZ}/${h.n}/${h.tileSize}`;
// Coefficients a tile of each depth may use (bit k = coefficient k: d1, d2, d3, L(d1), L(d2), L(d3), L(q1)).
const COEF_MASK = [0, 0x40, 0x49, 0x5b, 0x7f];
const TEMPORAL_COEFS = 7;

// The 40-byte prefix of a codec 3 payload, validated, and its references looked up (in this order).
function readTemporalPrefix(h, t, bytes, start, state) {
  const count = t.width * t.height, npairs = (count + 1) >> 1;
  if (t.payloadLen < TEMPORAL_PREFIX) throw fail('corrupt', 'temporal payload shorter than its prefix');
  const dv = new DataView(bytes.buffer, bytes.byteOffset + start, TEMPORAL_PREFIX);
  const depth = bytes[start], packing = bytes[start + 1], escWidth = bytes[start + 2];
  const escCount = dv.getUint32(4, true), pairEsc = dv.getUint32(8, true);
  const refSeq = dv.getBigUint64(16, true);
  const coef = [];
  for (let k = 0; k < TEMPORAL_COEFS; k++) coef.push(dv.getInt16(24 + 2 * k, true));
  let zero = bytes[start + 3] | dv.getUint32(12, true);
  for (let k = 24 + 2 * TEMPORAL_COEFS; k < TEMPORAL_PREFIX; k++) zero |= bytes[start + k];
  if (depth < 1 || depth > MAX_DEPTH || packing > 1 || escWidth > 4 || zero) throw fail('corrupt', 'temporal prefix');
  coef.forEach((c, k) => { if (c && !(COEF_MASK[depth] & (1 << k))) throw fail('corrupt', `coefficient ${k} at depth ${depth}`); });
  if ((escCount === 0) !== (escWidth === 0)) throw fail('corrupt', 'esc_count/esc_width');
  let n;
  if (packing === 0) {
    if (pairEsc || escCount > count) throw fail('corrupt', 'escape counts');
    n = count + escCount * escWidth;
  } else {
    if (pairEsc > npairs || escCount > 2 * pairEsc) throw fail('corrupt', 'escape counts');
    n = npairs + 2 * pairEsc + escCount * escWidth;
  }
  if (!state) throw fail('reference', 'a predicted tile (codec 3) needs decodeFrame(buf, { state })');
  const slots = state.tiles.get(tileKey(h, t)) || [];
  const refs = [];
  for (let i = 0; i < depth; i++) {
    const want = refSeq - BigInt(i);
    const s = slots.find((x) => x.seq === want && x.offset === t.offset && x.scale === t.scale && x.bound === t.bound
      && x.codes.length === count);
    if (!s) throw fail('reference', `tile ${tileKey(h, t)}: reference frame ${want} missing or on another grid`);
    refs.push(s);
  }
  return { depth, packing, escWidth, escCount, pairEsc, coef, refs, n, src: bytes.subarray(start + TEMPORAL_PREFIX, start + t.payloadLen) };
}

// Pair packing: one byte per two samples (15*z1 + z2 when both are below 15, 255 = escaped pair).
// Scratch arrays are reused (reconstructTemporal never awaits, so tiles cannot interleave here).
let pairScratch = new Int32Array(4097);
let yScratch = new Int32Array(64);
const PAIR_HI = new Int32Array(256), PAIR_LO = new Int32Array(256); // b -> (z1, z2); 255 marks an escape
for (let b = 0; b < 256; b++) {
  PAIR_HI[b] = b < PAIR_LIMIT * PAIR_LIMIT ? (b / PAIR_LIMIT) | 0 : -1;
  PAIR_LO[b] = b < PAIR_LIMIT * PAIR_LIMIT ? b % PAIR_LIMIT : -1;
}
function unpackPairs(packed, count, pairEsc, escCount, escWidth) {
  const npairs = (count + 1) >> 1, ny = 2 * pairEsc;
  if (yScratch.length < ny) yScratch = new Int32Array(ny);
  const y = yScratch;
  unpackEscapes(y, packed.subarray(npairs), ny, escCount, escWidth);
  if (pairScratch.length < 2 * npairs) pairScratch = new Int32Array(2 * npairs);
  const zz = pairScratch;
  let e = 0;
  for (let p = 0, k = 0; p < npairs; p++, k += 2) {
    const b = packed[p];
    const hi = PAIR_HI[b];
    if (hi >= 0) {
      zz[k] = hi;
      zz[k + 1] = PAIR_LO[b];
    } else if (b === 255 && e < pairEsc) {
      zz[k] = y[2 * e];
      zz[k + 1] = y[2 * e + 1];
      e++;
    } else {
      throw fail('corrupt', `pair byte ${b}`);
    }
  }
  if (e !== pairEsc) throw fail('corrupt', 'fewer escaped pairs than pair_esc_count');
  if (count & 1 && zz[count] !== 0) throw fail('corrupt', 'padding value of an odd tile is not 0');
  return zz;
}

// Predictions from the references (no sample of this frame is needed), plus the residuals.
// S of §5.8 regrouped: S = Σ a_k·q_k + Σ b_k·L(q_k) = A + L(B), with A = Σ a_k·q_k and
// B = Σ b_k·q_k, because the clamped 5-point Laplacian is linear. The same integer: with
// |q| < 2^31 and |a|, |b| < 2^17, |A|, |B| < 2^50 and |L(B)| < 2^53, so every partial sum is
// exact in float64; one pass builds A and B, a second applies L to B, with no Laplacian per
// reference (nothing to compute or keep per frame). `| 0` wraps the code to int32 as C does.
let aScratch = new Float64Array(4096), bScratch = new Float64Array(4096);
function reconstructTemporal(t, packed, l, state, dst) {
  const w = t.width, h = t.height, count = w * h;
  if (temporalKernel && l.packing === 1 && l.pairEsc === 0) { // the kernel unpacks the pairs too
    const q = takeCodes(state, count);
    if (temporalKernel(l.refs.map((r) => r.codes), l.depth, packed, w, h, l.coef, q, dst, t.offset, t.scale, true)) return q;
    if (state) state.spare.push(q);
  }
  let zz;
  if (l.packing === 1) zz = unpackPairs(packed, count, l.pairEsc, l.escCount, l.escWidth);
  else if (l.escCount === 0) zz = packed;
  else { zz = new Int32Array(count); unpackEscapes(zz, packed, count, l.escCount, l.escWidth); }
  const q = takeCodes(state, count), out = dst.array, os = dst.stride, ors = dst.rowStride;
  const [c0, c1, c2, c3, c4, c5, c6] = l.coef, depth = l.depth;
  if (temporalKernel && temporalKernel(l.refs.map((r) => r.codes), depth, zz, w, h, l.coef, q, dst, t.offset, t.scale)) return q;
  const a1 = c0, a2 = c1 - c0, a3 = c2 - c1, a4 = -c2, b1 = c3 + c6, b2 = c4 - c3, b3 = c5 - c4, b4 = -c5;
  // Missing references (depth < 4) stand in as q1: their coefficients are 0.
  const ref = (k) => l.refs[k < depth ? k : 0].codes;
  const q1 = ref(0), q2 = ref(1), q3 = ref(2), q4 = ref(3);
  const off = t.offset, sc = t.scale;
  if (!(c0 | c1 | c2 | c3 | c4 | c5 | c6)) { // all coefficients 0 (a still tile): S = 0, P = q1
    for (let j = 0, k = 0; j < h; j++) {
      for (let i = 0, o = dst.offset + j * ors; i < w; i++, k++, o += os) {
        const z = zz[k], v = (q1[k] + ((z >>> 1) ^ -(z & 1))) | 0;
        q[k] = v; out[o] = off + v * sc;
      }
    }
    return q;
  }
  if (aScratch.length < count) { aScratch = new Float64Array(count); bScratch = new Float64Array(count); }
  const A = aScratch, B = bScratch;
  for (let k = 0; k < count; k++) {
    const x1 = q1[k], x2 = q2[k], x3 = q3[k], x4 = q4[k];
    A[k] = a1 * x1 + a2 * x2 + a3 * x3 + a4 * x4;
    B[k] = b1 * x1 + b2 * x2 + b3 * x3 + b4 * x4;
  }
  const inv = 1 / 4096; // exact: a power of two
  for (let j = 0; j < h; j++) {
    const r = j * w, up = (j > 0 ? j - 1 : 0) * w, dn = (j + 1 < h ? j + 1 : h - 1) * w;
    let o = dst.offset + j * ors;
    if (w === 1) {
      const S = A[r] + B[up] + B[dn] - 2 * B[r], z = zz[r];
      const v = (q1[r] + Math.floor((S + 2048) * inv) + ((z >>> 1) ^ -(z & 1))) | 0;
      q[r] = v; out[o] = off + v * sc;
      continue;
    }
    // i = 0: the W neighbour clamps to the sample itself.
    let z = zz[r];
    let S = A[r] + B[r + 1] + B[up] + B[dn] - 3 * B[r];
    let v = (q1[r] + Math.floor((S + 2048) * inv) + ((z >>> 1) ^ -(z & 1))) | 0;
    q[r] = v; out[o] = off + v * sc;
    const end = r + w - 1, du = up - r, dd = dn - r;
    for (let k = r + 1; k < end; k++) {
      z = zz[k];
      S = A[k] + B[k - 1] + B[k + 1] + B[k + du] + B[k + dd] - 4 * B[k];
      v = (q1[k] + Math.floor((S + 2048) * inv) + ((z >>> 1) ^ -(z & 1))) | 0;
      o += os;
      q[k] = v; out[o] = off + v * sc;
    }
    z = zz[end]; // i = w - 1: the E neighbour clamps
    S = A[end] + B[end - 1] + B[end + du] + B[end + dd] - 3 * B[end];
    v = (q1[end] + Math.floor((S + 2048) * inv) + ((z >>> 1) ^ -(z & 1))) | 0;
    q[end] = v; out[o + os] = off + v * sc;
  }
  return q;
}

// Where a tile's samples go: sample (i, j) to dst.array[dst.offset + j * dst.rowStride + i * dst.stride].
// Without a caller's target, a new Float32Array of the tile (the returned tile's `samples`).
const ownArray = (t) => ({ array: new Float32Array(t.width * t.height), offset: 0, stride: 1, rowStride: t.width });

// One tile, synchronously; inflate = a synchronous raw-DEFLATE inflater. Writes the samples to
// dst; returns the tile's int32 codes when a state keeps them, else null.
function decodeTileSync(h, t, bytes, start, inflate, state, dst) {
  if (t.codec === CODEC_RAW_F32) { decodeRaw(t, bytes, start, dst); return null; }
  if (t.codec === CODEC_TEMPORAL) {
    const l = readTemporalPrefix(h, t, bytes, start, state);
    return reconstructTemporal(t, inflate(l.src, l.n), l, state, dst);
  }
  const l = readLossyPrefix(t, bytes, start);
  const packed = t.codec === CODEC_QUANT_LORENZO ? inflate(l.src, l.n) : unzstd(l.src, l.n);
  reconstruct(t, packed, l.escCount, l.escWidth, l.coef, dst);
  return state ? copyCodes(state, t.width * t.height) : null;
}

// One tile with DecompressionStream for codec 1 and 3 (the other codecs are synchronous).
async function decodeTileStream(h, t, bytes, start, state, dst) {
  if (t.codec === CODEC_TEMPORAL) {
    const l = readTemporalPrefix(h, t, bytes, start, state);
    return reconstructTemporal(t, await inflateRawStream(l.src, l.n), l, state, dst);
  }
  if (t.codec !== CODEC_QUANT_LORENZO) return decodeTileSync(h, t, bytes, start, null, state, dst);
  const l = readLossyPrefix(t, bytes, start);
  reconstruct(t, await inflateRawStream(l.src, l.n), l.escCount, l.escWidth, l.coef, dst);
  return state ? copyCodes(state, t.width * t.height) : null;
}

// The codes reconstruct() left in scratch, copied into an array the state keeps.
function copyCodes(state, count) {
  const c = takeCodes(state, count);
  c.set(scratch.subarray(0, count));
  return c;
}

// After a whole frame decoded: its lossy tiles become references (at most HISTORY_SLOTS per tile;
// the oldest seq goes first).
function commitReferences(state, header, metas, decoded) {
  const seq = BigInt(header.seq);
  metas.forEach(({ t }, i) => {
    const codes = decoded[i];
    if (!codes) return;
    const key = tileKey(header, t);
    const slots = state.tiles.get(key) || [];
    if (slots.length >= HISTORY_SLOTS) {
      let oldest = 0;
      slots.forEach((s, k) => { if (s.seq < slots[oldest].seq) oldest = k; });
      state.spare.push(slots.splice(oldest, 1)[0].codes);
    }
    slots.push({ seq, offset: t.offset, scale: t.scale, bound: t.bound, codes });
    state.tiles.set(key, slots);
  });
}

/**
 * Decode a whole binary frame: {header, tiles:[{field, fieldName, lod, codec, cascade, tileX, tileZ, width, height,
 * bound, offset, scale, samples: Float32Array}]}. options.useNodeZlib = false skips node's zlib under node
 * (then DecompressionStream and any setInflateRaw() inflater are used, as in a browser: the tests cover
 * the browser paths so). options.state = a DecoderState: keeps the references predicted tiles (codec 3)
 * need; decode the frames of one stream in order with the same state. A frame that throws leaves it as it was.
 * options.target(header, tiles) (optional) places the samples where the caller wants them (e.g. straight into
 * interleaved texture arrays: no array per tile, no copy): called once the frame's headers are validated, with
 * the tiles' descriptions (as returned, without samples), it returns an array with, per tile, null (that tile
 * gets its own `samples`) or {array: Float32Array, offset, stride, rowStride}: sample (i, j) of the tile goes to
 * array[offset + j * rowStride + i * stride] (the caller keeps tiles' regions apart and in bounds). Such a
 * tile is returned with `samples: null`. A frame that throws may have written to the targets.
 */
export async function decodeFrame(arrayBuffer, options = {}) {
  const useNodeZlib = options.useNodeZlib !== false;
  const state = options.state || null;
  const bytes = asBytes(arrayBuffer);
  const header = readFrameHeader(bytes);
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  // Validate every tile header and length first, then decode the payloads.
  const metas = [];
  let pos = header.headerSize;
  for (let i = 0; i < header.tileCount; i++) {
    const t = readTileHeader(bytes, dv, pos, header);
    pos += TILE_HEADER_SIZE;
    metas.push({ t, start: pos });
    pos += t.payloadLen;
  }
  if (pos !== bytes.length) throw fail('corrupt', `${bytes.length - pos} bytes after the last tile`);
  const describe = (t) => ({
    field: t.field, fieldName: FIELD_NAMES[t.field], lod: t.lod, codec: t.codec, cascade: t.flags & 3,
    tileX: t.tileX, tileZ: t.tileZ, width: t.width, height: t.height, bound: t.bound, offset: t.offset, scale: t.scale,
  });
  const tiles = metas.map(({ t }) => describe(t));
  const wanted = options.target ? options.target(header, tiles) : null;
  metas.forEach((m, i) => {
    const d = wanted && wanted[i];
    if (d) {
      const { array, offset, stride, rowStride } = d, t = m.t;
      const last = offset + (t.height - 1) * rowStride + (t.width - 1) * stride;
      if (!(array instanceof Float32Array) || !Number.isInteger(offset) || !Number.isInteger(stride) || !Number.isInteger(rowStride)
        || offset < 0 || last >= array.length || (t.height > 1 && rowStride < 0) || stride < 0)
        throw new RangeError(`oceand decodeFrame: target of tile ${i} out of bounds`);
      m.dst = d;
      tiles[i].samples = null;
    } else {
      m.dst = ownArray(m.t);
      tiles[i].samples = m.dst.array;
    }
  });
  let codes; // per tile: its int32 codes (references for the next frames), or null
  if (nodeZlib && useNodeZlib) {
    // Synchronous: tile after tile, the first bad payload throws.
    codes = metas.map(({ t, start, dst }) => decodeTileSync(header, t, bytes, start, inflateRawNode, state, dst));
  } else if (inflateRawSync && !(haveStreams && metas.some(({ t }) => preferStream(t)))) {
    codes = metas.map(({ t, start, dst }) => decodeTileSync(header, t, bytes, start, inflateRawInstalled, state, dst));
  } else {
    // Some tiles through DecompressionStream, all in flight at once; the others synchronously.
    // The first bad payload in frame order wins.
    const decoded = await Promise.allSettled(metas.map(({ t, start, dst }) => {
      if ((t.codec === CODEC_QUANT_LORENZO || t.codec === CODEC_TEMPORAL) && (!inflateRawSync || preferStream(t)))
        return decodeTileStream(header, t, bytes, start, state, dst);
      try {
        return Promise.resolve(decodeTileSync(header, t, bytes, start, inflateRawInstalled, state, dst));
      } catch (e) {
        return Promise.reject(e);
      }
    }));
    codes = decoded.map((d) => { if (d.status === 'rejected') throw d.reason; return d.value; });
  }
  if (state) commitReferences(state, header, metas, codes);
  return { header, tiles };
}

// oc_decode.js — decoder for oceand protocol v1 binary frames (proto/PROTOCOL.md).
// ES module for browsers and node >= 20, no dependencies: codec 1 (the
// default) inflates raw DEFLATE with the platform: node's zlib when running
// under node (process.getBuiltinModule, no import, so bundlers leave it
// alone), else DecompressionStream('deflate-raw').
// Codec 2 (zstd) is optional: call setZstdDecompressor(fzstd.decompress) to
// enable it. Every length is checked before it is read; bad input throws an
// Error whose `code` is 'truncated' | 'magic' | 'version' | 'corrupt' |
// 'too_large' | 'unsupported'.

export const PROTO_VERSION = 1;
export const SUBPROTOCOL = 'oceand.v1';
export const FIELD_NAMES = Object.freeze(['height', 'dx', 'dz', 'slope_x', 'slope_z', 'jacobian']);
export const CODEC_RAW_F32 = 0;
export const CODEC_QUANT_LORENZO = 1;       // deflate-raw entropy coder (default)
export const CODEC_QUANT_LORENZO_ZSTD = 2;  // zstd entropy coder
export const FRAME_HEADER_SIZE = 48;
export const TILE_HEADER_SIZE = 40;
export const MAX_N = 2048;
export const MAX_LOD = 4;
const LOSSY_PREFIX = 16;
const nodeZlib = globalThis.process?.getBuiltinModule?.('node:zlib') ?? null;

let zstdDecompress = null;
/** Enable codec 2: fn(Uint8Array compressed, Uint8Array out) -> Uint8Array (e.g. fzstd's decompress). */
export function setZstdDecompressor(fn) { zstdDecompress = fn; }

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
  return h;
}

/** Parse and validate the 48-byte frame header only (synchronous). */
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
  if (t.codec === CODEC_QUANT_LORENZO || t.codec === CODEC_QUANT_LORENZO_ZSTD) {
    if (!Number.isFinite(t.offset) || !Number.isFinite(t.scale) || !(t.scale > 0)) throw fail('corrupt', 'offset/scale');
  } else if (t.codec !== CODEC_RAW_F32) {
    throw fail('corrupt', `codec ${t.codec}`);
  }
  if (t.payloadLen > bytes.length - pos - TILE_HEADER_SIZE) throw fail('truncated', `payload of ${t.payloadLen} bytes`);
  return t;
}

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

async function inflateRaw(src, n, useNodeZlib) {
  if (nodeZlib && useNodeZlib) return inflateRawNode(src, n);
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

const unzig = (z) => (z >>> 1) ^ -(z & 1);

// Streams A + B -> zigzag residuals -> prediction inverse (int32 wrap-around)
// -> float32(offset + q*scale). Mirrors proto/c/oc_transform.c exactly.
let scratch = new Int32Array(4096); // reused: reconstruct() never awaits, so tiles cannot interleave here

function reconstruct(t, packed, escCount, escWidth, coef) {
  const w = t.width, h = t.height, count = w * h;
  if (scratch.length < count) scratch = new Int32Array(count);
  const q = scratch;
  // Residuals: one byte each, 255 = take the next escaped value from stream B.
  if (escCount === 0) {
    for (let k = 0; k < count; k++) { const z = packed[k]; q[k] = (z >>> 1) ^ -(z & 1); }
  } else {
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
      q[k] = (z >>> 1) ^ -(z & 1);
    }
    if (e !== escCount) throw fail('corrupt', 'fewer escapes than esc_count');
  }
  // q holds residuals; integrate in place (row 0 from the left, column 0 from above, Lorenzo at the
  // borders, the 6-coefficient predictor inside).
  for (let i = 1; i < w; i++) q[i] = (q[i] + q[i - 1]) | 0;
  const cW = coef[0], cN = coef[1], cNW = coef[2], cNE = coef[3], cWW = coef[4], cNN = coef[5];
  for (let j = 1; j < h; j++) {
    const r = j * w, u = r - w, u2 = u - w;
    q[r] = (q[r] + q[u]) | 0;
    if (j < 2 || w < 4) {
      for (let i = 1; i < w; i++) q[r + i] = (q[r + i] + q[r + i - 1] + q[u + i] - q[u + i - 1]) | 0;
      continue;
    }
    let ww = q[r];
    let wv = (q[r + 1] + ww + q[u + 1] - q[u]) | 0;
    q[r + 1] = wv;
    for (let i = 2; i <= w - 2; i++) {
      // Exact: |s| < 2^41, so s is an exact double. In int32 range (always, for real data) the
      // floor division is an arithmetic shift; outside it, floor of the exact quotient, clamped.
      const s = cN * q[u + i] + cNW * q[u + i - 1] + cNE * q[u + i + 1] + cNN * q[u2 + i] + cW * wv + cWW * ww + 32;
      let p;
      if (s >= -2147483648 && s <= 2147483647) p = s >> 6;
      else p = Math.max(-2147483648, Math.min(2147483647, Math.floor(s * 0.015625)));
      ww = wv;
      wv = (q[r + i] + p) | 0;
      q[r + i] = wv;
    }
    q[r + w - 1] = (q[r + w - 1] + wv + q[u + w - 1] - q[u + w - 2]) | 0;
  }
  const out = new Float32Array(count); // the store rounds to float32, as the C cast does
  const off = t.offset, sc = t.scale;
  for (let k = 0; k < count; k++) out[k] = off + q[k] * sc;
  return out;
}

async function decodeTile(t, bytes, start, useNodeZlib) {
  const count = t.width * t.height;
  if (t.codec === CODEC_RAW_F32) {
    if (t.payloadLen !== count * 4) throw fail('corrupt', `raw payload ${t.payloadLen} bytes for ${count} samples`);
    const out = new Float32Array(count);
    new Uint8Array(out.buffer).set(bytes.subarray(start, start + t.payloadLen));
    if (new Uint8Array(new Uint16Array([1]).buffer)[0] !== 1) { // big-endian host: decode explicitly
      const dv = new DataView(bytes.buffer, bytes.byteOffset + start, t.payloadLen);
      for (let k = 0; k < count; k++) out[k] = dv.getFloat32(4 * k, true);
    }
    return out;
  }
  if (t.payloadLen < LOSSY_PREFIX) throw fail('corrupt', 'lossy payload shorter than its prefix');
  const dv = new DataView(bytes.buffer, bytes.byteOffset + start, LOSSY_PREFIX);
  const escWidth = bytes[start];
  const escCount = dv.getUint32(4, true);
  if (escWidth > 4 || bytes[start + 1] || dv.getUint16(2, true) || dv.getUint16(14, true)) throw fail('corrupt', 'lossy prefix');
  if (escCount > count || (escCount === 0) !== (escWidth === 0)) throw fail('corrupt', 'esc_count/esc_width');
  const coef = [0, 1, 2, 3, 4, 5].map((i) => dv.getInt8(8 + i));
  const src = bytes.subarray(start + LOSSY_PREFIX, start + t.payloadLen);
  const n = count + escCount * escWidth;
  const packed = t.codec === CODEC_QUANT_LORENZO ? await inflateRaw(src, n, useNodeZlib) : unzstd(src, n);
  return reconstruct(t, packed, escCount, escWidth, coef);
}

/**
 * Decode a whole binary frame: {header, tiles:[{field, fieldName, lod, codec, tileX, tileZ, width, height,
 * bound, offset, scale, samples: Float32Array}]}. options.useNodeZlib = false forces DecompressionStream
 * under node too (the tests use it to cover the browser path).
 */
export async function decodeFrame(arrayBuffer, options = {}) {
  const useNodeZlib = options.useNodeZlib !== false;
  const bytes = asBytes(arrayBuffer);
  const header = readFrameHeader(bytes);
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  // Validate every tile header and length first, then decode the payloads concurrently.
  const metas = [];
  let pos = header.headerSize;
  for (let i = 0; i < header.tileCount; i++) {
    const t = readTileHeader(bytes, dv, pos, header);
    pos += TILE_HEADER_SIZE;
    metas.push({ t, start: pos });
    pos += t.payloadLen;
  }
  if (pos !== bytes.length) throw fail('corrupt', `${bytes.length - pos} bytes after the last tile`);
  const decoded = await Promise.allSettled(metas.map(({ t, start }) => decodeTile(t, bytes, start, useNodeZlib)));
  const tiles = metas.map(({ t }, i) => {
    if (decoded[i].status === 'rejected') throw decoded[i].reason;
    return {
      field: t.field, fieldName: FIELD_NAMES[t.field], lod: t.lod, codec: t.codec,
      tileX: t.tileX, tileZ: t.tileZ, width: t.width, height: t.height,
      bound: t.bound, offset: t.offset, scale: t.scale, samples: decoded[i].value,
    };
  });
  return { header, tiles };
}

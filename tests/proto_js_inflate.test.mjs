// proto_js_inflate.test.mjs — the decoder with an installed synchronous inflater, each of the
// two web/src/worker.js wires in the browser: fflate's inflateSync (the fallback) and the
// WebAssembly one (proto/wasm/oc_inflate.c via proto/js/oc_wasm.js, build/wasm/oc_kernels.wasm:
// `make` builds it; missing, these tests fail). Each must reproduce every deflate vector bit for
// bit and reject every bad input with the listed code, like the node-zlib and
// DecompressionStream paths in tests/proto_js.test.mjs.
//   node --test tests/proto_js_inflate.test.mjs      (fflate's: skipped when web/node_modules lacks it)
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, existsSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import { dirname, join } from 'node:path';
import { createRequire } from 'node:module';
import { decodeFrame, setInflateRaw, setTemporalKernel, DecoderState } from '../proto/js/oc_decode.js';
import { mutateAndDecode } from './proto_js_mutate.mjs';
import { loadKernels } from '../proto/js/oc_wasm.js';

const root = join(dirname(fileURLToPath(import.meta.url)), '..');
const vdir = join(root, 'proto/vectors');
const manifest = JSON.parse(readFileSync(join(vdir, 'manifest.json'), 'utf8'));
const load = (name) => {
  const b = readFileSync(join(vdir, name));
  return b.buffer.slice(b.byteOffset, b.byteOffset + b.byteLength);
};
const haveFflate = existsSync(join(root, 'web/node_modules/fflate'));
const inflaters = [];
if (haveFflate) {
  const { inflateSync } = createRequire(join(root, 'web/package.json'))('fflate');
  inflaters.push({ name: 'fflate', fn: (src, out) => inflateSync(src, { out }), temporal: null });
} else {
  inflaters.push({ name: 'fflate', fn: null, skip: 'fflate not installed in web/node_modules' });
}
const kernels = await loadKernels(readFileSync(join(root, 'build/wasm/oc_kernels.wasm')));
assert.ok(kernels, 'the WebAssembly kernels load in node');
inflaters.push({ name: 'wasm', fn: kernels.inflateRaw, temporal: kernels.temporal, all: true }); // + codec 3 prediction in SIMD; every tile, as the worker
const opts = { useNodeZlib: false }; // under node, zlib would win otherwise

// A frame with a 128x128 tile (inflated by DecompressionStream when both exist) and an 8x8 one
// (by the installed inflater), built here: both must equal node zlib's decode, and a bad stream in
// either must be reported.
function mixedFrame(deflateRawSync, badTile = -1) {
  let seed = 99;
  const rnd = () => (seed = (seed * 1103515245 + 12345) >>> 0) / 2 ** 32;
  const tiles = [[128, 0], [8, 1]].map(([side, tx], i) => {
    const a = new Uint8Array(side * side);
    for (let k = 0; k < a.length; k++) a[k] = Math.floor(rnd() * rnd() * 40);
    let stream = deflateRawSync(a);
    if (i === badTile) stream = stream.subarray(0, stream.length - 3);
    const payload = Buffer.alloc(16 + stream.length);
    Buffer.from([45, 30, -12, 8, -5, -2]).copy(payload, 8); // signed coefficients
    payload.set(stream, 16);
    const th = Buffer.alloc(40);
    th[0] = 0; th[2] = 1; // height, codec 1
    th.writeUInt16LE(tx, 4); th.writeUInt16LE(side, 8); th.writeUInt16LE(side, 10);
    th.writeFloatLE(0.01, 12); th.writeDoubleLE(0.25, 16); th.writeDoubleLE(0.0199, 24);
    th.writeUInt32LE(payload.length, 32);
    return Buffer.concat([th, payload]);
  });
  // n = 256, tile_size 128; the 8x8 tile is tile (1, 0) at lod 4.
  tiles[1][1] = 4;
  const fh = Buffer.alloc(48);
  fh.write('OCNF', 0, 'latin1'); fh.writeUInt16LE(1, 4); fh.writeUInt16LE(48, 6);
  fh.writeUInt16LE(256, 28); fh.writeUInt16LE(128, 30); fh.writeFloatLE(256, 32); fh.writeUInt16LE(2, 36);
  const b = Buffer.concat([fh, ...tiles]);
  return b.buffer.slice(b.byteOffset, b.byteOffset + b.length);
}

for (const inf of inflaters) {
for (const v of manifest.vectors.filter((x) => x.tiles.every((t) => t.codec !== 2))) {
  test(`vector ${v.name} (setInflateRaw + ${inf.name})`, { skip: inf.skip }, async () => {
    setInflateRaw(inf.fn, { allTiles: inf.all });
    setTemporalKernel(inf.temporal);
    const frame = await decodeFrame(load(v.file), opts);
    const expected = new Uint32Array(load(v.expected));
    assert.equal(frame.tiles.length, v.tiles.length);
    frame.tiles.forEach((t, i) => {
      const off = v.tiles[i].sampleOffset;
      assert.deepEqual(new Uint32Array(t.samples.buffer, t.samples.byteOffset, t.samples.length),
        expected.subarray(off, off + t.samples.length), `tile ${i}: float32 bits`);
    });
  });
}

for (const b of manifest.bad) {
  test(`bad input ${b.name} -> ${b.error} (setInflateRaw + ${inf.name})`, { skip: inf.skip }, async () => {
    setInflateRaw(inf.fn, { allTiles: inf.all });
    setTemporalKernel(inf.temporal);
    await assert.rejects(decodeFrame(load(b.file), opts), (e) => {
      assert.equal(e.code, b.error, e.message);
      return true;
    });
  });
}

test(`deflate streams that end early or run long are corrupt (setInflateRaw + ${inf.name})`, { skip: inf.skip }, async () => {
    setInflateRaw(inf.fn, { allTiles: inf.all });
    setTemporalKernel(inf.temporal);
  const v = manifest.vectors.find((x) => x.name === 'v03_height_1mm');
  const raw = new Uint8Array(load(v.file));
  const dv = new DataView(raw.buffer);
  const { deflateRawSync } = await import('node:zlib');
  // Re-encode tile 0's stream with one byte more or less of content, keeping the frame consistent.
  const start = 48 + 40, len = dv.getUint32(48 + 32, true);
  const { inflateRawSync } = await import('node:zlib');
  const content = inflateRawSync(raw.subarray(start + 16, start + len));
  for (const c of [content.subarray(0, content.length - 1), Buffer.concat([content, Buffer.from([0])])]) {
    const stream = deflateRawSync(c);
    const frame = new Uint8Array(raw.length - (len - 16) + stream.length);
    frame.set(raw.subarray(0, start + 16));
    frame.set(stream, start + 16);
    frame.set(raw.subarray(start + len), start + 16 + stream.length);
    new DataView(frame.buffer).setUint32(48 + 32, 16 + stream.length, true);
    await assert.rejects(decodeFrame(frame.buffer, opts), (e) => e.code === 'corrupt');
    await assert.rejects(decodeFrame(frame.buffer), (e) => e.code === 'corrupt'); // node zlib agrees
  }
});

test(`large tiles via DecompressionStream (${inf.name}: ${inf.all ? "the inflater, allTiles" : "streams"}), small ones via the installed inflater, same bits`, { skip: inf.skip }, async () => {
    setInflateRaw(inf.fn, { allTiles: inf.all });
    setTemporalKernel(inf.temporal);
  const { deflateRawSync } = await import('node:zlib');
  const buf = mixedFrame(deflateRawSync);
  const want = await decodeFrame(buf); // node zlib
  const got = await decodeFrame(buf, opts);
  assert.deepEqual(got.tiles.map((t) => t.width), [128, 8]);
  got.tiles.forEach((t, i) => assert.deepEqual(new Uint32Array(t.samples.buffer), new Uint32Array(want.tiles[i].samples.buffer)));
  for (const bad of [0, 1]) await assert.rejects(decodeFrame(mixedFrame(deflateRawSync, bad), opts), (e) => e.code === 'corrupt');
});

test(`random truncations and bit flips are rejected or decode (setInflateRaw + ${inf.name})`, { skip: inf.skip }, async () => {
    setInflateRaw(inf.fn, { allTiles: inf.all });
    setTemporalKernel(inf.temporal);
  const frame = load(manifest.vectors.find((v) => v.name === 'v03_height_1mm').file);
  await mutateAndDecode(frame, 777, () => opts);
});

// Temporal streams (codec 3) through the installed inflater: frames in order, one DecoderState.
for (const st of manifest.streams) {
  test(`stream ${st.name} (setInflateRaw + ${inf.name})`, { skip: inf.skip }, async () => {
    setInflateRaw(inf.fn, { allTiles: inf.all });
    setTemporalKernel(inf.temporal);
    const state = new DecoderState();
    for (const [i, f] of st.frames.entries()) {
      if (f.error) {
        await assert.rejects(decodeFrame(load(f.file), { ...opts, state }), (e) => e.code === f.error);
        continue;
      }
      const frame = await decodeFrame(load(f.file), { ...opts, state });
      const expected = new Uint32Array(load(f.expected));
      let k = 0;
      for (const t of frame.tiles) {
        assert.deepEqual(new Uint32Array(t.samples.buffer, t.samples.byteOffset, t.samples.length),
          expected.subarray(k, k + t.samples.length), `frame ${i}: float32 bits`);
        k += t.samples.length;
      }
      assert.equal(k, expected.length);
    }
  });
}
}

// The SIMD prediction kernel against §5.8 computed here in BigInt (exact), on random tiles of
// every depth and small sizes (edge columns and rows, w = 1), and its refusal beyond its bound.
test('wasm temporal kernel = §5.8 in BigInt; refuses codes beyond its int32 bound', () => {
  let seed = 7;
  const rnd = () => (seed = (seed * 1103515245 + 12345) >>> 0) / 2 ** 32;
  const ri = (lo, hi) => lo + Math.floor(rnd() * (hi - lo + 1));
  const MASK = [0, 0x40, 0x49, 0x5b, 0x7f];
  for (let trial = 0; trial < 200; trial++) {
    const w = [1, 2, 3, 5, 8, 16][trial % 6], h = ri(1, 6), count = w * h, depth = ri(1, 4);
    const big = trial % 10 === 9; // codes near 2^30: beyond the bound
    const refs = Array.from({ length: depth }, () => Int32Array.from({ length: count }, () => (big ? ri(-(2 ** 30), 2 ** 30) : ri(-3000, 3000))));
    const coef = Array.from({ length: 7 }, (_, k) => (MASK[depth] & (1 << k) ? ri(-9000, 9000) : 0));
    const zz = Uint32Array.from({ length: count }, () => (rnd() < 0.9 ? ri(0, 14) : ri(0, 2 ** 32 - 1)));
    const offset = rnd() * 2 - 1, scale = 0.0199;
    const q = new Int32Array(count), out = new Float32Array(4 * count);
    const ok = kernels.temporal(refs, depth, new Int32Array(zz.buffer), w, h, coef, q, { array: out, offset: 1, stride: 4, rowStride: 4 * w }, offset, scale);
    if (big) { assert.equal(ok, false, `trial ${trial}: codes ~2^30 must be refused`); continue; }
    assert.equal(ok, true);
    const R = (k) => refs[k < depth ? k : 0];
    const L = (a, i, j) => {
      const at = (ii, jj) => BigInt(a[Math.min(h - 1, Math.max(0, jj)) * w + Math.min(w - 1, Math.max(0, ii))]);
      return at(i - 1, j) + at(i + 1, j) + at(i, j - 1) + at(i, j + 1) - 4n * at(i, j);
    };
    for (let j = 0; j < h; j++) for (let i = 0; i < w; i++) {
      const k = j * w + i, c = coef.map(BigInt), x = [0, 1, 2, 3].map((m) => BigInt(R(m)[k]));
      const l = [0, 1, 2, 3].map((m) => L(R(m), i, j));
      const S = c[0] * (x[0] - x[1]) + c[1] * (x[1] - x[2]) + c[2] * (x[2] - x[3]) + c[3] * (l[0] - l[1])
        + c[4] * (l[1] - l[2]) + c[5] * (l[2] - l[3]) + c[6] * l[0];
      const num = S + 2048n, fl = num >= 0n ? num / 4096n : -((-num + 4095n) / 4096n);
      const r = BigInt((zz[k] >>> 1) ^ -(zz[k] & 1));
      const v = Number(BigInt.asIntN(32, x[0] + fl + r));
      assert.equal(q[k], v, `trial ${trial} sample (${i}, ${j})`);
      assert.equal(out[1 + 4 * k], Math.fround(offset + v * scale));
    }
  }
});

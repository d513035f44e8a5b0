// bench_decode.mjs — JavaScript decode throughput (node), one JSON line per frame file.
//   node proto/js/bench_decode.mjs [DIR]   (DIR = frames written by `bench_codec --frames DIR`)
// dec_MBs = decoded float32 bytes per second of wall time (median of repetitions);
// dec_MBs_cpu = the same per second of process CPU time (mean), steadier on a shared machine.
// Codec 1 frames are measured with node's zlib and, when fflate is installed in
// web/node_modules, the way the browser client decodes: fflate's inflateSync through
// setInflateRaw() for tiles below 128x128 samples, DecompressionStream for larger ones
// ('fflate+streams'). Codec 2 (zstd) frames are measured only when fzstd is installed there.
// Then `codec_js_decode_frame` lines: the web client's default subscription (height, dx, dz
// at 1 cm, 64×64 tiles) joined into one frame per N, decoded with each inflater, including
// the no-dependency browser fallback (one DecompressionStream per tile).
// Last, `codec_js_decode_stream` lines: the temporal streams bench_codec wrote (stream_N*_*.frames,
// 10 s at 30 Hz of height, dx, dz at 1 cm, joined into one frame per tick), decoded in order with
// one DecoderState; ms = median per frame (predicted frames dominate), per inflater.
//   node proto/js/bench_decode.mjs --stream FILE   (FILE from record_frames.mjs: a daemon's frames with
// the web client's default subscription) instead: `codec_js_decode_recorded` lines, the stream decoded in
// order the way the web worker does (fflate + streams), whole and split by layers (cascade 0's
// height/dx/dz, foam, cascades 1-3: the same frames with only those tiles kept); cpu_ms = CPU per frame;
// once with the JavaScript path, once with the WebAssembly kernels (inflate: 'wasm').
import { readFileSync, readdirSync, existsSync } from 'node:fs';
import { join, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';
import { createRequire } from 'node:module';
import { decodeFrame, setZstdDecompressor, setInflateRaw, setTemporalKernel, DecoderState } from './oc_decode.js';
import { loadKernels } from './oc_wasm.js';

const root = join(dirname(fileURLToPath(import.meta.url)), '../..');
const streamArg = process.argv[2] === '--stream' ? process.argv[3] : null;
const dir = (!streamArg && process.argv[2]) || join(root, 'build/bench_frames');
const fzstdFrom = process.env.OCEAND_FZSTD_FROM || join(root, 'web/package.json');
let zstd = false;
try {
  setZstdDecompressor(createRequire(fzstdFrom)('fzstd').decompress);
  zstd = true;
} catch { /* codec 2 frames skipped */ }
let fflateInflate = null;
try {
  const { inflateSync } = createRequire(fzstdFrom)('fflate');
  fflateInflate = (src, out) => inflateSync(src, { out });
} catch { /* fflate runs skipped */ }
// The codec-1 inflaters: decodeFrame options + setInflateRaw() argument for each.
const inflaters = [
  { name: 'node zlib', opts: {}, fn: null },
  ...(fflateInflate ? [{ name: 'fflate+streams', opts: { useNodeZlib: false }, fn: fflateInflate }] : []),
];

// Median wall ms and mean CPU ms per decode of buf.
async function timeDecode(buf, opts, reps) {
  await decodeFrame(buf, opts); // warm-up
  const times = [];
  const cpu0 = process.cpuUsage();
  for (let r = 0; r < reps; r++) {
    const t0 = performance.now();
    await decodeFrame(buf, opts);
    times.push(performance.now() - t0);
  }
  const cpu = process.cpuUsage(cpu0);
  times.sort((x, y) => x - y);
  return { ms: times[times.length >> 1], cpuMs: (cpu.user + cpu.system) / 1e3 / reps };
}

if (streamArg) {
  await benchRecorded(streamArg);
  process.exit(0);
}
// A recorded stream (u32 LE length + frame, repeated), decoded as the web worker does, by layers.
async function benchRecorded(path) {
  const b = readFileSync(path), frames = [];
  for (let p = 0; p + 4 <= b.length; p += 4 + b.readUInt32LE(p)) frames.push(b.subarray(p + 4, p + 4 + b.readUInt32LE(p)));
  // The same frame with only the tiles keep(field, cascade) accepts.
  const only = (f, keep) => {
    const parts = [Buffer.from(f.subarray(0, f.readUInt16LE(6)))];
    let pos = f.readUInt16LE(6), n = 0;
    for (let i = 0, cnt = f.readUInt16LE(36); i < cnt; i++) {
      const len = f.readUInt32LE(pos + 32);
      if (keep(f[pos], f[pos + 3] & 3)) { parts.push(f.subarray(pos, pos + 40 + len)); n++; }
      pos += 40 + len;
    }
    const out = Buffer.concat(parts);
    out.writeUInt16LE(n, 36);
    return out.buffer.slice(out.byteOffset, out.byteOffset + out.length);
  };
  const sets = {
    all: () => true, 'height,dx,dz': (fl, c) => c === 0 && fl !== 6, foam: (fl) => fl === 6, 'cascades 1-3': (fl, c) => c > 0,
  };
  // The JavaScript path (fflate + streams) and the WebAssembly kernels (build/wasm/oc_kernels.wasm:
  // inflate + codec 3 prediction), as the web worker uses them; alternated, in one run.
  const wasmFile = join(root, 'build/wasm/oc_kernels.wasm');
  const kernels = existsSync(wasmFile) ? await loadKernels(readFileSync(wasmFile)) : null;
  const variants = [{ name: fflateInflate ? 'fflate+streams' : 'streams', inflate: fflateInflate, temporal: null }];
  if (kernels) variants.push({ name: 'wasm', inflate: kernels.inflateRaw, temporal: kernels.temporal });
  for (const [layers, keep] of Object.entries(sets)) for (const v of variants) {
    setInflateRaw(v.inflate, { allTiles: v.name === 'wasm' });
    setTemporalKernel(v.temporal);
    const fr = frames.map((f) => only(f, keep));
    const times = [];
    const cpu0 = process.cpuUsage();
    for (let rep = 0; rep < 3; rep++) {
      const state = new DecoderState();
      for (const f of fr) {
        const t0 = performance.now();
        await decodeFrame(f, { state, useNodeZlib: false });
        if (rep) times.push(performance.now() - t0);
      }
    }
    const cpu = process.cpuUsage(cpu0);
    times.sort((x, y) => x - y);
    console.log(JSON.stringify({
      bench: 'codec_js_decode_recorded', file: path.split('/').pop(), layers, frames: fr.length,
      kB_per_frame: +(fr.reduce((c, f) => c + f.byteLength, 0) / fr.length / 1e3).toFixed(1),
      inflate: v.name,
      ms: +times[times.length >> 1].toFixed(2), cpu_ms: +((cpu.user + cpu.system) / 1e3 / (3 * fr.length)).toFixed(2),
    }));
  }
  setInflateRaw(null);
  setTemporalKernel(null);
}

if (!existsSync(dir)) {
  console.error(`bench_decode: no frames in ${dir} (run bench_codec --frames ${dir})`);
  process.exit(1);
}
const files = readdirSync(dir).filter((n) => n.endsWith('.bin')).sort();
for (const f of files) {
  const [, n, field, bound, codec, tile] = f.match(/^N(\d+)_(\w+?)_([\d.e-]+)_c(\d)_t(\d+)\.bin$/) || [];
  if (!n || (codec === '2' && !zstd)) continue;
  const b = readFileSync(join(dir, f));
  const buf = b.buffer.slice(b.byteOffset, b.byteOffset + b.byteLength);
  let samples = 0;
  for (const t of (await decodeFrame(buf)).tiles) samples += t.samples.length;
  const reps = Number(n) >= 512 ? 25 : 60;
  for (const inf of codec === '1' ? inflaters : [{ name: 'fzstd', opts: {}, fn: null }]) {
    setInflateRaw(inf.fn);
    const { ms, cpuMs } = await timeDecode(buf, inf.opts, reps);
    console.log(JSON.stringify({
      bench: 'codec_js_decode', N: Number(n), field, bound: Number(bound), codec: Number(codec), tile: Number(tile),
      entropy: codec === '1' ? `deflate-raw (${inf.name})` : 'zstd (fzstd)',
      bytes: b.length, dec_MBs: Math.round((samples * 4) / 1e3 / ms), ms: Number(ms.toFixed(3)),
      dec_MBs_cpu: Math.round((samples * 4) / 1e3 / cpuMs),
    }));
  }
}

// One frame holding several single-field frames' tiles (same n, tile_size; header of the first).
function joinFrames(bufs) {
  const head = bufs[0].subarray(0, bufs[0].readUInt16LE(6));
  const out = Buffer.concat([head, ...bufs.map((b) => b.subarray(b.readUInt16LE(6)))]);
  out.writeUInt16LE(bufs.reduce((c, b) => c + b.readUInt16LE(36), 0), 36);
  return out.buffer.slice(out.byteOffset, out.byteOffset + out.length);
}
for (const n of [256, 512]) {
  const names = ['height', 'dx', 'dz'].map((fld) => `N${n}_${fld}_0.01_c1_t64.bin`);
  if (!names.every((f) => files.includes(f))) continue;
  const buf = joinFrames(names.map((f) => readFileSync(join(dir, f))));
  const stream = { name: 'DecompressionStream', opts: { useNodeZlib: false }, fn: null };
  for (const inf of [...inflaters, stream]) {
    setInflateRaw(inf.fn);
    const { ms, cpuMs } = await timeDecode(buf, inf.opts, n >= 512 ? 15 : 40);
    console.log(JSON.stringify({
      bench: 'codec_js_decode_frame', N: n, fields: 'height,dx,dz', bound: 0.01, tile: 64, codec: 1,
      inflate: inf.name, bytes: buf.byteLength, ms: Number(ms.toFixed(2)), cpu_ms: Number(cpuMs.toFixed(2)),
    }));
  }
}
// Temporal streams: one frame per tick holding height, dx and dz (the web client's default layers).
function readFrames(path) {
  const b = readFileSync(path), out = [];
  for (let p = 0; p + 4 <= b.length;) {
    const len = b.readUInt32LE(p);
    out.push(b.subarray(p + 4, p + 4 + len));
    p += 4 + len;
  }
  return out;
}
for (const n of [256, 512]) {
  const names = ['height', 'dx', 'dz'].map((fld) => readdirSync(dir).find((f) => f.startsWith(`stream_N${n}_${fld}_0.01_`)));
  if (!names.every(Boolean)) continue;
  const perField = names.map((f) => readFrames(join(dir, f)));
  const ticks = perField[0].map((_, k) => joinFrames(perField.map((fr) => fr[k])));
  const bytes = ticks.reduce((c, t) => c + t.byteLength, 0);
  const stream = { name: 'DecompressionStream', opts: { useNodeZlib: false }, fn: null };
  for (const inf of [...inflaters, stream]) {
    setInflateRaw(inf.fn);
    const times = [];
    const cpu0 = process.cpuUsage();
    for (let rep = 0; rep < 2; rep++) {
      const state = new DecoderState();
      for (const t of ticks) {
        const t0 = performance.now();
        await decodeFrame(t, { ...inf.opts, state });
        if (rep) times.push(performance.now() - t0);
      }
    }
    const cpu = process.cpuUsage(cpu0);
    times.sort((x, y) => x - y);
    console.log(JSON.stringify({
      bench: 'codec_js_decode_stream', N: n, fields: 'height,dx,dz', bound: 0.01, codec: 3, inflate: inf.name,
      frames: ticks.length, mbytes_per_s_30hz: Number((bytes / ticks.length * 30 / 1e6).toFixed(3)),
      ms: Number(times[times.length >> 1].toFixed(2)), cpu_ms: Number(((cpu.user + cpu.system) / 1e3 / (2 * ticks.length)).toFixed(2)),
    }));
  }
}
setInflateRaw(null);

// bench_decode.mjs — JavaScript decode throughput (node), one JSON line per frame file.
//   node proto/js/bench_decode.mjs [DIR]   (DIR = frames written by `bench_codec --frames DIR`)
// dec_MBs = decoded float32 bytes per second of wall time (median of repetitions);
// dec_MBs_cpu = the same per second of process CPU time (mean), steadier on a shared machine.
// Codec 2 (zstd) frames are measured only when fzstd is installed in web/node_modules.
import { readFileSync, readdirSync, existsSync } from 'node:fs';
import { join, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';
import { createRequire } from 'node:module';
import { decodeFrame, setZstdDecompressor } from './oc_decode.js';

const root = join(dirname(fileURLToPath(import.meta.url)), '../..');
const dir = process.argv[2] || join(root, 'build/bench_frames');
const fzstdFrom = process.env.OCEAND_FZSTD_FROM || join(root, 'web/package.json');
let zstd = false;
try {
  setZstdDecompressor(createRequire(fzstdFrom)('fzstd').decompress);
  zstd = true;
} catch { /* codec 2 frames skipped */ }

if (!existsSync(dir)) {
  console.error(`bench_decode: no frames in ${dir} (run bench_codec --frames ${dir})`);
  process.exit(1);
}
for (const f of readdirSync(dir).filter((n) => n.endsWith('.bin')).sort()) {
  const [, n, field, bound, codec, tile] = f.match(/^N(\d+)_(\w+?)_([\d.e-]+)_c(\d)_t(\d+)\.bin$/) || [];
  if (!n || (codec === '2' && !zstd)) continue;
  const b = readFileSync(join(dir, f));
  const buf = b.buffer.slice(b.byteOffset, b.byteOffset + b.byteLength);
  let samples = 0;
  for (const t of (await decodeFrame(buf)).tiles) samples += t.samples.length;
  const times = [];
  const reps = Number(n) >= 512 ? 25 : 60;
  const cpu0 = process.cpuUsage();
  for (let r = 0; r < reps; r++) {
    const t0 = performance.now();
    await decodeFrame(buf);
    times.push(performance.now() - t0);
  }
  const cpu = process.cpuUsage(cpu0);
  const cpuMs = (cpu.user + cpu.system) / 1e3 / reps; // mean process CPU time per frame
  times.sort((x, y) => x - y);
  const ms = times[times.length >> 1];
  console.log(JSON.stringify({
    bench: 'codec_js_decode', N: Number(n), field, bound: Number(bound), codec: Number(codec), tile: Number(tile),
    entropy: codec === '1' ? 'deflate-raw (node zlib)' : 'zstd (fzstd)',
    bytes: b.length, dec_MBs: Math.round((samples * 4) / 1e3 / ms), ms: Number(ms.toFixed(3)),
    dec_MBs_cpu: Math.round((samples * 4) / 1e3 / cpuMs),
  }));
}

// record_frames.mjs — record a daemon's binary frames for decode benchmarks (bench_decode.mjs --stream).
//   node proto/js/record_frames.mjs ws://127.0.0.1:8080/ OUT.frames [FRAMES] [SUBSCRIBE_JSON]
// Subscribes as the web client does by default (temporal, height/dx/dz at LOD 0, cascades 1..3
// height at LOD 1 and 1 mm, foam at a 64x64 grid) unless SUBSCRIBE_JSON says otherwise, waits
// for the `subscribed` answer, then writes FRAMES (default 300) frames as u32 LE length + bytes.
import { writeFileSync } from 'node:fs';
import { createRequire } from 'node:module';
import { join, dirname } from 'node:path';
import { fileURLToPath } from 'node:url';

const root = join(dirname(fileURLToPath(import.meta.url)), '../..');
const WebSocket = createRequire(join(root, 'web/package.json'))('ws');
const [url, out, count = '300', subArg] = process.argv.slice(2);
if (!url || !out) { console.error('usage: record_frames.mjs WS_URL OUT.frames [FRAMES] [SUBSCRIBE_JSON]'); process.exit(2); }
const ws = new WebSocket(url, 'oceand.v1');
const frames = [];
let subscribed = false;
ws.on('message', (data, isBinary) => {
  if (!isBinary) {
    const msg = JSON.parse(String(data));
    if (msg.type === 'hello') {
      const n = msg.params?.resolution || 256;
      const sub = subArg ? JSON.parse(subArg) : {
        temporal: true, fields: ['height', 'dx', 'dz', 'foam'],
        field_lod: { foam: Math.max(0, Math.min(4, Math.round(Math.log2(n / 64)))) },
        ...(msg.cascade_patch_sizes ? { cascades: [1, 2, 3].map(() => ({ fields: ['height'], lod: 1, bound: 0.001 })) } : {}),
      };
      ws.send(JSON.stringify({ type: 'subscribe', id: 1, ...sub }));
    } else if (msg.type === 'subscribed') subscribed = true;
    else if (msg.type === 'error') { console.error(JSON.stringify(msg)); process.exit(1); }
    return;
  }
  if (!subscribed || frames.length >= Number(count)) return;
  frames.push(Buffer.from(data));
  if (frames.length >= Number(count)) {
    const parts = [];
    for (const f of frames) { const len = Buffer.alloc(4); len.writeUInt32LE(f.length); parts.push(len, f); }
    writeFileSync(out, Buffer.concat(parts));
    console.error(`recorded ${frames.length} frames, ${parts.reduce((c, p) => c + p.length, 0)} bytes`);
    ws.close();
  }
});
ws.on('error', (e) => { console.error(e.message); process.exit(1); });

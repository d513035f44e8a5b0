// bench-web: per-frame decode (worker: proto/js decodeFrame, which writes the samples straight
// into the texture arrays; `assemble_ms_median` is the layout of those arrays alone) + upload
// (float textures, waited for with gl.finish) in headless chromium, for N=256 and N=512 with
// the web client's default subscription, temporal (codec 3, the client's default) and
// intra-only (?temporal=0). The default subscription (printed in each row, as the server
// answered it): height, dx, dz at LOD 0 and 1 cm; foam at a 64x64 grid (LOD 2 at N=256);
// cascades 1..(cascades-1) height at LOD 1 and 1 mm (the daemon's default: 3 cascades). At
// N=256 a third row per codec, "layers":"base", is the page with ?cascades=0&foam=0 (height,
// dx, dz only), to show what the cascades and foam cost. One JSON line per row, medians.
//   node bench/web_bench.mjs --oceand build/oceand --web-root build/web [--seconds 8] [--sizes 256,512]
import { loadavg } from 'node:os';
import { parseArgs, freePort, startServer, launchBrowser, waitFor } from '../tests/web/harness.mjs';

const args = parseArgs(process.argv, { oceand: 'build/oceand', webRoot: 'build/web', seconds: '8', sizes: '256,512', fake: false });
const median = (a) => { const s = [...a].sort((x, y) => x - y); return s.length ? s[s.length >> 1] : null; };
// The subscription in force (the server's `subscribed`), in one line.
function describe(sub) {
  if (!sub) return 'server default';
  let d = `${sub.fields.join(',')} lod${sub.lod} bound${sub.bound}`;
  if (sub.field_lod) d += ` (${Object.entries(sub.field_lod).map(([f, l]) => `${f} lod${l}`).join(', ')})`;
  (sub.cascades || []).forEach((c, i) => { if (c && c.fields && c.fields.length) d += `; cascade ${i + 1}: ${c.fields.join(',')} lod${c.lod} bound${c.bound}`; });
  return d + (sub.temporal ? '; temporal' : '');
}
const browser = await launchBrowser();
let status = 0;
try {
  const runs = [];
  for (const n of args.sizes.split(',').map(Number)) for (const codec of ['temporal', 'intra']) {
    runs.push({ n, codec, layers: 'default' });
    if (n === 256) runs.push({ n, codec, layers: 'base' });
  }
  for (const { n, codec, layers } of runs) {
    const port = await freePort();
    const server = await startServer({ oceand: args.oceand, webRoot: args.webRoot, port, fake: args.fake, extra: ['--resolution', String(n)] });
    try {
      const page = await browser.newPage({ viewport: { width: 320, height: 200 } });
      await page.goto(`http://127.0.0.1:${port}/?bench=1&aa=0${codec === 'intra' ? '&temporal=0' : ''}${layers === 'base' ? '&cascades=0&foam=0' : ''}`);
      await waitFor(page, `frames at N=${n}`, (want) => window.oceand.stats.n === want && window.oceand.stats.timings.decode.length > 5, n, 30000);
      const f0 = await page.evaluate(() => window.oceand.framesReceived);
      const skip = await page.evaluate(() => window.oceand.stats.timings.decode.length); // warm-up frames
      await page.waitForTimeout(Number(args.seconds) * 1000);
      const s = await page.evaluate(() => ({ t: window.oceand.stats.timings, f: window.oceand.framesReceived, kBps: window.oceand.stats.kBps,
        sub: window.oceand.subscription, temporal: window.oceand.stats.temporal, inflater: window.oceand.stats.inflater }));
      const decode = s.t.decode.slice(skip), upload = s.t.upload.slice(skip), assemble = s.t.assemble.slice(skip);
      const total = decode.map((d, i) => d + upload[i]);
      console.log(JSON.stringify({
        bench: 'web_decode_upload', n, codec, layers, subscription: describe(s.sub), still_temporal: s.temporal, inflater: s.inflater, frames: decode.length,
        received_per_s: +((s.f - f0) / Number(args.seconds)).toFixed(1), kB_per_s: +s.kBps.toFixed(0),
        decode_ms_median: +median(decode).toFixed(2), assemble_ms_median: +median(assemble).toFixed(2), upload_ms_median: +median(upload).toFixed(2),
        total_ms_median: +median(total).toFixed(2), loadavg_1m: +loadavg()[0].toFixed(2),
      }));
      await page.close();
    } finally { await server.stop(); }
  }
} catch (e) { console.error(`bench-web: ${e.message}`); status = 1; }
await browser.close();
process.exit(status);

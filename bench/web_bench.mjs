// bench-web: per-frame decode (worker: proto/js decodeFrame + tile assembly into
// texture arrays; assembly also reported alone) + upload (float textures, waited for with
// gl.finish) in headless chromium, for N=256 and N=512 with the default
// subscription (height, dx, dz; LOD 0; bound 0.01), temporal (codec 3, the client's default)
// and intra-only (?temporal=0). One JSON line per N and codec, medians.
//   node bench/web_bench.mjs --oceand build/oceand --web-root build/web [--seconds 8]
import { loadavg } from 'node:os';
import { parseArgs, freePort, startServer, launchBrowser, waitFor } from '../tests/web/harness.mjs';

const args = parseArgs(process.argv, { oceand: 'build/oceand', webRoot: 'build/web', seconds: '8', fake: false });
const median = (a) => { const s = [...a].sort((x, y) => x - y); return s.length ? s[s.length >> 1] : null; };
const browser = await launchBrowser();
let status = 0;
try {
  for (const n of [256, 512]) for (const codec of ['temporal', 'intra']) {
    const port = await freePort();
    const server = await startServer({ oceand: args.oceand, webRoot: args.webRoot, port, fake: args.fake, extra: ['--resolution', String(n)] });
    try {
      const page = await browser.newPage({ viewport: { width: 320, height: 200 } });
      await page.goto(`http://127.0.0.1:${port}/?bench=1&aa=0${codec === 'intra' ? '&temporal=0' : ''}`);
      await waitFor(page, `frames at N=${n}`, (want) => window.oceand.stats.n === want && window.oceand.stats.timings.decode.length > 5, n, 30000);
      const f0 = await page.evaluate(() => window.oceand.framesReceived);
      const skip = await page.evaluate(() => window.oceand.stats.timings.decode.length); // warm-up frames
      await page.waitForTimeout(Number(args.seconds) * 1000);
      const s = await page.evaluate(() => ({ t: window.oceand.stats.timings, f: window.oceand.framesReceived, kBps: window.oceand.stats.kBps }));
      const decode = s.t.decode.slice(skip), upload = s.t.upload.slice(skip), assemble = s.t.assemble.slice(skip);
      const total = decode.map((d, i) => d + upload[i]);
      console.log(JSON.stringify({
        bench: 'web_decode_upload', n, codec, subscription: 'height,dx,dz lod0 bound0.01', frames: decode.length,
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

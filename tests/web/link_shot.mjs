// The web page as a viewer on a slow link sees it: opens URL (a daemon behind
// the link lab's shaper, bench/links/screenshot.sh runs this in the viewer's
// namespace), lets the quality ladder settle, takes a screenshot with the HUD
// and prints one JSON line: the HUD's text, the LOD drawn, frames per second.
//   node tests/web/link_shot.mjs --url http://10.201.x.1:8090/ --out FILE [--seconds 25]
import { parseArgs, launchBrowser, waitFor, sleep } from './harness.mjs';

const args = parseArgs(process.argv, { url: '', out: 'link.png', seconds: '25', hour: '12' });
if (!args.url) throw new Error('--url is required');
const browser = await launchBrowser();
try {
  const ctx = await browser.newContext({ viewport: { width: 1280, height: 720 } });
  const page = await ctx.newPage();
  page.setDefaultTimeout(600000); // software GL on a shared 2-core machine
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  const q = new URLSearchParams({ hour: args.hour, panel: 'closed' });
  await page.goto(`${args.url}?${q}`);
  await waitFor(page, 'connected and rendering', () => window.oceand.connected && window.oceand.rendered > 2, null, 300000);
  const r0 = await page.evaluate(() => window.oceand.framesReceived);
  await sleep(Number(args.seconds) * 1000); // the ladder steps down within about a second, probes up slowly
  const r1 = await page.evaluate(() => window.oceand.framesReceived);
  await page.screenshot({ path: args.out, type: 'png' });
  const hud = await page.evaluate(() => document.querySelector('.oc-hud-text')?.textContent ?? '');
  const s = await page.evaluate(() => window.oceand.stats);
  console.log(JSON.stringify({ out: args.out, frames_per_s_received: (r1 - r0) / Number(args.seconds),
    lod: s.lod, latency_ms: s.latencyMs, kBps: s.kBps, hud, errors }));
  if (errors.length) process.exitCode = 1;
} finally {
  await browser.close();
}

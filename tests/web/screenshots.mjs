// `make screenshots`: the gallery (docs/gallery/*.png) and docs/screenshot.png, taken
// from a real daemon in headless Debian chromium (SwiftShader). Sea presets are applied
// as a real client would, with one `set` over the WebSocket; the view (time of day,
// camera) comes from the page's URL options.
//   node tests/web/screenshots.mjs --oceand build/oceand --web-root build/web --out docs/gallery
//        [--only calm,night] [--shot docs/screenshot.png] [--size 640x400]
// --size overrides the desktop viewport (small pictures while iterating: software GL is slow);
// --only also takes the study views below (STUDY), which are not part of the gallery.
import fs from 'node:fs';
import path from 'node:path';
import { createRequire } from 'node:module';
import { parseArgs, freePort, startServer, launchBrowser, waitFor, sleep } from './harness.mjs';
import { ROOT } from './webdeps.mjs';
import { SEA_PRESETS, BEAUFORT_SCALE } from '../../web/src/presets.js';
import { sunDirection } from '../../web/src/sky.js';
import { ndbcLikeSummary } from './sea_fixture.mjs';

const require = createRequire(path.join(ROOT, 'web', 'package.json'));
const { devices } = require('playwright-core');
const WebSocket = require('ws');

const args = parseArgs(process.argv, { oceand: 'build/oceand', webRoot: 'build/web', out: 'docs/gallery', only: '', shot: 'docs/screenshot.png', size: '1280x720' });
const [W, H] = args.size.split('x').map(Number);
const DESKTOP = { viewport: { width: W, height: H } };
// cam/target in metres; hour = local solar time; preset = Beaufort sea preset.
// face: look toward the sun's azimuth turned by `yaw` degrees, `dist` m ahead, down to height ty.
const SHOTS = [
  { name: 'calm', preset: 'calm', hour: 17.5, cam: '0,5,40', face: { yaw: 12, dist: 120, ty: 0 } },
  { name: 'fresh', preset: 'fresh', hour: 17.5, cam: '0,14,48', face: { yaw: 20, dist: 100, ty: 2 } },
  { name: 'gale', preset: 'gale', hour: 17.5, cam: '0,24,80', face: { yaw: 25, dist: 140, ty: 2 } },
  { name: 'storm', preset: 'storm', hour: 17.5, cam: '0,30,100', face: { yaw: 25, dist: 160, ty: 2 } },
  { name: 'whitecaps', preset: 'storm', hour: 13, cam: '0,16,30', target: '0,0,-20' },
  { name: 'sunset', preset: 'fresh', hour: 18.4, cam: '0,12,40', face: { yaw: 8, dist: 120, ty: 4 } },
  { name: 'night', preset: 'fresh', hour: 23, cam: '0,14,48', face: { yaw: 0, dist: 120, ty: 8, moon: true } },
  { name: 'from-800m', preset: 'fresh', hour: 16, cam: '0,800,600', target: '0,0,-200' },
  { name: 'phone', preset: 'fresh', hour: 17.5, device: 'Pixel 7', hud: true, face: { yaw: 20, dist: 100, ty: 2 } },
  // A measured sea's card, compass and polar plot: the summary (sea_fixture.mjs, NDBC-like: a
  // swell from 285° at 12.5 s and a wind sea from 200° at 5 s) injected as the daemon would send
  // it, over a fresh breeze blowing toward 105° (wind_direction 195: the waves from 285°).
  { name: 'measured-sea', preset: 'fresh', set: { wind_direction: 195 }, hour: 15, hud: true, panel: true, sea: true, face: { yaw: -30, dist: 100, ty: 2 } },
  // Views a closer look takes: straight down on a gale and a storm, dusk, a crest, the glitter.
  { name: 'gale-down-30m', preset: 'gale', hour: 15, cam: '0,30,0.01', target: '0,0,0' },
  { name: 'storm-down-80m', preset: 'storm', hour: 15, cam: '0,80,0.01', target: '0,0,0' },
  { name: 'dusk', preset: 'fresh', hour: 19.5, cam: '0,14,48', face: { yaw: 0, dist: 300, ty: 12 } },
  { name: 'storm-crest', preset: 'storm', hour: 15, cam: '0,9,24', target: '0,1,0' },
  { name: 'sunset-glitter', preset: 'fresh', hour: 18.39, cam: '0,30,0', face: { yaw: 0, dist: 400, ty: 0 } },
  // The Beaufort row: every force 0-12 (presets.js BEAUFORT_SCALE) from one camera, 20 m up,
  // looking down 18° across the wind (it blows toward +x, left to right), the sun behind the
  // left shoulder, the horizon in the top of the picture; 640×360, a row of the gallery.
  ...BEAUFORT_SCALE.map((b) => ({ name: b.name, preset: b.name, hour: 15, cam: '0,20,60', target: '0,0,0', size: [640, 360] })),
];
// Foam at other distances and winds (iterating on the foam texture; `--only foam-gale,...`).
// ramp: coverage rises 0 → 1 over that many metres of x (ocean.js ?foamramp=), every stage in one view.
const STUDY = [
  { name: 'ramp-top', preset: 'fresh', hour: 13, cam: '0,6,0.01', target: '0,0,0', ramp: 10 },
  { name: 'ramp-top-storm', preset: 'storm', hour: 13, cam: '0,6,0.01', target: '0,0,0', ramp: 10 },
  { name: 'ramp-close', preset: 'storm', hour: 13, cam: '0,4,3', target: '0,0,-3', ramp: 10 },
  { name: 'ramp-mid', preset: 'gale', hour: 13, cam: '0,12,14', target: '0,0,-10', ramp: 30 },
  { name: 'ramp-fresh', preset: 'fresh', hour: 13, cam: '0,6,8', target: '0,0,-4', ramp: 16 },
  { name: 'foam-3m', preset: 'storm', hour: 13, cam: '0,3,6', target: '0,0,-3' },
  { name: 'foam-gale', preset: 'gale', hour: 13, cam: '0,6,12', target: '0,0,-6' },
  { name: 'foam-fresh', preset: 'fresh', hour: 13, cam: '0,8,16', target: '0,0,-10' },
  { name: 'measured-sea-phone', preset: 'fresh', set: { wind_direction: 195 }, hour: 15, device: 'iPhone 13', hud: true, sea: true, face: { yaw: -30, dist: 100, ty: 2 } },
  { name: 'down-80m-b7', preset: 'beaufort-7', hour: 15, cam: '0,80,0.01', target: '0,0,0', size: [480, 480] },
  { name: 'down-80m-b8', preset: 'beaufort-8', hour: 15, cam: '0,80,0.01', target: '0,0,0', size: [480, 480] },
  { name: 'down-80m-b10', preset: 'beaufort-10', hour: 15, cam: '0,80,0.01', target: '0,0,0', size: [480, 480] },
  { name: 'foam-far', preset: 'storm', hour: 13, cam: '0,60,120', target: '0,0,-150' },
];
// Moon direction of sky.js (altitude 38°, azimuth 155°), for the night shot.
const MOON = { x: -Math.sin(155 * Math.PI / 180), z: Math.cos(155 * Math.PI / 180) };
function faceTarget(s) {
  const [cx, cy, cz] = (s.cam || '0,14,48').split(',').map(Number);
  const d = s.face.moon ? MOON : sunDirection(s.hour);
  const a = Math.atan2(d.z, d.x) + s.face.yaw * Math.PI / 180, k = s.face.dist;
  return `${(cx + Math.cos(a) * k).toFixed(1)},${s.face.ty},${(cz + Math.sin(a) * k).toFixed(1)}`;
}
const only = new Set(args.only ? args.only.split(',') : []);

// One `set` from a plain protocol client; resolves with the new params_version.
async function applyPreset(port, name, extra = {}) {
  const preset = [...SEA_PRESETS, ...BEAUFORT_SCALE].find((p) => p.name === name);
  const ws = new WebSocket(`ws://127.0.0.1:${port}/`, 'oceand.v1');
  const reply = await new Promise((resolve, reject) => {
    const t = setTimeout(() => reject(new Error(`no reply to set ${name}`)), 10000);
    ws.on('message', (data, binary) => {
      if (binary) return;
      const m = JSON.parse(String(data));
      if (m.type === 'hello') ws.send(JSON.stringify({ type: 'set', id: 1, params: { ...preset.params, ...extra } }));
      if (m.id === 1) { clearTimeout(t); resolve(m); }
    });
    ws.on('error', reject);
  });
  ws.close();
  if (reply.type !== 'params') throw new Error(`set ${name} rejected: ${JSON.stringify(reply)}`);
  return reply.params_version;
}

async function take(browser, port, s, file) {
  const ctxOpts = s.device ? { ...devices[s.device] } : s.size ? { viewport: { width: s.size[0], height: s.size[1] } } : DESKTOP;
  const ctx = await browser.newContext(ctxOpts);
  ctx.setDefaultTimeout(300000); // software GL on a shared machine: a 1280×720 frame may take long
  try {
    return await shoot(ctx, port, s, file);
  } finally { await ctx.close().catch(() => {}); }
}

async function shoot(ctx, port, s, file) {
  const page = await ctx.newPage();
  page.setDefaultTimeout(600000); // software GL on a shared 2-core machine can take a while
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  const q = new URLSearchParams({ test: '1', hour: String(s.hour) });
  if (s.cam) q.set('cam', s.cam);
  if (s.ramp) q.set('foamramp', String(s.ramp));
  if (s.face) q.set('target', faceTarget(s));
  else if (s.target) q.set('target', s.target);
  if (!s.hud) q.set('hud', '0');
  if (!s.panel) q.set('panel', 'closed');
  if (!s.hud && !s.panel) q.set('ui', '0'); // the sea alone
  await page.goto(`http://127.0.0.1:${port}/?${q}`);
  await waitFor(page, 'connected and rendering', () => window.oceand.connected && window.oceand.rendered > 2, null, 300000);
  const version = s.preset ? await applyPreset(port, s.preset, s.set) : null;
  if (version !== null) await waitFor(page, 'frames of the preset', (v) => window.oceand.frameParamsVersion >= v, version, 300000);
  // The page's own subscription (the foam field, the finer cascades) comes a
  // little after the first frames: a picture before it shows foam from the folds instead.
  await waitFor(page, 'the foam field', () => window.oceand.foam.source === 'field', null, 300000);
  // Let the HUD fill in, frames blend, and a few more frames render.
  const r0 = await page.evaluate(() => window.oceand.rendered);
  await waitFor(page, 'three more frames', (r) => window.oceand.rendered >= r + 3, r0, 600000);
  if (s.sea) {
    await page.evaluate((summary) => window.oceandTest.sea(summary), ndbcLikeSummary());
    await page.click('[data-ui=sea-plot-toggle]');
    await waitFor(page, 'two more frames', (r) => window.oceand.rendered >= r + 2, await page.evaluate(() => window.oceand.rendered), 600000);
  }
  await sleep(600);
  await page.screenshot({ path: file, type: 'png' });
  // The surface's LOD in the picture: a server short of CPU, or a page slow to read, serves a
  // coarser one for a while (a blurred sea, fewer small waves): say so, to retake it.
  const view = await page.evaluate(() => ({ ...window.oceand.view, lod: window.oceand.stats.lod }));
  if (errors.length) throw new Error(`page errors: ${errors.join('; ')}`);
  return view;
}

const port = await freePort();
const server = await startServer({ oceand: args.oceand, webRoot: args.webRoot, port });
const browser = await launchBrowser();
fs.mkdirSync(args.out, { recursive: true });
let failed = 0;
try {
  for (const s of [...SHOTS, ...STUDY]) {
    if (only.size ? !only.has(s.name) : STUDY.includes(s)) continue;
    const file = path.join(args.out, `${s.name}.png`);
    const t0 = Date.now();
    try {
      const v = await take(browser, port, s, file);
      console.log(`${file}  (${((Date.now() - t0) / 1000).toFixed(1)} s; sun ${v.sky.sunAltitudeDeg.toFixed(1)}°, overcast ${v.sky.overcast.toFixed(2)}, surface lod ${v.lod}${v.lod ? ': COARSER than the stream offers, retake it' : ''})`);
    } catch (e) { failed++; console.log(`FAIL ${s.name}: ${e.message}`); }
  }
  if (!only.size || only.has('screenshot')) {
    // The README's picture: desktop, panel open, status shown, a fresh breeze.
    const v = await take(browser, port, { name: 'screenshot', preset: 'fresh', hour: 17.5, hud: true, panel: true, face: { yaw: 0, dist: 100, ty: 2 } }, args.shot);
    console.log(`${args.shot}  (sun ${v.sky.sunAltitudeDeg.toFixed(1)}°)`);
  }
} finally {
  await browser.close().catch(() => {});
  await server.stop().catch(() => {});
}
process.exit(failed ? 1 : 0);

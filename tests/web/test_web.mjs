// End-to-end tests of the web client against a real oceand on loopback, in
// headless Debian chromium (software WebGL2 through SwiftShader).
//   node tests/web/test_web.mjs --oceand build/oceand --web-root build/web --out build/web-test
// Closing line: "N passed, M failed"; exit status 1 on any failure.
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs, freePort, startServer, launchBrowser, waitFor, sleep } from './harness.mjs';
import { ROOT } from './webdeps.mjs';
import { createRequire } from 'node:module';
import { SEA_PRESETS } from '../../web/src/presets.js';
import { checkName, tidyName } from '../../web/src/name.js';
import { sunDirection } from '../../web/src/sky.js';
import { glitterRatio, twilightRatio, skyColour } from './light.mjs';
import { seaChecks } from './sea_checks.mjs';

const { devices } = createRequire(path.join(ROOT, 'web', 'package.json'))('playwright-core');

// --only REGEX: run only the checks whose name matches (the pages they share still open).
// --serial: run the side groups (seamGroup, lightGroup, capGroup) after the main one instead of beside it.
const args = parseArgs(process.argv, { oceand: 'build/oceand', webRoot: 'build/web', out: 'build/web-test', fake: false, only: '', serial: false });
const only = args.only ? new RegExp(args.only) : null;
fs.mkdirSync(args.out, { recursive: true });
const VIEW = { width: 800, height: 500 };
// test: keep the drawing buffer; aa=0: no MSAA; detail: a lighter mesh; scale=0.25: a 16th of
// the pixels (software GL is slow; the checks on this page compare whole images, flat against
// varied, noon against night, solid against wireframe, which hold at any resolution).
const QUERY_BASE = '?test=1&aa=0&detail=0.25&scale=0.25';
// catchup=0: a page that software GL puts behind would otherwise step itself down and reopen
// its connection in the middle of a check (catchup.js); only the catch-up check keeps it on.
const QUERY = `${QUERY_BASE}&catchup=0`;
// Pages whose checks read state and layout, not pixels, do not draw the sea (?draw=0): every
// drawing page slows all the others (software GL renders them all in one GPU process).
const QUERY_NODRAW = `${QUERY}&draw=0`;

let passed = 0, failed = 0;
const T0 = Date.now();
// tag: the side group a check runs in ('' for the main one), printed before its lines.
async function check(name, fn, tag = '') {
  if (only && !only.test(name)) return;
  const t0 = Date.now();
  try {
    await fn();
    passed++;
    console.log(`${tag}ok   ${name} (${((Date.now() - t0) / 1000).toFixed(1)} s, done at ${((Date.now() - T0) / 1000).toFixed(0)} s)`);
  } catch (e) {
    failed++;
    console.log(`${tag}FAIL ${name}: ${e.message}`);
  }
}
function assert(cond, msg) { if (!cond) throw new Error(msg); }

// Screenshots are decoded by the browser itself and their pixels kept in the
// page (window.__shots[name]); only statistics come back. Region: the water
// below the horizon, left of the panel and below the HUD (so neither can make a
// flat canvas look varied).
async function shot(page, name) {
  // (a frame of software GL on a loaded 2-core machine can take longer than the default 30 s)
  const png = await page.screenshot({ type: 'png', timeout: 120000 });
  const variance = await page.evaluate(async ({ b64, name }) => {
    const panel = document.getElementById('panel').getBoundingClientRect();
    const hud = document.getElementById('hud').getBoundingClientRect();
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const x = 4, y = Math.max(Math.floor(hud.bottom) + 4, Math.floor(img.height * 0.45));
    const c = document.createElement('canvas');
    c.width = Math.floor(panel.left) - 8 - x; c.height = img.height - 4 - y;
    const g = c.getContext('2d');
    g.drawImage(img, -x, -y);
    const rgba = g.getImageData(0, 0, c.width, c.height).data;
    const px = new Float32Array((rgba.length / 4) * 3);
    for (let i = 0, k = 0; i < rgba.length; i += 4) { px[k++] = rgba[i]; px[k++] = rgba[i + 1]; px[k++] = rgba[i + 2]; }
    (window.__shots ||= {})[name] = px;
    let s = 0, s2 = 0;
    for (const v of px) { s += v; s2 += v * v; }
    return { variance: s2 / px.length - (s / px.length) ** 2, mean: s / px.length };
  }, { b64: png.toString('base64'), name });
  return { png, ...variance };
}
// Mean absolute difference (0..255) between two kept screenshots, over the rows both hold
// (the region starts below the HUD, which grows by a line when the page says it is behind:
// the regions then end at the same bottom row, and are compared from there up).
const shotDiff = (page, a, b) => page.evaluate(([a, b]) => {
  const p = window.__shots[a], q = window.__shots[b], n = Math.min(p.length, q.length), op = p.length - n, oq = q.length - n;
  let s = 0;
  for (let i = 0; i < n; i++) s += Math.abs(p[op + i] - q[oq + i]);
  return s / n;
}, [a, b]);
const state = (page) => page.evaluate(() => ({ ...window.oceand, params: window.oceand.params, stats: window.oceand.stats, view: window.oceand.view, camera: window.oceand.camera }));

// Boxes of the HUD, the panel title (or the whole panel when open) and the banner must
// not overlap, and the panel starts closed on a phone.
async function layoutCheck(page, what, banner, open = false) {
  const boxes = await page.evaluate(({ banner, open }) => {
    const r = (el) => { const b = el.getBoundingClientRect(); return { x: b.left, y: b.top, w: b.width, h: b.height }; };
    const panel = document.getElementById('panel');
    const out = { hud: r(document.getElementById('hud')), panel: r(open ? panel : panel.querySelector(':scope > .title')) };
    if (banner) out.banner = r(document.getElementById('banner'));
    out.closed = panel.classList.contains('closed');
    out.vw = window.innerWidth; out.vh = window.innerHeight;
    return out;
  }, { banner, open });
  if (!open) assert(boxes.closed, `${what}: the panel starts open`);
  const names = ['hud', 'panel', ...(banner ? ['banner'] : [])];
  for (const n of names) {
    const b = boxes[n];
    assert(b.w > 0 && b.h > 0, `${what}: ${n} has no size`);
    assert(b.x >= 0 && b.y >= 0 && b.x + b.w <= boxes.vw + 0.5 && b.y + b.h <= boxes.vh + 0.5, `${what}: ${n} ${JSON.stringify(b)} runs off the ${boxes.vw}x${boxes.vh} screen`);
  }
  for (let i = 0; i < names.length; i++) for (let j = i + 1; j < names.length; j++) {
    const p = boxes[names[i]], q = boxes[names[j]];
    const overlap = p.x < q.x + q.w && q.x < p.x + p.w && p.y < q.y + q.h && q.y < p.y + p.h;
    assert(!overlap, `${what}: ${names[i]} ${JSON.stringify(p)} overlaps ${names[j]} ${JSON.stringify(q)}`);
  }
}
// (up to 2 min: a frame of a large view in software GL on a loaded 2-core machine can take
// many seconds; the wait ends with the frames, so it costs nothing when they come sooner)
const renderedMore = async (page, k) => {
  const r = (await state(page)).rendered;
  await waitFor(page, `${k} more rendered frames`, ([r0, n]) => window.oceand.rendered >= r0 + n, [r, k], 120000);
};

// The local hour at which the sun stands altDeg above the horizon in the evening (bisection
// on sky.js's sunDirection, which falls monotonically from noon to midnight).
function eveningHour(altDeg) {
  let lo = 12, hi = 23.9;
  for (let k = 0; k < 40; k++) {
    const mid = (lo + hi) / 2;
    if (Math.asin(sunDirection(mid).y) * 180 / Math.PI > altDeg) lo = mid; else hi = mid;
  }
  return (lo + hi) / 2;
}

// One `set` from a plain protocol client (as a preset button sends it); resolves with the
// new params_version.
async function setParams(port, params) {
  const { default: WebSocket } = await import(path.join(ROOT, 'web', 'node_modules', 'ws', 'index.js'));
  const ws = new WebSocket(`ws://127.0.0.1:${port}/`, 'oceand.v1');
  try {
    const reply = await new Promise((resolve, reject) => {
      const t = setTimeout(() => reject(new Error('no reply to set')), 15000);
      ws.on('message', (data, binary) => {
        if (binary) return;
        const m = JSON.parse(String(data));
        if (m.type === 'hello') ws.send(JSON.stringify({ type: 'set', id: 1, params }));
        if (m.id === 1) { clearTimeout(t); resolve(m); }
      });
      ws.on('error', reject);
    });
    if (reply.type !== 'params') throw new Error(`set refused: ${JSON.stringify(reply)}`);
    return reply.params_version;
  } finally { ws.close(); }
}

// The page's full subscription in: frames of params_version >= version drawn, the foam field
// and the finer cascades (they come with the page's own subscription, a little later), with
// fullDetail the surface at lod 0 too, and 3 frames more.
async function settle(p, version, fullDetail = false) {
  await waitFor(p, 'frames of the parameters set', (v) => window.oceand.frameParamsVersion >= v && window.oceand.rendered > 3, version, 120000);
  if (!args.fake) {
    await waitFor(p, `frames with the foam field${fullDetail ? ' at full detail' : ''}`,
      (full) => window.oceand.foam.source === 'field' && (!full || window.oceand.stats.lod === 0), fullDetail, 120000);
  }
  await renderedMore(p, 3);
}
// Change the view of an open page (window.oceandTest.options and look: what the URL's ?hour=,
// ?cam=, ?target=, ... set at load), then let it draw 3 frames of the new view.
async function setView(p, { viewport, cam, target, ...options }) {
  if (viewport) await p.setViewportSize(viewport);
  await p.evaluate(([o, c, t]) => {
    window.oceandTest.options(o);
    if (c) window.oceandTest.look(c, t);
  }, [options, cam || null, target || null]);
  await renderedMore(p, 3);
}

// The foam amount of a debug-view picture (red): the share of pixels above 0.5, and the
// autocorrelation length (lag where the normalised autocovariance falls below 1/e,
// interpolated; at most 100 px) along the screen's x and y.
async function foamTexture(p, png) {
  return p.evaluate(async (b64) => {
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const c = document.createElement('canvas');
    const w = c.width = img.width, h = c.height = img.height;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, w, h).data, a = new Float64Array(w * h);
    let m = 0, white = 0;
    for (let i = 0; i < w * h; i++) { a[i] = d[4 * i]; m += a[i]; white += a[i] > 127; }
    m /= w * h;
    let v = 0;
    for (let i = 0; i < w * h; i++) { a[i] -= m; v += a[i] * a[i]; }
    v /= w * h;
    const length = (dx, dy) => {
      let prev = 1;
      for (let k = 1; k <= 100; k++) {
        let s = 0, n = 0;
        for (let y = 0; y + k * dy < h; y++) for (let x = 0; x + k * dx < w; x++) { s += a[y * w + x] * a[(y + k * dy) * w + x + k * dx]; n++; }
        const r = v > 0 ? s / n / v : 0;
        if (r < Math.exp(-1)) return k - 1 + (prev - Math.exp(-1)) / (prev - r);
        prev = r;
      }
      return 100;
    };
    return { white: white / (w * h), along: length(1, 0), across: length(0, 1) };
  }, png.toString('base64'));
}

// Height of the displaced surface at (x, z) from the page's grids (oceandTest.grids), by
// brute force: every point of a 0.1 m lattice within 10 m is displaced (bilinear between the
// grid's nodes) and the highest that lands within 0.2 m of (x, z) counts, plus the finer
// cascades' heights at (x, z) (the higher of the two frames each).
function surfaceAt(g, x, z) {
  const bil = (w, px, pz, ch) => {
    const fx = px / w.cell - w.i0, fz = pz / w.cell - w.j0, a = Math.floor(fx), b = Math.floor(fz), tx = fx - a, tz = fz - b;
    const at = (i, j) => w.v[3 * (j * w.w + i) + ch];
    return (at(a, b) * (1 - tx) + at(a + 1, b) * tx) * (1 - tz) + (at(a, b + 1) * (1 - tx) + at(a + 1, b + 1) * tx) * tz;
  };
  let best = -Infinity;
  for (const w of g.disp) {
    for (let a = -10; a <= 10; a += 0.1) for (let b = -10; b <= 10; b += 0.1) {
      const px = x + a, pz = z + b;
      const X = px + bil(w, px, pz, 0), Z = pz + bil(w, px, pz, 2);
      if (Math.hypot(X - x, Z - z) <= 0.2) best = Math.max(best, bil(w, px, pz, 1));
    }
  }
  for (const c of g.cascades) if (c) best += Math.max(...c.map((w) => bil(w, x, z, 1)));
  return best;
}

// Drags and zooms that push the camera down into a storm's waves; the least height of the
// camera above the surface beneath it after each.
async function lowestClearance(p) {
  const box = await p.locator('#ocean').boundingBox();
  const cx = box.x + box.width / 2, cy = box.y + box.height / 2;
  let least = Infinity;
  const gestures = [
    async () => { await p.mouse.move(cx, cy); await p.mouse.wheel(0, -400); },
    async () => { await p.mouse.move(cx, cy); await p.mouse.down(); await p.mouse.move(cx, cy - 120, { steps: 6 }); await p.mouse.up(); },
    async () => { await p.mouse.move(cx, cy); await p.mouse.wheel(0, -800); },
    async () => { await p.mouse.move(cx - 100, cy); await p.mouse.down(); await p.mouse.move(cx + 60, cy - 80, { steps: 6 }); await p.mouse.up(); },
    async () => { await p.keyboard.press('ArrowUp'); await p.keyboard.press('ArrowUp'); },
  ];
  for (const g of gestures) {
    await g();
    await renderedMore(p, 2);
    const { cam, grids } = await p.evaluate(() => {
      const c = window.oceand.camera.position;
      return { cam: c, grids: window.oceandTest.grids(c[0], c[2], 11) };
    });
    least = Math.min(least, cam[1] - surfaceAt(grids, cam[0], cam[2]));
  }
  return least;
}

// Magenta (?gapprobe=1: sky and skirts) pixels of a view looking down on patch seams, for
// the crack fixes off and on, all on one held frame, at full resolution; `again` repeats the
// first variant. The page is left drawing as before (crack fixes on, no probe colour).
async function seamPixels(p) {
  try {
    await setView(p, { viewport: { width: 420, height: 420 }, scale: 1, gapProbe: true, cam: [0, 150, 150], target: [0, 0, -100] });
    await p.evaluate(() => window.oceandTest.freeze(true));
    await renderedMore(p, 2); // the held frame fully blended in (uMix 1)
    const count = async (fixes) => {
      await p.evaluate((f) => window.oceandTest.crackFixes(f), fixes);
      await renderedMore(p, 2);
      const png = await p.screenshot({ type: 'png', timeout: 120000 });
      return await p.evaluate(async (b64) => {
        const img = new Image();
        img.src = `data:image/png;base64,${b64}`;
        await img.decode();
        const c = document.createElement('canvas');
        c.width = img.width; c.height = img.height;
        const g = c.getContext('2d');
        g.drawImage(img, 0, 0);
        const d = g.getImageData(0, 0, c.width, c.height).data;
        let n = 0; // this view looks down, below the horizon: magenta is sky or skirt in a seam
        for (let i = 0; i < d.length; i += 4) if (d[i] > 200 && d[i + 1] < 60 && d[i + 2] > 200) n++;
        return n;
      }, png.toString('base64'));
    };
    const open = await count({ stitch: false, skirts: false }), old = await count({ stitch: false, skirts: true });
    const stitched = await count({ stitch: true, skirts: false }), normal = await count({ stitch: true, skirts: true });
    const again = await count({ stitch: false, skirts: false });
    return { open, old, stitched, normal, again };
  } finally {
    await p.evaluate(() => {
      window.oceandTest.crackFixes({ stitch: true, skirts: true });
      window.oceandTest.freeze(false);
      window.oceandTest.options({ gapProbe: false });
    });
  }
}

const port = await freePort();
const srvOpts = { oceand: args.oceand, webRoot: args.webRoot, port, fake: args.fake };
let server = await startServer(srvOpts);
console.log(`web tests against ${args.fake ? 'the FAKE server' : args.oceand} on 127.0.0.1:${port}`);
const browser = await launchBrowser();
const url = `http://127.0.0.1:${port}/${QUERY}`;
const pageErrors = [];
async function openPage(query = QUERY) {
  const p = await browser.newPage({ viewport: VIEW });
  p.on('pageerror', (e) => pageErrors.push(e.message));
  await p.goto(`http://127.0.0.1:${port}/${query}`, { timeout: 120000 });
  return p;
}

// Page A draws the sea in software GL, at times well under 1 frame/s beside the other groups'
// pages: playwright's click waits for two animation frames of a still element, which such a page
// may not give in 30 s. Its buttons are pressed as a script would press them (these checks are
// of what a press does; the phone checks use real taps).
const domClick = (p, sel) => p.evaluate((s) => { const e = document.querySelector(s); if (!e) throw new Error(`no ${s}`); e.click(); }, sel);

// Light, foam and seams on a sea that holds still (--paused: t = 0, seed 1), so every variant
// sees the same waves, each group on ONE page of its own daemon (a new page costs a load, a
// shader compile and the wait for the full subscription; views change with setView): the
// seams on the daemon's own sea (seamGroup); a fresh breeze for the sky and glitter, a storm
// for the camera and the foam (lightGroup). The two run in browsers of their own, so that
// both cores draw once the main group is done.
async function withStillPage(br, fn) {
  const port5 = await freePort();
  const still = await startServer({ ...srvOpts, port: port5, extra: ['--paused', 'true'] });
  let p = null;
  try {
    p = await br.newPage({ viewport: { width: 600, height: 600 } });
    p.on('pageerror', (e) => pageErrors.push(e.message));
    await p.goto(`http://127.0.0.1:${port5}/?test=1&aa=0&detail=0.5&ui=0&scale=0.5&catchup=0`, { timeout: 120000 });
    await settle(p, 0, true); // the seams are counted on the surface at full detail
    await fn(p, port5);
  } finally {
    if (p) await p.close().catch(() => {});
    await still.stop();
  }
}

async function seamGroup(check, br) {
  await withStillPage(br, async (p) => {

    // Seen from above, choppy waves move patch edges sideways; where a fine patch meets a
    // coarser one the edges used to part: the sky showed through (without skirts), or the
    // skirt did (with them), as a dashed seam. ?gapprobe=1 paints sky and skirts magenta,
    // so whatever shows in the seams can be counted; the unstitched views must show some,
    // so the check can fail. The counts depend on the moment of the sea, so it is always the
    // same one: the daemon's clock stopped (t = 0, seed 1), and all variants drawn from one
    // held frame (display frozen, fixes switched by window.oceandTest).
    await check('no sky or skirt in the seams between patches of different detail', async () => {
      const c = await seamPixels(p);
      console.log(`     magenta pixels in the seams of one frame: no skirts ${c.open} unstitched -> ${c.stitched} stitched; with skirts ${c.old} unstitched -> ${c.normal} stitched`);
      assert(c.again === c.open, `the held frame changed: ${c.open} then ${c.again} pixels`);
      assert(c.open >= 20 && c.old >= 20, `the unstitched views show only ${c.open} / ${c.old} seam pixels: this view no longer tests the seams`);
      assert(c.stitched <= c.open / 5, `sky shows through the stitched seams: ${c.stitched} pixels (unstitched ${c.open})`);
      assert(c.normal <= c.old / 2, `skirts show in the stitched seams: ${c.normal} pixels (unstitched ${c.old})`);
    });

  });
}

async function lightGroup(check, br) {
  await withStillPage(br, async (p, port5) => {
    const fresh = SEA_PRESETS.find((q) => q.name === 'fresh').params, storm = SEA_PRESETS.find((q) => q.name === 'storm').params;
    let version = await setParams(port5, { ...fresh, paused: true });
    await settle(p, version);
    const skyView = { width: 480, height: 300 };
    await check('sunset glitter: the path under a sun 2° up is at least twice the water 20° beside it', async () => {
      const hour = eveningHour(2), sun = sunDirection(hour).toArray(), cam = [0, 30, 0];
      await setView(p, { viewport: skyView, scale: 0.5, hour, cam, target: [sun[0] * 1000, 0, sun[2] * 1000] });
      const r = await glitterRatio(p, cam, sun);
      fs.writeFileSync(path.join(args.out, 'glitter.png'), r.png);
      console.log(`     path ${r.path.toFixed(1)}, water 20° beside ${r.side.toFixed(1)} (luminance 0..255): ratio ${r.ratio.toFixed(2)}`);
      assert(r.on.every((n) => n >= 5), `points off screen: ${r.on}`);
      assert(r.ratio >= 2, `the glitter path is only ${r.ratio.toFixed(2)}x the water beside it`);
    });
    // The clear sky 30°..60° from a noon sun (60° up) is blue, not washed out to near white
    // (the Sky addon's display gamma, under our own tone curve and sRGB encoding, left a
    // saturation of about 0.1 there and blue/red 1.1: sky.js skyMaterial).
    await check('noon sky: the clear sky 30-60° from the sun is blue, not washed out', async () => {
      const hour = 12, sun = sunDirection(hour).toArray(), cam = [0, 10, 0];
      await setView(p, { viewport: skyView, scale: 0.5, hour, cam, target: [sun[0] * 1000, 9, sun[2] * 1000] });
      const r = await skyColour(p, cam, sun);
      fs.writeFileSync(path.join(args.out, 'noon-sky.png'), r.png);
      console.log(`     ${r.on} of ${r.points} sky points on screen: saturation ${r.saturation.toFixed(2)}, blue/red ${r.blueRed.toFixed(2)} (upper quartiles), luminance ${r.mean.toFixed(0)}`);
      assert(r.on >= 15, `sky points off screen: ${r.on} of ${r.points}`);
      assert(r.saturation >= 0.2 && r.blueRed >= 1.25, `the noon sky is washed out: saturation ${r.saturation.toFixed(2)}, blue/red ${r.blueRed.toFixed(2)}`);
      assert(r.mean >= 120, `the noon sky is dark: luminance ${r.mean.toFixed(0)}`);
    });
    await check('dusk: the band above the horizon under a sun 3° below is brighter than the top of the sky', async () => {
      const hour = eveningHour(-3), sun = sunDirection(hour).toArray(), cam = [0, 10, 0];
      await setView(p, { viewport: skyView, scale: 0.5, hour, cam, target: [sun[0] * 1000, 9, sun[2] * 1000] });
      const r = await twilightRatio(p, cam, sun);
      fs.writeFileSync(path.join(args.out, 'dusk.png'), r.png);
      console.log(`     band 0-5° ${r.band.toFixed(1)}, top of the view (25° up) ${r.top.toFixed(1)}: ratio ${r.ratio.toFixed(2)}`);
      assert(r.on[0] >= 20 && r.on[1] >= 5, `points off screen: ${r.on}`);
      assert(r.ratio >= 1.2, `the twilight band is only ${r.ratio.toFixed(2)}x the top of the sky`);
    });
    version = await setParams(port5, { ...storm, paused: true });
    await settle(p, version);
    await check('storm: drags and zooms never take the camera within 1 m of the surface beneath it', async () => {
      // Only the camera's position is looked at: a small view. With the floor, then without.
      const start = { viewport: { width: 240, height: 150 }, cam: [0, 6, 14], target: [0, 0, 0] };
      await setView(p, { ...start, camFloor: true });
      const kept = await lowestClearance(p);
      await setView(p, { ...start, camFloor: false });
      const free = await lowestClearance(p);
      await p.evaluate(() => window.oceandTest.options({ camFloor: true }));
      console.log(`     least height above the surface beneath: ${kept.toFixed(2)} m (without the floor: ${free.toFixed(2)} m)`);
      assert(free < 1, `without the floor the gestures stay ${free.toFixed(2)} m above the waves: they no longer test it`);
      assert(kept >= 1 - 0.05, `the camera came within ${kept.toFixed(2)} m of the surface`);
    });
    // The orbit's polar limit was relative to its target (0.495π): a 1.5 m camera aimed 200 m
    // away went up to 3.64 m. Over a trough of the held storm (surface + 1 m below 1.5 m) it
    // stays at 1.5 m.
    await check('storm: the orbit limit leaves a low camera aimed far away where it is', async () => {
      let spot = null;
      for (let x = 0; x <= 120 && !spot; x += 6) {
        const g = await p.evaluate(([x]) => window.oceandTest.grids(x, 0, 11), [x]);
        const h = Math.max(...[[0, 0], [0.6, 0], [-0.6, 0], [0, 0.6], [0, -0.6]].map(([a, b]) => surfaceAt(g, x + a, b)));
        if (h < 0) spot = x;
      }
      assert(spot !== null, 'no trough found on the held storm');
      await setView(p, { viewport: { width: 240, height: 150 }, cam: [spot, 1.5, 0], target: [spot + 200, 0.5, 0] });
      await renderedMore(p, 3);
      const c = (await state(p)).camera;
      console.log(`     camera at 1.5 m over a trough at x = ${spot} m, aimed 200 m away: drawn at ${c.position[1].toFixed(2)} m`);
      assert(Math.abs(c.position[1] - 1.5) < 0.05, `the camera went to ${c.position[1].toFixed(2)} m`);
    });
    await check('storm from 80 m straight down: the foam lies on the crests, not at random', async () => {
      // The foam field is a history: held still it keeps what the earlier (fresh) sea left, so
      // the storm runs here, 8 s of its clock before the pictures (foam fades with an e-folding
      // time of 3 s: the fresh sea's is down to 7 %), and the statistics below carry the check.
      version = await setParams(port5, { paused: false });
      await settle(p, version);
      const t0 = await p.evaluate(() => window.oceand.frameSimTime);
      await waitFor(p, '8 s of the running storm', (t) => window.oceand.frameSimTime >= t + 8, t0, 120000);
      // The streaks (checked below) lie along the wind over crests and troughs alike: this check
      // is of where the field's own foam lies, so it leaves them out.
      await setView(p, { viewport: { width: 400, height: 400 }, cam: [0, 80, 0.01], target: [0, 0, 0], debugFoam: true, foamStreaks: false });
      // (the camera taken there, not still on its way from the low view before: a picture of a
      // few metres of water has no crests to follow)
      await waitFor(p, 'the camera 80 m up', () => window.oceand.camera.position[1] > 79, null, 15000)
        .catch(async () => assert(false, `the camera is at ${JSON.stringify((await state(p)).camera)}`));
      const corr = async (shift) => {
        await p.evaluate((s) => window.oceandTest.options({ foamShift: s }), shift);
        await renderedMore(p, 2);
        const png = await p.screenshot({ type: 'png', timeout: 240000 });
        if (!shift) fs.writeFileSync(path.join(args.out, 'foam-mask.png'), png);
        return await p.evaluate(async (b64) => {
          const img = new Image();
          img.src = `data:image/png;base64,${b64}`;
          await img.decode();
          const c = document.createElement('canvas');
          c.width = img.width; c.height = img.height;
          const g = c.getContext('2d');
          g.drawImage(img, 0, 0);
          const d = g.getImageData(0, 0, c.width, c.height).data;
          // Pearson correlation of the foam (red) with -J (green) and with height (blue).
          const r = (ch) => {
            let n = 0, sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
            for (let i = 0; i < d.length; i += 4) { const a = d[i], b = d[i + ch]; n++; sa += a; sb += b; saa += a * a; sbb += b * b; sab += a * b; }
            const va = saa / n - (sa / n) ** 2, vb = sbb / n - (sb / n) ** 2;
            return (sab / n - (sa / n) * (sb / n)) / Math.sqrt(Math.max(va * vb, 1e-9));
          };
          let foam = 0;
          for (let i = 0; i < d.length; i += 4) foam += d[i] > 127;
          return { squeeze: r(1), height: r(2), foam: foam / (d.length / 4) };
        }, png.toString('base64'));
      };
      const placed = await corr(null), random = await corr([37.3, -53.9]);
      console.log(`     camera ${JSON.stringify((await state(p)).camera.position.map((v) => +v.toFixed(2)))}; foam vs -J ${placed.squeeze.toFixed(2)}, vs height ${placed.height.toFixed(2)} (foam on ${(100 * placed.foam).toFixed(1)} % of pixels); moved 37 m, 54 m: ${random.squeeze.toFixed(2)}, ${random.height.toFixed(2)}`);
      assert(placed.foam > 0.01, `hardly any foam in a storm: ${(100 * placed.foam).toFixed(2)} %`);
      assert(placed.squeeze > 0.2 && placed.height > 0.05, `foam does not follow the crests: ${JSON.stringify(placed)}`);
      assert(placed.squeeze > random.squeeze + 0.15, `foam placed at random correlates as well: ${JSON.stringify(random)}`);
    });
    // A crest lifted a 1.5 m camera to 2.24 m and it stayed there when the water fell back: the
    // floor only ever lifted. On the running storm (after the foam check) the camera, left at
    // 1.5 m, rises over each crest and comes down again as the water falls, never below it.
    await check('storm: the camera rides over a crest and comes back down as the water falls', async () => {
      version = await setParams(port5, { paused: false }); // (the foam check has let it run already)
      await settle(p, version);
      await setView(p, { viewport: { width: 240, height: 150 }, debugFoam: false, foamShift: null, foamStreaks: true, cam: [0, 1.5, 0], target: [200, 0.5, 0] });
      // The camera's height at every frame drawn (in the page), and now and then the floor
      // beneath it as the test computes it from the grids (surfaceAt).
      await p.evaluate(() => {
        const ys = window.__camTrace = [];
        const f = () => { ys.push(window.oceand.camera.position[1]); if (ys.length < 20000) requestAnimationFrame(f); };
        requestAnimationFrame(f);
      });
      let under = Infinity;
      const end = Date.now() + 30000;
      while (Date.now() < end) {
        const s = await p.evaluate(() => { const c = window.oceand.camera.position; return { y: c[1], x: c[0], z: c[2], g: window.oceandTest.grids(c[0], c[2], 11) }; });
        under = Math.min(under, s.y - surfaceAt(s.g, s.x, s.z) - 1);
        await sleep(500);
      }
      const ys = await p.evaluate(() => { const t = window.__camTrace.slice(); window.__camTrace.length = 20000; return t; });
      const top = ys.reduce((m, y, i) => (y > ys[m] ? i : m), 0), low = Math.min(...ys.slice(top));
      let fall = 0; // the largest descent over the trace
      for (let i = 1, hi = ys[0]; i < ys.length; i++) { hi = Math.max(hi, ys[i]); fall = Math.max(fall, hi - ys[i]); }
      console.log(`     ${ys.length} frames: camera at 1.5 m, lifted up to ${ys[top].toFixed(2)} m, down again to ${low.toFixed(2)} m after it (largest fall ${fall.toFixed(2)} m); least height above the floor (sampled) ${under.toFixed(2)} m`);
      assert(ys[top] > 2, `no crest lifted the camera (highest ${ys[top].toFixed(2)} m): this does not test the floor`);
      assert(fall > 0.5, `the camera never came down after a crest (largest fall ${fall.toFixed(2)} m)`);
      assert(under >= -0.05, `the camera went ${(-under).toFixed(2)} m below the floor`);
    });
    // Beaufort's sea: white foam "blown in streaks along the direction of the wind" from force 7,
    // "well-marked streaks" at 8, the sea whiter with the wind. On the storm preset at forces
    // 7, 8 and 10 (15.5, 19, 26.5 m/s, each run 8 s of its clock so the foam field is its own),
    // from 80 m straight down on four spots of the patch, the foam amount (debug view, red):
    // the share of the pixels foam-white (amount > 0.5) rises with the wind, and its texture's
    // autocorrelation length along the wind (+x, the screen's x) is at least twice that across
    // it from force 8 (crest foam alone lies across the wind: long crests, short along it).
    await check('storm from 80 m straight down: more foam-white with the wind, streaked along it from Beaufort 8', async () => {
      const rows = [];
      try {
        for (const [force, wind] of [[7, 15.5], [8, 19], [10, 26.5]]) {
          version = await setParams(port5, { ...storm, wind_speed: wind, paused: false });
          await settle(p, version);
          const t0 = await p.evaluate(() => window.oceand.frameSimTime);
          await waitFor(p, '8 s of the running sea', (t) => window.oceand.frameSimTime >= t + 8, t0, 120000);
          const stats = [];
          for (const [x, z] of [[0, 0], [130, 40], [-60, 170], [210, -150]]) {
            await setView(p, { viewport: { width: 320, height: 320 }, debugFoam: true, foamShift: null, foamStreaks: true, cam: [x, 80, z + 0.01], target: [x, 0, z] });
            const png = await p.screenshot({ type: 'png', timeout: 240000 });
            if (force === 10 && !x) fs.writeFileSync(path.join(args.out, 'foam-streaks.png'), png);
            stats.push(await foamTexture(p, png));
          }
          // Lengths: the median over the spots (one spot can hold a great patch that is long
          // both ways); the share: the mean.
          const mean = (k) => stats.reduce((a, s) => a + s[k], 0) / stats.length;
          const mid = (k) => { const v = stats.map((s) => s[k]).sort((a, b) => a - b); return 0.5 * (v[(v.length - 1) >> 1] + v[v.length >> 1]); };
          rows.push({ force, wind, white: mean('white'), along: mid('along'), across: mid('across'), spots: stats.map((s) => `${s.along.toFixed(0)}/${s.across.toFixed(0)}`).join(' ') });
        }
      } finally {
        await setParams(port5, { ...storm, paused: false });
        await setView(p, { debugFoam: false });
      }
      for (const r of rows) console.log(`     Beaufort ${r.force} (${r.wind} m/s): foam-white ${(100 * r.white).toFixed(1)} % of the picture; autocorrelation length along the wind ${r.along.toFixed(1)} px, across ${r.across.toFixed(1)} px (ratio ${(r.along / r.across).toFixed(2)}; spots along/across ${r.spots})`);
      assert(rows[0].white < rows[1].white && rows[1].white < rows[2].white, `the foam-white share does not rise with the wind: ${rows.map((r) => (100 * r.white).toFixed(1)).join(', ')} %`);
      assert(rows[2].white > 0.05, `a storm is hardly white: ${(100 * rows[2].white).toFixed(1)} %`);
      for (const r of rows.slice(1)) assert(r.along >= 2 * r.across, `Beaufort ${r.force}: foam not streaked along the wind (autocorrelation ${r.along.toFixed(1)} px along, ${r.across.toFixed(1)} px across)`);
    });
  });
}

// Servers of their own that refuse or cap: a full one, one with a small memory cap.
async function capGroup(check, br) {
  await check('a full server is reported as refusing, not as unreachable', async () => {
    if (args.fake) return;
    const port2 = await freePort();
    const full = await startServer({ ...srvOpts, port: port2, extra: ['--max-clients', '1'] });
    const pages = [];
    try {
      for (let i = 0; i < 2; i++) {
        const p = await br.newPage({ viewport: { width: 320, height: 200 } });
        p.on('pageerror', (e) => pageErrors.push(e.message));
        await p.goto(`http://127.0.0.1:${port2}/${QUERY_NODRAW}`);
        pages.push(p);
        if (i === 0) await waitFor(p, 'first client connected', () => window.oceand.connected);
      }
      await waitFor(pages[1], 'second client retrying', () => window.oceand.connectionState === 'retrying', null, 10000);
      await waitFor(pages[1], 'banner saying refused', () => /refused/.test(document.getElementById('banner').textContent), null, 10000);
    } finally {
      for (const p of pages) await p.close();
      await full.stop();
    }
  });

  await check('resolutions over the memory cap are disabled in the panel (capacity)', async () => {
    if (args.fake) return;
    const port3 = await freePort();
    const small = await startServer({ ...srvOpts, port: port3, extra: ['--max-memory-mb', '64', '--resolution', '64'] });
    const p = await br.newPage({ viewport: VIEW });
    p.on('pageerror', (e) => pageErrors.push(e.message));
    try {
      await p.goto(`http://127.0.0.1:${port3}/${QUERY_NODRAW}`);
      await waitFor(p, 'connected', () => window.oceand.connected && window.oceand.params !== null);
      const opts = await p.$$eval('[data-param=resolution] select option',
        (els) => els.map((o) => ({ n: parseInt(o.textContent, 10), disabled: o.disabled, why: o.title })));
      const off = opts.filter((o) => o.disabled), on = opts.filter((o) => !o.disabled);
      assert(off.length > 0 && on.length > 0, `options ${JSON.stringify(opts)}`);
      assert(Math.min(...off.map((o) => o.n)) > Math.max(...on.map((o) => o.n)), `disabled sizes not the largest: ${JSON.stringify(opts)}`);
      assert(off.every((o) => /memory cap/.test(o.why)), `no reason on a disabled size: ${JSON.stringify(off)}`);
      // Open the folders that hold the grid resolution (the schema says which), if closed.
      await p.evaluate(() => {
        for (let f = document.querySelector('[data-param=resolution]').parentElement; f; f = f.parentElement) {
          if (f.classList.contains('lil-gui') && f.classList.contains('closed')) f.querySelector(':scope > .title').click();
        }
      });
      await waitFor(p, 'the reason beside the option', () => {
        const n = document.querySelector('[data-param=resolution] + [data-ui=capacity-note]');
        return n && !n.hidden && n.getBoundingClientRect().height > 0 && /memory cap of 64 MB/.test(n.textContent);
      }, null, 10000).catch(async () => assert(false, `the reason is not beside the option: "${await p.locator('[data-ui=capacity-note]').innerText().catch(() => '')}"`));
    } finally {
      await p.close();
      await small.stop();
    }
  });

  // A daemon that cannot encode the subscription within its budget serves a coarser LOD and
  // says why (`degraded`, PROTOCOL.md §7.2): the HUD shows that reason, not just "lod 1".
  await check('a degraded subscription: the HUD shows the reason the server gave', async () => {
    if (args.fake) return;
    const port4 = await freePort();
    const busy = await startServer({ ...srvOpts, port: port4, extra: ['--encode-budget', '60000'] });
    const p = await br.newPage({ viewport: VIEW });
    p.on('pageerror', (e) => pageErrors.push(e.message));
    try {
      await p.goto(`http://127.0.0.1:${port4}/${QUERY_NODRAW}`, { timeout: 120000 });
      await waitFor(p, 'a degraded message', () => window.oceand.degraded && window.oceand.degraded.reason, null, 60000);
      const d = await p.evaluate(() => window.oceand.degraded);
      await waitFor(p, 'the reason in the HUD', (why) => (document.querySelector('#hud [data-ui=degraded]')?.textContent || '').includes(why), d.reason, 15000)
        .catch(async () => assert(false, `HUD: "${await p.locator('#hud').innerText()}", reason "${d.reason}"`));
      const line = await p.locator('#hud [data-ui=degraded]').innerText();
      console.log(`     HUD: "${line.replace(/\n/g, ' ')}"`);
      assert(d.lod === d.subscribed_lod || line.includes(`lod ${d.lod} (asked ${d.subscribed_lod})`), `the HUD does not say which LOD for which: "${line}"`);
      // Wrapped inside the HUD, not cut off by it.
      const fit = await p.evaluate(() => {
        const h = document.getElementById('hud').getBoundingClientRect(), l = document.querySelector('#hud [data-ui=degraded]').getBoundingClientRect();
        return l.right <= h.right + 0.5 && l.bottom <= h.bottom + 0.5;
      });
      assert(fit, 'the reason runs out of the HUD');
    } finally {
      await p.close();
      await busy.stop();
    }
  });

  // Settings the grids cannot show (a 10 km patch over a 0.5 m deep sea; ?cascades=0, else the
  // finer cascades hold some of the slope): the note that says so lay over the HUD (top
  // centre). It lies in the bottom strip, clear of the HUD, the open panel and the toast.
  await check('the flat-sea note lies clear of the HUD and the panel, on a desktop and a phone', async () => {
    if (args.fake) return;
    const port6 = await freePort();
    const flat = await startServer({ ...srvOpts, port: port6, extra: ['--patch-size', '10000', '--depth', '0.5'] });
    try {
      for (const dev of [null, 'Pixel 7', 'Pixel 7 landscape']) {
        const ctx = await br.newContext(dev ? { ...devices[dev], deviceScaleFactor: 1 } : { viewport: VIEW });
        try {
          const p = await ctx.newPage();
          p.on('pageerror', (e) => pageErrors.push(e.message));
          await p.goto(`http://127.0.0.1:${port6}/${QUERY_NODRAW}&cascades=0`, { timeout: 120000 });
          await waitFor(p, 'the flat-sea note', () => window.oceand.flatNotice && !document.getElementById('flat-note').hidden, null, 60000);
          if (dev) { await p.tap('#panel > .title'); await sleep(600); }
          await waitFor(p, 'the HUD drawn', () => /fps/.test(document.querySelector('.oc-hud-text').textContent), null, 15000);
          const boxes = await p.evaluate(() => {
            const r = (el) => { const b = el.getBoundingClientRect(); return { x: b.left, y: b.top, w: b.width, h: b.height }; };
            return { note: r(document.getElementById('flat-note')), hud: r(document.getElementById('hud')), panel: r(document.getElementById('panel')), vw: innerWidth, vh: innerHeight };
          });
          const n = boxes.note, what = dev || 'desktop';
          // Its text whole and in a few lines (centred by left: 50%, it had half the screen to
          // wrap in: 6 lines on a phone, cut off).
          assert(n.h <= 90, `${what}: the note is ${n.h.toFixed(0)} px tall in a box ${n.w.toFixed(0)} px wide`);
          assert(n.x >= 0 && n.y >= 0 && n.x + n.w <= boxes.vw + 0.5 && n.y + n.h <= boxes.vh + 0.5, `${what}: the note ${JSON.stringify(n)} runs off the screen`);
          for (const k of ['hud', 'panel']) {
            const q = boxes[k];
            assert(!(n.x < q.x + q.w && q.x < n.x + n.w && n.y < q.y + q.h && q.y < n.y + n.h), `${what}: the flat-sea note ${JSON.stringify(n)} lies over the ${k} ${JSON.stringify(q)}`);
          }
          if (!dev) fs.writeFileSync(path.join(args.out, 'flat-note.png'), await p.screenshot({ type: 'png' }));
        } finally { await ctx.close(); }
      }
    } finally { await flat.stop(); }
  });
}

// The side groups share nothing with the main one (their own daemons, pages and browser: a
// browser's pages all draw through its one GPU process, where SwiftShader queues them, so a
// second browser is what lets two drawing pages run at once). They run beside the main group
// once its timing checks are done (the 1 s stall check wants the machine to itself), one after
// the other; their lines carry their tag. --serial: after the main group, in the same browser.
let side = null;
async function sideGroups(br, groups) {
  try {
    for (const [tag, group] of groups) {
      try { await group((name, fn) => check(name, fn, tag), br); } catch (e) { failed++; console.log(`${tag}FAIL harness: ${e.stack || e}`); }
    }
  } finally { if (br !== browser) await br.close().catch(() => {}); }
}
const SIDE = [[['[seams] ', seamGroup]], [['[light] ', lightGroup], ['[caps] ', capGroup]]];
const startSide = () => {
  if (!side && !args.serial) side = Promise.all(SIDE.map((groups) => launchBrowser().then((br) => sideGroups(br, groups))));
};

try {
  await check('display names are checked as the server does (no browser)', async () => {
    for (const ok of ['Ana', 'José María', '日本語の名前', 'x'.repeat(32), '']) assert(checkName(ok) === null, `"${ok}" refused: ${checkName(ok)}`);
    for (const bad of ['x'.repeat(33), '<b>Ana</b>', 'Ana & Bo', '"Ana"', "O'Neil", ' Ana', 'Ana ', 'A\u200bna', 'A\u0007na', 'A\u202ena', 'A\ue000na']) {
      assert(checkName(bad) !== null, `"${bad}" accepted`);
    }
    assert(tidyName('  Ana   Bo ') === 'Ana Bo', 'tidyName');
  });

  const a = await openPage();

  await check('page connects and receives hello', async () => {
    await waitFor(a, 'connected', () => window.oceand.connected && window.oceand.params !== null);
    const s = await state(a);
    assert(typeof s.paramsVersion === 'number', `paramsVersion is ${s.paramsVersion}`);
    assert(s.params && typeof s.params.wind_speed === 'number', 'params has no wind_speed');
    const names = await a.$$eval('[data-param]', (els) => els.map((e) => e.dataset.param));
    for (const k of Object.keys(s.params)) assert(names.includes(k), `panel has no controller for ${k}`);
  });

  await check('panel: human labels, developer switches in a closed folder', async () => {
    const label = await a.locator('[data-param=wind_speed] .name').innerText();
    assert(label === 'Wind speed (m/s)', `wind_speed label "${label}"`);
    const dev = a.locator('[data-folder=developer]');
    assert(await dev.evaluate((el) => el.classList.contains('closed')), 'developer folder is open');
    for (const sel of ['[data-param=transform]', '[data-sub=lod]', '[data-ui=wireframe]']) {
      assert(await a.locator(`[data-folder=developer] ${sel}`).count() === 1, `${sel} is not in the developer folder`);
    }
    assert(await a.locator('[data-folder=sea] [data-param=wind_speed]').count() === 1, 'wind speed is not in the sea folder');
  });

  await check('frames are received, decoded and rendered', async () => {
    await waitFor(a, 'frames received and 3 rendered', () => window.oceand.framesReceived >= 5 && window.oceand.rendered >= 3);
    const s = await state(a);
    assert(s.lastSeq !== null && s.lastSeq > 0, `lastSeq ${s.lastSeq}`);
    assert(s.stats.n >= 16, `N is ${s.stats.n}`);
    assert(s.stats.lastError === null, `error: ${JSON.stringify(s.stats.lastError)}`);
    // The HUD refreshes on its own timer: wait for it to show the stream.
    try {
      await waitFor(a, 'HUD shows N', (n) => {
        const t = document.querySelector('#hud')?.innerText || '';
        return t.includes(`N ${n}`) && t.includes('frames/s');
      }, s.stats.n, 15000);
    } catch (e) {
      const hud = await a.locator('#hud').innerText();
      assert(false, `HUD does not show the stream: "${hud}"`);
    }
    const ro = await a.evaluate(() => {
      try { window.oceand.framesReceived = -1; window.oceand.params.wind_speed = -1; } catch { /* frozen */ }
      return window.oceand.framesReceived !== -1 && window.oceand.params.wind_speed !== -1;
    });
    assert(ro, 'window.oceand is writable');
  });

  await check('temporal codec by default: predicted frames decode in order, no reference error', async () => {
    const f0 = (await state(a)).framesReceived;
    await waitFor(a, '30 more frames', (n) => window.oceand.framesReceived >= n + 30, f0, 60000);
    // This thread busy for a second (as when it compiles shaders or renders slowly in software
    // GL): 30 frames reach it at once. They all go to the decoder, which keeps up: the page
    // drops nothing and stays temporal (the page used to drop past 8 in flight, and give the
    // temporal codec up on the third drop, at once on such a page).
    const d0 = (await state(a)).stats.localDrops;
    await a.evaluate(() => { const t = performance.now(); while (performance.now() - t < 1000); });
    const f1 = (await state(a)).framesReceived;
    await waitFor(a, '10 more frames after the stall', (n) => window.oceand.framesReceived >= n + 10, f1, 60000);
    const s = await state(a);
    assert(s.stats.localDrops === d0, `the page dropped frames after a 1 s stall of its main thread: ${d0} -> ${s.stats.localDrops}`);
    // The burst after the stall is not a faster stream: the rate is counted on the server's clock
    // (the daemon ticks at 30 Hz by default; a burst read on the page's clock gave up to 90).
    assert(s.stats.framesPerSec > 0 && s.stats.framesPerSec <= 33, `stream rate after the stall ${s.stats.framesPerSec.toFixed(1)} frames/s from a 30 Hz daemon`);
    // Giving the temporal codec up happens only after the start-up grace, when the decoder itself
    // fell behind three times in 10 s (worker.js MAX_WAIT_MS).
    const fb = s.stats.fallback;
    assert(s.stats.temporal === true || (fb && s.stats.firstDrawnMs !== null && fb.atMs >= s.stats.firstDrawnMs + s.stats.graceMs && fb.drops >= 3),
      `the page gave the temporal codec up: ${JSON.stringify(fb)}, first frame drawn at ${s.stats.firstDrawnMs} ms`);
    // A reference error is only allowed after the page itself dropped a frame (its decoder
    // fell a second behind on a loaded machine): the server never breaks the chain.
    assert(s.stats.lastError === null && (s.stats.referenceErrors === 0 || s.stats.localDrops > 0),
      `decode errors: ${s.stats.referenceErrors} reference (${s.stats.localDrops} dropped by the page), last ${JSON.stringify(s.stats.lastError)}`);
    if (!args.fake) {
      // The page asks for parts (PROTOCOL.md §3.4): its first frames, keyframes of ~100 kB, come
      // in parts of at most 64 kB, which it joins (the decode checks above saw the result).
      assert(s.subscription && s.subscription.parts === true, `subscription in force ${JSON.stringify(s.subscription)}`);
      assert(s.stats.framesInParts > 0, 'no frame came in parts');
    }
    if (!args.fake) { // the daemon sent it predicted (shared) tiles, not only keyframes...
      const m = await (await fetch(`http://127.0.0.1:${port}/metrics`)).text();
      const num = (re) => Number((m.match(re) || [])[1]);
      const shared = num(/^oceand_temporal_tiles_sent_total\{kind="shared"\} (\S+)$/m);
      const degraded = num(/^oceand_degraded_groups (\S+)$/m);
      const intra = num(/^oceand_intra_groups (\S+)$/m);
      // ...unless the capacity plan thinned the stream (every frame then follows a gap: keyframes,
      // PROTOCOL.md §5.9), served it intra (the codec rung: the temporal codec did not fit the
      // tick on a loaded machine), or the page gave the temporal codec up (its worker fell behind).
      if (degraded === 0 && intra === 0 && s.stats.temporal && s.stats.localDrops === 0)
        assert(shared > 0, `no shared (predicted) tiles sent: ${shared}`);
      else console.log(`     (not checked: ${degraded} degraded groups, ${intra} served intra, ${s.stats.localDrops} frames dropped by the page)`);
    }
  });

  startSide(); // the timing checks above are done: the side groups may start

  await check('foam: the shared foam field is subscribed at a coarse LOD and drawn', async () => {
    if (args.fake) return;
    await waitFor(a, 'foam drawn from the field', () => window.oceand.foam.source === 'field', null, 20000);
    // (a daemon short of CPU serves a coarser surface for a while: the assert below reads the
    // LOD once it is back at 0, or after 30 s)
    await waitFor(a, 'the surface at lod 0', () => window.oceand.stats.lod === 0, null, 30000).catch(() => {});
    const s = await a.evaluate(() => ({ foam: window.oceand.foam, sub: window.oceand.subscription, n: window.oceand.stats.n, lod: window.oceand.stats.lod }));
    assert(s.sub && s.sub.fields.includes('foam') && s.sub.fields.includes('height'), `subscription ${JSON.stringify(s.sub)}`);
    // A 64×64 foam grid for any N (N = 256: lod 2), the surface at its own LOD.
    const want = Math.round(Math.log2(s.n / 64));
    assert(s.sub.field_lod && s.sub.field_lod.foam === want && s.foam.lod === want && s.foam.size === 64, `foam ${JSON.stringify(s.foam)}, subscription ${JSON.stringify(s.sub)}`);
    assert(s.lod === 0, `the surface came at lod ${s.lod}`);
    // ?foam=0 (or a server without the field): foam from the folds, no foam asked for
    // (the page may still subscribe, for the finer cascades).
    const p = await browser.newPage({ viewport: { width: 320, height: 200 } });
    p.on('pageerror', (e) => pageErrors.push(e.message));
    try {
      await p.goto(`${url}&draw=0&foam=0`, { timeout: 120000 });
      await waitFor(p, 'rendering', () => window.oceand.rendered > 1, null, 60000);
      const q = await p.evaluate(() => ({ foam: window.oceand.foam, sub: window.oceand.subscription }));
      const asked = q.sub && ((q.sub.fields || []).includes('foam') || q.sub.field_lod);
      assert(q.foam.source === 'jacobian' && !asked, `?foam=0: ${JSON.stringify(q)}`);
    } finally { await p.close(); }
  });

  await check('canvas shows a varied image (not a flat colour)', async () => {
    await renderedMore(a, 1);
    const base = await shot(a, 'base');
    const v = base.variance;
    fs.writeFileSync(path.join(args.out, 'ocean.png'), base.png);
    console.log(`     pixel variance ${v.toFixed(1)}; screenshot ${path.join(args.out, 'ocean.png')}`);
    assert(v > 20, `pixel variance ${v.toFixed(2)} is too low: the canvas looks flat`);
  });

  await check('wireframe toggle changes the image', async () => {
    await domClick(a, '[data-folder=developer] > .title'); // wireframe and freeze are developer switches
    // lil-gui opens a folder over two animation frames and a height transition; until it ends
    // the folder's title lies over its first switches.
    await waitFor(a, 'the developer folder open', () => {
      const f = document.querySelector('[data-folder=developer]');
      return !f.classList.contains('closed') && !f.classList.contains('transition');
    }, null, 30000);
    await domClick(a, '[data-ui=freeze] input');          // hold the sea still: only the toggle may change pixels
    await renderedMore(a, 2);
    await shot(a, 'still1');
    await shot(a, 'still2');
    await domClick(a, '[data-ui=wireframe] input');
    await waitFor(a, 'wireframe on', () => window.oceand.wireframe === true, null, 5000);
    await renderedMore(a, 1);
    const wire = await shot(a, 'wire');
    fs.writeFileSync(path.join(args.out, 'wireframe.png'), wire.png);
    const noise = await shotDiff(a, 'still1', 'still2'), diff = await shotDiff(a, 'still1', 'wire');
    console.log(`     frozen-vs-frozen diff ${noise.toFixed(2)}, solid-vs-wireframe diff ${diff.toFixed(2)}`);
    assert(diff > 3 && diff > 4 * noise, `wireframe changed the image by only ${diff.toFixed(2)} (noise ${noise.toFixed(2)})`);
    await domClick(a, '[data-ui=wireframe] input');
    await domClick(a, '[data-ui=freeze] input');
    await waitFor(a, 'wireframe off', () => window.oceand.wireframe === false, null, 5000);
  });

  await check('double-click drops a buoy: probe and exact query agree', async () => {
    if (args.fake) return;
    const box = await a.locator('#ocean').boundingBox();
    await a.mouse.dblclick(box.x + box.width / 2, box.y + box.height * 0.7); // below the horizon: the sea
    await waitFor(a, 'probe values and an exact query', () => window.oceandProbe.probe && window.oceandProbe.exact,
      null, 15000);
    const r = await a.evaluate(() => ({ p: window.oceandProbe.point, e: window.oceandProbe.exact,
      label: [...document.querySelectorAll('div')].map((d) => d.textContent).find((t) => t.startsWith('buoy')) }));
    const diff = Math.abs(r.e.probeHeight - r.e.height);
    console.log(`     buoy at (${r.p[0].toFixed(1)}, ${r.p[1].toFixed(1)}): probe - exact = ${(diff * 1000).toFixed(1)} mm`);
    assert(diff < 0.05, `probe ${r.e.probeHeight} vs exact ${r.e.height}`);
    assert(r.label && r.label.includes('exact query'), `no buoy label: ${r.label}`);
    // Double-clicking the label removes the buoy. The label (bottom left) changes its text, so
    // its width, with every probe message: near its left end, without waiting for it to hold still.
    await a.getByText(/^buoy \(/).dblclick({ position: { x: 12, y: 6 }, force: true });
    await waitFor(a, 'buoy removed', () => window.oceandProbe.point === null, null, 5000);
  });

  const b = await openPage(QUERY_NODRAW); // its checks read its panel and state, not pixels
  await check('a set in one page reaches the other page and the frames, with a display name', async () => {
    await waitFor(b, 'second page connected', () => window.oceand.connected && window.oceand.framesReceived > 0);
    // Page A names itself in the panel; a name the server would refuse is not sent.
    const nameInput = a.locator('[data-ui=name] input');
    await nameInput.fill('<b>Ana</b>');
    await nameInput.press('Enter');
    await waitFor(a, 'the panel says why', () => /name not set/.test(document.querySelector('[data-ui=last-change]').textContent), null, 5000);
    await nameInput.fill('  Ana ');
    await nameInput.press('Enter');
    await waitFor(a, 'the server has the name', () => window.oceand.name === 'Ana', null, 15000);
    assert(await a.evaluate(() => localStorage.getItem('oceand.name')) === 'Ana', 'name not kept in localStorage');
    const before = await state(b);
    const target = before.params.wind_speed === 17.5 ? 13.25 : 17.5;
    const input = a.locator('[data-param=wind_speed] input').first();
    await input.fill(String(target));
    await input.press('Enter');
    await waitFor(b, `page B params.wind_speed == ${target}`, (t) => window.oceand.params.wind_speed === t, target, 15000);
    const sb = await state(b);
    assert(sb.paramsVersion > before.paramsVersion, `version did not grow: ${before.paramsVersion} -> ${sb.paramsVersion}`);
    const shown = await b.locator('[data-param=wind_speed] input').first().inputValue();
    assert(Number(shown) === target, `page B panel shows ${shown}, want ${target}`);
    const idA = (await state(a)).clientId;
    // Page A has a control connection (no frames on it, PROTOCOL.md §1.2) and sent the set on
    // both under one "once" key: the copy applied came from one of its two sessions, and the
    // other's `duplicate` is not shown as a refusal (the note below says "you set").
    const ctlA = await a.evaluate(() => window.oceand.controlId);
    assert(ctlA && ctlA !== idA, `page A has no control connection (${ctlA})`);
    assert([idA, ctlA].includes(sb.paramsBy), `the change came from ${sb.paramsBy}, not page A (${idA}, ${ctlA})`);
    const note = await b.locator('[data-ui=last-change]').innerText();
    assert(/^Ana set Wind speed/.test(note) && note.includes(String(target)) && !note.includes(idA), `page B does not say who changed what: "${note}"`);
    const own = await a.locator('[data-ui=last-change]').innerText();
    assert(/^you set Wind speed/.test(own) && !own.includes(idA), `page A does not say "you": "${own}"`);
    await waitFor(b, `frames with params_version ${sb.paramsVersion}`, (v) => window.oceand.frameParamsVersion >= v, sb.paramsVersion, 15000);
    await waitFor(a, 'page A frames with the new version', (v) => window.oceand.frameParamsVersion >= v, sb.paramsVersion, 15000);
  });
  await check('typed values out of range are refused in the panel with the range, not clamped and sent', async () => {
    await waitFor(b, 'second page connected', () => window.oceand.connected && window.oceand.framesReceived > 0);
    await waitFor(a, 'page A has the same version', (v) => window.oceand.paramsVersion === v, (await state(b)).paramsVersion, 15000);
    const v0 = (await state(b)).paramsVersion, w0 = (await state(b)).params.wind_speed;
    const input = a.locator('[data-param=wind_speed] input').first();
    for (const bad of ['-5', '1e9']) {
      await input.fill(bad);
      await input.press('Enter');
      await waitFor(a, `the panel refuses ${bad}`, (t) => document.querySelector('[data-ui=last-change]').textContent.includes(`${Number(t)} is outside 0 to 40`), bad, 5000)
        .catch(async () => assert(false, `note after typing ${bad}: "${await a.locator('[data-ui=last-change]').innerText()}"`));
      assert(Number(await input.inputValue()) === w0, `the field shows ${await input.inputValue()} after refusing ${bad}, not ${w0}`);
    }
    // A valid value now: if a refused one had been sent, the version would have moved twice.
    const good = w0 === 12.5 ? 11.5 : 12.5;
    await input.fill(String(good));
    await input.press('Enter');
    await waitFor(b, 'page B has the valid value', (g) => window.oceand.params.wind_speed === g, good, 15000);
    const v1 = (await state(b)).paramsVersion;
    assert(v1 === v0 + 1, `parameters version ${v0} -> ${v1}: something besides the valid value was sent`);
    // The wind's compass says where the wind comes from beside where it blows.
    const compass = await a.locator('[data-ui=compass] .oc-compass-text').innerText();
    const dir = (await state(a)).params.wind_direction;
    assert(/from [NESW]{1,3} \(\d+°\), blowing toward [NESW]{1,3} \(\d+°\)/.test(compass), `compass: "${compass}"`);
    if (dir === 0) assert(compass.startsWith('from E (90°)') && compass.includes('toward W (270°)'), `wind toward +x (west) reads "${compass}"`);
  });
  await check('a sea preset is one shared set: it applies and syncs to the other page', async () => {
    const storm = SEA_PRESETS.find((p) => p.name === 'storm');
    const v0 = (await state(b)).paramsVersion;
    await domClick(a, '[data-preset=storm]');
    await waitFor(b, 'page B has the storm parameters', (want) => Object.entries(want).every(([k, v]) => window.oceand.params[k] === v), storm.params, 15000);
    const sb = await state(b);
    assert(sb.paramsVersion === v0 + 1, `one preset should be one set: version ${v0} -> ${sb.paramsVersion}`);
    await waitFor(b, 'page B marks the storm preset', () => document.querySelector('[data-preset=storm]').classList.contains('oc-active'), null, 5000);
    const note = await b.locator('[data-ui=last-change]').innerText();
    assert(note.includes('storm') && note.startsWith('Ana '), `page B's note: "${note}"`);
    // Page A renders in software GL, so it may read the broadcast later than page B.
    await waitFor(a, 'page A says "you chose storm"', () => document.querySelector('[data-ui=last-change]').innerText.startsWith('you chose storm'), null, 30000)
      .catch(async () => assert(false, `page A's note: "${await a.locator('[data-ui=last-change]').innerText()}"`));
    await waitFor(b, 'the sky of page B follows the wind (overcast)', () => window.oceand.view.sky && window.oceand.view.sky.overcast > 0.95, null, 10000);
    await domClick(a, '[data-preset=fresh]');
    await waitFor(b, 'page B back to fresh', () => window.oceand.params.wind_speed === 9.4, null, 15000);
    // The next check photographs page A: it must be back to fresh (not the storm's overcast) too.
    await waitFor(a, 'page A back to fresh', () => window.oceand.params.wind_speed === 9.4, null, 30000);
    await renderedMore(a, 2);
  });

  await check('view presets are local: night is darker than noon but not black', async () => {
    await domClick(a, '[data-view=noon]');
    await waitFor(a, 'noon', () => window.oceand.view.sky.sunAltitudeDeg > 50);
    await renderedMore(a, 2);
    const noon = await shot(a, 'noon');
    await domClick(a, '[data-view=night]');
    await waitFor(a, 'night', () => window.oceand.view.sky.sunAltitudeDeg < -20);
    await renderedMore(a, 2);
    const night = await shot(a, 'night');
    fs.writeFileSync(path.join(args.out, 'night.png'), night.png);
    console.log(`     mean pixel value noon ${noon.mean.toFixed(1)}, night ${night.mean.toFixed(1)}, night variance ${night.variance.toFixed(1)}`);
    assert(night.mean < 0.6 * noon.mean, `night (${night.mean.toFixed(1)}) is not darker than noon (${noon.mean.toFixed(1)})`);
    assert(night.mean > 12 && night.variance > 4, `night is black (mean ${night.mean.toFixed(1)}, variance ${night.variance.toFixed(1)})`);
    const hb = (await state(b)).view.hour;
    assert(hb !== 23, `page B's time of day changed with page A's (${hb})`);
    await domClick(a, '[data-view=sunset]');
  });

  await check('the HUD can be hidden (button and H key) and stays hidden after a reload', async () => {
    await b.click('[data-ui=hud-toggle]');
    assert(await b.locator('.oc-hud-text').isHidden(), 'HUD text still shown');
    await b.reload({ timeout: 120000 }); // slow while page A renders in software GL
    await waitFor(b, 'page B reconnected', () => window.oceand.connected);
    assert(await b.locator('.oc-hud-text').isHidden(), 'HUD shown again after a reload');
    await b.keyboard.press('h');
    await waitFor(b, 'HUD shown by the H key', () => window.oceand.view.hud === true, null, 5000);
    // (30 s: right after a reload the first draw waits for the water shader to compile, slow in software GL)
    await waitFor(b, 'HUD text drawn', () => /fps/.test(document.querySelector('.oc-hud-text').textContent), null, 30000);
    assert(await b.locator('.oc-hud-text').isVisible(), 'HUD text not visible after H');
  });
  await b.close();

  await check('daemon killed and restarted: the page reconnects', async () => {
    await server.stop();
    await waitFor(a, 'disconnected', () => !window.oceand.connected, null, 10000);
    const banner = await a.locator('#banner').innerText();
    assert(/unreachable|lost|retrying/.test(banner), `no clear message while down: "${banner}"`);
    // The panel is locked and greyed while down: no shared control can be used.
    const locked = await a.evaluate(() => ({
      offline: document.getElementById('panel').classList.contains('oc-offline'),
      inputs: [...document.querySelectorAll('[data-param] input, [data-param] select')].map((e) => e.disabled),
      presets: [...document.querySelectorAll('[data-preset]')].map((e) => e.disabled),
    }));
    assert(locked.offline, 'panel not marked offline');
    assert(locked.inputs.length > 5 && locked.inputs.every(Boolean), `panel inputs editable while down: ${JSON.stringify(locked.inputs)}`);
    assert(locked.presets.length === 5 && locked.presets.every(Boolean), 'sea presets usable while down');
    await sleep(500);
    server = await startServer(srvOpts);
    const f0 = (await state(a)).framesReceived;
    await waitFor(a, 'reconnected and receiving frames', (f) => window.oceand.connected && window.oceand.framesReceived > f + 3, f0, 30000);
    assert(await a.locator('#banner').isHidden(), 'banner still shown after reconnecting');
    const enabled = await a.evaluate(() => [...document.querySelectorAll('[data-param] input')].every((e) => !e.disabled));
    assert(enabled, 'panel still locked after reconnecting');
    // The new daemon has no saved state (a new state file): the sea was reset, and the page says so.
    await waitFor(a, 'the note says the server restarted', () => /server restarted and the sea was reset: .*→/.test(window.oceand.note.panel), null, 15000)
      .catch(async () => assert(false, `note after the restart: "${(await state(a)).note.panel}"`));
  });

  { // (a loaded machine can put page A behind: say when it asked for less, catchup.js)
    const ev = await a.evaluate(() => window.oceand.catchup?.events || []).catch(() => []);
    if (ev.length) console.log(`     page A stepped ${ev.map((e) => `${e.from}->${e.step} at ${(e.atMs / 1000).toFixed(0)} s (lag ${e.lagMs} ms)`).join(', ')}`);
  }
  await a.close(); // a rendering page in the background only slows the rest down


  // Phones: playwright's device descriptors (viewport, touch, mobile user agent), with
  // deviceScaleFactor 1 so that SwiftShader renders 1/7 of the pixels (layout is in CSS px).
  const deadPort = await freePort();
  for (const name of ['Pixel 7', 'Pixel 7 landscape', 'iPhone 13', 'iPhone 13 landscape']) {
    await check(`phone ${name}: panel closed, HUD/panel/banner disjoint, one-finger drag orbits`, async () => {
      const ctx = await browser.newContext({ ...devices[name], deviceScaleFactor: 1 });
      try {
        const p = await ctx.newPage();
        p.on('pageerror', (e) => pageErrors.push(e.message));
        await p.goto(`${url}&draw=0`);
        await waitFor(p, 'connected and rendering', () => window.oceand.connected && window.oceand.rendered > 1);
        await layoutCheck(p, name, false);
        // A one-finger drag across the middle of the screen turns the camera around its target.
        const vp = devices[name].viewport;
        const az = (c) => Math.atan2(c.position[0] - c.target[0], c.position[2] - c.target[2]);
        const before = (await state(p)).camera;
        const cdp = await ctx.newCDPSession(p);
        const y = Math.round(vp.height * 0.6), x0 = Math.round(vp.width * 0.3), x1 = Math.round(vp.width * 0.7);
        await cdp.send('Input.dispatchTouchEvent', { type: 'touchStart', touchPoints: [{ x: x0, y }] });
        for (let k = 1; k <= 8; k++) await cdp.send('Input.dispatchTouchEvent', { type: 'touchMove', touchPoints: [{ x: x0 + (x1 - x0) * k / 8, y }] });
        await cdp.send('Input.dispatchTouchEvent', { type: 'touchEnd', touchPoints: [] });
        await renderedMore(p, 2);
        const after = (await state(p)).camera;
        const turned = Math.abs(az(after) - az(before)) * 180 / Math.PI;
        assert(turned > 10, `one-finger drag turned the camera by ${turned.toFixed(1)}°`);
        if (name === 'Pixel 7' && !args.fake) { // another user's change reaches the phone with its panel closed
          const w = (await state(p)).params.wind_speed === 14 ? 15 : 14;
          await setParams(port, { wind_speed: w });
          await waitFor(p, 'a note outside the closed panel', (w) => {
            const t = document.querySelector('[data-ui=toast]');
            return t && !t.hidden && t.getBoundingClientRect().height > 0 && t.textContent.includes(`Wind speed ${w}`);
          }, w, 15000).catch(async () => assert(false, `no note on the phone: ${JSON.stringify((await state(p)).note)}`));
        }
        // In landscape (390 px high) the open panel ran to 55 % of the height: two controls,
        // and "Wind direction, toward (deg)" cut off. It now runs the height of the screen:
        // the first controls of the Sea folder lie wholly inside it, and no label overflows.
        if (name.includes('landscape')) {
          await p.tap('#panel > .title');
          const opened = () => waitFor(p, 'the panel open and still', () => !document.getElementById('panel').classList.contains('closed') && !document.querySelector('#panel.transition, #panel .transition'), null, 5000);
          await opened().catch(async () => { await p.evaluate(() => document.querySelector('#panel > .title').click()); await opened(); }); // (a tap lost while busy)
          const r = await p.evaluate(() => {
            const pn = document.getElementById('panel'), box = pn.querySelector(':scope > .children').getBoundingClientRect();
            const rows = [...pn.querySelectorAll('[data-folder=sea] .controller')].slice(0, 3).map((c) => {
              const b = c.getBoundingClientRect(), n = c.querySelector('.name');
              return { label: n.textContent, inside: b.top >= box.top - 0.5 && b.bottom <= box.bottom + 0.5, clipped: n.scrollWidth > n.clientWidth + 1 || n.scrollHeight > n.clientHeight + 1 || n.getBoundingClientRect().bottom > b.bottom + 1 };
            });
            return { h: pn.getBoundingClientRect().height, vh: innerHeight, rows };
          });
          assert(r.h >= 0.8 * r.vh, `${name}: the open panel is ${r.h.toFixed(0)} px of ${r.vh}`);
          assert(r.rows.length === 3 && r.rows.every((x) => x.inside && !x.clipped), `${name}: controls cut off: ${JSON.stringify(r.rows)}`);
        }
        await p.close();
        // A page whose server is down: the banner joins the HUD and the panel title.
        const d = await ctx.newPage();
        await d.goto(`${url}&draw=0&server=ws://127.0.0.1:${deadPort}/`);
        await waitFor(d, 'banner shown', () => !document.getElementById('banner').hidden && /unreachable/.test(document.getElementById('banner').textContent), null, 10000);
        await layoutCheck(d, `${name} (server down)`, true);
        await d.tap('#panel > .title');
        await waitFor(d, 'panel opened', () => !document.getElementById('panel').classList.contains('closed'), null, 5000);
        await sleep(400); // lil-gui's open animation
        await layoutCheck(d, `${name} (panel open)`, true, true);
      } finally { await ctx.close(); }
    });
  }

  // A page whose main thread is slow (here a busy loop of 500 ms every animation frame, by
  // window.oceandTest; like software GL drawing on it) reads its socket slower than the stream
  // comes: the browser holds the rest and the page showed an ever older sea (49 s -> 189 s in
  // 150 s) under a HUD that read a healthy frame rate. It must notice, say so, ask for less
  // (a coarser subscription on a fresh connection) so that its lag stops growing, and come
  // back to the full stream once its thread is free again.
  {
    const ctx = await browser.newContext({ viewport: VIEW }); // a renderer of its own: the loop slows no other page
    const p = await ctx.newPage();
    p.on('pageerror', (e) => pageErrors.push(e.message));
    try {
      await p.goto(`http://127.0.0.1:${port}/${QUERY_BASE}&draw=0`, { timeout: 120000 });
      await waitFor(p, 'connected and rendering', () => window.oceand.connected && window.oceand.rendered > 3, null, 120000);
      await check('HUD: on loopback the link line says the link is local, not a rate', async () => {
        await waitFor(p, 'the link line', () => !!document.querySelector('#hud [data-ui=link]'), null, 15000);
        const line = await p.locator('#hud [data-ui=link]').innerText();
        assert(/local/.test(line) && !/\d+(\.\d)? [GM]bit\/s/.test(line), `link line on loopback: "${line}"`);
      });
      await check('a page that falls behind says so, asks for less, stops falling behind and recovers', async () => {
        if (args.fake) return;
        await waitFor(p, 'the grace after the first frame', () => performance.now() > window.oceand.stats.firstDrawnMs + window.oceand.stats.graceMs, null, 30000);
        const r0 = await p.evaluate(() => ({ sub: window.oceand.subscription, step: window.oceand.catchup.step }));
        assert(r0.step === 0, `the page asks for less before it is slowed: ${JSON.stringify(r0)}`);
        await p.evaluate(() => window.oceandTest.options({ busyMs: 500 }));
        const lags = [];
        const sample = async () => { const c = await p.evaluate(() => window.oceand.catchup); lags.push([Date.now(), c.lagMs, c.step]); return c; };
        // Noticed and asked for less (it steps down once its lag stays over 1 s for 3 s).
        const tDown = Date.now() + 120000;
        let c = await sample();
        while (c.step === 0 && Date.now() < tDown) { await sleep(500); c = await sample(); }
        assert(c.step > 0, `the page never asked for less; lags ${JSON.stringify(lags.slice(-10))}`);
        const ev = c.events.find((e) => e.step > e.from);
        console.log(`     slowed: lag ${ev.lagMs} ms, reads ${ev.readKBps} kB/s of ${ev.wantKBps} wanted -> step ${ev.step} (${c.asked})`);
        const hud = await p.locator('#hud [data-ui=behind]').innerText().catch(() => '');
        assert(/behind|slow/.test(hud) && /asking for less/.test(hud) && /lod \d/.test(hud), `the HUD does not say so: "${hud}"`);
        await waitFor(p, 'the coarser subscription in force', (lod0) => (window.oceand.subscription?.lod ?? 0) > lod0, r0.sub?.lod ?? 0, 30000)
          .catch(async () => assert(false, `subscription in force ${JSON.stringify(await p.evaluate(() => window.oceand.subscription))}`));
        // Its lag stops growing: over the 12 s after that, still slowed, it stays under 1 s.
        const t1 = Date.now() + 12000;
        while (Date.now() < t1) { await sleep(1000); c = await sample(); }
        const tail = lags.filter(([t]) => t > t1 - 8000).map(([, l]) => l).filter((l) => l !== null);
        console.log(`     lag while slowed, after asking for less: ${tail.map((l) => (l / 1000).toFixed(1)).join(' ')} s (step ${c.step})`);
        assert(tail.length >= 4 && Math.max(...tail) < 1000, `still falling behind after asking for less: ${JSON.stringify(tail)}`);
        // Its thread free again: back to the full stream, and the HUD says so.
        await p.evaluate(() => window.oceandTest.options({ busyMs: 0 }));
        await waitFor(p, 'back to the full stream, and the HUD says so', () => window.oceand.catchup.step === 0
          && /caught up/.test(document.querySelector('#hud [data-ui=behind]')?.textContent || ''), null, 120000)
          .catch(async () => assert(false, `not back: ${JSON.stringify(await p.evaluate(() => window.oceand.catchup))}; HUD "${await p.locator('#hud').innerText()}"`));
        await waitFor(p, 'the subscription as chosen again', (lod0) => (window.oceand.subscription?.lod ?? 0) === lod0, r0.sub?.lod ?? 0, 30000);
      });
    } finally { await ctx.close(); }
  }

  await check('tablet: the open panel leaves most of the sea in view, apart from the HUD', async () => {
    const ctx = await browser.newContext({ ...devices['iPad Mini'], deviceScaleFactor: 1 });
    try {
      const p = await ctx.newPage();
      p.on('pageerror', (e) => pageErrors.push(e.message));
      await p.goto(`${url}&draw=0`);
      await waitFor(p, 'connected', () => window.oceand.connected && window.oceand.params !== null);
      const r = await p.evaluate(() => {
        const b = (el) => el.getBoundingClientRect();
        const pn = b(document.getElementById('panel')), h = b(document.getElementById('hud'));
        return { share: (pn.width * pn.height) / (innerWidth * innerHeight), overlap: h.right > pn.left && pn.right > h.left && h.bottom > pn.top && pn.bottom > h.top, open: !document.getElementById('panel').classList.contains('closed') };
      });
      console.log(`     open panel covers ${(100 * r.share).toFixed(0)} % of the screen`);
      assert(r.share <= 0.2, `the open panel covers ${(100 * r.share).toFixed(0)} % of a tablet's screen`);
      assert(!r.overlap, 'the panel overlaps the HUD');
    } finally { await ctx.close(); }
  });

  // What sea the page says it shows: the compass, the sea line, the polar plot (sea_checks.mjs).
  await seaChecks({ check, browser, url, devices, pageErrors, assert, waitFor, tap: args.fake ? null : path.join(path.dirname(args.oceand), 'ocean-tap') });

  if (side) await side; else for (const groups of SIDE) await sideGroups(browser, groups);

  await check('no uncaught errors in the pages', async () => {
    assert(pageErrors.length === 0, pageErrors.join('; '));
  });
} catch (e) {
  failed++;
  console.log(`FAIL harness: ${e.stack || e}`);
} finally {
  if (side) await side.catch(() => {});
  await browser.close().catch(() => {});
  await server.stop().catch(() => {});
}
console.log(`${passed} passed, ${failed} failed (${((Date.now() - T0) / 1000).toFixed(0)} s)`);
process.exit(failed ? 1 : 0);

// End-to-end tests of the web client against a real oceand on loopback, in
// headless Debian chromium (software WebGL2 through SwiftShader).
//   node tests/web/test_web.mjs --oceand build/oceand --web-root build/web --out build/web-test
// Closing line: "N passed, M failed"; exit status 1 on any failure.
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs, freePort, startServer, launchBrowser, waitFor, sleep } from './harness.mjs';

const args = parseArgs(process.argv, { oceand: 'build/oceand', webRoot: 'build/web', out: 'build/web-test', fake: false });
fs.mkdirSync(args.out, { recursive: true });
const VIEW = { width: 800, height: 500 };
// test: keep the drawing buffer; aa=0: no MSAA; detail: a lighter mesh (software GL is slow)
const QUERY = '?test=1&aa=0&detail=0.25';

let passed = 0, failed = 0;
async function check(name, fn) {
  const t0 = Date.now();
  try {
    await fn();
    passed++;
    console.log(`ok   ${name} (${((Date.now() - t0) / 1000).toFixed(1)} s)`);
  } catch (e) {
    failed++;
    console.log(`FAIL ${name}: ${e.message}`);
  }
}
function assert(cond, msg) { if (!cond) throw new Error(msg); }

// Screenshots are decoded by the browser itself and their pixels kept in the
// page (window.__shots[name]); only statistics come back. Region: the water
// below the horizon, left of the panel and below the HUD (so neither can make a
// flat canvas look varied).
async function shot(page, name) {
  const png = await page.screenshot({ type: 'png' });
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
    return s2 / px.length - (s / px.length) ** 2;
  }, { b64: png.toString('base64'), name });
  return { png, variance };
}
// Mean absolute difference (0..255) between two kept screenshots.
const shotDiff = (page, a, b) => page.evaluate(([a, b]) => {
  const p = window.__shots[a], q = window.__shots[b];
  let s = 0;
  for (let i = 0; i < p.length; i++) s += Math.abs(p[i] - q[i]);
  return s / p.length;
}, [a, b]);
const state = (page) => page.evaluate(() => ({ ...window.oceand, params: window.oceand.params, stats: window.oceand.stats }));
const renderedMore = async (page, k) => {
  const r = (await state(page)).rendered;
  await waitFor(page, `${k} more rendered frames`, ([r0, n]) => window.oceand.rendered >= r0 + n, [r, k]);
};

const port = await freePort();
const srvOpts = { oceand: args.oceand, webRoot: args.webRoot, port, fake: args.fake };
let server = await startServer(srvOpts);
console.log(`web tests against ${args.fake ? 'the FAKE server' : args.oceand} on 127.0.0.1:${port}`);
const browser = await launchBrowser();
const url = `http://127.0.0.1:${port}/${QUERY}`;
const pageErrors = [];
async function openPage() {
  const p = await browser.newPage({ viewport: VIEW });
  p.on('pageerror', (e) => pageErrors.push(e.message));
  await p.goto(url);
  return p;
}

try {
  const a = await openPage();

  await check('page connects and receives hello', async () => {
    await waitFor(a, 'connected', () => window.oceand.connected && window.oceand.params !== null);
    const s = await state(a);
    assert(typeof s.paramsVersion === 'number', `paramsVersion is ${s.paramsVersion}`);
    assert(s.params && typeof s.params.wind_speed === 'number', 'params has no wind_speed');
    const names = await a.$$eval('[data-param]', (els) => els.map((e) => e.dataset.param));
    for (const k of Object.keys(s.params)) assert(names.includes(k), `panel has no controller for ${k}`);
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

  await check('canvas shows a varied image (not a flat colour)', async () => {
    await renderedMore(a, 1);
    const base = await shot(a, 'base');
    const v = base.variance;
    fs.writeFileSync(path.join(args.out, 'ocean.png'), base.png);
    console.log(`     pixel variance ${v.toFixed(1)}; screenshot ${path.join(args.out, 'ocean.png')}`);
    assert(v > 20, `pixel variance ${v.toFixed(2)} is too low: the canvas looks flat`);
  });

  await check('wireframe toggle changes the image', async () => {
    await a.click('[data-ui=freeze] input');          // hold the sea still: only the toggle may change pixels
    await renderedMore(a, 2);
    await shot(a, 'still1');
    await shot(a, 'still2');
    await a.click('[data-ui=wireframe] input');
    await waitFor(a, 'wireframe on', () => window.oceand.wireframe === true, null, 5000);
    await renderedMore(a, 1);
    const wire = await shot(a, 'wire');
    fs.writeFileSync(path.join(args.out, 'wireframe.png'), wire.png);
    const noise = await shotDiff(a, 'still1', 'still2'), diff = await shotDiff(a, 'still1', 'wire');
    console.log(`     frozen-vs-frozen diff ${noise.toFixed(2)}, solid-vs-wireframe diff ${diff.toFixed(2)}`);
    assert(diff > 3 && diff > 4 * noise, `wireframe changed the image by only ${diff.toFixed(2)} (noise ${noise.toFixed(2)})`);
    await a.click('[data-ui=wireframe] input');
    await a.click('[data-ui=freeze] input');
    await waitFor(a, 'wireframe off', () => window.oceand.wireframe === false, null, 5000);
  });

  const b = await openPage();
  await check('a set in one page reaches the other page and the frames', async () => {
    await waitFor(b, 'second page connected', () => window.oceand.connected && window.oceand.framesReceived > 0);
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
    const note = await b.locator('[data-ui=last-change]').innerText();
    assert(note.includes(idA) && note.includes('wind_speed'), `page B does not say who changed what: "${note}"`);
    await waitFor(b, `frames with params_version ${sb.paramsVersion}`, (v) => window.oceand.frameParamsVersion >= v, sb.paramsVersion, 15000);
    await waitFor(a, 'page A frames with the new version', (v) => window.oceand.frameParamsVersion >= v, sb.paramsVersion, 15000);
  });
  await b.close();

  await check('daemon killed and restarted: the page reconnects', async () => {
    await server.stop();
    await waitFor(a, 'disconnected', () => !window.oceand.connected, null, 10000);
    const banner = await a.locator('#banner').innerText();
    assert(/unreachable|lost|retrying/.test(banner), `no clear message while down: "${banner}"`);
    await sleep(500);
    server = await startServer(srvOpts);
    const f0 = (await state(a)).framesReceived;
    await waitFor(a, 'reconnected and receiving frames', (f) => window.oceand.connected && window.oceand.framesReceived > f + 3, f0, 30000);
    assert(await a.locator('#banner').isHidden(), 'banner still shown after reconnecting');
  });

  await a.close(); // a rendering page in the background only slows the rest down

  await check('a full server is reported as refusing, not as unreachable', async () => {
    if (args.fake) return;
    const port2 = await freePort();
    const full = await startServer({ ...srvOpts, port: port2, extra: ['--max-clients', '1'] });
    const pages = [];
    try {
      for (let i = 0; i < 2; i++) {
        const p = await browser.newPage({ viewport: { width: 320, height: 200 } });
        p.on('pageerror', (e) => pageErrors.push(e.message));
        await p.goto(`http://127.0.0.1:${port2}/${QUERY}`);
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
    const p = await browser.newPage({ viewport: VIEW });
    p.on('pageerror', (e) => pageErrors.push(e.message));
    try {
      await p.goto(`http://127.0.0.1:${port3}/${QUERY}`);
      await waitFor(p, 'connected', () => window.oceand.connected && window.oceand.params !== null);
      const opts = await p.$$eval('[data-param=resolution] select option',
        (els) => els.map((o) => ({ n: parseInt(o.textContent, 10), disabled: o.disabled, why: o.title })));
      const off = opts.filter((o) => o.disabled), on = opts.filter((o) => !o.disabled);
      assert(off.length > 0 && on.length > 0, `options ${JSON.stringify(opts)}`);
      assert(Math.min(...off.map((o) => o.n)) > Math.max(...on.map((o) => o.n)), `disabled sizes not the largest: ${JSON.stringify(opts)}`);
      assert(off.every((o) => /memory cap/.test(o.why)), `no reason on a disabled size: ${JSON.stringify(off)}`);
    } finally {
      await p.close();
      await small.stop();
    }
  });

  await check('no uncaught errors in the pages', async () => {
    assert(pageErrors.length === 0, pageErrors.join('; '));
  });
} catch (e) {
  failed++;
  console.log(`FAIL harness: ${e.stack || e}`);
} finally {
  await browser.close().catch(() => {});
  await server.stop().catch(() => {});
}
console.log(`${passed} passed, ${failed} failed`);
process.exit(failed ? 1 : 0);

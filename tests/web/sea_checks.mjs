// Web checks of what sea the page says it shows (web/src/seaview.js): the compass against the
// world's axes as the camera turns, the sea line, the polar plot's pixels, and the layout on a
// desk and a phone. The measured sea's summary is injected through window.oceandTest.sea (as
// the daemon's `sea` would arrive). Called by test_web.mjs with its check() harness.
import { ndbcLikeSummary, SWELL, WIND_SEA } from './sea_fixture.mjs';
import { colourAt } from '../../web/src/polarplot.js';
import { execFileSync } from 'node:child_process';

// The world's axes as docs/simulation.md states them (not the page's code): north = +z,
// east = -x; wind_direction a (toward) is the vector (cos a, sin a) in (x, z); a wave coming
// from bearing b travels toward (sin b, -cos b).
const rad = (d) => d * Math.PI / 180;
const NORTH = [0, 1];
const windToward = (a) => [Math.cos(rad(a)), Math.sin(rad(a))];
const wavesToward = (b) => [Math.sin(rad(b)), -Math.cos(rad(b))];
const headingVector = (h) => [-Math.sin(rad(h)), Math.cos(rad(h))]; // a bearing's (x, z)
const angleDiff = (a, b) => Math.abs(((a - b) % 360 + 540) % 360 - 180);
const screenAngle = ([dx, dy]) => Math.atan2(dx, -dy) * 180 / Math.PI; // clockwise from screen up

export async function seaChecks({ check, browser, url, devices, pageErrors, assert, waitFor, tap }) {
  const summary = ndbcLikeSummary();
  const newPage = async (ctxOpts) => {
    const ctx = await browser.newContext(ctxOpts);
    const p = await ctx.newPage();
    p.on('pageerror', (e) => pageErrors.push(e.message));
    await p.goto(`${url}&draw=0`, { timeout: 120000 });
    await waitFor(p, 'connected', () => window.oceand.connected && window.oceand.params !== null && !document.getElementById('sea-card').hidden, null, 60000);
    return { ctx, p };
  };
  const frames = (p, n = 3) => p.evaluate((n) => new Promise((r) => { let k = 0; const f = () => (++k >= n ? r() : requestAnimationFrame(f)); requestAnimationFrame(f); }), n);

  // A steep view (10° off straight down) looking along heading h at the origin; then where
  // world directions land on screen beside where the compass points.
  async function readCompass(p, h, dirs) {
    const [hx, hz] = headingVector(h), s = Math.sin(rad(10)) * 100, c = Math.cos(rad(10)) * 100;
    await p.evaluate(([pos]) => window.oceandTest.look(pos, [0, 0, 0]), [[-hx * s, c, -hz * s]]);
    await frames(p);
    return p.evaluate((dirs) => {
      const at = (el, x, y) => { const m = el.getScreenCTM(); return [m.a * x + m.c * y + m.e, m.b * x + m.d * y + m.f]; };
      const rose = document.querySelector('[data-ui=compass-rose]');
      const c0 = at(rose, 0, 0);
      const tip = (sel) => {
        const g = document.querySelector(sel);
        if (!g || getComputedStyle(g).display === 'none') return null;
        if (g.tagName === 'circle') return at(g, +g.getAttribute('cx'), +g.getAttribute('cy'));
        const l = g.querySelector('line');
        return at(l, +l.getAttribute('x2'), +l.getAttribute('y2'));
      };
      const o = window.oceandTest.project([0, 0, 0]);
      const out = {};
      for (const [name, sel, [x, z]] of dirs) {
        const t = tip(sel), q = window.oceandTest.project([40 * x, 0, 40 * z]);
        out[name] = { compass: t && [t[0] - c0[0], t[1] - c0[1]], world: [q[0] - o[0], q[1] - o[1]] };
      }
      return out;
    }, dirs);
  }
  const agree = (r, what, h) => {
    for (const [name, v] of Object.entries(r)) {
      assert(v.compass, `${what}: heading ${h}°: no ${name} on the compass`);
      const d = angleDiff(screenAngle(v.compass), screenAngle(v.world));
      assert(d <= 3, `${what}: heading ${h}°: the compass's ${name} points ${screenAngle(v.compass).toFixed(1)}° on screen, the world's ${screenAngle(v.world).toFixed(1)}° (${d.toFixed(1)}° apart)`);
    }
  };

  await check('compass: north and the wind point where the world has them, as the camera turns; a measured sea: its line and its waves arrow', async () => {
    const { ctx, p } = await newPage({ viewport: { width: 1280, height: 800 } });
    try {
      const params = await p.evaluate(() => window.oceand.params);
      // A parametric sea: the wind (toward, in the x-z plane) on the compass, and the line says it.
      const line0 = await p.locator('[data-ui=sea-line]').textContent();
      assert(/^wind [\d.]+ m\/s from [NESW]{1,3} \(\d+°\)$/.test(line0), `the parametric sea's line: "${line0}"`);
      for (const h of [30, 135, 250]) {
        agree(await readCompass(p, h, [['north', '[data-ui=compass-n]', NORTH], ['wind', '[data-ui=compass-wind]', windToward(params.wind_direction)]]), 'parametric sea', h);
      }
      // The measured sea: the line reads the summary, the waves arrow runs from where they come.
      assert(await p.evaluate((s) => window.oceandTest.sea(s), summary), 'the summary was not applied');
      const line = await p.locator('[data-ui=sea-line]').textContent();
      assert(line === 'NDBC 46026, 2026-12-01 20:40 UTC: Hs 2.3 m, Tp 12.5 s from 285°', `the sea line: "${line}"`);
      const shown = await p.evaluate(() => window.oceand.sea);
      assert(shown && shown.source === summary.source && shown.version === summary.version, `window.oceand.sea: ${JSON.stringify(shown)?.slice(0, 200)}`);
      const folder = await p.locator('[data-ui=sea-folder-line]').textContent();
      assert(folder.includes(line), `the panel's Measured sea folder: "${folder}"`);
      for (const h of [30, 135, 250]) {
        const r = await readCompass(p, h, [['north', '[data-ui=compass-n]', NORTH], ['waves', '[data-ui=compass-waves]', wavesToward(SWELL.fromDeg)], ['wind', '[data-ui=compass-wind]', [1, 0]]]);
        assert(r.wind.compass === null, 'the wind arrow is still shown over a measured sea');
        delete r.wind;
        agree(r, 'measured sea', h);
      }
      // Copies and order: the same version again (the other connection's copy) changes nothing;
      // null goes back to the wind; a late copy of the cleared summary stays out; a new session
      // starts afresh.
      assert(!(await p.evaluate((s) => window.oceandTest.sea({ ...s, source: 'stale copy' }), summary)), 'a copy of the same version was applied');
      await p.evaluate(() => window.oceandTest.sea(null));
      assert(/^wind /.test(await p.locator('[data-ui=sea-line]').textContent()) && (await p.evaluate(() => window.oceand.sea)) === null, 'null did not bring the parametric sea back');
      assert(!(await p.evaluate((s) => window.oceandTest.sea(s), summary)), 'a late copy of a cleared summary came back');
      assert(await p.evaluate((s) => window.oceandTest.sea(s, { fresh: true }), summary), 'a new session (hello) did not take its summary');
    } finally { await ctx.close(); }
  });

  await check('polar plot: the peak pixel lies at the summary\'s peak direction and period, the wind sea at its own', async () => {
    const { ctx, p } = await newPage({ viewport: { width: 1280, height: 800 } });
    try {
      await p.evaluate((s) => window.oceandTest.sea(s), summary);
      await p.click('[data-ui=sea-plot-toggle]');
      await waitFor(p, 'the plot open', () => !document.getElementById('sea-plot').hidden && document.querySelector('[data-ui=sea-polar]').width > 100, null, 10000);
      // Pixels are read back to values through the plot's colour scale (its colour bar's map):
      // a pixel far from every colour of it (a ring, a label, an edge) is no value.
      const lut = Array.from({ length: 256 }, (_, i) => colourAt(i / 255));
      const r = await p.evaluate(({ wind, lut }) => {
        const cv = document.querySelector('[data-ui=sea-polar]'), g = cv.getContext('2d');
        const k = cv.width / cv.getBoundingClientRect().width; // canvas pixels per CSS pixel
        const { cx, cy, r, rim } = Object.fromEntries(Object.entries(cv.dataset).map(([a, b]) => [a, Number(b)]));
        const px = g.getImageData(0, 0, cv.width, cv.height).data;
        const score = (i) => {
          let bi = -1, bd = 1e9;
          for (let t = 0; t < 256; t++) { const c = lut[t], d = (c[0] - px[i]) ** 2 + (c[1] - px[i + 1]) ** 2 + (c[2] - px[i + 2]) ** 2; if (d < bd) { bd = d; bi = t; } }
          return bd <= 36 && px[i + 3] === 255 ? bi : -1;
        };
        const where = (x, y) => { const dx = x / k - cx, dy = y / k - cy; return { bearing: (Math.atan2(dx, -dy) * 180 / Math.PI + 360) % 360, f: Math.hypot(dx, dy) / r * rim }; };
        // The value of every pixel; the peak (and the wind sea's, in its part of the plot) is the
        // centroid of the pixels at the highest value (cells a colour step apart read as equal).
        const val = new Int16Array(cv.width * cv.height), inWind = new Uint8Array(cv.width * cv.height);
        let best = -1, wbest = -1;
        for (let y = 0; y < cv.height; y++) for (let x = 0; x < cv.width; x++) {
          const n = y * cv.width + x, s = score(4 * n), w = where(x, y);
          val[n] = s;
          inWind[n] = Math.abs(((w.bearing - wind.from) % 360 + 540) % 360 - 180) < 60 && Math.abs(w.f - 1 / wind.tp) < 0.06;
          best = Math.max(best, s);
          if (inWind[n]) wbest = Math.max(wbest, s);
        }
        const centroid = (keep) => {
          let sx = 0, sy = 0, k = 0;
          for (let n = 0; n < val.length; n++) if (keep(n)) { sx += n % cv.width; sy += Math.floor(n / cv.width); k++; }
          return k ? { ...where(sx / k, sy / k), pixels: k } : null;
        };
        return { peak: centroid((n) => val[n] === best), score: best, wind: wbest >= 0 ? centroid((n) => inWind[n] && val[n] === wbest) : null, rim };
      }, { wind: { from: WIND_SEA.fromDeg, tp: WIND_SEA.tpS }, lut });
      console.log(`     peak pixel from ${r.peak.bearing.toFixed(1)}° at ${(1 / r.peak.f).toFixed(2)} s (colour ${r.score}/255); the wind sea's from ${r.wind?.bearing.toFixed(1)}° at ${r.wind ? (1 / r.wind.f).toFixed(2) : '–'} s; rim ${r.rim} Hz`);
      assert(r.score >= 250, `the colour scale's top is not in the plot: its highest value ${r.score}/255`);
      // The summary's grid has 10° directions (the swell's peak at 285° falls between 280 and
      // 290, equal) and 0.005 Hz bands here (the wind sea's: 0.01 Hz).
      assert(angleDiff(r.peak.bearing, SWELL.fromDeg) <= 3, `the peak is drawn from ${r.peak.bearing.toFixed(1)}°, the sea's is from ${SWELL.fromDeg}°`);
      assert(Math.abs(r.peak.f - 1 / SWELL.tpS) <= 0.0025, `the peak is drawn at ${r.peak.f.toFixed(4)} Hz (${(1 / r.peak.f).toFixed(2)} s), the sea's at ${(1 / SWELL.tpS).toFixed(4)} Hz (${SWELL.tpS} s)`);
      assert(r.wind && angleDiff(r.wind.bearing, WIND_SEA.fromDeg) <= 5 && Math.abs(r.wind.f - 1 / WIND_SEA.tpS) <= 0.005,
        `the wind sea's brightest pixel from ${r.wind?.bearing.toFixed(1)}° at ${r.wind?.f.toFixed(3)} Hz, the sea's from ${WIND_SEA.fromDeg}° at ${1 / WIND_SEA.tpS} Hz`);
      const scale = await p.locator('#sea-plot .oc-plot-scale-text').textContent();
      assert(/log scale/.test(scale), `the colour scale does not say it is logarithmic: "${scale}"`);
    } finally { await ctx.close(); }
  });

  // The card and the open plot: on the screen, clear of the HUD and of the panel (its title bar
  // when closed, all of it when open), on a desk and a phone both ways round. On a phone the
  // plot and the open panel take turns.
  await check('measured sea: the card and the polar plot lie clear of the HUD and the panel, on a desk and a phone', async () => {
    for (const dev of [null, 'iPhone 13', 'iPhone 13 landscape']) {
      const what = dev || 'desk 1280x800';
      const { ctx, p } = await newPage(dev ? { ...devices[dev], deviceScaleFactor: 1 } : { viewport: { width: 1280, height: 800 } });
      try {
        await p.evaluate((s) => window.oceandTest.sea(s), summary);
        await waitFor(p, 'the HUD drawn', () => /fps/.test(document.querySelector('.oc-hud-text').textContent), null, 15000);
        await p.locator('[data-ui=sea-plot-toggle]').click();
        await waitFor(p, 'the plot open', () => !document.getElementById('sea-plot').hidden, null, 10000);
        const boxes = () => p.evaluate(() => {
          const r = (el) => { const b = el.getBoundingClientRect(); return { x: b.left, y: b.top, w: b.width, h: b.height }; };
          const panel = document.getElementById('panel'), closed = panel.classList.contains('closed');
          const plot = document.getElementById('sea-plot');
          return { hud: r(document.getElementById('hud')), panel: r(closed ? panel.querySelector(':scope > .title') : panel), closed,
            card: r(document.getElementById('sea-card')), plot: plot.hidden ? null : r(plot), vw: innerWidth, vh: innerHeight };
        });
        const clear = (b, names, stage) => {
          for (const n of names) {
            const q = b[n];
            if (!q) continue;
            assert(q.w > 0 && q.h > 0 && q.x >= 0 && q.y >= 0 && q.x + q.w <= b.vw + 0.5 && q.y + q.h <= b.vh + 0.5, `${what} (${stage}): the ${n} ${JSON.stringify(q)} runs off the ${b.vw}x${b.vh} screen`);
            for (const o of ['hud', 'panel']) {
              const z = b[o];
              assert(!(q.x < z.x + z.w && z.x < q.x + q.w && q.y < z.y + z.h && z.y < q.y + q.h), `${what} (${stage}): the ${n} ${JSON.stringify(q)} lies over the ${o} ${JSON.stringify(z)}`);
            }
          }
        };
        let b = await boxes();
        assert(b.plot, `${what}: the plot did not open`);
        assert(b.plot.w >= 150, `${what}: the plot is ${b.plot.w.toFixed(0)} px wide`);
        clear(b, ['card', 'plot'], b.closed ? 'plot open, panel closed' : 'plot and panel open');
        if (dev) { // the panel opened on a phone: the plot gives way, the card stays clear of it
          await p.tap('#panel > .title');
          await waitFor(p, 'the panel open and still', () => !document.getElementById('panel').classList.contains('closed') && !document.querySelector('#panel.transition, #panel .transition'), null, 5000);
          await frames(p, 4);
          b = await boxes();
          assert(!b.plot, `${what}: the plot stays open under the open panel`);
          clear(b, ['card'], 'panel open');
        }
      } finally { await ctx.close(); }
    }
  });

  // A real sea from the daemon (ocean-tap sends the NDBC fixture) reaches a page opened before
  // it: the card names it, the panel offers and shows "measured", and choosing JONSWAP there
  // takes the shared sea back to the parametric one (the checks after this one expect it).
  await check('a buoy\'s sea sent to the daemon reaches an open page, which offers "measured" and can leave it', async () => {
    if (!tap) return;
    const { ctx, p } = await newPage({ viewport: { width: 1280, height: 800 } });
    const spectrum = () => p.evaluate(() => { const s = document.querySelector('[data-param=spectrum] select'); return { value: s.value, options: [...s.options].map((o) => o.value) }; });
    try {
      const before = await spectrum();
      assert(!before.options.includes('measured'), `"measured" offered before a sea: ${JSON.stringify(before)}`);
      const ws = url.replace(/^http/, 'ws').replace(/\/\?.*$/, '/');
      execFileSync(tap, ['sea', 'tests/sea/fixtures/ndbc-rt/46026.data_spec', ws], { stdio: 'pipe', timeout: 30000 });
      await waitFor(p, 'the sea line names the buoy', () => /NDBC 46026/.test(document.getElementById('sea-card').innerText), null, 15000);
      const after = await spectrum();
      assert(after.value === 'measured' && after.options.includes('measured'), `the panel after the sea: ${JSON.stringify(after)}`);
      await p.evaluate(() => document.querySelector('#panel .title')?.closest('.closed') && document.querySelector('#panel > .title').click());
      await p.locator('[data-param=spectrum] select').selectOption('jonswap', { force: true });
      await waitFor(p, 'back to JONSWAP, "measured" no longer offered', () => window.oceand.params.spectrum === 'jonswap'
        && ![...document.querySelector('[data-param=spectrum] select').options].some((o) => o.value === 'measured'), null, 15000)
        .catch(async () => assert(false, `not back: ${JSON.stringify(await spectrum())}`));
      const card = (await p.locator('#sea-card').innerText()).replace(/\s+/g, ' ');
      assert(!/NDBC/.test(card) && /wind/.test(card), `the card after leaving the measured sea still names it: "${card}"`);
    } finally { await ctx.close(); }
  });
}

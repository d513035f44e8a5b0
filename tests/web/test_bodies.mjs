// Bodies on the shared sea, end to end: two pages of the web client in headless Debian chromium
// against a real oceand on loopback (PROTOCOL.md §3.5, §7.6; web/src/bodies.js).
//   node tests/web/test_bodies.mjs --oceand build/oceand --web-root build/web --out build/web-test
// Closing line: "N passed, M failed"; exit status 1 on any failure.
import fs from 'node:fs';
import path from 'node:path';
import { parseArgs, freePort, startServer, launchBrowser, waitFor, sleep } from './harness.mjs';

const args = parseArgs(process.argv, { oceand: 'build/oceand', webRoot: 'build/web', out: 'build/web-test' });
fs.mkdirSync(args.out, { recursive: true });
// The checks read the pages' state, not pixels: no drawing (software GL), except the picture;
// catchup=0: a page that falls behind on a loaded machine keeps its connection (and client id).
const QUERY = '?test=1&aa=0&detail=0.25&scale=0.25&draw=0&catchup=0';

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
const median = (a) => { const s = [...a].sort((x, y) => x - y); return s[Math.floor(s.length / 2)]; };

const port = await freePort();
// N = 128 (a light sea for software GL); a grace of 10 s: long enough for a reload's claim on a
// loaded machine, short enough to see a body abandoned (2 x grace after its page closed).
const server = await startServer({ oceand: args.oceand, webRoot: args.webRoot, port, extra: ['--resolution', '128', '--body-grace', '10'] });
const browser = await launchBrowser();
const pageErrors = [];
async function openPage(query = QUERY, viewport = { width: 800, height: 500 }) {
  const p = await browser.newPage({ viewport });
  p.on('pageerror', (e) => pageErrors.push(e.message));
  await p.goto(`http://127.0.0.1:${port}/${query}`, { timeout: 120000 });
  await waitFor(p, 'the first frame', () => window.oceand?.connected && window.oceand.framesReceived > 3, null, 60000);
  await waitFor(p, 'the control connection', () => window.oceand.controlId !== null, null, 30000);
  return p;
}
const bodiesOf = (p) => p.evaluate(() => window.oceand.bodies);
const stats = (p) => p.evaluate(() => window.oceand.stats);
// A body's record in the newest frame a page has shown.
async function newestRecord(p, id) {
  return p.evaluate((id) => {
    const seqs = window.oceandTest.bodySeqs();
    const recs = window.oceandTest.bodyRecords(seqs[seqs.length - 1]) || [];
    return recs.find((r) => r.id === id) || null;
  }, id);
}

let A, B, boat = null, ball = null, kinds = null;
try {
  A = await openPage();
  B = await openPage();
  // The kinds as the server describes them (the page builds its meshes and panel from them).
  kinds = await A.evaluate(async (port) => new Promise((resolve, reject) => {
    const ws = new WebSocket(`ws://127.0.0.1:${port}/?frames=0`, 'oceand.v1');
    ws.onmessage = (ev) => { const m = JSON.parse(ev.data); if (m.type === 'hello') { ws.close(); resolve(m.body_kinds); } };
    ws.onerror = () => reject(new Error('no hello'));
  }), port);

  await check('the panel lists every kind the server has, and launches one', async () => {
    const options = await A.$$eval('[data-ui=body-kind] select option', (os) => os.map((o) => o.textContent));
    assert(kinds && kinds.length >= 5, `hello.body_kinds: ${JSON.stringify(kinds)}`);
    const labels = kinds.map((k) => k.label || k.name);
    assert(JSON.stringify(options) === JSON.stringify(labels), `panel offers ${options}, server has ${labels}`);
    await A.selectOption('[data-ui=body-kind] select', { label: kinds.find((k) => k.name === 'boat').label });
    await A.click('[data-ui=launch] button');
    await waitFor(A, 'A draws its own boat', () => window.oceand.bodies.some((b) => b.mine && b.kind === 'boat'));
    boat = (await bodiesOf(A)).find((b) => b.mine && b.kind === 'boat');
    assert(await A.evaluate(() => !document.querySelector('[data-ui=steer]').hidden), 'the steering bar is not shown to the owner');
    const label = await A.$eval(`.oc-body-label[data-body="${boat.body}"]`, (e) => ({ mine: e.classList.contains('mine'), text: e.textContent }));
    assert(label.mine, `A's label of its own boat is not highlighted: ${JSON.stringify(label)}`);
  });

  await check("page B draws A's boat: the same body, A's, not B's", async () => {
    assert(boat, 'no boat launched');
    await waitFor(B, "B draws A's boat", (id) => window.oceand.bodies.some((b) => b.body === id), boat.body);
    const b = (await bodiesOf(B)).find((x) => x.body === boat.body);
    const aId = await A.evaluate(() => window.oceand.clientId);
    assert(!b.mine && b.owner === aId && b.kind === 'boat', `B sees ${JSON.stringify(b)}, A is ${aId}`);
    assert(await B.evaluate(() => document.querySelector('[data-ui=steer]').hidden), 'B is offered the steering bar of a boat it does not own');
  });

  await check('both pages hold the same record of the boat for the same tick', async () => {
    let common = [];
    for (let k = 0; k < 50 && common.length < 5; k++) {
      const [sa, sb] = [await A.evaluate(() => window.oceandTest.bodySeqs()), await B.evaluate(() => window.oceandTest.bodySeqs())];
      common = sa.filter((s) => sb.includes(s));
      if (common.length < 5) await sleep(200);
    }
    assert(common.length >= 5, `the pages share only ${common.length} ticks`);
    let compared = 0;
    for (const seq of common.slice(-5)) {
      const [ra, rb] = [await A.evaluate((s) => window.oceandTest.bodyRecords(s), seq), await B.evaluate((s) => window.oceandTest.bodyRecords(s), seq)];
      if (!ra || !rb) continue; // fell out of a page's history meanwhile
      const a = ra.find((r) => r.id === boat.body), b = rb.find((r) => r.id === boat.body);
      assert(a && b, `tick ${seq}: the boat is missing from ${a ? 'B' : 'A'}`);
      assert(JSON.stringify(a) === JSON.stringify(b), `tick ${seq}: A ${JSON.stringify(a)} != B ${JSON.stringify(b)}`);
      compared++;
    }
    assert(compared >= 3, `only ${compared} ticks compared`);
    // The records move (a live sea), so equal records are not just two copies of one value.
    const first = await A.evaluate((s) => window.oceandTest.bodyRecords(s), common[0]);
    const last = await A.evaluate((s) => window.oceandTest.bodyRecords(s), common[common.length - 1]);
    const y0 = first?.find((r) => r.id === boat.body)?.pos[1], y1 = last?.find((r) => r.id === boat.body)?.pos[1];
    assert(y0 !== y1, `the boat's height did not change over ${common.length} ticks (${y0})`);
  });

  await check('the keyboard steers the boat, and B sees it go', async () => {
    await A.bringToFront();
    await A.evaluate(() => document.activeElement?.blur()); // keys go to the page, not the panel's last button
    for (let k = 0; k < 6; k++) { await A.keyboard.press('w'); await sleep(60); }
    await waitFor(B, "B's record shows A's throttle", (id) => {
      const seqs = window.oceandTest.bodySeqs(), r = (window.oceandTest.bodyRecords(seqs[seqs.length - 1]) || []).find((x) => x.id === id);
      return r && r.throttle > 0.55 && r.throttle < 0.65;
    }, boat.body, 15000);
    await waitFor(B, 'the boat under way (over 2 m/s, as B sees it)', (id) => {
      const seqs = window.oceandTest.bodySeqs(), r = (window.oceandTest.bodyRecords(seqs[seqs.length - 1]) || []).find((x) => x.id === id);
      return r && Math.hypot(r.vel[0], r.vel[2]) > 2;
    }, boat.body, 30000);
    // Rudder held to starboard: the heading turns clockwise (seen from above: toward east = -x).
    const r0 = await newestRecord(B, boat.body);
    await A.keyboard.down('d');
    await waitFor(B, 'the rudder in force', (id) => {
      const seqs = window.oceandTest.bodySeqs(), r = (window.oceandTest.bodyRecords(seqs[seqs.length - 1]) || []).find((x) => x.id === id);
      return r && r.rudder > 0.9;
    }, boat.body, 15000);
    await sleep(5000);
    const r1 = await newestRecord(B, boat.body);
    await A.keyboard.up('d');
    // The bow's bearing from the orientation (the course through waves wanders with the sway):
    // bow = q (0, 0, 1) q*, bearing clockwise from north = atan2(-x, z) (north = +z, east = -x).
    const heading = (r) => {
      const [w, x, y, z] = r.quat;
      const bx = 2 * (x * z + w * y), bz = 1 - 2 * (x * x + y * y);
      return Math.atan2(-bx, bz) * 180 / Math.PI;
    };
    const turned = ((heading(r1) - heading(r0)) % 360 + 540) % 360 - 180;
    assert(turned > 10, `the bow turned ${turned.toFixed(1)}° in 5 s with the rudder to starboard (want clockwise, > 10°)`);
    console.log(`     the bow turned ${turned.toFixed(1)}° in 5 s at ${Math.hypot(r0.vel[0], r0.vel[2]).toFixed(1)} m/s`);
  });

  await check("another page cannot steer or remove it (not_owner), and nothing changes", async () => {
    const before = await newestRecord(B, boat.body);
    // (the page's connection numbers its requests: the error carries the number send returned)
    const steerId = await B.evaluate((id) => window.oceandTest.send({ type: 'steer', body: id, throttle: -1 }), boat.body);
    await waitFor(B, 'an error for the steer', (rid) => window.oceand.stats.serverError?.id === rid, steerId);
    assert((await stats(B)).serverError.code === 'not_owner', `B's steer: ${JSON.stringify((await stats(B)).serverError)}`);
    const removeId = await B.evaluate((id) => window.oceandTest.send({ type: 'remove', body: id }), boat.body);
    await waitFor(B, 'an error for the remove', (rid) => window.oceand.stats.serverError?.id === rid, removeId);
    assert((await stats(B)).serverError.code === 'not_owner', `B's remove: ${JSON.stringify((await stats(B)).serverError)}`);
    await sleep(500);
    const after = await newestRecord(B, boat.body);
    assert(after && Math.abs(after.throttle - before.throttle) < 0.01, `the throttle went from ${before.throttle} to ${after?.throttle}`);
  });

  await check('a ball buoy rides the waves it is drawn on (a calm sea, the drawn frame held)', async () => {
    await A.evaluate(() => window.oceandTest.send({ type: 'set', params: { wind_speed: 7 } }));
    await A.evaluate(() => window.oceandTest.send({ type: 'launch', id: 'ball', kind: 'ball', x: 30, z: 20 }));
    await waitFor(A, 'the ball', () => window.oceand.bodies.some((b) => b.mine && b.kind === 'ball'));
    ball = (await bodiesOf(A)).find((b) => b.mine && b.kind === 'ball');
    const k = kinds.find((x) => x.name === 'ball');
    await sleep(6000); // the wind's change eases in; the ball settles
    const gaps = [], swell = [];
    for (let i = 0; i < 12; i++) {
      await A.evaluate(() => window.oceandTest.freeze(true));
      await sleep(400); // the blend reaches the newer frame: it alone is drawn, with its records
      const g = await A.evaluate(({ id, kg, draft }) => {
        const r = (window.oceandTest.bodyRecords(window.oceandTest.drawnBodySeq()) || []).find((x) => x.id === id);
        if (!r) return null;
        const surface = window.oceandTest.surfaceHeight(r.pos[0], r.pos[2], 1);
        return { waterline: r.pos[1] - kg + draft, surface };
      }, { id: ball.body, kg: k.kg ?? k.height / 2, draft: k.draft });
      if (g) { gaps.push(Math.abs(g.waterline - g.surface)); swell.push(g.surface); }
      await A.evaluate(() => window.oceandTest.freeze(false));
      await sleep(300 + 97 * i);
    }
    assert(gaps.length >= 8, `only ${gaps.length} of 12 held frames had the ball's record`);
    const range = Math.max(...swell) - Math.min(...swell);
    assert(range > 0.1, `the surface under the ball hardly moved (${range.toFixed(3)} m): the check would prove nothing`);
    assert(median(gaps) < 0.12, `the ball's waterline is ${median(gaps).toFixed(3)} m (median) from the drawn surface (waves ${range.toFixed(2)} m)`);
    console.log(`     ball: waterline to drawn surface ${median(gaps).toFixed(3)} m median, ${Math.max(...gaps).toFixed(3)} m max, surface range ${range.toFixed(2)} m`);
  });

  await check('a reload claims the boat back (resume key), and a remove takes it away for everyone', async () => {
    const before = await A.evaluate(() => window.oceand.clientId);
    await A.reload({ timeout: 120000 });
    await waitFor(A, 'the first frame after the reload', () => window.oceand?.connected && window.oceand.framesReceived > 3, null, 60000);
    await waitFor(A, 'the boat is ours again', (id) => window.oceand.bodies.some((b) => b.body === id && b.mine), boat.body, 20000);
    const after = await A.evaluate(() => window.oceand.clientId);
    assert(after !== before, 'the reload kept the client id?');
    const owner = (await bodiesOf(B)).find((b) => b.body === boat.body)?.owner;
    assert(owner === after, `B sees owner ${owner}, A is now ${after}`);
    await A.evaluate((id) => { /* select the boat (the ball was launched later) */ }, boat.body);
    await A.evaluate(() => window.oceandTest.send({ type: 'remove', id: 'rm', body: window.oceand.bodies.find((b) => b.kind === 'boat' && b.mine).body }));
    await waitFor(B, 'the boat gone from B', (id) => !window.oceand.bodies.some((b) => b.body === id), boat.body);
    await waitFor(A, 'the boat gone from A', (id) => !window.oceand.bodies.some((b) => b.body === id), boat.body);
  });

  await check('a body whose page is gone drifts, then is removed after the grace', async () => {
    await A.close();
    A = null;
    await waitFor(B, 'the ball adrift', (id) => document.querySelector(`.oc-body-label[data-body="${id}"]`)?.classList.contains('adrift'), ball.body, 15000);
    await waitFor(B, 'the ball removed (abandoned)', (id) => !window.oceand.bodies.some((b) => b.body === id), ball.body, 45000);
  });

  await check('a picture: a boat under way and a ball, seen from 25 m', async () => {
    const C = await browser.newPage({ viewport: { width: 900, height: 560 } });
    C.on('pageerror', (e) => pageErrors.push(e.message));
    await C.goto(`http://127.0.0.1:${port}/?test=1&aa=0&hour=15&scale=0.75&catchup=0`, { timeout: 120000 });
    await waitFor(C, 'frames', () => window.oceand?.connected && window.oceand.framesReceived > 3, null, 60000);
    await C.evaluate(() => window.oceandTest.send({ type: 'launch', id: 'p1', kind: 'boat', x: 0, z: 0, heading: 300 }));
    await C.evaluate(() => window.oceandTest.send({ type: 'launch', id: 'p2', kind: 'ball', x: -14, z: 10 }));
    await waitFor(C, 'two bodies drawn (software GL draws slowly)', () => window.oceand.bodies.length >= 2, null, 120000);
    await sleep(4000);
    await C.evaluate(() => window.oceandTest.look([22, 9, -20], [0, 0, 2]));
    await sleep(2500);
    const file = path.join(args.out, 'bodies.png');
    await C.screenshot({ path: file, timeout: 120000 });
    console.log(`     picture: ${file}`);
    await C.close();
  });

  await check('no page errors', async () => { assert(pageErrors.length === 0, pageErrors.join('; ')); });
} finally {
  await browser.close().catch(() => {});
  await server.stop();
}
console.log(`${passed} passed, ${failed} failed`);
process.exit(failed ? 1 : 0);

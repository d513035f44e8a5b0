// oceand browser client: wires the connection, the decoder worker, the renderer,
// the panel and the HUD together, and exposes read-only state as window.oceand.
import * as THREE from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import { Connection, serverUrl, controlUrl } from './connection.js';
import { Ocean } from './ocean.js';
import { Panel } from './panel.js';
import { Hud, Stats } from './hud.js';
import { ProbeMarker } from './probe.js';
import { Bodies } from './bodies.js';
import { SkyModel } from './sky.js';
import { DEFAULT_HOUR } from './presets.js';
import { CatchUp } from './catchup.js';
import { SeaView } from './seaview.js';

// How far seq may go back before the page takes it for a restarted stream: an edge adopts a new
// count only when it is more than 2 s of ticks behind, and frames decoded out of order differ
// by a tick or two.
const STREAM_RESTART_TICKS = 30;
const query = new URLSearchParams(location.search);
const canvas = document.getElementById('ocean');
// ?aa=0 turns off multisampling (software GL in tests); ?detail=x scales mesh density.
const renderer = new THREE.WebGLRenderer({ canvas, antialias: query.get('aa') !== '0', preserveDrawingBuffer: query.has('test') });
// ?scale=x (0.25..1): draw at x times the screen's resolution, then let the browser stretch
// it: fewer pixels to shade, for slow GPUs (and software GL in tests).
const renderScale = Math.min(1, Math.max(0.25, Number(query.get('scale')) || 1));
renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2) * renderScale);
renderer.outputColorSpace = THREE.LinearSRGBColorSpace; // shaders write display-ready colour
const camera = new THREE.PerspectiveCamera(55, 1, 0.5, 120000);
camera.position.set(0, 14, 48);
const camArg = (query.get('cam') || '').split(',').map(Number); // ?cam=x,y,z: start elsewhere
if (camArg.length === 3 && camArg.every(Number.isFinite)) camera.position.set(...camArg);
const controls = new OrbitControls(camera, canvas);
controls.target.set(0, 2, 0);
const tgtArg = (query.get('target') || '').split(',').map(Number); // ?target=x,y,z: look there
if (tgtArg.length === 3 && tgtArg.every(Number.isFinite)) controls.target.set(...tgtArg);
controls.enableDamping = true;
controls.screenSpacePanning = false;           // pan slides over the sea: a simple fly mode
// The polar limit is relative to the target: at 0.495π it raised a 1.5 m camera aimed 200 m
// away to 3.6 m. The camera floor (keepAboveWaves) keeps the camera above the water; this limit
// only keeps the orbit from turning over (a camera may sit a little below its target's level).
controls.maxPolarAngle = Math.PI / 2 + 0.1;
controls.minDistance = 3;
controls.maxDistance = 3000;
controls.listenToKeyEvents(window);            // arrow keys pan
// Phones in either orientation (and small windows): panel closed, HUD compact.
const compact = window.matchMedia('(max-width: 700px), (max-height: 480px)').matches;
const sky = new SkyModel(renderer);
// ?skirt=0 / ?stitch=0: turn off the crack fixes (to see, and test, what they hide);
// ?hex=0: periodic normals to the horizon (to measure what the hex tiling breaks up).
const ocean = new Ocean(renderer, sky.uniforms, { detail: Number(query.get('detail') || 1), skirts: query.get('skirt') !== '0', hexTiling: query.get('hex') !== '0' });
ocean.setCrackFixes({ stitch: query.get('stitch') !== '0', skirts: query.get('skirt') !== '0' });
sky.uniforms.uGapProbe.value = query.get('gapprobe') === '1' ? 1 : 0; // ?gapprobe=1: magenta sky and skirts (tests)
// ?debugview=foam: the water writes (foam amount, -Jacobian, height) as colour; ?foamshift=x,z
// moves every foam lookup by (x, z) metres (tests: foam placed away from its crests).
ocean.uniforms.uDebugView.value = query.get('debugview') === 'foam' ? 1 : 0;
const foamShift = (query.get('foamshift') || '').split(',').map(Number);
if (foamShift.length === 2 && foamShift.every(Number.isFinite)) ocean.uniforms.uFoamShift.value.set(...foamShift);
const stats = new Stats();
// Notes about the shared sea (who changed what, a restart) also reach a user whose panel
// is closed (phones start so): a line at the bottom for a few seconds.
const toast = document.createElement('div');
toast.id = 'toast';
toast.dataset.ui = 'toast';
toast.setAttribute('role', 'status');
toast.hidden = true;
document.body.appendChild(toast);
let toastTimer = 0;
function showToast(text) {
  if (!panel.closed) return;
  toast.textContent = text;
  toast.hidden = false;
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => { toast.hidden = true; }, 8000);
}
const hud = new Hud(document.getElementById('hud'), document.getElementById('banner'), { compact });
if (query.get('hud') === '0') hud.setVisible(false, false); // ?hud=0: hide for this visit only
if (query.get('ui') === '0') document.body.classList.add('oc-no-ui'); // ?ui=0: the sea alone (pictures, measurements)

// Everything a test or a curious user may read; window.oceand hands out copies.
const st = {
  connected: false, connectionState: 'idle', clientId: null, role: null,
  controlState: 'idle', controlId: null, paramsBy: null, // the control connection (sets and their replies)
  framesReceived: 0, lastSeq: null, paramsVersion: null, params: null,
  rendered: 0, n: null, lod: null, frameParamsVersion: null, frameSimTime: null, lastError: null, serverError: null,
  name: null, subscription: null, foamLod: null, foamM: 0,
  clusterState: null, // edge's {"type":"status"}: 'ok', 'sim_unavailable', 'nats_unavailable'
  referenceErrors: 0, resyncs: 0, // temporal: predicted frames without their references, and resubscriptions
  localDrops: 0,   // temporal: times the page dropped frames because the decoder fell behind (breaks the chain)
  firstDrawnMs: null, // when the first frame was drawn (ms since the page loaded): the grace starts
  fallback: null,  // temporal given up: { atMs (since the page loaded), drops (within 10 s) }
};
// Local view state: never sent. ?hour=h starts at that local time of day.
const hourArg = Number(query.get('hour'));
const view = { wireframe: false, freeze: false, hour: query.has('hour') && hourArg >= 0 && hourArg <= 24 ? hourArg : DEFAULT_HOUR, hud: hud.visible };
// ?bench=1: time decode + upload per frame (upload waits for the GPU with finish())
// and draw nothing, so rendering does not compete for the CPU being measured.
const bench = query.has('bench');
// ?draw=0 (tests): everything but drawing the sea (frames decoded and uploaded, sky, HUD,
// panel), for pages whose checks read the page's state and layout, not its pixels.
const draw = !bench && query.get('draw') !== '0';
const timings = { decode: [], assemble: [], upload: [] };
// A page that falls behind the live sea says so and asks for less (catchup.js). ?catchup=0:
// never (pages that measure one held picture); never in bench mode.
const catchUp = new CatchUp({ enabled: !bench && query.get('catchup') !== '0' });
let testBusyMs = 0, lastPing = -Infinity; // ?test: a busy main thread (options({busyMs}))
let catchUpReopen = false; // the frame connection is being opened afresh by catchUp, not lost

const worker = new Worker(new URL('./worker.js', import.meta.url), { type: 'module' });
let workerBusy = 0;            // frames handed to the worker and not yet back
let pendingFrame = null;       // newest decoded frame waiting for the render loop
// Temporal codec (codec 3, PROTOCOL.md §5.9) unless ?temporal=0 asks for intra-only frames:
// every frame must then reach the decoder (its codes are the next frame's references), so
// frames are never dropped before the worker except when it falls far behind (then resync).
let temporal = query.get('temporal') !== '0';
// Temporal: every frame goes to the worker, which alone can tell whether the decoder keeps up
// (worker.js MAX_WAIT_MS); this thread counts frames it handed over and has not heard back
// about, which grows while it is busy itself (rendering, compiling shaders) without the
// decoder being behind: it drops only past MAX_IN_FLIGHT (10 s at 30 Hz; bounds the memory).
const MAX_IN_FLIGHT = 300;
// The first seconds of a page (shaders compile, the JIT warms up, the first frames come in
// a burst) say nothing about whether it keeps up: drops then resync but never make the page
// give the temporal codec up. The grace ends GRACE_MS after the first frame is drawn.
const GRACE_MS = 10000;
let graceEnd = Infinity;
// parts: a tick's frame may come in several messages, so a reply (the panel's `set`) need not
// wait behind a whole keyframe on a slow link (PROTOCOL.md §3.4; connection.js joins them).
const wantedSub = temporal ? { temporal: true, parts: true } : { parts: true }; // kept across reconnects, with the panel's changes
let lastResync = -Infinity;
// Cascades 1..3 (PROTOCOL.md §4.1): their height, at LOD 1 (each holds waves up to half its
// Nyquist wavenumber, so LOD 1 loses nothing) and 1 mm (their heights are centimetres).
// Asked for always: the server leaves out cascades that are not in force. ?cascades=0: none.
const CASCADE_SUB = [1, 2, 3].map(() => ({ fields: ['height'], lod: 1, bound: 0.001 }));
const useCascades = query.get('cascades') !== '0';
// Foam: the server's shared `foam` field, at a coarse LOD of its own (a 64×64 grid for
// any N: 1-5 % more bytes, bench/foam_bytes.py). ?foam=0: don't ask (the shader then
// makes foam from the Jacobian, as it does with a server that has no foam field).
const wantFoam = query.get('foam') !== '0';
const foamLodFor = (n) => Math.max(0, Math.min(4, Math.round(Math.log2((n || 256) / 64))));
function foamSubscription(hello, n) {
  if (!wantFoam || !(hello.fields || []).includes('foam')) return null;
  const field_lod = { foam: foamLodFor(n) };
  if (wantedSub.fields) return { field_lod }; // the developer panel chose the fields: keep them
  const fields = hello.subscription?.fields || ['height', 'dx', 'dz'];
  return { fields: fields.includes('foam') ? fields : [...fields, 'foam'], field_lod };
}
let lastHello = null;

const conn = new Connection(serverUrl(), {
  onState(state, detail) {
    st.connectionState = state;
    st.connected = state === 'open';
    // Banner: the first "connecting…", then why we are down; a retry's own
    // "connecting" keeps the last reason on screen. Cleared by hello.
    if (state === 'closed' || state === 'retrying') hud.message(detail);
    else if (state === 'connecting' && st.framesReceived === 0 && st.clientId === null) hud.message(detail);
    if (state === 'retrying' || state === 'closed') catchUpReopen = false; // the fresh connection failed: lost
    if (state !== 'open' && !catchUpReopen && (st.clientId !== null || panel.connected)) { st.clientId = null; panel.disconnected(); }
  },
  onMessage(msg) {
    if (probe.onMessage(msg)) return; // the buoy marker's probe/query answers (probe.js)
    seaFrom(msg);
    switch (msg.type) {
      case 'hello': {
        // A new session after an old one: did the sea change meanwhile? A lower parameters
        // version means the daemon restarted (without its saved state, if the sea differs).
        const prev = lastHello ? { params: st.params, version: st.paramsVersion } : null;
        st.clientId = msg.client_id; st.role = msg.role; st.name = null;
        st.lastSeq = null; // a new session: seq gaps across a reconnect are not drops
        worker.postMessage({ type: 'reset' }); // its references belong to the old session
        st.params = msg.params; st.paramsVersion = msg.params_version;
        // A fresh connection of this page's own (catchup.js) to the same sea keeps the panel as it
        // is (a value being typed, the notes): only its client id is new.
        if (catchUpReopen && prev?.params && !panel.differences(prev.params, msg.params || {}).length) panel.myId = msg.client_id;
        else panel.build(msg);
        catchUpReopen = false;
        // Bodies: the kinds, the list, and this tab's bodies claimed back (the new session's id).
        bodies.hello(msg, [msg.client_id, st.controlId]);
        bodies.buildPanel(panel.gui);
        if (msg.subscription) panel.subscribed(msg.subscription);
        if (panel.me.name) conn.send({ type: 'name', name: panel.me.name }); // our display name, every session
        ocean.setWind(msg.params?.wind_speed, msg.params?.wind_direction);
        seaView.setParams(msg.params);
        seaView.applySea(msg.sea ?? null, { fresh: true }); // the measured sea's summary, or null
        lastHello = msg;
        if (msg.role === 'controller' && control.state === 'idle') control.start(); // only a controller sets
        // After a reconnect, ask again for what the user had chosen; the finer cascades,
        // where the server has them (hello.cascade_patch_sizes); and the foam field.
        {
          const foam = foamSubscription(msg, msg.params?.resolution);
          const casc = msg.cascade_patch_sizes && useCascades ? { cascades: CASCADE_SUB } : null;
          if (Object.keys(wantedSub).length || foam || casc || catchUp.step) conn.send({ type: 'subscribe', ...(casc || {}), ...wantedSub, ...(foam || {}), ...catchUpSub() });
          catchUp.tickRate = msg.tick_rate || 30;
        }
        hud.message('');
        if (prev && prev.params) {
          const diff = panel.differences(prev.params, msg.params || {});
          const restarted = msg.params_version < prev.version;
          if (diff.length) {
            st.restartNote = `${restarted ? 'the server restarted and the sea was reset' : 'the sea changed while you were away'}: ${diff.slice(0, 4).join(', ')}${diff.length > 4 ? ', …' : ''}`;
            panel.announce(st.restartNote);
          } else if (restarted) panel.announce(`the server restarted; the sea is as it was (you are now ${msg.client_id})`);
        }
        break;
      }
      case 'params':
        onParams(msg);
        break;
      case 'bodies': // who owns which body, under what name; bodies gone (PROTOCOL.md §7.6)
        bodies.list(msg);
        break;
      case 'launched': case 'claimed': // our body (a launch, or one claimed back after a reload)
        bodies.launched(msg);
        break;
      case 'named': // our display name as the server now has it
        st.name = msg.name;
        panel.named(msg.name);
        break;
      case 'subscribed':
        st.subscription = msg.subscription || msg;
        panel.subscribed(msg.subscription || msg);
        break;
      case 'link': // the server's quality ladder for this link (PROTOCOL.md §7.2): shown in the HUD
        st.link = msg;
        break;
      case 'degraded': // the server serves this subscription coarser or less often, and says why (§7.2)
        st.degraded = msg.active === false ? null : msg;
        break;
      case 'pong': catchUp.pong(msg, performance.now()); break; // the clock offset
      case 'status': // cluster edge: the simulation behind it is unavailable (or back); the socket stays open
        st.clusterState = msg.state;
        hud.message(msg.state === 'ok' ? '' : (msg.message || 'simulation unavailable'));
        break;
      case 'error': // a rejected request: the panel says why (decode errors go to the HUD)
        if (msg.code === 'duplicate') break; // a change's copy that the control connection brought first
        if (bodies.claimRefused(msg)) break;  // a body of this tab's that is gone: forget it quietly
        st.serverError = msg;
        panel.error(msg);
        break;
      default: break;
    }
  },
  onFrame(buf) {
    if (buf.byteLength >= 48) catchUp.arrived(Number(new DataView(buf).getBigUint64(40, true)), performance.now(), buf.byteLength);
    st.framesReceived++;
    stats.frames++;
    stats.bytes += buf.byteLength;
    // Never queue behind a slow decoder: skip instead of lagging (the seq gap counts it).
    // Temporal: the worker decodes every frame in order, skips only the assembly of
    // overtaken ones, and drops its queue when it falls behind (then we ask for keyframes).
    if (temporal ? workerBusy >= MAX_IN_FLIGHT : workerBusy >= (bench ? 1 : 2)) { // bench: one at a time
      if (temporal) dropped();
      return;
    }
    workerBusy++;
    worker.postMessage({ type: 'frame', buf, temporal }, [buf]);
  },
});

// A `params` from either connection, applied once: both carry every change (the frame
// connection's copy may wait behind a lost segment of a frame; the control connection's not).
function onParams(msg) {
  if (st.paramsVersion !== null && msg.params_version <= st.paramsVersion) return; // seen, or a set that changed nothing
  st.params = msg.params; st.paramsVersion = msg.params_version; st.paramsBy = msg.by ?? null;
  panel.update(msg);
  ocean.setWind(msg.params?.wind_speed, msg.params?.wind_direction);
  seaView.setParams(msg.params);
  if ('sea' in msg) seaView.applySea(msg.sea);
  // A new N: keep the foam grid at about 64×64.
  if ((msg.changed || []).includes('resolution') && lastHello) {
    const foam = foamSubscription(lastHello, msg.params.resolution);
    if (foam) conn.send({ type: 'subscribe', field_lod: foam.field_lod });
  }
}

// The panel's sets go on a second connection that carries no frames (?frames=0, PROTOCOL.md
// §1.2): over one TCP connection a reply waits behind any lost segment of the frames sent
// before it (a round trip or more on a lossy link); on its own connection it waits for
// nothing. Opened once this page is a controller; until it is open, sets use the frame
// connection only. Its session has its own client id, which is "you" too.
const control = new Connection(controlUrl(serverUrl()), {
  onState(state) {
    st.controlState = state;
    if (state !== 'open') { st.controlId = null; panel.controlId = null; }
  },
  onMessage(msg) {
    seaFrom(msg);
    switch (msg.type) {
      case 'hello':
        st.controlId = msg.client_id;
        panel.controlId = msg.client_id;
        bodies.setMyIds([st.clientId, st.controlId]);
        if (panel.me.name) control.send({ type: 'name', name: panel.me.name }); // shown with our changes
        break;
      case 'params': onParams(msg); break;
      case 'pong': catchUp.pong(msg, performance.now()); break;
      case 'error': // a refused set; `duplicate`: its copy on the frame connection came first
        if (msg.id !== undefined && msg.code !== 'duplicate') { st.serverError = msg; panel.error(msg); }
        break;
      default: break; // named, capacity, status: the frame connection says them
    }
  },
});
// A change goes out on both connections, under one random "once" key (PROTOCOL.md §7.1): the
// server applies the copy that arrives first and answers the other with `duplicate`, so a lost
// packet on either connection does not delay it. Without the control connection: one copy.
function sendChange(msg) {
  if (!st.controlId) return conn.send(msg);
  const bytes = crypto.getRandomValues(new Uint8Array(12)); // randomUUID needs a secure context
  const once = Array.from(bytes, (b) => b.toString(16).padStart(2, '0')).join('');
  const id = control.send({ ...msg, once });
  conn.send({ ...msg, once });
  return id;
}

// Double-click the sea to drop a buoy (point probe + exact query, probe.js).
const probe = new ProbeMarker({ scene: ocean.scene, camera, canvas, send: (m) => conn.send(m) });
// Bodies on the shared sea (bodies.js): every body request goes on the frame connection, whose
// session owns what it launches (the control connection is another session, PROTOCOL.md §7.6).
const bodies = new Bodies({ scene: ocean.scene, camera, controls, send: (m) => conn.send(m) });

const panel = new Panel({
  set: (params) => sendChange({ type: 'set', params }),
  name: (name) => { conn.send({ type: 'name', name }); control.send({ type: 'name', name }); },
  subscribe: (sub) => { Object.assign(wantedSub, sub); conn.send({ type: 'subscribe', ...sub }); },
  view,
  onView(key, v) {
    if (key === 'wireframe') ocean.wireframe = v;
    if (key === 'hud' && v !== hud.visible) hud.setVisible(v);
  },
}, { compact: compact || query.get('panel') === 'closed' });
hud.onToggle = (on) => { view.hud = on; panel.refreshView(); };
// What sea this is, the compass, the measured spectrum's polar plot (seaview.js). Its summary
// comes in hello and in the broadcasts (onParams); any other message that carries `sea` is a
// broadcast of it too (applySea keeps the newest version of the copies both connections bring).
const seaView = new SeaView({ gui: panel.gui, after: panel.folders.sea, compact });
function seaFrom(msg) { if ('sea' in msg && msg.type !== 'hello' && msg.type !== 'params') seaView.applySea(msg.sea); }
panel.onAnnounce = showToast;
hud.onBanner = (shown) => { if (shown) toast.hidden = true; }; // the banner's place
if (query.get('wireframe') === '1') { view.wireframe = true; ocean.wireframe = true; panel.refreshView(); }
// H shows or hides the status (not while typing in a panel field).
window.addEventListener('keydown', (ev) => {
  if ((ev.key === 'h' || ev.key === 'H') && !ev.ctrlKey && !ev.metaKey && !ev.altKey && !(ev.target instanceof HTMLInputElement)) hud.setVisible(!hud.visible);
});

// The decoder fell behind and frames were dropped: resync; a third time within 10 s after the
// start-up grace, give up the temporal codec for this page (intra frames can be skipped
// before decoding, so a slow decoder then shows fewer frames instead of falling behind).
const dropTimes = [];
function dropped() {
  st.localDrops++;
  const now = performance.now();
  if (now < graceEnd) { resync(); return; }
  dropTimes.push(now);
  while (dropTimes.length && now - dropTimes[0] > 10000) dropTimes.shift();
  if (dropTimes.length < 3) { resync(); return; }
  temporal = false;
  st.fallback = { atMs: Math.round(now), drops: dropTimes.length };
  wantedSub.temporal = false;
  conn.send({ type: 'subscribe', temporal: false });
}

// Subscribing again makes the server send keyframe tiles from its next frame on (§5.9): the
// way out of a broken chain. At most once a second (frames already on their way still fail).
function resync() {
  const now = performance.now();
  if (now - lastResync < 1000) return;
  lastResync = now;
  st.resyncs++;
  conn.send({ type: 'subscribe', ...wantedSub, ...catchUpSub() });
}

// Behind the live sea (catchup.js): a step down opens a fresh connection (the browser's backlog
// of the old one is dropped) whose hello asks for less; a step up asks for more on this one.
function catchUpBase() {
  return { lod: wantedSub.lod ?? lastHello?.subscription?.lod ?? 0, tickRate: wantedSub.max_rate ?? lastHello?.tick_rate ?? 30,
    cascades: lastHello?.cascade_patch_sizes && useCascades ? CASCADE_SUB : null };
}
function catchUpSub() { return catchUp.overrides(catchUpBase()); }
function catchUpTick(now) {
  if (testBusyMs) { const t = performance.now(); while (performance.now() - t < testBusyMs); }
  if (now - lastPing > 20000 && st.connected) { lastPing = now; (st.controlId ? control : conn).send({ type: 'ping', t: performance.now() }); }
  catchUp.notBefore = graceEnd;
  const act = st.connected ? catchUp.update(now) : null;
  if (act?.down) { catchUpReopen = true; conn.reopen(); }
  else if (act?.up) conn.send({ type: 'subscribe', ...catchUp.restore(catchUpBase()) });
  st.catchup = catchUp.status(now, { ...(st.subscription || {}), ...catchUpSub() }); // what it asks for
}

worker.onmessage = (ev) => {
  const msg = ev.data;
  if (msg.type === 'behind') { workerBusy -= msg.count; dropped(); return; } // it dropped its queue
  workerBusy--;
  if (msg.type === 'skip' || msg.type === 'frame') { stats.decoded(msg.seq ?? msg.header?.seq, msg.serverTimeUs ?? msg.header?.serverTimeUs); stats.lastDecodedAt = performance.now(); }
  if (msg.type === 'skip') return; // decoded (a reference for the next), overtaken before assembly
  if (msg.type === 'error' && msg.code === 'reference') { st.referenceErrors++; resync(); return; }
  if (msg.type === 'error') { st.lastError = { code: 'decode', message: msg.message }; return; }
  const h = msg.header;
  st.lastError = null;
  // A seq far behind the last one is a new stream (an edge whose simulation was replaced,
  // PROTOCOL.md §3.3): count afresh instead of waiting for seq to pass the old value.
  if (st.lastSeq !== null && h.seq + STREAM_RESTART_TICKS < st.lastSeq) st.lastSeq = null;
  // Two frames may decode at once (the decoder awaits); never show an older one after a newer.
  if (st.lastSeq !== null && h.seq <= st.lastSeq) { recycle(msg); return; }
  if (st.lastSeq !== null && h.seq > st.lastSeq + 1) stats.dropped += h.seq - st.lastSeq - 1;
  st.lastSeq = h.seq;
  bodies.record(h.seq, h.bodies);
  stats.decodeMs = msg.decodeMs;
  stats.inflater = msg.inflater; // 'wasm' or 'fflate' (the worker's raw-DEFLATE inflater)
  if (pendingFrame) recycle(pendingFrame); // superseded before it was shown
  pendingFrame = msg;
};

function recycle(f) {
  const buffers = [];
  if (f.disp) buffers.push({ buffer: f.disp.buffer, channels: 4 });
  if (f.slope) buffers.push({ buffer: f.slope.buffer, channels: 2 });
  for (const c of f.fine || []) buffers.push({ buffer: c.disp.buffer, channels: 4 });
  if (f.foam) buffers.push({ buffer: f.foam.buffer, channels: 1 });
  worker.postMessage({ type: 'recycle', buffers }, buffers.map((b) => b.buffer));
}

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.floor(w * renderer.getPixelRatio()) || canvas.height !== Math.floor(h * renderer.getPixelRatio())) {
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
  }
}

// The camera never goes below the displaced surface beneath it + CAMERA_CLEARANCE (the
// orbit's polar limit does not keep it above the water; a storm's crests are metres high).
// The surface is read from the grids drawn (cascade 0 and the finer cascades), at the
// camera and a ring of points as wide as the near plane's half-diagonal, so the view does
// not cut into a crest beside it. ?camfloor=0 turns it off (tests show what it prevents).
const CAMERA_CLEARANCE = 1;
let camFloor = query.get('camfloor') !== '0';
function clearanceAt(x, z) {
  let h = ocean.surfaceHeight(x, z);
  const r = 0.6; // metres: beyond the near plane's corners (0.5 m, 55° field of view)
  for (let k = 0; k < 6; k++) h = Math.max(h, ocean.surfaceHeight(x + r * Math.cos(k * Math.PI / 3), z + r * Math.sin(k * Math.PI / 3)));
  return h;
}
// The floor lifts the camera drawn, not the user's camera: the orbit (OrbitControls) keeps the
// height the user chose, the lift is taken off before each of its updates and put back after, so
// when the water beneath falls back the camera follows it down, easing (LIFT_EASE_S) to the
// user's height and never below the floor; over a crest it rises at once.
const LIFT_EASE_S = 0.35;
let camLift = 0, liftAt = 0;
{
  const orbitUpdate = controls.update.bind(controls);
  controls.update = (...a) => {
    camera.position.y -= camLift;
    const r = orbitUpdate(...a);
    camera.position.y += camLift;
    if (camLift) camera.lookAt(controls.target);
    return r;
  };
}
function keepAboveWaves(now) {
  const dt = Math.min(1, Math.max(0, (now - liftAt) / 1000));
  liftAt = now;
  const p = camera.position, own = p.y - camLift;
  const want = camFloor && ocean.hasData ? Math.max(0, clearanceAt(p.x, p.z) + CAMERA_CLEARANCE - own) : 0;
  let lift = want >= camLift ? want : want + (camLift - want) * Math.exp(-dt / LIFT_EASE_S);
  if (lift < 1e-4) lift = 0;
  if (lift === camLift) return;
  camLift = lift;
  p.y = own + lift;
  camera.lookAt(controls.target);
}

// Settings whose waves are all shorter than the grids resolve (a patch of kilometres over
// a half-metre-deep sea) draw a flat, featureless sea: say why on screen, and what helps.
// Flat: the grids hold under 2 % of the slope variance the wind gives (Cox & Munk).
function flatNotice() {
  const v = ocean.slopeVar;
  const flat = !!(v && st.connected && v.cascade0 + v.cascades[0] + v.cascades[1] + v.cascades[2] < 0.02 * v.total && v.total > 0.004);
  const text = flat ? `The sea looks flat: its waves are shorter than the grid resolves (cells of ${v.cell >= 10 ? v.cell.toFixed(0) : v.cell.toFixed(1)} m). A smaller patch size, a deeper sea or a longer fetch shows them.` : '';
  if (text === st.flatNotice) return;
  st.flatNotice = text;
  flatEl.hidden = !text;
  flatEl.textContent = text;
}
const flatEl = document.createElement('div');
flatEl.id = 'flat-note';
flatEl.dataset.ui = 'flat-note';
flatEl.hidden = true;
document.body.appendChild(flatEl);

function frameLoop() {
  const now = performance.now();
  resize();
  if (pendingFrame && !view.freeze) {
    const f = pendingFrame;
    pendingFrame = null;
    const { uploadMs, released } = ocean.setFrame(f, now, bench);
    stats.shownFrames++;
    bodies.setFrame(f.header.bodies, f.header.seq);
    stats.uploadMs = uploadMs;
    if (bench && timings.decode.length < 10000) { timings.decode.push(f.decodeMs); timings.assemble.push(f.assembleMs); timings.upload.push(uploadMs); }
    const buffers = released.map((a) => ({ buffer: a.buffer, channels: a.length === f.m * f.m * 4 ? 4 : a.length === f.m * f.m * 2 ? 2 : 1 }));
    for (const a of ocean.setCascades(f.fine)) buffers.push({ buffer: a.buffer, channels: 4 });
    worker.postMessage({ type: 'recycle', buffers }, buffers.map((b) => b.buffer));
    st.n = f.header.n; st.lod = f.lod; st.frameParamsVersion = f.header.paramsVersion; st.frameSimTime = f.header.simTime;
    if (graceEnd === Infinity) { graceEnd = now + GRACE_MS; st.firstDrawnMs = Math.round(now); }
    st.foamLod = f.foam ? f.foamLod : null; st.foamM = f.foam ? f.fm : 0;
    // Latency: server encode time to the frame reaching the screen (clocks of one machine, or NTP).
    stats.latencyMs = (performance.timeOrigin + now) - f.header.serverTimeUs / 1000;
  }
  controls.update();
  keepAboveWaves(now);
  // Sky, sun and light follow the local hour and the shared sea's wind; haze thickens with it.
  if (sky.update(view.hour, st.params?.wind_speed ?? 10)) ocean.uniforms.uFogDensity.value = sky.state.fogDensity;
  // The bodies are blended between the same two frames as the sea, by the same amount.
  bodies.update(ocean.lastArrival ? Math.min(Math.max((now - ocean.lastArrival) / ocean.interval, 0), 1) : 1, sky.uniforms, now);
  if (draw) ocean.render(camera, now);
  if (ocean.hasData) st.rendered++;
  flatNotice();
  stats.renders++;
  stats.tick(now);
  catchUpTick(now);
  hud.draw(now, stats, st);
  seaView.frame(camera);
  requestAnimationFrame(frameLoop);
}

// Read-only view for tests and curious users.
const snapshot = (o) => (o === null || typeof o !== 'object' ? o : Object.freeze(structuredClone(o)));
window.oceand = Object.freeze({
  get connected() { return st.connected; },
  get connectionState() { return st.connectionState; },
  get framesReceived() { return st.framesReceived; },
  get lastSeq() { return st.lastSeq; },
  get paramsVersion() { return st.paramsVersion; },
  get frameParamsVersion() { return st.frameParamsVersion; },
  get frameSimTime() { return st.frameSimTime; }, // sim_time (s) of the frame drawn last
  get params() { return snapshot(st.params); },
  get rendered() { return st.rendered; },
  get clientId() { return st.clientId; },
  get controlId() { return st.controlId; }, // the control connection's client id (null: not open)
  get paramsBy() { return st.paramsBy; },   // `by` of the last change applied
  get name() { return st.name; },  // our display name in force on the server (null: none yet)
  get subscription() { return snapshot(st.subscription); },
  get bodies() { return snapshot(bodies.snapshot()); }, // every body drawn: kind, owner, name, mine, pose
  get selectedBody() { return bodies.selected; },
  // Where the foam drawn comes from: the server's field (at lod, F×F) or the Jacobian.
  get foam() { return snapshot({ source: ocean.uniforms.uFoamField.value ? 'field' : 'jacobian', lod: st.foamLod, size: st.foamM }); },
  get wireframe() { return ocean.wireframe; },
  get view() { return snapshot({ hour: view.hour, hud: hud.visible, compact, sky: sky.state }); },
  get flatNotice() { return st.flatNotice || null; },
  get sea() { return snapshot(seaView.summary); }, // the measured sea's summary shown (null: parametric)
  get catchup() { return snapshot(st.catchup || null); }, // behind the live sea? (catchup.js)
  get degraded() { return snapshot(st.degraded || null); }, // the server's last `degraded` (active), or null
  get link() { return snapshot(st.link || null); },
  get note() { return { panel: document.querySelector('[data-ui=last-change]')?.textContent ?? null, toast: toast.hidden ? null : toast.textContent }; },
  get camera() { return snapshot({ position: camera.position.toArray(), target: controls.target.toArray(), lift: camLift }); }, // lift: the floor's
  get stats() {
    return Object.freeze({
      fps: stats.fps, framesPerSec: stats.framesPerSec, kBps: stats.kBps, latencyMs: stats.latencyMs,
      dropped: stats.dropped, decodeMs: stats.decodeMs, uploadMs: stats.uploadMs, inflater: stats.inflater, n: st.n, lod: st.lod,
      temporal, referenceErrors: st.referenceErrors, resyncs: st.resyncs, localDrops: st.localDrops,
      framesInParts: conn.joiner ? conn.joiner.joined : 0, // this connection's ticks that came in parts (§3.4)
      fallback: snapshot(st.fallback), firstDrawnMs: st.firstDrawnMs, graceMs: GRACE_MS,
      lastError: snapshot(st.lastError), serverError: snapshot(st.serverError),
      ...(bench ? { timings: snapshot(timings) } : {}),
    });
  },
});

// ?test=1 only: switches a test needs on one held frame (the page's own state, never sent).
if (query.has('test')) {
  window.oceandTest = Object.freeze({
    freeze(on) { view.freeze = !!on; panel.refreshView(); },
    crackFixes(fixes) { ocean.setCrackFixes(fixes); },
    // The grids drawn around (x, z), as plain arrays (tests compute the surface beneath the
    // camera themselves): the nodes of cascade 0 within r metres, of both frames blended
    // ((dx, h, dz) at node (i0 + a, j0 + b) = patch-periodic index), and the finer cascades'.
    grids(x, z, r) {
      const win = (data, m, L, stride) => {
        const cell = L / m, i0 = Math.floor((x - r) / cell), j0 = Math.floor((z - r) / cell), w = Math.ceil(2 * r / cell) + 2;
        const out = [];
        for (let b = 0; b < w; b++) for (let a = 0; a < w; a++) {
          const i = ((i0 + a) % m + m) % m, j = ((j0 + b) % m + m) % m, k = stride * (j * m + i);
          out.push(data[k], data[k + 1], data[k + 2]);
        }
        return { cell, i0, j0, w, v: out };
      };
      return {
        disp: ocean.disp.filter((t) => t && t.image.data.length === ocean.m * ocean.m * 4).map((t) => win(t.image.data, ocean.m, ocean.patch, 4)),
        cascades: [1, 2, 3].map((c) => (ocean.cascades[c] && ocean.uniforms.uCOn.value.getComponent(c - 1) > 0
          ? ocean.cascades[c].tex.map((t) => win(t.image.data, ocean.cascades[c].m, ocean.uniforms.uCPatch.value.getComponent(c - 1), 4)) : null)),
      };
    },
    // Where a world point lands on the canvas, in CSS pixels (null: behind the camera).
    project([x, y, z]) {
      const v = new THREE.Vector3(x, y, z).project(camera);
      if (v.z > 1) return null;
      return [(v.x + 1) / 2 * canvas.clientWidth, (1 - v.y) / 2 * canvas.clientHeight];
    },
    slopeVariance() { return ocean.slopeVar || null; },
    // Bodies: the records of the frame of tick seq as this page received them (null: not kept),
    // the drawn surface's height at (x, z), and a raw message on the frame connection.
    bodyRecords(seq) { const r = bodies.history.get(seq); return r ? structuredClone(r) : null; },
    bodySeqs() { return [...bodies.history.keys()]; },
    drawnBodySeq() { return bodies.seq ?? null; }, // the tick whose records are drawn (the newer of the two frames)
    surfaceHeight(x, z, slot = null) { return ocean.surfaceHeight(x, z, slot); },
    send(msg) { return conn.send(msg); },
    // A measured sea's summary as if the daemon had broadcast it (seaview.js), and its plot opened.
    sea(summary, { fresh = false } = {}) { // with the spectrum "measured", as the daemon's params bring it
      if (summary) seaView.setParams({ ...(seaView.params || {}), spectrum: 'measured' });
      return seaView.applySea(summary, { fresh });
    },
    seaPlot(on) { seaView.openPlot(on); },
    // The foam field drawn: size, and the share of samples at >= 0.5 and > 0.1.
    foamStats() {
      const f = ocean.foam[1]?.image.data;
      if (!f) return null;
      let half = 0, some = 0;
      for (const v of f) { half += v >= 0.5; some += v > 0.1; }
      return { size: ocean.foamM, covered: half / f.length, some: some / f.length, jc: ocean.uniforms.uFoamJc.value };
    },
    // Put the camera at pos looking at target (as the URL's ?cam= and ?target= do).
    // (The orbit's damped motion left from earlier gestures is dropped: it would turn the new view.)
    look(pos, target) {
      camLift = 0; controls._sphericalDelta.set(0, 0, 0); controls._panOffset.set(0, 0, 0); controls._scale = 1;
      camera.position.set(...pos); controls.target.set(...target); controls.update();
    },
    // What the URL's ?hour=, ?gapprobe=, ?debugview=foam, ?foamshift=, ?camfloor= and ?scale= set, on
    // a page already open (one page serves several views; any member may be left out);
    // foamStreaks: false leaves the wind's streaks out of the foam (the crest-placement check).
    options({ hour, gapProbe, debugFoam, foamShift: shift, foamStreaks, camFloor: floorOn, scale, busyMs } = {}) {
      if (hour !== undefined) view.hour = hour;
      if (busyMs !== undefined) testBusyMs = Math.max(0, Number(busyMs) || 0); // every animation frame this long
      if (scale !== undefined) renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2) * Math.min(1, Math.max(0.25, scale)));
      if (gapProbe !== undefined) sky.uniforms.uGapProbe.value = gapProbe ? 1 : 0;
      if (debugFoam !== undefined) ocean.uniforms.uDebugView.value = debugFoam ? 1 : 0;
      if (shift !== undefined) ocean.uniforms.uFoamShift.value.set(...(shift || [0, 0]));
      if (foamStreaks !== undefined) ocean.uniforms.uFoamStreaks.value = foamStreaks ? 1 : 0;
      if (floorOn !== undefined) camFloor = !!floorOn;
      panel.refreshView();
    },
  });
}

conn.start();
requestAnimationFrame(frameLoop);

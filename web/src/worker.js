// Decoder worker: turns one binary frame into GPU-ready arrays so the render
// loop never decodes. Frame tiles are assembled into M×M textures (M = N >> lod):
//   disp  RGBA float32: (dx, height, dz, jacobian)  — jacobian 1 when not streamed
//   slope RG   float32: (slope_x, slope_z)          — only when slopes are streamed
//   foam  R    float32: server foam 0..1, F×F at its own LOD (F = N >> foamLod) — only when streamed
// Output buffers are transferred to the main thread, which hands them back for
// reuse (no 4 MB allocation per frame at N=512).
import { inflateSync } from 'fflate';
import kernelBytes from 'oc-kernels.wasm';
import { decodeFrame, setInflateRaw, setTemporalKernel, DecoderState } from '../../proto/js/oc_decode.js';
import { loadKernels } from '../../proto/js/oc_wasm.js';

// Raw DEFLATE (codecs 1 and 3): a synchronous inflater for small tiles, where one async
// DecompressionStream per tile costs more than the inflating (the decoder picks per tile).
// The WebAssembly one (proto/wasm/oc_inflate.c, embedded in this bundle) once it has loaded;
// fflate until then, and for good where WebAssembly is missing or refuses the module
// (same bytes, checked on proto/vectors/: tests/proto_js_inflate.test.mjs). The module also
// predicts codec 3 tiles (SIMD, proto/wasm/oc_predict.c); the JavaScript predictor is its fallback.
let inflater = 'fflate';
setInflateRaw((src, out) => inflateSync(src, { out }));
const kernelsReady = loadKernels(kernelBytes).then((k) => {
  // every tile: faster than a DecompressionStream at any size (docs/web.md)
  if (k) { setInflateRaw(k.inflateRaw, { allTiles: true }); setTemporalKernel(k.temporal); inflater = 'wasm'; }
}, () => {});

const CHANNEL = { dx: [0, 4], height: [1, 4], dz: [2, 4], jacobian: [3, 4], slope_x: [0, 2], slope_z: [1, 2] };
const pool = { 4: [], 2: [], 1: [] }; // recycled ArrayBuffers by channel count

// The pool of a channel count holds buffers of several sizes (the surface's and the cascades'
// RGBA arrays): take one of the size wanted and keep the others (dropping them, as this did,
// made a new 1 MB array most frames once cascades were subscribed).
function take(channels, count) {
  const list = pool[channels], bytes = count * channels * 4;
  for (let i = list.length - 1; i >= 0; i--) {
    if (list[i].byteLength === bytes) return new Float32Array(list.splice(i, 1)[0]);
  }
  return new Float32Array(count * channels);
}

// Codec 3 (temporal) tiles are predicted from the previous frames: one DecoderState keeps
// their codes, and frames are decoded strictly one after the other, in arrival order (a
// frame's tiles may inflate asynchronously, so a queue serialises them). A frame that a
// newer one has already overtaken in the queue is decoded (its codes are the next frame's
// references) but not assembled: the render loop would never show it (unless nothing was
// assembled for 100 ms: a worker that is always behind still shows ten frames a second).
// The main thread hands every temporal frame over at once, however busy it is itself (a page
// that renders slowly, or compiles its shaders, gets its messages in bursts); only this
// worker can tell whether the *decoder* keeps up: when the oldest frame in its queue has
// waited more than MAX_WAIT_MS, it drops the whole queue (the chain is broken: the main thread
// resubscribes for keyframes, and counts the event towards giving the temporal codec up).
const MAX_WAIT_MS = 1000;
const state = new DecoderState();
const queue = [];
let running = false;
let lastAssembled = 0;

self.onmessage = (ev) => {
  const msg = ev.data;
  if (msg.type === 'recycle') {
    for (const b of msg.buffers) if (b && pool[b.channels]) pool[b.channels].push(b.buffer);
    return;
  }
  if (msg.type === 'reset') { state.reset(); return; }
  if (msg.type !== 'frame') return;
  msg.arrived = performance.now();
  queue.push(msg);
  if (!running) drain();
};

// Yield to the event loop between frames (a message, not a clamped timer), so that frames
// arriving meanwhile join the queue: its length and age are then the decoder's real backlog.
const yieldChannel = new MessageChannel();
const yieldWaiters = [];
yieldChannel.port1.onmessage = () => yieldWaiters.shift()?.();
const yieldTask = () => new Promise((resolve) => { yieldWaiters.push(resolve); yieldChannel.port2.postMessage(0); });

async function drain() {
  running = true;
  while (queue.length) {
    if (queue[0].temporal && performance.now() - queue[0].arrived > MAX_WAIT_MS) {
      const count = queue.length;
      queue.length = 0;
      self.postMessage({ type: 'behind', count });
      break;
    }
    const msg = queue.shift();
    await kernelsReady; // resolves once, within milliseconds of start-up
    await handle(msg, queue.length > 0);
    await yieldTask();
  }
  running = false;
}

async function handle(msg, superseded) {
  const t0 = performance.now();
  // A frame overtaken in the queue is decoded (references) but not assembled: samples only.
  const assemble = !(superseded && t0 - lastAssembled < 100);
  let frame, plan = null, layoutMs = 0;
  try {
    frame = await decodeFrame(msg.buf, {
      state,
      target: assemble ? (h, tiles) => {
        const t = performance.now();
        plan = layout(h, tiles);
        layoutMs = performance.now() - t;
        return plan.targets;
      } : null,
    });
  } catch (e) {
    if (plan) release(plan);
    self.postMessage({ type: 'error', code: e && e.code, message: String(e && e.message || e) });
    return;
  }
  if (!assemble) { self.postMessage({ type: 'skip', seq: frame.header.seq, serverTimeUs: frame.header.serverTimeUs }); return; }
  lastAssembled = t0;
  const { lod, m, present, disp, slope, fine, foam, foamLod, fm } = plan;
  const decodeMs = performance.now() - t0;
  const transfer = [disp.buffer];
  if (slope) transfer.push(slope.buffer);
  for (const c of fine) transfer.push(c.disp.buffer);
  if (foam) transfer.push(foam.buffer);
  self.postMessage({
    type: 'frame', header: frame.header, lod, m, present, disp, slope, fine, foam, foamLod, fm, decodeMs, assembleMs: layoutMs, bytes: msg.buf.byteLength, inflater,
  }, transfer);
}

// Where each tile's samples go, decided from the tile headers before any payload is decoded:
// the decoder writes them straight into the texture arrays (decodeFrame's `target`), so there is
// no array per tile and no copy. Cascade 0's surface fields into disp/slope at the surface's LOD;
// foam (at a coarser LOD of its own, subscribe field_lod) into its F×F array; cascades 1..3
// (PROTOCOL.md §4.1) each into its own M_c×M_c RGBA (dx, height, dz, 0), M_c = N >> its LOD,
// patch side L_c = patch_size / 3.543^c. Tiles that fit nowhere get their own arrays (unused).
const CASCADE_RATIO = 3.543;
function layout(h, tiles) {
  const base = tiles.filter((t) => !t.cascade);   // cascade 0 (tile flags 0)
  const surfTile = base.find((t) => t.fieldName !== 'foam');
  const lod = surfTile ? surfTile.lod : (base.length ? base[0].lod : 0);
  const foamTile = base.find((t) => t.fieldName === 'foam');
  const foamLod = foamTile ? foamTile.lod : null;
  const fm = foamTile ? h.n >> foamLod : 0;
  const foam = foamTile ? take(1, fm * fm) : null;
  const m = h.n >> lod;
  const count = m * m;
  const present = {};
  for (const t of base) present[t.fieldName] = true;
  const disp = take(4, count);
  if (!present.jacobian) for (let i = 3; i < disp.length; i += 4) disp[i] = 1;
  const slope = (present.slope_x || present.slope_z) ? take(2, count) : null;
  const fine = [], fineLod = {};
  for (let c = 1; c < 4; c++) {
    const first = tiles.find((t) => t.cascade === c && CHANNEL[t.fieldName] && CHANNEL[t.fieldName][1] === 4);
    if (!first) continue;
    const mc = h.n >> first.lod, d = take(4, mc * mc);
    d.fill(0);
    fineLod[c] = { lod: first.lod, m: mc, disp: d };
    fine.push({ c, m: mc, patch: h.patchSize / CASCADE_RATIO ** c, disp: d });
  }
  const targets = tiles.map((t) => {
    const ch = CHANNEL[t.fieldName];
    let array, mm, c, stride;
    if (!t.cascade && t.fieldName === 'foam' && t.lod === foamLod) { array = foam; mm = fm; c = 0; stride = 1; }
    else if (!t.cascade && ch && t.lod === lod) { [c, stride] = ch; array = stride === 4 ? disp : slope; mm = m; }
    else if (t.cascade && ch && ch[1] === 4 && fineLod[t.cascade] && fineLod[t.cascade].lod === t.lod) {
      array = fineLod[t.cascade].disp; mm = fineLod[t.cascade].m; c = ch[0]; stride = 4;
    } else return null;
    const step = h.tileSize >> t.lod;           // samples per tile side at this LOD
    const x0 = t.tileX * step, z0 = t.tileZ * step;
    return { array, offset: (z0 * mm + x0) * stride + c, stride, rowStride: mm * stride };
  });
  return { targets, lod, m, present, disp, slope, fine, foam, foamLod, fm };
}

// A frame that failed: its arrays back to the pool.
function release(plan) {
  if (plan.disp) pool[4].push(plan.disp.buffer);
  if (plan.slope) pool[2].push(plan.slope.buffer);
  for (const c of plan.fine) pool[4].push(c.disp.buffer);
  if (plan.foam) pool[1].push(plan.foam.buffer);
}

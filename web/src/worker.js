// Decoder worker: turns one binary frame into GPU-ready arrays so the render
// loop never decodes. Frame tiles are assembled into M×M textures (M = N >> lod):
//   disp  RGBA float32: (dx, height, dz, jacobian)  — jacobian 1 when not streamed
//   slope RG   float32: (slope_x, slope_z)          — only when slopes are streamed
//   foam  R    float32: server foam 0..1, F×F at its own LOD (F = N >> foamLod) — only when streamed
// Output buffers are transferred to the main thread, which hands them back for
// reuse (no 4 MB allocation per frame at N=512).
import { inflateSync } from 'fflate';
import { decodeFrame, setInflateRaw, DecoderState } from '../../proto/js/oc_decode.js';

// Codec 1 (raw DEFLATE): fflate's synchronous inflate for small tiles, where one async
// DecompressionStream per tile costs more than the inflating (the decoder picks per tile).
setInflateRaw((src, out) => inflateSync(src, { out }));

const CHANNEL = { dx: [0, 4], height: [1, 4], dz: [2, 4], jacobian: [3, 4], slope_x: [0, 2], slope_z: [1, 2] };
const pool = { 4: [], 2: [], 1: [] }; // recycled ArrayBuffers by channel count

function take(channels, count) {
  const list = pool[channels];
  while (list.length) {
    const b = list.pop();
    if (b.byteLength === count * channels * 4) return new Float32Array(b);
  }
  return new Float32Array(count * channels);
}

// Codec 3 (temporal) tiles are predicted from the previous frames: one DecoderState keeps
// their codes, and frames are decoded strictly one after the other, in arrival order (a
// frame's tiles may inflate asynchronously, so a queue serialises them). A frame that a
// newer one has already overtaken in the queue is decoded (its codes are the next frame's
// references) but not assembled: the render loop would never show it (unless nothing was
// assembled for 100 ms: a worker that is always behind still shows ten frames a second).
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
  queue.push(msg);
  if (!running) drain();
};

async function drain() {
  running = true;
  while (queue.length) {
    const msg = queue.shift();
    await handle(msg, queue.length > 0);
  }
  running = false;
}

async function handle(msg, superseded) {
  const t0 = performance.now();
  let frame;
  try {
    frame = await decodeFrame(msg.buf, { state });
  } catch (e) {
    self.postMessage({ type: 'error', code: e && e.code, message: String(e && e.message || e) });
    return;
  }
  if (superseded && t0 - lastAssembled < 100) { self.postMessage({ type: 'skip', seq: frame.header.seq }); return; }
  lastAssembled = t0;
  const t1 = performance.now();
  const h = frame.header;
  const base = frame.tiles.filter((t) => !t.cascade);   // cascade 0 (tile flags 0)
  // The surface's LOD; foam may come at a coarser one of its own (subscribe field_lod).
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

  for (const t of base) {
    if (t.fieldName === 'foam' && t.lod === foamLod) { placeFoam(t, h, foam, fm); continue; }
    const ch = CHANNEL[t.fieldName];
    if (!ch || t.lod !== lod) continue;
    const [c, stride] = ch;
    const dst = stride === 4 ? disp : slope;
    const step = h.tileSize >> lod;           // samples per tile side at this LOD
    const x0 = t.tileX * step, z0 = t.tileZ * step;
    const s = t.samples;
    for (let j = 0; j < t.height; j++) {
      let o = ((z0 + j) * m + x0) * stride + c;
      let i0 = j * t.width;
      for (let i = 0; i < t.width; i++, o += stride) dst[o] = s[i0 + i];
    }
  }
  const fine = assembleCascades(frame);
  const t2 = performance.now();
  const decodeMs = t2 - t0, assembleMs = t2 - t1;
  const transfer = [disp.buffer];
  if (slope) transfer.push(slope.buffer);
  for (const c of fine) transfer.push(c.disp.buffer);
  if (foam) transfer.push(foam.buffer);
  self.postMessage({
    type: 'frame', header: h, lod, m, present, disp, slope, fine, foam, foamLod, fm, decodeMs, assembleMs, bytes: msg.buf.byteLength,
  }, transfer);
}

// Cascades 1..3 (PROTOCOL.md §4.1): each its own M_c x M_c texture (M_c = N >> its LOD),
// RGBA (dx, height, dz, 0); patch side L_c = patch_size / 3.543^c. Only cascades with tiles.
const CASCADE_RATIO = 3.543;
function assembleCascades(frame) {
  const h = frame.header, out = [];
  for (let c = 1; c < 4; c++) {
    const tiles = frame.tiles.filter((t) => t.cascade === c && CHANNEL[t.fieldName] && CHANNEL[t.fieldName][1] === 4);
    if (!tiles.length) continue;
    const lod = tiles[0].lod, m = h.n >> lod, step = h.tileSize >> lod;
    const disp = take(4, m * m);
    disp.fill(0);
    for (const t of tiles) {
      if (t.lod !== lod) continue;
      const ch = CHANNEL[t.fieldName][0], s = t.samples;
      const x0 = t.tileX * step, z0 = t.tileZ * step;
      for (let j = 0; j < t.height; j++) {
        let o = ((z0 + j) * m + x0) * 4 + ch;
        const i0 = j * t.width;
        for (let i = 0; i < t.width; i++, o += 4) disp[o] = s[i0 + i];
      }
    }
    out.push({ c, m, patch: h.patchSize / CASCADE_RATIO ** c, disp });
  }
  return out;
}

// A foam tile into the F×F foam array (one channel).
function placeFoam(t, h, dst, fm) {
  const step = h.tileSize >> t.lod, x0 = t.tileX * step, z0 = t.tileZ * step, s = t.samples;
  for (let j = 0; j < t.height; j++) dst.set(s.subarray(j * t.width, (j + 1) * t.width), (z0 + j) * fm + x0);
}

// The sea as three.js objects: streamed fields as float textures, a field of
// instanced patches (one per period of the simulation, finer near the camera),
// a flat far ring to the horizon, and a sky dome sharing the same lighting.
import * as THREE from 'three';
import { skyVertex, skyFragment, waterVertex, waterFragment } from './shaders.js';

const MAX_GRID = 128;        // segments per patch side at the finest level
const MIN_GRID = 2;
const NEAR_RANGE = 4000;     // metres of real geometry; beyond is the flat far ring
const MAX_RING = 40;         // patches from the camera patch, whatever the patch size
const HORIZON = 60000;       // metres to the end of the far ring
const LOD_PIXEL = 0.012;     // wanted segment length per metre of distance (at detail 1)
const SKIRT_DEPTH = 0.1;     // metres
const SKIRT_TOP = 0.05;      // the skirt top, as a fraction of its depth below the edge (5 mm)

function floatTexture(data, m, format) {
  const t = new THREE.DataTexture(data, m, m, format, THREE.FloatType);
  t.wrapS = t.wrapT = THREE.RepeatWrapping;
  t.magFilter = t.minFilter = THREE.LinearFilter;
  t.generateMipmaps = false;
  t.needsUpdate = true;
  return t;
}

// A patch of g×g cells on [0,1]² (scaled to the patch size by the instance matrix),
// with a skirt hanging below its border (edges are stitched to coarser neighbours in the
// vertex shader; the skirt only hides the pinholes float rounding leaves at T-junctions).
function patchGeometry(g) {
  const pos = [], skirt = [], index = [];
  for (let j = 0; j <= g; j++) for (let i = 0; i <= g; i++) { pos.push(i / g, 0, j / g); skirt.push(0); }
  const v = (i, j) => j * (g + 1) + i;
  for (let j = 0; j < g; j++) for (let i = 0; i < g; i++) {
    index.push(v(i, j), v(i, j + 1), v(i + 1, j), v(i + 1, j), v(i, j + 1), v(i + 1, j + 1));
  }
  const ring = [];
  for (let i = 0; i < g; i++) ring.push(v(i, 0));
  for (let j = 0; j < g; j++) ring.push(v(g, j));
  for (let i = g; i > 0; i--) ring.push(v(i, g));
  for (let j = g; j > 0; j--) ring.push(v(0, j));
  // The skirt's top starts a hair below the edge (SKIRT_TOP of the skirt depth) rather than
  // on it: sharing the edge, its pixels tied with the surface's in depth and won some,
  // drawing a faint one-pixel line along every patch border.
  const top = pos.length / 3, n = ring.length;
  ring.forEach((r) => { pos.push(pos[3 * r], 0, pos[3 * r + 2]); skirt.push(SKIRT_TOP); });
  ring.forEach((r) => { pos.push(pos[3 * r], 0, pos[3 * r + 2]); skirt.push(1); });
  for (let k = 0; k < n; k++) {
    const a = top + k, b = top + (k + 1) % n, a2 = a + n, b2 = b + n;
    index.push(a, a2, b, b, a2, b2);
  }
  const geo = new THREE.BufferGeometry();
  geo.setAttribute('position', new THREE.Float32BufferAttribute(pos, 3));
  geo.setAttribute('skirt', new THREE.Float32BufferAttribute(skirt, 1));
  geo.setIndex(index);
  return geo;
}

// Flat square ring between the patch field and the horizon (4 quads).
function farRingGeometry() {
  const geo = new THREE.BufferGeometry();
  geo.setAttribute('position', new THREE.Float32BufferAttribute(new Float32Array(8 * 3), 3));
  geo.setAttribute('skirt', new THREE.Float32BufferAttribute(new Float32Array(8), 1));
  // outer 0..3, inner 4..7 (counter-clockwise)
  geo.setIndex([0, 1, 4, 4, 1, 5, 1, 2, 5, 5, 2, 6, 2, 3, 6, 6, 3, 7, 3, 0, 7, 7, 0, 4]);
  return geo;
}

// The server's breaking threshold on the Jacobian for wind speed U10 (server/sim/ocean_foam.c,
// ocean_foam_threshold): the page's fresh foam starts where the server's field is fed.
export function foamThreshold(u) {
  const over = Math.max((u ?? 10) - 8, 0);
  return 0.707 + 0.0008 * over + 0.00018 * over * over;
}

export class Ocean {
  // skyUniforms: the shared sky cube, key light and exposure (sky.js SkyModel.uniforms).
  constructor(renderer, skyUniforms, { detail = 1, skirts = true, hexTiling = true } = {}) {
    this.renderer = renderer;
    this.lodPixel = LOD_PIXEL / Math.max(detail, 0.05);
    this.skirts = skirts;
    this.hexTiling = hexTiling;
    this.scene = new THREE.Scene();
    this.m = 0;             // texture size (N >> lod)
    this.patch = 0;         // patch size, metres
    this.levels = [];       // InstancedMesh per detail level
    this.layoutKey = '';
    this.lastArrival = 0;
    this.interval = 1000 / 30;
    this.hasData = false;
    this.uniforms = {
      ...skyUniforms,
      uDispA: { value: null }, uDispB: { value: null },
      uSlopeA: { value: null }, uSlopeB: { value: null },
      uMix: { value: 1 }, uPatch: { value: 1 }, uTexel: { value: 1 },
      uHasSlope: { value: 0 }, uHasJac: { value: 0 },
      uFadeNear: { value: 1000 }, uFadeFar: { value: 3000 }, uSkirtDepth: { value: 2 }, uStitch: { value: 1 },
      uHexNear: { value: 1e9 }, uHexFar: { value: 2e9 },
      uDeep: { value: new THREE.Color(0.004, 0.035, 0.07) },
      uScatter: { value: new THREE.Color(0.02, 0.16, 0.16) },
      uFogDensity: { value: 0.00009 }, uFoam: { value: 1 },
      // Cascades 1..3 (shaders.js CASCADES): textures, patch sides, texel sizes, on/off.
      uC1A: { value: null }, uC1B: { value: null }, uC2A: { value: null }, uC2B: { value: null },
      uC3A: { value: null }, uC3B: { value: null },
      uCPatch: { value: new THREE.Vector3(1, 1, 1) }, uCTexel: { value: new THREE.Vector3(1, 1, 1) },
      uCOn: { value: new THREE.Vector3(0, 0, 0) },
      uMinCell: { value: 1 }, uLodPixel: { value: this.lodPixel },
      // Slope variance per axis (shaders.js LIGHT): cascade 0, cascades 1..3 (measured on
      // the streamed grids, slopeVariance) and the band finer than the finest cascade
      // (Cox & Munk's total less what the cascades hold).
      uVar0: { value: 0 }, uCVar: { value: new THREE.Vector3(0, 0, 0) }, uVarBeyond: { value: 0.004 },
      // Foam (shaders.js FOAM): the server's field, two frames like the displacement.
      uFoamA: { value: null }, uFoamB: { value: null }, uFoamField: { value: 0 }, uFoamTexel: { value: 1 },
      uFoamWind: { value: new THREE.Vector2(1, 0) }, uFoamWindSpeed: { value: 10 },
      // ?foamramp=M (pictures of the foam texture): coverage rises 0 → 1 over M metres of x
      // from x = -M/2, instead of the field's, so every stage of the foam shows in one view.
      uFoamRamp: { value: Number(new URLSearchParams(globalThis.location?.search).get('foamramp')) || 0 },
      uFoamJc: { value: foamThreshold(10) }, uFoamGain: { value: 1 }, uFoamShift: { value: new THREE.Vector2(0, 0) }, uFoamStreaks: { value: 1 },
      uDebugView: { value: 0 },
    };
    this.material = new THREE.ShaderMaterial({
      uniforms: this.uniforms, vertexShader: waterVertex, fragmentShader: waterFragment,
      side: THREE.DoubleSide,
    });
    const sky = new THREE.Mesh(new THREE.SphereGeometry(1, 32, 16), new THREE.ShaderMaterial({
      uniforms: skyUniforms,
      vertexShader: skyVertex, fragmentShader: skyFragment, side: THREE.BackSide, depthWrite: false,
    }));
    sky.scale.setScalar(HORIZON * 0.9);
    sky.frustumCulled = false;
    sky.renderOrder = -1;
    this.sky = sky;
    this.scene.add(sky);
    this.far = new THREE.Mesh(farRingGeometry(), this.material);
    this.far.frustumCulled = false;
    this.far.visible = false;
    this.scene.add(this.far);
    // Two texture slots (older A, newer B); data arrays are swapped in.
    this.disp = [null, null];
    this.slope = [null, null];
    this.cascades = [null, null, null, null]; // [c] = { m, tex: [A, B] } for cascades 1..3
    this.foam = [null, null]; // F×F single-channel float, F = N >> foam LOD
    this.foamM = 0;
    this.windSpeed = 10;
    this.foamFrames = 0;
    this.varFrames = 0;       // frames since the slope variances were last measured
  }

  // Slope variances per axis, <(dh/dx)^2 + (dh/dz)^2> / 2, of cascade 0 and 1..3 from their
  // newest grids (forward differences of height on the undisplaced grid), and what remains
  // of the wind's total (Cox & Munk 1954: mean square slope 0.003 + 5.12e-3 U, clean sea)
  // for the waves finer than the finest cascade. A few ms at N = 512: every 30 frames.
  measureSlopeVariance() {
    const u = this.uniforms;
    const grid = (data, m, L) => {
      if (!data || !m) return 0;
      const k2 = (m / L) ** 2;
      let s = 0, n = 0;
      for (let j = 0; j < m; j++) for (let i = 0; i < m; i++) {
        const h = data[4 * (j * m + i) + 1];
        const hx = data[4 * (j * m + (i + 1) % m) + 1], hz = data[4 * (((j + 1) % m) * m + i) + 1];
        s += ((hx - h) ** 2 + (hz - h) ** 2) * k2; n++;
      }
      return n ? 0.5 * s / n : 0;
    };
    const v0 = grid(this.disp[1]?.image.data, this.m, this.patch);
    const cv = [1, 2, 3].map((c) => {
      const slot = this.cascades[c];
      return slot && u.uCOn.value.getComponent(c - 1) > 0 ? grid(slot.tex[1].image.data, slot.m, u.uCPatch.value.getComponent(c - 1)) : 0;
    });
    const total = 0.5 * (0.003 + 5.12e-3 * Math.max(this.windSpeed, 0));
    u.uVar0.value = v0;
    u.uCVar.value.set(cv[0], cv[1], cv[2]);
    u.uVarBeyond.value = Math.max(total - v0 - cv[0] - cv[1] - cv[2], 0.05 * total);
    this.slopeVar = { cascade0: v0, cascades: cv, beyond: u.uVarBeyond.value, total, cell: this.patch / Math.max(this.m, 1) };
  }

  // Height of the displaced surface at world (x, z) on the frames drawn (the larger of the
  // two being blended, and the finer cascades' heights): the undisplaced point whose
  // displacement lands on (x, z) is found by fixed-point iteration (horizontal
  // displacement is smooth and smaller than the wavelength, so it converges in a few steps).
  // slot 0 or 1: that frame only (1 = the newer, drawn alone once the blend reaches it).
  surfaceHeight(x, z, slot = null) {
    if (!this.hasData) return 0;
    const m = this.m, L = this.patch;
    const bilinear = (data, mm, LL, px, pz, ch) => {
      const fx = ((px / LL) * mm % mm + mm) % mm, fz = ((pz / LL) * mm % mm + mm) % mm;
      const i0 = Math.floor(fx), j0 = Math.floor(fz), tx = fx - i0, tz = fz - j0, i1 = (i0 + 1) % mm, j1 = (j0 + 1) % mm;
      const at = (i, j) => data[4 * (j * mm + i) + ch];
      return (at(i0, j0) * (1 - tx) + at(i1, j0) * tx) * (1 - tz) + (at(i0, j1) * (1 - tx) + at(i1, j1) * tx) * tz;
    };
    let best = -Infinity;
    for (const t of slot === null ? this.disp : [this.disp[slot]]) {
      const d = t?.image.data;
      if (!d || d.length !== m * m * 4) continue;
      let px = x, pz = z;
      for (let k = 0; k < 6; k++) { px = x - bilinear(d, m, L, px, pz, 0); pz = z - bilinear(d, m, L, px, pz, 2); }
      best = Math.max(best, bilinear(d, m, L, px, pz, 1));
    }
    for (let c = 1; c < 4; c++) {
      const cs = this.cascades[c];
      if (!cs || !(this.uniforms.uCOn.value.getComponent(c - 1) > 0)) continue;
      const Lc = this.uniforms.uCPatch.value.getComponent(c - 1);
      best += Math.max(...(slot === null ? cs.tex : [cs.tex[slot]]).map((t) => bilinear(t.image.data, cs.m, Lc, x, z, 1)));
    }
    return Number.isFinite(best) ? best : 0;
  }

  // The finer cascades of a frame (worker.js assembleCascades): each its own pair of
  // textures, swapped like cascade 0's; a cascade missing from the frame is switched off.
  // Returns the arrays to hand back to the worker.
  setCascades(fine) {
    const released = [], u = this.uniforms, on = [0, 0, 0];
    for (const f of fine || []) {
      let slot = this.cascades[f.c];
      if (!slot || slot.m !== f.m) {
        if (slot) for (const t of slot.tex) t.dispose();
        slot = this.cascades[f.c] = { m: f.m, tex: [0, 1].map(() => floatTexture(f.disp.slice(), f.m, THREE.RGBAFormat)) };
      }
      slot.tex.reverse();
      released.push(slot.tex[1].image.data);
      slot.tex[1].image.data = f.disp;
      slot.tex[1].needsUpdate = true;
      this.renderer.initTexture(slot.tex[1]);
      u[`uC${f.c}A`].value = slot.tex[0];
      u[`uC${f.c}B`].value = slot.tex[1];
      u.uCPatch.value.setComponent(f.c - 1, f.patch);
      u.uCTexel.value.setComponent(f.c - 1, 1 / f.m);
      on[f.c - 1] = 1;
    }
    // A cascade that stopped coming: off, and no texture left bound to it.
    for (let c = 1; c < 4; c++) if (!on[c - 1]) { u[`uC${c}A`].value = u[`uC${c}B`].value = this.blank(); }
    u.uCOn.value.set(on[0], on[1], on[2]);
    // (here: the frame's cascades are in; a new wind or layout measures at once)
    if (this.hasData && this.varFrames++ % 30 === 0) this.measureSlopeVariance();
    return released.filter((a) => a && a.buffer.byteLength);
  }

  // A 1x1 zero texture for unused cascade samplers.
  blank() {
    if (!this.blankTex) this.blankTex = floatTexture(new Float32Array(4), 1, THREE.RGBAFormat);
    return this.blankTex;
  }

  // Wind of the shared sea (params): the foam streaks follow it.
  setWind(speed, directionDeg) {
    this.windSpeed = speed ?? 10;
    this.varFrames = 0;
    const a = (directionDeg || 0) * Math.PI / 180;
    this.uniforms.uFoamWind.value.set(Math.cos(a), Math.sin(a));
    this.uniforms.uFoamWindSpeed.value = speed ?? 10;
    this.uniforms.uFoamJc.value = foamThreshold(speed);
  }

  // The foam field of a frame (or none: the shader falls back to the Jacobian).
  setFoam(f, released) {
    const u = this.uniforms;
    if (!f.foam) { u.uFoamField.value = 0; return; }
    const fresh = f.fm !== this.foamM || !this.foam[0];
    if (fresh) {
      for (const t of this.foam) if (t) t.dispose();
      this.foam = [0, 1].map(() => floatTexture(new Float32Array(f.fm * f.fm), f.fm, THREE.RedFormat));
      this.foamM = f.fm;
    }
    this.foam.reverse();
    released.push(this.foam[1].image.data);
    this.foam[1].image.data = f.foam;
    this.foam[1].needsUpdate = true;
    this.renderer.initTexture(this.foam[1]);
    if (fresh) { this.foam[0].image.data = f.foam.slice(); this.foam[0].needsUpdate = true; }
    u.uFoamA.value = this.foam[0]; u.uFoamB.value = this.foam[1];
    if (fresh || this.foamFrames++ % 30 === 0) this.foamCoverage(f.foam);
    u.uFoamTexel.value = 1 / f.fm;
    u.uFoamField.value = 1;
  }

  // The streamed field is coarse (about 64×64: each value a mean over some 16 of the
  // server's samples), so fewer of its values reach 0.5 than the server's own do, most of
  // all in light winds where whitecaps are smaller than a cell. The gain scales it so that
  // the share at >= 0.5 is Monahan & O'Muircheartaigh's W(U) (docs/simulation.md, Foam), to
  // which the server's full field is calibrated: the field keeps where and how long foam
  // lives, the law sets how much of the sea it covers.
  foamCoverage(data) {
    const W = Math.min(3.84e-6 * Math.max(this.windSpeed, 0) ** 3.41, 0.5);
    const sorted = Float32Array.from(data).sort();
    const q = sorted[Math.min(sorted.length - 1, Math.floor((1 - W) * sorted.length))];
    this.uniforms.uFoamGain.value = W > 1e-4 && q > 0.02 ? Math.min(Math.max(0.5 / q, 1), 4) : 1;
  }

  set wireframe(on) { this.material.wireframe = on; }
  get wireframe() { return this.material.wireframe; }

  // New decoded frame from the worker. Returns { uploadMs, released: [arrays] }.
  // sync: wait for the GPU to finish the upload (benchmarks only).
  setFrame(f, now, sync = false) {
    const released = [];
    const patch = f.header.patchSize;
    if (f.m !== this.m || patch !== this.patch) this.rebuild(f.m, patch);
    // The newer texture becomes the older one; the older one takes the new data.
    const t0 = performance.now();
    this.disp.reverse();
    released.push(this.disp[1].image.data);
    this.disp[1].image.data = f.disp;
    this.disp[1].needsUpdate = true;
    this.renderer.initTexture(this.disp[1]);
    if (f.slope) {
      if (!this.slope[0]) this.slope = [0, 1].map(() => floatTexture(new Float32Array(f.m * f.m * 2), f.m, THREE.RGFormat));
      this.slope.reverse();
      released.push(this.slope[1].image.data);
      this.slope[1].image.data = f.slope;
      this.slope[1].needsUpdate = true;
      this.renderer.initTexture(this.slope[1]);
    }
    this.setFoam(f, released);
    if (sync) this.renderer.getContext().finish();
    const uploadMs = performance.now() - t0;
    if (!this.hasData) { // first frame: both slots hold it, no blend from zeros
      this.disp[0].image.data = f.disp.slice(); this.disp[0].needsUpdate = true;
    }
    const u = this.uniforms;
    u.uDispA.value = this.disp[0]; u.uDispB.value = this.disp[1];
    u.uHasSlope.value = f.slope ? 1 : 0;
    if (f.slope) { u.uSlopeA.value = this.slope[0]; u.uSlopeB.value = this.slope[1]; }
    u.uHasJac.value = f.present.jacobian ? 1 : 0;
    // Estimate the frame interval to blend over (smoothed).
    if (this.lastArrival) {
      const dt = Math.min(Math.max(now - this.lastArrival, 5), 500);
      this.interval += (dt - this.interval) * 0.2;
    }
    this.lastArrival = now;
    this.hasData = true;
    return { uploadMs, released: released.filter((a) => a && a.buffer.byteLength) };
  }

  rebuild(m, patch) {
    this.m = m; this.patch = patch;
    for (const t of [...this.disp, ...this.slope]) if (t && t.dispose) t.dispose();
    this.disp = [0, 1].map(() => floatTexture(new Float32Array(m * m * 4), m, THREE.RGBAFormat));
    this.slope = [null, null];
    this.hasData = false;
    this.varFrames = 0;
    const u = this.uniforms;
    u.uPatch.value = patch; u.uTexel.value = 1 / m;
    u.uMinCell.value = patch / Math.min(MAX_GRID, m);
    for (const l of this.levels) { this.scene.remove(l.mesh); l.mesh.geometry.dispose(); l.mesh.dispose(); }
    this.levels = [];
    this.ring = Math.min(MAX_RING, Math.ceil(NEAR_RANGE / patch));
    const maxInstances = (2 * this.ring + 1) ** 2;
    for (let g = Math.min(MAX_GRID, m); g >= MIN_GRID; g >>= 1) {
      const geo = patchGeometry(g);
      geo.setAttribute('aEdge', new THREE.InstancedBufferAttribute(new Float32Array(maxInstances * 4), 4));
      const mesh = new THREE.InstancedMesh(geo, this.material, maxInstances);
      mesh.frustumCulled = false;
      mesh.count = 0;
      this.levels.push({ g, mesh });
      this.scene.add(mesh);
    }
    u.uFadeFar.value = this.ring * patch * 0.95;
    u.uFadeNear.value = u.uFadeFar.value * 0.35;
    // Short: the stitched edges meet, so the skirt only has to fill rounding pinholes.
    u.uSkirtDepth.value = this.skirts ? SKIRT_DEPTH : 0;
    // Hex-tiled normals from one patch away (single waves still resolved nearer).
    if (this.hexTiling) { u.uHexNear.value = patch; u.uHexFar.value = 2.5 * patch; }
    this.layoutKey = '';
  }

  // The crack fixes on or off (?stitch=0, ?skirt=0, or tests on one frozen frame).
  setCrackFixes({ stitch = true, skirts = true } = {}) {
    this.skirts = skirts;
    this.uniforms.uStitch.value = stitch ? 1 : 0;
    this.uniforms.uSkirtDepth.value = skirts ? SKIRT_DEPTH : 0;
  }

  // Place patch instances around the camera; only when the camera changes cell.
  layout(camera) {
    const L = this.patch, R = this.ring;
    const ci = Math.floor(camera.position.x / L), cj = Math.floor(camera.position.z / L);
    const hq = Math.round(Math.log2(Math.max(camera.position.y, 1)) * 2);
    const key = `${ci},${cj},${hq}`;
    if (key === this.layoutKey) return;
    this.layoutKey = key;
    const camY = Math.max(Math.abs(camera.position.y), 1);
    const mat = new THREE.Matrix4();
    for (const l of this.levels) l.mesh.count = 0;
    // First the level of every patch, then the instances with their edges' levels.
    const W = 2 * R + 1, lvls = new Int32Array(W * W);
    for (let j = cj - R; j <= cj + R; j++) for (let i = ci - R; i <= ci + R; i++) {
      const x0 = i * L, z0 = j * L;
      const dx = Math.max(x0 - camera.position.x, 0, camera.position.x - x0 - L);
      const dz = Math.max(z0 - camera.position.z, 0, camera.position.z - z0 - L);
      const d = Math.hypot(dx, dz, camY);
      const want = L / (d * this.lodPixel);    // segments this patch deserves
      let lvl = this.levels.findIndex((l) => l.g <= want);
      if (lvl < 0) lvl = this.levels.length - 1;
      lvls[(j - cj + R) * W + (i - ci + R)] = lvl;
    }
    const gAt = (a, b, own) => (a < 0 || b < 0 || a >= W || b >= W ? own : Math.min(own, this.levels[lvls[b * W + a]].g));
    for (let b = 0; b < W; b++) for (let a = 0; a < W; a++) {
      const level = this.levels[lvls[b * W + a]], mesh = level.mesh, g = level.g, k = mesh.count++;
      mat.makeScale(L, 1, L).setPosition((ci - R + a) * L, 0, (cj - R + b) * L);
      mesh.setMatrixAt(k, mat);
      mesh.geometry.attributes.aEdge.setXYZW(k, gAt(a - 1, b, g), gAt(a + 1, b, g), gAt(a, b - 1, g), gAt(a, b + 1, g));
    }
    for (const l of this.levels) { l.mesh.instanceMatrix.needsUpdate = true; l.mesh.geometry.attributes.aEdge.needsUpdate = true; }
    // Far ring: from the patch field's edge to the horizon.
    const a0 = (ci - R) * L, a1 = (ci + R + 1) * L, bx = camera.position.x, bz = camera.position.z;
    const p = this.far.geometry.attributes.position;
    const pts = [[bx - HORIZON, bz - HORIZON], [bx + HORIZON, bz - HORIZON], [bx + HORIZON, bz + HORIZON], [bx - HORIZON, bz + HORIZON],
      [a0, (cj - R) * L], [a1, (cj - R) * L], [a1, (cj + R + 1) * L], [a0, (cj + R + 1) * L]];
    pts.forEach(([x, z], k) => p.setXYZ(k, x, -0.05, z));
    p.needsUpdate = true;
    this.far.visible = true;
  }

  render(camera, now) {
    if (!this.m) { this.renderer.render(this.scene, camera); return; }
    this.sky.position.copy(camera.position);
    this.layout(camera);
    this.uniforms.uMix.value = Math.min(Math.max((now - this.lastArrival) / this.interval, 0), 1);
    this.renderer.render(this.scene, camera);
  }
}

// bodies.js — the buoys, boats and ships on the shared sea (PROTOCOL.md §3.5, §7.6).
//
// Every tick's frame carries each body's state of that tick (its header's BODY section),
// so a body is drawn from the same two frames the sea is blended from, with the same
// blend (ocean.uniforms.uMix): a boat rides exactly the waves it is drawn on. The `bodies`
// message (and hello) says who owns which body and under what name; hello.body_kinds gives
// each kind's size and hull, from which the meshes are built here.
//
// Your own bodies (launched from this page, or claimed back after a reload with the resume
// key kept in sessionStorage) are highlighted, steered with the keyboard (W/S or ↑/↓:
// throttle, A/D or ←/→: rudder, held) or the touch bar, and can be followed by the camera.
import * as THREE from 'three';

// Shaders write display-ready colour (renderer.outputColorSpace is linear): give materials
// the sRGB components as they are, not converted.
const col = (hex) => new THREE.Color().setRGB(((hex >> 16) & 255) / 255, ((hex >> 8) & 255) / 255, (hex & 255) / 255, THREE.LinearSRGBColorSpace);

// Looks per kind: hull above / below the waterline, deck, and what stands on it.
const LOOKS = {
  spar: { top: 0xf2c81c, bottom: 0x2a2a2a },
  ball: { top: 0xd8261d, bottom: 0x5c1410, stripe: 0xf2f2f2 },
  dinghy: { top: 0xf4f4f0, bottom: 0x1d4f8f, deck: 0xc9a36b },
  boat: { top: 0xf7f7f5, bottom: 0x14233b, deck: 0xb58d5a, house: 0xf0f0ee },
  ship: { top: 0x1f2f48, bottom: 0x8f2418, deck: 0x6b6f72, house: 0xeeeeea, funnel: 0xd04a1c },
};
const HISTORY = 150;            // frames whose records are kept (5 s at 30 Hz)
const STEER_HZ = 10;            // steering messages per second at most, while something changes
const THROTTLE_STEP = 0.1;      // per key press (held keys repeat)
const RESUME_KEY = 'oceand.bodies.resume'; // sessionStorage: {body: resume} of this tab's bodies

// ---- meshes -------------------------------------------------------------------------------

// Vertex colours by height: below the waterline (body y < wl) one colour, above another.
function paintByHeight(geo, wl, below, above, band = 0) {
  const p = geo.attributes.position, c = new Float32Array(p.count * 3), a = col(above), b = col(below);
  for (let i = 0; i < p.count; i++) {
    const y = p.getY(i), t = band > 0 ? THREE.MathUtils.smoothstep(y, wl - band, wl + band) : (y >= wl ? 1 : 0);
    const k = new THREE.Color().copy(b).lerp(a, t);
    c.set([k.r, k.g, k.b], 3 * i);
  }
  geo.setAttribute('color', new THREE.BufferAttribute(c, 3));
  return geo;
}

// A ship-shaped hull: stations from stern (s = -1) to bow (s = 1); each section a
// superellipse from the keel to the deck edge. Sharp bow, wide transom stern, the keel
// rising toward the bow. Body frame: +z bow, +y up, +x port; keel at y = keel.
function shipHull(L, B, H, keel, { box = 3, sharp = 1.6, transom = 0.75, sheer = 0.08 } = {}) {
  const ns = 28, nc = 10, pos = [], idx = [];
  const half = (s) => (s >= 0 ? Math.max(0, 1 - s ** sharp) ** 0.6 : transom + (1 - transom) * (1 - s * s) ** 0.5) * B / 2;
  for (let i = 0; i <= ns; i++) {
    const s = -1 + 2 * i / ns, z = s * L / 2, b = Math.max(half(s), 0.002 * B);
    const lift = s > 0.55 ? ((s - 0.55) / 0.45) ** 2 * 0.7 * H : 0;   // the forefoot rises to the stem
    const deck = keel + H + sheer * H * s * s;                          // sheer: ends a little higher
    for (let j = 0; j <= 2 * nc; j++) {
      const u = (j - nc) / nc, phi = Math.abs(u) * Math.PI / 2;        // -1 port deck .. 0 keel .. 1 starboard deck
      const sx = Math.sin(phi) ** (2 / box), sy = 1 - Math.cos(phi) ** (2 / box);
      pos.push(Math.sign(u) * b * sx, keel + lift + (deck - keel - lift) * sy, z);
    }
  }
  const row = 2 * nc + 1;
  for (let i = 0; i < ns; i++) for (let j = 0; j < 2 * nc; j++) {
    const a = i * row + j, b = a + row;
    idx.push(a, b, a + 1, a + 1, b, b + 1);
  }
  // Deck: a fan over the deck edges of each station, and the transom's flat stern.
  const deck0 = pos.length / 3;
  for (let i = 0; i <= ns; i++) {
    const l = i * row, r = i * row + 2 * nc;
    pos.push(pos[3 * l], pos[3 * l + 1], pos[3 * l + 2], pos[3 * r], pos[3 * r + 1], pos[3 * r + 2]);
  }
  for (let i = 0; i < ns; i++) { const a = deck0 + 2 * i; idx.push(a, a + 1, a + 2, a + 1, a + 3, a + 2); }
  for (let j = 0; j < 2 * nc - 1; j++) idx.push(0, j + 2, j + 1); // transom
  const hull = new THREE.BufferGeometry();
  hull.setAttribute('position', new THREE.Float32BufferAttribute(pos, 3));
  hull.setIndex(idx);
  hull.computeVertexNormals();
  return { hull, deckFrom: idx.length - 6 * ns - 3 * (2 * nc - 1) };
}

function box(w, h, d, x, y, z, color) {
  const m = new THREE.Mesh(new THREE.BoxGeometry(w, h, d), new THREE.MeshLambertMaterial({ color: col(color) }));
  m.position.set(x, y, z);
  return m;
}

// The mesh of a kind (hello.body_kinds row), its origin at the body's centre of mass.
export function kindMesh(kind) {
  const look = LOOKS[kind.name] || LOOKS.boat, g = new THREE.Group();
  const L = kind.length, B = kind.beam, H = kind.height;
  const keel = -(kind.kg ?? H / 2);                      // keel below the centre of mass (hello's kg)
  const wl = keel + (kind.draft ?? H / 2);                // the still-water line in the body frame
  const lambert = (extra = {}) => new THREE.MeshLambertMaterial({ vertexColors: true, ...extra });
  if (kind.hull === 'cylinder') {
    const geo = new THREE.CylinderGeometry(B / 2, B / 2, H, 20, 8);
    geo.translate(0, keel + H / 2, 0);
    g.add(new THREE.Mesh(paintByHeight(geo, wl, look.bottom, look.top), lambert()));
    const mast = new THREE.Mesh(new THREE.CylinderGeometry(0.04 * B + 0.02, 0.04 * B + 0.02, 0.6 * B + 0.6, 6), new THREE.MeshLambertMaterial({ color: col(0x333333) }));
    mast.position.y = keel + H + 0.3 * B + 0.3;
    const light = new THREE.Mesh(new THREE.SphereGeometry(0.08 * B + 0.05, 10, 8), new THREE.MeshBasicMaterial({ color: col(0xffe08a) }));
    light.position.y = mast.position.y + 0.3 * B + 0.3;
    g.add(mast, light);
  } else if (kind.hull === 'sphere') {
    const geo = new THREE.SphereGeometry(B / 2, 24, 16);
    geo.translate(0, keel + H / 2, 0);
    paintByHeight(geo, wl, look.bottom, look.top);
    const c = geo.attributes.color, p = geo.attributes.position, s = col(look.stripe);
    for (let i = 0; i < p.count; i++) { // a white band above the waterline: seen from afar
      const y = p.getY(i) - (keel + H / 2);
      if (y > 0.05 * B && y < 0.18 * B) c.setXYZ(i, s.r, s.g, s.b);
    }
    g.add(new THREE.Mesh(geo, lambert()));
    const mark = new THREE.Mesh(new THREE.ConeGeometry(0.18 * B, 0.35 * B, 12), new THREE.MeshLambertMaterial({ color: col(look.top) }));
    mark.position.y = keel + H + 0.25 * B;
    g.add(mark);
  } else {
    const ship = kind.hull === 'ship' || kind.hull === 'box';
    const shape = kind.name === 'ship' ? { box: 6, sharp: 2.2, transom: 0.85, sheer: 0.05 } : kind.name === 'dinghy' ? { box: 1.6, sharp: 1.4, transom: 0.7, sheer: 0.12 } : { box: 2.2, sharp: 1.5, transom: 0.7, sheer: 0.1 };
    const { hull } = shipHull(L, B, H, keel, ship ? shape : shape);
    g.add(new THREE.Mesh(paintByHeight(hull, wl + 0.02 * H, look.bottom, look.top), lambert({ side: THREE.DoubleSide })));
    const deckY = keel + H;
    if (kind.name === 'dinghy') {
      g.add(box(B * 0.8, 0.04, 0.18, 0, deckY - 0.25 * H, -0.05 * L, look.deck)); // thwart
      const mast = new THREE.Mesh(new THREE.CylinderGeometry(0.03, 0.04, 1.6 * L, 6), new THREE.MeshLambertMaterial({ color: col(0xd8d8d8) }));
      mast.position.set(0, deckY + 0.8 * L - 0.2, 0.18 * L);
      g.add(mast);
    } else if (kind.name === 'boat') {
      g.add(box(0.55 * B, 0.22 * H + 0.4, 0.3 * L, 0, deckY + 0.11 * H + 0.2, 0.02 * L, look.house)); // wheelhouse
      g.add(box(0.5 * B, 0.04, 0.08 * L, 0, deckY + 0.22 * H + 0.42, 0.1 * L, 0x20303a));          // its roof's dark glass
      const mast = new THREE.Mesh(new THREE.CylinderGeometry(0.05, 0.05, 0.25 * L, 6), new THREE.MeshLambertMaterial({ color: col(0xdddddd) }));
      mast.position.set(0, deckY + 0.125 * L + 0.6, -0.02 * L);
      g.add(mast);
    } else {
      g.add(box(0.9 * B, 0.12 * H, 0.82 * L, 0, deckY + 0.06 * H - 0.02, 0.04 * L, look.deck)); // deck cargo line
      g.add(box(0.86 * B, 0.55 * H, 0.12 * L, 0, deckY + 0.27 * H, -0.34 * L, look.house));      // bridge aft
      g.add(box(0.96 * B, 0.08 * H, 0.05 * L, 0, deckY + 0.58 * H, -0.31 * L, look.house));      // bridge wings
      const funnel = new THREE.Mesh(new THREE.CylinderGeometry(0.08 * B, 0.1 * B, 0.35 * H, 12), new THREE.MeshLambertMaterial({ color: col(look.funnel) }));
      funnel.position.set(0, deckY + 0.72 * H, -0.42 * L);
      g.add(funnel);
    }
  }
  // The ring that marks your own body, a little wider than the hull.
  const r = 0.62 * Math.max(L, B) + 0.3;
  // It floats a little above the waterline (a ring at the waterline disappears into every wave
  // that passes the pitching hull) and half transparent, so the water shows through it.
  const ring = new THREE.Mesh(new THREE.TorusGeometry(r, Math.max(0.05, 0.015 * r), 6, 48),
    new THREE.MeshBasicMaterial({ color: col(0x6ff0ff), transparent: true, opacity: 0.75 }));
  ring.rotation.x = Math.PI / 2;
  ring.position.y = wl + 0.15 + 0.03 * r;
  ring.visible = false;
  ring.name = 'mine';
  g.add(ring);
  return g;
}

// ---- state ----------------------------------------------------------------------------------

// A record of the frame header's BODY section (proto/js oc_decode.js header.bodies) as three.js values.
function stateOf(r) {
  return { id: r.id, kind: r.kind, adrift: !!r.adrift, powered: !!r.powered, throttle: r.throttle, rudder: r.rudder,
    pos: new THREE.Vector3(...r.pos), quat: new THREE.Quaternion(r.quat[1], r.quat[2], r.quat[3], r.quat[0]),
    vel: new THREE.Vector3(...r.vel) };
}

export class Bodies {
  // opts: { scene, camera, controls, send(msg) -> request id }
  constructor({ scene, camera, controls, send }) {
    this.scene = scene; this.camera = camera; this.controls = controls; this.send = send;
    this.group = new THREE.Group();
    this.group.name = 'bodies';
    scene.add(this.group);
    // Lit like the sea: the sky's key light and a hemisphere (set from the sky each frame).
    this.sun = new THREE.DirectionalLight(0xffffff, 2.4);
    this.hemi = new THREE.HemisphereLight(0xbfd4ea, 0x1b2a33, 1.4);
    this.group.add(this.sun, this.sun.target, this.hemi);
    this.kinds = [];             // hello.body_kinds
    this.meshes = new Map();     // body id -> { mesh, label, kindIndex }
    this.info = new Map();       // body id -> { kind, owner, name, adrift } from `bodies`
    this.a = new Map(); this.b = new Map(); // body id -> state, in the two frames the sea blends
    this.mine = new Set(); this.myIds = [];
    this.history = new Map();    // seq -> that frame's records
    this.selected = null;        // the body steered and followed
    this.follow = false;
    this.control = { throttle: 0, rudder: 0 };
    this.keys = new Set();
    this.lastSteer = 0; this.steerDirty = false;
    this.resume = JSON.parse(sessionStorage.getItem(RESUME_KEY) || '{}');
    this.labels = document.createElement('div');
    this.labels.className = 'oc-body-labels';
    document.body.appendChild(this.labels);
    this.bar = this.touchBar();
    window.addEventListener('keydown', (e) => this.key(e, true));
    window.addEventListener('keyup', (e) => this.key(e, false));
    window.addEventListener('blur', () => { this.keys.clear(); this.setRudder(0); });
  }

  // hello: the kinds, the bodies there are now, who we are. Claims back this tab's bodies.
  hello(msg, myIds) {
    this.kinds = msg.body_kinds || [];
    this.limits = msg.body_limits || null;
    this.myIds = myIds;
    for (const { mesh, label } of this.meshes.values()) { this.group.remove(mesh); label.remove(); }
    this.meshes.clear(); this.a.clear(); this.b.clear();
    this.list(msg);
    this.claims = new Map();     // request id -> the body it claims (the connection numbers requests)
    for (const [id, resume] of Object.entries(this.resume)) this.claims.set(this.send({ type: 'claim', body: Number(id), resume }), Number(id));
  }
  setMyIds(ids) { this.myIds = ids.filter(Boolean); this.refreshMine(); }

  // `bodies` (and hello's list): owners and names; bodies gone are dropped.
  list(msg) {
    const seen = new Set();
    for (const b of msg.bodies || []) { this.info.set(b.body, b); seen.add(b.body); }
    for (const id of [...this.info.keys()]) if (!seen.has(id)) this.drop(id);
    for (const r of msg.removed || []) { this.drop(r.body); this.forget(r.body); }
    this.refreshMine();
  }
  drop(id) {
    this.info.delete(id); this.a.delete(id); this.b.delete(id);
    const m = this.meshes.get(id);
    if (m) { this.group.remove(m.mesh); m.label.remove(); this.meshes.delete(id); }
    if (this.selected === id) this.select(null);
  }
  refreshMine() {
    this.mine = new Set([...this.info.values()].filter((b) => this.myIds.includes(b.owner)).map((b) => b.body));
    if (this.selected !== null && !this.mine.has(this.selected)) this.select(null);
    if (this.selected === null && this.mine.size) this.select(Math.max(...this.mine));
    for (const [id, m] of this.meshes) this.decorate(id, m);
    this.bar.hidden = this.selected === null;
  }

  // An error that answers one of our claims: that body is gone or no longer ours to claim,
  // so its resume key is dropped. True when it was one.
  claimRefused(msg) {
    if (!this.claims?.has(msg.id)) return false;
    this.forget(this.claims.get(msg.id));
    this.claims.delete(msg.id);
    return true;
  }
  launched(msg) { // our launch's answer: keep its resume key for a reload, steer it
    if (msg.resume) { this.resume[msg.body] = msg.resume; this.store(); }
    this.pendingSelect = msg.body;
  }
  forget(id) { if (id in this.resume) { delete this.resume[id]; this.store(); } }
  store() { sessionStorage.setItem(RESUME_KEY, JSON.stringify(this.resume)); }

  launch(kindName, at) {
    const x = at?.x ?? this.controls.target.x, z = at?.z ?? this.controls.target.z;
    const heading = (Math.atan2(-(this.camera.position.x - x), this.camera.position.z - z) * 180 / Math.PI + 540) % 360; // bow away from the camera
    this.send({ type: 'launch', kind: kindName, x: Math.round(x * 10) / 10, z: Math.round(z * 10) / 10, heading: Math.round(heading) });
  }
  remove() { if (this.selected !== null) this.send({ type: 'remove', body: this.selected }); }

  // A frame decoded (whether or not it is shown): its records, kept by seq for a few seconds
  // (tests compare two pages tick for tick; a page in the background draws nothing).
  record(seq, records) {
    this.history.set(seq, records || []);
    if (this.history.size > HISTORY) this.history.delete(this.history.keys().next().value);
  }

  // A new frame shown by the sea (its header's bodies): the newer slot becomes the older.
  setFrame(records, seq) {
    this.a = this.b;
    this.b = new Map();
    for (const r of records || []) this.b.set(r.id, stateOf(r));
    this.seq = seq;
    for (const id of this.b.keys()) if (!this.meshes.has(id)) this.make(id);
    for (const id of [...this.meshes.keys()]) if (!this.b.has(id) && !this.info.has(id)) this.drop(id);
    if (this.pendingSelect !== undefined && this.mine.has(this.pendingSelect)) { this.select(this.pendingSelect); this.pendingSelect = undefined; }
  }

  make(id) {
    const st = this.b.get(id), kind = this.kinds[st.kind];
    if (!kind) return;
    const mesh = kindMesh(kind);
    const label = document.createElement('div');
    label.className = 'oc-body-label';
    label.dataset.body = id;
    this.labels.appendChild(label);
    const m = { mesh, label, kind };
    this.meshes.set(id, m);
    this.group.add(mesh);
    this.decorate(id, m);
  }
  decorate(id, m) {
    const b = this.info.get(id), mine = this.mine.has(id);
    m.mesh.getObjectByName('mine').visible = mine;
    m.label.classList.toggle('mine', mine);
    m.label.classList.toggle('adrift', !!b?.adrift);
    m.label.textContent = `${b?.name || b?.owner || '…'} · ${m.kind.label || m.kind.name}${b?.adrift ? ' (adrift)' : ''}`;
  }

  select(id) {
    this.selected = id;
    this.control = { throttle: 0, rudder: 0 };
    const st = id !== null && this.b.get(id);
    if (st) this.control = { throttle: st.throttle, rudder: 0 };
    // Arrow keys steer your boat, not the camera, while you have one.
    if (id !== null) this.controls.stopListenToKeyEvents?.(); else this.controls.listenToKeyEvents?.(window);
    this.bar.hidden = id === null;
  }

  // ---- steering ---------------------------------------------------------------------------
  key(e, down) {
    if (this.selected === null || e.ctrlKey || e.metaKey || e.altKey || e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
    const k = e.key.toLowerCase();
    const act = { w: 'ahead', arrowup: 'ahead', s: 'astern', arrowdown: 'astern', a: 'port', arrowleft: 'port', d: 'starboard', arrowright: 'starboard' }[k];
    if (!act) return;
    e.preventDefault();
    if (down && (act === 'ahead' || act === 'astern')) this.setThrottle(this.control.throttle + (act === 'ahead' ? THROTTLE_STEP : -THROTTLE_STEP));
    if (act === 'port' || act === 'starboard') {
      if (down) this.keys.add(act); else this.keys.delete(act);
      this.setRudder((this.keys.has('starboard') ? 1 : 0) - (this.keys.has('port') ? 1 : 0));
    }
  }
  setThrottle(v) { this.control.throttle = Math.round(Math.max(-1, Math.min(1, v)) * 100) / 100; this.steerDirty = true; }
  setRudder(v) { if (v !== this.control.rudder) { this.control.rudder = v; this.steerDirty = true; } }
  flushSteer(now) {
    if (!this.steerDirty || this.selected === null || now - this.lastSteer < 1000 / STEER_HZ) return;
    this.steerDirty = false;
    this.lastSteer = now;
    this.send({ type: 'steer', body: this.selected, throttle: this.control.throttle, rudder: this.control.rudder });
  }

  // Phones: hold ◀ ▶ for the rudder, tap ▲ ▼ for the throttle; ◎ follows the boat.
  touchBar() {
    const bar = document.createElement('div');
    bar.className = 'oc-steer';
    bar.dataset.ui = 'steer';
    bar.hidden = true;
    const button = (text, title, down, up) => {
      const b = document.createElement('button');
      b.type = 'button'; b.textContent = text; b.title = title;
      b.addEventListener('pointerdown', (e) => { e.preventDefault(); b.setPointerCapture?.(e.pointerId); down(); });
      if (up) for (const ev of ['pointerup', 'pointercancel']) b.addEventListener(ev, up);
      bar.appendChild(b);
      return b;
    };
    button('◀', 'rudder to port (hold)', () => this.setRudder(-1), () => this.setRudder(0));
    button('▼', 'slower / astern', () => this.setThrottle(this.control.throttle - 2 * THROTTLE_STEP));
    this.throttleEl = document.createElement('span');
    this.throttleEl.className = 'oc-throttle';
    bar.appendChild(this.throttleEl);
    button('▲', 'faster', () => this.setThrottle(this.control.throttle + 2 * THROTTLE_STEP));
    button('▶', 'rudder to starboard (hold)', () => this.setRudder(1), () => this.setRudder(0));
    this.followEl = button('◎', 'follow your boat with the camera', () => this.setFollow(!this.follow));
    document.body.appendChild(bar);
    return bar;
  }
  setFollow(on) {
    this.follow = on;
    this.followEl.classList.toggle('on', on);
    if (this.ui) { this.ui.follow = on; this.followCtrl?.updateDisplay(); }
  }

  // The panel's folder: launch a kind at the centre of the view, follow, remove.
  buildPanel(gui) {
    if (!this.folder) {
      this.folder = gui.addFolder('Boats & buoys');
      this.folder.domElement.dataset.folder = 'bodies';
      this.ui = { kind: '', launch: () => this.launch(this.ui.kind), follow: false, remove: () => this.remove() };
    }
    for (const c of [...this.folder.controllers]) c.destroy();
    const labels = Object.fromEntries(this.kinds.map((k) => [k.label || k.name, k.name]));
    if (!this.kinds.length) return;
    if (!this.kinds.some((k) => k.name === this.ui.kind)) this.ui.kind = (this.kinds.find((k) => k.powered) || this.kinds[0]).name;
    const rows = [
      this.folder.add(this.ui, 'kind', labels).name('Kind'),
      this.folder.add(this.ui, 'launch').name('Launch at the centre of the view'),
      this.folder.add(this.ui, 'follow').name('Follow your boat').onChange((v) => this.setFollow(v)),
      this.folder.add(this.ui, 'remove').name('Remove your boat'),
    ];
    ['body-kind', 'launch', 'follow', 'remove'].forEach((n, i) => { rows[i].domElement.dataset.ui = n; });
    this.followCtrl = rows[2];
    const help = this.folder.domElement.querySelector('.oc-body-help') || document.createElement('div');
    help.className = 'oc-note oc-body-help';
    help.textContent = 'Steer your boat: W/S or ↑/↓ throttle, A/D or ←/→ rudder (held).';
    this.folder.$children.append(help);
  }

  // ---- every animation frame --------------------------------------------------------------
  // mix: the sea's blend between the older (0) and newer (1) frame.
  update(mix, sky, now) {
    this.flushSteer(now);
    if (sky) {
      this.sun.position.copy(sky.uSunDir.value).multiplyScalar(100);
      this.sun.color.copy(sky.uSunColor.value).multiplyScalar(1.9);
      this.hemi.intensity = 0.5 + 1.0 * Math.max(0, sky.uSunDir.value.y);
    }
    const w = this.labels.clientWidth || window.innerWidth, h = this.labels.clientHeight || window.innerHeight;
    const v = new THREE.Vector3(), camPos = this.camera.position;
    for (const [id, m] of this.meshes) {
      const b = this.b.get(id), a = this.a.get(id) || b;
      if (!b) { m.mesh.visible = false; m.label.hidden = true; continue; }
      m.mesh.visible = true;
      m.mesh.position.lerpVectors(a.pos, b.pos, mix);
      m.mesh.quaternion.slerpQuaternions(a.quat, b.quat, mix);
      // Label: above the body, hidden behind the camera or far away.
      v.copy(m.mesh.position); v.y += m.kind.height * 0.8 + 1.5;
      const dist = v.distanceTo(camPos);
      v.project(this.camera);
      const shown = v.z < 1 && dist < 60 * Math.max(m.kind.length, 4);
      m.label.hidden = !shown;
      if (shown) m.label.style.transform = `translate(-50%, -100%) translate(${((v.x + 1) / 2 * w).toFixed(1)}px, ${((1 - v.y) / 2 * h).toFixed(1)}px)`;
    }
    const sel = this.selected !== null && this.meshes.get(this.selected);
    if (this.throttleEl) this.throttleEl.textContent = `${Math.round(this.control.throttle * 100)} %`;
    if (sel && this.follow) { // the camera keeps its offset from the boat
      const d = sel.mesh.position.clone().sub(this.controls.target);
      d.y = 0;
      this.controls.target.add(d);
      this.camera.position.add(d);
    }
  }

  // For tests and curious users (window.oceand.bodies).
  snapshot(mix) {
    return [...this.meshes].map(([id, m]) => ({ body: id, kind: m.kind.name, mine: this.mine.has(id), name: this.info.get(id)?.name ?? null,
      owner: this.info.get(id)?.owner ?? null, position: m.mesh.position.toArray(), quaternion: m.mesh.quaternion.toArray(), mix,
      seq: this.seq ?? null }));
  }
}

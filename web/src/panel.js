// Parameter panel built entirely from hello.schema: one controller per
// parameter, `set` on release, refreshed by every `params` broadcast.
// Plus the view (wireframe, freeze) and subscription (fields, LOD, bound) folders.
import GUI from 'lil-gui';

function label(s) { return s.unit ? `${s.name} (${s.unit})` : s.name; }

// hello/params.capacity (PROTOCOL.md §7.2): resolutions the server would refuse
// (over its memory cap) are shown disabled with the reason, so the panel cannot
// pick them; those that would stream degraded with the subscribed fields say so.
export function showCapacity(ctrl, capacity, nfields) {
  const select = ctrl?.$select, values = ctrl?._values;
  if (!select || !values || !capacity) return;
  const sizes = new Map((capacity.resolutions || []).map((z) => [z.n, z]));
  values.forEach((n, i) => {
    const opt = select.options[i], z = sizes.get(Number(n));
    if (!opt) return;
    const over = Number(n) > capacity.max_resolution;
    opt.disabled = over;
    opt.dataset.capacity = over ? 'memory' : (z && z.full_rate_fields < nfields ? 'degraded' : 'ok');
    opt.textContent = String(n) + (over ? ' (over memory cap)' : opt.dataset.capacity === 'degraded' ? ' (degraded)' : '');
    opt.title = over ? `the server's memory cap of ${capacity.memory_cap_mb} MB allows N ≤ ${capacity.max_resolution}`
      : opt.dataset.capacity === 'degraded'
        ? `about ${z.est_ms[Math.min(nfields, 6) - 1]} ms per frame with ${nfields} fields, the tick allows ${capacity.budget_ms} ms: served at a coarser LOD or lower rate`
        : '';
  });
}

export class Panel {
  // actions: { set(params), subscribe(sub), view: {wireframe, freeze} object, onView(key, value) }
  constructor(actions) {
    this.actions = actions;
    this.gui = new GUI({ title: 'oceand' });
    this.gui.domElement.id = 'panel';
    if (window.innerWidth < 700) this.gui.close(); // phones: the sea first, panel on tap
    this.values = {};          // bound to the parameter controllers
    this.ctrls = {};           // name -> controller
    this.params = null;
    this.sim = null;
    const view = this.gui.addFolder('View');
    this.viewCtrls = {
      wireframe: view.add(actions.view, 'wireframe').name('wireframe').onChange((v) => actions.onView('wireframe', v)),
      freeze: view.add(actions.view, 'freeze').name('freeze display').onChange((v) => actions.onView('freeze', v)),
    };
    for (const [k, c] of Object.entries(this.viewCtrls)) c.domElement.dataset.ui = k;
    this.note = document.createElement('div');
    this.note.className = 'oc-note';
    this.note.dataset.ui = 'last-change';
    this.note.textContent = 'waiting for the server…';
    this.gui.$children.prepend(this.note);
  }

  // hello: (re)build the simulation and subscription folders from the schema.
  build(hello) {
    if (this.sim) this.sim.destroy();
    if (this.sub) this.sub.destroy();
    this.ctrls = {};
    this.values = { ...hello.params };
    this.params = { ...hello.params };
    this.readOnly = hello.role !== 'controller';
    this.sim = this.gui.addFolder(this.readOnly ? 'Simulation (view only)' : 'Simulation');
    for (const s of hello.schema || []) this.addParam(s);
    this.buildSubscription(hello);
    this.capacity = hello.capacity;
    this.refreshCapacity();
    this.note.textContent = `connected as ${hello.client_id} (${hello.role}), params v${hello.params_version}`;
  }

  addParam(s) {
    const folder = this.sim, obj = this.values, name = s.name;
    if (!(name in obj)) obj[name] = s.default;
    let c;
    if (s.type === 'enum') c = folder.add(obj, name, s.choices);
    else if (s.type === 'bool') c = folder.add(obj, name);
    else if (s.type === 'int' && s.pow2) {
      const opts = [];
      for (let v = Math.max(1, s.min ?? 1); v <= (s.max ?? 4096); v *= 2) opts.push(v);
      c = folder.add(obj, name, opts);
    } else if (s.min !== undefined && s.max !== undefined && Number.isFinite(s.min) && Number.isFinite(s.max)) {
      // Round step (0.01, 0.1, …) about 1/1000 of the range, so typed values stay as typed.
      const step = s.type === 'int' ? 1 : 10 ** Math.floor(Math.log10((s.max - s.min) / 1000));
      c = folder.add(obj, name, s.min, s.max, step);
    } else {
      c = folder.add(obj, name);
      if (s.type === 'int') c.step(1);
    }
    c.name(label(s));
    c.domElement.dataset.param = name;
    if (s.description) c.domElement.title = s.description;
    if (this.readOnly) c.disable();
    // Send on release (not on every drag step): the server rate-limits sets.
    c.onFinishChange((v) => {
      if (v === this.params[name]) return;
      let val = v;
      if (s.type === 'int') val = Math.round(Number(v));
      this.actions.set({ [name]: val });
    });
    this.ctrls[name] = c;
  }

  buildSubscription(hello) {
    const sub = hello.subscription || {};
    this.subValues = { lod: sub.lod ?? 0, bound: sub.bound ?? 0.01 };
    this.sub = this.gui.addFolder('Subscription');
    const send = (extra) => this.actions.subscribe(extra);
    this.subCtrls = {
      lod: this.sub.add(this.subValues, 'lod', hello.lods || [0]).name('LOD').onChange((v) => send({ lod: Number(v) })),
      bound: this.sub.add(this.subValues, 'bound', hello.bounds || [0]).name('error bound (0 = raw)')
        .onChange((v) => send({ bound: Number(v) })),
    };
    const fields = new Set(sub.fields || ['height', 'dx', 'dz']);
    for (const f of hello.fields || []) {
      this.subValues[f] = fields.has(f);
      this.subCtrls[f] = this.sub.add(this.subValues, f).name(`field ${f}`).onChange(() => {
        send({ fields: (hello.fields || []).filter((n) => this.subValues[n]) });
      });
    }
    for (const [k, c] of Object.entries(this.subCtrls)) c.domElement.dataset.sub = k;
    this.sub.close();
  }

  refreshCapacity() {
    const nfields = (this.lastFields || ['height', 'dx', 'dz']).length;
    showCapacity(this.ctrls.resolution, this.capacity, nfields);
  }

  // Connection lost: the values shown are the last known ones.
  disconnected() {
    this.note.textContent = 'disconnected — showing the last known values';
  }

  // subscribed: reflect the normalised subscription.
  subscribed(s) {
    if (!this.subCtrls) return;
    if (s.lod !== undefined) this.subValues.lod = s.lod;
    if (s.bound !== undefined) this.subValues.bound = s.bound;
    if (s.fields) for (const k of Object.keys(this.subValues)) if (k in this.subCtrls && k !== 'lod' && k !== 'bound') this.subValues[k] = s.fields.includes(k);
    for (const c of Object.values(this.subCtrls)) c.updateDisplay();
    if (s.fields) { this.lastFields = s.fields; this.refreshCapacity(); }
  }

  // params broadcast: new values, and who changed what.
  update(msg) {
    this.params = { ...msg.params };
    Object.assign(this.values, msg.params);
    for (const c of Object.values(this.ctrls)) c.updateDisplay();
    if (msg.capacity) { this.capacity = msg.capacity; this.refreshCapacity(); }
    const changed = msg.changed || [];
    for (const name of changed) {
      const el = this.ctrls[name]?.domElement;
      if (el) { el.classList.remove('oc-changed'); void el.offsetWidth; el.classList.add('oc-changed'); }
    }
    if (changed.length) {
      const what = changed.map((n) => `${n}=${JSON.stringify(msg.params[n])}`).join(', ');
      this.note.textContent = `v${msg.params_version}: ${msg.by || 'server'} set ${what}`;
    }
  }

  // A rejected set: show why and put the server's values back.
  error(msg) {
    this.note.textContent = `rejected: ${msg.message || msg.code}${msg.param ? ` (${msg.param})` : ''}`;
    if (this.params) { Object.assign(this.values, this.params); for (const c of Object.values(this.ctrls)) c.updateDisplay(); }
  }
}

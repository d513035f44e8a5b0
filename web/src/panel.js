// The parameter panel, built from hello.schema. Each parameter gets a human label,
// a group (sea / advanced / developer) and a one-line help: from the schema when the
// server sends `label`, `group` and `help`, else from the table below (today's names).
// A `set` is sent on release; every `params` broadcast refreshes the panel and says
// who changed what ("you" for our own changes). Folders: Sea (Beaufort presets and
// the everyday parameters), View (local: time of day, status), Advanced, Developer
// (closed: transform, wireframe, freeze, the subscription).
import GUI from 'lil-gui';
import { SEA_PRESETS, VIEW_PRESETS, matchSeaPreset } from './presets.js';
import { checkName, tidyName, storedName, storeName, NAME_MAX_CHARS } from './name.js';
import { windBearings } from './compass.js'; // the wind's bearings, as sailors name winds

// Fallback labels and groups for the parameters of today's schema.
export const PARAM_INFO = {
  wind_speed: { label: 'Wind speed', group: 'sea' },
  wind_direction: { label: 'Wind direction', group: 'sea' },
  fetch: { label: 'Fetch', group: 'sea' },
  choppiness: { label: 'Choppiness', group: 'sea' },
  swell: { label: 'Swell (long crests)', group: 'sea' },
  paused: { label: 'Pause the sea', group: 'sea' },
  spectrum: { label: 'Wave spectrum', group: 'advanced' },
  amplitude: { label: 'Wave height scale', group: 'advanced' },
  depth: { label: 'Water depth', group: 'advanced' },
  gamma: { label: 'Peak sharpness (γ)', group: 'advanced' },
  directional_spread: { label: 'Directional spreading', group: 'advanced' },
  small_wave_cutoff: { label: 'Shortest waves', group: 'advanced' },
  patch_size: { label: 'Patch size', group: 'advanced' },
  resolution: { label: 'Grid resolution', group: 'advanced' },
  time_scale: { label: 'Playback speed', group: 'advanced' },
  loop_period: { label: 'Loop period', group: 'advanced' },
  seed: { label: 'Random seed', group: 'advanced' },
  transform: { label: 'Transform (FFT/DFT)', group: 'developer' },
};
const GROUPS = ['sea', 'advanced', 'developer'];

// A schema entry with its human face: label, group and help, wherever they come from.
export function describe(s) {
  const info = PARAM_INFO[s.name] || {};
  const pretty = s.name.replace(/_/g, ' ').replace(/^./, (c) => c.toUpperCase());
  const group = GROUPS.includes(s.group) ? s.group : (info.group || 'advanced');
  return { label: s.label || info.label || pretty, group, help: s.help || s.description || '' };
}

function formatValue(v, s) {
  if (typeof v === 'number' && s?.type === 'float') v = Number(v.toPrecision(4));
  return `${typeof v === 'string' ? v : JSON.stringify(v)}${s?.unit ? ` ${s.unit}` : ''}`;
}

// A row of small buttons inside a folder (lil-gui has one button per row).
function buttonRow(folder, kind, items, onClick) {
  const row = document.createElement('div');
  row.className = 'oc-buttons';
  row.dataset.ui = `${kind}-presets`;
  const buttons = {};
  for (const it of items) {
    const b = document.createElement('button');
    b.type = 'button';
    b.textContent = it.label;
    b.title = it.help;
    b.dataset[kind] = it.name;
    b.addEventListener('click', () => onClick(it));
    row.appendChild(b);
    buttons[it.name] = b;
  }
  folder.$children.prepend(row);
  return buttons;
}

// hello/params.capacity (PROTOCOL.md §7.2): resolutions the server would refuse
// (over its memory cap) are shown disabled with the reason, so the panel cannot
// pick them; those that would stream degraded with the subscribed fields say so,
// and, for a temporal subscription, those streamed at full detail only with the
// intra codec (more bytes) say that (the server's ladder, `degraded` with codec 1).
export function showCapacity(ctrl, capacity, nfields, temporal = true) {
  const select = ctrl?.$select, values = ctrl?._values;
  if (!select || !values || !capacity) return;
  const sizes = new Map((capacity.resolutions || []).map((z) => [z.n, z]));
  const k = Math.min(Math.max(nfields, 1), 6) - 1;
  let capped = null;
  values.forEach((n, i) => {
    const opt = select.options[i], z = sizes.get(Number(n));
    if (!opt) return;
    const over = Number(n) > capacity.max_resolution;
    const tf = z ? (z.temporal_fields ?? z.full_rate_fields) : 6; // a server before the codec rung: no difference
    opt.disabled = over;
    if (over && capped === null) capped = Number(n);
    opt.dataset.capacity = over ? 'memory' : !z ? 'ok' : z.full_rate_fields < nfields ? 'degraded' : temporal && tf < nfields ? 'intra' : 'ok';
    const label = { memory: ' (over memory cap)', degraded: ' (degraded)', intra: ' (intra codec)' }[opt.dataset.capacity] || '';
    opt.textContent = String(n) + label;
    const intraMs = z?.est_intra_ms ? z.est_intra_ms[k] : undefined;
    opt.title = over ? `the server's memory cap of ${capacity.memory_cap_mb} MB allows N ≤ ${capacity.max_resolution}`
      : opt.dataset.capacity === 'degraded'
        ? `about ${intraMs ?? z.est_ms[k]} ms per frame with ${nfields} fields even with the intra codec, the tick allows ${capacity.budget_ms} ms: served at a coarser LOD or lower rate`
        : opt.dataset.capacity === 'intra'
          ? `about ${z.est_ms[k]} ms per frame with ${nfields} fields with the temporal codec, ${intraMs} ms intra; the tick allows ${capacity.budget_ms} ms: full detail and rate with the intra codec (more bytes)`
          : '';
  });
  // The reason beside the option too: a disabled option's tooltip is seldom seen.
  let note = ctrl.domElement.nextElementSibling;
  if (!note || !note.classList.contains('oc-capnote')) {
    note = document.createElement('div');
    note.className = 'oc-capnote';
    note.dataset.ui = 'capacity-note';
    ctrl.domElement.after(note);
  }
  note.hidden = capped === null;
  note.textContent = capped === null ? '' : `N ≥ ${capped} is off: over the server's memory cap of ${capacity.memory_cap_mb} MB (N ≤ ${capacity.max_resolution})`;
}

// A value typed into a number field that the parameter's range does not hold: the reason,
// or null. (lil-gui would clamp it to the range and the clamped value would be sent.)
export function rangeError(s, v) {
  if (!s || (s.type !== 'float' && s.type !== 'int') || !Number.isFinite(s.min) || !Number.isFinite(s.max)) return null;
  if (!Number.isFinite(v)) return `not a number; allowed ${s.min} to ${s.max}${s.unit ? ` ${s.unit}` : ''}`;
  if (v >= s.min && v <= s.max) return null;
  return `${v} is outside ${s.min} to ${s.max}${s.unit ? ` ${s.unit}` : ''}`;
}

// "measured" is a sea a buoy or a forecast gives (ocean-tap sea): offered only while in force.
function enumChoices(s, value) { return s.choices.filter((v) => v !== 'measured' || value === 'measured'); }

export class Panel {
  // actions: { set(params), subscribe(sub), name(text), view: {wireframe, freeze, hour, hud}, onView(key, value) }
  constructor(actions, { compact = false } = {}) {
    this.actions = actions;
    this.gui = new GUI({ title: 'oceand' });
    this.gui.domElement.id = 'panel';
    if (compact) this.gui.close(); // phones, either way round: the sea first, panel on tap
    this.values = {};          // bound to the parameter controllers
    this.ctrls = {};           // name -> controller
    this.schema = {};          // name -> schema entry
    this.params = null;
    this.myId = null;
    this.controlId = null; // our control connection's client id (main.js): its changes are ours too
    this.connected = false;
    this.folders = {};
    this.note = document.createElement('div');
    this.note.className = 'oc-note';
    this.note.dataset.ui = 'last-change';
    this.note.textContent = 'waiting for the server…';
    this.gui.$children.prepend(this.note);

    // Your display name: shown to others with your changes; kept in localStorage and
    // sent on every connect. Checked here as the server does (name.js).
    this.me = { name: storedName() };
    this.nameCtrl = this.gui.add(this.me, 'name').name('Your name');
    this.nameCtrl.domElement.dataset.ui = 'name';
    this.nameCtrl.domElement.title = `shown to others with your changes (at most ${NAME_MAX_CHARS} characters, no markup)`;
    this.nameCtrl.$input.maxLength = 2 * NAME_MAX_CHARS; // UTF-16 units; checkName counts characters
    this.nameCtrl.$input.placeholder = 'anonymous';
    this.nameCtrl.$input.autocomplete = 'nickname';
    this.nameCtrl.onFinishChange((v) => this.setName(v));
    this.note.after(this.nameCtrl.domElement);
    this.serverName = null;    // the name in force on the server (named), null before

    // Sea: presets first; the parameters are added on hello.
    this.folders.sea = this.gui.addFolder('Sea');
    this.folders.sea.domElement.dataset.folder = 'sea';
    this.seaButtons = buttonRow(this.folders.sea, 'preset', SEA_PRESETS, (p) => this.actions.set({ ...p.params }));

    // View: local only, never sent.
    const view = this.gui.addFolder('View (this screen only)');
    view.domElement.dataset.folder = 'view';
    this.viewButtons = buttonRow(view, 'view', VIEW_PRESETS, (p) => this.setHour(p.hour));
    this.viewCtrls = {
      hour: view.add(actions.view, 'hour', 0, 24, 0.05).name('Time of day (h)').onChange((v) => actions.onView('hour', v)),
      hud: view.add(actions.view, 'hud').name('Show status (H)').onChange((v) => actions.onView('hud', v)),
    };
    this.folders.advanced = this.gui.addFolder('Advanced');
    this.folders.advanced.domElement.dataset.folder = 'advanced';
    this.folders.advanced.close();
    this.folders.developer = this.gui.addFolder('Developer');
    this.folders.developer.domElement.dataset.folder = 'developer';
    this.folders.developer.close();
    const dev = this.folders.developer;
    this.viewCtrls.wireframe = dev.add(actions.view, 'wireframe').name('wireframe').onChange((v) => actions.onView('wireframe', v));
    this.viewCtrls.freeze = dev.add(actions.view, 'freeze').name('freeze display').onChange((v) => actions.onView('freeze', v));
    for (const [k, c] of Object.entries(this.viewCtrls)) c.domElement.dataset.ui = k;
    this.paramFolders = [];    // per-hello sub-folders to destroy on the next hello
    this.setConnected(false);
  }

  // The field's text: tidy, check, store and send (or say what is wrong).
  setName(v) {
    const name = tidyName(v);
    const why = checkName(name);
    if (why) {
      this.note.textContent = `name not set: ${why}`;
      this.nameCtrl.domElement.classList.add('oc-invalid');
      return;
    }
    this.nameCtrl.domElement.classList.remove('oc-invalid');
    this.me.name = name;
    this.nameCtrl.updateDisplay();
    storeName(name);
    if (this.connected) this.actions.name(name);
  }
  // The server's answer (named): the name now in force.
  named(name) {
    this.serverName = name;
    if (this.keepNote) return; // a restart's note outranks "you are …"
    this.note.textContent = name ? `you are ${name} (${this.myId})` : `connected as ${this.myId}`;
  }

  setHour(h) {
    this.actions.view.hour = h;
    this.viewCtrls.hour.updateDisplay();
    this.actions.onView('hour', h);
  }
  // Local view changes made elsewhere (keyboard): show them.
  refreshView() { for (const c of Object.values(this.viewCtrls)) c.updateDisplay(); }

  // hello: (re)build the parameter controllers and the subscription folder.
  build(hello) {
    for (const c of Object.values(this.ctrls)) c.destroy();
    if (this.sub) this.sub.destroy();
    this.compass?.remove();
    this.compass = null;
    for (const e of this.gui.domElement.querySelectorAll('.oc-capnote')) e.remove();
    this.ctrls = {};
    this.schema = {};
    this.values = { ...hello.params };
    this.params = { ...hello.params };
    this.myId = hello.client_id;
    this.readOnly = hello.role !== 'controller';
    this.folders.sea.title(this.readOnly ? 'Sea (view only)' : 'Sea');
    for (const s of hello.schema || []) this.addParam(s);
    this.buildSubscription(hello);
    this.markPreset();
    this.capacity = hello.capacity;
    this.refreshCapacity();
    this.note.textContent = `connected as ${hello.client_id}${this.readOnly ? ' (view only)' : ''}`;
    this.keepNote = false;
    this.setConnected(true);
  }

  addParam(s) {
    const info = describe(s);
    const folder = this.folders[info.group], obj = this.values, name = s.name;
    this.schema[name] = { ...s, ...info };
    if (!(name in obj)) obj[name] = s.default;
    let c;
    if (s.type === 'enum') c = folder.add(obj, name, enumChoices(s, obj[name]));
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
    // (wind_direction is where the wind blows toward: said in the label, the compass says "from")
    const label = name === 'wind_direction' ? `${info.label}, toward` : info.label;
    c.name(s.unit ? `${label} (${s.unit})` : label);
    c.domElement.dataset.param = name;
    c.domElement.dataset.group = info.group;
    if (info.help) c.domElement.title = info.help;
    // What was typed, before lil-gui clamps it to the range (capture: before its own listener).
    let typed = null;
    if (c.$input && (s.type === 'float' || s.type === 'int')) {
      c.domElement.addEventListener('input', (ev) => { if (ev.target === c.$input) typed = c.$input.value; }, true);
    }
    // Send on release (not on every drag step): the server rate-limits sets.
    c.onFinishChange((v) => {
      const raw = typed;
      typed = null;
      if (raw !== null && raw.trim() !== '') {
        const why = rangeError(s, Number(raw));
        if (why) { this.refuse(name, why); return; }
      }
      c.domElement.classList.remove('oc-invalid');
      if (v === this.params[name]) return;
      let val = v;
      if (s.type === 'int') val = Math.round(Number(v));
      this.actions.set({ [name]: val });
    });
    this.ctrls[name] = c;
    if (name === 'wind_direction') this.addCompass(c);
  }

  // A typed value out of range: not sent; the field shows the value in force again.
  refuse(name, why) {
    const c = this.ctrls[name];
    this.note.textContent = `${this.schema[name]?.label || name} not changed: ${why}`;
    c.domElement.classList.add('oc-invalid');
    if (this.params && name in this.params) this.values[name] = this.params[name];
    c.updateDisplay();
  }

  // A compass under the wind direction: an arrow the way the wind blows, and the direction
  // it comes from (as sailors name winds) beside the one it blows toward.
  addCompass(ctrl) {
    const el = document.createElement('div');
    el.className = 'oc-compass';
    el.dataset.ui = 'compass';
    el.innerHTML = `<svg viewBox="-20 -20 40 40" width="40" height="40" aria-hidden="true">
      <circle r="17" fill="none" stroke="currentColor" stroke-opacity="0.5"/>
      <text y="-10" text-anchor="middle" font-size="8" fill="currentColor">N</text>
      <g class="oc-arrow"><line y1="11" y2="-9" stroke="#7fd0ff" stroke-width="2.5"/><path d="M0 -14 L-5 -6 L5 -6 Z" fill="#7fd0ff"/></g>
    </svg><span class="oc-compass-text"></span>`;
    ctrl.domElement.after(el);
    this.compass = el;
    this.updateCompass();
  }
  updateCompass() {
    if (!this.compass) return;
    const b = windBearings(this.values.wind_direction);
    this.compass.querySelector('.oc-arrow').setAttribute('transform', `rotate(${b.toward.toFixed(1)})`);
    this.compass.querySelector('.oc-compass-text').textContent =
      `from ${b.fromName} (${Math.round(b.from)}°), blowing toward ${b.towardName} (${Math.round(b.toward)}°)`;
  }

  buildSubscription(hello) {
    const sub = hello.subscription || {};
    this.subValues = { lod: sub.lod ?? 0, bound: sub.bound ?? 0.01 };
    this.sub = this.folders.developer.addFolder('Subscription');
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
  }

  // Shared controls (parameters, sea presets, subscription) work only while connected;
  // the view folder is local and stays usable.
  setConnected(on) {
    this.connected = on;
    this.gui.domElement.classList.toggle('oc-offline', !on);
    const lock = !on || this.readOnly;
    for (const c of Object.values(this.ctrls)) c.disable(lock);
    for (const b of Object.values(this.seaButtons)) b.disabled = lock;
    if (this.subCtrls) for (const c of Object.values(this.subCtrls)) c.disable(!on);
  }

  refreshCapacity() {
    const nfields = (this.lastFields || ['height', 'dx', 'dz']).length;
    showCapacity(this.ctrls.resolution, this.capacity, nfields, this.lastTemporal !== false);
  }

  // Connection lost: the values shown are the last known ones.
  disconnected() {
    this.setConnected(false);
    this.note.textContent = 'disconnected — showing the last known values';
  }

  // subscribed: reflect the normalised subscription.
  subscribed(s) {
    if (!this.subCtrls) return;
    if (s.lod !== undefined) this.subValues.lod = s.lod;
    if (s.bound !== undefined) this.subValues.bound = s.bound;
    if (s.fields) for (const k of Object.keys(this.subValues)) if (k in this.subCtrls && k !== 'lod' && k !== 'bound') this.subValues[k] = s.fields.includes(k);
    for (const c of Object.values(this.subCtrls)) c.updateDisplay();
    if (s.fields || s.temporal !== undefined) {
      if (s.fields) this.lastFields = s.fields;
      this.lastTemporal = s.temporal === true;
      this.refreshCapacity();
    }
  }

  // Said in the note and outside the panel (a daemon restart that changed the sea).
  announce(text) {
    this.note.textContent = text;
    this.keepNote = true;
    this.onAnnounce?.(text);
  }
  get closed() { return this.gui._closed; }

  // What differs between two parameter sets, as the note says it ("Wind speed 13.25 → 10 m/s").
  differences(before, after) {
    return Object.keys(after).filter((k) => before && k in before && before[k] !== after[k])
      .map((k) => `${this.schema[k]?.label || k} ${formatValue(before[k], this.schema[k])} → ${formatValue(after[k], this.schema[k])}`);
  }

  // Who a change came from: "you", the changer's display name, or its id.
  who(msg) {
    if (msg.by && (msg.by === this.myId || msg.by === this.controlId)) return 'you';
    return msg.by_name || msg.by || 'the server';
  }

  markPreset() {
    const p = matchSeaPreset(this.params || {});
    for (const [name, b] of Object.entries(this.seaButtons)) b.classList.toggle('oc-active', p?.name === name);
    return p;
  }

  // params broadcast: new values, and who changed what.
  update(msg) {
    this.params = { ...msg.params };
    Object.assign(this.values, msg.params);
    for (const [name, c] of Object.entries(this.ctrls)) {
      // a sea attached (or let go) since the panel was built: offer "measured" while it is in force
      const want = this.schema[name]?.type === 'enum' && enumChoices(this.schema[name], this.values[name]);
      if (want && want.length !== c.$select.options.length) c.options(want);
      else c.updateDisplay();
    }
    this.updateCompass();
    if (msg.capacity) { this.capacity = msg.capacity; this.refreshCapacity(); }
    const changed = msg.changed || [];
    for (const name of changed) {
      const el = this.ctrls[name]?.domElement;
      if (el) { el.classList.remove('oc-changed'); void el.offsetWidth; el.classList.add('oc-changed'); }
    }
    const preset = this.markPreset();
    if (!changed.length) return;
    this.keepNote = false;
    const what = changed.map((n) => `${this.schema[n]?.label || n} ${formatValue(msg.params[n], this.schema[n])}`).join(', ');
    this.note.textContent = preset && changed.length > 1
      ? `${this.who(msg)} chose ${preset.label} (${preset.beaufort}): ${what}`
      : `${this.who(msg)} set ${what}`;
    this.note.title = `parameters version ${msg.params_version}`;
    // Someone else's change: also said outside the panel (closed on phones).
    if (this.who(msg) !== 'you') this.onAnnounce?.(this.note.textContent);
  }

  // A rejected set: show why and put the server's values back.
  error(msg) {
    const s = msg.param && this.schema[msg.param];
    this.note.textContent = `rejected: ${msg.message || msg.code}${s ? ` (${s.label})` : ''}`;
    if (this.params) { Object.assign(this.values, this.params); for (const c of Object.values(this.ctrls)) c.updateDisplay(); }
  }
}

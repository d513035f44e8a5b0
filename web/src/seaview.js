// What sea the page shows, in words and pictures: a card under the HUD with the compass (it turns
// with the camera) and the sea line ("NDBC 46026, 2026-12-01 20:40 UTC: Hs 2.3 m, Tp 12.5 s from
// 285°"; with a parametric sea, the wind), and the measured sea's directional spectrum as a polar
// plot that opens from the card or from the panel's "Measured sea" folder. The daemon's summary
// (`sea` in hello and in the broadcasts that carry it; null: a parametric sea) reaches it
// through applySea alone.
import { Compass, windBearings, pointName, cameraHeading } from './compass.js';
import { polarModel, drawPolar, colourGradient, LOG_DECADES } from './polarplot.js';

const num = (v) => typeof v === 'number' && Number.isFinite(v);
const fix = (v, d) => (num(v) ? Number(v.toFixed(d)).toString() : null);
// "2026-12-01T20:40:00Z" -> "2026-12-01 20:40 UTC"; any other text as it came (the daemon does
// not parse it).
export function seaTime(t) {
  if (typeof t !== 'string') return null;
  const m = /^(\d{4}-\d\d-\d\d)[T ](\d\d:\d\d)(:\d\d(\.\d*)?)?(Z|[+-]00:?00)$/.exec(t.trim());
  return m ? `${m[1]} ${m[2]} UTC` : t.trim() || null;
}
// The sea line: source and time, then what a sailor asks first (as two parts, so that a narrow
// card breaks the line between them).
export function seaLineParts(s) {
  if (!s) return ['', ''];
  const head = [typeof s.source === 'string' && s.source.trim() ? s.source.trim() : null, seaTime(s.time)].filter(Boolean).join(', ');
  const what = [fix(s.hs_m, 1) && `Hs ${fix(s.hs_m, 1)} m`,
    [fix(s.tp_s, 1) && `Tp ${fix(s.tp_s, 1)} s`, num(s.dir_from_deg) && `from ${Math.round(s.dir_from_deg) % 360}°`].filter(Boolean).join(' ')]
    .filter(Boolean).join(', ');
  return head && what ? [`${head}:`, what] : [head || what || 'a measured sea', ''];
}
export const seaLine = (s) => seaLineParts(s).filter(Boolean).join(' ');
// The parametric sea's line: its wind, named as sailors name winds.
export function windLine(p) {
  if (!p || !num(p.wind_speed)) return '';
  const b = windBearings(p.wind_direction);
  return `wind ${fix(p.wind_speed, 1)} m/s from ${b.fromName} (${Math.round(b.from) % 360}°)`;
}
// What else the summary says that matters: how much of the sea the grid holds, and why not.
export function fitLine(s) {
  if (!s) return '';
  const parts = [];
  if (typeof s.fit_note === 'string' && s.fit_note.trim()) parts.push(s.fit_note.trim());
  else if (num(s.captured) && s.captured < 0.9) parts.push(`the grid holds ${Math.round(100 * s.captured)} % of its energy`);
  return parts.join('; ');
}

export class SeaView {
  // gui: the panel's lil-gui root (the "Measured sea" folder goes after `after`, its Sea folder);
  // compact: a phone (one overlay at a time: the plot and the open panel take turns).
  constructor({ gui, after, compact = false }) {
    this.compact = compact; this.gui = gui;
    this.summary = null; this.version = null; this.params = null; this.model = null; this.plotOpen = false;
    this.card = document.createElement('div');
    this.card.id = 'sea-card';
    this.card.dataset.ui = 'sea-card';
    this.compass = new Compass();
    this.text = document.createElement('div');
    this.text.className = 'oc-sea-text';
    this.line = document.createElement('div');
    this.line.dataset.ui = 'sea-line';
    this.fit = document.createElement('div');
    this.fit.className = 'oc-sea-fit';
    this.fit.dataset.ui = 'sea-fit';
    this.button = document.createElement('button');
    this.button.type = 'button';
    this.button.dataset.ui = 'sea-plot-toggle';
    this.button.addEventListener('click', () => this.openPlot(!this.plotOpen));
    this.text.append(this.line, this.fit, this.button);
    this.card.append(this.compass.svg, this.text);
    document.body.appendChild(this.card);

    this.plot = document.createElement('div');
    this.plot.id = 'sea-plot';
    this.plot.dataset.ui = 'sea-plot';
    this.plot.hidden = true;
    this.plot.innerHTML = `<div class="oc-plot-head"><span class="oc-plot-title">Directional spectrum</span>
      <button type="button" class="oc-plot-close" data-ui="sea-plot-close" title="close">×</button></div>
      <canvas data-ui="sea-polar"></canvas>
      <div class="oc-plot-scale"><span class="oc-plot-bar"></span><span class="oc-plot-scale-text"></span></div>
      <div class="oc-plot-caption" data-ui="sea-plot-caption"></div>`;
    this.canvas = this.plot.querySelector('canvas');
    this.plot.querySelector('.oc-plot-bar').style.background = colourGradient();
    this.plot.querySelector('.oc-plot-close').addEventListener('click', () => this.openPlot(false));
    document.body.appendChild(this.plot);

    if (gui) {
      this.folder = gui.addFolder('Measured sea');
      this.folder.domElement.dataset.folder = 'measured';
      if (after) after.domElement.after(this.folder.domElement);
      this.folderNote = document.createElement('div');
      this.folderNote.className = 'oc-note';
      this.folderNote.dataset.ui = 'sea-folder-line';
      this.folder.$children.prepend(this.folderNote);
      this.folderButton = this.folder.add({ plot: () => this.openPlot(!this.plotOpen) }, 'plot').name('Directional spectrum (polar plot)');
      this.folderButton.domElement.dataset.ui = 'sea-folder-plot';
      this.folder.hide();
      gui.onOpenClose((g) => { if (g === gui && !g._closed && this.compact) this.openPlot(false); });
    }
    const again = () => this.layout();
    this.observer = new ResizeObserver(again);
    for (const id of ['hud', 'panel']) { const e = document.getElementById(id); if (e) this.observer.observe(e); }
    window.addEventListener('resize', again);
    this.render();
  }

  // The one way in for the daemon's summary (hello, and every broadcast that carries `sea`).
  // fresh: a new session (hello), whose versions may start again lower (a restarted daemon).
  // Both connections bring each broadcast: a summary whose version is not newer than the one in
  // force is a copy (null after a summary keeps its version, so a late copy of it stays out).
  applySea(summary, { fresh = false } = {}) {
    const s = summary && typeof summary === 'object' ? summary : null;
    if (fresh) this.version = null;
    if (s && num(s.version) && this.version !== null && s.version <= this.version) return false;
    if (s && num(s.version)) this.version = s.version;
    this.summary = s;
    this.model = s ? polarModel(s.polar) : null;
    if (!this.model && this.plotOpen) this.openPlot(false);
    this.render();
    if (this.plotOpen) this.drawPlot();
    return true;
  }
  // The shared parameters (the wind, for a parametric sea).
  setParams(params) { this.params = params || null; this.render(); }

  // The measured sea shown: the summary while the shared spectrum is "measured" (a sea stays
  // attached when someone picks a parametric spectrum again, and the page then shows the wind).
  shown() { return this.summary && (!this.params || this.params.spectrum === 'measured') ? this.summary : null; }

  render() {
    const s = this.shown(), wind = this.params ? windBearings(this.params.wind_direction) : null;
    this.compass.setWaves(s && num(s.dir_from_deg) ? s.dir_from_deg : null);
    this.compass.setWind(!s && wind ? wind.toward : null);
    const [a, b] = s ? seaLineParts(s) : [windLine(this.params), ''];
    const text = [a, b].filter(Boolean).join(' ');
    this.line.replaceChildren(...[a, b].filter(Boolean).map((t, i) => Object.assign(document.createElement('span'), { textContent: (i ? ' ' : '') + t })));
    this.line.className = s ? 'oc-sea-line oc-sea-waves' : 'oc-sea-line oc-sea-wind';
    const fit = fitLine(s);
    this.fit.textContent = fit;
    this.fit.hidden = !fit;
    if (!s && this.plotOpen) { this.plotOpen = false; this.plot.hidden = true; }
    this.button.hidden = !this.model || !s;
    this.button.textContent = this.plotOpen ? 'hide the spectrum' : 'directional spectrum ▸';
    this.card.classList.toggle('oc-measured', !!s);
    this.card.hidden = !text && !s; // before the first hello: nothing to say
    this.card.title = s && num(s.dir_from_deg) ? `waves from ${pointName(s.dir_from_deg)}` : '';
    if (this.folder) {
      if (s) this.folder.show(); else this.folder.hide();
      this.folderNote.textContent = [seaLine(s), fit].filter(Boolean).join('. ');
      this.folderButton.name(this.plotOpen ? 'Hide the directional spectrum' : 'Directional spectrum (polar plot)');
      this.folderButton.disable(!this.model || !s);
    }
    this.layout();
  }

  openPlot(on) {
    this.plotOpen = !!(on && this.model && this.shown());
    this.plot.hidden = !this.plotOpen;
    if (this.plotOpen && this.compact && this.gui && !this.gui._closed) this.gui.close(); // the sea, not two overlays
    this.render();
    if (this.plotOpen) this.drawPlot();
  }

  drawPlot() {
    const m = this.model, s = this.summary;
    if (!m) return;
    drawPolar(this.canvas, m, this.plotSize || 260);
    const unit = 'm²/Hz/°';
    const lo = Number((m.peak * 10 ** -LOG_DECADES).toPrecision(2)), hi = Number(m.peak.toPrecision(2));
    this.plot.querySelector('.oc-plot-scale-text').textContent = `log scale, ${lo} to ${hi} ${unit}`;
    const more = [num(s.spread_deg) && `spread ${Math.round(s.spread_deg)}°`, num(s.depth_m) && `depth ${fix(s.depth_m, 1)} m`,
      num(s.captured) && `the grid holds ${Math.round(100 * s.captured)} %`].filter(Boolean);
    this.plot.querySelector('.oc-plot-caption').textContent =
      `Around: the direction waves come from. Out: frequency, rings in periods.${more.length ? ` ${more.join(', ').replace(/^./, (c) => c.toUpperCase())}.` : ''}`;
    this.plot.querySelector('.oc-plot-title').textContent = s.source ? `${String(s.source).trim()} · directional spectrum` : 'Directional spectrum';
    if (!this.plot.classList.contains('oc-row')) this.plotExtra = this.plot.offsetHeight - this.canvas.offsetHeight; // header, scale, caption
  }

  // Placement: the card at the left under the HUD (which grows and shrinks); the plot under the
  // card where it has room, else beside it, never over the HUD or the panel (the open panel's
  // box, or its title bar when closed) and never off the screen.
  layout(again = 0) {
    const vw = window.innerWidth, vh = window.innerHeight, M = 8;
    const hud = document.getElementById('hud')?.getBoundingClientRect();
    const panelEl = document.getElementById('panel');
    const panel = panelEl?.getBoundingClientRect();
    const top = Math.round((hud && hud.height ? hud.bottom : 0) + 6);
    // What the panel takes on the right at a given height (the card and plot stay left of it).
    const rightAt = (y0, y1) => (panel && panel.width && y0 < panel.bottom + 4 && y1 > panel.top - 4 ? panel.left - M : vw - M);
    this.card.style.top = `${top}px`;
    this.card.style.maxWidth = `${Math.max(120, Math.min(340, rightAt(top, top + 90) - M))}px`;
    const card = this.card.hidden ? { left: M, right: M, top, bottom: top } : this.card.getBoundingClientRect();
    if (!this.plotOpen) return;
    // Column: the texts under the canvas; row (short screens): beside it, in a column TEXT_W wide.
    const TEXT_W = 150, cap = this.compact ? 300 : 360;
    const extra = (this.plotExtra || 90) + 4; // the header, scale and caption around the canvas
    const below = { left: M, top: card.bottom + 6 }, beside = { left: card.right + M, top: card.top };
    const fit = (p, row) => {
      const h = vh - M - p.top - (row ? 34 : extra);
      const w = rightAt(p.top, vh) - p.left - 12 - (row ? TEXT_W + 8 : 0);
      return { ...p, row, size: Math.floor(Math.min(cap, h, w)) };
    };
    const opts = [fit(below, false), fit(beside, false), fit(beside, true), fit(below, true)];
    const at = opts[0].size >= 240 ? opts[0] : opts.reduce((x, y) => (y.size > x.size + 20 ? y : x)); // (a row only when clearly larger)
    this.plotSize = Math.max(120, at.size);
    this.plot.classList.toggle('oc-row', at.row);
    this.plot.style.left = `${at.left}px`; this.plot.style.top = `${at.top}px`;
    // (a column never narrower than its texts want, where the screen has the room: squeezed, they
    // wrapped into a tall column that left the canvas less room still)
    this.plot.style.width = at.row ? '' : `${Math.max(this.plotSize + 12, Math.min(260, rightAt(at.top, vh) - at.left))}px`;
    const key = `${this.plotSize} ${at.row}`;
    if (this.drawnSize !== key) {
      this.drawnSize = key;
      const extra = this.plotExtra;
      this.drawPlot();
      if (this.plotExtra !== extra && again < 2) this.layout(again + 1); // the texts wrapped otherwise at this width
    }
  }

  // Every animation frame: the compass turns with the camera.
  // (Its matrices brought up to date here: a page that does not draw, ?draw=0, never renders them.)
  frame(camera) { camera.updateMatrixWorld(); this.compass.setHeading(cameraHeading(camera)); }
}

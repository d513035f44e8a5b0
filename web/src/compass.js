// Bearings and the on-screen compass. The sea's world frame (docs/simulation.md "Frames"): y up,
// north = +z, east = -x. Two direction conventions meet here and the compass makes both read right:
// the simulation's wind_direction is where the wind blows *toward*, an angle in the x-z plane
// (0 = +x, 90 = +z); a measured sea's directions are where the waves come *from*, compass bearings
// clockwise from true north (NDBC, CDIP). Every arrow is drawn the way its thing travels: its
// tail on the side it comes from.

const POINTS = ['N', 'NNE', 'NE', 'ENE', 'E', 'ESE', 'SE', 'SSE', 'S', 'SSW', 'SW', 'WSW', 'W', 'WNW', 'NW', 'NNW'];
const wrap = (deg) => ((deg % 360) + 360) % 360;
export const pointName = (bearing) => POINTS[Math.round(wrap(bearing) / 22.5) % 16];

// The compass bearing (degrees clockwise from north) of a horizontal world vector (x, z).
export function bearingOf(x, z) { return wrap(Math.atan2(-x, z) * 180 / Math.PI); }
// The horizontal world vector (x, z) of a compass bearing.
export function worldOf(bearing) { const b = bearing * Math.PI / 180; return [-Math.sin(b), Math.cos(b)]; }

// The wind: where it comes from (as sailors name winds) and where it blows toward.
export function windBearings(towardDeg) {
  const a = (towardDeg || 0) * Math.PI / 180;
  const toward = bearingOf(Math.cos(a), Math.sin(a));
  const from = wrap(toward + 180);
  return { from, toward, fromName: pointName(from), towardName: pointName(toward) };
}

// Which way the screen's "up" looks over the sea: the horizontal part of the camera's forward
// plus its up axis (looking level, forward; looking straight down, up; both lie along the same
// horizontal direction for any pitch in between). camera: a three.js camera, matrixWorld current.
export function cameraHeading(camera) {
  const m = camera.matrixWorld.elements; // columns: right, up, -forward
  const x = m[4] - m[8], z = m[6] - m[10];
  return Math.hypot(x, z) < 1e-9 ? 0 : bearingOf(x, z);
}

const SVG = 'http://www.w3.org/2000/svg';
const R = 26; // the rose's radius in the SVG's units (viewBox -32..32)
function el(name, attrs, parent) {
  const e = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}

// The compass rose, turned so that its top is the way the camera looks (the mark at the top):
// N/E/S/W, and arrows for the waves (a measured sea's mean direction) and the wind.
export class Compass {
  constructor() {
    this.svg = el('svg', { viewBox: '-32 -32 64 64', class: 'oc-rose', 'data-ui': 'compass-rose', role: 'img' });
    this.title = el('title', {}, this.svg);
    el('circle', { r: 31, class: 'oc-rose-disc' }, this.svg);
    el('path', { d: 'M0 -31.5 L-3.5 -26 L3.5 -26 Z', class: 'oc-rose-view' }, this.svg); // the way you look
    this.rose = el('g', { 'data-ui': 'compass-turn' }, this.svg);
    el('circle', { r: R - 4, class: 'oc-rose-ring' }, this.rose);
    for (let b = 45; b < 360; b += 90) { // the letters mark the quarters, ticks the points between
      el('line', { x1: 0, y1: -(R - 8), x2: 0, y2: -(R - 4), class: 'oc-rose-tick', transform: `rotate(${b})` }, this.rose);
    }
    this.north = el('circle', { cx: 0, cy: -(R + 1), r: 1.6, class: 'oc-rose-north', 'data-ui': 'compass-n' }, this.rose);
    this.labels = [];
    for (const [b, t] of [[0, 'N'], [90, 'E'], [180, 'S'], [270, 'W']]) {
      const g = el('g', { transform: `rotate(${b}) translate(0 ${-(R - 10)})` }, this.rose);
      const txt = el('text', { class: `oc-rose-label${t === 'N' ? ' oc-rose-label-n' : ''}`, 'text-anchor': 'middle', 'dominant-baseline': 'central', 'data-dir': t }, g);
      txt.textContent = t;
      this.labels.push({ g, txt, b });
    }
    this.wind = this.arrow('oc-rose-wind', 'compass-wind', 10);
    this.waves = this.arrow('oc-rose-waves', 'compass-waves', 10);
    this.heading = null;
    this.setHeading(0);
    this.setWind(null);
    this.setWaves(null);
  }
  // An arrow from the rim on the "from" side through the centre to the "toward" side.
  arrow(cls, ui, len) {
    const g = el('g', { class: cls, 'data-ui': ui }, this.rose);
    el('line', { x1: 0, y1: len, x2: 0, y2: -len + 4 }, g);
    el('path', { d: `M0 ${-len - 2} L-4 ${-len + 5} L4 ${-len + 5} Z` }, g);
    return g;
  }
  // heading: the compass bearing the camera looks along (screen up).
  setHeading(heading) {
    if (this.heading !== null && Math.abs(wrap(heading - this.heading + 180) - 180) < 0.2) return;
    this.heading = heading;
    this.rose.setAttribute('transform', `rotate(${(-heading).toFixed(2)})`);
    // the letters stay upright as the rose turns
    for (const l of this.labels) l.txt.setAttribute('transform', `rotate(${(heading - l.b).toFixed(2)})`);
    this.updateTitle();
  }
  // toward: the bearing the wind blows toward (null: no arrow).
  setWind(toward) {
    this.windToward = toward;
    this.wind.style.display = toward === null ? 'none' : '';
    if (toward !== null) this.wind.setAttribute('transform', `rotate(${toward.toFixed(2)})`);
    this.updateTitle();
  }
  // from: the bearing the waves come from (null: no arrow).
  setWaves(from) {
    this.wavesFrom = from;
    this.waves.style.display = from === null ? 'none' : '';
    if (from !== null) this.waves.setAttribute('transform', `rotate(${wrap(from + 180).toFixed(2)})`);
    this.updateTitle();
  }
  updateTitle() {
    if (!this.title) return;
    const parts = [`looking ${pointName(this.heading ?? 0)} (${Math.round(this.heading ?? 0)}°)`];
    if (this.wavesFrom !== null && this.wavesFrom !== undefined) parts.push(`waves from ${Math.round(this.wavesFrom)}°`);
    if (this.windToward !== null && this.windToward !== undefined) parts.push(`wind from ${Math.round(wrap(this.windToward + 180))}°`);
    this.title.textContent = `Compass: ${parts.join(', ')}`;
  }
}

// The directional spectrum as a polar plot (a 2-D canvas): north up, east right, each band and
// direction of the summary's grid a sector at the bearing the waves come FROM (as buoy plots
// show it, and as "from 285°" reads), at a radius proportional to frequency (0 at the centre),
// with rings labelled in periods. Colour: a log scale from the peak down to 1/1000 of it
// (30 dB: a wind sea a tenth of the swell's density still shows), viridis (its lightness rises
// with the value, so it reads in grey too).

export const LOG_DECADES = 3;
// viridis, 9 stops (matplotlib's table at 0, 1/8, …, 1)
const VIRIDIS = [[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141], [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]];
export function colourAt(t) {
  const x = Math.min(1, Math.max(0, t)) * (VIRIDIS.length - 1), i = Math.min(VIRIDIS.length - 2, Math.floor(x)), u = x - i;
  return VIRIDIS[i].map((c, k) => Math.round(c + (VIRIDIS[i + 1][k] - c) * u));
}
export const colourGradient = () => `linear-gradient(to right, ${VIRIDIS.map((c, i) => `rgb(${c.join(',')}) ${(100 * i / (VIRIDIS.length - 1)).toFixed(1)}%`).join(', ')})`;

// Cell edges around sorted centres: half way to each neighbour, the outer ones as far out as the
// neighbouring half-width.
function edges(c) {
  const n = c.length, e = new Array(n + 1);
  if (n === 1) return [c[0] * 0.9, c[0] * 1.1];
  for (let i = 1; i < n; i++) e[i] = (c[i - 1] + c[i]) / 2;
  e[0] = Math.max(0, c[0] - (c[1] - c[0]) / 2);
  e[n] = c[n - 1] + (c[n - 1] - c[n - 2]) / 2;
  return e;
}
// Each direction's sector [from, to] in degrees: half way to its neighbours round the circle.
function sectors(dirs) {
  const order = dirs.map((d, j) => [((d % 360) + 360) % 360, j]).sort((a, b) => a[0] - b[0]);
  const n = order.length, out = new Array(n);
  for (let k = 0; k < n; k++) {
    const [d, j] = order[k];
    if (n === 1) { out[j] = [d - 180, d + 180]; continue; }
    const prev = order[(k + n - 1) % n][0] - (k === 0 ? 360 : 0), next = order[(k + 1) % n][0] + (k === n - 1 ? 360 : 0);
    out[j] = [(prev + d) / 2, (d + next) / 2];
  }
  return out;
}
// A measured sea's own limits (docs/simulation.md): more than that is no summary of one.
const MAX_BANDS = 128, MAX_DIRECTIONS = 72;
const NICE_RIM = [0.1, 0.125, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6, 0.8, 1, 1.5, 2];
const RING_PERIODS = [30, 20, 10, 8, 6, 5, 4, 3, 2.5, 2, 1.5, 1, 0.5]; // round periods, the roundest first when crowded

// What the plot shows of a summary's polar grid: checked (sizes, finite, non-negative), the peak,
// and the frequency at the rim (the top of the band holding energy over the colour scale's floor).
export function polarModel(polar) {
  const f = polar?.f_hz, d = polar?.dir_from_deg, e = polar?.e;
  if (!Array.isArray(f) || !Array.isArray(d) || !Array.isArray(e) || !f.length || !d.length || e.length !== f.length) return null;
  if (f.length > MAX_BANDS || d.length > MAX_DIRECTIONS) return null; // (the daemon sends at most 32 x 36)
  if (!f.every((v, i) => Number.isFinite(v) && v > 0 && (i === 0 || v > f[i - 1])) || !d.every(Number.isFinite)) return null;
  let peak = 0, pi = 0, pj = 0;
  for (let i = 0; i < f.length; i++) {
    if (!Array.isArray(e[i]) || e[i].length !== d.length) return null;
    for (let j = 0; j < d.length; j++) {
      const v = e[i][j];
      if (!Number.isFinite(v) || v < 0) return null;
      if (v > peak) { peak = v; pi = i; pj = j; }
    }
  }
  const fe = edges(f);
  let top = 0;
  for (let i = 0; i < f.length; i++) if (e[i].some((v) => v >= peak * 10 ** -LOG_DECADES)) top = i;
  const rim = NICE_RIM.find((r) => r >= fe[top + 1] - 1e-9) ?? fe[f.length];
  return { f, d, e, fe, sec: sectors(d), peak, peakF: f[pi], peakDir: d[pj], rim };
}

// Draw model m into canvas (size: CSS pixels, square). Returns the axes, as the canvas's dataset
// also says them (cx, cy, r in CSS pixels; rim in Hz): a test reads where a value landed.
export function drawPolar(canvas, m, size) {
  const dpr = Math.min(window.devicePixelRatio || 1, 2);
  canvas.width = Math.round(size * dpr); canvas.height = Math.round(size * dpr);
  canvas.style.width = `${size}px`; canvas.style.height = `${size}px`;
  const g = canvas.getContext('2d');
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, size, size);
  const font = Math.max(10, Math.round(size / 26));
  const cx = size / 2, cy = size / 2, r = size / 2 - font - 6;
  const rad = (f) => r * Math.min(f, m.rim) / m.rim;
  const ang = (b) => (b - 90) * Math.PI / 180; // bearing (clockwise from north, north up) -> canvas angle
  g.fillStyle = 'rgb(14, 22, 34)';
  g.beginPath(); g.arc(cx, cy, r, 0, 2 * Math.PI); g.fill();
  // Spokes every 30° and rings at round periods inside the rim (about 4 of them, labelled),
  // light on the empty disc, under the cells.
  const rings = RING_PERIODS.filter((p) => 1 / p <= m.rim * 1.0001 && 1 / p >= m.rim * 0.15);
  const shown = [];
  for (const p of rings) { // thin out: at least a label and a half apart
    if (!shown.length || rad(1 / p) - rad(1 / shown[shown.length - 1]) >= font * 1.5) shown.push(p);
  }
  // The ring labels go along the spoke (of every 30°, between the N/E/S/W ones) with the least
  // energy under it, so they hide as little of the sea as they can.
  let spoke = 150, least = Infinity;
  for (let b = 30; b < 360; b += 30) {
    if (b % 90 === 0) continue;
    let sum = 0;
    for (let j = 0; j < m.d.length; j++) {
      const [a0, a1] = m.sec[j], off = ((b - a0) % 360 + 360) % 360;
      if (off <= a1 - a0) for (let i = 0; i < m.f.length; i++) sum += m.e[i][j];
    }
    if (sum < least - 1e-12) { least = sum; spoke = b; }
  }
  const grid = (spokes, ringStyle) => {
    g.lineWidth = 1;
    g.strokeStyle = spokes;
    for (let b = 0; b < 360; b += 30) {
      g.beginPath(); g.moveTo(cx, cy); g.lineTo(cx + r * Math.cos(ang(b)), cy + r * Math.sin(ang(b))); g.stroke();
    }
    g.strokeStyle = ringStyle;
    for (const p of shown) { g.beginPath(); g.arc(cx, cy, rad(1 / p), 0, 2 * Math.PI); g.stroke(); }
  };
  grid('rgba(255, 255, 255, 0.22)', 'rgba(255, 255, 255, 0.4)');
  const floor = m.peak * 10 ** -LOG_DECADES;
  for (let i = 0; i < m.f.length; i++) {
    const r0 = rad(m.fe[i]), r1 = rad(m.fe[i + 1]);
    if (r0 >= r) break;
    for (let j = 0; j < m.d.length; j++) {
      const v = m.e[i][j];
      if (!(v > floor)) continue;
      const [c0, c1, c2] = colourAt(Math.log10(v / m.peak) / LOG_DECADES + 1);
      g.fillStyle = `rgb(${c0},${c1},${c2})`;
      const [a0, a1] = m.sec[j];
      g.beginPath();
      g.arc(cx, cy, r1, ang(a0), ang(a1));
      g.arc(cx, cy, r0, ang(a1), ang(a0), true);
      g.closePath();
      g.fill();
    }
  }
  // The grid again over the cells, dark: a light line over the colours tinted them (a lilac ring
  // over the purple of the scale's foot read as a feature of the sea).
  grid('rgba(14, 22, 34, 0.5)', 'rgba(14, 22, 34, 0.6)');
  g.font = `${font - 1}px system-ui, sans-serif`; g.textAlign = 'center'; g.textBaseline = 'middle';
  for (const p of shown) {
    const rr = rad(1 / p);
    // the label on the ring at that spoke, on a dark patch so it reads over colour
    const t = `${p} s`, x = cx + rr * Math.cos(ang(spoke)), y = cy + rr * Math.sin(ang(spoke)), w = g.measureText(t).width + 4;
    g.fillStyle = 'rgba(14, 22, 34, 0.75)'; g.fillRect(x - w / 2, y - font / 2, w, font);
    g.fillStyle = '#e8f1f8'; g.fillText(t, x, y);
  }
  g.strokeStyle = 'rgba(232, 241, 248, 0.8)'; g.lineWidth = 1.2;
  g.beginPath(); g.arc(cx, cy, r, 0, 2 * Math.PI); g.stroke();
  g.font = `600 ${font}px system-ui, sans-serif`;
  for (const [b, t] of [[0, 'N'], [90, 'E'], [180, 'S'], [270, 'W']]) {
    g.fillStyle = t === 'N' ? '#ff8a7a' : '#e8f1f8';
    g.fillText(t, cx + (r + font / 2 + 3) * Math.cos(ang(b)), cy + (r + font / 2 + 3) * Math.sin(ang(b)));
  }
  Object.assign(canvas.dataset, { cx: cx.toFixed(2), cy: cy.toFixed(2), r: r.toFixed(2), rim: String(m.rim) });
  return { cx, cy, r, rim: m.rim };
}

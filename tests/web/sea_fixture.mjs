// A measured sea's summary as the daemon broadcasts it (`sea` in hello and its broadcasts), made
// here from a known sea: a swell from 285° at 12.5 s and a wind sea from 200° at 5 s, on NDBC's
// frequency bands (0.005 Hz apart to 0.1 Hz, then 0.01 Hz) and 10° directions. For the web tests
// and screenshots, which inject it through window.oceandTest.sea until a daemon sends one.
export const SWELL = { fromDeg: 285, tpS: 12.5, hsM: 2.0, s: 12 };
export const WIND_SEA = { fromDeg: 200, tpS: 5, hsM: 1.1, s: 3 };

// cos^2s spreading about `from` (normalised per degree) times a Gaussian peak in frequency.
function part(f, dirs, p) {
  const fp = 1 / p.tpS, sig = 0.07 * fp + 0.004;
  const d = dirs.map((t) => Math.max(0, Math.cos((t - p.fromDeg) * Math.PI / 360)) ** (2 * p.s));
  const dn = d.reduce((a, b) => a + b, 0) * (dirs[1] - dirs[0]);
  return f.map((x) => d.map((v) => Math.exp(-0.5 * ((x - fp) / sig) ** 2) * v / dn));
}

export function ndbcLikeSummary({ version = 1 } = {}) {
  const f = [];
  for (let x = 0.04; x < 0.1001; x += 0.005) f.push(Number(x.toFixed(3)));
  for (let x = 0.11; x < 0.2901; x += 0.01) f.push(Number(x.toFixed(3)));
  const dirs = Array.from({ length: 36 }, (_, j) => 10 * j);
  const df = f.map((x, i) => ((f[i + 1] ?? x + (x - f[i - 1])) - (f[i - 1] ?? x - (f[i + 1] - x))) / 2);
  const m0 = (e) => e.reduce((a, row, i) => a + row.reduce((b, v) => b + v, 0) * df[i] * 10, 0);
  const scale = (e, hs) => { const k = (hs / 4) ** 2 / m0(e); return e.map((r) => r.map((v) => v * k)); };
  const sw = scale(part(f, dirs, SWELL), SWELL.hsM), ws = scale(part(f, dirs, WIND_SEA), WIND_SEA.hsM);
  const e = sw.map((r, i) => r.map((v, j) => Number((v + ws[i][j]).toPrecision(4))));
  return {
    version, source: 'NDBC 46026', time: '2026-12-01T20:40:00Z',
    hs_m: Number((4 * Math.sqrt(m0(e))).toFixed(2)), tp_s: SWELL.tpS, dir_from_deg: SWELL.fromDeg, spread_deg: 30,
    captured: 0.97, fit_note: null, depth_m: 52, convention: 'from_clockwise_north',
    polar: { f_hz: f, dir_from_deg: dirs, e },
  };
}

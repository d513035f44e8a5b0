// One-click seas (shared: each is one `set`) and views (local: time of day only).
//
// Sea presets are named after the Beaufort scale. Wind speeds are mid-range values of
// the WMO Beaufort scale (m/s at 10 m: Bft 1 0.3–1.5, Bft 3 3.4–5.4, Bft 5 8.0–10.7,
// Bft 8 17.2–20.7, Bft 10 24.5–28.4; WMO-No. 306 / Manual on Marine Meteorological
// Services, WMO-No. 558). The fetch is chosen so that the JONSWAP significant wave
// height the daemon computes (Hasselmann et al. 1973 fetch laws, capped at the fully
// developed sea) matches the WMO "probable wave height" for that force (0.1, 0.6,
// 2, 5.5, 9 m): integrating the daemon's spectrum gives Hs 0.07, 0.59, 2.0, 5.6 and
// 9.4 m. The patch must hold the peak wavelength (2, 18, 58, 148, 242 m) and resolve
// it: 128 m for light air, 512 m for gale and storm. Choppiness stays at 1, the
// first-order Lagrangian (Gerstner) displacement; spectrum, amplitude and gamma are
// the JONSWAP defaults, so a preset always gives the same sea.
// Cascades (docs/simulation.md, Cascades): the fewest that carry the spectrum down to
// the small-wave cutoff (0.5 m) at the default N = 256. Cascade c's patch is
// L / 3.543^c and holds waves down to 4 of its samples (patch / 64), so the finest
// cascade's shortest wave is 0.16 m for L = 128 and 0.32 m for 256 with 3 cascades,
// and 0.64 m for 512 with 3 (too coarse) but 0.18 m with 4: gale and storm take 4.
const COMMON = { spectrum: 'jonswap', amplitude: 1, gamma: 3.3, choppiness: 1 };
export const SEA_PRESETS = [
  { name: 'calm', label: 'calm', beaufort: 'Beaufort 1, light air', probableHs: 0.1,
    params: { ...COMMON, wind_speed: 1.5, fetch: 100, patch_size: 128, cascades: 3 } },
  { name: 'breeze', label: 'breeze', beaufort: 'Beaufort 3, gentle breeze', probableHs: 0.6,
    params: { ...COMMON, wind_speed: 4.5, fetch: 100, patch_size: 256, cascades: 3 } },
  { name: 'fresh', label: 'fresh', beaufort: 'Beaufort 5, fresh breeze', probableHs: 2,
    params: { ...COMMON, wind_speed: 9.4, fetch: 100, patch_size: 256, cascades: 3 } },
  { name: 'gale', label: 'gale', beaufort: 'Beaufort 8, gale', probableHs: 5.5,
    params: { ...COMMON, wind_speed: 19, fetch: 200, patch_size: 512, cascades: 4 } },
  { name: 'storm', label: 'storm', beaufort: 'Beaufort 10, storm', probableHs: 9,
    params: { ...COMMON, wind_speed: 26.5, fetch: 300, patch_size: 512, cascades: 4 } },
].map((p) => ({ ...p, help: `${p.beaufort}: wind ${p.params.wind_speed} m/s, fetch ${p.params.fetch} km, waves about ${p.probableHs} m (a shared change)` }));

// The whole Beaufort scale, one sea a force (the gallery's row, `make screenshots`; not in
// the panel, whose five presets above are the same seas at 3, 5, 8 and 10). Wind: the middle
// of the force's WMO range in m/s at 10 m (force 12 has no upper bound: 35 m/s, a little over
// its 32.7). Fetch: chosen as above for the WMO probable wave height, from the fetch law the
// presets above calibrate (Hs ~ 0.0212 U sqrt(fetch km), capped at the developed sea,
// ~0.030 U^2); forces 0-3 are developed seas at 100 km. `sea`: the WMO specification
// (WMO-No. 306 / the Beaufort scale's sea criterion), which the gallery captions quote.
const BEAUFORT_ROWS = [
  [0, 'calm', 0.1, 0, 100, 128, 3, 'Sea like a mirror'],
  [1, 'light air', 0.9, 0.1, 100, 128, 3, 'Ripples with the appearance of scales are formed, but without foam crests'],
  [2, 'light breeze', 2.5, 0.2, 100, 128, 3, 'Small wavelets, still short but more pronounced; crests have a glassy appearance and do not break'],
  [3, 'gentle breeze', 4.4, 0.6, 100, 256, 3, 'Large wavelets; crests begin to break; foam of glassy appearance; perhaps scattered white horses'],
  [4, 'moderate breeze', 6.7, 1, 50, 256, 3, 'Small waves, becoming longer; fairly frequent white horses'],
  [5, 'fresh breeze', 9.4, 2, 100, 256, 3, 'Moderate waves, taking a more pronounced long form; many white horses are formed; chance of some spray'],
  [6, 'strong breeze', 12.3, 3, 130, 256, 3, 'Large waves begin to form; the white foam crests are more extensive everywhere; probably some spray'],
  [7, 'near gale', 15.5, 4, 150, 512, 4, 'Sea heaps up and white foam from breaking waves begins to be blown in streaks along the direction of the wind'],
  [8, 'gale', 19, 5.5, 200, 512, 4, 'Moderately high waves of greater length; edges of crests begin to break into spindrift; the foam is blown in well-marked streaks along the direction of the wind'],
  [9, 'strong gale', 22.6, 7, 220, 512, 4, 'High waves; dense streaks of foam along the direction of the wind; crests of waves begin to topple, tumble and roll over; spray may affect visibility'],
  [10, 'storm', 26.5, 9, 300, 512, 4, 'Very high waves with long overhanging crests; the resulting foam, in great patches, is blown in dense white streaks along the direction of the wind; on the whole the surface of the sea takes on a white appearance; the tumbling of the sea becomes heavy and shock-like; visibility affected'],
  [11, 'violent storm', 30.6, 11.5, 320, 512, 4, 'Exceptionally high waves; the sea is completely covered with long white patches of foam lying along the direction of the wind; everywhere the edges of the wave crests are blown into froth; visibility affected'],
  [12, 'hurricane', 35, 14, 360, 512, 4, 'The air is filled with foam and spray; sea completely white with driving spray; visibility very seriously affected'],
];
export const BEAUFORT_SCALE = BEAUFORT_ROWS.map(([force, name, wind, probableHs, fetch, patch, cascades, sea]) => ({
  name: `beaufort-${force}`, force, beaufort: `Beaufort ${force}, ${name}`, probableHs, sea,
  params: { ...COMMON, wind_speed: wind, fetch, patch_size: patch, cascades },
}));

// Local solar time at latitude 40° N, sun declination +10° (sky.js): the sun is
// about 1° up at dawn and at sunset, 60° up at noon, 38° below the horizon at night.
export const VIEW_PRESETS = [
  { name: 'dawn', label: 'dawn', hour: 5.6 },
  { name: 'noon', label: 'noon', hour: 12 },
  { name: 'sunset', label: 'sunset', hour: 18.4 },
  { name: 'night', label: 'night', hour: 23 },
].map((p) => ({ ...p, help: `time of day ${p.hour} h (this screen only)` }));

export const DEFAULT_HOUR = 17;

// The sea preset the parameters currently match, if any.
export function matchSeaPreset(params) {
  return SEA_PRESETS.find((p) => Object.entries(p.params).every(([k, v]) => params[k] === v)) || null;
}

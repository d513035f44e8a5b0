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

// Sky, sun and moon for a local time of day and the shared sea's wind.
// The sky is three.js's Sky addon (Preetham, Shirley & Smits 1999, "A practical
// analytic model for daylight"), extended here with a cloud deck whose cover and
// darkness grow with the wind, and a dim night floor. It is rendered into a small
// cube map whenever the view changes; the visible dome, the water's reflections,
// its ambient light and the fog all read that one cube, so they always agree.
import * as THREE from 'three';
import { Sky } from 'three/examples/jsm/objects/Sky.js';

const LATITUDE = 40;      // degrees north: a mid-latitude sea
const DECLINATION = 10;   // degrees: the sun in late April / mid August
const CUBE_SIZE = 128;    // texels per cube face: the sky is smooth, the sun is drawn apart
// World axes: north = +z, east = -x, up = +y; the default camera looks south (-z),
// so the sun rises on the left, culminates ahead and sets on the right.
const NORTH = new THREE.Vector3(0, 0, 1), EAST = new THREE.Vector3(-1, 0, 0);

// Sun direction for a local solar time (hours), by the standard altitude/azimuth
// formulas of spherical astronomy (e.g. Meeus, Astronomical Algorithms, ch. 13).
export function sunDirection(hour, lat = LATITUDE, dec = DECLINATION) {
  const r = Math.PI / 180, H = (hour - 12) * 15 * r, phi = lat * r, d = dec * r;
  const sinAlt = Math.sin(phi) * Math.sin(d) + Math.cos(phi) * Math.cos(d) * Math.cos(H);
  const alt = Math.asin(Math.max(-1, Math.min(1, sinAlt)));
  const cosAz = (Math.sin(d) - sinAlt * Math.sin(phi)) / Math.max(Math.cos(alt) * Math.cos(phi), 1e-9);
  let az = Math.acos(Math.max(-1, Math.min(1, cosAz)));   // from north, 0..pi
  if (Math.sin(H) > 0) az = 2 * Math.PI - az;             // afternoon: west of south
  return dirFromAltAz(alt, az);
}

function dirFromAltAz(alt, az) {
  const h = Math.cos(alt);
  return NORTH.clone().multiplyScalar(Math.cos(az) * h).addScaledVector(EAST, Math.sin(az) * h).setY(Math.sin(alt)).normalize();
}

// Cloud cover and darkening from the wind (10 m wind speed, m/s). Not a physical
// model: fair-weather cumulus in light winds, a closed, dark deck by storm force
// (Beaufort 10, 24.5 m/s), which is what a sailor sees. fogDensity: the haze's extinction
// over the water (1/m; visibility = 3.912 / fogDensity, Koschmieder): some 40 km in fair
// weather, 9 km under a closed deck, and from force 9 the spray blown off the crests on top
// ("spray may affect visibility" at 9, "visibility affected" at 10-11, "very seriously
// affected" at 12): about 6 km at force 10, 1.3 km at 11, 0.5 km at 12.
export function weatherFromWind(u) {
  const s = (a, b, x) => { const t = Math.min(Math.max((x - a) / (b - a), 0), 1); return t * t * (3 - 2 * t); };
  const overcast = 0.12 + 0.88 * s(6, 24, u);
  const fogDensity = 0.00009 * (1 + 4 * overcast ** 2) + 0.0075 * s(21, 36, u) ** 3;
  return { overcast, darkening: 0.5 * s(10, 28, u), fogDensity };
}

const s01 = (a, b, x) => { const t = Math.min(Math.max((x - a) / (b - a), 0), 1); return t * t * (3 - 2 * t); };

// Direct sunlight after the atmosphere: Beer-Lambert with the Kasten & Young (1989)
// air mass and sea-level optical depths (Rayleigh ~0.05/0.10/0.24 at 680/550/440 nm,
// plus aerosol), so the sun reddens and dims toward the horizon.
function sunTransmittance(sinAlt, turbidity) {
  const altDeg = Math.asin(Math.max(sinAlt, -1)) * 180 / Math.PI;
  if (altDeg < -1) return new THREE.Color(0, 0, 0);
  const m = 1 / (Math.max(sinAlt, 0) + 0.50572 * Math.pow(Math.max(altDeg, 0) + 6.07995, -1.6364));
  const aerosol = 0.03 * turbidity;
  const t = [0.046, 0.097, 0.236].map((tr) => Math.exp(-(tr + aerosol) * m));
  const edge = s01(-1, 0.5, altDeg); // the disc sinks below the horizon
  return new THREE.Color(t[0] * edge, t[1] * edge, t[2] * edge);
}

// The Sky addon's shader with three edits: its sun disc is left out (the dome draws a
// sharp one; a disc in a 128² cube would be a blurred blob); its closing
// pow(texColor, 1/2.4), a display gamma (the addon's sunPosition is a unit vector, so
// vSunfade is 1 and the exponent always 1/2.4), is undone by day: our own tone curve and
// sRGB encoding follow (shaders.js toDisplay), and the two gammas in a row made the clear
// sky almost white (saturation ~0.1 at 40° from a noon sun, linear blue/red ~1.7 where
// Preetham's radiances give ~5). With the sun low the addon's curve is kept (uSkyLinear 0):
// the sunset and twilight looks were judged with it. Then its colour passes through
// weather() — night floor and cloud deck — before it is written.
function skyMaterial() {
  const src = Sky.SkyShader;
  const disc = 'L0 += ( vSunE * 19000.0 * Fex ) * sundisk;';
  const gamma = 'vec3 retColor = pow( texColor, vec3( 1.0 / ( 1.2 + ( 1.2 * vSunfade ) ) ) );';
  const out = 'gl_FragColor = vec4( retColor, 1.0 );';
  if (![disc, gamma, out].every((s) => src.fragmentShader.includes(s))) {
    throw new Error('three.js Sky shader changed: update web/src/sky.js');
  }
  const fragmentShader = src.fragmentShader
    .replace(disc, '')
    .replace(gamma, `vec3 retColor = mix( pow( texColor, vec3( 1.0 / ( 1.2 + ( 1.2 * vSunfade ) ) ) ), ${LINEAR_GAIN.toFixed(3)} * texColor, uSkyLinear );`)
    .replace('void main() {', `${WEATHER}\nvoid main() {`)
    .replace(out, 'gl_FragColor = vec4( weather( direction, retColor ), 1.0 );');
  return new THREE.ShaderMaterial({
    name: 'OceandSky',
    uniforms: {
      ...THREE.UniformsUtils.clone(src.uniforms),
      uSkyLinear: { value: 0 },
      uSkyGain: { value: new THREE.Color(1, 1, 1) },
      uNight: { value: new THREE.Color(0, 0, 0) },
      uOvercast: { value: 0 },
      uCloudLit: { value: new THREE.Color(1, 1, 1) },
      uTwilight: { value: new THREE.Color(0, 0, 0) },
      uTwilightSky: { value: new THREE.Color(0, 0, 0) },
      uCloudWarm: { value: new THREE.Color(0, 0, 0) },
    },
    vertexShader: src.vertexShader, fragmentShader, side: THREE.BackSide, depthWrite: false,
  });
}

// Preetham's radiance (texColor) kept linear is scaled by this, so the clear sky 30-60° from a
// high sun has about the luminance it had through the addon's gamma (blue much the same, red less).
const LINEAR_GAIN = 0.3;

const WEATHER = /* glsl */`
uniform float uSkyLinear; // 0: the addon's gamma-curved colour (low sun), 1: its linear radiance (day)
uniform vec3 uSkyGain;    // dims and tints the clear sky at night
uniform vec3 uNight;      // night floor: airglow and moonlit sky
uniform float uOvercast;  // 0 clear .. 1 closed deck
uniform vec3 uCloudLit;   // cloud base colour in the current light
uniform vec3 uTwilight;   // twilight glow at the horizon below the sun (0 by day and night)
uniform vec3 uTwilightSky; // the twilight sky's blue, over the whole dome
uniform vec3 uCloudWarm;  // low sun: light on the clouds toward it, reddened
// Twilight: Preetham's model has no sky once the sun is down; the glow is added as it is
// seen (Rozenberg 1966, Twilight, ch. 1): brightest on the horizon under the sun, falling
// off within a few degrees of elevation and some tens of degrees of azimuth, orange at the
// horizon and yellow then blue above it; the anti-solar side keeps a faint pink band.
vec3 twilight(vec3 dir) {
  float h = max(dir.y, 0.0);
  vec2 sh = normalize(vSunDirection.xz + vec2(1e-5, 0.0)), dh = normalize(dir.xz + vec2(1e-5, 0.0));
  float toward = 0.5 + 0.5 * dot(sh, dh);
  float band = exp(-h / 0.06), broad = exp(-h / 0.18);
  vec3 glow = uTwilight * (pow(toward, 3.0) * (band * vec3(1.0, 0.55, 0.25) + 0.35 * broad * vec3(1.0, 0.8, 0.55))
                         + 0.12 * pow(1.0 - toward, 2.0) * exp(-h / 0.15) * vec3(0.9, 0.6, 0.75));
  return glow + uTwilightSky * (0.6 + 0.4 * broad);
}
float oc_hash(vec2 p) { return fract(sin(dot(p, vec2(127.1, 311.7))) * 43758.5453); }
float oc_noise(vec2 p) {
  vec2 i = floor(p), f = fract(p);
  f = f * f * (3.0 - 2.0 * f);
  return mix(mix(oc_hash(i), oc_hash(i + vec2(1.0, 0.0)), f.x), mix(oc_hash(i + vec2(0.0, 1.0)), oc_hash(i + vec2(1.0, 1.0)), f.x), f.y);
}
float oc_fbm(vec2 p) {
  float s = 0.0, a = 0.5;
  for (int i = 0; i < 5; i++) { s += a * oc_noise(p); p = p * 2.03 + vec2(1.7, 9.2); a *= 0.5; }
  return s;
}
vec3 weather(vec3 dir, vec3 clear) {
  // Under a spreading deck the clear sky left in the gaps is dimmer too.
  vec3 c = clear * uSkyGain * (1.0 - 0.5 * uOvercast) + uNight * (0.55 + 0.45 * max(dir.y, 0.0)) + twilight(dir) * (1.0 - 0.6 * uOvercast);
  // A cloud layer seen as a plane overhead: cells shrink toward the horizon.
  float h = max(dir.y, 0.0);
  float n = oc_fbm(dir.xz / (h + 0.12) * 1.3);
  float cover = smoothstep(1.05 - uOvercast, 1.3 - uOvercast, n + 0.35);
  cover = max(cover, smoothstep(0.8, 1.0, uOvercast));
  float silver = pow(max(dot(dir, vSunDirection), 0.0), 6.0) * (1.0 - uOvercast);
  // Broken cloud: lumpy, lit toward the sun. A closed deck follows the CIE overcast
  // sky (Moon & Spencer 1942): L(h) = Lz (1 + 2 sin h) / 3, the horizon a third of the zenith.
  float deck = smoothstep(0.6, 1.0, uOvercast);
  vec3 cloud = uCloudLit * mix(0.78 + 0.3 * n + 0.8 * silver, (1.0 + 2.0 * h) / 3.0 * (0.9 + 0.2 * n), deck);
  // Low sun: clouds toward it are lit from the side and below, warmest at their thin edges
  // (forward scattering), and keep that light a little after sunset at their height.
  float az = 0.5 + 0.5 * dot(normalize(dir.xz + vec2(1e-5, 0.0)), normalize(vSunDirection.xz + vec2(1e-5, 0.0)));
  float edge = 1.0 - smoothstep(1.05 - uOvercast, 1.6 - uOvercast, n + 0.35);
  cloud += uCloudWarm * (0.25 + 2.2 * pow(az, 6.0) * (0.4 + edge)) * (1.0 - 0.7 * deck);
  return mix(c, cloud, cover * mix(0.55 + 0.45 * smoothstep(0.0, 0.1, dir.y), 1.0, deck));
}
`;

export class SkyModel {
  constructor(renderer) {
    this.renderer = renderer;
    this.sky = new THREE.Mesh(new THREE.BoxGeometry(1, 1, 1), skyMaterial());
    this.sky.frustumCulled = false;
    this.scene = new THREE.Scene();
    this.scene.add(this.sky);
    this.target = new THREE.WebGLCubeRenderTarget(CUBE_SIZE, {
      type: THREE.HalfFloatType, generateMipmaps: true,
      minFilter: THREE.LinearMipmapLinearFilter, magFilter: THREE.LinearFilter,
    });
    this.cubeCamera = new THREE.CubeCamera(0.1, 10, this.target);
    this.key = '';
    // What the water and dome shaders read (shared uniform objects).
    this.uniforms = {
      uEnv: { value: this.target.texture },
      uSunDir: { value: new THREE.Vector3(0, 1, 0) },     // the key light: sun by day, moon by night
      uSunColor: { value: new THREE.Color(1, 1, 1) },
      uDiscSize: { value: 0.99999 },                      // cos of the disc's angular radius
      uDiscGain: { value: 600 },                          // sun 600, moon 60 (shaders.js sunDisc)
      // The key light's irradiance on the water in units of its colour: its disc's radiance
      // times its solid angle, so the moon's is a tenth of the sun's as its disc is.
      uSunIrr: { value: 40 },
      uMoonDir: { value: new THREE.Vector3(0, 1, 0) },
      uMoonColor: { value: new THREE.Color(0, 0, 0) },
      uStars: { value: 0 },
      uExposure: { value: 1 },
      uGapProbe: { value: 0 },
    };
    this.state = null;
  }

  // hour: local solar time 0..24; wind: m/s. Re-renders the cube only on change.
  update(hour, wind) {
    const key = `${hour.toFixed(3)},${wind.toFixed(2)}`;
    if (key === this.key) return false;
    this.key = key;
    const sun = sunDirection(hour);
    const { overcast, darkening, fogDensity } = weatherFromWind(wind);
    const sinAlt = sun.y;
    const day = s01(-0.2, 0.08, sinAlt);        // 0 at night (sun 12° below), 1 in daylight
    const turbidity = 2 + 6 * overcast;
    const u = this.sky.material.uniforms;
    u.sunPosition.value.copy(sun);
    u.turbidity.value = turbidity;
    u.rayleigh.value = 2 + 1.5 * (1 - day);      // deeper blue at twilight
    u.mieCoefficient.value = 0.003 + 0.01 * overcast;
    u.mieDirectionalG.value = 0.75;
    // The addon's display gamma is undone as the sun climbs from 6° to 20° (skyMaterial).
    u.uSkyLinear.value = s01(6, 20, Math.asin(sinAlt) * 180 / Math.PI);
    u.uSkyGain.value.setRGB(0.08 + 0.92 * day, 0.1 + 0.9 * day, 0.2 + 0.8 * day).multiplyScalar(1 - darkening * 0.5);
    u.uNight.value.setRGB(0.006, 0.011, 0.026).multiplyScalar(1 - day);
    u.uOvercast.value = overcast;
    // Cloud base: lit by the sun (reddened when low) and the sky; moonlit grey at
    // night; greyer and darker as the wind rises.
    const sunT0 = sunTransmittance(sinAlt, turbidity);
    const lit = u.uCloudLit.value;
    lit.copy(sunT0).multiplyScalar(0.35 * s01(-0.05, 0.2, sinAlt));
    // The night floor is the moonlit sky's blue (as the dome's uNight), not a neutral grey:
    // grey clouds against the blue night sky read olive-brown.
    lit.r += 0.5 * s01(-0.1, 0.4, sinAlt) + 0.0075;
    lit.g += 0.52 * s01(-0.1, 0.4, sinAlt) + 0.0105;
    lit.b += 0.56 * s01(-0.1, 0.4, sinAlt) + 0.0200;
    // A high sun lights broken cloud from above and the side: brighter than the blue sky
    // around it (the sky is no longer washed out to near white, so clouds lit as before read
    // as grey-brown blots), sunlight plus the sky's blue fill, for a cloud's white; not a
    // closing deck, which stays grey.
    const high = s01(6, 20, Math.asin(sinAlt) * 180 / Math.PI) * (1 - s01(0.5, 0.95, overcast));
    lit.r += (1.3 * sunT0.r + 0.25) * high;
    lit.g += (1.3 * sunT0.g + 0.32) * high;
    lit.b += (1.3 * sunT0.b + 0.45) * high;
    lit.multiplyScalar(1 - darkening);
    // Twilight (sun from +4° to -18°): glow under the sun and the dome's blue, strongest
    // around sunset, fading with the depression (about e-fold per 4°).
    const altDeg = Math.asin(sinAlt) * 180 / Math.PI;
    const tw = s01(4, 0, altDeg) * Math.exp(-Math.max(-altDeg, 0) / 4.5) * s01(-18, -8, altDeg);
    u.uTwilight.value.setRGB(0.5, 0.38, 0.3).multiplyScalar(tw);
    u.uTwilightSky.value.setRGB(0.010, 0.022, 0.065).multiplyScalar(s01(3, -1, altDeg) * Math.exp(-Math.max(-altDeg, 0) / 5) * s01(-18, -6, altDeg));
    // Clouds at ~2 km see the sun until it is ~1.5° below the sea horizon: their warm light
    // is the sunlight through the air mass at that altitude.
    const warm = sunTransmittance(Math.sin((altDeg + 1.5) * Math.PI / 180), turbidity);
    u.uCloudWarm.value.copy(warm).multiplyScalar(1.4 * s01(12, 1, altDeg) * s01(-5, -0.5, altDeg) * (1 - darkening));
    // Key light: the sun, then the moon (fixed high in the south-east) once the sun is down.
    const sunT = sunTransmittance(sinAlt, turbidity);
    const hidden = 1 - s01(0.4, 0.85, overcast); // a closed deck hides the disc
    const moonDir = dirFromAltAz(38 * Math.PI / 180, 155 * Math.PI / 180);
    const night = 1 - s01(-0.12, 0.0, sinAlt);
    const U = this.uniforms;
    U.uMoonDir.value.copy(moonDir);
    U.uMoonColor.value.setRGB(0.035, 0.039, 0.046).multiplyScalar(night * hidden);
    if (sinAlt > -0.02) {
      U.uSunDir.value.copy(sun);
      U.uSunColor.value.copy(sunT).multiplyScalar(1.25 * hidden);
      U.uDiscSize.value = Math.cos(0.27 * Math.PI / 180);
      U.uDiscGain.value = 600;
      // Eased from 40 to 12 as the sun climbs past 3°..12°: with the full value the path of a
      // higher sun is a solid white band after the tone curve (a look: the curve cannot hold it).
      U.uSunIrr.value = 12 + 28 * (1 - s01(3, 12, Math.asin(sinAlt) * 180 / Math.PI));
    } else {
      U.uSunDir.value.copy(moonDir);
      U.uSunColor.value.copy(U.uMoonColor.value);
      U.uDiscSize.value = Math.cos(0.26 * Math.PI / 180);
      U.uDiscGain.value = 60;
      U.uSunIrr.value = 4;
    }
    U.uStars.value = night * (1 - s01(0.3, 0.8, overcast));
    // The eye adapts, but not fully: twilight and night stay darker than day. While the sun
    // is up the exposure is kept for the bright sky around it (as a camera would), so the
    // sunset sky keeps its colour and the water before it stays dark; it opens up at dusk.
    U.uExposure.value = 0.42 + 0.88 * (1 - s01(-0.1, 0.06, sinAlt)) + 2.2 * night;
    this.state = { hour, wind, sun: sun.toArray(), sunAltitudeDeg: Math.asin(sinAlt) * 180 / Math.PI, overcast, darkening, fogDensity };
    this.cubeCamera.update(this.renderer, this.scene);
    return true;
  }
}

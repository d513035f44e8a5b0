// GLSL for the water surface and the sky. Written in GLSL ES 1 style
// (attribute/varying/texture2D); three.js compiles it as GLSL ES 3 on WebGL2.

// Shared lighting: the sky cube rendered by sky.js (uEnv) is the one source for the
// dome, the reflections, the ambient light and the fog, so the horizon is seamless.
const SKY = /* glsl */`
uniform samplerCube uEnv;
uniform vec3 uSunDir;      // key light: the sun by day, the moon by night
uniform vec3 uSunColor;
uniform float uDiscSize;   // cos of the key light's angular radius
uniform float uDiscGain;   // the disc's radiance in units of the key light's colour
uniform vec3 uMoonDir;
uniform vec3 uMoonColor;
uniform float uStars;
uniform float uExposure;
uniform float uGapProbe;   // tests: paint sky and skirts magenta, so what shows in the seams is countable
vec3 skyColor(vec3 d, float lod) {
  d.y = max(d.y, 0.0);     // below the horizon: the horizon's haze
  return textureLod(uEnv, normalize(d + vec3(0.0, 1e-4, 0.0)), lod).rgb;
}
// Average light from the sky above: the cube's coarsest mip straight up.
vec3 skyAmbient() { return textureLod(uEnv, vec3(0.0, 1.0, 0.0), 6.0).rgb; }
float discMask(vec3 d, vec3 c, float cosR) { return smoothstep(cosR - 0.000015, cosR + 0.000005, dot(d, c)); }
vec3 sunDisc(vec3 d) {
  // The disc plus a narrow aureole; its colour is the transmitted sunlight.
  float s = max(dot(d, uSunDir), 0.0);
  // (the sun's 600: the disc must stand out of the sunset glow after the tone curve, even reddened
  // to a few % of its noon brightness.)
  return uSunColor * (uDiscGain * discMask(d, uSunDir, uDiscSize) + 0.6 * pow(s, 400.0) + 0.08 * pow(s, 40.0));
}
vec3 moonDisc(vec3 d) { return uMoonColor * 60.0 * discMask(d, uMoonDir, 0.99999); }
// ACES filmic fit (Narkowicz) and sRGB output: we write display-ready colour.
vec3 toDisplay(vec3 c) {
  c *= uExposure;
  c = clamp((c * (2.51 * c + 0.03)) / (c * (2.43 * c + 0.59) + 0.14), 0.0, 1.0);
  return pow(c, vec3(1.0 / 2.2));
}
`;

export const skyVertex = /* glsl */`
varying vec3 vDir;
void main() {
  vec4 wp = modelMatrix * vec4(position, 1.0);
  vDir = wp.xyz - cameraPosition;
  gl_Position = projectionMatrix * viewMatrix * wp;
  gl_Position.z = gl_Position.w; // on the far plane: never hides the sea
}`;

export const skyFragment = /* glsl */`
${SKY}
varying vec3 vDir;
float starHash(vec3 p) { return fract(sin(dot(p, vec3(12.9898, 78.233, 37.719))) * 43758.5453); }
void main() {
  vec3 d = normalize(vDir);
  vec3 c = skyColor(d, 0.0);
  if (d.y > 0.0) {
    c += sunDisc(d) + moonDisc(d);
    // Stars: a fixed random field on a fine direction grid, dimmed by haze near the horizon.
    vec3 g = floor(d * 700.0);
    float st = step(0.9985, starHash(g)) * starHash(g + 1.0);
    c += vec3(0.05) * st * uStars * smoothstep(0.05, 0.3, d.y);
  }
  gl_FragColor = uGapProbe > 0.5 ? vec4(1.0, 0.0, 1.0, 1.0) : vec4(toDisplay(c), 1.0);
}`;

// Displacement textures: RGBA = (dx, height, dz, jacobian), two frames (A older,
// B newer) mixed by uMix so 30 Hz data moves smoothly at display rate.
const SAMPLE = /* glsl */`
uniform sampler2D uDispA;
uniform sampler2D uDispB;
uniform float uMix;
uniform float uPatch;      // patch size in metres (texture period)
uniform float uTexel;      // 1 / texture size
vec4 dispAt(vec2 xz) {
  vec2 uv = xz / uPatch + 0.5 * uTexel;   // sample i sits at x = i * L / M
  return mix(textureLod(uDispA, uv, 0.0), textureLod(uDispB, uv, 0.0), uMix);
}
`;


// ---- Cascades (docs/web.md "Cascades"; kept apart from the rest on purpose) ----
// The finer cascades 1..3: each a periodic patch of side uCPatch[c-1] (the server's
// cascade_patch_sizes), streamed as height at its own LOD, tiled with its own period.
// They add to cascade 0 per vertex (height, where the mesh resolves them) and per
// pixel (slopes from forward differences of each cascade's height, each with its own
// step, faded out where a pixel covers more than a few of its samples: unresolved,
// they would only alias into sparkle).
const CASCADES = /* glsl */`
uniform sampler2D uC1A, uC1B, uC2A, uC2B, uC3A, uC3B; // (dx, height, dz, 0) of cascades 1..3, older / newer
uniform vec3 uCPatch;   // patch side of cascades 1..3, m
uniform vec3 uCTexel;   // 1 / texture size of cascades 1..3
uniform vec3 uCOn;      // 1 where a cascade has data, else 0
uniform float uMinCell, uLodPixel; // the mesh's finest cell (m) and cells per metre of distance
float cascadeH(sampler2D a, sampler2D b, vec2 xz, float L, float texel) {
  vec2 uv = xz / L + 0.5 * texel;
  return mix(textureLod(a, uv, 0.0).y, textureLod(b, uv, 0.0).y, uMix);
}
// Weight of cascade c for a sampling step 'step' (m, half a pixel's or a cell's width):
// 1 while its shortest waves (two samples of its texture) span several steps, 0 once a
// step reaches one sample. Unresolved, a cascade would alias into a lattice of its own
// period (seen from 1 km up with a gentler fade: squares of 72 m).
vec3 cascadeWeights(float step) {
  vec3 spacing = max(uCPatch * uCTexel, vec3(1e-6));
  return uCOn * (1.0 - smoothstep(vec3(0.35), vec3(1.0), vec3(step) / spacing));
}
// Summed height of the finer cascades at xz, each weighted by w.
float cascadesHeight(vec2 xz, vec3 w) {
  float h = 0.0;
  if (w.x > 0.0) h += w.x * cascadeH(uC1A, uC1B, xz, uCPatch.x, uCTexel.x);
  if (w.y > 0.0) h += w.y * cascadeH(uC2A, uC2B, xz, uCPatch.y, uCTexel.y);
  if (w.z > 0.0) h += w.z * cascadeH(uC3A, uC3B, xz, uCPatch.z, uCTexel.z);
  return h;
}
// Forward differences on the newer frame only: 3 texture reads per cascade instead of 8
// (software GL renders the page on the CPU; the small waves need no blending between frames).
vec2 cascadeSlope(sampler2D b, vec2 xz, float L, float texel, float footprint) {
  float e = max(L * texel, footprint);
  float c = textureLod(b, xz / L + 0.5 * texel, 0.0).y;
  return vec2(textureLod(b, (xz + vec2(e, 0.0)) / L + 0.5 * texel, 0.0).y - c,
              textureLod(b, (xz + vec2(0.0, e)) / L + 0.5 * texel, 0.0).y - c) / e;
}
// Summed slopes (dh/dx, dh/dz) of the finer cascades for a pixel of this footprint (m).
vec2 cascadesSlope(vec2 xz, float footprint) {
  vec3 w = cascadeWeights(footprint);
  vec2 s = vec2(0.0);
  if (w.x > 0.0) s += w.x * cascadeSlope(uC1B, xz, uCPatch.x, uCTexel.x, footprint);
  if (w.y > 0.0) s += w.y * cascadeSlope(uC2B, xz, uCPatch.y, uCTexel.y, footprint);
  if (w.z > 0.0) s += w.z * cascadeSlope(uC3B, xz, uCPatch.z, uCTexel.z, footprint);
  return s;
}
`;

export const waterVertex = /* glsl */`
${SAMPLE}
${CASCADES}
attribute float skirt;
#ifdef USE_INSTANCING
// Cells per side of the coarser of this patch and its neighbour, on each edge:
// (x = 0, x = 1, z = 0, z = 1). Where a neighbour is coarser, this patch's edge
// vertices between the neighbour's are put on the neighbour's straight edge, so the
// two meet exactly (no T-junction gap: choppy waves move vertices sideways, and a
// gap seen from above shows the sky as a bright seam or speck; skirts hang straight
// down and cannot hide it).
attribute vec4 aEdge;
#endif
uniform float uFadeNear, uFadeFar, uSkirtDepth, uStitch;
varying float vSkirt;
varying vec3 vWorld;
varying vec2 vGround;
varying float vHeight;
// Far away the grid is coarser than the waves: fade displacement out (the
// fragment shader keeps the small waves in the normals).
vec4 dispFaded(vec2 xz) { return dispAt(xz) * (1.0 - smoothstep(uFadeNear, uFadeFar, distance(xz, cameraPosition.xz))); }
void main() {
#ifdef USE_INSTANCING
  vec4 base = modelMatrix * instanceMatrix * vec4(position, 1.0);
#else
  vec4 base = modelMatrix * vec4(position, 1.0);
#endif
  vec2 xz = base.xz;
  vec4 d = dispFaded(xz);
#ifdef USE_INSTANCING
  float g = 0.0, t = 0.0;
  vec2 along = vec2(0.0);
  if (position.x == 0.0) { g = aEdge.x; t = position.z; along = vec2(0.0, 1.0); }
  else if (position.x == 1.0) { g = aEdge.y; t = position.z; along = vec2(0.0, 1.0); }
  else if (position.z == 0.0) { g = aEdge.z; t = position.x; along = vec2(1.0, 0.0); }
  else if (position.z == 1.0) { g = aEdge.w; t = position.x; along = vec2(1.0, 0.0); }
  float f = fract(t * g); // exact: t = i / 2^a, g = 2^b
  if (g > 0.0 && f > 0.0 && uStitch > 0.5) {
    float cell = instanceMatrix[0][0] / g;  // the neighbour's cell, metres
    vec2 a = xz - along * (f * cell);       // its vertices, bit-identical to its own
    d = mix(dispFaded(a), dispFaded(a + along * cell), f);
  }
#endif
  vec3 p = vec3(xz.x + d.x, d.y - skirt * uSkirtDepth, xz.y + d.z);
  // Finer cascades' heights where the mesh's cells resolve them (cascades block): a
  // cell is about uLodPixel x the distance (ocean.js layout), never below uMinCell.
  float camDist = distance(vec3(xz.x, 0.0, xz.y), cameraPosition);
  float cell = max(uMinCell, uLodPixel * camDist);
  p.y += (1.0 - smoothstep(uFadeNear, uFadeFar, camDist)) * cascadesHeight(xz, cascadeWeights(0.5 * cell));
  vWorld = p;
  vSkirt = skirt;
  vGround = xz;
  vHeight = d.y;
  gl_Position = projectionMatrix * viewMatrix * vec4(p, 1.0);
}`;

// Foam (whitecaps), kept apart from the rest of the water shading. Coverage comes from
// the server's shared `foam` field (0..1, field 6, usually at a coarser LOD than the
// surface; two frames mixed by uMix like the displacement), or, when the field is not
// streamed, from the Jacobian as before. Detail is procedural, in world metres on the
// undisplaced (Lagrangian) points, so it rides the orbital motion with the water:
// a domain-warped fractal noise is thresholded by the coverage (fresh foam nearly solid
// with bubbles and holes, fading foam breaks up into patches and curved, torn threads
// instead of turning grey; no cells, no period), and from about 12 m/s the pattern is
// stretched along the wind into streaks (Beaufort 7+: "foam blown in streaks along the
// direction of the wind"). Octaves finer than the pixel footprint are replaced by their
// mean and widen the threshold instead, so it does not sparkle.
const FOAM = /* glsl */`
uniform sampler2D uFoamA;
uniform sampler2D uFoamB;
uniform float uFoamField;    // 1: the server's foam field is streamed; 0: from the Jacobian
uniform float uFoamTexel;    // 1 / foam texture size
uniform vec2 uFoamWind;      // unit vector the wind blows toward (x, z)
uniform float uFoamWindSpeed; // m/s
uniform float uFoam;         // overall strength (1)
uniform float uFoamRamp;     // > 0: coverage is a ramp along x over this many metres (pictures)
uniform float uFoamJc;       // the server's breaking threshold on J for this wind (ocean_foam.c)
uniform vec2 uFoamShift;     // metres: every foam lookup moved (tests: foam placed at random)
uniform float uFoamGain;     // the streamed field's scale to Monahan's coverage (ocean.js foamCoverage)
uniform float uFoamStreaks;  // 1: the wind's streaks (0: tests of where the field's foam lies)
float foamHash(vec2 p) {     // Hoskins' hash without sine: stable for large coordinates
  vec3 p3 = fract(vec3(p.xyx) * 0.1031);
  p3 += dot(p3, p3.yzx + 33.33);
  return fract((p3.x + p3.y) * p3.z);
}
float foamValueNoise(vec2 p) {
  vec2 i = floor(p), f = fract(p);
  f = f * f * (3.0 - 2.0 * f);
  return mix(mix(foamHash(i), foamHash(i + vec2(1.0, 0.0)), f.x),
             mix(foamHash(i + vec2(0.0, 1.0)), foamHash(i + vec2(1.0)), f.x), f.y);
}
// Worley noise: F1, distance to the nearest random point, and that point's own random value.
vec2 foamCells(vec2 p) {
  vec2 i = floor(p), f = fract(p);
  vec2 d = vec2(8.0, 0.0);
  for (int y = -1; y <= 1; y++) for (int x = -1; x <= 1; x++) {
    vec2 o = vec2(float(x), float(y));
    vec2 r = o + vec2(foamHash(i + o), foamHash(i + o + 17.3)) - f;
    float q = dot(r, r);
    if (q < d.x) d = vec2(q, foamHash(i + o + 41.9));
  }
  return vec2(sqrt(d.x), d.y);
}
// Octave at scale s metres, faded to its mean where a pixel covers more than s.
float foamOctave(vec2 q, float s, float px) {
  return mix(foamValueNoise(q / s), 0.5, smoothstep(0.25 * s, s, px));
}
// Fractal value noise from scale s (m) down, n octaves (at most 5), each turned by 37°
// and scaled by 0.47 (no common axis or period, so no grid shows): x = value (mean 0.5),
// y = the standard deviation of the octaves a pixel of footprint px no longer resolves,
// used to widen the threshold below (the pattern is averaged, not aliased).
vec2 foamFbm(vec2 q, float s, int n, float px) {
  const mat2 turn = mat2(0.8, 0.6, -0.6, 0.8);
  float sum = 0.0, norm = 0.0, lost = 0.0, amp = 1.0;
  for (int i = 0; i < 5; i++) {
    if (i >= n) break;
    float gone = smoothstep(0.25 * s, s, px);
    sum += amp * mix(foamValueNoise(q / s), 0.5, gone);
    lost += amp * amp * gone;
    norm += amp;
    q = turn * q + 19.7;
    s *= 0.47;
    amp *= 0.6;
  }
  return vec2(sum / norm, 0.29 * sqrt(lost) / norm);  // 0.29: std of one octave of value noise
}
float foamFieldAt(vec2 xz) {
  vec2 uv = xz / uPatch + 0.5 * uFoamTexel;
  return min(uFoamGain * mix(textureLod(uFoamA, uv, 0.0).r, textureLod(uFoamB, uv, 0.0).r, uMix), 1.0);
}
// The field seen far away: read at the hex-tiled offsets of hexSample (same lattice),
// so whitecaps do not print the patch lattice from above.
float foamFieldHex(vec2 xz) {
  vec3 w; vec2 v1, v2, v3;
  hexCells(xz, w, v1, v2, v3);
  float f = w.x * foamFieldAt(xz + hexHash(v1) * uPatch) + w.y * foamFieldAt(xz + hexHash(v2) * uPatch)
          + w.z * foamFieldAt(xz + hexHash(v3) * uPatch);
  return f / max(w.x + w.y + w.z, 1e-3);
}
// Streaks (Beaufort 7 on: "white foam from breaking waves begins to be blown in streaks
// along the direction of the wind"; 8: "well-marked streaks"; 10: "dense white streaks ...
// the surface takes on a white appearance"). The foam the crests left upwind is drawn out
// downwind and gathered into lines where the wind's rolls converge: lines some 30 m long
// and 1-3 m across, in two families (see below), fed by the field read over 40 m upwind,
// so the streaks lie behind the breaking the stream carries (every viewer sees the same).
// Denser and wider with the wind; below the pixel the lines give way to their mean cover,
// so far off they do not sparkle.
float foamStreaks(vec2 xz, float px) {
  float on = smoothstep(13.0, 18.0, uFoamWindSpeed) * uFoamStreaks;
  if (on <= 0.0) return 0.0;
  vec2 w = uFoamWind, across = vec2(-w.y, w.x);
  vec2 q = vec2(dot(xz, w), dot(xz, across));
  float supply = 0.0;
  for (int k = 0; k < 4; k++) supply += foamFieldAt(xz - w * (4.0 + 12.0 * float(k)));
  supply = smoothstep(0.01, 0.12, 0.25 * supply);
  float dense = smoothstep(15.0, 34.0, uFoamWindSpeed);
  // Each family: the mid-level crossings of a noise in the across coordinate alone, which
  // wander slowly (a coarse noise bends them), so lines run on along the wind and never
  // close into loops; a coarser noise along the wind breaks them into lengths.
  float v1 = q.y / 2.5 + 2.5 * foamValueNoise(q / vec2(70.0, 30.0));
  float v2 = q.y / 1.1 + 2.0 * foamValueNoise(q / vec2(30.0, 12.0) + 9.1);
  float r1 = 1.0 - 2.0 * abs(foamValueNoise(vec2(v1, 0.5)) - 0.5);
  float r2 = 1.0 - 2.0 * abs(foamValueNoise(vec2(v2, 7.5)) - 0.5);
  float th1 = mix(0.8, 0.45, dense), th2 = mix(0.88, 0.6, dense);
  float l1 = mix(smoothstep(th1, th1 + 0.12, r1), 1.0 - th1, smoothstep(0.5, 2.5, px));
  float l2 = mix(smoothstep(th2, th2 + 0.08, r2), 1.0 - th2, smoothstep(0.15, 0.6, px));
  l1 *= smoothstep(0.3, 0.55, foamValueNoise(q / vec2(45.0, 8.0) + 3.1));
  l2 *= smoothstep(0.35, 0.6, foamValueNoise(q / vec2(18.0, 4.0) + 5.7));
  return on * supply * mix(0.7, 1.0, dense) * max(l1, 0.8 * l2);
}
// Coverage 0..1 at xz. The server's field (about 4 m a cell) says where foam lives and
// for how long: it is the persistence and the calibrated coverage. Where in that cell it
// lies comes from the Jacobian at the surface grid's full resolution (1-2 m): foam sits on
// the squeezed water of the crests (J < 1) and thins where the surface is stretched, and
// water breaking now (J below the server's threshold uFoamJc) is foam at once. Foam left
// behind trails downwind: the field is also read a few metres upwind (streaks, stronger
// with the wind). uFoamShift moves every foam lookup (tests: foam placed at random).
float foamCover(vec2 xz, float jac, float hex, float px, out float young) {
  xz += uFoamShift;
  young = 0.0;
  if (uFoamRamp > 0.0) return clamp(xz.x / uFoamRamp + 0.5, 0.0, 1.0);
  float fresh = smoothstep(uFoamJc + 0.06, uFoamJc - 0.12, jac);
  young = fresh;
  if (uFoamField < 0.5) return max(fresh, smoothstep(0.7, 0.25, jac));
  float f = foamFieldAt(xz);
  young = max(fresh, smoothstep(0.75, 0.98, f));   // the field near 1: broken this second
  if (hex > 0.0) f = mix(f, foamFieldHex(xz), hex);
  float trail = 1.5 + 2.5 * smoothstep(8.0, 20.0, uFoamWindSpeed);   // metres per tap
  if (hex < 1.0) for (int k = 1; k <= 3; k++) f = max(f, foamFieldAt(xz - uFoamWind * (trail * float(k))) * (1.0 - 0.24 * float(k)) * (1.0 - hex));
  float crest = smoothstep(1.2, 0.7, jac);
  // Streak foam too is spread thin where the surface stretches (J > 1) and gathered where it
  // is squeezed, as foam collects where the surface converges.
  return clamp(max(max(f * mix(0.2, 1.35, crest), fresh), foamStreaks(xz, px) * mix(0.75, 1.1, crest)), 0.0, 1.0);
}
// How much of the pixel is foam (0..1), with texture; px = pixel footprint in metres.
// A domain-warped fractal noise (swirled like foam stirred by the breaking, many scales,
// nothing periodic) is thresholded by the coverage: fresh foam (cover near 1) is nearly
// solid, with holes and bubbles; as it fades it breaks into patches and then into thin
// marbled threads, the contour lines of a second warped noise, torn in places.
float foamAmount(vec2 xz, float cover, float px) {
  if (cover < 0.01) return 0.0;
  // Far away the pattern is below a pixel: what is left is about its mean.
  float far = 0.8 * smoothstep(0.3, 0.8, cover) + 0.12 * smoothstep(0.05, 0.3, cover);
  if (px > 4.0) return far;
  vec2 w = uFoamWind, across = vec2(-w.y, w.x);
  float streak = 1.0 + 3.0 * smoothstep(12.0, 24.0, uFoamWindSpeed);  // elongation along the wind
  vec2 q = vec2(dot(xz, w) / streak, dot(xz, across));
  // Patchiness over metres: ragged edges, not the field's bilinear blobs.
  float n = foamFbm(q + 41.7, 4.0, 2, px).x;
  float cv = clamp(cover * (0.55 + 0.9 * n), 0.0, 1.0);
  // Swirls: the pattern is read through a warp of about half a metre.
  vec2 warp = vec2(foamFbm(q + 7.1, 1.8, 2, px).x, foamFbm(q + 93.2, 1.8, 2, px).x) - 0.5;
  vec2 p = q + 1.3 * warp;
  // Body: the part of the noise above a threshold that falls as coverage rises.
  vec2 b = foamFbm(p, 1.0, 5, px);
  float th = mix(0.68, 0.3, smoothstep(0.15, 0.95, cv));
  float body = smoothstep(th - 0.012 - b.y, th + 0.012 + b.y, b.x);
  // Lace: just outside a patch the foam frays into a net of bubble rims (the ridges of a
  // Worley noise about 0.2 m a cell) that thins out away from it, instead of cutting off;
  // below the pixel the net is its mean.
  float fray = smoothstep(th - 0.14 - b.y, th - 0.01, b.x) * (1.0 - body) * smoothstep(0.3, 0.6, cv);
  float net = fray > 0.0 ? mix(smoothstep(0.3, 0.46, foamCells(p / 0.2 + 3.7).x), 0.35, smoothstep(0.03, 0.12, px)) : 0.0;
  body = max(body, 0.85 * fray * fray * net);
  // Threads: bands around the mid level of two more noises (a coarse and a fine
  // network of curved lines, wider with coverage); an unresolved band counts its area.
  // Torn: threads thin out and break where a coarser noise is low.
  float tear = smoothstep(0.36, 0.58, foamFbm(q * vec2(0.6, 1.4) + 17.9, 1.6, 2, px).x);
  float tw = mix(0.012, 0.05, smoothstep(0.1, 0.7, cv)) * (0.5 + 0.8 * tear);
  vec2 l1 = foamFbm(p + 57.3, 1.2, 4, px), l2 = foamFbm(p + 11.9, 0.45, 3, px);
  float w1 = 0.006 + l1.y, w2 = 0.006 + l2.y;
  float thread = max((1.0 - smoothstep(tw - w1, tw + w1, abs(l1.x - 0.5))) * min(1.0, tw / w1),
                     0.8 * (1.0 - smoothstep(0.7 * tw - w2, 0.7 * tw + w2, abs(l2.x - 0.5))) * min(1.0, 0.7 * tw / w2));
  float a = max(body, thread * mix(0.4 + 0.6 * tear, 1.0, smoothstep(0.4, 0.8, cv)));
  // Dense foam is not flat: its thickness varies, and small holes and bubbles open in it,
  // round ones (Worley F1 against a random radius per bubble, mostly tiny) and ragged
  // ones (a fine noise's low values).
  vec2 h = foamFbm(p * 2.3 + 3.3, 0.5, 3, px);
  vec2 cell = foamCells(q / 0.1);
  float r = 0.4 * cell.y * cell.y * cell.y;
  float bub = mix(smoothstep(r - 0.1, r + 0.1, cell.x), 1.0, smoothstep(0.015, 0.08, px));
  float hole = smoothstep(0.28 - h.y - 0.02, 0.34 + h.y, h.x);
  a *= mix(1.0, (0.55 + 0.45 * bub) * (0.6 + 0.4 * hole) * (0.8 + 0.4 * h.x), smoothstep(0.35, 0.9, cv));
  // Thin old foam lets the water through.
  a *= smoothstep(0.05, 0.25, cv) * mix(0.7, 1.0, smoothstep(0.3, 0.65, cv));
  return mix(a, far, smoothstep(0.8, 4.0, px));
}

// Foam shaded as a rough white layer a few centimetres thick: Lambert under the sun and the
// sky, with its own relief (the slope of its thickness, from the screen-space derivatives
// of the amount), so dense foam shows lumps and the sun side of a crest is brighter than
// its lee. Thin foam lets the water through, a little green-blue.
vec3 foamShade(vec3 c, vec2 xz, float jac, float hex, vec3 n, float px, out float amount) {
  float young;
  float a = foamAmount(xz, foamCover(xz, jac, hex, px, young), px) * uFoam;
  amount = a;
  vec2 dxz = dFdx(xz), dyz = dFdy(xz), da = vec2(dFdx(a), dFdy(a)); // (before any branch)
  if (a <= 0.0) return c;
  float det = dxz.x * dyz.y - dxz.y * dyz.x;
  vec2 g = abs(det) > 1e-12 ? vec2(dyz.y * da.x - dxz.y * da.y, -dyz.x * da.x + dxz.x * da.y) / det : vec2(0.0);
  vec3 nf = normalize(n - vec3(g.x, 0.0, g.y) * 0.06 * (1.0 - smoothstep(0.05, 0.5, px)));
  float sun = max(dot(nf, uSunDir), 0.0) * step(0.0, uSunDir.y);
  vec3 amb = skyAmbient() * (0.75 + 0.25 * nf.y);
  // Body: the foam breaking now on a crest is thick, dense and bright; older foam behind it
  // (patches, streaks) is a thinner layer, greyer and more translucent, and the thin parts
  // of any foam sit in the shade of the thick (a soft self-shadow).
  vec3 lit = 0.85 * (amb * 1.3 + uSunColor * sun * 0.95) * mix(0.8, 1.08, young) * (0.86 + 0.14 * a);
  vec3 thin = lit * vec3(0.78, 0.92, 0.95);
  return mix(c, mix(thin, lit, a), a * mix(0.78, 0.97, young));
}
`;

export const waterFragment = /* glsl */`
${SKY}
${SAMPLE}
${CASCADES}
uniform sampler2D uSlopeA;
uniform sampler2D uSlopeB;
uniform float uHasSlope, uHasJac, uFogDensity;
uniform float uHexNear, uHexFar; // metres: from periodic normals to hex-tiled ones
uniform vec3 uDeep, uScatter;
uniform float uVar0, uVarBeyond; // slope variance per axis: cascade 0, the band beyond the finest cascade
uniform vec3 uCVar;              // ... and of cascades 1..3
uniform float uSunIrr;           // the sun's irradiance on the water in units of uSunColor
uniform float uDebugView;        // tests: 1 writes (foam amount, -J, height) instead of colour
varying vec3 vWorld;
varying vec2 vGround;
varying float vHeight;
varying float vSkirt;

vec3 surf(vec2 xz) { vec4 d = dispAt(xz); return vec3(xz.x + d.x, d.y, xz.y + d.z); }

// Far-field sample: slope (dh/dx, dh/dz) by forward differences over e, and height,
// from the newer frame only: 3 texture reads instead of 8 (this runs 3 times a pixel).
vec3 farSample(vec2 xz, float e) {
  vec4 c = textureLod(uDispB, xz / uPatch + 0.5 * uTexel, 0.0);
  vec4 x = textureLod(uDispB, (xz + vec2(e, 0.0)) / uPatch + 0.5 * uTexel, 0.0);
  vec4 z = textureLod(uDispB, (xz + vec2(0.0, e)) / uPatch + 0.5 * uTexel, 0.0);
  vec3 tx = vec3(e + x.x - c.x, x.y - c.y, x.z - c.z), tz = vec3(z.x - c.x, z.y - c.y, e + z.z - c.z);
  vec3 n = cross(tz, tx);
  return vec3(-n.xz / max(n.y, 1e-4), c.y);
}
vec2 hexHash(vec2 p) { return fract(sin(vec2(dot(p, vec2(127.1, 311.7)), dot(p, vec2(269.5, 183.3)))) * 43758.5453); }
// Far away the periodic patch shows as a lattice. There the slopes are read from the
// patch shifted by a random offset per cell of a triangular grid and blended with
// weights normalised to keep the variance (Heitz & Neyret 2018, "High-performance
// by-example noise using a histogram-preserving blending operator", sec. 3; slopes of a
// linear sea are Gaussian, so the blend has the same statistics). Wind direction is
// kept: offsets only, no rotations. The geometry stays periodic, so this is only used
// where single waves are no longer resolved (uHexNear..uHexFar).
// The hex tiling's cell around xz: its three lattice points and their barycentric
// weights (hexSample, and the foam's foamFieldHex, read at offsets hashed from them).
void hexCells(vec2 xz, out vec3 w, out vec2 v1, out vec2 v2, out vec2 v3) {
  vec2 uv = xz / (0.8 * uPatch) * 3.4641016;              // cells a little smaller than the patch
  vec2 sk = mat2(1.0, 0.0, -0.57735027, 1.15470054) * uv;  // skewed triangular grid
  vec2 id = floor(sk);
  vec3 t = vec3(fract(sk), 0.0);
  t.z = 1.0 - t.x - t.y;
  if (t.z > 0.0) { w = vec3(t.z, t.y, t.x); v1 = id; v2 = id + vec2(0.0, 1.0); v3 = id + vec2(1.0, 0.0); }
  else { w = vec3(-t.z, 1.0 - t.y, 1.0 - t.x); v1 = id + vec2(1.0); v2 = id + vec2(1.0, 0.0); v3 = id + vec2(0.0, 1.0); }
}
vec3 hexSample(vec2 xz, float e) {
  vec3 w; vec2 v1, v2, v3;
  hexCells(xz, w, v1, v2, v3);
  vec2 o1 = xz + hexHash(v1) * uPatch, o2 = xz + hexHash(v2) * uPatch, o3 = xz + hexHash(v3) * uPatch;
  vec3 s = w.x * farSample(o1, e) + w.y * farSample(o2, e) + w.z * farSample(o3, e);
  return s / max(length(w), 1e-3);   // (slope x, slope z, height)
}
${FOAM}

// Sun glitter from the slopes a pixel does not resolve (Bruneton, Neyret & Holzschuch 2010,
// "Real-time realistic ocean lighting using seamless transitions from geometry to BRDF",
// eq. 8-9 and 14): within a pixel the facets' slopes are Gaussian about the resolved normal
// n with variance s2 per axis, and the sun is reflected by those facing the half vector,
// with Smith's shadowing and masking.
float erfcApprox(float x) { return 2.0 * exp(-x * x) / (1.7724539 * (x + sqrt(x * x + 1.2732395))); }
float smithLambda(float mu, float s2) {
  mu = clamp(mu, 1e-3, 0.9999);
  float v = mu / sqrt(2.0 * s2 * (1.0 - mu * mu));
  return max(0.0, (exp(-v * v) - v * 1.7724539 * erfcApprox(v)) / (2.0 * v * 1.7724539));
}
float sunGlitter(vec3 n, vec3 V, vec3 L, float s2) {
  vec3 H = normalize(L + V);
  float zH = max(dot(H, n), 1e-3), zV = max(dot(V, n), 0.01), zL = max(dot(L, n), 0.01);
  float t2 = (1.0 - zH * zH) / (zH * zH);
  float p = exp(-0.5 * t2 / s2) / (6.2831853 * s2);
  float Fh = 0.02 + 0.98 * pow(1.0 - max(dot(V, H), 0.0), 5.0);
  return Fh * p / (4.0 * zV * zH * zH * zH * zH * (1.0 + smithLambda(zL, s2) + smithLambda(zV, s2)));
}

void main() {
  vec2 xz = vGround;
  // Central differences of the displaced surface. The step grows with the pixel
  // footprint: a difference over 2e is the mean slope over 2e, i.e. a box filter,
  // which keeps distant water from sparkling.
  vec2 fw = fwidth(xz);
  float e = max(uPatch * uTexel, 0.5 * max(fw.x, fw.y));
  vec3 tx = surf(xz + vec2(e, 0.0)) - surf(xz - vec2(e, 0.0));
  vec3 tz = surf(xz + vec2(0.0, e)) - surf(xz - vec2(0.0, e));
  vec3 n = normalize(cross(tz, tx));
  if (uHasSlope > 0.5) {
    vec2 uv = xz / uPatch + 0.5 * uTexel;
    vec2 s = mix(texture(uSlopeA, uv).xy, texture(uSlopeB, uv).xy, uMix);
    n = normalize(vec3(-s.x, 1.0, -s.y));
  }
  float hex = smoothstep(uHexNear, uHexFar, distance(vWorld, cameraPosition));
  float height = vHeight;
  if (hex > 0.0) {
    vec3 hs = hexSample(xz, e);
    n = normalize(mix(n, normalize(vec3(-hs.x, 1.0, -hs.y)), hex));
    height = mix(height, hs.z, hex);
  }
  // Finer cascades: their slopes add to cascade 0's (cascades block).
  float fp = 0.5 * max(fw.x, fw.y);
  vec2 cs = cascadesSlope(xz, fp);
  vec2 s0 = -n.xz / max(n.y, 1e-3);          // n is along (-dh/dx, 1, -dh/dz)
  n = normalize(vec3(-(s0.x + cs.x), 1.0, -(s0.y + cs.y)));
  // What the pixel does not resolve goes into the BRDF as slope variance: the band finer
  // than the finest cascade, the cascades faded out for this footprint, and the octaves of
  // cascade 0 the difference over 2e averages away (a Phillips-like sea holds about the
  // same slope variance in each octave of wavenumber).
  float spacing0 = uPatch * uTexel;
  float lost0 = clamp(log2(e / spacing0) / max(log2(1.0 / uTexel) - 3.0, 1.0), 0.0, 1.0);
  float s2 = uVarBeyond + lost0 * uVar0 + dot(vec3(1.0) - cascadeWeights(fp), uCVar);
  s2 = max(s2, 2e-4);
  // Jacobian of the horizontal map: < 1 where crests fold, which is where foam forms.
  float jac = (tx.x * tz.z - tz.x * tx.z) / (4.0 * e * e);
  if (uHasJac > 0.5) jac = dispAt(xz).w;

  float dist = distance(vWorld, cameraPosition);
  vec3 V = normalize(cameraPosition - vWorld);
  if (dot(n, V) < 0.0) n = normalize(n + V * (0.01 - dot(n, V))); // back-facing: bend toward viewer
  vec3 L = uSunDir;
  vec3 R = reflect(-V, n);
  R.y = abs(R.y);

  // Fresnel averaged over the unresolved facets (Bruneton et al. 2010, the fit of their
  // sec. 4.2, meanFresnel): a rough sea reflects less at grazing angles than a mirror, as
  // the facets that face the viewer reflect little and those that face away are hidden.
  float sV = sqrt(s2);
  float F = 0.02 + 0.98 * pow(1.0 - max(dot(n, V), 0.0), 5.0 * exp(-2.69 * sV)) / (1.0 + 22.7 * pow(sV, 1.5));
  // Reflection of the same sky, blurred by the unresolved slopes: the reflected ray spreads
  // by twice the slope's deviation (a cube texel is 1/81 rad at 128 per face).
  vec3 refl = skyColor(R, clamp(log2(163.0 * sqrt(s2)), 0.0, 5.0));
  // Water body: deep colour lit by the sky and the key light, plus light scattered
  // through thin crests toward the viewer.
  // The sky light a facet gathers depends on where it faces (the cube's blurriest level in
  // the normal's direction), so the slopes show in the body even under an even sky.
  vec3 amb = skyAmbient();
  vec3 ambN = mix(amb, skyColor(n, 6.0), 0.6);
  float diff = max(dot(n, L), 0.0);
  vec3 light = ambN * 1.6 + uSunColor * diff * 0.7;
  vec3 body = uDeep * light;
  // Bubbles left in the squeezed water of the crests scatter light back up (turquoise).
  body += uScatter * amb * 1.2 * smoothstep(1.05, 0.6, jac);
  // (Far away the height is hex-tiled too: the crests would print the lattice back.)
  float crest = clamp(height * 0.25 + 0.3, 0.0, 1.0);
  body += uScatter * crest * (uSunColor * pow(max(dot(V, -L) * 0.5 + 0.5, 0.0), 3.0) * 0.6 + amb * 0.9);
  vec3 c = mix(body, refl, F);
  // Glitter: the sun (or moon) in the facets of the unresolved slopes.
  c += uSunColor * uSunIrr * sunGlitter(n, V, L, s2) * step(0.0, L.y);
  // Foam: the server's shared field shaped by the Jacobian (FOAM above), lit.
  float foamA, foamJ = jac;
  if (uFoamShift != vec2(0.0)) { // (tests) the crest signal moves with the foam
    vec2 q = xz + uFoamShift;
    vec3 qx = surf(q + vec2(e, 0.0)) - surf(q - vec2(e, 0.0)), qz = surf(q + vec2(0.0, e)) - surf(q - vec2(0.0, e));
    foamJ = (qx.x * qz.z - qz.x * qx.z) / (4.0 * e * e);
  }
  c = foamShade(c, xz, foamJ, hex, n, max(fw.x, fw.y), foamA);
  if (uDebugView > 0.5) {
    gl_FragColor = vec4(foamA, clamp(0.5 - 0.5 * (jac - 1.0), 0.0, 1.0), clamp(0.5 + 0.125 * height, 0.0, 1.0), 1.0);
    return;
  }
  // Aerial perspective into the horizon colour.
  float fog = 1.0 - exp(-dist * uFogDensity);
  // The haze takes the horizon's colour in the direction of view near the horizon,
  // and the horizon's average looking down: the horizon's detail (clouds) would fan
  // out as rays around the nadir.
  vec3 hazeAvg = 0.25 * (skyColor(vec3(1.0, 0.0, 0.0), 3.0) + skyColor(vec3(-1.0, 0.0, 0.0), 3.0)
                       + skyColor(vec3(0.0, 0.0, 1.0), 3.0) + skyColor(vec3(0.0, 0.0, -1.0), 3.0));
  vec3 haze = mix(skyColor(vec3(-V.x, 0.0, -V.z) + vec3(1e-4, 0.0, 0.0), 0.0), hazeAvg, smoothstep(0.05, 0.4, V.y));
  c = mix(c, haze, fog);
  gl_FragColor = uGapProbe > 0.5 && vSkirt > 0.0 ? vec4(1.0, 0.0, 1.0, 1.0) : vec4(toDisplay(c), 1.0);
}`;

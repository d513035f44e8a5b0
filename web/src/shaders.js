// GLSL for the water surface and the sky. Written in GLSL ES 1 style
// (attribute/varying/texture2D); three.js compiles it as GLSL ES 3 on WebGL2.

// Shared lighting: one analytic sky, used for the dome, for reflections and for fog,
// so the horizon is seamless.
const SKY = /* glsl */`
uniform vec3 uSunDir;
uniform vec3 uSunColor;
vec3 skyColor(vec3 d) {
  float y = max(d.y, 0.0);
  vec3 zenith  = vec3(0.07, 0.22, 0.52);
  vec3 horizon = vec3(0.62, 0.74, 0.86);
  vec3 c = mix(horizon, zenith, pow(y, 0.45));
  float s = max(dot(d, uSunDir), 0.0);
  c += uSunColor * (0.35 * pow(s, 10.0) + 0.9 * pow(s, 180.0));
  return c;
}
vec3 sunDisc(vec3 d) {
  float s = max(dot(d, uSunDir), 0.0);
  return uSunColor * 40.0 * smoothstep(0.99985, 0.99995, s);
}
// ACES filmic fit (Narkowicz) and sRGB output: we write display-ready colour.
vec3 toDisplay(vec3 c) {
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
void main() {
  vec3 d = normalize(vDir);
  vec3 c = skyColor(d) + sunDisc(d);
  if (d.y < 0.0) c = skyColor(vec3(d.x, 0.0, d.z)); // below the horizon: haze
  gl_FragColor = vec4(toDisplay(c * 1.05), 1.0);
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

export const waterVertex = /* glsl */`
${SAMPLE}
attribute float skirt;
uniform float uFadeNear, uFadeFar, uSkirtDepth;
varying vec3 vWorld;
varying vec2 vGround;
varying float vHeight;
void main() {
#ifdef USE_INSTANCING
  vec4 base = modelMatrix * instanceMatrix * vec4(position, 1.0);
#else
  vec4 base = modelMatrix * vec4(position, 1.0);
#endif
  vec2 xz = base.xz;
  // Far away the grid is coarser than the waves: fade displacement out (the
  // fragment shader keeps the small waves in the normals).
  float fade = 1.0 - smoothstep(uFadeNear, uFadeFar, distance(xz, cameraPosition.xz));
  vec4 d = dispAt(xz) * fade;
  vec3 p = vec3(xz.x + d.x, d.y - skirt * uSkirtDepth, xz.y + d.z);
  vWorld = p;
  vGround = xz;
  vHeight = d.y;
  gl_Position = projectionMatrix * viewMatrix * vec4(p, 1.0);
}`;

export const waterFragment = /* glsl */`
${SKY}
${SAMPLE}
uniform sampler2D uSlopeA;
uniform sampler2D uSlopeB;
uniform float uHasSlope, uHasJac, uFogDensity, uFoam;
uniform vec3 uDeep, uScatter;
varying vec3 vWorld;
varying vec2 vGround;
varying float vHeight;

vec3 surf(vec2 xz) { vec4 d = dispAt(xz); return vec3(xz.x + d.x, d.y, xz.y + d.z); }

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
  // Jacobian of the horizontal map: < 1 where crests fold, which is where foam forms.
  float jac = (tx.x * tz.z - tz.x * tx.z) / (4.0 * e * e);
  if (uHasJac > 0.5) jac = dispAt(xz).w;

  float dist = distance(vWorld, cameraPosition);
  vec3 V = normalize(cameraPosition - vWorld);
  if (dot(n, V) < 0.0) n = normalize(n + V * (0.01 - dot(n, V))); // back-facing: bend toward viewer
  vec3 L = uSunDir;
  vec3 R = reflect(-V, n);
  R.y = abs(R.y);

  float F = 0.02 + 0.98 * pow(1.0 - max(dot(n, V), 0.0), 5.0);
  vec3 refl = skyColor(R);
  // Water body: deep colour lit by the sun and sky, plus light scattered
  // through thin crests toward the viewer.
  float diff = max(dot(n, L), 0.0);
  vec3 body = uDeep * (0.35 + 0.65 * diff);
  float crest = clamp(vHeight * 0.25 + 0.3, 0.0, 1.0);
  body += uScatter * crest * pow(max(dot(V, -L) * 0.5 + 0.5, 0.0), 3.0) * 0.6;
  body += uScatter * 0.15 * crest;
  vec3 c = mix(body, refl, F);
  // Sun glints: sharp Blinn-Phong lobe, widened with distance (unresolved waves).
  vec3 H = normalize(L + V);
  float shin = mix(900.0, 140.0, clamp(dist / 2500.0, 0.0, 1.0));
  c += uSunColor * pow(max(dot(n, H), 0.0), shin) * (shin / 60.0) * F * 1.6;
  // Foam where the surface folds.
  float foam = smoothstep(0.7, 0.25, jac) * 0.9 * uFoam;
  c = mix(c, vec3(0.82, 0.86, 0.88) * (0.55 + 0.45 * diff) + 0.12, foam);
  // Aerial perspective into the horizon colour.
  float fog = 1.0 - exp(-dist * uFogDensity);
  c = mix(c, skyColor(vec3(-V.x, 0.0, -V.z)), fog);
  gl_FragColor = vec4(toDisplay(c), 1.0);
}`;

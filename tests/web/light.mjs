// Light measured as a user sees it: the luminance of screenshot pixels around the points
// where world directions from the camera land on the canvas (window.oceandTest.project).
// Used by test_web.mjs (glitter, twilight) and handy while tuning the sky and water.

// World point at distance d from cam in the direction of azimuth az (radians, atan2(z, x))
// and elevation el (radians).
export function along(cam, az, el, d = 1000) {
  return [cam[0] + d * Math.cos(el) * Math.cos(az), cam[1] + d * Math.sin(el), cam[2] + d * Math.cos(el) * Math.sin(az)];
}

// Mean luminance (0..255, Rec. 709 weights on the sRGB values) of boxes of (2 half + 1)²
// pixels around each point's projection, from one screenshot; also returns how many
// points were on screen.
export async function luminanceAt(page, points, half = 3) {
  const png = await page.screenshot({ type: 'png', timeout: 240000 });
  return page.evaluate(async ({ b64, points, half }) => {
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const c = document.createElement('canvas');
    c.width = img.width; c.height = img.height;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0);
    const sx = img.width / document.getElementById('ocean').clientWidth, sy = img.height / document.getElementById('ocean').clientHeight;
    let sum = 0, n = 0, on = 0;
    const each = [];
    for (const p of points) {
      const q = window.oceandTest.project(p);
      if (!q) continue;
      const x = Math.round(q[0] * sx), y = Math.round(q[1] * sy);
      if (x - half < 0 || y - half < 0 || x + half >= img.width || y + half >= img.height) continue;
      on++;
      const d = g.getImageData(x - half, y - half, 2 * half + 1, 2 * half + 1).data;
      let s1 = 0;
      for (let i = 0; i < d.length; i += 4) { const l = 0.2126 * d[i] + 0.7152 * d[i + 1] + 0.0722 * d[i + 2]; sum += l; s1 += l; n++; }
      each.push(Math.round(s1 / (d.length / 4)));
    }
    return { mean: n ? sum / n : NaN, on, each };
  }, { b64: png.toString('base64'), points, half });
}

// Glitter: the water below the sun against the water 20° of azimuth to either side (the
// brighter side counts), at 1.5°..9° below the horizon as seen from cam.
export async function glitterRatio(page, cam, sun) {
  const az = Math.atan2(sun[2], sun[0]), rad = Math.PI / 180;
  const onWater = (a) => [1.5, 2.5, 3.5, 5, 7, 9].map((dep) => along(cam, a, -dep * rad, cam[1] / Math.tan(dep * rad)));
  const path = await luminanceAt(page, onWater(az), 2);
  const left = await luminanceAt(page, onWater(az - 20 * rad), 2);
  const right = await luminanceAt(page, onWater(az + 20 * rad), 2);
  return { path: path.mean, side: Math.max(left.mean, right.mean), ratio: path.mean / Math.max(left.mean, right.mean, 1e-3), on: [path.on, left.on, right.on], each: [path.each, left.each, right.each] };
}

// Twilight: the band 0.5°..4.5° above the horizon below the sun against the top of a view
// that looks at that horizon (24°..26° up: the orbit never looks higher than level), both
// over the sun's azimuth ± 20°.
export async function twilightRatio(page, cam, sun) {
  const az = Math.atan2(sun[2], sun[0]), rad = Math.PI / 180;
  const ring = (els) => els.flatMap((el) => [-20, -10, 0, 10, 20].map((da) => along(cam, az + da * rad, el * rad)));
  const band = await luminanceAt(page, ring([0.5, 1.5, 2.5, 3.5, 4.5]), 2);
  const top = await luminanceAt(page, ring([24, 25, 26]), 2);
  return { band: band.mean, top: top.mean, ratio: band.mean / Math.max(top.mean, 1e-3), on: [band.on, top.on] };
}

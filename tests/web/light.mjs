// Light measured as a user sees it: the luminance of screenshot pixels around the points
// where world directions from the camera land on the canvas (window.oceandTest.project).
// Used by test_web.mjs (glitter, twilight) and handy while tuning the sky and water.

// World point at distance d from cam in the direction of azimuth az (radians, atan2(z, x))
// and elevation el (radians).
export function along(cam, az, el, d = 1000) {
  return [cam[0] + d * Math.cos(el) * Math.cos(az), cam[1] + d * Math.sin(el), cam[2] + d * Math.cos(el) * Math.sin(az)];
}

// From ONE screenshot (a frame of software GL is slow): for each set of world points, the
// mean luminance (0..255, Rec. 709 weights on the sRGB values) of boxes of (2 half + 1)²
// pixels around the points' projections, how many points were on screen, each box's
// luminance and mean colour (rgb, 0..255). Returns { png, sets }.
export async function measureAt(page, sets, half = 3) {
  const png = await page.screenshot({ type: 'png', timeout: 240000 });
  const out = await page.evaluate(async ({ b64, sets, half }) => {
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const c = document.createElement('canvas');
    c.width = img.width; c.height = img.height;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0);
    const sx = img.width / document.getElementById('ocean').clientWidth, sy = img.height / document.getElementById('ocean').clientHeight;
    return sets.map((points) => {
      let sum = 0, n = 0, on = 0;
      const each = [], rgb = [];
      for (const p of points) {
        const q = window.oceandTest.project(p);
        if (!q) continue;
        const x = Math.round(q[0] * sx), y = Math.round(q[1] * sy);
        if (x - half < 0 || y - half < 0 || x + half >= img.width || y + half >= img.height) continue;
        on++;
        const d = g.getImageData(x - half, y - half, 2 * half + 1, 2 * half + 1).data;
        let s1 = 0, r = 0, gg = 0, b = 0;
        for (let i = 0; i < d.length; i += 4) { const l = 0.2126 * d[i] + 0.7152 * d[i + 1] + 0.0722 * d[i + 2]; sum += l; s1 += l; n++; r += d[i]; gg += d[i + 1]; b += d[i + 2]; }
        const k = d.length / 4;
        each.push(Math.round(s1 / k));
        rgb.push([r / k, gg / k, b / k]);
      }
      return { mean: n ? sum / n : NaN, on, each, rgb };
    });
  }, { b64: png.toString('base64'), sets, half });
  return { png, sets: out };
}

// One set of points: { mean, on, each } as above.
export async function luminanceAt(page, points, half = 3) {
  return (await measureAt(page, [points], half)).sets[0];
}

// Glitter: the water below the sun against the water 20° of azimuth to either side (the
// brighter side counts), at 1.5°..9° below the horizon as seen from cam.
export async function glitterRatio(page, cam, sun) {
  const az = Math.atan2(sun[2], sun[0]), rad = Math.PI / 180;
  const onWater = (a) => [1.5, 2.5, 3.5, 5, 7, 9].map((dep) => along(cam, a, -dep * rad, cam[1] / Math.tan(dep * rad)));
  const { png, sets: [path, left, right] } = await measureAt(page, [onWater(az), onWater(az - 20 * rad), onWater(az + 20 * rad)], 2);
  return { png, path: path.mean, side: Math.max(left.mean, right.mean), ratio: path.mean / Math.max(left.mean, right.mean, 1e-3), on: [path.on, left.on, right.on], each: [path.each, left.each, right.each] };
}

// Twilight: the band 0.5°..4.5° above the horizon below the sun against the top of a view
// that looks at that horizon (24°..26° up: the orbit never looks higher than level), both
// over the sun's azimuth ± 20°.
export async function twilightRatio(page, cam, sun) {
  const az = Math.atan2(sun[2], sun[0]), rad = Math.PI / 180;
  const ring = (els) => els.flatMap((el) => [-20, -10, 0, 10, 20].map((da) => along(cam, az + da * rad, el * rad)));
  const { png, sets: [band, top] } = await measureAt(page, [ring([0.5, 1.5, 2.5, 3.5, 4.5]), ring([24, 25, 26])], 2);
  return { png, band: band.mean, top: top.mean, ratio: band.mean / Math.max(top.mean, 1e-3), on: [band.on, top.on] };
}

// Clear sky by day: the colour of the sky 8°..24° up, over the sun's azimuth ± 40°, at the
// points 30°..60° from the sun (HSV saturation (max - min) / max and blue / red of each
// 5×5 box). Clouds are white or grey by design, so the statistics are the upper quartiles
// (the clear sky between them); a washed-out sky has no saturated quarter.
export async function skyColour(page, cam, sun) {
  const az = Math.atan2(sun[2], sun[0]), rad = Math.PI / 180;
  const pts = [8, 12, 16, 20, 24].flatMap((el) => [-40, -30, -20, -10, 0, 10, 20, 30, 40].map((da) => along(cam, az + da * rad, el * rad)))
    .filter((q) => {
      const v = [q[0] - cam[0], q[1] - cam[1], q[2] - cam[2]], n = Math.hypot(...v);
      const deg = Math.acos((v[0] * sun[0] + v[1] * sun[1] + v[2] * sun[2]) / n) / rad;
      return deg >= 30 && deg <= 60;
    });
  const { png, sets: [s] } = await measureAt(page, [pts], 2);
  const q3 = (xs) => { const a = [...xs].sort((x, y) => x - y); return a.length ? a[Math.floor(0.75 * (a.length - 1))] : NaN; };
  const sat = s.rgb.map(([r, g, b]) => (Math.max(r, g, b) - Math.min(r, g, b)) / Math.max(r, g, b, 1));
  const blue = s.rgb.map(([r, , b]) => b / Math.max(r, 1));
  return { png, on: s.on, points: pts.length, saturation: q3(sat), blueRed: q3(blue), mean: s.mean };
}

// How much does the sea repeat when seen from above? A real daemon, headless chromium,
// the camera looking straight down from the height at which a square view spans
// `--patches` × `--patches` patches; the luminance of the screenshot is correlated with
// itself shifted by one patch period (x and z), relative to zero lag:
//   rho(P) = <(L(p) - m)(L(p + P) - m)> / <(L(p) - m)^2>
// after removing trends longer than P (see detrend). 1 means the picture repeats exactly
// every patch; the issue asks for <= 0.3.
//   node tests/web/repetition.mjs --oceand build/oceand --web-root build/web [--query "&hex=0"]
//        [--patches 4] [--size 512] [--png out.png] [--height 400]
// Prints one JSON object per run.
import fs from 'node:fs';
import { parseArgs, freePort, startServer, launchBrowser, waitFor, sleep } from './harness.mjs';

const args = parseArgs(process.argv, { oceand: 'build/oceand', webRoot: 'build/web', query: '', patches: '4', size: '512', png: '', height: '', hour: '15', runs: '3' });
const FOV = 55; // web/src/main.js: the camera's vertical field of view, degrees

// Remove trends longer than the period (sky gradient, haze, the sun's side): subtract the
// mean over a P×P box. A P-periodic pattern is untouched by this (its box mean is constant).
export function detrend(lum, w, h, P) {
  const S = new Float64Array((w + 1) * (h + 1)); // summed-area table
  for (let y = 0; y < h; y++) for (let x = 0; x < w; x++) S[(y + 1) * (w + 1) + x + 1] = lum[y * w + x] + S[y * (w + 1) + x + 1] + S[(y + 1) * (w + 1) + x] - S[y * (w + 1) + x];
  const r = P >> 1, out = [];
  for (let y = r; y < h - r; y++) for (let x = r; x < w - r; x++) {
    const x0 = x - r, y0 = y - r, x1 = x0 + P, y1 = y0 + P;
    const m = (S[y1 * (w + 1) + x1] - S[y0 * (w + 1) + x1] - S[y1 * (w + 1) + x0] + S[y0 * (w + 1) + x0]) / (P * P);
    out.push(lum[y * w + x] - m);
  }
  return { lum: out, w: w - 2 * r, h: h - 2 * r };
}

// Luminance autocorrelation at lag (dx, dy) pixels over the overlap, relative to zero lag.
export function autocorrelation(lum, w, h, dx, dy) {
  let m = 0;
  for (const v of lum) m += v;
  m /= lum.length;
  let c0 = 0, c = 0, n = 0;
  for (const v of lum) c0 += (v - m) * (v - m);
  c0 /= lum.length;
  for (let y = 0; y + dy < h; y++) for (let x = 0; x + dx < w; x++) {
    c += (lum[y * w + x] - m) * (lum[(y + dy) * w + x + dx] - m); n++;
  }
  return c / n / c0;
}

const port = await freePort();
const server = await startServer({ oceand: args.oceand, webRoot: args.webRoot, port });
const browser = await launchBrowser();
try {
  const size = Number(args.size), k = Number(args.patches);
  const page = await browser.newPage({ viewport: { width: size, height: size } });
  // First load: learn the patch size, then place the camera.
  await page.goto(`http://127.0.0.1:${port}/?test=1&aa=0&ui=0${args.query}`);
  await waitFor(page, 'params', () => window.oceand.params !== null, null, 30000);
  const L = (await page.evaluate(() => window.oceand.params)).patch_size;
  const H = args.height ? Number(args.height) : (k * L) / (2 * Math.tan((FOV / 2) * Math.PI / 180));
  const lag = Math.round(L * size / (2 * H * Math.tan((FOV / 2) * Math.PI / 180)));
  // Offset by a third of a patch so patch corners are not at the picture's centre.
  const cx = L / 3, cz = L / 3;
  await page.goto(`http://127.0.0.1:${port}/?test=1&aa=0&ui=0&hour=${args.hour}&cam=${cx},${H},${cz + 0.01}&target=${cx},0,${cz}${args.query}`);
  await waitFor(page, 'rendering', () => window.oceand.connected && window.oceand.rendered > 3, null, 60000);
  const rhos = [];
  for (let r = 0; r < Number(args.runs); r++) {
    if (r) await sleep(1500); // another moment of the sea
    const png = await page.screenshot({ type: 'png' });
    if (args.png && r === 0) fs.writeFileSync(args.png, png);
    const lum = await page.evaluate(async (b64) => {
      const img = new Image();
      img.src = `data:image/png;base64,${b64}`;
      await img.decode();
      const c = document.createElement('canvas');
      c.width = img.width; c.height = img.height;
      const g = c.getContext('2d');
      g.drawImage(img, 0, 0);
      const d = g.getImageData(0, 0, c.width, c.height).data;
      const out = [];
      for (let i = 0; i < d.length; i += 4) out.push(0.2126 * d[i] + 0.7152 * d[i + 1] + 0.0722 * d[i + 2]);
      return out;
    }, png.toString('base64'));
    const d = detrend(lum, size, size, lag);
    const rx = autocorrelation(d.lum, d.w, d.h, lag, 0), rz = autocorrelation(d.lum, d.w, d.h, 0, lag);
    const half = (autocorrelation(d.lum, d.w, d.h, lag >> 1, 0) + autocorrelation(d.lum, d.w, d.h, 0, lag >> 1)) / 2;
    rhos.push({ rho: (rx + rz) / 2, rx, rz, half });
  }
  const med = (a) => [...a].sort((p, q) => p - q)[a.length >> 1];
  console.log(JSON.stringify({
    name: 'web_luminance_autocorrelation', query: args.query, patch_m: L, height_m: Number(H.toFixed(1)),
    lag_px: lag, size_px: size, hour: Number(args.hour),
    rho_patch: Number(med(rhos.map((x) => x.rho)).toFixed(3)),
    rho_patch_x: Number(med(rhos.map((x) => x.rx)).toFixed(3)), rho_patch_z: Number(med(rhos.map((x) => x.rz)).toFixed(3)),
    rho_half_patch: Number(med(rhos.map((x) => x.half)).toFixed(3)), runs: rhos.length,
  }));
  await page.close();
} finally {
  await browser.close().catch(() => {});
  await server.stop().catch(() => {});
}

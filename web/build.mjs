// Bundle the browser client into a static folder the daemon serves.
//   node build.mjs [outdir]      (default ../build/web)
// Output: index.html, style.css, app.js (main thread), worker.js (decoder worker).
// Everything is bundled: no CDN, nothing is fetched at run time.
import * as esbuild from 'esbuild';
import { copyFile, mkdir } from 'node:fs/promises';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
const outdir = path.resolve(process.argv[2] || path.join(here, '..', 'build', 'web'));

await mkdir(outdir, { recursive: true });
await esbuild.build({
  entryPoints: {
    app: path.join(here, 'src', 'main.js'),
    worker: path.join(here, 'src', 'worker.js'),
  },
  outdir,
  bundle: true,
  format: 'esm',
  target: ['es2020'],
  minify: true,
  sourcemap: true,
  logLevel: 'warning',
});
await copyFile(path.join(here, 'src', 'style.css'), path.join(outdir, 'style.css'));
// index.html last: it is the make target, so it is only fresh when everything else is.
await copyFile(path.join(here, 'index.html'), path.join(outdir, 'index.html'));
console.log(`web: built ${outdir}`);

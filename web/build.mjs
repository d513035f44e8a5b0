// Bundle the browser client into a static folder the daemon serves.
//   node build.mjs [outdir] [kernels.wasm]   (defaults ../build/web, ../build/wasm/oc_kernels.wasm)
// Output: index.html, style.css, app.js (main thread), worker.js (decoder worker).
// Everything is bundled: no CDN, nothing is fetched at run time. The worker's WebAssembly kernels
// (built by `make`, mk/wasm.mk) are embedded as bytes: `import bytes from 'oc-kernels.wasm'`.
import * as esbuild from 'esbuild';
import { copyFile, mkdir } from 'node:fs/promises';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
const outdir = path.resolve(process.argv[2] || path.join(here, '..', 'build', 'web'));
const kernels = path.resolve(process.argv[3] || path.join(here, '..', 'build', 'wasm', 'oc_kernels.wasm'));
const kernelsPlugin = {
  name: 'oc-kernels',
  setup(build) {
    build.onResolve({ filter: /^oc-kernels\.wasm$/ }, () => ({ path: kernels }));
  },
};

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
  loader: { '.wasm': 'binary' },
  plugins: [kernelsPlugin],
});
await copyFile(path.join(here, 'src', 'style.css'), path.join(outdir, 'style.css'));
// index.html last: it is the make target, so it is only fresh when everything else is.
await copyFile(path.join(here, 'index.html'), path.join(outdir, 'index.html'));
console.log(`web: built ${outdir}`);

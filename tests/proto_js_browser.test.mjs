// proto_js_browser.test.mjs — the JavaScript decoder inside headless Chromium
// (node --test): the browser path (DecompressionStream('deflate-raw'), no node
// zlib) must give the same float32 bits as the C decoder on every deflate
// vector and reject every bad input with the listed code, and decode the temporal streams
// (codec 3) frame by frame with one DecoderState; all of it twice: with DecompressionStream,
// then with the WebAssembly inflater and prediction (proto/js/oc_wasm.js, build/wasm/). Skipped when no
// Chromium is installed.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, writeFileSync, mkdtempSync, rmSync, existsSync } from 'node:fs';
import { execFileSync } from 'node:child_process';
import { tmpdir } from 'node:os';
import { fileURLToPath } from 'node:url';
import { dirname, join } from 'node:path';

const root = join(dirname(fileURLToPath(import.meta.url)), '..');
const vdir = join(root, 'proto/vectors');
const chromium = ['/usr/bin/chromium', '/usr/bin/chromium-browser', '/usr/bin/google-chrome'].find(existsSync);

test('decoder in headless Chromium reproduces the vectors', { skip: !chromium && 'no chromium', timeout: 120000 }, () => {
  const manifest = JSON.parse(readFileSync(join(vdir, 'manifest.json'), 'utf8'));
  const b64 = (f) => readFileSync(join(vdir, f)).toString('base64');
  const good = manifest.vectors.filter((v) => v.tiles.every((t) => t.codec !== 2))
    .map((v) => ({ name: v.name, bin: b64(v.file), exp: b64(v.expected) }));
  const bad = manifest.bad.map((b) => ({ name: b.name, bin: b64(b.file), error: b.error }));
  // Temporal streams: frames in order through one DecoderState.
  const streams = manifest.streams.map((st) => ({ name: st.name,
    frames: st.frames.map((f) => ({ bin: b64(f.file), exp: f.expected && b64(f.expected), error: f.error })) }));
  const nStreamFrames = streams.reduce((c, st) => c + st.frames.length, 0);
  // The module has no imports: inline it as a classic module script without its `export`s.
  const lib = readFileSync(join(root, 'proto/js/oc_decode.js'), 'utf8').replace(/^export /gm, '')
    + readFileSync(join(root, 'proto/js/oc_wasm.js'), 'utf8').replace(/^export /gm, '');
  const wasmB64 = readFileSync(join(root, 'build/wasm/oc_kernels.wasm')).toString('base64'); // `make` builds it
  const page = `<!doctype html><pre id=out>running</pre><script type=module>
${lib.replace(/<\/script/g, '<\\/script')}
const good = ${JSON.stringify(good)}, bad = ${JSON.stringify(bad)}, streams = ${JSON.stringify(streams)}, wasmB64 = '${wasmB64}';
const ab = (s) => Uint8Array.from(atob(s), (c) => c.charCodeAt(0)).buffer;
const res = { ok: 0, fail: [] , node: typeof process !== 'undefined' };
async function runAll(pass) {
for (const v of good) {
  try {
    const f = await decodeFrame(ab(v.bin));
    const e = new Uint32Array(ab(v.exp));
    let k = 0, same = true;
    for (const t of f.tiles) { const u = new Uint32Array(t.samples.buffer); for (let i = 0; i < u.length; i++) same &&= u[i] === e[k++]; }
    if (same && k === e.length) res.ok++; else res.fail.push(pass + v.name + ': samples differ');
  } catch (err) { res.fail.push(pass + v.name + ': ' + err.message); }
}
for (const b of bad) {
  try { await decodeFrame(ab(b.bin)); res.fail.push(pass + b.name + ': accepted'); }
  catch (err) { if (err.code === b.error) res.ok++; else res.fail.push(pass + b.name + ': ' + err.code + ' != ' + b.error); }
}
for (const st of streams) {
  const state = new DecoderState();
  for (const [i, f] of st.frames.entries()) {
    try {
      const fr = await decodeFrame(ab(f.bin), { state });
      if (f.error) { res.fail.push(pass + st.name + ' ' + i + ': accepted'); continue; }
      const e = new Uint32Array(ab(f.exp));
      let k = 0, same = true;
      for (const t of fr.tiles) { const u = new Uint32Array(t.samples.buffer); for (let j = 0; j < u.length; j++) same &&= u[j] === e[k++]; }
      if (same && k === e.length) res.ok++; else res.fail.push(pass + st.name + ' ' + i + ': samples differ');
    } catch (err) { if (f.error && err.code === f.error) res.ok++; else res.fail.push(pass + st.name + ' ' + i + ': ' + err.message); }
  }
}
}
await runAll('streams: ');
// Again with the WebAssembly inflater and codec 3 prediction, as the web worker does once they have loaded.
const kernels = await loadKernels(ab(wasmB64));
if (!kernels) res.fail.push('the WebAssembly kernels did not load');
else { setInflateRaw(kernels.inflateRaw, { allTiles: true }); setTemporalKernel(kernels.temporal); await runAll('wasm: '); }
document.getElementById('out').textContent = 'RESULT' + JSON.stringify(res) + 'END';
</script>`;
  const dir = mkdtempSync(join(tmpdir(), 'oceand-proto-'));
  try {
    const file = join(dir, 'page.html');
    writeFileSync(file, page);
    const dom = execFileSync(chromium, ['--headless', '--no-sandbox', '--disable-gpu', `--user-data-dir=${join(dir, 'profile')}`,
      '--virtual-time-budget=20000', '--dump-dom', `file://${file}`], { encoding: 'utf8', timeout: 90000, stdio: ['ignore', 'pipe', 'ignore'] });
    const m = dom.match(/RESULT(.*?)END/);
    assert.ok(m, 'page did not finish: ' + dom.slice(0, 300));
    const res = JSON.parse(m[1].replace(/&quot;/g, '"').replace(/&amp;/g, '&').replace(/&lt;/g, '<').replace(/&gt;/g, '>'));
    assert.deepEqual(res.fail, []);
    assert.equal(res.ok, 2 * (good.length + bad.length + nStreamFrames)); // streams, then wasm
    assert.equal(res.node, false);
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

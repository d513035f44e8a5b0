// proto_js.test.mjs — the JavaScript decoder against proto/vectors/ (node --test).
// Every vector must decode to exactly the expected float32 bits (same as the
// C decoder), within its bound of the input; every bad input must be rejected
// with the listed code; control-message examples must carry their members.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, readdirSync, existsSync } from 'node:fs';
import { execFileSync } from 'node:child_process';
import { fileURLToPath } from 'node:url';
import { dirname, join } from 'node:path';
import { createRequire } from 'node:module';
import {
  decodeFrame, parseFrameHeader, setZstdDecompressor, DecoderState, FIELD_NAMES, PROTO_VERSION, SUBPROTOCOL,
  FrameJoiner, FrameError, FRAME_FLAG_PART,
} from '../proto/js/oc_decode.js';
import { mutateAndDecode } from './proto_js_mutate.mjs';

const root = join(dirname(fileURLToPath(import.meta.url)), '..');
const vdir = join(root, 'proto/vectors');
const manifest = JSON.parse(readFileSync(join(vdir, 'manifest.json'), 'utf8'));
const load = (name) => {
  const b = readFileSync(join(vdir, name));
  return b.buffer.slice(b.byteOffset, b.byteOffset + b.byteLength); // exact-size ArrayBuffer
};

// Codec 2 (zstd) needs fzstd, which web/ installs; without it those vectors must fail with 'unsupported'.
let haveZstd = false;
const fzstdPath = join(root, 'web/node_modules/fzstd');
if (existsSync(fzstdPath)) {
  const fzstd = createRequire(join(root, 'web/package.json'))('fzstd');
  setZstdDecompressor(fzstd.decompress);
  haveZstd = true;
}

test('constants', () => {
  assert.equal(PROTO_VERSION, manifest.protocol);
  assert.equal(SUBPROTOCOL, manifest.subprotocol);
  assert.deepEqual([...FIELD_NAMES], ['height', 'dx', 'dz', 'slope_x', 'slope_z', 'jacobian', 'foam']);
});

test('floating bodies: the BODY section of v13_bodies, exactly; none in the other vectors (PROTOCOL.md §3.5)', async () => {
  for (const v of manifest.vectors) {
    const header = parseFrameHeader(load(v.file));
    const want = v.bodies || [];
    assert.equal(header.bodies.length, want.length, `${v.name}: bodies`);
    header.bodies.forEach((b, i) => {
      const w = want[i];
      assert.equal(b.id, w.id); assert.equal(b.kind, w.kind); assert.equal(b.flags, w.flags);
      assert.equal(Math.round(b.throttle * 127), w.throttle); assert.equal(Math.round(b.rudder * 127), w.rudder);
      assert.equal(b.adrift, (w.flags & 1) !== 0); assert.equal(b.powered, (w.flags & 2) !== 0);
      for (const k of ['pos', 'quat', 'vel']) w[k].forEach((x, j) => assert.equal(b[k][j], Math.fround(x), `${k}[${j}]`));
    });
  }
  const v = manifest.vectors.find((x) => x.name === 'v13_bodies');
  assert.ok(v, 'no v13_bodies vector');
  const frame = await decodeFrame(load(v.file));
  assert.equal(frame.header.bodies.length, 3);
  assert.equal(frame.tiles.length, 1);
  const bad = new Uint8Array(load(v.file));
  bad[52] = 4; // four records in a section of three
  assert.throws(() => parseFrameHeader(bad), (e) => e.code === 'corrupt');
});

for (const [v, useNodeZlib] of manifest.vectors.flatMap((x) => [[x, true], [x, false]])) {
  const usesZstd = v.tiles.some((t) => t.codec === 2);
  test(`vector ${v.name} (${useNodeZlib ? 'node zlib' : 'DecompressionStream'})`, async () => {
    const buf = load(v.file);
    if (usesZstd && !haveZstd) {
      await assert.rejects(decodeFrame(buf, { useNodeZlib }), (e) => e.code === 'unsupported');
      return;
    }
    const expected = new Float32Array(load(v.expected));
    const input = new Float32Array(load(v.input));
    const header = parseFrameHeader(buf);
    for (const k of Object.keys(v.header)) assert.equal(header[k], v.header[k], `header.${k}`);
    const frame = await decodeFrame(buf, { useNodeZlib });
    for (const k of Object.keys(v.header)) assert.equal(frame.header[k], v.header[k], `header.${k}`);
    assert.equal(frame.tiles.length, v.tiles.length);
    frame.tiles.forEach((t, i) => {
      const m = v.tiles[i];
      assert.equal(t.fieldName, m.field);
      assert.equal(FIELD_NAMES[t.field], m.field);
      for (const k of ['lod', 'codec', 'tileX', 'tileZ', 'width', 'height', 'offset', 'scale']) assert.equal(t[k], m[k], k);
      assert.equal(t.cascade, m.cascade ?? 0, 'cascade');
      assert.equal(t.bound, Math.fround(m.bound));
      const want = expected.subarray(m.sampleOffset, m.sampleOffset + t.samples.length);
      const got = new Uint32Array(t.samples.buffer, t.samples.byteOffset, t.samples.length);
      const wantBits = new Uint32Array(want.buffer, want.byteOffset, want.length);
      assert.deepEqual(got, wantBits, `tile ${i}: float32 bits`);
      let maxErr = 0;
      for (let k = 0; k < t.samples.length; k++) maxErr = Math.max(maxErr, Math.abs(t.samples[k] - input[m.sampleOffset + k]));
      assert.ok(maxErr <= t.bound, `tile ${i}: max error ${maxErr} > bound ${t.bound}`);
    });
  });
}

for (const [b, useNodeZlib] of manifest.bad.flatMap((x) => [[x, true], [x, false]])) {
  test(`bad input ${b.name} -> ${b.error} (${useNodeZlib ? 'node zlib' : 'DecompressionStream'})`, async () => {
    const buf = load(b.file);
    await assert.rejects(decodeFrame(buf, { useNodeZlib }), (e) => {
      assert.equal(e.code, b.error, e.message);
      return true;
    });
  });
}

// Temporal streams (codec 3): one DecoderState per stream, frames in order; every frame decodes to the
// expected bits within its bound, or fails with the listed code (and then changes nothing).
for (const [st, useNodeZlib] of manifest.streams.flatMap((x) => [[x, true], [x, false]])) {
  test(`stream ${st.name} (${useNodeZlib ? 'node zlib' : 'DecompressionStream'})`, async () => {
    const state = new DecoderState();
    for (const [i, f] of st.frames.entries()) {
      if (f.error) {
        await assert.rejects(decodeFrame(load(f.file), { useNodeZlib, state }), (e) => {
          assert.equal(e.code, f.error, `frame ${i}: ${e.message}`);
          return true;
        });
        continue;
      }
      const frame = await decodeFrame(load(f.file), { useNodeZlib, state });
      assert.equal(frame.header.seq, f.seq);
      const expected = new Uint32Array(load(f.expected));
      const input = new Float32Array(load(f.input));
      assert.equal(frame.tiles.length, f.tiles.length);
      frame.tiles.forEach((t, k) => {
        const m = f.tiles[k];
        for (const key of ['lod', 'codec', 'tileX', 'tileZ', 'width']) assert.equal(t[key], m[key], key);
        const got = new Uint32Array(t.samples.buffer, t.samples.byteOffset, t.samples.length);
        assert.deepEqual(got, expected.subarray(m.sampleOffset, m.sampleOffset + got.length), `frame ${i} tile ${k}: float32 bits`);
        for (let j = 0; j < t.samples.length; j++) assert.ok(Math.abs(t.samples[j] - input[m.sampleOffset + j]) <= t.bound);
      });
    }
  });
}

test('a predicted frame without a DecoderState is a reference error', async () => {
  const f = manifest.streams.find((x) => x.name === 's01_chain').frames[1];
  await assert.rejects(decodeFrame(load(f.file)), (e) => e.code === 'reference');
});

test('random truncations and bit flips of a predicted frame are rejected or decode', async () => {
  const chain = manifest.streams.find((x) => x.name === 's01_chain').frames;
  const state = new DecoderState();
  for (const f of chain.slice(0, 5)) await decodeFrame(load(f.file), { state });
  // every mutation decodes against the same references (a failed frame changes nothing; a decoded
  // one adds seq 105's codes, which the next mutation of 105 may still use)
  await mutateAndDecode(load(chain[5].file), 777, (it) => ({ useNodeZlib: it % 4 < 2, state }), ['reference']);
});

// options.target: every stream decoded straight into one interleaved array (3 floats per sample,
// each tile its own region, rows padded) gives the same float32 bits as the tiles' own arrays.
test('options.target places the same bits as samples (strided, offset, padded rows)', async () => {
  const single = manifest.vectors.filter((v) => haveZstd || v.tiles.every((t) => t.codec !== 2))
    .map((v) => ({ name: v.name, frames: [{ file: v.file, seq: 0 }] }));
  assert.ok(single.some((v) => manifest.vectors.find((x) => x.name === v.name).tiles.some((t) => t.codec === 0)), 'no raw (codec 0) vector');
  for (const st of [...manifest.streams, ...single]) {
    const own = new DecoderState(), placed = new DecoderState();
    for (const f of st.frames) {
      if (f.error) continue;
      const a = await decodeFrame(load(f.file), { state: own });
      let arr = null;
      const regions = [];
      const b = await decodeFrame(load(f.file), {
        state: placed,
        target: (h, tiles) => {
          let size = 0;
          for (const t of tiles) { regions.push({ offset: size + 5, rowStride: 3 * t.width + 7 }); size += 5 + t.height * (3 * t.width + 7); }
          arr = new Float32Array(size);
          return tiles.map((t, i) => ({ array: arr, offset: regions[i].offset + 1, stride: 3, rowStride: regions[i].rowStride }));
        },
      });
      a.tiles.forEach((t, i) => {
        assert.equal(b.tiles[i].samples, null);
        const got = new Float32Array(t.samples.length);
        for (let j = 0; j < t.height; j++) for (let x = 0; x < t.width; x++) got[j * t.width + x] = arr[regions[i].offset + 1 + j * regions[i].rowStride + 3 * x];
        assert.deepEqual(new Uint32Array(got.buffer), new Uint32Array(t.samples.buffer, t.samples.byteOffset, t.samples.length), `${st.name} seq ${f.seq} tile ${i}`);
      });
    }
  }
  await assert.rejects(decodeFrame(load(manifest.vectors[0].file), { target: () => [{ array: new Float32Array(4), offset: 0, stride: 1, rowStride: 1 }] }), RangeError);
});

// A predicted tile whose coefficients are all 0 (P = q1: the decoder's shortcut) against the Python
// reference decoder (proto/tools/ref_decode.py), on the vectors' chain with its coefficients zeroed.
test('predicted tiles with all coefficients 0 match the reference decoder', { skip: !existsSync('/usr/bin/python3') && 'no python3' }, async () => {
  const chain = manifest.streams.find((x) => x.name === 's01_chain').frames.filter((f) => !f.error);
  const frames = chain.map((f) => {
    const b = Buffer.from(load(f.file));
    for (let pos = b.readUInt16LE(6), i = 0, n = b.readUInt16LE(36); i < n; i++) {
      if (b[pos + 2] === 3) b.fill(0, pos + 40 + 24, pos + 40 + 24 + 14);
      pos += 40 + b.readUInt32LE(pos + 32);
    }
    return b;
  });
  assert.ok(frames.some((b) => b.includes(Buffer.from([3]))));
  const py = `import sys, json, struct, base64
sys.path.insert(0, ${JSON.stringify(join(root, 'proto/tools'))})
from ref_decode import decode_frame
refs, out = {}, []
for line in sys.stdin:
    h, tiles = decode_frame(base64.b64decode(line), refs)
    s = [x for t in tiles for x in t["samples"]]
    out.append(base64.b64encode(struct.pack("<%df" % len(s), *s)).decode())
print(json.dumps(out))`;
  const want = JSON.parse(execFileSync('/usr/bin/python3', ['-c', py], { input: frames.map((b) => b.toString('base64')).join('\n') + '\n' }).toString());
  const state = new DecoderState();
  let predicted = 0;
  for (const [k, b] of frames.entries()) {
    const fr = await decodeFrame(b, { state, useNodeZlib: k % 2 === 0 });
    predicted += fr.tiles.filter((t) => t.codec === 3).length;
    const got = Buffer.concat(fr.tiles.map((t) => Buffer.from(t.samples.buffer, t.samples.byteOffset, t.samples.byteLength)));
    assert.equal(got.toString('base64'), want[k], `frame ${k}`);
  }
  assert.ok(predicted > 0, 'no predicted tile decoded');
});

test('typed-array views and offsets are accepted', async () => {
  const v = manifest.vectors[0];
  const raw = new Uint8Array(load(v.file));
  const padded = new Uint8Array(raw.length + 3);
  padded.set(raw, 3);
  const frame = await decodeFrame(padded.subarray(3));
  assert.equal(frame.tiles.length, v.tiles.length);
});

test('a longer frame header (header_size 56) is skipped; 40 is corrupt', async () => {
  const v = manifest.vectors[0];
  const raw = new Uint8Array(load(v.file));
  const longer = new Uint8Array(raw.length + 8);
  longer.set(raw.subarray(0, 48));
  longer.fill(0xab, 48, 56);
  longer.set(raw.subarray(48), 56);
  longer[6] = 56;
  const frame = await decodeFrame(longer.buffer);
  assert.equal(frame.tiles.length, v.tiles.length);
  assert.equal(parseFrameHeader(longer.buffer).headerSize, 56);
  longer[6] = 40;
  assert.throws(() => parseFrameHeader(longer.buffer), (e) => e.code === 'corrupt');
});

test('random truncations and bit flips are rejected or decode', async () => {
  const frame = load(manifest.vectors.find((v) => v.name === 'v03_height_1mm').file);
  await mutateAndDecode(frame, 12345, (it) => ({ useNodeZlib: it % 4 < 2 }));
});

// Parts (PROTOCOL.md §3.4): a frame cut into messages of `counts` tiles each, as a server does.
function splitFrame(buf, counts) {
  const raw = new Uint8Array(buf), dv = new DataView(buf);
  const hs = dv.getUint16(6, true);
  const ends = [];
  for (let pos = hs, i = 0; i < dv.getUint16(36, true); i++) { pos += 40 + dv.getUint32(pos + 32, true); ends.push(pos); }
  const parts = [];
  let from = hs, tile = 0;
  counts.forEach((k, i) => {
    const to = ends[tile + k - 1];
    const p = new Uint8Array(hs + to - from);
    p.set(raw.subarray(0, hs));
    p.set(raw.subarray(from, to), hs);
    const pv = new DataView(p.buffer);
    pv.setUint16(36, k, true);
    pv.setUint16(38, dv.getUint16(38, true) | (i < counts.length - 1 ? FRAME_FLAG_PART : 0), true);
    parts.push(p.buffer);
    from = to; tile += k;
  });
  return parts;
}

test('FrameJoiner: parts join to the whole frame; a whole frame passes as it is', async () => {
  const v = manifest.vectors.find((x) => x.name === 'v04_fields');
  const buf = load(v.file);
  for (const counts of [[1, 1, 1, 1, 1], [2, 3], [4, 1], [5]]) {
    const j = new FrameJoiner();
    const parts = splitFrame(buf, counts);
    const got = parts.map((p) => j.push(p));
    assert.ok(got.slice(0, -1).every((x) => x === null), `held until the last part (${counts})`);
    assert.deepEqual(new Uint8Array(got.at(-1)), new Uint8Array(buf), `joined = whole (${counts})`);
    const frame = await decodeFrame(got.at(-1));
    assert.equal(frame.tiles.length, v.tiles.length);
  }
  const j = new FrameJoiner();
  assert.equal(j.push(buf), buf);
});

test('FrameJoiner: a part of another tick drops the unfinished one', () => {
  const buf = load(manifest.vectors.find((x) => x.name === 'v04_fields').file);
  const [p1] = splitFrame(buf, [2, 3]);
  const other = splitFrame(buf, [1, 4]);
  new DataView(other[0]).setBigUint64(8, 999n, true);
  new DataView(other[1]).setBigUint64(8, 999n, true);
  const j = new FrameJoiner();
  assert.equal(j.push(p1), null);
  assert.equal(j.push(other[0]), null);
  const whole = j.push(other[1]);
  assert.equal(new DataView(whole).getUint16(36, true), 5, 'the tiles of seq 999 only');
  assert.equal(new DataView(whole).getBigUint64(8, true), 999n);
});

test('FrameJoiner: random truncations and bit flips of parts are rejected or decode', async () => {
  const buf = load(manifest.vectors.find((x) => x.name === 'v03_height_1mm').file);
  const parts = splitFrame(buf, [1, 2, 1]);
  let seed = 777;
  const rnd = (n) => { seed = (seed * 1103515245 + 12345) >>> 0; return seed % n; };
  let joined = 0;
  for (let it = 0; it < 400; it++) {
    const j = new FrameJoiner();
    let out = null;
    try {
      for (const p of parts) {
        let b = new Uint8Array(p.slice(0));
        if (rnd(3) === 0) b = b.slice(0, rnd(b.length + 1));
        for (let k = rnd(4); k > 0 && b.length; k--) b[rnd(b.length)] ^= 1 << rnd(8);
        out = j.push(b.buffer) ?? out;
      }
    } catch (e) {
      assert.ok(e instanceof FrameError, `joiner threw ${e}`);
      continue;
    }
    if (!out) continue;
    joined++;
    try { await decodeFrame(out); } catch (e) { assert.ok(e instanceof FrameError, `decoder threw ${e}`); }
  }
  assert.ok(joined > 20, `only ${joined} of 400 mutated streams came out joined`);
});

// Control messages: each example carries the members the spec requires.
const required = {
  hello: ['protocol', 'server', 'client_id', 'role', 'params', 'params_version', 'schema', 'fields', 'lods', 'bounds',
    'tick_rate', 'tile_size', 'subscription'],
  set: ['params'],
  params: ['params', 'params_version', 'changed', 'by'],
  subscribe: [],
  subscribed: ['subscription'],
  error: ['code', 'message'],
  ping: [],
  pong: ['server_time_us'],
  pause: [],
  resume: [],
  name: ['name'],
  named: ['name'],
  render: ['start', 'fps', 'frames', 'fields'],
  rendering: ['frames', 'start', 'fps', 'params_version', 'n', 'cascades', 'units', 'layers'],
  rendered: ['frames'],
  render_cancel: [],
  launch: ['kind', 'x', 'z'],
  launched: ['body', 'resume'],
  steer: ['body'],
  steered: ['body'],
  remove: ['body'],
  removed: ['body'],
  claim: ['body', 'resume'],
  claimed: ['body'],
  bodies: ['seq', 'bodies', 'removed'],
};
const cdir = join(vdir, 'control');
for (const f of readdirSync(cdir).filter((n) => n.endsWith('.json')).sort()) {
  test(`control example ${f}`, () => {
    const msg = JSON.parse(readFileSync(join(cdir, f), 'utf8'));
    assert.ok(msg.type in required, `unknown type ${msg.type}`);
    for (const k of required[msg.type]) assert.ok(k in msg, `${msg.type} lacks ${k}`);
    if (msg.type === 'hello') {
      assert.equal(msg.protocol, PROTO_VERSION);
      assert.deepEqual(msg.fields, [...FIELD_NAMES]);
      for (const s of msg.schema) for (const k of ['name', 'type', 'default', 'description', 'label', 'group', 'help']) assert.ok(k in s, `schema ${s.name} lacks ${k}`);
    }
    if (msg.type === 'error') assert.match(msg.code, /^[a-z_]+$/);
  });
}

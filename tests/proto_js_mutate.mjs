// Shared by the JS decoder tests: 400 random truncations (even rounds) and
// 3-bit flips (odd rounds) of a valid frame. A truncated frame must be
// rejected with a protocol error code; a flipped one may decode or be
// rejected, never throw anything else.
import assert from 'node:assert/strict';
import { decodeFrame } from '../proto/js/oc_decode.js';

const CODES = new Set(['truncated', 'magic', 'version', 'corrupt', 'too_large']);

export async function mutateAndDecode(frame, seed, optsFor, extraCodes = []) {
  const base = new Uint8Array(frame);
  const rnd = () => (seed = (seed * 1103515245 + 12345) >>> 0) / 2 ** 32;
  for (let it = 0; it < 400; it++) {
    const cut = it % 2 === 0 ? Math.floor(rnd() * base.length) : base.length;
    const m = base.slice(0, cut);
    if (it % 2) for (let f = 0; f < 3; f++) m[Math.floor(rnd() * m.length)] ^= 1 << Math.floor(rnd() * 8);
    try {
      await decodeFrame(m.buffer, optsFor(it));
      assert.ok(it % 2 === 1, 'a truncated frame decoded');
    } catch (e) {
      assert.ok(CODES.has(e.code) || extraCodes.includes(e.code), `unexpected error ${e.code}: ${e.message}`);
    }
  }
}

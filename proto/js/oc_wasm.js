// oc_wasm.js — the decoder's WebAssembly kernels (proto/wasm/, built by the Makefile into
// build/wasm/oc_kernels.wasm with Debian's clang + wasm-ld; the web bundle embeds the bytes).
// No imports, like oc_decode.js: the caller brings the module's bytes.
//   const k = await loadKernels(bytes);        // null when WebAssembly is missing or refuses it
//   setInflateRaw(k.inflateRaw);                // oc_decode.js then inflates codec 1/3 tiles with it
//   setTemporalKernel(k.temporal);              // and predicts codec 3 tiles with it (SIMD)
// inflateRaw(src, out) has setInflateRaw()'s contract: the inflated bytes (a view of `out`),
// throwing on a bad stream or one longer than `out`. The pure-JavaScript path (fflate, or
// DecompressionStream) stays the fallback, and both are checked bit-exact on proto/vectors/.

const ERRORS = { '-1': 'corrupt stream', '-2': 'truncated stream', '-3': 'stream longer than expected', '-4': 'bytes after the end of the stream' };

/** Instantiate the kernels from the module's bytes (Uint8Array / ArrayBuffer / WebAssembly.Module). */
export async function loadKernels(bytes) {
  if (typeof WebAssembly !== 'object') return null;
  let instance;
  try {
    const mod = bytes instanceof WebAssembly.Module ? bytes : await WebAssembly.compile(bytes);
    instance = await WebAssembly.instantiate(mod, {});
  } catch {
    return null; // no SIMD / bulk memory in this engine: the caller keeps the JavaScript path
  }
  return makeKernels(instance.exports);
}

function makeKernels(x) {
  const memory = x.memory;
  const align = (v) => (v + 15) & ~15;
  const scratch = align(x.__heap_base.value);          // the inflater's state
  const inPtr = align(scratch + x.oc_inflate_scratch_size());
  let u8 = new Uint8Array(memory.buffer);
  // The input, then the output, after the scratch: grow the memory when a tile needs more.
  function reserve(end) {
    if (end > memory.buffer.byteLength) memory.grow(Math.ceil((end - memory.buffer.byteLength) / 65536));
    if (u8.buffer !== memory.buffer) u8 = new Uint8Array(memory.buffer);
  }
  function inflateRaw(src, out) {
    const outPtr = align(inPtr + src.length);
    reserve(outPtr + out.length);
    u8.set(src, inPtr);
    const n = x.oc_inflate_raw(inPtr, src.length, outPtr, out.length, scratch);
    if (n < 0) throw new Error(`deflate: ${ERRORS[n] || n}`);
    out.set(u8.subarray(outPtr, outPtr + n));
    return out.subarray(0, n);
  }
  // Codec 3's prediction (oc_predict.c): the references, residuals and scratch copied into the
  // module's memory, the codes and samples copied back (strided into the caller's target).
  // false = the tile is outside the kernel's int32 bound: the caller decodes it in JavaScript.
  // pairs = true: zz is stream A of pair packing (PROTOCOL.md §5.7) without escaped pairs, unpacked here.
  function temporal(refs, depth, zz, w, h, coef, q, dst, offset, scale, pairs = false) {
    const count = w * h, bytes = 4 * count;
    const base = align(scratch + x.oc_inflate_scratch_size());
    const refPtr = base, zzPtr = refPtr + depth * bytes, coefPtr = zzPtr + bytes, aPtr = coefPtr + 32,
      bPtr = aPtr + bytes, qPtr = bPtr + bytes, fPtr = qPtr + bytes;
    reserve(fPtr + bytes);
    const i32 = new Int32Array(memory.buffer);
    for (let k = 0; k < depth; k++) i32.set(refs[k], (refPtr >> 2) + k * count);
    if (pairs) {
      const pPtr = fPtr; // the samples' room, free until the prediction writes them
      u8 = new Uint8Array(memory.buffer);
      u8.set(zz.subarray(0, (count + 1) >> 1), pPtr);
      if (x.oc_unpack_pairs(pPtr, count, zzPtr)) return false;
    } else {
      i32.set(zz.length === count ? zz : zz.subarray(0, count), zzPtr >> 2); // zigzag values (u32 patterns; bytes widen)
    }
    for (let k = 0; k < 7; k++) i32[(coefPtr >> 2) + k] = coef[k];
    if (x.oc_temporal_predict(refPtr, depth, zzPtr, w, h, coefPtr, aPtr, bPtr, qPtr, fPtr, offset, scale)) return false;
    q.set(i32.subarray(qPtr >> 2, (qPtr >> 2) + count));
    const f = new Float32Array(memory.buffer, fPtr, count), out = dst.array, os = dst.stride, ors = dst.rowStride;
    if (os === 1 && ors === w) { out.set(f, dst.offset); return true; }
    for (let j = 0, k = 0; j < h; j++) {
      for (let i = 0, o = dst.offset + j * ors; i < w; i++, k++, o += os) out[o] = f[k];
    }
    return true;
  }
  return { inflateRaw, temporal, memory };
}

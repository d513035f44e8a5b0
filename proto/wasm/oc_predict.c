/* oc_predict.c — codec 3's temporal prediction (PROTOCOL.md §5.8) for the browser client,
 * built to WebAssembly with SIMD (mk/wasm.mk: clang -msimd128 vectorises these loops, 4 lanes).
 * proto/c/oc_temporal.c computes S exactly in float64/int64; here S is computed modulo 2^32
 * (int32 lanes), which is the same integer whenever the true S + 2048 lies within int32: the
 * caller's data are checked first, from the references' largest code M:
 *   |S| <= (|a1|+|a2|+|a3|+|a4|) M + 8 (|b1|+|b2|+|b3|+|b4|) M  (a, b as in proto/js/oc_decode.js),
 * and a tile beyond that (never for real data: M is a few thousand) returns 1 and is decoded by
 * the JavaScript path. Then P = q1 + ((S + 2048) >> 12) (floor), q = P + r mod 2^32 and the
 * sample float32(offset + q * scale) in double: bit for bit the C and JavaScript decoders. */
#include "oc_inflate.h"   /* stdint, stddef */

static inline uint32_t uabs(int32_t v) { return v < 0 ? 0u - (uint32_t)v : (uint32_t)v; }

/* A = sum a_k q_k and B = sum b_k q_k modulo 2^32 (restrict: vectorised without alias checks) */
static void ab_pass(const int32_t *restrict q1, const int32_t *restrict q2, const int32_t *restrict q3,
                    const int32_t *restrict q4, size_t count, uint32_t a1, uint32_t a2, uint32_t a3, uint32_t a4,
                    uint32_t b1, uint32_t b2, uint32_t b3, uint32_t b4, uint32_t *restrict A, uint32_t *restrict B)
{
#pragma clang loop vectorize(enable)
    for (size_t k = 0; k < count; k++) {
        uint32_t x1 = (uint32_t)q1[k], x2 = (uint32_t)q2[k], x3 = (uint32_t)q3[k], x4 = (uint32_t)q4[k];
        A[k] = a1 * x1 + a2 * x2 + a3 * x3 + a4 * x4;
        B[k] = b1 * x1 + b2 * x2 + b3 * x3 + b4 * x4;
    }
}

/* refs: depth (1..4) arrays of count codes each, back to back (q1 first); zz: zigzag residuals;
 * coef: the tile's 7 coefficients; A, B: scratch of count int32 each; q: the codes out; f: the
 * samples out (row-major, w per row). 0 = done, 1 = outside the int32 bound (nothing usable). */
int oc_temporal_predict(const int32_t *refs, int depth, const uint32_t *zz, int w, int h, const int32_t *coef,
                        int32_t *A, int32_t *B, int32_t *q, float *f, double offset, double scale)
{
    const size_t count = (size_t)w * h;
    const int32_t *q1 = refs, *q2 = depth > 1 ? refs + count : q1, *q3 = depth > 2 ? refs + 2 * count : q1,
                  *q4 = depth > 3 ? refs + 3 * count : q1;
    const int32_t c0 = coef[0], c1 = coef[1], c2 = coef[2], c3 = coef[3], c4 = coef[4], c5 = coef[5], c6 = coef[6];
    const int32_t a1 = c0, a2 = c1 - c0, a3 = c2 - c1, a4 = -c2, b1 = c3 + c6, b2 = c4 - c3, b3 = c5 - c4, b4 = -c5;
    uint32_t m = 0;
    for (size_t k = 0; k < (size_t)depth * count; k++) {
        uint32_t v = uabs(refs[k]);
        m = v > m ? v : m;
    }
    double sa = (double)uabs(a1) + uabs(a2) + uabs(a3) + uabs(a4), sb = (double)uabs(b1) + uabs(b2) + uabs(b3) + uabs(b4);
    if ((sa + 8.0 * sb) * (double)m + 2048.0 >= 2147483647.0) return 1;
    /* A = sum a_k q_k, B = sum b_k q_k, modulo 2^32 */
    const uint32_t ua1 = (uint32_t)a1, ua2 = (uint32_t)a2, ua3 = (uint32_t)a3, ua4 = (uint32_t)a4;
    const uint32_t ub1 = (uint32_t)b1, ub2 = (uint32_t)b2, ub3 = (uint32_t)b3, ub4 = (uint32_t)b4;
    ab_pass(q1, q2, q3, q4, count, ua1, ua2, ua3, ua4, ub1, ub2, ub3, ub4, (uint32_t *)A, (uint32_t *)B);
    const uint32_t *uA = (const uint32_t *)A, *uB = (const uint32_t *)B;
    for (int j = 0; j < h; j++) {
        const size_t r = (size_t)j * w, up = (size_t)(j > 0 ? j - 1 : 0) * w, dn = (size_t)(j + 1 < h ? j + 1 : h - 1) * w;
        const uint32_t *br = uB + r, *bu = uB + up, *bd = uB + dn, *ar = uA + r, *z = zz + r;
        const int32_t *p1 = q1 + r;
        int32_t *qr = q + r;
        float *fr = f + r;
        /* interior: W and E are i - 1 and i + 1 (vectorised) */
        for (int i = 1; i < w - 1; i++) {
            uint32_t s = ar[i] + br[i - 1] + br[i + 1] + bu[i] + bd[i] - 4u * br[i];
            int32_t t = (int32_t)(s + 2048u) >> 12;
            uint32_t res = (z[i] >> 1) ^ (0u - (z[i] & 1));
            int32_t v = (int32_t)((uint32_t)p1[i] + (uint32_t)t + res);
            qr[i] = v;
            fr[i] = (float)(offset + (double)v * scale);
        }
        /* i = 0 and i = w - 1: W / E clamp to the sample itself (w = 1: both) */
        for (int i = 0; i < w; i += (w > 1 ? w - 1 : 1)) {
            uint32_t lw = i > 0 ? br[i - 1] : br[i], le = i + 1 < w ? br[i + 1] : br[i];
            uint32_t s = ar[i] + lw + le + bu[i] + bd[i] - 4u * br[i];
            int32_t t = (int32_t)(s + 2048u) >> 12;
            uint32_t res = (z[i] >> 1) ^ (0u - (z[i] & 1));
            int32_t v = (int32_t)((uint32_t)p1[i] + (uint32_t)t + res);
            qr[i] = v;
            fr[i] = (float)(offset + (double)v * scale);
        }
    }
    return 0;
}

/* Pair packing (PROTOCOL.md §5.7) without escaped pairs: byte b = 15 z1 + z2 (b < 225) -> the
 * zigzag values z1, z2 of two samples; count odd: the last pair's z2 is padding and must be 0.
 * 0 = done; 1 = a byte >= 225 or bad padding (the caller's JavaScript reports the error). */
int oc_unpack_pairs(const uint8_t *p, size_t count, uint32_t *zz)
{
    const size_t npairs = (count + 1) / 2;
    uint32_t bad = 0;
    for (size_t k = 0; k < count / 2; k++) {
        uint32_t b = p[k], hi = (b * 137u) >> 11;   /* = b / 15 for b < 225 (checked by the tests) */
        bad |= b >= 225;
        zz[2 * k] = hi;
        zz[2 * k + 1] = b - 15u * hi;
    }
    if (count & 1) {
        uint32_t b = p[npairs - 1];
        bad |= b >= 225 || b % 15 != 0;
        zz[count - 1] = b / 15;
    }
    return bad != 0;
}

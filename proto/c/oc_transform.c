/* oc_transform.c — the integer part of the lossy codec (PROTOCOL.md §5):
 * a per-tile linear predictor on the integer codes, zigzag, and escape
 * packing of the residuals into one byte per sample.
 *
 * Prediction of code q[j][i] (i = column, j = row) from its causal
 * neighbours W = q[j][i-1], N = q[j-1][i], NW = q[j-1][i-1], NE = q[j-1][i+1],
 * WW = q[j][i-2], NN = q[j-2][i]:
 *   interior (j >= 2, 2 <= i <= w-2):  P = clamp_int32(floor((sum c_k * n_k + 32) / 64))
 *   j = 0: P = W (0 at i = 0);  i = 0 (j >= 1): P = N;  otherwise: P = W + N - NW (Lorenzo)
 * The sum is an integer below 2^53 in magnitude, so it is computed exactly in
 * double (here and in JavaScript). Residuals r = q - P are taken modulo 2^32,
 * which makes every step exactly invertible whatever the payload says. */
#include "oc_internal.h"

#include <math.h>
#include <string.h>

static inline uint32_t zigzag(uint32_t r) { return (r << 1) ^ (uint32_t)-(int32_t)(r >> 31); }
static inline uint32_t unzigzag(uint32_t z) { return (z >> 1) ^ (uint32_t)-(int32_t)(z & 1); }

const int8_t oc_lorenzo_coef[OC_PRED_COEFS] = { 64, 64, -64, 0, 0, 0 };

#ifndef OC_FIT_ROW_STEP
#define OC_FIT_ROW_STEP 8
#endif

static inline int32_t interior_pred(double s)
{
    double p = floor((s + 32.0) * (1.0 / 64.0));
    p = p < -2147483648.0 ? -2147483648.0 : p > 2147483647.0 ? 2147483647.0 : p;
    return (int32_t)p;
}

/* The 27 sums of the normal equations over the interior samples of every
 * OC_FIT_ROW_STEP-th row: x_a*x_b for a <= b (row-major upper triangle), then
 * x_a*y. Neighbours x0..x5 = W, N, NW, NE, WW, NN; y = the sample. */
#define FIT_SUMS 27

/* Exact version, for tiles where every product and partial sum is an integer
 * below 2^53 (the caller checks max|q|^2 * terms): then the double sums are
 * exact whatever the order, so four samples at a time (one AVX2 vector) give
 * bit for bit the sums of the sample-by-sample loop below, ~4x faster. */
typedef double v4d __attribute__((vector_size(32)));
typedef int32_t v4i __attribute__((vector_size(16)));

OC_VECTOR_CLONES
static void fit_sums_exact(const int32_t *q, int w, int h, double out[FIT_SUMS])
{
    v4d acc[FIT_SUMS];
    memset(acc, 0, sizeof acc);
    double tail[FIT_SUMS] = { 0 };
    for (int j = 2; j < h; j += OC_FIT_ROW_STEP) {
        const int32_t *row = q + (size_t)j * w, *up = row - w, *up2 = up - w;
        int i = 2;
        for (; i + 4 <= w - 1; i += 4) {
            const int32_t *src[7] = { row + i - 1, up + i, up + i - 1, up + i + 1, row + i - 2, up2 + i, row + i };
            v4d x[7];
            for (int a = 0; a < 7; a++) {
                v4i t;
                memcpy(&t, src[a], sizeof t);
                x[a] = __builtin_convertvector(t, v4d);
            }
            int k = 0;
            for (int a = 0; a < OC_PRED_COEFS; a++)
                for (int b = a; b < OC_PRED_COEFS; b++) acc[k++] += x[a] * x[b];
            for (int a = 0; a < OC_PRED_COEFS; a++) acc[k++] += x[a] * x[6];
        }
        for (; i <= w - 2; i++) {
            const double x[7] = { row[i - 1], up[i], up[i - 1], up[i + 1], row[i - 2], up2[i], row[i] };
            int k = 0;
            for (int a = 0; a < OC_PRED_COEFS; a++)
                for (int b = a; b < OC_PRED_COEFS; b++) tail[k++] += x[a] * x[b];
            for (int a = 0; a < OC_PRED_COEFS; a++) tail[k++] += x[a] * x[6];
        }
    }
    for (int k = 0; k < FIT_SUMS; k++) out[k] = acc[k][0] + acc[k][1] + acc[k][2] + acc[k][3] + tail[k];
}

/* General version: sample by sample, the order that defines the result when
 * the sums round. */
static void fit_sums_ordered(const int32_t *q, int w, int h, double out[FIT_SUMS])
{
    double s[FIT_SUMS] = { 0 };
    for (int j = 2; j < h; j += OC_FIT_ROW_STEP) {
        const int32_t *row = q + (size_t)j * w, *up = row - w, *up2 = up - w;
        for (int i = 2; i <= w - 2; i++) {
            const double x[7] = { row[i - 1], up[i], up[i - 1], up[i + 1], row[i - 2], up2[i], row[i] };
            int k = 0;
            for (int a = 0; a < OC_PRED_COEFS; a++)
                for (int b = a; b < OC_PRED_COEFS; b++) s[k++] += x[a] * x[b];
            for (int a = 0; a < OC_PRED_COEFS; a++) s[k++] += x[a] * x[6];
        }
    }
    memcpy(out, s, sizeof s);
}

/* Least-squares coefficients over interior samples of every OC_FIT_ROW_STEP-th row, solved
 * by Gaussian elimination; Lorenzo when the system is singular (e.g. flat).
 * maxabs = max |q| (oc_max_abs), which picks the exact fast sums when it can. */
void oc_predict_fit_m(const int32_t *q, int w, int h, uint32_t maxabs, int8_t coef[OC_PRED_COEFS])
{
    memcpy(coef, oc_lorenzo_coef, OC_PRED_COEFS);
    if (w < 4 || h < 3) return;
    double sums[FIT_SUMS];
    double terms = (double)((h - 3) / OC_FIT_ROW_STEP + 1) * (w - 3);
    if ((double)maxabs * maxabs * terms < 0x1p52) fit_sums_exact(q, w, h, sums);
    else fit_sums_ordered(q, w, h, sums);
    double A[OC_PRED_COEFS][OC_PRED_COEFS + 1];
    int at = 0;
    for (int a = 0; a < OC_PRED_COEFS; a++)
        for (int b = a; b < OC_PRED_COEFS; b++) A[a][b] = sums[at++];
    for (int a = 0; a < OC_PRED_COEFS; a++) A[a][OC_PRED_COEFS] = sums[at++];
    for (int a = 0; a < OC_PRED_COEFS; a++)
        for (int b = 0; b < a; b++) A[a][b] = A[b][a];
    double scale = 0;
    for (int a = 0; a < OC_PRED_COEFS; a++) scale = fmax(scale, A[a][a]);
    if (!(scale > 0)) return;
    for (int a = 0; a < OC_PRED_COEFS; a++) A[a][a] += scale * 1e-9; /* tiny ridge: stable on near-flat tiles */
    for (int c = 0; c < OC_PRED_COEFS; c++) {
        int piv = c;
        for (int r = c + 1; r < OC_PRED_COEFS; r++)
            if (fabs(A[r][c]) > fabs(A[piv][c])) piv = r;
        if (!(fabs(A[piv][c]) > scale * 1e-12)) return;
        if (piv != c)
            for (int k = 0; k <= OC_PRED_COEFS; k++) { double t = A[c][k]; A[c][k] = A[piv][k]; A[piv][k] = t; }
        for (int r = 0; r < OC_PRED_COEFS; r++) {
            if (r == c) continue;
            double f = A[r][c] / A[c][c];
            for (int k = c; k <= OC_PRED_COEFS; k++) A[r][k] -= f * A[c][k];
        }
    }
    for (int a = 0; a < OC_PRED_COEFS; a++) {
        double v = nearbyint(A[a][OC_PRED_COEFS] / A[a][a] * 64.0);
        if (!isfinite(v)) { memcpy(coef, oc_lorenzo_coef, OC_PRED_COEFS); return; }
        coef[a] = (int8_t)(v < -128 ? -128 : v > 127 ? 127 : v);
    }
}

/* Residuals of the border samples (row 0, column 0, rows/columns where a
 * neighbour is missing): the Lorenzo family. */
static inline uint32_t border_residual(const uint32_t *u, int w, int i, int j)
{
    size_t k = (size_t)j * w + i;
    if (j == 0) return i == 0 ? u[0] : u[k] - u[k - 1];
    if (i == 0) return u[k] - u[k - w];
    return u[k] - (u[k - 1] + u[k - w] - u[k - w - 1]);
}

/* One interior row in int32 arithmetic, for tiles where the caller has
 * checked |sum| + 32 < 2^31: then the sum is exact in int32, no clamp can act,
 * and floor(x / 64) is an arithmetic shift (GCC and Clang shift negative
 * values arithmetically). Eight lanes per AVX2 instruction. */
OC_VECTOR_CLONES
static void interior_row(const int32_t *restrict row, const int32_t *restrict up, const int32_t *restrict up2,
                         uint32_t *restrict o, int w, const int8_t coef[OC_PRED_COEFS])
{
    const int32_t cW = coef[0], cN = coef[1], cNW = coef[2], cNE = coef[3], cWW = coef[4], cNN = coef[5];
    for (int i = 2; i < w - 1; i++) {
        int32_t s = cW * row[i - 1] + cN * up[i] + cNW * up[i - 1] + cNE * up[i + 1] + cWW * row[i - 2]
                    + cNN * up2[i] + 32;
        o[i] = zigzag((uint32_t)row[i] - (uint32_t)(s >> 6));
    }
}

OC_VECTOR_CLONES
uint32_t oc_max_abs(const int32_t *restrict q, size_t count)
{
    uint32_t m = 0;
    for (size_t k = 0; k < count; k++) {
        uint32_t u = (uint32_t)q[k], a = q[k] < 0 ? 0u - u : u;
        m = a > m ? a : m;
    }
    return m;
}

void oc_predict_fit(const int32_t *q, int w, int h, int8_t coef[OC_PRED_COEFS])
{
    oc_predict_fit_m(q, w, h, oc_max_abs(q, (size_t)w * h), coef);
}

void oc_predict_residuals(const int32_t *q, int w, int h, const int8_t coef[OC_PRED_COEFS], uint32_t *zz)
{
    oc_predict_residuals_m(q, w, h, oc_max_abs(q, (size_t)w * h), coef, zz);
}

void oc_predict_residuals_m(const int32_t *q, int w, int h, uint32_t maxabs, const int8_t coef[OC_PRED_COEFS],
                            uint32_t *zz)
{
    const uint32_t *u = (const uint32_t *)q;
    const double c[OC_PRED_COEFS] = { coef[0], coef[1], coef[2], coef[3], coef[4], coef[5] };
    /* |sum| <= max|q| * sum|c|: when that (+ 32) fits int32, the fast int32 path is exact. */
    uint64_t sum_c = 0;
    for (int k = 0; k < OC_PRED_COEFS; k++) sum_c += (uint64_t)(coef[k] < 0 ? -coef[k] : coef[k]);
    const int small = (uint64_t)maxabs * sum_c + 64 < 0x80000000u;
    for (int j = 0; j < h; j++) {
        uint32_t *o = zz + (size_t)j * w;
        if (j < 2 || w < 4) {
            for (int i = 0; i < w; i++) o[i] = zigzag(border_residual(u, w, i, j));
            continue;
        }
        const int32_t *row = q + (size_t)j * w, *up = row - w, *up2 = up - w;
        o[0] = zigzag(border_residual(u, w, 0, j));
        o[1] = zigzag(border_residual(u, w, 1, j));
        if (small) {
            interior_row(row, up, up2, o, w, coef);
        } else {
            for (int i = 2; i <= w - 2; i++) {
                double s = c[0] * row[i - 1] + c[1] * up[i] + c[2] * up[i - 1] + c[3] * up[i + 1]
                           + c[4] * row[i - 2] + c[5] * up2[i];
                o[i] = zigzag((uint32_t)row[i] - (uint32_t)interior_pred(s));
            }
        }
        o[w - 1] = zigzag(border_residual(u, w, w - 1, j));
    }
}

/* floor(s / 64) for any int64, without relying on >> of negatives. */
static inline int64_t floor_div64(int64_t s) { return s < 0 ? ~(~s >> 6) : s >> 6; }
static inline uint32_t clamp_i32(int64_t p)
{
    return (uint32_t)(int32_t)(p < INT32_MIN ? INT32_MIN : p > INT32_MAX ? INT32_MAX : p);
}

/* Decoder side: exact int64 arithmetic (|sum| < 2^41), identical to the
 * encoder's double arithmetic. The terms from the previous rows are summed
 * for the whole row first, so the serial chain per sample is short. */
void oc_unpredict(const uint32_t *zz, int w, int h, const int8_t coef[OC_PRED_COEFS], int32_t *q)
{
    uint32_t *u = (uint32_t *)q;
    const int64_t cW = coef[0], cN = coef[1], cNW = coef[2], cNE = coef[3], cWW = coef[4], cNN = coef[5];
    int64_t t[OC_MAX_N];
    for (int j = 0; j < h; j++) {
        uint32_t *row = u + (size_t)j * w;
        const uint32_t *in = zz + (size_t)j * w;
        if (j == 0) {
            row[0] = unzigzag(in[0]);
            for (int i = 1; i < w; i++) row[i] = row[i - 1] + unzigzag(in[i]);
            continue;
        }
        const uint32_t *up = row - w;
        row[0] = up[0] + unzigzag(in[0]);
        if (j < 2 || w < 4) {
            for (int i = 1; i < w; i++) row[i] = row[i - 1] + up[i] - up[i - 1] + unzigzag(in[i]);
            continue;
        }
        const int32_t *sup = (const int32_t *)up, *sup2 = sup - w;
        for (int i = 2; i <= w - 2; i++)
            t[i] = cN * sup[i] + cNW * sup[i - 1] + cNE * sup[i + 1] + cNN * sup2[i] + 32;
        row[1] = row[0] + up[1] - up[0] + unzigzag(in[1]);
        int64_t ww = (int32_t)row[0], wv = (int32_t)row[1];
        for (int i = 2; i <= w - 2; i++) {
            uint32_t v = clamp_i32(floor_div64(t[i] + cW * wv + cWW * ww)) + unzigzag(in[i]);
            row[i] = v;
            ww = wv;
            wv = (int32_t)v;
        }
        row[w - 1] = row[w - 2] + up[w - 1] - up[w - 2] + unzigzag(in[w - 1]);
    }
}

/* Escape packing: stream A = one byte per sample, min(zz, 255); stream B =
 * zz - 255 for each sample whose byte is 255, in order, as esc_width-byte
 * values split into byte planes (plane 0 = least significant bytes). */
OC_VECTOR_CLONES
static uint32_t pack_bytes(const uint32_t *restrict zz, size_t count, uint8_t *restrict out)
{
    uint32_t m = 0;
    for (size_t k = 0; k < count; k++) {
        uint32_t z = zz[k];
        out[k] = (uint8_t)(z < 255 ? z : 255);
        m = z > m ? z : m;
    }
    return m;
}

size_t oc_pack_escapes(const uint32_t *zz, size_t count, uint8_t *out, uint32_t *esc_scratch, int *esc_width)
{
    *esc_width = 0;
    if (pack_bytes(zz, count, out) < 255) return 0;   /* the common case: one byte per sample */
    size_t ne = 0;
    uint32_t all = 0;
    /* Escapes are rare: find them with memchr (SIMD in every libc) on stream A. */
    for (const uint8_t *p = out, *end = out + count; (p = memchr(p, 255, (size_t)(end - p))) != NULL; p++) {
        uint32_t x = zz[p - out] - 255;
        esc_scratch[ne++] = x;
        all |= x;
    }
    int nb = all < 0x100u ? 1 : all < 0x10000u ? 2 : all < 0x1000000u ? 3 : 4;
    uint8_t *b = out + count;
    for (int p = 0; p < nb; p++)
        for (size_t e = 0; e < ne; e++) b[(size_t)p * ne + e] = (uint8_t)(esc_scratch[e] >> (8 * p));
    *esc_width = nb;
    return ne;
}

int oc_unpack_escapes(const uint8_t *in, size_t count, size_t esc_count, int esc_width, uint32_t *zz)
{
    const uint8_t *b = in + count;
    size_t e = 0;
    for (size_t k = 0; k < count; k++) {
        uint32_t z = in[k];
        if (z == 255) {
            if (e == esc_count) return OC_E_CORRUPT;
            uint32_t x = 0;
            for (int p = 0; p < esc_width; p++) x |= (uint32_t)b[(size_t)p * esc_count + e] << (8 * p);
            if (x > UINT32_MAX - 255) return OC_E_CORRUPT;
            z = 255 + x;
            e++;
        }
        zz[k] = z;
    }
    return e == esc_count ? OC_OK : OC_E_CORRUPT;
}

/* oc_temporal.c — the integer part of codec 3 (PROTOCOL.md §5.6-5.8): each
 * code is predicted from the same sample's codes in the 1..4 previous frames of
 * its chain (same grid), never from samples of the frame being decoded, so a
 * whole tile's predictions are known before its residuals are read.
 *
 * With q1..q4 the reference codes (q1 = frame ref_seq, q2 = ref_seq - 1, ...),
 * d1 = q1 - q2, d2 = q2 - q3, d3 = q3 - q4 and L(a) the 5-point Laplacian
 * a[W] + a[E] + a[N] + a[S] - 4a inside the tile (indices clamped to the tile):
 *   S = c0*d1 + c1*d2 + c2*d3 + c3*L(d1) + c4*L(d2) + c5*L(d3) + c6*L(q1)   (units of 1/4096)
 *   P = q1 + floor((S + 2048) / 4096),  q = (P + r) mod 2^32
 * |S| < 2^52, so every step is exact in float64 (here and in JavaScript) and in int64.
 * Measured on the simulation (docs/codec.md): a per-tile least-squares fit of the
 * wave's own time evolution; the Laplacian terms stand in for the dispersion
 * operator (not a local one), and take height at 1 mm from 2.2 bits (2*q1 - q2) to 1.5. */
#include "oc_internal.h"

#include <math.h>
#include <string.h>

/* Which coefficients a tile may use with `depth` references: d_k needs q_{k+1}. */
unsigned oc_temporal_coef_mask(int depth)
{
    switch (depth) {
    case 1: return 0x40;        /* L(q1) */
    case 2: return 0x49;        /* d1, L(d1), L(q1) */
    case 3: return 0x5b;        /* + d2, L(d2) */
    case 4: return 0x7f;        /* + d3, L(d3) */
    default: return 0;
    }
}

/* The encoder keeps each reference's Laplacian (int32: its codes are below 2^27 in
 * magnitude, so |L| < 2^30) and predicts from those; the decoder computes them on
 * the fly in double. Both are exact integer arithmetic: the same predictions. */
void oc_temporal_laplacian(const int32_t *q, int w, int h, int32_t *L)
{
    for (int j = 0; j < h; j++) {
        const int32_t *row = q + (size_t)j * w, *up = q + (size_t)(j > 0 ? j - 1 : 0) * w,
                      *dn = q + (size_t)(j + 1 < h ? j + 1 : h - 1) * w;
        int32_t *o = L + (size_t)j * w;
        if (w == 1) { o[0] = up[0] + dn[0] - 2 * row[0]; continue; }
        o[0] = row[1] + up[0] + dn[0] - 3 * row[0];
        for (int i = 1; i < w - 1; i++) o[i] = row[i - 1] + row[i + 1] + up[i] + dn[i] - 4 * row[i];
        o[w - 1] = row[w - 2] + up[w - 1] + dn[w - 1] - 3 * row[w - 1];
    }
}

/* floor(x) for |x| < 2^51 with the round-to-nearest trick and a compare: unlike floor()
 * it vectorises without -ffast-math. Exact: every step is. */
static inline double floor_d(double x)
{
    double r = (x + 0x1.8p52) - 0x1.8p52;
    return r - (double)(r > x);
}

/* t (an integer, |t| < 2^42, exact in double) modulo 2^32, as the int32 of the same bits:
 * exact steps that vectorise (no double -> int64 conversion in AVX2). */
static inline uint32_t wrap_u32(double t)
{
    double m = t - 4294967296.0 * floor_d(t * 0x1p-32);     /* [0, 2^32) */
    return (uint32_t)(int32_t)(m - 2147483648.0) ^ 0x80000000u;   /* branch-free: shift into int32 range and back */
}

/* The references' rows for one output row: row j and its clamped neighbours above and below. */
struct ref_rows { const int32_t *r[OC_TEMPORAL_MAX_DEPTH], *u[OC_TEMPORAL_MAX_DEPTH], *d[OC_TEMPORAL_MAX_DEPTH]; };

/* Samples i0 <= i < i1 of a row whose W/E neighbours are i-1/i+1 (no clamping).
 * Depths below 4 pass q1 for the missing references: their coefficients are 0. */
OC_VECTOR_CLONES
static void predict_span(const struct ref_rows *rr, int i0, int i1, const double *cf, uint32_t *restrict pred)
{
    const int32_t *restrict a = rr->r[0], *restrict b = rr->r[1], *restrict c = rr->r[2], *restrict d = rr->r[3];
    const int32_t *restrict au = rr->u[0], *restrict bu = rr->u[1], *restrict cu = rr->u[2], *restrict du = rr->u[3];
    const int32_t *restrict ad = rr->d[0], *restrict bd = rr->d[1], *restrict cd = rr->d[2], *restrict dd = rr->d[3];
    const double c0 = cf[0], c1 = cf[1], c2 = cf[2], c3 = cf[3], c4 = cf[4], c5 = cf[5], c6 = cf[6];
    for (int i = i0; i < i1; i++) {
        double q1 = a[i], q2 = b[i], q3 = c[i], q4 = d[i];
        double l1 = (double)a[i - 1] + (double)a[i + 1] + (double)au[i] + (double)ad[i] - 4.0 * q1;
        double l2 = (double)b[i - 1] + (double)b[i + 1] + (double)bu[i] + (double)bd[i] - 4.0 * q2;
        double l3 = (double)c[i - 1] + (double)c[i + 1] + (double)cu[i] + (double)cd[i] - 4.0 * q3;
        double l4 = (double)d[i - 1] + (double)d[i + 1] + (double)du[i] + (double)dd[i] - 4.0 * q4;
        double s = c0 * (q1 - q2) + c1 * (q2 - q3) + c2 * (q3 - q4) + c3 * (l1 - l2) + c4 * (l2 - l3)
                   + c5 * (l3 - l4) + c6 * l1;                  /* exact: |s| < 2^52 */
        double t = floor_d((s + 2048.0) * (1.0 / 4096));
        pred[i] = (uint32_t)a[i] + wrap_u32(t);
    }
}

/* One sample with clamped neighbours (the tile's first and last columns). */
static uint32_t predict_at(const struct ref_rows *rr, int i, int il, int ir, const double *cf)
{
    double q[OC_TEMPORAL_MAX_DEPTH], l[OC_TEMPORAL_MAX_DEPTH];
    for (int k = 0; k < OC_TEMPORAL_MAX_DEPTH; k++) {
        q[k] = rr->r[k][i];
        l[k] = (double)rr->r[k][il] + (double)rr->r[k][ir] + (double)rr->u[k][i] + (double)rr->d[k][i] - 4.0 * q[k];
    }
    double s = cf[0] * (q[0] - q[1]) + cf[1] * (q[1] - q[2]) + cf[2] * (q[2] - q[3]) + cf[3] * (l[0] - l[1])
               + cf[4] * (l[1] - l[2]) + cf[5] * (l[2] - l[3]) + cf[6] * l[0];
    return (uint32_t)rr->r[0][i] + wrap_u32(floor_d((s + 2048.0) * (1.0 / 4096)));
}

void oc_temporal_predict_row(const int32_t *const *refs, int depth, int w, int h, int j,
                             const int16_t coef[OC_TEMPORAL_COEFS], uint32_t *pred)
{
    const size_t r = (size_t)j * w, u = (size_t)(j > 0 ? j - 1 : 0) * w, dn = (size_t)(j + 1 < h ? j + 1 : h - 1) * w;
    struct ref_rows rr;
    for (int k = 0; k < OC_TEMPORAL_MAX_DEPTH; k++) {
        const int32_t *q = k < depth ? refs[k] : refs[0];    /* coefficient 0 for the missing ones */
        rr.r[k] = q + r;
        rr.u[k] = q + u;
        rr.d[k] = q + dn;
    }
    double cf[OC_TEMPORAL_COEFS];
    for (int k = 0; k < OC_TEMPORAL_COEFS; k++) cf[k] = coef[k];
    pred[0] = predict_at(&rr, 0, 0, w > 1 ? 1 : 0, cf);
    if (w == 1) return;
    predict_span(&rr, 1, w - 1, cf, pred);
    pred[w - 1] = predict_at(&rr, w - 1, w - 2, w - 1, cf);
}

/* The encoder's predictions of row j from the references and their Laplacians
 * (oc_temporal_laplacian): the same values as oc_temporal_predict_row. With codes
 * below 2^27 every feature fits int32 and S is an exact int64 (|S| < 2^50); the
 * floor division by 4096 is a logical shift of S + 2048 + 2^50 (no 64-bit arithmetic
 * shift in AVX2), and P mod 2^32 is the low half of the int64 sum. */
OC_VECTOR_CLONES
static void predict_cached(const int32_t *restrict a, const int32_t *restrict b, const int32_t *restrict c,
                           const int32_t *restrict d, const int32_t *restrict la, const int32_t *restrict lb,
                           const int32_t *restrict lc, const int32_t *restrict ld, int w, const int16_t *cf,
                           uint32_t *restrict pred)
{
    const int64_t c0 = cf[0], c1 = cf[1], c2 = cf[2], c3 = cf[3], c4 = cf[4], c5 = cf[5], c6 = cf[6];
    for (int i = 0; i < w; i++) {
        int64_t s = c0 * (int64_t)(a[i] - b[i]) + c1 * (int64_t)(b[i] - c[i]) + c2 * (int64_t)(c[i] - d[i])
                    + c3 * (int64_t)(la[i] - lb[i]) + c4 * (int64_t)(lb[i] - lc[i]) + c5 * (int64_t)(lc[i] - ld[i])
                    + c6 * (int64_t)la[i];
        uint64_t t = ((uint64_t)(s + 2048) + (1ull << 50)) >> 12;   /* floor((s + 2048) / 4096) + 2^38 */
        pred[i] = (uint32_t)a[i] + (uint32_t)t;                      /* 2^38 vanishes mod 2^32 */
    }
}

void oc_temporal_predict_row_cached(const int32_t *const *refs, const int32_t *const *laps, int depth, int w, int j,
                                    const int16_t coef[OC_TEMPORAL_COEFS], uint32_t *pred)
{
    const size_t o = (size_t)j * w;
    const int32_t *q[OC_TEMPORAL_MAX_DEPTH], *l[OC_TEMPORAL_MAX_DEPTH];
    for (int k = 0; k < OC_TEMPORAL_MAX_DEPTH; k++) {
        q[k] = (k < depth ? refs[k] : refs[0]) + o;        /* coefficient 0 for the missing ones */
        l[k] = (k < depth ? laps[k] : laps[0]) + o;
    }
    predict_cached(q[0], q[1], q[2], q[3], l[0], l[1], l[2], l[3], w, coef, pred);
}

/* The encoder's choice of codes on a refined grid (oc_stream.c): a sample whose
 * prediction reconstructs within the bound takes it (residual 0); any other keeps its
 * rounded code q, the centre of its valid codes. (Measured against the valid code
 * nearest the prediction: 0.5 % fewer bytes at 1 cm and one exact check per sample.) */
OC_VECTOR_CLONES
void oc_temporal_snap_row(int32_t *restrict q, const uint32_t *restrict pred, const float *restrict v, int w,
                          double offset, double scale, double bound)
{
    for (int i = 0; i < w; i++) {
        const int32_t p = (int32_t)pred[i];
        const int ok = fabs((double)(float)(offset + (double)p * scale) - (double)v[i]) <= bound;
        q[i] = ok ? p : q[i];
    }
}

/* Least squares over every FIT_ROW_STEP-th row (the fit only steers the encoder; the
 * coefficients travel in the payload). Features the depth does not allow get 0. */
#define FIT_ROW_STEP 16
#define FIT_F 8                 /* the 7 features and the target y = q - q1 */

/* The normal equations' sums S[a][b] = sum of f_a * f_b over the sampled rows, for all
 * seven features and the target. A depth's system takes its entries from these.
 *
 * The defining order is sample by sample (fit_sums_ordered). The features are
 * integers; when every partial sum stays below 2^53 no step rounds and any order gives
 * the same bits. By Cauchy-Schwarz every partial sum of f_a * f_b is at most
 * max(S_aa, S_bb), so diagonal sums below 2^51 (computed; a true one at or above 2^52
 * cannot round down that far) prove it: then fit_sums_exact's four-lane sums are the
 * ordered sums bit for bit, ~4x faster (as oc_transform.c's intra fit). */
typedef double v4d __attribute__((vector_size(32)));
typedef int32_t v4i __attribute__((vector_size(16)));
enum { FIT_SUMS = FIT_F * (FIT_F + 1) / 2 };

/* Four int32 as doubles (a macro: a function returning v4d would change the ABI without AVX). */
#define LOAD4(p) __extension__({ v4i t_; memcpy(&t_, (p), sizeof t_); __builtin_convertvector(t_, v4d); })

static void fit_fill(const double *sums, double S[FIT_F][FIT_F])
{
    int k = 0;
    for (int a = 0; a < FIT_F; a++)
        for (int b = a; b < FIT_F; b++) S[a][b] = S[b][a] = sums[k++];
}

/* 1 if the sums are exact (S filled), 0 if some may round (use the ordered sums). */
OC_VECTOR_CLONES
static int fit_sums_exact(const int32_t *const *qr, const int32_t *const *lr, const int32_t *q, int w, int h,
                          double S[FIT_F][FIT_F])
{
    v4d acc[FIT_SUMS];
    memset(acc, 0, sizeof acc);
    double tail[FIT_SUMS] = { 0 }, sums[FIT_SUMS];
    for (int j = FIT_ROW_STEP / 2 < h ? FIT_ROW_STEP / 2 : 0; j < h; j += FIT_ROW_STEP) {
        const size_t o = (size_t)j * w;
        const int32_t *pa = qr[0] + o, *pb = qr[1] + o, *pc = qr[2] + o, *pd = qr[3] + o;
        const int32_t *pla = lr[0] + o, *plb = lr[1] + o, *plc = lr[2] + o, *pld = lr[3] + o, *py = q + o;
        int i = 0;
        for (; i + 4 <= w; i += 4) {
            const v4d a = LOAD4(pa + i), b = LOAD4(pb + i), c = LOAD4(pc + i), d = LOAD4(pd + i);
            const v4d la = LOAD4(pla + i), lb = LOAD4(plb + i), lc = LOAD4(plc + i), ld = LOAD4(pld + i);
            const v4d x[FIT_F] = { a - b, b - c, c - d, la - lb, lb - lc, lc - ld, la, LOAD4(py + i) - a };
            int k = 0;
            for (int r = 0; r < FIT_F; r++)
                for (int t = r; t < FIT_F; t++) acc[k++] += x[r] * x[t];
        }
        for (; i < w; i++) {
            const double a = pa[i], b = pb[i], c = pc[i], la = pla[i], lb = plb[i], lc = plc[i];
            const double x[FIT_F] = { a - b, b - c, c - pd[i], la - lb, lb - lc, lc - pld[i], la, py[i] - a };
            int k = 0;
            for (int r = 0; r < FIT_F; r++)
                for (int t = r; t < FIT_F; t++) tail[k++] += x[r] * x[t];
        }
    }
    double diag = 0;
    for (int k = 0; k < FIT_SUMS; k++) sums[k] = acc[k][0] + acc[k][1] + acc[k][2] + acc[k][3] + tail[k];
    for (int a = 0, k = 0; a < FIT_F; k += FIT_F - a, a++) diag = sums[k] > diag ? sums[k] : diag;
    if (!(diag < 0x1p51)) return 0;
    fit_fill(sums, S);
    return 1;
}

/* The defining order: sample by sample (what the sums are when they round). */
static void fit_sums_ordered(const int32_t *const *qr, const int32_t *const *lr, const int32_t *q, int w, int h,
                             double S[FIT_F][FIT_F])
{
    double sums[FIT_SUMS] = { 0 };
    for (int j = FIT_ROW_STEP / 2 < h ? FIT_ROW_STEP / 2 : 0; j < h; j += FIT_ROW_STEP) {
        const size_t o = (size_t)j * w;
        for (int i = 0; i < w; i++) {
            double qq[OC_TEMPORAL_MAX_DEPTH], ll[OC_TEMPORAL_MAX_DEPTH];
            for (int k = 0; k < OC_TEMPORAL_MAX_DEPTH; k++) {
                qq[k] = qr[k][o + i];
                ll[k] = lr[k][o + i];
            }
            const double x[FIT_F] = { qq[0] - qq[1], qq[1] - qq[2], qq[2] - qq[3], ll[0] - ll[1],
                                      ll[1] - ll[2], ll[2] - ll[3], ll[0], (double)q[o + i] - qq[0] };
            int k = 0;
            for (int r = 0; r < FIT_F; r++)
                for (int t = r; t < FIT_F; t++) sums[k++] += x[r] * x[t];
        }
    }
    fit_fill(sums, S);
}

void oc_temporal_fit(const int32_t *const *refs, const int32_t *const *laps, int depth, const int32_t *q, int w,
                     int h, int16_t coef[OC_TEMPORAL_COEFS])
{
    enum { K = OC_TEMPORAL_COEFS };
    memset(coef, 0, sizeof(int16_t) * K);
    unsigned mask = oc_temporal_coef_mask(depth);
    int idx[K], m = 0;
    for (int k = 0; k < K; k++) if (mask & (1u << k)) idx[m++] = k;
    if (m == 0) return;
    const int32_t *qr[OC_TEMPORAL_MAX_DEPTH], *lr[OC_TEMPORAL_MAX_DEPTH];
    for (int k = 0; k < OC_TEMPORAL_MAX_DEPTH; k++) {
        qr[k] = k < depth ? refs[k] : refs[0];                /* missing ones: features 0 */
        lr[k] = k < depth ? laps[k] : laps[0];
    }
    double S[FIT_F][FIT_F], A[K][K + 1];
    if (!fit_sums_exact(qr, lr, q, w, h, S)) fit_sums_ordered(qr, lr, q, w, h, S);
    for (int a = 0; a < m; a++) {
        for (int b = 0; b < m; b++) A[a][b] = S[idx[a]][idx[b]];
        A[a][m] = S[idx[a]][FIT_F - 1];
    }
    double scale = 0;
    for (int a = 0; a < m; a++) scale = fmax(scale, A[a][a]);
    if (!(scale > 0)) return;                               /* no motion: P = q1 */
    for (int a = 0; a < m; a++) A[a][a] += scale * 1e-9;    /* tiny ridge: stable on flat tiles */
    for (int c = 0; c < m; c++) {
        int piv = c;
        for (int r = c + 1; r < m; r++)
            if (fabs(A[r][c]) > fabs(A[piv][c])) piv = r;
        if (!(fabs(A[piv][c]) > scale * 1e-12)) return;
        if (piv != c)
            for (int k = 0; k <= m; k++) { double t = A[c][k]; A[c][k] = A[piv][k]; A[piv][k] = t; }
        for (int r = 0; r < m; r++) {
            if (r == c) continue;
            double g = A[r][c] / A[c][c];
            for (int k = c; k <= m; k++) A[r][k] -= g * A[c][k];
        }
    }
    for (int a = 0; a < m; a++) {
        double v = nearbyint(A[a][m] / A[a][a] * 4096.0);
        if (!isfinite(v)) { memset(coef, 0, sizeof(int16_t) * K); return; }
        coef[idx[a]] = (int16_t)(v < -32768 ? -32768 : v > 32767 ? 32767 : v);
    }
}

/* Pair packing: one byte per two samples when both zigzag values are below 15
 * (measured: at 1 cm most residuals are 0 or +-1, and DEFLATE's Huffman code
 * spends at least one bit per byte; two samples per byte halves that floor). */
OC_VECTOR_CLONES
static void pair_bytes_even(const uint32_t *restrict zz, size_t npairs, uint8_t *restrict out)
{
    for (size_t p = 0; p < npairs; p++) {
        const uint32_t z1 = zz[2 * p], z2 = zz[2 * p + 1];
        out[p] = z1 < OC_PAIR_LIMIT && z2 < OC_PAIR_LIMIT ? (uint8_t)(OC_PAIR_LIMIT * z1 + z2) : 255;
    }
}

void oc_pair_bytes(const uint32_t *zz, size_t count, uint8_t *out)
{
    pair_bytes_even(zz, count / 2, out);
    if (count & 1) {                                        /* the last pair's second value is 0 */
        const uint32_t z1 = zz[count - 1];
        out[count / 2] = z1 < OC_PAIR_LIMIT ? (uint8_t)(OC_PAIR_LIMIT * z1) : 255;
    }
}

size_t oc_pack_pair_escapes(const uint32_t *zz, size_t count, uint8_t *out, uint32_t *esc_scratch,
                            size_t *pair_esc_count, size_t *esc_count, int *esc_width)
{
    const size_t npairs = (count + 1) / 2;
    size_t ny = 0;
    uint32_t *y = esc_scratch + count;                     /* the escaped pairs' values (<= count + 1) */
    /* Escaped pairs are rare: find them with memchr (SIMD in every libc). */
    for (const uint8_t *q = out, *end = out + npairs; (q = memchr(q, 255, (size_t)(end - q))) != NULL; q++) {
        const size_t p = (size_t)(q - out);
        y[ny++] = zz[2 * p];
        y[ny++] = 2 * p + 1 < count ? zz[2 * p + 1] : 0;
    }
    *pair_esc_count = ny / 2;
    *esc_count = oc_pack_escapes(y, ny, out + npairs, esc_scratch, esc_width);
    return npairs + ny + *esc_count * (size_t)*esc_width;
}

size_t oc_pack_pairs(const uint32_t *zz, size_t count, uint8_t *out, uint32_t *esc_scratch,
                     size_t *pair_esc_count, size_t *esc_count, int *esc_width)
{
    oc_pair_bytes(zz, count, out);
    return oc_pack_pair_escapes(zz, count, out, esc_scratch, pair_esc_count, esc_count, esc_width);
}

int oc_unpack_pairs(const uint8_t *in, size_t plain_len, size_t count, size_t pair_esc_count, size_t esc_count,
                    int esc_width, uint32_t *zz, uint32_t *scratch)
{
    const size_t npairs = (count + 1) / 2, ny = 2 * pair_esc_count;
    if (pair_esc_count > npairs || esc_count > ny) return OC_E_CORRUPT;
    if (plain_len != npairs + ny + esc_count * (size_t)esc_width) return OC_E_CORRUPT;
    int rc = oc_unpack_escapes(in + npairs, ny, esc_count, esc_width, scratch);
    if (rc) return rc;
    size_t e = 0;
    for (size_t p = 0; p < npairs; p++) {
        uint32_t b = in[p], z1, z2;
        if (b < OC_PAIR_LIMIT * OC_PAIR_LIMIT) {
            z1 = b / OC_PAIR_LIMIT;
            z2 = b % OC_PAIR_LIMIT;
        } else if (b == 255 && e < pair_esc_count) {
            z1 = scratch[2 * e];
            z2 = scratch[2 * e + 1];
            e++;
        } else {
            return OC_E_CORRUPT;                            /* 225..254, or more escapes than declared */
        }
        zz[2 * p] = z1;
        if (2 * p + 1 < count) zz[2 * p + 1] = z2;
        else if (z2 != 0) return OC_E_CORRUPT;              /* the padding value of an odd count is 0 */
    }
    return e == pair_esc_count ? OC_OK : OC_E_CORRUPT;
}

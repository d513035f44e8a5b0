/* ocean_step.c — one time step on the FFT path.
 *
 * Per mode of the half spectrum: h~(k,t) = h~0(k) e^{-iwt} + conj(h~0(-k)) e^{iwt}
 * (a wave h~0 e^{i(k.x - wt)} travels along +k, i.e. downwind), then each
 * requested real field's spectrum is h~ times a factor:
 *   height 1, Dx i lambda kx/k, Dz i lambda kz/k, slopes i kx, i kz,
 *   Jacobian terms -lambda kx^2/k, -lambda kz^2/k, -lambda kx kz/k,
 * where every "1/k" is coth(kD)/k in water of depth D (linear theory's
 * orbits are wider than tall in shallow water; 1/k in deep water): the
 * per-mode "invk" below (the amplitudes' linvk, lambda folded in) holds
 * lambda times that, displacement_over_k().
 * (lambda > 0 moves points toward crests and sharpens them; Tessendorf writes
 * the same with D = -i k/k h~ and a negative lambda.)
 *
 * The 2-D inverse transform is split (see enum ocean_column): five z passes
 * over the kz-dependent parts, then eight real row transforms with the kx
 * factors. Stage 1 (fill_tiles), per tile of OCEAN_COL_TILE kx columns:
 * fill, z pass on contiguous columns while they are in cache, store
 * block-major. Stage 2 (row_blocks), per block of OCEAN_ROW_BLOCK rows: kx
 * factor and the real transform's split in one pass (row_pretwiddle), a
 * half-length c2c straight into the output arrays, Jacobian. Tiles and
 * blocks are shared among the pool's threads. One real transform per field
 * measured faster than packing two real fields per c2c: docs/simulation.md.
 *
 * Speed: the phase w t is reduced to a quadrant in double precision (so a
 * sea that has run for days does not jitter), then sin and cos come from
 * short float polynomials in branch-free code that the compiler vectorises;
 * an AVX2 clone is picked at run time. */
#include <math.h>
#include <stdint.h>
#include <string.h>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include "ocean_internal.h"

/* sin and cos of w*t for n modes. Quadrant reduction by the 1.5*2^52 trick:
 * adding it rounds to an integer whose low bits are the quadrant; no
 * libm calls, so the loop vectorises. Valid for |w t| < 2^50 rad. The
 * polynomials are the Cephes library's single-precision minimax ones
 * (S. Moshier, sinf.c / cosf.c: degree 7 / 8 on [-pi/4, pi/4]), error
 * < 8e-8 against double sin/cos: as good as Taylor to degree 9/10, one
 * term shorter each. */
static inline void sincos_row(const double *restrict omega, double t, int n, float *restrict s_out,
                       float *restrict c_out)
{
    const double magic = 6755399441055744.0, two_over_pi = 0.63661977236758134308,
                 pio2_hi = 1.5707963267948966192, pio2_lo = 6.123233995736766036e-17;
    for (int i = 0; i < n; i++) {
        double y = omega[i] * t;
        double q = y * two_over_pi + magic;
        uint64_t bits;
        memcpy(&bits, &q, sizeof bits);
        q -= magic;
        float r = (float)((y - q * pio2_hi) - q * pio2_lo);
        float r2 = r * r;
        float sn = r + r * r2 * (-1.6666654611e-1f + r2 * (8.3321608736e-3f + r2 * -1.9515295891e-4f));
        float cs = 1.0f - 0.5f * r2 + r2 * r2 * (4.166664568298827e-2f + r2 * (-1.388731625493765e-3f +
                                                                                 r2 * 2.443315711809948e-5f));
        unsigned quad = (unsigned)bits & 3u;
        float s1 = (quad & 1u) ? cs : sn;     /* quadrants 1, 3 swap sin and cos */
        float c1 = (quad & 1u) ? sn : cs;
        s_out[i] = (quad & 2u) ? -s1 : s1;    /* quadrants 2, 3: sin < 0 */
        c_out[i] = ((quad + 1u) & 2u) ? -c1 : c1; /* quadrants 1, 2: cos < 0 */
    }
}

struct fill_ctx {
    struct ocean *o;
    struct ocean_grid *g; /* the grid stepped: cascade 0's (o->g) or a finer cascade's */
    double t;
    unsigned cols;  /* ocean_column bits */
    unsigned tm;    /* transforms (fields) */
    unsigned skip;  /* benchmark: OCEAN_SKIP_* parts of our own work left out (all: FFTW only) */
    const struct ocean_foam_update *foam; /* or NULL: no foam this step */
    float ease_w;   /* < 1: an easing is under way, the fill mixes g->ease_from into the amplitudes */
};

/* Which z-pass spectra a set of transforms needs. */
static unsigned columns_for(unsigned tm)
{
    unsigned c = 0;
    if (tm & (1u << TR_H | 1u << TR_SX)) c |= 1u << COL_H;
    if (tm & (1u << TR_SZ)) c |= 1u << COL_KZ;
    if (tm & (1u << TR_DX | 1u << TR_JXX)) c |= 1u << COL_INVK;
    if (tm & (1u << TR_DZ | 1u << TR_JXZ)) c |= 1u << COL_KZINVK;
    if (tm & (1u << TR_JZZ)) c |= 1u << COL_KZ2INVK;
    return c;
}

/* One column (fixed kx) of a z-pass spectrum, N values along kz, from h~
 * (interleaved complex) and lambda coth(kD)/k of that column; kz and
 * constants folded in (enum ocean_column). COL_H is h~ itself: the z pass
 * transforms the h~ column in place, no copy. */
__attribute__((target_clones("avx512f", "avx2", "default")))
static void column_spectrum(float *restrict out, const float *restrict h, const float *restrict invk,
                            const float *restrict kz, int col, int n)
{
    switch (col) {
    case COL_KZ: /* i kz h~ = slope_z */
        for (int i = 0; i < n; i++) {
            out[2 * i] = -kz[i] * h[2 * i + 1];
            out[2 * i + 1] = kz[i] * h[2 * i];
        }
        break;
    case COL_INVK: /* lambda h~/k */
        for (int i = 0; i < n; i++) {
            out[2 * i] = invk[i] * h[2 * i];
            out[2 * i + 1] = invk[i] * h[2 * i + 1];
        }
        break;
    case COL_KZINVK: /* i lambda kz h~/k = Dz */
        for (int i = 0; i < n; i++) {
            float f = kz[i] * invk[i];
            out[2 * i] = -f * h[2 * i + 1];
            out[2 * i + 1] = f * h[2 * i];
        }
        break;
    default: /* COL_KZ2INVK: -lambda kz^2 h~/k = dDz/dz */
        for (int i = 0; i < n; i++) {
            float f = -kz[i] * kz[i] * invk[i];
            out[2 * i] = f * h[2 * i];
            out[2 * i + 1] = f * h[2 * i + 1];
        }
        break;
    }
}

/* A worker's fill scratch for one tile of T columns: h~ (interleaved
 * complex, column-major), then the spectrum being transformed, both T
 * columns of N complex with column stride tile_sd complex: N plus a cache
 * line, so that T columns, a multiple of 4 KiB apart otherwise, do not all
 * fall into the same L1 set. Same layout and alignment, so col_plan runs
 * on either (the h~ tile is COL_H's spectrum). Then the sines and cosines
 * of one column's phases (rows 0 .. N/2, padded to 16). */
static size_t tile_sd(int n) { return (size_t)n + 8; }
static size_t phase_floats(int n) { return (size_t)n / 2 + 16; }
size_t ocean_tile_floats(int n, int tile) { return (size_t)4 * tile * tile_sd(n) + 2 * phase_floats(n); }
float *ocean_tile_spectrum(float *scratch, int n, int tile) { return scratch + (size_t)2 * tile * tile_sd(n); }
int ocean_tile_dist(int n) { return (int)tile_sd(n); }
/* Stage 2's scratch: one block of kx-factored input (B x nh complex), then
 * the block's three Jacobian terms and a field's block of rows on its way
 * to the output (B x N floats each); 64-byte aligned. */
static size_t row_buf_floats(int n) { return ((size_t)2 * OCEAN_ROW_BLOCK * (n / 2 + 1) + 15) & ~(size_t)15; }
size_t ocean_row_scratch_floats(int n) { return row_buf_floats(n) + (size_t)4 * OCEAN_ROW_BLOCK * n; }
float *ocean_row_jacobian_terms(float *scratch, int n) { return scratch + row_buf_floats(n); }

/* h~(k, t) down one kx column (N modes, N a multiple of 16), interleaved
 * complex, from its column-major amplitudes (ocean_amp_col):
 * h~ = (a c + b s) + i (d c - e s). w depends on |k| only (one value per
 * ring, ocean_grid.c), so rows iz and N - iz of a column have the same w, bit
 * for bit: sin and cos are computed for rows 0 .. N/2 only (16 at a time:
 * a fixed trip count vectorises fully) into s, c (phase_floats each), and
 * rows N/2+1 .. N-1 use those of row N - iz. Half the phase work. */
__attribute__((target_clones("avx512f", "avx2", "default")))
static void fill_column(const float *restrict col, double t, int n, float *restrict h, float *restrict s,
                        float *restrict c)
{
    const float *a = col, *b = col + n, *d = col + 2 * (size_t)n, *e = col + 3 * (size_t)n;
    const double *omega = (const double *)(col + 5 * (size_t)n);
    const int half = n / 2;
    for (int i0 = 0; i0 <= half; i0 += 16)
        sincos_row(omega + i0, t, 16, s + i0, c + i0);
    for (int i = 0; i <= half; i++) {
        h[2 * i] = a[i] * c[i] + b[i] * s[i];
        h[2 * i + 1] = d[i] * c[i] - e[i] * s[i];
    }
    for (int i = half + 1; i < n; i++) {
        const int m = n - i; /* same |kz|, same w */
        h[2 * i] = a[i] * c[m] + b[i] * s[m];
        h[2 * i + 1] = d[i] * c[m] - e[i] * s[m];
    }
}

/* fill_column during an easing: the amplitudes are ocean_ease_mix(from,
 * to, w) per mode (from: the column's OCEAN_EASE_COL_FLOATS), the rest as
 * above. A separate function so that the usual step's loop is untouched. */
__attribute__((target_clones("avx512f", "avx2", "default")))
static void fill_column_eased(const float *restrict col, const float *restrict from, float w, double t, int n,
                              float *restrict h, float *restrict s, float *restrict c)
{
    const float *a = col, *b = col + n, *d = col + 2 * (size_t)n, *e = col + 3 * (size_t)n;
    const float *fa = from, *fb = from + n, *fd = from + 2 * (size_t)n, *fe = from + 3 * (size_t)n;
    const double *omega = (const double *)(col + 5 * (size_t)n);
    const int half = n / 2;
    for (int i0 = 0; i0 <= half; i0 += 16)
        sincos_row(omega + i0, t, 16, s + i0, c + i0);
    for (int i = 0; i < n; i++) {
        const int m = i <= half ? i : n - i; /* same |kz|, same w */
        const float ai = ocean_ease_mix(fa[i], a[i], w), bi = ocean_ease_mix(fb[i], b[i], w);
        const float di = ocean_ease_mix(fd[i], d[i], w), ei = ocean_ease_mix(fe[i], e[i], w);
        h[2 * i] = ai * c[m] + bi * s[m];
        h[2 * i + 1] = di * c[m] - ei * s[m];
    }
}

/* Whether this step writes with non-temporal stores where they pay from
 * from_n on (OCEAN_STREAM_STORE_FROM_N, OCEAN_STREAM_OUT_FROM_N), or as the
 * benchmark's and tests' flags force. */
static bool streams(const struct fill_ctx *c, int from_n)
{
    return (c->g->n >= from_n || (c->skip & OCEAN_STORE_STREAMING)) && !(c->skip & OCEAN_STORE_FFTW);
}

/* count floats (a multiple of 4, both ends 16-byte aligned) with
 * non-temporal stores. They are weakly ordered: the caller fences
 * (stream_fence) before anyone reads them. */
static inline void stream_floats(float *restrict dst, const float *restrict src, size_t count)
{
#if defined(__SSE__)
    for (size_t i = 0; i < count; i += 4)
        _mm_stream_ps(dst + i, _mm_load_ps(src + i));
#else
    memcpy(dst, src, count * sizeof(float));
#endif
}

static inline void stream_fence(void)
{
#if defined(__SSE__)
    _mm_sfence();
#endif
}

/* store_plan's copy with non-temporal stores (N >= OCEAN_STREAM_STORE_FROM_N):
 * a transformed tile (T columns of N complex, stride sd) into its columns
 * of the block-major spectrum. Per block of B rows the tile's T x B
 * complex are one contiguous run of the destination, written whole, so
 * the cache's read of each line before writing it (21 MB a step at N =
 * 1024 with the five spectra) is wasted; streaming stores skip it. Hand-
 * written because FFTW's copy plans use ordinary stores. Every address is
 * 64-byte aligned (OCEAN_ROW_BLOCK complex = 64 bytes, aligned arrays). */
static void store_tile_streaming(float *restrict dst, const float *restrict src, int n, int nh, int T, size_t sd,
                                 int c0)
{
    enum { B = OCEAN_ROW_BLOCK };
    for (int b = 0; b < n / B; b++) {
        float *d = dst + 2 * ((size_t)b * nh + c0) * B;
        const float *s = src + 2 * (size_t)b * B;
        for (int j = 0; j < T; j++, d += 2 * B, s += 2 * sd)
            stream_floats(d, s, 2 * B);
    }
    stream_fence(); /* done before the row pass reads them */
}

/* A block of output rows (count floats, contiguous, 64-byte aligned) from
 * the worker's scratch to a field with non-temporal stores (N >=
 * OCEAN_STREAM_OUT_FROM_N): the field is written whole, so reading each
 * line first (24 MB a step at N = 1024 with six fields) is wasted, as in
 * store_tile_streaming. Hand-written because FFTW writes with ordinary stores. */
static void store_rows_streaming(float *restrict dst, const float *restrict src, size_t count)
{
    stream_floats(dst, src, count);
    stream_fence();
}

/* Fill and z pass of tiles [t0, t1) of T kx columns, fused so that each
 * spectrum is transformed while it is in cache: h~(k,t) of the tile is
 * computed column by column (from the column-major amplitudes, a
 * sequential stream) into the scratch; then per z-pass spectrum the tile's
 * T columns are written contiguously (with lambda coth(kD)/k and kz read
 * straight from the amplitudes and the k table), transformed in place by
 * col_plan (contiguous columns: ~3x faster than FFTW's strided column
 * transform over a row-major array, which copies every column in and out),
 * and stored by store_plan (FFTW's copy; from OCEAN_STREAM_STORE_FROM_N
 * our streaming copy) in the block-major layout that the row pass reads
 * without any reshuffling. COL_H goes last: it is the h~
 * tile itself, transformed in place once the others are made from it. */
static void fill_tiles(void *arg, int t0, int t1, int worker)
{
    const struct fill_ctx *c = arg;
    struct ocean_grid *g = c->g;
    const int n = g->n, T = g->tile;
    const size_t sd = tile_sd(n);
    const float *kz = g->kz;
    float *h = g->scratch + (size_t)worker * g->scratch_floats;
    float *spec = ocean_tile_spectrum(h, n, T);
    float *ps = spec + (size_t)2 * T * sd, *pc = ps + phase_floats(n);
    static const enum ocean_column order[COL_COUNT] = {COL_KZ, COL_INVK, COL_KZINVK, COL_KZ2INVK, COL_H};
    for (int tl = t0; tl < t1; tl++) {
        const int c0 = tl * T;
        for (int j = 0; j < T && !(c->skip & OCEAN_SKIP_FILL); j++) {
            if (c->ease_w < 1.0f)
                fill_column_eased(ocean_amp_col(g->ampc, n, c0 + j), ocean_ease_col(g->ease_from, n, c0 + j),
                                  c->ease_w, c->t, n, h + 2 * j * sd, ps, pc);
            else
                fill_column(ocean_amp_col(g->ampc, n, c0 + j), c->t, n, h + 2 * j * sd, ps, pc);
        }
        for (int q = 0; q < COL_COUNT; q++) {
            const enum ocean_column k = order[q];
            if (!(c->cols & (1u << k)))
                continue;
            float *z = k == COL_H ? h : spec;
            for (int j = 0; j < T && k != COL_H && !(c->skip & OCEAN_SKIP_SPECTRA); j++)
                column_spectrum(spec + 2 * j * sd, h + 2 * j * sd,
                                ocean_amp_col(g->ampc, n, c0 + j) + 4 * (size_t)n, kz, k, n);
            fftwf_execute_dft(g->col_plan, (fftwf_complex *)z, (fftwf_complex *)z);
            if (streams(c, OCEAN_STREAM_STORE_FROM_N))
                store_tile_streaming(g->col[k], z, n, g->nh, T, sd, c0);
            else
                fftwf_execute_dft(g->store_plan, (fftwf_complex *)z,
                                  (fftwf_complex *)(g->col[k] + 2 * (size_t)c0 * OCEAN_ROW_BLOCK));
        }
    }
}

/* A kx factor of the row pass: i kx (slope_x, Dx, dDx/dz) or -kx^2 (dDx/dx). */
enum kx_factor { KX_NONE, KX_I, KX_NEG2 };

/* out = factor(kx) * in for one block of B rows (block-major, see
 * ocean_grid.col): contiguous in and out, vectorised. */
__attribute__((target_clones("avx2", "default"))) /* GCC's AVX-512 version of this loop is slower */
static void block_factor(float *restrict out, const float *restrict in, enum kx_factor how,
                         const float *restrict kx, int nh)
{
    enum { B = OCEAN_ROW_BLOCK };
    for (int ix = 0; ix < nh; ix++, in += 2 * B, out += 2 * B) {
        const float m = how == KX_I ? kx[ix] : -kx[ix] * kx[ix];
        if (how == KX_I)
            for (int r = 0; r < B; r++) {
                out[2 * r] = -m * in[2 * r + 1];
                out[2 * r + 1] = m * in[2 * r];
            }
        else
            for (int r = 0; r < 2 * B; r++)
                out[r] = m * in[r];
    }
}

/* The row pass's real transforms as half-length complex ones. A row's
 * N-point c2r (FFTW's backward real transform of the half spectrum X[0 ..
 * N/2]) equals one N/2-point c2c of
 *   Z[k] = E[k] + i O[k],  E[k] = X[k] + conj(X[N/2-k]),
 *   O[k] = (X[k] - conj(X[N/2-k])) e^{2 pi i k/N},  k = 0 .. N/2-1,
 * whose output, read as N floats, is the row itself (re = even samples, im
 * = odd ones): the even and odd outputs are the two half-length transforms
 * of the spectrum folded at N/2 (Cooley-Tukey's first split, with X's
 * symmetry X[N-k] = conj(X[k])). This pass writes Z for one block of B
 * rows (interleaved, as the input) with the field's kx factor folded in
 * (X[k] times i kx, -kx^2 or 1); row_half_plan does the rest. Hand-written
 * because FFTW's batched c2r of interleaved rows runs scalar codelets
 * (r2cb) where the c2c runs AVX ones: a six-field step x0.57-0.94 at 64 to
 * 2048, a draw at 1024 (make bench-step, "rows_half" rows); the input is
 * left as it was. The kx factor is a constant argument of an always_inline
 * function, so each of the three loops is compiled and vectorised apart. */
static inline __attribute__((always_inline)) void pretwiddle_rows(float *restrict z, const float *restrict in,
                                                                  enum kx_factor how, const float *restrict kx,
                                                                  const float *restrict tw, int half)
{
    enum { B = OCEAN_ROW_BLOCK };
    for (int k = 0; k < half; k++) {
        const float *a = in + 2 * (size_t)k * B, *b = in + 2 * (size_t)(half - k) * B; /* X[k], X[N/2-k] */
        const float c = tw[2 * k], s = tw[2 * k + 1];
        const float ma = how == KX_I ? kx[k] : -kx[k] * kx[k];
        const float mb = how == KX_I ? kx[half - k] : -kx[half - k] * kx[half - k];
        float *o = z + 2 * (size_t)k * B;
        for (int r = 0; r < B; r++) {
            float ar, ai, br, bi; /* X[k] and conj(X[N/2-k]), factors applied */
            if (how == KX_NONE) {
                ar = a[2 * r], ai = a[2 * r + 1], br = b[2 * r], bi = -b[2 * r + 1];
            } else if (how == KX_I) {
                ar = -ma * a[2 * r + 1], ai = ma * a[2 * r], br = -mb * b[2 * r + 1], bi = -mb * b[2 * r];
            } else {
                ar = ma * a[2 * r], ai = ma * a[2 * r + 1], br = mb * b[2 * r], bi = -mb * b[2 * r + 1];
            }
            const float er = ar + br, ei = ai + bi, dr = ar - br, di = ai - bi;
            const float orr = dr * c - di * s, oi = dr * s + di * c; /* O[k] */
            o[2 * r] = er - oi; /* E + i O */
            o[2 * r + 1] = ei + orr;
        }
    }
}

__attribute__((target_clones("avx2", "default")))
static void row_pretwiddle(float *restrict z, const float *restrict in, enum kx_factor how, const float *restrict kx,
                           const float *restrict tw, int half)
{
    if (how == KX_NONE)
        pretwiddle_rows(z, in, KX_NONE, kx, tw, half);
    else if (how == KX_I)
        pretwiddle_rows(z, in, KX_I, kx, tw, half);
    else
        pretwiddle_rows(z, in, KX_NEG2, kx, tw, half);
}

/* A row block's Jacobian from its three terms, and with u the foam
 * update (ocean_foam_samples) in the same pass, while J is in a register:
 * the same float operations as ocean_combine_jacobian and
 * ocean_foam_samples one after the other, so the same bits. */
__attribute__((target_clones("avx512f", "avx2", "default")))
static void jacobian_foam(float *restrict J, float *restrict foam, const float *restrict xx,
                          const float *restrict zz, const float *restrict xz, size_t count,
                          const struct ocean_foam_update *u)
{
    if (!u) {
        for (size_t i = 0; i < count; i++)
            J[i] = (1.0f + xx[i]) * (1.0f + zz[i]) - xz[i] * xz[i];
        return;
    }
    const float decay = u->decay, jc = u->threshold, inv = u->inv_ramp;
    for (size_t i = 0; i < count; i++) {
        float j = (1.0f + xx[i]) * (1.0f + zz[i]) - xz[i] * xz[i];
        J[i] = j;
        float in = (jc - j) * inv;
        in = in < 0.0f ? 0.0f : in > 1.0f ? 1.0f : in;
        float old = foam[i] * decay;
        foam[i] = old > in ? old : in;
    }
}

/* Row stage over blocks [b0, b1) of OCEAN_ROW_BLOCK rows. A block of a
 * z-pass spectrum is contiguous, B rows interleaved: row_pretwiddle reads
 * it with the field's kx factor (slope_x, Dx, dDx/dz: i kx; dDx/dx: -kx^2)
 * into the worker's buffer, and row_half_plan writes the rows into the
 * output: straight below OCEAN_STREAM_OUT_FROM_N, from there through the
 * worker's scratch and store_rows_streaming. The Jacobian's three terms go
 * into the worker's scratch, and the block's Jacobian (and foam, if asked
 * for) is made from them while they are in cache. The reference (OCEAN_ROWS_C2R):
 * FFTW's c2r, fields without a kx factor straight from the spectrum, last,
 * since c2r destroys its input, the others after block_factor. */
static void row_blocks(void *arg, int b0, int b1, int worker)
{
    const struct fill_ctx *c = arg;
    struct ocean_grid *g = c->g;
    const int n = g->n, nh = g->nh, B = OCEAN_ROW_BLOCK;
    const unsigned tm = c->tm;
    float *buf = g->scratch + (size_t)worker * g->scratch_floats;
    float *terms = ocean_row_jacobian_terms(buf, n);
    float *rows = terms + (size_t)3 * B * n; /* a block of output rows before its streaming store */
    const bool stream = streams(c, OCEAN_STREAM_OUT_FROM_N);
    static const struct {
        enum ocean_transform tr;
        enum ocean_column col;
        enum kx_factor f;
    } order[] = { /* per spectrum, the factor fields before the direct one */
        {TR_SX, COL_H, KX_I}, {TR_H, COL_H, KX_NONE}, {TR_SZ, COL_KZ, KX_NONE},
        {TR_DX, COL_INVK, KX_I}, {TR_JXX, COL_INVK, KX_NEG2}, {TR_JXZ, COL_KZINVK, KX_I},
        {TR_DZ, COL_KZINVK, KX_NONE}, {TR_JZZ, COL_KZ2INVK, KX_NONE}};
    for (int blk = b0; blk < b1; blk++) {
        const int r0 = blk * B;
        const size_t at = (size_t)r0 * n, count = (size_t)B * n;
        float *jac[3]; /* this block's Jacobian terms */
        for (int k = 0; k < 3; k++)
            jac[k] = g->jac[k] ? g->jac[k] + at : terms + k * count;
        /* The Nyquist column is zero and the fill never writes it, but a
         * reference step's direct c2r (OCEAN_ROWS_C2R: benchmark, tests) may
         * have scribbled on it (c2r destroys its input): clear it before any
         * field of this block reads it. */
        for (int k = 0; k < COL_COUNT && !(c->skip & OCEAN_SKIP_FACTORS); k++)
            if (c->cols & (1u << k))
                memset(g->col[k] + 2 * ((size_t)blk * nh + nh - 1) * B, 0, 2 * B * sizeof(float));
        for (size_t q = 0; q < sizeof order / sizeof order[0]; q++) {
            const enum ocean_transform tr = order[q].tr;
            if (!(tm & (1u << tr)))
                continue;
            float *in = g->col[order[q].col] + 2 * (size_t)blk * nh * B;
            float *out = tr >= TR_JXX ? jac[tr - TR_JXX] : ocean_transform_dest(g, tr) + at;
            if (!(c->skip & OCEAN_ROWS_C2R)) {
                row_pretwiddle(buf, in, c->skip & OCEAN_SKIP_FACTORS ? KX_NONE : order[q].f, g->kx, g->row_twiddle,
                               n / 2);
                if (stream && tr < TR_JXX) {
                    fftwf_execute_dft(g->row_half_plan, (fftwf_complex *)buf, (fftwf_complex *)rows);
                    store_rows_streaming(out, rows, count);
                } else {
                    fftwf_execute_dft(g->row_half_plan, (fftwf_complex *)buf, (fftwf_complex *)out);
                }
            } else if (order[q].f != KX_NONE) {
                if (!(c->skip & OCEAN_SKIP_FACTORS))
                    block_factor(buf, in, order[q].f, g->kx, nh);
                fftwf_execute_dft_c2r(g->row_plan, (fftwf_complex *)buf, out);
            } else {
                fftwf_execute_dft_c2r(g->row_plan, (fftwf_complex *)in, out);
            }
        }
        if ((tm & (1u << TR_JXX)) && !(c->skip & OCEAN_SKIP_JACOBIAN)) { /* all three Jacobian terms are there */
            jacobian_foam(g->out[OCEAN_JACOBIAN] + at, g->out[OCEAN_FOAM] + at, jac[0], jac[1], jac[2], count,
                          c->foam);
        }
    }
}

/* Both stages of a step. Stage 1 (fill + z pass) needs every row of its
 * columns, stage 2 (row pass) every column of its rows, so they are two
 * rounds on the pool. With every OCEAN_SKIP_* set, exactly the FFTW executes of a
 * step run (same arrays, same threads): the benchmark's reference. */
static void run_step(struct fill_ctx *c, int threads)
{
    struct ocean_grid *g = c->g;
    struct pool *pool = c->o->pool;
    /* Tiles cover kx columns 0 .. N/2-1; the Nyquist column is zero. */
    pool_for(pool, threads, (g->n / 2) / g->tile, fill_tiles, c);
    pool_for(pool, threads, g->n / OCEAN_ROW_BLOCK, row_blocks, c);
}

static int step_threads(const struct ocean_grid *g)
{
    return g->n >= OCEAN_THREADS_FROM_N ? g->workers : 1;
}

void ocean_step_parts(struct ocean *o, double t, unsigned fields, unsigned skip)
{
    if ((skip & OCEAN_ROWS_C2R) && ocean_reference_row_plan(o->g) != 0)
        return;
    unsigned tm = ocean_transforms_for(fields);
    struct fill_ctx c = {o, o->g, ocean_phase_time(o, t), columns_for(tm), tm, skip, NULL, 1.0f};
    run_step(&c, step_threads(o->g));
}

void ocean_fft_only(struct ocean *o, unsigned fields)
{
    ocean_step_parts(o, 0, fields, OCEAN_SKIP_ALL);
}

int ocean_step_fft_grid(struct ocean *o, struct ocean_grid *g, double t, unsigned fields,
                        const struct ocean_foam_update *foam)
{
    unsigned tm = ocean_transforms_for(fields);
    if (!tm)
        return 0;
    if (foam && !(tm & (1u << TR_JXX)))
        return -1;
    /* The easing's weight from t itself, not the phase time: an easing is
     * in sim time, whether or not the sea loops. */
    float ease_w = g->ease_from ? ocean_ease_weight(g->ease_t0, g->ease_len, t) : 1.0f;
    struct fill_ctx c = {o, g, ocean_phase_time(o, t), columns_for(tm), tm, 0, foam, ease_w};
    run_step(&c, step_threads(g));
    return 0;
}

int ocean_step_fft_foam(struct ocean *o, double t, unsigned fields, const struct ocean_foam_update *foam)
{
    return ocean_step_fft_grid(o, o->g, t, fields, foam);
}

int ocean_step_fft(struct ocean *o, double t, unsigned fields)
{
    return ocean_step_fft_foam(o, t, fields, NULL);
}

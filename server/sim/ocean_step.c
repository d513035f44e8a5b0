/* ocean_step.c — one time step on the FFT path.
 *
 * Per mode of the half spectrum: h~(k,t) = h~0(k) e^{-iwt} + conj(h~0(-k)) e^{iwt}
 * (a wave h~0 e^{i(k.x - wt)} travels along +k, i.e. downwind), then each
 * requested real field's spectrum is h~ times a factor:
 *   height 1, Dx i lambda kx/k, Dz i lambda kz/k, slopes i kx, i kz,
 *   Jacobian terms -lambda kx^2/k, -lambda kz^2/k, -lambda kx kz/k,
 * where every "1/k" is coth(kD)/k in water of depth D (linear theory's
 * orbits are wider than tall in shallow water; 1/k in deep water): the
 * per-mode "invk" below holds that, displacement_over_k().
 * (lambda > 0 moves points toward crests and sharpens them; Tessendorf writes
 * the same with D = -i k/k h~ and a negative lambda.)
 *
 * The 2-D inverse transform is split (see enum ocean_column): five z passes
 * over the kz-dependent parts, then eight row c2r with the kx factors.
 * Stage 1 (fill_tiles), per tile of OCEAN_COL_TILE kx columns: fill, z
 * pass on contiguous columns while they are in cache, store block-major.
 * Stage 2 (row_blocks), per block of OCEAN_ROW_BLOCK rows: kx factor where
 * needed, c2r straight into the output arrays, Jacobian. Tiles and blocks
 * are shared among the pool's threads. Real-to-complex (c2r) measured
 * faster than packing two real fields per c2c: docs/simulation.md.
 *
 * Speed: the phase w t is reduced to a quadrant in double precision (so a
 * sea that has run for days does not jitter), then sin and cos come from
 * short float polynomials in branch-free code that the compiler vectorises;
 * an AVX2 clone is picked at run time. */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "ocean_internal.h"

/* sin and cos of w*t for n modes. Quadrant reduction by the 1.5*2^52 trick:
 * adding it rounds to an integer whose low bits are the quadrant; no
 * libm calls, so the loop vectorises. Valid for |w t| < 2^50 rad. The
 * polynomials are Taylor to degree 9/10 on [-pi/4, pi/4]: error < 4e-8. */
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
        float sn = r * (1.0f + r2 * (-1.0f / 6 + r2 * (1.0f / 120 + r2 * (-1.0f / 5040 + r2 * (1.0f / 362880)))));
        float cs = 1.0f + r2 * (-0.5f + r2 * (1.0f / 24 + r2 * (-1.0f / 720 + r2 * (1.0f / 40320 + r2 * (-1.0f / 3628800)))));
        unsigned quad = (unsigned)bits & 3u;
        float s1 = (quad & 1u) ? cs : sn;     /* quadrants 1, 3 swap sin and cos */
        float c1 = (quad & 1u) ? sn : cs;
        s_out[i] = (quad & 2u) ? -s1 : s1;    /* quadrants 2, 3: sin < 0 */
        c_out[i] = ((quad + 1u) & 2u) ? -c1 : c1; /* quadrants 1, 2: cos < 0 */
    }
}

struct fill_ctx {
    struct ocean *o;
    double t;
    unsigned cols;  /* ocean_column bits */
    unsigned tm;    /* transforms (fields) */
    float lambda;
    int fft_only;   /* benchmark: run the same FFTW executes, skip our own work */
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
 * and lambda/k of that column; kz and constants folded in (enum ocean_column). */
__attribute__((target_clones("avx2", "default")))
static void column_spectrum(float *restrict out, const float *restrict hr, const float *restrict hi,
                            const float *restrict invk, const float *restrict kz, int col, int n)
{
    switch (col) {
    case COL_H: /* h~ */
        for (int i = 0; i < n; i++) {
            out[2 * i] = hr[i];
            out[2 * i + 1] = hi[i];
        }
        break;
    case COL_KZ: /* i kz h~ = slope_z */
        for (int i = 0; i < n; i++) {
            out[2 * i] = -kz[i] * hi[i];
            out[2 * i + 1] = kz[i] * hr[i];
        }
        break;
    case COL_INVK: /* lambda h~/k */
        for (int i = 0; i < n; i++) {
            out[2 * i] = invk[i] * hr[i];
            out[2 * i + 1] = invk[i] * hi[i];
        }
        break;
    case COL_KZINVK: /* i lambda kz h~/k = Dz */
        for (int i = 0; i < n; i++) {
            float f = kz[i] * invk[i];
            out[2 * i] = -f * hi[i];
            out[2 * i + 1] = f * hr[i];
        }
        break;
    default: /* COL_KZ2INVK: -lambda kz^2 h~/k = dDz/dz */
        for (int i = 0; i < n; i++) {
            float f = -kz[i] * kz[i] * invk[i];
            out[2 * i] = f * hr[i];
            out[2 * i + 1] = f * hi[i];
        }
        break;
    }
}

/* A worker's fill scratch for one tile of T columns: h~ (real, imaginary)
 * and lambda/k, column-major with column stride tile_ld floats; then the
 * spectrum being transformed, T columns of N complex, stride tile_sd. The
 * strides are N plus a cache line, so that T columns, a multiple of 4 KiB
 * apart otherwise, do not all fall into the same L1 set. */
static size_t tile_ld(int n) { return (size_t)n + 16; }
static size_t tile_sd(int n) { return (size_t)n + 8; }
size_t ocean_tile_floats(int n, int tile) { return (size_t)tile * (3 * tile_ld(n) + 2 * tile_sd(n)); }
float *ocean_tile_spectrum(float *scratch, int n, int tile) { return scratch + (size_t)3 * tile * tile_ld(n); }
int ocean_tile_dist(int n) { return (int)tile_sd(n); }

/* The fill's per-row work for the T modes of one row of a tile, read from
 * the tile-ordered amplitudes: h~ = (a c + b s) + i (d c - e s), and
 * lambda/k. */
__attribute__((target_clones("avx2", "default")))
static void tile_row(const struct ocean_tile_row *restrict r, double t, float lam, float *restrict hr,
                     float *restrict hi, float *restrict lk)
{
    /* Always the full OCEAN_COL_TILE (a narrower tile, N < 32, has zero
     * amplitudes in the unused slots): a fixed trip count vectorises fully. */
    float s[OCEAN_COL_TILE], c[OCEAN_COL_TILE];
    sincos_row(r->omega, t, OCEAN_COL_TILE, s, c);
    for (int i = 0; i < OCEAN_COL_TILE; i++) {
        hr[i] = r->a[i] * c[i] + r->b[i] * s[i];
        hi[i] = r->d[i] * c[i] - r->e[i] * s[i];
        lk[i] = lam * r->invk[i];
    }
}

/* Transformed tile -> its columns of the block-major half spectrum: per
 * block of B rows, the tile's T columns are T*B contiguous complex values
 * (1 KiB), copied as T pieces of B values. */
static void store_tile(float *restrict col, const float *restrict spec, size_t sd, int n, int nh, int c0, int T)
{
    enum { B = OCEAN_ROW_BLOCK };
    for (int b = 0; b < n / B; b++) {
        float *dst = col + 2 * (((size_t)b * nh + c0) * B);
        for (int j = 0; j < T; j++)
            memcpy(dst + 2 * (size_t)j * B, spec + 2 * ((size_t)j * sd + (size_t)b * B), 2 * B * sizeof(float));
    }
}

/* Fill and z pass of tiles [t0, t1) of T kx columns, fused so that each
 * spectrum is transformed while it is in cache: h~(k,t) of the tile is
 * computed row by row (from amplitudes stored in tile order, a sequential
 * stream) into a column-major scratch; then per z-pass spectrum the tile's
 * T columns are written contiguously, transformed in place by col_plan
 * (contiguous columns: ~3x faster than FFTW's strided column transform over
 * a row-major array, which copies every column in and out), and stored in
 * the block-major layout that the row pass reads without any reshuffling. */
static void fill_tiles(void *arg, int t0, int t1, int worker)
{
    const struct fill_ctx *c = arg;
    struct ocean_grid *g = c->o->g;
    const int n = g->n, T = g->tile;
    const size_t ld = tile_ld(n), sd = tile_sd(n);
    const float *kz = g->kz, lam = c->lambda;
    float *scratch = g->scratch + (size_t)worker * g->scratch_floats;
    float *hr = scratch, *hi = hr + (size_t)T * ld, *invk = hi + (size_t)T * ld; /* column-major */
    float *spec = ocean_tile_spectrum(scratch, n, T);
    float rr[OCEAN_COL_TILE], ri[OCEAN_COL_TILE], rk[OCEAN_COL_TILE];
    for (int tl = t0; tl < t1; tl++) {
        const int c0 = tl * T;
        if (!c->fft_only) {
            const struct ocean_tile_row *row = g->amp + (size_t)tl * n;
            for (int iz = 0; iz < n; iz++) {
                tile_row(row + iz, c->t, lam, rr, ri, rk);
                for (int j = 0; j < T; j++) {
                    hr[(size_t)j * ld + iz] = rr[j];
                    hi[(size_t)j * ld + iz] = ri[j];
                    invk[(size_t)j * ld + iz] = rk[j];
                }
            }
        }
        for (int k = 0; k < COL_COUNT; k++) {
            if (!(c->cols & (1u << k)))
                continue;
            for (int j = 0; j < T && !c->fft_only; j++)
                column_spectrum(spec + 2 * j * sd, hr + j * ld, hi + j * ld, invk + j * ld, kz, k, n);
            fftwf_execute_dft(g->col_plan, (fftwf_complex *)spec, (fftwf_complex *)spec);
            if (!c->fft_only)
                store_tile(g->col[k], spec, sd, n, g->nh, c0, T);
        }
    }
}

/* A kx factor of the row pass: i kx (slope_x, Dx, dDx/dz) or -kx^2 (dDx/dx). */
enum kx_factor { KX_NONE, KX_I, KX_NEG2 };

/* out = factor(kx) * in for one block of B rows (block-major, see
 * ocean_grid.col): contiguous in and out, vectorised. */
__attribute__((target_clones("avx2", "default")))
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

/* Row stage over blocks [b0, b1) of OCEAN_ROW_BLOCK rows. A block of a
 * z-pass spectrum is contiguous and already in row_plan's input layout:
 * fields without a kx factor are transformed straight from it, last,
 * since c2r destroys its input; the others (slope_x, Dx, dDx/dz: i kx;
 * dDx/dx: -kx^2) get their factor into the worker's buffer first. The c2r
 * writes the rows straight into the output, and the Jacobian of the block
 * is combined while it is in cache. */
static void row_blocks(void *arg, int b0, int b1, int worker)
{
    const struct fill_ctx *c = arg;
    struct ocean_grid *g = c->o->g;
    const int n = g->n, nh = g->nh, B = OCEAN_ROW_BLOCK;
    const unsigned tm = c->tm;
    float *buf = g->scratch + (size_t)worker * g->scratch_floats;
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
        /* The Nyquist column is zero and the fill never writes it, but the
         * previous step's direct c2r may have scribbled on it (c2r destroys
         * its input): clear it before any field of this block reads it. */
        for (int k = 0; k < COL_COUNT && !c->fft_only; k++)
            if (c->cols & (1u << k))
                memset(g->col[k] + 2 * ((size_t)blk * nh + nh - 1) * B, 0, 2 * B * sizeof(float));
        for (size_t q = 0; q < sizeof order / sizeof order[0]; q++) {
            if (!(tm & (1u << order[q].tr)))
                continue;
            float *in = g->col[order[q].col] + 2 * (size_t)blk * nh * B;
            float *out = ocean_transform_dest(g, order[q].tr) + (size_t)r0 * n;
            if (order[q].f != KX_NONE) {
                if (!c->fft_only)
                    block_factor(buf, in, order[q].f, g->kx, nh);
                fftwf_execute_dft_c2r(g->row_plan, (fftwf_complex *)buf, out);
            } else {
                fftwf_execute_dft_c2r(g->row_plan, (fftwf_complex *)in, out);
            }
        }
        if ((tm & (1u << TR_JXX)) && !c->fft_only) /* all three Jacobian terms are there */
            ocean_combine_jacobian_rows(g, r0, r0 + B);
    }
}

/* Both stages of a step. Stage 1 (fill + z pass) needs every row of its
 * columns, stage 2 (row pass) every column of its rows, so they are two
 * rounds on the pool. With fft_only set, exactly the FFTW executes of a
 * step run (same arrays, same threads): the benchmark's reference. */
static void run_step(struct fill_ctx *c, int threads)
{
    struct ocean_grid *g = c->o->g;
    struct ocean_pool *pool = c->o->pool;
    /* Tiles cover kx columns 0 .. N/2-1; the Nyquist column is zero. */
    ocean_parallel(pool, threads, (g->n / 2) / g->tile, fill_tiles, c);
    ocean_parallel(pool, threads, g->n / OCEAN_ROW_BLOCK, row_blocks, c);
}

static int step_threads(const struct ocean *o)
{
    return o->g->n >= OCEAN_THREADS_FROM_N ? o->g->workers : 1;
}

void ocean_fft_only(struct ocean *o, unsigned fields)
{
    unsigned tm = ocean_transforms_for(fields);
    struct fill_ctx c = {o, 0, columns_for(tm), tm, 0, 1};
    run_step(&c, step_threads(o));
}

int ocean_step_fft(struct ocean *o, double t, unsigned fields)
{
    unsigned tm = ocean_transforms_for(fields);
    if (!tm)
        return 0;
    struct fill_ctx c = {o, ocean_phase_time(o, t), columns_for(tm), tm, (float)o->p.choppiness, 0};
    run_step(&c, step_threads(o));
    return 0;
}

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
    double t;
    unsigned cols;  /* ocean_column bits */
    unsigned tm;    /* transforms (fields) */
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
 * and lambda coth(kD)/k of that column; kz and constants folded in (enum ocean_column). */
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

/* A worker's fill scratch for one tile of T columns: h~ (real, imaginary),
 * column-major with column stride tile_ld floats; then the spectrum being
 * transformed, T columns of N complex, stride tile_sd. The strides are N
 * plus a cache line, so that T columns, a multiple of 4 KiB apart
 * otherwise, do not all fall into the same L1 set. */
static size_t tile_ld(int n) { return (size_t)n + 16; }
static size_t tile_sd(int n) { return (size_t)n + 8; }
size_t ocean_tile_floats(int n, int tile) { return (size_t)tile * (2 * tile_ld(n) + 2 * tile_sd(n)); }
float *ocean_tile_spectrum(float *scratch, int n, int tile) { return scratch + (size_t)2 * tile * tile_ld(n); }
int ocean_tile_dist(int n) { return (int)tile_sd(n); }

/* h~(k, t) down one kx column (N modes, N a multiple of 16), from its
 * column-major amplitudes (ocean_amp_col): h~ = (a c + b s) + i (d c - e s),
 * 16 modes at a time (a fixed trip count vectorises fully). */
__attribute__((target_clones("avx2", "default")))
static void fill_column(const float *restrict col, double t, int n, float *restrict hr, float *restrict hi)
{
    const float *a = col, *b = col + n, *d = col + 2 * (size_t)n, *e = col + 3 * (size_t)n;
    const double *omega = (const double *)(col + 5 * (size_t)n);
    for (int i0 = 0; i0 < n; i0 += 16) {
        float s[16], c[16];
        sincos_row(omega + i0, t, 16, s, c);
        for (int i = 0; i < 16; i++) {
            hr[i0 + i] = a[i0 + i] * c[i] + b[i0 + i] * s[i];
            hi[i0 + i] = d[i0 + i] * c[i] - e[i0 + i] * s[i];
        }
    }
}

/* Fill and z pass of tiles [t0, t1) of T kx columns, fused so that each
 * spectrum is transformed while it is in cache: h~(k,t) of the tile is
 * computed column by column (from the column-major amplitudes, a
 * sequential stream) into the scratch; then per z-pass spectrum the tile's
 * T columns are written contiguously (with lambda coth(kD)/k and kz read
 * straight from the amplitudes and the k table), transformed in place by
 * col_plan (contiguous columns: ~3x faster than FFTW's strided column
 * transform over a row-major array, which copies every column in and out),
 * and stored by store_plan (FFTW's copy) in the block-major layout that the
 * row pass reads without any reshuffling. */
static void fill_tiles(void *arg, int t0, int t1, int worker)
{
    const struct fill_ctx *c = arg;
    struct ocean_grid *g = c->o->g;
    const int n = g->n, T = g->tile;
    const size_t ld = tile_ld(n), sd = tile_sd(n);
    const float *kz = g->kz;
    float *scratch = g->scratch + (size_t)worker * g->scratch_floats;
    float *hr = scratch, *hi = hr + (size_t)T * ld; /* column-major */
    float *spec = ocean_tile_spectrum(scratch, n, T);
    for (int tl = t0; tl < t1; tl++) {
        const int c0 = tl * T;
        for (int j = 0; j < T && !c->fft_only; j++)
            fill_column(ocean_amp_col(g->ampc, n, c0 + j), c->t, n, hr + j * ld, hi + j * ld);
        for (int k = 0; k < COL_COUNT; k++) {
            if (!(c->cols & (1u << k)))
                continue;
            for (int j = 0; j < T && !c->fft_only; j++)
                column_spectrum(spec + 2 * j * sd, hr + j * ld, hi + j * ld,
                                ocean_amp_col(g->ampc, n, c0 + j) + 4 * (size_t)n, kz, k, n);
            fftwf_execute_dft(g->col_plan, (fftwf_complex *)spec, (fftwf_complex *)spec);
            fftwf_execute_dft(g->store_plan, (fftwf_complex *)spec,
                              (fftwf_complex *)(g->col[k] + 2 * (size_t)c0 * OCEAN_ROW_BLOCK));
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
    struct fill_ctx c = {o, 0, columns_for(tm), tm, 1};
    run_step(&c, step_threads(o));
}

int ocean_step_fft(struct ocean *o, double t, unsigned fields)
{
    unsigned tm = ocean_transforms_for(fields);
    if (!tm)
        return 0;
    struct fill_ctx c = {o, ocean_phase_time(o, t), columns_for(tm), tm, 0};
    run_step(&c, step_threads(o));
    return 0;
}

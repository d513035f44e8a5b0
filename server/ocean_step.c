/* ocean_step.c — one time step on the FFT path.
 *
 * Per mode of the half spectrum: h~(k,t) = h~0(k) e^{-iwt} + conj(h~0(-k)) e^{iwt}
 * (a wave h~0 e^{i(k.x - wt)} travels along +k, i.e. downwind), then each
 * requested real field's spectrum is h~ times a factor:
 *   height 1, Dx i lambda kx/k, Dz i lambda kz/k, slopes i kx, i kz,
 *   Jacobian terms -lambda kx^2/k, -lambda kz^2/k, -lambda kx kz/k.
 * (lambda > 0 moves points toward crests and sharpens them; Tessendorf writes
 * the same with D = -i k/k h~ and a negative lambda.)
 *
 * The 2-D inverse transform is split (see enum ocean_column): five z passes
 * over the kz-dependent parts, then per block of rows the kx factor and a
 * batch of c2r along x straight into the output arrays, while the block is
 * in cache. Real-to-complex (c2r) measured faster than packing two real
 * fields per c2c: notes/readme-sim.md.
 *
 * Speed: the phase w t is reduced to a quadrant in double precision (so a
 * sea that has run for days does not jitter), then sin and cos come from
 * short float polynomials in branch-free code that the compiler vectorises;
 * an AVX2 clone is picked at run time. Rows are split across threads. */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "ocean_internal.h"

#define MAX_NH 1025 /* N/2 + 1 for N = 2048 */

/* sin and cos of w*t for one row. Quadrant reduction by the 1.5*2^52 trick:
 * adding it rounds to an integer whose low bits are the quadrant; no
 * libm calls, so the loop vectorises. Valid for |w t| < 2^50 rad. The
 * polynomials are Taylor to degree 9/10 on [-pi/4, pi/4]: error < 4e-8. */
__attribute__((target_clones("avx2", "default")))
static void sincos_row(const double *restrict omega, double t, int n, float *restrict s_out,
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

__attribute__((target_clones("avx2", "default")))
static void row_height(const float *restrict a, const float *restrict b, const float *restrict d,
                       const float *restrict e, const float *restrict s, const float *restrict c,
                       float *restrict hr, float *restrict hi, int n)
{
    for (int i = 0; i < n; i++) {
        hr[i] = a[i] * c[i] + b[i] * s[i];
        hi[i] = d[i] * c[i] - e[i] * s[i];
    }
}

/* out = f * (hr + i hi), interleaved */
__attribute__((target_clones("avx2", "default")))
static void put_scaled(float *restrict out, const float *restrict hr, const float *restrict hi,
                       const float *restrict f, int n)
{
    for (int i = 0; i < n; i++) {
        out[2 * i] = f[i] * hr[i];
        out[2 * i + 1] = f[i] * hi[i];
    }
}

/* out = i f (hr + i hi), interleaved */
__attribute__((target_clones("avx2", "default")))
static void put_scaled_i(float *restrict out, const float *restrict hr, const float *restrict hi,
                         const float *restrict f, int n)
{
    for (int i = 0; i < n; i++) {
        out[2 * i] = -f[i] * hi[i];
        out[2 * i + 1] = f[i] * hr[i];
    }
}

/* Fill: h~(k,t) per mode, and the kz-dependent spectra the z passes need. */
static void fill_rows(void *arg, int r0, int r1, int worker)
{
    const struct fill_ctx *c = arg;
    struct ocean_grid *g = c->o->g;
    const int nh = g->nh;
    const float *kx = g->kx, lam = c->lambda;
    float s[MAX_NH], co[MAX_NH], hr[MAX_NH], hi[MAX_NH], invk[MAX_NH], f[MAX_NH];
    for (int iz = r0; iz < r1; iz++) {
        size_t base = (size_t)iz * nh;
        const float kz = g->kz[iz];
        sincos_row(g->omega + base, c->t, nh, s, co);
        row_height(g->a + base, g->b + base, g->d + base, g->e + base, s, co, hr, hi, nh);
        /* Constant and kz factors are folded in here (lambda, i), so four
         * fields need no work at the row stage at all. */
        if (c->cols & (1u << COL_H)) { /* h~ */
            float *o = g->col[COL_H] + 2 * base;
            for (int i = 0; i < nh; i++) {
                o[2 * i] = hr[i];
                o[2 * i + 1] = hi[i];
            }
        }
        if (c->cols & (1u << COL_KZ)) { /* i kz h~ = slope_z */
            for (int i = 0; i < nh; i++) f[i] = kz;
            put_scaled_i(g->col[COL_KZ] + 2 * base, hr, hi, f, nh);
        }
        if (c->cols & (1u << COL_INVK | 1u << COL_KZINVK | 1u << COL_KZ2INVK))
            for (int i = 0; i < nh; i++) {
                float k2 = kx[i] * kx[i] + kz * kz;
                invk[i] = k2 > 0 ? lam / sqrtf(k2) : 0.0f; /* lambda / k */
            }
        if (c->cols & (1u << COL_INVK)) /* lambda h~/k */
            put_scaled(g->col[COL_INVK] + 2 * base, hr, hi, invk, nh);
        if (c->cols & (1u << COL_KZINVK)) { /* i lambda kz h~/k = Dz */
            for (int i = 0; i < nh; i++) f[i] = kz * invk[i];
            put_scaled_i(g->col[COL_KZINVK] + 2 * base, hr, hi, f, nh);
        }
        if (c->cols & (1u << COL_KZ2INVK)) { /* -lambda kz^2 h~/k = dDz/dz */
            for (int i = 0; i < nh; i++) f[i] = -kz * kz * invk[i];
            put_scaled(g->col[COL_KZ2INVK] + 2 * base, hr, hi, f, nh);
        }
    }
}

/* Row stage input for one field: m(kx) * col, times i when `imag`. */
__attribute__((target_clones("avx2", "default")))
static void row_factor(float *restrict out, const float *restrict in, const float *restrict m, int imag, int n)
{
    if (imag)
        for (int i = 0; i < n; i++) {
            out[2 * i] = -m[i] * in[2 * i + 1];
            out[2 * i + 1] = m[i] * in[2 * i];
        }
    else
        for (int i = 0; i < n; i++) {
            out[2 * i] = m[i] * in[2 * i];
            out[2 * i + 1] = m[i] * in[2 * i + 1];
        }
}

/* Row stage over blocks [b0, b1) of OCEAN_ROW_BLOCK rows. Fields that
 * need a kx factor (slope_x, Dx: i kx; dDx/dx: -kx^2; dDx/dz: i kx) get it
 * into the worker's buffer; the others are transformed straight from
 * their z-pass spectrum, last, since c2r destroys its input. */
static void row_blocks(void *arg, int b0, int b1, int worker)
{
    const struct fill_ctx *c = arg;
    struct ocean_grid *g = c->o->g;
    const int n = g->n, nh = g->nh, B = OCEAN_ROW_BLOCK;
    const unsigned tm = c->tm;
    float *buf = g->rowbuf + (size_t)worker * B * nh * 2;
    float ikx[MAX_NH], kx2[MAX_NH];
    for (int i = 0; i < nh; i++) {
        ikx[i] = g->kx[i];
        kx2[i] = -g->kx[i] * g->kx[i];
    }
    for (int blk = b0; blk < b1; blk++) {
        const int r0 = blk * B;
        const size_t off = (size_t)r0 * nh * 2;
#define FACTOR(tr, colk, m, imag)                                                                   \
    if (tm & (1u << (tr))) {                                                                        \
        for (int r = 0; r < B && !c->fft_only; r++)                                                 \
            row_factor(buf + (size_t)r * nh * 2, g->col[colk] + off + (size_t)r * nh * 2, m, imag, nh); \
        fftwf_execute_dft_c2r(g->row_plan, (fftwf_complex *)buf, ocean_transform_dest(g, tr) + (size_t)r0 * n); \
    }
#define DIRECT(tr, colk)                                                                            \
    if (tm & (1u << (tr)))                                                                          \
        fftwf_execute_dft_c2r(g->row_plan, (fftwf_complex *)(g->col[colk] + off),                   \
                              ocean_transform_dest(g, tr) + (size_t)r0 * n);
        FACTOR(TR_SX, COL_H, ikx, 1)
        DIRECT(TR_H, COL_H)
        FACTOR(TR_DX, COL_INVK, ikx, 1)
        FACTOR(TR_JXX, COL_INVK, kx2, 0)
        FACTOR(TR_JXZ, COL_KZINVK, ikx, 1)
        DIRECT(TR_DZ, COL_KZINVK)
        DIRECT(TR_SZ, COL_KZ)
        DIRECT(TR_JZZ, COL_KZ2INVK)
#undef FACTOR
#undef DIRECT
        if ((tm & (1u << TR_JXX)) && !c->fft_only) /* all three Jacobian terms are there */
            ocean_combine_jacobian_rows(g, r0, r0 + B);
    }
}

/* The FFTW executes of a step, exactly as ocean_step_fft runs them (same
 * arrays, same threads), without the fill, the kx factors and the Jacobian. */
static void transforms(struct fill_ctx *c, int threads)
{
    struct ocean_grid *g = c->o->g;
    for (int k = 0; k < COL_COUNT; k++)
        if (c->cols & (1u << k))
            fftwf_execute_dft(g->col_plan, (fftwf_complex *)g->col[k], (fftwf_complex *)g->col[k]);
    ocean_parallel_rows(threads, g->n / OCEAN_ROW_BLOCK, row_blocks, c);
}

static int step_threads(const struct ocean *o)
{
    return o->g->n >= OCEAN_THREADS_FROM_N ? o->g->workers : 1;
}

void ocean_fft_only(struct ocean *o, unsigned fields)
{
    unsigned tm = ocean_transforms_for(fields);
    struct fill_ctx c = {o, 0, columns_for(tm), tm, 0, 1};
    transforms(&c, step_threads(o));
}

int ocean_step_fft(struct ocean *o, double t, unsigned fields)
{
    unsigned tm = ocean_transforms_for(fields);
    if (!tm)
        return 0;
    struct fill_ctx c = {o, ocean_phase_time(o, t), columns_for(tm), tm, (float)o->p.choppiness, 0};
    int threads = step_threads(o);
    ocean_parallel_rows(threads, o->g->n, fill_rows, &c);
    transforms(&c, threads);
    return 0;
}

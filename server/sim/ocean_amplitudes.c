/* ocean_amplitudes.c — the amplitude fill of a parameter change: the cached
 * standard normals per mode (seed), the radial spectrum per ring, then
 * h~0(k), h~0(-k) and w(k) per mode with the fill's column-major copy, and
 * the wavenumber tables. Pure functions of the parameters, run on the
 * preparing thread's pool (ocean_prepare.c); the step only reads the result. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "ocean_internal.h"
#include "sea_model.h"

/* Per mode of the half spectrum, the standard normals of h~0(k) and
 * h~0(-k): a pure function of (seed, integer k), cached because the hash,
 * log and sincos are a fifth of a rebuild. */
struct gauss_ctx {
    int n, nh;
    uint32_t seed;
    float *gauss;
};

static void gauss_rows(void *arg, int r0, int r1, int worker)
{
    const struct gauss_ctx *c = arg;
    for (int iz = r0; iz < r1; iz++) {
        int mz = iz > c->n / 2 ? iz - c->n : iz;
        for (int mx = 0; mx < c->nh; mx++) {
            float *q = c->gauss + 4 * ((size_t)iz * c->nh + mx);
            double a, b, ma, mb;
            spectrum_gauss_pair(c->seed, mx, mz, &a, &b);
            spectrum_gauss_pair(c->seed, -mx, -mz, &ma, &mb);
            q[0] = (float)a;
            q[1] = (float)b;
            q[2] = (float)ma;
            q[3] = (float)mb;
        }
    }
}

void ocean_gauss_compute(int n, uint32_t seed, float *gauss, struct pool *pool, int threads)
{
    struct gauss_ctx c = {n, n / 2 + 1, seed, gauss};
    pool_for(pool, threads, n, gauss_rows, &c);
}

/* The radial table (spectrum_radial_at per ring), in `chunks` pieces. */
struct radial_ctx {
    const struct spectrum_model *m;
    const uint32_t *ring_m2;
    struct spectrum_radial *out;
    size_t rings;
    int chunks;
};

static void radial_chunks(void *arg, int c0, int c1, int worker)
{
    const struct radial_ctx *c = arg;
    double dk = 2.0 * M_PI / c->m->patch;
    size_t per = (c->rings + c->chunks - 1) / c->chunks;
    for (size_t r = (size_t)c0 * per; r < (size_t)c1 * per && r < c->rings; r++)
        spectrum_radial_at(c->m, dk * sqrt((double)c->ring_m2[r]), &c->out[r]);
}

struct amp_ctx {
    const struct ocean_grid *g;       /* n, ring */
    const struct spectrum_model *m;
    double lambda;                    /* choppiness, folded into linvk */
    const struct spectrum_radial *radial;
    const float *gauss;
    struct ocean_amps *amps;
};

/* Columns per tile of the amplitude pass (one 64-byte line of each
 * row-major array per row), and rows per block (an item). */
#define AMP_TILE 16
#define AMP_ROWS 16
#define AMP_AHEAD 2 /* rows prefetched ahead */

/* h~0(k) and h~0(-k) per mode from the radial table, the spreading's angle
 * and the cached normals; then a, b, d, e and omega (see ocean_grid) and,
 * in the same pass, the fill's column-major copy (ocean_amp_col). Items are
 * blocks of AMP_ROWS rows, done tile by tile (AMP_TILE columns, kx): the
 * row-major arrays are read and written a line per row and tile, moving
 * along the rows (a tile walked down all N rows started a new page on every
 * row of every array: a TLB and cache miss each); the block's tile is kept
 * in a small buffer and written down each column of the copy a whole cache
 * line at a time (the copy's 6 arrays per column lie a multiple of 4 KiB
 * apart: written a float at a time, 16 columns' worth fall into one L1
 * set). One pass: writing the row-major arrays and reading them back
 * column by column (stride N/2 + 1) for the copy cost a second pass over
 * every array. Same values, bit for bit. */
static void amp_tiles(void *arg, int b0, int b1, int worker)
{
    (void)worker;
    const struct amp_ctx *c = arg;
    const struct ocean_grid *g = c->g;
    const struct spectrum_model *m = c->m;
    struct ocean_amps *s = c->amps;
    const int n = g->n, nh = g->nh, rows = n < AMP_ROWS ? n : AMP_ROWS;
    const double half_dk = 0.5 * 2.0 * M_PI / m->patch, wx = cos(m->wind_angle), wz = sin(m->wind_angle);
    const double lambda = c->lambda;
    float buf[5][AMP_TILE][AMP_ROWS]; /* a, b, d, e, linvk of the block, per column */
    double wbuf[AMP_TILE][AMP_ROWS];
    const int tiles = (nh + AMP_TILE - 1) / AMP_TILE;
    for (int blk = b0; blk < b1; blk++) {
        const int z0 = blk * rows;
        for (int t = 0; t < tiles; t++) {
            const int x0 = t * AMP_TILE, x1 = x0 + AMP_TILE < nh ? x0 + AMP_TILE : nh;
            for (int iz = z0; iz < z0 + rows; iz++) {
                int mz = iz > n / 2 ? iz - n : iz;
                /* The radial table is larger than the cache at large N (48 B
                 * per ring, ~400 k rings at N = 2048) and the rings of a
                 * tile's modes lie far apart in it: ask for the entries
                 * AMP_AHEAD rows on now (past the block: the next tile's
                 * first rows). A hint; it changes no value. */
                int pz = iz + AMP_AHEAD, px0 = x0, px1 = x1;
                if (pz >= z0 + rows) {
                    pz -= rows;
                    px0 = x1;
                    px1 = x1 + AMP_TILE < nh ? x1 + AMP_TILE : nh;
                }
                for (int ix = px0; ix < px1; ix++) {
                    const struct spectrum_radial *ahead = &c->radial[g->ring[(size_t)pz * nh + ix]];
                    __builtin_prefetch(ahead);
                    __builtin_prefetch((const char *)(ahead + 1) - 1);
                }
                for (int ix = x0; ix < x1; ix++) {
                    size_t i = (size_t)iz * nh + ix;
                    int mx = ix;
                    float a = 0, b = 0, d = 0, e = 0;
                    double omega = 0;
                    /* Nyquist row and column stay zero: their -k aliases onto
                     * themselves, so they could not be both hermitian and random. */
                    if (ix != n / 2 && iz != n / 2 && spectrum_in_band(m, mx, mz)) { /* or a coarser cascade's */
                        const struct spectrum_radial *r = &c->radial[g->ring[i]];
                        double len = sqrt((double)mx * mx + (double)mz * mz);
                        double cs = len > 0 ? (mx * wx + mz * wz) / len : 0; /* cos(angle of k - wind) */
                        double psi_p = 0, psi_m = 0;
                        if (m->sea && r->band != SEA_BAND_WIND) {
                            /* A measured sea is one-sided: k and -k each from its own direction. */
                            if (r->psi_k > 0) {
                                psi_p = r->psi_k * sea_model_direction(m->sea, r->band, mx, mz);
                                psi_m = r->psi_k * sea_model_direction(m->sea, r->band, -mx, -mz);
                            }
                        } else if (r->psi_k > 0) {
                            psi_p = r->psi_k * spectrum_spreading_cos(m, r, cs);
                            psi_m = r->psi_k * spectrum_spreading_cos(m, r, -cs);
                        }
                        double ap = psi_p > 0 ? half_dk * sqrt(psi_p) : 0, am = psi_m > 0 ? half_dk * sqrt(psi_m) : 0;
                        const float *q = c->gauss + 4 * i;
                        /* p = h~0(k), conj(h~0(-k)) = mr - i mi */
                        double pr = ap * q[0], pi = ap * q[1], mr = am * q[2], mi = -am * q[3];
                        a = (float)(pr + mr);
                        b = (float)(pi - mi);
                        d = (float)(pi + mi);
                        e = (float)(pr - mr);
                        omega = r->omega;
                    }
                    s->a[i] = a;
                    s->b[i] = b;
                    s->d[i] = d;
                    s->e[i] = e;
                    s->omega[i] = omega;
                    if (ix == n / 2)
                        continue; /* the Nyquist column has no column-major copy */
                    const int x = ix - x0, z = iz - z0;
                    buf[0][x][z] = a;
                    buf[1][x][z] = b;
                    buf[2][x][z] = d;
                    buf[3][x][z] = e;
                    /* the fill's 1/k factor: every row but the Nyquist one, in band or not */
                    buf[4][x][z] = iz == n / 2 ? 0.0f : (float)(lambda * c->radial[g->ring[i]].disp);
                    wbuf[x][z] = omega;
                }
            }
            const int xc = x1 < n / 2 ? x1 : n / 2; /* columns with a copy */
            for (int ix = x0; ix < xc; ix++) {
                float *col = ocean_amp_col(s->ampc, n, ix);
                for (int k = 0; k < 5; k++)
                    memcpy(col + (size_t)k * n + z0, buf[k][ix - x0], (size_t)rows * sizeof(float));
                memcpy((double *)(col + 5 * (size_t)n) + z0, wbuf[ix - x0], (size_t)rows * sizeof(double));
            }
        }
    }
}

/* h~0 and w for every mode into `amps`, for grid g's N and rings, from the
 * normals `gauss`. Depends only on the parameters (the random numbers on
 * seed and integer k), so reconfiguring keeps the sea's phases. Returns
 * false without memory for the radial table. */
bool ocean_amps_compute(const struct ocean_grid *g, const struct spectrum_model *m, double lambda,
                         const float *gauss, struct ocean_amps *amps, struct pool *pool, int threads)
{
    struct spectrum_radial *radial = malloc((g->rings ? g->rings : 1) * sizeof *radial);
    if (!radial)
        return false;
    struct radial_ctx rc = {m, g->ring_m2, radial, g->rings, 64};
    pool_for(pool, threads, rc.chunks, radial_chunks, &rc);
    struct amp_ctx c = {g, m, lambda, radial, gauss, amps};
    pool_for(pool, threads, g->n < AMP_ROWS ? 1 : g->n / AMP_ROWS, amp_tiles, &c);
    free(radial);
    return true;
}

void ocean_set_k_tables(struct ocean_grid *g, double patch)
{
    for (int i = 0; i < g->nh; i++)
        g->kx[i] = (float)ocean_wavenumber(i, g->n, patch);
    for (int i = 0; i < g->n; i++)
        g->kz[i] = (float)ocean_wavenumber(i, g->n, patch);
}

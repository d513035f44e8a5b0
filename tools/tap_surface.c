/* tap_surface.c — see tap_surface.h. */
#include "tap_surface.h"

#include <fftw3.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* FFTW plans for one (side, fine side) pair, kept across frames. */
struct plan_pair {
    int side, fine;
    float *in, *out;               /* side^2 real, fine^2 real */
    fftwf_complex *spec, *pad;     /* side*(side/2+1), fine*(fine/2+1) */
    fftwf_plan fwd, inv;
};

struct tap_surface {
    struct plan_pair p[8];
    int np;
};

struct tap_surface *tap_surface_new(void)
{
    return calloc(1, sizeof(struct tap_surface));
}

static void free_pair(struct plan_pair *p)
{
    if (p->fwd) fftwf_destroy_plan(p->fwd);
    if (p->inv) fftwf_destroy_plan(p->inv);
    fftwf_free(p->in);
    fftwf_free(p->out);
    fftwf_free(p->spec);
    fftwf_free(p->pad);
    memset(p, 0, sizeof *p);
}

void tap_surface_free(struct tap_surface *s)
{
    if (!s) return;
    for (int i = 0; i < s->np; i++) free_pair(&s->p[i]);
    free(s);
}

static struct plan_pair *pair_for(struct tap_surface *s, int side, int fine)
{
    for (int i = 0; i < s->np; i++)
        if (s->p[i].side == side && s->p[i].fine == fine) return &s->p[i];
    if (s->np == (int)(sizeof s->p / sizeof s->p[0])) free_pair(&s->p[--s->np]);
    struct plan_pair *p = &s->p[s->np];
    p->side = side;
    p->fine = fine;
    p->in = fftwf_alloc_real((size_t)side * side);
    p->out = fftwf_alloc_real((size_t)fine * fine);
    p->spec = fftwf_alloc_complex((size_t)side * (side / 2 + 1));
    p->pad = fftwf_alloc_complex((size_t)fine * (fine / 2 + 1));
    if (!p->in || !p->out || !p->spec || !p->pad) { free_pair(p); return NULL; }
    /* ESTIMATE: planning once per size must not cost a frame's time. */
    p->fwd = fftwf_plan_dft_r2c_2d(side, side, p->in, p->spec, FFTW_ESTIMATE);
    p->inv = fftwf_plan_dft_c2r_2d(fine, fine, p->pad, p->out, FFTW_ESTIMATE);
    if (!p->fwd || !p->inv) { free_pair(p); return NULL; }
    s->np++;
    return p;
}

/* The grid on a fine^2 grid: spectrum zero-padded. The Nyquist row and column
 * are left out: the server puts no wave there, only quantisation noise. */
static const float *upsample(struct tap_surface *s, const float *grid, int side, int fine)
{
    struct plan_pair *p = pair_for(s, side, fine);
    if (!p) return NULL;
    memcpy(p->in, grid, (size_t)side * side * sizeof(float));
    fftwf_execute(p->fwd);
    int h = side / 2, sc = side / 2 + 1, fc = fine / 2 + 1;
    float norm = 1.0f / ((float)side * (float)side); /* FFTW does not normalise */
    memset(p->pad, 0, (size_t)fine * fc * sizeof(fftwf_complex));
    for (int kz = 0; kz < side; kz++) {
        if (kz == h) continue;
        int row = kz < h ? kz : fine - (side - kz);
        for (int kx = 0; kx < h; kx++) {
            p->pad[(size_t)row * fc + kx][0] = p->spec[(size_t)kz * sc + kx][0] * norm;
            p->pad[(size_t)row * fc + kx][1] = p->spec[(size_t)kz * sc + kx][1] * norm;
        }
    }
    fftwf_execute(p->inv);
    return p->out;
}

static void catmull_rom(double t, double w[4])
{
    double t2 = t * t, t3 = t2 * t;
    w[0] = -0.5 * t3 + t2 - 0.5 * t;
    w[1] = 1.5 * t3 - 2.5 * t2 + 1;
    w[2] = -1.5 * t3 + 2 * t2 + 0.5 * t;
    w[3] = 0.5 * t3 - 0.5 * t2;
}

static int wrap(long i, int m)
{
    long r = i % m;
    return (int)(r < 0 ? r + m : r);
}

/* Per axis: the 4 taps and weights of each output coordinate (separable). */
struct taps { int idx[4]; double w[4]; };

static void axis_taps(struct taps *t, int m, double o, double size, double period, int gside, int cubic)
{
    for (int i = 0; i < m; i++) {
        double u = (o + i * size / m) / period * gside, f = floor(u);
        long i0 = (long)f;
        double fr = u - f;
        if (cubic) {
            catmull_rom(fr, t[i].w);
            for (int k = 0; k < 4; k++) t[i].idx[k] = wrap(i0 + k - 1, gside);
        } else {
            t[i].w[0] = 0; t[i].w[1] = 1 - fr; t[i].w[2] = fr; t[i].w[3] = 0;
            for (int k = 0; k < 4; k++) t[i].idx[k] = wrap(i0 + k - 1, gside);
        }
    }
}

/* 1 when every output coordinate of this axis is a node of a grid of gside. */
static int on_nodes(int m, double o, double size, double period, int gside)
{
    for (int i = 0; i < m; i++) {
        double u = (o + i * size / m) / period * gside;
        if (fabs(u - nearbyint(u)) > 1e-6) return 0;
    }
    return 1;
}

int tap_surface_grid(struct tap_surface *s, const struct tap_cascade_grid *g, int ncasc, int m, double x0, double z0,
                     double size, int bilinear, float *out)
{
    double *acc = calloc((size_t)m * m, sizeof *acc);
    struct taps *tx = malloc((size_t)m * sizeof *tx), *tz = malloc((size_t)m * sizeof *tz);
    int r = -1;
    if (!acc || !tx || !tz) goto done;
    for (int c = 0; c < ncasc; c++) {
        const float *grid = g[c].data;
        int side = g[c].side;
        if (!grid) continue;
        int exact = on_nodes(m, x0, size, g[c].period, side) && on_nodes(m, z0, size, g[c].period, side);
        if (exact || bilinear) {
            /* Nodes: the samples themselves (weight 1 on tap 1); else bilinear. */
            axis_taps(tx, m, x0, size, g[c].period, side, 0);
            axis_taps(tz, m, z0, size, g[c].period, side, 0);
        } else {
            int up = TAP_SURFACE_UPSAMPLE;
            while (up > 1 && side * up > TAP_SURFACE_MAX_FINE) up /= 2;
            int fine = side * up;
            grid = upsample(s, grid, side, fine);
            if (!grid) goto done;
            side = fine;
            axis_taps(tx, m, x0, size, g[c].period, side, 1);
            axis_taps(tz, m, z0, size, g[c].period, side, 1);
        }
        for (int j = 0; j < m; j++)
            for (int a = 0; a < 4; a++) {
                double wz = tz[j].w[a];
                if (wz == 0) continue;
                const float *row = grid + (size_t)tz[j].idx[a] * side;
                double *o = acc + (size_t)j * m;
                for (int i = 0; i < m; i++) {
                    const struct taps *t = &tx[i];
                    o[i] += wz * (t->w[0] * row[t->idx[0]] + t->w[1] * row[t->idx[1]] + t->w[2] * row[t->idx[2]] +
                                  t->w[3] * row[t->idx[3]]);
                }
            }
    }
    for (size_t k = 0; k < (size_t)m * m; k++) out[k] = (float)acc[k];
    r = 0;
done:
    free(acc);
    free(tx);
    free(tz);
    return r;
}

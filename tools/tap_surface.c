/* tap_surface.c — see tap_surface.h.
 *
 * The spectral way is separable: zero-padding a grid's 2-D spectrum (its
 * Nyquist row and column dropped) is the same 1-D padding along x and then
 * along z, and the Catmull-Rom cubic is a product of 1-D cubics too. So a
 * cascade is read one axis at a time: each row of its grid upsampled (1-D
 * FFTs) and read at the output's x, then each column of that upsampled and
 * read at the output's z. The values are those of one FFT of the whole
 * padded grid followed by 16 taps a point (the same linear map), for a
 * fraction of the work: side + m transforms of length fine, instead of a
 * fine x fine one. */
#include "tap_surface.h"

#include <fftw3.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

/* FFTW's planner is not thread-safe: writers with a tap_surface each plan under this lock. */
static pthread_mutex_t planner_lock = PTHREAD_MUTEX_INITIALIZER;

/* Per axis: the 4 taps and weights of each output coordinate (separable). */
struct taps { int idx[4]; double w[4]; float f[4]; /* w as floats */ };

/* Plans and buffers for one (side, fine, m) geometry, kept across frames. */
struct plan_set {
    int side, fine, m;
    float *xin;              /* side x side: the cascade's grid */
    fftwf_complex *xspec;    /* side x (side/2+1): its rows' spectra */
    fftwf_complex *xpad;     /* side x (fine/2+1): ... zero-padded */
    float *xfine;            /* side x fine: the rows upsampled */
    float *a;                /* m x side: ... read at the output's x, transposed: row i is
                                the grid's column at x_i, a contiguous transform like the rows */
    fftwf_complex *zspec;    /* m x (side/2+1): those columns' spectra */
    fftwf_complex *zpad;     /* m x (fine/2+1): ... zero-padded */
    float *zfine;            /* m x fine: the columns upsampled */
    fftwf_plan xf, xi, zf, zi;
};

struct tap_surface {
    struct plan_set p[8];
    int np;
    double *acc;             /* m x m sums, kept from call to call */
    float *acct;             /* m x m sums of the spectral cascades, transposed ([i*m + j]) */
    struct taps *tx, *tz;    /* m each */
    int cap;                 /* the m they hold */
};

struct tap_surface *tap_surface_new(void)
{
    return calloc(1, sizeof(struct tap_surface));
}

static void free_set(struct plan_set *p)
{
    pthread_mutex_lock(&planner_lock);
    if (p->xf) fftwf_destroy_plan(p->xf);
    if (p->xi) fftwf_destroy_plan(p->xi);
    if (p->zf) fftwf_destroy_plan(p->zf);
    if (p->zi) fftwf_destroy_plan(p->zi);
    pthread_mutex_unlock(&planner_lock);
    fftwf_free(p->xin);
    fftwf_free(p->xspec);
    fftwf_free(p->xpad);
    fftwf_free(p->xfine);
    fftwf_free(p->a);
    fftwf_free(p->zspec);
    fftwf_free(p->zpad);
    fftwf_free(p->zfine);
    memset(p, 0, sizeof *p);
}

void tap_surface_free(struct tap_surface *s)
{
    if (!s) return;
    for (int i = 0; i < s->np; i++) free_set(&s->p[i]);
    free(s->acc);
    free(s->acct);
    free(s->tx);
    free(s->tz);
    free(s);
}

static struct plan_set *set_for(struct tap_surface *s, int side, int fine, int m)
{
    for (int i = 0; i < s->np; i++)
        if (s->p[i].side == side && s->p[i].fine == fine && s->p[i].m == m) return &s->p[i];
    if (s->np == (int)(sizeof s->p / sizeof s->p[0])) free_set(&s->p[--s->np]);
    struct plan_set *p = &s->p[s->np];
    int sc = side / 2 + 1, fc = fine / 2 + 1;
    p->side = side;
    p->fine = fine;
    p->m = m;
    p->xin = fftwf_alloc_real((size_t)side * side);
    p->xspec = fftwf_alloc_complex((size_t)side * sc);
    p->xpad = fftwf_alloc_complex((size_t)side * fc);
    p->xfine = fftwf_alloc_real((size_t)side * fine);
    p->a = fftwf_alloc_real((size_t)m * side);
    p->zspec = fftwf_alloc_complex((size_t)m * sc);
    p->zpad = fftwf_alloc_complex((size_t)m * fc);
    p->zfine = fftwf_alloc_real((size_t)m * fine);
    if (!p->xin || !p->xspec || !p->xpad || !p->xfine || !p->a || !p->zspec || !p->zpad || !p->zfine) {
        free_set(p);
        return NULL;
    }
    /* ESTIMATE: planning once per size must not cost a frame's time. Every
     * transform is a contiguous row (strided ones run several times slower). */
    pthread_mutex_lock(&planner_lock);
    p->xf = fftwf_plan_many_dft_r2c(1, &side, side, p->xin, NULL, 1, side, p->xspec, NULL, 1, sc, FFTW_ESTIMATE);
    p->xi = fftwf_plan_many_dft_c2r(1, &fine, side, p->xpad, NULL, 1, fc, p->xfine, NULL, 1, fine, FFTW_ESTIMATE);
    p->zf = fftwf_plan_many_dft_r2c(1, &side, m, p->a, NULL, 1, side, p->zspec, NULL, 1, sc, FFTW_ESTIMATE);
    p->zi = fftwf_plan_many_dft_c2r(1, &fine, m, p->zpad, NULL, 1, fc, p->zfine, NULL, 1, fine, FFTW_ESTIMATE);
    pthread_mutex_unlock(&planner_lock);
    if (!p->xf || !p->xi || !p->zf || !p->zi) { free_set(p); return NULL; }
    s->np++;
    return p;
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

static void axis_taps(struct taps *t, int m, double o, double size, double period, int gside, int cubic)
{
    for (int i = 0; i < m; i++) {
        double u = (o + i * size / m) / period * gside, f = floor(u);
        long i0 = (long)f;
        double fr = u - f;
        if (cubic) {
            catmull_rom(fr, t[i].w);
        } else {
            t[i].w[0] = 0; t[i].w[1] = 1 - fr; t[i].w[2] = fr; t[i].w[3] = 0;
        }
        for (int k = 0; k < 4; k++) {
            t[i].idx[k] = wrap(i0 + k - 1, gside);
            t[i].f[k] = (float)t[i].w[k];
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

/* acc += the grid's taps (weights along z times weights along x), read from the grid itself. */
static void add_taps(double *acc, int m, const float *grid, int side, const struct taps *tx, const struct taps *tz)
{
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

/* acct += the band-limited signal of one cascade's grid at the output points
 * (transposed: [i*m + j] is point (i, j)), through a grid `up` times finer:
 * rows first, then columns. */
static int add_spectral(struct tap_surface *s, const struct tap_cascade_grid *g, int up, int m, double x0, double z0,
                        double size, struct taps *tx, struct taps *tz, float *acct)
{
    int side = g->side, fine = side * up, h = side / 2, sc = side / 2 + 1, fc = fine / 2 + 1;
    struct plan_set *p = set_for(s, side, fine, m);
    if (!p) return -1;
    float norm = 1.0f / (float)side; /* FFTW does not normalise: once per axis */
    memcpy(p->xin, g->data, (size_t)side * side * sizeof(float));
    fftwf_execute(p->xf);
    /* Each row's spectrum zero-padded, the Nyquist bin left out (the server puts
     * no wave there, only quantisation noise). */
    for (int r = 0; r < side; r++) {
        const fftwf_complex *src = p->xspec + (size_t)r * sc;
        fftwf_complex *dst = p->xpad + (size_t)r * fc;
        for (int k = 0; k < h; k++) {
            dst[k][0] = src[k][0] * norm;
            dst[k][1] = src[k][1] * norm;
        }
        memset(dst + h, 0, (size_t)(fc - h) * sizeof *dst);
    }
    fftwf_execute(p->xi);
    axis_taps(tx, m, x0, size, g->period, fine, 1);
    for (int r = 0; r < side; r++) {
        const float *row = p->xfine + (size_t)r * fine;
        for (int i = 0; i < m; i++) {
            const struct taps *t = &tx[i];
            p->a[(size_t)i * side + r] =
                t->f[0] * row[t->idx[0]] + t->f[1] * row[t->idx[1]] + t->f[2] * row[t->idx[2]] + t->f[3] * row[t->idx[3]];
        }
    }
    fftwf_execute(p->zf);
    /* The same along z, for the grid's column at each x_i. */
    for (int i = 0; i < m; i++) {
        const fftwf_complex *src = p->zspec + (size_t)i * sc;
        fftwf_complex *dst = p->zpad + (size_t)i * fc;
        for (int k = 0; k < h; k++) {
            dst[k][0] = src[k][0] * norm;
            dst[k][1] = src[k][1] * norm;
        }
        memset(dst + h, 0, (size_t)(fc - h) * sizeof *dst);
    }
    fftwf_execute(p->zi);
    axis_taps(tz, m, z0, size, g->period, fine, 1);
    for (int i = 0; i < m; i++) {
        const float *col = p->zfine + (size_t)i * fine;
        float *o = acct + (size_t)i * m;
        for (int j = 0; j < m; j++) {
            const struct taps *t = &tz[j];
            o[j] += t->f[0] * col[t->idx[0]] + t->f[1] * col[t->idx[1]] + t->f[2] * col[t->idx[2]] + t->f[3] * col[t->idx[3]];
        }
    }
    return 0;
}

int tap_surface_grid(struct tap_surface *s, const struct tap_cascade_grid *g, int ncasc, int m, double x0, double z0,
                     double size, int bilinear, float *out)
{
    if (m > s->cap) {
        free(s->acc);
        free(s->acct);
        free(s->tx);
        free(s->tz);
        s->acc = malloc((size_t)m * m * sizeof *s->acc);
        s->acct = malloc((size_t)m * m * sizeof *s->acct);
        s->tx = malloc((size_t)m * sizeof *s->tx);
        s->tz = malloc((size_t)m * sizeof *s->tz);
        s->cap = s->acc && s->acct && s->tx && s->tz ? m : 0;
        if (!s->cap) return -1;
    }
    double *acc = s->acc;
    struct taps *tx = s->tx, *tz = s->tz;
    int spectral = 0;
    memset(acc, 0, (size_t)m * m * sizeof *acc);
    for (int c = 0; c < ncasc; c++) {
        const float *grid = g[c].data;
        int side = g[c].side;
        if (!grid) continue;
        int exact = on_nodes(m, x0, size, g[c].period, side) && on_nodes(m, z0, size, g[c].period, side);
        if (exact || bilinear) {
            /* Nodes: the samples themselves (weight 1 on tap 1); else bilinear. */
            axis_taps(tx, m, x0, size, g[c].period, side, 0);
            axis_taps(tz, m, z0, size, g[c].period, side, 0);
            add_taps(acc, m, grid, side, tx, tz);
        } else {
            int up = TAP_SURFACE_UPSAMPLE;
            while (up > 1 && side * up > TAP_SURFACE_MAX_FINE) up /= 2;
            if (!spectral) memset(s->acct, 0, (size_t)m * m * sizeof *s->acct);
            if (add_spectral(s, &g[c], up, m, x0, z0, size, tx, tz, s->acct) != 0) return -1;
            spectral = 1;
        }
    }
    if (!spectral) {
        for (size_t k = 0; k < (size_t)m * m; k++) out[k] = (float)acc[k];
        return 0;
    }
    /* out = acc + acct transposed, in 32 x 32 blocks (both stay in the cache) */
    for (int j0 = 0; j0 < m; j0 += 32)
        for (int i0 = 0; i0 < m; i0 += 32)
            for (int j = j0; j < j0 + 32 && j < m; j++)
                for (int i = i0; i < i0 + 32 && i < m; i++)
                    out[(size_t)j * m + i] = (float)(acc[(size_t)j * m + i] + s->acct[(size_t)i * m + j]);
    return 0;
}

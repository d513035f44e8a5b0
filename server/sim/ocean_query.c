/* ocean_query.c — exact surface values at arbitrary world points.
 *
 * Method: the spectral sum itself, evaluated at the point, over every mode
 * of the simulation's half spectrum (the same h~0 and w that the FFT path
 * uses), in double precision:
 *     f(x, z) = Re sum_k w_k F~(k, t) e^{i(kx x + kz z)},   w_k = 1 (kx = 0) or 2,
 * with F~ = h~ times the factor of the field (i kx, i lambda kx/k, ...).
 * This is the DFT reference evaluated off the grid, so there is no
 * interpolation error at all; what the FFT grid cannot give (values between
 * samples, exact derivatives in time and space) comes out of the same sums.
 *
 * The height "above (x, z)" belongs to the surface point that lands on
 * (x, z): the displaced surface is x0 -> (x0 + D(x0), h(x0)), so we solve
 * x0 + D(x0) = x by Newton's method on the exact D and its exact Jacobian
 * (quadratic convergence, typically 3-5 steps to 1e-9 m), then evaluate
 * h, the tangents (normal) and the time derivatives at x0. The vertical
 * velocity and acceleration at the fixed world point follow by the chain
 * rule through x0(t) (dx0/dt = -A^-1 dD/dt, A = I + grad D).
 *
 * Cost: O(modes) per evaluation, ~26 multiply-adds per mode for the final
 * evaluation and 5 per Newton step; bench/bench_query.c measures it. No
 * mode is left out: a rigorous bound on what dropped modes could add (the
 * sum of their amplitudes) stays above 1 mm unless almost all are kept
 * (measured for the default sea: dropping the weakest 1000 of 32639 modes
 * at N = 256 already allows 0.1 m), so truncation would buy nothing safe.
 *
 * The sea is the sum of the cascades (ocean.h, docs/simulation.md
 * "Cascades"): cascade c has its own patch L_c = L / 3.543^c and its own
 * band of modes, and every sum above runs over the modes of every cascade
 * (their tables are concatenated, each row knowing its cascade), so height,
 * displacement, slopes and time derivatives are those of the whole sea and
 * Newton inverts the summed displacement. The horizontal factor is
 * coth(k depth)/k (displacement_over_k), as on the FFT path.
 *
 * Coordinates are reduced modulo each cascade's patch L_c separately (kx L_c
 * = 2 pi mx exactly, so this changes no phase), which keeps the phases exact
 * for any finite x. The cascades' periods are incommensurate, so a point is
 * carried as its raw coordinates plus a small offset (the Newton unknown),
 * never as one reduced coordinate. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ocean_internal.h"

#define NEWTON_TOL 1e-9   /* m, |x0 + D(x0) - x| */
#define MAXC OCEAN_MAX_CASCADES

struct ocean_surface {
    struct ocean_params p;
    double lambda, loop;            /* choppiness, loop period (0 = none) */
    int ncasc;                      /* cascades summed */
    double patch[MAXC];             /* L_c */
    int crow[MAXC + 1];             /* rows of cascade c: [crow[c], crow[c + 1]) */
    int n, nh, rows;                /* N, N/2 + 1, rows that hold kept modes (all cascades) */
    int modes, spans;               /* non-zero modes; entries of the row spans (all cascades) */
    /* Rows: the modes of row r are [row_start[r], row_start[r + 1]), the
     * columns mx = row_c0[r], row_c0[r] + 1, ... in order (a contiguous
     * span, so the inner loops vectorise; a mode inside a span may be
     * zero), all with kz = row_kz[r] and integer wavenumber row_mz[r]. */
    int *row_start, *row_mz, *row_c0;
    double *row_kz;
    /* Per mode: kx, coth(k depth)/k (0 at k = 0), w, and a, b, d, e
     * (ocean_internal.h) with the weight w_k (1 for kx = 0, else 2: the
     * mirrored half) folded in. */
    double *kx, *invk, *omega, *a, *b, *d, *e;
    /* An easing (ocean_commit_eased): with ease_len > 0, the amplitudes at
     * time t are ocean_ease_mix(from, a, w(t)) etc. per mode, from = fa, fb,
     * fd, fe (same layout and weight, NULL when the snapshot has no room). */
    double *fa, *fb, *fd, *fe;
    double ease_t0, ease_len;
};

struct ocean_surface *ocean_surface_new(const struct ocean *o, char *err, size_t errlen)
{
    if (!o) {
        snprintf(err, errlen, "no simulation");
        return NULL;
    }
    const struct ocean_grid *grids[MAXC] = {o->g};
    int count = o->ncascades < 1 ? 1 : o->ncascades > MAXC ? MAXC : o->ncascades;
    for (int c = 1; c < count; c++)
        grids[c] = o->fine[c];
    if (!(o->g->ease_len > 0))
        return ocean_surface_from(grids, count, &o->p, err, errlen);
    struct surface_ease ease = {.fill = true, .t0 = o->g->ease_t0, .len = o->g->ease_len};
    for (int c = 0; c < count; c++)
        ease.from[c] = grids[c]->ease_from;
    return ocean_surface_from_eased(grids, count, &o->p, &ease, err, errlen);
}

/* Amplitude k (0..3: a, b, d, e) of mode (ix, iz) in a column-major copy
 * with `stride` floats per column (the Nyquist column ix = N/2 has none: 0). */
static float col_amp(const float *buf, size_t stride, int n, int ix, int iz, int k)
{
    return ix < n / 2 ? buf[(size_t)ix * stride + (size_t)k * n + iz] : 0.0f;
}

/* The snapshot's `from` amplitudes of cascade c from a grid's ease_from. */
static void fill_from(struct ocean_surface *s, int c, const float *from)
{
    const int n = s->n;
    const size_t stride = OCEAN_EASE_COL_FLOATS(n);
    double *dst[4] = {s->fa, s->fb, s->fd, s->fe};
    for (int r = s->crow[c]; r < s->crow[c + 1]; r++) {
        const int mz = s->row_mz[r], iz = mz < 0 ? mz + n : mz;
        for (int at = s->row_start[r]; at < s->row_start[r + 1]; at++) {
            const int ix = s->row_c0[r] + (at - s->row_start[r]);
            const double w = ix == 0 ? 1.0 : 2.0;
            for (int k = 0; k < 4; k++)
                dst[k][at] = w * col_amp(from, stride, n, ix, iz, k);
        }
    }
}

int ocean_surface_ease(struct ocean_surface *s, const struct ocean *o)
{
    if (!s || !o)
        return -1;
    if (!(o->g->ease_len > 0)) {
        s->ease_len = 0;
        return 0;
    }
    if (!s->fa || o->ncascades != s->ncasc || o->g->n != s->n)
        return -1; /* no room was made: not a snapshot of this easing */
    for (int c = 0; c < s->ncasc; c++)
        fill_from(s, c, c == 0 ? o->g->ease_from : o->fine[c]->ease_from);
    s->ease_t0 = o->g->ease_t0;
    s->ease_len = o->g->ease_len;
    return 0;
}

/* Which modes of grid g to keep (non-zero amplitude: the Nyquist row and
 * column, k = 0, a calm sea and a finer cascade's modes outside its band
 * add nothing), and per row the span from its first to its last kept
 * column. Returns the spans' total length; *kept counts kept modes. */
static size_t grid_spans(const struct ocean_grid *g, const float *also[2], const size_t stride[2], char *keep,
                         size_t *kept, int *rows)
{
    const int n = g->n, nh = g->nh;
    size_t span = 0;
    for (size_t i = 0; i < g->modes; i++)
        keep[i] = g->a[i] != 0 || g->b[i] != 0 || g->d[i] != 0 || g->e[i] != 0;
    for (int j = 0; j < 2; j++) /* an easing's other amplitudes: their modes too */
        if (also[j])
            for (int ix = 0; ix < n / 2; ix++)
                for (int k = 0; k < 4; k++)
                    for (int iz = 0; iz < n; iz++)
                        keep[(size_t)iz * nh + ix] |= col_amp(also[j], stride[j], n, ix, iz, k) != 0;
    for (int iz = 0; iz < n; iz++) {
        int c0 = -1, c1 = -1;
        for (int ix = 0; ix < nh; ix++)
            if (keep[(size_t)iz * nh + ix]) {
                c0 = c0 < 0 ? ix : c0;
                c1 = ix;
                ++*kept;
            }
        span += c0 < 0 ? 0 : (size_t)(c1 - c0 + 1);
        *rows += c0 >= 0;
    }
    return span;
}

/* The snapshot of the grids of cascades 0 .. count-1 (all of the same N)
 * under parameters pp (ocean_prepare.c also calls it on a prepared state). */
struct ocean_surface *ocean_surface_from(const struct ocean_grid *const *grids, int count,
                                         const struct ocean_params *pp, char *err, size_t errlen)
{
    return ocean_surface_from_eased(grids, count, pp, NULL, err, errlen);
}

struct ocean_surface *ocean_surface_from_eased(const struct ocean_grid *const *grids, int count,
                                               const struct ocean_params *pp, const struct surface_ease *ease,
                                               char *err, size_t errlen)
{
    if (count < 1 || count > MAXC || !grids || !grids[0]) {
        snprintf(err, errlen, "no simulation");
        return NULL;
    }
    const int n = grids[0]->n, nh = grids[0]->nh;
    for (int c = 1; c < count; c++)
        if (!grids[c] || grids[c]->n != n) {
            snprintf(err, errlen, "cascade %d missing or of another resolution", c);
            return NULL;
        }
    struct ocean_surface *s = calloc(1, sizeof *s);
    char *keep[MAXC] = {NULL};
    if (!s)
        goto nomem;
    s->p = *pp;
    s->lambda = pp->choppiness;
    s->loop = pp->loop_period > 0 ? pp->loop_period : 0;
    s->n = n;
    s->nh = nh;
    s->ncasc = count;

    size_t span = 0, kept = 0;
    int rows = 0;
    for (int c = 0; c < count; c++) {
        keep[c] = calloc(grids[c]->modes, 1);
        if (!keep[c])
            goto nomem;
        const float *also[2] = {ease ? ease->keep[c] : NULL, ease ? ease->from[c] : NULL};
        const size_t stride[2] = {ease ? ease->keep_stride : 0, OCEAN_EASE_COL_FLOATS(n)};
        span += grid_spans(grids[c], also, stride, keep[c], &kept, &rows);
    }
    s->modes = (int)kept;
    size_t m = span ? span : 1;
    s->spans = (int)span;
    s->row_start = malloc((size_t)(rows + 1) * sizeof *s->row_start);
    s->row_mz = malloc((size_t)(rows + 1) * sizeof *s->row_mz);
    s->row_c0 = malloc((size_t)(rows + 1) * sizeof *s->row_c0);
    s->row_kz = malloc((size_t)(rows + 1) * sizeof *s->row_kz);
    double **arrays[] = {&s->kx, &s->invk, &s->omega, &s->a, &s->b, &s->d, &s->e};
    for (size_t j = 0; j < sizeof arrays / sizeof arrays[0]; j++)
        *arrays[j] = calloc(m, sizeof(double));
    if (!s->row_start || !s->row_mz || !s->row_c0 || !s->row_kz || !s->kx || !s->invk || !s->omega || !s->a ||
        !s->b || !s->d || !s->e)
        goto nomem;
    if (ease) {
        double **from[] = {&s->fa, &s->fb, &s->fd, &s->fe};
        for (size_t j = 0; j < sizeof from / sizeof from[0]; j++)
            if (!(*from[j] = calloc(m, sizeof(double))))
                goto nomem;
    }
    size_t at = 0;
    for (int c = 0; c < count; c++) {
        const struct ocean_grid *g = grids[c];
        const double L = ocean_cascade_patch(pp->patch_size, c);
        s->patch[c] = L;
        s->crow[c] = s->rows;
        for (int iz = 0; iz < n; iz++) {
            int c0 = -1, c1 = -1;
            for (int ix = 0; ix < nh; ix++)
                if (keep[c][(size_t)iz * nh + ix]) {
                    c0 = c0 < 0 ? ix : c0;
                    c1 = ix;
                }
            if (c0 < 0)
                continue;
            double kz = ocean_wavenumber(iz, n, L);
            s->row_start[s->rows] = (int)at;
            s->row_mz[s->rows] = iz > n / 2 ? iz - n : iz;
            s->row_c0[s->rows] = c0;
            s->row_kz[s->rows] = kz;
            s->rows++;
            for (int ix = c0; ix <= c1; ix++, at++) {
                size_t i = (size_t)iz * nh + ix;
                double kx = ocean_wavenumber(ix, n, L), k = hypot(kx, kz), w = ix == 0 ? 1.0 : 2.0;
                s->kx[at] = kx;
                s->invk[at] = displacement_over_k(k, pp->depth);
                s->omega[at] = g->omega[i];
                if (!keep[c][i])
                    continue; /* zero amplitude: stays 0 */
                s->a[at] = w * g->a[i];
                s->b[at] = w * g->b[i];
                s->d[at] = w * g->d[i];
                s->e[at] = w * g->e[i];
            }
        }
    }
    s->crow[count] = s->rows;
    s->row_start[s->rows] = (int)at;
    if (ease && ease->fill && ease->len > 0) {
        for (int c = 0; c < count; c++)
            if (ease->from[c])
                fill_from(s, c, ease->from[c]);
        s->ease_t0 = ease->t0;
        s->ease_len = ease->len;
    }
    for (int c = 0; c < count; c++)
        free(keep[c]);
    return s;
nomem:
    for (int c = 0; c < MAXC; c++)
        free(keep[c]);
    ocean_surface_free(s);
    snprintf(err, errlen, "out of memory for a query snapshot");
    return NULL;
}

void ocean_surface_free(struct ocean_surface *s)
{
    if (!s)
        return;
    free(s->row_start);
    free(s->row_mz);
    free(s->row_c0);
    free(s->row_kz);
    free(s->kx);
    free(s->invk);
    free(s->omega);
    free(s->a);
    free(s->b);
    free(s->d);
    free(s->e);
    free(s->fa);
    free(s->fb);
    free(s->fd);
    free(s->fe);
    free(s);
}

int ocean_surface_modes(const struct ocean_surface *s)
{
    return s ? s->modes : 0;
}

const struct ocean_params *ocean_surface_params(const struct ocean_surface *s)
{
    return s ? &s->p : NULL;
}

/* ---- evaluation ------------------------------------------------------------ */

/* Per query call: the time-dependent part of every kept mode, P = w h~(k,t),
 * Q = w dh~/dt and R = w d2h~/dt2 (complex; R = -omega^2 P but during an
 * easing's ramp), and per point the x phase table. */
struct work {
    double *pr, *pi, *qr, *qi, *rr, *ri;
    double *cx, *sx;       /* cos, sin(2 pi mx x / L), mx = 0 .. N/2 */
    double *cz, *sz;       /* cos, sin(2 pi mz z / L), mz = 0 .. N/2 */
};

/* Everything the outputs need, at one undisplaced point x0. */
struct surface_sums {
    double h, hx, hz, hxx, hxz, hzz;           /* height and its space derivatives */
    double ht, htx, htz, htt;                  /* time derivatives */
    double dx, dz, dxx, dxz, dzz;              /* displacement, its gradient (symmetric) */
    double dtx, dtz, dttx, dttz;               /* dD/dt, d2D/dt2 */
    double dtxx, dtxz, dtzz;                   /* grad dD/dt */
    double d3xxx, d3xxz, d3xzz, d3zzz;         /* second derivatives of D: D = grad psi,
                                                * these are psi's third derivatives */
};

/* A world point (x, z) reduced modulo each cascade's patch (exact: fmod),
 * x[c] in [0, L_c); the points evaluated are base + a small offset. */
struct base {
    double x[MAXC], z[MAXC];
};

/* x in [0, L) * 2 pi / L as a fraction u in [0, 1): exact for any finite x
 * (fmod is exact), so e^{i kx x} = e^{2 pi i mx u} loses nothing. */
static double turns(double x, double L)
{
    double r = fmod(x, L);
    if (r < 0)
        r += L;
    double u = r / L;
    return u < 1.0 ? u : 0.0;
}

/* c[m] + i s[m] = e^{2 pi i m u}, m = 0 .. count-1: by the angle-addition
 * recurrence (one complex multiply per entry instead of a sin and a cos,
 * which were a quarter of an evaluation), re-anchored with an exact
 * sin/cos every 16 entries so rounding cannot build up (error ~1e-15). */
static void phase_table(double u, int count, double *c, double *s)
{
    double ang1 = 2.0 * M_PI * u, c1 = cos(ang1), s1 = sin(ang1);
    for (int m = 0; m < count; m++) {
        if (m % 16 == 0) {
            double ang = 2.0 * M_PI * fmod(m * u, 1.0);
            c[m] = cos(ang);
            s[m] = sin(ang);
        } else {
            c[m] = c[m - 1] * c1 - s[m - 1] * s1;
            s[m] = s[m - 1] * c1 + c[m - 1] * s1;
        }
    }
}

/* e^{i kz z} of row r from the table of |mz| (rows with mz < 0: conjugate). */
static inline void row_phase(const struct ocean_surface *s, const struct work *w, int r, double *cz, double *sz)
{
    int mz = s->row_mz[r];
    *cz = w->cz[mz < 0 ? -mz : mz];
    *sz = mz < 0 ? -w->sz[-mz] : w->sz[mz];
}

/* D and grad D only: what one Newton step needs (5 sums instead of 26). */
__attribute__((target_clones("avx2", "default")))
static void eval_displacement(const struct ocean_surface *s, struct work *w, const struct base *b, double ox,
                              double oz, struct surface_sums *o)
{
    double dx = 0, dz = 0, dxx = 0, dxz = 0, dzz = 0;
    for (int c = 0; c < s->ncasc; c++) {
        phase_table(turns(b->x[c] + ox, s->patch[c]), s->nh, w->cx, w->sx);
        phase_table(turns(b->z[c] + oz, s->patch[c]), s->nh, w->cz, w->sz);
        for (int r = s->crow[c]; r < s->crow[c + 1]; r++) {
            double cz, sz, kz = s->row_kz[r];
            row_phase(s, w, r, &cz, &sz);
            double rdx = 0, rdz = 0, rdxx = 0, rdxz = 0, rdzz = 0;
            const int m0 = s->row_start[r], m1 = s->row_start[r + 1];
            const double *cxr = w->cx + s->row_c0[r] - m0, *sxr = w->sx + s->row_c0[r] - m0; /* index by mode */
#pragma omp simd reduction(+ : rdx, rdz, rdxx, rdxz, rdzz)
            for (int m = m0; m < m1; m++) {
                double cx = cxr[m], sx = sxr[m];
                double er = cx * cz - sx * sz, ei = cx * sz + sx * cz;
                double pr = w->pr[m] * er - w->pi[m] * ei, pi = w->pr[m] * ei + w->pi[m] * er;
                double g = s->invk[m], kx = s->kx[m], gpi = g * pi, gpr = g * pr;
                rdx += kx * gpi;
                rdz += gpi;
                rdxx += kx * kx * gpr;
                rdxz += kx * gpr;
                rdzz += gpr;
            }
            dx -= rdx;
            dz -= kz * rdz;
            dxx -= rdxx;
            dxz -= kz * rdxz;
            dzz -= kz * kz * rdzz;
        }
    }
    const double lam = s->lambda;
    o->dx = lam * dx;
    o->dz = lam * dz;
    o->dxx = lam * dxx;
    o->dxz = lam * dxz;
    o->dzz = lam * dzz;
}

/* Every sum, for the outputs. Per mode, with P = w h~ e^{ik.x0} and
 * Q = w dh~/dt e^{ik.x0}: h = Re P, dh/dx = Re(i kx P) = -kx Im P,
 * Dx = Re(i lambda kx/k P), d/dt h~ = Q, d2/dt2 h~ = -w^2 h~, and so on;
 * factors that depend on kz only are applied once per row. */
__attribute__((target_clones("avx2", "default")))
static void eval_all(const struct ocean_surface *s, struct work *w, const struct base *b, double ox, double oz,
                     struct surface_sums *o)
{
    memset(o, 0, sizeof *o);
    for (int c = 0; c < s->ncasc; c++) {
        phase_table(turns(b->x[c] + ox, s->patch[c]), s->nh, w->cx, w->sx);
        phase_table(turns(b->z[c] + oz, s->patch[c]), s->nh, w->cz, w->sz);
        for (int r = s->crow[c]; r < s->crow[c + 1]; r++) {
            double cz, sz;
            row_phase(s, w, r, &cz, &sz);
            double kz = s->row_kz[r], kz2 = kz * kz;
            double h = 0, hx = 0, spi = 0, hxx = 0, kxpr = 0, ht = 0, htx = 0, sqi = 0, htt = 0;
            double dx = 0, dz = 0, dxx = 0, dxz = 0, dzz = 0, dtx = 0, dtz = 0, dttx = 0, dttz = 0;
            double dtxx = 0, dtxz = 0, dtzz = 0, d3xxx = 0, d3xxz = 0;
            const int m0 = s->row_start[r], m1 = s->row_start[r + 1];
            const double *cxr = w->cx + s->row_c0[r] - m0, *sxr = w->sx + s->row_c0[r] - m0;
#pragma omp simd reduction(+ : h, hx, spi, hxx, kxpr, ht, htx, sqi, htt, dx, dz, dxx, dxz, dzz, dtx, dtz, dttx, \
                                       dttz, dtxx, dtxz, dtzz, d3xxx, d3xxz)
            for (int m = m0; m < m1; m++) {
                double cx = cxr[m], sx = sxr[m];
                double er = cx * cz - sx * sz, ei = cx * sz + sx * cz;
                double pr = w->pr[m] * er - w->pi[m] * ei, pi = w->pr[m] * ei + w->pi[m] * er;
                double qr = w->qr[m] * er - w->qi[m] * ei, qi = w->qr[m] * ei + w->qi[m] * er;
                double rr = w->rr[m] * er - w->ri[m] * ei, ri = w->rr[m] * ei + w->ri[m] * er;
                double g = s->invk[m], kx = s->kx[m], kx2 = kx * kx;
                double gpi = g * pi, gpr = g * pr, gqi = g * qi, gqr = g * qr;
                h += pr;
                hx += kx * pi;
                spi += pi;
                hxx += kx2 * pr;
                kxpr += kx * pr;
                ht += qr;
                htx += kx * qi;
                sqi += qi;
                htt += rr;
                dx += kx * gpi;
                dz += gpi;
                dxx += kx2 * gpr;
                dxz += kx * gpr;
                dzz += gpr;
                dtx += kx * gqi;
                dtz += gqi;
                dttx += kx * g * ri;
                dttz += g * ri;
                dtxx += kx2 * gqr;
                dtxz += kx * gqr;
                dtzz += gqr;
                d3xxx += kx2 * kx * gpi;
                d3xxz += kx2 * gpi;
            }
            o->h += h;
            o->hx -= hx;
            o->hz -= kz * spi;
            o->hxx -= hxx;
            o->hxz -= kz * kxpr;
            o->hzz -= kz2 * h;
            o->ht += ht;
            o->htx -= htx;
            o->htz -= kz * sqi;
            o->htt += htt;
            o->dx -= dx;
            o->dz -= kz * dz;
            o->dxx -= dxx;
            o->dxz -= kz * dxz;
            o->dzz -= kz2 * dzz;
            o->dtx -= dtx;
            o->dtz -= kz * dtz;
            o->dttx -= dttx;
            o->dttz -= kz * dttz;
            o->dtxx -= dtxx;
            o->dtxz -= kz * dtxz;
            o->dtzz -= kz2 * dtzz;
            o->d3xxx += d3xxx;
            o->d3xxz += kz * d3xxz;
            o->d3xzz += kz2 * dx;
            o->d3zzz += kz2 * kz * dz;
        }
    }
    const double lam = s->lambda;
    double *dterms[] = {&o->dx, &o->dz, &o->dxx, &o->dxz, &o->dzz, &o->dtx, &o->dtz, &o->dttx, &o->dttz,
                        &o->dtxx, &o->dtxz, &o->dtzz, &o->d3xxx, &o->d3xxz, &o->d3xzz, &o->d3zzz};
    for (size_t i = 0; i < sizeof dterms / sizeof dterms[0]; i++)
        *dterms[i] *= lam;
}

/* Newton's method with a backtracking line search for the offset o of the
 * source from the world point b: o + D(b + o) = 0 (metres), from the start
 * (x, z); where the map is singular (det A ~ 0, the crest of a fold) a
 * fixed-point step is taken. Returns the final residual |o + D(b + o)|;
 * *steps += iterations. */
static double newton(const struct ocean_surface *s, struct work *w, const struct base *b, double x, double z,
                     int max_steps, double *x0, double *z0, int *steps)
{
    const double L = s->patch[0];
    struct surface_sums d;
    eval_displacement(s, w, b, x, z, &d);
    double rx = x + d.dx, rz = z + d.dz, res = hypot(rx, rz);
    for (int it = 0; it < max_steps && res >= NEWTON_TOL; it++) {
        double a11 = 1 + d.dxx, a12 = d.dxz, a22 = 1 + d.dzz, det = a11 * a22 - a12 * a12;
        double sx = rx, sz = rz; /* fixed-point step: x0 <- x - D(x0) */
        if (fabs(det) > 1e-3) {
            sx = (a22 * rx - a12 * rz) / det;
            sz = (a11 * rz - a12 * rx) / det;
        }
        double len = hypot(sx, sz), cap = 0.125 * L;
        if (len > cap) {
            sx *= cap / len;
            sz *= cap / len;
        }
        double step = 1.0, nx = x, nz = z, nrx = rx, nrz = rz, nres = res;
        for (int tries = 0; tries < 8; tries++, step *= 0.5) {
            nx = x - step * sx;
            nz = z - step * sz;
            eval_displacement(s, w, b, nx, nz, &d);
            nrx = nx + d.dx;
            nrz = nz + d.dz;
            nres = hypot(nrx, nrz);
            if (nres < res)
                break;
        }
        x = nx;
        z = nz;
        rx = nrx;
        rz = nrz;
        res = nres;
        ++*steps;
    }
    *x0 = x;
    *z0 = z;
    return res;
}

/* Offset (x0, z0) of the source of the world point b from it, starting
 * from the offset (sx0, sz0). Newton from the point itself almost always
 * converges; where the surface folds it can stall in a local minimum of
 * the residual, and then it is restarted from points around, at the
 * distance of the displacement found so far (a fold has several sources:
 * any converged one is a correct answer). */
static void invert_displacement(const struct ocean_surface *s, struct work *w, const struct base *b, double sx0,
                                double sz0, double *x0, double *z0, int *iterations, int *converged)
{
    *iterations = 0;
    *converged = 0;
    if (s->lambda == 0) { /* no horizontal displacement: the point is its own source */
        *x0 = 0;
        *z0 = 0;
        *converged = 1;
        return;
    }
    double bx, bz, best = newton(s, w, b, sx0, sz0, 30, &bx, &bz, iterations);
    if (best >= NEWTON_TOL && (sx0 != 0 || sz0 != 0)) { /* a poor guess: start over from the point */
        double cx, cz, res = newton(s, w, b, 0, 0, 30, &cx, &cz, iterations);
        if (res < best) {
            best = res;
            bx = cx;
            bz = cz;
        }
    }
    double radius = fmax(hypot(bx, bz), 1e-3 * s->patch[0]);
    for (int k = 0; k < 24 && best >= NEWTON_TOL; k++) {
        double ang = 2.0 * M_PI * k / 8.0, r = radius * (0.5 + 0.5 * (k / 8)); /* 3 rings of 8 */
        double cx, cz, res = newton(s, w, b, r * cos(ang), r * sin(ang), 30, &cx, &cz, iterations);
        if (res < best) {
            best = res;
            bx = cx;
            bz = cz;
        }
    }
    *converged = best < NEWTON_TOL;
    *x0 = bx;
    *z0 = bz;
}

/* The outputs from the sums at the source point (see struct ocean_point). */
static void fill_point(const struct surface_sums *q, struct ocean_point *p)
{
    p->height = q->h;
    p->displacement[0] = q->dx;
    p->displacement[1] = q->dz;
    /* Tangents of the displaced surface x0 -> (x0 + Dx, h, z0 + Dz):
     * Tx = (1 + Dxx, hx, Dxz), Tz = (Dxz, hz, 1 + Dzz); normal = Tz x Tx. */
    double a11 = 1 + q->dxx, a12 = q->dxz, a22 = 1 + q->dzz, det = a11 * a22 - a12 * a12;
    double nx = q->hz * a12 - a22 * q->hx, ny = det, nz = a12 * q->hx - q->hz * a11;
    double len = sqrt(nx * nx + ny * ny + nz * nz);
    if (len > 0) {
        nx /= len;
        ny /= len;
        nz /= len;
    } else {
        nx = nz = 0;
        ny = 1;
    }
    p->normal[0] = nx;
    p->normal[1] = ny;
    p->normal[2] = nz;
    p->jacobian = det;
    p->particle_velocity = q->ht;
    p->particle_acceleration = q->htt;
    /* The surface point over a fixed (x, z) moves: x0(t) with
     * A dx0/dt = -dD/dt. Chain rule for height(t) = h(x0(t), t). */
    if (fabs(det) < 1e-12) { /* crest of a fold: the source does not move smoothly */
        p->vertical_velocity = q->ht;
        p->vertical_acceleration = q->htt;
        return;
    }
    double vx = -(a22 * q->dtx - a12 * q->dtz) / det, vz = -(a11 * q->dtz - a12 * q->dtx) / det;
    p->vertical_velocity = q->ht + q->hx * vx + q->hz * vz;
    /* A dv/dt = -(d2D/dt2 + 2 (grad dD/dt) v + (grad grad D)[v, v]) */
    double fx = q->dttx + 2 * (q->dtxx * vx + q->dtxz * vz) + q->d3xxx * vx * vx + 2 * q->d3xxz * vx * vz +
                q->d3xzz * vz * vz;
    double fz = q->dttz + 2 * (q->dtxz * vx + q->dtzz * vz) + q->d3xxz * vx * vx + 2 * q->d3xzz * vx * vz +
                q->d3zzz * vz * vz;
    double ax = -(a22 * fx - a12 * fz) / det, az = -(a11 * fz - a12 * fx) / det;
    p->vertical_acceleration = q->htt + 2 * (q->htx * vx + q->htz * vz) + q->hxx * vx * vx +
                               2 * q->hxz * vx * vz + q->hzz * vz * vz + q->hx * ax + q->hz * az;
}

int ocean_surface_query(const struct ocean_surface *s, double t, const double (*xz)[2], int npoints,
                        struct ocean_point *out)
{
    return ocean_surface_query_from(s, t, xz, NULL, npoints, out);
}

int ocean_surface_query_from(const struct ocean_surface *s, double t, const double (*xz)[2],
                             const double (*start)[2], int npoints, struct ocean_point *out)
{
    if (!s || !isfinite(t) || npoints < 0 || (npoints > 0 && (!xz || !out)))
        return -1;
    for (int i = 0; i < npoints; i++)
        if (!isfinite(xz[i][0]) || !isfinite(xz[i][1]) ||
            (start && (!isfinite(start[i][0]) || !isfinite(start[i][1]))))
            return -1;
    if (npoints == 0)
        return 0;
    size_t m = s->spans ? (size_t)s->spans : 1;
    struct work w;
    double *buf = malloc((6 * m + 4 * (size_t)s->nh) * sizeof *buf);
    if (!buf)
        return -1;
    w.pr = buf;
    w.pi = w.pr + m;
    w.qr = w.pi + m;
    w.qi = w.qr + m;
    w.rr = w.qi + m;
    w.ri = w.rr + m;
    w.cx = w.ri + m;
    w.sx = w.cx + s->nh;
    w.cz = w.sx + s->nh;
    w.sz = w.cz + s->nh;
    /* Phases at t (wrapped into the loop period when the sea loops: the
     * modes' w are whole multiples of 2 pi / period, so this is exact). */
    double tt = t;
    if (s->loop > 0) {
        tt = fmod(t, s->loop);
        if (tt < 0)
            tt += s->loop;
    }
    /* During an easing, the amplitudes the step reads at t: the same float
     * mix (the weights w_k = 1, 2 folded in scale it exactly). Inside the
     * ramp the amplitudes move at rw (to - from) per second, rw the weight's
     * rate, which the time derivatives include (docs/simulation.md "Easing"):
     * with P = a cos + b sin, P' = om (b cos - a sin) + a' cos + b' sin and
     * P'' = -om^2 P + 2 om (b' cos - a' sin) (a'' = 0 on a linear ramp). */
    const bool easing = s->fa && s->ease_len > 0;
    const float ew = easing ? ocean_ease_weight(s->ease_t0, s->ease_len, t) : 1.0f;
    const double rw = easing ? ocean_ease_rate(s->ease_t0, s->ease_len, t) : 0;
    for (int i = 0; i < s->spans; i++) {
        double om = s->omega[i], c = cos(om * tt), sn = sin(om * tt);
        double a = s->a[i], b = s->b[i], d = s->d[i], e = s->e[i];
        double at = 0, bt = 0, dt = 0, et = 0; /* the amplitudes' rates */
        if (ew < 1.0f) {
            if (rw > 0) {
                at = rw * (a - s->fa[i]);
                bt = rw * (b - s->fb[i]);
                dt = rw * (d - s->fd[i]);
                et = rw * (e - s->fe[i]);
            }
            a = ocean_ease_mix((float)s->fa[i], (float)a, ew);
            b = ocean_ease_mix((float)s->fb[i], (float)b, ew);
            d = ocean_ease_mix((float)s->fd[i], (float)d, ew);
            e = ocean_ease_mix((float)s->fe[i], (float)e, ew);
        }
        w.pr[i] = a * c + b * sn;
        w.pi[i] = d * c - e * sn;
        w.qr[i] = om * (b * c - a * sn) + at * c + bt * sn;
        w.qi[i] = -om * (d * sn + e * c) + dt * c - et * sn;
        w.rr[i] = -om * om * w.pr[i] + 2 * om * (bt * c - at * sn);
        w.ri[i] = -om * om * w.pi[i] - 2 * om * (dt * sn + et * c);
    }
    for (int i = 0; i < npoints; i++) {
        const double L = s->patch[0];
        double x = xz[i][0], z = xz[i][1];
        struct base bs;
        for (int c = 0; c < s->ncasc; c++) { /* in [0, L_c) */
            bs.x[c] = turns(x, s->patch[c]) * s->patch[c];
            bs.z[c] = turns(z, s->patch[c]) * s->patch[c];
        }
        double ox, oz;
        struct ocean_point *p = &out[i];
        memset(p, 0, sizeof *p);
        /* The guess, as an offset from the point; guesses further than L/4
         * away are not guesses. */
        double gx = 0, gz = 0;
        if (start && fabs(start[i][0] - x) < 0.25 * L && fabs(start[i][1] - z) < 0.25 * L) {
            gx = start[i][0] - x;
            gz = start[i][1] - z;
        }
        invert_displacement(s, &w, &bs, gx, gz, &ox, &oz, &p->iterations, &p->converged);
        struct surface_sums q;
        eval_all(s, &w, &bs, ox, oz, &q);
        fill_point(&q, p);
        p->source[0] = x + ox;
        p->source[1] = z + oz;
    }
    free(buf);
    return 0;
}

int ocean_query(const struct ocean *o, double t, const double (*xz)[2], int npoints, struct ocean_point *out)
{
    char err[128];
    struct ocean_surface *s = ocean_surface_new(o, err, sizeof err);
    if (!s)
        return -1;
    int r = ocean_surface_query(s, t, xz, npoints, out);
    ocean_surface_free(s);
    return r;
}

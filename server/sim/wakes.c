/* wakes.c — the layer of dynamic waves bodies make (wakes.h).
 *
 * Each region is an n x n periodic grid that an absorbing sponge along its
 * edges makes non-periodic in effect. Its state is the height h and its
 * quadrature partner q, with q~ = (w/g) phi~ (phi the surface velocity
 * potential), so that per mode linear theory is
 *     (h~ + i q~)' = -i w (h~ + i q~) - i w P~,   P = pressure / (rho g),
 * a rotation by w dt about the static depression -P~: exact over any dt for
 * P held over the step, and energy-preserving (g/2 (|h~|^2 + |q~|^2) per
 * mode is the wave energy per density). A step:
 *   1. rasterise P, the bodies' footprints swept along their paths (r2c);
 *   2. turn every mode (the forced rotation above);
 *   3. back to the grid (c2r), shift by whole samples to follow the bodies
 *      (what leaves the grid is dropped, what enters is still water), and
 *      multiply h and q by the sponge's exp(-gamma dt) <= 1;
 *   4. forward again (r2c) for the next step; slopes, foam and energy.
 * Steps 3's factor <= 1 on both h and q is why the energy never grows.
 * Written by hand (not a library): it is the model itself; FFTW does the
 * transforms. docs/simulation.md, "Wakes". */
#include <complex.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <fftw3.h>

#include "ocean_internal.h"
#include "pool.h"
#include "wakes.h"

#define G        9.81
#define RHO      1025.0
#define PI       3.14159265358979323846
#define DEEP_KD  20.0   /* tanh(kD) = 1 above this */
#define CUT      1.6    /* the footprint is drawn out to this many lengths/beams from its centre */
#define HOLD     0.8    /* a region holds a body while its footprint to HOLD lengths is inside the interior */
#define LEAD     0.5    /* a moving body sits this share of the interior's half ahead of the centre (no wave runs ahead of it) */
#define FOAM_U0  1.5    /* m/s: slower bodies leave no stern foam */
#define FOAM_U1  6.0    /* m/s above FOAM_U0 for full stern foam */
#define FOAM_S0  0.25   /* wave slope where crests begin to break into foam */
#define FOAM_S1  0.15   /* slope above FOAM_S0 for full foam */
#define SPONGE_RATE 0.7 /* the sponge's strongest damping, per the frequency of waves as long as it (region_coef) */
#define QUIET_M  1e-6   /* a region idle and below this height everywhere is freed */

struct region {
    uint32_t id;
    double cell;
    long cx, cz;              /* centre in samples of the world lattice: x0 = (cx - n/2) cell */
    int shift_x, shift_z;     /* samples the centre moves this step */
    int nsrc, *src;           /* the step's sources (indices into the caller's array) */
    double idle;              /* s since a source last forced it */
    double energy, max_abs;
    double coef_dt;           /* dt the tables below are for (0: none yet) */
    float *omega, *cw, *sw;   /* per mode: w, cos(w dt), sin(w dt) */
    float *disp_x, *disp_z;   /* per mode: i kx/k coth(kD), i kz/k coth(kD) (imaginary parts) */
    float *damp;              /* per sample along an edge: exp(-gamma dt) */
    float *h, *q, *prev, *sx, *sz, *foam, *dx, *dz, *t1, *t2, *p;
    fftwf_complex *hh, *qh, *ph, *w1, *w2;
    double last_dt;
};

struct member { uint32_t id, region; };
struct order { uint32_t id; int i; };

struct wakes {
    struct wakes_options o;
    int n, nh;                /* n and n (n/2 + 1) complex modes */
    fftwf_plan r2c, c2r;
    struct region *reg[WAKES_MAX_REGIONS];
    int nreg;
    uint32_t next_region;
    double t;
    struct member *mem, *mem2; /* body -> region, ascending id; the next step's (swapped in) */
    int nmem, capmem;
    struct order *ord;
    int capord;
    struct pool *pool;
    const struct wake_source *src; /* during a step */
    double dt;
};

static int fail(char *err, size_t len, const char *msg)
{
    if (err && len)
        snprintf(err, len, "%s", msg);
    return -1;
}

static double tanh_kd(double k, double depth)
{
    return depth <= 0 || k * depth > DEEP_KD ? 1.0 : tanh(k * depth);
}

static void region_free(struct region *r)
{
    if (!r)
        return;
    float **f[] = {&r->omega, &r->cw, &r->sw, &r->disp_x, &r->disp_z, &r->damp, &r->h, &r->q, &r->prev,
                   &r->sx, &r->sz, &r->foam, &r->dx, &r->dz, &r->t1, &r->t2, &r->p};
    for (size_t i = 0; i < sizeof f / sizeof *f; i++)
        fftwf_free(*f[i]);
    fftwf_complex **c[] = {&r->hh, &r->qh, &r->ph, &r->w1, &r->w2};
    for (size_t i = 0; i < sizeof c / sizeof *c; i++)
        fftwf_free(*c[i]);
    free(r->src);
    free(r);
}

static float *zeros(size_t n)
{
    float *p = fftwf_malloc(n * sizeof *p);
    if (p)
        memset(p, 0, n * sizeof *p);
    return p;
}

static struct region *region_new(const struct wakes *w, double cell, long cx, long cz, int capsrc)
{
    int n = w->n, nh = w->nh;
    size_t nn = (size_t)n * n;
    struct region *r = calloc(1, sizeof *r);
    if (!r)
        return NULL;
    r->cell = cell;
    r->cx = cx;
    r->cz = cz;
    r->src = malloc((size_t)(capsrc > 0 ? capsrc : 1) * sizeof *r->src);
    r->omega = zeros((size_t)nh);
    r->cw = zeros((size_t)nh);
    r->sw = zeros((size_t)nh);
    r->disp_x = zeros((size_t)nh);
    r->disp_z = zeros((size_t)nh);
    r->damp = zeros((size_t)n);
    float **f[] = {&r->h, &r->q, &r->prev, &r->sx, &r->sz, &r->foam, &r->dx, &r->dz, &r->t1, &r->t2, &r->p};
    for (size_t i = 0; i < sizeof f / sizeof *f; i++)
        *f[i] = zeros(nn);
    fftwf_complex **c[] = {&r->hh, &r->qh, &r->ph, &r->w1, &r->w2};
    for (size_t i = 0; i < sizeof c / sizeof *c; i++) {
        *c[i] = fftwf_malloc((size_t)nh * sizeof(fftwf_complex));
        if (*c[i])
            memset(*c[i], 0, (size_t)nh * sizeof(fftwf_complex));
    }
    if (!r->src || !r->omega || !r->cw || !r->sw || !r->disp_x || !r->disp_z || !r->damp || !r->h || !r->q ||
        !r->prev || !r->sx || !r->sz || !r->foam || !r->dx || !r->dz || !r->t1 || !r->t2 || !r->p || !r->hh ||
        !r->qh || !r->ph || !r->w1 || !r->w2) {
        region_free(r);
        return NULL;
    }
    /* Modes of the half spectrum: row iz (kz), column ix <= n/2 (kx). */
    double dk = 2 * PI / (n * cell);
    for (int iz = 0; iz < n; iz++)
        for (int ix = 0; ix <= n / 2; ix++) {
            double kx = ix * dk, kz = (iz <= n / 2 ? iz : iz - n) * dk, k = hypot(kx, kz);
            size_t m = (size_t)iz * (n / 2 + 1) + ix;
            double th = tanh_kd(k, w->o.depth);
            r->omega[m] = (float)sqrt(G * k * th);
            bool nyq = ix == n / 2 || iz == n / 2 || k == 0;
            r->disp_x[m] = nyq ? 0 : (float)(kx / k / th);
            r->disp_z[m] = nyq ? 0 : (float)(kz / k / th);
        }
    return r;
}

/* cos, sin and the sponge for a new dt. The sponge's rate rises as the
 * cube of the depth into it, to gamma_max at the edge: SPONGE_RATE times
 * the angular frequency of a deep-water wave as long as the sponge is
 * wide. Stronger reflects more off the rise, weaker lets long waves
 * through: 0.7 leaves the least of a drop's ring in shallow water
 * (test_wakes energy.absorbed: 0.25 -> 8.7e-3, 0.5 -> 6.2e-4, 1 -> 8.8e-4,
 * 2 -> 1.8e-3 of the energy left after 60 s). */
static void region_coef(const struct wakes *w, struct region *r, double dt)
{
    if (r->coef_dt == dt)
        return;
    for (int m = 0; m < w->nh; m++) {
        r->cw[m] = (float)cos(r->omega[m] * dt);
        r->sw[m] = (float)sin(r->omega[m] * dt);
    }
    int n = w->n, s = w->o.sponge;
    double gmax = SPONGE_RATE * sqrt(G * 2 * PI / (s * r->cell));
    for (int i = 0; i < n; i++) {
        int d = i < s ? s - i : i >= n - s ? i - (n - s - 1) : 0;
        double u = (double)d / s;
        r->damp[i] = (float)exp(-gmax * u * u * u * dt);
    }
    r->coef_dt = dt;
}

/* ---- one region's step (may run on a pool thread) ------------------------ */

static void bow_of(const struct wake_source *s, double *bx, double *bz)
{
    double h = s->heading_deg * (PI / 180);
    *bx = -sin(h);
    *bz = cos(h);
}

/* Add the footprint of s centred at (x, z) times weight to field f (origin
 * x0, z0). mode 0: P (static depression, m); mode 1: stern foam as
 * max(f, weight * hull shape). */
static void draw(const struct wakes *w, const struct region *r, float *f, double x0, double z0,
                 const struct wake_source *s, double x, double z, double weight, int mode)
{
    int n = w->n;
    double bx, bz, c = r->cell;
    bow_of(s, &bx, &bz);
    double rad = CUT * fmax(s->length, s->beam);
    int ix0 = (int)floor((x - rad - x0) / c), ix1 = (int)ceil((x + rad - x0) / c);
    int iz0 = (int)floor((z - rad - z0) / c), iz1 = (int)ceil((z + rad - z0) / c);
    if (ix0 < 0) ix0 = 0;
    if (iz0 < 0) iz0 = 0;
    if (ix1 > n - 1) ix1 = n - 1;
    if (iz1 > n - 1) iz1 = n - 1;
    double il2 = 1 / (s->length * s->length), ib2 = 1 / (s->beam * s->beam);
    double cut2 = CUT * CUT;
    for (int iz = iz0; iz <= iz1; iz++) {
        double rz = z0 + iz * c - z;
        for (int ix = ix0; ix <= ix1; ix++) {
            double rx = x0 + ix * c - x;
            double a = rx * bx + rz * bz, b = -rx * bz + rz * bx;
            double e = a * a * il2 + b * b * ib2;
            if (e > cut2)
                continue;
            double v = weight * exp(-PI * e);
            size_t i = (size_t)iz * n + ix;
            if (mode == 0)
                f[i] += (float)v;
            else if (v > f[i])
                f[i] = (float)v;
        }
    }
}

static void region_step(struct wakes *w, struct region *r)
{
    const int n = w->n, nh = w->nh;
    const size_t nn = (size_t)n * n;
    const double dt = w->dt, cell = r->cell;
    region_coef(w, r, dt);
    double x0 = (r->cx - n / 2) * cell, z0 = (r->cz - n / 2) * cell; /* before the shift */

    /* 1. The forcing: each footprint averaged along its path over the step. */
    bool forced = r->nsrc > 0;
    if (forced) {
        memset(r->p, 0, nn * sizeof *r->p);
        for (int j = 0; j < r->nsrc; j++) {
            const struct wake_source *s = &w->src[r->src[j]];
            double amp = s->mass / (RHO * s->length * s->beam);
            double path = hypot(s->vx, s->vz) * dt;
            int m = (int)ceil(path / (0.5 * cell));
            m = m < 1 ? 1 : m > 16 ? 16 : m;
            for (int k = 0; k < m; k++) {
                double back = dt * (1 - (k + 0.5) / m);
                draw(w, r, r->p, x0, z0, s, s->x - s->vx * back, s->z - s->vz * back, amp / m, 0);
            }
        }
        fftwf_execute_dft_r2c(w->r2c, r->p, r->ph);
    }

    /* 2. Every mode turns by w dt about its static depression -P~. */
    float *hh = (float *)r->hh, *qh = (float *)r->qh, *ph = (float *)r->ph;
    float *w1 = (float *)r->w1, *w2 = (float *)r->w2;
    for (int m = 0; m < nh; m++) {
        float c = r->cw[m], s = r->sw[m];
        for (int part = 0; part < 2; part++) {
            float hp = forced ? -ph[2 * m + part] : 0.0f;
            float e = hh[2 * m + part] - hp, qv = qh[2 * m + part];
            hh[2 * m + part] = hp + c * e + s * qv;
            qh[2 * m + part] = c * qv - s * e;
        }
        if (w->o.displacement) { /* D~ = i k^ coth(kD) h~ */
            float re = hh[2 * m], im = hh[2 * m + 1];
            w1[2 * m] = -r->disp_x[m] * im;
            w1[2 * m + 1] = r->disp_x[m] * re;
            w2[2 * m] = -r->disp_z[m] * im;
            w2[2 * m + 1] = r->disp_z[m] * re;
        }
    }

    /* 3. Back to the grid, shifted and damped. */
    fftwf_execute_dft_c2r(w->c2r, r->hh, r->t1);
    fftwf_execute_dft_c2r(w->c2r, r->qh, r->t2);
    const float scale = 1.0f / (float)nn;
    const int sx = r->shift_x, sz = r->shift_z;
    const float fdecay = (float)exp(-dt / WAKES_FOAM_TAU);
    double energy = 0, max_abs = 0;
    const int x_lo = sx < 0 ? -sx : 0, x_hi = sx > 0 ? n - sx : n; /* new columns with an old sample */
    for (int iz = 0; iz < n; iz++) {
        int oz = iz + sz;
        float *hr = r->h + (size_t)iz * n, *qr = r->q + (size_t)iz * n;
        if (oz < 0 || oz >= n || x_lo >= x_hi) {
            memset(hr, 0, (size_t)n * sizeof *hr);
            memset(qr, 0, (size_t)n * sizeof *qr);
            continue;
        }
        const float *t1 = r->t1 + (size_t)oz * n + sx, *t2 = r->t2 + (size_t)oz * n + sx;
        const float dz = r->damp[iz] * scale;
        float row_max = 0;
        for (int ix = 0; ix < x_lo; ix++)
            hr[ix] = qr[ix] = 0;
        for (int ix = x_hi; ix < n; ix++)
            hr[ix] = qr[ix] = 0;
        for (int ix = x_lo; ix < x_hi; ix++) {
            float d = r->damp[ix] * dz;
            hr[ix] = t1[ix] * d;
            qr[ix] = t2[ix] * d;
            float a = fabsf(hr[ix]);
            row_max = a > row_max ? a : row_max;
        }
        for (int ix = x_lo; ix < x_hi; ix++)
            energy += (double)hr[ix] * hr[ix] + (double)qr[ix] * qr[ix];
        if (row_max > max_abs)
            max_abs = row_max;
    }
    /* prev and foam move with the grid: copied in an order that never reads a written sample. */
    float *moved[] = {r->prev, r->foam};
    for (int f = 0; f < 2; f++) {
        float *a = moved[f];
        if (sx == 0 && sz == 0)
            break;
        memcpy(r->t1, a, nn * sizeof *a);
        for (int iz = 0; iz < n; iz++)
            for (int ix = 0; ix < n; ix++) {
                int ox = ix + sx, oz = iz + sz;
                a[(size_t)iz * n + ix] = ox >= 0 && ox < n && oz >= 0 && oz < n ? r->t1[(size_t)oz * n + ox] : 0;
            }
    }
    if (w->o.displacement) {
        fftwf_execute_dft_c2r(w->c2r, r->w1, r->t1);
        fftwf_execute_dft_c2r(w->c2r, r->w2, r->t2);
        for (int iz = 0; iz < n; iz++)
            for (int ix = 0; ix < n; ix++) {
                int ox = ix + sx, oz = iz + sz;
                size_t i = (size_t)iz * n + ix, o = (size_t)oz * n + ox;
                bool in = ox >= 0 && ox < n && oz >= 0 && oz < n;
                r->dx[i] = in ? r->t1[o] * scale : 0;
                r->dz[i] = in ? r->t2[o] * scale : 0;
            }
    }
    r->cx += sx;
    r->cz += sz;
    r->shift_x = r->shift_z = 0;

    /* 4. Forward for the next step. */
    fftwf_execute_dft_r2c(w->r2c, r->h, r->hh); /* out of place: h is kept */
    fftwf_execute_dft_r2c(w->r2c, r->q, r->qh);

    /* Slopes (fourth-order differences: within 1 % up to waves of 8 samples). */
    const float inv = (float)(1.0 / (12 * cell));
    for (int iz = 0; iz < n; iz++) {
        const float *row = r->h + (size_t)iz * n;
        const float *up1 = r->h + (size_t)((iz + 1) % n) * n, *up2 = r->h + (size_t)((iz + 2) % n) * n;
        const float *dn1 = r->h + (size_t)((iz + n - 1) % n) * n, *dn2 = r->h + (size_t)((iz + n - 2) % n) * n;
        float *ox = r->sx + (size_t)iz * n, *oz = r->sz + (size_t)iz * n;
        for (int ix = 2; ix < n - 2; ix++) { /* the interior: no wrapping, vectorises */
            ox[ix] = (8 * (row[ix + 1] - row[ix - 1]) - (row[ix + 2] - row[ix - 2])) * inv;
            oz[ix] = (8 * (up1[ix] - dn1[ix]) - (up2[ix] - dn2[ix])) * inv;
        }
        const int edge[4] = {0, 1, n - 2, n - 1};
        for (int e = 0; e < 4; e++) {
            int ix = edge[e], a1 = (ix + 1) % n, a2 = (ix + 2) % n, b1 = (ix + n - 1) % n, b2 = (ix + n - 2) % n;
            ox[ix] = (8 * (row[a1] - row[b1]) - (row[a2] - row[b2])) * inv;
            oz[ix] = (8 * (up1[ix] - dn1[ix]) - (up2[ix] - dn2[ix])) * inv;
        }
    }

    /* Foam: the old fades; steep crests and the sterns of fast bodies add. */
    for (size_t i = 0; i < nn; i++) {
        float s = sqrtf(r->sx[i] * r->sx[i] + r->sz[i] * r->sz[i]);
        float inject = (s - (float)FOAM_S0) * (float)(1.0 / FOAM_S1);
        inject = inject < 0 ? 0 : inject > 1 ? 1 : inject;
        float old = r->foam[i] * fdecay;
        r->foam[i] = old > inject ? old : inject;
    }
    double nx0 = (r->cx - n / 2) * cell, nz0 = (r->cz - n / 2) * cell;
    for (int j = 0; j < r->nsrc; j++) {
        const struct wake_source *s = &w->src[r->src[j]];
        double u = (hypot(s->vx, s->vz) - FOAM_U0) / FOAM_U1;
        if (u > 0)
            draw(w, r, r->foam, nx0, nz0, s, s->x, s->z, fmin(u, 1.0), 1);
    }

    /* prev becomes this step's h after dhdt's sample reads (h - prev) / dt: keep both. */
    memcpy(r->t2, r->prev, nn * sizeof *r->t2); /* t2 = the previous height, shifted */
    memcpy(r->prev, r->h, nn * sizeof *r->prev);
    r->energy = 0.5 * G * energy * cell * cell;
    r->max_abs = max_abs;
    r->last_dt = dt;
}

static void step_item(void *ctx, int i0, int i1, int worker)
{
    struct wakes *w = ctx;
    for (int i = i0; i < i1; i++)
        region_step(w, w->reg[i]);
}

/* ---- the layer ------------------------------------------------------------ */

static bool is_pow2(int n) { return n > 0 && (n & (n - 1)) == 0; }

struct wakes *wakes_new(const struct wakes_options *opt, char *err, size_t errlen)
{
    struct wakes_options o = opt ? *opt : (struct wakes_options){0};
    if (!isfinite(o.depth) || o.depth < 0)
        return fail(err, errlen, "depth: must be > 0 m (0 = deep)"), NULL;
    if (o.depth >= 1e4)
        o.depth = 0;
    if (o.n == 0)
        o.n = 128;
    if (!is_pow2(o.n) || o.n < 32 || o.n > 1024)
        return fail(err, errlen, "n: must be a power of two, 32..1024"), NULL;
    if (!isfinite(o.cell) || (o.cell != 0 && (o.cell < 0.05 || o.cell > 50)))
        return fail(err, errlen, "cell: must be 0.05..50 m (0 = per region)"), NULL;
    if (o.sponge == 0)
        o.sponge = o.n / 8;
    if (o.sponge < 4 || o.sponge > o.n / 4)
        return fail(err, errlen, "sponge: must be 4..n/4 samples"), NULL;
    if (o.max_regions == 0)
        o.max_regions = 16;
    if (o.max_regions < 1 || o.max_regions > WAKES_MAX_REGIONS)
        return fail(err, errlen, "max_regions: must be 1..64"), NULL;
    if (o.threads == 0)
        o.threads = 1;
    if (o.threads < 1 || o.threads > 64)
        return fail(err, errlen, "threads: must be 1..64"), NULL;
    o.displacement = o.displacement != 0;
    if (o.plan_rigor != 0 && o.plan_rigor != 1)
        return fail(err, errlen, "plan_rigor: must be 0 (estimate) or 1 (measure)"), NULL;

    struct wakes *w = calloc(1, sizeof *w);
    if (!w)
        return fail(err, errlen, "no memory"), NULL;
    w->o = o;
    w->n = o.n;
    w->nh = o.n * (o.n / 2 + 1);
    w->next_region = 1;
    float *a = fftwf_malloc((size_t)o.n * o.n * sizeof *a);
    fftwf_complex *b = fftwf_malloc((size_t)w->nh * sizeof *b);
    if (a && b) {
        /* Planned once for every region (executed on each one's own
         * arrays, all from fftwf_malloc: the same alignment); one thread
         * each, since regions run in parallel. */
        ocean_fftw_init();
        ocean_fftw_lock();
        fftwf_plan_with_nthreads(1);
        unsigned rigor = o.plan_rigor ? FFTW_MEASURE : FFTW_ESTIMATE;
        w->r2c = fftwf_plan_dft_r2c_2d(o.n, o.n, a, b, rigor);
        w->c2r = fftwf_plan_dft_c2r_2d(o.n, o.n, b, a, rigor | FFTW_DESTROY_INPUT);
        ocean_fftw_unlock();
    }
    fftwf_free(a);
    fftwf_free(b);
    if (!w->r2c || !w->c2r) {
        wakes_free(w);
        return fail(err, errlen, "no memory (FFT plans)"), NULL;
    }
    if (o.threads > 1)
        w->pool = pool_new(o.threads - 1); /* NULL: the caller steps every region itself */
    return w;
}

void wakes_free(struct wakes *w)
{
    if (!w)
        return;
    pool_free(w->pool);
    for (int i = 0; i < w->nreg; i++)
        region_free(w->reg[i]);
    ocean_fftw_lock();
    if (w->r2c)
        fftwf_destroy_plan(w->r2c);
    if (w->c2r)
        fftwf_destroy_plan(w->c2r);
    ocean_fftw_unlock();
    free(w->mem);
    free(w->mem2);
    free(w->ord);
    free(w);
}

static int cmp_order(const void *a, const void *b)
{
    uint32_t x = ((const struct order *)a)->id, y = ((const struct order *)b)->id;
    return (x > y) - (x < y);
}

static bool source_ok(const struct wake_source *s)
{
    return s->id != 0 && isfinite(s->x) && isfinite(s->z) && isfinite(s->vx) && isfinite(s->vz) &&
           isfinite(s->heading_deg) && isfinite(s->length) && isfinite(s->beam) && isfinite(s->mass) &&
           s->length > 0 && s->beam > 0 && s->mass >= 0;
}

static double auto_cell(const struct wakes *w, const struct wake_source *s)
{
    if (w->o.cell > 0)
        return w->o.cell;
    double c = exp2(round(log2(s->length / 6)));
    return c < 0.25 ? 0.25 : c > 8 ? 8 : c;
}

/* Whether r's interior holds s's footprint (HOLD of its size) around (x, z). */
static bool holds(const struct wakes *w, const struct region *r, const struct wake_source *s)
{
    double half = (w->n / 2 - w->o.sponge) * r->cell - HOLD * fmax(s->length, s->beam);
    return half > 0 && fabs(s->x - r->cx * r->cell) <= half && fabs(s->z - r->cz * r->cell) <= half;
}

static uint32_t member_region(const struct wakes *w, uint32_t id)
{
    int lo = 0, hi = w->nmem - 1;
    while (lo <= hi) {
        int mid = (lo + hi) / 2;
        if (w->mem[mid].id == id)
            return w->mem[mid].region;
        if (w->mem[mid].id < id)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return 0;
}

static struct region *region_by_id(struct wakes *w, uint32_t id)
{
    for (int i = 0; i < w->nreg; i++)
        if (w->reg[i]->id == id)
            return w->reg[i];
    return NULL;
}

/* Where a region centres on its bodies: their mean position, moved back
 * against their mean velocity so that more of the wake stays inside. */
static void target_centre(const struct wakes *w, const struct region *r, long *cx, long *cz)
{
    double x = 0, z = 0, vx = 0, vz = 0;
    for (int j = 0; j < r->nsrc; j++) {
        const struct wake_source *s = &w->src[r->src[j]];
        x += s->x;
        z += s->z;
        vx += s->vx;
        vz += s->vz;
    }
    x /= r->nsrc;
    z /= r->nsrc;
    vx /= r->nsrc;
    vz /= r->nsrc;
    double v = hypot(vx, vz);
    if (v > 1e-9) {
        double lead = LEAD * (w->n / 2 - w->o.sponge) * r->cell * fmin(1.0, v);
        x -= lead * vx / v;
        z -= lead * vz / v;
    }
    *cx = lround(x / r->cell);
    *cz = lround(z / r->cell);
}

static void region_drop(struct wakes *w, int i)
{
    region_free(w->reg[i]);
    memmove(&w->reg[i], &w->reg[i + 1], (size_t)(w->nreg - i - 1) * sizeof *w->reg);
    w->nreg--;
}

int wakes_step(struct wakes *w, double dt, int n, const struct wake_source *src, uint32_t *uncovered,
               int max_uncovered)
{
    if (!w || !isfinite(dt) || dt <= 0 || dt > WAKES_STEP_MAX_S || n < 0 || (n > 0 && !src))
        return -1;
    for (int i = 0; i < n; i++)
        if (!source_ok(&src[i]))
            return -1;
    /* Room first (so that a refusal for no memory changes nothing either). */
    if (n > w->capord || n > w->capmem) {
        int cap = n + n / 2 + 8;
        struct order *o = realloc(w->ord, (size_t)cap * sizeof *o);
        if (!o)
            return -1;
        w->ord = o;
        w->capord = cap;
        struct member *m = malloc((size_t)cap * sizeof *m), *m2 = malloc((size_t)cap * sizeof *m2);
        if (!m || !m2) {
            free(m);
            free(m2);
            return -1;
        }
        if (w->nmem)
            memcpy(m, w->mem, (size_t)w->nmem * sizeof *m);
        free(w->mem);
        free(w->mem2);
        w->mem = m;
        w->mem2 = m2;
        w->capmem = cap;
    }
    for (int i = 0; i < n; i++)
        w->ord[i] = (struct order){src[i].id, i};
    qsort(w->ord, (size_t)n, sizeof *w->ord, cmp_order);
    for (int i = 1; i < n; i++)
        if (w->ord[i].id == w->ord[i - 1].id)
            return -1;
    for (int i = 0; i < w->nreg; i++) {
        int *s = realloc(w->reg[i]->src, (size_t)(n > 0 ? n : 1) * sizeof *s);
        if (!s)
            return -1;
        w->reg[i]->src = s;
        w->reg[i]->nsrc = 0;
    }

    /* Bodies to regions, in ascending id order (deterministic). A body
     * keeps its region while the region's interior holds it; else it
     * joins another that does (of its cell size), else opens one. */
    w->src = src;
    w->dt = dt;
    int nun = 0, nmem = 0;
    struct member *newmem = w->mem2; /* the old table is read while the new one is written */
    for (int k = 0; k < n; k++) {
        const struct wake_source *s = &src[w->ord[k].i];
        struct region *r = NULL;
        bool inside = fabs(s->x) <= WAKES_WORLD_HALF_M && fabs(s->z) <= WAKES_WORLD_HALF_M;
        if (inside) {
            struct region *old = region_by_id(w, member_region(w, s->id));
            double cell = auto_cell(w, s);
            if (old && holds(w, old, s))
                r = old;
            for (int i = 0; !r && i < w->nreg; i++)
                if (w->reg[i]->cell == cell && holds(w, w->reg[i], s))
                    r = w->reg[i];
            /* A new region, centred as target_centre will put it, must hold the body. */
            bool fits = (w->n / 2 - w->o.sponge) * cell * (1 - LEAD) >= HOLD * fmax(s->length, s->beam) + cell;
            if (!r && fits && w->nreg == w->o.max_regions) { /* room: the longest idle region goes */
                int best = -1;
                for (int i = 0; i < w->nreg; i++)
                    if (w->reg[i]->idle > 0 && w->reg[i]->nsrc == 0 &&
                        (best < 0 || w->reg[i]->idle > w->reg[best]->idle))
                        best = i;
                if (best >= 0)
                    region_drop(w, best);
            }
            if (!r && fits && w->nreg < w->o.max_regions) {
                r = region_new(w, cell, lround(s->x / cell), lround(s->z / cell), n);
                if (r) {
                    r->id = w->next_region < UINT32_MAX ? w->next_region++ : UINT32_MAX;
                    w->reg[w->nreg++] = r;
                    r->nsrc = 0;
                    r->src[r->nsrc++] = w->ord[k].i;
                    long cx, cz;
                    target_centre(w, r, &cx, &cz);
                    r->cx = cx; /* a new grid is still water: centre it where it belongs */
                    r->cz = cz;
                    r->nsrc = 0;
                }
            }
        }
        if (!r) {
            if (uncovered && nun < max_uncovered)
                uncovered[nun] = s->id;
            nun++;
            continue;
        }
        r->src[r->nsrc++] = w->ord[k].i;
        newmem[nmem++] = (struct member){s->id, r->id};
    }
    w->mem2 = w->mem;
    w->mem = newmem;
    w->nmem = nmem;

    /* Regions follow their bodies; idle ones linger, then go. */
    for (int i = 0; i < w->nreg; i++) {
        struct region *r = w->reg[i];
        if (r->nsrc > 0) {
            long cx, cz;
            target_centre(w, r, &cx, &cz);
            long dx = cx - r->cx, dz = cz - r->cz, lim = w->n;
            r->shift_x = (int)(dx > lim ? lim : dx < -lim ? -lim : dx);
            r->shift_z = (int)(dz > lim ? lim : dz < -lim ? -lim : dz);
            r->idle = 0;
        } else {
            r->shift_x = r->shift_z = 0;
        }
    }
    for (int i = w->nreg - 1; i >= 0; i--) {
        struct region *r = w->reg[i];
        if (r->nsrc == 0 && (r->idle >= WAKES_LINGER_S || (r->idle > 0 && r->max_abs < QUIET_M)))
            region_drop(w, i);
    }

    pool_for(w->pool, w->o.threads, w->nreg, step_item, w);
    for (int i = 0; i < w->nreg; i++)
        if (w->reg[i]->nsrc == 0)
            w->reg[i]->idle += dt;
    w->src = NULL;
    w->t += dt;
    return nun;
}

void wakes_sample(const struct wakes *w, int n, const double (*xz)[2], struct wakes_point *out)
{
    const int g = w->n;
    for (int k = 0; k < n; k++) {
        struct wakes_point p = {0};
        for (int i = 0; i < w->nreg; i++) {
            const struct region *r = w->reg[i];
            double fx = xz[k][0] / r->cell - (r->cx - g / 2), fz = xz[k][1] / r->cell - (r->cz - g / 2);
            if (!(fx >= 0 && fz >= 0 && fx < g - 1 && fz < g - 1))
                continue;
            int ix = (int)fx, iz = (int)fz;
            double ax = fx - ix, az = fz - iz;
            size_t i00 = (size_t)iz * g + ix, i10 = i00 + 1, i01 = i00 + g, i11 = i01 + 1;
            double w00 = (1 - ax) * (1 - az), w10 = ax * (1 - az), w01 = (1 - ax) * az, w11 = ax * az;
#define BIL(f) (w00 * (f)[i00] + w10 * (f)[i10] + w01 * (f)[i01] + w11 * (f)[i11])
            p.height += BIL(r->h);
            p.slope_x += BIL(r->sx);
            p.slope_z += BIL(r->sz);
            if (w->o.displacement) {
                p.dx += BIL(r->dx);
                p.dz += BIL(r->dz);
            }
            if (r->last_dt > 0)
                p.dhdt += (BIL(r->h) - BIL(r->t2)) / r->last_dt;
            p.foam += BIL(r->foam);
#undef BIL
        }
        p.foam = p.foam > 1 ? 1 : p.foam;
        out[k] = p;
    }
}

double wakes_energy(const struct wakes *w)
{
    double e = 0;
    for (int i = 0; i < w->nreg; i++)
        e += w->reg[i]->energy;
    return e;
}

double wakes_time(const struct wakes *w) { return w->t; }
int wakes_region_count(const struct wakes *w) { return w->nreg; }

int wakes_region_get(const struct wakes *w, int i, struct wakes_region *out)
{
    if (i < 0 || i >= w->nreg)
        return -1;
    const struct region *r = w->reg[i];
    int n = w->n;
    *out = (struct wakes_region){r->id, n, r->cell, (r->cx - n / 2) * r->cell, (r->cz - n / 2) * r->cell,
                                 w->o.sponge, r->nsrc, r->h, r->sx, r->sz, r->foam,
                                 w->o.displacement ? r->dx : NULL, w->o.displacement ? r->dz : NULL};
    return 0;
}

/* test_query.c — point queries (ocean_query.c) against a brute-force reference.
 *
 * The reference is computed here, independently of ocean_query.c: the full
 * N x N spectrum h~(k, t) from ocean_reference_spectrum (double precision,
 * amplitudes recomputed from the spectrum model, not the stored floats),
 * every field summed directly as Re sum_k F~(k) e^{i k.x} with the raw
 * (unreduced) coordinates, and the displacement inverted by its own Newton
 * iteration. Checks, at random points including negative and very large
 * coordinates, choppiness 0, 1 and 2, N = 32 .. 512:
 *   - the returned source x0 maps onto the queried point under the
 *     reference displacement, and the height is the reference height there
 *     (<= 1 mm; in fact ~1e-9 m);
 *   - the normal is the reference normal of the displaced surface (<= 0.5 deg);
 *   - vertical velocity / acceleration match central finite differences in
 *     time of the reference height over the fixed world point, and the
 *     particle values match differences at the fixed source point;
 *   - periodicity, agreement with the FFT grid, bad input, thread safety.
 * One line per check, then "N passed, M failed"; exit 1 on any failure.
 * OCEAN_TEST_QUICK=1 (valgrind) skips N >= 256. Build: make test-query. */
#include <complex.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ocean_internal.h"

#include "common/check.h"

static int quick;

/* cascades 0: the default (params_defaults); depth 0: the default. */
static struct ocean *make_sea(int n, double chop, int spectrum, int cascades, double depth)
{
    struct ocean_params p;
    params_defaults(&p);
    if (cascades > 0)
        p.cascades = cascades;
    if (depth > 0)
        p.depth = depth;
    p.resolution = n;
    p.choppiness = chop;
    p.spectrum = spectrum;
    p.wind_speed = 12;
    p.patch_size = n <= 64 ? 64 : 256;
    char err[256] = "";
    struct ocean_options opt = {1, NULL, 0};
    struct ocean *o = ocean_create(&p, &opt, err, sizeof err);
    if (!o)
        CHECK(0, "create: ocean_create failed: %s", err);
    return o;
}

static struct ocean *make(int n, double chop, int spectrum)
{
    return make_sea(n, chop, spectrum, 0, 0);
}

/* xorshift: reproducible random points without libc's rand state. */
static unsigned long long rng = 0x9e3779b97f4a7c15ull;
static double uniform(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (rng >> 11) * 0x1.0p-53;
}

/* ---- the reference ------------------------------------------------------- */

enum { R_H, R_DX, R_DZ, R_SX, R_SZ, R_JXX, R_JZZ, R_JXZ, R_COUNT };

/* The whole sea: the sum over its cascades c (each over its own patch L_c
 * and its own spectrum, ocean_reference_spectrum_of), or cascade 0 alone
 * when ref_init_cascades is asked for 1 (to show a test would fail). */
struct reference {
    int n, nc;
    double L[OCEAN_MAX_CASCADES], lambda, depth;
    double complex *h[OCEAN_MAX_CASCADES];  /* N x N spectrum of the height at time t */
    double *k[OCEAN_MAX_CASCADES];          /* wavenumber per index */
};

static void ref_init_cascades(struct reference *r, const struct ocean *o, double t, int count)
{
    memset(r, 0, sizeof *r);
    r->n = ocean_resolution(o);
    r->nc = count;
    r->lambda = ocean_get_params(o)->choppiness;
    r->depth = ocean_get_params(o)->depth;
    size_t nn = (size_t)r->n * r->n;
    for (int c = 0; c < r->nc; c++) {
        r->L[c] = ocean_get_params(o)->patch_size / pow(OCEAN_CASCADE_RATIO, c);
        r->h[c] = malloc(nn * sizeof *r->h[c]);
        r->k[c] = malloc((size_t)r->n * sizeof *r->k[c]);
        if (c == 0)
            ocean_reference_spectrum(o, t, TR_H, r->h[c]);
        else
            ocean_reference_spectrum_of(o, o->fine[c], &o->fine_model[c], t, TR_H, r->h[c]);
        for (int i = 0; i < r->n; i++)
            r->k[c][i] = 2.0 * M_PI * (i <= r->n / 2 ? i : i - r->n) / r->L[c];
    }
}

static void ref_init(struct reference *r, const struct ocean *o, double t)
{
    ref_init_cascades(r, o, t, ocean_cascades(o));
}

static void ref_free(struct reference *r)
{
    for (int c = 0; c < r->nc; c++) {
        free(r->h[c]);
        free(r->k[c]);
    }
}

/* All eight fields at the world point (x, z), straight from their
 * definition: the raw coordinates, every mode of every cascade, the
 * horizontal factor coth(k depth)/k of linear theory. */
static void ref_eval(const struct reference *r, double x, double z, double v[R_COUNT])
{
    double complex s[R_COUNT] = {0};
    for (int c = 0; c < r->nc; c++) {
        for (int iz = 0; iz < r->n; iz++) {
            for (int ix = 0; ix < r->n; ix++) {
                double complex h = r->h[c][(size_t)iz * r->n + ix];
                if (h == 0)
                    continue;
                double kx = r->k[c][ix], kz = r->k[c][iz], k = hypot(kx, kz);
                double ik = k > 0 ? 1.0 / (k * tanh(k * r->depth)) : 0.0;
                double complex f = h * cexp(I * (kx * x + kz * z));
                s[R_H] += f;
                s[R_DX] += I * r->lambda * kx * ik * f;
                s[R_DZ] += I * r->lambda * kz * ik * f;
                s[R_SX] += I * kx * f;
                s[R_SZ] += I * kz * f;
                s[R_JXX] += -r->lambda * kx * kx * ik * f;
                s[R_JZZ] += -r->lambda * kz * kz * ik * f;
                s[R_JXZ] += -r->lambda * kx * kz * ik * f;
            }
        }
    }
    for (int i = 0; i < R_COUNT; i++)
        v[i] = creal(s[i]);
}

/* Source x0 of the world point (x, z): x0 + D(x0) = x, by Newton from x.
 * Returns 1 when converged to tol. */
static int ref_invert(const struct reference *r, double x, double z, double tol, double *x0, double *z0)
{
    double a = x, b = z, v[R_COUNT];
    for (int it = 0; it < 80; it++) {
        ref_eval(r, a, b, v);
        double rx = a + v[R_DX] - x, rz = b + v[R_DZ] - z;
        if (hypot(rx, rz) < tol) {
            *x0 = a;
            *z0 = b;
            return 1;
        }
        double a11 = 1 + v[R_JXX], a12 = v[R_JXZ], a22 = 1 + v[R_JZZ], det = a11 * a22 - a12 * a12;
        double sx = rx, sz = rz;
        if (fabs(det) > 1e-2) {
            sx = (a22 * rx - a12 * rz) / det;
            sz = (a11 * rz - a12 * rx) / det;
        }
        double damp = it < 20 ? 1.0 : 0.5;
        a -= damp * sx;
        b -= damp * sz;
    }
    *x0 = a;
    *z0 = b;
    return 0;
}

static void ref_normal(const double v[R_COUNT], double n[3])
{
    double tx[3] = {1 + v[R_JXX], v[R_SX], v[R_JXZ]}, tz[3] = {v[R_JXZ], v[R_SZ], 1 + v[R_JZZ]};
    n[0] = tz[1] * tx[2] - tz[2] * tx[1];
    n[1] = tz[2] * tx[0] - tz[0] * tx[2];
    n[2] = tz[0] * tx[1] - tz[1] * tx[0];
    double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int i = 0; i < 3; i++)
        n[i] /= l;
}

static double angle_deg(const double a[3], const double b[3])
{
    double c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    return atan2(sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), dot) * 180.0 / M_PI;
}

/* Random query points: a third near the origin (both signs), a third far
 * (|x| up to 1e7 m), the rest in between. */
static void random_points(double (*xz)[2], int count, double L)
{
    for (int i = 0; i < count; i++) {
        double scale = i % 3 == 0 ? 2 * L : i % 3 == 1 ? 1e7 : 1e4;
        xz[i][0] = (2 * uniform() - 1) * scale;
        xz[i][1] = (2 * uniform() - 1) * scale;
    }
    xz[0][0] = -0.0; /* a grid point, and a negative-zero sign */
    xz[0][1] = 0.0;
}

/* ---- accuracy against the reference ---------------------------------------- */

/* cascades, depth: 0 = the defaults (3 cascades, 1000 m). */
static void test_accuracy_sea(int n, double chop, int spectrum, int count, int cascades, double depth)
{
    struct ocean *o = make_sea(n, chop, spectrum, cascades, depth);
    if (!o)
        return;
    const double t = 37.25, L = ocean_get_params(o)->patch_size;
    double(*xz)[2] = malloc((size_t)count * sizeof *xz);
    struct ocean_point *out = malloc((size_t)count * sizeof *out);
    random_points(xz, count, L);
    struct reference r, r0;
    ref_init(&r, o, t);
    ref_init_cascades(&r0, o, t, 1);
    int rc = ocean_query(o, t, (const double(*)[2])xz, count, out);
    double worst_h = 0, worst_map = 0, worst_n = 0, worst_d = 0, hmax = 0, c0_off = 0;
    int unconverged = 0, folded = 0, ref_agree = 0, ref_tried = 0;
    for (int i = 0; i < count && rc == 0; i++) {
        const struct ocean_point *p = &out[i];
        double v[R_COUNT], nref[3];
        /* Solution-agnostic: wherever our source lies, the reference must
         * map it onto the queried point and give our height there. */
        ref_eval(&r, p->source[0], p->source[1], v);
        double map = hypot(p->source[0] + v[R_DX] - xz[i][0], p->source[1] + v[R_DZ] - xz[i][1]);
        worst_map = fmax(worst_map, map);
        worst_h = fmax(worst_h, fabs(p->height - v[R_H]));
        worst_d = fmax(worst_d, fmax(fabs(p->displacement[0] - v[R_DX]), fabs(p->displacement[1] - v[R_DZ])));
        hmax = fmax(hmax, fabs(v[R_H]));
        double v0[R_COUNT]; /* cascade 0 alone, at the same source: what the query must not be */
        ref_eval(&r0, p->source[0], p->source[1], v0);
        c0_off = fmax(c0_off, fabs(p->height - v0[R_H]));
        ref_normal(v, nref);
        worst_n = fmax(worst_n, angle_deg(p->normal, nref));
        unconverged += !p->converged;
        folded += p->jacobian <= 0;
        /* Where the surface does not fold, the source is unique: the
         * reference's own inversion must find the same height. */
        if (p->jacobian > 0.2) {
            double x0, z0;
            ref_tried++;
            if (ref_invert(&r, xz[i][0], xz[i][1], 1e-8, &x0, &z0)) {
                double w[R_COUNT];
                ref_eval(&r, x0, z0, w);
                ref_agree += fabs(w[R_H] - p->height) <= 1e-3;
            }
        }
    }
    const int nc = ocean_cascades(o);
    char name[128];
    snprintf(name, sizeof name, "query.accuracy.N%d.%s.chop%g.cascades%d%s", n,
             param_enum_name(param_find("spectrum"), spectrum), chop, nc, depth > 0 ? ".shallow" : "");
    /* With finer cascades, cascade 0 alone is centimetres off the sum at
     * some point: a query of cascade 0 only would fail the 1 mm bound. */
    CHECK(rc == 0 && worst_h <= 1e-3 && worst_map <= 1e-6 && worst_n <= 0.5 && worst_d <= 1e-3 &&
              unconverged == 0 && ref_agree == ref_tried && hmax > 0 && (nc == 1 || c0_off > 2e-3),
          "%s: %d points (|x| to 1e7 m), %d cascade(s), depth %g m: height err %.2e m (max |h| %.2f m; cascade 0 alone "
          "%.1e m off), |x0+D(x0)-x| %.1e m, disp err %.1e m, normal %.2e deg, unconverged %d, folded %d, "
          "reference inversion agrees %d/%d", name,
          count, nc, ocean_get_params(o)->depth, worst_h, hmax, c0_off, worst_map, worst_d, worst_n, unconverged,
          folded, ref_agree, ref_tried);
    ref_free(&r);
    ref_free(&r0);
    free(xz);
    free(out);
    ocean_free(o);
}

static void test_accuracy(int n, double chop, int spectrum, int count)
{
    test_accuracy_sea(n, chop, spectrum, count, 0, 0);
}

/* A steep, very choppy sea folds over: several surface points land on one
 * (x, z). Whichever the query picks, the reference must map it there. */
static void test_folds(void)
{
    struct ocean *o = make(64, 4.0, SPECTRUM_JONSWAP);
    if (!o)
        return;
    struct ocean_params p = *ocean_get_params(o);
    p.wind_speed = 20;
    p.amplitude = 3;
    char err[128];
    ocean_reconfigure(o, &p, err, sizeof err);
    enum { COUNT = 200 };
    double(*xz)[2] = malloc(COUNT * sizeof *xz);
    struct ocean_point *out = malloc(COUNT * sizeof *out);
    random_points(xz, COUNT, p.patch_size);
    struct reference r;
    ref_init(&r, o, 3.0);
    int rc = ocean_query(o, 3.0, (const double(*)[2])xz, COUNT, out);
    int folded = 0, converged = 0;
    double worst_map = 0, worst_h = 0;
    for (int i = 0; i < COUNT && rc == 0; i++) {
        double v[R_COUNT];
        ref_eval(&r, out[i].source[0], out[i].source[1], v);
        folded += out[i].jacobian <= 0;
        converged += out[i].converged;
        worst_map = fmax(worst_map, hypot(out[i].source[0] + v[R_DX] - xz[i][0], out[i].source[1] + v[R_DZ] - xz[i][1]));
        worst_h = fmax(worst_h, fabs(out[i].height - v[R_H]));
    }
    CHECK(rc == 0 && folded > 0 && converged == COUNT && worst_map <= 1e-6 && worst_h <= 1e-3, "query.folds: chop "
          "4, amplitude 3: %d of %d sources on folded sheets, %d converged, |x0+D(x0)-x| %.1e m, height %.1e m",
          folded, COUNT, converged, worst_map, worst_h);
    ref_free(&r);
    free(xz);
    free(out);
    ocean_free(o);
}

/* ---- time derivatives against finite differences --------------------------- */

static void test_derivatives(int n, double chop)
{
    struct ocean *o = make(n, chop, SPECTRUM_JONSWAP);
    if (!o)
        return;
    const double t = 12.5, dt = 1e-3, L = ocean_get_params(o)->patch_size;
    enum { COUNT = 8 };
    double xz[COUNT][2];
    random_points(xz, COUNT, L);
    struct ocean_point out[COUNT];
    int rc = ocean_query(o, t, (const double(*)[2])xz, COUNT, out);
    struct reference rm, r0, rp;
    ref_init(&rm, o, t - dt);
    ref_init(&r0, o, t);
    ref_init(&rp, o, t + dt);
    double ev = 0, ea = 0, epv = 0, epa = 0, vmax = 0, amax = 0, euler_vs_particle = 0;
    int used = 0;
    for (int i = 0; i < COUNT && rc == 0; i++) {
        const struct ocean_point *p = &out[i];
        if (p->jacobian < 0.2)
            continue; /* near a fold the source jumps: no smooth height(t) */
        double hs[3], ps[3];
        const struct reference *rs[3] = {&rm, &r0, &rp};
        int ok = 1;
        for (int k = 0; k < 3; k++) {
            double x0, z0, v[R_COUNT];
            ok &= ref_invert(rs[k], xz[i][0], xz[i][1], 1e-12 * fmax(1.0, fabs(xz[i][0]) + fabs(xz[i][1])), &x0, &z0);
            ref_eval(rs[k], x0, z0, v);
            hs[k] = v[R_H];
            ref_eval(rs[k], p->source[0], p->source[1], v);
            ps[k] = v[R_H];
        }
        if (!ok)
            continue;
        used++;
        double fv = (hs[2] - hs[0]) / (2 * dt), fa = (hs[2] - 2 * hs[1] + hs[0]) / (dt * dt);
        double pv = (ps[2] - ps[0]) / (2 * dt), pa = (ps[2] - 2 * ps[1] + ps[0]) / (dt * dt);
        ev = fmax(ev, fabs(p->vertical_velocity - fv));
        ea = fmax(ea, fabs(p->vertical_acceleration - fa));
        epv = fmax(epv, fabs(p->particle_velocity - pv));
        epa = fmax(epa, fabs(p->particle_acceleration - pa));
        vmax = fmax(vmax, fabs(fv));
        amax = fmax(amax, fabs(fa));
        euler_vs_particle = fmax(euler_vs_particle, fabs(fv - pv));
    }
    char name[64];
    snprintf(name, sizeof name, "query.time_derivatives.N%d.chop%g", n, chop);
    /* Tolerances: finite-difference truncation (dt^2 w^3 a) and rounding
     * (1e-12 m / dt^2 for the acceleration) are far below these. */
    CHECK(rc == 0 && used >= COUNT / 2 && ev <= 1e-5 + 1e-4 * vmax && ea <= 1e-3 + 1e-3 * amax && epv <= 1e-5 &&
              epa <= 1e-3,
          "%s: %d points: d(height)/dt err %.1e m/s (max %.2f), d2/dt2 err %.1e m/s^2 (max %.2f); particle %.1e, %.1e; "
          "|Eulerian - particle| up to %.2e m/s", name,
          used, ev, vmax, ea, amax, epv, epa, euler_vs_particle);
    ref_free(&rm);
    ref_free(&r0);
    ref_free(&rp);
    ocean_free(o);
}


/* During an easing's ramp (ocean_commit_eased: the amplitudes move from the
 * old sea's to the new one's over len seconds) the time derivatives include
 * the amplitudes' own rate: they match finite differences of the query's own
 * heights at a fixed world point (the heights equal the stepped sea's during
 * an easing: easing.query_equals_step in test_ocean). Without the rate the
 * velocity misses (to - from)/len, as large as the swell's own rate here. */
static void test_derivatives_easing(void)
{
    struct ocean *o = make(64, 1.0, SPECTRUM_JONSWAP);
    if (!o)
        return;
    struct ocean_params q = *ocean_get_params(o);
    q.wind_speed = 20; /* a new sea's worth of amplitude over 8 ticks */
    char err[256];
    const double t0 = 30.0, len = 8.0 / 30, dt = 4e-3, L = q.patch_size;
    struct ocean_prepared *pr = ocean_prepare(o, &q, err, sizeof err);
    int rc = pr && ocean_prepared_easable(pr) ? ocean_commit_eased(o, pr, t0, len) : -1;
    ocean_prepared_free(pr);
    struct ocean_surface *sf = rc == 0 ? ocean_surface_new(o, err, sizeof err) : NULL;
    enum { COUNT = 8 };
    double xz[COUNT][2];
    random_points(xz, COUNT, L);
    double ev = 0, ea = 0, vmax = 0, amax = 0;
    int used = 0;
    const double ts[] = {t0 + 0.3 * len, t0 + 0.7 * len};
    for (int k = 0; sf && k < 2; k++) {
        struct ocean_point pm[COUNT], p0[COUNT], pp[COUNT];
        if (ocean_surface_query(sf, ts[k] - dt, (const double(*)[2])xz, COUNT, pm) ||
            ocean_surface_query(sf, ts[k], (const double(*)[2])xz, COUNT, p0) ||
            ocean_surface_query(sf, ts[k] + dt, (const double(*)[2])xz, COUNT, pp)) {
            rc = -1;
            break;
        }
        for (int i = 0; i < COUNT; i++) {
            if (p0[i].jacobian < 0.2 || !p0[i].converged)
                continue; /* near a fold the source jumps: no smooth height(t) */
            double fv = (pp[i].height - pm[i].height) / (2 * dt);
            double fa = (pp[i].height - 2 * p0[i].height + pm[i].height) / (dt * dt);
            ev = fmax(ev, fabs(p0[i].vertical_velocity - fv));
            ea = fmax(ea, fabs(p0[i].vertical_acceleration - fa));
            vmax = fmax(vmax, fabs(fv));
            amax = fmax(amax, fabs(fa));
            used++;
        }
    }
    /* dt = 4 ms: the heights come from float amplitudes (the step's mix), whose
     * rounding a 1 ms second difference would amplify to 0.06 m/s^2; the
     * truncation at 4 ms is ~5e-4 m/s and ~5e-3 m/s^2. Without the ramp's rate
     * the errors are 1.5 m/s and 3.7 m/s^2. */
    CHECK(rc == 0 && sf && used >= COUNT && ev <= 1e-3 + 1e-3 * vmax && ea <= 1e-2 + 2e-3 * amax,
          "query.time_derivatives.easing: %d points inside the ramp: d(height)/dt err %.1e m/s (max %.2f), d2/dt2 "
          "err %.1e m/s^2 (max %.2f)", used, ev,
          vmax, ea, amax);
    ocean_surface_free(sf);
    ocean_free(o);
}

/* ---- properties ---------------------------------------------------------- */

/* One cascade: periodic in L, and the FFT grid at its samples. */
static void test_periodic_and_grid(void)
{
    struct ocean *o = make_sea(64, 1.0, SPECTRUM_JONSWAP, 1, 0);
    if (!o)
        return;
    const double L = ocean_get_params(o)->patch_size, t = 5.0;
    double xz[4][2] = {{3.3, -7.1}, {3.3 + 1000 * L, -7.1 - 7 * L}, {-3.3, 7.1}, {-3.3 - 250 * L, 7.1 + 99 * L}};
    struct ocean_point out[4];
    int rc = ocean_query(o, t, (const double(*)[2])xz, 4, out);
    double d = 0;
    for (int k = 0; k < 2; k++) {
        const struct ocean_point *a = &out[2 * k], *b = &out[2 * k + 1];
        d = fmax(d, fabs(a->height - b->height));
        d = fmax(d, fabs(a->normal[0] - b->normal[0]) + fabs(a->vertical_velocity - b->vertical_velocity));
        d = fmax(d, fabs((b->source[0] - xz[2 * k + 1][0]) - (a->source[0] - xz[2 * k][0])));
    }
    CHECK(rc == 0 && d < 1e-8, "query.periodic: (x, z) vs (x + 1000 L, z - 7 L) and (x - 250 L, z + 99 L): max "
          "diff %.1e",
          d);

    /* Choppiness 0: the height at a grid sample is the FFT's sample there. */
    struct ocean_params p = *ocean_get_params(o);
    p.choppiness = 0;
    char err[128];
    int re = ocean_reconfigure(o, &p, err, sizeof err);
    ocean_step(o, t, OCEAN_ALL_FIELDS);
    const float *h = ocean_field(o, OCEAN_HEIGHT), *sx = ocean_field(o, OCEAN_SLOPE_X);
    int n = ocean_resolution(o);
    double gxz[3][2] = {{0, 0}, {5 * L / n, 17 * L / n}, {(n - 1) * L / n, 9 * L / n}};
    int gi[3] = {0, 17 * n + 5, 9 * n + n - 1};
    struct ocean_point g[3];
    rc = ocean_query(o, t, (const double(*)[2])gxz, 3, g);
    double e = 0, es = 0;
    for (int k = 0; k < 3; k++) {
        e = fmax(e, fabs(g[k].height - h[gi[k]]));
        /* slope from the normal: n = (-sx, 1, -sz) / |.| when nothing folds */
        es = fmax(es, fabs(-g[k].normal[0] / g[k].normal[1] - sx[gi[k]]));
    }
    CHECK(re == 0 && rc == 0 && e < 1e-5 && es < 1e-4, "query.grid: chop 0, 3 grid samples vs the FFT step: "
          "height %.1e m, slope_x %.1e", e, es);
    ocean_free(o);
}

/* Three cascades, choppiness 0: the origin is a sample of every cascade's
 * grid, and the query there is the sum of the cascades' FFT samples, as a
 * client sums the streamed fields; cascade 0's sample alone is not. */
static void test_cascade_grid(void)
{
    struct ocean *o = make_sea(64, 0.0, SPECTRUM_JONSWAP, 3, 0);
    if (!o)
        return;
    const double t = 7.0;
    ocean_step(o, t, OCEAN_ALL_FIELDS);
    const double xz[1][2] = {{0, 0}};
    struct ocean_point q;
    int rc = ocean_query(o, t, xz, 1, &q);
    double h = 0, sx = 0, sz = 0;
    for (int c = 0; c < ocean_cascades(o); c++) {
        h += ocean_cascade_field(o, c, OCEAN_HEIGHT)[0];
        sx += ocean_cascade_field(o, c, OCEAN_SLOPE_X)[0];
        sz += ocean_cascade_field(o, c, OCEAN_SLOPE_Z)[0];
    }
    double h0 = ocean_field(o, OCEAN_HEIGHT)[0];
    double e = fabs(q.height - h);
    double es = fmax(fabs(-q.normal[0] / q.normal[1] - sx), fabs(-q.normal[2] / q.normal[1] - sz));
    CHECK(rc == 0 && ocean_cascades(o) == 3 && e < 1e-5 && es < 1e-4 && fabs(q.height - h0) > 1e-4,
          "query.cascade_grid: chop 0, 3 cascades, origin: height %.1e m and slopes %.1e off the sum of the "
          "cascades' FFT samples (cascade 0 alone: %.1e m off)", e, es, fabs(q.height - h0));
    ocean_free(o);
}

static void test_bad_input(void)
{
    struct ocean *o = make(32, 1.0, SPECTRUM_JONSWAP);
    if (!o)
        return;
    char err[128];
    struct ocean_surface *s = ocean_surface_new(o, err, sizeof err);
    struct ocean_point out[2], sentinel;
    memset(&sentinel, 0x5a, sizeof sentinel);
    double good[2][2] = {{1, 2}, {3, 4}};
    double nan_x[2][2] = {{1, 2}, {NAN, 4}}, inf_z[2][2] = {{1, INFINITY}, {3, 4}};
    int fails = 0, untouched = 1;
    struct {
        const char *what;
        int rc;
    } cases[] = {
        {"NaN x", 0}, {"inf z", 0}, {"t NaN", 0}, {"t inf", 0}, {"npoints < 0", 0}, {"NULL points", 0}, {"NULL snapshot", 0},
    };
    out[0] = out[1] = sentinel;
    cases[0].rc = ocean_surface_query(s, 1.0, (const double(*)[2])nan_x, 2, out);
    cases[1].rc = ocean_surface_query(s, 1.0, (const double(*)[2])inf_z, 2, out);
    cases[2].rc = ocean_surface_query(s, NAN, (const double(*)[2])good, 2, out);
    cases[3].rc = ocean_surface_query(s, INFINITY, (const double(*)[2])good, 2, out);
    cases[4].rc = ocean_surface_query(s, 1.0, (const double(*)[2])good, -1, out);
    cases[5].rc = ocean_surface_query(s, 1.0, NULL, 2, out);
    cases[6].rc = ocean_surface_query(NULL, 1.0, (const double(*)[2])good, 2, out);
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        fails += cases[i].rc == -1;
    untouched = !memcmp(&out[0], &sentinel, sizeof sentinel) && !memcmp(&out[1], &sentinel, sizeof sentinel);
    int zero = ocean_surface_query(s, 1.0, NULL, 0, NULL);
    int okq = ocean_surface_query(s, 1.0, (const double(*)[2])good, 2, out);
    CHECK(s && fails == (int)(sizeof cases / sizeof cases[0]) && untouched && zero == 0 && okq == 0,
          "query.bad_input: %d/%zu bad calls return -1 and write nothing; 0 points ok; a good call after them works",
          fails,
          sizeof cases / sizeof cases[0]);
    ocean_surface_free(s);

    /* A calm sea (no wind): every amplitude is zero; flat water, normal up. */
    struct ocean_params p = *ocean_get_params(o);
    p.wind_speed = 0;
    ocean_reconfigure(o, &p, err, sizeof err);
    struct ocean_point calm[2];
    int rc = ocean_query(o, 4.0, (const double(*)[2])good, 2, calm);
    CHECK(rc == 0 && calm[1].height == 0 && calm[1].normal[1] == 1 && calm[1].vertical_velocity == 0 &&
              calm[1].converged && calm[1].source[0] == 3 && calm[1].jacobian == 1,
          "query.calm: wind 0: height %g, normal y %g, source (%g, %g)", calm[1].height, calm[1].normal[1],
          calm[1].source[0], calm[1].source[1]);
    ocean_free(o);
}

/* The snapshot is read-only: queries from several threads at once give
 * exactly the single-threaded answers, and the owner may step meanwhile. */
struct thread_job {
    const struct ocean_surface *s;
    double (*xz)[2];
    int count, rc;
    struct ocean_point *out;
};

static void *query_thread(void *arg)
{
    struct thread_job *j = arg;
    for (int rep = 0; rep < 3; rep++)
        j->rc |= ocean_surface_query(j->s, 9.0, (const double(*)[2])j->xz, j->count, j->out);
    return NULL;
}

static void test_threads_and_snapshot(void)
{
    struct ocean *o = make(64, 1.5, SPECTRUM_JONSWAP);
    if (!o)
        return;
    char err[128];
    struct ocean_surface *s = ocean_surface_new(o, err, sizeof err);
    enum { COUNT = 16, THREADS = 3 };
    double xz[COUNT][2];
    random_points(xz, COUNT, 64);
    struct ocean_point ref[COUNT], got[THREADS][COUNT];
    int rc = ocean_surface_query(s, 9.0, (const double(*)[2])xz, COUNT, ref);
    pthread_t tid[THREADS];
    struct thread_job jobs[THREADS];
    for (int i = 0; i < THREADS; i++) {
        jobs[i] = (struct thread_job){s, xz, COUNT, 0, got[i]};
        pthread_create(&tid[i], NULL, query_thread, &jobs[i]);
    }
    for (int k = 0; k < 5; k++) /* the owner keeps stepping meanwhile */
        ocean_step(o, 9.0 + k, OCEAN_ALL_FIELDS);
    int same = 1;
    for (int i = 0; i < THREADS; i++) {
        pthread_join(tid[i], NULL);
        same &= jobs[i].rc == 0 && !memcmp(got[i], ref, sizeof ref);
    }
    CHECK(s && rc == 0 && same, "query.threads: %d threads x 3 queries on one snapshot while stepping: bit-identical",
          THREADS);

    /* A snapshot keeps the sea it was made from: reconfiguring the ocean
     * afterwards changes new snapshots, not this one. */
    struct ocean_params p = *ocean_get_params(o);
    p.wind_speed = 20;
    ocean_reconfigure(o, &p, err, sizeof err);
    struct ocean_surface *s2 = ocean_surface_new(o, err, sizeof err);
    struct ocean_point after[COUNT], other[COUNT];
    ocean_surface_query(s, 9.0, (const double(*)[2])xz, COUNT, after);
    ocean_surface_query(s2, 9.0, (const double(*)[2])xz, COUNT, other);
    CHECK(!memcmp(after, ref, sizeof ref) && memcmp(other, ref, sizeof ref) != 0 &&
              ocean_surface_params(s)->wind_speed == 12 && ocean_surface_params(s2)->wind_speed == 20,
          "query.snapshot: old snapshot unchanged by reconfigure; new one sees wind 20 m/s");
    /* Every mode off the Nyquist row and column (and k = 0) is non-zero in
     * cascade 0; a finer cascade has its band's modes (ocean.h) of the half
     * spectrum kx >= 0: so many modes per point. */
    int expect = 63 * 32 - 1;
    for (int c = 1; c < ocean_cascades(o); c++)
        for (int mz = -31; mz <= 31; mz++)
            for (int mx = 0; mx <= 31; mx++) {
                int a = abs(mz) > mx ? abs(mz) : mx;
                expect += a >= ocean_cascade_band(64, c) && a <= ocean_cascade_band_top(64, c);
            }
    CHECK(ocean_surface_modes(s) == expect && ocean_cascades(o) == 3, "query.modes: N=64, %d cascades: %d "
          "non-zero modes in the snapshot (expected %d)", ocean_cascades(o),
          ocean_surface_modes(s), expect);
    /* Warm start, as a probe does: sources of the previous tick as guesses.
     * Same answers, fewer Newton steps. */
    struct ocean_point prev[COUNT], cold[COUNT], warm[COUNT];
    double guess[COUNT][2];
    ocean_surface_query(s2, 9.0, (const double(*)[2])xz, COUNT, prev);
    for (int i = 0; i < COUNT; i++) {
        guess[i][0] = prev[i].source[0];
        guess[i][1] = prev[i].source[1];
    }
    int rc1 = ocean_surface_query(s2, 9.0 + 1.0 / 30, (const double(*)[2])xz, COUNT, cold);
    int rc2 = ocean_surface_query_from(s2, 9.0 + 1.0 / 30, (const double(*)[2])xz, (const double(*)[2])guess, COUNT, warm);
    int steps_cold = 0, steps_warm = 0, all = 1;
    double dh = 0;
    for (int i = 0; i < COUNT; i++) {
        steps_cold += cold[i].iterations;
        steps_warm += warm[i].iterations;
        all &= cold[i].converged && warm[i].converged;
        dh = fmax(dh, fabs(cold[i].height - warm[i].height) + fabs(cold[i].vertical_velocity - warm[i].vertical_velocity));
    }
    CHECK(rc1 == 0 && rc2 == 0 && all && dh < 1e-7 && steps_warm < steps_cold, "query.warm_start: %d points one "
          "tick later: %d Newton steps from the previous sources vs %d from the points, same values (%.1e)",
          COUNT, steps_warm, steps_cold, dh);
    ocean_surface_free(s);
    ocean_surface_free(s2);
    ocean_free(o);
}

int main(void)
{
    check_verbose = 1; /* the passing lines carry the measured values */
    quick = check_quick();
    test_bad_input();
    test_periodic_and_grid();
    test_cascade_grid();
    test_threads_and_snapshot();
    test_folds();
    const double chops[] = {0, 1, 2};
    for (int c = 0; c < 3; c++) { /* one cascade and the default three */
        test_accuracy_sea(32, chops[c], SPECTRUM_JONSWAP, 16, 1, 0);
        test_accuracy_sea(64, chops[c], SPECTRUM_JONSWAP, 16, 3, 0);
    }
    /* Shallow water: the horizontal displacement is coth(k d)/k, not 1/k. */
    test_accuracy_sea(64, 1.0, SPECTRUM_TMA, 16, 3, 4.0);
    test_accuracy_sea(32, 1.0, SPECTRUM_JONSWAP, 16, 4, 0);
    for (int c = 0; c < 3; c++) {
        test_accuracy(32, chops[c], SPECTRUM_PHILLIPS, 24);
        test_accuracy(64, chops[c], SPECTRUM_JONSWAP, 24);
        if (!quick) {
            test_accuracy(128, chops[c], SPECTRUM_PIERSON_MOSKOWITZ, 16);
            test_accuracy(256, chops[c], SPECTRUM_JONSWAP, 8);
        }
        test_derivatives(32, chops[c]);
        if (!quick)
            test_derivatives(64, chops[c]);
    }
    test_derivatives_easing();
    if (!quick)
        test_accuracy(512, 1.0, SPECTRUM_JONSWAP, 4);
    return check_done();
}

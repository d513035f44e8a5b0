/* test_ocean.c — the simulation library against physics and a reference DFT.
 *
 * One line per check ("ok" / "FAIL"), then "N passed, M failed"; exit 1 on
 * any failure. OCEAN_TEST_QUICK=1 runs a reduced set (smaller N, fewer
 * seeds) for valgrind. Plans use FFTW_ESTIMATE and no wisdom: deterministic.
 * Build and run: make test-sim (see mk/sim.mk). */
#include <complex.h>
#include <malloc.h>
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "ocean_internal.h"

#include "common/check.h"

static int quick;

static struct ocean *make(const struct ocean_params *p, int threads)
{
    char err[256] = "";
    struct ocean_options opt = {threads, NULL, 0};
    struct ocean *o = ocean_create(p, &opt, err, sizeof err);
    if (!o)
        CHECK(0, "create: ocean_create failed: %s", err);
    return o;
}

/* The default sea at resolution n, one cascade, on two threads. */
static struct ocean *make_default(int n)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = n;
    p.cascades = 1;
    return make(&p, 2);
}

static float *copy_field(const struct ocean *o, enum ocean_field f)
{
    size_t nn = (size_t)ocean_resolution(o) * ocean_resolution(o);
    float *c = malloc(nn * sizeof *c);
    memcpy(c, ocean_field(o, f), nn * sizeof *c);
    return c;
}

static double max_abs(const float *a, size_t n)
{
    double m = 0;
    for (size_t i = 0; i < n; i++)
        m = fmax(m, fabs(a[i]));
    return m;
}

/* max |a - b| / max |b| */
static double rel_err(const float *a, const float *b, size_t n)
{
    double d = 0;
    for (size_t i = 0; i < n; i++)
        d = fmax(d, fabs((double)a[i] - b[i]));
    double m = max_abs(b, n);
    return m > 0 ? d / m : d;
}

static double variance(const float *a, size_t n)
{
    double s = 0, s2 = 0;
    for (size_t i = 0; i < n; i++) {
        s += a[i];
        s2 += (double)a[i] * a[i];
    }
    return s2 / n - (s / n) * (s / n);
}

static const char *spec_name(int s)
{
    return param_enum_name(param_find("spectrum"), s);
}

/* ---- parameters --------------------------------------------------------- */

static void test_params(void)
{
    struct ocean_params p, q;
    char err[256];
    params_defaults(&p);
    CHECK(params_validate(&p, err, sizeof err) == 0, "params.defaults_valid: %s",
          params_validate(&p, err, sizeof err) == 0 ? "defaults pass validation" : err);
    static const char *const names[] = {"resolution", "patch_size", "cascades", "wind_speed", "wind_direction",
        "amplitude", "spectrum", "fetch", "depth", "gamma", "directional_spread", "swell",
        "choppiness", "small_wave_cutoff", "loop_period", "seed", "transform", "time_scale", "paused"};
    int found = 0, sane = 1;
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        const struct param_def *d = param_find(names[i]);
        if (!d)
            continue;
        found++;
        if (!(d->min <= d->def && d->def <= d->max) || !d->description || !d->unit)
            sane = 0;
    }
    CHECK(found == (int)(sizeof names / sizeof names[0]) && param_count == sizeof names / sizeof names[0] && sane,
          "params.table: %d of %zu fields in the table (param_count %zu), defaults in range: %s", found,
          sizeof names / sizeof names[0], param_count, sane ? "yes" : "no");
    const struct param_def *res = param_find("resolution");
    CHECK((res->flags & PARAM_POW2) && (res->flags & PARAM_REPLAN) && res->min == 16 && res->max == 2048 &&
          (param_find("time_scale")->flags & PARAM_PLAYBACK) && (param_find("paused")->flags & PARAM_PLAYBACK),
          "params.flags: resolution POW2|REPLAN 16..2048, time_scale and paused PLAYBACK");

    q = p;
    int bad = 0;
    err[0] = 0;
    bad += param_set(&q, res, 100, err, sizeof err) == -1 && strstr(err, "power of two");
    bad += param_set(&q, res, 4096, err, sizeof err) == -1 && strstr(err, "range");
    bad += param_set(&q, param_find("wind_speed"), -1, err, sizeof err) == -1;
    bad += param_set(&q, param_find("wind_speed"), NAN, err, sizeof err) == -1;
    bad += param_set(&q, param_find("seed"), 1.5, err, sizeof err) == -1;
    bad += param_set_text(&q, param_find("spectrum"), "bretschneider", err, sizeof err) == -1 &&
           strstr(err, "jonswap");
    bad += param_set_text(&q, param_find("wind_speed"), "12x", err, sizeof err) == -1;
    CHECK(bad == 7 && memcmp(&q, &p, sizeof p) == 0, "params.set_rejects: %d/7 invalid values rejected, "
          "params unchanged: %s; last message: \"%s\"", bad, memcmp(&q, &p, sizeof p) == 0 ? "yes" : "no", err);

    int good = 0;
    good += param_set_text(&q, param_find("spectrum"), "tma", err, sizeof err) == 0 && q.spectrum == SPECTRUM_TMA;
    good += param_set_text(&q, param_find("paused"), "true", err, sizeof err) == 0 && q.paused;
    good += param_set_text(&q, res, "512", err, sizeof err) == 0 && q.resolution == 512;
    good += param_set(&q, param_find("wind_speed"), 17.5, err, sizeof err) == 0 && q.wind_speed == 17.5;
    good += param_get(&q, param_find("wind_speed")) == 17.5 && param_get(&q, param_find("paused")) == 1;
    good += param_enum_index(param_find("transform"), "dft") == TRANSFORM_DFT &&
            strcmp(param_enum_name(param_find("spectrum"), 1), "pierson_moskowitz") == 0;
    CHECK(good == 6, "params.set_accepts: %d/6 valid settings applied", good);

    q = p;
    q.transform = TRANSFORM_DFT;
    q.resolution = 128;
    int r1 = params_validate(&q, err, sizeof err);
    CHECK(r1 == -1 && strstr(err, "dft"), "params.validate_dft_bound: dft at N=128: %s", err);
    q.resolution = 64;
    CHECK(params_validate(&q, err, sizeof err) == 0, "params.validate_dft_small: dft at N=64 accepted");
    q = p;
    q.resolution = 48;
    CHECK(params_validate(&q, err, sizeof err) == -1, "params.validate_range: N=48: %s", err);
}

/* ---- physics helpers ----------------------------------------------------- */

static void test_spreading_and_dispersion(void)
{
    struct ocean_params p;
    params_defaults(&p);
    double worst = 0;
    for (int b = 0; b <= 2; b++)
        for (int sw = 0; sw <= 1; sw++)
            for (int wi = 0; wi < 5; wi++) {
                p.directional_spread = b * 0.5;
                p.swell = sw;
                struct spectrum_model m;
                spectrum_model_init(&m, &p);
                double w = m.omega_p * (0.25 * (1 << wi)), sum = 0;
                int n = quick ? 4000 : 20000; /* the midpoint rule meets a cusp at theta = pi when s < 1 */
                for (int i = 0; i < n; i++) {
                    double th = -M_PI + (i + 0.5) * 2 * M_PI / n;
                    sum += spectrum_spreading(&m, w, th) * 2 * M_PI / n;
                }
                worst = fmax(worst, fabs(sum - 1));
            }
    double tol = quick ? 1e-4 : 1e-5;
    CHECK(worst < tol, "physics.spreading_unit_integral: max |int D dtheta - 1| = %.2e over spread, swell, w "
          "(limit %.0e)", worst, tol);

    double dworst = 0;
    double depths[] = {0.5, 5, 50, 5000};
    for (int di = 0; di < 4; di++)
        for (double k = 0.001; k < 100; k *= 3.7) {
            double h = k * 1e-5;
            double num = (dispersion_omega(k + h, depths[di]) - dispersion_omega(k - h, depths[di])) / (2 * h);
            dworst = fmax(dworst, fabs(num / dispersion_domega_dk(k, depths[di]) - 1));
        }
    double deep = dispersion_omega(1.0, 1e4), shallow = dispersion_omega(0.001, 1.0);
    CHECK(dworst < 1e-6 && fabs(deep - sqrt(9.81)) < 1e-9 && fabs(shallow / 0.001 - sqrt(9.81)) < 1e-3,
          "physics.dispersion: dw/dk vs finite difference %.1e; deep w(1)=%.6f, shallow c=%.4f", dworst, deep,
          shallow / 0.001);
}

/* ---- FFT against the brute-force DFT -------------------------------------- */

static void test_fft_vs_dft(void)
{
    int sizes[] = {16, 32, 64};
    int nsizes = quick ? 1 : 3;
    for (int si = 0; si < nsizes; si++)
        for (int s = 0; s < 4; s++) {
            int n = sizes[si];
            if (n == 64 && s != SPECTRUM_JONSWAP)
                continue; /* N=64 costs 0.3 s per spectrum: one is enough */
            struct ocean_params p;
            params_defaults(&p);
            p.resolution = n;
            p.spectrum = s;
            p.patch_size = 4.0 * n; /* 4 m spacing keeps many waves in band */
            p.depth = s == SPECTRUM_TMA ? 15 : 1000;
            p.choppiness = 1.3;
            struct ocean *o = make(&p, 1);
            if (!o)
                continue;
            size_t nn = (size_t)n * n;
            double t = 37.25;
            ocean_step_fft(o, t, OCEAN_ALL_FIELDS);
            float *fft[OCEAN_FIELD_COUNT];
            for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
                fft[f] = copy_field(o, f);
            ocean_step_dft(o, t, OCEAN_ALL_FIELDS);
            double worst = 0;
            int worst_f = 0;
            for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
                double e = rel_err(fft[f], ocean_field(o, f), nn);
                if (e > worst) {
                    worst = e;
                    worst_f = f;
                }
                free(fft[f]);
            }
            double hmax = max_abs(ocean_field(o, OCEAN_HEIGHT), nn);
            char name[64];
            snprintf(name, sizeof name, "fft_eq_dft.N%d.%s", n, spec_name(s));
            CHECK(worst <= 1e-5 && hmax > 0, "%s: all 6 fields, worst rel err %.2e (%s), max|h| %.3f m", name, worst,
                  ocean_field_name(worst_f), hmax);
            ocean_free(o);
        }

    /* The public switch: transform=dft through ocean_step. */
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 16;
    struct ocean *o = make(&p, 1);
    if (!o)
        return;
    ocean_step(o, 5.0, OCEAN_ALL_FIELDS);
    float *h = copy_field(o, OCEAN_HEIGHT);
    p.transform = TRANSFORM_DFT;
    char err[256];
    int r = ocean_reconfigure(o, &p, err, sizeof err);
    ocean_step(o, 5.0, OCEAN_ALL_FIELDS);
    double e = rel_err(h, ocean_field(o, OCEAN_HEIGHT), 256);
    CHECK(r == 0 && e <= 1e-5, "fft_eq_dft.switch: ocean_step with transform=dft vs fft: rel err %.2e", e);
    free(h);
    ocean_free(o);
}

/* ---- wavenumber layout and symmetry --------------------------------------- */

static void test_layout(void)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 32;
    p.patch_size = 100;
    struct ocean *o = make(&p, 1);
    if (!o)
        return;
    int n = 32, bad = 0;
    for (int i = 0; i < n; i++) {
        double want = 2 * M_PI * (i - n * (i > n / 2)) / p.patch_size;
        if (fabs(ocean_wavenumber(i, n, p.patch_size) - want) > 1e-12 || fabs(o->g->kz[i] - want) > 1e-5 ||
            (i <= n / 2 && fabs(o->g->kx[i] - want) > 1e-5))
            bad++;
    }
    CHECK(bad == 0, "layout.k_table: kx[i] = 2pi(i - N[i > N/2])/L for all i: %d mismatches", bad);

    /* End to end: the FFT output's mode at index (ix, iz) must be the
     * reference amplitude of e^{i(kx x + kz z)} with k from that formula. */
    ocean_step_fft(o, 3.0, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
    const float *h = ocean_field(o, OCEAN_HEIGHT);
    double complex *ref = malloc((size_t)n * n * sizeof *ref);
    ocean_reference_spectrum(o, 3.0, TR_H, ref);
    double refmax = 0;
    for (int i = 0; i < n * n; i++)
        refmax = fmax(refmax, cabs(ref[i]));
    int idx[][2] = {{1, 0}, {0, 1}, {3, 5}, {31, 2}, {5, 29}, {17, 13}, {15, 17}};
    double worst = 0;
    for (size_t q = 0; q < sizeof idx / sizeof idx[0]; q++) {
        int ix = idx[q][0], iz = idx[q][1];
        double kx = 2 * M_PI * (ix - n * (ix > n / 2)) / p.patch_size;
        double kz = 2 * M_PI * (iz - n * (iz > n / 2)) / p.patch_size;
        double complex sum = 0;
        for (int z = 0; z < n; z++)
            for (int x = 0; x < n; x++)
                sum += h[z * n + x] * cexp(-I * (kx * x + kz * z) * p.patch_size / n);
        sum /= (double)n * n;
        worst = fmax(worst, cabs(sum - ref[iz * n + ix]) / refmax);
    }
    CHECK(worst < 1e-5 && refmax > 0, "layout.modes: forward DFT of h at 7 indices vs reference h~(k): rel err %.2e",
          worst);

    /* Hermitian symmetry of every transform's spectrum, and real output. */
    double herm = 0;
    for (int tr = 0; tr < TR_COUNT; tr++) {
        ocean_reference_spectrum(o, 3.0, tr, ref);
        double m = 0;
        for (int i = 0; i < n * n; i++)
            m = fmax(m, cabs(ref[i]));
        for (int iz = 0; iz < n; iz++)
            for (int ix = 0; ix < n; ix++) {
                int jx = (n - ix) % n, jz = (n - iz) % n;
                herm = fmax(herm, cabs(ref[iz * n + ix] - conj(ref[jz * n + jx])) / m);
            }
    }
    ocean_reference_spectrum(o, 3.0, TR_H, ref);
    double im = 0, re = 0;
    for (int z = 0; z < n; z += 7)
        for (int x = 0; x < n; x += 5) {
            double complex s = 0;
            for (int kz = 0; kz < n; kz++)
                for (int kx = 0; kx < n; kx++)
                    s += ref[kz * n + kx] * cexp(2 * M_PI * I * (double)(kx * x + kz * z) / n);
            im = fmax(im, fabs(cimag(s)));
            re = fmax(re, fabs(creal(s)));
        }
    CHECK(herm < 1e-12 && im < 1e-9 * re, "layout.hermitian_real: max |F(-k) - conj F(k)| / max|F| = %.1e over 8 "
          "spectra; complex sum: max|Im| %.1e vs max|Re| %.3f", herm,
          im, re);
    free(ref);
    ocean_free(o);
}

/* ---- derivatives and displacement ------------------------------------------ */

static void test_slopes(void)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 64;
    p.patch_size = 64;
    p.small_wave_cutoff = 12; /* resolve what we differentiate */
    struct ocean *o = make(&p, 1);
    if (!o)
        return;
    int n = 64;
    double dx = p.patch_size / n;
    ocean_step(o, 11.0, OCEAN_ALL_FIELDS);
    const float *h = ocean_field(o, OCEAN_HEIGHT);
    const float *sx = ocean_field(o, OCEAN_SLOPE_X), *sz = ocean_field(o, OCEAN_SLOPE_Z);
    double ex = 0, ez = 0, nx = 0, nz = 0;
#define H(x, z) h[(((z) + n) % n) * n + (((x) + n) % n)]
    for (int z = 0; z < n; z++)
        for (int x = 0; x < n; x++) {
            /* fourth-order central differences, periodic */
            double fx = (-H(x + 2, z) + 8 * H(x + 1, z) - 8 * H(x - 1, z) + H(x - 2, z)) / (12 * dx);
            double fz = (-H(x, z + 2) + 8 * H(x, z + 1) - 8 * H(x, z - 1) + H(x, z - 2)) / (12 * dx);
            ex += pow(sx[z * n + x] - fx, 2);
            ez += pow(sz[z * n + x] - fz, 2);
            nx += pow(fx, 2);
            nz += pow(fz, 2);
        }
#undef H
    double rx = sqrt(ex / nx), rz = sqrt(ez / nz);
    CHECK(rx < 0.02 && rz < 0.02 && nx > 0, "slopes.finite_differences: rms(slope - FD)/rms(FD): x %.4f, z %.4f "
          "(limit 0.02)", rx, rz);

    /* Jacobian from the displacement by finite differences too. */
    const float *dX = ocean_field(o, OCEAN_DX), *dZ = ocean_field(o, OCEAN_DZ), *J = ocean_field(o, OCEAN_JACOBIAN);
    double ej = 0, nj = 0;
#define F(a, x, z) a[(((z) + n) % n) * n + (((x) + n) % n)]
#define D1X(a, x, z) ((-F(a, x + 2, z) + 8 * F(a, x + 1, z) - 8 * F(a, x - 1, z) + F(a, x - 2, z)) / (12 * dx))
#define D1Z(a, x, z) ((-F(a, x, z + 2) + 8 * F(a, x, z + 1) - 8 * F(a, x, z - 1) + F(a, x, z - 2)) / (12 * dx))
    for (int z = 0; z < n; z++)
        for (int x = 0; x < n; x++) {
            double j = (1 + D1X(dX, x, z)) * (1 + D1Z(dZ, x, z)) - D1Z(dX, x, z) * D1X(dZ, x, z);
            ej += pow(J[z * n + x] - j, 2);
            nj += pow(j - 1, 2);
        }
#undef F
#undef D1X
#undef D1Z
    double rj = sqrt(ej / nj);
    CHECK(rj < 0.02 && nj > 0, "jacobian.finite_differences: rms(J - J_FD)/rms(J_FD - 1) = %.4f (limit 0.02)", rj);

    /* lambda > 0 sharpens crests: the surface is compressed (J < 1) where h is high. */
    size_t nn = (size_t)n * n;
    double cov = 0;
    for (size_t i = 0; i < nn; i++)
        cov += h[i] * (J[i] - 1.0);
    CHECK(cov < 0, "jacobian.crests_compressed: cov(h, J - 1) = %.3g (negative: crests sharpen)", cov / nn);

    p.choppiness = 0;
    char err[256];
    ocean_reconfigure(o, &p, err, sizeof err);
    ocean_step(o, 11.0, OCEAN_ALL_FIELDS);
    double mdx = max_abs(ocean_field(o, OCEAN_DX), nn), mdz = max_abs(ocean_field(o, OCEAN_DZ), nn);
    double mj = 0;
    for (size_t i = 0; i < nn; i++)
        mj = fmax(mj, fabs(ocean_field(o, OCEAN_JACOBIAN)[i] - 1.0));
    double dx_before = max_abs(dX, nn); /* dX aliases the output: now lambda = 0 */
    (void)dx_before;
    CHECK(mdx == 0 && mdz == 0 && mj == 0 && max_abs(ocean_field(o, OCEAN_HEIGHT), nn) > 0,
          "displacement.lambda_zero: lambda=0: max|Dx| %g, max|Dz| %g, max|J-1| %g", mdx, mdz, mj);
    ocean_free(o);
}

/* ---- periodicity in space and time ---------------------------------------- */

static void test_periodic(void)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 32;
    p.patch_size = 64;
    struct ocean *o = make(&p, 1);
    if (!o)
        return;
    int n = 32;
    size_t nn = (size_t)n * n;
    /* The continuous sum at x = L equals x = 0 (the k are multiples of 2pi/L). */
    double complex *ref = malloc(nn * sizeof *ref);
    ocean_reference_spectrum(o, 2.0, TR_H, ref);
    double worst = 0, scale = 0;
    for (int z = 0; z < n; z += 3) {
        double complex s0 = 0, sL = 0;
        for (int kz = 0; kz < n; kz++)
            for (int kx = 0; kx < n; kx++) {
                double kxv = ocean_wavenumber(kx, n, p.patch_size), kzv = ocean_wavenumber(kz, n, p.patch_size);
                double zz = z * p.patch_size / n;
                s0 += ref[kz * n + kx] * cexp(I * (kzv * zz));
                sL += ref[kz * n + kx] * cexp(I * (kxv * p.patch_size + kzv * (zz + p.patch_size)));
            }
        worst = fmax(worst, cabs(sL - s0));
        scale = fmax(scale, cabs(s0));
    }
    free(ref);
    /* Seam: the jump across the tile edge is like any neighbour difference. */
    ocean_step(o, 2.0, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
    const float *h = ocean_field(o, OCEAN_HEIGHT);
    double seam = 0, inner = 0;
    for (int z = 0; z < n; z++) {
        seam += pow(h[z * n] - h[z * n + n - 1], 2) + pow(h[z] - h[(n - 1) * n + z], 2);
        for (int x = 1; x < n; x++)
            inner += pow(h[z * n + x] - h[z * n + x - 1], 2) + pow(h[x * n + z] - h[(x - 1) * n + z], 2);
    }
    double ratio = sqrt(seam / (2.0 * n)) / sqrt(inner / (2.0 * n * (n - 1)));
    CHECK(worst < 1e-9 * scale && ratio < 1.6, "periodic.tiling: |h(L,z+L) - h(0,z)| = %.1e m; seam jump rms / "
          "neighbour rms = %.2f", worst, ratio);

    p.loop_period = 20;
    char err[256];
    ocean_reconfigure(o, &p, err, sizeof err);
    double e = 0, e_half = 1e9;
    float *a[OCEAN_FIELD_COUNT];
    ocean_step(o, 7.3, OCEAN_ALL_FIELDS);
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        a[f] = copy_field(o, f);
    ocean_step(o, 7.3 + 20 * 1000, OCEAN_ALL_FIELDS); /* a thousand periods later */
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        e = fmax(e, rel_err(ocean_field(o, f), a[f], nn));
    /* The FFT path wraps t into [0, T); the reference does not: they agree
     * only if every w is a multiple of 2 pi / T. */
    ocean_step_dft(o, 7.3 + 20 * 1000, OCEAN_ALL_FIELDS);
    double e_ref = 0;
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        e_ref = fmax(e_ref, rel_err(a[f], ocean_field(o, f), nn));
    ocean_step(o, 7.3 + 10, OCEAN_ALL_FIELDS);
    e_half = rel_err(ocean_field(o, OCEAN_HEIGHT), a[OCEAN_HEIGHT], nn);
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        free(a[f]);
    CHECK(e <= 1e-5 && e_ref <= 1e-5 && e_half > 0.1, "periodic.loop_period: T = 20 s, all fields: field(t + 1000 "
          "T) vs field(t) %.1e, vs unwrapped reference %.1e; at t + T/2: %.2f (must differ)", e, e_ref, e_half);

    /* No loop: phases in double precision, so day-long runs stay exact: the
     * step at t = 10 days must match the double-precision reference. */
    p.loop_period = 0;
    ocean_reconfigure(o, &p, err, sizeof err);
    double tday = 864000.123;
    ocean_step_fft(o, tday, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
    float *hf = copy_field(o, OCEAN_HEIGHT);
    ocean_step_dft(o, tday, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
    double ed = rel_err(hf, ocean_field(o, OCEAN_HEIGHT), nn);
    free(hf);
    CHECK(ed <= 1e-5, "time.ten_days: t = 10 days: FFT path vs double reference rel err %.1e", ed);
    ocean_free(o);
}

/* The end of the documented time range (ocean.h, OCEAN_TIME_MAX): the FFT
 * path's phases at t = 1e9 s must match the double-precision reference as
 * well as at small t, for a sea that loops and one that does not, and for
 * a tiny patch whose short waves have the largest w t of any setting. */
static void test_time_max(void)
{
    struct {
        const char *what;
        int n;
        double patch, loop, cutoff;
    } cases[] = {{"default", 32, 256, 0, 0.5}, {"loop_20s", 32, 256, 20, 0.5}, {"patch_1m", 64, 1, 0, 0}};
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        if (quick && c == 2)
            continue; /* N = 64 DFT: slow under valgrind */
        struct ocean_params p;
        params_defaults(&p);
        p.resolution = cases[c].n;
        p.patch_size = cases[c].patch;
        p.loop_period = cases[c].loop;
        p.small_wave_cutoff = cases[c].cutoff;
        struct ocean *o = make(&p, 1);
        if (!o)
            continue;
        size_t nn = (size_t)p.resolution * p.resolution;
        double times[2] = {37.25, OCEAN_TIME_MAX}, err[2] = {0, 0};
        for (int ti = 0; ti < 2; ti++) {
            float *fft[OCEAN_FIELD_COUNT];
            ocean_step_fft(o, times[ti], OCEAN_ALL_FIELDS);
            for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
                fft[f] = copy_field(o, f);
            ocean_step_dft(o, times[ti], OCEAN_ALL_FIELDS);
            for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
                err[ti] = fmax(err[ti], rel_err(fft[f], ocean_field(o, f), nn));
                free(fft[f]);
            }
        }
        char name[64];
        snprintf(name, sizeof name, "time.max.%s", cases[c].what);
        CHECK(err[1] <= 1e-5 && err[0] <= 1e-5, "%s: N=%d L=%g m loop %g s: FFT vs double reference, all fields, "
              "at t = %.0e s %.1e, at t = %.2f s %.1e (limit 1e-5 for "
              "both)", name, p.resolution, p.patch_size, p.loop_period, times[1], err[1], times[0], err[0]);
        ocean_free(o);
    }
}

/* ---- energy ------------------------------------------------------------------ */

static void test_parseval(void)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 64;
    struct ocean *o = make(&p, 1);
    if (!o)
        return;
    int n = 64;
    size_t nn = (size_t)n * n;
    if (ocean_keep_jacobian_terms(o) != 0) /* the three Jacobian terms as whole fields */
        abort();
    ocean_step(o, 4.0, OCEAN_ALL_FIELDS);
    double complex *ref = malloc(nn * sizeof *ref);
    double worst = 0;
    for (int tr = 0; tr < TR_COUNT; tr++) {
        ocean_reference_spectrum(o, 4.0, tr, ref);
        double es = 0, ex = 0;
        for (size_t i = 0; i < nn; i++)
            es += pow(cabs(ref[i]), 2);
        const float *f = ocean_transform_dest(o->g, tr);
        for (size_t i = 0; i < nn; i++)
            ex += (double)f[i] * f[i];
        worst = fmax(worst, fabs(ex / nn / es - 1));
    }
    free(ref);
    CHECK(worst < 1e-5, "energy.parseval: mean f^2 vs sum |F(k)|^2 over 8 transforms: worst rel diff %.1e", worst);
    ocean_free(o);
}

static void test_variance_vs_n(void)
{
    struct ocean_params p;
    params_defaults(&p);
    int sizes[] = {64, 128, 256};
    double v[3];
    int count = quick ? 2 : 3;
    for (int i = 0; i < count; i++) {
        p.resolution = sizes[i];
        struct ocean *o = make(&p, 1);
        if (!o)
            return;
        ocean_step(o, 9.0, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
        v[i] = variance(ocean_field(o, OCEAN_HEIGHT), (size_t)sizes[i] * sizes[i]);
        ocean_free(o);
    }
    double lo = v[0], hi = v[0];
    for (int i = 1; i < count; i++) {
        lo = fmin(lo, v[i]);
        hi = fmax(hi, v[i]);
    }
    CHECK(hi / lo - 1 < 0.03, "energy.variance_independent_of_N: L=256 m, N=64/128%s: var(h) %.4f / %.4f%s%.4f "
          "m^2, spread %.1f%% (limit 3%%)", quick ? "" : "/256", v[0],
          v[1], quick ? "" : " / ", quick ? 0.0 : v[2], 100 * (hi / lo - 1));
}

/* m0 of the spectrum over the resolved band: S integrated over w between
 * the lowest and the Nyquist wavenumbers (Phillips: F over k). Simpson on a
 * log grid; independent of the 2-D Psi, the spreading and dw/dk. */
static double band_m0(const struct spectrum_model *m, double k_lo, double k_hi)
{
    int n = 20000;
    double a, b;
    int phillips = m->kind == SPECTRUM_PHILLIPS;
    a = log(phillips ? k_lo : dispersion_omega(k_lo, m->depth));
    b = log(phillips ? k_hi : dispersion_omega(k_hi, m->depth));
    double h = (b - a) / n, sum = 0;
    for (int i = 0; i <= n; i++) {
        double u = exp(a + i * h);
        double f = (phillips ? spectrum_omni_k(m, u) : spectrum_frequency(m, u)) * u; /* d(u) = u d(log u) */
        sum += f * (i == 0 || i == n ? 1 : (i % 2 ? 4 : 2));
    }
    return sum * h / 3;
}

static void test_significant_height(void)
{
    for (int s = 0; s < 4; s++) {
        struct ocean_params p;
        params_defaults(&p);
        p.spectrum = s;
        p.resolution = quick ? 64 : 256;
        p.patch_size = quick ? 250 : 1000; /* Nyquist k = 0.8 rad/m either way */
        p.small_wave_cutoff = 0;
        p.depth = s == SPECTRUM_TMA ? 20 : 1000;
        int seeds = quick ? 4 : 24;
        double m0 = 0;
        struct ocean *o = make(&p, 1);
        if (!o)
            return;
        for (int seed = 0; seed < seeds; seed++) {
            p.seed = 1000 + seed;
            char err[256];
            ocean_reconfigure(o, &p, err, sizeof err);
            ocean_step(o, 0.0, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
            m0 += variance(ocean_field(o, OCEAN_HEIGHT), (size_t)p.resolution * p.resolution) / seeds;
        }
        double dk = 2 * M_PI / p.patch_size;
        double ref = band_m0(&o->model, 0.5 * dk, M_PI * p.resolution / p.patch_size);
        double hs = 4 * sqrt(m0), hs_ref = 4 * sqrt(ref);
        char name[64];
        snprintf(name, sizeof name, "energy.hs.%s", spec_name(s));
        double tol = quick ? 0.10 : 0.05;
        CHECK(fabs(hs / hs_ref - 1) <= tol && hs_ref > 0.1, "%s: Hs = 4 sqrt(m0): field %.3f m (mean of %d seeds) "
              "vs spectrum %.3f m, %+.1f%% (limit %.0f%%)", name, hs,
              seeds, hs_ref, 100 * (hs / hs_ref - 1), 100 * tol);
        ocean_free(o);
    }
}

/* ---- horizontal displacement in finite depth -------------------------------- */

/* F(k) = 1/N^2 sum f(x) e^{-i k.x} at every index (ix, iz), separably, in
 * double: the outputs' own Fourier coefficients, independent of our FFT. */
static void forward_dft(const float *f, int n, double complex *out)
{
    double complex *rows = malloc((size_t)n * n * sizeof *rows), *w = malloc((size_t)n * sizeof *w);
    for (int j = 0; j < n; j++)
        w[j] = cexp(-2.0 * M_PI * I * j / n);
    for (int z = 0; z < n; z++)
        for (int kx = 0; kx < n; kx++) {
            double complex s = 0;
            for (int x = 0; x < n; x++)
                s += f[(size_t)z * n + x] * w[(kx * x) & (n - 1)];
            rows[(size_t)z * n + kx] = s;
        }
    for (int kz = 0; kz < n; kz++)
        for (int kx = 0; kx < n; kx++) {
            double complex s = 0;
            for (int z = 0; z < n; z++)
                s += rows[(size_t)z * n + kx] * w[(kz * z) & (n - 1)];
            out[(size_t)kz * n + kx] = s / ((double)n * n);
        }
    free(rows);
    free(w);
}

/* Linear theory (Dean & Dalrymple, Water Wave Mechanics for Engineers and
 * Scientists, 1991, §4.4; US Army Corps of Engineers, Coastal Engineering
 * Manual EM 1110-2-1100 Part II-1, eqs. II-1-29 and II-1-30): a surface
 * particle of a wave h = H/2 cos(theta) in depth d moves by
 *   xi = -H/2 cosh(kd)/sinh(kd) sin(theta) along k, zeta = H/2 cos(theta) up,
 * an ellipse whose horizontal semi-axis is coth(kd) times the vertical one.
 * Per Fourier mode that is D^(k) = i (k/|k|) coth(kd) h^(k) for lambda = 1
 * (both the +k and the -k travelling wave of a mode obey it). The check
 * reads h, Dx and Dz back from the output fields (forward DFT in double)
 * and compares with cosh/sinh written out here. */
static double orbit_error(const struct ocean *o, double depth, double *kd_lo, double *kd_hi, double *from_deep)
{
    int n = ocean_resolution(o);
    size_t nn = (size_t)n * n;
    double L = ocean_get_params(o)->patch_size;
    double complex *H = malloc(nn * sizeof *H), *X = malloc(nn * sizeof *X), *Z = malloc(nn * sizeof *Z);
    forward_dft(ocean_field(o, OCEAN_HEIGHT), n, H);
    forward_dft(ocean_field(o, OCEAN_DX), n, X);
    forward_dft(ocean_field(o, OCEAN_DZ), n, Z);
    double hmax = 0;
    for (size_t i = 0; i < nn; i++)
        hmax = fmax(hmax, cabs(H[i]));
    double worst = 0, deep = 0;
    *kd_lo = 1e9;
    *kd_hi = 0;
    for (int iz = 0; iz < n; iz++)
        for (int ix = 0; ix < n; ix++) {
            size_t i = (size_t)iz * n + ix;
            if (cabs(H[i]) < 1e-3 * hmax)
                continue; /* float rounding dominates the tiny modes */
            double kx = 2 * M_PI * (ix - n * (ix > n / 2)) / L, kz = 2 * M_PI * (iz - n * (iz > n / 2)) / L;
            double k = hypot(kx, kz), kd = k * depth;
            double ratio = cosh(kd) / sinh(kd); /* horizontal / vertical semi-axis */
            double complex ex = I * kx / k * ratio * H[i], ez = I * kz / k * ratio * H[i];
            double e = (cabs(X[i] - ex) + cabs(Z[i] - ez)) / (ratio * cabs(H[i]));
            worst = fmax(worst, e);
            /* how far the deep-water displacement i k/|k| h^ would be off */
            deep = fmax(deep, (cabs(X[i] - I * kx / k * H[i]) + cabs(Z[i] - I * kz / k * H[i])) / (ratio * cabs(H[i])));
            *kd_lo = fmin(*kd_lo, kd);
            *kd_hi = fmax(*kd_hi, kd);
        }
    *from_deep = deep;
    free(H);
    free(X);
    free(Z);
    return worst;
}

static void test_depth_displacement(void)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 64;
    p.patch_size = 128; /* k up to 1.57 rad/m */
    p.depth = 4;        /* kd from ~0.3 (the peak) to ~6 (Nyquist) */
    p.choppiness = 1;
    p.small_wave_cutoff = 0;
    unsigned hxz = OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX) | OCEAN_FIELD_BIT(OCEAN_DZ);
    struct ocean *o = make(&p, 1);
    if (!o)
        return;
    for (int path = 0; path < (quick ? 1 : 2); path++) {
        if (path == 0)
            ocean_step_fft(o, 17.3, hxz);
        else
            ocean_step_dft(o, 17.3, hxz);
        double lo, hi, deep;
        double e = orbit_error(o, p.depth, &lo, &hi, &deep);
        char name[64];
        snprintf(name, sizeof name, "displacement.finite_depth.%s", path ? "dft" : "fft");
        CHECK(e < 1e-3 && lo < 0.5 && hi > 3 && deep > 0.3, "%s: depth %.0f m, modes with kd %.2f..%.2f: |D^ - i "
              "k/|k| coth(kd) h^| / (coth |h^|) <= %.1e (limit 1e-3); "
              "the deep-water formula would be off by %.2f", name, p.depth, lo, hi, e, deep);
    }
    /* Deep water is unchanged: D^ = i k/|k| h^ to float precision. */
    p.depth = 1000;
    char err[256];
    ocean_reconfigure(o, &p, err, sizeof err);
    ocean_step_fft(o, 17.3, hxz);
    double lo, hi, deep;
    double e = orbit_error(o, p.depth, &lo, &hi, &deep);
    CHECK(e < 1e-3 && deep < 1e-3 && hi > lo, "displacement.deep_unchanged: depth 1000 m (kd >= %.0f): off the "
          "deep-water i k/|k| h^ by %.1e, off coth by %.1e", lo, deep, e);
    ocean_free(o);
}

/* ---- fetch laws ------------------------------------------------------------ */

/* m0 = integral of S(w) dw over the whole spectrum (Simpson on a log grid
 * from wp/10 to 50 wp: outside, S is below 1e-30 resp. 2e-7 of the total). */
static double spectrum_m0(const struct spectrum_model *m)
{
    int n = 20000;
    double a = log(m->omega_p / 10), b = log(m->omega_p * 50), h = (b - a) / n, sum = 0;
    for (int i = 0; i <= n; i++) {
        double w = exp(a + i * h);
        sum += spectrum_frequency(m, w) * w * (i == 0 || i == n ? 1 : (i % 2 ? 4 : 2));
    }
    return sum * h / 3;
}

/* Our JONSWAP sea against published fetch laws (chi = g F / U^2, eps = g^2 E / U^4):
 *   JONSWAP, Hasselmann et al. 1973: eps = 1.6e-7 chi, f_p = 3.5 (g/U) chi^-0.33;
 *   SPM 1984 (deep water, Shore Protection Manual vol. I ch. 3, eqs. 3-28a, 3-33a):
 *     g Hm0 / UA^2 = 1.6e-3 (g F / UA^2)^1/2, UA = 0.71 U^1.23, at most 0.2433;
 *   Kahma & Calkoen 1992 (composite, p. 1404): eps = 5.2e-7 chi^0.9.
 * The assertions hold us to the JONSWAP energy law; the other two are
 * printed for docs/simulation.md's table. */
static void test_fetch_laws(void)
{
    const double g = OCEAN_G;
    static const double cases[][2] = {{5, 1}, {5, 10}, {10, 1}, {10, 10}, {10, 15}, {10, 100}, {10, 190},
                                      {20, 10}, {20, 50}, {20, 100}, {20, 700}};
    double worst_near = 0, worst_far = 0, worst_peak = 0;
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        double U = cases[c][0], F = cases[c][1] * 1000, chi = g * F / (U * U);
        struct ocean_params p;
        params_defaults(&p);
        p.spectrum = SPECTRUM_JONSWAP;
        p.wind_speed = U;
        p.fetch = cases[c][1];
        struct spectrum_model m;
        spectrum_model_init(&m, &p);
        double hs = 4 * sqrt(spectrum_m0(&m));
        double hs_jonswap = 4 * sqrt(1.6e-7 * chi) * U * U / g;
        double ua = 0.71 * pow(U, 1.23);
        double hs_spm = fmin(1.6e-3 * sqrt(g * F / (ua * ua)), 0.2433) * ua * ua / g;
        double hs_kc = 4 * sqrt(5.2e-7 * pow(chi, 0.9)) * U * U / g;
        /* The spectrum's maximum sits at Hasselmann's f_p (below the fully
         * developed cap, chi ~ 18800): golden-section search for the peak. */
        double a = 0.3 * m.omega_p, b = 3 * m.omega_p, r = (sqrt(5) - 1) / 2;
        for (int it = 0; it < 100; it++) {
            double x1 = b - r * (b - a), x2 = a + r * (b - a);
            if (spectrum_frequency(&m, x1) > spectrum_frequency(&m, x2))
                b = x2;
            else
                a = x1;
        }
        double fp_paper = 3.5 * (g / U) * pow(chi, -0.33), fp = 0.5 * (a + b) / (2 * M_PI);
        if (chi < 18000)
            worst_peak = fmax(worst_peak, fabs(fp / fp_paper - 1));
        double dev = fabs(hs / hs_jonswap - 1);
        if (chi <= 1500)
            worst_near = fmax(worst_near, dev);
        else if (chi < 18000)
            worst_far = fmax(worst_far, dev);
        printf("     U %4.1f m/s, fetch %5.0f km, chi %7.0f: Hs ours %6.3f m | JONSWAP %6.3f (%+5.1f%%) | "
               "SPM 1984 %6.3f | Kahma-Calkoen %6.3f | fp %.4f Hz (paper %.4f)\n",
               U, F / 1000, chi, hs, hs_jonswap, 100 * (hs / hs_jonswap - 1), hs_spm, hs_kc, fp, fp_paper);
    }
    CHECK(worst_peak < 1e-4, "fetch.jonswap_peak: spectral peak at Hasselmann's f_p = 3.5 (g/U) chi^-0.33: "
          "worst rel diff %.1e", worst_peak);
    CHECK(worst_near <= 0.15 && worst_far <= 0.30, "fetch.jonswap_energy_law: Hs = 4 sqrt(m0) vs JONSWAP 4 "
          "sqrt(1.6e-7 chi) U^2/g: within %.1f%% for chi <= 1500 (limit 15%%), "
          "%.1f%% up to the fully developed cap (limit 30%%)", 100 * worst_near, 100 * worst_far);
}

/* ---- robustness ------------------------------------------------------------ */

static int all_finite(const struct ocean *o)
{
    size_t nn = (size_t)ocean_resolution(o) * ocean_resolution(o);
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
        const float *a = ocean_field(o, f);
        for (size_t i = 0; i < nn; i++)
            if (!isfinite(a[i]))
                return 0;
    }
    return 1;
}

static void test_sweep(void)
{
    int runs = 0, bad = 0;
    char where[512] = "";
    for (size_t i = 0; i < param_count; i++) {
        const struct param_def *d = &param_table[i];
        if (d->flags & PARAM_PLAYBACK || strcmp(d->name, "transform") == 0)
            continue;
        double vals[3] = {d->min, d->max, 0.5 * (d->min + d->max)};
        for (int vi = 0; vi < 3; vi++)
            for (int s = 0; s < 4; s++) {
                if (quick && (vi == 2 || s != (int)(i + vi) % 4))
                    continue; /* quick: min and max, one spectrum each */
                struct ocean_params p;
                params_defaults(&p);
                p.resolution = 16;
                p.spectrum = s;
                double v = vals[vi];
                if (d->flags & PARAM_POW2) {
                    if (vi == 2 || (quick && v > 64) || (!quick && s > 0))
                        continue; /* 2048 once: it is the slow one */
                } else if (d->type != PARAM_FLOAT) {
                    v = floor(v);
                }
                char err[256];
                if (param_set(&p, d, v, err, sizeof err) != 0) {
                    bad++;
                    snprintf(where, sizeof where, "%s=%g rejected: %s", d->name, v, err);
                    continue;
                }
                if (params_validate(&p, err, sizeof err) != 0)
                    continue; /* cross rule (e.g. loop_period in (0,1)): not a physics case */
                struct ocean *o = make(&p, 1);
                if (!o) {
                    bad++;
                    continue;
                }
                double times[] = {0.0, 1.5, 1e6};
                for (int ti = 0; ti < 3; ti++) {
                    ocean_step(o, times[ti], OCEAN_ALL_FIELDS);
                    runs++;
                    if (!all_finite(o)) {
                        bad++;
                        snprintf(where, sizeof where, "%s=%g spectrum=%s t=%g", d->name, v, spec_name(s), times[ti]);
                    }
                }
                /* Amplitudes finite; k = 0 and the Nyquist row/column zero.
                 * (The half spectra themselves are consumed by c2r.) */
                struct ocean_grid *g = o->g;
                int n = g->n, amp_bad = 0;
                for (size_t m = 0; m < g->modes; m++) {
                    int ix = (int)(m % g->nh), iz = (int)(m / g->nh);
                    int special = (ix == 0 && iz == 0) || ix == n / 2 || iz == n / 2;
                    float amp[4] = {g->a[m], g->b[m], g->d[m], g->e[m]};
                    for (int q = 0; q < 4; q++)
                        amp_bad += !isfinite(amp[q]) || (special && amp[q] != 0);
                    amp_bad += !isfinite(g->omega[m]);
                }
                if (amp_bad) {
                    bad++;
                    snprintf(where, sizeof where, "%s=%g spectrum=%s: amplitude not finite or k=0/Nyquist not zero",
                             d->name, v, spec_name(s));
                }
                ocean_free(o);
            }
    }
    /* Corners: no wind, shallowest water, tiny patch with the finest grid. */
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 32;
    p.wind_speed = 0;
    struct ocean *o = make(&p, 1);
    if (o) {
        ocean_step(o, 3, OCEAN_ALL_FIELDS);
        runs++;
        if (!all_finite(o) || max_abs(ocean_field(o, OCEAN_HEIGHT), 1024) != 0) {
            bad++;
            snprintf(where, sizeof where, "wind 0: not a flat finite sea");
        }
        p.wind_speed = 40;
        p.depth = 0.5;
        p.spectrum = SPECTRUM_TMA;
        p.patch_size = 1;
        p.fetch = 10000;
        p.swell = 1;
        p.gamma = 10;
        p.small_wave_cutoff = 0;
        char err[256];
        ocean_reconfigure(o, &p, err, sizeof err);
        ocean_step(o, 3, OCEAN_ALL_FIELDS);
        runs++;
        if (!all_finite(o)) {
            bad++;
            snprintf(where, sizeof where, "extreme corner not finite");
        }
        ocean_free(o);
    }
    CHECK(bad == 0 && runs > (quick ? 40 : 100), "robust.no_nan_sweep: %d steps over min/mid/max of every "
          "parameter x 4 spectra%s%s",
          runs, bad ? ", first failure: " : ", all finite", where);
}

static void test_determinism(void)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = quick ? 32 : 256; /* >= 256: the fill is split over threads too */
    size_t nn = (size_t)p.resolution * p.resolution;
    struct ocean *a = make(&p, 1), *b = make(&p, 2), *c = make(&p, 1);
    if (!a || !b || !c)
        return;
    ocean_step(a, 12.5, OCEAN_ALL_FIELDS);
    ocean_step(b, 12.5, OCEAN_ALL_FIELDS);
    ocean_step(c, 12.5, OCEAN_ALL_FIELDS);
    int same_threads = 1, same_runs = 1;
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
        same_threads &= memcmp(ocean_field(a, f), ocean_field(b, f), nn * sizeof(float)) == 0;
        same_runs &= memcmp(ocean_field(a, f), ocean_field(c, f), nn * sizeof(float)) == 0;
    }
    p.seed = 2;
    char err[256];
    ocean_reconfigure(c, &p, err, sizeof err);
    ocean_step(c, 12.5, OCEAN_ALL_FIELDS);
    int differs = memcmp(ocean_field(a, OCEAN_HEIGHT), ocean_field(c, OCEAN_HEIGHT), nn * sizeof(float)) != 0;
    CHECK(same_threads && same_runs && differs, "determinism.bit_identical: N=%d, all fields: 1 vs 2 threads %s, "
          "two runs %s, other seed differs %s", p.resolution,
          same_threads ? "identical" : "DIFFER", same_runs ? "identical" : "DIFFER", differs ? "yes" : "NO");
    ocean_free(a);
    ocean_free(b);
    ocean_free(c);

    /* Same seed, same large waves at any N: h~0 at equal integer k agree. */
    params_defaults(&p);
    p.resolution = 32;
    struct ocean *s = make(&p, 1);
    p.resolution = 64;
    struct ocean *l = make(&p, 1);
    if (!s || !l)
        return;
    int mism = 0, nonzero = 0;
    for (int mz = -15; mz <= 15; mz++)
        for (int mx = 0; mx <= 15; mx++) {
            size_t is = (size_t)((mz + 32) % 32) * s->g->nh + mx, il = (size_t)((mz + 64) % 64) * l->g->nh + mx;
            mism += s->g->a[is] != l->g->a[il] || s->g->b[is] != l->g->b[il] || s->g->omega[is] != l->g->omega[il];
            nonzero += s->g->a[is] != 0;
        }
    CHECK(mism == 0 && nonzero > 100, "determinism.same_waves_any_N: h~0 and w at |m| < 16 equal between N=32 and "
          "N=64: %d mismatches", mism);
    ocean_free(s);
    ocean_free(l);
}

static void test_reconfigure(void)
{
    struct ocean_params p, q;
    params_defaults(&p);
    p.resolution = 32;
    struct ocean *o = make(&p, 1);
    if (!o)
        return;
    size_t nn = 32 * 32;
    ocean_step(o, 6.0, OCEAN_ALL_FIELDS);
    float *h = copy_field(o, OCEAN_HEIGHT);
    char err[256];
    struct { const char *what; void (*set)(struct ocean_params *); } cases[] = {
        {"resolution 100", NULL}, {"wind_speed -5", NULL}, {"patch_size NaN", NULL},
        {"dft at N=128", NULL}, {"spectrum 7", NULL}, {"loop_period 0.5", NULL}};
    int rejected = 0, unchanged = 1, messages = 1;
    for (int i = 0; i < 6; i++) {
        q = p;
        switch (i) {
        case 0: q.resolution = 100; break;
        case 1: q.wind_speed = -5; break;
        case 2: q.patch_size = NAN; break;
        case 3: q.resolution = 128; q.transform = TRANSFORM_DFT; break;
        case 4: q.spectrum = 7; break;
        case 5: q.loop_period = 0.5; break;
        }
        err[0] = 0;
        if (ocean_reconfigure(o, &q, err, sizeof err) == -1)
            rejected++;
        if (strlen(err) < 10)
            messages = 0;
        printf("     rejected %-16s -> \"%s\"\n", cases[i].what, err);
        ocean_step(o, 6.0, OCEAN_ALL_FIELDS);
        unchanged &= memcmp(ocean_get_params(o), &p, sizeof p) == 0 && ocean_resolution(o) == 32 &&
                     memcmp(ocean_field(o, OCEAN_HEIGHT), h, nn * sizeof(float)) == 0;
    }
    struct ocean *none = ocean_create(&q, NULL, err, sizeof err);
    CHECK(rejected == 6 && unchanged && messages && !none, "params.invalid_rejected: %d/6 rejected with a "
          "message, simulation unchanged: %s; create with bad params: %s", rejected,
          unchanged ? "yes" : "NO", none ? "ACCEPTED" : "NULL");
    ocean_free(none);

    /* Valid changes keep the random phases: amplitude x4 doubles h exactly. */
    q = p;
    q.amplitude = 4 * p.amplitude;
    ocean_reconfigure(o, &q, err, sizeof err);
    ocean_step(o, 6.0, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
    float *h2 = copy_field(o, OCEAN_HEIGHT);
    for (size_t i = 0; i < nn; i++)
        h2[i] *= 0.5f;
    double e = rel_err(h2, h, nn);
    free(h2);
    CHECK(e < 1e-6, "reconfigure.keeps_phases: amplitude x4 gives 2 h: rel err %.1e", e);

    /* Re-plan to another N and back. */
    q.resolution = 64;
    int r = ocean_reconfigure(o, &q, err, sizeof err);
    ocean_step(o, 6.0, OCEAN_ALL_FIELDS);
    int ok64 = r == 0 && ocean_resolution(o) == 64 && all_finite(o);
    q = p;
    r = ocean_reconfigure(o, &q, err, sizeof err);
    ocean_step(o, 6.0, OCEAN_ALL_FIELDS);
    CHECK(ok64 && r == 0 && memcmp(ocean_field(o, OCEAN_HEIGHT), h, nn * sizeof(float)) == 0,
          "reconfigure.replan: 32 -> 64 -> 32: back to the identical field");
    CHECK(strcmp(ocean_field_name(OCEAN_SLOPE_Z), "slope_z") == 0 && ocean_field_name(OCEAN_FIELD_COUNT) == NULL,
          "api.field_names: stable names");
    free(h);
    ocean_free(o);
}

/* ---- parameter changes off the stepping thread ------------------------------- */

struct prep_job {
    struct ocean *o;
    struct ocean_params p;
    struct ocean_prepared *pr;
    char err[256];
};

static void *prep_thread(void *arg)
{
    struct prep_job *j = arg;
    j->pr = ocean_prepare(j->o, &j->p, j->err, sizeof j->err);
    return NULL;
}

/* The fields that are a function of (params, t): all but foam, which
 * carries its history across a reconfigure by design (test_foam). */
static int same_fields(const struct ocean *a, const struct ocean *b)
{
    int n = ocean_resolution(a);
    if (n != ocean_resolution(b))
        return 0;
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        if (f != OCEAN_FOAM && memcmp(ocean_field(a, f), ocean_field(b, f), (size_t)n * n * sizeof(float)) != 0)
            return 0;
    return 1;
}

static void test_prepare_commit(void)
{
    struct ocean_params p, q;
    params_defaults(&p);
    p.resolution = quick ? 32 : 256;
    struct ocean *o = make(&p, 2);
    if (!o)
        return;
    char err[256];
    /* Every kind of change through the cache (wind, seed, patch, depth,
     * spectrum, spreading, N) gives the bits a fresh ocean_create gives:
     * nothing stale survives in the cached normals, rings or k tables. */
    struct ocean_params steps[6];
    for (int i = 0; i < 6; i++)
        steps[i] = p;
    steps[0].wind_speed = 17;
    steps[1].seed = 7;
    steps[2].patch_size = 400;
    steps[3].depth = 6;
    steps[3].spectrum = SPECTRUM_TMA;
    steps[4].directional_spread = 0.3;
    steps[4].wind_direction = 130;
    steps[5].resolution = quick ? 64 : 128;
    int fresh_same = 0;
    for (int i = 0; i < 6; i++) {
        q = steps[i];
        ocean_reconfigure(o, &q, err, sizeof err);
        struct ocean *f = make(&q, 1);
        if (!f)
            continue;
        ocean_step(o, 21.5, OCEAN_ALL_FIELDS);
        ocean_step(f, 21.5, OCEAN_ALL_FIELDS);
        fresh_same += same_fields(o, f);
        ocean_free(f);
    }
    CHECK(fresh_same == 6, "reconfigure.equals_fresh: %d/6 changes (wind, seed, patch, depth+tma, spread+direction, "
          "N) bit-identical to a fresh ocean_create", fresh_same);

    /* Prepared on another thread while this one steps; committed here. */
    ocean_reconfigure(o, &p, err, sizeof err);
    struct prep_job job = {o, p, NULL, ""};
    job.p.wind_speed = 14;
    job.p.seed = 3;
    pthread_t th;
    int started = pthread_create(&th, NULL, prep_thread, &job) == 0;
    for (int i = 0; i < 5; i++)
        ocean_step(o, 1.0 + i, OCEAN_ALL_FIELDS);
    if (started)
        pthread_join(th, NULL);
    else
        prep_thread(&job);
    int before_commit = ocean_get_params(o)->seed == p.seed; /* prepare changed nothing yet */
    int rc = ocean_commit(o, job.pr);
    ocean_prepared_free(job.pr);
    struct ocean *f = make(&job.p, 1);
    int same = 0;
    if (f) {
        ocean_step(o, 8.25, OCEAN_ALL_FIELDS);
        ocean_step(f, 8.25, OCEAN_ALL_FIELDS);
        same = same_fields(o, f);
        ocean_free(f);
    }
    CHECK(started && before_commit && rc == 0 && same && ocean_get_params(o)->seed == 3, "prepare.other_thread: "
          "prepared on a second thread during 5 steps, committed: fields equal a fresh ocean's "
          "%s", same ? "yes" : "NO");

    /* A stale prepare is refused and changes nothing; bad parameters give NULL. */
    q = p;
    q.wind_speed = 5;
    struct ocean_prepared *stale = ocean_prepare(o, &q, err, sizeof err);
    ocean_reconfigure(o, &p, err, sizeof err);
    ocean_step(o, 3.0, OCEAN_ALL_FIELDS);
    float *h = copy_field(o, OCEAN_HEIGHT);
    int stale_rc = ocean_commit(o, stale);
    ocean_prepared_free(stale);
    ocean_step(o, 3.0, OCEAN_ALL_FIELDS);
    size_t nn = (size_t)p.resolution * p.resolution;
    int unchanged = ocean_get_params(o)->wind_speed == p.wind_speed &&
                    memcmp(h, ocean_field(o, OCEAN_HEIGHT), nn * sizeof(float)) == 0;
    free(h);
    q = p;
    q.resolution = 100;
    err[0] = 0;
    struct ocean_prepared *bad = ocean_prepare(o, &q, err, sizeof err);
    CHECK(stale != NULL && stale_rc == -1 && unchanged && !bad && strstr(err, "power of "
          "two"), "prepare.stale_and_invalid: commit after another reconfigure: %d (unchanged: %s); N=100: "
          "%s", stale_rc, unchanged ? "yes" : "NO", err);
    ocean_free(o);
}

/* ---- memory accounting -------------------------------------------------------- */

/* Heap bytes in use according to glibc (small blocks + mmapped blocks). */
static size_t heap_in_use(void)
{
    struct mallinfo2 mi = mallinfo2();
    return mi.uordblks + mi.hblkhd;
}

/* ocean_memory_bytes is what a memory cap counts: it must match what an
 * ocean really allocates. Two independent counts: the bytes that went
 * through the library's array allocator during ocean_create (the test
 * hook ocean_alloc_bytes), and glibc's own mallinfo2 before and after
 * (everything: plans, pool, structs), when the allocator is glibc's
 * (not under ASan or valgrind, which bring their own). */
/* Easing (ocean_commit_eased, docs/simulation.md "Easing"): an
 * amplitude-only change reaches exactly the new sea after its length; at the
 * start it is exactly the old; half way the fields are the mean of both
 * (they are linear in the amplitudes); a change in the middle of an easing
 * starts from where the sea is (the same bits just before and just after
 * the commit); a query snapshot agrees with the steps during an easing; a
 * change of seed or of choppiness alone is not eased. */
static int prepared_commit(struct ocean *o, const struct ocean_params *q, double t0, double len)
{
    char err[256];
    struct ocean_prepared *pr = ocean_prepare(o, q, err, sizeof err);
    if (!pr)
        return -1;
    int rc = ocean_commit_eased(o, pr, t0, len);
    ocean_prepared_free(pr);
    return rc;
}

static float *step_copy(struct ocean *o, double t, unsigned fields, enum ocean_field f)
{
    ocean_step(o, t, fields);
    return copy_field(o, f);
}

static void test_easing(void)
{
    const unsigned F = OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX) | OCEAN_FIELD_BIT(OCEAN_DZ);
    struct ocean_params p, q, r;
    params_defaults(&p);
    p.resolution = quick ? 32 : 128;
    p.cascades = 2;
    q = p;
    q.wind_speed = p.wind_speed + 3;
    q.wind_direction = p.wind_direction + 25;
    q.choppiness = p.choppiness + 0.5; /* changes at once, beside the eased amplitudes */
    r = q;
    r.wind_speed = p.wind_speed - 2;
    r.amplitude = p.amplitude * 1.5;
    struct ocean *o = make(&p, 2), *a = make(&p, 1), *b = make(&q, 1), *c = make(&r, 1);
    if (!o || !a || !b || !c)
        goto out;
    const int n = p.resolution;
    const size_t nn = (size_t)n * n;
    const double t0 = 40.0, dt = 1.0 / 30, len = 8 * dt;
    char err[256];
    size_t alloc0 = ocean_alloc_bytes;
    struct ocean_prepared *pr = ocean_prepare(o, &q, err, sizeof err);
    /* What a memory cap counts for a change being built (server/control.c:
     * a second simulation, ocean_memory_bytes per cascade) covers the
     * prepared amplitudes and the easing buffers the first eased change makes. */
    size_t change_bytes = ocean_alloc_bytes - alloc0, model_bytes = ocean_memory_bytes(n, 2) * (size_t)p.cascades;
    int easable = ocean_prepared_easable(pr);
    int rc = pr ? ocean_commit_eased(o, pr, t0, len) : -1;
    ocean_prepared_free(pr);
    /* The easing buffers are made once and kept: a second eased change (prepared, not
     * committed) allocates exactly ocean_ease_memory_bytes per cascade less, which is
     * what the memory cap (control_fits_memory) adds to a simulation at this N. */
    size_t alloc1 = ocean_alloc_bytes;
    struct ocean_prepared *pr2 = ocean_prepare(o, &r, err, sizeof err);
    size_t second_bytes = ocean_alloc_bytes - alloc1, ease_bytes = ocean_ease_memory_bytes(n) * (size_t)p.cascades;
    int ease_kept = pr2 && ocean_prepared_easable(pr2) && change_bytes - second_bytes == ease_bytes &&
                    ease_bytes == 8 * nn * (size_t)p.cascades && ocean_ease_memory_bytes(OCEAN_EASE_MAX_N * 2) == 0;
    ocean_prepared_free(pr2);
    /* At t0: the old sea, bit for bit (cascade 0's height; choppiness is
     * new, so the displacements are compared with the new choppiness at the
     * end only). After t0 + len: the new sea, bit for bit, on every cascade. */
    float *h0 = step_copy(o, t0, OCEAN_FIELD_BIT(OCEAN_HEIGHT), OCEAN_HEIGHT);
    float *ha = step_copy(a, t0, OCEAN_FIELD_BIT(OCEAN_HEIGHT), OCEAN_HEIGHT);
    int start_old = memcmp(h0, ha, nn * sizeof(float)) == 0;
    /* Half way: the mean of the two seas' heights (linear in the amplitudes). */
    const double tm = t0 + 0.5 * len;
    float *hm = step_copy(o, tm, OCEAN_FIELD_BIT(OCEAN_HEIGHT), OCEAN_HEIGHT);
    float *hma = step_copy(a, tm, OCEAN_FIELD_BIT(OCEAN_HEIGHT), OCEAN_HEIGHT);
    float *hmb = step_copy(b, tm, OCEAN_FIELD_BIT(OCEAN_HEIGHT), OCEAN_HEIGHT);
    double dmid = 0, dab = 0;
    for (size_t i = 0; i < nn; i++) {
        dmid = fmax(dmid, fabs(hm[i] - 0.5 * ((double)hma[i] + hmb[i])));
        dab = fmax(dab, fabs((double)hma[i] - hmb[i]));
    }
    ocean_step(o, t0 + len, OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM));
    ocean_step(b, t0 + len, OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM));
    int end_new = same_fields(o, b);
    const float *o1 = ocean_cascade_field(o, 1, OCEAN_HEIGHT), *b1 = ocean_cascade_field(b, 1, OCEAN_HEIGHT);
    end_new &= o1 && b1 && memcmp(o1, b1, nn * sizeof(float)) == 0;
    CHECK(easable && rc == 0 && start_old && end_new && dmid <= 1e-5 * (1 + dab) && dab > 0.1,
          "easing.reaches_new: wind %g -> %g m/s over %g s: old sea at t0 %s, new at t0 + len %s (both cascades), "
          "half way the mean of both within %.1e m (the seas differ by %.2f m)", p.wind_speed, q.wind_speed, len,
          start_old ? "bit for bit" : "NO", end_new ? "bit for bit" : "NO", dmid, dab);
    CHECK(change_bytes > 0 && change_bytes <= model_bytes / 2 && ease_kept, "easing.memory: the first eased "
          "change allocates %.2f MB (new amplitudes + easing buffers), the cap counts %.2f MB "
          "for a change being built; a second one %.2f MB less (ocean_ease_memory_bytes x cascades = %.2f MB): %s",
          change_bytes / 1e6, model_bytes / 1e6, (double)(change_bytes - second_bytes) / 1e6, ease_bytes / 1e6,
          ease_kept ? "yes" : "NO");
    free(h0);
    free(ha);
    free(hm);
    free(hma);
    free(hmb);

    /* A second change 3 ticks into a new easing: the sea just after the
     * commit is the sea just before it, bit for bit (no jump), on every field
     * but the displacements' choppiness (unchanged here); then it goes to the
     * third sea and gets there exactly. Each tick moves it a little. */
    double t1 = t0 + 100;
    rc = prepared_commit(o, &p, t1, len); /* back to p, eased */
    double t2 = t1 + 3 * dt;
    ocean_step(o, t2, F);
    float *before[3] = {copy_field(o, OCEAN_HEIGHT), copy_field(o, OCEAN_DX), copy_field(o, OCEAN_DZ)};
    struct ocean_params p2 = r;
    p2.choppiness = p.choppiness;
    int rc2 = prepared_commit(o, &p2, t2, len);
    ocean_step(o, t2, F);
    int no_jump = 1;
    for (int f = 0; f < 3; f++) {
        no_jump &= memcmp(before[f], ocean_field(o, (enum ocean_field)f), nn * sizeof(float)) == 0;
        free(before[f]);
    }
    /* The largest change of height from one tick to the next, during the
     * easing and in the steady new sea: no tick jumps. */
    double worst_tick = 0, steady_tick = 0;
    float *prev = step_copy(o, t2 - dt, OCEAN_FIELD_BIT(OCEAN_HEIGHT), OCEAN_HEIGHT);
    for (int k = 0; k <= 12; k++) {
        float *cur = step_copy(o, t2 + k * dt, OCEAN_FIELD_BIT(OCEAN_HEIGHT), OCEAN_HEIGHT);
        double d = 0;
        for (size_t i = 0; i < nn; i++)
            d = fmax(d, fabs((double)cur[i] - prev[i]));
        if (k <= 8)
            worst_tick = fmax(worst_tick, d);
        else
            steady_tick = fmax(steady_tick, d);
        free(prev);
        prev = cur;
    }
    free(prev);
    struct ocean *c2 = make(&p2, 1);
    int third = 0;
    if (c2) {
        ocean_step(o, t2 + 20 * dt, OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM));
        ocean_step(c2, t2 + 20 * dt, OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM));
        third = same_fields(o, c2);
        ocean_free(c2);
    }
    CHECK(rc == 0 && rc2 == 0 && no_jump && third && worst_tick < 3 * steady_tick, "easing.mid_change_no_jump: a "
          "change 3 ticks into an easing: the sea after the commit = before it %s; the largest tick-to-tick "
          "height change while easing %.3f m (steady sea: %.3f m); reaches the third sea exactly %s",
          no_jump ? "bit for bit" : "NO", worst_tick, steady_tick, third ? "yes" : "NO");

    /* Queries during an easing agree with the steps: one cascade,
     * choppiness 0, at grid nodes (a node is its own source). The snapshot
     * is made both ways the daemon makes them: prepared before the commit
     * and given the easing after it, and from the live ocean. */
    struct ocean_params s1 = p;
    s1.cascades = 1;
    s1.choppiness = 0;
    struct ocean_params s2 = s1;
    s2.wind_speed = s1.wind_speed + 4;
    struct ocean *oq = make(&s1, 2);
    double worst_q = 0, worst_live = 0, worst_old = 0;
    int qok = oq != NULL;
    if (oq) {
        double tq0 = 5.0;
        prepared_commit(oq, &s2, tq0 - 20, len); /* an easing before, finished */
        ocean_step(oq, tq0, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
        struct ocean_prepared *pq = ocean_prepare(oq, &s1, err, sizeof err); /* and back, eased */
        struct ocean_surface *sp = pq ? ocean_prepared_surface(oq, pq, err, sizeof err) : NULL;
        struct ocean_surface *splain = NULL;
        qok = pq && sp && ocean_commit_eased(oq, pq, tq0, len) == 0 && ocean_surface_ease(sp, oq) == 0;
        ocean_prepared_free(pq);
        struct ocean_surface *sl = ocean_surface_new(oq, err, sizeof err);
        {   /* what the old code had: the new amplitudes only */
            struct ocean *plain = make(&s1, 1);
            splain = plain ? ocean_surface_new(plain, err, sizeof err) : NULL;
            ocean_free(plain);
        }
        qok &= sl && splain;
        double xz[16][2];
        int node[16][2];
        for (int i = 0; i < 16; i++) {
            node[i][0] = (i * 37 + 5) % n;
            node[i][1] = (i * 11 + 3) % n;
            xz[i][0] = node[i][0] * s1.patch_size / n;
            xz[i][1] = node[i][1] * s1.patch_size / n;
        }
        for (int k = 1; k <= 7 && qok; k += 3) {
            double t = tq0 + k * dt;
            ocean_step(oq, t, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
            const float *h = ocean_field(oq, OCEAN_HEIGHT);
            struct ocean_point pt[16], lt[16], ot[16];
            qok &= ocean_surface_query(sp, t, (const double(*)[2])xz, 16, pt) == 0 &&
                   ocean_surface_query(sl, t, (const double(*)[2])xz, 16, lt) == 0 &&
                   ocean_surface_query(splain, t, (const double(*)[2])xz, 16, ot) == 0;
            for (int i = 0; i < 16; i++) {
                double g = h[(size_t)node[i][1] * n + node[i][0]];
                worst_q = fmax(worst_q, fabs(pt[i].height - g));
                worst_live = fmax(worst_live, fabs(lt[i].height - g));
                worst_old = fmax(worst_old, fabs(ot[i].height - g));
            }
        }
        ocean_surface_free(sp);
        ocean_surface_free(sl);
        ocean_surface_free(splain);
        ocean_free(oq);
    }
    CHECK(qok && worst_q < 1e-4 && worst_live < 1e-4 && worst_old > 1e-2, "easing.query_equals_step: grid nodes "
          "during an easing: |query - step| %.1e m (snapshot prepared, then eased), %.1e m (live "
          "snapshot); the new amplitudes alone are %.1e m off", worst_q, worst_live, worst_old);

    /* Not eased: a new seed (other phases), choppiness alone (no amplitude
     * changes), the DFT path; such a commit is the change at once. */
    struct ocean_params ns = p, nc = p;
    ns.seed = p.seed + 1;
    ns.wind_speed = p.wind_speed + 1;
    nc.choppiness = p.choppiness + 1;
    prepared_commit(o, &p, t0, 0);
    struct ocean_prepared *ps = ocean_prepare(o, &ns, err, sizeof err), *pc = ocean_prepare(o, &nc, err, sizeof err);
    int not_easable = ps && pc && !ocean_prepared_easable(ps) && !ocean_prepared_easable(pc);
    int crc = ps ? ocean_commit_eased(o, ps, t0, len) : -1;
    ocean_prepared_free(ps);
    ocean_prepared_free(pc);
    struct ocean *fs = make(&ns, 1);
    int at_once = 0;
    double e0, el;
    ocean_easing(o, &e0, &el);
    if (fs) {
        ocean_step(o, t0 + 0.01, OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM));
        ocean_step(fs, t0 + 0.01, OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM));
        at_once = same_fields(o, fs);
        ocean_free(fs);
    }
    CHECK(not_easable && crc == 0 && at_once && el == 0, "easing.only_amplitudes: a new seed and choppiness alone "
          "are not easable; the seed change applies at once %s",
          at_once ? "(bit for bit a fresh ocean's)" : "NO");
out:
    ocean_free(o);
    ocean_free(a);
    ocean_free(b);
    ocean_free(c);
}

static void test_memory_bytes(void)
{
    int sizes[] = {64, 256, 512, 1024};
    int first = quick ? 0 : 1, last = quick ? 1 : 3;
    /* Is mallinfo2 telling the truth here? A known 3 MB block must show. */
    size_t h0 = heap_in_use();
    void *volatile probe = malloc(3u << 20); /* volatile: the compiler may not elide it */
    if (probe)
        memset(probe, 1, 3u << 20);
    size_t h1 = heap_in_use();
    free(probe);
    int glibc = h1 - h0 >= (3u << 20) && h1 - h0 < (3u << 20) + 65536;
    double worst_hook = 0, worst_heap = 0;
    char line[512] = "";
    for (int i = first; i <= last; i++) {
        int n = sizes[i];
        struct ocean_params p;
        params_defaults(&p);
        p.resolution = n;
        size_t want = ocean_memory_bytes(n, 2) * (size_t)p.cascades; /* one grid per cascade */
        size_t hook0 = ocean_alloc_bytes, heap0 = heap_in_use();
        struct ocean *o = make(&p, 2);
        size_t hook = ocean_alloc_bytes - hook0, heap = heap_in_use() - heap0;
        ocean_free(o);
        double eh = fabs((double)hook / want - 1), ep = fabs((double)heap / want - 1);
        worst_hook = fmax(worst_hook, eh);
        if (glibc)
            worst_heap = fmax(worst_heap, ep);
        size_t len = strlen(line);
        snprintf(line + len, sizeof line - len, "%sN=%d: %.2f MB said, arrays %.2f, heap %s%.2f", i > first ? "; " : "",
                 n, want / 1e6, hook / 1e6, glibc ? "" : "(n/a) ", heap / 1e6);
    }
    /* threads = 0 means every online core, up to 64: a big machine's cores all help the step. */
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    int want_threads = cores < 1 ? 1 : cores > OCEAN_MAX_THREADS ? OCEAN_MAX_THREADS : (int)cores;
    struct ocean_params p0;
    params_defaults(&p0);
    p0.resolution = 64;
    struct ocean_options opt0 = {0, NULL, 0};
    char err0[256];
    struct ocean *o0 = ocean_create(&p0, &opt0, err0, sizeof err0);
    int got_threads = o0 ? o0->opt.threads : -1;
    ocean_free(o0);
    CHECK(got_threads == want_threads && ocean_threads(0) == want_threads && ocean_threads(100) == 64 &&
          ocean_threads(-3) == 1 && ocean_threads(12) == 12 &&
          ocean_memory_bytes(512, 0) == ocean_memory_bytes(512, want_threads),
          "threads.zero_is_every_core: threads 0 -> %d (cores online %ld; 12 -> %d, 100 -> %d, -3 -> %d)", got_threads,
          cores, ocean_threads(12), ocean_threads(100), ocean_threads(-3));
    CHECK(worst_hook <= 0.10 && worst_heap <= 0.10, "memory.bytes_match: %s (limit 10%%: arrays %.1f%%, heap "
          "%s%.1f%%)", line, 100 * worst_hook, glibc ? "" : "not measured ",
          100 * worst_heap);
}

static double seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

/* Run one group and say how long it took (to keep the suite's budget). */
static const char *only; /* OCEAN_TEST_ONLY=test_easing: that group alone */
#define RUN(fn)                                                       \
    do {                                                              \
        if (only && strcmp(only, #fn) != 0)                           \
            break;                                                    \
        double t0_ = seconds();                                       \
        fn();                                                         \
        printf("     (%s: %.2f s)\n", #fn, seconds() - t0_);          \
    } while (0)

/* FFTW_MEASURE with a wisdom file: the file appears, a second ocean plans
 * from it, and the fields equal the ESTIMATE ones to rounding. */
static void test_wisdom(void)
{
    char dir[] = "/tmp/test_ocean_XXXXXX", path[64];
    if (!mkdtemp(dir)) {
        CHECK(0, "fftw.wisdom: mkdtemp failed");
        return;
    }
    snprintf(path, sizeof path, "%s/wisdom", dir);
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 32;
    char err[256];
    struct ocean_options opt = {2, path, 1};
    struct ocean *a = ocean_create(&p, &opt, err, sizeof err);
    FILE *f = fopen(path, "r");
    long size = 0;
    if (f) {
        fseek(f, 0, SEEK_END);
        size = ftell(f);
        fclose(f);
    }
    struct ocean *b = ocean_create(&p, &opt, err, sizeof err), *c = make(&p, 1);
    double e = 1;
    if (a && b && c) {
        ocean_step(b, 3.0, OCEAN_ALL_FIELDS);
        ocean_step(c, 3.0, OCEAN_ALL_FIELDS);
        e = 0;
        for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
            e = fmax(e, rel_err(ocean_field(b, i), ocean_field(c, i), 32 * 32));
    }
    CHECK(a && b && size > 0 && e < 1e-5, "fftw.wisdom: MEASURE plans, wisdom file %ld bytes, fields vs ESTIMATE %.1e",
          size, e);
    ocean_free(a);
    ocean_free(b);
    ocean_free(c);
    remove(path);
    rmdir(dir);
}

/* ---- foam (ocean_foam.c) ------------------------------------------------ */

/* Fraction of samples with foam >= 0.5 ("covered"). */
static double foam_covered(const struct ocean *o)
{
    size_t nn = (size_t)ocean_resolution(o) * ocean_resolution(o), c = 0;
    const float *f = ocean_field(o, OCEAN_FOAM);
    for (size_t i = 0; i < nn; i++)
        c += f[i] >= 0.5f;
    return (double)c / (double)nn;
}

/* Whitecap coverage against Monahan & O'Muircheartaigh (1980), W = 3.84e-6
 * U10^3.41, at the default parameters (N = 256, choppiness 1), stepped as
 * the daemon does at its default 30 ticks per second: the covered fraction
 * (foam >= 0.5), averaged over 10 s, within a factor of 1.5 of W. Also: foam
 * stays in [0, 1], is reproducible, and fades once the wind drops. */
static void test_foam(void)
{
    const double winds[] = {8, 12, 16, 20, 25}, dt = 1.0 / 30;
    const int nwinds = quick ? 1 : 5, seconds = quick ? 2 : 10;
    for (int w = 0; w < nwinds; w++) {
        struct ocean_params p;
        params_defaults(&p);
        p.wind_speed = winds[quick ? 2 : w];
        if (quick)
            p.resolution = 64; /* coverage not checked: too few samples */
        struct ocean *o = make(&p, 1);
        if (!o)
            return;
        double sum = 0, lo = 1, hi = 0;
        int samples = 0;
        bool range = true;
        size_t nn = (size_t)p.resolution * p.resolution;
        for (int k = 0; k <= seconds * 30; k++) {
            ocean_step(o, 100.0 + k * dt, OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_FOAM));
            const float *f = ocean_field(o, OCEAN_FOAM);
            for (size_t i = 0; i < nn && range; i++)
                range = f[i] >= 0.0f && f[i] <= 1.0f;
            if (k % 15 == 0) {
                double c = foam_covered(o);
                sum += c;
                lo = fmin(lo, c);
                hi = fmax(hi, c);
                samples++;
            }
        }
        double cov = sum / samples, W = 3.84e-6 * pow(p.wind_speed, 3.41);
        char name[64];
        snprintf(name, sizeof name, "foam.coverage.U%g", p.wind_speed);
        CHECK(range && (quick || (cov >= W / 1.5 && cov <= 1.5 * W)), "%s: covered fraction %.4f (%.4f..%.4f over %d "
              "s) vs Monahan & O'Muircheartaigh W = %.4f: ratio %.2f%s", name,
              cov, lo, hi, seconds, W, cov / W, quick ? " (quick mode, N = 64: only the range 0..1 checked)" : "");
        ocean_free(o);
    }

    /* Reproducible: the same (params, step times) give the same foam, and a
     * cold start depends on (params, t) only, not on the resolution's past. */
    struct ocean_params p;
    params_defaults(&p);
    p.wind_speed = 20;
    p.resolution = quick ? 32 : 128;
    p.patch_size = quick ? 32 : 128;
    struct ocean *a = make(&p, 1), *b = make(&p, 2);
    if (!a || !b) {
        ocean_free(a);
        ocean_free(b);
        return;
    }
    size_t nn = (size_t)p.resolution * p.resolution;
    ocean_step(a, 3.0, OCEAN_ALL_FIELDS); /* b: a different history before a gap */
    for (int k = 0; k < 30; k++)
        ocean_step(a, 50.0 + k / 30.0, OCEAN_FIELD_BIT(OCEAN_FOAM));
    for (int k = 0; k < 30; k++)
        ocean_step(b, 50.0 + k / 30.0, OCEAN_FIELD_BIT(OCEAN_FOAM));
    double same = rel_err(ocean_field(a, OCEAN_FOAM), ocean_field(b, OCEAN_FOAM), nn);
    double c0 = foam_covered(a);
    /* The wind drops to nothing: no new foam, and the old fades (e-folding
     * 3 s: after 4 s nothing is left at 0.5). */
    p.wind_speed = 0;
    char err[256];
    ocean_reconfigure(a, &p, err, sizeof err);
    double fmaxv = 0;
    for (int k = 30; k <= 30 + 4 * 30; k++)
        ocean_step(a, 50.0 + k / 30.0, OCEAN_FIELD_BIT(OCEAN_FOAM));
    fmaxv = max_abs(ocean_field(a, OCEAN_FOAM), nn);
    CHECK(same == 0 && c0 > 0 && foam_covered(a) == 0 && fmaxv <= exp(-4.0 / 3.0) + 1e-6,
          "foam.deterministic_and_fades: two oceans (1 and 2 threads, different pasts) after the same steps: "
          "max diff %.1e; covered %.4f, 4 s after the wind stops: covered %.4f, max foam %.3f (<= exp(-4/3))",
          same, c0, foam_covered(a), fmaxv);
    ocean_free(a);
    ocean_free(b);
}

/* Every sea parameter has a label, a group and a one-line help for the
 * panel (params.h, struct param_ui), and no UI row names a missing one. */
static void test_param_ui(void)
{
    int missing = 0, groups[3] = {0};
    const char *first = "";
    for (size_t i = 0; i < param_count; i++) {
        const struct param_ui *u = param_ui(&param_table[i]);
        bool ok = u && u->label && *u->label && u->help && *u->help && strlen(u->help) <= 100 &&
                  !strchr(u->help, '\n') && (unsigned)u->group <= PARAM_GROUP_DEVELOPER;
        if (!ok && !missing++)
            first = param_table[i].name;
        if (ok)
            groups[u->group]++;
    }
    CHECK(missing == 0 && groups[PARAM_GROUP_SEA] > 0 && groups[PARAM_GROUP_DEVELOPER] > 0 &&
              strcmp(param_group_name(PARAM_GROUP_DEVELOPER), "developer") == 0,
          "params.ui: %d of %zu parameters without label/group/help (first: %s); sea %d, advanced %d, developer %d",
          missing, param_count, first, groups[0], groups[1], groups[2]);
}


/* ---- cascades ----------------------------------------------------------------- */

/* Hs of the sum of 3 cascades against the spectrum's integral over the
 * combined band (band_m0, the 1-D integral of S(w) over the wavenumbers
 * the three grids hold: from half the largest patch's dk to the finest
 * cascade's top, half its Nyquist). The cascades' random numbers are independent and
 * their bands disjoint, so the variance of the sum is the sum of their
 * variances (each from its own grid). A light wind puts the peak at the
 * border of cascades 0 and 1, so counting a band twice, or leaving a gap,
 * would move Hs well beyond the tolerance: the finer cascades must hold a
 * good share of the energy for the check to mean anything. */
static void test_cascades_hs(void)
{
    const int spectra[] = {SPECTRUM_PIERSON_MOSKOWITZ, SPECTRUM_JONSWAP};
    for (size_t si = 0; si < sizeof spectra / sizeof spectra[0]; si++) {
        struct ocean_params p;
        params_defaults(&p);
        p.spectrum = spectra[si];
        p.cascades = 3;
        p.resolution = quick ? 64 : 256;
        p.patch_size = quick ? 250 : 1000;
        p.wind_speed = 3;
        p.fetch = 5;
        p.small_wave_cutoff = 0;
        int seeds = quick ? 4 : 16;
        double m0[3] = {0, 0, 0};
        struct ocean *o = make(&p, 1);
        if (!o)
            return;
        size_t nn = (size_t)p.resolution * p.resolution;
        for (int seed = 0; seed < seeds; seed++) {
            p.seed = 2000 + seed;
            char err[256];
            ocean_reconfigure(o, &p, err, sizeof err);
            ocean_step(o, 0.0, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
            for (int c = 0; c < 3; c++)
                m0[c] += variance(ocean_cascade_field(o, c, OCEAN_HEIGHT), nn) / seeds;
        }
        double dk = 2 * M_PI / p.patch_size, L2 = ocean_cascade_patch(p.patch_size, 2);
        /* Up to the finest cascade's top: (N/4 - 1/2) of its wavenumber steps. */
        double ref = band_m0(&o->model, 0.5 * dk, (ocean_cascade_band_top(p.resolution, 2) + 0.5) * 2 * M_PI / L2);
        double sum = m0[0] + m0[1] + m0[2], hs = 4 * sqrt(sum), hs_ref = 4 * sqrt(ref);
        double fine = (m0[1] + m0[2]) / sum;
        char name[64];
        snprintf(name, sizeof name, "cascades.hs.%s", spec_name(spectra[si]));
        double tol = quick ? 0.10 : 0.05;
        CHECK(fabs(hs / hs_ref - 1) <= tol && fine > 0.2, "%s: 3 cascades (L %.0f / %.1f / %.1f m): Hs of the sum "
              "%.4f m (mean of %d seeds; variance shares %.0f / %.0f / %.0f %%) vs spectrum over the combined "
              "band %.4f m, %+.1f%% (limit %.0f%%)", name,
              p.patch_size, ocean_cascade_patch(p.patch_size, 1), L2, hs, seeds, 100 * m0[0] / sum,
              100 * m0[1] / sum, 100 * m0[2] / sum, hs_ref, 100 * (hs / hs_ref - 1), 100 * tol);
        ocean_free(o);
    }
}

/* Cascade 0 of any cascade count is the one-cascade sea bit for bit; the
 * finer cascades are zero below their band; FFT = DFT on cascade 1; a
 * change of the cascade count equals a fresh ocean. */
static void test_cascades_structure(void)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 64;
    p.patch_size = 64;
    p.cascades = 1;
    struct ocean *one = make(&p, 1);
    p.cascades = 3;
    struct ocean *three = make(&p, 1);
    if (!one || !three)
        return;
    size_t nn = 64 * 64;
    ocean_step(one, 7.5, OCEAN_ALL_FIELDS);
    ocean_step(three, 7.5, OCEAN_ALL_FIELDS);
    int same = 1;
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        same &= memcmp(ocean_field(one, f), ocean_cascade_field(three, 0, f), nn * sizeof(float)) == 0;
    CHECK(same && ocean_cascades(one) == 1 && ocean_cascades(three) == 3 && !ocean_cascade_field(one, 1, 0) &&
          !ocean_cascade_field(three, 1, OCEAN_FOAM) && ocean_cascade_field(three, 2, OCEAN_HEIGHT),
          "cascades.zero_is_single_patch: cascade 0 of a 3-cascade sea equals the 1-cascade sea in all %d fields: %s",
          OCEAN_FIELD_COUNT, same ? "yes" : "no");

    /* Forward DFT of cascades 1, 2's heights: zero outside their bands, which
     * meet: cascade 2 starts where cascade 1 ends, in physical wavenumber. */
    double complex *F = malloc(nn * sizeof *F);
    int bands_ok = 1;
    char msg[200] = "";
    for (int c = 1; c < 3; c++) {
        forward_dft(ocean_cascade_field(three, c, OCEAN_HEIGHT), 64, F);
        int lo = ocean_cascade_band(64, c), hi = ocean_cascade_band_top(64, c);
        double out = 0, in = 0;
        for (int iz = 0; iz < 64; iz++)
            for (int ix = 0; ix < 64; ix++) {
                int mx = ix > 32 ? ix - 64 : ix, mz = iz > 32 ? iz - 64 : iz;
                int m = abs(mx) > abs(mz) ? abs(mx) : abs(mz);
                double e = creal(F[iz * 64 + ix] * conj(F[iz * 64 + ix]));
                if (m < lo || m > hi)
                    out += e;
                else
                    in += e;
            }
        bands_ok &= out <= 1e-9 * in && in > 0;
        snprintf(msg + strlen(msg), sizeof msg - strlen(msg), "%scascade %d: [%d, %d] holds %.3g, outside %.3g",
                 c > 1 ? "; " : "", c, lo, hi, in, out);
    }
    free(F);
    bands_ok &= ocean_cascade_band(64, 1) == (int)ceil(31.5 / OCEAN_CASCADE_RATIO) &&
                ocean_cascade_band(64, 2) == (int)ceil(15.5 / OCEAN_CASCADE_RATIO) &&
                ocean_cascade_band_top(64, 1) == 15 && ocean_cascade_band_top(64, 0) == 31;
    CHECK(bands_ok, "cascades.band: N = 64, max(|mx|,|mz|) per cascade: %s", msg);

    /* FFT = DFT on the finer cascades (same band, patch and seed on both paths). */
    float *fft[3];
    for (int c = 1; c < 3; c++)
        fft[c] = memcpy(malloc(nn * sizeof(float)), ocean_cascade_field(three, c, OCEAN_DX), nn * sizeof(float));
    struct ocean_params q = p;
    q.transform = TRANSFORM_DFT;
    char err[256];
    ocean_reconfigure(three, &q, err, sizeof err);
    ocean_step(three, 7.5, OCEAN_FIELD_BIT(OCEAN_DX));
    double e1 = rel_err(fft[1], ocean_cascade_field(three, 1, OCEAN_DX), nn);
    double e2 = rel_err(fft[2], ocean_cascade_field(three, 2, OCEAN_DX), nn);
    CHECK(e1 <= 1e-5 && e2 <= 1e-5, "cascades.fft_eq_dft: dx of cascades 1, 2 at N = 64: rel err %.2g, %.2g "
          "(limit 1e-5)",
          e1, e2);

    /* 3 -> 1 -> 4 (another N too) against a fresh 4-cascade ocean. */
    q = p;
    q.cascades = 1;
    int rc = ocean_reconfigure(three, &q, err, sizeof err);
    q.cascades = 4;
    q.resolution = 32;
    rc |= ocean_reconfigure(three, &q, err, sizeof err);
    struct ocean *fresh = make(&q, 1);
    int eq = fresh && rc == 0 && ocean_cascades(three) == 4;
    if (eq) {
        ocean_step(three, 3.25, OCEAN_ALL_FIELDS);
        ocean_step(fresh, 3.25, OCEAN_ALL_FIELDS);
        for (int c = 0; c < 4; c++)
            eq &= memcmp(ocean_cascade_field(three, c, OCEAN_HEIGHT), ocean_cascade_field(fresh, c, OCEAN_HEIGHT),
                         32 * 32 * sizeof(float)) == 0;
    }
    CHECK(eq, "cascades.reconfigure_equals_fresh: cascades 3 -> 1 -> 4 (N 64 -> 32): every cascade bit-identical "
          "to a fresh ocean: %s", eq ? "yes" : "no");
    ocean_free(fresh);
    free(fft[1]);
    free(fft[2]);
    ocean_free(one);
    ocean_free(three);
}


/* ocean_exchange_cascade_field (the daemon's zero-copy hand-off): the caller
 * gets the samples just stepped, and the next step writes every sample of the
 * array it was given (a partial write would leave the frame before's samples
 * in a later frame): bit-identical to a sea that never exchanged, on every
 * cascade; foam (the foam's state) and bad arguments are refused. */
static void test_exchange_field(void)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 64;
    p.patch_size = 64;
    p.cascades = 2;
    struct ocean *a = make(&p, 2), *b = make(&p, 2);
    if (!a || !b)
        return;
    const size_t nn = 64 * 64;
    float *buf[2][OCEAN_FIELD_COUNT] = {{0}};
    int ok = 1, refused = 1;
    for (int c = 0; c < 2; c++)
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
            ok &= (buf[c][f] = ocean_field_buffer_new(64)) != NULL;
            if (buf[c][f]) /* not a value any step makes: a sample left unwritten shows */
                for (size_t i = 0; i < nn; i++)
                    buf[c][f][i] = 12345.0f;
        }
    refused &= ocean_exchange_cascade_field(a, 0, OCEAN_FOAM, &buf[0][OCEAN_FOAM]) != 0;
    refused &= ocean_exchange_cascade_field(a, 2, OCEAN_HEIGHT, &buf[0][OCEAN_HEIGHT]) != 0;
    refused &= ocean_exchange_cascade_field(NULL, 0, OCEAN_HEIGHT, &buf[0][OCEAN_HEIGHT]) != 0;
    double t[3] = {1.0, 1.5, 2.25};
    for (int k = 0; ok && k < 3; k++) {
        ocean_step(a, t[k], OCEAN_ALL_FIELDS);
        ocean_step(b, t[k], OCEAN_ALL_FIELDS);
        for (int c = 0; c < 2; c++)
            for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
                const float *want = ocean_cascade_field(b, c, f);
                if (!want || f == OCEAN_FOAM)
                    continue;
                ok &= ocean_exchange_cascade_field(a, c, f, &buf[c][f]) == 0;
                ok &= memcmp(buf[c][f], want, nn * sizeof(float)) == 0;
            }
    }
    CHECK(ok && refused, "exchange.frames_same: 3 steps of 2 cascades x 5 fields taken by exchange equal a sea that "
          "copies (every sample rewritten), foam and bad arguments refused: %s", ok && refused ? "yes" : "no");
    for (int c = 0; c < 2; c++)
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
            ocean_field_buffer_free(buf[c][f]);
    ocean_free(a);
    ocean_free(b);
}

/* The VmFlags of the mapping that holds addr ("hg": MADV_HUGEPAGE asked for) and
 * the huge pages it got, from /proc/self/smaps; 0 if not found. */
static int mapping_flags(const void *addr, char *flags, size_t flags_size, long *huge_kb)
{
    FILE *f = fopen("/proc/self/smaps", "r");
    if (!f)
        return 0;
    char line[512];
    int in = 0, found = 0;
    uintptr_t a = (uintptr_t)addr;
    while (fgets(line, sizeof line, f)) {
        unsigned long lo, hi;
        if (sscanf(line, "%lx-%lx ", &lo, &hi) == 2 && strchr(line, '-') < strchr(line, ' ')) {
            in = a >= lo && a < hi;
            continue;
        }
        if (in && sscanf(line, "AnonHugePages: %ld kB", huge_kb) == 1)
            continue;
        if (in && strncmp(line, "VmFlags:", 8) == 0) {
            size_t len = strlen(line + 8);
            len = len < flags_size ? len : flags_size - 1;
            memcpy(flags, line + 8, len);
            flags[len] = '\0';
            found = 1;
            break;
        }
    }
    fclose(f);
    return found;
}

static void test_huge_pages(void)
{
    if (quick) /* N = 1024 under valgrind: minutes */
        return;
    struct ocean *o = make_default(1024);
    if (!o)
        return;
    ocean_step(o, 1.0, OCEAN_FIELD_BIT(OCEAN_HEIGHT));
    const float *h = ocean_cascade_field(o, 0, OCEAN_HEIGHT);
    float *spare = ocean_field_buffer_new(1024);
    char flags[256] = "", spare_flags[256] = "";
    long huge_kb = -1, spare_kb = -1;
    int found = mapping_flags(h, flags, sizeof flags, &huge_kb) && spare &&
                mapping_flags(spare, spare_flags, sizeof spare_flags, &spare_kb);
    int aligned = h && spare && (uintptr_t)h % (2u << 20) == 0 && (uintptr_t)spare % (2u << 20) == 0;
    /* A kernel without THP has no such file and refuses the hint: only the alignment is checked. */
    int thp = access("/sys/kernel/mm/transparent_hugepage/enabled", F_OK) == 0;
    int asked = !thp || (found && strstr(flags, " hg") && strstr(spare_flags, " hg"));
    CHECK(aligned && asked, "memory.huge_pages: a 4 MB field (N = 1024) and a spare field buffer are 2 MB aligned "
          "(%s) and asked for as huge pages (VmFlags%s hg: %s); the field got %ld kB of them (up to the kernel's "
          "THP setting and free memory)",
          aligned ? "yes" : "no", found ? "" : " not found,", asked ? "yes" : "no", huge_kb);
    ocean_field_buffer_free(spare);
    ocean_free(o);
}

/* One step of the six fields at N two ways (ocean_step_parts flags): the
 * first way's fields are returned in *first (6 N^2 floats, the caller
 * frees), the second's are left in o->g->out. NULL if out of memory. */
static struct ocean *six_fields_two_ways(int n, unsigned way_a, unsigned way_b, float **first)
{
    const unsigned six = OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM);
    struct ocean *o = make_default(n);
    size_t nn = (size_t)n * n;
    *first = o ? malloc(6 * nn * sizeof(float)) : NULL;
    if (!*first) {
        ocean_free(o);
        return NULL;
    }
    ocean_step_parts(o, 7.25, six, way_a);
    for (int f = 0; f < 6; f++)
        memcpy(*first + f * nn, o->g->out[f], nn * sizeof(float));
    ocean_step_parts(o, 7.25, six, way_b);
    return o;
}

/* The streaming stores (the z pass's copy from OCEAN_STREAM_STORE_FROM_N,
 * the row pass's output through the worker's scratch from
 * OCEAN_STREAM_OUT_FROM_N) move the same values as FFTW's copy plan and
 * FFTW's own output, which the FFT-vs-DFT tests cover at smaller N: the six
 * fields must come out bit for bit the same both ways, at N = 512 as the
 * step does (the z pass streams) and at N = 64 with both forced to. */
static void test_streaming_store(void)
{
    int sizes[2] = {64, OCEAN_STREAM_STORE_FROM_N};
    for (int i = 0; i < (quick ? 1 : 2); i++) { /* N = 512 under valgrind: a minute */
        int n = sizes[i];
        float *streamed;
        struct ocean *o = six_fields_two_ways(
            n, n >= OCEAN_STREAM_STORE_FROM_N ? 0 : OCEAN_STORE_STREAMING, OCEAN_STORE_FFTW, &streamed);
        if (!o)
            return;
        size_t nn = (size_t)n * n;
        int differ = -1;
        double hmax = 0;
        for (int f = 0; f < 6 && differ < 0; f++)
            if (memcmp(streamed + f * nn, o->g->out[f], nn * sizeof(float)) != 0)
                differ = f;
        for (size_t j = 0; j < nn; j++)
            hmax = fmax(hmax, fabs(streamed[j]));
        CHECK(differ < 0 && hmax > 0, "step.streaming_store: N = %d: the six fields with the streaming store "
              "equal those with FFTW's copy bit for bit (%s); max |height| %.3f "
              "m", n, differ < 0 ? "yes" : ocean_field_name((enum ocean_field)differ), hmax);
        free(streamed);
        ocean_free(o);
    }
}

/* The row pass's half-length split (row_pretwiddle + row_half_plan)
 * against FFTW's own real transform of the same rows (OCEAN_ROWS_C2R): the
 * six fields agree to float rounding (a few 1e-7 of the largest value;
 * a wrong twiddle, sign or fold is off by the field's own size). The
 * FFT-vs-DFT checks cover the whole step at small N besides. */
static void test_rows_half_length(void)
{
    int sizes[3] = {16, 64, 512};
    for (int i = 0; i < (quick ? 2 : 3); i++) {
        int n = sizes[i];
        float *ours;
        struct ocean *o = six_fields_two_ways(n, 0, OCEAN_ROWS_C2R, &ours);
        if (!o)
            return;
        size_t nn = (size_t)n * n;
        double worst = 0;
        int worst_f = 0;
        for (int f = 0; f < 6; f++) {
            double d = 0, m = 0;
            for (size_t j = 0; j < nn; j++) {
                d = fmax(d, fabs((double)ours[f * nn + j] - o->g->out[f][j]));
                m = fmax(m, fabs((double)o->g->out[f][j]));
            }
            if (m > 0 && d / m > worst) {
                worst = d / m;
                worst_f = f;
            }
        }
        CHECK(worst < 1e-5, "step.rows_half_length: N = %d: six fields, half-length split vs FFTW's c2r: largest "
              "difference %.2g of the field's largest value (%s; limit 1e-5)",
              n, worst, ocean_field_name((enum ocean_field)worst_f));
        free(ours);
        ocean_free(o);
    }
}

/* The work pool (server/common/pool.c) on its own: a parallel-for covers
 * every item once with distinct worker numbers, and asynchronous jobs run
 * done once, on the thread that finished the last item, after every item,
 * whether a caller helps (pool_wait) or not, back to back on one job. */
struct pool_probe {
    atomic_int hits[64];
    atomic_int busy[4];        /* per worker number: items running now */
    atomic_int overlap, done, items_at_done;
    int items;
};

static void pool_probe_item(void *arg, int i0, int i1, int worker)
{
    struct pool_probe *c = arg;
    if (worker < 0 || worker >= 4 || atomic_fetch_add(&c->busy[worker], 1) != 0)
        atomic_fetch_add(&c->overlap, 1);
    for (int i = i0; i < i1; i++)
        atomic_fetch_add(&c->hits[i], 1);
    if (worker >= 0 && worker < 4)
        atomic_fetch_sub(&c->busy[worker], 1);
}

static void pool_probe_done(void *arg)
{
    struct pool_probe *c = arg;
    int sum = 0;
    for (int i = 0; i < c->items; i++)
        sum += atomic_load(&c->hits[i]);
    atomic_store(&c->items_at_done, sum);
    atomic_fetch_add(&c->done, 1);
}

static void pool_probe_reset(struct pool_probe *c, int items)
{
    memset(c, 0, sizeof *c); /* no thread touches it between jobs */
    c->items = items;
}

static bool pool_probe_once(struct pool_probe *c)
{
    for (int i = 0; i < c->items; i++)
        if (atomic_load(&c->hits[i]) != 1)
            return false;
    return atomic_load(&c->overlap) == 0;
}

static void test_pool(void)
{
    struct pool *p = pool_new(3);
    struct pool_probe c;
    int rounds = quick ? 20 : 200, bad_for = 0, bad_async = 0, bad_done = 0;
    for (int r = 0; r < rounds && p; r++) {
        pool_probe_reset(&c, 1 + r % 64);
        pool_for(p, 4, c.items, pool_probe_item, &c);
        bad_for += !pool_probe_once(&c);
    }
    struct pool_job job = {0};
    for (int r = 0; r < rounds && p; r++) {
        pool_probe_reset(&c, 1 + r % 64);
        pool_start(p, &job, c.items, pool_probe_item, pool_probe_done, &c);
        if (r % 2)
            pool_wait(p, &job); /* helping */
        else
            while (pool_busy(p, &job))
                sched_yield(); /* not helping: the pool's threads alone */
        bad_async += !pool_probe_once(&c);
        bad_done += atomic_load(&c.done) != 1 || atomic_load(&c.items_at_done) != c.items;
    }
    CHECK(p && pool_threads(p) == 3 && !bad_for && !bad_async && !bad_done, "pool.items_once: "
          "%d rounds each: parallel-for %d bad, async %d bad (items not run exactly once or a worker number "
          "used twice at a time), done %d bad (not once, or before an item)", rounds, bad_for, bad_async, bad_done);
    pool_free(p);
    pool_probe_reset(&c, 5);
    pool_for(NULL, 4, c.items, pool_probe_item, &c);
    pool_start(NULL, &job, c.items, pool_probe_item, pool_probe_done, &c); /* no pool: on the caller */
    CHECK(atomic_load(&c.hits[4]) == 2 && atomic_load(&c.done) == 1, "pool.none: "
          "without a pool the caller runs every item (item 4 ran %d times of 2) and done (%d times of 1)",
          atomic_load(&c.hits[4]), atomic_load(&c.done));
}

int main(void)
{
    check_verbose = 1; /* the passing lines carry the measured values */
    quick = check_quick();
    only = getenv("OCEAN_TEST_ONLY");
    if (only && !*only)
        only = NULL;
    if (quick)
        printf("quick mode (OCEAN_TEST_QUICK): smaller grids, fewer seeds\n");
    RUN(test_params);
    RUN(test_spreading_and_dispersion);
    RUN(test_fft_vs_dft);
    RUN(test_layout);
    RUN(test_slopes);
    RUN(test_periodic);
    RUN(test_time_max);
    RUN(test_parseval);
    RUN(test_variance_vs_n);
    RUN(test_significant_height);
    RUN(test_depth_displacement);
    RUN(test_fetch_laws);
    RUN(test_sweep);
    RUN(test_determinism);
    RUN(test_reconfigure);
    RUN(test_prepare_commit);
    RUN(test_easing);
    RUN(test_memory_bytes);
    RUN(test_wisdom);
    RUN(test_foam);
    RUN(test_param_ui);
    RUN(test_cascades_hs);
    RUN(test_cascades_structure);
    RUN(test_exchange_field);
    RUN(test_huge_pages);
    RUN(test_streaming_store);
    RUN(test_rows_half_length);
    RUN(test_pool);
    return check_done();
}

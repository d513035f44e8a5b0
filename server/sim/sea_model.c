/* sea_model.c — a measured sea ready for the amplitudes (frequency cells,
 * directional tables in the world frame, the tail), and what a grid
 * captures of it (sea_capture). docs/simulation.md, "Measured seas". */
#include "sea_model.h"

#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ocean.h"
#include "ocean_spectrum.h"

/* The periodic piecewise-linear interpolation of E(f_i, theta_j) over the
 * document's directions, on the table's angles, then scaled to a unit
 * trapezoid sum: D_i(alpha) = E(f_i, alpha) / E(f_i). */
static void table_2d(const struct sea_spectrum *s, int i, double *d)
{
    int order[SEA_MAX_DIRECTIONS], n = s->directions;
    for (int j = 0; j < n; j++)
        order[j] = j;
    for (int j = 1; j < n; j++) /* insertion sort by direction: at most 72 */
        for (int q = j; q > 0 && s->direction[order[q - 1]] > s->direction[order[q]]; q--) {
            int t = order[q];
            order[q] = order[q - 1];
            order[q - 1] = t;
        }
    int next = 0; /* first sorted direction above the table angle */
    for (int t = 0; t < SEA_TABLE; t++) {
        double a = 360.0 * t / SEA_TABLE;
        while (next < n && s->direction[order[next]] <= a)
            next++;
        int hi = order[next % n], lo = order[(next + n - 1) % n];
        double alo = s->direction[lo], ahi = s->direction[hi];
        double span = fmod(ahi - alo + 720, 360), off = fmod(a - alo + 720, 360);
        if (n == 1 || span <= 0)
            d[t] = s->energy2d[i][lo];
        else
            d[t] = s->energy2d[i][lo] + (s->energy2d[i][hi] - s->energy2d[i][lo]) * (off / span);
    }
    double sum = 0;
    for (int t = 0; t < SEA_TABLE; t++)
        sum += d[t];
    for (int t = 0; t < SEA_TABLE; t++) /* a band with no energy: any D, it carries nothing */
        d[t] = sum > 0 ? d[t] * SEA_TABLE / (2 * M_PI * sum) : 1 / (2 * M_PI);
}

struct sea_model *sea_model_new(const struct sea_spectrum *s)
{
    struct sea_model *m = calloc(1, sizeof *m);
    double *d = malloc(SEA_TABLE * sizeof *d);
    if (!m || !d) {
        free(m);
        free(d);
        return NULL;
    }
    m->doc = *s;
    m->bands = s->bands;
    m->tail = s->tail;
    const int nb = s->bands;
    for (int i = 0; i < nb; i++) {
        m->lo[i] = i == 0 ? s->frequency[0] - 0.5 * s->bandwidth[0] : m->hi[i - 1];
        m->hi[i] = i == nb - 1 ? s->frequency[i] + 0.5 * s->bandwidth[i]
                               : 0.5 * (s->frequency[i] + s->frequency[i + 1]);
        double e, coef[4];
        sea_spectrum_band(s, i, &e, coef);
        m->density[i] = e * s->bandwidth[i] / (m->hi[i] - m->lo[i]);
        if (s->form == SEA_FORM_MOMENTS)
            sea_directional_distribution(s->directional, coef[0], coef[1], coef[2], coef[3], d, SEA_TABLE);
        else
            table_2d(s, i, d);
        for (int t = 0; t < SEA_TABLE; t++)
            m->dir[i][t] = (float)d[t];
        m->dir[i][SEA_TABLE] = m->dir[i][0];
    }
    free(d);
    return m;
}

void sea_model_free(struct sea_model *m) { free(m); }

double sea_model_frequency(const struct sea_model *m, double f, int *band)
{
    *band = SEA_BAND_NONE;
    if (!(f >= m->lo[0]))
        return 0;
    const int last = m->bands - 1;
    if (f >= m->hi[last]) {
        double x = f / m->hi[last];
        switch (m->tail) {
        case SEA_TAIL_F4: *band = m->bands; return m->density[last] / (x * x * x * x);
        case SEA_TAIL_F5: *band = m->bands; return m->density[last] / (x * x * x * x * x);
        case SEA_TAIL_WIND: *band = SEA_BAND_WIND; return 0;
        default: return 0;
        }
    }
    int a = 0, b = last; /* the last cell with lo <= f */
    while (a < b) {
        int c = (a + b + 1) / 2;
        if (m->lo[c] <= f)
            a = c;
        else
            b = c - 1;
    }
    *band = a;
    return m->density[a];
}

double sea_model_direction(const struct sea_model *m, int band, double kx, double kz)
{
    if (band < 0)
        return 0;
    if (band >= m->bands)
        band = m->bands - 1;
    /* Travelling toward world angle phi = atan2(kz, kx), the wave comes
     * from compass bearing phi + 90 deg: (sin b, -cos b) = (cos phi, sin phi). */
    double u = (atan2(kz, kx) / (2 * M_PI) + 0.25) * SEA_TABLE;
    u = fmod(u + 2.0 * SEA_TABLE, SEA_TABLE);
    int j = (int)u;
    if (j >= SEA_TABLE) /* rounding at the wrap */
        j = SEA_TABLE - 1;
    double w = u - j;
    const float *t = m->dir[band];
    return t[j] + w * (t[j + 1] - t[j]);
}

double sea_wavenumber(double w, double depth)
{
    if (!(w > 0))
        return 0;
    const double g = OCEAN_G;
    double k = w * w / g;
    if (depth > 0 && isfinite(depth))
        k /= sqrt(tanh(k * depth)); /* a start above the root: Newton then falls onto it */
    for (int it = 0; it < 50; it++) {
        double th = tanh(k * depth), ch = cosh(k * depth);
        double f = g * k * th - w * w, fp = g * th + (isinf(ch) ? 0 : g * k * depth / (ch * ch));
        double step = f / fp;
        k -= step;
        if (fabs(step) < 1e-14 * k)
            break;
    }
    return k;
}

/* Source energy over [fa, fb) of the cells (exact: piecewise constant). */
static double cells_energy(const struct sea_model *m, double fa, double fb)
{
    double e = 0;
    for (int i = 0; i < m->bands; i++) {
        double a = fmax(fa, m->lo[i]), b = fmin(fb, m->hi[i]);
        if (b > a)
            e += m->density[i] * (b - a);
    }
    return e;
}

/* The frequency below which the cells hold `target` m^2. */
static double cells_quantile(const struct sea_model *m, double target)
{
    double e = 0;
    for (int i = 0; i < m->bands; i++) {
        double ei = m->density[i] * (m->hi[i] - m->lo[i]);
        if (e + ei >= target && ei > 0)
            return m->lo[i] + (target - e) / m->density[i];
        e += ei;
    }
    return m->hi[m->bands - 1];
}

static double freq_of_k(double k, double depth)
{
    return dispersion_omega(k, depth) / (2 * M_PI);
}

/* The Riemann sums of Psi dk^2 over one cascade's modes, as the amplitude
 * pass makes them (ocean_amplitudes.c): the source's part and the tail's. */
static void grid_sums(const struct spectrum_model *m, int n, double *source, double *tail)
{
    const double dk = 2 * M_PI / m->patch, cell = dk * dk;
    const struct sea_model *sea = m->sea;
    for (int iz = 0; iz < n; iz++) {
        if (iz == n / 2)
            continue; /* the Nyquist row and column are zero */
        int mz = iz > n / 2 ? iz - n : iz;
        for (int ix = 0; ix < n; ix++) {
            int mx = ix > n / 2 ? ix - n : ix;
            if (ix == n / 2 || (mx == 0 && mz == 0) || !spectrum_in_band(m, mx, mz))
                continue;
            double psi = spectrum_directional(m, mx * dk, mz * dk) * cell;
            int band;
            sea_model_frequency(sea, freq_of_k(hypot(mx, mz) * dk, m->depth), &band);
            if (band >= 0 && band < sea->bands)
                *source += psi;
            else
                *tail += psi;
        }
    }
}

enum sea_error sea_capture(const struct sea_spectrum *s, const struct ocean_params *p, struct sea_capture *out,
                           char *err, size_t errlen)
{
    enum sea_error e = sea_spectrum_check(s, err, errlen);
    if (e != SEA_OK)
        return e;
    if (!p || !out) {
        snprintf(err, errlen, "sea: no parameters or no report");
        return SEA_ERR_FORM;
    }
    struct ocean_params q = *p;
    q.spectrum = SPECTRUM_MEASURED;
    q.amplitude = 1; /* the fit, not the user's scale */
    if (params_validate_sea(&q, true, err, errlen) != 0)
        return SEA_ERR_PARAMS;
    struct sea_model *model = sea_model_new(s);
    if (!model) {
        snprintf(err, errlen, "sea: out of memory");
        return SEA_ERR_MEMORY;
    }
    const int cascades = q.cascades;
    struct sea_capture c;
    memset(&c, 0, sizeof c);
    c.m0_source = sea_spectrum_m0(s);
    double top_k = 0;
    for (int k = 0; k < cascades; k++) {
        struct spectrum_model m;
        spectrum_model_cascade(&m, &q, k);
        m.sea = model;
        grid_sums(&m, q.resolution, &c.m0_grid, &c.m0_tail);
        top_k = ocean_cascade_band_top(q.resolution, k) * 2 * M_PI / m.patch;
    }
    const double dk = 2 * M_PI / q.patch_size, D = q.depth;
    c.m0_long = cells_energy(model, 0, freq_of_k(dk, D));
    c.m0_coarse = cells_energy(model, 0, freq_of_k(4 * dk, D));
    c.m0_short = cells_energy(model, freq_of_k(top_k, D), INFINITY);
    c.share = c.m0_source > 0 ? c.m0_grid / c.m0_source : 1;
    c.hs_source = 4 * sqrt(c.m0_source);
    c.hs_grid = 4 * sqrt(c.m0_grid + c.m0_tail);
    c.peak_band = sea_spectrum_peak_band(s);
    if (c.peak_band >= 0) {
        double en, coef[4];
        sea_spectrum_band(s, c.peak_band, &en, coef);
        c.peak_frequency = s->frequency[c.peak_band];
        c.peak_wavelength = 2 * M_PI / sea_wavenumber(2 * M_PI * c.peak_frequency, D);
        c.peak_direction = sea_mean_direction(coef[0], coef[1]);
        c.peak_spread = sea_kuik_spread(coef[0], coef[1]);
    }
    /* A patch that fits: at most 1 % of m0 in waves longer than L / 4. */
    double f1 = cells_quantile(model, 0.01 * c.m0_source);
    double need = f1 > 0 ? 4 * 2 * M_PI / sea_wavenumber(2 * M_PI * f1, D) : 0;
    need = fmin(10000, ceil(need / 10) * 10);
    /* A share above 1: a band narrower than the grid's rings, sampled where it peaks. */
    c.fits = c.share >= 0.9 && c.share <= 1.1 && c.m0_coarse <= 0.05 * c.m0_source;
    c.suggested_patch = c.fits || need <= q.patch_size ? 0 : need;
    if (!c.fits) {
        double pct = c.m0_source > 0 ? 100 / c.m0_source : 0;
        int w = snprintf(c.warning, sizeof c.warning,
                         "the %.0f m patch, N = %d, holds %.0f %% of the sea's m0 (%.0f %% in waves longer than "
                         "L / 4, %.0f %% longer than L, %.0f %% shorter than the grid's finest)",
                         q.patch_size, q.resolution, 100 * c.share, pct * c.m0_coarse, pct * c.m0_long,
                         pct * c.m0_short);
        if (c.suggested_patch > 0 && w > 0 && (size_t)w < sizeof c.warning)
            snprintf(c.warning + w, sizeof c.warning - (size_t)w,
                     "; a patch of %.0f m fits the long swell (peak %.1f s, %.0f m)", c.suggested_patch,
                     c.peak_frequency > 0 ? 1 / c.peak_frequency : 0, c.peak_wavelength);
    }
    sea_model_free(model);
    *out = c;
    return SEA_OK;
}

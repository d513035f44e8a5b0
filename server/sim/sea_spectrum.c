/* sea_spectrum.c — a measured sea's document: the strict check, its
 * energies, and the directional distribution D(alpha) of a band's moments
 * (Longuet-Higgins et al. 1963, clipped or weighted; Lygre & Krogstad 1986's
 * maximum entropy). Pure functions; docs/simulation.md, "Measured seas". */
#include "sea_spectrum.h"

#include <complex.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static const char *const error_names[] = {
    "ok", "sea_form", "sea_size", "sea_text", "sea_not_finite", "sea_frequency", "sea_order",
    "sea_bandwidth", "sea_negative", "sea_coefficient", "sea_direction", "sea_duplicate", "sea_energy",
    "sea_depth", "sea_memory", "sea_params",
};
_Static_assert(sizeof error_names / sizeof error_names[0] == SEA_ERR_PARAMS + 1, "a name per sea_error");

const char *sea_error_name(enum sea_error e)
{
    return (unsigned)e <= SEA_ERR_PARAMS ? error_names[e] : "sea_unknown";
}

void sea_spectrum_init(struct sea_spectrum *s, enum sea_form form)
{
    memset(s, 0, sizeof *s);
    s->form = form;
    s->tail = SEA_TAIL_F4;
    s->directional = SEA_DIR_MEM;
}

/* NUL within the buffer and every byte printable ASCII. */
static bool text_ok(const char *t, size_t len)
{
    const char *end = memchr(t, 0, len);
    if (!end)
        return false;
    for (const char *c = t; c < end; c++)
        if (*c < 0x20 || *c > 0x7e)
            return false;
    return true;
}

/* A band's place in a message: "band 3 (0.048 Hz)". */
static void band_name(const struct sea_spectrum *s, int i, char *buf, size_t len)
{
    if (isfinite(s->frequency[i]))
        snprintf(buf, len, "band %d (%.4g Hz)", i, s->frequency[i]);
    else
        snprintf(buf, len, "band %d", i);
}

static enum sea_error fail(enum sea_error e, char *err, size_t errlen, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static enum sea_error fail(enum sea_error e, char *err, size_t errlen, const char *fmt, ...)
{
    if (err && errlen) {
        int n = snprintf(err, errlen, "sea: ");
        va_list ap;
        va_start(ap, fmt);
        if (n >= 0 && (size_t)n < errlen)
            vsnprintf(err + n, errlen - (size_t)n, fmt, ap);
        va_end(ap);
    }
    return e;
}

static enum sea_error check_bands(const struct sea_spectrum *s, char *err, size_t errlen)
{
    char b[48];
    for (int i = 0; i < s->bands; i++) {
        double f = s->frequency[i], w = s->bandwidth[i];
        band_name(s, i, b, sizeof b);
        if (!isfinite(f))
            return fail(SEA_ERR_NOT_FINITE, err, errlen, "frequency[%d] is not a finite number", i);
        if (!(f > 0 && f <= SEA_FREQUENCY_MAX))
            return fail(SEA_ERR_FREQUENCY, err, errlen, "frequency[%d] = %g Hz is outside (0, %g] Hz", i, f,
                        SEA_FREQUENCY_MAX);
        if (i > 0 && !(f > s->frequency[i - 1]))
            return fail(SEA_ERR_ORDER, err, errlen,
                        "frequency[%d] = %g Hz does not follow frequency[%d] = %g Hz: bands must be strictly "
                        "increasing", i, f, i - 1, s->frequency[i - 1]);
        if (!isfinite(w))
            return fail(SEA_ERR_NOT_FINITE, err, errlen, "bandwidth[%d] (%s) is not a finite number", i, b);
        if (!(w > 0 && w <= 2 * f))
            return fail(SEA_ERR_BANDWIDTH, err, errlen,
                        "bandwidth[%d] = %g Hz (%s) must be > 0 and at most twice the centre", i, w, b);
    }
    return SEA_OK;
}

static enum sea_error check_moments(const struct sea_spectrum *s, char *err, size_t errlen)
{
    static const char *const names[4] = {"a1", "b1", "a2", "b2"};
    char b[48];
    for (int i = 0; i < s->bands; i++) {
        band_name(s, i, b, sizeof b);
        if (!isfinite(s->energy[i]))
            return fail(SEA_ERR_NOT_FINITE, err, errlen, "energy[%d] (%s) is not a finite number", i, b);
        if (s->energy[i] < 0)
            return fail(SEA_ERR_NEGATIVE, err, errlen, "energy[%d] = %g m^2/Hz (%s) is negative", i,
                        s->energy[i], b);
        const double c[4] = {s->a1[i], s->b1[i], s->a2[i], s->b2[i]};
        for (int k = 0; k < 4; k++) {
            if (!isfinite(c[k]))
                return fail(SEA_ERR_NOT_FINITE, err, errlen, "%s[%d] (%s) is not a finite number", names[k], i, b);
            if (fabs(c[k]) > 1)
                return fail(SEA_ERR_COEFFICIENT, err, errlen, "%s[%d] = %g (%s): |%s| must be <= 1", names[k], i,
                            c[k], b, names[k]);
        }
    }
    return SEA_OK;
}

static enum sea_error check_2d(const struct sea_spectrum *s, char *err, size_t errlen)
{
    for (int j = 0; j < s->directions; j++) {
        double d = s->direction[j];
        if (!isfinite(d))
            return fail(SEA_ERR_NOT_FINITE, err, errlen, "direction[%d] is not a finite number", j);
        if (!(d >= 0 && d < 360))
            return fail(SEA_ERR_DIRECTION, err, errlen, "direction[%d] = %g deg is outside [0, 360)", j, d);
        for (int q = 0; q < j; q++)
            if (s->direction[q] == d)
                return fail(SEA_ERR_DUPLICATE, err, errlen, "direction[%d] = %g deg repeats direction[%d]", j, d, q);
    }
    char b[48];
    for (int i = 0; i < s->bands; i++) {
        band_name(s, i, b, sizeof b);
        for (int j = 0; j < s->directions; j++) {
            double e = s->energy2d[i][j];
            if (!isfinite(e))
                return fail(SEA_ERR_NOT_FINITE, err, errlen,
                            "energy[%d][%d] (%s; direction %d, %g deg) is not a finite number", i, j, b, j,
                            s->direction[j]);
            if (e < 0)
                return fail(SEA_ERR_NEGATIVE, err, errlen,
                            "energy[%d][%d] = %g m^2/(Hz rad) (%s; direction %d, %g deg) is negative", i, j, e, b,
                            j, s->direction[j]);
        }
    }
    return SEA_OK;
}

enum sea_error sea_spectrum_check(const struct sea_spectrum *s, char *err, size_t errlen)
{
    if (err && errlen)
        err[0] = 0;
    if (!s)
        return fail(SEA_ERR_FORM, err, errlen, "no sea");
    if (s->form != SEA_FORM_MOMENTS && s->form != SEA_FORM_SPECTRUM2D)
        return fail(SEA_ERR_FORM, err, errlen, "form %d is neither moments nor spectrum2d", (int)s->form);
    if ((unsigned)s->tail >= SEA_TAIL_COUNT)
        return fail(SEA_ERR_FORM, err, errlen, "tail %d is not one of f-4, f-5, none, wind", (int)s->tail);
    if ((unsigned)s->directional >= SEA_DIR_COUNT)
        return fail(SEA_ERR_FORM, err, errlen, "directional %d is not one of mem, lh, lh_weighted",
                    (int)s->directional);
    if (s->bands < 1 || s->bands > SEA_MAX_BANDS)
        return fail(SEA_ERR_SIZE, err, errlen, "%d frequencies: 1 to %d allowed", s->bands, SEA_MAX_BANDS);
    if (s->form == SEA_FORM_SPECTRUM2D && (s->directions < 1 || s->directions > SEA_MAX_DIRECTIONS))
        return fail(SEA_ERR_SIZE, err, errlen, "%d directions: 1 to %d allowed", s->directions,
                    SEA_MAX_DIRECTIONS);
    if (!text_ok(s->source, sizeof s->source))
        return fail(SEA_ERR_TEXT, err, errlen, "source must be printable text of at most %d bytes",
                    SEA_SOURCE_LEN - 1);
    if (!text_ok(s->time, sizeof s->time))
        return fail(SEA_ERR_TEXT, err, errlen, "time must be printable text of at most %d bytes", SEA_TIME_LEN - 1);
    if (!isfinite(s->depth))
        return fail(SEA_ERR_NOT_FINITE, err, errlen, "depth is not a finite number");
    if (s->depth != 0 && !(s->depth >= 0.5 && s->depth <= SEA_DEPTH_MAX))
        return fail(SEA_ERR_DEPTH, err, errlen, "depth %g m: 0 (unknown) or 0.5 to %g m", s->depth, SEA_DEPTH_MAX);
    enum sea_error e = check_bands(s, err, errlen);
    if (e == SEA_OK)
        e = s->form == SEA_FORM_MOMENTS ? check_moments(s, err, errlen) : check_2d(s, err, errlen);
    if (e != SEA_OK)
        return e;
    double m0 = sea_spectrum_m0(s);
    if (!(m0 <= SEA_M0_MAX)) /* also inf: each term is finite, the sum may not be */
        return fail(SEA_ERR_ENERGY, err, errlen, "total energy m0 = %g m^2 (Hs %.3g m) is above the cap of %g m^2 "
                    "(Hs 40 m)", m0, 4 * sqrt(m0), SEA_M0_MAX);
    return SEA_OK;
}

/* dtheta (radians) of each direction: half the arc to its two neighbours
 * on the circle (the trapezoid weights of a periodic piecewise-linear D). */
static void direction_weights(const struct sea_spectrum *s, double *w)
{
    const int n = s->directions;
    for (int j = 0; j < n; j++) {
        if (n == 1) {
            w[j] = 2 * M_PI;
            continue;
        }
        double d = s->direction[j], up = 360, down = 360; /* arcs to the next direction either way */
        for (int q = 0; q < n; q++) {
            if (q == j)
                continue;
            double a = fmod(s->direction[q] - d + 720, 360), b = 360 - a;
            if (a > 0 && a < up)
                up = a;
            if (b > 0 && b < down)
                down = b;
        }
        w[j] = 0.5 * (up + down) * M_PI / 180;
    }
}

void sea_spectrum_band(const struct sea_spectrum *s, int i, double *energy, double coef[4])
{
    if (s->form == SEA_FORM_MOMENTS) {
        *energy = s->energy[i];
        coef[0] = s->a1[i];
        coef[1] = s->b1[i];
        coef[2] = s->a2[i];
        coef[3] = s->b2[i];
        return;
    }
    double w[SEA_MAX_DIRECTIONS], e = 0, c[4] = {0, 0, 0, 0};
    direction_weights(s, w);
    for (int j = 0; j < s->directions; j++) {
        double a = s->direction[j] * M_PI / 180, ew = s->energy2d[i][j] * w[j];
        e += ew;
        c[0] += ew * cos(a);
        c[1] += ew * sin(a);
        c[2] += ew * cos(2 * a);
        c[3] += ew * sin(2 * a);
    }
    *energy = e;
    for (int k = 0; k < 4; k++)
        coef[k] = e > 0 ? c[k] / e : 0;
}

double sea_spectrum_m0(const struct sea_spectrum *s)
{
    double m0 = 0, c[4];
    for (int i = 0; i < s->bands; i++) {
        double e;
        sea_spectrum_band(s, i, &e, c);
        m0 += e * s->bandwidth[i];
    }
    return m0;
}

int sea_spectrum_peak_band(const struct sea_spectrum *s)
{
    int best = -1;
    double top = 0, c[4];
    for (int i = 0; i < s->bands; i++) {
        double e;
        sea_spectrum_band(s, i, &e, c);
        if (e > top) {
            top = e;
            best = i;
        }
    }
    return best;
}

double sea_mean_direction(double a1, double b1)
{
    double d = atan2(b1, a1) * 180 / M_PI;
    return d < 0 ? d + 360 : d;
}

double sea_kuik_spread(double a1, double b1)
{
    double r1 = hypot(a1, b1);
    return sqrt(2 * fmax(0, 1 - r1)) * 180 / M_PI;
}

/* Clip at zero and scale so that the trapezoid sum over the circle is 1. */
static void clip_normalise(double *d, int count)
{
    double sum = 0;
    for (int j = 0; j < count; j++) {
        if (!(d[j] > 0))
            d[j] = 0;
        sum += d[j];
    }
    double scale = sum > 0 ? count / (2 * M_PI * sum) : 0;
    for (int j = 0; j < count; j++)
        d[j] = sum > 0 ? d[j] * scale : 1 / (2 * M_PI);
}

int sea_directional_distribution(enum sea_directional method, double a1, double b1, double a2, double b2,
                                 double *d, int count)
{
    if (!d || count < 8 || (unsigned)method >= SEA_DIR_COUNT)
        return -1;
    /* A distribution has r1, r2 <= 1, and = 1 only for a single direction;
     * MEM divides by 1 - r1^2. */
    const double rmax = 1 - 1e-6;
    double r1 = hypot(a1, b1), r2 = hypot(a2, b2);
    if (r1 > rmax) {
        a1 *= rmax / r1;
        b1 *= rmax / r1;
    }
    if (r2 > rmax) {
        a2 *= rmax / r2;
        b2 *= rmax / r2;
    }
    if (method == SEA_DIR_MEM) {
        /* Lygre & Krogstad 1986, eqs. 11-13, with both exponentials of eq. 13
         * negative (the paper prints them positive: CDIP's note). */
        double complex c1 = a1 + I * b1, c2 = a2 + I * b2;
        double complex p1 = (c1 - c2 * conj(c1)) / (1 - creal(c1 * conj(c1)));
        double complex p2 = c2 - c1 * p1;
        for (int j = 0; j < count; j++) {
            double a = 2 * M_PI * j / count;
            double complex e1 = cexp(-I * a), e2 = cexp(-2 * I * a);
            double den = cabs(1 - p1 * e1 - p2 * e2);
            d[j] = 1 / fmax(den * den, 1e-300);
        }
    } else {
        double w1 = method == SEA_DIR_LH_WEIGHTED ? 2.0 / 3 : 1, w2 = method == SEA_DIR_LH_WEIGHTED ? 1.0 / 6 : 1;
        for (int j = 0; j < count; j++) {
            double a = 2 * M_PI * j / count;
            d[j] = (0.5 + w1 * (a1 * cos(a) + b1 * sin(a)) + w2 * (a2 * cos(2 * a) + b2 * sin(2 * a))) / M_PI;
        }
    }
    clip_normalise(d, count);
    return 0;
}

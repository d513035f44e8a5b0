/* sea_fixture.h — a known sea written as a sea document (sea_spectrum.h):
 * a JONSWAP wind sea plus a JONSWAP swell, each with a cos^2s(theta/2)
 * spreading about its own direction, on an NDBC-like band grid. For the
 * library's tests (tests/test_sea.c) and for fixture generators of the
 * readers (NDBC, WAVEWATCH III files of the same sea): header only, static
 * functions, no state.
 *
 * Per band i at centre f: E(f) = S_w(f) + S_s(f), the JONSWAP shape
 * S(f) ~ f^-5 exp(-5/4 (fp/f)^4) gamma^exp(-(f - fp)^2 / (2 sigma^2 fp^2))
 * (Hasselmann et al. 1973; sigma 0.07 / 0.09), each scaled to its Hs on a
 * fine grid. The coefficients of cos^2s about a mean "from" direction a0
 * are r1 = s / (s + 1), r2 = s (s - 1) / ((s + 1)(s + 2)) (Longuet-Higgins
 * et al. 1963), a1 = r1 cos a0, b1 = r1 sin a0, a2 = r2 cos 2 a0,
 * b2 = r2 sin 2 a0, mixed by energy. The 2-D form samples
 * E_w(f) D_w(theta) + E_s(f) D_s(theta) with each D normalised over the
 * sampled directions (so both forms have the same m0). */
#ifndef OCEAND_TESTS_SEA_FIXTURE_H
#define OCEAND_TESTS_SEA_FIXTURE_H

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "sea_spectrum.h"

struct sea_fixture {
    double hs, tp, gamma, from, s;    /* one component: m, s, -, compass deg (from), cos^2s exponent */
};
struct sea_fixture_sea {
    struct sea_fixture wind, swell;
};

/* Wind sea Hs 2 m, Tp 8 s from 225 deg (south-west), s = 8 (Kuik spread 27 deg);
 * swell Hs 1 m, Tp 13 s from 280 deg, gamma 5, s = 40 (13 deg). */
static const struct sea_fixture_sea sea_fixture_default = {
    {2.0, 8.0, 3.3, 225.0, 8.0},
    {1.0, 13.0, 5.0, 280.0, 40.0},
};

/* The unscaled JONSWAP shape at f Hz. */
static inline double sea_fixture_shape(const struct sea_fixture *c, double f)
{
    if (!(f > 0) || !(c->hs > 0))
        return 0;
    double fp = 1 / c->tp, r = fp / f, sig = f <= fp ? 0.07 : 0.09, d = (f - fp) / (sig * fp);
    return pow(f, -5) * exp(-1.25 * r * r * r * r) * pow(c->gamma, exp(-0.5 * d * d));
}

/* The factor that makes the shape's integral (0.005 .. 5 Hz, midpoints on
 * a log grid of 20000 steps) (Hs/4)^2: S(f) = scale * shape(f), m^2/Hz. */
static inline double sea_fixture_scale(const struct sea_fixture *c)
{
    if (!(c->hs > 0))
        return 0;
    const int steps = 20000;
    const double a = log(0.005), b = log(5.0), h = (b - a) / steps;
    double m0 = 0;
    for (int i = 0; i < steps; i++) {
        double f = exp(a + (i + 0.5) * h);
        m0 += sea_fixture_shape(c, f) * f * h; /* df = f dlog f */
    }
    return (c->hs * c->hs / 16) / m0;
}

/* NDBC-like bands: 0.0325 .. 0.0975 Hz by 0.005, 0.105 .. 0.345 by 0.01,
 * 0.36 .. 0.48 by 0.02 (46 bands, contiguous). Returns the count. */
static inline int sea_fixture_bands(double *f, double *bw)
{
    int n = 0;
    for (int i = 0; i < 14; i++, n++)
        f[n] = 0.0325 + 0.005 * i, bw[n] = 0.005;
    for (int i = 0; i < 25; i++, n++)
        f[n] = 0.105 + 0.01 * i, bw[n] = 0.01;
    for (int i = 0; i < 7; i++, n++)
        f[n] = 0.36 + 0.02 * i, bw[n] = 0.02;
    return n;
}

/* cos^2s((theta - a0)/2) at compass theta (deg), unnormalised. */
static inline double sea_fixture_spread(const struct sea_fixture *c, double theta)
{
    double h = 0.5 * (1 + cos((theta - c->from) * M_PI / 180));
    return pow(h > 0 ? h : 0, c->s);
}

/* Fill s with the sea in `form` (spectrum2d: `ndir` directions 0, 360/ndir, ...). */
static inline void sea_fixture_fill(struct sea_spectrum *s, const struct sea_fixture_sea *sea, enum sea_form form,
                                    int ndir)
{
    sea_spectrum_init(s, form);
    snprintf(s->source, sizeof s->source, "fixture JONSWAP + swell");
    snprintf(s->time, sizeof s->time, "2026-12-01T20:40:00Z");
    s->bands = sea_fixture_bands(s->frequency, s->bandwidth);
    const struct sea_fixture *c[2] = {&sea->wind, &sea->swell};
    double norm[2] = {0, 0}, scale[2] = {sea_fixture_scale(c[0]), sea_fixture_scale(c[1])};
    if (form == SEA_FORM_SPECTRUM2D) {
        s->directions = ndir;
        for (int j = 0; j < ndir; j++)
            s->direction[j] = 360.0 * j / ndir;
        for (int k = 0; k < 2; k++) {
            for (int j = 0; j < ndir; j++)
                norm[k] += sea_fixture_spread(c[k], s->direction[j]);
            norm[k] *= 2 * M_PI / ndir;
        }
    }
    for (int i = 0; i < s->bands; i++) {
        double e[2], sum = 0, a1 = 0, b1 = 0, a2 = 0, b2 = 0;
        for (int k = 0; k < 2; k++) {
            e[k] = scale[k] * sea_fixture_shape(c[k], s->frequency[i]);
            sum += e[k];
        }
        if (form == SEA_FORM_SPECTRUM2D) {
            for (int j = 0; j < ndir; j++) {
                double v = 0;
                for (int k = 0; k < 2; k++)
                    v += norm[k] > 0 ? e[k] * sea_fixture_spread(c[k], s->direction[j]) / norm[k] : 0;
                s->energy2d[i][j] = v;
            }
            continue;
        }
        for (int k = 0; k < 2; k++) {
            double sk = c[k]->s, r1 = sk / (sk + 1), r2 = sk * (sk - 1) / ((sk + 1) * (sk + 2));
            double a = c[k]->from * M_PI / 180, w = sum > 0 ? e[k] / sum : 0;
            a1 += w * r1 * cos(a);
            b1 += w * r1 * sin(a);
            a2 += w * r2 * cos(2 * a);
            b2 += w * r2 * sin(2 * a);
        }
        s->energy[i] = sum;
        s->a1[i] = a1;
        s->b1[i] = b1;
        s->a2[i] = a2;
        s->b2[i] = b2;
    }
}

#endif

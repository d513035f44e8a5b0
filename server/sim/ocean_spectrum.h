/* ocean_spectrum.h — the physics of the initial sea, in double precision.
 *
 * Dispersion, frequency spectra (Phillips, Pierson-Moskowitz, JONSWAP, TMA),
 * directional spreading, and the random amplitudes h~0(k). Pure functions
 * of the parameters; no FFT, no allocation. References in docs/simulation.md. */
#ifndef OCEAND_OCEAN_SPECTRUM_H
#define OCEAND_OCEAN_SPECTRUM_H

#include <complex.h>
#include <stdbool.h>
#include <stdint.h>

#include "params.h"

#define OCEAN_G 9.81 /* m/s^2 */

struct sea_model; /* sea_model.h: a measured sea ready for the amplitudes */

/* Constants derived once from the parameters. */
struct spectrum_model {
    int kind;              /* enum spectrum_kind */
    bool calm;             /* no wind: every amplitude is zero */
    double wind_speed;     /* U10, m/s */
    double wind_angle;     /* radians, direction the wind blows toward */
    double amplitude;      /* multiplier of the spectrum */
    double depth;          /* m */
    double alpha;          /* Phillips / PM / JONSWAP energy scale */
    double omega_p;        /* peak angular frequency, rad/s */
    double gamma;          /* JONSWAP peak enhancement */
    double blend;          /* directional_spread: 0 = cos^2, 1 = Mitsuyasu-Hasselmann */
    double swell;          /* 0..1 */
    double cutoff;         /* small_wave_cutoff, m (wavelength) */
    double loop_omega;     /* 2 pi / loop_period, 0 = no loop */
    double patch;          /* L, m (of this cascade) */
    uint32_t seed;         /* of this cascade */
    int band, band_top;    /* cascade >= 1: only modes with band <= max(|mx|, |mz|) <= band_top are
                            * non-zero (ocean_cascade_band); cascade 0: 0, INT_MAX (all) */
    const struct sea_model *sea; /* SPECTRUM_MEASURED: the sea in force (immutable, owned by the ocean
                                  * or the prepared change); NULL for the parametric spectra */
};

void spectrum_model_init(struct spectrum_model *m, const struct ocean_params *p);
/* The model of cascade c: p's, with the cascade's patch, seed and band. */
void spectrum_model_cascade(struct spectrum_model *m, const struct ocean_params *p, int cascade);
/* The random seed of cascade c (the seed itself for c = 0). */
uint32_t spectrum_cascade_seed(uint32_t seed, int cascade);
/* Whether integer wavenumber (mx, mz) lies in the model's band. */
static inline bool spectrum_in_band(const struct spectrum_model *m, int mx, int mz)
{
    int ax = mx < 0 ? -mx : mx, az = mz < 0 ? -mz : mz;
    int a = ax > az ? ax : az;
    return a >= m->band && a <= m->band_top;
}

/* Finite-depth dispersion w = sqrt(g k tanh(k d)) and its derivative. */
double dispersion_omega(double k, double depth);
double dispersion_domega_dk(double k, double depth);

/* One-sided frequency spectrum S(w), m^2 s (PM, JONSWAP, TMA; Phillips is
 * defined in wavenumber, see spectrum_omni_k). Without amplitude/cutoff. */
double spectrum_frequency(const struct spectrum_model *m, double omega);
/* Omnidirectional wavenumber spectrum F(k) = S(w) dw/dk, m^3, without
 * amplitude and cutoff. Integral of F over k = height variance. */
double spectrum_omni_k(const struct spectrum_model *m, double k);
/* Directional spreading D(w, theta), theta relative to the wind, radians;
 * integral over theta in (-pi, pi] is 1 for every w. */
double spectrum_spreading(const struct spectrum_model *m, double omega, double theta);
/* Directional wavenumber spectrum Psi(kx, kz), m^4: the height variance is
 * the integral of Psi over the plane. Includes amplitude and cutoff. */
double spectrum_directional(const struct spectrum_model *m, double kx, double kz);

/* Psi(k) split for the fast amplitude path (for SPECTRUM_MEASURED the angle
 * part is sea_model_direction of r->band, except in the wind tail) (ocean_amplitudes.c): everything but the
 * spreading's angle depends on |k| alone, so it is evaluated once per
 * distinct |k| ("ring") instead of twice per mode:
 *   Psi(kx, kz) = psi_k * spectrum_spreading_cos(m, r, cos theta). */
struct spectrum_radial {
    double psi_k;   /* amplitude * F(k) / k * cutoff damping, m^4 */
    double s, q;    /* Mitsuyasu exponent s(w) and normaliser Q(s) (0 when unused) */
    double omega;   /* spectrum_mode_omega(k) */
    double disp;    /* displacement_over_k(k) */
    int band;       /* SPECTRUM_MEASURED: the sea's part at this |k| (sea_model.h: a band, the
                     * power tail, SEA_BAND_WIND: the parametric terms above apply); else unused */
};
void spectrum_radial_at(const struct spectrum_model *m, double k, struct spectrum_radial *r);
/* D(w, theta) of spectrum_spreading from c = cos(theta) (theta relative to
 * the wind) and the ring's s, q: (1-b) c^2/pi + b q ((1+c)/2)^s. */
double spectrum_spreading_cos(const struct spectrum_model *m, const struct spectrum_radial *r, double c);

/* coth(k d) / k, 0 at k = 0: the horizontal displacement of linear waves in
 * depth d is D~ = i lambda (kx, kz) coth(k d)/k h~ (1/k in deep water; the
 * orbit's horizontal semi-axis is coth(k d) times the vertical one). */
double displacement_over_k(double k, double depth);

/* Angular frequency of a mode, quantised to multiples of 2 pi / loop_period. */
double spectrum_mode_omega(const struct spectrum_model *m, double k);

/* Two independent standard normal numbers for integer wavenumber (mx, mz),
 * a pure function of (seed, mx, mz): same seed, same waves at any N. */
void spectrum_gauss_pair(uint32_t seed, int mx, int mz, double *a, double *b);

/* h~0 for integer wavenumber (mx, mz) on a patch of side L:
 * 1/2 (xi_r + i xi_i) sqrt(Psi(k)) dk, dk = 2 pi / L. */
double complex spectrum_h0(const struct spectrum_model *m, int mx, int mz);

#endif

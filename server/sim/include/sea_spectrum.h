/* sea_spectrum.h — a measured sea: a buoy's or a forecast's directional
 * spectrum as the simulation takes it (spectrum "measured", params.h).
 *
 * A struct sea_spectrum holds one "sea document" (docs/simulation.md,
 * "Measured seas", has the contract agreed with the daemon and the readers)
 * in one of its two forms:
 *   moments     per band: C11 energy E(f) (m^2/Hz) and the normalised Fourier
 *               coefficients a1, b1, a2, b2 of the directional distribution;
 *   spectrum2d  per band and direction: E(f, theta) (m^2/(Hz rad)).
 * Every direction is where the waves come FROM, in degrees clockwise from
 * true north (NDBC, CDIP). The sea's world frame: y up, north = +z,
 * east = -x, so a wave from compass bearing b travels toward (sin b, -cos b)
 * in (x, z).
 *
 * Everything here is a pure function of its arguments (no allocation but
 * where named, no global state): any thread may call it. The struct has
 * fixed-size arrays (about 83 kB), so it copies with `=` and owns nothing. */
#ifndef OCEAND_SEA_SPECTRUM_H
#define OCEAND_SEA_SPECTRUM_H

#include <stdbool.h>
#include <stddef.h>

#include "params.h"

#define SEA_MAX_BANDS 128        /* frequencies of a document */
#define SEA_MAX_DIRECTIONS 72    /* directions of a spectrum2d document */
#define SEA_M0_MAX 100.0         /* m^2: total energy cap, Hs = 4 sqrt(m0) <= 40 m */
#define SEA_FREQUENCY_MAX 10.0   /* Hz: highest band centre accepted (1.6 cm waves) */
#define SEA_DEPTH_MAX 10000.0    /* m, as params' depth */
#define SEA_SOURCE_LEN 64        /* bytes of `source`, NUL included */
#define SEA_TIME_LEN 32          /* bytes of `time`, NUL included */

enum sea_form { SEA_FORM_MOMENTS, SEA_FORM_SPECTRUM2D };

/* What the sea has above its last band (docs/simulation.md, "The tail"). */
enum sea_tail {
    SEA_TAIL_F4,      /* E ~ f^-4 from the last band's edge (the equilibrium range), the last band's D */
    SEA_TAIL_F5,      /* E ~ f^-5 (Phillips' saturation range), the last band's D */
    SEA_TAIL_NONE,    /* nothing: the surface holds the measured bands only */
    SEA_TAIL_WIND,    /* the parametric JONSWAP wind sea of the parameters (wind speed, direction,
                       * fetch, gamma, spreading, swell) above the last band's edge */
    SEA_TAIL_COUNT
};

/* How D(theta) is made from a1, b1, a2, b2 (moments form only). The default
 * is MEM: of the three it alone keeps both the moments and D >= 0 for the
 * narrow seas buoys see (docs/simulation.md has the measured figures: the
 * clipped series broadens a 28 deg sea to 42 deg). */
enum sea_directional {
    SEA_DIR_MEM,          /* maximum entropy, Lygre & Krogstad 1986: positive, reproduces the four
                           * moments (default) */
    SEA_DIR_LH_CLIPPED,   /* Longuet-Higgins et al. 1963's truncated Fourier series
                           * 1/pi (1/2 + a1 cos + b1 sin + a2 cos 2 + b2 sin 2), clipped at 0 and
                           * renormalised: where it went negative it is broader than the moments */
    SEA_DIR_LH_WEIGHTED,  /* the positive weighted form 1/pi (1/2 + 2/3 (a1 cos + b1 sin) + 1/6 (a2 cos 2 +
                           * b2 sin 2)), also clipped for moments no real sea has: broader, r1 x 2/3 */
    SEA_DIR_COUNT
};

struct sea_spectrum {
    enum sea_form form;
    char source[SEA_SOURCE_LEN];     /* "NDBC 46026"; printable text */
    char time[SEA_TIME_LEN];         /* ISO 8601 UTC; printable text, not parsed */
    double depth;                    /* m at the source; 0 = unknown (the document's null) */
    int bands;                       /* 1 .. SEA_MAX_BANDS */
    double frequency[SEA_MAX_BANDS]; /* Hz, band centres, strictly increasing */
    double bandwidth[SEA_MAX_BANDS]; /* Hz, > 0, at most 2 x the centre (the band starts at f >= 0) */
    /* moments form */
    double energy[SEA_MAX_BANDS];    /* C11, m^2/Hz */
    double a1[SEA_MAX_BANDS], b1[SEA_MAX_BANDS], a2[SEA_MAX_BANDS], b2[SEA_MAX_BANDS];
    /* spectrum2d form */
    int directions;                          /* 1 .. SEA_MAX_DIRECTIONS */
    double direction[SEA_MAX_DIRECTIONS];    /* degrees, compass, from, distinct, in [0, 360), any order */
    double energy2d[SEA_MAX_BANDS][SEA_MAX_DIRECTIONS]; /* E(f, theta), m^2/(Hz rad), [band][direction] */
    /* How the library uses it (not in the agreed document: the daemon's defaults, see docs) */
    enum sea_tail tail;
    enum sea_directional directional;
};

/* Why a sea was refused. Stable: the daemon maps them to wire error codes
 * (sea_error_name gives the code's text). */
enum sea_error {
    SEA_OK = 0,
    SEA_ERR_FORM,          /* form, tail or directional not one of the enum's values */
    SEA_ERR_SIZE,          /* bands not in 1..128, directions not in 1..72 */
    SEA_ERR_TEXT,          /* source or time not NUL-terminated printable text */
    SEA_ERR_NOT_FINITE,    /* NaN or infinity anywhere */
    SEA_ERR_FREQUENCY,     /* a band centre <= 0 or above SEA_FREQUENCY_MAX */
    SEA_ERR_ORDER,         /* band centres not strictly increasing */
    SEA_ERR_BANDWIDTH,     /* bandwidth <= 0 or above 2 x its centre */
    SEA_ERR_NEGATIVE,      /* an energy < 0 */
    SEA_ERR_COEFFICIENT,   /* |a1|, |b1|, |a2| or |b2| > 1 */
    SEA_ERR_DIRECTION,     /* a direction outside [0, 360) */
    SEA_ERR_DUPLICATE,     /* two equal directions */
    SEA_ERR_ENERGY,        /* total m0 above SEA_M0_MAX */
    SEA_ERR_DEPTH,         /* depth < 0, or in (0, 0.5) m, or above SEA_DEPTH_MAX */
    SEA_ERR_MEMORY,        /* no memory for the tables (sea_capture) */
    SEA_ERR_PARAMS,        /* sea_capture's parameters fail params_validate_sea */
};

/* "ok", "sea_form", "sea_size", ... (lowercase, stable). */
const char *sea_error_name(enum sea_error e);

/* A sea with every field zero or empty, tail SEA_TAIL_F4, directional
 * SEA_DIR_MEM (both 0): fill in the bands and check it. */
void sea_spectrum_init(struct sea_spectrum *s, enum sea_form form);

/* The whole check: sizes, text, finite, non-negative, coefficients, band
 * order, directions, depth, the energy cap. Returns SEA_OK, or the first
 * fault's code with a message naming the band and direction index
 * ("energy[3][5] = -0.2 is negative (band 3, 0.048 Hz; direction 5, 75 deg)").
 * s is only read. Only the arrays' first `bands` (`directions`) entries are
 * looked at. */
enum sea_error sea_spectrum_check(const struct sea_spectrum *s, char *err, size_t errlen);

/* m0 = sum E df (moments) or sum E df dtheta (spectrum2d; dtheta of each
 * direction is half the arc to its two neighbours), m^2. Assumes a checked sea. */
double sea_spectrum_m0(const struct sea_spectrum *s);
/* The band with the most energy density E(f) (per Hz), or -1 for none. */
int sea_spectrum_peak_band(const struct sea_spectrum *s);
/* A band's energy density E(f) (m^2/Hz) and its first and second normalised
 * Fourier coefficients in the compass "from" frame (for spectrum2d: the
 * trapezoid sums of E(f, theta) cos theta ... over the directions). */
void sea_spectrum_band(const struct sea_spectrum *s, int band, double *energy, double coef[4]);

/* Statistics of a band from its coefficients: mean direction (compass,
 * from, degrees in [0, 360)) atan2(b1, a1), and Kuik et al. 1988's
 * directional spread sqrt(2 (1 - r1)), degrees, r1 = sqrt(a1^2 + b1^2). */
double sea_mean_direction(double a1, double b1);
double sea_kuik_spread(double a1, double b1);

/* D(alpha) of one band's moments by `method` on `count` equally spaced
 * compass "from" directions alpha_j = 360 j / count degrees, per radian,
 * normalised so that its trapezoid sum over the circle is 1 (exactly the
 * integral of the periodic piecewise-linear D the simulation samples).
 * Coefficients beyond what a distribution can have are pulled in first:
 * r1 = |a1 + i b1| and r2 to at most 1 - 1e-6 (each |.| <= 1 passes the
 * check, but a1 = b1 = 1 is r1 = 1.41). Returns 0, or -1 for count < 8 or a
 * bad method (d untouched). */
int sea_directional_distribution(enum sea_directional method, double a1, double b1, double a2, double b2,
                                 double *d, int count);

/* What a grid holds of a sea (docs/simulation.md, "What the grid captures").
 * All energies m^2, height variances; "grid" sums over the modes of every
 * cascade in force, as the amplitudes are made (the expected variance of the
 * surface, before the random numbers). */
struct sea_capture {
    double m0_source;        /* the document's m0 */
    double m0_grid;          /* the part of the source on the grid's modes (Riemann sum of Psi dk^2) */
    double m0_tail;          /* the tail on the grid's modes (0 for SEA_TAIL_NONE) */
    double share;            /* m0_grid / m0_source (1 for a calm source) */
    double m0_long;          /* source energy at k below the grid's first ring, 2 pi / L (lost) */
    double m0_short;         /* source energy at k above the finest cascade's top (lost) */
    double m0_coarse;        /* source energy at wavelengths longer than L / 4: on a handful of modes */
    double hs_source, hs_grid;   /* 4 sqrt(m0_source), 4 sqrt(m0_grid + m0_tail): m */
    int peak_band;           /* sea_spectrum_peak_band */
    double peak_frequency;   /* Hz, its centre; Tp = 1 / it */
    double peak_wavelength;  /* m, at the parameters' depth */
    double peak_direction;   /* compass "from", degrees, at the peak band */
    double peak_spread;      /* Kuik's, degrees, at the peak band */
    double suggested_patch;  /* m: a patch that fits (<= 1 % of m0 longer than L / 4); 0 when L fits */
    bool fits;               /* share in [0.9, 1.1] and m0_coarse <= 5 % of m0 (a share above 1: bands
                              * narrower than the grid's rings, sampled at a ring, not integrated) */
    char warning[256];       /* "" when it fits; else why, and the suggested patch */
};

/* The capture of sea s on the grid of parameters p (resolution, patch_size,
 * cascades, depth, and for SEA_TAIL_WIND the wind). Checks s first: returns
 * SEA_OK, or s's fault (out untouched); SEA_ERR_PARAMS when p is not a
 * valid parameter set (its spectrum aside); SEA_ERR_MEMORY when the tables
 * cannot be made. Costs a pass over the modes of every
 * cascade: about 6 ms per 100 k modes, 0.7 s at N = 2048 with 3 cascades
 * (measured on the project's machine): for the builder thread, not the tick. */
enum sea_error sea_capture(const struct sea_spectrum *s, const struct ocean_params *p, struct sea_capture *out,
                           char *err, size_t errlen);

#endif

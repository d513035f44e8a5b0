/* ocean_spectrum.c — spectra, spreading, dispersion and random amplitudes.
 *
 * Conventions: Psi(kx, kz) dkx dkz = S(w) D(w, theta) dw dtheta, so
 * Psi = S(w(k)) dw/dk D(w, theta) / k. With h~0(k) = 1/2 xi sqrt(Psi) dk and
 * h~(k,t) = h~0(k) e^{-iwt} + conj(h~0(-k)) e^{iwt}, the height variance is
 * sum Psi dk^2, the Riemann sum of the spectrum's integral: independent of
 * N and L once the spectrum is resolved. */
#include "ocean_spectrum.h"
#include "ocean.h"
#include "sea_model.h"

#include <limits.h>
#include <math.h>

#define PM_ALPHA 0.0081            /* Phillips constant */
#define PM_PEAK 0.855              /* PM: w_p = 0.855 g / U10 (Horvath 2015, eq. 27) */
/* JONSWAP fetch laws (Hasselmann et al. 1973, Dtsch. Hydrogr. Z. Suppl. A8(12)):
 * f_p = 3.5 (g/U) chi^-0.33, alpha = 0.076 chi^-0.22, chi = g F / U^2. */
#define JONSWAP_FP_COEF 3.5
#define JONSWAP_FP_EXP (-0.33)
#define JONSWAP_ALPHA_COEF 0.076
#define JONSWAP_ALPHA_EXP (-0.22)

void spectrum_model_init(struct spectrum_model *m, const struct ocean_params *p)
{
    const double g = OCEAN_G, U = p->wind_speed;
    m->kind = p->spectrum;
    m->calm = !(U > 1e-3);
    m->wind_speed = U;
    m->wind_angle = p->wind_direction * M_PI / 180.0;
    m->amplitude = p->amplitude;
    m->depth = p->depth;
    m->gamma = p->gamma;
    m->blend = p->directional_spread;
    m->swell = p->swell;
    m->cutoff = p->small_wave_cutoff;
    m->loop_omega = p->loop_period > 0 ? 2.0 * M_PI / p->loop_period : 0.0;
    m->patch = p->patch_size;
    m->seed = (uint32_t)p->seed;
    m->band = 0;
    m->band_top = INT_MAX;
    m->sea = NULL; /* the caller attaches a measured sea */
    m->alpha = PM_ALPHA;
    m->omega_p = m->calm ? 1.0 : PM_PEAK * g / U;
    /* A measured sea's wind tail (SEA_TAIL_WIND) is this JONSWAP sea. */
    if (!m->calm && (m->kind == SPECTRUM_JONSWAP || m->kind == SPECTRUM_TMA || m->kind == SPECTRUM_MEASURED)) {
        /* Hasselmann et al. 1973 fetch laws, capped at the fully developed
         * sea: the fetch (about 18770 U^2/g) where the JONSWAP w_p falls
         * to the PM one, 0.855 g/U. */
        double chi = g * p->fetch * 1000.0 / (U * U);
        double chi_full = pow(PM_PEAK / (2.0 * M_PI * JONSWAP_FP_COEF), 1.0 / JONSWAP_FP_EXP);
        if (chi > chi_full)
            chi = chi_full;
        m->alpha = JONSWAP_ALPHA_COEF * pow(chi, JONSWAP_ALPHA_EXP);
        m->omega_p = 2.0 * M_PI * JONSWAP_FP_COEF * (g / U) * pow(chi, JONSWAP_FP_EXP);
    }
}

uint32_t spectrum_cascade_seed(uint32_t seed, int cascade)
{
    if (cascade == 0)
        return seed;
    /* splitmix64's finaliser of (seed, cascade): independent streams. */
    uint64_t z = ((uint64_t)seed << 8 | (uint64_t)cascade) + 0x9E3779B97F4A7C15ull * (uint64_t)(cascade + 1);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return (uint32_t)(z ^ (z >> 31));
}

double ocean_cascade_patch(double patch_size, int cascade)
{
    return patch_size / pow(OCEAN_CASCADE_RATIO, cascade);
}

int ocean_cascade_band_top(int n, int cascade)
{
    return cascade > 0 ? n / 4 - 1 : n / 2 - 1;
}

int ocean_cascade_band(int n, int cascade)
{
    if (cascade <= 0)
        return 0;
    /* The coarser cascade's modes cover max(|m|) < its top + 1/2, in its units. */
    return (int)ceil((ocean_cascade_band_top(n, cascade - 1) + 0.5) / OCEAN_CASCADE_RATIO);
}

void spectrum_model_cascade(struct spectrum_model *m, const struct ocean_params *p, int cascade)
{
    spectrum_model_init(m, p);
    m->patch = ocean_cascade_patch(p->patch_size, cascade);
    m->seed = spectrum_cascade_seed((uint32_t)p->seed, cascade);
    m->band = ocean_cascade_band(p->resolution, cascade);
    m->band_top = cascade > 0 ? ocean_cascade_band_top(p->resolution, cascade) : INT_MAX;
}

double dispersion_omega(double k, double depth)
{
    return sqrt(OCEAN_G * k * tanh(k * depth));
}

double dispersion_domega_dk(double k, double depth)
{
    double kd = k * depth, w = dispersion_omega(k, depth);
    if (!(w > 0))
        return sqrt(OCEAN_G * depth); /* shallow-water limit at k = 0 */
    double ch = cosh(kd);             /* inf for deep water: the term vanishes */
    double sech2 = isinf(ch) ? 0.0 : 1.0 / (ch * ch);
    return OCEAN_G * (tanh(kd) + kd * sech2) / (2.0 * w);
}

/* Kitaigorodskii depth attenuation (TMA), Horvath 2015 eq. 29. */
static double tma_attenuation(double omega, double depth)
{
    double wh = omega * sqrt(depth / OCEAN_G);
    if (wh <= 1.0)
        return 0.5 * wh * wh;
    if (wh < 2.0)
        return 1.0 - 0.5 * (2.0 - wh) * (2.0 - wh);
    return 1.0;
}

double spectrum_frequency(const struct spectrum_model *m, double w)
{
    if (m->calm || !(w > 0))
        return 0.0;
    const double g = OCEAN_G, wp = m->omega_p;
    double r = wp / w, r4 = r * r * r * r;
    double s = m->alpha * g * g / (w * w * w * w * w) * exp(-1.25 * r4);
    if (m->kind == SPECTRUM_JONSWAP || m->kind == SPECTRUM_TMA) {
        double sigma = w <= wp ? 0.07 : 0.09;
        double d = (w - wp) / (sigma * wp);
        s *= pow(m->gamma, exp(-0.5 * d * d));
    }
    if (m->kind == SPECTRUM_TMA)
        s *= tma_attenuation(w, m->depth);
    return s;
}

double spectrum_omni_k(const struct spectrum_model *m, double k)
{
    if (m->calm || !(k > 0))
        return 0.0;
    if (m->kind == SPECTRUM_PHILLIPS) {
        /* Tessendorf's Phillips spectrum with a physical constant:
         * alpha/2 k^-3 exp(-1/(k Lw)^2), Lw = U^2/g; it equals the PM tail. */
        double lw = m->wind_speed * m->wind_speed / OCEAN_G, x = k * lw;
        return 0.5 * m->alpha / (k * k * k) * exp(-1.0 / (x * x));
    }
    double w = dispersion_omega(k, m->depth);
    return spectrum_frequency(m, w) * dispersion_domega_dk(k, m->depth);
}

/* Mitsuyasu spreading exponent s(w) (Horvath 2015 eq. 43) plus the swell
 * elongation 16 tanh(w/wp) swell^2 (eq. 44). */
static double spreading_exponent(const struct spectrum_model *m, double w)
{
    double r = w / m->omega_p, s;
    if (r <= 1.0)
        s = 6.97 * pow(r, 4.06);
    else
        s = 9.77 * pow(r, -2.33 - 1.45 * (m->wind_speed * m->omega_p / OCEAN_G - 1.17));
    return s + 16.0 * tanh(r) * m->swell * m->swell;
}

/* Hasselmann's normaliser Q(s) = 2^(2s-1) Gamma(s+1)^2 / (pi Gamma(2s+1)),
 * via lgamma for large s. */
static double spreading_norm(double s)
{
    /* lgamma_r, not lgamma: lgamma writes the global signgam, a data race
     * when the pool's threads build the spectrum together (ThreadSanitizer). */
    int sign;
    double g1 = lgamma_r(s + 1.0, &sign), g2 = lgamma_r(2.0 * s + 1.0, &sign);
    return exp((2.0 * s - 1.0) * M_LN2 + 2.0 * g1 - g2) / M_PI;
}

double spectrum_spreading(const struct spectrum_model *m, double w, double theta)
{
    /* Tessendorf's |k.w|^2, normalised over the full circle. */
    double c = cos(theta), d_cos2 = c * c / M_PI;
    if (m->blend <= 0)
        return d_cos2;
    /* Hasselmann cos^2s(theta/2) with its normaliser
     * Q(s) = 2^(2s-1) Gamma(s+1)^2 / (pi Gamma(2s+1)), via lgamma for large s. */
    double s = spreading_exponent(m, w);
    double q = spreading_norm(s);
    /* |cos(theta/2)|^2s as ((1 + cos theta)/2)^s: the same, but exactly 0
     * straight upwind (cos(pi/2) is 6e-17 in double, and (6e-17)^2s is not
     * small for the small s of short waves), as on the fast path. */
    double half = 0.5 * (1.0 + c);
    double d_h = q * pow(half > 0 ? half : 0.0, s);
    return (1.0 - m->blend) * d_cos2 + m->blend * d_h;
}

/* The parametric JONSWAP sea of a measured sea's wind tail. */
static struct spectrum_model wind_sea_of(const struct spectrum_model *m)
{
    struct spectrum_model w = *m;
    w.kind = SPECTRUM_JONSWAP;
    w.sea = NULL;
    return w;
}

/* A measured sea: E(f, theta) df dtheta = Psi(kx, kz) dkx dkz, with dkx dkz =
 * k dk dtheta and df = c_g dk / (2 pi), so Psi = E(f, theta) c_g / (2 pi k)
 * (docs/simulation.md, "Measured seas"). */
static double measured_directional(const struct spectrum_model *m, double kx, double kz)
{
    double k = hypot(kx, kz);
    if (!(k > 0))
        return 0.0;
    int band;
    double w = dispersion_omega(k, m->depth);
    double s = sea_model_frequency(m->sea, w / (2.0 * M_PI), &band);
    if (band == SEA_BAND_WIND) {
        struct spectrum_model wind = wind_sea_of(m);
        return spectrum_directional(&wind, kx, kz);
    }
    if (!(s > 0))
        return 0.0;
    double damp = m->cutoff > 0 ? exp(-pow(k * m->cutoff / (2.0 * M_PI), 2)) : 1.0;
    return m->amplitude * s * dispersion_domega_dk(k, m->depth) / (2.0 * M_PI * k) *
           sea_model_direction(m->sea, band, kx, kz) * damp;
}

double spectrum_directional(const struct spectrum_model *m, double kx, double kz)
{
    if (m->sea)
        return measured_directional(m, kx, kz);
    double k = hypot(kx, kz);
    if (m->calm || !(k > 0))
        return 0.0;
    double w = dispersion_omega(k, m->depth);
    double theta = remainder(atan2(kz, kx) - m->wind_angle, 2.0 * M_PI);
    double damp = m->cutoff > 0 ? exp(-pow(k * m->cutoff / (2.0 * M_PI), 2)) : 1.0;
    return m->amplitude * spectrum_omni_k(m, k) * spectrum_spreading(m, w, theta) / k * damp;
}

double displacement_over_k(double k, double depth)
{
    if (!(k > 0))
        return 0.0;
    /* Linear theory's particle orbits (docs/simulation.md): at the surface
     * the horizontal semi-axis is coth(kd) times the vertical one. tanh is
     * exactly 1 in double beyond kd ~ 19, so deep water is 1/k. */
    return 1.0 / (k * tanh(k * depth));
}

/* spectrum_radial_at of a measured sea: S(f) c_g / (2 pi k) per ring, the
 * band whose D the modes take; the wind tail's rings are the JONSWAP sea's. */
static void measured_radial_at(const struct spectrum_model *m, double k, struct spectrum_radial *r)
{
    if (!(k > 0))
        return;
    int band;
    double s = sea_model_frequency(m->sea, dispersion_omega(k, m->depth) / (2.0 * M_PI), &band);
    if (band == SEA_BAND_WIND) {
        struct spectrum_model wind = wind_sea_of(m);
        spectrum_radial_at(&wind, k, r);
        r->band = SEA_BAND_WIND;
        return;
    }
    r->band = band;
    if (!(s > 0))
        return;
    double damp = m->cutoff > 0 ? exp(-pow(k * m->cutoff / (2.0 * M_PI), 2)) : 1.0;
    r->psi_k = m->amplitude * s * dispersion_domega_dk(k, m->depth) / (2.0 * M_PI * k) * damp;
}

void spectrum_radial_at(const struct spectrum_model *m, double k, struct spectrum_radial *r)
{
    r->psi_k = r->s = r->q = 0.0;
    r->band = SEA_BAND_NONE;
    r->omega = spectrum_mode_omega(m, k);
    r->disp = displacement_over_k(k, m->depth);
    if (m->sea) {
        measured_radial_at(m, k, r);
        return;
    }
    if (m->calm || !(k > 0))
        return;
    double damp = m->cutoff > 0 ? exp(-pow(k * m->cutoff / (2.0 * M_PI), 2)) : 1.0;
    r->psi_k = m->amplitude * spectrum_omni_k(m, k) / k * damp;
    if (m->blend > 0) {
        r->s = spreading_exponent(m, dispersion_omega(k, m->depth));
        r->q = spreading_norm(r->s);
    }
}

double spectrum_spreading_cos(const struct spectrum_model *m, const struct spectrum_radial *r, double c)
{
    double d_cos2 = c * c / M_PI;
    if (m->blend <= 0)
        return d_cos2;
    double half = 0.5 * (1.0 + c); /* cos^2(theta/2) */
    /* powf: a third of the cost of pow, and the amplitudes end up in float
     * anyway (relative error ~1e-7 against spectrum_spreading). */
    double d_h = r->q * powf(half > 0 ? (float)half : 0.0f, (float)r->s);
    return (1.0 - m->blend) * d_cos2 + m->blend * d_h;
}

double spectrum_mode_omega(const struct spectrum_model *m, double k)
{
    double w = dispersion_omega(k, m->depth);
    if (m->loop_omega > 0 && w > 0) {
        /* Tessendorf's repeat period: nearest multiple, at least one. */
        double q = nearbyint(w / m->loop_omega);
        w = (q < 1 ? 1 : q) * m->loop_omega;
    }
    return w;
}

/* splitmix64 finaliser: a good 64-bit mix, cheap and portable. */
static uint64_t mix64(uint64_t x)
{
    x ^= x >> 30;
    x *= 0xbf58476d1ce4e5b9ull;
    x ^= x >> 27;
    x *= 0x94d049bb133111ebull;
    x ^= x >> 31;
    return x;
}

void spectrum_gauss_pair(uint32_t seed, int mx, int mz, double *a, double *b)
{
    uint64_t key = ((uint64_t)(uint32_t)mx << 32) | (uint32_t)mz;
    uint64_t h1 = mix64(mix64(key ^ 0x9e3779b97f4a7c15ull) + seed);
    uint64_t h2 = mix64(h1 ^ 0xd1b54a32d192ed03ull);
    /* 53-bit uniforms; u1 in (0, 1] so the log is finite. */
    double u1 = ((h1 >> 11) + 1) * 0x1.0p-53, u2 = (h2 >> 11) * 0x1.0p-53;
    double r = sqrt(-2.0 * log(u1));
    *a = r * cos(2.0 * M_PI * u2);
    *b = r * sin(2.0 * M_PI * u2);
}

double complex spectrum_h0(const struct spectrum_model *m, int mx, int mz)
{
    if (!spectrum_in_band(m, mx, mz))
        return 0.0;
    double dk = 2.0 * M_PI / m->patch;
    double psi = spectrum_directional(m, mx * dk, mz * dk);
    if (!(psi > 0))
        return 0.0;
    double a, b;
    spectrum_gauss_pair(m->seed, mx, mz, &a, &b);
    return 0.5 * sqrt(psi) * dk * (a + I * b);
}

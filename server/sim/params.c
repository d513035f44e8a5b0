/* params.c — the one table of sea parameters, and the checks on it.
 *
 * Defaults describe a moderate wind sea that looks right at N = 256:
 * a 256 m patch sampled every metre holds about four peak wavelengths of
 * a 10 m/s JONSWAP sea over 100 km of fetch (peak ~60 m, Hs ~2 m), so
 * the tiling is hard to spot and the shortest resolved wave (2 m) is
 * still in the equilibrium range. Units and conventions: docs/simulation.md. */
#include "params.h"

#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

static const char *const spectrum_names[] = {"phillips", "pierson_moskowitz", "jonswap", "tma", "measured", NULL};
static const char *const transform_names[] = {"fft", "dft", NULL};

/* Every sea parameter may change live (a JSON `set`). */
#define P(name_, type_, unit_, min_, max_, def_, choices_, desc_, field_, flags_)                         \
    { .name = name_, .type = type_, .unit = unit_, .min = min_, .max = max_, .def = def_,               \
      .choices = choices_, .description = desc_, .offset = offsetof(struct ocean_params, field_),        \
      .flags = (flags_) | PARAM_LIVE }

/* Largest N for transform=dft: the brute-force sum costs 8*N^4 complex
 * multiply-adds per step (~0.1 s at 64, ~2 s at 128). */
#define DFT_MAX_N 64

/* Cascades by default: docs/simulation.md, "Cascades" (the measurement that chose it). */
#define CASCADES_DEFAULT 3

const struct param_def param_table[] = {
    P("resolution", PARAM_INT, "", 16, 2048, 256, NULL,
     "grid samples per side N (power of two); changing it re-plans the FFT", resolution,
     PARAM_POW2 | PARAM_REPLAN | PARAM_PHASE),
    P("patch_size", PARAM_FLOAT, "m", 1, 10000, 256, NULL,
     "side L of the periodic square patch", patch_size, PARAM_PHASE),
    P("cascades", PARAM_INT, "", 1, 4, CASCADES_DEFAULT, NULL,
     "periodic patches summed: cascade c has side L / 3.543^c and adds the wavenumbers the coarser ones "
     "cannot hold (docs/simulation.md, Cascades)", cascades, 0),
    P("wind_speed", PARAM_FLOAT, "m/s", 0, 40, 10, NULL,
     "wind speed U10, 10 m above the sea", wind_speed, 0),
    P("wind_direction", PARAM_FLOAT, "deg", -360, 360, 0, NULL,
     "direction the wind blows toward: 0 = +x, 90 = +z", wind_direction, 0),
    P("amplitude", PARAM_FLOAT, "", 0, 10, 1, NULL,
     "multiplier of the spectrum (wave heights scale with its square root)", amplitude, 0),
    P("spectrum", PARAM_ENUM, "", 0, SPECTRUM_MEASURED, SPECTRUM_JONSWAP, spectrum_names,
     "wave spectrum: phillips (Tessendorf), pierson_moskowitz (fully developed), "
     "jonswap (fetch limited), tma (jonswap in finite depth), measured (a buoy's or a forecast's "
     "directional spectrum, sent as a sea; docs/simulation.md, Measured seas)",
     spectrum, 0),
    P("fetch", PARAM_FLOAT, "km", 0.1, 10000, 100, NULL,
     "open water upwind (jonswap, tma); long fetches saturate at the fully developed sea",
     fetch, 0),
    P("depth", PARAM_FLOAT, "m", 0.5, 10000, 1000, NULL,
     "water depth: dispersion w^2 = g k tanh(k d) and horizontal displacement coth(k d) for all spectra, plus the TMA attenuation",
     depth, PARAM_PHASE),
    P("gamma", PARAM_FLOAT, "", 1, 10, 3.3, NULL,
     "JONSWAP peak enhancement (1 = Pierson-Moskowitz shape)", gamma, 0),
    P("directional_spread", PARAM_FLOAT, "", 0, 1, 1, NULL,
     "directional spreading: 0 = Tessendorf's cos^2 (up- and downwind), "
     "1 = Mitsuyasu-Hasselmann cos^2s(theta/2) (downwind, narrower near the peak); blends between",
     directional_spread, 0),
    P("swell", PARAM_FLOAT, "", 0, 1, 0, NULL,
     "swell: longer crests, by narrowing the cos^2s part of the spreading (Horvath 2015)", swell, 0),
    P("choppiness", PARAM_FLOAT, "", 0, 4, 1, NULL,
     "lambda, horizontal displacement scale: > 0 sharpens crests, 0 = plain heights",
     choppiness, 0),
    P("small_wave_cutoff", PARAM_FLOAT, "m", 0, 100, 0.5, NULL,
     "waves shorter than this wavelength are damped (exp(-(k l / 2 pi)^2))",
     small_wave_cutoff, 0),
    P("loop_period", PARAM_FLOAT, "s", 0, 3600, 0, NULL,
     "the sea repeats exactly after this time (wave frequencies quantised); 0 = never",
     loop_period, PARAM_PHASE),
    P("seed", PARAM_INT, "", 0, 2147483647, 1, NULL,
     "random seed; the same seed gives the same waves at any resolution", seed, PARAM_PHASE),
    P("transform", PARAM_ENUM, "", 0, 1, TRANSFORM_FFT, transform_names,
     "fft (FFTW) or dft (the brute-force O(N^4) sum, N <= 64 only)", transform, 0),
    P("time_scale", PARAM_FLOAT, "", 0, 16, 1, NULL,
     "playback speed: simulated seconds per wall-clock second", time_scale, PARAM_PLAYBACK),
    P("paused", PARAM_BOOL, "", 0, 1, 0, NULL,
     "stop the simulation clock", paused, PARAM_PLAYBACK),
};
const size_t param_count = sizeof param_table / sizeof param_table[0];
_Static_assert(sizeof param_table / sizeof param_table[0] == PARAM_COUNT, "PARAM_COUNT must match the table");

/* Labels, groups and one-line help for people (params.h, struct param_ui). */
static const struct param_ui ui_table[] = {
    {"resolution", "Resolution", PARAM_GROUP_DEVELOPER,
     "Grid samples per side: more detail, more CPU and bandwidth"},
    {"patch_size", "Patch size", PARAM_GROUP_ADVANCED,
     "Side of the simulated square of sea, which repeats like a tile"},
    {"cascades", "Detail cascades", PARAM_GROUP_ADVANCED,
     "More cascades add finer ripples on smaller patches that never line up with the large one"},
    {"wind_speed", "Wind speed", PARAM_GROUP_SEA,
     "Wind 10 m above the sea: stronger wind, bigger and longer waves, more whitecaps"},
    {"wind_direction", "Wind direction", PARAM_GROUP_SEA,
     "Where the wind blows toward, in degrees"},
    {"amplitude", "Wave height scale", PARAM_GROUP_ADVANCED,
     "Multiplies the wave spectrum; 1 is the physical sea for this wind"},
    {"spectrum", "Spectrum", PARAM_GROUP_ADVANCED,
     "Which model of wave energy per wavelength the sea follows"},
    {"fetch", "Fetch", PARAM_GROUP_SEA,
     "Open water upwind: short fetch gives a young, choppy sea"},
    {"depth", "Water depth", PARAM_GROUP_SEA,
     "Shallow water slows waves and steepens them"},
    {"gamma", "Peak sharpness", PARAM_GROUP_ADVANCED,
     "JONSWAP peak enhancement: higher concentrates energy near the peak"},
    {"directional_spread", "Directional spread", PARAM_GROUP_ADVANCED,
     "How waves spread around the wind direction"},
    {"swell", "Swell", PARAM_GROUP_SEA,
     "Longer, more parallel crests, as in swell from a distant storm"},
    {"choppiness", "Choppiness", PARAM_GROUP_SEA,
     "Sharpens crests by moving water toward them; also makes more foam"},
    {"small_wave_cutoff", "Small wave cutoff", PARAM_GROUP_ADVANCED,
     "Damps ripples shorter than this wavelength"},
    {"loop_period", "Loop period", PARAM_GROUP_ADVANCED,
     "The sea repeats exactly after this many seconds; 0 = never"},
    {"seed", "Random seed", PARAM_GROUP_ADVANCED,
     "Another seed gives another sea with the same statistics"},
    {"transform", "Transform", PARAM_GROUP_DEVELOPER,
     "FFT, or the brute-force sum used to check it (small grids only)"},
    {"time_scale", "Playback speed", PARAM_GROUP_SEA,
     "Simulated seconds per real second"},
    {"paused", "Paused", PARAM_GROUP_SEA,
     "Stops the sea's clock for everyone"},
};

const struct param_ui *param_ui(const struct param_def *d)
{
    for (size_t i = 0; d && i < sizeof ui_table / sizeof ui_table[0]; i++)
        if (strcmp(ui_table[i].name, d->name) == 0)
            return &ui_table[i];
    return NULL;
}

const char *param_group_name(enum param_group g)
{
    switch (g) {
    case PARAM_GROUP_SEA: return "sea";
    case PARAM_GROUP_ADVANCED: return "advanced";
    case PARAM_GROUP_DEVELOPER: return "developer";
    }
    return "advanced";
}

double param_get(const struct ocean_params *p, const struct param_def *d)
{
    const char *f = (const char *)p + d->offset;
    switch (d->type) {
    case PARAM_INT:
    case PARAM_ENUM: { int v; memcpy(&v, f, sizeof v); return v; }
    case PARAM_BOOL: { bool v; memcpy(&v, f, sizeof v); return v ? 1.0 : 0.0; }
    case PARAM_FLOAT: { double v; memcpy(&v, f, sizeof v); return v; }
    case PARAM_STRING: break; /* not a number; no sea parameter is a string */
    }
    return 0;
}

/* Store an already checked number. */
static void store(void *base, const struct param_def *d, double v)
{
    char *f = (char *)base + d->offset;
    switch (d->type) {
    case PARAM_INT:
    case PARAM_ENUM: { int i = (int)v; memcpy(f, &i, sizeof i); break; }
    case PARAM_BOOL: { bool b = v != 0; memcpy(f, &b, sizeof b); break; }
    case PARAM_FLOAT: memcpy(f, &v, sizeof v); break;
    case PARAM_STRING: break;
    }
}

void setting_set_default(void *base, const struct param_def *d)
{
    if (d->type == PARAM_STRING) {
        const char *t = d->def_text ? d->def_text : "";
        char *f = (char *)base + d->offset;
        snprintf(f, d->size, "%s", t);
    } else {
        store(base, d, d->def);
    }
}

void params_defaults(struct ocean_params *p)
{
    memset(p, 0, sizeof *p);
    for (size_t i = 0; i < param_count; i++)
        setting_set_default(p, &param_table[i]);
}

const struct param_def *param_find(const char *name)
{
    if (!name)
        return NULL;
    for (size_t i = 0; i < param_count; i++)
        if (param_table[i].name[0] == name[0] && strcmp(param_table[i].name, name) == 0)
            return &param_table[i];
    return NULL;
}

/* The one check of a single value against its row, shared by every setter
 * and by params_validate: nothing else in the tree re-checks ranges. */
enum param_error setting_check(const struct param_def *d, double v, char *err, size_t errlen)
{
    if (d->type == PARAM_STRING) {
        snprintf(err, errlen, "%s: needs text, not a number", d->name);
        return PARAM_ERR_TYPE;
    }
    if (!isfinite(v)) {
        snprintf(err, errlen, "%s: value must be a finite number", d->name);
        return PARAM_ERR_NOT_FINITE;
    }
    if (d->type != PARAM_FLOAT && v != floor(v)) {
        snprintf(err, errlen, "%s: %.10g is not a whole number", d->name, v);
        return PARAM_ERR_NOT_INTEGER;
    }
    if (v < d->min || v > d->max) {
        if (d->type == PARAM_ENUM) {
            snprintf(err, errlen, "%s: index %.10g out of range 0..%.10g", d->name, v, d->max);
            return PARAM_ERR_BAD_ENUM;
        }
        snprintf(err, errlen, "%s: %.10g%s%s out of range [%.10g, %.10g]", d->name, v,
                 d->unit && *d->unit ? " " : "", d->unit ? d->unit : "", d->min, d->max);
        return PARAM_ERR_RANGE;
    }
    if (d->flags & PARAM_POW2) {
        long n = (long)v;
        if (n <= 0 || (n & (n - 1)) != 0) {
            snprintf(err, errlen, "%s: %ld is not a power of two", d->name, n);
            return PARAM_ERR_NOT_POW2;
        }
    }
    return PARAM_OK;
}

enum param_error setting_set_number(void *base, const struct param_def *d, double v, char *err, size_t errlen)
{
    if (!base || !d) {
        snprintf(err, errlen, "unknown parameter");
        return PARAM_ERR_UNKNOWN;
    }
    enum param_error rc = setting_check(d, v, err, errlen);
    if (rc == PARAM_OK)
        store(base, d, v);
    return rc;
}

int param_set(struct ocean_params *p, const struct param_def *d, double v, char *err, size_t errlen)
{
    return setting_set_number(p, d, v, err, errlen) == PARAM_OK ? 0 : -1;
}

const char *param_enum_name(const struct param_def *d, int index)
{
    if (!d || !d->choices || index < 0)
        return NULL;
    for (int i = 0; d->choices[i]; i++)
        if (i == index)
            return d->choices[i];
    return NULL;
}

int param_enum_index(const struct param_def *d, const char *name)
{
    if (!d || !d->choices || !name)
        return -1;
    for (int i = 0; d->choices[i]; i++)
        if (strcasecmp(d->choices[i], name) == 0)
            return i;
    return -1;
}

/* strtod, with surrounding blanks allowed and nothing else after the number. */
static int parse_number(const char *text, double *v)
{
    char *end;
    while (isspace((unsigned char)*text))
        text++;
    if (!*text)
        return -1;
    *v = strtod(text, &end);
    while (isspace((unsigned char)*end))
        end++;
    return *end ? -1 : 0;
}

enum param_error setting_set_text(void *base, const struct param_def *d, const char *text, char *err,
                                  size_t errlen)
{
    double v;
    if (!base || !d || !text) {
        snprintf(err, errlen, "unknown parameter or no value");
        return PARAM_ERR_UNKNOWN;
    }
    /* A secret's value never appears in a message. */
    const char *shown = (d->flags & PARAM_SECRET) ? "(secret)" : text;
    switch (d->type) {
    case PARAM_STRING: {
        size_t len = strlen(text);
        if (len >= d->size) {
            snprintf(err, errlen, "%s: value too long (%zu bytes, at most %zu)", d->name, len, d->size - 1);
            return PARAM_ERR_TOO_LONG;
        }
        memcpy((char *)base + d->offset, text, len + 1);
        return PARAM_OK;
    }
    case PARAM_BOOL: {
        static const char *const yes[] = {"true", "1", "yes", "on"}, *const no[] = {"false", "0", "no", "off"};
        for (int i = 0; i < 4; i++) {
            if (strcasecmp(text, yes[i]) == 0)
                return setting_set_number(base, d, 1, err, errlen);
            if (strcasecmp(text, no[i]) == 0)
                return setting_set_number(base, d, 0, err, errlen);
        }
        snprintf(err, errlen, "%s: '%.60s' is not true or false", d->name, shown);
        return PARAM_ERR_TYPE;
    }
    case PARAM_ENUM: {
        int i = param_enum_index(d, text);
        if (i >= 0)
            return setting_set_number(base, d, i, err, errlen);
        char list[256] = "";
        for (int c = 0; d->choices && d->choices[c]; c++) {
            strncat(list, c ? ", " : "", sizeof list - strlen(list) - 1);
            strncat(list, d->choices[c], sizeof list - strlen(list) - 1);
        }
        snprintf(err, errlen, "%s: '%.60s' is not one of %s", d->name, shown, list);
        return PARAM_ERR_BAD_ENUM;
    }
    case PARAM_INT:
    case PARAM_FLOAT:
        break;
    }
    if (parse_number(text, &v) != 0) {
        snprintf(err, errlen, "%s: '%.60s' is not a number", d->name, shown);
        return PARAM_ERR_TYPE;
    }
    return setting_set_number(base, d, v, err, errlen);
}

int param_set_text(struct ocean_params *p, const struct param_def *d, const char *text, char *err,
                   size_t errlen)
{
    return setting_set_text(p, d, text, err, errlen) == PARAM_OK ? 0 : -1;
}

void setting_default_text(const struct param_def *d, char *buf, size_t len)
{
    switch (d->type) {
    case PARAM_STRING:
        snprintf(buf, len, "%s", d->def_text ? d->def_text : "");
        break;
    case PARAM_ENUM: {
        const char *n = param_enum_name(d, (int)d->def);
        snprintf(buf, len, "%s", n ? n : "?");
        break;
    }
    case PARAM_BOOL:
        snprintf(buf, len, "%s", d->def != 0 ? "true" : "false");
        break;
    case PARAM_INT:
    case PARAM_FLOAT:
        snprintf(buf, len, "%.10g", d->def);
        break;
    }
}

int params_validate(const struct ocean_params *p, char *err, size_t errlen)
{
    return params_validate_sea(p, false, err, errlen);
}

int params_validate_sea(const struct ocean_params *p, bool have_sea, char *err, size_t errlen)
{
    if (!p) {
        snprintf(err, errlen, "no parameters");
        return -1;
    }
    for (size_t i = 0; i < param_count; i++)
        if (setting_check(&param_table[i], param_get(p, &param_table[i]), err, errlen) != PARAM_OK)
            return -1;
    if (p->transform == TRANSFORM_DFT && p->resolution > DFT_MAX_N) {
        snprintf(err, errlen,
                 "transform: dft is the O(N^4) brute-force sum, allowed only for resolution <= %d "
                 "(got %d)", DFT_MAX_N, p->resolution);
        return -1;
    }
    if (p->loop_period > 0 && p->loop_period < 1) {
        snprintf(err, errlen,
                 "loop_period: %g s is too short (0 = no loop, else >= 1 s, or all waves "
                 "would share one frequency)", p->loop_period);
        return -1;
    }
    if (p->spectrum == SPECTRUM_MEASURED && !have_sea) {
        snprintf(err, errlen,
                 "spectrum: measured needs a measured sea (a buoy's or a forecast's spectrum), and none is "
                 "attached: send the sea first");
        return -1;
    }
    return 0;
}

/* ---- whole parameter sets, as masks of param_table rows ---- */

uint64_t params_mask(unsigned flags)
{
    uint64_t m = 0;
    for (size_t i = 0; i < param_count && i < 64; i++)
        if (param_table[i].flags & flags)
            m |= 1ull << i;
    return m;
}

const struct param_def *param_with_flag(unsigned flag)
{
    for (size_t i = 0; i < param_count; i++)
        if (param_table[i].flags & flag)
            return &param_table[i];
    return NULL;
}

struct ocean_params params_with(const struct ocean_params *base, const struct ocean_params *values, uint64_t mask)
{
    struct ocean_params p = *base;
    char err[64];
    for (size_t i = 0; i < param_count && i < 64; i++)
        if (mask & (1ull << i))
            param_set(&p, &param_table[i], param_get(values, &param_table[i]), err, sizeof err);
    return p;
}

uint64_t params_diff(const struct ocean_params *a, const struct ocean_params *b)
{
    uint64_t m = 0;
    for (size_t i = 0; i < param_count && i < 64; i++)
        if (param_get(a, &param_table[i]) != param_get(b, &param_table[i]))
            m |= 1ull << i;
    return m;
}

bool params_physics_differ(const struct ocean_params *a, const struct ocean_params *b)
{
    return (params_diff(a, b) & ~params_mask(PARAM_PLAYBACK)) != 0;
}

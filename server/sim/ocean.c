/* ocean.c — lifetime of a simulation: create, reconfigure, step the
 * cascades, hand out fields, free; and the small helpers every part shares.
 *
 * Where the rest is: the grids (arrays, rings, FFTW plans) in
 * ocean_grid.c; the amplitude fill in ocean_amplitudes.c; parameter
 * changes (prepare, commit, easing) in ocean_prepare.c; the per-step work
 * in ocean_step.c (FFT) and ocean_dft.c (brute force); the physics in
 * ocean_spectrum.c; the threads are the program's one work pool
 * (server/common/pool.c). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ocean_internal.h"

static const char *const field_names[OCEAN_FIELD_COUNT] = {
    "height", "dx", "dz", "slope_x", "slope_z", "jacobian", "foam"};

const char *ocean_field_name(enum ocean_field f)
{
    return (unsigned)f < OCEAN_FIELD_COUNT ? field_names[f] : NULL;
}

double ocean_wavenumber(int i, int n, double patch)
{
    return 2.0 * M_PI * (i - (i > n / 2 ? n : 0)) / patch;
}

unsigned ocean_transforms_for(unsigned fields)
{
    unsigned t = 0;
    if (fields & OCEAN_FIELD_BIT(OCEAN_HEIGHT)) t |= 1u << TR_H;
    if (fields & OCEAN_FIELD_BIT(OCEAN_DX)) t |= 1u << TR_DX;
    if (fields & OCEAN_FIELD_BIT(OCEAN_DZ)) t |= 1u << TR_DZ;
    if (fields & OCEAN_FIELD_BIT(OCEAN_SLOPE_X)) t |= 1u << TR_SX;
    if (fields & OCEAN_FIELD_BIT(OCEAN_SLOPE_Z)) t |= 1u << TR_SZ;
    if (fields & OCEAN_FIELD_BIT(OCEAN_JACOBIAN)) t |= 1u << TR_JXX | 1u << TR_JZZ | 1u << TR_JXZ;
    return t;
}

float *ocean_transform_dest(struct ocean_grid *g, enum ocean_transform tr)
{
    switch (tr) {
    case TR_H: return g->out[OCEAN_HEIGHT];
    case TR_DX: return g->out[OCEAN_DX];
    case TR_DZ: return g->out[OCEAN_DZ];
    case TR_SX: return g->out[OCEAN_SLOPE_X];
    case TR_SZ: return g->out[OCEAN_SLOPE_Z];
    case TR_JXX: return g->jac[0];
    case TR_JZZ: return g->jac[1];
    case TR_JXZ: return g->jac[2];
    default: return NULL;
    }
}

void ocean_combine_jacobian(float *restrict j, const float *restrict xx, const float *restrict zz,
                            const float *restrict xz, size_t count)
{
    for (size_t i = 0; i < count; i++)
        j[i] = (1.0f + xx[i]) * (1.0f + zz[i]) - xz[i] * xz[i];
}

double ocean_phase_time(const struct ocean *o, double t)
{
    double T = o->p.loop_period;
    if (T > 0) {
        t = fmod(t, T);
        if (t < 0)
            t += T;
    }
    return t;
}

struct ocean *ocean_create(const struct ocean_params *p, const struct ocean_options *opt, char *err,
                           size_t errlen)
{
    return ocean_create_sea(p, NULL, opt, err, errlen);
}

struct ocean *ocean_create_sea(const struct ocean_params *p, const struct sea_spectrum *sea,
                               const struct ocean_options *opt, char *err, size_t errlen)
{
    struct ocean_options o_opt = {1, NULL, 0};
    if (opt)
        o_opt = *opt;
    o_opt.threads = ocean_threads(o_opt.threads);
    if (!p) {
        snprintf(err, errlen, "no parameters");
        return NULL;
    }
    if (params_validate_sea(p, sea != NULL, err, errlen) != 0)
        return NULL;
    if (sea && sea_spectrum_check(sea, err, errlen) != SEA_OK)
        return NULL;
    struct ocean *o = calloc(1, sizeof *o);
    if (!o) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    o->opt = o_opt;
    if (o_opt.wisdom_path && *o_opt.wisdom_path) { /* the caller's string may not outlive us */
        o->wisdom_path = strdup(o_opt.wisdom_path);
        if (!o->wisdom_path) {
            snprintf(err, errlen, "out of memory");
            free(o);
            return NULL;
        }
        o->opt.wisdom_path = o->wisdom_path;
    }
    o->pool = ocean_pool_new(o->opt.threads); /* NULL (one thread) is fine: slower, same result */
    struct ocean_prepared *pr = ocean_prepare_on(o, p, sea, o->pool, o->opt.threads, err, errlen);
    if (!pr) {
        pool_free(o->pool);
        free(o->wisdom_path);
        free(o);
        return NULL;
    }
    ocean_commit(o, pr);
    ocean_prepared_free(pr); /* holds the NULL grid we started with */
    return o;
}

int ocean_reconfigure(struct ocean *o, const struct ocean_params *p, char *err, size_t errlen)
{
    return ocean_reconfigure_sea(o, p, NULL, err, errlen);
}

int ocean_reconfigure_sea(struct ocean *o, const struct ocean_params *p, const struct sea_spectrum *sea, char *err,
                          size_t errlen)
{
    if (!o || !p) {
        snprintf(err, errlen, "no simulation or no parameters");
        return -1;
    }
    struct ocean_prepared *pr = ocean_prepare_on(o, p, sea, o->pool, o->opt.threads, err, errlen);
    if (!pr)
        return -1;
    ocean_commit(o, pr); /* cannot fail: prepared against o->g just now */
    ocean_prepared_free(pr);
    return 0;
}

/* Step cascade c >= 1 on its own grid and model. Nothing of `o` is written:
 * ocean_prepare may read the live ocean on another thread meanwhile. */
static int step_cascade(struct ocean *o, int c, double t, unsigned fields)
{
    return o->p.transform == TRANSFORM_DFT ? ocean_step_dft_grid(o, o->fine[c], &o->fine_model[c], t, fields)
                                           : ocean_step_fft_grid(o, o->fine[c], t, fields, NULL);
}

int ocean_step_cascades(struct ocean *o, double t, const unsigned *fields, int count)
{
    if (!o || !isfinite(t) || !fields || count < 0)
        return -1;
    if (count > o->ncascades)
        count = o->ncascades;
    int rc = 0;
    for (int c = 0; c < count && rc == 0; c++) {
        unsigned f = fields[c] & OCEAN_ALL_FIELDS;
        if (c == 0)
            rc = ocean_step_with_foam(o, t, f);
        else if (f & ~OCEAN_FIELD_BIT(OCEAN_FOAM))
            rc = step_cascade(o, c, t, f & ~OCEAN_FIELD_BIT(OCEAN_FOAM));
    }
    return rc;
}

int ocean_keep_jacobian_terms(struct ocean *o)
{
    struct ocean_grid *g = o->g;
    bool ok = true;
    for (int i = 0; i < 3; i++)
        if (!g->jac[i])
            g->jac[i] = ocean_zalloc((size_t)g->n * g->n * sizeof(float), &ok);
    return ok ? 0 : -1;
}

int ocean_step(struct ocean *o, double t, unsigned fields)
{
    unsigned all[OCEAN_MAX_CASCADES] = {fields, fields, fields, fields};
    return ocean_step_cascades(o, t, all, OCEAN_MAX_CASCADES);
}

const float *ocean_cascade_field(const struct ocean *o, int cascade, enum ocean_field f)
{
    if (!o || (unsigned)f >= OCEAN_FIELD_COUNT || cascade < 0 || cascade >= o->ncascades)
        return NULL;
    if (cascade == 0)
        return o->g->out[f];
    return f == OCEAN_FOAM ? NULL : o->fine[cascade]->out[f];
}

int ocean_exchange_cascade_field(struct ocean *o, int cascade, enum ocean_field f, float **buf)
{
    if (!o || !buf || !*buf || (unsigned)f >= OCEAN_FIELD_COUNT || f == OCEAN_FOAM || cascade < 0 ||
        cascade >= o->ncascades)
        return -1;
    struct ocean_grid *g = ocean_cascade_grid(o, cascade);
    float *mine = g->out[f];
    g->out[f] = *buf;
    *buf = mine;
    return 0;
}

float *ocean_field_buffer_new(int n)
{
    bool ok = true;
    return n > 0 ? ocean_zalloc((size_t)n * n * sizeof(float), &ok) : NULL;
}

void ocean_field_buffer_free(float *buf) { free(buf); }

int ocean_cascades(const struct ocean *o)
{
    return o ? o->ncascades : 0;
}

const float *ocean_field(const struct ocean *o, enum ocean_field f)
{
    if (!o || (unsigned)f >= OCEAN_FIELD_COUNT)
        return NULL;
    return o->g->out[f];
}

const struct sea_spectrum *ocean_sea(const struct ocean *o)
{
    return o && o->sea ? &o->sea->doc : NULL;
}

const struct ocean_params *ocean_get_params(const struct ocean *o)
{
    return o ? &o->p : NULL;
}

int ocean_resolution(const struct ocean *o)
{
    return o ? o->g->n : 0;
}

void ocean_free(struct ocean *o)
{
    if (!o)
        return;
    pool_free(o->pool);
    pool_free(o->prep_pool);
    ocean_grid_free(o->g);
    for (int c = 1; c < OCEAN_MAX_CASCADES; c++)
        ocean_grid_free(o->fine[c]);
    sea_model_free(o->sea);
    free(o->wisdom_path);
    free(o);
}

/* ocean_prepare.c — parameter changes: prepare beside the live state, commit
 * by swapping pointers, ease amplitudes in over sim time.
 *
 * Every parameter change is prepared beside the live state (new amplitudes,
 * or for a new N a complete new grid) and swapped in by pointers only when
 * everything succeeded: on error the old state is untouched, and the
 * preparing may run on another thread than the stepping (ocean.h has the
 * contract: ocean_prepare reads the live ocean, ocean_commit writes it). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ocean_internal.h"

/* What a parameter change makes for one cascade. */
struct cascade_prep {
    struct spectrum_model model;
    struct ocean_grid *grid;   /* a new N or a new cascade: the whole new grid (after commit: the old
                                * one, or a cascade the change dropped) */
    struct ocean_amps amps;    /* same N: the new amplitudes (after commit: the old ones) */
    float *gauss;              /* same N, new seed: its normals (after commit: the old ones) */
    uint32_t seed;             /* of `gauss` */
    float *ease_from;          /* an easable change of a grid that has no ease_from yet: its buffer */
};

struct ocean_prepared {
    struct ocean_params p;
    int ncascades;             /* p.cascades */
    struct cascade_prep c[OCEAN_MAX_CASCADES];
    struct sea_model *sea;     /* a new measured sea, made from ocean_prepare_sea's document (after
                                * commit: the one it replaced); NULL: the sea in force stays */
    unsigned long generation;  /* o->generation prepared against */
    bool easable;              /* only the amplitudes h~0 (and choppiness) change: ocean_commit_eased may ease */
};

void ocean_prepared_free(struct ocean_prepared *pr)
{
    if (!pr)
        return;
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++) {
        ocean_grid_free(pr->c[c].grid);
        ocean_amps_free(&pr->c[c].amps);
        free(pr->c[c].gauss);
        free(pr->c[c].ease_from);
    }
    sea_model_free(pr->sea);
    free(pr);
}

/* One cascade's share of ocean_prepare_on(): beside its live grid g (read only; NULL
 * for a cascade the change adds). */
static bool prepare_cascade(const struct ocean *o, const struct ocean_params *p, const struct sea_model *sea, int c,
                            struct cascade_prep *cp, struct pool *pool, int threads, char *err, size_t errlen)
{
    spectrum_model_cascade(&cp->model, p, c);
    cp->model.sea = p->spectrum == SPECTRUM_MEASURED ? sea : NULL;
    cp->seed = cp->model.seed;
    const struct ocean_grid *g = ocean_cascade_grid(o, c);
    if (!g || g->n != p->resolution) {
        cp->grid = ocean_grid_new(p->resolution, &o->opt, err, errlen);
        if (!cp->grid)
            return false;
        cp->grid->seed = cp->seed;
        ocean_gauss_compute(cp->grid->n, cp->seed, cp->grid->gauss, pool, threads);
        ocean_set_k_tables(cp->grid, cp->model.patch);
        struct ocean_amps amps = {cp->grid->a, cp->grid->b, cp->grid->d, cp->grid->e, cp->grid->omega,
                                  cp->grid->ampc};
        if (!ocean_amps_compute(cp->grid, &cp->model, p->choppiness, cp->grid->gauss, &amps, pool, threads))
            goto oom;
        return true;
    }
    if (!ocean_amps_alloc(&cp->amps, g->n))
        goto oom;
    const float *gauss = g->gauss;
    if (cp->seed != g->seed) {
        bool ok = true;
        cp->gauss = ocean_zalloc(g->modes * 4 * sizeof(float), &ok);
        if (!ok)
            goto oom;
        ocean_gauss_compute(g->n, cp->seed, cp->gauss, pool, threads);
        gauss = cp->gauss;
    }
    if (!ocean_amps_compute(g, &cp->model, p->choppiness, gauss, &cp->amps, pool, threads))
        goto oom;
    return true;
oom:
    snprintf(err, errlen, "out of memory for resolution %d", p->resolution);
    return false;
}

/* Whether a prepared change may be eased in (ocean_commit_eased): every
 * cascade keeps its grid, normals and wavenumbers (same N, seed, patch,
 * cascade count), the frequencies are the same (depth, loop period), the
 * FFT path runs before and after (the DFT path recomputes the spectrum from
 * the model), N <= OCEAN_EASE_MAX_N, and some amplitude h~0 changes (a change of choppiness alone
 * is not eased: its factor is not an amplitude). Then a grid that has no
 * easing buffer yet gets one here, off the tick. False: out of memory. */
static bool prepare_ease(const struct ocean *o, struct ocean_prepared *pr)
{
    pr->easable = false;
    if (!o->g || o->g->n > OCEAN_EASE_MAX_N || pr->ncascades != o->ncascades || pr->p.transform != TRANSFORM_FFT ||
        o->p.transform != TRANSFORM_FFT || pr->p.patch_size != o->p.patch_size || pr->p.depth != o->p.depth ||
        pr->p.loop_period != o->p.loop_period)
        return true;
    bool differ = false;
    for (int c = 0; c < pr->ncascades; c++) {
        const struct cascade_prep *cp = &pr->c[c];
        const struct ocean_grid *g = ocean_cascade_grid(o, c);
        if (cp->grid || cp->gauss || !g || !cp->amps.a)
            return true;
        if (memcmp(cp->amps.omega, g->omega, g->modes * sizeof(double)) != 0)
            return true;
        const float *now[] = {g->a, g->b, g->d, g->e}, *next[] = {cp->amps.a, cp->amps.b, cp->amps.d, cp->amps.e};
        for (int k = 0; k < 4 && !differ; k++)
            differ = memcmp(now[k], next[k], g->modes * sizeof(float)) != 0;
    }
    if (!differ)
        return true;
    for (int c = 0; c < pr->ncascades; c++) {
        const struct ocean_grid *g = ocean_cascade_grid(o, c);
        if (!g->ease_from) {
            bool ok = true;
            pr->c[c].ease_from = ocean_xalloc((size_t)(g->n / 2) * OCEAN_EASE_COL_FLOATS(g->n) * sizeof(float), &ok);
            if (!ok)
                return false;
        }
    }
    pr->easable = true;
    return true;
}

/* Everything new parameters need, beside the live grids (read only). */
struct ocean_prepared *ocean_prepare_on(const struct ocean *o, const struct ocean_params *p,
                                        const struct sea_spectrum *sea, struct pool *pool, int threads, char *err,
                                        size_t errlen)
{
    if (params_validate_sea(p, sea || o->sea, err, errlen) != 0)
        return NULL;
    if (sea && sea_spectrum_check(sea, err, errlen) != SEA_OK)
        return NULL;
    struct ocean_prepared *pr = calloc(1, sizeof *pr);
    if (!pr || (sea && !(pr->sea = sea_model_new(sea)))) {
        free(pr);
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    pr->p = *p;
    pr->ncascades = p->cascades;
    pr->generation = o->generation;
    const struct sea_model *in_force = pr->sea ? pr->sea : o->sea; /* o->sea is immutable, swapped only by a commit */
    for (int c = 0; c < pr->ncascades; c++)
        if (!prepare_cascade(o, p, in_force, c, &pr->c[c], pool, threads, err, errlen)) {
            ocean_prepared_free(pr);
            return NULL;
        }
    if (!prepare_ease(o, pr)) {
        snprintf(err, errlen, "out of memory for resolution %d", p->resolution);
        ocean_prepared_free(pr);
        return NULL;
    }
    return pr;
}

struct ocean_prepared *ocean_prepare(struct ocean *o, const struct ocean_params *p, char *err, size_t errlen)
{
    return ocean_prepare_sea(o, p, NULL, err, errlen);
}

struct ocean_prepared *ocean_prepare_sea(struct ocean *o, const struct ocean_params *p,
                                         const struct sea_spectrum *sea, char *err, size_t errlen)
{
    if (!o || !p) {
        snprintf(err, errlen, "no simulation or no parameters");
        return NULL;
    }
    /* Not o->pool: that one is the stepping thread's. Made on first use
     * (only this function touches it; prepares must not overlap). */
    if (!o->prep_pool && o->opt.threads > 1)
        o->prep_pool = ocean_pool_new(o->opt.threads);
    return ocean_prepare_on(o, p, sea, o->prep_pool, o->opt.threads, err, errlen);
}

/* The start of an easing at t0 on grid g, before its amplitudes are
 * replaced: ease_from becomes what a step at t0 reads, the amplitudes in
 * force (or, during an easing, the mix at t0: no jump), in column blocks. */
struct ease_ctx {
    struct ocean_grid *g;
    float w;                   /* the running easing's weight at t0; 1: none */
};

static void ease_columns(void *arg, int i0, int i1, int worker)
{
    (void)worker;
    const struct ease_ctx *c = arg;
    struct ocean_grid *g = c->g;
    const int n = g->n, per = (n / 2 + 7) / 8;
    const size_t len = OCEAN_EASE_COL_FLOATS(n);
    for (int ix = i0 * per; ix < i1 * per && ix < n / 2; ix++) {
        float *from = ocean_ease_col(g->ease_from, n, ix);
        const float *to = ocean_amp_col(g->ampc, n, ix); /* a, b, d, e: its first 4 N floats */
        if (c->w >= 1.0f)
            memcpy(from, to, len * sizeof(float));
        else
            for (size_t i = 0; i < len; i++)
                from[i] = ocean_ease_mix(from[i], to[i], c->w);
    }
}

static void ease_start(struct ocean *o, struct ocean_grid *g, double t0)
{
    struct ease_ctx c = {g, g->ease_len > 0 ? ocean_ease_weight(g->ease_t0, g->ease_len, t0) : 1.0f};
    int threads = g->n >= OCEAN_THREADS_FROM_N ? g->workers : 1;
    pool_for(o->pool, threads, 8, ease_columns, &c);
}

bool ocean_prepared_easable(const struct ocean_prepared *pr)
{
    return pr && pr->easable;
}

int ocean_commit(struct ocean *o, struct ocean_prepared *pr)
{
    return ocean_commit_eased(o, pr, 0, 0);
}

int ocean_commit_eased(struct ocean *o, struct ocean_prepared *pr, double t0, double len)
{
    if (!o || !pr || pr->generation != o->generation)
        return -1; /* prepared against another state: nothing changes */
    bool ease = pr->easable && isfinite(t0) && isfinite(len) && len > 0;
    for (int c = 0; c < o->ncascades; c++) {
        struct ocean_grid *g = ocean_cascade_grid(o, c);
        if (ease) {
            if (!g->ease_from) {
                g->ease_from = pr->c[c].ease_from;
                pr->c[c].ease_from = NULL;
            }
            ease_start(o, g, t0); /* before the amplitudes are swapped: it reads those in force */
            g->ease_t0 = t0;
            g->ease_len = len;
        } else {
            g->ease_len = 0; /* at once, also from the middle of an easing */
        }
    }
    o->p = pr->p;
    if (pr->sea) { /* the models below point at it; the one it replaces leaves with pr */
        struct sea_model *old = o->sea;
        o->sea = pr->sea;
        pr->sea = old;
    }
    for (int c = 0; c < pr->ncascades; c++) {
        struct cascade_prep *cp = &pr->c[c];
        struct ocean_grid **slot = c == 0 ? &o->g : &o->fine[c];
        if (c == 0)
            o->model = cp->model;
        else
            o->fine_model[c] = cp->model;
        if (cp->grid) {
            struct ocean_grid *old = *slot;
            *slot = cp->grid;
            cp->grid = old;
            if (c == 0)
                o->foam_warm = false; /* a new grid's foam is empty: rebuild its history */
            continue;
        }
        struct ocean_grid *g = *slot;
        ocean_amps_swap(g, &cp->amps);
        if (cp->gauss) {
            float *t = g->gauss;
            g->gauss = cp->gauss;
            cp->gauss = t;
            uint32_t s = g->seed;
            g->seed = cp->seed;
            cp->seed = s;
        }
        ocean_set_k_tables(g, cp->model.patch); /* N + 1 floats */
    }
    for (int c = pr->ncascades; c < o->ncascades; c++) { /* dropped cascades: freed with pr */
        pr->c[c].grid = o->fine[c];
        o->fine[c] = NULL;
    }
    o->ncascades = pr->ncascades;
    o->generation++; /* also refuses a second commit of the same object */
    return 0;
}

struct ocean_surface *ocean_prepared_surface(const struct ocean *o, const struct ocean_prepared *pr, char *err,
                                             size_t errlen)
{
    if (!o || !pr) {
        snprintf(err, errlen, "no simulation");
        return NULL;
    }
    /* Every cascade in force after the commit (queries sum them all): a new
     * grid (new N, new cascade) as it is; else the live grid with the prepared
     * amplitudes, a shallow copy (the snapshot reads only n, nh, modes and
     * the amplitudes). */
    struct ocean_grid view[OCEAN_MAX_CASCADES];
    const struct ocean_grid *grids[OCEAN_MAX_CASCADES];
    for (int c = 0; c < pr->ncascades; c++) {
        const struct cascade_prep *cp = &pr->c[c];
        if (cp->grid) {
            grids[c] = cp->grid;
            continue;
        }
        view[c] = *ocean_cascade_grid(o, c);
        view[c].a = cp->amps.a;
        view[c].b = cp->amps.b;
        view[c].d = cp->amps.d;
        view[c].e = cp->amps.e;
        view[c].omega = cp->amps.omega;
        grids[c] = &view[c];
    }
    if (!pr->easable)
        return ocean_surface_from(grids, pr->ncascades, &pr->p, err, errlen);
    /* An eased commit will start from the amplitudes in force (or from an
     * easing's mix of them with its own `from`): keep their modes too, and
     * make room for them (ocean_surface_ease fills it after the commit). */
    struct surface_ease ease = {.keep_stride = OCEAN_AMP_COL_FLOATS(o->g->n)};
    for (int c = 0; c < pr->ncascades; c++) {
        const struct ocean_grid *g = ocean_cascade_grid(o, c);
        ease.keep[c] = g->ampc;
        ease.from[c] = g->ease_len > 0 ? g->ease_from : NULL;
    }
    return ocean_surface_from_eased(grids, pr->ncascades, &pr->p, &ease, err, errlen);
}

void ocean_easing(const struct ocean *o, double *t0, double *len)
{
    *t0 = o && o->g ? o->g->ease_t0 : 0;
    *len = o && o->g ? o->g->ease_len : 0;
}

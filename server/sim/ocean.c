/* ocean.c — lifetime of a simulation: create, reconfigure, step, free.
 *
 * The N-dependent state (amplitudes, spectra, outputs, FFT plan) lives in
 * struct ocean_grid so that a change of N builds a complete new grid and
 * swaps it in only when everything succeeded: on error the old one is
 * untouched. The per-step work is in ocean_step.c (FFT) and ocean_dft.c
 * (brute force); the physics in ocean_spectrum.c. */
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "ocean_internal.h"

static const char *const field_names[OCEAN_FIELD_COUNT] = {
    "height", "dx", "dz", "slope_x", "slope_z", "jacobian"};

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

void ocean_combine_jacobian_rows(struct ocean_grid *g, int r0, int r1)
{
    size_t i0 = (size_t)r0 * g->n, i1 = (size_t)r1 * g->n;
    const float *restrict xx = g->jac[0], *restrict zz = g->jac[1], *restrict xz = g->jac[2];
    float *restrict j = g->out[OCEAN_JACOBIAN];
    for (size_t i = i0; i < i1; i++)
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

/* ---- threads: a small persistent pool ------------------------------------ */

/* Workers sleep on a condition variable between jobs. A job is "open" while
 * its caller is still handing out items; a worker joins it only while it is
 * open, and the caller waits only for workers that joined. So a worker the
 * shared machine has not scheduled yet costs nothing: the caller does its
 * items and returns without waiting for it to wake up. */
struct ocean_pool;
struct pool_worker {
    struct ocean_pool *pool;
    int id;                    /* 1..threads-1; the caller is worker 0 */
};

struct ocean_pool {
    pthread_mutex_t mu;
    pthread_cond_t wake, done;
    pthread_t tid[OCEAN_MAX_THREADS];
    struct pool_worker worker[OCEAN_MAX_THREADS];
    int started;               /* workers running (ids 1..started) */
    int stop;
    unsigned long gen;         /* job number, bumped per job */
    int open, joined, limit;   /* job accepting workers; workers inside; max worker id + 1 */
    void (*fn)(void *ctx, int i0, int i1, int worker);
    void *ctx;
    int items;
    atomic_int next;           /* next item to hand out */
};

static void run_items(struct ocean_pool *pool, void (*fn)(void *, int, int, int), void *ctx, int items, int id)
{
    for (int i; (i = atomic_fetch_add_explicit(&pool->next, 1, memory_order_relaxed)) < items;)
        fn(ctx, i, i + 1, id);
}

static void *pool_thread(void *arg)
{
    const struct pool_worker wa = *(const struct pool_worker *)arg;
    struct ocean_pool *pool = wa.pool;
    unsigned long seen = 0;
    pthread_mutex_lock(&pool->mu);
    for (;;) {
        while (!pool->stop && (pool->gen == seen || !pool->open || wa.id >= pool->limit)) {
            seen = pool->gen; /* a closed or too-small job: skip it */
            pthread_cond_wait(&pool->wake, &pool->mu);
        }
        if (pool->stop)
            break;
        seen = pool->gen;
        void (*fn)(void *, int, int, int) = pool->fn;
        void *ctx = pool->ctx;
        int items = pool->items;
        pool->joined++;
        pthread_mutex_unlock(&pool->mu);
        run_items(pool, fn, ctx, items, wa.id);
        pthread_mutex_lock(&pool->mu);
        if (--pool->joined == 0)
            pthread_cond_signal(&pool->done);
    }
    pthread_mutex_unlock(&pool->mu);
    return NULL;
}

struct ocean_pool *ocean_pool_new(int threads)
{
    if (threads > OCEAN_MAX_THREADS)
        threads = OCEAN_MAX_THREADS;
    if (threads <= 1)
        return NULL;
    struct ocean_pool *pool = calloc(1, sizeof *pool);
    if (!pool)
        return NULL; /* the caller then runs everything itself */
    pthread_mutex_init(&pool->mu, NULL);
    pthread_cond_init(&pool->wake, NULL);
    pthread_cond_init(&pool->done, NULL);
    atomic_init(&pool->next, 0);
    for (int i = 1; i < threads; i++) {
        pool->worker[i] = (struct pool_worker){pool, i};
        if (pthread_create(&pool->tid[pool->started], NULL, pool_thread, &pool->worker[i]) != 0)
            break; /* fewer workers: still correct, the caller does the rest */
        pool->started++;
    }
    return pool;
}

void ocean_pool_free(struct ocean_pool *pool)
{
    if (!pool)
        return;
    pthread_mutex_lock(&pool->mu);
    pool->stop = 1;
    pthread_cond_broadcast(&pool->wake);
    pthread_mutex_unlock(&pool->mu);
    for (int i = 0; i < pool->started; i++)
        pthread_join(pool->tid[i], NULL);
    pthread_mutex_destroy(&pool->mu);
    pthread_cond_destroy(&pool->wake);
    pthread_cond_destroy(&pool->done);
    free(pool);
}

void ocean_parallel(struct ocean_pool *pool, int threads, int items,
                    void (*fn)(void *ctx, int i0, int i1, int worker), void *ctx)
{
    if (!pool || threads <= 1 || items <= 1 || pool->started == 0) {
        fn(ctx, 0, items, 0);
        return;
    }
    pthread_mutex_lock(&pool->mu);
    pool->fn = fn;
    pool->ctx = ctx;
    pool->items = items;
    pool->limit = threads;
    atomic_store_explicit(&pool->next, 0, memory_order_relaxed);
    pool->open = 1;
    pool->gen++;
    pthread_cond_broadcast(&pool->wake);
    pthread_mutex_unlock(&pool->mu); /* the unlock/lock pairs order `next` and the job's data */
    run_items(pool, fn, ctx, items, 0);
    pthread_mutex_lock(&pool->mu);
    pool->open = 0; /* all items handed out: latecomers skip this job */
    while (pool->joined > 0)
        pthread_cond_wait(&pool->done, &pool->mu);
    pthread_mutex_unlock(&pool->mu);
}

/* ---- grid: allocation, plan, amplitudes ---------------------------------- */

static void grid_free(struct ocean_grid *g)
{
    if (!g)
        return;
    ocean_fftw_lock();
    if (g->col_plan)
        fftwf_destroy_plan(g->col_plan);
    if (g->row_plan)
        fftwf_destroy_plan(g->row_plan);
    ocean_fftw_unlock();
    float *floats[] = {g->a, g->b, g->d, g->e, g->kx, g->kz};
    for (size_t i = 0; i < sizeof floats / sizeof floats[0]; i++)
        fftwf_free(floats[i]);
    fftwf_free(g->omega);
    fftwf_free(g->amp);
    for (int i = 0; i < COL_COUNT; i++)
        fftwf_free(g->col[i]);
    fftwf_free(g->scratch);
    for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
        fftwf_free(g->out[i]);
    for (int i = 0; i < 3; i++)
        fftwf_free(g->jac[i]);
    free(g);
}

static void *zalloc(size_t bytes, bool *ok)
{
    void *p = fftwf_malloc(bytes); /* SIMD-aligned, as FFTW's new-array execute needs */
    if (p)
        memset(p, 0, bytes);
    else
        *ok = false;
    return p;
}

/* Write wisdom atomically (temp file + rename) so a concurrent reader never
 * sees half a file. Failure only costs planning time on the next start. */
static void export_wisdom(const char *path)
{
    char tmp[4096];
    if (snprintf(tmp, sizeof tmp, "%s.%ld.tmp", path, (long)getpid()) >= (int)sizeof tmp)
        return;
    if (fftwf_export_wisdom_to_filename(tmp))
        rename(tmp, path);
    else
        remove(tmp);
}

size_t ocean_memory_bytes(int n, int threads)
{
    if (n < 2)
        return 0;
    size_t nh = (size_t)n / 2 + 1, modes = (size_t)n * nh, nn = (size_t)n * n;
    int tile = n / 2 < OCEAN_COL_TILE ? n / 2 : OCEAN_COL_TILE;
    int workers = threads < 1 ? 1 : threads < OCEAN_MAX_THREADS ? threads : OCEAN_MAX_THREADS;
    size_t fill_floats = ocean_tile_floats(n, tile), row_floats = (size_t)2 * OCEAN_ROW_BLOCK * nh * 2;
    size_t scratch = ((fill_floats > row_floats ? fill_floats : row_floats) + 15) & ~(size_t)15;
    /* The same arrays as grid_new, in the same order. */
    return modes * (4 * sizeof(float) + sizeof(double))                   /* a, b, d, e, omega */
         + (size_t)(n / 2 / tile) * n * sizeof(struct ocean_tile_row)      /* amp */
         + (nh + (size_t)n) * sizeof(float)                               /* kx, kz */
         + COL_COUNT * modes * 2 * sizeof(float)                          /* col */
         + (size_t)workers * scratch * sizeof(float)                      /* scratch */
         + (OCEAN_FIELD_COUNT + 3) * nn * sizeof(float);                  /* out, jac */
}

static struct ocean_grid *grid_new(int n, const struct ocean_options *opt, char *err, size_t errlen)
{
    struct ocean_grid *g = calloc(1, sizeof *g);
    if (!g) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    bool ok = true;
    g->n = n;
    g->nh = n / 2 + 1;
    g->modes = (size_t)n * g->nh;
    g->tile = n / 2 < OCEAN_COL_TILE ? n / 2 : OCEAN_COL_TILE;
    size_t nn = (size_t)n * n;
    g->a = zalloc(g->modes * sizeof(float), &ok);
    g->b = zalloc(g->modes * sizeof(float), &ok);
    g->d = zalloc(g->modes * sizeof(float), &ok);
    g->e = zalloc(g->modes * sizeof(float), &ok);
    g->omega = zalloc(g->modes * sizeof(double), &ok);
    g->amp = zalloc((size_t)(n / 2 / g->tile) * n * sizeof *g->amp, &ok);
    g->kx = zalloc((size_t)g->nh * sizeof(float), &ok);
    g->kz = zalloc((size_t)n * sizeof(float), &ok);
    for (int i = 0; i < COL_COUNT; i++)
        g->col[i] = zalloc(g->modes * 2 * sizeof(float), &ok);
    g->workers = opt->threads < OCEAN_MAX_THREADS ? opt->threads : OCEAN_MAX_THREADS;
    /* Per worker: the fill's h~, lambda/k and spectrum for one tile; or
     * two blocks of row-pass input (ROW_BLOCK x nh complex each). */
    size_t fill_floats = ocean_tile_floats(n, g->tile), row_floats = (size_t)2 * OCEAN_ROW_BLOCK * g->nh * 2;
    g->scratch_floats = fill_floats > row_floats ? fill_floats : row_floats;
    g->scratch_floats = (g->scratch_floats + 15) & ~(size_t)15; /* keep every slot 64-byte aligned */
    g->scratch = zalloc((size_t)g->workers * g->scratch_floats * sizeof(float), &ok);
    for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
        g->out[i] = zalloc(nn * sizeof(float), &ok);
    for (int i = 0; i < 3; i++)
        g->jac[i] = zalloc(nn * sizeof(float), &ok);
    if (!ok) {
        snprintf(err, errlen, "out of memory for resolution %d", n);
        grid_free(g);
        return NULL;
    }
    for (size_t j = 0; j < nn; j++) /* a flat sea until the first step: J = 1 */
        g->out[OCEAN_JACOBIAN][j] = 1.0f;

    ocean_fftw_init();
    ocean_fftw_lock();
    if (opt->wisdom_path && *opt->wisdom_path)
        fftwf_import_wisdom_from_filename(opt->wisdom_path); /* missing file is fine */
    unsigned flags = opt->plan_rigor ? FFTW_MEASURE : FFTW_ESTIMATE;
    /* MEASURE overwrites the arrays while timing: we plan before filling.
     * Both plans are small batches that our own pool's workers execute
     * (new-array execute is thread-safe), so each is planned for one FFTW
     * thread: that lets the fill share a tile's cache with its z pass, and
     * the plans do not depend on the thread count (same bits on 1 or 2).
     * Columns: `tile` in-place N-point c2c over the contiguous columns of
     * a worker's fill tile (ocean_step.c).
     * Rows: a block of N-point c2r from a worker's scratch to the output. */
    fftwf_complex *tile = (fftwf_complex *)ocean_tile_spectrum(g->scratch, n, g->tile);
    int dist = ocean_tile_dist(n);
    fftwf_plan_with_nthreads(1);
    g->col_plan = fftwf_plan_many_dft(1, &n, g->tile, tile, NULL, 1, dist, tile, NULL, 1, dist, FFTW_BACKWARD, flags);
    g->row_plan = fftwf_plan_many_dft_c2r(1, &n, OCEAN_ROW_BLOCK, (fftwf_complex *)g->scratch, NULL,
                                          OCEAN_ROW_BLOCK, 1, g->out[0], NULL, 1, n, flags);
    if (g->col_plan && g->row_plan && opt->plan_rigor && opt->wisdom_path && *opt->wisdom_path)
        export_wisdom(opt->wisdom_path);
    ocean_fftw_unlock();
    if (!g->col_plan || !g->row_plan) {
        snprintf(err, errlen, "FFTW could not plan a %dx%d transform", n, n);
        grid_free(g);
        return NULL;
    }
    return g; /* kx, kz and the amplitudes: grid_set_amplitudes */
}

struct amp_ctx {
    struct ocean_grid *g;
    const struct spectrum_model *m;
};

static void amp_rows(void *arg, int r0, int r1, int worker)
{
    struct amp_ctx *c = arg;
    struct ocean_grid *g = c->g;
    const struct spectrum_model *m = c->m;
    int n = g->n;
    double dk = 2.0 * M_PI / m->patch;
    for (int iz = r0; iz < r1; iz++) {
        int mz = iz > n / 2 ? iz - n : iz;
        for (int ix = 0; ix < g->nh; ix++) {
            size_t i = (size_t)iz * g->nh + ix;
            int mx = ix;
            /* Nyquist row and column stay zero: their -k aliases onto
             * themselves, so they could not be both hermitian and random. */
            if (ix == n / 2 || iz == n / 2) {
                g->a[i] = g->b[i] = g->d[i] = g->e[i] = 0;
                g->omega[i] = 0;
                continue;
            }
            double complex p = spectrum_h0(m, mx, mz);
            double complex q = conj(spectrum_h0(m, -mx, -mz));
            g->a[i] = (float)(creal(p) + creal(q));
            g->b[i] = (float)(cimag(p) - cimag(q));
            g->d[i] = (float)(cimag(p) + cimag(q));
            g->e[i] = (float)(creal(p) - creal(q));
            g->omega[i] = spectrum_mode_omega(m, dk * hypot(mx, mz));
        }
        for (int ix = 0; ix < n / 2; ix++) { /* the fill's copy, in tile order */
            size_t i = (size_t)iz * g->nh + ix;
            struct ocean_tile_row *t = g->amp + (size_t)(ix / g->tile) * n + iz;
            int j = ix % g->tile;
            t->a[j] = g->a[i];
            t->b[j] = g->b[i];
            t->d[j] = g->d[i];
            t->e[j] = g->e[i];
            t->omega[j] = g->omega[i];
            t->invk[j] = (float)displacement_over_k(dk * hypot(ix, mz), m->depth);
        }
    }
}

/* h~0 and w for every mode. Depends only on the parameters (the random
 * numbers on seed and integer k), so reconfiguring keeps the sea's phases. */
static void grid_set_amplitudes(struct ocean_grid *g, const struct spectrum_model *m, struct ocean_pool *pool,
                                int threads)
{
    for (int i = 0; i < g->nh; i++)
        g->kx[i] = (float)ocean_wavenumber(i, g->n, m->patch);
    for (int i = 0; i < g->n; i++)
        g->kz[i] = (float)ocean_wavenumber(i, g->n, m->patch);
    struct amp_ctx c = {g, m};
    ocean_parallel(pool, threads, g->n, amp_rows, &c);
}

/* ---- public API ------------------------------------------------------- */

struct ocean *ocean_create(const struct ocean_params *p, const struct ocean_options *opt, char *err,
                           size_t errlen)
{
    struct ocean_options o_opt = {1, NULL, 0};
    if (opt)
        o_opt = *opt;
    if (o_opt.threads < 1)
        o_opt.threads = 1;
    if (!p) {
        snprintf(err, errlen, "no parameters");
        return NULL;
    }
    if (params_validate(p, err, errlen) != 0)
        return NULL;
    struct ocean *o = calloc(1, sizeof *o);
    if (!o) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    o->p = *p;
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
    spectrum_model_init(&o->model, p);
    o->g = grid_new(p->resolution, &o->opt, err, errlen);
    if (!o->g) {
        free(o->wisdom_path);
        free(o);
        return NULL;
    }
    o->pool = ocean_pool_new(o->opt.threads); /* NULL (one thread) is fine: slower, same result */
    grid_set_amplitudes(o->g, &o->model, o->pool, o->opt.threads);
    return o;
}

int ocean_reconfigure(struct ocean *o, const struct ocean_params *p, char *err, size_t errlen)
{
    if (!o || !p) {
        snprintf(err, errlen, "no simulation or no parameters");
        return -1;
    }
    if (params_validate(p, err, errlen) != 0)
        return -1;
    struct ocean_grid *g = o->g;
    if (p->resolution != g->n) {
        g = grid_new(p->resolution, &o->opt, err, errlen);
        if (!g)
            return -1;
    }
    /* Nothing below can fail: commit. */
    o->p = *p;
    spectrum_model_init(&o->model, p);
    grid_set_amplitudes(g, &o->model, o->pool, o->opt.threads);
    if (g != o->g) {
        grid_free(o->g);
        o->g = g;
    }
    return 0;
}

int ocean_step(struct ocean *o, double t, unsigned fields)
{
    if (!o || !isfinite(t))
        return -1;
    fields &= OCEAN_ALL_FIELDS;
    if (o->p.transform == TRANSFORM_DFT)
        return ocean_step_dft(o, t, fields);
    return ocean_step_fft(o, t, fields);
}

const float *ocean_field(const struct ocean *o, enum ocean_field f)
{
    if (!o || (unsigned)f >= OCEAN_FIELD_COUNT)
        return NULL;
    return o->g->out[f];
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
    ocean_pool_free(o->pool);
    grid_free(o->g);
    free(o->wisdom_path);
    free(o);
}

/* ocean.c — lifetime of a simulation: create, prepare + commit
 * (reconfigure), step, free.
 *
 * The N-dependent state (amplitudes, spectra, outputs, FFT plans, the
 * cached per-mode normals and rings) lives in struct ocean_grid. Every
 * parameter change is prepared beside the live state (new amplitudes, or
 * for a new N a complete new grid) and swapped in by pointers only when
 * everything succeeded: on error the old state is untouched, and the
 * preparing may run on another thread than the stepping. The per-step
 * work is in ocean_step.c (FFT) and ocean_dft.c (brute force); the
 * physics in ocean_spectrum.c. */
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

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

/* The amplitude arrays a step reads: what a parameter change replaces. */
struct ocean_amps {
    float *a, *b, *d, *e;
    double *omega;
    float *ampc;
};

static void amps_free(struct ocean_amps *s)
{
    float *floats[] = {s->a, s->b, s->d, s->e};
    for (size_t i = 0; i < sizeof floats / sizeof floats[0]; i++)
        free(floats[i]);
    free(s->omega);
    free(s->ampc);
    memset(s, 0, sizeof *s);
}

/* Swap the amplitude arrays of a grid with a set (commit: O(1)). */
static void amps_swap(struct ocean_grid *g, struct ocean_amps *s)
{
    struct ocean_amps t = {g->a, g->b, g->d, g->e, g->omega, g->ampc};
    g->a = s->a;
    g->b = s->b;
    g->d = s->d;
    g->e = s->e;
    g->omega = s->omega;
    g->ampc = s->ampc;
    *s = t;
}

static void grid_free(struct ocean_grid *g)
{
    if (!g)
        return;
    ocean_fftw_lock();
    if (g->col_plan)
        fftwf_destroy_plan(g->col_plan);
    if (g->row_plan)
        fftwf_destroy_plan(g->row_plan);
    if (g->row_half_plan)
        fftwf_destroy_plan(g->row_half_plan);
    if (g->store_plan)
        fftwf_destroy_plan(g->store_plan);
    ocean_fftw_unlock();
    struct ocean_amps amps = {g->a, g->b, g->d, g->e, g->omega, g->ampc};
    amps_free(&amps);
    free(g->kx);
    free(g->kz);
    free(g->row_twiddle);
    free(g->gauss);
    free(g->ring);
    free(g->ring_m2);
    free(g->ease_from);
    for (int i = 0; i < COL_COUNT; i++)
        free(g->col[i]);
    free(g->scratch);
    for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
        free(g->out[i]);
    for (int i = 0; i < 3; i++)
        free(g->jac[i]);
    free(g);
}

_Atomic size_t ocean_alloc_bytes;

/* Every array of the library comes from here and goes back with free(). Arrays
 * of 2 MB and more are aligned to 2 MB and asked for as transparent huge pages
 * (Debian's default is THP on madvise only): at N >= 1024 the step and the
 * encode stream through 50-200 MB, and with 4 kB pages they miss the TLB on
 * nearly every new page (in a VM each miss walks two page tables). Alternated
 * daemons, make bench-capacity --base: tick 0.92-0.96x at 1024 six fields and
 * 0.90-0.96x at 2048 height; bench-step 0.79-0.97x at N >= 1024 (docs/simulation.md).
 * 64-byte alignment otherwise: FFTW's new-array execute needs SIMD alignment. */
#define HUGE_PAGE ((size_t)2 << 20)
static void *array_alloc(size_t bytes)
{
    size_t align = bytes >= HUGE_PAGE ? HUGE_PAGE : 64;
    void *p = NULL;
    if (posix_memalign(&p, align, bytes) != 0)
        return NULL;
    if (align == HUGE_PAGE)
        (void)madvise(p, bytes & ~(HUGE_PAGE - 1), MADV_HUGEPAGE); /* a hint: without THP, plain pages */
    return p;
}

static void *zalloc(size_t bytes, bool *ok)
{
    void *p = array_alloc(bytes);
    if (p) {
        memset(p, 0, bytes);
        atomic_fetch_add_explicit(&ocean_alloc_bytes, bytes, memory_order_relaxed);
    }
    else
        *ok = false;
    return p;
}

/* Not zeroed: for arrays that amps_compute writes whole (every mode, every
 * column of the copy), so a parameter change does not write them twice. */
static void *xalloc(size_t bytes, bool *ok)
{
    void *p = array_alloc(bytes);
    if (p)
        atomic_fetch_add_explicit(&ocean_alloc_bytes, bytes, memory_order_relaxed);
    else
        *ok = false;
    return p;
}

static bool amps_alloc(struct ocean_amps *s, int n)
{
    bool ok = true;
    size_t modes = (size_t)n * (n / 2 + 1);
    s->a = xalloc(modes * sizeof(float), &ok);
    s->b = xalloc(modes * sizeof(float), &ok);
    s->d = xalloc(modes * sizeof(float), &ok);
    s->e = xalloc(modes * sizeof(float), &ok);
    s->omega = xalloc(modes * sizeof(double), &ok);
    s->ampc = xalloc((size_t)(n / 2) * OCEAN_AMP_COL_FLOATS(n) * sizeof(float), &ok);
    if (!ok)
        amps_free(s);
    return ok;
}

/* Rings: the distinct values of |m|^2 = mx^2 + mz^2 over the modes of the
 * half spectrum (Nyquist row and column left out, they are zero). Marks
 * them in `seen` (one byte per value 0..max_m2) and returns their count. */
static size_t ring_mark(int n, unsigned char *seen)
{
    size_t count = 0;
    for (int iz = 0; iz < n; iz++) {
        if (iz == n / 2)
            continue;
        int mz = iz > n / 2 ? iz - n : iz;
        for (int mx = 0; mx < n / 2; mx++) {
            size_t m2 = (size_t)mx * mx + (size_t)mz * mz;
            count += !seen[m2];
            seen[m2] = 1;
        }
    }
    return count;
}

static size_t ring_max_m2(int n)
{
    size_t h = (size_t)n / 2;
    return 2 * h * h; /* bound: |mx|, |mz| <= N/2 */
}

static size_t ring_count(int n)
{
    unsigned char *seen = calloc(ring_max_m2(n) + 1, 1);
    if (!seen)
        return (size_t)n * (n / 2 + 1); /* an upper bound */
    size_t c = ring_mark(n, seen);
    free(seen);
    return c;
}

/* g->ring[mode] = index of the mode's |m|^2 in g->ring_m2 (ascending). */
static bool grid_build_rings(struct ocean_grid *g)
{
    int n = g->n;
    size_t max = ring_max_m2(n);
    unsigned char *seen = calloc(max + 1, 1);
    uint32_t *index = malloc((max + 1) * sizeof *index);
    bool ok = seen && index;
    if (ok) {
        g->rings = ring_mark(n, seen);
        g->ring_m2 = zalloc((g->rings ? g->rings : 1) * sizeof *g->ring_m2, &ok);
    }
    if (ok) {
        uint32_t r = 0;
        for (size_t m2 = 0; m2 <= max; m2++)
            if (seen[m2]) {
                index[m2] = r;
                g->ring_m2[r++] = (uint32_t)m2;
            }
        for (int iz = 0; iz < n; iz++) {
            int mz = iz > n / 2 ? iz - n : iz;
            for (int ix = 0; ix < g->nh; ix++) {
                size_t i = (size_t)iz * g->nh + ix;
                bool nyquist = ix == n / 2 || iz == n / 2;
                g->ring[i] = nyquist ? 0 : index[(size_t)ix * ix + (size_t)mz * mz];
            }
        }
    }
    free(seen);
    free(index);
    return ok;
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

int ocean_threads(int requested)
{
    if (requested == 0) {
        long cores = sysconf(_SC_NPROCESSORS_ONLN);
        requested = cores < 1 ? 1 : cores > OCEAN_MAX_THREADS ? OCEAN_MAX_THREADS : (int)cores;
    }
    return requested < 1 ? 1 : requested > OCEAN_MAX_THREADS ? OCEAN_MAX_THREADS : requested;
}

size_t ocean_memory_bytes(int n, int threads)
{
    if (n < 2)
        return 0;
    threads = ocean_threads(threads);
    size_t nh = (size_t)n / 2 + 1, modes = (size_t)n * nh, nn = (size_t)n * n;
    int tile = n / 2 < OCEAN_COL_TILE ? n / 2 : OCEAN_COL_TILE;
    int workers = threads;
    size_t fill_floats = ocean_tile_floats(n, tile), row_floats = ocean_row_scratch_floats(n);
    size_t scratch = ((fill_floats > row_floats ? fill_floats : row_floats) + 15) & ~(size_t)15;
    /* The same arrays as grid_new, in the same order. */
    return modes * (4 * sizeof(float) + sizeof(double))                   /* a, b, d, e, omega */
         + (size_t)(n / 2) * OCEAN_AMP_COL_FLOATS(n) * sizeof(float)      /* ampc */
         + (nh + (size_t)n) * sizeof(float)                               /* kx, kz */
         + (size_t)n * sizeof(float)                                      /* row_twiddle */
         + modes * (4 * sizeof(float) + sizeof(uint32_t))                 /* gauss, ring */
         + ring_count(n) * sizeof(uint32_t)                               /* ring_m2 */
         + COL_COUNT * modes * 2 * sizeof(float)                          /* col */
         + (size_t)workers * scratch * sizeof(float)                      /* scratch */
         + OCEAN_FIELD_COUNT * nn * sizeof(float);                        /* out */
}

size_t ocean_ease_memory_bytes(int n)
{
    return n >= 2 && n <= OCEAN_EASE_MAX_N ? (size_t)(n / 2) * OCEAN_EASE_COL_FLOATS(n) * sizeof(float) : 0;
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
    struct ocean_amps amps = {0};
    ok = amps_alloc(&amps, n);
    amps_swap(g, &amps);
    g->kx = zalloc((size_t)g->nh * sizeof(float), &ok);
    g->kz = zalloc((size_t)n * sizeof(float), &ok);
    g->row_twiddle = zalloc((size_t)n * sizeof(float), &ok);
    g->gauss = zalloc(g->modes * 4 * sizeof(float), &ok);
    g->ring = zalloc(g->modes * sizeof(uint32_t), &ok);
    for (int i = 0; i < COL_COUNT; i++)
        g->col[i] = zalloc(g->modes * 2 * sizeof(float), &ok);
    g->workers = opt->threads < OCEAN_MAX_THREADS ? opt->threads : OCEAN_MAX_THREADS;
    /* Per worker: the fill's h~ and spectrum for one tile; or a block of
     * row-pass input and the block's Jacobian terms. */
    size_t fill_floats = ocean_tile_floats(n, g->tile), row_floats = ocean_row_scratch_floats(n);
    g->scratch_floats = fill_floats > row_floats ? fill_floats : row_floats;
    g->scratch_floats = (g->scratch_floats + 15) & ~(size_t)15; /* keep every slot 64-byte aligned */
    g->scratch = zalloc((size_t)g->workers * g->scratch_floats * sizeof(float), &ok);
    for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
        g->out[i] = zalloc(nn * sizeof(float), &ok);
    if (ok)
        ok = grid_build_rings(g);
    if (!ok) {
        snprintf(err, errlen, "out of memory for resolution %d", n);
        grid_free(g);
        return NULL;
    }
    for (size_t j = 0; j < nn; j++) /* a flat sea until the first step: J = 1 */
        g->out[OCEAN_JACOBIAN][j] = 1.0f;
    for (int k = 0; k < n / 2; k++) { /* the row pass's e^{2 pi i k / N} (ocean_step.c, row_pretwiddle) */
        double a = 2.0 * M_PI * k / n;
        g->row_twiddle[2 * k] = (float)cos(a);
        g->row_twiddle[2 * k + 1] = (float)sin(a);
    }

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
     * Rows: a block of N/2-point c2c from a worker's scratch to the output
     * (row_half_plan: each real row as a half-length complex transform, see
     * ocean_step.c); row_plan, FFTW's own real transform, is only the
     * benchmark's and tests' reference: planned on first use
     * (ocean_reference_row_plan), not here, where measuring it without
     * wisdom took longer than the plan the daemon does run, at every start
     * and every new N, for a plan the daemon never executes.
     * Between them, the transposition: a tile's transformed columns into
     * the block-major half spectrum (see ocean_grid.col), as FFTW's own
     * rank-0 (copy-only) guru plan over three loops: T columns (in: stride
     * dist, out: B), N/B blocks (in: B, out: nh*B), B rows (1, 1). The same
     * copy as a hand-written loop (measured equal: docs/simulation.md), but
     * part of the FFTW plan set, like the transposition inside FFTW's 2-D
     * transforms. From OCEAN_STREAM_STORE_FROM_N the step copies with
     * streaming stores instead (ocean_step.c, store_tile_streaming). */
    fftwf_complex *tile = (fftwf_complex *)ocean_tile_spectrum(g->scratch, n, g->tile);
    int dist = ocean_tile_dist(n);
    const int B = OCEAN_ROW_BLOCK;
    fftwf_iodim store_dims[3] = {{g->tile, dist, B}, {n / B, B, g->nh * B}, {B, 1, 1}};
    fftwf_plan_with_nthreads(1);
    g->col_plan = fftwf_plan_many_dft(1, &n, g->tile, tile, NULL, 1, dist, tile, NULL, 1, dist, FFTW_BACKWARD, flags);
    g->plan_flags = flags;
    g->store_plan = fftwf_plan_guru_dft(0, NULL, 3, store_dims, tile, (fftwf_complex *)g->col[0], FFTW_BACKWARD, flags);
    int half = n / 2;
    g->row_half_plan = fftwf_plan_many_dft(1, &half, B, (fftwf_complex *)g->scratch, NULL, B, 1,
                                           (fftwf_complex *)g->out[0], NULL, 1, half, FFTW_BACKWARD, flags);
    bool planned = g->col_plan && g->row_half_plan && g->store_plan;
    if (planned && opt->plan_rigor && opt->wisdom_path && *opt->wisdom_path)
        export_wisdom(opt->wisdom_path);
    ocean_fftw_unlock();
    if (!planned) {
        snprintf(err, errlen, "FFTW could not plan a %dx%d transform", n, n);
        grid_free(g);
        return NULL;
    }
    return g; /* the normals, kx, kz (they depend on L) and the amplitudes: prepare() */
}

int ocean_reference_row_plan(struct ocean_grid *g)
{
    if (g->row_plan)
        return 0;
    /* Planned between a worker's scratch slots (its input block, then its
     * Jacobian terms: same sizes and alignment as the step's arrays), so
     * that measuring overwrites no field. */
    int n = g->n;
    ocean_fftw_lock();
    fftwf_plan_with_nthreads(1);
    g->row_plan = fftwf_plan_many_dft_c2r(1, &n, OCEAN_ROW_BLOCK, (fftwf_complex *)g->scratch, NULL, OCEAN_ROW_BLOCK,
                                          1, ocean_row_jacobian_terms(g->scratch, n), NULL, 1, n, g->plan_flags);
    ocean_fftw_unlock();
    return g->row_plan ? 0 : -1;
}

/* ---- amplitudes ------------------------------------------------------------ */

/* Per mode of the half spectrum, the standard normals of h~0(k) and
 * h~0(-k): a pure function of (seed, integer k), cached because the hash,
 * log and sincos are a fifth of a rebuild. */
struct gauss_ctx {
    int n, nh;
    uint32_t seed;
    float *gauss;
};

static void gauss_rows(void *arg, int r0, int r1, int worker)
{
    const struct gauss_ctx *c = arg;
    for (int iz = r0; iz < r1; iz++) {
        int mz = iz > c->n / 2 ? iz - c->n : iz;
        for (int mx = 0; mx < c->nh; mx++) {
            float *q = c->gauss + 4 * ((size_t)iz * c->nh + mx);
            double a, b, ma, mb;
            spectrum_gauss_pair(c->seed, mx, mz, &a, &b);
            spectrum_gauss_pair(c->seed, -mx, -mz, &ma, &mb);
            q[0] = (float)a;
            q[1] = (float)b;
            q[2] = (float)ma;
            q[3] = (float)mb;
        }
    }
}

static void gauss_compute(int n, uint32_t seed, float *gauss, struct ocean_pool *pool, int threads)
{
    struct gauss_ctx c = {n, n / 2 + 1, seed, gauss};
    ocean_parallel(pool, threads, n, gauss_rows, &c);
}

/* The radial table (spectrum_radial_at per ring), in `chunks` pieces. */
struct radial_ctx {
    const struct spectrum_model *m;
    const uint32_t *ring_m2;
    struct spectrum_radial *out;
    size_t rings;
    int chunks;
};

static void radial_chunks(void *arg, int c0, int c1, int worker)
{
    const struct radial_ctx *c = arg;
    double dk = 2.0 * M_PI / c->m->patch;
    size_t per = (c->rings + c->chunks - 1) / c->chunks;
    for (size_t r = (size_t)c0 * per; r < (size_t)c1 * per && r < c->rings; r++)
        spectrum_radial_at(c->m, dk * sqrt((double)c->ring_m2[r]), &c->out[r]);
}

struct amp_ctx {
    const struct ocean_grid *g;       /* n, ring */
    const struct spectrum_model *m;
    double lambda;                    /* choppiness, folded into linvk */
    const struct spectrum_radial *radial;
    const float *gauss;
    struct ocean_amps *amps;
};

/* Columns per tile of the amplitude pass (one 64-byte line of each
 * row-major array per row), and rows per block (an item). */
#define AMP_TILE 16
#define AMP_ROWS 16
#define AMP_AHEAD 2 /* rows prefetched ahead */

/* h~0(k) and h~0(-k) per mode from the radial table, the spreading's angle
 * and the cached normals; then a, b, d, e and omega (see ocean_grid) and,
 * in the same pass, the fill's column-major copy (ocean_amp_col). Items are
 * blocks of AMP_ROWS rows, done tile by tile (AMP_TILE columns, kx): the
 * row-major arrays are read and written a line per row and tile, moving
 * along the rows (a tile walked down all N rows started a new page on every
 * row of every array: a TLB and cache miss each); the block's tile is kept
 * in a small buffer and written down each column of the copy a whole cache
 * line at a time (the copy's 6 arrays per column lie a multiple of 4 KiB
 * apart: written a float at a time, 16 columns' worth fall into one L1
 * set). Until this round a row pass wrote the row-major arrays and a second
 * pass read them back column by column (stride N/2 + 1) to make the copy.
 * Same values, bit for bit. */
static void amp_tiles(void *arg, int b0, int b1, int worker)
{
    (void)worker;
    const struct amp_ctx *c = arg;
    const struct ocean_grid *g = c->g;
    const struct spectrum_model *m = c->m;
    struct ocean_amps *s = c->amps;
    const int n = g->n, nh = g->nh, rows = n < AMP_ROWS ? n : AMP_ROWS;
    const double half_dk = 0.5 * 2.0 * M_PI / m->patch, wx = cos(m->wind_angle), wz = sin(m->wind_angle);
    const double lambda = c->lambda;
    float buf[5][AMP_TILE][AMP_ROWS]; /* a, b, d, e, linvk of the block, per column */
    double wbuf[AMP_TILE][AMP_ROWS];
    const int tiles = (nh + AMP_TILE - 1) / AMP_TILE;
    for (int blk = b0; blk < b1; blk++) {
        const int z0 = blk * rows;
        for (int t = 0; t < tiles; t++) {
            const int x0 = t * AMP_TILE, x1 = x0 + AMP_TILE < nh ? x0 + AMP_TILE : nh;
            for (int iz = z0; iz < z0 + rows; iz++) {
                int mz = iz > n / 2 ? iz - n : iz;
                /* The radial table is larger than the cache at large N (40 B
                 * per ring, ~400 k rings at N = 2048) and the rings of a
                 * tile's modes lie far apart in it: ask for the entries
                 * AMP_AHEAD rows on now (past the block: the next tile's
                 * first rows). A hint; it changes no value. */
                int pz = iz + AMP_AHEAD, px0 = x0, px1 = x1;
                if (pz >= z0 + rows) {
                    pz -= rows;
                    px0 = x1;
                    px1 = x1 + AMP_TILE < nh ? x1 + AMP_TILE : nh;
                }
                for (int ix = px0; ix < px1; ix++) {
                    const struct spectrum_radial *ahead = &c->radial[g->ring[(size_t)pz * nh + ix]];
                    __builtin_prefetch(ahead);
                    __builtin_prefetch((const char *)(ahead + 1) - 1);
                }
                for (int ix = x0; ix < x1; ix++) {
                    size_t i = (size_t)iz * nh + ix;
                    int mx = ix;
                    float a = 0, b = 0, d = 0, e = 0;
                    double omega = 0;
                    /* Nyquist row and column stay zero: their -k aliases onto
                     * themselves, so they could not be both hermitian and random. */
                    if (ix != n / 2 && iz != n / 2 && spectrum_in_band(m, mx, mz)) { /* or a coarser cascade's */
                        const struct spectrum_radial *r = &c->radial[g->ring[i]];
                        double len = sqrt((double)mx * mx + (double)mz * mz);
                        double cs = len > 0 ? (mx * wx + mz * wz) / len : 0; /* cos(angle of k - wind) */
                        double psi_p = r->psi_k > 0 ? r->psi_k * spectrum_spreading_cos(m, r, cs) : 0;
                        double psi_m = r->psi_k > 0 ? r->psi_k * spectrum_spreading_cos(m, r, -cs) : 0;
                        double ap = psi_p > 0 ? half_dk * sqrt(psi_p) : 0, am = psi_m > 0 ? half_dk * sqrt(psi_m) : 0;
                        const float *q = c->gauss + 4 * i;
                        /* p = h~0(k), conj(h~0(-k)) = mr - i mi */
                        double pr = ap * q[0], pi = ap * q[1], mr = am * q[2], mi = -am * q[3];
                        a = (float)(pr + mr);
                        b = (float)(pi - mi);
                        d = (float)(pi + mi);
                        e = (float)(pr - mr);
                        omega = r->omega;
                    }
                    s->a[i] = a;
                    s->b[i] = b;
                    s->d[i] = d;
                    s->e[i] = e;
                    s->omega[i] = omega;
                    if (ix == n / 2)
                        continue; /* the Nyquist column has no column-major copy */
                    const int x = ix - x0, z = iz - z0;
                    buf[0][x][z] = a;
                    buf[1][x][z] = b;
                    buf[2][x][z] = d;
                    buf[3][x][z] = e;
                    /* the fill's 1/k factor: every row but the Nyquist one, in band or not */
                    buf[4][x][z] = iz == n / 2 ? 0.0f : (float)(lambda * c->radial[g->ring[i]].disp);
                    wbuf[x][z] = omega;
                }
            }
            const int xc = x1 < n / 2 ? x1 : n / 2; /* columns with a copy */
            for (int ix = x0; ix < xc; ix++) {
                float *col = ocean_amp_col(s->ampc, n, ix);
                for (int k = 0; k < 5; k++)
                    memcpy(col + (size_t)k * n + z0, buf[k][ix - x0], (size_t)rows * sizeof(float));
                memcpy((double *)(col + 5 * (size_t)n) + z0, wbuf[ix - x0], (size_t)rows * sizeof(double));
            }
        }
    }
}

/* h~0 and w for every mode into `amps`, for grid g's N and rings, from the
 * normals `gauss`. Depends only on the parameters (the random numbers on
 * seed and integer k), so reconfiguring keeps the sea's phases. Returns
 * false without memory for the radial table. */
static bool amps_compute(const struct ocean_grid *g, const struct spectrum_model *m, double lambda,
                         const float *gauss, struct ocean_amps *amps, struct ocean_pool *pool, int threads)
{
    struct spectrum_radial *radial = malloc((g->rings ? g->rings : 1) * sizeof *radial);
    if (!radial)
        return false;
    struct radial_ctx rc = {m, g->ring_m2, radial, g->rings, 64};
    ocean_parallel(pool, threads, rc.chunks, radial_chunks, &rc);
    struct amp_ctx c = {g, m, lambda, radial, gauss, amps};
    ocean_parallel(pool, threads, g->n < AMP_ROWS ? 1 : g->n / AMP_ROWS, amp_tiles, &c);
    free(radial);
    return true;
}

/* ---- parameter changes: prepare, commit ------------------------------------- */

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
    unsigned long generation;  /* o->generation prepared against */
    bool easable;              /* only the amplitudes h~0 (and choppiness) change: ocean_commit_eased may ease */
};

void ocean_prepared_free(struct ocean_prepared *pr)
{
    if (!pr)
        return;
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++) {
        grid_free(pr->c[c].grid);
        amps_free(&pr->c[c].amps);
        free(pr->c[c].gauss);
        free(pr->c[c].ease_from);
    }
    free(pr);
}

static void set_k_tables(struct ocean_grid *g, double patch)
{
    for (int i = 0; i < g->nh; i++)
        g->kx[i] = (float)ocean_wavenumber(i, g->n, patch);
    for (int i = 0; i < g->n; i++)
        g->kz[i] = (float)ocean_wavenumber(i, g->n, patch);
}

/* The live grid of cascade c, or NULL. */
static struct ocean_grid *cascade_grid(const struct ocean *o, int c)
{
    return c == 0 ? o->g : c < o->ncascades ? o->fine[c] : NULL;
}

/* One cascade's share of prepare(): beside its live grid g (read only; NULL
 * for a cascade the change adds). */
static bool prepare_cascade(const struct ocean *o, const struct ocean_params *p, int c, struct cascade_prep *cp,
                            struct ocean_pool *pool, int threads, char *err, size_t errlen)
{
    spectrum_model_cascade(&cp->model, p, c);
    cp->seed = cp->model.seed;
    const struct ocean_grid *g = cascade_grid(o, c);
    if (!g || g->n != p->resolution) {
        cp->grid = grid_new(p->resolution, &o->opt, err, errlen);
        if (!cp->grid)
            return false;
        cp->grid->seed = cp->seed;
        gauss_compute(cp->grid->n, cp->seed, cp->grid->gauss, pool, threads);
        set_k_tables(cp->grid, cp->model.patch);
        struct ocean_amps amps = {cp->grid->a, cp->grid->b, cp->grid->d, cp->grid->e, cp->grid->omega,
                                  cp->grid->ampc};
        if (!amps_compute(cp->grid, &cp->model, p->choppiness, cp->grid->gauss, &amps, pool, threads))
            goto oom;
        return true;
    }
    if (!amps_alloc(&cp->amps, g->n))
        goto oom;
    const float *gauss = g->gauss;
    if (cp->seed != g->seed) {
        bool ok = true;
        cp->gauss = zalloc(g->modes * 4 * sizeof(float), &ok);
        if (!ok)
            goto oom;
        gauss_compute(g->n, cp->seed, cp->gauss, pool, threads);
        gauss = cp->gauss;
    }
    if (!amps_compute(g, &cp->model, p->choppiness, gauss, &cp->amps, pool, threads))
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
        const struct ocean_grid *g = cascade_grid(o, c);
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
        const struct ocean_grid *g = cascade_grid(o, c);
        if (!g->ease_from) {
            bool ok = true;
            pr->c[c].ease_from = xalloc((size_t)(g->n / 2) * OCEAN_EASE_COL_FLOATS(g->n) * sizeof(float), &ok);
            if (!ok)
                return false;
        }
    }
    pr->easable = true;
    return true;
}

/* Everything new parameters need, beside the live grids (read only). */
static struct ocean_prepared *prepare(const struct ocean *o, const struct ocean_params *p, struct ocean_pool *pool,
                                      int threads, char *err, size_t errlen)
{
    if (params_validate(p, err, errlen) != 0)
        return NULL;
    struct ocean_prepared *pr = calloc(1, sizeof *pr);
    if (!pr) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    pr->p = *p;
    pr->ncascades = p->cascades;
    pr->generation = o->generation;
    for (int c = 0; c < pr->ncascades; c++)
        if (!prepare_cascade(o, p, c, &pr->c[c], pool, threads, err, errlen)) {
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
    if (!o || !p) {
        snprintf(err, errlen, "no simulation or no parameters");
        return NULL;
    }
    /* Not o->pool: that one is the stepping thread's. Made on first use
     * (only this function touches it; prepares must not overlap). */
    if (!o->prep_pool && o->opt.threads > 1)
        o->prep_pool = ocean_pool_new(o->opt.threads);
    return prepare(o, p, o->prep_pool, o->opt.threads, err, errlen);
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
    ocean_parallel(o->pool, threads, 8, ease_columns, &c);
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
        struct ocean_grid *g = cascade_grid(o, c);
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
        amps_swap(g, &cp->amps);
        if (cp->gauss) {
            float *t = g->gauss;
            g->gauss = cp->gauss;
            cp->gauss = t;
            uint32_t s = g->seed;
            g->seed = cp->seed;
            cp->seed = s;
        }
        set_k_tables(g, cp->model.patch); /* N + 1 floats */
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
        view[c] = *cascade_grid(o, c);
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
        const struct ocean_grid *g = cascade_grid(o, c);
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

/* ---- public API ------------------------------------------------------- */

struct ocean *ocean_create(const struct ocean_params *p, const struct ocean_options *opt, char *err,
                           size_t errlen)
{
    struct ocean_options o_opt = {1, NULL, 0};
    if (opt)
        o_opt = *opt;
    o_opt.threads = ocean_threads(o_opt.threads);
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
    struct ocean_prepared *pr = prepare(o, p, o->pool, o->opt.threads, err, errlen);
    if (!pr) {
        ocean_pool_free(o->pool);
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
    if (!o || !p) {
        snprintf(err, errlen, "no simulation or no parameters");
        return -1;
    }
    struct ocean_prepared *pr = prepare(o, p, o->pool, o->opt.threads, err, errlen);
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
            g->jac[i] = zalloc((size_t)g->n * g->n * sizeof(float), &ok);
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
    struct ocean_grid *g = cascade_grid(o, cascade);
    float *mine = g->out[f];
    g->out[f] = *buf;
    *buf = mine;
    return 0;
}

float *ocean_field_buffer_new(int n)
{
    bool ok = true;
    return n > 0 ? zalloc((size_t)n * n * sizeof(float), &ok) : NULL;
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
    ocean_pool_free(o->prep_pool);
    grid_free(o->g);
    for (int c = 1; c < OCEAN_MAX_CASCADES; c++)
        grid_free(o->fine[c]);
    free(o->wisdom_path);
    free(o);
}

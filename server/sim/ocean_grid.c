/* ocean_grid.c — the N-dependent state of a simulation (struct ocean_grid):
 * the library's array allocator, the grid's arrays, its rings of equal |k|
 * and its FFTW plans, made once per grid (here, under the planner's lock)
 * and executed by every step (ocean_step.c). What fills the arrays with
 * amplitudes is ocean_amplitudes.c; who swaps grids in, ocean_prepare.c. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "ocean_internal.h"

void ocean_amps_free(struct ocean_amps *s)
{
    float *floats[] = {s->a, s->b, s->d, s->e};
    for (size_t i = 0; i < sizeof floats / sizeof floats[0]; i++)
        free(floats[i]);
    free(s->omega);
    free(s->ampc);
    memset(s, 0, sizeof *s);
}

/* Swap the amplitude arrays of a grid with a set (commit: O(1)). */
void ocean_amps_swap(struct ocean_grid *g, struct ocean_amps *s)
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

void ocean_grid_free(struct ocean_grid *g)
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
    ocean_amps_free(&amps);
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

void *ocean_zalloc(size_t bytes, bool *ok)
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

/* Not zeroed: for arrays that ocean_amps_compute writes whole (every mode, every
 * column of the copy), so a parameter change does not write them twice. */
void *ocean_xalloc(size_t bytes, bool *ok)
{
    void *p = array_alloc(bytes);
    if (p)
        atomic_fetch_add_explicit(&ocean_alloc_bytes, bytes, memory_order_relaxed);
    else
        *ok = false;
    return p;
}

bool ocean_amps_alloc(struct ocean_amps *s, int n)
{
    bool ok = true;
    size_t modes = (size_t)n * (n / 2 + 1);
    s->a = ocean_xalloc(modes * sizeof(float), &ok);
    s->b = ocean_xalloc(modes * sizeof(float), &ok);
    s->d = ocean_xalloc(modes * sizeof(float), &ok);
    s->e = ocean_xalloc(modes * sizeof(float), &ok);
    s->omega = ocean_xalloc(modes * sizeof(double), &ok);
    s->ampc = ocean_xalloc((size_t)(n / 2) * OCEAN_AMP_COL_FLOATS(n) * sizeof(float), &ok);
    if (!ok)
        ocean_amps_free(s);
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
        g->ring_m2 = ocean_zalloc((g->rings ? g->rings : 1) * sizeof *g->ring_m2, &ok);
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
    /* The same arrays as ocean_grid_new, in the same order. */
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

struct ocean_grid *ocean_grid_new(int n, const struct ocean_options *opt, char *err, size_t errlen)
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
    ok = ocean_amps_alloc(&amps, n);
    ocean_amps_swap(g, &amps);
    g->kx = ocean_zalloc((size_t)g->nh * sizeof(float), &ok);
    g->kz = ocean_zalloc((size_t)n * sizeof(float), &ok);
    g->row_twiddle = ocean_zalloc((size_t)n * sizeof(float), &ok);
    g->gauss = ocean_zalloc(g->modes * 4 * sizeof(float), &ok);
    g->ring = ocean_zalloc(g->modes * sizeof(uint32_t), &ok);
    for (int i = 0; i < COL_COUNT; i++)
        g->col[i] = ocean_zalloc(g->modes * 2 * sizeof(float), &ok);
    g->workers = opt->threads < OCEAN_MAX_THREADS ? opt->threads : OCEAN_MAX_THREADS;
    /* Per worker: the fill's h~ and spectrum for one tile; or a block of
     * row-pass input and the block's Jacobian terms. */
    size_t fill_floats = ocean_tile_floats(n, g->tile), row_floats = ocean_row_scratch_floats(n);
    g->scratch_floats = fill_floats > row_floats ? fill_floats : row_floats;
    g->scratch_floats = (g->scratch_floats + 15) & ~(size_t)15; /* keep every slot 64-byte aligned */
    g->scratch = ocean_zalloc((size_t)g->workers * g->scratch_floats * sizeof(float), &ok);
    for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
        g->out[i] = ocean_zalloc(nn * sizeof(float), &ok);
    if (ok)
        ok = grid_build_rings(g);
    if (!ok) {
        snprintf(err, errlen, "out of memory for resolution %d", n);
        ocean_grid_free(g);
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
        ocean_grid_free(g);
        return NULL;
    }
    return g; /* the normals, kx, kz (they depend on L) and the amplitudes: ocean_prepare_on() */
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

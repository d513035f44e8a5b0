/* ocean_internal.h — the inside of struct ocean, shared by ocean*.c, the
 * tests and the benchmark. Not part of the daemon's contract (ocean.h). */
#ifndef OCEAND_OCEAN_INTERNAL_H
#define OCEAND_OCEAN_INTERNAL_H

#include <complex.h>
#include <stdbool.h>
#include <stdint.h>
#include <fftw3.h>

#include "ocean.h"
#include "ocean_spectrum.h"
#include "sea_model.h"
#include "pool.h"

/* The real fields that go through an inverse FFT. Output fields map onto
 * them; the Jacobian needs three (dDx/dx, dDz/dz, dDx/dz = dDz/dx). */
enum ocean_transform { TR_H, TR_DX, TR_DZ, TR_SX, TR_SZ, TR_JXX, TR_JZZ, TR_JXZ, TR_COUNT };

/* The 2-D inverse FFT is done as two 1-D passes: along z (columns, one per
 * kx), then along x (rows, c2r). A factor that depends on kx only commutes
 * with the z pass, so the eight fields need only five z passes, over these
 * spectra (constants folded in); the kx factor is applied before the row pass:
 *   COL_H       h~              -> height (1), slope_x (i kx)
 *   COL_KZ      i kz h~         -> slope_z (1)
 *   COL_INVK    lambda h~/k     -> Dx (i kx), dDx/dx (-kx^2)
 *   COL_KZINVK  i lambda kz h~/k -> Dz (1), dDx/dz (i kx)
 *   COL_KZ2INVK -lambda kz^2 h~/k -> dDz/dz (1)
 * ("1/k" is coth(kD)/k throughout: displacement_over_k, depth D.) */
enum ocean_column { COL_H, COL_KZ, COL_INVK, COL_KZINVK, COL_KZ2INVK, COL_COUNT };
#define OCEAN_ROW_BLOCK 8    /* rows per c2r batch (measured: 8 beats 4 and 16) */
#define OCEAN_COL_TILE 16    /* kx columns per fill + z-pass tile (fewer if N/2 < 16) */
#define OCEAN_MAX_THREADS 64
#define OCEAN_THREADS_FROM_N 256 /* smaller grids run on one thread (at 128 a second thread did not pay, measured) */
/* From this N the z pass stores its tiles with non-temporal stores
 * (store_tile_streaming: the five spectra, 5 MB at 512 and 21 MB at 1024,
 * are read back by the row pass only after the whole z pass): a six-field
 * step x0.91-0.96 at 512-2048; at 256, where they stay in cache, x1.02-1.08,
 * so FFTW's copy stays there (make bench-step, "store" rows). */
#define OCEAN_STREAM_STORE_FROM_N 512
/* From this N the row pass writes the fields with non-temporal stores too
 * (store_rows_streaming): six fields are 24 MB at 1024, most of the cache,
 * and the reads before each write went to memory. In the daemon, alternated
 * run by run (make bench-capacity --base): tick x0.93 at 1024 h/dx/dz and
 * x0.96 at 2048 h/dx/dz; at 512 (6 MB, still in cache when the encode reads
 * it) x1.04 with the encode x1.04 slower, so 512 keeps ordinary stores. */
#define OCEAN_STREAM_OUT_FROM_N 1024

/* The fill's copy of the amplitudes, one kx column (ix < N/2) after the
 * other, each column-major along kz: a, b, d, e (as below), linvk =
 * lambda coth(kD)/k (0 at k = 0; lambda folded in, so the step needs no
 * division, square root or scaling), each N floats, then omega, N doubles.
 * A tile's columns are one sequential stream, and the fill writes h~ down
 * a column with no transposition. */
#define OCEAN_AMP_COL_FLOATS(n) (7 * (size_t)(n)) /* 5 float + 1 double arrays of N */
static inline float *ocean_amp_col(float *ampc, int n, int ix) { return ampc + (size_t)ix * OCEAN_AMP_COL_FLOATS(n); }
#define OCEAN_EASE_COL_FLOATS(n) (4 * (size_t)(n)) /* a, b, d, e of a column */
static inline float *ocean_ease_col(float *from, int n, int ix) { return from + (size_t)ix * OCEAN_EASE_COL_FLOATS(n); }

/* The easing's weight at sim time t of a change eased in over [t0, t0 +
 * len]: 0 (the old amplitudes) up to t0, 1 (the new) from t0 + len on,
 * linear between (a temporal predictor extrapolates a linear ramp exactly
 * but at its two ends; docs/simulation.md "Easing" has the measurement).
 * One function for the step and the query snapshots: the same float. */
static inline float ocean_ease_weight(double t0, double len, double t)
{
    if (!(len > 0))
        return 1.0f;
    double u = (t - t0) / len;
#ifdef OCEAN_EASE_SMOOTH /* measurement only (docs/simulation.md "Easing"): smoothstep */
    u = u >= 1 ? 1 : u > 0 ? u * u * (3 - 2 * u) : 0;
#endif
    return u >= 1 ? 1.0f : u > 0 ? (float)u : 0.0f;
}
/* One amplitude during an easing: from + w (to - from), in float. */
static inline float ocean_ease_mix(float from, float to, float w) { return from + w * (to - from); }
/* d(weight)/dt at t: 1/len inside the ramp, 0 outside (the query's time
 * derivatives include it: an amplitude changing by half over 8 ticks moves
 * the heave rate of an 8 s swell by more than its own oscillation does). */
static inline double ocean_ease_rate(double t0, double len, double t)
{
    if (!(len > 0))
        return 0;
    double u = (t - t0) / len;
    if (!(u > 0 && u < 1))
        return 0;
#ifdef OCEAN_EASE_SMOOTH
    return 6 * u * (1 - u) / len;
#else
    return 1 / len;
#endif
}

/* Within a column: a = col, b = col + N, d = col + 2N, e = col + 3N,
 * linvk = col + 4N, omega = (double *)(col + 5N). */

/* Everything whose size depends on N: made together, swapped together.
 * Who writes and who reads (ocean.h: one thread steps and commits, the
 * stepping thread; another may prepare meanwhile, the preparing thread):
 *   n, nh, tile, modes, ring*, rings, workers, scratch_floats, row_twiddle,
 *     the plans, plan_flags: ocean_grid_new (ocean_grid.c), once; read by all.
 *   a, b, d, e, omega, ampc, gauss, seed, kx, kz: a new grid's filled by the
 *     preparing thread (ocean_prepare.c, ocean_amplitudes.c) before anyone
 *     else sees it; a live grid's swapped in by ocean_commit (stepping
 *     thread); read by the step, the DFT path and the preparing thread
 *     (the next change, query snapshots), which never overlaps a commit.
 *   ease_*: ocean_commit_eased (stepping thread); read by the step and by
 *     ocean_prepared_surface (preparing thread, not during a commit).
 *   col, scratch, jac: the step's own (each worker its items' parts).
 *   out: written by the step; read by the caller between steps, swapped by
 *     ocean_exchange_cascade_field (stepping thread). */
struct ocean_grid {
    int n, nh;                 /* N, N/2 + 1 (columns of the half spectrum) */
    int tile;                  /* OCEAN_COL_TILE, or N/2 if smaller */
    size_t modes;              /* n * nh */
    /* Per mode of the half spectrum (row iz = kz index, column ix = kx index
     * 0..N/2, index iz*nh + ix), from h~0(k) = p and conj(h~0(-k)) = m:
     *   hr = a c + b s, hi = d c - e s, with c, s = cos, sin(w t)
     * a = pr + mr, b = pi - mi, d = pi + mi, e = pr - mr. */
    float *a, *b, *d, *e;
    double *omega;             /* rad/s, per mode */
    float *kx, *kz;            /* rad/m, per column / per row (layout formula) */
    /* What a parameter change keeps (ocean_prepare.c): per mode, the four
     * standard normals of h~0(k) and h~0(-k) for `seed` (xi_r, xi_i of +k,
     * of -k), and its ring: the index of |m|^2 = mx^2 + mz^2 in ring_m2
     * (ascending, `rings` distinct values), since all of Psi but the
     * spreading's angle depends on |k| alone. */
    float *gauss;
    uint32_t seed;
    uint32_t *ring, *ring_m2;
    size_t rings;
    /* The same amplitudes as the fill reads them: OCEAN_AMP_COL_FLOATS(N)
     * per column ix = 0 .. N/2-1 (the Nyquist column, zero, left out), see
     * ocean_amp_col. */
    float *ampc;
    /* Easing (ocean_commit_eased, docs/simulation.md "Easing"): while
     * ease_len > 0, a step at time t reads per mode the amplitudes
     * ocean_ease_mix(from, to, ocean_ease_weight(ease_t0, ease_len, t)),
     * `to` being a, b, d, e above and `from` these: OCEAN_EASE_COL_FLOATS(N)
     * per column ix = 0 .. N/2-1 (a, b, d, e of the column, N floats each,
     * as in ampc). Allocated by the first eased change and kept (reused by
     * the next); NULL before. */
    float *ease_from;
    double ease_t0, ease_len;  /* s of sim time; ease_len 0: no easing */
    /* z-pass spectra (after the z pass), block-major: the values of rows
     * iz = b*B + r (B = OCEAN_ROW_BLOCK) are at col[k][2*((b*nh + ix)*B + r)],
     * so a block of B rows is one contiguous piece that row_plan reads as
     * is (B interleaved c2r inputs). The Nyquist column ix = N/2 is zero. */
    float *col[COL_COUNT];
    float *out[OCEAN_FIELD_COUNT];
    /* dDx/dx, dDz/dz, dDx/dz before combining, whole fields: NULL unless
     * ocean_keep_jacobian_terms (tests) asked for them. Otherwise the FFT
     * path transforms a row block's three terms into the worker's scratch
     * and combines them there while they are in cache (no 3 N x N arrays
     * written and read back), and the DFT path uses a temporary. */
    float *jac[3];
    /* Per worker, scratch_floats each (64-byte aligned): stage 1, a fill
     * tile (ocean_tile_floats); stage 2, one row block of kx-factored
     * input (ROW_BLOCK x nh complex), then the block's three Jacobian
     * terms and a field's block of rows before its streaming store
     * (ROW_BLOCK x N floats each): ocean_row_scratch_floats. */
    float *scratch;
    size_t scratch_floats;
    int workers;               /* scratch slots */
    fftwf_plan col_plan;       /* in place, `tile` contiguous N-point c2c (one thread each) */
    fftwf_plan store_plan;     /* rank 0 (a copy): a transformed tile -> its columns of col[k]
                                * (below OCEAN_STREAM_STORE_FROM_N; the reference's at every N) */
    fftwf_plan row_half_plan;  /* OCEAN_ROW_BLOCK N/2-point c2c along x, input interleaved (stride
                                * ROW_BLOCK), rows out contiguous: each real row of N as N/2
                                * complex (ocean_step.c, row_pretwiddle; one thread each) */
    float *row_twiddle;        /* cos, sin of 2 pi k / N for k < N/2 (row_pretwiddle) */
    fftwf_plan row_plan;       /* OCEAN_ROW_BLOCK N-point c2r, same layouts: FFTW's own real
                                * transform, the reference's (OCEAN_ROWS_C2R); NULL until
                                * ocean_reference_row_plan */
    unsigned plan_flags;       /* FFTW_MEASURE or FFTW_ESTIMATE, as the grid's plans were made */
};

/* The library's threads are instances of the program's one work pool
 * (server/common/pool.h): `threads` - 1 pool threads beside the caller,
 * whose parallel-for (pool_for) hands items out one at a time from a
 * shared counter, so a thread that the (shared) machine deschedules does
 * not hold up the others; which thread does an item never changes its
 * result; worker numbers 0..threads-1 index the grid's scratch slots.
 * NULL for one thread (pool_for then runs everything on the caller). */
static inline struct pool *ocean_pool_new(int threads)
{
    return threads > 1 ? pool_new((threads < OCEAN_MAX_THREADS ? threads : OCEAN_MAX_THREADS) - 1) : NULL;
}

/* Who writes and who reads: opt, wisdom_path, pool: ocean_create, then
 * read only. p, model, g, ncascades, fine*, sea, generation: written only by
 * ocean_create and the commit (stepping thread); read by the step and by
 * the preparing thread (ocean_prepare, never during a commit). prep_pool:
 * the preparing thread's alone. foam_*: the step's (ocean_foam.c); the
 * commit clears foam_warm with a new grid. */
struct ocean {
    struct ocean_params p;
    struct ocean_options opt;  /* opt.wisdom_path points at our own copy */
    char *wisdom_path;
    struct spectrum_model model;
    struct ocean_grid *g;      /* cascade 0; ocean_step_fft/_dft step g under `model` */
    /* Cascades 1 .. ncascades-1 ([0] unused): their grids and models. A
     * cascade is stepped on its own grid and model (ocean.c, step_cascade:
     * ocean_step_fft_grid / ocean_step_dft_grid), so stepping writes
     * nothing of struct ocean but the foam's fields. */
    int ncascades;
    struct ocean_grid *fine[OCEAN_MAX_CASCADES];
    struct spectrum_model fine_model[OCEAN_MAX_CASCADES];
    struct pool *pool;         /* opt.threads - 1 pool threads; NULL for one thread. Made by
                                * ocean_create; used by the stepping thread (step, commit's easing) */
    struct pool *prep_pool;    /* ocean_prepare's own (the preparing thread's), made on its first call */
    unsigned long generation;  /* commits so far: a prepare made before the last one is stale */
    /* The measured sea in force (ocean_create_sea, ocean_prepare_sea), immutable; NULL if none
     * was given. Kept while another spectrum is in force (a later "measured" reuses it);
     * replaced only by the commit of a change that brings a new one. The models of a
     * "measured" sea point at it. */
    struct sea_model *sea;
    /* Foam (ocean_foam.c): the state is g->out[OCEAN_FOAM] itself. */
    double foam_time;          /* t of the last foam step */
    bool foam_warm;            /* g->out[OCEAN_FOAM] holds history up to foam_time */
};

/* One foam update, from the Jacobian just computed: foam = max(foam *
 * decay, clamp((threshold - J) * inv_ramp, 0, 1)) per sample. The FFT path
 * applies it per row block right after the block's Jacobian (in cache). */
struct ocean_foam_update {
    float decay, threshold, inv_ramp;
};
void ocean_foam_samples(const struct ocean_foam_update *u, const float *J, float *foam, size_t count);

/* Foam model constants (ocean_foam.c, docs/simulation.md "Foam"). */
#define FOAM_TAU 3.0            /* s, e-folding time of foam after breaking */
#define FOAM_RAMP 0.1           /* J this far below the threshold injects full foam */
#define FOAM_SPINUP_STEP 0.25   /* s, lattice of a cold start's history */
#define FOAM_SPINUP_STEPS 20    /* ...that many steps: 5 s, covered foam (>= 0.5) lives ~2 s */
#define FOAM_SPINUP_TIME (FOAM_SPINUP_STEP * FOAM_SPINUP_STEPS)
/* The Jacobian threshold of breaking at wind speed U10 (m/s). */
double ocean_foam_threshold(double wind_speed);
/* ocean_step's body: the step on p.transform's path, plus the foam. */
int ocean_step_with_foam(struct ocean *o, double t, unsigned fields);

/* Test hook: bytes ever allocated for the library's arrays (grids,
 * amplitudes, normals), summed; never decreases. */
extern _Atomic size_t ocean_alloc_bytes;

/* Transforms needed for an OCEAN_FIELD_BIT mask. */
unsigned ocean_transforms_for(unsigned fields);

/* The FFT path and the brute-force path, whatever p.transform says.
 * ocean_step_fft_foam also updates the foam (fields must include the
 * Jacobian); foam may be NULL. */
int ocean_step_fft(struct ocean *o, double t, unsigned fields);
int ocean_step_fft_foam(struct ocean *o, double t, unsigned fields, const struct ocean_foam_update *foam);
int ocean_step_dft(struct ocean *o, double t, unsigned fields);
/* The same on a given grid and model (a finer cascade's): o supplies only the
 * pool, the parameters shared by every cascade (choppiness, loop period) and
 * the transform; o itself is not written. */
int ocean_step_fft_grid(struct ocean *o, struct ocean_grid *g, double t, unsigned fields,
                        const struct ocean_foam_update *foam);
int ocean_step_dft_grid(struct ocean *o, struct ocean_grid *g, const struct spectrum_model *m, double t,
                        unsigned fields);
/* Only the FFTW executes the step for these fields would run, on whatever
 * the buffers hold (benchmark). */
void ocean_fft_only(struct ocean *o, unsigned fields);
/* Benchmark: a step (no foam) without some of our own parts, to see what
 * each costs: the fill (h~(k,t): phases, amplitudes), the z-pass spectra
 * (kz and 1/k factors), the kx factors of the row pass (and the Nyquist
 * clear), the Jacobian. OCEAN_STORE_FFTW: ordinary stores at every N, the
 * z pass's tiles with FFTW's copy plan and the row pass's output written by
 * FFTW itself (the streaming stores are ours too).
 * OCEAN_ROWS_C2R: the row pass with FFTW's real transform (row_plan)
 * instead of our half-length split (row_pretwiddle + row_half_plan). All
 * of them: ocean_fft_only, FFTW alone doing the same transforms.
 * OCEAN_STORE_STREAMING (benchmark, tests): the streaming stores at every N. */
enum { OCEAN_SKIP_FILL = 1, OCEAN_SKIP_SPECTRA = 2, OCEAN_SKIP_FACTORS = 4, OCEAN_SKIP_JACOBIAN = 8,
       OCEAN_STORE_FFTW = 16, OCEAN_ROWS_C2R = 32, OCEAN_SKIP_ALL = 63, OCEAN_STORE_STREAMING = 64 };
void ocean_step_parts(struct ocean *o, double t, unsigned fields, unsigned skip);
/* Plans g->row_plan (the reference's c2r) if it is not there yet: 0, or -1
 * if FFTW cannot. Benchmark and tests only; not while g is being stepped. */
int ocean_reference_row_plan(struct ocean_grid *g);

/* Reference spectrum of transform tr at time t over the full N x N grid,
 * out[iz*N + ix] for k = (kx(ix), kz(iz)), computed in double from the
 * spectrum model (independently of the fast path's stored amplitudes). */
void ocean_reference_spectrum(const struct ocean *o, double t, enum ocean_transform tr,
                              double complex *out);
/* The same for grid g under model m (a finer cascade's). */
void ocean_reference_spectrum_of(const struct ocean *o, const struct ocean_grid *g, const struct spectrum_model *m,
                                 double t, enum ocean_transform tr, double complex *out);
/* Time at which the phases are evaluated: t, or t wrapped into
 * [0, loop_period) so that a looping sea is exactly periodic. */
double ocean_phase_time(const struct ocean *o, double t);
/* j = (1 + dDx/dx)(1 + dDz/dz) - (dDx/dz)^2 for `count` samples. */
void ocean_combine_jacobian(float *j, const float *xx, const float *zz, const float *xz, size_t count);
/* Test hook: keep the three Jacobian terms as whole fields in g->jac (for
 * ocean_transform_dest) from the next step on. 0, or -1 out of memory. */
int ocean_keep_jacobian_terms(struct ocean *o);
/* A stage-2 worker's scratch: floats, and where its Jacobian terms start. */
size_t ocean_row_scratch_floats(int n);
float *ocean_row_jacobian_terms(float *scratch, int n);
/* Output array that transform tr lands in. */
float *ocean_transform_dest(struct ocean_grid *g, enum ocean_transform tr);

/* Layout of a worker's fill scratch (ocean_step.c): its size in floats,
 * where its spectrum (col_plan's array) starts, and that one's column stride. */
size_t ocean_tile_floats(int n, int tile);
float *ocean_tile_spectrum(float *scratch, int n, int tile);
int ocean_tile_dist(int n);

/* Wavenumber of index i on an N grid of side L: 2 pi (i - N [i > N/2]) / L. */
double ocean_wavenumber(int i, int n, double patch);

/* ocean_grid.c: the library's arrays and grids. Every array comes from
 * ocean_zalloc (zeroed) or ocean_xalloc (not: for arrays written whole
 * before they are read), counted in ocean_alloc_bytes, and goes back with
 * free(); *ok becomes false when one fails (so a run of allocations is
 * checked once). */
void *ocean_zalloc(size_t bytes, bool *ok);
void *ocean_xalloc(size_t bytes, bool *ok);
/* The amplitude arrays a step reads: what a parameter change replaces.
 * Written by ocean_amps_compute (the preparing thread); swapped into the
 * grid by the commit (the stepping thread); read by the step. */
struct ocean_amps {
    float *a, *b, *d, *e;
    double *omega;
    float *ampc;
};
bool ocean_amps_alloc(struct ocean_amps *s, int n);
void ocean_amps_free(struct ocean_amps *s);
/* Swap the amplitude arrays of a grid with a set (commit: O(1)). */
void ocean_amps_swap(struct ocean_grid *g, struct ocean_amps *s);
/* A grid for N: every array, the rings, the FFTW plans (planned here, once,
 * under ocean_fftw_lock); amplitudes, normals and wavenumbers are left for
 * the caller (ocean_prepare.c). NULL with err on failure. */
struct ocean_grid *ocean_grid_new(int n, const struct ocean_options *opt, char *err, size_t errlen);
void ocean_grid_free(struct ocean_grid *g);

/* ocean_amplitudes.c: the fill of a parameter change, on the preparing
 * thread and its pool (threads as for pool_for). The normals of (seed,
 * k) into gauss (4 floats per mode); h~0 and w for every mode of grid g
 * into amps (false: no memory for the radial table); kx, kz for a patch. */
void ocean_gauss_compute(int n, uint32_t seed, float *gauss, struct pool *pool, int threads);
bool ocean_amps_compute(const struct ocean_grid *g, const struct spectrum_model *m, double lambda,
                        const float *gauss, struct ocean_amps *amps, struct pool *pool, int threads);
void ocean_set_k_tables(struct ocean_grid *g, double patch);

/* ocean_prepare.c: everything new parameters need, made beside the live
 * grids (read only) on `pool` (ocean_create and ocean_reconfigure use the
 * stepping pool, ocean_prepare its own). */
struct ocean_prepared *ocean_prepare_on(const struct ocean *o, const struct ocean_params *p,
                                        const struct sea_spectrum *sea, struct pool *pool, int threads, char *err,
                                        size_t errlen);
/* The live grid of cascade c, or NULL. */
static inline struct ocean_grid *ocean_cascade_grid(const struct ocean *o, int c)
{
    return c == 0 ? o->g : c < o->ncascades ? o->fine[c] : NULL;
}

/* ocean_fftw.c: once-per-process FFTW threads setup and the lock that
 * serialises planning and wisdom I/O (FFTW's planner is global state). */
void ocean_fftw_init(void);
void ocean_fftw_lock(void);
void ocean_fftw_unlock(void);

/* ocean_query.c: a query snapshot of the amplitudes of cascades 0 .. count-1,
 * grids[c] (all of one N), under parameters p: queries sum them all. */
struct ocean_surface *ocean_surface_from(const struct ocean_grid *const *grids, int count,
                                         const struct ocean_params *p, char *err, size_t errlen);
/* The same, with an easing (ocean_commit_eased): keep[c] (column-major a,
 * b, d, e with `keep_stride` floats per column, or NULL) and from[c]
 * (OCEAN_EASE_COL_FLOATS per column, or NULL) add the modes they hold to
 * those kept; with fill, from[] are the amplitudes eased from over [t0, t0 +
 * len], else the snapshot only makes room for them (ocean_surface_ease). */
struct surface_ease {
    const float *keep[OCEAN_MAX_CASCADES];
    size_t keep_stride;
    const float *from[OCEAN_MAX_CASCADES];
    bool fill;
    double t0, len;
};
struct ocean_surface *ocean_surface_from_eased(const struct ocean_grid *const *grids, int count,
                                               const struct ocean_params *p, const struct surface_ease *ease,
                                               char *err, size_t errlen);

#endif

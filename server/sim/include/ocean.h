/* ocean.h — Tessendorf FFT ocean simulation, no networking, no globals.
 *
 * One struct ocean holds a whole simulation: parameters, the initial
 * spectrum h~0(k), FFTW plans and output fields. Create it once, step it
 * at any time t, reconfigure it when parameters change, free it.
 *
 * Output fields are N*N float arrays, row-major: sample (ix, iz) is at
 * index iz*N + ix and lies at world position x = ix*L/N, z = iz*L/N
 * (metres, y is up). The patch is periodic in x and z.
 *   OCEAN_HEIGHT    h(x,z,t), m, positive up
 *   OCEAN_DX/DZ     horizontal displacement, m, already scaled by the
 *                   choppiness lambda: the surface point is (x+Dx, h, z+Dz)
 *   OCEAN_SLOPE_X/Z dh/dx, dh/dz of the undisplaced height, dimensionless
 *   OCEAN_JACOBIAN  det of d(x+Dx, z+Dz)/d(x,z), dimensionless; 1 = flat,
 *                   < 0 where the surface folds (foam)
 *   OCEAN_FOAM      whitecap foam, 0..1, accumulated from the Jacobian over
 *                   the steps that asked for it and fading over seconds
 *                   (ocean_foam.c): a sample is "covered" where foam >= 0.5.
 *                   Unlike the others it has a history: it depends on the
 *                   times of the previous foam steps (a cold start rebuilds
 *                   it from (params, t) alone; see ocean_step). */
#ifndef OCEAND_OCEAN_H
#define OCEAND_OCEAN_H

#include "params.h"

enum ocean_field {
    OCEAN_HEIGHT, OCEAN_DX, OCEAN_DZ, OCEAN_SLOPE_X, OCEAN_SLOPE_Z, OCEAN_JACOBIAN, OCEAN_FOAM,
    OCEAN_FIELD_COUNT
};
#define OCEAN_FIELD_BIT(f) (1u << (f))
#define OCEAN_ALL_FIELDS ((1u << OCEAN_FIELD_COUNT) - 1u)

/* Largest simulation time, s (about 31.7 years), for which ocean_step keeps
 * its phase accuracy: phases w*t are formed in double, whose rounding at
 * t = 1e9 s stays below 1e-4 rad for every w up to N = 2048 on a 1 m patch.
 * Callers (the daemon's state file) must refuse times outside [0, max]. */
#define OCEAN_TIME_MAX 1.0e9
/* The clock's one rule (the daemon's tick, a take-over, the state file):
 * it runs within [0, OCEAN_TIME_MAX] and stops at the end, so every time it
 * reaches can be saved and restored. NaN reads as 0. */
static inline double ocean_time_clamp(double t) { return t >= 0 ? (t < OCEAN_TIME_MAX ? t : OCEAN_TIME_MAX) : 0; }

/* Cascades (docs/simulation.md, "Cascades"). A simulation sums
 * p.cascades periodic patches on grids of the same N: cascade c has side
 * L_c = patch_size / OCEAN_CASCADE_RATIO^c and holds only the wavenumbers
 * the coarser cascades cannot: cascade 0 all of its grid (it is exactly
 * the single patch of a one-cascade sea); cascade c >= 1 its modes with
 * ocean_cascade_band(N, c) <= max(|mx|, |mz|) <= ocean_cascade_band_top(N, c)
 * = N/4 - 1, i.e. up to half its Nyquist wavenumber, so that LOD 1 (every
 * other sample) carries it exactly; the next cascade starts where it ends.
 * So the spectrum's energy is counted once. Each cascade has its own
 * random numbers (seed mixed with c). The ratio is not an integer, and r, r^2, r^3 all lie
 * within 0.06 of a half-integer: at the largest period L each finer patch
 * is shifted by about half its own period, so no two tilings line up. */
#define OCEAN_MAX_CASCADES 4
#define OCEAN_CASCADE_RATIO 3.543
/* L_c for a patch_size L: L / ratio^c. */
double ocean_cascade_patch(double patch_size, int cascade);
/* The first and the last integer wavenumber max(|mx|, |mz|) that cascade c
 * holds on an N grid: 0 and N/2 - 1 for cascade 0 (all of them);
 * ceil((top(c-1) + 1/2) / ratio) and N/4 - 1 for c >= 1. */
int ocean_cascade_band(int n, int cascade);
int ocean_cascade_band_top(int n, int cascade);

struct ocean_options {
    int threads;               /* worker threads for the step (fill + transforms), >= 1;
                                * 0 = one per online core (ocean_threads) */
    const char *wisdom_path;   /* FFTW wisdom cache file, NULL = none */
    int plan_rigor;            /* 0 = FFTW_ESTIMATE (tests), 1 = FFTW_MEASURE */
};

struct ocean;

/* Returns NULL with a message in err on invalid parameters or no memory. */
struct ocean *ocean_create(const struct ocean_params *p, const struct ocean_options *opt,
                           char *err, size_t errlen);
/* Apply new parameters. Random phases are kept (the sea evolves rather than
 * jumps); a change of N re-plans. On error returns -1, the simulation is
 * unchanged and err says why. */
int ocean_reconfigure(struct ocean *o, const struct ocean_params *p, char *err, size_t errlen);
/* Parameter changes prepared off the stepping thread (the daemon's builder).
 * ocean_prepare computes everything new parameters change into a separate
 * object: for the same N, the amplitudes and frequencies (reusing the
 * per-mode random numbers cached for the seed and the per-|k| table, so it
 * costs a fraction of ocean_create); for another N, a whole new grid with
 * its FFT plans. It only reads what `o` does not change while stepping, so
 * it MAY RUN ON ANOTHER THREAD WHILE ocean_step / ocean_field run; it uses
 * its own worker threads (o's thread count), made on first use. Two
 * prepares on one ocean must not overlap. Returns NULL with a message in
 * err on invalid parameters or no memory (o unchanged either way).
 * ocean_commit swaps the prepared state in: O(1), no allocation or freeing,
 * on the stepping thread (it must not overlap ocean_step, ocean_field's
 * readers or an ocean_prepare on the same ocean). It returns -1 and changes
 * nothing if `o` was committed or reconfigured since the prepare. Either
 * way pr then holds the old state: free it with ocean_prepared_free (on
 * any thread). ocean_reconfigure = prepare + commit + free, on the
 * stepping thread's own workers. */
struct ocean_prepared;
struct ocean_prepared *ocean_prepare(struct ocean *o, const struct ocean_params *p, char *err, size_t errlen);
int ocean_commit(struct ocean *o, struct ocean_prepared *pr);
void ocean_prepared_free(struct ocean_prepared *pr);
/* Easing (docs/simulation.md, "Easing"): ocean_commit_eased(o, pr, t0, len)
 * commits like ocean_commit, but when the change alters only the
 * amplitudes h~0 (ocean_prepared_easable: same N, seed, patch, depth, loop
 * period and cascades, FFT path; wind, amplitude, spectrum, fetch, ...)
 * N <= OCEAN_EASE_MAX_N and len > 0, the sea eases from the amplitudes in force at t0 (during
 * another easing: its mix at t0, so there is no jump) to the new ones over
 * sim time [t0, t0 + len]: a step at t uses from + w (to - from) per mode,
 * w = (t - t0) / len clamped to [0, 1]. Choppiness changes at once. Any
 * other commit ends an easing at once. ocean_commit = ocean_commit_eased
 * with len 0. Same threads as ocean_commit; the start of an easing copies
 * the amplitudes in force (O(N^2), on o's own workers). */
int ocean_commit_eased(struct ocean *o, struct ocean_prepared *pr, double t0, double len);
/* Largest N eased: the start of an easing copies 8 N^2 bytes per cascade on
 * the committing (tick) thread, 5 ms at N = 1024 with 3 cascades, 30 ms at
 * 2048 (a whole tick): there a change applies at once, as before. */
#define OCEAN_EASE_MAX_N 1024
bool ocean_prepared_easable(const struct ocean_prepared *pr);
/* The easing in force (len 0: none), for callers that must know when the
 * sea is exactly the parameters' (tests, frame checks). */
void ocean_easing(const struct ocean *o, double *t0, double *len);
/* Compute the fields in the mask (OCEAN_FIELD_BIT...) at time t seconds.
 * With OCEAN_FOAM the Jacobian is computed too, and the foam is decayed
 * for the time since the previous foam step and fed from this step's
 * Jacobian. A foam step with no usable history (the first, after a change
 * of resolution, t earlier than the previous foam step or more than 5 s
 * after it) first rebuilds the history from 20 Jacobian-only steps at
 * t - 5 s ... t - 0.25 s, so the foam is a function of (params, t) there;
 * after that, of the step times too. */
int ocean_step(struct ocean *o, double t, unsigned fields);
/* The same with a field mask per cascade (fields[c] for c < count; cascades
 * beyond count, or with mask 0, are not stepped and keep their last
 * output). OCEAN_FOAM is computed for cascade 0 only. */
int ocean_step_cascades(struct ocean *o, double t, const unsigned *fields, int count);
/* Output of the last step (cascade 0); valid until the next step/reconfigure/free. */
const float *ocean_field(const struct ocean *o, enum ocean_field f);
/* Output of cascade c (0 .. ocean_cascades - 1), or NULL (also for
 * OCEAN_FOAM of c >= 1: foam lives on cascade 0). */
const float *ocean_cascade_field(const struct ocean *o, int cascade, enum ocean_field f);
/* Zero-copy hand-off of a step's output (the daemon encodes tick t while
 * tick t+1 is stepped): exchange cascade c's output array of field f with
 * *buf, an array from ocean_field_buffer_new at this resolution (or from an
 * earlier exchange at it). The caller then owns the samples just stepped,
 * and the library the old *buf, which the next step of f overwrites whole;
 * until then ocean_cascade_field(o, c, f) reads the old contents. Not for
 * OCEAN_FOAM: its array is the foam's state. Returns 0, or -1 (nothing
 * exchanged: bad argument). */
int ocean_exchange_cascade_field(struct ocean *o, int cascade, enum ocean_field f, float **buf);
/* An output-sized array (N x N floats, aligned as FFTW's plans need), zeroed; NULL if out of memory. */
float *ocean_field_buffer_new(int n);
void ocean_field_buffer_free(float *buf);
/* Cascades in force (p.cascades). */
int ocean_cascades(const struct ocean *o);
const struct ocean_params *ocean_get_params(const struct ocean *o);
int ocean_resolution(const struct ocean *o);
/* The thread count ocean_create uses for options.threads = requested:
 * 0 = one per online core (sysconf), with no cap but OCEAN_MAX_THREADS (64);
 * below 0 = 1; above 64 = 64. */
int ocean_threads(int requested);
/* Bytes one cascade of a simulation of resolution n with `threads` workers (as above)
 * allocates for its grid (a sea of C cascades allocates C times this): for
 * its grids (spectra, FFT work arrays, output fields): what a memory cap
 * should count. FFTW's plans are not included (small beside the arrays). */
size_t ocean_memory_bytes(int n, int threads);
/* Bytes one cascade adds, from its first eased change on, for the amplitudes an
 * easing starts from (8 N^2 at N <= OCEAN_EASE_MAX_N, kept and reused; 0 above,
 * where changes are not eased): a memory cap counts them too. */
size_t ocean_ease_memory_bytes(int n);
void ocean_free(struct ocean *o);

/* Stable lowercase names: "height", "dx", "dz", "slope_x", "slope_z", "jacobian", "foam". */
const char *ocean_field_name(enum ocean_field f);

/* ---- measured seas (sea_spectrum.h; docs/simulation.md "Measured seas") ----
 *
 * Spectrum "measured" takes its amplitudes from a measured directional
 * spectrum attached to the ocean. The _sea variants below are the plain
 * calls with a sea document: a non-NULL `sea` is checked
 * (sea_spectrum_check; refused with its message, nothing changes), copied,
 * and becomes the ocean's sea with the commit of that change, whatever
 * p->spectrum says; NULL keeps the sea in force. "measured" without a sea
 * in force or given is refused ("spectrum: measured needs a measured
 * sea ..."). A change of the sea alone is an amplitude change: it eases
 * like any other (ocean_commit_eased). The parameters still apply:
 * depth (the dispersion: a mode of wavenumber k takes the sea's energy at
 * its frequency in this depth; set p->depth from the sea's depth), patch
 * size and resolution (what the grid holds: sea_capture), amplitude,
 * small_wave_cutoff, choppiness, seed, loop_period, cascades, and for the
 * wind tail the wind. Threads: exactly those of the plain calls (the sea
 * is copied into the prepared change; the live one is only read by a
 * prepare and replaced by a commit). */
struct sea_spectrum;
struct ocean *ocean_create_sea(const struct ocean_params *p, const struct sea_spectrum *sea,
                               const struct ocean_options *opt, char *err, size_t errlen);
int ocean_reconfigure_sea(struct ocean *o, const struct ocean_params *p, const struct sea_spectrum *sea, char *err,
                          size_t errlen);
struct ocean_prepared *ocean_prepare_sea(struct ocean *o, const struct ocean_params *p,
                                         const struct sea_spectrum *sea, char *err, size_t errlen);
/* The sea in force as it was given (the state file, hello), or NULL; valid
 * until the next commit, reconfigure or free. Same threads as ocean_get_params. */
const struct sea_spectrum *ocean_sea(const struct ocean *o);

/* ---- point queries (ocean_query.c) ---------------------------------------
 *
 * Exact values of the displaced surface at any world point (x, z), from the
 * spectral sum over the simulation's modes (not from the FFT grid): see
 * docs/simulation.md, "Point queries". A query works on a snapshot of the
 * amplitudes (struct ocean_surface) that never changes once made, so any
 * number of threads may query one snapshot at once while the owner of the
 * struct ocean keeps stepping it. ocean_surface_new reads only what
 * ocean_create/ocean_reconfigure write (never what ocean_step writes): it
 * must not run concurrently with ocean_reconfigure or ocean_free of the same
 * ocean, and may run concurrently with ocean_step. */
struct ocean_surface;

/* Per queried world point (x, z), metres; y is up. */
struct ocean_point {
    double height;                /* m, surface height above (x, z): h at the surface
                                   * point that lands on (x, z) after displacement */
    double displacement[2];       /* m, [Dx, Dz] of that surface point */
    double source[2];             /* m, its undisplaced position (x0, z0): x0 + Dx = x */
    double normal[3];             /* unit normal [nx, ny, nz] of the displaced surface;
                                   * ny < 0 where the surface folds over (jacobian < 0) */
    double jacobian;              /* det d(x0 + D)/d(x0): 1 = flat, <= 0 folded (foam) */
    double vertical_velocity;     /* m/s, d height / dt at the fixed world point (x, z):
                                   * the heave a probe at (x, z) sees */
    double vertical_acceleration; /* m/s^2, d^2 height / dt^2 at (x, z) */
    double particle_velocity;     /* m/s, dh/dt of the surface point itself (fixed x0) */
    double particle_acceleration; /* m/s^2, d^2h/dt^2 at fixed x0 */
    int iterations;               /* Newton steps taken to invert the displacement */
    int converged;                /* 1 when |x0 + D(x0) - x| < 1e-9 m was reached */
};

/* Snapshot the current amplitudes and parameters for queries: O(N^2) time
 * and memory (56 bytes per mode). Returns NULL with err on no memory. */
struct ocean_surface *ocean_surface_new(const struct ocean *o, char *err, size_t errlen);
/* The snapshot of what a prepared change (ocean_prepare) of o will put in
 * force, made before ocean_commit: on the thread that prepared it, while o
 * keeps stepping (it reads only what ocean_step does not write). */
struct ocean_surface *ocean_prepared_surface(const struct ocean *o, const struct ocean_prepared *pr, char *err,
                                             size_t errlen);
/* After ocean_commit_eased of pr: give s, pr's ocean_prepared_surface, the
 * amplitudes the easing starts from (O(modes), on the committing thread),
 * so that a query at any time agrees with the steps. A commit that did not
 * ease leaves s as it is (the new amplitudes at every time). 0, or -1 when
 * s was not made for this commit (then it holds the new amplitudes only). */
int ocean_surface_ease(struct ocean_surface *s, const struct ocean *o);
void ocean_surface_free(struct ocean_surface *s);
/* Values at npoints world points xz[i] = {x, z} at simulation time t (s).
 * Any finite coordinates (the sea is periodic). Returns 0, or -1 (nothing
 * written) when t or a coordinate is not finite, npoints < 0, or no memory.
 * Thread-safe: s is only read. */
int ocean_surface_query(const struct ocean_surface *s, double t, const double (*xz)[2], int npoints,
                        struct ocean_point *out);
/* The same, with a guess of each point's source (x0, z0) to start the
 * inversion from, e.g. the `source` a probe's previous tick returned: the
 * sea moves little in a tick, so this saves most Newton steps. start may be
 * NULL; a guess further than L/4 from its point is ignored. */
int ocean_surface_query_from(const struct ocean_surface *s, double t, const double (*xz)[2],
                             const double (*start)[2], int npoints, struct ocean_point *out);
/* Modes with a non-zero amplitude in the snapshot (each costs the same). */
int ocean_surface_modes(const struct ocean_surface *s);
/* The parameters the snapshot was made from. */
const struct ocean_params *ocean_surface_params(const struct ocean_surface *s);
/* One-shot convenience: snapshot, query, free. */
int ocean_query(const struct ocean *o, double t, const double (*xz)[2], int npoints, struct ocean_point *out);

#endif

/* ocean_foam.c — whitecaps that live: the `foam` field, 0..1, accumulated
 * from the Jacobian over the steps a simulation is given, and decaying.
 *
 * A crest breaks where the surface is squeezed: the Jacobian J of the
 * horizontal displacement drops well below 1 (folds at J < 0). Each step
 * that computes foam "injects" up to 1 where J is below a threshold,
 *   inject = clamp((J_c(U) - J) / FOAM_RAMP, 0, 1),
 * and lets the older foam fade with an e-folding time FOAM_TAU:
 *   foam(t) = max(foam(t_prev) * exp(-(t - t_prev) / FOAM_TAU), inject).
 * This is the foam fade of an offline bake (Blender's ocean modifier), but
 * live and on the server, so every client and remote program sees the same
 * whitecaps. A sample counts as covered where foam >= 0.5.
 *
 * Calibration (docs/simulation.md, "Foam"): the covered fraction follows
 * Monahan & O'Muircheartaigh (1980), W = 3.84e-6 U10^3.41, within a factor
 * of 1.5 for U10 = 8..25 m/s at the default parameters (tests/test_ocean.c,
 * foam.coverage). The linear sea's compression statistics grow only slowly
 * with wind (a developed sea is self-similar: sd(J) 0.12 -> 0.17 from 8 to
 * 25 m/s at N = 256), while observed coverage grows as U^3.4, which is set
 * by wind forcing the linear model does not have; so the threshold J_c
 * rises with U (foam_threshold), fitted once to that law: a parabola in
 * U10 - 8 m/s, as the gap between U^3.4 and the linear sea's slower growth
 * widens with the wind.
 *
 * Determinism: the foam at a step depends only on the parameters and the
 * times of the steps that computed foam. When foam is asked for with no
 * usable history (the first time, after a new resolution, after time went
 * backwards or jumped by more than FOAM_SPINUP_TIME), the history is
 * rebuilt on a fixed lattice, t - k FOAM_SPINUP_STEP for k = K..1, before
 * t itself: foam after a cold start is a function of (params, t) alone,
 * and already near its steady state instead of starting clear. */
#include <math.h>
#include <string.h>

#include "ocean_internal.h"

/* Foam threshold on J for wind speed U10 (m/s): see the header comment.
 * 0.707 up to 8 m/s, then rising faster with the wind (0.71 at 12, 0.73 at
 * 16, 0.74 at 20, 0.77 at 25 m/s). */
double ocean_foam_threshold(double wind_speed)
{
    double over = wind_speed > 8.0 ? wind_speed - 8.0 : 0.0;
    return 0.707 + 0.0008 * over + 0.00018 * over * over;
}

void ocean_foam_samples(const struct ocean_foam_update *u, const float *restrict J, float *restrict foam,
                        size_t count)
{
    const float decay = u->decay, jc = u->threshold, inv = u->inv_ramp;
    for (size_t i = 0; i < count; i++) {
        float in = (jc - J[i]) * inv;
        in = in < 0.0f ? 0.0f : in > 1.0f ? 1.0f : in;
        float old = foam[i] * decay;
        foam[i] = old > in ? old : in;
    }
}

struct foam_ctx {
    struct ocean_grid *g;
    struct ocean_foam_update u;
};

/* Blocks [b0, b1) of OCEAN_ROW_BLOCK rows (the DFT path's separate pass). */
static void foam_rows(void *arg, int b0, int b1, int worker)
{
    (void)worker;
    const struct foam_ctx *c = arg;
    const size_t rows = (size_t)OCEAN_ROW_BLOCK * c->g->n, i0 = (size_t)b0 * rows;
    ocean_foam_samples(&c->u, c->g->out[OCEAN_JACOBIAN] + i0, c->g->out[OCEAN_FOAM] + i0, (size_t)(b1 - b0) * rows);
}

static struct ocean_foam_update foam_update(const struct ocean *o, double dt)
{
    struct ocean_foam_update u = {(float)exp(-dt / FOAM_TAU), (float)ocean_foam_threshold(o->p.wind_speed),
                                  (float)(1.0 / FOAM_RAMP)};
    return u;
}

/* A step on p.transform's path that also accumulates foam, dt s after the
 * last: fused into the FFT path's row stage (the Jacobian's block is in
 * cache), a separate pass after the DFT. */
static int step_and_foam(struct ocean *o, double t, unsigned fields, double dt, bool fft)
{
    struct ocean_foam_update u = foam_update(o, dt);
    if (fft)
        return ocean_step_fft_foam(o, t, fields, &u);
    if (ocean_step_dft(o, t, fields) != 0)
        return -1;
    struct foam_ctx c = {o->g, u};
    struct ocean_grid *g = o->g;
    int threads = g->n >= OCEAN_THREADS_FROM_N ? g->workers : 1;
    pool_for(o->pool, threads, g->n / OCEAN_ROW_BLOCK, foam_rows, &c);
    return 0;
}

int ocean_step_with_foam(struct ocean *o, double t, unsigned fields)
{
    bool fft = o->p.transform != TRANSFORM_DFT;
    if (!(fields & OCEAN_FIELD_BIT(OCEAN_FOAM)))
        return fft ? ocean_step_fft(o, t, fields) : ocean_step_dft(o, t, fields);
    fields |= OCEAN_FIELD_BIT(OCEAN_JACOBIAN);
    double dt = t - o->foam_time;
    if (!o->foam_warm || !(dt >= 0) || dt > FOAM_SPINUP_TIME) {
        /* Cold: rebuild the history on the lattice (FFT path whatever the
         * transform: the Jacobians agree to 1e-5, and it keeps the cost of a
         * cold start to FOAM_SPINUP_STEPS small steps). */
        struct ocean_grid *g = o->g;
        memset(g->out[OCEAN_FOAM], 0, (size_t)g->n * g->n * sizeof(float));
        for (int k = FOAM_SPINUP_STEPS; k >= 1; k--)
            if (step_and_foam(o, t - k * FOAM_SPINUP_STEP, OCEAN_FIELD_BIT(OCEAN_JACOBIAN), FOAM_SPINUP_STEP, true) != 0)
                return -1;
        dt = FOAM_SPINUP_STEP;
    }
    if (step_and_foam(o, t, fields, dt, fft) != 0)
        return -1;
    o->foam_time = t;
    o->foam_warm = true;
    return 0;
}

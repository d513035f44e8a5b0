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
 * of 2 for U10 = 8..25 m/s at the default parameters (tests/test_ocean.c,
 * foam.coverage). The linear sea's compression statistics grow only slowly
 * with wind (a developed sea is self-similar: sd(J) 0.12 -> 0.17 from 8 to
 * 25 m/s at N = 256), while observed coverage grows as U^3.4, which is set
 * by wind forcing the linear model does not have; so the threshold J_c
 * rises with U (foam_threshold), fitted once to that law.
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
 * 0.70 up to 8 m/s, then +0.0035 per m/s. */
double ocean_foam_threshold(double wind_speed)
{
    double over = wind_speed > 8.0 ? wind_speed - 8.0 : 0.0;
    return 0.70 + 0.0035 * over;
}

struct foam_ctx {
    struct ocean_grid *g;
    float decay, threshold, inv_ramp;
};

/* Rows [r0, r1) of blocks of OCEAN_ROW_BLOCK rows: decay, then inject. */
static void foam_rows(void *arg, int b0, int b1, int worker)
{
    (void)worker;
    const struct foam_ctx *c = arg;
    const size_t n = (size_t)c->g->n;
    const size_t i0 = (size_t)b0 * OCEAN_ROW_BLOCK * n, i1 = (size_t)b1 * OCEAN_ROW_BLOCK * n;
    const float *restrict J = c->g->out[OCEAN_JACOBIAN];
    float *restrict foam = c->g->out[OCEAN_FOAM];
    const float decay = c->decay, jc = c->threshold, inv = c->inv_ramp;
    for (size_t i = i0; i < i1; i++) {
        float in = (jc - J[i]) * inv;
        in = in < 0.0f ? 0.0f : in > 1.0f ? 1.0f : in;
        float old = foam[i] * decay;
        foam[i] = old > in ? old : in;
    }
}

/* One accumulation from the Jacobian now in the grid, dt s after the last. */
static void foam_accumulate(struct ocean *o, double dt)
{
    struct ocean_grid *g = o->g;
    struct foam_ctx c = {g, (float)exp(-dt / FOAM_TAU), (float)ocean_foam_threshold(o->p.wind_speed),
                         (float)(1.0 / FOAM_RAMP)};
    int threads = g->n >= OCEAN_THREADS_FROM_N ? g->workers : 1;
    ocean_parallel(o->pool, threads, g->n / OCEAN_ROW_BLOCK, foam_rows, &c);
}

int ocean_step_with_foam(struct ocean *o, double t, unsigned fields)
{
    int (*step)(struct ocean *, double, unsigned) =
        o->p.transform == TRANSFORM_DFT ? ocean_step_dft : ocean_step_fft;
    if (!(fields & OCEAN_FIELD_BIT(OCEAN_FOAM)))
        return step(o, t, fields);
    fields |= OCEAN_FIELD_BIT(OCEAN_JACOBIAN);
    double dt = t - o->foam_time;
    if (!o->foam_warm || !(dt >= 0) || dt > FOAM_SPINUP_TIME) {
        /* Cold: rebuild the history on the lattice (FFT path whatever the
         * transform: the Jacobians agree to 1e-5, and it keeps the cost of a
         * cold start to FOAM_SPINUP_STEPS small steps). */
        struct ocean_grid *g = o->g;
        memset(g->out[OCEAN_FOAM], 0, (size_t)g->n * g->n * sizeof(float));
        for (int k = FOAM_SPINUP_STEPS; k >= 1; k--) {
            if (ocean_step_fft(o, t - k * FOAM_SPINUP_STEP, OCEAN_FIELD_BIT(OCEAN_JACOBIAN)) != 0)
                return -1;
            foam_accumulate(o, FOAM_SPINUP_STEP);
        }
        dt = FOAM_SPINUP_STEP;
    }
    if (step(o, t, fields) != 0)
        return -1;
    foam_accumulate(o, dt);
    o->foam_time = t;
    o->foam_warm = true;
    return 0;
}

/* capacity.h — what this daemon can do at its tick rate, and what it does
 * when asked for more (issue 15, issue 16 defect 2).
 *
 * A cost model measured at start-up (sim_start: a few steps and encodes at
 * the starting N, on this machine) and kept current from every frame:
 *   step(N, fields)  scaled from the measured N by N^2 log2 N,
 *   encode(samples)  wall seconds per sample on the encode pool.
 * From it:
 *   - the encode budget: samples per tick that may be encoded at N (what a
 *     frame may take, 80 % of the tick, minus the step), or --encode-budget;
 *     a subscription that would push the distinct layers past it is refused
 *     with `busy` (the lws thread, capacity_admit in server/net/capacity.c);
 *   - the plan of each tick (capacity_plan): when demand does not fit, the
 *     most expensive subscription groups (same LOD and bound) are encoded one
 *     LOD coarser, then at a lower rate; only when the step alone does not
 *     fit does every group's rate go down. The clients concerned are told
 *     with a `degraded` message (PROTOCOL.md);
 *   - the announcement in hello and params (which N fit memory and the tick).
 * Pure functions: no threads, no clocks. */
#ifndef OCEAND_CAPACITY_H
#define OCEAND_CAPACITY_H

#include <stdbool.h>

#include "control.h"
#include "frame.h"

#define CAP_SIDES 13 /* layer sides 1 .. 4096 (N <= 2048) */

struct cost_model {
    double period_s;            /* 1 / tick rate */
    double budget_s;            /* share of the period a frame may take (0.8 period) */
    int n0;                     /* N the step was measured at */
    double step1_s, step6_s;    /* step at n0: height only, all six fields */
    double step_scale;          /* live correction: measured / predicted (EWMA) */
    double enc_s_per_sample;    /* encode wall per sample on the pool (EWMA over every frame; the
                                   start-up measure: intra, height, lod 0) */
    double enc_side_s[CAP_SIDES]; /* the same per layer side (N >> lod; index log2 side), learned
                                   from the frames that encoded that side, 0 = not yet: a sample
                                   does not cost the same at every size (1024 h/dx/dz temporal,
                                   two cores: 7 ns at side 1024, 3.6 at 512: the larger layers
                                   and their references fall out of the caches). Without it a
                                   group degraded to lod 1 measured the cheap side, predicted
                                   that lod 0 fit, went back, and degraded again (flapping) */
    double penalty;             /* transient factor on both costs (<= 1 = none): x1.25 for each tick
                                   the producer had not even started the frame before, back
                                   toward 1 on each tick it had (sim_thread.c, tick). Kept apart
                                   from the EWMAs, which frames update: a plan degraded by it
                                   makes frames rare, so frames alone would undo it only slowly.
                                   Not used for admission (cost_encode_budget) */
    long encode_budget;         /* --encode-budget: samples per tick at most, 0 = derived only */
    int max_memory_mb;
    int cores;
};

double cost_step_s(const struct cost_model *m, int n, int nfields);
double cost_encode_s(const struct cost_model *m, long samples);
/* Encode seconds per sample of a layer of this side (N >> lod): what frames
 * of that side cost, else the all-frames figure; with the penalty. */
double cost_encode_side_s(const struct cost_model *m, int side);
/* Learn from a frame: side_samples[i] samples of side 2^i took `seconds` on
 * the pool. Up quickly enough to follow the machine, but one frame counts
 * as at most twice the prediction: a frame's first keyframes, a chain's
 * start and the first touch of its buffers cost 3-7 times the steady
 * figure (first frames of 1024 h/dx/dz temporal: 24 ns/sample against 7),
 * and used to degrade a subscription that fits before it had been
 * served once. Sustained slowness still raises it 10 % a frame; overruns
 * raise the penalty at once (sim_thread.c). */
void cost_learn_encode(struct cost_model *m, const long side_samples[CAP_SIDES], double seconds);

/* Samples per tick the distinct layers may add up to at resolution n (the
 * admission limit): --encode-budget if set, else what fits the budget after
 * a step of all six fields, and at least six fields at full resolution. */
long cost_encode_budget(const struct cost_model *m, int n);

/* A group: the keys with demand that share a LOD and a bound. A client's
 * keys all lie in one group, so degrading groups keeps each client's frame
 * coherent (one LOD, one rate). */
#define PLAN_GROUPS ((CTL_MAX_LOD + 1) * CTL_BOUND_COUNT)
static inline int plan_group(int lod, int bound_index) { return lod * CTL_BOUND_COUNT + bound_index; }

struct plan {
    unsigned fields[PLAN_GROUPS];   /* demanded fields per group (0 = no demand) */
    unsigned char lod[PLAN_GROUPS]; /* encoded LOD per group (>= the group's own) */
    float rate[PLAN_GROUPS];        /* share of ticks the group is encoded on, (0, 1] */
    char reason[200];               /* why, when anything is degraded: the demand at full detail
                                       (samples per tick), the budget in samples at what those
                                       sizes cost, the step and the frame budget */
};

/* Demand -> plan at resolution n with tile side ts (per-tick samples and
 * time from the model; budget_scale < 1 plans with headroom). */
void capacity_plan(const struct cost_model *m, int n, int ts, const int demand[LAYER_KEYS_ALL], double budget_scale,
                   struct plan *out);
bool plan_degraded(const struct plan *p, int group);
/* What the plan delivers, comparable between plans of the same demand:
 * sum over groups of rate * samples encoded. */
double plan_value(const struct plan *p, int n);
bool plan_same(const struct plan *a, const struct plan *b);
/* Forget what sides not in `keep` (bit i = side 2^i) cost: they fall back to
 * the all-frames figure (a degraded group's recovery probe, sim_thread.c). */
void cost_forget_sides(struct cost_model *m, unsigned keep);
/* Bit log2(side) of every side the plan encodes (for cost_forget_sides),
 * and its samples per side; only the groups with due[g] unless due is NULL. */
unsigned plan_sides(const struct plan *p, int n, const bool *due, long side_samples[CAP_SIDES]);
/* The model's moving average: down fast (a quarter), up slowly (a tenth). */
double cost_ewma(double model, double measured);

/* The announcement (control.h) from the model, at the current resolution. */
void capacity_info_fill(const struct cost_model *m, int n, struct capacity_info *out);

#endif

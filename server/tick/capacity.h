/* capacity.h — what this daemon can do at its tick rate, and what it does
 * when asked for more (docs/daemon.md, "Capacity").
 *
 * A cost model measured at start-up (sim_start: a few steps and encodes at
 * the starting N, on this machine) and kept current from every frame:
 *   step(N, fields)  scaled from the measured N by N^2 log2 N,
 *   encode(samples)  wall seconds per sample on the encode pool, per codec
 *                    (intra; temporal, 1.5-2x as much: the ratio measured at start-up),
 *                    at LOD 0; a sample at LOD L costs 2^L of them (capacity.c, group_work).
 * From it:
 *   - the encode budget: samples per tick that may be encoded at N (what a
 *     frame may take, 80 % of the tick, minus the step), or --encode-budget;
 *     a subscription that would push the distinct layers past it is refused
 *     with `busy` (the lws thread, capacity_admit in server/net/degraded.c);
 *   - the plan of each tick (capacity_plan): when demand does not fit, the
 *     ladder, one rung after the other: a subscription group (same LOD and
 *     bound) with temporal clients is encoded intra at its own LOD (same
 *     detail and rate, more bytes; the most expensive group first), then the
 *     largest groups one LOD coarser, then at a lower rate; only when the
 *     step alone does not fit does every group's rate go down. The clients
 *     concerned are told with a `degraded` message (PROTOCOL.md);
 *   - the announcement in hello and params (which N fit memory and the tick).
 * Pure functions: no threads, no clocks. */
#ifndef OCEAND_CAPACITY_H
#define OCEAND_CAPACITY_H

#include <stdbool.h>

#include "control.h"
#include "frame.h"

enum { CAP_INTRA, CAP_TEMPORAL, CAP_CODECS }; /* how a group's layers are encoded */
#define CAP_TEMPORAL_PRIOR 2.0 /* temporal / intra cost per sample when start-up could not measure it */

struct cost_model {
    double period_s;            /* 1 / tick rate */
    double budget_s;            /* share of the period a frame may take (0.8 period) */
    int n0;                     /* N the step was measured at */
    double step1_s, step6_s;    /* step at n0: height only, all six fields */
    double step_scale;          /* live correction: measured / predicted (EWMA) */
    double enc_s_per_sample;    /* encode wall per sample on the pool, intra (codec 1): the start-up
                                   measure (height, lod 0), then EWMA from the frames */
    double enc_temporal_s;      /* the same for temporal layers (codec 3, each tile predicted and
                                   intra, the smaller sent): 0 = not measured yet, taken as
                                   CAP_TEMPORAL_PRIOR x intra. Kept apart because it is twice
                                   the intra figure (N = 1024 h/dx/dz, two cores: 7.0 against
                                   3.3-3.6 ns/sample) and a group degraded to a coarser LOD is
                                   sent intra (frame_job.c): one figure for both measured the cheap
                                   codec while degraded, predicted that lod 0 fit, went back, and
                                   degraded again within 0.2 s (flapping every 3.5 s) */
    double temporal_ratio;      /* temporal / intra cost per sample measured at start-up (a few ticks
                                   of one stream, calibrate.c), 0 = not measured:
                                   CAP_TEMPORAL_PRIOR. What enc_temporal_s starts from and goes back
                                   to when forgotten (the prior of 2 went stale when the encoder got
                                   1.5x faster: 2048 height stayed degraded, its probe never fitting) */
    double penalty;             /* transient factor on both costs (<= 1 = none): x1.25 for each tick
                                   the producer had not even started the frame before, back
                                   toward 1 on each tick it had (tick.c). Kept apart
                                   from the EWMAs, which frames update: a plan degraded by it
                                   makes frames rare, so frames alone would undo it only slowly.
                                   Not used for admission (cost_encode_budget) */
    long encode_budget;         /* --encode-budget: samples per tick at most, 0 = derived only */
    long temporal_budget;       /* --temporal-budget: samples per tick at most with the temporal codec,
                                   0 = derived only (groups beyond it are served intra at their LOD) */
    int max_memory_mb;
    int cores;
};

double cost_step_s(const struct cost_model *m, int n, int nfields);
double cost_encode_s(const struct cost_model *m, long samples);
/* Encode seconds per sample with this codec (CAP_INTRA, CAP_TEMPORAL), with the penalty. */
double cost_encode_codec_s(const struct cost_model *m, int codec);
/* Learn from a frame: samples[c] samples with codec c took `seconds` on the
 * pool. A frame of one codec teaches that codec's figure, a mixed one moves
 * both by its ratio to the prediction. Up slowly enough to ride out noise,
 * and one frame counts as at most twice the prediction: a frame's first
 * keyframes, a chain's start and the first touch of its buffers cost 3-7
 * times the steady figure (first frames of 1024 h/dx/dz temporal: 11-27
 * ns/sample against 7) and used to degrade a subscription before it had
 * been served once. Sustained slowness still raises it 10 % a frame;
 * overruns raise the penalty at once (tick.c, penalize_overrun). */
void cost_learn_encode(struct cost_model *m, const long samples[CAP_CODECS], double seconds);

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
    bool temporal[PLAN_GROUPS];     /* a temporal client asked for one of its layers */
    bool intra[PLAN_GROUPS];        /* the codec rung: a temporal group served intra at its own LOD
                                       because the temporal codec does not fit (plan_intra) */
    char reason[240];               /* why, when anything is degraded: the demand at full detail
                                       (samples per tick), the budget in samples at what those
                                       sizes cost, the step and the frame budget */
};

/* The re-plan's hysteresis (plan_governor.c), as budget scales:
 * a less degraded plan is taken only when it fits CAP_RECOVER_SCALE of the
 * budget; the plan in force is dropped only when it no longer fits
 * CAP_KEEP_SCALE of it. A new demand is planned at 1. Without the upper band
 * a plan costing the budget give or take the noise was dropped on its first
 * slow frames and could only come back under 80 %: N = 1024 six fields
 * (step 11-12 ms + encode 13-15 ms, budget 26.7 ms) went to LOD 1 two
 * seconds after it was planned at full detail and flapped every 5-12 s.
 * 1.05 x 0.8 of a tick is 28 ms at 30 Hz, 16 % short of the period; frames
 * that really do not fit make overruns, whose penalty degrades at once. */
#define CAP_RECOVER_SCALE 0.8
#define CAP_KEEP_SCALE 1.05

/* Demand -> plan at resolution n with tile side ts (per-tick samples and
 * time from the model; budget_scale < 1 plans with headroom). tdemand: the
 * temporal clients per key (NULL: none). */
void capacity_plan(const struct cost_model *m, int n, int ts, const int demand[LAYER_KEYS_ALL],
                   const int tdemand[LAYER_KEYS_ALL], double budget_scale, struct plan *out);
/* Served coarser or less often than asked (a loss of detail or rate). */
bool plan_degraded(const struct plan *p, int group);
/* A group with temporal clients served intra at its own LOD (the codec rung:
 * same detail and rate, more bytes); only its temporal clients are told. */
bool plan_intra(const struct plan *p, int group);
/* What the group's temporal clients get is not what they asked for:
 * plan_degraded, or plan_intra for a temporal client. */
static inline bool plan_degraded_for(const struct plan *p, int group, bool temporal_client)
{
    return plan_degraded(p, group) || (temporal_client && plan_intra(p, group));
}
/* Samples (x rate) served intra by the codec rung: at equal plan_value, the
 * plan with fewer is the better one (plan_governor.c). */
double plan_intra_value(const struct plan *p, int n);
/* What the plan delivers, comparable between plans of the same demand:
 * sum over groups of rate * samples encoded. */
double plan_value(const struct plan *p, int n);
bool plan_same(const struct plan *a, const struct plan *b);
/* Forget the temporal figure (back to temporal_ratio, or the prior, x intra): what a
 * degraded group's recovery probe assumes when no temporal layer has been
 * encoded to keep it current (plan_governor.c). */
void cost_forget_temporal(struct cost_model *m);
/* Encode work per codec the plan asks for, in LOD-0 samples (a sample at LOD
 * L counts 2^L: what the per-sample figures are learned and priced in; only
 * the groups with due[g] unless due is NULL): a group is temporal when it has
 * temporal demand and is encoded at its own LOD (a coarser one goes intra)
 * and not on the codec rung (plan_intra). */
void plan_samples(const struct plan *p, int n, const bool *due, long samples[CAP_CODECS]);
/* The model's moving average: down fast (a quarter), up slowly (a tenth). */
double cost_ewma(double model, double measured);

/* The announcement (control.h) from the model, at the current resolution. */
void capacity_info_fill(const struct cost_model *m, int n, struct capacity_info *out);

#endif

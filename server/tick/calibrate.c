/* calibrate.c — the cost model's start-up figures (capacity.h), measured on
 * this machine before the threads start. */
#include "tick_internal.h"

#include <math.h>
#include <stdint.h>

#include "clock.h"
#include "log.h"


/* Start-up measurement for the cost model (capacity.h): the step with one
 * field and with all six, and the encode of one field at 1 cm, on this
 * machine, best of three (the machine may be shared: the best run is what it
 * can do; the live model corrects it from every frame). */
static void measure_done(void *ctx) { ((struct sim *)ctx)->measure_done = true; }

/* One frame of w (header seq) begun and encoded on the pool, timed: seconds
 * per sample, TIME_ENCODE_NONE when it encoded no sample, TIME_ENCODE_STOP
 * (nothing encoded) when the frame could not be begun or, with need given,
 * has no item or no stream in need for key. */
#define TIME_ENCODE_NONE (-1.0)
#define TIME_ENCODE_STOP (-2.0)
static double time_encode(struct sim *s, const struct frame_want *w, uint64_t seq, const struct layer_streams *need,
                          int key)
{
    struct oc_frame_header h = { .seq = seq };
    int items = frame_job_begin(s->job, s->ocean, s->cfg.tile_size, w, &h);
    if (items < 0 || (need && (items == 0 || !need->st[key])))
        return TIME_ENCODE_STOP;
    s->measure_done = false;
    double t0 = mono_now();
    encode_pool_start(s->pool, items, encode_item, measure_done, s);
    encode_pool_wait(s->pool);
    double t1 = mono_now();
    long samples = frame_job_samples(s->job);
    return samples > 0 ? (t1 - t0) / (double)samples : TIME_ENCODE_NONE;
}

/* The temporal codec's cost per sample against intra's (best_enc, the same
 * field, pool and bound): one stream of height at 1 cm over a few ticks of a
 * moving sea (its first frames are keyframes on cold buffers; from the fifth
 * on, tiles predict from the full depth), best of the last three. 0 when it
 * cannot be measured (no memory): the model keeps CAP_TEMPORAL_PRIOR. */
#define MEASURE_TEMPORAL_TICKS 8
static double measure_temporal_ratio(struct sim *s, double best_enc)
{
    struct layer_streams ls;
    layer_streams_init(&ls, 0, SIZE_MAX);
    frame_job_set_streams(s->job, &ls);
    const unsigned h_only = OCEAN_FIELD_BIT(OCEAN_HEIGHT);
    int key = layer_key(OCEAN_HEIGHT, 0, 3 /* 1 cm */);
    struct frame_want w = { .fields = h_only, .cfields = { h_only }, .nkeys = 1 };
    w.keys[0] = (uint16_t)key;
    w.temporal[key] = 1;
    w.tclients[key] = 1;
    double best = 1e9;
    for (int i = 0; i < MEASURE_TEMPORAL_TICKS; i++) {
        ocean_step_cascades(s->ocean, s->sim_time + i / s->cfg.tick_rate, &h_only, 1);
        double t = time_encode(s, &w, (uint64_t)i, &ls, key);
        if (t == TIME_ENCODE_STOP)
            break;
        if (i >= MEASURE_TEMPORAL_TICKS - 3 && t >= 0)
            best = fmin(best, t);
    }
    struct frame_want none = { 0 };
    struct oc_frame_header h = { 0 };
    frame_job_begin(s->job, s->ocean, s->cfg.tile_size, &none, &h); /* lets the last frame go; no stream wanted */
    frame_job_set_streams(s->job, NULL);
    layer_streams_free(&ls);
    return best < 1e9 && best_enc > 0 && best_enc < 1e9 ? best / best_enc : 0;
}

void calibrate_cost_model(struct sim *s)
{
    struct cost_model *m = &s->model;
    int n = ocean_resolution(s->ocean);
    m->period_s = 1.0 / s->cfg.tick_rate;
    m->budget_s = 0.8 * m->period_s;
    m->n0 = n;
    m->step_scale = 1;
    m->penalty = 1;
    m->encode_budget = s->cfg.encode_budget;
    m->max_memory_mb = s->cfg.max_memory_mb;
    m->cores = s->cfg.cores;
    double best1 = 1e9, best6 = 1e9, best_enc = 1e9;
    for (int i = 0; i < 3; i++) {
        double t0 = mono_now();
        /* Cascade 0 only: the model's step is one cascade's (a finer cascade
         * costs as much again, and only when a client asks for it). */
        const unsigned h_only = OCEAN_FIELD_BIT(OCEAN_HEIGHT), six = OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM);
        ocean_step_cascades(s->ocean, s->sim_time, &h_only, 1);
        double t1 = mono_now();
        /* The six surface fields, not foam: a foam step would start its
         * history at the start-up wind, and foam later asked for under
         * another wind would build up from there instead of being spun up
         * (test_foam_field_streamed's coverage halved). */
        ocean_step_cascades(s->ocean, s->sim_time, &six, 1);
        double t2 = mono_now();
        best1 = fmin(best1, t1 - t0);
        best6 = fmin(best6, t2 - t1);
        struct frame_want w = { .fields = OCEAN_FIELD_BIT(OCEAN_HEIGHT), .cfields = { OCEAN_FIELD_BIT(OCEAN_HEIGHT) }, .nkeys = 1 };
        w.keys[0] = (uint16_t)layer_key(OCEAN_HEIGHT, 0, 3 /* 1 cm */);
        double t = time_encode(s, &w, 0, NULL, 0);
        if (t == TIME_ENCODE_STOP)
            break;
        if (t >= 0)
            best_enc = fmin(best_enc, t);
    }
    double ratio = measure_temporal_ratio(s, best_enc);
    /* Warm every encoder (its compressor and scratch) now: one first used
     * minutes later (the producer helps only now and then) would show as
     * memory growth under load. */
    frame_job_warm(s->job, s->ocean, s->cfg.tile_size);
    m->step1_s = best1;
    m->step6_s = fmax(best6, best1);
    m->enc_s_per_sample = best_enc < 1e9 ? best_enc : 1e-8;
    m->temporal_ratio = ratio;
    LOGI("capacity at N=%d: step %.2f ms (height) / %.2f ms (6 fields), encode %.2f ns/sample on %d threads; "
         "temporal x%.2f (%s); encode budget %ld samples per tick", n, best1 * 1e3, best6 * 1e3,
         m->enc_s_per_sample * 1e9, encode_pool_threads(s->pool) + 1, ratio > 0 ? ratio : CAP_TEMPORAL_PRIOR,
         ratio > 0 ? "measured" : "prior", cost_encode_budget(m, n));
    /* The announcement's memory figures once now: every hello and params
     * carries them, on the lws thread (control_fits_memory remembers them). */
    struct capacity_info warm;
    capacity_info_fill(m, n, &warm);
}

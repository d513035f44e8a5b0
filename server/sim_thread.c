/* sim_thread.c — the tick loop (apply -> step -> encode -> publish) and the
 * builder thread that prepares parameter sets off the tick path. */
#include "sim_thread.h"

#include "clock.h"

#include <errno.h>
#include <limits.h>
#include <malloc.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include "layer_stream.h"
#include "capacity.h"
#include "encode_pool.h"
#include "log.h"
#include "metrics.h"

/* A batch of sets the builder has prepared for one tick boundary. */
struct built {
    struct ocean_prepared *prepared; /* the new state for the ocean in force (ocean_prepare:
                                        new amplitudes, or a new grid and plans for a new N),
                                        or NULL when only playback changed */
    struct ocean_params params;   /* in force after the batch */
    struct sim_set *sets;         /* in order; each has ->prev, or a failed ->status */
    struct ocean_surface *surface; /* query snapshot of the prepared state (made by the builder), or NULL */
};

/* Each field says which thread writes it and which reads it ("tick",
 * "builder", "lws" = the network thread; docs/threads.md). */
struct sim {
    struct sim_config cfg;        /* sim_start writes; all read, never written after */
    pthread_t thread, builder;    /* sim_start writes; sim_stop reads */
    bool builder_started;         /* sim_start writes; sim_stop reads */
    atomic_bool stop;             /* sim_stop writes; tick and builder read */
    int test_fail_seed;           /* sim_start writes (OCEAND_TEST_FAIL_BUILD_SEED, -1 = none); builder reads */

    struct ocean *ocean;          /* sim_start writes the pointer, never changed after; the producer steps
                                   * it while prod_busy/prod_has_job, the tick commits into it only while
                                   * the producer is idle (handed over under the lock); the builder runs
                                   * ocean_prepare against it (allowed while it is stepped, ocean.h),
                                   * never while a commit runs (ready_full is cleared after the commit) */
    struct ocean_params params;   /* tick only: the parameters in force */
    uint32_t version;             /* tick only: params_version in force */
    double sim_time;              /* tick only: the clock (copied to now_time) */
    uint64_t seq;                 /* tick only: ticks run (PROTOCOL.md §3.3: +1 per tick, frame or not) */
    struct plan plan;             /* tick only: the plan in force (capacity.h) */
    int lower_ticks;              /* tick only: a less degraded plan seen for this many ticks in a row */
    int hold_ticks;               /* tick only: ...needed before it is taken (hysteresis; doubles when a
                                     recovery is undone soon after, update_plan) */
    int since_change;             /* tick only: ticks since the plan in force was taken */
    bool recovered;               /* tick only: the plan in force was a recovery (less degraded, same demand) */
    uint64_t grace_seq;           /* tick only: jobs queued before this seq (a new demand's or plan's
                                     first half second) neither raise the penalty nor teach the model */
    double credit[PLAN_GROUPS];   /* tick only: a group is encoded when its credit reaches 1 */
    bool had_demand;              /* tick only: last tick had subscribers */

    pthread_t producer;           /* sim_start writes; sim_stop joins */
    bool producer_started;        /* sim_start writes; sim_stop reads */
    struct encode_pool *pool;     /* sim_start creates; producer starts/waits jobs; sim_stop frees */
    struct frame_job *job;        /* producer fills it, the pool encodes it, the pool's last thread
                                     finishes it (encode_done); one job at a time (encode_pool) */
    uint64_t published;           /* encode_done only (jobs are serial): frames published, for struct frame.index */
    double job_t_tick, job_t_enc; /* producer writes before the job starts; encode_done reads */
    long job_samples;             /* same */
    long job_codec_samples[CAP_CODECS]; /* same: the plan's samples per codec (capacity.h) */
    bool job_cold;                /* same: queued within the grace (prod_job.cold) */
    /* Measuring at start-up (sim_start, before the threads). */
    bool measure_done;
    struct layer_streams streams; /* the temporal layers' encoder state: used by frame_job_begin (producer)
                                     and one encode thread per layer, one job at a time (encode_pool) */
    bool reset_streams;           /* tick only: a new sea (seed, patch, depth, loop, N): the next job resets the streams */
    bool sea_changed;             /* tick only: same phases, new amplitudes: the next job keeps the chains (codec.md) */

    /* builder only: the params of the newest state built (applied, or
     * waiting in `ready`): the base the next batch is checked against. */
    struct ocean_params build_base;

    pthread_mutex_t lock;             /* guards the fields below up to the atomics */
    pthread_cond_t cond;              /* tick and lws signal, builder waits */
    struct frame *latest;             /* tick writes (publish); lws reads (sim_latest) */
    bool builder_busy;                /* builder writes; sim_stop reads */
    struct sim_set *pending, **pending_tail;  /* lws appends (sim_submit); builder takes */
    struct built ready;               /* builder writes; tick takes at a tick boundary */
    bool ready_full;                  /* builder sets, tick clears */
    struct ocean_prepared *to_free;   /* tick writes (the state a commit swapped out); builder frees it */
    struct sim_set *answers, **answers_tail;  /* tick appends; lws takes (sim_take_answers) */
    pthread_cond_t prod_cond;         /* tick signals, producer waits */
    bool prod_busy;                   /* producer: stepping a frame or waiting for the encode before
                                         it (set when it takes a job, cleared once the frame's
                                         encode has started: the next step may overlap it) */
    bool prod_has_job;                /* tick sets (a job queued, one deep), producer clears */
    struct prod_job {                 /* tick writes, producer reads */
        double sim_time, t_tick;
        uint64_t seq;
        uint32_t version;
        float patch_size;
        long codec_samples[CAP_CODECS]; /* the plan's samples per codec on this tick (cost model) */
        bool cold;                      /* queued before grace_seq: its costs are not learned */
        struct frame_want want;
    } pj;
    uint64_t penalized_seq;           /* tick: the queued job (seq) the penalty was last raised for... */
    int penalized_ticks;              /* ...and on how many ticks */
    struct cost_model model;          /* producer and encode_done update (EWMA); tick and lws read */
    struct plan plan_pub;             /* tick writes; lws reads (sim_plan) */
    uint32_t plan_gen;                /* +1 per change of plan_pub */

    atomic_int demand[LAYER_KEYS_ALL]; /* atomic: lws writes (subscriptions); tick reads */
    atomic_int tdemand[LAYER_KEYS_ALL]; /* atomic: lws writes (temporal subscriptions, also in demand); tick reads */
    atomic_int key_want[LAYER_KEYS_ALL]; /* atomic: lws writes (temporal clients lacking references); tick reads */
    _Atomic double now_time;          /* atomic: tick writes; lws reads (state file) */
    atomic_uint_least64_t now_seq;    /* atomic: tick writes; lws reads (a new client's first frame) */
    atomic_int now_n;                 /* atomic: tick writes; lws reads (capacity at the N in force) */
};

void sim_set_free(struct sim_set *set) { free(set); }

struct ocean_params params_with(const struct ocean_params *base, const struct ocean_params *values, uint64_t mask)
{
    struct ocean_params p = *base;
    char err[64];
    for (size_t i = 0; i < param_count && i < 64; i++)
        if (mask & (1ull << i))
            param_set(&p, &param_table[i], param_get(values, &param_table[i]), err, sizeof err);
    return p;
}

/* ---- network-side API ---- */

void sim_submit(struct sim *s, struct sim_set *set)
{
    set->next = NULL;
    set->status = SIM_SET_QUEUED;
    pthread_mutex_lock(&s->lock);
    *s->pending_tail = set;
    s->pending_tail = &set->next;
    pthread_cond_signal(&s->cond);
    pthread_mutex_unlock(&s->lock);
}

struct sim_set *sim_take_answers(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    struct sim_set *a = s->answers;
    s->answers = NULL;
    s->answers_tail = &s->answers;
    pthread_mutex_unlock(&s->lock);
    return a;
}

struct frame *sim_latest(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    struct frame *f = s->latest;
    if (f)
        frame_ref(f);
    pthread_mutex_unlock(&s->lock);
    return f;
}

uint64_t sim_seq(struct sim *s) { return atomic_load(&s->now_seq); }
void sim_demand(struct sim *s, int key, int delta) { atomic_fetch_add(&s->demand[key], delta); }
void sim_demand_temporal(struct sim *s, int key, int delta) { atomic_fetch_add(&s->tdemand[key], delta); }
void sim_want_keyframes(struct sim *s, int key, int delta) { atomic_fetch_add(&s->key_want[key], delta); }
double sim_time_now(struct sim *s) { return atomic_load(&s->now_time); }

void sim_capacity(struct sim *s, struct capacity_info *out)
{
    pthread_mutex_lock(&s->lock);
    struct cost_model m = s->model;
    pthread_mutex_unlock(&s->lock);
    capacity_info_fill(&m, atomic_load(&s->now_n), out);
}

uint32_t sim_plan(struct sim *s, struct plan *out)
{
    pthread_mutex_lock(&s->lock);
    *out = s->plan_pub;
    uint32_t gen = s->plan_gen;
    pthread_mutex_unlock(&s->lock);
    return gen;
}

static void sub_keys(const struct subscription *sub, int demand[LAYER_KEYS_ALL], int delta)
{
    for (int c = 0; c < CTL_MAX_CASCADES; c++) {
        int lod, bound_index;
        unsigned fields = subscription_cascade(sub, c, &lod, &bound_index);
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
            if (fields & OCEAN_FIELD_BIT(f))
                demand[layer_key_cascade(c, f, c == 0 ? subscription_lod(sub, f) : lod, bound_index)] += delta;
    }
}

bool sim_admit(struct sim *s, const struct subscription *old, const struct subscription *want, long *need, long *budget)
{
    int demand[LAYER_KEYS_ALL], before[LAYER_KEYS_ALL];
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        before[k] = demand[k] = atomic_load(&s->demand[k]);
    if (old)
        sub_keys(old, demand, -1);
    sub_keys(want, demand, +1);
    int n = atomic_load(&s->now_n);
    long samples = 0;
    bool adds = false;
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        if (demand[k] > 0) {
            long side = n >> layer_key_lod(k);
            samples += side * side;
            adds |= before[k] <= 0;
        }
    pthread_mutex_lock(&s->lock);
    struct cost_model m = s->model;
    pthread_mutex_unlock(&s->lock);
    *need = samples;
    *budget = cost_encode_budget(&m, n);
    /* Layers someone already gets cost nothing more: never refused. */
    return !adds || samples <= *budget;
}

/* ---- builder thread ---- */

static uint64_t params_diff(const struct ocean_params *a, const struct ocean_params *b)
{
    uint64_t m = 0;
    for (size_t i = 0; i < param_count && i < 64; i++)
        if (param_get(a, &param_table[i]) != param_get(b, &param_table[i]))
            m |= 1ull << i;
    return m;
}

/* The parameters whose change gives the sea other phases (or another grid): the
 * previous frames do not predict it. */
static uint64_t phase_params(void)
{
    static const char *const names[] = { "resolution", "patch_size", "depth", "loop_period", "seed" };
    uint64_t m = 0;
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        const struct param_def *d = param_find(names[i]);
        if (d && d - param_table < 64)
            m |= 1ull << (d - param_table);
    }
    return m;
}

static bool physics_differ(const struct ocean_params *a, const struct ocean_params *b)
{
    for (size_t i = 0; i < param_count; i++)
        if (!(param_table[i].flags & PARAM_PLAYBACK) && param_get(a, &param_table[i]) != param_get(b, &param_table[i]))
            return true;
    return false;
}

static void set_failed(struct sim_set *set, enum sim_set_status status, const char *msg)
{
    set->status = status;
    snprintf(set->message, sizeof set->message, "%s", msg);
}

/* ocean_prepare against the ocean in force, or the test hook's simulated
 * out-of-memory (see sim_thread.h). ocean_prepare only reads what the
 * producer's ocean_step does not change, so it runs while frames are made;
 * it never overlaps a commit (the tick commits before it clears ready_full,
 * and the builder prepares only while ready_full is clear). */
static struct ocean_prepared *build_state(struct sim *s, const struct ocean_params *p, enum sim_set_status *why,
                                          char *err, size_t errlen)
{
    if (s->test_fail_seed >= 0 && p->seed == s->test_fail_seed) {
        usleep(500 * 1000); /* long enough for a test to queue another set behind this one */
        snprintf(err, errlen, "out of memory (test hook OCEAND_TEST_FAIL_BUILD_SEED)");
        *why = SIM_SET_NO_MEMORY;
        return NULL;
    }
    *why = SIM_SET_INVALID;
    return ocean_prepare(s->ocean, p, err, errlen);
}

/* Check each set of a batch on top of the previous one (all or nothing per
 * set) and prepare ONE new state for the whole batch if any physics changed.
 * Allocates nothing but that state: whatever fails, every set is answered
 * and build_base moves only to what was really prepared. */
static void build_batch(struct sim *s, struct sim_set *sets, struct built *out)
{
    struct ocean_params cur = s->build_base;
    char err[200];
    for (struct sim_set *set = sets; set; set = set->next) {
        struct ocean_params next = params_with(&cur, &set->values, set->mask);
        if (params_validate(&next, err, sizeof err) != 0) {
            set_failed(set, SIM_SET_INVALID, err);
            continue;
        }
        set->prev = cur;
        cur = next;
    }
    out->prepared = NULL;
    out->surface = NULL;
    if (physics_differ(&s->build_base, &cur)) {
        enum sim_set_status why;
        out->prepared = build_state(s, &cur, &why, err, sizeof err);
        if (!out->prepared) {
            LOGW("applying parameters failed: %s", err);
            for (struct sim_set *set = sets; set; set = set->next)
                if (set->status == SIM_SET_QUEUED)
                    set_failed(set, why, err);
            cur = s->build_base;
        }
        if (out->prepared && s->cfg.queries) /* the query snapshot, here rather than on the tick (1-8 ms) */
            out->surface = query_snapshot_prepared(s->cfg.queries, s->ocean, out->prepared);
    }
    s->build_base = cur;
    out->params = cur;
    out->sets = sets;
}

static void *builder_main(void *arg)
{
    struct sim *s = arg;
    pthread_mutex_lock(&s->lock);
    while (!atomic_load(&s->stop)) {
        if (s->to_free) {
            struct ocean_prepared *old = s->to_free;
            s->to_free = NULL;
            pthread_mutex_unlock(&s->lock);
            ocean_prepared_free(old);
            pthread_mutex_lock(&s->lock);
            continue;
        }
        if (!s->pending || s->ready_full) {
            pthread_cond_wait(&s->cond, &s->lock);
            continue;
        }
        struct sim_set *sets = s->pending;
        s->pending = NULL;
        s->pending_tail = &s->pending;
        s->builder_busy = true;
        pthread_mutex_unlock(&s->lock);

        struct built b;
        build_batch(s, sets, &b);

        pthread_mutex_lock(&s->lock);
        s->builder_busy = false;
        s->ready = b;
        s->ready_full = true;
    }
    pthread_mutex_unlock(&s->lock);
    return NULL;
}

/* ---- tick thread ---- */

/* At a tick boundary: swap in what the builder prepared, one version per
 * applied set, and hand every set back to the network thread answered. */
static void apply_pending(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    bool have = s->ready_full;
    struct built b = s->ready;
    pthread_mutex_unlock(&s->lock);
    if (!have)
        return;
    int commit_rc = 0;
    if (b.prepared) {
        /* O(1), and the producer is idle (our caller checked): no step or
         * field reader overlaps it, nor a prepare (ready_full is still set). */
        int n_before = ocean_resolution(s->ocean);
        /* An amplitude-only change eases in over ease_ticks ticks of the clock
         * (docs/simulation.md "Easing"), in sim time: from the previous tick
         * on, so this tick's frame is 1/K of the way. Paused: at once. */
        double dt = b.params.paused ? 0 : b.params.time_scale / s->cfg.tick_rate;
        commit_rc = ocean_commit_eased(s->ocean, b.prepared, s->sim_time - dt, s->cfg.ease_ticks * dt);
        if (commit_rc == 0 && b.surface && ocean_surface_ease(b.surface, s->ocean) != 0)
            LOGW("point queries: the snapshot of version %u misses the easing", (unsigned)(s->version + 1));
        if (commit_rc != 0) {
            LOGE("a prepared parameter change no longer fits the simulation; refused");
            for (struct sim_set *set = b.sets; set; set = set->next)
                if (set->status == SIM_SET_QUEUED)
                    set_failed(set, SIM_SET_INVALID, "internal: prepared against another state");
            b.params = s->params;
            ocean_surface_free(b.surface); /* a snapshot of what was not committed */
            b.surface = NULL;
        } else {
            /* A sea with other phases (seed, patch size, depth, loop period) or a new N:
             * the previous frames do not predict it, so every temporal layer starts new
             * chains (keyframes) with the next job. Any other change (wind, amplitude,
             * choppiness, spectrum shape, ...) keeps the phases: the chains go on and each
             * tile of the next frame is predicted or intra on its chain's grid, whichever
             * is smaller (docs/codec.md, "Changes of the sea"). Either way every frame
             * decodes; the split only decides bytes. */
            if (params_diff(&s->params, ocean_get_params(s->ocean)) & phase_params())
                s->reset_streams = true;
            else
                s->sea_changed = true;
            if (n_before != ocean_resolution(s->ocean)) {
                atomic_fetch_add(&g_metrics.replans, 1);
                LOGI("resolution now %d", ocean_resolution(s->ocean));
            }
        }
    }
    pthread_mutex_lock(&s->lock);
    s->ready_full = false;
    pthread_cond_signal(&s->cond);
    bool slot_free = b.prepared && s->to_free == NULL;
    if (slot_free)
        s->to_free = b.prepared; /* the old state: freeing 10-100 MB is the builder's job, not the tick's */
    pthread_mutex_unlock(&s->lock);
    if (b.prepared && !slot_free)
        ocean_prepared_free(b.prepared);
    struct sim_set *last = NULL;
    uint32_t version_before = s->version;
    for (struct sim_set *set = b.sets; set; set = set->next) {
        if (set->status == SIM_SET_QUEUED) {
            struct ocean_params before = s->params;
            s->params = params_with(&set->prev, &set->values, set->mask);
            s->version++;
            atomic_fetch_add(&g_metrics.param_changes, 1);
            set->status = SIM_SET_APPLIED;
            set->changed = params_diff(&before, &s->params);
        }
        set->params = s->params;
        set->version = s->version;
        last = set;
    }
    s->params = b.params;
    if (s->version != version_before || b.surface) /* point queries: this version from now on */
        query_version(s->cfg.queries, s->version, s->sim_time, b.surface != NULL || (b.prepared && commit_rc == 0),
                      b.surface);
    if (last) {
        pthread_mutex_lock(&s->lock);
        *s->answers_tail = b.sets;
        s->answers_tail = &last->next;
        pthread_mutex_unlock(&s->lock);
    }
}

/* The newest frame replaces the previous one. */
static void publish(struct sim *s, struct frame *f)
{
    pthread_mutex_lock(&s->lock);
    struct frame *old = s->latest;
    s->latest = f;
    pthread_mutex_unlock(&s->lock);
    frame_unref(old);
}

/* ---- encode (pool threads) ---- */

static void encode_item(void *ctx, int item, int worker) { frame_job_item(((struct sim *)ctx)->job, item, worker); }

/* The last encode thread of a job: finish the frame, publish it, wake lws. */
static void encode_done(void *ctx)
{
    struct sim *s = ctx;
    struct frame *f = frame_job_finish(s->job);
    double now = mono_now();
    if (f) {
        f->index = s->published++;
        frame_ref(f); /* for on_frame: publish() may hand the last reference on at once */
        publish(s, f);
        if (s->cfg.on_frame)
            s->cfg.on_frame(s->cfg.cluster_user, f); /* on this encode thread (frames are published in order) */
        frame_unref(f);
    }
    double enc = now - s->job_t_enc;
    histogram_observe(&g_metrics.encode_seconds, enc);
    histogram_observe(&g_metrics.tick_seconds, now - s->job_t_tick);
    /* The cost model follows each frame (cost_learn_encode: up slowly, one
     * frame at most twice the prediction; down quickly). */
    /* Tiny jobs are all overhead: they would skew the per-sample cost. Cold
     * ones (a new plan's or demand's first half second: keyframes, new
     * chains, buffers touched for the first time) cost more than the next
     * ones do: learned from, six of them took N = 1024 six fields from full
     * detail to LOD 1 0.2 s after it was planned, for good. */
    if (s->job_samples >= 4096 && !s->job_cold) {
        pthread_mutex_lock(&s->lock);
        cost_learn_encode(&s->model, s->job_codec_samples, enc);
        pthread_mutex_unlock(&s->lock);
    }
    if (s->cfg.wake)
        s->cfg.wake(s->cfg.wake_user);
}

/* ---- producer thread: step, copy the fields, start their encode ---- */

static int popcount_u(unsigned v)
{
    int c = 0;
    for (; v; v &= v - 1)
        c++;
    return c;
}

static void produce(struct sim *s, const struct prod_job *pj)
{
    double t0 = mono_now();
    /* Each cascade is stepped for the fields asked of it (probes read every cascade). */
    if (ocean_step_cascades(s->ocean, pj->sim_time, pj->want.cfields, OCEAN_MAX_CASCADES) != 0) {
        LOGE("ocean_step failed at t=%g", pj->sim_time);
        return;
    }
    double t_step = mono_now() - t0;
    histogram_observe(&g_metrics.step_seconds, t_step);
    /* probes: copies 3 grids per cascade */
    query_tick(s->cfg.queries, s->ocean, pj->want.cfields, pj->seq, pj->sim_time, pj->version);
    if (!pj->want.nkeys)
        return; /* stepped for the probes only: no frame */
    pthread_mutex_lock(&s->lock);
    struct cost_model base = s->model; /* the prediction without the live corrections */
    base.step_scale = 1;
    base.penalty = 1;
    double predicted = cost_step_s(&base, ocean_resolution(s->ocean), popcount_u(pj->want.fields));
    /* One step far slower than the model counts as at most twice the
     * current scale: a one-off (foam's cold spin-up, ~20 steps, after a new
     * N or a first foam subscription; a page-fault storm) must not make the
     * plan step-bound for everyone and then, with frames made rare, stay so
     * (under ASan the spin-up read as an 85 ms step at N = 256: 2 frames in
     * 4 s). Sustained slowness still raises it by 10 % a frame. Cold
     * jobs (a new demand's first half second) are not learned from at all. */
    if (predicted > 0 && !pj->cold)
        s->model.step_scale = cost_ewma(s->model.step_scale, fmin(t_step / predicted, 2 * s->model.step_scale));
    pthread_mutex_unlock(&s->lock);
    /* The previous frame's encode overlapped this step; its buffers are about
     * to be reused, so it must be done (we help rather than sleep). */
    encode_pool_wait(s->pool);
    struct oc_frame_header h = {
        .seq = pj->seq, .sim_time = pj->sim_time, .params_version = pj->version, .patch_size = pj->patch_size,
    };
    int items = frame_job_begin(s->job, s->ocean, s->cfg.tile_size, &pj->want, &h);
    if (items < 0) {
        LOGE("out of memory preparing frame %llu", (unsigned long long)pj->seq);
        return;
    }
    s->job_t_tick = pj->t_tick;
    s->job_t_enc = mono_now();
    s->job_samples = frame_job_samples(s->job);
    memcpy(s->job_codec_samples, pj->codec_samples, sizeof s->job_codec_samples);
    s->job_cold = pj->cold;
    encode_pool_start(s->pool, items, encode_item, encode_done, s);
}

static void *producer_main(void *arg)
{
    struct sim *s = arg;
    pthread_mutex_lock(&s->lock);
    for (;;) {
        while (!atomic_load(&s->stop) && !s->prod_has_job)
            pthread_cond_wait(&s->prod_cond, &s->lock);
        if (atomic_load(&s->stop))
            break;
        struct prod_job pj = s->pj;
        s->prod_has_job = false;
        s->prod_busy = true;
        pthread_mutex_unlock(&s->lock);
        produce(s, &pj);
        pthread_mutex_lock(&s->lock);
        s->prod_busy = false;
    }
    pthread_mutex_unlock(&s->lock);
    return NULL;
}

/* ---- tick thread: the clock, the plan, and handing frames to the producer ---- */

/* Re-plan from the demand: a more degraded plan as soon as the plan in
 * force no longer fits CAP_KEEP_SCALE of the budget, a less degraded one
 * only after it has held for hold_ticks (3 s at first) with 20 % headroom
 * (CAP_RECOVER_SCALE; hysteresis: clients are told every change). The
 * headroom was 40 %: a plan bound by the step (N = 2048: a step of 20-30 ms
 * against a budget of 26.7) never had it, so once degraded by a slow moment
 * it stayed there (20 frames/s where 25-30 fit). A degrade also needs the
 * value to fall under 90 % of the plan in force.
 *
 * Recovery probe: a group degraded to a coarser LOD is sent intra, so
 * while no temporal layer is encoded the temporal cost figure is not
 * measured again, and one taken under load or from a slow start would keep
 * the group degraded for good. After hold_ticks degraded with no recovery
 * in sight, the plan is computed again with the temporal figure forgotten
 * (the start-up temporal_ratio x the intra figure, which the degraded frames keep
 * current); if that fits with the headroom it is taken (the figure starts
 * afresh) and its frames tell. A recovery undone within PLAN_FAILED_S (the
 * probe, or a recovery the model predicted, did not fit) doubles
 * hold_ticks, up to PLAN_HOLD_MAX_S, so a group that does not fit is tried
 * less and less often; a new demand, or a recovery that holds PLAN_HELD_S,
 * resets it. */
#define PLAN_HOLD_S 3
#define PLAN_HOLD_MAX_S 60
#define PLAN_FAILED_S 5
#define PLAN_HELD_S 10
static bool plan_any_degraded(const struct plan *p)
{
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (plan_degraded(p, g) || plan_intra(p, g))
            return true;
    return false;
}

/* a better than b for the same demand: more detail x rate (plan_value), or
 * as much with fewer samples on the codec rung (temporal clients served
 * intra: same detail, more bytes). Equal values are sums of the same terms. */
static bool plan_better(const struct plan *a, const struct plan *b, int n)
{
    double va = plan_value(a, n), vb = plan_value(b, n);
    return va > vb || (va == vb && plan_intra_value(a, n) < plan_intra_value(b, n));
}

/* a worse than b, to be taken at once: under 90 % of its value (the band
 * against noise), or no more value and more samples on the codec rung (the
 * temporal codec no longer fits: same detail, so no band is needed; the
 * way back still needs the headroom and the hold). */
static bool plan_worse(const struct plan *a, const struct plan *b, int n)
{
    double va = plan_value(a, n), vb = plan_value(b, n);
    return va < 0.9 * vb || (va <= vb && plan_intra_value(a, n) > plan_intra_value(b, n));
}

static void update_plan(struct sim *s, const int demand[LAYER_KEYS_ALL], const int tdemand[LAYER_KEYS_ALL], int n, int ts)
{
    const int rate = (int)s->cfg.tick_rate > 0 ? (int)s->cfg.tick_rate : 1;
    if (s->hold_ticks <= 0)
        s->hold_ticks = PLAN_HOLD_S * rate;
    if (s->since_change < INT_MAX)
        s->since_change++;
    pthread_mutex_lock(&s->lock);
    struct cost_model m = s->model;
    pthread_mutex_unlock(&s->lock);
    struct plan now, easy;
    /* The plan in force keeps its place up to CAP_KEEP_SCALE of the budget;
     * a new demand is planned at the budget itself. */
    capacity_plan(&m, n, ts, demand, tdemand, CAP_KEEP_SCALE, &now);
    bool same_demand = true;
    for (int g = 0; g < PLAN_GROUPS; g++)
        same_demand &= now.fields[g] == s->plan.fields[g] && now.temporal[g] == s->plan.temporal[g];
    if (!same_demand)
        capacity_plan(&m, n, ts, demand, tdemand, 1.0, &now);
    struct plan next = s->plan;
    bool probe = false;
    if (!same_demand) {
        next = now;
        s->lower_ticks = 0;
        s->hold_ticks = PLAN_HOLD_S * rate;
    } else if (plan_worse(&now, &s->plan, n)) {
        capacity_plan(&m, n, ts, demand, tdemand, 1.0, &next); /* out of the band: what fits the budget */
        s->lower_ticks = 0;
        if (s->recovered && s->since_change < PLAN_FAILED_S * rate) /* the recovery did not fit */
            s->hold_ticks = s->hold_ticks * 2 < PLAN_HOLD_MAX_S * rate ? s->hold_ticks * 2 : PLAN_HOLD_MAX_S * rate;
    } else {
        capacity_plan(&m, n, ts, demand, tdemand, CAP_RECOVER_SCALE, &easy);
        if (plan_better(&easy, &s->plan, n)) {
            if (++s->lower_ticks >= s->hold_ticks) {
                next = easy;
                s->lower_ticks = 0;
            }
        } else {
            s->lower_ticks = 0;
            long encoded[CAP_CODECS];
            plan_samples(&s->plan, n, NULL, encoded);
            if (s->since_change >= s->hold_ticks && plan_any_degraded(&s->plan) && encoded[CAP_TEMPORAL] == 0 &&
                m.enc_temporal_s > 0) {
                struct cost_model fresh = m;
                cost_forget_temporal(&fresh);
                capacity_plan(&fresh, n, ts, demand, tdemand, CAP_RECOVER_SCALE, &easy);
                if (plan_better(&easy, &s->plan, n)) {
                    next = easy;
                    probe = true;
                } else {
                    s->since_change = 0; /* nothing to try: look again after another hold */
                }
            }
        }
    }
    if (s->recovered && s->since_change >= PLAN_HELD_S * rate && s->hold_ticks != PLAN_HOLD_S * rate)
        s->hold_ticks = PLAN_HOLD_S * rate; /* the recovery held */
    if (!same_demand)
        s->grace_seq = s->seq + (uint64_t)(rate / 2 + 1);
    if (plan_same(&next, &s->plan))
        return;
    if (probe) { /* the temporal figure starts afresh from the probe's frames */
        pthread_mutex_lock(&s->lock);
        cost_forget_temporal(&s->model);
        pthread_mutex_unlock(&s->lock);
    }
    LOGD("plan change at seq %llu: step x%.2f, encode %.2f ns/sample intra, %.2f temporal%s, penalty x%.2f, hold %.0f s%s",
         (unsigned long long)s->seq, m.step_scale, m.enc_s_per_sample * 1e9, cost_encode_codec_s(&m, CAP_TEMPORAL) * 1e9 / fmax(m.penalty, 1),
         m.enc_temporal_s > 0 ? "" : " (prior)", fmax(m.penalty, 1), s->hold_ticks / (double)rate, probe ? ", recovery probe" : "");
    s->recovered = same_demand && plan_better(&next, &s->plan, n);
    s->since_change = 0;
    /* New layers or LODs start with keyframes and cold buffers: their first
     * slow frames must not raise the penalty (tick) and undo the plan */
    s->grace_seq = s->seq + (uint64_t)(rate / 2 + 1);
    int degraded = 0, intra = 0;
    for (int g = 0; g < PLAN_GROUPS; g++) {
        degraded += plan_degraded(&next, g);
        intra += plan_intra(&next, g);
        if ((plan_degraded(&next, g) && !plan_degraded(&s->plan, g)) || (plan_intra(&next, g) && !plan_intra(&s->plan, g)))
            LOGI("degrading lod %d bound %g: encoded at lod %d%s, %g frames/s (%s)", g / CTL_BOUND_COUNT,
                 ctl_bounds[g % CTL_BOUND_COUNT], next.lod[g], plan_intra(&next, g) ? " intra" : "",
                 next.rate[g] * s->cfg.tick_rate, next.reason);
        if (s->credit[g] == 0) /* spread the groups' ticks: equal rates must not all fall on one tick */
            s->credit[g] = fmod(0.618034 * (g + 1), 1.0);
    }
    atomic_store(&g_metrics.degraded_groups, degraded);
    atomic_store(&g_metrics.intra_groups, intra);
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (next.fields[g])
            LOGD("plan: lod %d bound %g: encoded at lod %d%s, %g frames/s (%s)", g / CTL_BOUND_COUNT,
                 ctl_bounds[g % CTL_BOUND_COUNT], next.lod[g], plan_intra(&next, g) ? " intra" : "", next.rate[g] * s->cfg.tick_rate,
                 next.reason[0] ? next.reason : "not degraded");
    s->plan = next;
    pthread_mutex_lock(&s->lock);
    s->plan_pub = next;
    s->plan_gen++;
    pthread_mutex_unlock(&s->lock);
}

static void tick(struct sim *s, double t_tick)
{
    pthread_mutex_lock(&s->lock);
    bool idle = !s->prod_busy && !s->prod_has_job, queued = s->prod_has_job, set_ready = s->ready_full;
    pthread_mutex_unlock(&s->lock);
    if (idle) {
        apply_pending(s); /* the producer is not using the ocean: it may be swapped */
        if (s->model.penalty > 1) { /* it kept up: the transient penalty fades (see below) */
            pthread_mutex_lock(&s->lock);
            s->model.penalty = s->model.penalty * 0.95 > 1 ? s->model.penalty * 0.95 : 1;
            pthread_mutex_unlock(&s->lock);
        }
    }
    s->seq++;
    int n = ocean_resolution(s->ocean);
    atomic_store(&s->now_seq, s->seq);
    atomic_store(&s->now_time, s->sim_time);
    atomic_store(&s->now_n, n);
    atomic_store(&g_metrics.sim_time, s->sim_time);
    atomic_store(&g_metrics.params_version, s->version);
    atomic_store(&g_metrics.resolution, n);

    int demand[LAYER_KEYS_ALL], tdemand[LAYER_KEYS_ALL];
    bool any = false;
    uint8_t remote[SIM_DEMAND_BYTES] = { 0 };
    if (s->cfg.remote_demand) /* --role sim: the layer keys other daemons want */
        s->cfg.remote_demand(s->cfg.cluster_user, remote);
    for (int k = 0; k < LAYER_KEYS_ALL; k++) {
        demand[k] = atomic_load(&s->demand[k]);
        tdemand[k] = atomic_load(&s->tdemand[k]);
        if (demand[k] <= 0 && ((remote[k >> 3] >> (k & 7)) & 1))
            demand[k] = 1;
        any |= demand[k] > 0;
    }
    unsigned probe_fields = query_probe_fields(s->cfg.queries); /* probes need height, dx, dz */
    if (!any) {
        if (s->had_demand)
            publish(s, NULL); /* nobody is ever handed a frame from before an idle period */
        s->had_demand = false;
        if (!probe_fields)
            return;
    } else {
        s->had_demand = true;
        update_plan(s, demand, tdemand, n, frame_tile_size(s->cfg.tile_size, n));
    }

    /* The groups due this tick, at their planned LOD. */
    struct prod_job pj = { .sim_time = s->sim_time, .t_tick = t_tick, .seq = s->seq, .version = s->version,
                           .patch_size = (float)s->params.patch_size };
    bool due[PLAN_GROUPS];
    for (int g = 0; g < PLAN_GROUPS; g++) {
        due[g] = false;
        if (!s->plan.fields[g])
            continue;
        s->credit[g] += s->plan.rate[g];
        if (s->credit[g] > 2)
            s->credit[g] = 2; /* a group held back by a busy producer does not pile up */
        due[g] = s->credit[g] >= 1;
    }
    for (int k = 0; k < LAYER_KEYS_ALL; k++) {
        int g = plan_group(layer_key_lod(k), layer_key_bound(k));
        if (demand[k] > 0 && due[g]) {
            pj.want.fields |= OCEAN_FIELD_BIT(layer_key_field(k));
            pj.want.cfields[layer_key_which_cascade(k)] |= OCEAN_FIELD_BIT(layer_key_field(k));
            pj.want.lod[pj.want.nkeys] = s->plan.lod[g];
            pj.want.keys[pj.want.nkeys++] = (uint16_t)k;
            /* Temporal layers (PROTOCOL.md §5.9): a stream when a temporal client wants
             * the key; intra tiles for clients that are not temporal (edges included),
             * and this tick's keyframes for temporal ones that lack the references. */
            int temporal = atomic_load(&s->tdemand[k]);
            pj.want.temporal[k] = temporal > 0;
            bool edge = (remote[k >> 3] >> (k & 7)) & 1;
            int key_want = atomic_load(&s->key_want[k]);
            pj.want.intra[k] = demand[k] > temporal || edge || key_want > 0;
            if (plan_intra(&s->plan, g)) { /* the codec rung: intra tiles for everyone, no stream (its state is dropped) */
                pj.want.temporal[k] = 0;
                pj.want.intra[k] = 1;
            }
            pj.want.kclients[k] = (uint16_t)(key_want < 0 ? 0 : key_want > 65535 ? 65535 : key_want);
            /* who takes this layer every tick: the stream's grid refinement (layer_stream.h) */
            pj.want.tclients[k] = (uint16_t)(temporal < 0 ? 0 : temporal > 65535 ? 65535 : temporal);
            pj.want.iclients[k] = (uint16_t)(edge ? 65535 : demand[k] - temporal > 65535 ? 65535
                                                         : demand[k] > temporal ? demand[k] - temporal : 0);
        }
    }
    if (!pj.want.nkeys && !probe_fields)
        return; /* a degraded group's off tick */
    pj.want.fields |= probe_fields; /* stepped for the probes, not encoded unless a layer wants them */
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++) /* probes sum every cascade in force */
        pj.want.cfields[c] |= probe_fields;
    if (!idle && set_ready)
        return; /* let the producer drain so that the parameter change applies next tick */
    if (queued) {
        /* The producer has not even started the frame before: this one cannot
         * start on time. Counted as an overrun, and taken as proof that the
         * model is optimistic (a shared machine, a slower N): costs up by a
         * quarter at once (the penalty, at most x64), so the next plan
         * degrades; each tick that finds the producer idle takes 5 % of it
         * back (x64 -> x1 in ~2.7 s), whether or not frames are rare. */
        atomic_fetch_add(&g_metrics.overruns, 1);
        pthread_mutex_lock(&s->lock);
        /* On the first three ticks a job is found waiting, not on every
         * tick it keeps waiting: one step slowed to 300 ms by the machine
         * (another process, a page-fault storm) used to find the same job
         * queued on 9 ticks in a row and raise the costs x1.25^9 = x7.5,
         * which planned the client down to 1-2 frames/s for seconds (seen
         * at N = 2048). At most x1.95 per job now; jobs found waiting one
         * after the other still add up. */
        if (s->pj.seq != s->penalized_seq) {
            s->penalized_seq = s->pj.seq;
            s->penalized_ticks = 0;
        }
        /* Nor in the first half second of new demand or a new plan: its
         * first frames (keyframes, new chains, buffers touched for the first
         * time) cost 3-7 times what the next ones do, and raising the costs
         * on them degraded a subscription that fits within 0.15 s (N = 1024
         * h/dx/dz temporal); if it really does not fit, the frames' costs
         * say so a few frames later (cost_learn_encode). */
        if (s->penalized_ticks++ < 3 && s->seq >= s->grace_seq)
            s->model.penalty = fmin(fmax(s->model.penalty, 1) * 1.25, 64);
        pthread_mutex_unlock(&s->lock);
        return;
    }
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (due[g])
            s->credit[g] -= 1;
    plan_samples(&s->plan, n, due, pj.codec_samples);
    pj.cold = s->seq < s->grace_seq;
    pj.want.reset_streams = s->reset_streams;
    pj.want.sea_changed = s->sea_changed && !s->reset_streams;
    s->reset_streams = false;
    s->sea_changed = false;
    pthread_mutex_lock(&s->lock);
    s->pj = pj;
    s->prod_has_job = true; /* one deep: taken when the producer is done with the frame before */
    pthread_cond_signal(&s->prod_cond);
    pthread_mutex_unlock(&s->lock);
}

static void *sim_main(void *arg)
{
    struct sim *s = arg;
    /* Linux nice values are per thread: raise only the tick's priority. */
    if (s->cfg.nice && setpriority(PRIO_PROCESS, (id_t)gettid(), s->cfg.nice) != 0)
        LOGW("cannot set the tick thread's nice value to %d: %s", s->cfg.nice, strerror(errno));
    const double period = 1.0 / s->cfg.tick_rate;
    const long period_ns = (long)(1e9 / s->cfg.tick_rate);
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    double elapsed = 0; /* wall seconds since the previous tick (0 on the first) */
    while (!atomic_load(&s->stop)) {
        double t0 = mono_now();
        /* The clock runs under the parameters that were in force during the
         * interval, with or without clients (PROTOCOL.md §3.1). */
        if (!s->params.paused)
            s->sim_time += s->params.time_scale * elapsed;
        tick(s, t0);
        /* Always wake lws: answers (params) may be waiting even without a frame. */
        if (s->cfg.wake)
            s->cfg.wake(s->cfg.wake_user);
        atomic_fetch_add(&g_metrics.ticks, 1);

        /* Absolute schedule: next deadline = previous + period, never drifting.
         * If we are already past it, count an overrun and skip the missed
         * ticks instead of running them back to back. */
        long steps = 1;
        next.tv_nsec += period_ns;
        while (next.tv_nsec >= 1000000000L) {
            next.tv_nsec -= 1000000000L;
            next.tv_sec++;
        }
        struct timespec now;
        clock_gettime(CLOCK_MONOTONIC, &now);
        double late = (double)(now.tv_sec - next.tv_sec) + (now.tv_nsec - next.tv_nsec) * 1e-9;
        if (late > 0) {
            long skip = (long)(late / period) + 1;
            atomic_fetch_add(&g_metrics.overruns, 1);
            atomic_fetch_add(&g_metrics.ticks_late, 1);
            steps += skip;
            long long ns = (long long)next.tv_nsec + (long long)skip * period_ns;
            next.tv_sec += (time_t)(ns / 1000000000LL);
            next.tv_nsec = (long)(ns % 1000000000LL);
        }
        elapsed = (double)steps * period;
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL) == EINTR && !atomic_load(&s->stop))
            ;
    }
    return NULL;
}

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

static void measure_model(struct sim *s)
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

static void sim_free_parts(struct sim *s)
{
    encode_pool_free(s->pool);
    frame_job_free(s->job);
    layer_streams_free(&s->streams);
    ocean_free(s->ocean);
    pthread_cond_destroy(&s->prod_cond);
    pthread_cond_destroy(&s->cond);
    pthread_mutex_destroy(&s->lock);
    free(s);
}

struct sim *sim_start(const struct ocean_params *p, const struct sim_config *cfg, char *err, size_t errlen)
{
    struct sim *s = calloc(1, sizeof *s);
    if (!s) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    s->cfg = *cfg;
    if (s->cfg.encode_threads < 1)
        s->cfg.encode_threads = 1;
    s->params = *p;
    s->version = cfg->start_version;
    s->sim_time = cfg->start_time;
    s->seq = cfg->start_seq;
    s->pending_tail = &s->pending;
    s->answers_tail = &s->answers;
    layer_streams_init(&s->streams, cfg->keyframe_interval, cfg->stream_budget);
    const char *hook = getenv("OCEAND_TEST_FAIL_BUILD_SEED");
    s->test_fail_seed = hook && *hook ? atoi(hook) : -1;
    if (s->test_fail_seed >= 0)
        LOGW("test hook: builds with seed %d will fail (OCEAND_TEST_FAIL_BUILD_SEED)", s->test_fail_seed);
    /* Frames are allocated on whichever encode thread finishes them and freed
     * on the lws thread: with one malloc arena per thread, each would keep its
     * own cache of freed frames (RSS creeping up by megabytes); one arena
     * reuses them. Allocations are a few per frame: no contention to speak of. */
    mallopt(M_ARENA_MAX, 1);
    /* Fixed thresholds (setting them turns glibc's dynamic ones off, which
     * after one large free keep megabytes of freed frames in the heap). */
    mallopt(M_MMAP_THRESHOLD, 128 * 1024);
    mallopt(M_TRIM_THRESHOLD, 256 * 1024);
    pthread_mutex_init(&s->lock, NULL);
    pthread_cond_init(&s->cond, NULL);
    pthread_cond_init(&s->prod_cond, NULL);
    s->build_base = *p;
    s->ocean = ocean_create(p, &cfg->opts, err, errlen);
    if (!s->ocean) {
        sim_free_parts(s);
        return NULL;
    }
    /* The encode pool: encode_threads threads (while the producer sleeps
     * until the next tick every core may encode), plus the producer, which
     * helps while it waits for the previous frame (encode_pool_wait). */
    s->pool = encode_pool_new(s->cfg.encode_threads);
    s->job = s->pool ? frame_job_new(encode_pool_threads(s->pool)) : NULL;
    if (!s->pool || !s->job) {
        snprintf(err, errlen, "out of memory (encoder threads)");
        sim_free_parts(s);
        return NULL;
    }
    measure_model(s);
    s->model.temporal_budget = s->cfg.temporal_budget;
    frame_job_set_streams(s->job, &s->streams); /* after the start-up measurement: intra only */
    atomic_store(&s->now_time, s->sim_time);
    if (cfg->queries)
        query_version(cfg->queries, s->version, s->sim_time, true, query_snapshot(cfg->queries, s->ocean));
    atomic_store(&s->now_n, p->resolution);
    atomic_store(&g_metrics.resolution, p->resolution);
    atomic_store(&g_metrics.params_version, s->version);
    /* The tick thread must never take SIGINT/SIGTERM: block them for it
     * (and for the builder and producer threads), whatever the caller did.
     * (The encode pool's threads were started above with the caller's mask:
     * main blocks nothing before its handlers exist, and they only encode.) */
    sigset_t block, old;
    sigemptyset(&block);
    sigaddset(&block, SIGINT);
    sigaddset(&block, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &block, &old);
    int rc = pthread_create(&s->producer, NULL, producer_main, s);
    s->producer_started = rc == 0;
    if (rc == 0) {
        rc = pthread_create(&s->thread, NULL, sim_main, s);
        if (rc != 0) {
            atomic_store(&s->stop, true);
            pthread_mutex_lock(&s->lock);
            pthread_cond_broadcast(&s->prod_cond);
            pthread_mutex_unlock(&s->lock);
            pthread_join(s->producer, NULL);
        }
    }
    if (rc == 0) {
        s->builder_started = pthread_create(&s->builder, NULL, builder_main, s) == 0;
        if (!s->builder_started)
            LOGW("no builder thread: parameter changes will not be applied");
    }
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (rc != 0) {
        snprintf(err, errlen, "cannot start the simulation threads: %s", strerror(rc));
        sim_free_parts(s);
        return NULL;
    }
    return s;
}

static void free_sets(struct sim_set *set)
{
    while (set) {
        struct sim_set *n = set->next;
        sim_set_free(set);
        set = n;
    }
}

void sim_stop(struct sim *s)
{
    if (!s)
        return;
    atomic_store(&s->stop, true);
    pthread_join(s->thread, NULL);
    pthread_mutex_lock(&s->lock);
    pthread_cond_broadcast(&s->prod_cond);
    pthread_mutex_unlock(&s->lock);
    pthread_join(s->producer, NULL);
    encode_pool_wait(s->pool); /* its last frame, published before we free */
    pthread_mutex_lock(&s->lock);
    pthread_cond_broadcast(&s->cond);
    bool busy = s->builder_busy;
    pthread_mutex_unlock(&s->lock);
    if (s->builder_started && busy) {
        /* A build at large N may take a while; do not hold up shutdown for it.
         * The builder still uses *s: leave it all to the process exit. */
        pthread_detach(s->builder);
        LOGW("exiting while a parameter change is being built");
        return;
    }
    if (s->builder_started)
        pthread_join(s->builder, NULL);
    free_sets(s->pending);
    free_sets(s->answers);
    if (s->ready_full) {
        free_sets(s->ready.sets);
        ocean_surface_free(s->ready.surface);
        if (s->ready.prepared)
            ocean_prepared_free(s->ready.prepared);
    }
    ocean_prepared_free(s->to_free);
    frame_unref(s->latest);
    sim_free_parts(s);
}

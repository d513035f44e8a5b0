/* sim_thread.c — starting and stopping the tick pipeline (tick, producer and
 * builder threads, the encode pool), and the calls the network thread makes
 * into it: sets in, answers and frames out, demand counters. */
#include "tick_internal.h"

#include <errno.h>
#include <malloc.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "metrics.h"

void sim_set_free(struct sim_set *set)
{
    if (!set)
        return;
    free(set->sea);
    free(set->sea_summary);
    free(set);
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
bool sim_take_trim(struct sim *s) { return atomic_exchange(&s->trim_wanted, false); }

int sim_adopt(struct sim *s, const struct ocean_params *p, uint32_t version, double sim_time, uint64_t wall_us,
              uint64_t seq, const struct sea_spectrum *sea)
{
    struct sim_set *set = calloc(1, sizeof *set);
    if (!set)
        return -1;
    if (sea && !(set->sea = malloc(sizeof *set->sea))) {
        free(set);
        return -1;
    }
    if (sea)
        *set->sea = *sea;
    set->values = *p;
    set->mask = PARAM_COUNT >= 64 ? ~0ull : (1ull << PARAM_COUNT) - 1; /* every parameter */
    set->adopt = true;
    set->adopt_version = version;
    set->adopt_time = sim_time;
    set->adopt_wall_us = wall_us;
    set->adopt_seq = seq;
    sim_submit(s, set);
    return 0;
}

char *sim_sea_summary(struct sim *s)
{
    char *t = s->start_sea_summary;
    s->start_sea_summary = NULL;
    return t;
}

void sim_save_now(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    s->save_wanted = true;
    pthread_cond_signal(&s->cond);
    pthread_mutex_unlock(&s->lock);
}

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

bool sim_admit(struct sim *s, const struct subscription *old, const struct subscription *want, long *need, long *budget)
{
    int demand[LAYER_KEYS_ALL], before[LAYER_KEYS_ALL];
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        before[k] = demand[k] = atomic_load(&s->demand[k]);
    if (old)
        subscription_layer_keys(old, demand, -1);
    subscription_layer_keys(want, demand, +1);
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

static void sim_free_parts(struct sim *s)
{
    encode_pool_free(s->pool);
    frame_job_free(s->job);
    layer_streams_free(&s->streams);
    ocean_free(s->ocean);
    free(s->build_sea);
    free(s->start_sea_summary);
    body_sim_free(s->bodies);
    body_cmds_free(s->body_cmds);
    body_cmds_free(s->body_answers);
    body_snap_unref(s->bodies_latest);
    body_snap_unref(s->job_bodies);
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
    s->body_cmds_tail = &s->body_cmds;
    s->body_answers_tail = &s->body_answers;
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
    s->build_version = cfg->start_version;
    s->cfg.sea = NULL; /* copied here: the caller's may go */
    if (cfg->sea && !(s->build_sea = malloc(sizeof *s->build_sea))) {
        snprintf(err, errlen, "out of memory (the measured sea)");
        sim_free_parts(s);
        return NULL;
    }
    if (cfg->sea)
        *s->build_sea = *cfg->sea;
    s->ocean = ocean_create_sea(p, cfg->sea, &cfg->opts, err, errlen);
    if (!s->ocean) {
        sim_free_parts(s);
        return NULL;
    }
    if (cfg->sea) { /* what hello says of it until the first change (sim_sea_summary) */
        char why[200];
        struct sea_capture cap;
        bool have_cap = sea_capture(cfg->sea, p, &cap, why, sizeof why) == SEA_OK;
        s->start_sea_summary = sim_sea_summary_text(cfg->sea, have_cap ? &cap : NULL, cfg->start_version);
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
    if (!(s->bodies = body_sim_new(cfg, &s->bodies_restored, err, errlen))) {
        sim_free_parts(s);
        return NULL;
    }
    s->cfg.restore = NULL; /* copied into the world: the caller's array may go */
    s->cfg.nrestore = 0;
    calibrate_cost_model(s);
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
        rc = pthread_create(&s->thread, NULL, tick_main, s);
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


/* sim_thread.c — the tick loop (apply -> step -> encode -> publish) and the
 * builder thread that prepares parameter sets off the tick path. */
#include "sim_thread.h"

#include "clock.h"

#include <errno.h>
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

#include "log.h"
#include "metrics.h"

/* A batch of sets the builder has prepared for one tick boundary. */
struct built {
    struct ocean_prepared *prepared; /* new state for s->ocean (ocean_prepare), or NULL when only playback changed */
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

    struct ocean *ocean;          /* sim_start writes the pointer, never changed after; tick steps and
                                   * commits it; builder runs ocean_prepare against it (allowed while
                                   * the tick steps, ocean.h), never while a commit runs (lock) */
    struct ocean_params params;   /* tick only: the parameters in force */
    uint32_t version;             /* tick only: params_version in force */
    double sim_time;              /* tick only: the clock (copied to now_time) */
    uint64_t seq;                 /* tick only: ticks run (PROTOCOL.md §3.3: +1 per tick, frame or not) */
    uint64_t published;           /* tick only: frames published, for struct frame.index */
    struct oc_encoder *enc;       /* tick only */

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

    atomic_int demand[LAYER_KEYS_ALL]; /* atomic: lws writes (subscriptions); tick reads */
    _Atomic double now_time;          /* atomic: tick writes; lws reads (state file) */
    atomic_uint_least64_t now_seq;    /* atomic: tick writes; lws reads (a new client's first frame) */
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
double sim_time_now(struct sim *s) { return atomic_load(&s->now_time); }

/* ---- builder thread ---- */

static uint64_t params_diff(const struct ocean_params *a, const struct ocean_params *b)
{
    uint64_t m = 0;
    for (size_t i = 0; i < param_count && i < 64; i++)
        if (param_get(a, &param_table[i]) != param_get(b, &param_table[i]))
            m |= 1ull << i;
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

/* ocean_prepare, or the test hook's simulated out-of-memory (see sim_thread.h). */
static struct ocean_prepared *build_ocean(struct sim *s, const struct ocean_params *p, enum sim_set_status *why,
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
 * set) and build ONE new ocean for the whole batch if any physics changed.
 * Allocates nothing but the ocean: whatever fails, every set is answered
 * and build_base moves only to what was really built. */
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
        out->prepared = build_ocean(s, &cur, &why, err, sizeof err);
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
    int commit_rc = 0, old_n = ocean_resolution(s->ocean);
    /* Commit under the lock, before the builder is told `ready` is free:
     * it may then start the next ocean_prepare, which must not overlap a
     * commit. The commit only swaps pointers (ocean.h). */
    if (have && b.prepared)
        commit_rc = ocean_commit(s->ocean, b.prepared);
    s->ready_full = false;
    if (have)
        pthread_cond_signal(&s->cond);
    pthread_mutex_unlock(&s->lock);
    if (!have)
        return;
    if (b.prepared) {
        if (commit_rc != 0) {
            LOGE("applying parameters failed: the prepared state was stale");
            for (struct sim_set *set = b.sets; set; set = set->next)
                if (set->status == SIM_SET_QUEUED)
                    set_failed(set, SIM_SET_INVALID, "internal: stale prepared state");
            b.params = s->params;
            ocean_surface_free(b.surface); /* a snapshot of what was not committed */
            b.surface = NULL;
        } else if (old_n != ocean_resolution(s->ocean)) {
            atomic_fetch_add(&g_metrics.replans, 1);
            LOGI("resolution now %d", ocean_resolution(s->ocean));
        }
        /* b.prepared now holds the old state (or the unused new one). */
        pthread_mutex_lock(&s->lock);
        bool slot_free = s->to_free == NULL;
        if (slot_free) {
            s->to_free = b.prepared; /* freeing 10-100 MB is the builder's job, not the tick's */
            pthread_cond_signal(&s->cond);
        }
        pthread_mutex_unlock(&s->lock);
        if (!slot_free)
            ocean_prepared_free(b.prepared);
    }
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

/* Which layers clients want now, from the demand counters. */
static void demand_snapshot(struct sim *s, struct frame_want *w)
{
    memset(w->cfields, 0, sizeof w->cfields);
    w->fields = 0;
    w->nkeys = 0;
    uint8_t remote[SIM_DEMAND_BYTES] = { 0 };
    if (s->cfg.remote_demand)
        s->cfg.remote_demand(s->cfg.cluster_user, remote);
    for (int k = 0; k < LAYER_KEYS_ALL; k++) /* a cluster's remote demand: cascade 0 keys only */
        if (atomic_load(&s->demand[k]) > 0 || (k < LAYER_KEYS && ((remote[k >> 3] >> (k & 7)) & 1))) {
            w->fields |= OCEAN_FIELD_BIT(layer_key_field(k));
            w->cfields[layer_key_which_cascade(k)] |= OCEAN_FIELD_BIT(layer_key_field(k));
            w->keys[w->nkeys++] = (uint16_t)k;
        }
}

/* Each cascade is stepped for the fields asked of it (probes read cascade 0). */
static bool step(struct sim *s, const struct frame_want *want, unsigned probe_fields)
{
    unsigned fields[OCEAN_MAX_CASCADES];
    memcpy(fields, want->cfields, sizeof fields);
    fields[0] |= probe_fields;
    if (ocean_step_cascades(s->ocean, s->sim_time, fields, OCEAN_MAX_CASCADES) == 0)
        return true;
    LOGE("ocean_step failed at t=%g", s->sim_time);
    return false;
}

static struct frame *encode(struct sim *s, const struct frame_want *want)
{
    double t0 = mono_now();
    struct oc_frame_header h = {
        .seq = s->seq, .sim_time = s->sim_time, .params_version = s->version,
        .patch_size = (float)s->params.patch_size,
    };
    struct frame *f = frame_encode(s->ocean, s->enc, s->cfg.tile_size, want, &h);
    if (f)
        f->index = s->published++;
    histogram_observe(&g_metrics.encode_seconds, mono_now() - t0);
    return f;
}

/* The newest frame replaces the previous one; NULL (no frame this tick)
 * too, so that nobody is ever handed a frame from an earlier tick. */
static void publish(struct sim *s, struct frame *f)
{
    pthread_mutex_lock(&s->lock);
    struct frame *old = s->latest;
    s->latest = f;
    pthread_mutex_unlock(&s->lock);
    frame_unref(old);
}

static void tick(struct sim *s)
{
    apply_pending(s);
    s->seq++;
    atomic_store(&s->now_seq, s->seq);
    atomic_store(&s->now_time, s->sim_time);
    atomic_store(&g_metrics.sim_time, s->sim_time);
    atomic_store(&g_metrics.params_version, s->version);
    atomic_store(&g_metrics.resolution, ocean_resolution(s->ocean));

    struct frame_want want;
    demand_snapshot(s, &want);
    struct frame *f = NULL;
    unsigned probe_fields = query_probe_fields(s->cfg.queries); /* probes need height, dx, dz */
    if ((want.nkeys || probe_fields) && step(s, &want, probe_fields)) {
        query_tick(s->cfg.queries, s->ocean, s->seq, s->sim_time, s->version);
        if (want.nkeys)
            f = encode(s, &want);
    }
    publish(s, f);
    if (f && s->cfg.on_frame)
        s->cfg.on_frame(s->cfg.cluster_user, f); /* publish() keeps our reference alive until the next tick */
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
        tick(s);
        /* Always wake lws: answers (params) may be waiting even without a frame. */
        if (s->cfg.wake)
            s->cfg.wake(s->cfg.wake_user);
        atomic_fetch_add(&g_metrics.ticks, 1);
        histogram_observe(&g_metrics.tick_seconds, mono_now() - t0);

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

struct sim *sim_start(const struct ocean_params *p, const struct sim_config *cfg, char *err, size_t errlen)
{
    struct sim *s = calloc(1, sizeof *s);
    if (!s) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    s->cfg = *cfg;
    s->params = *p;
    s->version = cfg->start_version;
    s->sim_time = cfg->start_time;
    s->seq = cfg->start_seq;
    s->pending_tail = &s->pending;
    s->answers_tail = &s->answers;
    const char *hook = getenv("OCEAND_TEST_FAIL_BUILD_SEED");
    s->test_fail_seed = hook && *hook ? atoi(hook) : -1;
    if (s->test_fail_seed >= 0)
        LOGW("test hook: builds with seed %d will fail (OCEAND_TEST_FAIL_BUILD_SEED)", s->test_fail_seed);
    pthread_mutex_init(&s->lock, NULL);
    pthread_cond_init(&s->cond, NULL);
    s->build_base = *p;
    s->ocean = ocean_create(p, &cfg->opts, err, errlen);
    s->enc = oc_encoder_new();
    if (!s->ocean || !s->enc) {
        if (s->ocean && !s->enc)
            snprintf(err, errlen, "out of memory (encoder)");
        ocean_free(s->ocean);
        oc_encoder_free(s->enc);
        free(s);
        return NULL;
    }
    atomic_store(&s->now_time, s->sim_time);
    if (cfg->queries)
        query_version(cfg->queries, s->version, s->sim_time, true, query_snapshot(cfg->queries, s->ocean));
    atomic_store(&g_metrics.resolution, p->resolution);
    atomic_store(&g_metrics.params_version, s->version);
    /* The tick thread must never take SIGINT/SIGTERM: block them for it
     * (and for the builder thread), whatever the caller did. */
    sigset_t block, old;
    sigemptyset(&block);
    sigaddset(&block, SIGINT);
    sigaddset(&block, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &block, &old);
    int rc = pthread_create(&s->thread, NULL, sim_main, s);
    if (rc == 0) {
        s->builder_started = pthread_create(&s->builder, NULL, builder_main, s) == 0;
        if (!s->builder_started)
            LOGW("no builder thread: parameter changes will not be applied");
    }
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (rc != 0) {
        snprintf(err, errlen, "cannot start the simulation thread: %s", strerror(rc));
        ocean_free(s->ocean);
        oc_encoder_free(s->enc);
        free(s);
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
    if (s->to_free)
        ocean_prepared_free(s->to_free);
    frame_unref(s->latest);
    ocean_free(s->ocean);
    oc_encoder_free(s->enc);
    pthread_cond_destroy(&s->cond);
    pthread_mutex_destroy(&s->lock);
    free(s);
}

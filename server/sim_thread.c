/* sim_thread.c — fixed-rate tick, parameter application, re-plan, encode, publish. */
#include "sim_thread.h"

#include "clock.h"

#include <errno.h>
#include <math.h>
#include <signal.h>
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
    struct ocean *ocean;          /* new simulation, or NULL when only playback changed */
    struct ocean_params params;   /* in force after the batch */
    struct sim_set *sets;         /* in order; each has ->prev, or ->failed with ->err */
};

struct sim {
    pthread_t thread;
    atomic_bool stop;
    struct sim_config cfg;

    /* Owned by the sim thread. */
    struct ocean *ocean;
    struct ocean_params params;   /* in force */
    uint32_t version;
    double sim_time;
    uint64_t seq;
    struct oc_encoder *enc;

    /* The builder thread applies parameter sets off the tick path: it builds
     * a new ocean (ocean_create: spectrum, and FFTW plans for a new N cost
     * 20-80 ms at N = 256-512, several ticks) and leaves it in `ready`; the
     * next tick swaps it in. The builder owns build_base. */
    pthread_t builder;
    bool builder_started;
    struct ocean_params build_base;  /* params of the newest state built */

    /* Shared with the network thread, under lock. */
    pthread_mutex_t lock;
    struct frame *latest;
    pthread_cond_t cond;              /* wakes the builder */
    bool builder_busy;                /* inside ocean_create */
    struct sim_set *pending, **pending_tail;
    struct built *ready;              /* built, waiting for a tick boundary */
    struct ocean *to_free;            /* swapped out, for the builder to free */
    struct sim_event *events, **events_tail;
    atomic_int demand[SIM_DEMAND_KEYS];
    _Atomic double now_time;
};

/* ---- frames ---- */

void frame_ref(struct frame *f) { atomic_fetch_add(&f->refs, 1); }

void frame_unref(struct frame *f)
{
    if (!f || atomic_fetch_sub(&f->refs, 1) != 1)
        return;
    for (int i = 0; i < f->nlayers; i++) {
        oc_buf_free(&f->layers[i].buf);
        free(f->layers[i].tile_off);
    }
    free(f->layers);
    free(f);
}

const struct layer *frame_layer(const struct frame *f, int field, int lod, int bound_index)
{
    for (int i = 0; i < f->nlayers; i++) {
        const struct layer *l = &f->layers[i];
        if (l->field == field && l->lod == lod && l->bound_index == bound_index)
            return l;
    }
    return NULL;
}

void sim_event_free(struct sim_event *e)
{
    if (e) {
        cJSON_Delete(e->id);
        free(e);
    }
}

static void set_free(struct sim_set *s)
{
    if (s) {
        cJSON_Delete(s->id);
        free(s);
    }
}

/* ---- network-side API ---- */

void sim_submit(struct sim *s, struct sim_set *set)
{
    set->next = NULL;
    pthread_mutex_lock(&s->lock);
    *s->pending_tail = set;
    s->pending_tail = &set->next;
    pthread_cond_signal(&s->cond);
    pthread_mutex_unlock(&s->lock);
}

struct sim_event *sim_take_events(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    struct sim_event *e = s->events;
    s->events = NULL;
    s->events_tail = &s->events;
    pthread_mutex_unlock(&s->lock);
    return e;
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

void sim_demand(struct sim *s, int key, int delta) { atomic_fetch_add(&s->demand[key], delta); }
double sim_time_now(struct sim *s) { return atomic_load(&s->now_time); }

/* ---- sim-thread internals ---- */

static void emit(struct sim *s, struct sim_event *e)
{
    e->next = NULL;
    pthread_mutex_lock(&s->lock);
    *s->events_tail = e;
    s->events_tail = &e->next;
    pthread_mutex_unlock(&s->lock);
}

/* Event for a set: applied (changed vs before) or failed with err. Takes the set's id. */
static void emit_for_set(struct sim *s, struct sim_set *set, const struct ocean_params *before,
                         const struct ctl_error *err)
{
    struct sim_event *e = calloc(1, sizeof *e);
    if (!e)
        return;
    e->failed = err != NULL;
    if (err)
        e->err = *err;
    e->params = s->params;
    e->version = s->version;
    for (size_t i = 0; i < param_count && i < 64; i++)
        if (param_get(&s->params, &param_table[i]) != param_get(before, &param_table[i]))
            e->changed |= 1ull << i;
    e->origin = set->origin;
    memcpy(e->by, set->by, sizeof e->by);
    e->id = set->id;
    set->id = NULL;
    emit(s, e);
}

/* The set's values for the params it names, on top of base. */
static struct ocean_params merged(const struct ocean_params *base, const struct sim_set *set)
{
    struct ocean_params p = *base;
    char err[64];
    for (size_t i = 0; i < param_count && i < 64; i++)
        if (set->mask & (1ull << i))
            param_set(&p, &param_table[i], param_get(&set->values, &param_table[i]), err, sizeof err);
    return p;
}

static bool physics_differ(const struct ocean_params *a, const struct ocean_params *b)
{
    for (size_t i = 0; i < param_count; i++)
        if (!(param_table[i].flags & PARAM_PLAYBACK) && param_get(a, &param_table[i]) != param_get(b, &param_table[i]))
            return true;
    return false;
}

static void internal_error(struct ctl_error *e, const char *code, const char *msg)
{
    memset(e, 0, sizeof *e);
    e->code = code;
    snprintf(e->message, sizeof e->message, "%s", msg);
}

/* Builder thread: take the queued sets, check each on top of the previous
 * one (all or nothing per set), build one new ocean for the whole batch if
 * any physics changed, and hand it to the tick thread. */
static void *builder_main(void *arg)
{
    struct sim *s = arg;
    pthread_mutex_lock(&s->lock);
    while (!atomic_load(&s->stop)) {
        if (s->to_free) {
            struct ocean *old = s->to_free;
            s->to_free = NULL;
            pthread_mutex_unlock(&s->lock);
            ocean_free(old);
            pthread_mutex_lock(&s->lock);
            continue;
        }
        if (!s->pending || s->ready) {
            pthread_cond_wait(&s->cond, &s->lock);
            continue;
        }
        struct sim_set *sets = s->pending;
        s->pending = NULL;
        s->pending_tail = &s->pending;
        s->builder_busy = true;
        pthread_mutex_unlock(&s->lock);

        struct built *b = calloc(1, sizeof *b);
        struct ocean_params cur = s->build_base;
        for (struct sim_set *set = sets; set; set = set->next) {
            struct ocean_params next = merged(&cur, set);
            char err[200];
            if (params_validate(&next, err, sizeof err) != 0) {
                set->failed = true;
                internal_error(&set->err, "invalid", err);
                continue;
            }
            set->prev = cur;
            cur = next;
        }
        if (b && physics_differ(&s->build_base, &cur)) {
            char err[200];
            b->ocean = ocean_create(&cur, &s->cfg.opts, err, sizeof err);
            if (!b->ocean) {
                LOGW("applying parameters failed: %s", err);
                for (struct sim_set *set = sets; set; set = set->next)
                    if (!set->failed) {
                        set->failed = true;
                        internal_error(&set->err, "invalid", err);
                    }
                cur = s->build_base;
            }
        }
        s->build_base = cur;
        pthread_mutex_lock(&s->lock);
        s->builder_busy = false;
        if (b) {
            b->params = cur;
            b->sets = sets;
            s->ready = b;
        } else {
            while (sets) { /* out of memory: drop the batch */
                struct sim_set *n = sets->next;
                set_free(sets);
                sets = n;
            }
        }
    }
    pthread_mutex_unlock(&s->lock);
    return NULL;
}

/* At a tick boundary: swap in what the builder prepared, one version per set. */
static void apply_pending(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    struct built *b = s->ready;
    s->ready = NULL;
    if (b)
        pthread_cond_signal(&s->cond);
    pthread_mutex_unlock(&s->lock);
    if (!b)
        return;
    if (b->ocean) {
        struct ocean *old = s->ocean;
        s->ocean = b->ocean;
        if (ocean_resolution(old) != ocean_resolution(s->ocean)) {
            atomic_fetch_add(&g_metrics.replans, 1);
            LOGI("resolution now %d", ocean_resolution(s->ocean));
        }
        pthread_mutex_lock(&s->lock);
        bool slot_free = s->to_free == NULL;
        if (slot_free) {
            s->to_free = old; /* freeing 10-100 MB is the builder's job, not the tick's */
            pthread_cond_signal(&s->cond);
        }
        pthread_mutex_unlock(&s->lock);
        if (!slot_free)
            ocean_free(old);
    }
    struct sim_set *set = b->sets;
    while (set) {
        struct sim_set *next = set->next;
        if (set->failed) {
            emit_for_set(s, set, &s->params, &set->err);
        } else {
            s->params = merged(&set->prev, set);
            s->version++;
            atomic_fetch_add(&g_metrics.param_changes, 1);
            emit_for_set(s, set, &set->prev, NULL);
        }
        set_free(set);
        set = next;
    }
    s->params = b->params;
    free(b);
}

/* Step and encode what is subscribed; NULL if nobody wants anything. */
static struct frame *make_frame(struct sim *s)
{
    int n = ocean_resolution(s->ocean);
    int ts = s->cfg.tile_size < n ? s->cfg.tile_size : n;
    int tps = n / ts;
    unsigned fields = 0;
    int nlayers = 0;
    for (int k = 0; k < SIM_DEMAND_KEYS; k++)
        if (atomic_load(&s->demand[k]) > 0) {
            fields |= OCEAN_FIELD_BIT(k / ((CTL_MAX_LOD + 1) * CTL_BOUND_COUNT));
            nlayers++;
        }
    if (!fields)
        return NULL;
    if (ocean_step(s->ocean, s->sim_time, fields) != 0) {
        LOGE("ocean_step failed at t=%g", s->sim_time);
        return NULL;
    }
    double t0 = mono_now();
    struct frame *f = calloc(1, sizeof *f);
    if (!f)
        return NULL;
    atomic_init(&f->refs, 1);
    f->layers = calloc((size_t)nlayers, sizeof *f->layers);
    f->tiles_per_side = tps;
    if (!f->layers) {
        free(f);
        return NULL;
    }
    for (int k = 0; k < SIM_DEMAND_KEYS; k++) {
        if (atomic_load(&s->demand[k]) <= 0 || f->nlayers == nlayers)
            continue;
        int field = k / ((CTL_MAX_LOD + 1) * CTL_BOUND_COUNT);
        int lod = (k / CTL_BOUND_COUNT) % (CTL_MAX_LOD + 1);
        int bi = k % CTL_BOUND_COUNT;
        if ((ts >> lod) < 1)
            continue;
        const float *data = ocean_field(s->ocean, (enum ocean_field)field);
        if (!(fields & OCEAN_FIELD_BIT(field)) || !data)
            continue;
        struct layer *l = &f->layers[f->nlayers];
        l->field = (uint8_t)field;
        l->lod = (uint8_t)lod;
        l->bound_index = (uint8_t)bi;
        l->tile_off = malloc(sizeof(uint32_t) * ((size_t)tps * tps + 1));
        int rc = l->tile_off ? 0 : OC_E_NOMEM;
        for (int tz = 0; rc == 0 && tz < tps; tz++)
            for (int tx = 0; rc == 0 && tx < tps; tx++) {
                l->tile_off[tz * tps + tx] = (uint32_t)l->buf.len;
                rc = oc_encode_tile(s->enc, data, n, ts, tx, tz, lod, (enum oc_field)field, ctl_bounds[bi], &l->buf);
            }
        if (rc != 0) {
            LOGE("encoding %s lod %d: %s", ocean_field_name((enum ocean_field)field), lod, oc_strerror(rc));
            oc_buf_free(&l->buf);
            free(l->tile_off);
            memset(l, 0, sizeof *l);
            continue;
        }
        l->tile_off[tps * tps] = (uint32_t)l->buf.len;
        f->nlayers++;
    }
    histogram_observe(&g_metrics.encode_seconds, mono_now() - t0);
    f->hdr.seq = ++s->seq;
    f->hdr.sim_time = s->sim_time;
    f->hdr.params_version = s->version;
    f->hdr.n = (uint16_t)n;
    f->hdr.tile_size = (uint16_t)ts;
    f->hdr.patch_size = (float)s->params.patch_size;
    f->hdr.server_time_us = unix_us();
    return f;
}

static void publish(struct sim *s, struct frame *f)
{
    pthread_mutex_lock(&s->lock);
    struct frame *old = s->latest;
    s->latest = f;
    pthread_mutex_unlock(&s->lock);
    frame_unref(old);
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
        /* The clock runs under the parameters that were in force during the interval. */
        if (!s->params.paused)
            s->sim_time += s->params.time_scale * elapsed;
        apply_pending(s);
        atomic_store(&s->now_time, s->sim_time);
        atomic_store(&g_metrics.sim_time, s->sim_time);
        atomic_store(&g_metrics.params_version, s->version);
        atomic_store(&g_metrics.resolution, ocean_resolution(s->ocean));
        struct frame *f = make_frame(s);
        if (f)
            publish(s, f);
        /* Always wake lws: events (params) may be waiting even without a frame. */
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
    s->pending_tail = &s->pending;
    s->events_tail = &s->events;
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
    struct sim_set *lists[2] = { s->pending, s->ready ? s->ready->sets : NULL };
    for (int i = 0; i < 2; i++)
        while (lists[i]) {
            struct sim_set *n = lists[i]->next;
            set_free(lists[i]);
            lists[i] = n;
        }
    if (s->ready) {
        if (s->ready->ocean)
            ocean_free(s->ready->ocean);
        free(s->ready);
    }
    if (s->to_free)
        ocean_free(s->to_free);
    struct sim_event *e = s->events;
    while (e) {
        struct sim_event *n = e->next;
        sim_event_free(e);
        e = n;
    }
    frame_unref(s->latest);
    ocean_free(s->ocean);
    oc_encoder_free(s->enc);
    pthread_cond_destroy(&s->cond);
    pthread_mutex_destroy(&s->lock);
    free(s);
}

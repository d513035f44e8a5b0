/* tick.c — the tick thread: a clock on absolute deadlines, and tick(), which
 * at each boundary applies what the builder prepared, takes a snapshot of
 * the demand, updates the plan, decides what is wanted and queues it for
 * the producer. It never steps or encodes, so it keeps its schedule
 * whatever a frame costs. */
#include "tick_internal.h"

#include <errno.h>
#include <math.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "log.h"
#include "metrics.h"

/* Apply what the builder prepared while the producer is not using the
 * ocean, and let the transient cost penalty fade: the producer kept up. */
static void apply_if_idle(struct sim *s, bool idle)
{
    if (!idle)
        return;
    apply_prepared(s);
    if (s->model.penalty > 1) { /* see penalize_overrun */
        pthread_mutex_lock(&s->lock);
        s->model.penalty = s->model.penalty * 0.95 > 1 ? s->model.penalty * 0.95 : 1;
        pthread_mutex_unlock(&s->lock);
    }
}

/* The clock, tick number and N for the other threads and /metrics. */
static void advance_clock(struct sim *s, int n)
{
    s->seq++;
    atomic_store(&s->now_seq, s->seq);
    atomic_store(&s->now_time, s->sim_time);
    atomic_store(&s->now_n, n);
    atomic_store(&g_metrics.sim_time, s->sim_time);
    atomic_store(&g_metrics.params_version, s->version);
    atomic_store(&g_metrics.resolution, n);
}

/* The demand at this moment: the lws thread's counters, and for --role sim
 * the keys other daemons want (an edge's key counts as one subscriber). */
static void gather_demand(struct sim *s, struct demand_snapshot *d)
{
    uint8_t stream[SIM_DEMAND_BYTES] = { 0 }, wish[SIM_DEMAND_BYTES] = { 0 };
    memset(d->remote, 0, sizeof d->remote);
    if (s->cfg.remote_demand)
        s->cfg.remote_demand(s->cfg.cluster_user, d->remote, stream, wish);
    d->any = false;
    for (int k = 0; k < LAYER_KEYS_ALL; k++) {
        d->demand[k] = atomic_load(&s->demand[k]);
        d->tdemand[k] = atomic_load(&s->tdemand[k]);
        d->key_want[k] = atomic_load(&s->key_want[k]);
        uint8_t bit = (uint8_t)(1u << (k & 7));
        bool remote = d->remote[k >> 3] & bit;
        if (d->demand[k] <= 0 && remote)
            d->demand[k] = 1;
        if (remote && (stream[k >> 3] & bit)) {
            /* Edges stream it (docs/scaling.md): one temporal subscriber, that
             * takes this tick's keyframe tiles only while some edge wishes for
             * them; d->remote keeps the keys edges take intra every tick. */
            if (d->tdemand[k] < d->demand[k])
                d->tdemand[k]++;
            if (wish[k >> 3] & bit)
                d->key_want[k]++;
            d->remote[k >> 3] = (uint8_t)(d->remote[k >> 3] & ~bit);
        }
        d->any |= d->demand[k] > 0;
    }
}

/* Each planned group earns its rate in credit every tick; it is due when it
 * has a whole frame's worth. */
static void groups_due(struct sim *s, bool due[PLAN_GROUPS])
{
    for (int g = 0; g < PLAN_GROUPS; g++) {
        due[g] = false;
        if (!s->plan.fields[g])
            continue;
        s->credit[g] += s->plan.rate[g];
        if (s->credit[g] > 2)
            s->credit[g] = 2; /* a group held back by a busy producer does not pile up */
        due[g] = s->credit[g] >= 1;
    }
}

/* The producer has not even started the frame before: this one cannot
 * start on time. Counted as an overrun, and taken as proof that the
 * model is optimistic (a shared machine, a slower N): costs up by a
 * quarter at once (the penalty, at most x64), so the next plan
 * degrades; each tick that finds the producer idle takes 5 % of it
 * back (x64 -> x1 in ~2.7 s), whether or not frames are rare. */
static void penalize_overrun(struct sim *s)
{
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
}

/* Hand the job to the producer (one deep: it takes it when it is done
 * with the frame before), spending the due groups' credit. */
static void queue_job(struct sim *s, struct prod_job *pj, const bool due[PLAN_GROUPS], int n)
{
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (due[g])
            s->credit[g] -= 1;
    plan_samples(&s->plan, n, due, pj->codec_samples);
    pj->cold = s->seq < s->grace_seq;
    pj->want.reset_streams = s->reset_streams;
    pj->want.sea_changed = s->sea_changed && !s->reset_streams;
    s->reset_streams = false;
    s->sea_changed = false;
    pthread_mutex_lock(&s->lock);
    s->pj = *pj;
    s->prod_has_job = true;
    pthread_cond_signal(&s->prod_cond);
    pthread_mutex_unlock(&s->lock);
}

/* Nobody is subscribed: the producer frees the temporal streams (tens of
 * MB with many layers), which would otherwise wait for the next frame. */
static void queue_release(struct sim *s)
{
    s->release_due = false;
    pthread_mutex_lock(&s->lock);
    s->pj = (struct prod_job){ .seq = s->seq, .release_streams = true };
    s->prod_has_job = true;
    pthread_cond_signal(&s->prod_cond);
    pthread_mutex_unlock(&s->lock);
}

static void tick(struct sim *s, double t_tick)
{
    pthread_mutex_lock(&s->lock);
    bool idle = !s->prod_busy && !s->prod_has_job, queued = s->prod_has_job, set_ready = s->ready_full;
    bool bodies = body_wanted_locked(s); /* bodies float on the sea with or without viewers */
    pthread_mutex_unlock(&s->lock);
    apply_if_idle(s, idle);
    int n = ocean_resolution(s->ocean);
    advance_clock(s, n);

    struct demand_snapshot d;
    gather_demand(s, &d);
    unsigned probe_fields = query_probe_fields(s->cfg.queries); /* probes need height, dx, dz */
    if (!d.any) {
        if (s->had_demand) {
            publish(s, NULL); /* nobody is ever handed a frame from before an idle period */
            s->release_due = true;
        }
        s->had_demand = false;
        if (s->release_due && idle) {
            queue_release(s);
            return;
        }
        if (!probe_fields && !bodies)
            return;
    } else {
        s->had_demand = true;
        plan_update(s, d.demand, d.tdemand, n, frame_tile_size(s->cfg.tile_size, n));
    }

    struct prod_job pj = { .sim_time = s->sim_time, .t_tick = t_tick, .seq = s->seq, .version = s->version,
                           .patch_size = (float)s->params.patch_size };
    bool due[PLAN_GROUPS];
    groups_due(s, due);
    frame_want_build(&s->plan, due, &d, probe_fields, &pj.want);
    if (bodies)
        body_want(&pj.want);
    if (!pj.want.nkeys && !probe_fields && !bodies)
        return; /* a degraded group's off tick */
    if (!idle && set_ready)
        return; /* let the producer drain so that the parameter change applies next tick */
    if (queued) {
        penalize_overrun(s);
        return;
    }
    queue_job(s, &pj, due, n);
}

void *tick_main(void *arg)
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
        if (!s->params.paused && s->sim_time < OCEAN_TIME_MAX) {
            s->sim_time = ocean_time_clamp(s->sim_time + s->params.time_scale * elapsed);
            if (s->sim_time == OCEAN_TIME_MAX) /* once: the loader takes this time back (ocean.h) */
                LOGW("the simulation clock reached its limit of %.0f s and stops there (the sea stands still)",
                     OCEAN_TIME_MAX);
        }
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

/* query_worker.c — exact point queries and per-tick probes on worker
 * threads (query_worker.h): an instance of the program's one work pool
 * (server/common/pool.h). Each piece of work queued (a query, a tick's
 * grids, a probe set change) starts a drain on the pool unless `threads`
 * drains run already; a drain runs what it finds (probes first) until
 * nothing is left. Who touches what:
 *   lock-guarded: epochs (snapshots per params_version), the job queue,
 *     the probe grid buffers (spare / pending), probe commands, results,
 *     the drains (which run, how many);
 *   the worker doing a probe tick (one at a time: probe_busy): the probe
 *     clients and their history;
 *   lws thread only: the budget bucket and the per-client probe counts;
 *   atomics: probe_fields (lws writes, tick reads), the counters. */
#include "query_worker.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "log.h"
#include "metrics.h"
#include "pool.h"
#include "probe.h"

#define MAX_EPOCHS 32             /* versions kept at most (a burst of sets inside the window) */
#define QUERY_UNIT_MODES 32639    /* modes of one cascade at N = 256: the budget's unit point */
#define MAX_SNAPSHOTS 3           /* distinct snapshots kept (7 MB each at N = 512): under a stream of
                                   * physics changes the window shrinks to the last three of them */

/* A snapshot, shared by the epochs (versions) it serves and the jobs using it. */
struct snap {
    atomic_int refs;
    struct ocean_surface *surf;   /* NULL: could not be made (no memory) */
    double cost;                  /* budget units per point: its modes (all cascades) over those of
                                   * one cascade at N = 256, ~(N/256)^2 x 1.4 at 3 cascades */
};

struct epoch {
    uint32_t version;
    double since;                 /* sim time from which it is in force */
    struct snap *snap;            /* one reference */
};

struct job {
    struct job *next;
    uint64_t serial;
    cJSON *id;                    /* owned copy */
    double t;
    uint32_t version;
    struct snap *snap;            /* one reference */
    int n;
    double xz[][2];
};

/* One tick's copy of the grids the probes read: height, dx, dz of every
 * cascade (one block: h of cascade c at h + 3 c N^2, then its dx, dz). */
struct grids {
    int n, ncasc;
    double patch[OCEAN_MAX_CASCADES];
    uint64_t seq;
    double t;
    uint32_t version;
    size_t cap;                   /* floats allocated in h */
    float *h;
};

struct probe_client {
    struct probe_client *next;
    uint64_t serial;
    int n, nhist;                 /* points; ticks of history (0..3) */
    double hist_t[3];             /* sim times of the history, newest first */
    struct probe_point {
        double xz[2], guess[2], hist_h[3];
    } pt[];
};

/* A change of a client's probe set, applied by the next probe tick. */
struct probe_cmd {
    struct probe_cmd *next;
    uint64_t serial;
    struct probe_client *pc;      /* NULL = remove */
};

struct probe_count {
    uint64_t serial;
    int n;
};

/* One drain's pool job (pool.h: reused only once the pool has finished it). */
struct drain {
    struct query_service *q;
    struct pool_job job;
    bool running;                 /* under the service's lock: started, and has not found nothing yet */
};

struct query_service {
    struct query_config cfg;
    struct pool *pool;            /* cfg.threads threads */
    struct drain *drains;         /* one per thread */
    int nthreads;

    pthread_mutex_t lock;
    int draining;                 /* drains running (<= nthreads) */
    bool stop;
    struct epoch epochs[MAX_EPOCHS];
    int nepochs;
    struct job *jobs, **jobs_tail;
    int njobs;
    struct grids *spare, *pending;
    bool probe_busy;
    struct probe_cmd *cmds, **cmds_tail;
    struct query_out *out, **out_tail;

    struct probe_client *clients; /* the probe-tick worker only */

    double tokens, tokens_t;      /* lws only: the global point budget */
    struct probe_count *counts;   /* lws only: points per probing client */
    int ncounts, capcounts, probe_total;

    atomic_uint probe_fields;     /* lws writes, tick reads */
};

/* ---- snapshots ---- */

static struct snap *snap_new(struct ocean_surface *surf)
{
    struct snap *s = calloc(1, sizeof *s);
    if (!s) {
        ocean_surface_free(surf);
        return NULL;
    }
    atomic_init(&s->refs, 1);
    s->surf = surf;
    /* A point costs in proportion to the modes summed (bench-query). */
    s->cost = surf ? ocean_surface_modes(surf) / (double)QUERY_UNIT_MODES : 1.0;
    if (!(s->cost > 0))
        s->cost = 1.0 / QUERY_UNIT_MODES; /* a calm sea: no modes, still a point */
    return s;
}

static void snap_unref(struct snap *s)
{
    if (s && atomic_fetch_sub(&s->refs, 1) == 1) {
        ocean_surface_free(s->surf);
        free(s);
    }
}

struct ocean_surface *query_snapshot(struct query_service *q, const struct ocean *o)
{
    if (!q || !o)
        return NULL;
    char err[128];
    struct ocean_surface *s = ocean_surface_new(o, err, sizeof err);
    if (!s)
        LOGW("point queries: %s", err);
    return s;
}

struct ocean_surface *query_snapshot_prepared(struct query_service *q, const struct ocean *o,
                                              const struct ocean_prepared *pr)
{
    if (!q || !o || !pr)
        return NULL;
    char err[128];
    struct ocean_surface *s = ocean_prepared_surface(o, pr, err, sizeof err);
    if (!s)
        LOGW("point queries: %s", err);
    return s;
}

void query_version(struct query_service *q, uint32_t version, double since, bool new_physics,
                   struct ocean_surface *surface)
{
    if (!q) {
        ocean_surface_free(surface);
        return;
    }
    struct snap *fresh = new_physics ? snap_new(surface) : NULL;
    pthread_mutex_lock(&q->lock);
    struct snap *snap = fresh;
    if (!new_physics && q->nepochs > 0) {
        snap = q->epochs[q->nepochs - 1].snap;
        if (snap)
            atomic_fetch_add(&snap->refs, 1);
    }
    struct snap *drop[MAX_EPOCHS + 1];
    int ndrop = 0;
    /* A change of N: the earlier snapshots (up to 8 MB each at N = 512) are
     * given back at once rather than kept for the window (RSS after N is
     * flapped, test-hostile resolution_flapping); times before the change
     * are then out of the window (PROTOCOL.md §7.4). */
    if (fresh && fresh->surf && q->nepochs > 0) {
        const struct snap *prev = q->epochs[q->nepochs - 1].snap;
        if (prev && prev->surf &&
            ocean_surface_params(prev->surf)->resolution != ocean_surface_params(fresh->surf)->resolution) {
            for (int i = 0; i < q->nepochs; i++)
                drop[ndrop++] = q->epochs[i].snap;
            q->nepochs = 0;
        }
    }
    /* Keep what the window can still ask for: an epoch is needed while the
     * next one starts after since - window. */
    while (q->nepochs > 0 && (q->nepochs == MAX_EPOCHS ||
                              (q->nepochs >= 2 && q->epochs[1].since < since - q->cfg.window - 1.0))) {
        drop[ndrop++] = q->epochs[0].snap;
        memmove(&q->epochs[0], &q->epochs[1], (size_t)(q->nepochs - 1) * sizeof q->epochs[0]);
        q->nepochs--;
    }
    q->epochs[q->nepochs++] = (struct epoch){ .version = version, .since = since, .snap = snap };
    /* At most MAX_SNAPSHOTS distinct snapshots: drop the epochs before the oldest kept one. */
    int distinct = 0, keep_from = 0;
    for (int i = q->nepochs - 1; i >= 0; i--) {
        if (i == q->nepochs - 1 || q->epochs[i].snap != q->epochs[i + 1].snap)
            distinct++;
        if (distinct > MAX_SNAPSHOTS) {
            keep_from = i + 1;
            break;
        }
    }
    for (int i = 0; i < keep_from; i++)
        drop[ndrop++] = q->epochs[i].snap;
    if (keep_from) {
        memmove(&q->epochs[0], &q->epochs[keep_from], (size_t)(q->nepochs - keep_from) * sizeof q->epochs[0]);
        q->nepochs -= keep_from;
    }
    pthread_mutex_unlock(&q->lock);
    for (int i = 0; i < ndrop; i++)
        snap_unref(drop[i]);
}

/* ---- results ---- */

static void post(struct query_service *q, struct query_out *first, struct query_out *last)
{
    if (!first)
        return;
    pthread_mutex_lock(&q->lock);
    *q->out_tail = first;
    q->out_tail = &last->next;
    pthread_mutex_unlock(&q->lock);
    if (q->cfg.wake)
        q->cfg.wake(q->cfg.wake_user);
}

static struct query_out *out_new(uint64_t serial, bool probe, char *text)
{
    if (!text)
        return NULL;
    struct query_out *o = calloc(1, sizeof *o);
    if (!o) {
        free(text);
        return NULL;
    }
    o->serial = serial;
    o->probe = probe;
    o->text = text;
    return o;
}

void query_out_free(struct query_out *o)
{
    if (o) {
        free(o->text);
        free(o);
    }
}

struct query_out *query_take_results(struct query_service *q)
{
    if (!q)
        return NULL;
    pthread_mutex_lock(&q->lock);
    struct query_out *o = q->out;
    q->out = NULL;
    q->out_tail = &q->out;
    pthread_mutex_unlock(&q->lock);
    return o;
}

/* ---- exact queries (worker) ---- */

static void run_job(struct query_service *q, struct job *j)
{
    double t0 = mono_now();
    char *text = NULL;
    struct ocean_point *pts = calloc((size_t)j->n, sizeof *pts);
    if (pts && ocean_surface_query(j->snap->surf, j->t, (const double(*)[2])j->xz, j->n, pts) == 0) {
        text = control_print(query_result_msg(j->id, j->t, j->version, j->n, pts));
    } else {
        struct ctl_error e = { .code = "internal", .message = "the query could not be evaluated (out of memory)" };
        text = control_print(control_error_msg(&e, j->id));
    }
    free(pts);
    histogram_observe(&g_metrics.query_seconds, mono_now() - t0);
    struct query_out *o = out_new(j->serial, false, text);
    post(q, o, o);
}

static void job_free(struct job *j)
{
    if (j) {
        cJSON_Delete(j->id);
        snap_unref(j->snap);
        free(j);
    }
}

/* ---- probes (worker) ---- */

static void apply_cmds(struct query_service *q, struct probe_cmd *c)
{
    while (c) {
        struct probe_cmd *next = c->next;
        for (struct probe_client **pp = &q->clients; *pp; pp = &(*pp)->next)
            if ((*pp)->serial == c->serial) {
                struct probe_client *gone = *pp;
                *pp = gone->next;
                free(gone);
                break;
            }
        if (c->pc) {
            c->pc->next = q->clients;
            q->clients = c->pc;
        }
        free(c);
        c = next;
    }
}

static void run_probes(struct query_service *q, struct grids *g)
{
    double t0 = mono_now();
    struct probe_grids pg = { .n = g->n, .ncasc = g->ncasc };
    const size_t samples = (size_t)g->n * g->n;
    for (int c = 0; c < g->ncasc; c++) {
        pg.patch[c] = g->patch[c];
        pg.h[c] = g->h + 3 * c * samples;
        pg.dx[c] = pg.h[c] + samples;
        pg.dz[c] = pg.dx[c] + samples;
    }
    struct query_out *first = NULL, **tail = &first, *last = NULL;
    struct probe_value v[PROBE_MAX_POINTS];
    for (struct probe_client *c = q->clients; c; c = c->next) {
        /* History shifts by one tick (same sim time: paused, keep it). */
        bool advance = c->nhist == 0 || g->t != c->hist_t[0];
        if (advance) {
            c->hist_t[2] = c->hist_t[1];
            c->hist_t[1] = c->hist_t[0];
            c->hist_t[0] = g->t;
            if (c->nhist < 3)
                c->nhist++;
        }
        for (int i = 0; i < c->n; i++) {
            struct probe_point *p = &c->pt[i];
            probe_eval(&pg, p->xz[0], p->xz[1], p->guess, &v[i]);
            if (advance) {
                p->hist_h[2] = p->hist_h[1];
                p->hist_h[1] = p->hist_h[0];
            }
            p->hist_h[0] = v[i].height;
            double ht[3] = { c->hist_t[0], c->nhist > 1 ? c->hist_t[1] : c->hist_t[0],
                             c->nhist > 2 ? c->hist_t[2] : c->hist_t[0] };
            probe_derivatives(p->hist_h, ht, &v[i].vertical_velocity, &v[i].vertical_acceleration);
        }
        struct query_out *o = out_new(c->serial, true, probe_data_text(g->seq, g->t, g->version, c->n, v));
        if (o) {
            *tail = o;
            tail = &o->next;
            last = o;
        }
    }
    atomic_fetch_add(&g_metrics.probe_ticks, 1);
    histogram_observe(&g_metrics.probe_seconds, mono_now() - t0);
    post(q, first, last);
}

/* A pool job: run what is queued until nothing is (or the service stops). */
static void drain_run(void *arg, int i0, int i1, int worker)
{
    struct drain *d = arg;
    struct query_service *q = d->q;
    pthread_mutex_lock(&q->lock);
    while (!q->stop) {
        if (q->pending && !q->probe_busy) { /* probes first: they are due every tick */
            struct grids *g = q->pending;
            q->pending = NULL;
            q->probe_busy = true;
            struct probe_cmd *cmds = q->cmds;
            q->cmds = NULL;
            q->cmds_tail = &q->cmds;
            pthread_mutex_unlock(&q->lock);
            apply_cmds(q, cmds);
            run_probes(q, g);
            pthread_mutex_lock(&q->lock);
            q->probe_busy = false;
            if (!q->spare) {
                q->spare = g;
                g = NULL;
            }
            pthread_mutex_unlock(&q->lock);
            if (g) {
                free(g->h);
                free(g);
            }
            pthread_mutex_lock(&q->lock);
            continue;
        }
        if (q->cmds && !q->probe_busy) { /* probe set changes while no tick probes: apply them now, so
                                          * a client toggling its probes cannot grow the list */
            struct probe_cmd *cmds = q->cmds;
            q->cmds = NULL;
            q->cmds_tail = &q->cmds;
            q->probe_busy = true;
            pthread_mutex_unlock(&q->lock);
            apply_cmds(q, cmds);
            pthread_mutex_lock(&q->lock);
            q->probe_busy = false;
            continue;
        }
        if (q->jobs) {
            struct job *j = q->jobs;
            q->jobs = j->next;
            if (!q->jobs)
                q->jobs_tail = &q->jobs;
            q->njobs--;
            pthread_mutex_unlock(&q->lock);
            run_job(q, j);
            job_free(j);
            pthread_mutex_lock(&q->lock);
            continue;
        }
        break;
    }
    d->running = false; /* in the same critical section as finding nothing: no work is left behind */
    q->draining--;
    pthread_mutex_unlock(&q->lock);
}

/* Work was just queued (lock held): the drain to start on the pool, or NULL
 * when `threads` drains run already (one of them takes it). */
static struct drain *kick_locked(struct query_service *q)
{
    if (q->stop || q->draining >= q->nthreads)
        return NULL;
    for (int i = 0; i < q->nthreads; i++)
        if (!q->drains[i].running) {
            q->drains[i].running = true;
            q->draining++;
            return &q->drains[i];
        }
    return NULL;
}

/* Without the service's lock: pool_start waits if the pool is still
 * finishing this drain's previous run (its function has returned). */
static void kick_start(struct query_service *q, struct drain *d)
{
    if (d)
        pool_start(q->pool, &d->job, 1, drain_run, NULL, d);
}

/* ---- tick thread: probe grids ---- */

unsigned query_probe_fields(const struct query_service *q)
{
    return q ? atomic_load(&q->probe_fields) : 0;
}

void query_tick(struct query_service *q, const struct ocean *o, const unsigned *stepped, uint64_t seq,
                double sim_time, uint32_t version)
{
    const unsigned need = OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX) | OCEAN_FIELD_BIT(OCEAN_DZ);
    if (!q || !stepped || !atomic_load(&q->probe_fields))
        return;
    /* Every cascade in force: the probes answer the whole sea. */
    const int nc = ocean_cascades(o);
    const float *f[OCEAN_MAX_CASCADES][3];
    for (int c = 0; c < nc; c++) {
        if ((stepped[c] & need) != need)
            return; /* planned before the probes came: this tick's grids are not all fresh */
        f[c][0] = ocean_cascade_field(o, c, OCEAN_HEIGHT);
        f[c][1] = ocean_cascade_field(o, c, OCEAN_DX);
        f[c][2] = ocean_cascade_field(o, c, OCEAN_DZ);
        if (!f[c][0] || !f[c][1] || !f[c][2])
            return;
    }
    pthread_mutex_lock(&q->lock);
    struct grids *g = q->spare;
    q->spare = NULL;
    if (!g && q->pending) { /* the worker has not taken the last one: this tick replaces it */
        g = q->pending;
        q->pending = NULL;
        atomic_fetch_add(&g_metrics.probe_skipped, 1);
    }
    pthread_mutex_unlock(&q->lock);
    const int n = ocean_resolution(o);
    const size_t samples = (size_t)n * n, floats = 3 * (size_t)nc * samples;
    if (!g)
        g = calloc(1, sizeof *g);
    if (g && g->cap < floats) { /* first tick, or N or the cascades grew: one block for all fields */
        free(g->h);
        g->h = malloc(floats * sizeof(float));
        g->cap = g->h ? floats : 0;
    }
    if (!g || !g->h) {
        if (g)
            free(g);
        return;
    }
    for (int c = 0; c < nc; c++)
        for (int k = 0; k < 3; k++)
            memcpy(g->h + (3 * (size_t)c + k) * samples, f[c][k], samples * sizeof(float));
    g->n = n;
    g->ncasc = nc;
    for (int c = 0; c < nc; c++)
        g->patch[c] = ocean_cascade_patch(ocean_get_params(o)->patch_size, c);
    g->seq = seq;
    g->t = sim_time;
    g->version = version;
    pthread_mutex_lock(&q->lock);
    struct grids *old = q->pending;
    q->pending = g;
    if (old) {
        atomic_fetch_add(&g_metrics.probe_skipped, 1);
        if (!q->spare) {
            q->spare = old;
            old = NULL;
        }
    }
    struct drain *d = kick_locked(q);
    pthread_mutex_unlock(&q->lock);
    kick_start(q, d);
    if (old) {
        free(old->h);
        free(old);
    }
}

/* ---- lws thread ---- */

static int fail(struct ctl_error *e, const char *code, const char *msg)
{
    e->code = code;
    e->param[0] = '\0';
    snprintf(e->message, sizeof e->message, "%s", msg);
    return -1;
}

int query_submit(struct query_service *q, uint64_t serial, const cJSON *id, const struct query_req *r, double now,
                 struct ctl_error *e)
{
    double t = r->has_time ? r->time : now;
    if (t < now - q->cfg.window - 1e-9 || t > now + 1e-6) {
        e->code = "time_out_of_window";
        e->param[0] = '\0';
        snprintf(e->message, sizeof e->message, "time %.17g is outside [%.17g, %.17g] (the last %g s of sim time)", t,
                 now - q->cfg.window, now, q->cfg.window);
        return -1;
    }
    pthread_mutex_lock(&q->lock);
    int at = -1;
    for (int i = 0; i < q->nepochs; i++)
        if (q->epochs[i].since <= t)
            at = i;
    struct snap *snap = at >= 0 ? q->epochs[at].snap : NULL;
    uint32_t version = at >= 0 ? q->epochs[at].version : 0;
    bool full = q->njobs >= q->cfg.queue;
    if (snap && !full)
        atomic_fetch_add(&snap->refs, 1);
    pthread_mutex_unlock(&q->lock);
    if (at < 0)
        return fail(e, "time_out_of_window", "no parameters recorded that far back (restart, or many changes)");
    if (!snap || !snap->surf)
        return fail(e, "internal", "no snapshot of the sea for that time (out of memory when it was made)");
    if (full) {
        atomic_fetch_add(&g_metrics.query_busy, 1);
        return fail(e, "busy", "too many queries waiting; try again shortly");
    }
    /* The global budget: a token bucket of points (counted at N = 256). */
    double cost = r->n * snap->cost, tnow = mono_now();
    double cap = fmax(2 * q->cfg.budget, QUERY_MAX_POINTS * snap->cost);
    q->tokens = fmin(cap, q->tokens + (tnow - q->tokens_t) * q->cfg.budget);
    q->tokens_t = tnow;
    if (q->tokens < cost) {
        snap_unref(snap);
        atomic_fetch_add(&g_metrics.query_busy, 1);
        e->code = "busy";
        e->param[0] = '\0';
        snprintf(e->message, sizeof e->message, "the server's query budget (%g points/s at N = 256) is spent; "
                 "try again shortly", q->cfg.budget);
        return -1;
    }
    struct job *j = calloc(1, sizeof *j + (size_t)r->n * sizeof j->xz[0]);
    cJSON *idc = id ? cJSON_Duplicate(id, 1) : NULL;
    if (!j || (id && !idc)) {
        free(j);
        cJSON_Delete(idc);
        snap_unref(snap);
        return fail(e, "internal", "out of memory");
    }
    q->tokens -= cost;
    j->serial = serial;
    j->id = idc;
    j->t = t;
    j->version = version;
    j->snap = snap;
    j->n = r->n;
    memcpy(j->xz, r->xz, (size_t)r->n * sizeof j->xz[0]);
    atomic_fetch_add(&g_metrics.queries, 1);
    atomic_fetch_add(&g_metrics.query_points, (uint64_t)r->n);
    pthread_mutex_lock(&q->lock);
    *q->jobs_tail = j;
    q->jobs_tail = &j->next;
    q->njobs++;
    struct drain *d = kick_locked(q);
    pthread_mutex_unlock(&q->lock);
    kick_start(q, d);
    return 0;
}

static struct probe_count *count_of(struct query_service *q, uint64_t serial)
{
    for (int i = 0; i < q->ncounts; i++)
        if (q->counts[i].serial == serial)
            return &q->counts[i];
    return NULL;
}

static void send_cmd(struct query_service *q, uint64_t serial, struct probe_client *pc)
{
    struct probe_cmd *c = calloc(1, sizeof *c);
    if (!c) { /* cannot happen in practice; the set stays as it was */
        free(pc);
        return;
    }
    c->serial = serial;
    c->pc = pc;
    pthread_mutex_lock(&q->lock);
    *q->cmds_tail = c;
    q->cmds_tail = &c->next;
    struct drain *d = kick_locked(q);
    pthread_mutex_unlock(&q->lock);
    kick_start(q, d);
}

static void set_count(struct query_service *q, uint64_t serial, int n)
{
    struct probe_count *c = count_of(q, serial);
    int old = c ? c->n : 0;
    if (!c && n > 0) {
        if (q->ncounts == q->capcounts) {
            int cap = q->capcounts ? 2 * q->capcounts : 16;
            struct probe_count *nc = realloc(q->counts, (size_t)cap * sizeof *nc);
            if (!nc)
                return;
            q->counts = nc;
            q->capcounts = cap;
        }
        c = &q->counts[q->ncounts++];
        c->serial = serial;
    }
    if (c)
        c->n = n;
    q->probe_total += n - old;
    atomic_store(&g_metrics.probe_points, q->probe_total);
    if (c && n == 0)
        *c = q->counts[--q->ncounts];
    atomic_store(&q->probe_fields, q->probe_total > 0 ? OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX) |
                                                            OCEAN_FIELD_BIT(OCEAN_DZ)
                                                      : 0u);
}

int query_probe_set(struct query_service *q, uint64_t serial, const struct probe_req *p, struct ctl_error *e)
{
    if (p->n > q->cfg.probe_max_points) {
        e->code = "too_many_points";
        e->param[0] = '\0';
        snprintf(e->message, sizeof e->message, "%d probe points; at most %d per client", p->n,
                 q->cfg.probe_max_points);
        return -1;
    }
    struct probe_count *c = count_of(q, serial);
    int old = c ? c->n : 0;
    if (q->probe_total - old + p->n > q->cfg.probe_max_total) {
        atomic_fetch_add(&g_metrics.query_busy, 1);
        e->code = "busy";
        e->param[0] = '\0';
        snprintf(e->message, sizeof e->message, "the server probes %d points already (at most %d for all clients)",
                 q->probe_total - old, q->cfg.probe_max_total);
        return -1;
    }
    struct probe_client *pc = NULL;
    if (p->n > 0) {
        pc = calloc(1, sizeof *pc + (size_t)p->n * sizeof pc->pt[0]);
        if (!pc)
            return fail(e, "internal", "out of memory");
        pc->serial = serial;
        pc->n = p->n;
        for (int i = 0; i < p->n; i++) {
            pc->pt[i].xz[0] = pc->pt[i].guess[0] = p->xz[i][0];
            pc->pt[i].xz[1] = pc->pt[i].guess[1] = p->xz[i][1];
        }
    }
    if (!pc && !c)
        return 0; /* nothing to remove */
    send_cmd(q, serial, pc);
    set_count(q, serial, p->n);
    return 0;
}

void query_client_gone(struct query_service *q, uint64_t serial)
{
    if (!q || !count_of(q, serial))
        return;
    send_cmd(q, serial, NULL);
    set_count(q, serial, 0);
}

/* ---- life ---- */

struct query_service *query_service_new(const struct query_config *c, char *err, size_t errlen)
{
    struct query_service *q = calloc(1, sizeof *q);
    int nt = c->threads < 1 ? 1 : c->threads;
    if (q)
        q->drains = calloc((size_t)nt, sizeof *q->drains);
    if (!q || !q->drains) {
        free(q);
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    q->cfg = *c;
    q->jobs_tail = &q->jobs;
    q->cmds_tail = &q->cmds;
    q->out_tail = &q->out;
    q->tokens = INFINITY; /* a full bucket: clipped to its cap (which depends on the snapshot) at first use */
    q->tokens_t = mono_now();
    pthread_mutex_init(&q->lock, NULL);
    for (int i = 0; i < nt; i++)
        q->drains[i].q = q;
    q->pool = pool_new(nt);
    if (!q->pool) {
        snprintf(err, errlen, "cannot start the query workers");
        query_service_free(q);
        return NULL;
    }
    q->nthreads = pool_threads(q->pool); /* fewer if not all could start */
    return q;
}

void query_service_free(struct query_service *q)
{
    if (!q)
        return;
    pthread_mutex_lock(&q->lock);
    q->stop = true; /* drains still queued return at once */
    pthread_mutex_unlock(&q->lock);
    pool_free(q->pool);
    free(q->drains);
    while (q->jobs) {
        struct job *j = q->jobs;
        q->jobs = j->next;
        job_free(j);
    }
    for (int i = 0; i < q->nepochs; i++)
        snap_unref(q->epochs[i].snap);
    struct grids *gs[2] = { q->spare, q->pending };
    for (int i = 0; i < 2; i++)
        if (gs[i]) {
            free(gs[i]->h);
            free(gs[i]);
        }
    apply_cmds(q, q->cmds);
    while (q->clients) {
        struct probe_client *c = q->clients;
        q->clients = c->next;
        free(c);
    }
    while (q->out) {
        struct query_out *o = q->out;
        q->out = o->next;
        query_out_free(o);
    }
    free(q->counts);
    pthread_mutex_destroy(&q->lock);
    free(q);
}

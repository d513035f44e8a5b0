/* render_worker.c — the render workers (render_worker.h): one queue of
 * renders, `workers` threads that each take the oldest waiting render and
 * make its frames one at a time, on a simulation of their own.
 *
 * Under the service's lock: the list of renders (waiting and running), each
 * one's frames in flight and cancel flag, the work outstanding, the pacing
 * bucket, the results list. A worker holds it only to take a render, to
 * wait for room (flow control, pacing) and to post a frame; it steps and
 * encodes without it. */
#include "render_worker.h"

#include "clock.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include "log.h"
#include "metrics.h"
#include "oc_proto.h"

struct rjob {
    struct rjob *next;
    uint64_t serial;
    uint64_t number;            /* the service's count of renders accepted: tells its frames apart */
    cJSON *id;                  /* owned copy, or NULL */
    struct render_req req;
    struct ocean_params params; /* the sea at request time: the whole render shows it */
    uint32_t version;
    double frame_units;
    long posted;                /* frames handed over (worker, under the lock) */
    int inflight;               /* ...and not yet written to the socket (under the lock) */
    size_t inflight_bytes;      /* their bytes (under the lock) */
    bool running;               /* a worker took it (under the lock) */
    bool cancelled;             /* under the lock */
};

struct render_service {
    struct render_config c;
    char wisdom[512];
    pthread_mutex_t lock;
    pthread_cond_t cond;        /* a render queued or cancelled, room in a window, stop */
    struct rjob *jobs;          /* waiting and running, oldest first */
    double outstanding;         /* units accepted and not yet rendered */
    double tokens, tokens_t;    /* pacing bucket (units) and its last refill (mono) */
    struct render_out *out, *out_tail;
    uint64_t accepted;          /* renders accepted so far */
    bool stop;
    int nthreads;
    pthread_t *threads;
};

/* One worker's own simulation and encoder, kept from render to render. */
struct worker {
    struct render_service *r;
    struct ocean *o;
    struct ocean_params p;
    struct oc_encoder *enc;
    struct oc_buf buf;
};

static void post(struct render_service *r, struct render_out *o)
{
    /* under the lock */
    o->next = NULL;
    if (r->out_tail)
        r->out_tail->next = o;
    else
        r->out = o;
    r->out_tail = o;
}

static struct render_out *text_out(uint64_t serial, cJSON *msg)
{
    char *text = control_print(msg);
    struct render_out *o = text ? calloc(1, sizeof *o) : NULL;
    if (!o) {
        free(text);
        return NULL;
    }
    o->serial = serial;
    o->data = (uint8_t *)text;
    o->len = strlen(text);
    return o;
}

/* The closing `rendered` of render `render`, printed when it is sent (render_out_print). */
static struct render_out *rendered_out(uint64_t serial, uint64_t render, cJSON *msg)
{
    struct render_out *o = msg ? calloc(1, sizeof *o) : NULL;
    if (!o) {
        cJSON_Delete(msg);
        return NULL;
    }
    o->serial = serial;
    o->render = render;
    o->rendered = msg;
    return o;
}

/* CPU time of the calling thread, s: a frame's cost whatever else runs on the machine. */
static double thread_cpu_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* Wait on the service's condition for at most `s` seconds (under the lock). */
static void wait_for(struct render_service *r, double s)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    double end = (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9 + s;
    ts.tv_sec = (time_t)end;
    ts.tv_nsec = (long)((end - floor(end)) * 1e9);
    pthread_cond_timedwait(&r->cond, &r->lock, &ts);
}

/* Under the lock: wait until job j may make a frame (room in its window and
 * in the pacing bucket), then take the frame's units. false: cancelled or stopping. */
static bool wait_turn(struct render_service *r, struct rjob *j)
{
    for (;;) {
        if (j->cancelled || r->stop)
            return false;
        if (j->inflight >= RENDER_WINDOW || (j->inflight > 0 && j->inflight_bytes >= RENDER_WINDOW_BYTES)) {
            pthread_cond_wait(&r->cond, &r->lock);
            continue;
        }
        double now = mono_now(), burst = r->c.budget * 0.5;
        r->tokens += (now - r->tokens_t) * r->c.budget;
        r->tokens_t = now;
        if (r->tokens > burst)
            r->tokens = burst;
        if (r->tokens < 0) { /* over the budget: wait for the refill (a frame may take the bucket below 0) */
            wait_for(r, -r->tokens / r->c.budget + 1e-4);
            continue;
        }
        r->tokens -= j->frame_units;
        return true;
    }
}

/* The simulation for job j: the worker's own when it shows the same sea
 * (and no foam, whose history depends on the steps before), else a new one. */
static int prepare_ocean(struct worker *w, const struct rjob *j, char *err, size_t errlen)
{
    bool foam = (j->req.sub.fields & OCEAN_FIELD_BIT(OCEAN_FOAM)) != 0;
    if (w->o && !foam && params_diff(&w->p, &j->params) == 0)
        return 0;
    ocean_free(w->o);
    struct ocean_options opt = { .threads = 1, .wisdom_path = w->r->wisdom[0] ? w->r->wisdom : NULL,
                                 .plan_rigor = w->r->c.plan_rigor };
    w->o = ocean_create(&j->params, &opt, err, errlen);
    w->p = j->params;
    return w->o ? 0 : -1;
}

/* A worker with no render waiting keeps nothing of the last one: the
 * memory is given back when its clients are done (a next render of the same
 * sea makes its simulation again, a few ms against its frames' time). */
static void release_idle(struct worker *w)
{
    ocean_free(w->o);
    w->o = NULL;
    oc_buf_free(&w->buf);
}

/* Frame k of j into w->buf: step, then every asked tile of every layer. */
static int render_frame(struct worker *w, const struct rjob *j, long k)
{
    const struct render_req *q = &j->req;
    int n = ocean_resolution(w->o), ncasc = ocean_cascades(w->o);
    if (ncasc > q->sub.ncascades)
        ncasc = q->sub.ncascades;
    unsigned masks[OCEAN_MAX_CASCADES] = { 0 };
    int lods[OCEAN_MAX_CASCADES] = { 0 }, bis[OCEAN_MAX_CASCADES] = { 0 };
    for (int c = 0; c < ncasc; c++)
        masks[c] = subscription_cascade(&q->sub, c, &lods[c], &bis[c]);
    double t = render_time(q, k);
    if (ocean_step_cascades(w->o, t, masks, ncasc) != 0)
        return -1;
    int ts = w->r->c.tile_size < n ? w->r->c.tile_size : n, tps = n / ts;
    uint16_t tiles[CTL_MAX_TILES];
    int ntiles = 0;
    if (q->sub.all_tiles) {
        for (int i = 0; i < tps * tps && i < CTL_MAX_TILES; i++)
            tiles[ntiles++] = (uint16_t)i;
    } else {
        for (int i = 0; i < q->sub.ntiles; i++)
            if (q->sub.tiles[i][0] < tps && q->sub.tiles[i][1] < tps)
                tiles[ntiles++] = (uint16_t)(q->sub.tiles[i][1] * tps + q->sub.tiles[i][0]);
    }
    w->buf.len = 0;
    if (oc_buf_reserve(&w->buf, OC_FRAME_HEADER_SIZE) != 0)
        return -1;
    w->buf.len = OC_FRAME_HEADER_SIZE;
    long count = 0;
    for (int c = 0; c < ncasc; c++)
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
            if (!(masks[c] & OCEAN_FIELD_BIT(f)))
                continue;
            int lod = c == 0 ? subscription_lod(&q->sub, f) : lods[c];
            const float *data = ocean_cascade_field(w->o, c, (enum ocean_field)f);
            if ((ts >> lod) < 1 || !data)
                continue; /* a LOD finer than one sample per tile: as in the live frames */
            for (int i = 0; i < ntiles; i++) {
                if (oc_encode_tile_cascade(w->enc, data, n, ts, tiles[i] % tps, tiles[i] / tps, lod, (enum oc_field)f,
                                           ctl_bounds[bis[c]], c, &w->buf) != 0)
                    return -1;
                count++;
            }
        }
    const struct ocean_params *p = ocean_get_params(w->o);
    struct oc_frame_header h = {
        .seq = (uint64_t)k, .sim_time = t, .params_version = j->version, .n = (uint16_t)n,
        .tile_size = (uint16_t)ts, .patch_size = (float)p->patch_size, .tile_count = (uint16_t)count,
        .flags = RENDER_FRAME_FLAG, .server_time_us = unix_us(),
    };
    oc_frame_header_write(w->buf.data, &h);
    return count <= 65535 ? 0 : -1;
}

/* Make job j's frames; post them, then take j off the list and post `rendered` (or an error). */
static void run_job(struct worker *w, struct rjob *j)
{
    struct render_service *r = w->r;
    char err[256];
    const char *fail = NULL;
    if (prepare_ocean(w, j, err, sizeof err) != 0) {
        LOGW("render: the simulation could not be made: %s", err);
        fail = "the render's simulation could not be made (out of memory?)";
    }
    long k = 0;
    for (; !fail && k < j->req.frames; k++) {
        pthread_mutex_lock(&r->lock);
        bool go = wait_turn(r, j);
        pthread_mutex_unlock(&r->lock);
        if (!go)
            break;
        double t0 = mono_now(), c0 = thread_cpu_s();
        struct render_out *o = calloc(1, sizeof *o);
        if (!o || render_frame(w, j, k) != 0) {
            free(o);
            fail = "a frame could not be rendered (out of memory?)";
            break;
        }
        o->data = w->buf.data; /* handed over whole: the next frame starts a buffer of the same size */
        o->len = w->buf.len;
        o->frame = true;
        o->serial = j->serial;
        o->render = j->number;
        memset(&w->buf, 0, sizeof w->buf);
        if (oc_buf_reserve(&w->buf, o->len) != 0) {
            render_out_free(o);
            fail = "out of memory";
            break;
        }
        atomic_fetch_add(&g_metrics.render_frames, 1);
        atomic_fetch_add(&g_metrics.render_us, (uint64_t)((mono_now() - t0) * 1e6));
        atomic_fetch_add(&g_metrics.render_cpu_us, (uint64_t)((thread_cpu_s() - c0) * 1e6));
        pthread_mutex_lock(&r->lock);
        if (j->cancelled) { /* cancelled while it was being made: never handed over */
            pthread_mutex_unlock(&r->lock);
            render_out_free(o);
            break;
        }
        r->outstanding -= j->frame_units;
        j->inflight++;
        j->inflight_bytes += o->len;
        j->posted++;
        post(r, o);
        pthread_mutex_unlock(&r->lock);
        r->c.wake(r->c.wake_user);
    }
    pthread_mutex_lock(&r->lock);
    bool cancelled = j->cancelled;
    pthread_mutex_unlock(&r->lock);
    cJSON *end;
    if (fail) {
        struct ctl_error e = { .code = "internal" };
        snprintf(e.message, sizeof e.message, "%s; %ld of %ld frames rendered", fail, k, j->req.frames);
        end = control_error_msg(&e, j->id);
    } else {
        end = render_rendered_msg(j->id, k, cancelled || k < j->req.frames ? "cancelled" : NULL);
    }
    struct render_out *o = fail ? text_out(j->serial, end) : rendered_out(j->serial, j->number, end);
    /* Off the books before its client hears `rendered`: a next render may follow at once. */
    pthread_mutex_lock(&r->lock);
    r->outstanding -= (double)(j->req.frames - j->posted) * j->frame_units; /* what it did not render */
    if (r->outstanding < 1e-6)
        r->outstanding = 0;
    for (struct rjob **pp = &r->jobs; *pp; pp = &(*pp)->next)
        if (*pp == j) {
            *pp = j->next;
            break;
        }
    if (o)
        post(r, o);
    pthread_mutex_unlock(&r->lock);
    r->c.wake(r->c.wake_user);
}

static void *worker_main(void *arg)
{
    struct worker *w = arg;
    struct render_service *r = w->r;
    sigset_t block; /* signals are the main thread's (main.c) */
    sigemptyset(&block);
    sigaddset(&block, SIGINT);
    sigaddset(&block, SIGTERM);
    sigaddset(&block, SIGHUP);
    sigaddset(&block, SIGUSR1);
    sigaddset(&block, SIGUSR2);
    pthread_sigmask(SIG_BLOCK, &block, NULL);
    /* Below the tick's priority: on a full machine the live sea goes first. */
    if (setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), r->c.nice) != 0)
        LOGW("render worker: nice %d: %s", r->c.nice, strerror(errno));
    pthread_mutex_lock(&r->lock);
    while (!r->stop) {
        struct rjob *j = r->jobs;
        while (j && j->running)
            j = j->next;
        if (!j) {
            if (w->o || w->buf.data) { /* idle: its simulation and frame buffer go back (tens of MB at N = 256) */
                pthread_mutex_unlock(&r->lock);
                release_idle(w);
                pthread_mutex_lock(&r->lock);
                continue;
            }
            pthread_cond_wait(&r->cond, &r->lock);
            continue;
        }
        j->running = true;
        pthread_mutex_unlock(&r->lock);
        run_job(w, j); /* takes j off the list */
        cJSON_Delete(j->id);
        free(j);
        pthread_mutex_lock(&r->lock);
    }
    pthread_mutex_unlock(&r->lock);
    ocean_free(w->o);
    oc_encoder_free(w->enc);
    oc_buf_free(&w->buf);
    free(w);
    return NULL;
}

struct render_service *render_service_new(const struct render_config *c, char *err, size_t errlen)
{
    struct render_service *r = calloc(1, sizeof *r);
    if (!r) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    r->c = *c;
    if (c->wisdom_path)
        snprintf(r->wisdom, sizeof r->wisdom, "%s", c->wisdom_path);
    r->c.wisdom_path = NULL;
    if (r->c.workers < 1)
        r->c.workers = 1;
    r->tokens_t = mono_now();
    pthread_mutex_init(&r->lock, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&r->cond, &ca);
    pthread_condattr_destroy(&ca);
    r->threads = calloc((size_t)r->c.workers, sizeof *r->threads);
    for (int i = 0; r->threads && i < r->c.workers; i++) {
        struct worker *w = calloc(1, sizeof *w);
        if (!w || !(w->enc = oc_encoder_new())) {
            free(w);
            break;
        }
        w->r = r;
        if (pthread_create(&r->threads[i], NULL, worker_main, w) != 0) {
            oc_encoder_free(w->enc);
            free(w);
            break;
        }
        r->nthreads++;
    }
    if (r->nthreads == 0) {
        snprintf(err, errlen, "no render worker could be started");
        render_service_free(r);
        return NULL;
    }
    return r;
}

void render_service_free(struct render_service *r)
{
    if (!r)
        return;
    pthread_mutex_lock(&r->lock);
    r->stop = true;
    pthread_cond_broadcast(&r->cond);
    pthread_mutex_unlock(&r->lock);
    for (int i = 0; i < r->nthreads; i++)
        pthread_join(r->threads[i], NULL);
    free(r->threads);
    while (r->jobs) { /* queued, never started */
        struct rjob *j = r->jobs;
        r->jobs = j->next;
        cJSON_Delete(j->id);
        free(j);
    }
    render_out_free(r->out);
    pthread_cond_destroy(&r->cond);
    pthread_mutex_destroy(&r->lock);
    free(r);
}

int render_submit(struct render_service *r, uint64_t serial, const cJSON *id, const struct render_req *req,
                  const struct ocean_params *p, uint32_t version, double *units, struct ctl_error *e)
{
    struct rjob *j = calloc(1, sizeof *j);
    if (!j || (id && !(j->id = cJSON_Duplicate(id, 1)))) {
        free(j);
        e->code = "internal";
        snprintf(e->message, sizeof e->message, "out of memory");
        return -1;
    }
    j->serial = serial;
    j->req = *req;
    j->params = *p;
    j->version = version;
    j->frame_units = render_frame_units(req, p->resolution, p->cascades);
    double total = j->frame_units * (double)req->frames;
    *units = total;
    int rc = 0;
    pthread_mutex_lock(&r->lock);
    bool mine = false;
    for (struct rjob *x = r->jobs; x && !mine; x = x->next)
        mine = x->serial == serial; /* a cancelled one too, until its `rendered` is posted */
    if (total > r->c.max_units) {
        e->code = "bad_render";
        snprintf(e->message, sizeof e->message, "this render costs %.0f units, more than --render-max-units %.0f: "
                 "ask for fewer frames (or layers) at a time", total, r->c.max_units);
        rc = -1;
    } else if (mine) {
        e->code = "busy";
        snprintf(e->message, sizeof e->message, "a render of this client is in progress (render_cancel ends it; "
                 "its `rendered` says when)");
        rc = -1;
    } else if (r->outstanding + total > r->c.max_units) {
        e->code = "busy";
        snprintf(e->message, sizeof e->message, "the render budget is spent: %.0f units of renders waiting, "
                 "%.0f more asked, at most %.0f (--render-max-units); try again later", r->outstanding, total,
                 r->c.max_units);
        rc = -1;
    } else {
        struct rjob **pp = &r->jobs;
        while (*pp)
            pp = &(*pp)->next;
        *pp = j;
        j->number = ++r->accepted;
        r->outstanding += total;
        pthread_cond_broadcast(&r->cond);
    }
    pthread_mutex_unlock(&r->lock);
    if (rc) {
        e->param[0] = 0;
        cJSON_Delete(j->id);
        free(j);
        atomic_fetch_add(&g_metrics.render_refused, 1);
    }
    return rc;
}

bool render_cancel(struct render_service *r, uint64_t serial)
{
    bool found = false;
    pthread_mutex_lock(&r->lock);
    for (struct rjob **pp = &r->jobs; *pp;) {
        struct rjob *j = *pp;
        if (j->serial != serial || j->cancelled) {
            pp = &j->next;
            continue;
        }
        found = true;
        j->cancelled = true;
        if (j->running) { /* its worker stops before its next frame and posts `rendered` */
            pp = &j->next;
            continue;
        }
        *pp = j->next; /* never started: answered here */
        r->outstanding -= (double)j->req.frames * j->frame_units;
        if (r->outstanding < 1e-6)
            r->outstanding = 0;
        struct render_out *o = rendered_out(serial, j->number, render_rendered_msg(j->id, 0, "cancelled"));
        if (o)
            post(r, o);
        cJSON_Delete(j->id);
        free(j);
    }
    pthread_cond_broadcast(&r->cond);
    pthread_mutex_unlock(&r->lock);
    if (found)
        r->c.wake(r->c.wake_user);
    return found;
}

void render_frame_sent(struct render_service *r, const struct render_out *o)
{
    pthread_mutex_lock(&r->lock);
    for (struct rjob *j = r->jobs; j; j = j->next)
        if (j->number == o->render && j->inflight > 0) {
            size_t bytes = o->len;
            j->inflight--;
            j->inflight_bytes -= bytes < j->inflight_bytes ? bytes : j->inflight_bytes;
            pthread_cond_broadcast(&r->cond);
            break;
        }
    pthread_mutex_unlock(&r->lock);
}

struct render_out *render_take_results(struct render_service *r)
{
    pthread_mutex_lock(&r->lock);
    struct render_out *o = r->out;
    r->out = r->out_tail = NULL;
    pthread_mutex_unlock(&r->lock);
    return o;
}

void render_out_free(struct render_out *o)
{
    while (o) {
        struct render_out *next = o->next;
        cJSON_Delete(o->rendered);
        free(o->data);
        free(o);
        o = next;
    }
}

int render_out_print(struct render_out *o, long written)
{
    if (!o->rendered)
        return 0;
    cJSON *frames = cJSON_CreateNumber((double)written);
    if (!frames || !cJSON_ReplaceItemInObjectCaseSensitive(o->rendered, "frames", frames)) {
        cJSON_Delete(frames);
        return -1;
    }
    char *text = control_print(o->rendered); /* deletes the tree */
    o->rendered = NULL;
    if (!text)
        return -1;
    o->data = (uint8_t *)text;
    o->len = strlen(text);
    return 0;
}

int render_active(struct render_service *r)
{
    int n = 0;
    pthread_mutex_lock(&r->lock);
    for (struct rjob *j = r->jobs; j; j = j->next)
        n++;
    pthread_mutex_unlock(&r->lock);
    return n;
}

/* producer.c — the producer thread (step the ocean for the due fields, hand
 * them to a frame job, start its encode on the encode pool) and the end of
 * each encode (the pool's last thread publishes the frame). */
#include "tick_internal.h"

#include <math.h>
#include <string.h>

#include "clock.h"
#include "log.h"
#include "metrics.h"

void publish(struct sim *s, struct frame *f)
{
    pthread_mutex_lock(&s->lock);
    struct frame *old = s->latest;
    s->latest = f;
    pthread_mutex_unlock(&s->lock);
    frame_unref(old);
}

/* ---- encode (pool threads) ---- */

void encode_item(void *ctx, int item, int worker) { frame_job_item(((struct sim *)ctx)->job, item, worker); }

/* The last encode thread of a job: finish the frame, publish it, wake lws. */
static void encode_done(void *ctx)
{
    struct sim *s = ctx;
    struct frame *f = frame_job_finish(s->job);
    double now = mono_now();
    if (f) { /* the tick's bodies travel in its frame's header (PROTOCOL.md §3.5) */
        f->bodies = s->job_bodies;
        s->job_bodies = NULL;
    }
    body_snap_unref(s->job_bodies); /* no frame came of it */
    s->job_bodies = NULL;
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

/* Streams freed (their encoder state: megabytes each): the lws thread
 * hands the pages back to the system (malloc_trim is not the producer's job). */
#define TRIM_AFTER_BYTES ((size_t)1 << 20)
static void streams_freed(struct sim *s, size_t before)
{
    if (before >= s->streams.used + TRIM_AFTER_BYTES)
        atomic_store(&s->trim_wanted, true);
}

static void produce(struct sim *s, const struct prod_job *pj)
{
    if (pj->release_streams) {
        encode_pool_wait(s->pool); /* the frame before may still use them */
        size_t before = s->streams.used;
        layer_streams_free(&s->streams);
        streams_freed(s, before);
        return;
    }
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
    /* The bodies on this tick's grids, before the frame job takes them. */
    struct body_snap *bodies = body_tick(s, pj);
    if (!pj->want.nkeys) {
        body_snap_unref(bodies);
        return; /* stepped for the probes or the bodies only: no frame */
    }
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
    size_t streams_before = s->streams.used;
    int items = frame_job_begin(s->job, s->ocean, s->cfg.tile_size, &pj->want, &h);
    streams_freed(s, streams_before);
    s->job_bodies = items < 0 ? NULL : bodies; /* the encode before is done: encode_done took its own */
    if (items < 0) {
        body_snap_unref(bodies);
        LOGE("out of memory preparing frame %llu", (unsigned long long)pj->seq);
        return;
    }
    /* What this frame encodes (/metrics: encode work against the number of ladder rungs in use). */
    int keyframed = 0, n = ocean_resolution(s->ocean);
    uint64_t samples = 0, samples_key = 0;
    for (int k = 0; k < pj->want.nkeys; k++) {
        uint64_t side = (uint64_t)(n >> pj->want.lod[k]), sk = side * side;
        bool key = pj->want.intra[pj->want.keys[k]] != 0;
        keyframed += key;
        samples += sk;
        samples_key += key ? sk : 0;
    }
    atomic_fetch_add(&g_metrics.layers_encoded, (uint64_t)pj->want.nkeys);
    atomic_fetch_add(&g_metrics.layers_keyframed, (uint64_t)keyframed);
    atomic_fetch_add(&g_metrics.samples_encoded, samples);
    atomic_fetch_add(&g_metrics.samples_keyframed, samples_key);
    s->job_t_tick = pj->t_tick;
    s->job_t_enc = mono_now();
    s->job_samples = frame_job_samples(s->job);
    memcpy(s->job_codec_samples, pj->codec_samples, sizeof s->job_codec_samples);
    s->job_cold = pj->cold;
    encode_pool_start(s->pool, items, encode_item, encode_done, s);
}

void *producer_main(void *arg)
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

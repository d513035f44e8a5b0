/* tap_watch.c — frames: the subscription (cascade 0 and the finer ones), the
 * frames as they arrive, the file writer thread, --stats; and the tiny
 * subscription of a pure --watch. */
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tap.h"

/* Fields of the finer cascades: foam is cascade 0's only; a bake sums the
 * finer cascades and takes the Jacobian (which does not add) from cascade 0. */
unsigned fine_fields(const struct opts *o)
{
    return o->fields & ~(1u << OC_FIELD_FOAM) & (o->format == TAP_EXR ? ~(1u << OC_FIELD_JACOBIAN) : ~0u);
}
int fine_lod(const struct opts *o) { return o->lod > 1 ? o->lod : 1; }

void send_subscribe(struct session *s)
{
    cJSON *j = cJSON_CreateObject(), *fields = cJSON_CreateArray();
    int render = s->stage == ST_RENDER;
    cJSON_AddStringToObject(j, "type", render ? "render" : "subscribe");
    cJSON_AddNumberToObject(j, "id", render ? ID_RENDER : ID_SUBSCRIBE);
    if (render) {
        cJSON_AddNumberToObject(j, "start", s->o->start);
        cJSON_AddNumberToObject(j, "fps", s->o->fps);
        cJSON_AddNumberToObject(j, "frames", (double)s->o->frames);
    }
    for (int f = 0; f < OC_FIELD_COUNT; f++)
        if (s->o->fields & (1u << f)) cJSON_AddItemToArray(fields, cJSON_CreateString(oc_field_name(f)));
    cJSON_AddItemToObject(j, "fields", fields);
    cJSON_AddNumberToObject(j, "lod", s->o->lod);
    if (s->o->bound >= 0) cJSON_AddNumberToObject(j, "bound", s->o->bound);
    if (!render) {
        cJSON_AddStringToObject(j, "tiles", "all");
        if (s->o->max_rate > 0) cJSON_AddNumberToObject(j, "max_rate", s->o->max_rate);
        cJSON_AddBoolToObject(j, "temporal", !s->o->intra); /* PROTOCOL.md §5.9 */
    }
    /* The finer cascades (§4.1): same fields but foam (cascade 0's only), at LOD
     * 1 or coarser (they hold nothing LOD 1 drops) and 1 mm, their heights being
     * centimetres; lossless stays lossless. */
    cJSON *casc = s->ncasc > 1 ? cJSON_AddArrayToObject(j, "cascades") : NULL;
    for (int c = 1; c < s->ncasc; c++) {
        cJSON *e = cJSON_CreateObject(), *ef = cJSON_AddArrayToObject(e, "fields");
        for (int f = 0; f < OC_FIELD_COUNT; f++)
            if (fine_fields(s->o) & (1u << f)) cJSON_AddItemToArray(ef, cJSON_CreateString(oc_field_name(f)));
        cJSON_AddNumberToObject(e, "lod", fine_lod(s->o));
        cJSON_AddNumberToObject(e, "bound", s->o->bound == 0 ? 0 : 0.001);
        cJSON_AddItemToArray(casc, e);
    }
    send_json(s, j);
}

/* A watcher wants no frames, but a subscription cannot be empty: ask for one
 * 4x4-sample tile of one field, once a second (about 100 bytes/s). */
void send_quiet_subscribe(struct session *s)
{
    cJSON *j = cJSON_CreateObject(), *tiles = cJSON_CreateArray(), *t00 = cJSON_CreateArray();
    cJSON_AddStringToObject(j, "type", "subscribe");
    cJSON_AddNumberToObject(j, "id", ID_QUIET);
    cJSON *fields = cJSON_AddArrayToObject(j, "fields");
    cJSON_AddItemToArray(fields, cJSON_CreateString("height"));
    cJSON_AddNumberToObject(j, "lod", OC_MAX_LOD);
    cJSON_AddItemToArray(t00, cJSON_CreateNumber(0));
    cJSON_AddItemToArray(t00, cJSON_CreateNumber(0));
    cJSON_AddItemToArray(tiles, t00);
    cJSON_AddItemToObject(j, "tiles", tiles);
    cJSON_AddNumberToObject(j, "max_rate", 1);
    send_json(s, j);
}

/* ---- the writer thread ----------------------------------------------------
 * Files are written by a thread of their own, from copies of complete frames,
 * so that the connection is read while a frame is being written: a client that
 * stops reading misses ticks (the server sends the latest frame only). */


const float *job_field(const struct job *j, int c, int f, int *side, float *bound)
{
    if (c < 0 || c >= OC_MAX_CASCADES || f < 0 || f >= OC_FIELD_COUNT || !j->data[c][f]) return NULL;
    *side = j->side[c][f];
    *bound = j->bound[c][f];
    return j->data[c][f];
}

static void job_free(struct job *j)
{
    if (!j) return;
    for (int c = 0; c < OC_MAX_CASCADES; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) free(j->data[c][f]);
    free(j);
}

/* The writer's first failure: kept for the main thread, which reports it. */
void wfail(struct session *s, int code, const char *fmt, ...)
{
    pthread_mutex_lock(&s->wr.mu);
    if (!s->wr.err_code) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(s->wr.err, sizeof s->wr.err, fmt, ap);
        va_end(ap);
        s->wr.err_code = code;
    }
    pthread_mutex_unlock(&s->wr.mu);
}

static int write_frame(struct session *s, const struct job *j);

static void *writer_main(void *arg)
{
    struct session *s = arg;
    pthread_mutex_lock(&s->wr.mu);
    for (;;) {
        while (!s->wr.count && !s->wr.closing) pthread_cond_wait(&s->wr.cv_get, &s->wr.mu);
        if (!s->wr.count) break;
        struct job *j = s->wr.q[s->wr.head];
        s->wr.head = (s->wr.head + 1) % WRITER_QUEUE;
        s->wr.count--;
        int failed = s->wr.err_code != 0;
        pthread_cond_signal(&s->wr.cv_put);
        pthread_mutex_unlock(&s->wr.mu);
        if (!failed) write_frame(s, j); /* after a failure: drain, write nothing more */
        job_free(j);
        pthread_mutex_lock(&s->wr.mu);
    }
    pthread_mutex_unlock(&s->wr.mu);
    return NULL;
}

/* Copy the complete frame in the grids and queue it; waits while the queue is
 * full (its depth keeps the copies under WRITER_BYTES). */
static int writer_put(struct session *s, const struct oc_frame_header *fh)
{
    struct job *j = calloc(1, sizeof *j);
    if (!j) return -1;
    j->fh = *fh;
    j->number = s->frames_done;
    j->ncasc = s->ncasc > 0 ? s->ncasc : 1;
    memcpy(j->patch, s->patch, sizeof j->patch);
    size_t bytes = 0;
    for (int c = 0; c < j->ncasc; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            int side;
            float bound;
            const float *d = oc_grid_field(s->grid, c, f, &side, &bound);
            if (!d) continue;
            size_t n = (size_t)side * side * sizeof(float);
            if (!(j->data[c][f] = malloc(n))) { job_free(j); return -1; }
            memcpy(j->data[c][f], d, n);
            j->side[c][f] = side;
            j->bound[c][f] = bound;
            bytes += n;
        }
    int depth = bytes ? (int)(WRITER_BYTES / bytes) : WRITER_QUEUE;
    depth = depth < 1 ? 1 : depth > WRITER_QUEUE ? WRITER_QUEUE : depth;
    pthread_mutex_lock(&s->wr.mu);
    if (!s->wr.started) {
        if (pthread_create(&s->wr.th, NULL, writer_main, s) != 0) {
            pthread_mutex_unlock(&s->wr.mu);
            job_free(j);
            return -1;
        }
        s->wr.started = 1;
    }
    while (s->wr.count >= depth) pthread_cond_wait(&s->wr.cv_put, &s->wr.mu);
    s->wr.q[(s->wr.head + s->wr.count) % WRITER_QUEUE] = j;
    s->wr.count++;
    pthread_cond_signal(&s->wr.cv_get);
    pthread_mutex_unlock(&s->wr.mu);
    return 0;
}

/* The writer's failure, if any: code (0 = none) and message. */
int writer_error(struct session *s, char *msg, size_t len)
{
    pthread_mutex_lock(&s->wr.mu);
    int code = s->wr.err_code;
    if (code) snprintf(msg, len, "%s", s->wr.err);
    pthread_mutex_unlock(&s->wr.mu);
    return code;
}

/* Write what is queued, then stop the thread. */
void writer_close(struct session *s)
{
    pthread_mutex_lock(&s->wr.mu);
    s->wr.closing = 1;
    pthread_cond_signal(&s->wr.cv_get);
    int started = s->wr.started;
    pthread_mutex_unlock(&s->wr.mu);
    if (started) pthread_join(s->wr.th, NULL);
    s->wr.started = 0;
}

static int write_one(struct session *s, const char *path, const float *data, int side, const struct tap_meta *m)
{
    if (tap_write_field(s->o->format, path, data, side, m) != 0) {
        wfail(s, EXIT_OUTPUT, "cannot write %s: %s", path, strerror(errno));
        return -1;
    }
    return 0;
}

static int write_frame(struct session *s, const struct job *j)
{
    const struct oc_frame_header *fh = &j->fh;
    if (s->o->format == TAP_EXR) return write_bake(s, j);
    unsigned long long seq = (unsigned long long)fh->seq;
    for (int c = 0; c < j->ncasc; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            int side;
            float bound;
            const float *data = job_field(j, c, f, &side, &bound);
            if (!data) continue;
            char path[4096];
            /* Cascade 0 keeps the names of a one-cascade sea. */
            if (c == 0)
                snprintf(path, sizeof path, "%s/%s-%08llu.%s", s->o->out_dir, oc_field_name(f), seq,
                         tap_format_ext(s->o->format));
            else
                snprintf(path, sizeof path, "%s/%s-c%d-%08llu.%s", s->o->out_dir, oc_field_name(f), c, seq,
                         tap_format_ext(s->o->format));
            struct tap_meta m = {.field = oc_field_name(f), .seq = fh->seq, .sim_time = fh->sim_time,
                                 .params_version = fh->params_version, .n = fh->n,
                                 .lod = c == 0 ? s->o->lod : fine_lod(s->o),
                                 .patch_size = (float)(c == 0 ? fh->patch_size : j->patch[c]), .bound = bound,
                                 .server_time_us = fh->server_time_us, .cascade = c};
            if (write_one(s, path, data, side, &m) != 0) return -1;
        }
    if (!s->o->sum_m) return 0;
    struct sum_grid sg = sum_geometry(s, j);
    float *buf = sum_buffers(s, sg.m, 1);
    if (!buf) return -1;
    static const enum oc_field summed[5] = {OC_FIELD_HEIGHT, OC_FIELD_DX, OC_FIELD_DZ, OC_FIELD_SLOPE_X,
                                            OC_FIELD_SLOPE_Z};
    for (int k = 0; k < 5; k++) {
        float bound;
        int r = sum_field(s, j, &sg, summed[k], 0, buf, &bound);
        if (r < 0) return -1;
        if (r > 0) continue; /* not subscribed */
        char path[4096];
        snprintf(path, sizeof path, "%s/%s-sum-%08llu.%s", s->o->out_dir, oc_field_name(summed[k]), seq,
                 tap_format_ext(s->o->format));
        struct tap_meta m = {.field = oc_field_name(summed[k]), .seq = fh->seq, .sim_time = fh->sim_time,
                             .params_version = fh->params_version, .n = fh->n, .lod = 0,
                             .patch_size = (float)sg.size, .bound = bound, .server_time_us = fh->server_time_us,
                             .cascade = TAP_CASCADE_SUM, .origin_x = sg.x0, .origin_z = sg.z0};
        if (write_one(s, path, buf, sg.m, &m) != 0) return -1;
    }
    return 0;
}

void report_stats(struct session *s, double t, int final)
{
    struct stats *st = &s->st;
    double dt = t - (final ? st->t0 : st->last_report);
    long frames = final ? s->frames_done : s->frames_done - st->frames_at_report;
    unsigned long long bytes = final ? st->bytes : st->bytes - st->bytes_at_report;
    if (dt <= 0) dt = 1e-9;
    if (final) {
        /* Latency percentiles over all frames (sorted copy). */
        double p50 = 0, p95 = 0, mx = 0;
        if (st->nlat) {
            double *v = st->lat_ms;
            for (size_t i = 1; i < st->nlat; i++) /* insertion sort: counts are small */
                for (size_t k = i; k > 0 && v[k - 1] > v[k]; k--) { double x = v[k]; v[k] = v[k - 1]; v[k - 1] = x; }
            p50 = v[st->nlat / 2];
            p95 = v[(size_t)((st->nlat - 1) * 0.95)];
            mx = v[st->nlat - 1];
        }
        printf("frames=%ld seconds=%.3f fps=%.2f bytes=%llu bytes_per_frame=%.0f mbit_per_s=%.3f "
               "latency_ms_p50=%.2f latency_ms_p95=%.2f latency_ms_max=%.2f\n",
               frames, dt, frames / dt, bytes, frames ? (double)bytes / frames : 0.0,
               bytes * 8 / dt / 1e6, p50, p95, mx);
        fflush(stdout);
    } else {
        fprintf(stderr, "ocean-tap: %ld frames, %.1f fps, %.3f Mbit/s\n", s->frames_done,
                frames / dt, bytes * 8 / dt / 1e6);
        st->last_report = t;
        st->frames_at_report = s->frames_done;
        st->bytes_at_report = st->bytes;
    }
}

void on_binary(struct session *s, const uint8_t *data, size_t len)
{
    if (s->stage != ST_RUN || !s->want_frames) return; /* frames of the default subscription */
    struct oc_frame_header fh;
    if (s->o->bake) {
        /* Only the rendered frames, every one, in order, at exactly start + k/fps. */
        if (len < 40 || !((data[38] | data[39] << 8) & RENDER_FRAME_FLAG)) return;
    }
    int r = oc_grid_add(s->grid, data, len, &fh);
    if (r == OC_E_REFERENCE) {
        /* A predicted frame whose references we lack (we missed one): subscribing
         * again makes the server send keyframes next (PROTOCOL.md §5.9). Once a
         * second at most: frames already on their way fail the same way. */
        double t = now_s();
        if (t - s->resync_t >= 1.0) {
            s->resync_t = t;
            fprintf(stderr, "ocean-tap: frame %llu lacks its references: resubscribing\n",
                    (unsigned long long)fh.seq);
            send_subscribe(s);
        }
        return;
    }
    if (r) {
        fail(s, EXIT_PROTOCOL, "bad binary frame (%zu bytes): %s", len, oc_strerror(r));
        return;
    }
    if (s->o->bake) {
        double want = s->o->start + (double)s->frames_done / s->o->fps;
        if (fh.seq != (uint64_t)s->frames_done || !oc_grid_complete(s->grid) || fabs(fh.sim_time - want) > 1e-6) {
            fail(s, EXIT_PROTOCOL, "render frame %llu at sim time %.9f: expected frame %ld, complete, at %.9f",
                 (unsigned long long)fh.seq, fh.sim_time, s->frames_done, want);
            return;
        }
    }
    if (!oc_grid_complete(s->grid)) return; /* not every tile of every field at our LOD (degraded, or before
                                                  the subscription took effect): nothing new to write */
    s->frames_done++;
    s->last_frame = now_s();
    s->st.bytes += len;
    if (s->st.nlat == s->st.caplat) {
        size_t cap = s->st.caplat ? 2 * s->st.caplat : 256;
        double *p = realloc(s->st.lat_ms, cap * sizeof *p);
        if (p) { s->st.lat_ms = p; s->st.caplat = cap; }
    }
    if (s->st.nlat < s->st.caplat) s->st.lat_ms[s->st.nlat++] = (wall_us() - (double)fh.server_time_us) / 1e3;
    if (s->o->out_dir && writer_put(s, &fh) != 0) {
        fail(s, EXIT_OUTPUT, "out of memory for a frame's copy");
        return;
    }
    if (s->o->frames > 0 && s->frames_done >= s->o->frames) finish(s, EXIT_OK);
}

/* ---- libwebsockets ------------------------------------------------------ */

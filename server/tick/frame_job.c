/* frame_job.c — encode a tick's subscribed layers once, in parallel (one row
 * of tiles of a layer per item on the encode pool) into a new frame. */
#include "frame_job.h"

#include "clock.h"

#include <stdlib.h>
#include <string.h>

#include "layer_stream.h"
#include "log.h"

/* Which layer a piece of work belongs to. A stream-state (temporal) codec
 * keeps its state per (cascade, field, encoded_lod, bound_index, tile). */
struct layer_id {
    int field, encoded_lod, bound_index, cascade;
};

/* Intra tiles of rows [tz0, tz1) of tiles, in tile order, appended to out;
 * tile_off[tile] gets each tile's offset relative to out's start. */
static int encode_rows(struct oc_encoder *enc, const struct layer_id *id, const float *data, int n, int ts, int tz0,
                       int tz1, struct oc_buf *out, uint32_t *tile_off)
{
    int tps = n / ts;
    for (int tz = tz0; tz < tz1; tz++)
        for (int tx = 0; tx < tps; tx++) {
            tile_off[tz * tps + tx] = (uint32_t)out->len;
            int rc = oc_encode_tile_cascade(enc, data, n, ts, tx, tz, id->encoded_lod, (enum oc_field)id->field,
                                            ctl_bounds[id->bound_index], id->cascade, out);
            if (rc != 0)
                return rc;
        }
    return 0;
}

/* A layer's work in a job: its tile rows are cut into items (one row of
 * tiles each) that any encode thread may take; the thread that finishes the
 * layer's last item assembles it (layer_finish), so assembling overlaps the
 * other layers' encodes instead of adding to the job's end. */
struct layer_work {
    int key_index;              /* into want.keys */
    struct layer_id id;
    struct oc_stream *st;       /* temporal: this layer's stream, NULL = intra */
    bool keyframes;             /* temporal: make this tick's keyframe tiles too */
    struct oc_stream_stats before; /* temporal: the stream's counters at the job's start */
    int first_item, nitems;
    atomic_int left;            /* items not finished */
    atomic_int rc;              /* the first error of its items, then the layer's; 0 = none */
};

/* One item: rows [tz0, tz1) of tiles of one layer. An intra item encodes into
 * its own buffer (kept, with its capacity, from job to job); layer_finish
 * concatenates them in order. */
struct work_item {
    int layer, tz0, tz1;
    struct oc_buf out;
};

struct frame_job {
    int nenc;
    struct oc_encoder **enc;    /* one per encode thread + the caller */
    float *snap[OCEAN_MAX_CASCADES][OCEAN_FIELD_COUNT]; /* the step's fields per cascade, exchanged
                                                           with the library's arrays (foam: copied, it is
                                                           the foam's state): the next step writes elsewhere */
    size_t snap_cap[OCEAN_MAX_CASCADES][OCEAN_FIELD_COUNT];
    struct frame *f;            /* being built: one layer per struct layer_work (frame_job_finish hands it over) */
    int nlayers;
    struct layer_work lw[LAYER_KEYS_ALL];
    int nitems, items_cap;
    struct work_item *items;    /* every layer's items, layer after layer */
    size_t last_len[LAYER_KEYS_ALL]; /* bytes of each key's layer last time: reserved up front */
    struct frame_want want;
    struct oc_frame_header hdr;
    int n, ts, tps;
    long samples;
    struct layer_streams *streams; /* temporal layers, NULL = none (frame_job_set_streams) */
};

struct frame_job *frame_job_new(int workers)
{
    struct frame_job *j = calloc(1, sizeof *j);
    if (!j)
        return NULL;
    j->nenc = workers + 1;
    j->enc = calloc((size_t)j->nenc, sizeof *j->enc);
    if (!j->enc) {
        free(j);
        return NULL;
    }
    for (int i = 0; i < j->nenc; i++)
        if (!(j->enc[i] = oc_encoder_new())) {
            frame_job_free(j);
            return NULL;
        }
    return j;
}

/* A frame begun and never finished (start-up measurement, out of memory
 * half way): its encoded layers are not counted in nlayers yet. */
static void drop_unfinished(struct frame_job *j)
{
    if (!j->f)
        return;
    for (int i = 0; i < j->nlayers; i++) {
        oc_buf_free(&j->f->layers[i].buf);
        free(j->f->layers[i].tile_off);
        oc_buf_free(&j->f->layers[i].shared);
        free(j->f->layers[i].shared_off);
    }
    j->f->nlayers = 0;
    frame_unref(j->f);
    j->f = NULL;
}

void frame_job_free(struct frame_job *j)
{
    if (!j)
        return;
    drop_unfinished(j);
    for (int i = 0; i < j->nenc; i++)
        oc_encoder_free(j->enc[i]);
    free(j->enc);
    for (int i = 0; i < j->items_cap; i++)
        oc_buf_free(&j->items[i].out);
    free(j->items);
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++)
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
            ocean_field_buffer_free(j->snap[c][f]);
    free(j);
}

long frame_job_samples(const struct frame_job *j) { return j->samples; }

void frame_job_set_streams(struct frame_job *j, struct layer_streams *streams) { j->streams = streams; }

int frame_job_begin(struct frame_job *j, struct ocean *o, int tile_size, const struct frame_want *want,
                    const struct oc_frame_header *hdr)
{
    int n = ocean_resolution(o);
    j->n = n;
    j->ts = frame_tile_size(tile_size, n);
    j->tps = n / j->ts;
    j->want = *want;
    j->hdr = *hdr;
    if (j->streams) {
        /* The previous job is finished: its items no longer use the streams. */
        if (want->reset_streams)
            layer_streams_reset(j->streams);
        else if (want->sea_changed)
            layer_streams_sea_changed(j->streams);
        for (int k = 0; k < want->nkeys; k++) /* a layer degraded to a coarser LOD goes intra */
            if (want->lod[k] != layer_key_lod(want->keys[k])) {
                j->want.temporal[want->keys[k]] = 0;
                j->want.intra[want->keys[k]] = 1;
            }
        layer_streams_prepare(j->streams, n, j->ts, &j->want);
    }
    j->hdr.n = (uint16_t)n;
    j->hdr.tile_size = (uint16_t)j->ts;
    drop_unfinished(j); /* before nlayers is reset: it counts that frame's layers */
    j->nlayers = 0;
    j->nitems = 0;
    j->samples = 0;
    size_t nn = (size_t)n * n;
    int ncascades = ocean_cascades(o);
    for (int c = 0; c < ncascades && c < OCEAN_MAX_CASCADES; c++)
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
            const float *src = (want->cfields[c] & OCEAN_FIELD_BIT(f)) ? ocean_cascade_field(o, c, (enum ocean_field)f) : NULL;
            if (!src)
                continue;
            if (j->snap_cap[c][f] != nn) { /* exchanged arrays must be the library's size */
                ocean_field_buffer_free(j->snap[c][f]);
                j->snap_cap[c][f] = 0;
                if (!(j->snap[c][f] = ocean_field_buffer_new(n)))
                    return -1;
                j->snap_cap[c][f] = nn;
            }
            /* An exchange instead of a copy: 2.5 ms of one core at N = 1024 with six fields. */
            if (f == OCEAN_FOAM || ocean_exchange_cascade_field(o, c, (enum ocean_field)f, &j->snap[c][f]) != 0)
                memcpy(j->snap[c][f], src, nn * sizeof(float));
        }
    if (!(j->f = frame_new(want->nkeys)))
        return -1;
    j->f->tiles_per_side = j->tps;
    j->f->ncascades = ncascades;
    for (int k = 0; k < want->nkeys; k++) {
        int key = want->keys[k], field = layer_key_field(key), lod = want->lod[k], c = layer_key_which_cascade(key);
        if ((j->ts >> lod) < 1 || c >= ncascades || !(want->cfields[c] & OCEAN_FIELD_BIT(field)) ||
            !ocean_cascade_field(o, c, (enum ocean_field)field))
            continue; /* a LOD finer than one sample per tile, a field not stepped, a cascade not in force */
        j->samples += (long)(n >> lod) * (n >> lod);
        struct layer_work *w = &j->lw[j->nlayers];
        w->key_index = k;
        w->id = (struct layer_id){ field, lod, layer_key_bound(key), c };
        w->st = j->streams && j->want.temporal[key] ? j->streams->st[key] : NULL;
        w->keyframes = j->want.intra[key];
        /* One item per row of tiles: a one-layer frame (N = 2048 height: 16 rows
         * of 16 tiles) keeps every encode thread busy. */
        w->first_item = j->nitems;
        w->nitems = j->tps;
        atomic_init(&w->left, w->nitems);
        atomic_init(&w->rc, 0);
        if (j->nitems + w->nitems > j->items_cap) {
            int cap = (j->nitems + w->nitems) * 2;
            struct work_item *grown = realloc(j->items, sizeof *grown * (size_t)cap);
            if (!grown)
                return -1;
            memset(grown + j->items_cap, 0, sizeof *grown * (size_t)(cap - j->items_cap));
            j->items = grown;
            j->items_cap = cap;
        }
        struct layer *l = &j->f->layers[j->nlayers];
        if (!w->st && !(l->tile_off = malloc(sizeof(uint32_t) * ((size_t)j->tps * j->tps + 1))))
            return -1;
        l->cascade = (uint8_t)c;
        l->field = (uint8_t)field;
        l->lod = (uint8_t)layer_key_lod(key);
        l->bound_index = (uint8_t)w->id.bound_index;
        l->encoded_lod = (uint8_t)lod;
        for (int r = 0; r < w->nitems; r++) {
            struct work_item *it = &j->items[j->nitems++];
            it->layer = j->nlayers;
            it->tz0 = r;
            it->tz1 = r + 1;
            it->out.len = 0;
        }
        j->nlayers++;
        if (w->st)
            layer_temporal_begin(w->st, hdr->seq, &w->before);
    }
    return j->nitems;
}

/* The layer's last item is done (on that item's thread): assemble it. */
static void layer_finish(struct frame_job *j, int li)
{
    struct layer_work *w = &j->lw[li];
    struct layer *l = &j->f->layers[li];
    int rc = atomic_load(&w->rc);
    if (w->st) {
        rc = layer_temporal_collect(w->st, rc, w->keyframes, j->tps, &w->before, l);
    } else if (rc == 0) {
        size_t total = 0;
        for (int i = w->first_item; i < w->first_item + w->nitems; i++)
            total += j->items[i].out.len;
        if (oc_buf_reserve(&l->buf, total) != 0)
            rc = OC_E_NOMEM;
        for (int i = w->first_item; rc == 0 && i < w->first_item + w->nitems; i++) {
            const struct work_item *it = &j->items[i];
            for (int t = it->tz0 * j->tps; t < it->tz1 * j->tps; t++)
                l->tile_off[t] += (uint32_t)l->buf.len;
            memcpy(l->buf.data + l->buf.len, it->out.data, it->out.len);
            l->buf.len += it->out.len;
        }
        if (rc == 0)
            l->tile_off[j->tps * j->tps] = (uint32_t)l->buf.len;
    }
    atomic_store(&w->rc, rc);
}

void frame_job_item(struct frame_job *j, int index, int worker)
{
    struct work_item *it = &j->items[index];
    struct layer_work *w = &j->lw[it->layer];
    const float *data = j->snap[w->id.cascade][w->id.field];
    int rc;
    if (w->st) /* temporal: ranges of one stream run concurrently (oc_stream_encode_tiles) */
        rc = layer_temporal_tiles(w->st, j->enc[worker], data, w->keyframes, j->tps, it->tz0 * j->tps,
                                  (it->tz1 - it->tz0) * j->tps);
    else {
        size_t reserve = j->last_len[j->want.keys[w->key_index]] / (size_t)w->nitems;
        rc = reserve && oc_buf_reserve(&it->out, reserve) != 0
                 ? OC_E_NOMEM
                 : encode_rows(j->enc[worker], &w->id, data, j->n, j->ts, it->tz0, it->tz1, &it->out,
                               j->f->layers[it->layer].tile_off);
    }
    if (rc != 0) {
        int none = 0;
        atomic_compare_exchange_strong(&w->rc, &none, rc);
    }
    if (atomic_fetch_sub(&w->left, 1) == 1) /* seq_cst: every item's writes are visible to the last */
        layer_finish(j, it->layer);
}

void frame_job_warm(struct frame_job *j, const struct ocean *o, int tile_size)
{
    int n = ocean_resolution(o), ts = frame_tile_size(tile_size, n);
    for (int e = 0; e < j->nenc; e++)
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
            const float *data = ocean_field(o, (enum ocean_field)f);
            if (!data)
                continue;
            struct layer_id id = { f, 0, 3 /* 1 cm */, 0 };
            struct oc_buf out = { 0 };
            uint32_t *off = malloc(sizeof(uint32_t) * (size_t)(n / ts) * (size_t)(n / ts));
            if (off)
                encode_rows(j->enc[e], &id, data, n, ts, 0, n / ts, &out, off);
            oc_buf_free(&out);
            free(off);
        }
}

struct frame *frame_job_finish(struct frame_job *j)
{
    struct frame *f = j->f;
    j->f = NULL;
    if (!f)
        return NULL;
    /* Keep the layers that encoded, in key order. */
    int kept = 0;
    for (int i = 0; i < j->nlayers; i++) {
        struct layer *l = &f->layers[i];
        int rc = atomic_load(&j->lw[i].rc);
        if (rc != 0) {
            LOGE("encoding %s lod %d cascade %d: %s", ocean_field_name((enum ocean_field)l->field), l->encoded_lod,
                 l->cascade, oc_strerror(rc));
            oc_buf_free(&l->buf);
            free(l->tile_off);
            oc_buf_free(&l->shared);
            free(l->shared_off);
            continue;
        }
        j->last_len[j->want.keys[j->lw[i].key_index]] = l->buf.len + l->buf.len / 8;
        if (kept != i)
            f->layers[kept] = *l;
        kept++;
    }
    for (int i = kept; i < j->nlayers; i++)
        memset(&f->layers[i], 0, sizeof f->layers[i]);
    f->nlayers = kept;
    f->hdr = j->hdr;
    f->hdr.server_time_us = unix_us();
    return f;
}

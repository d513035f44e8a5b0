/* frame.c — encode a tick's subscribed layers once, in parallel (one layer
 * per item on the encode pool); reference-counted frames. */
#include "frame.h"

#include "clock.h"

#include <stdlib.h>
#include <string.h>

#include "layer_stream.h"
#include "log.h"

struct frame *frame_new(int nlayers)
{
    struct frame *f = calloc(1, sizeof *f);
    if (!f)
        return NULL;
    atomic_init(&f->refs, 1);
    f->ncascades = 1;
    f->layers = calloc(nlayers > 0 ? (size_t)nlayers : 1, sizeof *f->layers);
    if (!f->layers) {
        free(f);
        return NULL;
    }
    return f;
}

void frame_ref(struct frame *f) { atomic_fetch_add(&f->refs, 1); }

void frame_unref(struct frame *f)
{
    if (!f || atomic_fetch_sub(&f->refs, 1) != 1)
        return;
    for (int i = 0; i < f->nlayers; i++) {
        oc_buf_free(&f->layers[i].buf);
        free(f->layers[i].tile_off);
        oc_buf_free(&f->layers[i].shared);
        free(f->layers[i].shared_off);
    }
    free(f->layers);
    free(f);
}

const struct layer *frame_layer_cascade(const struct frame *f, int cascade, int field, int lod, int bound_index)
{
    for (int i = 0; i < f->nlayers; i++) {
        const struct layer *l = &f->layers[i];
        if (l->field == field && l->lod == lod && l->bound_index == bound_index && l->cascade == cascade)
            return l;
    }
    return NULL;
}

const struct layer *frame_layer(const struct frame *f, int field, int lod, int bound_index)
{
    return frame_layer_cascade(f, 0, field, lod, bound_index);
}

/* Which layer a piece of work belongs to. A stream-state (temporal) codec
 * keeps its state per (cascade, field, encoded_lod, bound_index, tile). */
struct layer_id {
    int field, encoded_lod, bound_index, cascade;
};

/* The whole encode of one layer: every tile, in tile order, into l (buf and
 * tile_off, fresh: the frame owns them once published). One call per layer,
 * handed to one encode thread, so that per-layer codec state needs no lock. */
static int encode_layer(struct oc_encoder *enc, const struct layer_id *id, const float *data, int n, int ts,
                        size_t reserve, struct layer *l)
{
    int tps = n / ts;
    l->tile_off = malloc(sizeof(uint32_t) * ((size_t)tps * tps + 1));
    if (!l->tile_off || (reserve && oc_buf_reserve(&l->buf, reserve) != 0))
        return OC_E_NOMEM;
    for (int tz = 0; tz < tps; tz++)
        for (int tx = 0; tx < tps; tx++) {
            l->tile_off[tz * tps + tx] = (uint32_t)l->buf.len;
            int rc = oc_encode_tile_cascade(enc, data, n, ts, tx, tz, id->encoded_lod, (enum oc_field)id->field,
                                            ctl_bounds[id->bound_index], id->cascade, &l->buf);
            if (rc != 0)
                return rc;
        }
    l->tile_off[tps * tps] = (uint32_t)l->buf.len;
    return 0;
}

struct frame_job {
    int nenc;
    struct oc_encoder **enc;    /* one per encode thread + the caller */
    float *snap[OCEAN_MAX_CASCADES][OCEAN_FIELD_COUNT]; /* the step's fields per cascade, copied:
                                                           the next step overwrites them */
    size_t snap_cap[OCEAN_MAX_CASCADES][OCEAN_FIELD_COUNT];
    struct frame *f;            /* being built: one layer per item (frame_job_finish hands it over) */
    int nitems;
    int item_key[LAYER_KEYS_ALL];   /* item -> index into want.keys */
    int item_rc[LAYER_KEYS_ALL];
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
    for (int i = 0; i < j->nitems; i++) {
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
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++)
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
            free(j->snap[c][f]);
    free(j);
}

long frame_job_samples(const struct frame_job *j) { return j->samples; }

void frame_job_set_streams(struct frame_job *j, struct layer_streams *streams) { j->streams = streams; }

int frame_job_begin(struct frame_job *j, const struct ocean *o, int tile_size, const struct frame_want *want,
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
    drop_unfinished(j); /* before nitems is reset: it counts that frame's layers */
    j->nitems = 0;
    j->samples = 0;
    size_t nn = (size_t)n * n;
    int ncascades = ocean_cascades(o);
    for (int c = 0; c < ncascades && c < OCEAN_MAX_CASCADES; c++)
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
            const float *src = (want->cfields[c] & OCEAN_FIELD_BIT(f)) ? ocean_cascade_field(o, c, (enum ocean_field)f) : NULL;
            if (!src)
                continue;
            if (j->snap_cap[c][f] < nn) {
                free(j->snap[c][f]);
                j->snap_cap[c][f] = 0;
                if (!(j->snap[c][f] = malloc(nn * sizeof(float))))
                    return -1;
                j->snap_cap[c][f] = nn;
            }
            memcpy(j->snap[c][f], src, nn * sizeof(float));
        }
    if (!(j->f = frame_new(want->nkeys)))
        return -1;
    j->f->tiles_per_side = j->tps;
    j->f->ncascades = ncascades;
    for (int k = 0; k < want->nkeys; k++) {
        int field = layer_key_field(want->keys[k]), lod = want->lod[k], c = layer_key_which_cascade(want->keys[k]);
        if ((j->ts >> lod) < 1 || c >= ncascades || !(want->cfields[c] & OCEAN_FIELD_BIT(field)) ||
            !ocean_cascade_field(o, c, (enum ocean_field)field))
            continue; /* a LOD finer than one sample per tile, a field not stepped, a cascade not in force */
        j->samples += (long)(n >> lod) * (n >> lod);
        j->item_key[j->nitems] = k;
        j->item_rc[j->nitems] = 0;
        j->nitems++;
    }
    return j->nitems;
}

void frame_job_item(struct frame_job *j, int index, int worker)
{
    int k = j->item_key[index], key = j->want.keys[k];
    struct layer_id id = { layer_key_field(key), j->want.lod[k], layer_key_bound(key), layer_key_which_cascade(key) };
    struct layer *l = &j->f->layers[index];
    l->cascade = (uint8_t)id.cascade;
    l->field = (uint8_t)id.field;
    l->lod = (uint8_t)layer_key_lod(key);
    l->bound_index = (uint8_t)id.bound_index;
    l->encoded_lod = (uint8_t)id.encoded_lod;
    struct oc_stream *st = j->streams && key < LAYER_KEYS && j->want.temporal[key] ? j->streams->st[key] : NULL;
    if (st) /* temporal: this layer's stream, used by this thread alone (jobs run one at a time) */
        j->item_rc[index] = layer_encode_temporal(st, j->enc[worker], j->snap[id.cascade][id.field], j->hdr.seq,
                                                  j->want.intra[key], j->tps, l);
    else
        j->item_rc[index] = encode_layer(j->enc[worker], &id, j->snap[id.cascade][id.field], j->n, j->ts,
                                         j->last_len[key], l);
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
            struct layer l = { 0 };
            encode_layer(j->enc[e], &id, data, n, ts, 0, &l);
            oc_buf_free(&l.buf);
            free(l.tile_off);
        }
}

struct frame *frame_job_finish(struct frame_job *j)
{
    struct frame *f = j->f;
    j->f = NULL;
    if (!f)
        return NULL;
    /* Keep the layers that encoded, in item order. */
    int kept = 0;
    for (int i = 0; i < j->nitems; i++) {
        struct layer *l = &f->layers[i];
        if (j->item_rc[i] != 0) {
            LOGE("encoding %s lod %d cascade %d: %s", ocean_field_name((enum ocean_field)l->field), l->encoded_lod,
                 l->cascade, oc_strerror(j->item_rc[i]));
            oc_buf_free(&l->buf);
            free(l->tile_off);
            oc_buf_free(&l->shared);
            free(l->shared_off);
            continue;
        }
        j->last_len[j->want.keys[j->item_key[i]]] = l->buf.len + l->buf.len / 8;
        if (kept != i)
            f->layers[kept] = *l;
        kept++;
    }
    for (int i = kept; i < j->nitems; i++)
        memset(&f->layers[i], 0, sizeof f->layers[i]);
    f->nlayers = kept;
    f->hdr = j->hdr;
    f->hdr.server_time_us = unix_us();
    return f;
}

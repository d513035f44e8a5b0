/* frame.c — encode a tick's subscribed layers once, in parallel (rows of
 * tiles on the encode pool); reference-counted frames. */
#include "frame.h"

#include "clock.h"

#include <stdlib.h>
#include <string.h>

#include "log.h"

struct frame *frame_new(int nlayers)
{
    struct frame *f = calloc(1, sizeof *f);
    if (!f)
        return NULL;
    atomic_init(&f->refs, 1);
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

/* Which layer a piece of work belongs to. A stream-state (temporal) codec
 * keeps its state per (field, encoded_lod, bound_index, tile). */
struct layer_id {
    int field, encoded_lod, bound_index;
};

/* Tiles [tx0, tx1) of row tz of one layer, appended to out; off[i] = where
 * tile tx0 + i starts in out. This is the whole per-layer encode: one call
 * per row here, one call per layer when run with the full range. */
static int encode_tiles(struct oc_encoder *enc, const struct layer_id *id, const float *data, int n, int ts,
                        int tz, int tx0, int tx1, struct oc_buf *out, uint32_t *off)
{
    for (int tx = tx0; tx < tx1; tx++) {
        off[tx - tx0] = (uint32_t)out->len;
        int rc = oc_encode_tile(enc, data, n, ts, tx, tz, id->encoded_lod, (enum oc_field)id->field,
                                ctl_bounds[id->bound_index], out);
        if (rc != 0)
            return rc;
    }
    off[tx1 - tx0] = (uint32_t)out->len;
    return 0;
}

/* One row of tiles of one layer. */
struct item {
    int key_index;              /* into want.keys */
    int row;                    /* tz */
    struct oc_buf buf;          /* kept across frames: no allocation once warm */
    uint32_t *off;              /* tps + 1 */
    int off_cap;
    int rc;
};

struct frame_job {
    int nenc;
    struct oc_encoder **enc;    /* one per encode thread + the caller */
    float *snap[OCEAN_FIELD_COUNT]; /* the step's fields, copied: the next step overwrites them */
    size_t snap_cap[OCEAN_FIELD_COUNT];
    struct item *items;
    int nitems, items_cap;
    struct frame_want want;
    struct oc_frame_header hdr;
    int n, ts, tps;
    long samples;
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

void frame_job_free(struct frame_job *j)
{
    if (!j)
        return;
    for (int i = 0; i < j->nenc; i++)
        oc_encoder_free(j->enc[i]);
    free(j->enc);
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        free(j->snap[f]);
    for (int i = 0; i < j->items_cap; i++) {
        oc_buf_free(&j->items[i].buf);
        free(j->items[i].off);
    }
    free(j->items);
    free(j);
}

long frame_job_samples(const struct frame_job *j) { return j->samples; }

static int grow_items(struct frame_job *j, int need)
{
    if (need <= j->items_cap)
        return 0;
    struct item *it = realloc(j->items, sizeof *it * (size_t)need);
    if (!it)
        return -1;
    memset(it + j->items_cap, 0, sizeof *it * (size_t)(need - j->items_cap));
    j->items = it;
    j->items_cap = need;
    return 0;
}

int frame_job_begin(struct frame_job *j, const struct ocean *o, int tile_size, const struct frame_want *want,
                    const struct oc_frame_header *hdr)
{
    int n = ocean_resolution(o);
    j->n = n;
    j->ts = frame_tile_size(tile_size, n);
    j->tps = n / j->ts;
    j->want = *want;
    j->hdr = *hdr;
    j->hdr.n = (uint16_t)n;
    j->hdr.tile_size = (uint16_t)j->ts;
    j->nitems = 0;
    j->samples = 0;
    size_t nn = (size_t)n * n;
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++) {
        const float *src = (want->fields & OCEAN_FIELD_BIT(f)) ? ocean_field(o, (enum ocean_field)f) : NULL;
        if (!src)
            continue;
        if (j->snap_cap[f] < nn) {
            free(j->snap[f]);
            j->snap_cap[f] = 0;
            if (!(j->snap[f] = malloc(nn * sizeof(float))))
                return -1;
            j->snap_cap[f] = nn;
        }
        memcpy(j->snap[f], src, nn * sizeof(float));
    }
    if (grow_items(j, want->nkeys * j->tps) != 0)
        return -1;
    for (int k = 0; k < want->nkeys; k++) {
        int field = layer_key_field(want->keys[k]), lod = want->lod[k];
        if ((j->ts >> lod) < 1 || !(want->fields & OCEAN_FIELD_BIT(field)) || !ocean_field(o, (enum ocean_field)field))
            continue; /* a LOD finer than one sample per tile, or a field not stepped */
        j->samples += (long)(n >> lod) * (n >> lod);
        for (int tz = 0; tz < j->tps; tz++) {
            struct item *it = &j->items[j->nitems++];
            it->key_index = k;
            it->row = tz;
            it->buf.len = 0;
            it->rc = 0;
            if (it->off_cap < j->tps + 1) {
                free(it->off);
                it->off_cap = 0;
                if (!(it->off = malloc(sizeof(uint32_t) * (size_t)(j->tps + 1))))
                    return -1;
                it->off_cap = j->tps + 1;
            }
        }
    }
    return j->nitems;
}

void frame_job_item(struct frame_job *j, int index, int worker)
{
    struct item *it = &j->items[index];
    int key = j->want.keys[it->key_index];
    struct layer_id id = { layer_key_field(key), j->want.lod[it->key_index], layer_key_bound(key) };
    it->rc = encode_tiles(j->enc[worker], &id, j->snap[id.field], j->n, j->ts, it->row, 0, j->tps, &it->buf, it->off);
}

/* Join rows [first, first + tps) into layer l. */
static int join_rows(struct frame_job *j, int first, struct layer *l)
{
    size_t total = 0;
    for (int r = 0; r < j->tps; r++) {
        if (j->items[first + r].rc != 0)
            return j->items[first + r].rc;
        total += j->items[first + r].buf.len;
    }
    l->tile_off = malloc(sizeof(uint32_t) * ((size_t)j->tps * j->tps + 1));
    if (!l->tile_off || oc_buf_reserve(&l->buf, total ? total : 1) != 0)
        return OC_E_NOMEM;
    for (int r = 0; r < j->tps; r++) {
        const struct item *it = &j->items[first + r];
        for (int tx = 0; tx < j->tps; tx++)
            l->tile_off[r * j->tps + tx] = (uint32_t)(l->buf.len + it->off[tx]);
        memcpy(l->buf.data + l->buf.len, it->buf.data, it->buf.len);
        l->buf.len += it->buf.len;
    }
    l->tile_off[j->tps * j->tps] = (uint32_t)l->buf.len;
    return 0;
}

struct frame *frame_job_finish(struct frame_job *j)
{
    struct frame *f = calloc(1, sizeof *f);
    if (!f)
        return NULL;
    atomic_init(&f->refs, 1);
    f->tiles_per_side = j->tps;
    int nlayers = j->tps ? j->nitems / j->tps : 0;
    f->layers = calloc(nlayers ? (size_t)nlayers : 1, sizeof *f->layers);
    if (!f->layers) {
        free(f);
        return NULL;
    }
    for (int first = 0; first < j->nitems; first += j->tps) {
        int k = j->items[first].key_index, key = j->want.keys[k];
        struct layer *l = &f->layers[f->nlayers];
        l->field = (uint8_t)layer_key_field(key);
        l->lod = (uint8_t)layer_key_lod(key);
        l->bound_index = (uint8_t)layer_key_bound(key);
        l->encoded_lod = j->want.lod[k];
        int rc = join_rows(j, first, l);
        if (rc != 0) {
            LOGE("encoding %s lod %d: %s", ocean_field_name((enum ocean_field)l->field), l->encoded_lod, oc_strerror(rc));
            oc_buf_free(&l->buf);
            free(l->tile_off);
            memset(l, 0, sizeof *l);
            continue;
        }
        f->nlayers++;
    }
    f->hdr = j->hdr;
    f->hdr.server_time_us = unix_us();
    return f;
}

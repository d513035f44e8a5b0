/* layer_stream.c — temporal layers: one oc_stream per wanted layer key. */
#include "layer_stream.h"

#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "metrics.h"

/* oc_stream keeps, per sample, the codes and Laplacians of 5 ticks (int32)
 * plus its shared and keyframe tile buffers: ~40 bytes, rounded up. */
size_t layer_stream_bytes(int side) { return (size_t)side * (size_t)side * 44; }

void layer_streams_init(struct layer_streams *ls, int keyframe_interval, size_t budget)
{
    memset(ls, 0, sizeof *ls);
    ls->keyframe_interval = keyframe_interval;
    ls->budget = budget;
}

void layer_streams_reset(struct layer_streams *ls)
{
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        oc_stream_reset(ls->st[k]);
}

void layer_streams_sea_changed(struct layer_streams *ls)
{
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        oc_stream_sea_changed(ls->st[k]);
}

static void drop(struct layer_streams *ls, int k)
{
    if (!ls->st[k])
        return;
    oc_stream_free(ls->st[k]);
    ls->st[k] = NULL;
    ls->used -= layer_stream_bytes(ls->tile_size >> layer_key_lod(k)) * (size_t)(ls->n / ls->tile_size) *
                (size_t)(ls->n / ls->tile_size);
}

void layer_streams_free(struct layer_streams *ls)
{
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        drop(ls, k);
}

/* Bytes per frame at N = 256, 1 cm (docs/codec.md): shared 21.4 kB fine vs 27.7 coarse,
 * keyframes 105 vs 68 kB: the fine grid pays when tclients * 6.3 > iclients * 37. */
static void pick_refine(struct layer_streams *ls, int k, const struct frame_want *want)
{
    ls->key_rate[k] += (want->kclients[k] - ls->key_rate[k]) / 32;
    double takers = want->iclients[k] + ls->key_rate[k], keep = want->tclients[k] - ls->key_rate[k];
    bool coarse = want->iclients[k] == 65535 || takers * 6 > keep + 1;   /* + 1: a client joining is not a trend */
    ls->coarse_ticks[k] = coarse ? 0 : ls->coarse_ticks[k] + 1;
    if (coarse)
        oc_stream_set_grid_refine(ls->st[k], 1);                 /* no-op when already there */
    else if (ls->coarse_ticks[k] >= 64)
        oc_stream_set_grid_refine(ls->st[k], OC_STREAM_GRID_REFINE(ctl_bounds[layer_key_bound(k)]));
}

void layer_streams_prepare(struct layer_streams *ls, int n, int tile_size, struct frame_want *want)
{
    if (ls->n != n || ls->tile_size != tile_size) {
        layer_streams_free(ls);
        ls->n = n;
        ls->tile_size = tile_size;
    }
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        if (ls->st[k] && !want->temporal[k])
            drop(ls, k);
    for (int i = 0; i < want->nkeys; i++) {
        int k = want->keys[i];
        int side = tile_size >> layer_key_lod(k);
        if (!want->temporal[k])
            continue;
        if (ls->st[k]) {
            pick_refine(ls, k, want);
            continue;
        }
        size_t bytes = layer_stream_bytes(side) * (size_t)(n / tile_size) * (size_t)(n / tile_size);
        if (side >= 1 && ls->used + bytes <= ls->budget)
            ls->st[k] = oc_stream_new(n, tile_size, layer_key_lod(k), (enum oc_field)layer_key_field(k),
                                      ctl_bounds[layer_key_bound(k)]);
        if (!ls->st[k]) { /* over the budget, or no memory: this layer stays intra for now */
            want->temporal[k] = 0;
            want->intra[k] = 1;
            continue;
        }
        oc_stream_set_keyframe_interval(ls->st[k], ls->keyframe_interval);
        ls->coarse_ticks[k] = 64;
        ls->key_rate[k] = 0;
        pick_refine(ls, k, want);
        ls->used += bytes;
    }
}

/* Copy one tile (header + payload) into buf, recording its offset, and mark
 * its cascade in the header's flags (bits 0-1, PROTOCOL.md §3.2), as
 * oc_encode_tile_cascade does: oc_stream writes 0 there. */
static int append(struct oc_buf *buf, uint32_t *off, const uint8_t *tile, size_t len, int cascade)
{
    *off = (uint32_t)buf->len;
    if (len < OC_TILE_HEADER_SIZE || oc_buf_reserve(buf, len))
        return len < OC_TILE_HEADER_SIZE ? OC_E_ARG : OC_E_NOMEM;
    memcpy(buf->data + buf->len, tile, len);
    buf->data[buf->len + 3] = (uint8_t)cascade;
    buf->len += len;
    return 0;
}

static void clear(struct layer *l)
{
    oc_buf_free(&l->buf);
    oc_buf_free(&l->shared);
    free(l->tile_off);
    free(l->shared_off);
    l->tile_off = l->shared_off = NULL;
    l->need = 0;
}

int layer_temporal_begin(struct oc_stream *st, uint64_t seq, struct oc_stream_stats *before)
{
    oc_stream_stats(st, before);
    return oc_stream_begin(st, seq);
}

int layer_temporal_tiles(struct oc_stream *st, struct oc_encoder *enc, const float *data, bool keyframes, int tps,
                         int first, int count)
{
    int rc = oc_stream_encode_tiles(st, enc, data, first, count);
    for (int k = first; rc == 0 && keyframes && k < first + count; k++) {
        const uint8_t *p;   /* made now, on this thread; layer_temporal_collect takes it from the stream */
        size_t len;
        rc = oc_stream_keyframe_tile(st, enc, k % tps, k / tps, &p, &len);
    }
    return rc;
}

int layer_temporal_collect(struct oc_stream *st, int rc, bool keyframes, int tps,
                           const struct oc_stream_stats *before, struct layer *l)
{
    int cascade = l->cascade;
    int end = oc_stream_end(st);    /* resets the stream when a range failed */
    if (rc == 0)
        rc = end;
    size_t ntiles = (size_t)tps * (size_t)tps;
    if (rc == 0 && !(l->shared_off = malloc(sizeof(uint32_t) * (ntiles + 1))))
        rc = OC_E_NOMEM;
    if (rc == 0 && keyframes && !(l->tile_off = malloc(sizeof(uint32_t) * (ntiles + 1))))
        rc = OC_E_NOMEM;
    for (int tz = 0; rc == 0 && tz < tps; tz++)
        for (int tx = 0; rc == 0 && tx < tps; tx++) {
            const uint8_t *p;
            size_t len;
            rc = oc_stream_tile(st, tx, tz, &p, &len);
            if (rc == 0)
                rc = append(&l->shared, &l->shared_off[tz * tps + tx], p, len, cascade);
            if (rc == 0 && keyframes && (rc = oc_stream_keyframe_tile(st, NULL, tx, tz, &p, &len)) == 0)
                rc = append(&l->buf, &l->tile_off[tz * tps + tx], p, len, cascade);
        }
    if (rc != 0) {
        oc_stream_reset(st);
        clear(l);
        return rc;
    }
    l->shared_off[ntiles] = (uint32_t)l->shared.len;
    if (keyframes)
        l->tile_off[ntiles] = (uint32_t)l->buf.len;
    l->need = (uint8_t)oc_stream_need(st);
    struct oc_stream_stats after;
    oc_stream_stats(st, &after);
    atomic_fetch_add(&g_metrics.stream_key_tiles, after.key_tiles - before->key_tiles);
    atomic_fetch_add(&g_metrics.stream_predicted_tiles, after.predicted_tiles - before->predicted_tiles);
    atomic_fetch_add(&g_metrics.stream_demand_key_tiles, after.demand_key_tiles - before->demand_key_tiles);
    return 0;
}

/* frame.c — encode a tick's subscribed layers once; reference-counted frames. */
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

const struct layer *frame_layer(const struct frame *f, int field, int lod, int bound_index)
{
    for (int i = 0; i < f->nlayers; i++) {
        const struct layer *l = &f->layers[i];
        if (l->field == field && l->lod == lod && l->bound_index == bound_index)
            return l;
    }
    return NULL;
}

/* Every tile of one layer, in tile order, with the offsets clients slice by. */
static int encode_layer(struct layer *l, struct oc_encoder *enc, const float *data, int n, int ts)
{
    int tps = n / ts;
    l->tile_off = malloc(sizeof(uint32_t) * ((size_t)tps * tps + 1));
    if (!l->tile_off)
        return OC_E_NOMEM;
    for (int tz = 0; tz < tps; tz++)
        for (int tx = 0; tx < tps; tx++) {
            l->tile_off[tz * tps + tx] = (uint32_t)l->buf.len;
            int rc = oc_encode_tile(enc, data, n, ts, tx, tz, l->lod, (enum oc_field)l->field,
                                    ctl_bounds[l->bound_index], &l->buf);
            if (rc != 0)
                return rc;
        }
    l->tile_off[tps * tps] = (uint32_t)l->buf.len;
    return 0;
}

struct frame *frame_encode(const struct ocean *o, struct oc_encoder *enc, int tile_size,
                           const struct frame_want *want, const struct oc_frame_header *hdr,
                           struct layer_streams *streams)
{
    int n = ocean_resolution(o);
    int ts = frame_tile_size(tile_size, n);
    struct frame *f = calloc(1, sizeof *f);
    if (!f)
        return NULL;
    atomic_init(&f->refs, 1);
    f->tiles_per_side = n / ts;
    f->layers = calloc(want->nkeys ? (size_t)want->nkeys : 1, sizeof *f->layers);
    if (!f->layers) {
        free(f);
        return NULL;
    }
    for (int i = 0; i < want->nkeys; i++) {
        int key = want->keys[i];
        struct layer *l = &f->layers[f->nlayers];
        l->field = (uint8_t)layer_key_field(key);
        l->lod = (uint8_t)layer_key_lod(key);
        l->bound_index = (uint8_t)layer_key_bound(key);
        const float *data = ocean_field(o, (enum ocean_field)l->field);
        if ((ts >> l->lod) < 1 || !data)
            continue; /* a LOD finer than one sample per tile, or a field not stepped */
        struct oc_stream *st = want->temporal[key] && streams ? streams->st[key] : NULL;
        int rc = st ? layer_encode_temporal(st, enc, data, hdr->seq, want->intra[key], f->tiles_per_side, l)
                    : encode_layer(l, enc, data, n, ts);
        if (rc != 0) {
            LOGE("encoding %s lod %d: %s", ocean_field_name((enum ocean_field)l->field), l->lod, oc_strerror(rc));
            oc_buf_free(&l->buf);
            free(l->tile_off);
            oc_buf_free(&l->shared);
            free(l->shared_off);
            memset(l, 0, sizeof *l);
            continue;
        }
        f->nlayers++;
    }
    f->hdr = *hdr;
    f->hdr.n = (uint16_t)n;
    f->hdr.tile_size = (uint16_t)ts;
    f->hdr.server_time_us = unix_us();
    return f;
}

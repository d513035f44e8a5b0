/* frame.c — encode a tick's subscribed layers once; reference-counted frames. */
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
            int rc = oc_encode_tile_cascade(enc, data, n, ts, tx, tz, l->lod, (enum oc_field)l->field,
                                            ctl_bounds[l->bound_index], l->cascade, &l->buf);
            if (rc != 0)
                return rc;
        }
    l->tile_off[tps * tps] = (uint32_t)l->buf.len;
    return 0;
}

struct frame *frame_encode(const struct ocean *o, struct oc_encoder *enc, int tile_size,
                           const struct frame_want *want, const struct oc_frame_header *hdr)
{
    int n = ocean_resolution(o);
    int ts = frame_tile_size(tile_size, n);
    struct frame *f = calloc(1, sizeof *f);
    if (!f)
        return NULL;
    atomic_init(&f->refs, 1);
    f->tiles_per_side = n / ts;
    f->ncascades = ocean_cascades(o);
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
        l->cascade = (uint8_t)layer_key_which_cascade(key);
        const float *data = ocean_cascade_field(o, l->cascade, (enum ocean_field)l->field);
        if ((ts >> l->lod) < 1 || !data)
            continue; /* a LOD finer than one sample per tile, a field not stepped, a cascade not in force */
        int rc = encode_layer(l, enc, data, n, ts);
        if (rc != 0) {
            LOGE("encoding %s lod %d cascade %d: %s", ocean_field_name((enum ocean_field)l->field), l->lod, l->cascade,
                 oc_strerror(rc));
            oc_buf_free(&l->buf);
            free(l->tile_off);
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

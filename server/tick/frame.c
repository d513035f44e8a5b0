/* frame.c — a tick's encoded output: reference-counted frames and the
 * lookup of their layers (frame_job.c builds them). */
#include "frame.h"

#include "body_snap.h"

#include <stdlib.h>
#include <string.h>

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

size_t frame_bytes(const struct frame *f)
{
    size_t b = 0;
    for (int i = 0; f && i < f->nlayers; i++)
        b += f->layers[i].buf.len + f->layers[i].shared.len;
    return b;
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
    body_snap_unref(f->bodies);
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

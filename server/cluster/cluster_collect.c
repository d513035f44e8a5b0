/* cluster_collect.c — the edge's frame collector: complete layers in,
 * frames (all layers of one seq) out. Pure and single-threaded; the rules
 * are in cluster.h. */
#include "cluster.h"

#include <stdlib.h>
#include <string.h>

struct cl_collector {
    struct cl_frame_set *pending;   /* the seq being collected, or NULL */
    struct cl_collector_stats st;
};

struct cl_collector *cl_collector_new(void) { return calloc(1, sizeof(struct cl_collector)); }

void cl_frame_set_free(struct cl_frame_set *f)
{
    if (!f)
        return;
    for (int i = 0; i < f->nlayers; i++)
        cl_layer_free(f->layers[i]);
    free(f);
}

void cl_collector_free(struct cl_collector *c)
{
    if (!c)
        return;
    cl_frame_set_free(c->pending);
    free(c);
}

void cl_collector_stats(const struct cl_collector *c, struct cl_collector_stats *out) { *out = c->st; }

void cl_collector_reset(struct cl_collector *c)
{
    if (!c)
        return;
    cl_frame_set_free(c->pending);
    c->pending = NULL;
}

/* Same frame: every field of the WebSocket frame header, and the encoded set. */
static bool same_frame(const struct cl_layer_info *a, const struct cl_layer_info *b)
{
    return a->seq == b->seq && memcmp(&a->sim_time, &b->sim_time, sizeof a->sim_time) == 0 &&
           a->params_version == b->params_version && a->n == b->n && a->tile_size == b->tile_size &&
           memcmp(&a->patch_size, &b->patch_size, sizeof a->patch_size) == 0 && a->frame_flags == b->frame_flags &&
           a->server_time_us == b->server_time_us && a->tiles_per_side == b->tiles_per_side &&
           a->ncascades == b->ncascades &&
           memcmp(a->encoded, b->encoded, CL_KEY_BYTES) == 0;
}

static int key_of(const struct cl_layer *l) { return cl_info_key(&l->info); }

static bool complete(const struct cl_frame_set *f, const uint8_t want[CL_KEY_BYTES])
{
    uint8_t have[CL_KEY_BYTES] = { 0 };
    for (int i = 0; i < f->nlayers; i++)
        cl_bit_set(have, key_of(f->layers[i]), true);
    for (int b = 0; b < CL_KEY_BYTES; b++)
        if (want[b] & f->hdr.encoded[b] & ~have[b])
            return false;
    return true;
}

static struct cl_frame_set *take(struct cl_collector *c, bool partial)
{
    struct cl_frame_set *f = c->pending;
    c->pending = NULL;
    f->partial = partial;
    c->st.frames++;
    if (partial)
        c->st.partial++;
    return f;
}

int cl_collector_add(struct cl_collector *c, struct cl_layer *l, const uint8_t want[CL_KEY_BYTES],
                     struct cl_frame_set *out[2])
{
    if (!c || !l || !want || !out) {
        cl_layer_free(l);
        return CL_E_ARG;
    }
    int n = 0;
    struct cl_frame_set *p = c->pending;
    if (p && l->info.seq < p->hdr.seq) {
        c->st.stale++;
        cl_layer_free(l);
        return CL_E_CORRUPT;
    }
    if (p && l->info.seq > p->hdr.seq) {
        /* some layer of it never came (or nobody wants it any more): hand it out as it is */
        out[n++] = take(c, !complete(p, want));
        p = NULL;
    }
    if (p) {
        int k = key_of(l);
        bool dup = false;
        for (int i = 0; i < p->nlayers; i++)
            dup |= key_of(p->layers[i]) == k;
        if (dup || !same_frame(&p->hdr, &l->info)) {
            c->st.mismatched++;
            cl_layer_free(l);
            return n ? n : CL_E_CORRUPT;
        }
    } else {
        p = c->pending = calloc(1, sizeof *p);
        if (!p) {
            cl_layer_free(l);
            return n ? n : CL_E_NOMEM;
        }
        p->hdr = l->info;
    }
    /* insert in key order */
    int k = key_of(l), i = p->nlayers;
    while (i > 0 && key_of(p->layers[i - 1]) > k) {
        p->layers[i] = p->layers[i - 1];
        i--;
    }
    p->layers[i] = l;
    p->nlayers++;
    if (complete(p, want))
        out[n++] = take(c, false);
    return n;
}

struct cl_frame_set *cl_collector_check(struct cl_collector *c, const uint8_t want[CL_KEY_BYTES])
{
    if (c && c->pending && complete(c->pending, want))
        return take(c, false);
    return NULL;
}

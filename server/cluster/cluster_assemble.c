/* cluster_assemble.c — the edge's reassembly: parts into whole layers
 * (the assembler), complete layers into frames of one seq (the collector).
 * Pure and single-threaded; fuzzed by fuzz/fuzz_cluster.c. The rules are in
 * cluster.h. */
#include "cluster.h"

#include <stdlib.h>
#include <string.h>

/* Same frame: every field of the WebSocket frame header, and the encoded set. */
static bool same_frame(const struct cl_layer_info *a, const struct cl_layer_info *b)
{
    return a->seq == b->seq && memcmp(&a->sim_time, &b->sim_time, sizeof a->sim_time) == 0 &&
           a->params_version == b->params_version && a->n == b->n && a->tile_size == b->tile_size &&
           memcmp(&a->patch_size, &b->patch_size, sizeof a->patch_size) == 0 && a->frame_flags == b->frame_flags &&
           a->server_time_us == b->server_time_us && a->tiles_per_side == b->tiles_per_side &&
           a->ncascades == b->ncascades && a->epoch == b->epoch &&
           memcmp(a->encoded, b->encoded, CL_KEY_BYTES) == 0;
}

/* Same layer: the same frame, and the same layer of it (every part of a
 * layer repeats its header). */
static bool same_layer(const struct cl_layer_info *a, const struct cl_layer_info *b)
{
    return same_frame(a, b) && a->field == b->field && a->lod == b->lod && a->bound_index == b->bound_index &&
           a->layer_flags == b->layer_flags && a->cascade == b->cascade && a->encoded_lod == b->encoded_lod &&
           a->need == b->need;
}

/* ---- assembler: parts -> layers ---- */

struct slot {
    bool active;
    struct cl_layer_info info;
    int next_tile, total;
    uint8_t *data;
    size_t len, cap;
    uint32_t *off;
};

struct cl_assembler {
    struct slot slots[CL_KEYS];
    uint64_t dropped;
    size_t held, budget;      /* bytes of every slot's data and offsets; its cap */
};

struct cl_assembler *cl_assembler_new(void)
{
    struct cl_assembler *a = calloc(1, sizeof(struct cl_assembler));
    if (a)
        a->budget = CL_MAX_ASSEMBLY_BYTES;
    return a;
}

void cl_assembler_set_budget(struct cl_assembler *a, size_t bytes) { a->budget = bytes; }
size_t cl_assembler_held(const struct cl_assembler *a) { return a->held; }

static size_t slot_bytes(const struct slot *s)
{
    return s->cap + (s->off ? sizeof(uint32_t) * ((size_t)s->total + 1) : 0);
}

static void slot_reset(struct cl_assembler *a, struct slot *s)
{
    a->held -= slot_bytes(s);
    free(s->data);
    free(s->off);
    memset(s, 0, sizeof *s);
}

void cl_assembler_free(struct cl_assembler *a)
{
    if (!a)
        return;
    for (int k = 0; k < CL_KEYS; k++)
        slot_reset(a, &a->slots[k]);
    free(a);
}

uint64_t cl_assembler_dropped(const struct cl_assembler *a) { return a->dropped; }

/* Room for `more` bytes in slot s: drop other incomplete layers of older
 * seqs first (left behind by lost parts), then give up. */
static bool make_room(struct cl_assembler *a, const struct slot *s, size_t more)
{
    for (int k = 0; k < CL_KEYS && a->held + more > a->budget; k++) {
        struct slot *o = &a->slots[k];
        if (o != s && o->active && o->info.seq < s->info.seq) {
            a->dropped++;
            slot_reset(a, o);
        }
    }
    return a->held + more <= a->budget;
}

int cl_assembler_add(struct cl_assembler *a, const struct cl_layer_part *p, struct cl_layer **out)
{
    if (!a || !p || !out)
        return CL_E_ARG;
    *out = NULL;
    struct slot *s = &a->slots[cl_info_key(&p->info)];
    if (p->tile_first == 0) {
        if (s->active)
            a->dropped++; /* a new layer began before the old one was complete */
        slot_reset(a, s);
        s->info = p->info;
        s->total = cl_layer_tiles(&p->info); /* every section's tiles */
        size_t off_bytes = sizeof(uint32_t) * ((size_t)s->total + 1);
        if (!make_room(a, s, off_bytes)) {
            a->dropped++;
            memset(s, 0, sizeof *s);
            return CL_E_TOO_LARGE;
        }
        s->off = malloc(off_bytes);
        if (!s->off)
            return CL_E_NOMEM;
        a->held += off_bytes;
        s->active = true;
    } else if (!s->active || p->tile_first != s->next_tile || !same_layer(&s->info, &p->info)) {
        if (s->active)
            a->dropped++; /* a part went missing: the layer cannot be completed */
        slot_reset(a, s);
        return CL_E_CORRUPT;
    }
    if (p->data_len > CL_MAX_LAYER_BYTES - s->len) {
        a->dropped++;
        slot_reset(a, s);
        return CL_E_TOO_LARGE;
    }
    if (s->len + p->data_len > s->cap) {
        size_t cap = s->next_tile + p->tile_count == s->total ? s->len + p->data_len : 2 * (s->len + p->data_len);
        if (cap > CL_MAX_LAYER_BYTES)
            cap = CL_MAX_LAYER_BYTES;
        if (!make_room(a, s, cap - s->cap)) {
            a->dropped++;
            slot_reset(a, s);
            return CL_E_TOO_LARGE;
        }
        uint8_t *d = realloc(s->data, cap ? cap : 1);
        if (!d) {
            slot_reset(a, s);
            return CL_E_NOMEM;
        }
        a->held += cap - s->cap;
        s->data = d;
        s->cap = cap;
    }
    for (int i = 0; i < p->tile_count; i++)
        s->off[s->next_tile + i] = (uint32_t)s->len + cl_part_off(p, i);
    if (p->data_len)
        memcpy(s->data + s->len, p->data, p->data_len);
    s->len += p->data_len;
    s->next_tile += p->tile_count;
    if (s->next_tile < s->total)
        return 0;
    s->off[s->total] = (uint32_t)s->len;
    struct cl_layer *l = malloc(sizeof *l);
    if (!l) {
        slot_reset(a, s);
        return CL_E_NOMEM;
    }
    l->info = s->info;
    l->data = s->data;
    l->len = s->len;
    l->tile_off = s->off;
    a->held -= slot_bytes(s); /* handed over: no longer the assembler's */
    s->data = NULL;
    s->off = NULL;
    s->cap = 0;
    slot_reset(a, s);
    *out = l;
    return 1;
}

/* ---- collector: layers -> frames ---- */

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

/* frame.h — one tick's encoded output, shared read-only by every client.
 *
 * The tick thread encodes each (field, LOD, bound) layer that some client
 * subscribes to, once, into a struct frame; the lws thread copies byte
 * ranges of it (the tiles each client asked for) into its sockets. A frame is
 * immutable once built and freed when its last reference goes (frame_ref /
 * frame_unref are atomic, so either thread may drop the last one). */
#ifndef OCEAND_FRAME_H
#define OCEAND_FRAME_H

#include <stdatomic.h>
#include <stdint.h>

#include "control.h"
#include "oc_proto.h"
#include "ocean.h"

/* A layer key: one (field, LOD, bound index) combination, 0..LAYER_KEYS-1.
 * Subscriptions are counted per key (demand); a frame holds one layer per
 * key that had demand when it was built. */
#define LAYER_KEYS (OCEAN_FIELD_COUNT * (CTL_MAX_LOD + 1) * CTL_BOUND_COUNT)
static inline int layer_key(int field, int lod, int bound_index)
{
    return (field * (CTL_MAX_LOD + 1) + lod) * CTL_BOUND_COUNT + bound_index;
}
static inline int layer_key_field(int key) { return key / ((CTL_MAX_LOD + 1) * CTL_BOUND_COUNT); }
static inline int layer_key_lod(int key) { return (key / CTL_BOUND_COUNT) % (CTL_MAX_LOD + 1); }
static inline int layer_key_bound(int key) { return key % CTL_BOUND_COUNT; }

/* The tile side frames use at resolution n: the configured size, or n when
 * the grid is smaller. hello and params announce this value too. */
static inline int frame_tile_size(int configured, int n) { return configured < n ? configured : n; }

/* All tiles of one field at one LOD and bound, encoded back to back.
 * buf holds intra tiles (codec 1, or 0), which any client can decode: for a
 * temporal layer these are this tick's keyframe tiles, present only when
 * some client needed them (else tile_off is NULL). A temporal layer also has
 * the shared tiles of its stream (PROTOCOL.md §5.9), for the clients that
 * received the layer in each of the `need` previous ticks. */
struct layer {
    uint8_t field, lod, bound_index;
    uint8_t need;           /* temporal: ticks of history the shared tiles need (0 = none) */
    struct oc_buf buf;
    uint32_t *tile_off;     /* tiles_per_side^2 + 1 offsets into buf; tile i = tz*tps + tx; NULL = none */
    struct oc_buf shared;   /* temporal: the shared tiles (codec 3, or a chain's keyframe) */
    uint32_t *shared_off;   /* offsets into shared, as tile_off; NULL = not a temporal layer this tick */
};

struct frame {
    atomic_int refs;
    struct oc_frame_header hdr; /* tile_count is per client: set when sending */
    uint64_t index;             /* frames published before this one (not on the wire): counts
                                   frames the lws thread never saw, unlike seq, which also
                                   advances on ticks that built no frame */
    int tiles_per_side;
    int nlayers;
    struct layer *layers;
};

/* Which layers to build: the keys with demand, and the fields they need. */
struct frame_want {
    unsigned fields;            /* OCEAN_FIELD_BIT mask of the keys below */
    int nkeys;
    uint16_t keys[LAYER_KEYS];
    uint8_t temporal[LAYER_KEYS]; /* by key: a temporal client wants it (encode its stream) */
    uint8_t intra[LAYER_KEYS];  /* by key: a client needs intra / keyframe tiles this tick */
};

struct layer_streams;

/* Encode the wanted layers of the ocean's last step into a new frame (one
 * reference, held by the caller). hdr gives seq, sim_time, params_version,
 * patch_size; n, tile_size and server_time_us are filled in here. Temporal
 * keys are encoded by their stream in `streams` (layer_streams_prepare made
 * them), the others as intra tiles. A layer that fails to encode is left
 * out (logged). NULL when out of memory. */
struct frame *frame_encode(const struct ocean *o, struct oc_encoder *enc, int tile_size,
                           const struct frame_want *want, const struct oc_frame_header *hdr,
                           struct layer_streams *streams);

/* An empty frame with room for nlayers layers (nlayers = 0 so far), one
 * reference: for frames not encoded here (an edge rebuilds them from the
 * sim's layers, server/role_edge.c). Each layer's buf.data and tile_off
 * must be malloc'd: frame_unref frees them. NULL when out of memory. */
struct frame *frame_new(int nlayers);

void frame_ref(struct frame *f);
void frame_unref(struct frame *f);     /* NULL is fine */
/* The layer for (field, lod, bound), or NULL if nobody asked for it this tick. */
const struct layer *frame_layer(const struct frame *f, int field, int lod, int bound_index);

#endif

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
#include <stdbool.h>
#include <stdint.h>

#include "control.h"
#include "layer_key.h"
#include "oc_proto.h"
#include "ocean.h"

struct body_snap;

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
    uint8_t field, lod, bound_index, cascade; /* lod: of the key clients subscribed to */
    uint8_t encoded_lod;        /* lod of its tiles: lod, or coarser when the tick degraded it
                                   (capacity.h; the clients concerned were told with `degraded`) */
    uint8_t need;               /* temporal: ticks of history the shared tiles need (0 = none) */
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
    int ncascades;              /* cascades in force when it was built (layers of higher ones never come) */
    int nlayers;
    struct layer *layers;
    struct body_snap *bodies;   /* the floating bodies of this tick (one reference), NULL = none: its
                                   BODY section follows the 48-byte header (PROTOCOL.md §3.5) */
};

/* Which layers to build: the keys due this tick, the encoded LOD of each,
 * and the fields they need. */
struct frame_want {
    unsigned fields;            /* OCEAN_FIELD_BIT mask of the keys below (all cascades) */
    unsigned cfields[OCEAN_MAX_CASCADES]; /* the same per cascade: what each must be stepped for */
    int nkeys;
    uint16_t keys[LAYER_KEYS_ALL];
    uint8_t lod[LAYER_KEYS_ALL]; /* encoded LOD of keys[i]: layer_key_lod(keys[i]) or coarser */
    uint8_t temporal[LAYER_KEYS_ALL]; /* by key: a temporal client wants it (encode its stream; any cascade) */
    uint8_t intra[LAYER_KEYS_ALL];  /* by key: a client needs intra / keyframe tiles this tick */
    uint16_t tclients[LAYER_KEYS_ALL]; /* by key: temporal clients (saturating) */
    uint16_t iclients[LAYER_KEYS_ALL]; /* by key: clients that take intra tiles every tick (an edge: 65535) */
    uint16_t kclients[LAYER_KEYS_ALL]; /* by key: temporal clients that need this tick's keyframe tiles */
    bool reset_streams;         /* a new sea (N, seed, patch, depth, loop): every temporal layer starts new chains */
    bool sea_changed;           /* the sea's amplitudes changed (same phases): chains go on, oc_stream_sea_changed */
};

/* An empty frame with room for nlayers layers (nlayers = 0 so far), one
 * reference: for frames not encoded here (an edge rebuilds them from the
 * sim's layers, server/roles/role_edge.c). Each layer's buf.data and tile_off
 * must be malloc'd: frame_unref frees them. NULL when out of memory. */
struct frame *frame_new(int nlayers);

/* Bytes of encoded tiles the frame holds (every layer's buffers). */
size_t frame_bytes(const struct frame *f);

void frame_ref(struct frame *f);
void frame_unref(struct frame *f);     /* NULL is fine */
/* The layer for (field, lod, bound) of cascade 0, or NULL if nobody asked for it this tick. */
const struct layer *frame_layer(const struct frame *f, int field, int lod, int bound_index);
/* The same for any cascade. */
const struct layer *frame_layer_cascade(const struct frame *f, int cascade, int field, int lod, int bound_index);

#endif

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
#include "oc_proto.h"
#include "ocean.h"

/* A layer key: one (cascade, field, LOD, bound index) combination.
 * Subscriptions are counted per key (demand); a frame holds one layer per
 * key that had demand when it was built. Cascade 0's keys are
 * 0..LAYER_KEYS-1; cascade c's are c * LAYER_KEYS + the same, up to
 * LAYER_KEYS_ALL - 1 (server/cluster's CL_KEYS, role_link.h). */
#define LAYER_KEYS (OCEAN_FIELD_COUNT * (CTL_MAX_LOD + 1) * CTL_BOUND_COUNT)
#define LAYER_KEYS_ALL (LAYER_KEYS * OCEAN_MAX_CASCADES)
static inline int layer_key(int field, int lod, int bound_index)
{
    return (field * (CTL_MAX_LOD + 1) + lod) * CTL_BOUND_COUNT + bound_index;
}
static inline int layer_key_cascade(int cascade, int field, int lod, int bound_index)
{
    return cascade * LAYER_KEYS + layer_key(field, lod, bound_index);
}
static inline int layer_key_field(int key) { return key % LAYER_KEYS / ((CTL_MAX_LOD + 1) * CTL_BOUND_COUNT); }
static inline int layer_key_lod(int key) { return (key / CTL_BOUND_COUNT) % (CTL_MAX_LOD + 1); }
static inline int layer_key_bound(int key) { return key % CTL_BOUND_COUNT; }
static inline int layer_key_which_cascade(int key) { return key / LAYER_KEYS; }

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

struct layer_streams;

/* One frame being encoded, in three steps, so that the encode runs on a pool
 * of threads while the producer steps the next tick:
 *   frame_job_begin   (producer, after the step) takes the wanted fields out
 *                     of the simulation (ocean_exchange_cascade_field: the next
 *                     step writes into the arrays of the frame before; foam,
 *                     the foam's state, is copied) and
 *                     cuts the work into items: one row of tiles of one layer
 *                     each, so that one layer alone keeps every thread busy
 *                     (a temporal layer's stream is begun here: oc_stream_begin);
 *   frame_job_item    (any encode thread, items in any order, concurrently):
 *                     encodes its row with that thread's encoder (a temporal
 *                     layer: its range of the stream, oc_stream_encode_tiles);
 *                     the thread that finishes a layer's last item assembles
 *                     the layer (rows in order; a temporal stream's end). Jobs
 *                     run one at a time in seq order, so state kept across
 *                     frames (the streams) needs no lock. The bytes do not
 *                     depend on which thread took which item;
 *   frame_job_finish  (the thread that finished the last item) drops the
 *                     layers that failed and returns the frame.
 * A job is reused frame after frame (buffers keep their capacity). */
struct frame_job;
struct frame_job *frame_job_new(int workers);    /* workers + 1 encoders (the caller helps) */
void frame_job_free(struct frame_job *j);
/* hdr gives seq, sim_time, params_version, patch_size; n and tile_size are
 * filled in here (server_time_us at finish). Returns the number of items
 * (0 = nothing to encode), or -1 when out of memory. */
int frame_job_begin(struct frame_job *j, struct ocean *o, int tile_size, const struct frame_want *want,
                    const struct oc_frame_header *hdr);
/* The temporal layers' streams (layer_stream.h) the jobs use, NULL = none: owned by
 * whoever runs frame_job_begin; frame_job_begin prepares them (the previous job must be
 * finished), the items of one job each use their own layer's stream. */
void frame_job_set_streams(struct frame_job *j, struct layer_streams *streams);
void frame_job_item(struct frame_job *j, int item, int worker);
/* The frame (one reference, held by the caller), or NULL when out of memory.
 * A layer that failed to encode is left out (logged). */
struct frame *frame_job_finish(struct frame_job *j);
/* Encode every field the ocean has once with every encoder (start-up: their
 * compressors and scratch grow now, not minutes later under load). */
void frame_job_warm(struct frame_job *j, const struct ocean *o, int tile_size);
/* Samples the last begun job encodes (all its layers, at their encoded LOD). */
long frame_job_samples(const struct frame_job *j);

/* An empty frame with room for nlayers layers (nlayers = 0 so far), one
 * reference: for frames not encoded here (an edge rebuilds them from the
 * sim's layers, server/role_edge.c). Each layer's buf.data and tile_off
 * must be malloc'd: frame_unref frees them. NULL when out of memory. */
struct frame *frame_new(int nlayers);

void frame_ref(struct frame *f);
void frame_unref(struct frame *f);     /* NULL is fine */
/* The layer for (field, lod, bound) of cascade 0, or NULL if nobody asked for it this tick. */
const struct layer *frame_layer(const struct frame *f, int field, int lod, int bound_index);
/* The same for any cascade. */
const struct layer *frame_layer_cascade(const struct frame *f, int cascade, int field, int lod, int bound_index);

#endif

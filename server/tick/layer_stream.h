/* layer_stream.h — temporal layers (codec 3, PROTOCOL.md §5.9): one
 * oc_stream per layer key that a temporal client subscribes to.
 *
 * Owned by the thread that encodes (the tick): each tick, a temporal
 * layer's stream encodes the shared frame of the layer once (predicted
 * tiles and the chains' keyframes) and, when some client needs them, this
 * tick's keyframe tiles; both go into the frame's struct layer, and the lws
 * thread picks per client which one it sends. The work per layer and tick
 * is one shared encode plus at most one keyframe encode, whatever the
 * number of clients. A layer's tiles are encoded by ranges on any threads
 * (layer_temporal_tiles), between one begin and one collect. */
#ifndef OCEAND_LAYER_STREAM_H
#define OCEAND_LAYER_STREAM_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "frame.h"

/* The streams of every layer key (tick only). */
struct layer_streams {
    struct oc_stream *st[LAYER_KEYS_ALL]; /* every cascade's keys; NULL = no temporal client for that key (yet) */
    int n, tile_size;                 /* the grid they were made for; another resets all */
    int keyframe_interval;            /* periodic keyframes, ticks (0 = only when needed) */
    size_t budget;                    /* bytes the streams may keep (encoder state); beyond: intra */
    size_t used;                      /* bytes kept by the streams in st[] */
    int coarse_ticks[LAYER_KEYS_ALL];    /* consecutive ticks the fine grid was the better one */
    float key_rate[LAYER_KEYS_ALL];      /* temporal clients taking keyframe tiles per tick, smoothed */
};

/* Encoder state a stream keeps for a layer of side `side` samples (codes and
 * Laplacians of 5 ticks): about 40 bytes a sample. */
size_t layer_stream_bytes(int side);

void layer_streams_init(struct layer_streams *ls, int keyframe_interval, size_t budget);
/* New chains everywhere: the next tick's shared tiles are keyframes (a change of the sea). */
void layer_streams_reset(struct layer_streams *ls);
/* The sea's amplitudes changed, its phases did not: chains go on (oc_stream_sea_changed). */
void layer_streams_sea_changed(struct layer_streams *ls);
void layer_streams_free(struct layer_streams *ls);

/* Make the streams agree with this tick's wish: free those of keys no
 * temporal client wants, create the wanted ones at grid n / tile_size (a
 * new grid frees them all first). A wanted key (of any cascade) whose stream
 * does not fit the budget (or cannot be allocated) loses its temporal flag in
 * `want` and gets intra tiles instead (want->intra set). Streams are made in
 * key order, so cascade 0's layers come first when the budget runs short.
 * Also picks each stream's grid refinement (docs/codec.md, "Grid refinement"):
 * the fine grid makes the shared tiles ~23 % smaller and the keyframe tiles ~50 %
 * larger. Keyframe takers per tick = clients that are not temporal + the temporal
 * ones short of references (throttled, skipping, joining; smoothed over ~30 ticks);
 * per key, the coarse grid (1) while takers * 6 > the others + 1 (or an edge
 * takes the layer), the fine one once that has not held for 64 ticks (a switch starts
 * new chains). */
void layer_streams_prepare(struct layer_streams *ls, int n, int tile_size, struct frame_want *want);

/* Encode one temporal layer of this tick, in three parts so that the encode
 * pool's threads share a layer (oc_stream_begin / _encode_tiles / _end):
 *   layer_temporal_begin    one thread, before any range (the job's start):
 *                           the stream's counters so far go in *before;
 *   layer_temporal_tiles    any thread, concurrently on disjoint tile ranges
 *                           (tile k = tile_z * tiles_per_side + tile_x), each
 *                           with its own encoder: the shared tiles and, when
 *                           `keyframes`, this tick's keyframe tiles of the range;
 *   layer_temporal_collect  one thread, after every range returned (rc: the
 *                           first range's error, or 0): l->shared +
 *                           l->shared_off + l->need always, l->buf + l->tile_off
 *                           when `keyframes` (field/lod/bound_index/cascade set by
 *                           the caller; the tiles' headers carry l->cascade).
 * Returns 0 or an OC_E_* (the stream is then reset, l holds nothing). */
int layer_temporal_begin(struct oc_stream *st, uint64_t seq, struct oc_stream_stats *before);
int layer_temporal_tiles(struct oc_stream *st, struct oc_encoder *enc, const float *data, bool keyframes,
                         int tiles_per_side, int first, int count);
int layer_temporal_collect(struct oc_stream *st, int rc, bool keyframes, int tiles_per_side,
                           const struct oc_stream_stats *before, struct layer *l);

#endif

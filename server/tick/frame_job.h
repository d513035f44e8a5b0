/* frame_job.h — building a frame: the encode of one tick's wanted layers
 * on the encode pool (the producer begins it, pool threads run its items,
 * the last of them finishes it). */
#ifndef OCEAND_FRAME_JOB_H
#define OCEAND_FRAME_JOB_H

#include "frame.h"

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

#endif

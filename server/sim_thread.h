/* sim_thread.h — the fixed-rate simulation thread and the frames it hands out.
 *
 * Parameter sets are prepared off the tick path by a builder thread (a new
 * ocean for the batch: spectrum, and plans for a new N) and swapped in at
 * the next tick boundary.
 * Data path per tick: swap in prepared parameters -> ocean_step (FFT) ->
 * encode each (field, LOD, bound) layer that some client subscribes to ->
 * publish an immutable, reference-counted struct frame -> lws_cancel_service.
 * The mutex is held only to swap pointers and move queue heads: the network
 * thread never waits for a step or an encode, and the sim never waits for a
 * socket. */
#ifndef OCEAND_SIM_THREAD_H
#define OCEAND_SIM_THREAD_H

#include <cjson/cJSON.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "control.h"
#include "ocean.h"
#include "oc_proto.h"

/* All tiles of one field at one LOD and bound, encoded back to back. */
struct layer {
    uint8_t field, lod, bound_index;
    struct oc_buf buf;
    uint32_t *tile_off;     /* tiles_per_side^2 + 1 offsets into buf; tile i = tz*tps + tx */
};

/* Immutable once published; freed when the last reference goes. */
struct frame {
    atomic_int refs;
    struct oc_frame_header hdr; /* tile_count is per client: set when sending */
    int tiles_per_side;
    int nlayers;
    struct layer *layers;
};
void frame_ref(struct frame *f);
void frame_unref(struct frame *f);
/* The layer for (field, lod, bound), or NULL if nobody asked for it this tick. */
const struct layer *frame_layer(const struct frame *f, int field, int lod, int bound_index);

/* A parameter change accepted by the network thread, waiting for a tick. */
struct sim_set {
    struct sim_set *next;
    struct ocean_params values; /* the network thread's view after this set */
    uint64_t mask;              /* param_table bits this set changes */
    uint64_t origin;            /* session serial of the sender */
    char by[24];                /* its client id */
    cJSON *id;                  /* owned copy of the request id, or NULL */
    /* sim threads only: */
    struct ocean_params prev;   /* the params before this set */
    bool failed;                /* rejected when applied (whole-set check, build error) */
    struct ctl_error err;
};

/* What happened at a tick, for the network thread to broadcast. */
struct sim_event {
    struct sim_event *next;
    bool failed;                /* true: the set was rejected at apply time */
    struct ctl_error err;
    struct ocean_params params; /* in force after the event */
    uint32_t version;
    uint64_t changed;
    uint64_t origin;
    char by[24];
    cJSON *id;                  /* owned */
};
void sim_event_free(struct sim_event *e);

#define SIM_DEMAND_KEYS (OCEAN_FIELD_COUNT * (CTL_MAX_LOD + 1) * CTL_BOUND_COUNT)
static inline int sim_demand_key(int field, int lod, int bound_index)
{
    return (field * (CTL_MAX_LOD + 1) + lod) * CTL_BOUND_COUNT + bound_index;
}

struct sim_config {
    double tick_rate;
    int tile_size;
    struct ocean_options opts;
    double start_time;          /* sim time to resume from */
    int nice;                   /* of the tick thread; 0 = leave as is */
    uint32_t start_version;
    void (*wake)(void *user);   /* called after publishing (lws_cancel_service) */
    void *wake_user;
};

struct sim;
/* Creates the ocean (may take a while at large N) and starts the tick
 * thread and the builder thread (which applies parameter sets off the tick
 * path, see sim_thread.c).
 * The calling thread's signal mask is inherited; main blocks SIGINT/SIGTERM
 * around this call. Returns NULL with err on failure. */
struct sim *sim_start(const struct ocean_params *p, const struct sim_config *cfg, char *err, size_t errlen);
void sim_stop(struct sim *s);

/* Network side. */
void sim_submit(struct sim *s, struct sim_set *set);        /* takes ownership */
struct sim_event *sim_take_events(struct sim *s);            /* list, caller frees each */
struct frame *sim_latest(struct sim *s);                     /* new reference or NULL */
void sim_demand(struct sim *s, int key, int delta);          /* subscriptions in force */
double sim_time_now(struct sim *s);

#endif

/* query_worker.h — point queries and probes off the tick and lws threads.
 *
 * Exact queries (`query`) run on a small pool of query worker threads over
 * ref-counted snapshots of the sea's amplitudes, every cascade's (struct
 * ocean_surface), one per parameter version still inside the time window.
 * Probes (`probe`) are computed once per tick on a worker from a copy of the
 * tick's height/dx/dz grids of every cascade (probe.c). Both answer the sum
 * of the cascades. Results go back to the lws thread through a locked list
 * and a wake-up (lws_cancel_service). docs/threads.md has the contract;
 * docs/query.md the method, limits and figures. */
#ifndef OCEAND_QUERY_WORKER_H
#define OCEAND_QUERY_WORKER_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stdint.h>

#include "control.h"
#include "ocean.h"
#include "query_msg.h"

struct query_config {
    int threads;                /* query worker threads (>= 1) */
    double window;              /* s of sim time before now that `time` may ask for */
    double budget;              /* query points per second, all clients together, counted at N = 256
                                 * (a point costs its modes over those of one cascade at N = 256) */
    int queue;                  /* queries waiting at most; more: busy */
    int probe_max_points;       /* per client */
    int probe_max_total;        /* all clients together */
    void (*wake)(void *user);   /* wake the lws thread (net_wake) */
    void *wake_user;
};

struct query_service;
struct query_service *query_service_new(const struct query_config *c, char *err, size_t errlen);
/* Stops the workers; results not taken are freed. */
void query_service_free(struct query_service *q);

/* ---- the thread that owns struct ocean (tick; builder for a new ocean) ---- */

/* A snapshot for an ocean about to be put in force: made by whoever built
 * it, before it is handed to the tick (NULL on no memory; then queries at
 * its version get `internal`). */
struct ocean_surface *query_snapshot(struct query_service *q, const struct ocean *o);
/* The same for a prepared parameter change (ocean_prepare) of o, before it
 * is committed: the builder thread, which made pr. */
struct ocean_surface *query_snapshot_prepared(struct query_service *q, const struct ocean *o,
                                              const struct ocean_prepared *pr);
/* Parameters version `version` is in force from sim time `since` on.
 * new_physics: it comes with a new ocean whose snapshot is `surface` (owned
 * from now on, may be NULL); else the previous snapshot stays valid. Tick thread. */
void query_version(struct query_service *q, uint32_t version, double since, bool new_physics,
                   struct ocean_surface *surface);
/* Fields the tick must compute for the probes (0 when nobody probes). Tick thread. */
unsigned query_probe_fields(const struct query_service *q);
/* After the step: copy what the probes need (height, dx, dz of every cascade
 * in force) and hand it to a worker. stepped[c]: the fields cascade c was
 * stepped for at this tick (OCEAN_MAX_CASCADES masks): a tick planned before
 * the first probe arrived, whose cascades were not all stepped for the
 * probes' fields, is skipped rather than read stale grids. Tick thread. */
void query_tick(struct query_service *q, const struct ocean *o, const unsigned *stepped, uint64_t seq,
                double sim_time, uint32_t version);

/* ---- lws thread ---- */

/* Queue an exact query for client `serial`; `now` = the current tick's sim
 * time. Returns 0, or -1 with e (bad_query, time_out_of_window, busy, internal). */
int query_submit(struct query_service *q, uint64_t serial, const cJSON *id, const struct query_req *r, double now,
                 struct ctl_error *e);
/* Replace client `serial`'s probe set (n = 0: none). -1 with e: too_many_points, busy. */
int query_probe_set(struct query_service *q, uint64_t serial, const struct probe_req *p, struct ctl_error *e);
/* A client went away. */
void query_client_gone(struct query_service *q, uint64_t serial);

/* What the workers answered: a list to deliver (text: a whole JSON message). */
struct query_out {
    struct query_out *next;
    uint64_t serial;
    bool probe;                 /* probe_data (may be dropped for a slow reader) */
    char *text;
};
struct query_out *query_take_results(struct query_service *q);
void query_out_free(struct query_out *o);

#endif

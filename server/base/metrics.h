/* metrics.h — process-wide counters, rendered as Prometheus text at /metrics.
 * Counters are C11 atomics: the sim thread and the lws thread both update them. */
#ifndef OCEAND_METRICS_H
#define OCEAND_METRICS_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#define METRICS_HIST_BUCKETS 10
struct histogram {
    atomic_uint_least64_t bucket[METRICS_HIST_BUCKETS + 1]; /* last = +Inf */
    atomic_uint_least64_t sum_us, count;
};
extern const double metrics_hist_le[METRICS_HIST_BUCKETS]; /* upper bounds, seconds */

struct metrics {
    struct histogram tick_seconds, encode_seconds, step_seconds;
    atomic_uint_least64_t ticks, overruns, replans;
    atomic_uint_least64_t ticks_late;  /* the overruns where the clock itself woke late (descheduled) */
    atomic_uint_least64_t frames_sent, bytes_sent, text_sent;
    atomic_uint_least64_t dropped_slow, dropped_rate;
    atomic_uint_least64_t control_messages, control_errors, param_changes;
    atomic_uint_least64_t control_units, control_rate_limited, control_busy; /* dispatch_take_token */
    atomic_uint_least64_t rejected_full, rejected_origin, closed_too_large;
    /* refusals and closes of hostile peers (server/net/; docs/reliability.md) */
    atomic_uint_least64_t rejected_host, rejected_handshake, http_refused_host, http_refused_symlink;
    atomic_uint_least64_t closed_output_limit, closed_unmasked, closed_stalled, closed_pinned, refused_fd_limit;
    atomic_int clients;
    atomic_int degraded_groups;       /* subscription groups encoded coarser or less often (capacity.h) */
    atomic_int intra_groups;          /* groups with temporal clients served intra at their LOD (capacity.h plan_intra) */
    atomic_uint_least64_t refused_busy, degraded_sent; /* subscriptions refused `busy`; `degraded` messages sent */
    atomic_uint_least32_t params_version;
    atomic_int resolution;
    _Atomic double sim_time;
    /* point queries and probes (query_worker.c) */
    struct histogram query_seconds, probe_seconds;  /* worker time per query / per probe tick */
    atomic_uint_least64_t queries, query_points, query_busy, probe_ticks, probe_skipped;
    atomic_int probe_points;
    /* exact-time renders (render_worker.c) */
    atomic_uint_least64_t render_frames, render_us, render_cpu_us, render_refused;
    /* temporal layers (codec 3, layer_stream.c, fanout.c) */
    atomic_uint_least64_t stream_key_tiles, stream_predicted_tiles, stream_demand_key_tiles;
    atomic_uint_least64_t sent_shared_tiles, sent_key_tiles, frames_waited_keyframe;
    /* layers (and their samples) per encoded frame (producer.c): all, and those that also carry keyframe tiles */
    atomic_uint_least64_t layers_encoded, layers_keyframed, samples_encoded, samples_keyframed;
    /* per-client ladder (server/net/ladder.c) */
    atomic_uint_least64_t link_sent, rung_changes, frames_caught_up;
    /* floating bodies (server/tick/body_tick.c, server/net/body_net.c) */
    struct histogram body_step_seconds;   /* the producer's bodies step of one tick (requests, physics, snapshot) */
    atomic_int bodies;                    /* bodies in the world */
    atomic_uint_least64_t body_launches;  /* launches accepted */
    atomic_uint_least64_t body_removed[3]; /* bodies gone, by reason: removed, sunk, abandoned */
};
extern struct metrics g_metrics;

void histogram_observe(struct histogram *h, double seconds);
/* Render into buf; returns the length (truncated to cap-1). */
size_t metrics_render(char *buf, size_t cap);

#endif

/* metrics.c — Prometheus text exposition of g_metrics. */
#include "metrics.h"

#include <stdarg.h>
#include <stdio.h>

#include "log.h"

struct metrics g_metrics;
const double metrics_hist_le[METRICS_HIST_BUCKETS] = {
    0.001, 0.002, 0.005, 0.01, 0.02, 0.033, 0.05, 0.1, 0.25, 1.0
};

void histogram_observe(struct histogram *h, double seconds)
{
    int i = 0;
    while (i < METRICS_HIST_BUCKETS && seconds > metrics_hist_le[i])
        i++;
    atomic_fetch_add(&h->bucket[i], 1);
    atomic_fetch_add(&h->sum_us, (uint64_t)(seconds * 1e6));
    atomic_fetch_add(&h->count, 1);
}

struct out { char *buf; size_t cap, len; };

static void put(struct out *o, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(struct out *o, const char *fmt, ...)
{
    if (o->len >= o->cap)
        return;
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(o->buf + o->len, o->cap - o->len, fmt, ap);
    va_end(ap);
    if (n > 0)
        o->len = o->len + (size_t)n < o->cap ? o->len + (size_t)n : o->cap - 1;
}

static void counter(struct out *o, const char *name, const char *help, uint64_t v)
{
    put(o, "# HELP %s %s\n# TYPE %s counter\n%s %llu\n", name, help, name, name, (unsigned long long)v);
}

static void gauge(struct out *o, const char *name, const char *help, double v)
{
    put(o, "# HELP %s %s\n# TYPE %s gauge\n%s %.17g\n", name, help, name, name, v);
}

static void hist(struct out *o, const char *name, const char *help, struct histogram *h)
{
    put(o, "# HELP %s %s\n# TYPE %s histogram\n", name, help, name);
    uint64_t cum = 0;
    for (int i = 0; i < METRICS_HIST_BUCKETS; i++) {
        cum += atomic_load(&h->bucket[i]);
        put(o, "%s_bucket{le=\"%g\"} %llu\n", name, metrics_hist_le[i], (unsigned long long)cum);
    }
    cum += atomic_load(&h->bucket[METRICS_HIST_BUCKETS]);
    put(o, "%s_bucket{le=\"+Inf\"} %llu\n", name, (unsigned long long)cum);
    put(o, "%s_sum %.6f\n%s_count %llu\n", name, (double)atomic_load(&h->sum_us) / 1e6, name,
        (unsigned long long)cum);
}

size_t metrics_render(char *buf, size_t cap)
{
    struct out o = { buf, cap, 0 };
    struct metrics *m = &g_metrics;
    buf[0] = 0;
    hist(&o, "oceand_tick_duration_seconds", "From a tick's deadline to its frame's publication (step, copy, encode).",
         &m->tick_seconds);
    hist(&o, "oceand_step_duration_seconds", "Time to step the simulation for one frame.", &m->step_seconds);
    hist(&o, "oceand_encode_duration_seconds", "Time to encode the layers of one frame (on the encode pool, "
         "while the next frame is stepped).", &m->encode_seconds);
    counter(&o, "oceand_ticks_total", "Simulation ticks run.", atomic_load(&m->ticks));
    counter(&o, "oceand_tick_overruns_total", "Ticks that started a whole period late (skipped, not queued), "
            "or whose frame could not start because the one before was still being stepped.",
            atomic_load(&m->overruns));
    counter(&o, "oceand_tick_late_total", "Of the overruns, the ticks whose clock thread itself woke a whole "
            "period late (the machine did not run it); the rest are frames the producer could not start.",
            atomic_load(&m->ticks_late));
    gauge(&o, "oceand_degraded_groups", "Subscription groups (LOD, bound) encoded at a coarser LOD or a lower "
          "rate than asked, because demand exceeds the encode budget.", atomic_load(&m->degraded_groups));
    gauge(&o, "oceand_intra_groups", "Subscription groups with temporal clients served with the intra codec at "
          "their own LOD (the same detail, more bytes), because the temporal codec does not fit the encode budget.",
          atomic_load(&m->intra_groups));
    counter(&o, "oceand_subscriptions_refused_busy_total", "Subscriptions refused with `busy` (encode budget).",
            atomic_load(&m->refused_busy));
    counter(&o, "oceand_degraded_messages_total", "`degraded` messages sent to clients.", atomic_load(&m->degraded_sent));
    counter(&o, "oceand_link_messages_total", "`link` messages sent to clients (their rung changed).", atomic_load(&m->link_sent));
    counter(&o, "oceand_rung_changes_total", "Changes of a client's rung on its quality ladder.", atomic_load(&m->rung_changes));
    counter(&o, "oceand_frames_caught_up_total",
            "Frames sent to a temporal client behind the newest one, to keep its chain.", atomic_load(&m->frames_caught_up));
    counter(&o, "oceand_replans_total", "FFT re-plans after a resolution change.", atomic_load(&m->replans));
    gauge(&o, "oceand_clients", "Connected WebSocket clients.", atomic_load(&m->clients));
    put(&o, "# HELP oceand_clients_rejected_total WebSocket upgrades refused.\n"
            "# TYPE oceand_clients_rejected_total counter\n"
            "oceand_clients_rejected_total{reason=\"max_clients\"} %llu\n"
            "oceand_clients_rejected_total{reason=\"origin\"} %llu\n",
        (unsigned long long)atomic_load(&m->rejected_full), (unsigned long long)atomic_load(&m->rejected_origin));
    counter(&o, "oceand_frames_sent_total", "Binary frames sent to clients.", atomic_load(&m->frames_sent));
    counter(&o, "oceand_bytes_sent_total", "Bytes of binary frames sent to clients.", atomic_load(&m->bytes_sent));
    counter(&o, "oceand_text_messages_sent_total", "JSON messages sent to clients.", atomic_load(&m->text_sent));
    put(&o, "# HELP oceand_frames_dropped_total Frames a client skipped (latest frame wins).\n"
            "# TYPE oceand_frames_dropped_total counter\n"
            "oceand_frames_dropped_total{reason=\"slow_client\"} %llu\n"
            "oceand_frames_dropped_total{reason=\"max_rate\"} %llu\n",
        (unsigned long long)atomic_load(&m->dropped_slow), (unsigned long long)atomic_load(&m->dropped_rate));
    counter(&o, "oceand_control_messages_total", "JSON control messages received.", atomic_load(&m->control_messages));
    counter(&o, "oceand_control_errors_total", "JSON control messages answered with an error.",
            atomic_load(&m->control_errors));
    counter(&o, "oceand_control_units_total", "Control units charged to accepted messages (1 + 1 per full KiB).",
            atomic_load(&m->control_units));
    put(&o, "# HELP oceand_control_refused_total Control messages dropped unread: the client's own limit "
            "(rate_limited) or the budget of all clients (busy).\n"
            "# TYPE oceand_control_refused_total counter\n"
            "oceand_control_refused_total{reason=\"rate_limited\"} %llu\n"
            "oceand_control_refused_total{reason=\"busy\"} %llu\n",
        (unsigned long long)atomic_load(&m->control_rate_limited), (unsigned long long)atomic_load(&m->control_busy));
    counter(&o, "oceand_param_changes_total", "Parameter sets applied.", atomic_load(&m->param_changes));
    counter(&o, "oceand_closed_too_large_total", "Clients closed with 1009 (message too large).",
            atomic_load(&m->closed_too_large));
    hist(&o, "oceand_query_duration_seconds", "Worker time of one exact point query.", &m->query_seconds);
    hist(&o, "oceand_probe_tick_duration_seconds", "Worker time to evaluate every probe of one tick.",
         &m->probe_seconds);
    counter(&o, "oceand_queries_total", "Point queries accepted.", atomic_load(&m->queries));
    counter(&o, "oceand_query_points_total", "Points of the accepted queries.", atomic_load(&m->query_points));
    counter(&o, "oceand_query_busy_total", "Queries and probes refused with busy (budget, queue).",
            atomic_load(&m->query_busy));
    counter(&o, "oceand_probe_ticks_total", "Ticks whose probes were evaluated.", atomic_load(&m->probe_ticks));
    counter(&o, "oceand_probe_ticks_skipped_total", "Ticks whose probes were skipped (worker behind).",
            atomic_load(&m->probe_skipped));
    gauge(&o, "oceand_probe_points", "Points probed by all clients.", atomic_load(&m->probe_points));
    counter(&o, "oceand_render_frames_total", "Frames rendered for `render` requests.",
            atomic_load(&m->render_frames));
    put(&o, "# HELP oceand_render_seconds_total Render worker time (step and encode) of those frames.\n"
            "# TYPE oceand_render_seconds_total counter\noceand_render_seconds_total %.6f\n",
        (double)atomic_load(&m->render_us) / 1e6);
    put(&o, "# HELP oceand_render_cpu_seconds_total CPU time of the render workers for those frames.\n"
            "# TYPE oceand_render_cpu_seconds_total counter\noceand_render_cpu_seconds_total %.6f\n",
        (double)atomic_load(&m->render_cpu_us) / 1e6);
    counter(&o, "oceand_render_refused_total", "Renders refused with busy or over --render-max-units.",
            atomic_load(&m->render_refused));
    put(&o, "# HELP oceand_clients_refused_total WebSocket upgrades refused before a session.\n"
            "# TYPE oceand_clients_refused_total counter\n"
            "oceand_clients_refused_total{reason=\"host\"} %llu\n"
            "oceand_clients_refused_total{reason=\"handshake\"} %llu\n",
        (unsigned long long)atomic_load(&m->rejected_host), (unsigned long long)atomic_load(&m->rejected_handshake));
    put(&o, "# HELP oceand_http_refused_total HTTP requests refused: unknown Host (421), symlink in the web root (404).\n"
            "# TYPE oceand_http_refused_total counter\n"
            "oceand_http_refused_total{reason=\"host\"} %llu\n"
            "oceand_http_refused_total{reason=\"symlink\"} %llu\n",
        (unsigned long long)atomic_load(&m->http_refused_host), (unsigned long long)atomic_load(&m->http_refused_symlink));
    put(&o, "# HELP oceand_clients_closed_total Clients closed by the daemon: reply queue over --output-limit-kb (1008), "
            "unmasked frame (1002), no byte of its frame taken for --idle-timeout (stalled, 1008), holding the "
            "oldest frame when the frames held by slow clients pass their budget (pinned, 1008).\n"
            "# TYPE oceand_clients_closed_total counter\n"
            "oceand_clients_closed_total{reason=\"output_limit\"} %llu\n"
            "oceand_clients_closed_total{reason=\"unmasked\"} %llu\n"
            "oceand_clients_closed_total{reason=\"stalled\"} %llu\n"
            "oceand_clients_closed_total{reason=\"pinned\"} %llu\n",
        (unsigned long long)atomic_load(&m->closed_output_limit), (unsigned long long)atomic_load(&m->closed_unmasked),
        (unsigned long long)atomic_load(&m->closed_stalled), (unsigned long long)atomic_load(&m->closed_pinned));
    counter(&o, "oceand_connections_refused_total", "TCP connections closed at accept to keep a reserve of file "
            "descriptors (RLIMIT_NOFILE).", atomic_load(&m->refused_fd_limit));
    put(&o, "# HELP oceand_stream_tiles_total Tiles encoded by the temporal layers (codec 3): shared tiles "
            "predicted or keyframes (periodic, new grid, after a gap), and keyframe tiles made on demand for clients "
            "without the references.\n"
            "# TYPE oceand_stream_tiles_total counter\n"
            "oceand_stream_tiles_total{kind=\"predicted\"} %llu\n"
            "oceand_stream_tiles_total{kind=\"key\"} %llu\n"
            "oceand_stream_tiles_total{kind=\"demand_key\"} %llu\n",
        (unsigned long long)atomic_load(&m->stream_predicted_tiles), (unsigned long long)atomic_load(&m->stream_key_tiles),
        (unsigned long long)atomic_load(&m->stream_demand_key_tiles));
    put(&o, "# HELP oceand_temporal_tiles_sent_total Tiles of temporal layers sent to temporal clients: the shared "
            "tiles, or this tick's keyframe tiles (joined, resubscribed, skipped a frame, max_rate).\n"
            "# TYPE oceand_temporal_tiles_sent_total counter\n"
            "oceand_temporal_tiles_sent_total{kind=\"shared\"} %llu\n"
            "oceand_temporal_tiles_sent_total{kind=\"key\"} %llu\n",
        (unsigned long long)atomic_load(&m->sent_shared_tiles), (unsigned long long)atomic_load(&m->sent_key_tiles));
    put(&o, "# HELP oceand_layers_encoded_total Layers encoded, summed over the frames (one per field, LOD, bound "
            "and cascade subscribed by someone, per frame; clients on the same ladder rung share them): all, and "
            "those that also encoded keyframe or intra tiles (a client needed them that tick).\n"
            "# TYPE oceand_layers_encoded_total counter\n"
            "oceand_layers_encoded_total{kind=\"all\"} %llu\n"
            "oceand_layers_encoded_total{kind=\"keyframe\"} %llu\n",
        (unsigned long long)atomic_load(&m->layers_encoded), (unsigned long long)atomic_load(&m->layers_keyframed));
    put(&o, "# HELP oceand_samples_encoded_total Samples of those layers (N / 2^lod squared each): all, and those "
            "of the layers that also encoded keyframe or intra tiles.\n"
            "# TYPE oceand_samples_encoded_total counter\n"
            "oceand_samples_encoded_total{kind=\"all\"} %llu\n"
            "oceand_samples_encoded_total{kind=\"keyframe\"} %llu\n",
        (unsigned long long)atomic_load(&m->samples_encoded), (unsigned long long)atomic_load(&m->samples_keyframed));
    counter(&o, "oceand_frames_waited_keyframe_total", "Frames a temporal client was not sent because it lacked "
            "their references and they carried no keyframe tiles (it gets the next one).",
            atomic_load(&m->frames_waited_keyframe));
    put(&o, "# HELP oceand_log_lines_dropped_total Log lines not written: over 10 a second (rate), or stderr full "
            "(blocked).\n"
            "# TYPE oceand_log_lines_dropped_total counter\n"
            "oceand_log_lines_dropped_total{reason=\"rate\"} %llu\n"
            "oceand_log_lines_dropped_total{reason=\"blocked\"} %llu\n",
        log_dropped(false), log_dropped(true));
    gauge(&o, "oceand_bodies", "Floating bodies in the world.", atomic_load(&m->bodies));
    counter(&o, "oceand_body_launches_total", "Bodies launched.", atomic_load(&m->body_launches));
    put(&o, "# HELP oceand_body_removals_total Bodies that left the world: removed by their owner, sunk, or "
            "abandoned (the owner gone for twice --body-grace).\n"
            "# TYPE oceand_body_removals_total counter\n"
            "oceand_body_removals_total{reason=\"removed\"} %llu\n"
            "oceand_body_removals_total{reason=\"sunk\"} %llu\n"
            "oceand_body_removals_total{reason=\"abandoned\"} %llu\n",
        (unsigned long long)atomic_load(&m->body_removed[0]), (unsigned long long)atomic_load(&m->body_removed[1]),
        (unsigned long long)atomic_load(&m->body_removed[2]));
    hist(&o, "oceand_body_step_duration_seconds", "The bodies step of one tick on the producer (requests, "
         "physics on the tick's grids, the BODY section).", &m->body_step_seconds);
    gauge(&o, "oceand_params_version", "Current parameter version.", atomic_load(&m->params_version));
    gauge(&o, "oceand_resolution", "Current simulation resolution N.", atomic_load(&m->resolution));
    gauge(&o, "oceand_sim_time_seconds", "Current simulation time.", atomic_load(&m->sim_time));
    return o.len;
}

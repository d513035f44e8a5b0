/* config.h — the one place that reads configuration.
 *
 * Precedence, lowest first: built-in defaults <- saved state file <-
 * --config FILE (JSON) <- command-line flags. Sea parameters come from the
 * params table (server/sim/include/params.h); daemon options from the table
 * of the same shape in config.c, checked by the same setters. Both are accepted in the config file and as flags, e.g.
 * --wind-speed 20 or --wind_speed=20, --port 9000. */
#ifndef OCEAND_CONFIG_H
#define OCEAND_CONFIG_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "params.h"

struct daemon_config {
    int    port;
    char   bind[64];
    char   web_root[512];
    double tick_rate;
    int    log_level;          /* enum log_level (an ENUM setting: stored as int) */
    char   state_file[512];    /* "" = do not save state */
    char   config_file[512];
    int    max_clients;
    int    max_message;        /* bytes of one JSON text message */
    double control_rate;       /* control units per second per client (a unit: a message, + 1 per KiB) */
    int    control_burst;
    double control_budget;     /* control units per second, all clients together */
    int    ping_interval;      /* s of silence before we ping */
    int    idle_timeout;       /* s of silence before we hang up */
    char   allowed_origins[512]; /* "" = same host or no Origin; "*" = any; else comma list */
    char   control_token[128];   /* "" = everyone may set */
    int    fft_threads;
    int    encode_threads;     /* frame encoders (pool), 0 = one per core (resolved by config_load) */
    int    encode_budget;      /* samples encoded per tick at most; 0 = derived from the measured tick */
    int    temporal_budget;    /* samples per tick at most with the temporal codec; 0 = derived only */
    int    plan_rigor;
    char   wisdom_file[512];
    int    max_memory_mb;
    int    tile_size;
    int    keyframe_interval;  /* temporal layers: periodic keyframe every this many ticks (0 = none) */
    int    ease_ticks;         /* amplitude-only changes ease in over this many ticks (0 = at once) */
    int    send_buffer_kb;     /* SO_SNDBUF per client: bounds the frames queued in the kernel */
    int    sim_nice;           /* nice value of the tick thread (< 0 needs CAP_SYS_NICE) */
    char   tls_cert[512];      /* PEM certificate (chain): "" = plain http/ws */
    char   tls_key[512];       /* PEM private key of tls_cert */
    /* point queries and probes (query_worker.h, docs/query.md) */
    int    query_threads;      /* query worker threads */
    double query_window;       /* s of sim time a query's "time" may go back */
    double query_budget;       /* query points per second for all clients (at N = 256) */
    int    query_queue;        /* queries waiting at most */
    int    probe_max_points;   /* probe points per client */
    int    probe_max_total;    /* probe points, all clients */
    /* exact-time renders (render_worker.h, PROTOCOL.md §7.5) */
    int    render_workers;     /* render threads: renders that run at once */
    double render_budget;      /* render units per second, all renders together */
    double render_max_units;   /* units accepted and not yet rendered; more: busy */
    int    render_nice;        /* nice value of the render threads */
    /* Cluster (docs/scaling.md): --role all needs none of these. */
    char   role[8];            /* "all", "sim" or "edge" */
    char   nats_url[512];      /* --nats: nats://HOST:4222 (comma-separated list allowed) */
    char   nats_prefix[72];    /* subject prefix: several seas share one NATS */
    char   nats_name[64];      /* this daemon's name on NATS ("" = <role>-<host>-<pid>) */
    char   nats_creds[512];    /* JWT + NKey seed file */
    char   nats_tls_ca[512];   /* trust these CAs (implies TLS) */
    char   nats_tls_cert[512]; /* client certificate ... */
    char   nats_tls_key[512];  /* ... and its key */
    char   server_name[512];   /* extra Host names accepted (comma list); "*" = any Host */
    int    output_limit_kb;    /* JSON replies queued per client (KiB) before it is closed */
    /* floating bodies (PROTOCOL.md §7.6) */
    int    bodies_per_session; /* bodies one session may own at once */
    int    max_bodies;         /* bodies in the world at once */
    double launch_rate;        /* launches per minute per session */
    double body_grace;         /* s an owner may be gone before its body drifts unpowered (and as long again: removed) */
};

/* What config_load found besides the values. */
struct config_result {
    bool help;                 /* --help was given: usage printed, exit 0 */
    bool state_loaded;
    uint32_t params_version;   /* from the state file, else 0 */
    double sim_time;           /* from the state file, else 0 */
};

/* Fill *dc and *p. Returns 0, or -1 with a message in err. */
int config_load(int argc, char **argv, struct daemon_config *dc, struct ocean_params *p,
                struct config_result *res, char *err, size_t errlen);
/* Apply the text of a config file (one JSON object) onto *dc and *p, all or
 * nothing, then check the whole parameter set. Returns 0, or -1 with a
 * message in err and nothing changed. (config_load uses the same path.) */
int config_apply_text(struct daemon_config *dc, struct ocean_params *p, const char *text, size_t len,
                      char *err, size_t errlen);
void config_usage(FILE *out, const char *argv0);
/* The default --max-memory-mb: a quarter of MemTotal or of the cgroup's
 * memory limit, whichever is lower, at least 256. */
int config_default_memory_mb(void);

#endif

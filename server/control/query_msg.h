/* query_msg.h — the JSON of point queries and probe subscriptions
 * (proto/PROTOCOL.md §7.4): parse and validate `query` and `probe`, build
 * `query_result` and `probe_data`. Pure like control.c (no threads, no
 * globals), so it is unit-tested and fuzzed on its own. */
#ifndef OCEAND_QUERY_MSG_H
#define OCEAND_QUERY_MSG_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stdint.h>

#include "control.h"
#include "ocean.h"

#define QUERY_MAX_POINTS 256   /* points of one `query` */
#define PROBE_MAX_POINTS 64    /* points of one client's `probe` subscription (hard ceiling) */

/* A parsed `query`. */
struct query_req {
    int n;                                 /* 1..QUERY_MAX_POINTS */
    double xz[QUERY_MAX_POINTS][2];        /* world (x, z), m: any finite values */
    bool has_time;                         /* "time" given; else the current tick */
    double time;                           /* s of sim time, finite */
};

/* A parsed `probe` (n = 0: unsubscribe). */
struct probe_req {
    int n;                                 /* 0..max_points */
    double xz[PROBE_MAX_POINTS][2];
};

/* Errors, code first: bad_query (wrong types, NaN/Inf, empty), too_many_points.
 * max_points caps the probe's points (the server's --probe-max-points). */
int query_parse(const cJSON *root, struct query_req *q, struct ctl_error *e);
int probe_parse(const cJSON *root, int max_points, struct probe_req *p, struct ctl_error *e);

/* `query_result`: one object per point (struct ocean_point). */
cJSON *query_result_msg(const cJSON *id, double sim_time, uint32_t params_version, int n,
                        const struct ocean_point *pts);

/* One probe value (the cheap path, probe.c). */
struct probe_value {
    double height, dx, dz, normal[3], vertical_velocity, vertical_acceleration;
};
/* `probe_data` for one tick: "points":[[h, dx, dz, nx, ny, nz, vv, va], ...]. */
char *probe_data_text(uint64_t seq, double sim_time, uint32_t params_version, int n, const struct probe_value *v);

/* `probing`: the probe subscription now in force. */
cJSON *probing_msg(const cJSON *id, int n, const double (*xz)[2]);

#endif

/* render_msg.h — the JSON of exact-time renders (proto/PROTOCOL.md §7.5):
 * parse and validate `render`, build `rendering` and `rendered`. Pure like
 * control.c (no threads, no globals), so it is unit-tested and fuzzed with
 * the other control messages. */
#ifndef OCEAND_RENDER_MSG_H
#define OCEAND_RENDER_MSG_H

#include <cjson/cJSON.h>
#include <stdint.h>

#include "control.h"

#define RENDER_MAX_FRAMES 100000   /* frames of one render */
#define RENDER_MAX_FPS 1000.0      /* frames per second of sim time, at most */
#define RENDER_FRAME_FLAG 1u       /* frame header flags bit 0: a rendered frame, not a live tick */

/* A parsed `render`: frame k (0 <= k < frames) shows sim time
 * render_time(r, k) = start + k / fps, of the layers `sub` names (fields,
 * lod, field_lod, bound, cascades, tiles; never temporal). */
struct render_req {
    double start;                  /* s of sim time, 0 <= start */
    double fps;                    /* 0 < fps <= RENDER_MAX_FPS */
    long frames;                   /* 1..RENDER_MAX_FRAMES; start + (frames - 1) / fps <= OCEAN_TIME_MAX */
    struct subscription sub;       /* what each frame carries (max_rate, temporal, adapt unused) */
};

static inline double render_time(const struct render_req *r, long k) { return r->start + (double)k / r->fps; }

/* Errors: bad_render (a member missing, ill-typed or out of range; what
 * subscribe would refuse, with this code). */
int render_parse(const cJSON *root, const struct ctl_limits *lim, struct render_req *r, struct ctl_error *e);

/* Units of render work one frame of r costs at resolution n with `cascades`
 * in force: one unit = one field of one cascade stepped at N = 256. */
double render_frame_units(const struct render_req *r, int n, int cascades);

/* {"type":"rendering","id":..,"frames":K,"start":T,"fps":F,"params_version":V,"n":N,"cascades":C,"units":U} */
cJSON *render_rendering_msg(const cJSON *id, const struct render_req *r, uint32_t params_version, int n,
                            int cascades, double units);
/* {"type":"rendered","id":..,"frames":k}: the render ended after k frames (all, or fewer when cancelled). */
cJSON *render_rendered_msg(const cJSON *id, long frames, const char *reason);

#endif

/* tap_bake.c — the sum of the cascades on a grid (--sum) and Blender bakes
 * (--format exr, from the stream or from --bake's render request). */
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tap.h"


struct sum_grid sum_geometry(const struct session *s, const struct job *j)
{
    int side = 0;
    float b;
    job_field(j, 0, OC_FIELD_HEIGHT, &side, &b);
    if (!side) side = j->fh.n >> s->o->lod;
    struct sum_grid g = {s->o->sum_m > 0 ? s->o->sum_m : side, 0, 0, j->fh.patch_size};
    if (s->o->has_area) { g.x0 = s->o->area[0]; g.z0 = s->o->area[1]; g.size = s->o->area[2]; }
    return g;
}

/* Field f summed over the received cascades (or cascade 0 alone: only0) on
 * the sum grid, into out (m*m floats). Returns 0, 1 when a cascade lacks the
 * field, -1 on failure. */
int sum_field(struct session *s, const struct job *j, const struct sum_grid *sg, enum oc_field f,
                     int only0, float *out, float *bound)
{
    struct tap_cascade_grid g[OC_MAX_CASCADES];
    int nc = only0 ? 1 : j->ncasc;
    *bound = 0;
    for (int c = 0; c < nc; c++) {
        float b = 0;
        g[c].data = job_field(j, c, f, &g[c].side, &b);
        g[c].period = c == 0 ? j->fh.patch_size : j->patch[c];
        if (!g[c].data) return 1;
        if (!(g[c].period > 0)) {
            wfail(s, EXIT_PROTOCOL, "the server did not say the patch size of cascade %d", c);
            return -1;
        }
        *bound += b;
    }
    if (!s->wr.surface && !(s->wr.surface = tap_surface_new())) { wfail(s, EXIT_OUTPUT, "out of memory"); return -1; }
    if (tap_surface_grid(s->wr.surface, g, nc, sg->m, sg->x0, sg->z0, sg->size, s->o->bilinear, out) != 0) {
        wfail(s, EXIT_OUTPUT, "out of memory for the %dx%d sum", sg->m, sg->m);
        return -1;
    }
    return 0;
}

/* Room for count fields on the m x m sum grid, kept from frame to frame. */
float *sum_buffers(struct session *s, int m, int count)
{
    size_t bytes = (size_t)count * m * m * sizeof(float);
    if (bytes <= s->wr.sum_bytes) return s->wr.sum_buf;
    free(s->wr.sum_buf);
    s->wr.sum_buf = malloc(bytes);
    s->wr.sum_bytes = s->wr.sum_buf ? bytes : 0;
    if (!s->wr.sum_buf) wfail(s, EXIT_OUTPUT, "out of memory for the %dx%d sum", m, m);
    return s->wr.sum_buf;
}

/* --format exr: one Blender bake frame (tap_exr.h) from the six fields: cascade
 * 0's grids, or with --cascades the sum of the cascades on the --sum grid. */
int write_bake(struct session *s, const struct job *j)
{
    const struct oc_frame_header *fh = &j->fh;
    const float *f[OC_FIELD_COUNT];
    int side = 0;
    float bound = 0, b;
    double x0 = 0, z0 = 0, size = fh->patch_size;
    if (s->o->sum_m) {
        struct sum_grid sg = sum_geometry(s, j);
        float *buf = sum_buffers(s, sg.m, 6);
        if (!buf) return -1;
        static const enum oc_field order[6] = {OC_FIELD_HEIGHT, OC_FIELD_DX, OC_FIELD_DZ, OC_FIELD_SLOPE_X,
                                               OC_FIELD_SLOPE_Z, OC_FIELD_JACOBIAN};
        for (int k = 0; k < 6; k++) {
            float *out = buf + (size_t)k * sg.m * sg.m;
            /* The Jacobian does not add across cascades (§4.1): cascade 0's, for the foam. */
            if (sum_field(s, j, &sg, order[k], order[k] == OC_FIELD_JACOBIAN, out, &b) != 0) {
                wfail(s, EXIT_PROTOCOL, "the frame lacks %s", oc_field_name(order[k]));
                return -1;
            }
            f[order[k]] = out;
            bound = b > bound ? b : bound;
        }
        side = sg.m;
        x0 = sg.x0;
        z0 = sg.z0;
        size = sg.size;
    } else {
        for (int i = 0; i < OC_FIELD_COUNT; i++) {
            f[i] = job_field(j, 0, i, &side, &b);
            bound = b > bound ? b : bound;
        }
    }
    struct tap_exr_fields ef = {f[OC_FIELD_HEIGHT], f[OC_FIELD_DX], f[OC_FIELD_DZ],
                                f[OC_FIELD_SLOPE_X], f[OC_FIELD_SLOPE_Z], f[OC_FIELD_JACOBIAN]};
    struct tap_meta m = {.field = "bake", .seq = fh->seq, .sim_time = fh->sim_time,
                         .params_version = fh->params_version, .n = fh->n, .lod = s->o->lod,
                         .patch_size = (float)size, .bound = bound, .server_time_us = fh->server_time_us,
                         .cascade = s->o->sum_m ? TAP_CASCADE_SUM : 0, .origin_x = x0, .origin_z = z0};
    char err[512];
    if (tap_exr_bake(s->o->out_dir, (int)j->number, side, &ef, &m, j->ncasc, err, sizeof err) != 0) {
        wfail(s, EXIT_OUTPUT, "cannot write the bake: %s", err);
        return -1;
    }
    return 0;
}

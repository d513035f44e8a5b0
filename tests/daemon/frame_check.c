/* frame_check — decode oceand binary frames and compare them with what the
 * simulation library computes directly for the same parameters and time.
 *
 *   frame_check PARAMS.json FRAME.bin...
 * PARAMS.json: a params object, or a hello/params message holding one.
 * For every tile sample: |decoded - direct| <= bound (bound 0: bit-exact).
 * Prints one JSON line per frame; exits 1 on any mismatch or decode error. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "control.h"
#include "oc_proto.h"
#include "ocean.h"

#include "../common/slurp.h"

struct check {
    struct ocean *o;
    long samples, bad;
    double max_err, max_excess;
    int n;
};

static int on_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th, const float *v)
{
    struct check *c = user;
    const float *ref = ocean_field(c->o, (enum ocean_field)th->field);
    if (!ref)
        return -1;
    int step = 1 << th->lod;
    for (int j = 0; j < th->height; j++)
        for (int i = 0; i < th->width; i++) {
            int ix = th->tile_x * fh->tile_size + i * step, iz = th->tile_z * fh->tile_size + j * step;
            double want = ref[iz * c->n + ix], got = v[j * th->width + i];
            double err = fabs(got - want);
            c->samples++;
            if (err > c->max_err)
                c->max_err = err;
            bool ok = th->bound > 0 ? err <= (double)th->bound * (1 + 1e-6) : memcmp(&v[j * th->width + i], &ref[iz * c->n + ix], 4) == 0;
            if (!ok) {
                if (c->bad < 5)
                    fprintf(stderr, "frame_check: %s tile (%d,%d) lod %d sample (%d,%d): got %.9g want %.9g (bound %g)\n",
                            oc_field_name((enum oc_field)th->field), th->tile_x, th->tile_z, th->lod, ix, iz, got, want,
                            (double)th->bound);
                c->bad++;
            }
        }
    return 0;
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: frame_check PARAMS.json FRAME.bin...\n");
        return 2;
    }
    size_t len;
    char *text = slurp(argv[1], &len);
    cJSON *root = text ? cJSON_ParseWithLength(text, len) : NULL;
    free(text);
    const cJSON *obj = cJSON_GetObjectItemCaseSensitive(root, "params");
    if (!obj)
        obj = root;
    struct ocean_params defs, p;
    params_defaults(&defs);
    struct ctl_error e;
    if (control_apply_params(obj, &defs, NULL, &p, NULL, &e) != 0) {
        fprintf(stderr, "frame_check: %s: %s\n", argv[1], root ? e.message : "cannot read JSON");
        return 2;
    }
    cJSON_Delete(root);
    char err[200];
    struct ocean_options opt = { .threads = 1, .wisdom_path = NULL, .plan_rigor = 0 };
    struct ocean *o = ocean_create(&p, &opt, err, sizeof err);
    if (!o) {
        fprintf(stderr, "frame_check: ocean_create: %s\n", err);
        return 2;
    }
    struct oc_decoder *d = oc_decoder_new();
    int failed = 0;
    for (int a = 2; a < argc; a++) {
        char *data = slurp(argv[a], &len);
        struct oc_frame_header fh;
        if (!data || oc_frame_header_read((const uint8_t *)data, len, &fh) != 0) {
            fprintf(stderr, "frame_check: %s: cannot read frame header\n", argv[a]);
            failed = 1;
            free(data);
            continue;
        }
        struct check c = { .o = o, .n = fh.n };
        if (fh.n != p.resolution) {
            fprintf(stderr, "frame_check: %s: n=%d but params say %d\n", argv[a], fh.n, p.resolution);
            failed = 1;
        } else {
            ocean_step(o, fh.sim_time, OCEAN_ALL_FIELDS);
            int rc = oc_decode_frame(d, (const uint8_t *)data, len, &fh, on_tile, &c);
            if (rc != 0) {
                fprintf(stderr, "frame_check: %s: %s\n", argv[a], oc_strerror(rc));
                failed = 1;
            }
            if (c.bad || c.samples == 0)
                failed = 1;
        }
        printf("{\"file\":\"%s\",\"seq\":%llu,\"sim_time\":%.17g,\"n\":%d,\"tiles\":%d,\"samples\":%ld,\"bad\":%ld,\"max_err\":%.9g}\n",
               argv[a], (unsigned long long)fh.seq, fh.sim_time, fh.n, fh.tile_count, c.samples, c.bad, c.max_err);
        free(data);
    }
    oc_decoder_free(d);
    ocean_free(o);
    return failed;
}

/* load_bytes — the bytes per frame a temporal client keeping up receives for the
 * default layers (height, dx, dz; N = 256, 128-sample tiles, 30 Hz, t from 10 s),
 * encoded by oc_stream exactly as the daemon's shared frames, decoded by one
 * oc_decoder (max error and RMS error / bound against the simulation), with a
 * parameter change every PERIOD ticks as bench/load_client.c sends (wind 11 <-> 12):
 *   POLICY 0: no changes; 1: each change resets the streams (new chains);
 *          2: changes ignored by the encoder; 3: oc_stream_sea_changed (the daemon's).
 * The measurements of docs/codec.md ("Grid refinement", "Changes of the sea").
 *   cc -O2 -std=c11 -D_GNU_SOURCE -Iproto/c -Iserver/sim/include -o build/load_bytes bench/load_bytes.c \
 *      build/liboc_proto.a build/libocean.a -lfftw3f -lfftw3f_threads -lzstd -lz -ldeflate -lm -pthread
 *   [REFINE=r] [BOUND=b] [TILE=t] [KEY=1] [V=1] build/load_bytes POLICY [PERIOD [TICKS [PARAM A B]]]
 * KEY=1 also encodes every tick's keyframe tiles (what a joining/skipping client gets).
 * EASE=K eases each change in over K ticks (ocean_commit_eased, the daemon's --ease-ticks). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "oc_proto.h"
#include "ocean.h"
#include "params.h"

#include "bench_time.h"
static int cb(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th, const float *s)
{
    float *d = user; int n = fh->n;
    for (int j = 0; j < th->height; j++)
        memcpy(d + (size_t)(th->tile_z * fh->tile_size + j) * n + th->tile_x * fh->tile_size, s + (size_t)j * th->width, sizeof(float) * th->width);
    return 0;
}
int main(int argc, char **argv)
{
    int policy = atoi(argv[1]), period = argc > 2 ? atoi(argv[2]) : 10, T = argc > 3 ? atoi(argv[3]) : 300;
    int n = 256, tile = getenv("TILE") ? atoi(getenv("TILE")) : 128, grid = 256 / tile; float bound = getenv("BOUND") ? atof(getenv("BOUND")) : 0.01f;
    const char *param = argc > 4 ? argv[4] : "wind_speed";
    double va = argc > 5 ? atof(argv[5]) : 11, vb = argc > 6 ? atof(argv[6]) : 12;
    struct ocean_params prm; params_defaults(&prm); prm.resolution = n;
    struct ocean_options opt = { .threads = 1 };
    char err[256];
    struct ocean *o = ocean_create(&prm, &opt, err, sizeof err);
    struct oc_encoder *e = oc_encoder_new();
    struct oc_stream *st[3]; struct oc_decoder *dec[3]; float *df[3];
    for (int f = 0; f < 3; f++) { st[f] = oc_stream_new(n, tile, 0, f, bound); if (getenv("REFINE")) oc_stream_set_grid_refine(st[f], atoi(getenv("REFINE"))); dec[f] = oc_decoder_new(); df[f] = malloc(4 * n * n); }
    struct oc_buf buf = { 0 };
    double tenc = 0, tchg = 0, kbytes = 0, bytes = 0, fb[3] = { 0 }, maxerr = 0, se = 0, ne = 0; int nsets = 0; long keys = 0;
    const struct param_def *pd = param_find(param);
    for (int tick = 0; tick < T; tick++) {
        int change = policy > 0 && tick > 0 && tick % period == 0;
        if (change) {
            param_set(&prm, pd, (nsets++ % 2) ? vb : va, err, sizeof err);
            /* EASE=K: ease the change in over K ticks from the previous tick, as the daemon (--ease-ticks) */
            struct ocean_prepared *pr = ocean_prepare(o, &prm, err, sizeof err);
            double dt = 1 / 30.0, ease = getenv("EASE") ? atof(getenv("EASE")) : 0;
            if (!pr || ocean_commit_eased(o, pr, 10.0 + tick / 30.0 - dt, ease * dt)) { fprintf(stderr, "%s\n", err); return 1; }
            ocean_prepared_free(pr);
        }
        if (ocean_step(o, 10.0 + tick / 30.0, 7)) return 1;
        double fr = 48;
        for (int f = 0; f < 3; f++) {
            if (change && policy == 1) oc_stream_reset(st[f]);
            if (change && policy == 3) oc_stream_sea_changed(st[f]);
            const float *field = ocean_field(o, f);
            struct oc_frame_header fh = { .seq = 1000 + (uint64_t)tick, .n = n, .tile_size = tile, .patch_size = 256, .tile_count = (uint16_t)(grid * grid) };
            double t0 = thread_cpu_s(); if (oc_stream_encode(st[f], e, field, fh.seq)) abort(); tenc += thread_cpu_s() - t0; if (change) tchg += thread_cpu_s() - t0;
            buf.len = 0; oc_buf_reserve(&buf, 48); oc_frame_header_write(buf.data, &fh); buf.len = 48;
            for (int tz = 0; tz < grid; tz++) for (int tx = 0; tx < grid; tx++) {
                const uint8_t *p; size_t len; oc_stream_tile(st[f], tx, tz, &p, &len);
                if (p[2] != 3) keys++;
                oc_buf_reserve(&buf, len); memcpy(buf.data + buf.len, p, len); buf.len += len;
            }
            if (getenv("KEY")) for (int tz = 0; tz < grid; tz++) for (int tx = 0; tx < grid; tx++) {
                const uint8_t *p; size_t len; oc_stream_keyframe_tile(st[f], e, tx, tz, &p, &len); kbytes += len;
            }
            struct oc_frame_header out;
            int rc = oc_decode_frame(dec[f], buf.data, buf.len, &out, cb, df[f]);
            if (rc) { fprintf(stderr, "decode %s\n", oc_strerror(rc)); return 1; }
            for (int i = 0; i < n * n; i++) { double d = (double)df[f][i] - field[i]; maxerr = fmax(maxerr, fabs(d)); se += d * d; ne++; }
            fr += buf.len - 48; fb[f] += buf.len - 48;
        }
        bytes += fr;
        if (getenv("V")) printf("tick %d %s %.0f\n", tick, change ? "*" : " ", fr);
    }
    printf("policy %d period %d: %.0f B/frame (%.3f MB/s) h %.0f dx %.0f dz %.0f key tiles %ld max_err %.6f rms/b %.3f %s\n", policy, period,
           bytes / T, bytes / T * 30 / 1e6, fb[0] / T, fb[1] / T, fb[2] / T, keys, maxerr, sqrt(se / ne) / bound, maxerr <= bound ? "ok" : "BOUND!");
    printf("  enc ms/tick %.3f (change ticks %.3f) MB/s %.0f\n", 1e3 * tenc / T, nsets ? 1e3 * tchg / nsets : 0, 3 * 4.0 * n * n * T / 1e6 / tenc);
    if (getenv("KEY")) printf("  on-demand keyframe frames: %.0f B/frame\n", kbytes / T + 48);
    return 0;
}

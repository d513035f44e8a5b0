/* bench_codec.c — tile codec benchmark: bits/sample, max error, encode and
 * decode MB/s (float32 input bytes per second, one core) for oceand's codec
 * (codec 1 deflate-raw, codec 2 zstd) and, in the same run, the peers raw
 * float32+zstd-1 and zfp fixed-accuracy at the largest tolerance that still
 * meets the bound. One JSON object per line, medians of repetitions; speeds are
 * float32 bytes per second of thread CPU time (one core).
 *
 * Input: the real simulation (ocean_create with params_defaults, t = 10 s)
 * when built with HAVE_OCEAN, else a synthetic Phillips-spectrum sea made
 * with FFTW (same spectrum shape, fixed seed). The "source" member says which.
 *
 *   bench_codec [--height] [--tile-size T] [--frames DIR]
 *   --height       height field only;  --tile-size T  tile side of the tiled runs
 *   (power of two, default 64 = the daemon's default; clamped to N);
 *   --frames DIR   keep every encoded frame for the JS decode benchmark.
 *   --streams      only the temporal stream rows (codec_stream: 10 s at 30 Hz, all
 *                  fields, bounds 1 mm and 1 cm); --keyframe-interval K their periodic
 *                  keyframe interval in ticks (default OC_STREAM_KEYFRAME_INTERVAL, 0 = none);
 *                  --stream-n N only that N (256 or 512). Their "hash" (FNV-1a 64 of every
 *                  byte sent) tells whether two encoder builds wrote identical streams.
 *   --dump-fields N FRAMES FILE  write FRAMES ticks of all fields (raw float32) and exit. */
#include "oc_proto.h"

#include <fftw3.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <zfp.h>
#include <zstd.h>
#ifdef HAVE_OCEAN
#include "ocean.h"
#endif

#include "bench_time.h"

/* Tile side of the tiled runs: the daemon's default (128) unless --tile-size T. */
static int tile_size = 128;

/* Timings are thread CPU time (thread_cpu_s): "MB/s per core" on a shared
 * machine, where wall time would also count the time other processes hold
 * the core. */
/* ---- synthetic sea: Phillips spectrum, wind 12 m/s along x, L = 256 m ---- */
static unsigned long long rng_state = 0x9e3779b97f4a7c15ull;
static double urand(void)
{
    rng_state ^= rng_state << 13; rng_state ^= rng_state >> 7; rng_state ^= rng_state << 17;
    return ((rng_state >> 11) + 0.5) * 0x1p-53;
}
static double gauss(void) { return sqrt(-2 * log(urand())) * cos(2 * M_PI * urand()); }

static void synth_fields(int n, float *out[OC_FIELD_COUNT])
{
    const double L = 256.0, V = 12.0, g = 9.81, Lw = V * V / g, lambda = 1.0, l_small = L / 1000;
    fftwf_complex *spec[5], *tmp = fftwf_malloc(sizeof(fftwf_complex) * n * n);
    for (int f = 0; f < 5; f++) spec[f] = fftwf_malloc(sizeof(fftwf_complex) * n * n);
    rng_state = 0x9e3779b97f4a7c15ull;
    for (int m = 0; m < n; m++)
        for (int l = 0; l < n; l++) {
            int kx_i = l < n / 2 ? l : l - n, kz_i = m < n / 2 ? m : m - n;
            double kx = 2 * M_PI * kx_i / L, kz = 2 * M_PI * kz_i / L, k = hypot(kx, kz);
            double a = 0;
            if (k > 0) {
                double c = kx / k; /* wind along +x */
                a = sqrt(2e-3 * exp(-1 / (k * Lw * k * Lw)) / (k * k * k * k) * c * c
                         * exp(-k * k * l_small * l_small) / 2);
            }
            double re = a * gauss(), im = a * gauss();
            size_t i = (size_t)m * n + l;
            double ux = k > 0 ? kx / k : 0, uz = k > 0 ? kz / k : 0;
            /* height, Dx = -i lambda kx/k h, Dz, slope_x = i kx h, slope_z = i kz h */
            spec[0][i][0] = re; spec[0][i][1] = im;
            spec[1][i][0] = lambda * ux * im; spec[1][i][1] = -lambda * ux * re;
            spec[2][i][0] = lambda * uz * im; spec[2][i][1] = -lambda * uz * re;
            spec[3][i][0] = -kx * im; spec[3][i][1] = kx * re;
            spec[4][i][0] = -kz * im; spec[4][i][1] = kz * re;
        }
    /* The real part of the inverse transform is the sea for the Hermitian part of the spectrum. */
    fftwf_plan p = fftwf_plan_dft_2d(n, n, tmp, tmp, FFTW_BACKWARD, FFTW_ESTIMATE);
    for (int f = 0; f < 5; f++) {
        memcpy(tmp, spec[f], sizeof(fftwf_complex) * n * n);
        fftwf_execute(p);
        for (size_t i = 0; i < (size_t)n * n; i++) out[f][i] = tmp[i][0];
    }
    /* Jacobian of the horizontal map by central differences of Dx, Dz. */
    double dx = L / n;
    for (int z = 0; z < n; z++)
        for (int x = 0; x < n; x++) {
            int xp = (x + 1) % n, xm = (x + n - 1) % n, zp = (z + 1) % n, zm = (z + n - 1) % n;
            const float *DX = out[1], *DZ = out[2];
            double jxx = (DX[z * n + xp] - DX[z * n + xm]) / (2 * dx);
            double jzz = (DZ[zp * n + x] - DZ[zm * n + x]) / (2 * dx);
            double jxz = (DX[zp * n + x] - DX[zm * n + x]) / (2 * dx);
            double jzx = (DZ[z * n + xp] - DZ[z * n + xm]) / (2 * dx);
            out[5][z * n + x] = (float)((1 + jxx) * (1 + jzz) - jxz * jzx);
        }
    fftwf_destroy_plan(p);
    for (int f = 0; f < 5; f++) fftwf_free(spec[f]);
    fftwf_free(tmp);
}

static const char *make_fields(int n, float *out[OC_FIELD_COUNT])
{
#ifdef HAVE_OCEAN
    struct ocean_params prm;
    params_defaults(&prm);
    prm.resolution = n;
    struct ocean_options opt = { .threads = 1, .wisdom_path = NULL, .plan_rigor = 0 };
    char err[256];
    struct ocean *o = ocean_create(&prm, &opt, err, sizeof err);
    if (o && ocean_step(o, 10.0, OCEAN_ALL_FIELDS) == 0) {
        for (int f = 0; f < OC_FIELD_COUNT; f++)
            memcpy(out[f], ocean_field(o, (enum ocean_field)f), sizeof(float) * n * n);
        ocean_free(o);
        return "ocean";
    }
    fprintf(stderr, "bench_codec: ocean_create failed (%s), using synthetic sea\n", o ? "step" : err);
    if (o) ocean_free(o);
#endif
    synth_fields(n, out);
    return "synthetic";
}

/* ---- oceand codec: whole field as TILE x TILE tiles, all bytes counted ---- */
struct stats { double bits, max_err, enc, dec; };

static int check_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th,
                      const float *s)
{
    float **ctx = user; /* ctx[0] = decoded field */
    int n = fh->n;
    for (int j = 0; j < th->height; j++)
        memcpy(ctx[0] + (size_t)(th->tile_z * fh->tile_size + j) * n + th->tile_x * fh->tile_size,
               s + (size_t)j * th->width, sizeof(float) * th->width);
    return 0;
}

static const char *frames_dir; /* --frames DIR: keep each encoded frame for the JS decode bench */

static struct stats bench_oceand(const float *f, int n, int tile, int field, float bound, enum oc_codec codec, int reps)
{
    struct oc_encoder *e = oc_encoder_new();
    struct oc_decoder *d = oc_decoder_new();
    oc_encoder_set_codec(e, codec, 0);
    struct oc_buf buf = { 0 };
    float *dec = malloc(sizeof(float) * n * n);
    double *te = malloc(sizeof(double) * reps), *td = malloc(sizeof(double) * reps);
    int grid = n / tile;
    for (int r = 0; r < reps; r++) {
        buf.len = 0;
        oc_buf_reserve(&buf, OC_FRAME_HEADER_SIZE);
        struct oc_frame_header fh = { .seq = 1, .n = (uint16_t)n, .tile_size = (uint16_t)tile, .patch_size = 256,
                                      .tile_count = (uint16_t)(grid * grid) };
        double t0 = thread_cpu_s();
        oc_frame_header_write(buf.data, &fh);
        buf.len = OC_FRAME_HEADER_SIZE;
        for (int tz = 0; tz < grid; tz++)
            for (int tx = 0; tx < grid; tx++)
                if (oc_encode_tile(e, f, n, tile, tx, tz, 0, (enum oc_field)field, bound, &buf)) abort();
        te[r] = thread_cpu_s() - t0;
        float *ctx[1] = { dec };
        struct oc_frame_header out;
        t0 = thread_cpu_s();
        if (oc_decode_frame(d, buf.data, buf.len, &out, check_tile, ctx)) abort();
        td[r] = thread_cpu_s() - t0;
    }
    struct stats s = { .bits = buf.len * 8.0 / ((double)n * n) };
    if (frames_dir) {
        char path[512];
        snprintf(path, sizeof path, "%s/N%d_%s_%g_c%d_t%d.bin", frames_dir, n, oc_field_name((enum oc_field)field),
                 bound, (int)codec, tile);
        FILE *fp = fopen(path, "wb");
        if (!fp || fwrite(buf.data, 1, buf.len, fp) != buf.len || fclose(fp)) perror(path);
    }
    for (size_t i = 0; i < (size_t)n * n; i++) s.max_err = fmax(s.max_err, fabs((double)dec[i] - f[i]));
    double mb = 4.0 * n * n / 1e6;
    s.enc = mb / median(te, reps);
    s.dec = mb / median(td, reps);
    free(te); free(td); free(dec); oc_buf_free(&buf);
    oc_encoder_free(e); oc_decoder_free(d);
    return s;
}

static struct stats bench_zstd_raw(const float *f, int n, int reps)
{
    size_t sz = sizeof(float) * n * n, cap = ZSTD_compressBound(sz);
    void *c = malloc(cap), *dec = malloc(sz);
    double *te = malloc(sizeof(double) * reps), *td = malloc(sizeof(double) * reps);
    ZSTD_CCtx *cc = ZSTD_createCCtx();
    ZSTD_DCtx *dc = ZSTD_createDCtx();
    size_t clen = 0;
    for (int r = 0; r < reps; r++) {
        double t0 = thread_cpu_s();
        clen = ZSTD_compressCCtx(cc, c, cap, f, sz, 1);
        te[r] = thread_cpu_s() - t0;
        t0 = thread_cpu_s();
        if (ZSTD_decompressDCtx(dc, dec, sz, c, clen) != sz) abort();
        td[r] = thread_cpu_s() - t0;
    }
    struct stats s = { .bits = clen * 8.0 / ((double)n * n), .max_err = memcmp(dec, f, sz) ? NAN : 0 };
    s.enc = sz / 1e6 / median(te, reps);
    s.dec = sz / 1e6 / median(td, reps);
    ZSTD_freeCCtx(cc); ZSTD_freeDCtx(dc);
    free(c); free(dec); free(te); free(td);
    return s;
}

/* zfp fixed-accuracy round trip; returns compressed bytes, fills dec and times. */
static size_t zfp_run(const float *f, int n, double tol, float *dec, void *buf, size_t cap,
                      double *t_enc, double *t_dec)
{
    zfp_field *field = zfp_field_2d((void *)f, zfp_type_float, n, n);
    zfp_stream *zs = zfp_stream_open(NULL);
    zfp_stream_set_accuracy(zs, tol);
    bitstream *bs = stream_open(buf, cap);
    zfp_stream_set_bit_stream(zs, bs);
    double t0 = thread_cpu_s();
    zfp_stream_rewind(zs);
    size_t len = zfp_compress(zs, field);
    *t_enc = thread_cpu_s() - t0;
    zfp_field *out = zfp_field_2d(dec, zfp_type_float, n, n);
    t0 = thread_cpu_s();
    zfp_stream_rewind(zs);
    if (!zfp_decompress(zs, out)) len = 0;
    *t_dec = thread_cpu_s() - t0;
    zfp_field_free(out); zfp_field_free(field);
    stream_close(bs); zfp_stream_close(zs);
    return len;
}

static double max_err(const float *a, const float *b, size_t n)
{
    double m = 0;
    for (size_t i = 0; i < n; i++) m = fmax(m, fabs((double)a[i] - b[i]));
    return m;
}

static struct stats bench_zfp(const float *f, int n, float bound, int reps, double *tol_out)
{
    size_t cap = sizeof(float) * n * n * 2 + 4096;
    void *buf = malloc(cap);
    float *dec = malloc(sizeof(float) * n * n);
    double te, td;
    /* Largest tolerance (bisection in log space over [bound/16, 16*bound]) still meeting the bound. */
    double lo = bound / 16.0, hi = bound * 16.0;
    for (int it = 0; it < 30; it++) {
        double mid = sqrt(lo * hi);
        zfp_run(f, n, mid, dec, buf, cap, &te, &td);
        if (max_err(f, dec, (size_t)n * n) <= bound) lo = mid; else hi = mid;
    }
    double *tes = malloc(sizeof(double) * reps), *tds = malloc(sizeof(double) * reps);
    size_t len = 0;
    for (int r = 0; r < reps; r++) len = zfp_run(f, n, lo, dec, buf, cap, &tes[r], &tds[r]);
    struct stats s = { .bits = len * 8.0 / ((double)n * n), .max_err = max_err(f, dec, (size_t)n * n) };
    s.enc = 4.0 * n * n / 1e6 / median(tes, reps);
    s.dec = 4.0 * n * n / 1e6 / median(tds, reps);
    *tol_out = lo;
    free(buf); free(dec); free(tes); free(tds);
    return s;
}

#ifdef HAVE_OCEAN
/* --dump-fields N FRAMES FILE: FRAMES consecutive ticks at 30 Hz from t = 10 s, all six
 * fields, raw float32 (frame-major, then field, then row-major): the input of
 * proto/tools/temporal_predictors.py, which measured the predictor choice. */
static int dump_fields(int n, int frames, const char *path)
{
    struct ocean_params prm;
    params_defaults(&prm);
    prm.resolution = n;
    struct ocean_options opt = { .threads = 1, .wisdom_path = NULL, .plan_rigor = 0 };
    char err[256];
    struct ocean *o = ocean_create(&prm, &opt, err, sizeof err);
    FILE *fp = fopen(path, "wb");
    if (!o || !fp) { fprintf(stderr, "bench_codec: %s\n", o ? path : err); return 1; }
    for (int k = 0; k < frames; k++) {
        if (ocean_step(o, 10.0 + k / 30.0, OCEAN_ALL_FIELDS)) return 1;
        for (int f = 0; f < OC_FIELD_COUNT; f++)
            if (fwrite(ocean_field(o, (enum ocean_field)f), sizeof(float), (size_t)n * n, fp) != (size_t)n * n) return 1;
    }
    ocean_free(o);
    return fclose(fp) != 0;
}

/* ---- temporal streams (codec 3): 10 s at 30 Hz of the real simulation ----
 * One oc_stream per field and bound, every tile of every tick: the shared
 * frame a receiver that keeps up gets (keyframes and headers included).
 * Decoded by one decoder per stream; max_err against the simulation's floats.
 * intra_bits / intra_enc_MBs: codec 1 on the same fresh fields in the same run. */
#define STREAM_TICKS 300
struct stream_run {
    struct oc_stream *st;
    struct oc_decoder *dec;
    struct oc_buf buf;
    double bytes, max_err, t_enc, t_dec, t_intra, intra_bytes;
    uint64_t hash;             /* FNV-1a of every byte sent: equal hashes = bit-identical encoder output */
    float *dec_field;
    FILE *dump;
};

static int stream_tile_cb(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th,
                          const float *s)
{
    return check_tile(user, fh, th, s);
}

static void bench_streams(int n, int interval)
{
    const float bounds[2] = { 0.001f, 0.01f };
    struct ocean_params prm;
    params_defaults(&prm);
    prm.resolution = n;
    struct ocean_options opt = { .threads = 1, .wisdom_path = NULL, .plan_rigor = 0 };
    char err[256];
    struct ocean *o = ocean_create(&prm, &opt, err, sizeof err);
    if (!o) { fprintf(stderr, "bench_codec: %s\n", err); return; }
    int tile = tile_size < n ? tile_size : n, grid = n / tile;
    struct oc_encoder *e = oc_encoder_new(), *e_intra = oc_encoder_new();
    struct oc_buf intra = { 0 };
    struct stream_run run[OC_FIELD_COUNT][2];
    memset(run, 0, sizeof run);
    for (int f = 0; f < OC_FIELD_COUNT; f++)
        for (int b = 0; b < 2; b++) {
            run[f][b].st = oc_stream_new(n, tile, 0, (enum oc_field)f, bounds[b]);
            oc_stream_set_keyframe_interval(run[f][b].st, interval);
            run[f][b].dec = oc_decoder_new();
            run[f][b].hash = 0xcbf29ce484222325ull;
            run[f][b].dec_field = malloc(sizeof(float) * n * n);
            if (frames_dir && f < 3 && b == 1) {   /* the web client's default layers, for bench_decode.mjs */
                char path[512];
                snprintf(path, sizeof path, "%s/stream_N%d_%s_%g_t%d.frames", frames_dir, n,
                         oc_field_name((enum oc_field)f), bounds[b], tile);
                run[f][b].dump = fopen(path, "wb");
            }
        }
    for (int tick = 0; tick < STREAM_TICKS; tick++) {
        if (ocean_step(o, 10.0 + tick / 30.0, OCEAN_ALL_FIELDS)) abort();
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            const float *field = ocean_field(o, (enum ocean_field)f);
            for (int b = 0; b < 2; b++) {
                struct stream_run *r = &run[f][b];
                struct oc_frame_header fh = { .seq = 1000 + (uint64_t)tick, .sim_time = tick / 30.0, .n = (uint16_t)n,
                                              .tile_size = (uint16_t)tile, .patch_size = 256,
                                              .tile_count = (uint16_t)(grid * grid) };
                double t0 = thread_cpu_s();
                if (oc_stream_encode(r->st, e, field, fh.seq)) abort();
                r->buf.len = 0;
                oc_buf_reserve(&r->buf, OC_FRAME_HEADER_SIZE);
                oc_frame_header_write(r->buf.data, &fh);
                r->buf.len = OC_FRAME_HEADER_SIZE;
                for (int tz = 0; tz < grid; tz++)
                    for (int tx = 0; tx < grid; tx++) {
                        const uint8_t *p;
                        size_t len;
                        oc_stream_tile(r->st, tx, tz, &p, &len);
                        oc_buf_reserve(&r->buf, len);
                        memcpy(r->buf.data + r->buf.len, p, len);
                        r->buf.len += len;
                    }
                r->t_enc += thread_cpu_s() - t0;
                r->bytes += (double)r->buf.len;
                for (size_t k = 0; k < r->buf.len; k++) r->hash = (r->hash ^ r->buf.data[k]) * 0x100000001b3ull;
                /* The intra codec on the same fresh field, for a same-conditions speed ratio. */
                t0 = thread_cpu_s();
                for (int tz = 0; tz < grid; tz++)
                    for (int tx = 0; tx < grid; tx++) {
                        intra.len = 0;
                        if (oc_encode_tile(e_intra, field, n, tile, tx, tz, 0, (enum oc_field)f, bounds[b], &intra)) abort();
                        r->intra_bytes += (double)intra.len;
                    }
                r->t_intra += thread_cpu_s() - t0;
                float *ctx[1] = { r->dec_field };
                struct oc_frame_header out;
                t0 = thread_cpu_s();
                int rc = oc_decode_frame(r->dec, r->buf.data, r->buf.len, &out, stream_tile_cb, ctx);
                r->t_dec += thread_cpu_s() - t0;
                if (rc) { fprintf(stderr, "bench_codec: stream decode: %s\n", oc_strerror(rc)); abort(); }
                r->max_err = fmax(r->max_err, max_err(field, r->dec_field, (size_t)n * n));
                if (r->dump) {
                    uint32_t len32 = (uint32_t)r->buf.len;
                    fwrite(&len32, 4, 1, r->dump);
                    fwrite(r->buf.data, 1, r->buf.len, r->dump);
                }
            }
        }
    }
    double mb = 4.0 * n * n * STREAM_TICKS / 1e6;
    for (int f = 0; f < OC_FIELD_COUNT; f++)
        for (int b = 0; b < 2; b++) {
            struct stream_run *r = &run[f][b];
            printf("{\"bench\":\"codec_stream\",\"N\":%d,\"field\":\"%s\",\"bound\":%g,\"tile\":%d,\"bits\":%.3f,"
                   "\"max_err\":%.6g,\"keyframe_interval\":%d,\"ticks\":%d,\"enc_MBs\":%.0f,\"dec_MBs\":%.0f,"
                   "\"intra_bits\":%.3f,\"intra_enc_MBs\":%.0f,\"hash\":\"%016llx\"}\n",
                   n, oc_field_name((enum oc_field)f), bounds[b], tile, r->bytes * 8 / ((double)n * n * STREAM_TICKS),
                   r->max_err, interval, STREAM_TICKS, mb / r->t_enc, mb / r->t_dec,
                   (r->intra_bytes + (double)OC_FRAME_HEADER_SIZE * STREAM_TICKS) * 8 / ((double)n * n * STREAM_TICKS),
                   mb / r->t_intra, (unsigned long long)r->hash);
            oc_stream_free(r->st);
            oc_decoder_free(r->dec);
            oc_buf_free(&r->buf);
            free(r->dec_field);
            if (r->dump) fclose(r->dump);
        }
    fflush(stdout);
    oc_encoder_free(e);
    oc_encoder_free(e_intra);
    oc_buf_free(&intra);
    ocean_free(o);
}
#endif

static void print(int n, const char *src, int field, float bound, const char *codec, int tile, struct stats s,
                  const char *extra)
{
    printf("{\"bench\":\"codec\",\"N\":%d,\"source\":\"%s\",\"field\":\"%s\",\"bound\":%g,\"codec\":\"%s\","
           "\"tile\":%d,\"bits\":%.3f,\"max_err\":%.6g,\"enc_MBs\":%.0f,\"dec_MBs\":%.0f%s}\n",
           n, src, oc_field_name((enum oc_field)field), bound, codec, tile, s.bits, s.max_err, s.enc, s.dec,
           extra ? extra : "");
    fflush(stdout);
}

int main(int argc, char **argv)
{
    int only_height = 0, only_streams = 0, interval = OC_STREAM_KEYFRAME_INTERVAL, stream_n = 0;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--height") == 0) only_height = 1;
        else if (strcmp(argv[i], "--frames") == 0 && i + 1 < argc) frames_dir = argv[++i];
        else if (strcmp(argv[i], "--streams") == 0) only_streams = 1;
        else if (strcmp(argv[i], "--stream-n") == 0 && i + 1 < argc) stream_n = atoi(argv[++i]);
#ifdef HAVE_OCEAN
        else if (strcmp(argv[i], "--dump-fields") == 0 && i + 3 < argc)
            return dump_fields(atoi(argv[i + 1]), atoi(argv[i + 2]), argv[i + 3]);
#endif
        else if (strcmp(argv[i], "--keyframe-interval") == 0 && i + 1 < argc) interval = atoi(argv[++i]);
        else if (strcmp(argv[i], "--tile-size") == 0 && i + 1 < argc) {
            tile_size = atoi(argv[++i]);
            if (tile_size < 1 || tile_size > OC_MAX_N || (tile_size & (tile_size - 1))) {
                fprintf(stderr, "bench_codec: --tile-size must be a power of two in 1..%d\n", OC_MAX_N);
                return 2;
            }
        } else { fprintf(stderr, "usage: bench_codec [--height] [--streams] [--stream-n N] [--keyframe-interval K] [--tile-size T] [--frames DIR]\n"); return 2; }
    }
    const int sizes[2] = { 256, 512 };
    const float bounds[2] = { 0.001f, 0.01f };
#ifdef HAVE_OCEAN
    for (int si = 0; si < 2; si++)
        if (!stream_n || stream_n == sizes[si]) bench_streams(sizes[si], interval);
#else
    (void)interval;
#endif
    for (int si = 0; si < 2 && !only_streams; si++) {
        int n = sizes[si], reps = n == 256 ? 21 : 9, tile = tile_size < n ? tile_size : n;
        float *fields[OC_FIELD_COUNT];
        for (int f = 0; f < OC_FIELD_COUNT; f++) fields[f] = malloc(sizeof(float) * n * n);
        const char *src = make_fields(n, fields);
        for (int f = 0; f < (only_height ? 1 : OC_FIELD_COUNT); f++) {
            print(n, src, f, 0, "zstd-raw", n, bench_zstd_raw(fields[f], n, reps), NULL);
            for (int b = 0; b < 2; b++) {
                struct stats s1 = bench_oceand(fields[f], n, tile, f, bounds[b], OC_CODEC_QUANT_LORENZO, reps);
                struct stats s2 = bench_oceand(fields[f], n, tile, f, bounds[b], OC_CODEC_QUANT_LORENZO_ZSTD, reps);
                struct stats s3 = bench_oceand(fields[f], n, n, f, bounds[b], OC_CODEC_QUANT_LORENZO, reps);
                double tol;
                struct stats sz = bench_zfp(fields[f], n, bounds[b], reps, &tol);
                char extra[128];
                snprintf(extra, sizeof extra, ",\"entropy\":\"deflate-raw\",\"zfp_bits_ratio\":%.2f", sz.bits / s1.bits);
                print(n, src, f, bounds[b], "oceand", tile, s1, extra);
                snprintf(extra, sizeof extra, ",\"entropy\":\"zstd-1\",\"zfp_bits_ratio\":%.2f", sz.bits / s2.bits);
                print(n, src, f, bounds[b], "oceand-zstd", tile, s2, extra);
                snprintf(extra, sizeof extra, ",\"entropy\":\"deflate-raw\",\"zfp_bits_ratio\":%.2f", sz.bits / s3.bits);
                print(n, src, f, bounds[b], "oceand", n, s3, extra);
                snprintf(extra, sizeof extra, ",\"tolerance\":%.6g", tol);
                print(n, src, f, bounds[b], "zfp", n, sz, extra);
            }
        }
        for (int f = 0; f < OC_FIELD_COUNT; f++) free(fields[f]);
    }
    return 0;
}

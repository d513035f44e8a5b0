/* test_proto.c — oceand wire protocol and tile codec tests.
 *   test_proto VECTOR_DIR
 * 1. every checked-in vector decodes to exactly the expected float32 bits,
 *    with the headers the manifest lists, and within its bound of the input;
 * 2. every bad input is rejected with the listed error;
 * 3. header round trips; 4. random smooth/noisy fields at several bounds,
 *    LODs and both lossy codecs stay within the bound; 5. edge cases (NaN,
 *    huge range, constant, float32 resolution); 6. random truncations and bit
 *    flips never crash (run under ASan by test-proto-asan); 7. the codec-1
 *    Huffman-only DEFLATE writer, read back by zlib, never writes past its
 *    buffer and fails cleanly when the buffer is one byte short. */
#include "oc_internal.h"   /* the entropy writer's own entry points (test 7) */
#include "oc_proto.h"

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "common/check.h"
#include "common/slurp.h"

static unsigned long long rng = 0x2545F4914F6CDD1Dull;
static uint32_t rnd(void) { rng ^= rng << 13; rng ^= rng >> 7; rng ^= rng << 17; return (uint32_t)(rng >> 32); }
static double urand(void) { return rnd() * 0x1p-32; }

static uint8_t *read_all(const char *dir, const char *name, size_t *len)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    uint8_t *p = (uint8_t *)slurp(path, len);
    CHECK(p != NULL, "cannot read %s", path);
    return p;
}

/* ---- 1. vectors ---- */
struct vec_ctx { const char *name; cJSON *tiles; int index; const float *expected, *input; size_t nexp; };

static int vec_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th, const float *s)
{
    struct vec_ctx *c = user;
    cJSON *t = cJSON_GetArrayItem(c->tiles, c->index++);
    if (!t) { CHECK(0, "%s: more tiles than the manifest lists", c->name); return 1; }
    const char *field = cJSON_GetObjectItem(t, "field")->valuestring;
    CHECK(strcmp(oc_field_name((enum oc_field)th->field), field) == 0, "%s: field %d vs %s", c->name, th->field, field);
    CHECK(th->lod == cJSON_GetObjectItem(t, "lod")->valueint, "%s: lod", c->name);
    CHECK(th->codec == cJSON_GetObjectItem(t, "codec")->valueint, "%s: codec", c->name);
    const cJSON *mc = cJSON_GetObjectItem(t, "cascade");
    CHECK(oc_tile_cascade(th) == (mc ? mc->valueint : 0), "%s: cascade", c->name);
    CHECK(th->tile_x == cJSON_GetObjectItem(t, "tileX")->valueint, "%s: tile_x", c->name);
    CHECK(th->tile_z == cJSON_GetObjectItem(t, "tileZ")->valueint, "%s: tile_z", c->name);
    CHECK(th->width == cJSON_GetObjectItem(t, "width")->valueint, "%s: width", c->name);
    CHECK(th->height == cJSON_GetObjectItem(t, "height")->valueint, "%s: height", c->name);
    CHECK(th->offset == cJSON_GetObjectItem(t, "offset")->valuedouble, "%s: offset", c->name);
    CHECK(th->scale == cJSON_GetObjectItem(t, "scale")->valuedouble, "%s: scale", c->name);
    CHECK(th->bound == (float)cJSON_GetObjectItem(t, "bound")->valuedouble, "%s: bound", c->name);
    size_t at = (size_t)cJSON_GetObjectItem(t, "sampleOffset")->valuedouble, count = (size_t)th->width * th->height;
    if (at + count > c->nexp) { CHECK(0, "%s: expected file too short", c->name); return 1; }
    CHECK(memcmp(s, c->expected + at, count * sizeof(float)) == 0, "%s tile %d: samples differ from expected bits",
          c->name, c->index - 1);
    double maxerr = 0;
    for (size_t k = 0; k < count; k++) maxerr = fmax(maxerr, fabs((double)s[k] - c->input[at + k]));
    CHECK(maxerr <= th->bound, "%s tile %d: max error %g > bound %g", c->name, c->index - 1, maxerr, th->bound);
    return 0;
}

static const char *err_name(int rc)
{
    switch (rc) {
    case OC_E_TRUNCATED: return "truncated";
    case OC_E_MAGIC: return "magic";
    case OC_E_VERSION: return "version";
    case OC_E_CORRUPT: return "corrupt";
    case OC_E_TOO_LARGE: return "too_large";
    case OC_E_REFERENCE: return "reference";
    default: return oc_strerror(rc);
    }
}

static void test_vectors(const char *dir)
{
    size_t mlen;
    char *mtext = (char *)read_all(dir, "manifest.json", &mlen);
    if (!mtext) return;   /* NUL-terminated by slurp */
    cJSON *m = cJSON_Parse(mtext);
    if (!m) { CHECK(0, "manifest.json does not parse"); free(mtext); return; }
    struct oc_decoder *d = oc_decoder_new();
    int nvec = 0, nbad = 0;
    cJSON *v;
    cJSON_ArrayForEach(v, cJSON_GetObjectItem(m, "vectors")) {
        size_t blen, elen, ilen;
        const char *name = cJSON_GetObjectItem(v, "name")->valuestring;
        uint8_t *bin = read_all(dir, cJSON_GetObjectItem(v, "file")->valuestring, &blen);
        float *exp = (float *)read_all(dir, cJSON_GetObjectItem(v, "expected")->valuestring, &elen);
        float *in = (float *)read_all(dir, cJSON_GetObjectItem(v, "input")->valuestring, &ilen);
        if (!bin || !exp || !in) continue;
        struct vec_ctx c = { name, cJSON_GetObjectItem(v, "tiles"), 0, exp, in, elen / 4 };
        struct oc_frame_header fh;
        int rc = oc_decode_frame(d, bin, blen, &fh, vec_tile, &c);
        CHECK(rc == OC_OK, "%s: decode returned %s", name, oc_strerror(rc));
        CHECK(c.index == cJSON_GetArraySize(c.tiles), "%s: %d tiles decoded", name, c.index);
        cJSON *h = cJSON_GetObjectItem(v, "header");
        CHECK(fh.n == cJSON_GetObjectItem(h, "n")->valueint && fh.tile_size == cJSON_GetObjectItem(h, "tileSize")->valueint
              && fh.seq == (uint64_t)cJSON_GetObjectItem(h, "seq")->valuedouble
              && fh.sim_time == cJSON_GetObjectItem(h, "simTime")->valuedouble
              && fh.params_version == (uint32_t)cJSON_GetObjectItem(h, "paramsVersion")->valuedouble,
              "%s: frame header differs from manifest", name);
        /* Floating bodies in the header (PROTOCOL.md §3.5): every record exactly; none in the others. */
        cJSON *bodies = cJSON_GetObjectItem(v, "bodies");
        struct oc_body_record rec[8];
        int nb = oc_body_section_read(bin, blen, rec, 8);
        CHECK(nb == (bodies ? cJSON_GetArraySize(bodies) : 0), "%s: %d bodies read", name, nb);
        for (int i = 0; bodies && i < nb && i < 8; i++) {
            cJSON *b = cJSON_GetArrayItem(bodies, i);
            bool same = rec[i].id == (uint32_t)cJSON_GetObjectItem(b, "id")->valuedouble &&
                        rec[i].kind == cJSON_GetObjectItem(b, "kind")->valueint &&
                        rec[i].flags == cJSON_GetObjectItem(b, "flags")->valueint &&
                        rec[i].throttle == cJSON_GetObjectItem(b, "throttle")->valueint &&
                        rec[i].rudder == cJSON_GetObjectItem(b, "rudder")->valueint;
            for (int k = 0; k < 3; k++)
                same = same && rec[i].pos[k] == (float)cJSON_GetArrayItem(cJSON_GetObjectItem(b, "pos"), k)->valuedouble &&
                       rec[i].vel[k] == (float)cJSON_GetArrayItem(cJSON_GetObjectItem(b, "vel"), k)->valuedouble;
            for (int k = 0; k < 4; k++)
                same = same && rec[i].quat[k] == (float)cJSON_GetArrayItem(cJSON_GetObjectItem(b, "quat"), k)->valuedouble;
            CHECK(same, "%s: body record %d differs from the manifest", name, i);
        }
        free(bin); free(exp); free(in);
        nvec++;
    }
    cJSON_ArrayForEach(v, cJSON_GetObjectItem(m, "bad")) {
        size_t blen;
        const char *name = cJSON_GetObjectItem(v, "name")->valuestring;
        const char *want = cJSON_GetObjectItem(v, "error")->valuestring;
        uint8_t *bin = read_all(dir, cJSON_GetObjectItem(v, "file")->valuestring, &blen);
        if (!bin) continue;
        struct oc_frame_header fh;
        int rc = oc_decode_frame(d, bin, blen, &fh, NULL, NULL);
        CHECK(rc < 0 && strcmp(err_name(rc), want) == 0, "%s: got %s, want %s", name, err_name(rc), want);
        free(bin);
        nbad++;
    }
    CHECK(nvec >= 8 && nbad >= 8, "manifest lists %d vectors and %d bad inputs", nvec, nbad);
    printf("vectors: %d frames bit-exact, %d bad inputs rejected\n", nvec, nbad);
    oc_decoder_free(d);
    cJSON_Delete(m);
    free(mtext);
}

/* ---- 3. header round trips ---- */
static int stop_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th, const float *s)
{
    return 42;
}

static void test_headers(void)
{
    for (int i = 0; i < 200; i++) {
        struct oc_frame_header h = {
            .seq = ((uint64_t)rnd() << 32) | rnd(), .sim_time = urand() * 1e6, .params_version = rnd(),
            .n = (uint16_t)(1u << (1 + rnd() % 11)), .patch_size = (float)(1 + urand() * 1000),
            .tile_count = (uint16_t)rnd(), .flags = 0, .server_time_us = ((uint64_t)rnd() << 32) | rnd(),
        };
        h.tile_size = (uint16_t)(h.n >> (rnd() % 3));
        if (!h.tile_size) h.tile_size = 1;
        uint8_t b[OC_FRAME_HEADER_SIZE];
        struct oc_frame_header r;
        oc_frame_header_write(b, &h);
        int rc = oc_frame_header_read(b, sizeof b, &r);
        CHECK(rc == OC_OK && r.seq == h.seq && r.sim_time == h.sim_time && r.params_version == h.params_version
              && r.n == h.n && r.tile_size == h.tile_size && r.patch_size == h.patch_size
              && r.tile_count == h.tile_count && r.server_time_us == h.server_time_us,
              "frame header round trip %d (rc %d)", i, rc);
        CHECK(oc_frame_header_read(b, sizeof b - 1, &r) == OC_E_TRUNCATED, "header: 47 bytes accepted");
    }
    CHECK(oc_field_from_name("jacobian") == OC_FIELD_JACOBIAN && oc_field_from_name("nope") == -1, "field names");

    /* A longer header (compatible extension) is skipped; a shorter or unaligned one is corrupt. */
    struct oc_encoder *e = oc_encoder_new();
    struct oc_decoder *d = oc_decoder_new();
    float field[16 * 16];
    for (int i = 0; i < 256; i++) field[i] = (float)sin(i * 0.1);
    struct oc_buf buf = { 0 };
    oc_buf_reserve(&buf, OC_FRAME_HEADER_SIZE + 8);
    struct oc_frame_header h = { .seq = 5, .n = 16, .tile_size = 16, .patch_size = 10, .tile_count = 1 };
    oc_frame_header_write(buf.data, &h);
    buf.data[6] = OC_FRAME_HEADER_SIZE + 8;
    memset(buf.data + OC_FRAME_HEADER_SIZE, 0xAB, 8);
    buf.len = OC_FRAME_HEADER_SIZE + 8;
    oc_encode_tile(e, field, 16, 16, 0, 0, 0, OC_FIELD_DZ, 1e-3f, &buf);
    struct oc_frame_header out;
    int rc = oc_decode_frame(d, buf.data, buf.len, &out, NULL, NULL);
    CHECK(rc == OC_OK && out.seq == 5, "header_size 56 not skipped (rc %d)", rc);
    buf.data[6] = OC_FRAME_HEADER_SIZE - 8;
    CHECK(oc_decode_frame(d, buf.data, buf.len, &out, NULL, NULL) == OC_E_CORRUPT, "header_size 40 accepted");
    buf.data[6] = OC_FRAME_HEADER_SIZE + 4;
    CHECK(oc_decode_frame(d, buf.data, buf.len, &out, NULL, NULL) == OC_E_CORRUPT, "header_size 52 accepted");
    /* A tile callback's nonzero return stops decoding and is returned. */
    buf.data[6] = OC_FRAME_HEADER_SIZE + 8;
    CHECK(oc_decode_frame(d, buf.data, buf.len, &out, stop_tile, NULL) == 42, "callback return not propagated");
    oc_buf_free(&buf);
    oc_encoder_free(e);
    oc_decoder_free(d);
}

/* ---- 4./5. codec bound ---- */
static float *field_smooth(int n, double amp, double noise)
{
    float *f = malloc(sizeof(float) * n * n);
    double p1 = urand() * 6, p2 = urand() * 6, k1 = 1 + rnd() % 4, k2 = 1 + rnd() % 9;
    for (int z = 0; z < n; z++)
        for (int x = 0; x < n; x++)
            f[z * n + x] = (float)(amp * (sin(2 * M_PI * k1 * x / n + p1) * cos(2 * M_PI * k2 * z / n + p2)
                                          + 0.2 * sin(2 * M_PI * (k2 * x + k1 * z) / n))
                                   + noise * (urand() - 0.5));
    return f;
}

struct cmp_ctx { const float *field; int n; double maxerr; int tiles; float bound; int codec_seen[3]; };

static int cmp_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th, const float *s)
{
    struct cmp_ctx *c = user;
    int step = 1 << th->lod;
    for (int j = 0; j < th->height; j++)
        for (int i = 0; i < th->width; i++) {
            float v = c->field[((size_t)th->tile_z * fh->tile_size + (size_t)j * step) * c->n
                               + (size_t)th->tile_x * fh->tile_size + (size_t)i * step];
            c->maxerr = fmax(c->maxerr, fabs((double)s[(size_t)j * th->width + i] - v));
        }
    c->tiles++;
    c->codec_seen[th->codec < 3 ? th->codec : 0]++;
    return 0;
}

/* Encode every tile of f at lod, decode, return max error (or -1 on error). */
static double roundtrip(struct oc_encoder *e, struct oc_decoder *d, const float *f, int n, int ts, int lod,
                        float bound, struct cmp_ctx *c, struct oc_buf *buf)
{
    int grid = n / ts;
    struct oc_frame_header fh = { .seq = 7, .n = (uint16_t)n, .tile_size = (uint16_t)ts, .patch_size = 100,
                                  .tile_count = (uint16_t)(grid * grid) };
    buf->len = 0;
    if (oc_buf_reserve(buf, OC_FRAME_HEADER_SIZE)) return -1;
    oc_frame_header_write(buf->data, &fh);
    buf->len = OC_FRAME_HEADER_SIZE;
    for (int tz = 0; tz < grid; tz++)
        for (int tx = 0; tx < grid; tx++) {
            int rc = oc_encode_tile(e, f, n, ts, tx, tz, lod, OC_FIELD_HEIGHT, bound, buf);
            if (rc) { CHECK(0, "encode: %s", oc_strerror(rc)); return -1; }
        }
    memset(c, 0, sizeof *c);
    c->field = f; c->n = n; c->bound = bound;
    struct oc_frame_header out;
    int rc = oc_decode_frame(d, buf->data, buf->len, &out, cmp_tile, c);
    if (rc) { CHECK(0, "decode of a fresh encode: %s", oc_strerror(rc)); return -1; }
    return c->maxerr;
}

static void test_bounds(void)
{
    struct oc_encoder *e = oc_encoder_new();
    struct oc_decoder *d = oc_decoder_new();
    struct oc_buf buf = { 0 };
    const float bounds[] = { 1e-5f, 1e-4f, 1e-3f, 5e-3f, 1e-2f, 0.1f };
    int cases = 0;
    for (int codec = 1; codec <= 2; codec++) {
        oc_encoder_set_codec(e, (enum oc_codec)codec, 0);
        for (int trial = 0; trial < 6; trial++) {
            int n = 32 << (trial % 3), ts = n >> (trial % 2 + 1), lod = trial % 3;
            double amp = trial < 3 ? 2.0 : 40.0, noise = (trial & 1) ? 0.5 : 0.0;
            float *f = field_smooth(n, amp, noise);
            for (size_t b = 0; b < sizeof bounds / sizeof *bounds; b++) {
                struct cmp_ctx c;
                double err = roundtrip(e, d, f, n, ts, lod, bounds[b], &c, &buf);
                CHECK(err >= 0 && err <= bounds[b], "codec %d n %d lod %d amp %g noise %g bound %g: max err %g",
                      codec, n, lod, amp, noise, bounds[b], err);
                cases++;
            }
            free(f);
        }
    }
    /* Scale close to float32 resolution: values ~3000 m at 0.1 mm (ulp 2.4e-4). */
    float *f = field_smooth(64, 1.0, 0);
    for (int i = 0; i < 64 * 64; i++) f[i] += 3000.0f;
    struct cmp_ctx c;
    for (int i = 0; i < 4; i++) {
        float b = (float[]){ 1e-4f, 2e-4f, 3e-4f, 1e-3f }[i];
        double err = roundtrip(e, d, f, 64, 32, 0, b, &c, &buf);
        CHECK(err >= 0 && err <= b, "offset 3000, bound %g: max err %g", b, err);
    }
    /* Constant tile: exact, 4-byte payload. */
    for (int i = 0; i < 64 * 64; i++) f[i] = -1.75f;
    double err = roundtrip(e, d, f, 64, 64, 0, 1e-3f, &c, &buf);
    CHECK(err == 0 && c.codec_seen[OC_CODEC_RAW_F32] == 0 && buf.len < OC_FRAME_HEADER_SIZE + 120,
          "constant tile: err %g, %zu bytes", err, buf.len);
    /* Huge dynamic range: falls back to raw, exact. */
    f[100] = 1e30f; f[200] = -1e30f;
    err = roundtrip(e, d, f, 64, 64, 0, 1e-3f, &c, &buf);
    CHECK(err == 0 && c.codec_seen[OC_CODEC_RAW_F32] == 1, "huge range: err %g, raw tiles %d", err,
          c.codec_seen[OC_CODEC_RAW_F32]);
    /* NaN and Inf are rejected; bad arguments too. */
    f[300] = NAN;
    CHECK(oc_encode_tile(e, f, 64, 64, 0, 0, 0, OC_FIELD_HEIGHT, 1e-3f, &buf) == OC_E_ARG, "NaN accepted");
    CHECK(oc_encode_tile(e, f, 64, 64, 0, 0, 0, OC_FIELD_HEIGHT, 0, &buf) == OC_E_ARG, "NaN accepted (raw)");
    f[300] = INFINITY;
    CHECK(oc_encode_tile(e, f, 64, 64, 0, 0, 0, OC_FIELD_HEIGHT, 1e-3f, &buf) == OC_E_ARG, "Inf accepted");
    f[300] = 0;
    CHECK(oc_encode_tile(e, f, 64, 48, 0, 0, 0, OC_FIELD_HEIGHT, 1e-3f, &buf) == OC_E_ARG, "tile 48 accepted");
    CHECK(oc_encode_tile(e, f, 64, 32, 2, 0, 0, OC_FIELD_HEIGHT, 1e-3f, &buf) == OC_E_ARG, "tile_x 2 accepted");
    CHECK(oc_encode_tile(e, f, 64, 32, 0, 0, 5, OC_FIELD_HEIGHT, 1e-3f, &buf) == OC_E_ARG, "lod 5 accepted");
    CHECK(oc_encode_tile(e, f, 64, 32, 0, 0, 0, OC_FIELD_HEIGHT, -1.0f, &buf) == OC_E_ARG, "negative bound accepted");
    CHECK(oc_encode_tile(e, f, 4096, 32, 0, 0, 0, OC_FIELD_HEIGHT, 1e-3f, &buf) == OC_E_TOO_LARGE, "n 4096 accepted");
    CHECK(oc_encoder_set_codec(e, (enum oc_codec)3, 0) == OC_E_ARG, "codec 3 accepted");
    free(f);
    printf("bounds: %d random cases within bound (+ edge cases)\n", cases);
    oc_buf_free(&buf);
    oc_encoder_free(e);
    oc_decoder_free(d);
}

/* ---- 6. robustness: mutated frames must be rejected or decode in bounds ---- */
static int count_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th, const float *s)
{
    ++*(int *)user;
    return 0;
}

static void test_fuzz(void)
{
    struct oc_encoder *e = oc_encoder_new();
    struct oc_decoder *d = oc_decoder_new();
    struct oc_buf buf = { 0 };
    int n = 64, ts = 32;
    float *f = field_smooth(n, 1.0, 0.01);
    struct cmp_ctx c;
    int rejected = 0, accepted = 0;
    for (int codec = 1; codec <= 2; codec++) {
        oc_encoder_set_codec(e, (enum oc_codec)codec, 0);
        for (int lod = 0; lod < 3; lod++) {
            roundtrip(e, d, f, n, ts, lod, 1e-3f, &c, &buf);
            /* Mix in a raw tile so that path gets mutated too. */
            uint8_t *copy = malloc(buf.len);
            for (int it = 0; it < 700; it++) {
                memcpy(copy, buf.data, buf.len);
                size_t len = buf.len;
                int kind = (int)(rnd() % 3);
                if (kind == 0) len = rnd() % buf.len;                 /* truncation */
                int flips = kind == 0 ? 0 : 1 + (int)(rnd() % 4);
                for (int k = 0; k < flips; k++) copy[rnd() % len] ^= (uint8_t)(1u << (rnd() % 8));
                /* Exact-size heap copy: ASan sees any read past its end. */
                uint8_t *exact = malloc(len ? len : 1);
                memcpy(exact, copy, len);
                struct oc_frame_header fh;
                int delivered = 0;
                int rc = oc_decode_frame(d, exact, len, &fh, count_tile, &delivered);
                if (rc == OC_OK) accepted++; else rejected++;
                CHECK(rc != OC_E_TRUNCATED || delivered == 0, "fuzz: %d tiles delivered from a truncated frame",
                      delivered);
                CHECK(rc <= 0 && (rc >= OC_E_TOO_LARGE || rc == OC_E_REFERENCE), "fuzz: unexpected return %d", rc);
                CHECK(kind != 0 || len == buf.len || rc != OC_OK, "fuzz: truncated frame accepted (%zu of %zu)",
                      len, buf.len);
                free(exact);
            }
            free(copy);
        }
    }
    printf("fuzz: %d mutated frames rejected, %d decoded (flips inside values)\n", rejected, accepted);
    free(f);
    oc_buf_free(&buf);
    oc_encoder_free(e);
    oc_decoder_free(d);
}

/* ---- 7. temporal streams (codec 3) ---- */
static int cb(void *u, const struct oc_frame_header *h, const struct oc_tile_header *th, const float *s);

/* The vectors' streams: one decoder per stream, frames in order; each frame decodes
 * bit-exactly within its bound, or fails with the listed error. A receiver that joined
 * late (s02) gets the same samples as one that kept up (s01) at equal seq. */
static void test_stream_vectors(const char *dir)
{
    size_t mlen;
    char *mtext = (char *)read_all(dir, "manifest.json", &mlen);
    if (!mtext) return;   /* NUL-terminated by slurp */
    cJSON *m = cJSON_Parse(mtext);
    cJSON *streams = cJSON_GetObjectItem(m, "streams"), *st;
    int frames = 0, errors = 0, same = 0, packings[2] = { 0, 0 };
    float *chain_exp[64] = { 0 };   /* s01's expected samples by seq - 100 */
    size_t chain_len[64] = { 0 };
    cJSON_ArrayForEach(st, streams) {
        const char *name = cJSON_GetObjectItem(st, "name")->valuestring;
        struct oc_decoder *d = oc_decoder_new();
        cJSON *f;
        cJSON_ArrayForEach(f, cJSON_GetObjectItem(st, "frames")) {
            size_t blen, elen, ilen;
            uint8_t *bin = read_all(dir, cJSON_GetObjectItem(f, "file")->valuestring, &blen);
            struct oc_frame_header fh;
            cJSON *err = cJSON_GetObjectItem(f, "error");
            if (err) {
                int delivered = 0;
                int rc = oc_decode_frame(d, bin, blen, &fh, count_tile, &delivered);
                CHECK(strcmp(err_name(rc), err->valuestring) == 0 || (rc == OC_E_REFERENCE && !strcmp(err->valuestring, "reference")),
                      "%s: got %s, want %s", name, oc_strerror(rc), err->valuestring);
                errors++;
                free(bin);
                continue;
            }
            float *exp = (float *)read_all(dir, cJSON_GetObjectItem(f, "expected")->valuestring, &elen);
            float *in = (float *)read_all(dir, cJSON_GetObjectItem(f, "input")->valuestring, &ilen);
            cJSON *tiles = cJSON_GetObjectItem(f, "tiles"), *t;
            /* the vec_tile checker wants offset/scale/bound in the manifest: check samples here instead */
            struct { const float *exp, *in; size_t at, n; int bad; double maxerr; float bound; } c = { exp, in, 0, elen / 4, 0, 0, 0 };
            int rc = oc_decode_frame(d, bin, blen, &fh, cb, &c);
            CHECK(rc == OC_OK, "%s frame %d: %s", name, frames, oc_strerror(rc));
            CHECK(c.at == elen / 4 && !c.bad, "%s seq %llu: samples differ from expected (%zu of %zu)", name,
                  (unsigned long long)fh.seq, c.at, elen / 4);
            CHECK(c.maxerr <= c.bound, "%s: max error %g > bound", name, c.maxerr);
            CHECK(fh.seq == (uint64_t)cJSON_GetObjectItem(f, "seq")->valuedouble, "%s: seq", name);
            cJSON_ArrayForEach(t, tiles) {
                cJSON *pk = cJSON_GetObjectItem(t, "packing");
                if (pk) packings[pk->valueint & 1]++;
            }
            uint64_t k = fh.seq - 100;
            if (k < 64 && !strcmp(name, "s01_chain")) {
                chain_exp[k] = exp; chain_len[k] = elen; exp = NULL;
            } else if (k < 64 && !strcmp(name, "s02_join_skip") && chain_exp[k]) {
                CHECK(chain_len[k] == elen && !memcmp(chain_exp[k], exp, elen), "s02 seq %llu differs from s01", (unsigned long long)fh.seq);
                same++;
            }
            free(bin); free(exp); free(in);
            frames++;
        }
        oc_decoder_free(d);
    }
    for (int k = 0; k < 64; k++) free(chain_exp[k]);
    CHECK(frames >= 20 && errors >= 5 && same >= 8 && packings[0] && packings[1],
          "stream vectors: %d frames, %d errors, %d equal to s01, packings %d/%d", frames, errors, same, packings[0], packings[1]);
    printf("stream vectors: %d frames bit-exact, %d broken-chain/bad frames rejected, %d join frames equal to the chain\n",
           frames, errors, same);
    cJSON_Delete(m);
    free(mtext);
}

static int cb(void *u, const struct oc_frame_header *h, const struct oc_tile_header *th, const float *s)
{
    struct { const float *exp, *in; size_t at, n; int bad; double maxerr; float bound; } *c = u;
    size_t count = (size_t)th->width * th->height;
    if (c->at + count > c->n) { c->bad = 1; return 1; }
    if (memcmp(s, c->exp + c->at, count * 4)) c->bad = 1;
    for (size_t k = 0; k < count; k++) c->maxerr = fmax(c->maxerr, fabs((double)s[k] - c->in[c->at + k]));
    if (th->bound > c->bound) c->bound = th->bound;
    c->at += count;
    return 0;
}

/* A synthetic sea evolving in time: a few dispersive travelling waves (omega^2 = g k).
 * The phase term kx*x + kz*z is an integer j, so each wave's sine is tabulated once per
 * j (a few hundred per call instead of one per sample, where this test spent two thirds
 * of its time, and of its valgrind run); the same expression per value: the same bits. */
static void sea(float *f, int n, double t, double amp)
{
    static const double kx[5] = { 1, 2, -3, 4, 1 }, kz[5] = { 0, 1, 2, -1, 5 }, a[5] = { 1, 0.5, 0.3, 0.2, 0.1 };
    static double tab[5][6 * 255 + 1];   /* j spans (|kx| + |kz|) * (n - 1) + 1 <= 6 * 255 + 1 values */
    int j0[5];
    if (n < 1 || n > 256) abort();
    for (int m = 0; m < 5; m++) {
        double k = 2 * M_PI / 64.0 * sqrt(kx[m] * kx[m] + kz[m] * kz[m]);
        int lo = (int)((kx[m] < 0 ? kx[m] : 0) + (kz[m] < 0 ? kz[m] : 0)) * (n - 1);
        int hi = (int)((kx[m] > 0 ? kx[m] : 0) + (kz[m] > 0 ? kz[m] : 0)) * (n - 1);
        j0[m] = lo;
        for (int j = lo; j <= hi; j++)
            tab[m][j - lo] = sin(2 * M_PI * (double)j / n - sqrt(9.81 * k) * t + m);
    }
    for (int z = 0; z < n; z++)
        for (int x = 0; x < n; x++) {
            double v = 0;
            for (int m = 0; m < 5; m++)
                v += a[m] * tab[m][(int)(kx[m] * x + kz[m] * z) - j0[m]];
            f[(size_t)z * n + x] = (float)(amp * v);
        }
}

/* A receiver of a stream, following the daemon's rule (PROTOCOL.md §5.9): for each tick
 * it gets, the shared tiles if it received the previous `need` ticks, else the keyframe tiles. */
struct receiver {
    const char *name;
    struct oc_decoder *d;
    long last, run;
    int frames, keyframes, predicted;
};

struct bound_ctx { const float *fields[2]; int n; float bound[2]; double maxerr[2]; int codec3, tiles; };
static int bound_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th, const float *s)
{
    struct bound_ctx *c = user;
    int l = th->field == OC_FIELD_HEIGHT ? 0 : 1, step = 1 << th->lod;
    for (int j = 0; j < th->height; j++)
        for (int i = 0; i < th->width; i++) {
            float v = c->fields[l][((size_t)th->tile_z * fh->tile_size + (size_t)j * step) * c->n
                                   + (size_t)th->tile_x * fh->tile_size + (size_t)i * step];
            double e = fabs((double)s[(size_t)j * th->width + i] - v);
            if (!(e <= c->maxerr[l])) c->maxerr[l] = e;     /* NaN-safe */
        }
    c->codec3 += th->codec == OC_CODEC_TEMPORAL;
    c->tiles++;
    return 0;
}

static void test_stream_60s(void)
{
    enum { N = 64, TS = 16, GRID = N / TS, TICKS = 1800, NREC = 5 };
    const float bounds[2] = { 0.01f, 1e-4f };
    const int lods[2] = { 0, 1 };
    struct oc_encoder *e = oc_encoder_new();
    struct oc_stream *st[2];
    for (int l = 0; l < 2; l++) {
        st[l] = oc_stream_new(N, TS, lods[l], l ? OC_FIELD_JACOBIAN : OC_FIELD_HEIGHT, bounds[l]);
        oc_stream_set_keyframe_interval(st[l], 90);   /* periodic keyframes every 3 s, staggered */
    }
    const uint8_t *p;
    size_t plen;
    CHECK(oc_stream_tile(st[0], 0, 0, &p, &plen) == OC_E_ARG, "stream tile before any encode");
    CHECK(oc_stream_new(48, 16, 0, OC_FIELD_HEIGHT, 0.01f) == NULL, "stream with n 48 created");
    static const char *const names[NREC] = { "keeps up", "skips 10 %", "10 Hz", "rejoins", "ignores the rule" };
    struct receiver rec[NREC];
    memset(rec, 0, sizeof rec);
    for (int r = 0; r < NREC; r++) { rec[r].name = names[r]; rec[r].d = oc_decoder_new(); rec[r].last = -10; }
    static float f[2][N * N];
    struct oc_buf buf = { 0 };
    int ref_errors = 0, wrong = 0, bad_bound = 0, nan_tick = 1234;
    for (long k = 0; k < TICKS; k++) {
        uint64_t seq = 5000 + (uint64_t)k;
        double t = k / 30.0;
        sea(f[0], N, t, 1.5);
        /* the second layer grows 1000x at 40 s: its grid (bound 0.1 mm) no longer fits, new chains */
        sea(f[1], N, t + 3, k < 1200 ? 0.8 : 800.0);
        if (k == nan_tick) f[1][0] = NAN;   /* bad input: the stream resets, the next tick is a keyframe */
        int need = 0;
        for (int l = 0; l < 2; l++) {
            int rc = oc_stream_encode(st[l], e, f[l], seq);
            if (k == nan_tick && l == 1) {   /* rejected; the same tick again with valid data starts new chains */
                CHECK(rc == OC_E_ARG, "NaN input: %d", rc);
                f[1][0] = 0;
                rc = oc_stream_encode(st[l], e, f[l], seq);
                CHECK(oc_stream_need(st[l]) == 0, "after a reset: need %d", oc_stream_need(st[l]));
            }
            CHECK(rc == OC_OK, "stream encode tick %ld: %s", k, oc_strerror(rc));
            if (oc_stream_need(st[l]) > need) need = oc_stream_need(st[l]);
        }
        for (int r = 0; r < NREC; r++) {
            struct receiver *R = &rec[r];
            int gets = 1;
            if (r == 1) gets = rnd() % 10 != 0;                        /* latest-frame-wins drops */
            if (r == 2) gets = k % 3 == 0;                              /* max_rate 10 */
            if (r == 3 && k % 97 == 50) { oc_decoder_reset(R->d); R->run = 0; R->last = -10; }   /* resubscribe */
            if (r == 3) gets = k % 97 >= 50 || k % 97 < 30;             /* away 20 ticks of every 97 */
            if (r == 4) gets = rnd() % 7 != 0;
            if (!gets) continue;
            R->run = R->last == k - 1 ? R->run : 0;
            int key = r == 4 ? 0 : R->run < need;
            struct oc_frame_header fh = { .seq = seq, .sim_time = t, .n = N, .tile_size = TS, .patch_size = 64,
                                          .tile_count = 2 * GRID * GRID };
            buf.len = 0;
            oc_buf_reserve(&buf, OC_FRAME_HEADER_SIZE);
            oc_frame_header_write(buf.data, &fh);
            buf.len = OC_FRAME_HEADER_SIZE;
            for (int l = 0; l < 2; l++)
                for (int tz = 0; tz < GRID; tz++)
                    for (int tx = 0; tx < GRID; tx++) {
                        int rc = key ? oc_stream_keyframe_tile(st[l], e, tx, tz, &p, &plen) : oc_stream_tile(st[l], tx, tz, &p, &plen);
                        CHECK(rc == OC_OK, "stream tile: %s", oc_strerror(rc));
                        oc_buf_reserve(&buf, plen);
                        memcpy(buf.data + buf.len, p, plen);
                        buf.len += plen;
                    }
            struct bound_ctx c = { { f[0], f[1] }, N, { bounds[0], bounds[1] }, { 0, 0 }, 0, 0 };
            struct oc_frame_header out;
            int rc = oc_decode_frame(R->d, buf.data, buf.len, &out, bound_tile, &c);
            if (r == 4 && rc == OC_E_REFERENCE) { ref_errors++; R->run = 0; R->last = k; continue; }
            if (rc != OC_OK) { wrong++; CHECK(0, "%s: tick %ld (%s frame): %s", R->name, k, key ? "key" : "shared", oc_strerror(rc)); }
            else if (!(c.maxerr[0] <= bounds[0] && c.maxerr[1] <= bounds[1])) {
                bad_bound++;
                CHECK(0, "%s tick %ld: max error %g / %g over the bound", R->name, k, c.maxerr[0], c.maxerr[1]);
            }
            R->frames++;
            R->keyframes += key;
            R->predicted += c.codec3 > 0;
            R->last = k;
            R->run++;
        }
    }
    struct oc_stream_stats s0;
    oc_stream_stats(st[1], &s0);
    CHECK(rec[0].predicted > TICKS * 9 / 10 && rec[0].keyframes == 0, "keeps-up receiver: %d predicted of %d",
          rec[0].predicted, rec[0].frames);
    CHECK(rec[1].predicted > 0 && rec[1].keyframes > 0, "skipping receiver: %d predicted, %d keyframes", rec[1].predicted, rec[1].keyframes);
    CHECK(rec[2].frames == TICKS / 3 && rec[2].predicted == 0, "10 Hz receiver: %d frames, %d predicted",
          rec[2].frames, rec[2].predicted);
    CHECK(rec[3].predicted > 0 && rec[3].keyframes > 0, "rejoining receiver: %d predicted, %d keyframes", rec[3].predicted, rec[3].keyframes);
    CHECK(ref_errors > 10, "the receiver that ignores the rule saw only %d reference errors", ref_errors);
    /* A decoder that keeps no references (limit 0) decodes keyframes and reports every predicted frame. */
    struct oc_decoder *d0 = oc_decoder_new();
    oc_decoder_set_history_limit(d0, 0);
    struct oc_stream *s1 = oc_stream_new(N, N, 0, OC_FIELD_HEIGHT, 0.01f);
    for (int k = 0; k < 2; k++) {
        sea(f[0], N, k / 30.0, 1.5);
        oc_stream_encode(s1, e, f[0], 10 + (uint64_t)k);
        struct oc_frame_header fh1 = { .seq = 10 + (uint64_t)k, .n = N, .tile_size = N, .patch_size = 64, .tile_count = 1 };
        buf.len = 0;
        oc_buf_reserve(&buf, OC_FRAME_HEADER_SIZE);
        oc_frame_header_write(buf.data, &fh1);
        buf.len = OC_FRAME_HEADER_SIZE;
        oc_stream_tile(s1, 0, 0, &p, &plen);
        oc_buf_reserve(&buf, plen);
        memcpy(buf.data + buf.len, p, plen);
        buf.len += plen;
        struct oc_frame_header out0;
        int rc0 = oc_decode_frame(d0, buf.data, buf.len, &out0, NULL, NULL);
        CHECK(rc0 == (k ? OC_E_REFERENCE : OC_OK), "history limit 0, tick %d: %s", k, oc_strerror(rc0));
    }
    oc_stream_free(s1);
    oc_decoder_free(d0);
    CHECK(s0.key_tiles > 2 * (uint64_t)(GRID * GRID) * 20, "grid overflow / periodic keyframes: %llu key tiles",
          (unsigned long long)s0.key_tiles);
    printf("stream 60 s: %d ticks, receivers %d/%d/%d/%d frames all within the bound (%d wrong, %d over), "
           "%d reference errors for the rule breaker\n", TICKS, rec[0].frames, rec[1].frames, rec[2].frames, rec[3].frames,
           wrong, bad_bound, ref_errors);
    for (int r = 0; r < NREC; r++) oc_decoder_free(rec[r].d);
    for (int l = 0; l < 2; l++) oc_stream_free(st[l]);
    oc_buf_free(&buf);
    oc_encoder_free(e);
}

/* Tiny tiles (1x1, 2x2, 3 rows of odd width do not exist: tiles are square powers of two)
 * through a stream: the clamped Laplacian and odd pair counts at their edges. */
static void test_stream_tiny_tiles(void)
{
    enum { N = 16 };
    static float f[N * N];
    struct oc_encoder *e = oc_encoder_new();
    struct oc_buf buf = { 0 };
    const int cases[3][2] = { { 2, 1 }, { 4, 1 }, { 1, 0 } };   /* tile_size, lod: sides 1, 2, 1 */
    for (int c = 0; c < 3; c++) {
        int ts = cases[c][0], lod = cases[c][1], grid = N / ts, predicted = 0;
        struct oc_stream *st = oc_stream_new(N, ts, lod, OC_FIELD_DZ, 0.001f);
        struct oc_decoder *d = oc_decoder_new();
        double worst = 0;
        for (int k = 0; k < 12; k++) {
            sea(f, N, k / 30.0, 1.0);
            CHECK(oc_stream_encode(st, e, f, 40 + (uint64_t)k) == OC_OK, "tiny tiles: encode");
            struct oc_frame_header fh = { .seq = 40 + (uint64_t)k, .n = N, .tile_size = (uint16_t)ts, .patch_size = 16,
                                          .tile_count = (uint16_t)(grid * grid) };
            buf.len = 0;
            oc_buf_reserve(&buf, OC_FRAME_HEADER_SIZE);
            oc_frame_header_write(buf.data, &fh);
            buf.len = OC_FRAME_HEADER_SIZE;
            for (int tz = 0; tz < grid; tz++)
                for (int tx = 0; tx < grid; tx++) {
                    const uint8_t *p;
                    size_t len;
                    oc_stream_tile(st, tx, tz, &p, &len);
                    predicted += p[2] == OC_CODEC_TEMPORAL;
                    oc_buf_reserve(&buf, len);
                    memcpy(buf.data + buf.len, p, len);
                    buf.len += len;
                }
            struct bound_ctx bc = { { f, f }, N, { 0.001f, 0.001f }, { 0, 0 }, 0, 0 };
            struct oc_frame_header out;
            int rc = oc_decode_frame(d, buf.data, buf.len, &out, bound_tile, &bc);
            CHECK(rc == OC_OK, "tiny tiles ts %d lod %d tick %d: %s", ts, lod, k, oc_strerror(rc));
            worst = fmax(worst, fmax(bc.maxerr[0], bc.maxerr[1]));
        }
        CHECK(worst <= 0.001 && predicted > 0, "tiny tiles ts %d lod %d: max err %g, %d predicted", ts, lod, worst, predicted);
        oc_stream_free(st);
        oc_decoder_free(d);
    }
    oc_buf_free(&buf);
    oc_encoder_free(e);
}

/* Codes far from the usual: a large sea plus noise of thousands of metres (codes near 2^20,
 * residuals needing 3-byte escapes in both packings, and normal-equation sums past 2^51, so
 * the encoder's fit takes its sample-by-sample path). Every frame decodes within the bound. */
static void test_stream_wide_codes(void)
{
    enum { N = 128 };
    static float f[N * N];
    struct oc_encoder *e = oc_encoder_new();
    struct oc_stream *st = oc_stream_new(N, N, 0, OC_FIELD_HEIGHT, 0.01f);
    struct oc_decoder *d = oc_decoder_new();
    struct oc_buf buf = { 0 };
    int predicted = 0, escaped = 0;
    double worst = 0;
    for (int k = 0; k < 8; k++) {
        sea(f, N, k / 30.0, 4000.0);
        for (int i = 0; i < N * N; i++) f[i] += (float)(4000.0 * (2.0 * urand() - 1.0));
        CHECK(oc_stream_encode(st, e, f, 7 + (uint64_t)k) == OC_OK, "wide codes: encode");
        struct oc_frame_header fh = { .seq = 7 + (uint64_t)k, .n = N, .tile_size = N, .patch_size = 16, .tile_count = 1 };
        const uint8_t *p;
        size_t len;
        oc_stream_tile(st, 0, 0, &p, &len);
        if (p[2] == OC_CODEC_TEMPORAL) {
            predicted++;
            escaped += p[OC_TILE_HEADER_SIZE + 2] >= 3;   /* esc_width: residuals of 2^16 and more */
        }
        buf.len = 0;
        oc_buf_reserve(&buf, OC_FRAME_HEADER_SIZE + len);
        oc_frame_header_write(buf.data, &fh);
        memcpy(buf.data + OC_FRAME_HEADER_SIZE, p, len);
        buf.len = OC_FRAME_HEADER_SIZE + len;
        struct bound_ctx bc = { { f, f }, N, { 0.01f, 0.01f }, { 0, 0 }, 0, 0 };
        struct oc_frame_header out;
        int rc = oc_decode_frame(d, buf.data, buf.len, &out, bound_tile, &bc);
        CHECK(rc == OC_OK, "wide codes tick %d: %s", k, oc_strerror(rc));
        worst = fmax(worst, bc.maxerr[0]);
    }
    CHECK(worst <= 0.01 && predicted >= 6 && escaped == predicted, "wide codes: max err %g, %d predicted, %d escaped",
          worst, predicted, escaped);
    oc_buf_free(&buf);
    oc_stream_free(st);
    oc_decoder_free(d);
    oc_encoder_free(e);
}

/* One layer encoded by several threads (the daemon's encode pool): the stream
 * split into tile ranges, each range on its own thread and encoder, gives the
 * same bytes, need and counters as one oc_stream_encode call, through sea
 * changes, a reset, a gap in seq, a failing tile and keyframes on demand. */
struct range_job {
    struct oc_stream *s;
    struct oc_encoder *e;
    const float *f;
    int first, count, tick, rc;
};

/* A range, then the keyframes of a third of its tiles (before oc_stream_end, as the daemon's pool does). */
static void *range_main(void *arg)
{
    struct range_job *j = arg;
    j->rc = oc_stream_encode_tiles(j->s, j->e, j->f, j->first, j->count);
    const int grid = (int)sqrt((double)oc_stream_tile_count(j->s));
    for (int t = j->first; j->rc == OC_OK && t < j->first + j->count; t++) {
        const uint8_t *p;
        size_t len;
        /* not on the failing tick 36: keyframes the good ranges made would count, unlike the one-call path */
        if ((t + j->tick) % 3 == 0 && j->tick != 36 && oc_stream_keyframe_tile(j->s, j->e, t % grid, t / grid, &p, &len) != OC_OK)
            j->rc = OC_E_ARG;
    }
    return NULL;
}

static void test_stream_ranges(void)
{
    enum { N = 256, TS = 32, GRID = N / TS, TILES = GRID * GRID, THREADS = 3, TICKS = 48 };
    struct oc_encoder *e0 = oc_encoder_new(), *e[THREADS];
    for (int i = 0; i < THREADS; i++) e[i] = oc_encoder_new();
    struct oc_stream *a = oc_stream_new(N, TS, 0, OC_FIELD_HEIGHT, 0.01f);
    struct oc_stream *b = oc_stream_new(N, TS, 0, OC_FIELD_HEIGHT, 0.01f);
    oc_stream_set_keyframe_interval(a, 16);
    oc_stream_set_keyframe_interval(b, 16);
    CHECK(oc_stream_tile_count(b) == TILES, "tile count %d", oc_stream_tile_count(b));
    CHECK(oc_stream_encode_tiles(b, e[0], NULL, 0, 1) == OC_E_ARG, "range without data accepted");
    static float f[N * N];
    int same = 1, predicted = 0, failed_ticks = 0;
    uint64_t seq = 100;
    for (int k = 0; k < TICKS; k++) {
        sea(f, N, k / 30.0, k < 24 ? 1.5 : 2.5);
        if (k == 24) { oc_stream_sea_changed(a); oc_stream_sea_changed(b); }
        if (k == 32) { oc_stream_reset(a); oc_stream_reset(b); }
        seq += k == 40 ? 3 : 1;                              /* a gap: new chains */
        if (k == 36) f[(size_t)(N / 2) * N + 7] = NAN;        /* one tile fails: both streams reset */
        int ra = oc_stream_encode(a, e0, f, seq);
        /* b: ranges of random lengths in a shuffled order, THREADS at a time on real threads */
        int starts[TILES + 1], nr = 0;
        for (int t = 0; t < TILES; t += 1 + (int)(rnd() % 9)) starts[nr++] = t;
        starts[nr] = TILES;
        int order[TILES];
        for (int i = 0; i < nr; i++) order[i] = i;
        for (int i = nr - 1; i > 0; i--) { int j = (int)(rnd() % (uint32_t)(i + 1)), x = order[i]; order[i] = order[j]; order[j] = x; }
        oc_stream_begin(b, seq);
        const uint8_t *kp;
        size_t kl;
        CHECK(oc_stream_keyframe_tile(b, e[0], 0, 0, &kp, &kl) == OC_E_ARG, "keyframe of a tile not encoded yet");
        int rb_tiles = OC_OK;
        for (int i = 0; i < nr; i += THREADS) {
            struct range_job jobs[THREADS];
            pthread_t tid[THREADS];
            int nj = 0;
            for (; nj < THREADS && i + nj < nr; nj++) {
                int r = order[i + nj];
                jobs[nj] = (struct range_job){ b, e[nj], f, starts[r], starts[r + 1] - starts[r], k, 0 };
                pthread_create(&tid[nj], NULL, range_main, &jobs[nj]);
            }
            for (int x = 0; x < nj; x++) {
                pthread_join(tid[x], NULL);
                if (jobs[x].rc) rb_tiles = jobs[x].rc;
            }
        }
        int rb = oc_stream_end(b);
        if (k == 36) {
            f[(size_t)(N / 2) * N + 7] = 0;
            CHECK(ra != OC_OK && rb_tiles != OC_OK && rb != OC_OK, "NaN tile: %d / %d / %d", ra, rb_tiles, rb);
            failed_ticks++;
            continue;
        }
        CHECK(ra == OC_OK && rb == OC_OK && rb_tiles == OC_OK, "tick %d: %d / %d / %d", k, ra, rb_tiles, rb);
        same &= oc_stream_need(a) == oc_stream_need(b);
        predicted += oc_stream_need(a) > 0;
        for (int t = 0; t < TILES; t++) {
            const uint8_t *pa, *pb;
            size_t la, lb;
            oc_stream_tile(a, t % GRID, t / GRID, &pa, &la);
            oc_stream_tile(b, t % GRID, t / GRID, &pb, &lb);
            same &= la == lb && memcmp(pa, pb, la) == 0;
            if ((t + k) % 3 == 0) {   /* keyframes on demand: b's made by the range's thread */
                oc_stream_keyframe_tile(a, e0, t % GRID, t / GRID, &pa, &la);
                oc_stream_keyframe_tile(b, e[t % THREADS], t % GRID, t / GRID, &pb, &lb);
                same &= la == lb && memcmp(pa, pb, la) == 0;
            }
        }
        struct oc_stream_stats sa, sb;
        oc_stream_stats(a, &sa);
        oc_stream_stats(b, &sb);
        same &= memcmp(&sa, &sb, sizeof sa) == 0;
        if (!same) { CHECK(0, "tile ranges differ from one encode at tick %d", k); break; }
    }
    CHECK(same && failed_ticks == 1, "tile ranges: identical %d, failed ticks %d", same, failed_ticks);
    struct oc_stream_stats st;
    oc_stream_stats(b, &st);
    CHECK(predicted > 20 && st.predicted_tiles > 0 && st.key_tiles > (uint64_t)TILES && st.change_intra_tiles > 0
          && st.demand_key_tiles > 0,
          "tile ranges exercised too little: %d predicted ticks, %llu predicted / %llu key / %llu change / %llu demand tiles",
          predicted, (unsigned long long)st.predicted_tiles, (unsigned long long)st.key_tiles,
          (unsigned long long)st.change_intra_tiles, (unsigned long long)st.demand_key_tiles);
    oc_stream_free(a);
    oc_stream_free(b);
    oc_encoder_free(e0);
    for (int i = 0; i < THREADS; i++) oc_encoder_free(e[i]);
}

/* ---- 7. the Huffman-only DEFLATE writer (codec 1, level 1) ---- */

/* Raw inflate by zlib, a decoder independent of ours and of libdeflate:
 * 0 when src is one complete DEFLATE stream that inflates to exactly n bytes. */
static int zlib_inflate_exact(const uint8_t *src, size_t len, uint8_t *dst, size_t n)
{
    z_stream z;
    memset(&z, 0, sizeof z);
    if (inflateInit2(&z, -15) != Z_OK) return -1;
    uint8_t extra;
    z.next_in = (Bytef *)(uintptr_t)src;
    z.avail_in = (uInt)len;
    z.next_out = n ? dst : &extra;
    z.avail_out = n ? (uInt)n : 1;
    int rc = inflate(&z, Z_FINISH);
    int ok = rc == Z_STREAM_END && z.total_in == len && z.total_out == n;
    inflateEnd(&z);
    return ok ? 0 : -1;
}

/* Inputs of every shape the writer meets: residual-like (geometric), noise
 * (stored), one symbol, and Fibonacci frequencies whose optimal code is deeper
 * than DEFLATE's 15 bits (the length limit acts). Sizes around the writer's
 * three-literal groups and its 8-byte stores near the end of the buffer. */
static void fill_entropy_input(uint8_t *b, size_t n, int kind)
{
    static const uint32_t fib[24] = { 1, 1, 2, 3, 5, 8, 13, 21, 34, 55, 89, 144, 233, 377, 610, 987, 1597,
                                      2584, 4181, 6765, 10946, 17711, 28657, 46368 };
    for (size_t k = 0; k < n; k++) {
        if (kind == 0) { uint32_t g = 0; while (g < 254 && (rnd() & 3) == 0) g++; b[k] = (uint8_t)g; }
        else if (kind == 1) b[k] = (uint8_t)rnd();
        else if (kind == 2) b[k] = 7;
        else {
            uint32_t r = rnd() % 121392, s = 0;     /* 121392 = the sum of fib[0..23] */
            while (r >= fib[s]) r -= fib[s++];
            b[k] = (uint8_t)(s * 10);
        }
    }
}

static void test_entropy_writer(void)
{
    static const size_t sizes[] = { 0, 1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 17, 31, 100, 1000, 4095, 16384, 70001 };
    struct oc_entropy *c = oc_entropy_new();
    int types[4] = { 0 }, cases = 0;
    for (int kind = 0; kind < 4; kind++)
        for (size_t si = 0; si < sizeof sizes / sizeof sizes[0]; si++) {
            size_t n = sizes[si], cap = oc_entropy_bound(OC_CODEC_QUANT_LORENZO, n);
            uint8_t *src = malloc(n + 1), *big = malloc(cap), *back = malloc(n + 1);
            fill_entropy_input(src, n, kind);
            size_t len = oc_entropy_compress(c, OC_CODEC_QUANT_LORENZO, 1, src, n, big, cap);
            CHECK(len > 0 && len <= cap, "entropy kind %d n %zu: compressed to %zu of %zu", kind, n, len, cap);
            if (len == 0 || len > cap) goto next;
            types[(big[0] >> 1) & 3]++;
            CHECK(zlib_inflate_exact(big, len, back, n) == 0 && memcmp(back, src, n) == 0,
                  "entropy kind %d n %zu: zlib does not inflate the block to the input", kind, n);
            CHECK(oc_entropy_decompress(c, OC_CODEC_QUANT_LORENZO, big, len, back, n) == OC_OK && memcmp(back, src, n) == 0,
                  "entropy kind %d n %zu: our decoder does not read the block back", kind, n);
            /* Exactly enough room: the same bytes, and the 16 guard bytes after it untouched. */
            uint8_t *exact = malloc(len + 16);
            memset(exact, 0xa5, len + 16);
            size_t again = oc_entropy_compress(c, OC_CODEC_QUANT_LORENZO, 1, src, n, exact, len);
            int guard = 1;
            for (size_t k = len; k < len + 16; k++) guard &= exact[k] == 0xa5;
            CHECK(again == len && memcmp(exact, big, len) == 0 && guard,
                  "entropy kind %d n %zu: with a buffer of exactly %zu bytes got %zu (same bytes %d, guard intact %d)",
                  kind, n, len, again, again == len && memcmp(exact, big, len) == 0, guard);
            /* One byte short: no output, and nothing written past the buffer. */
            memset(exact, 0xa5, len + 16);
            size_t shorter = oc_entropy_compress(c, OC_CODEC_QUANT_LORENZO, 1, src, n, exact, len - 1);
            guard = 1;
            for (size_t k = len - 1; k < len + 16; k++) guard &= exact[k] == 0xa5;
            CHECK(shorter == 0 && guard, "entropy kind %d n %zu: a buffer one byte short gave %zu (guard intact %d)",
                  kind, n, shorter, guard);
            free(exact);
            cases++;
        next:
            free(src); free(big); free(back);
        }
    CHECK(types[0] > 0 && types[1] > 0 && types[2] > 0, "entropy writer: stored %d, fixed %d, dynamic %d blocks",
          types[0], types[1], types[2]);
    printf("entropy writer: %d inputs read back by zlib (%d stored, %d fixed, %d dynamic blocks), exact and short buffers respected\n",
           cases, types[0], types[1], types[2]);
    oc_entropy_free(c);
}

int main(int argc, char **argv)
{
    if (argc != 2) { fprintf(stderr, "usage: test_proto VECTOR_DIR\n"); return 2; }
    test_vectors(argv[1]);
    test_headers();
    test_bounds();
    test_fuzz();
    test_stream_vectors(argv[1]);
    test_stream_60s();
    test_stream_tiny_tiles();
    test_stream_wide_codes();
    test_stream_ranges();
    test_entropy_writer();
    return check_done();
}

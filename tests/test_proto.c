/* test_proto.c — oceand wire protocol and tile codec tests.
 *   test_proto VECTOR_DIR
 * 1. every checked-in vector decodes to exactly the expected float32 bits,
 *    with the headers the manifest lists, and within its bound of the input;
 * 2. every bad input is rejected with the listed error;
 * 3. header round trips; 4. random smooth/noisy fields at several bounds,
 *    LODs and both lossy codecs stay within the bound; 5. edge cases (NaN,
 *    huge range, constant, float32 resolution); 6. random truncations and bit
 *    flips never crash (run under ASan by test-proto-asan). */
#include "oc_proto.h"

#include <cjson/cJSON.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int failures, checks;
static void fail(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "FAIL: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    failures++;
}
#define CHECK(cond, ...) do { checks++; if (!(cond)) fail(__VA_ARGS__); } while (0)

static unsigned long long rng = 0x2545F4914F6CDD1Dull;
static uint32_t rnd(void) { rng ^= rng << 13; rng ^= rng >> 7; rng ^= rng << 17; return (uint32_t)(rng >> 32); }
static double urand(void) { return rnd() * 0x1p-32; }

static uint8_t *read_all(const char *dir, const char *name, size_t *len)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "rb");
    if (!f) { fail("cannot open %s", path); return NULL; }
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    uint8_t *p = malloc(n > 0 ? (size_t)n : 1);
    if (fread(p, 1, (size_t)n, f) != (size_t)n) { fail("short read %s", path); }
    fclose(f);
    *len = (size_t)n;
    return p;
}

/* ---- 1. vectors ---- */
struct vec_ctx { const char *name; cJSON *tiles; int index; const float *expected, *input; size_t nexp; };

static int vec_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th, const float *s)
{
    struct vec_ctx *c = user;
    cJSON *t = cJSON_GetArrayItem(c->tiles, c->index++);
    if (!t) { fail("%s: more tiles than the manifest lists", c->name); return 1; }
    const char *field = cJSON_GetObjectItem(t, "field")->valuestring;
    CHECK(strcmp(oc_field_name((enum oc_field)th->field), field) == 0, "%s: field %d vs %s", c->name, th->field, field);
    CHECK(th->lod == cJSON_GetObjectItem(t, "lod")->valueint, "%s: lod", c->name);
    CHECK(th->codec == cJSON_GetObjectItem(t, "codec")->valueint, "%s: codec", c->name);
    CHECK(th->tile_x == cJSON_GetObjectItem(t, "tileX")->valueint, "%s: tile_x", c->name);
    CHECK(th->tile_z == cJSON_GetObjectItem(t, "tileZ")->valueint, "%s: tile_z", c->name);
    CHECK(th->width == cJSON_GetObjectItem(t, "width")->valueint, "%s: width", c->name);
    CHECK(th->height == cJSON_GetObjectItem(t, "height")->valueint, "%s: height", c->name);
    CHECK(th->offset == cJSON_GetObjectItem(t, "offset")->valuedouble, "%s: offset", c->name);
    CHECK(th->scale == cJSON_GetObjectItem(t, "scale")->valuedouble, "%s: scale", c->name);
    CHECK(th->bound == (float)cJSON_GetObjectItem(t, "bound")->valuedouble, "%s: bound", c->name);
    size_t at = (size_t)cJSON_GetObjectItem(t, "sampleOffset")->valuedouble, count = (size_t)th->width * th->height;
    if (at + count > c->nexp) { fail("%s: expected file too short", c->name); return 1; }
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
    default: return oc_strerror(rc);
    }
}

static void test_vectors(const char *dir)
{
    size_t mlen;
    char *mtext = (char *)read_all(dir, "manifest.json", &mlen);
    if (!mtext) return;
    mtext = realloc(mtext, mlen + 1);
    mtext[mlen] = 0;
    cJSON *m = cJSON_Parse(mtext);
    if (!m) { fail("manifest.json does not parse"); free(mtext); return; }
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
            if (rc) { fail("encode: %s", oc_strerror(rc)); return -1; }
        }
    memset(c, 0, sizeof *c);
    c->field = f; c->n = n; c->bound = bound;
    struct oc_frame_header out;
    int rc = oc_decode_frame(d, buf->data, buf->len, &out, cmp_tile, c);
    if (rc) { fail("decode of a fresh encode: %s", oc_strerror(rc)); return -1; }
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
                CHECK(rc <= 0 && rc >= OC_E_TOO_LARGE, "fuzz: unexpected return %d", rc);
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

int main(int argc, char **argv)
{
    if (argc != 2) { fprintf(stderr, "usage: test_proto VECTOR_DIR\n"); return 2; }
    test_vectors(argv[1]);
    test_headers();
    test_bounds();
    test_fuzz();
    printf("%d checks, %d failed\n", checks, failures);
    if (failures) { printf("test_proto: FAILED\n"); return 1; }
    printf("test_proto: OK\n");
    return 0;
}

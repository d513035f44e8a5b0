/* gen_vectors.c — writes proto/vectors/: encoded frames (.bin), the exact
 * decoded samples (.expected.f32, all tiles in frame order, little-endian),
 * the encoder's input samples (.input.f32, same order, to check bounds), bad
 * inputs, and manifest.json. Deterministic: same output on every run.
 * Usage: gen_vectors DIR */
#include "oc_internal.h" /* OC_LOSSY_PREFIX and the integer pipeline, for the crafted vector */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static unsigned long long rng = 88172645463325252ull;
static double urand(void)
{
    rng ^= rng << 13; rng ^= rng >> 7; rng ^= rng << 17;
    return (rng >> 11) * 0x1p-53;
}

/* A smooth periodic sea-like field plus optional noise. */
static float *make_field(int n, double amp, double noise, double bias)
{
    float *f = malloc(sizeof(float) * n * n);
    for (int z = 0; z < n; z++)
        for (int x = 0; x < n; x++) {
            double a = 2 * M_PI * x / n, b = 2 * M_PI * z / n;
            double v = amp * (0.6 * sin(a + 0.3) + 0.3 * sin(2 * a + 3 * b + 1.1) + 0.1 * cos(5 * b - 4 * a));
            f[(size_t)z * n + x] = (float)(bias + v + noise * (urand() - 0.5));
        }
    return f;
}

struct tile_req { const float *data; int tx, tz, lod, field; float bound; int codec; int cascade; };

static FILE *manifest;
static const char *dir;
static int first_vector = 1;

static void write_file(const char *name, const void *p, size_t len)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(p, 1, len, f) != len || fclose(f)) { perror(path); exit(1); }
}

/* Floating bodies for the next emit (PROTOCOL.md §3.5): its header gets a
 * BODY section and its manifest entry the records a decoder must read. */
static const struct oc_body_record *emit_bodies;
static int emit_nbodies;

static void emit(const char *name, const char *desc, int n, int ts, const struct tile_req *reqs, int count,
                 struct oc_buf *keep)
{
    struct oc_encoder *e = oc_encoder_new();
    struct oc_buf buf = { 0 };
    struct oc_frame_header fh = { .seq = 1000 + (uint64_t)count, .sim_time = 12.5, .params_version = 3,
                                  .n = (uint16_t)n, .tile_size = (uint16_t)ts, .patch_size = 256.0f,
                                  .tile_count = (uint16_t)count, .flags = 0,
                                  .server_time_us = 1763719200000000ull };
    size_t hs = OC_FRAME_HEADER_SIZE + (emit_nbodies ? oc_body_section_size(emit_nbodies) : 0);
    oc_buf_reserve(&buf, hs);
    oc_frame_header_write(buf.data, &fh);
    if (emit_nbodies) { /* header_size covers the section */
        buf.data[6] = (uint8_t)hs;
        buf.data[7] = (uint8_t)(hs >> 8);
        oc_body_section_write(buf.data + OC_FRAME_HEADER_SIZE, emit_bodies, emit_nbodies);
    }
    buf.len = hs;
    /* Input samples gathered the way the encoder does, for the bound check. */
    size_t total = 0;
    for (int i = 0; i < count; i++) total += (size_t)(ts >> reqs[i].lod) * (ts >> reqs[i].lod);
    float *input = malloc(sizeof(float) * total), *expected = malloc(sizeof(float) * total);
    size_t at = 0;
    fprintf(manifest, "%s\n    {\"name\":\"%s\",\"description\":\"%s\",\"file\":\"%s.bin\","
            "\"expected\":\"%s.expected.f32\",\"input\":\"%s.input.f32\",\n     \"header\":{\"seq\":%llu,"
            "\"simTime\":%.17g,\"paramsVersion\":%u,\"n\":%d,\"tileSize\":%d,\"patchSize\":%.9g,"
            "\"tileCount\":%d,\"flags\":0,\"serverTimeUs\":%llu},\n     \"tiles\":[",
            first_vector ? "" : ",", name, desc, name, name, name, (unsigned long long)fh.seq, fh.sim_time,
            fh.params_version, n, ts, fh.patch_size, count, (unsigned long long)fh.server_time_us);
    first_vector = 0;
    for (int i = 0; i < count; i++) {
        const struct tile_req *r = &reqs[i];
        oc_encoder_set_codec(e, r->codec ? (enum oc_codec)r->codec : OC_CODEC_QUANT_LORENZO, 0);
        size_t before = buf.len;
        int rc = oc_encode_tile_cascade(e, r->data, n, ts, r->tx, r->tz, r->lod, (enum oc_field)r->field, r->bound,
                                        r->cascade, &buf);
        if (rc) { fprintf(stderr, "%s: encode: %s\n", name, oc_strerror(rc)); exit(1); }
        int side = ts >> r->lod, step = 1 << r->lod;
        for (int j = 0; j < side; j++)
            for (int k = 0; k < side; k++)
                input[at + (size_t)j * side + k] =
                    r->data[((size_t)r->tz * ts + (size_t)j * step) * n + (size_t)r->tx * ts + (size_t)k * step];
        /* Read back what the encoder chose (codec may fall back to raw). */
        const uint8_t *th = buf.data + before;
        double off, sc; float bnd;
        memcpy(&bnd, th + 12, 4); memcpy(&off, th + 16, 8); memcpy(&sc, th + 24, 8);
        fprintf(manifest, "%s\n       {\"field\":\"%s\",\"lod\":%d,\"codec\":%d,\"tileX\":%d,\"tileZ\":%d,"
                "\"width\":%d,\"height\":%d,\"bound\":%.9g,\"offset\":%.17g,\"scale\":%.17g,"
                "\"cascade\":%d,\"sampleOffset\":%zu}", i ? "," : "", oc_field_name((enum oc_field)r->field), r->lod,
                th[2], r->tx, r->tz, side, side, bnd, off, sc, r->cascade, at);
        at += (size_t)side * side;
    }
    fprintf(manifest, "]");
    if (emit_nbodies) {
        fprintf(manifest, ",\n     \"headerSize\":%zu,\"bodies\":[", hs);
        for (int i = 0; i < emit_nbodies; i++) {
            const struct oc_body_record *b = &emit_bodies[i];
            fprintf(manifest, "%s\n       {\"id\":%u,\"kind\":%u,\"flags\":%u,\"throttle\":%d,\"rudder\":%d,"
                    "\"pos\":[%.9g,%.9g,%.9g],\"quat\":[%.9g,%.9g,%.9g,%.9g],\"vel\":[%.9g,%.9g,%.9g]}", i ? "," : "",
                    b->id, b->kind, b->flags, b->throttle, b->rudder, b->pos[0], b->pos[1], b->pos[2], b->quat[0],
                    b->quat[1], b->quat[2], b->quat[3], b->vel[0], b->vel[1], b->vel[2]);
        }
        fprintf(manifest, "]");
    }
    fprintf(manifest, "}");
    /* Expected output = what this library's decoder produces; the tests check it against input. */
    struct oc_decoder *d = oc_decoder_new();
    struct oc_frame_header out;
    struct { float *dst; size_t at; } ctx = { expected, 0 };
    int decode_cb(void *u, const struct oc_frame_header *h, const struct oc_tile_header *t, const float *s);
    int rc = oc_decode_frame(d, buf.data, buf.len, &out, decode_cb, &ctx);
    if (rc) { fprintf(stderr, "%s: decode: %s\n", name, oc_strerror(rc)); exit(1); }
    char fn[256];
    snprintf(fn, sizeof fn, "%s.bin", name); write_file(fn, buf.data, buf.len);
    snprintf(fn, sizeof fn, "%s.expected.f32", name); write_file(fn, expected, sizeof(float) * total);
    snprintf(fn, sizeof fn, "%s.input.f32", name); write_file(fn, input, sizeof(float) * total);
    if (keep) { oc_buf_reserve(keep, buf.len); memcpy(keep->data, buf.data, buf.len); keep->len = buf.len; }
    oc_decoder_free(d); oc_encoder_free(e); oc_buf_free(&buf);
    free(input); free(expected);
}

int decode_cb(void *u, const struct oc_frame_header *h, const struct oc_tile_header *t, const float *s)
{
    struct { float *dst; size_t at; } *ctx = u;
    memcpy(ctx->dst + ctx->at, s, sizeof(float) * t->width * t->height);
    ctx->at += (size_t)t->width * t->height;
    return 0;
}

/* A hand-built lossy tile the encoder would never produce: codes near 2^30,
 * extreme coefficients (predictions need the int32 clamp, residuals wrap
 * modulo 2^32, 4-byte escapes). Checks that every decoder follows the
 * integer rules of PROTOCOL.md to the bit, not just on friendly data. */
static void emit_crafted(void)
{
    const int n = 16, ts = 16, side = 16, count = side * side;
    static int32_t q[256];
    static uint32_t zz[256], esc[256];
    static uint8_t packed[256 * 5], frame[8192];
    static float vals[256];
    const int8_t coef[OC_PRED_COEFS] = { 127, -128, 127, -128, 127, 127 };
    const double offset = 0.5, scale = 1e-9;
    for (int j = 0; j < side; j++)
        for (int i = 0; i < side; i++)
            q[j * side + i] = (int32_t)(((i * 7919 + j * 104729) % 2001 - 1000) * 1000000);
    oc_predict_residuals(q, side, side, coef, zz);
    int esc_width;
    size_t esc_count = oc_pack_escapes(zz, count, packed, esc, &esc_width);
    size_t plain = count + esc_count * (size_t)esc_width;
    struct oc_entropy *ent = oc_entropy_new();
    uint8_t *payload = frame + OC_FRAME_HEADER_SIZE + OC_TILE_HEADER_SIZE;
    memset(payload, 0, OC_LOSSY_PREFIX);
    payload[0] = (uint8_t)esc_width;
    payload[4] = (uint8_t)esc_count; payload[5] = (uint8_t)(esc_count >> 8);
    memcpy(payload + 8, coef, OC_PRED_COEFS);
    size_t clen = oc_entropy_compress(ent, OC_CODEC_QUANT_LORENZO, 1, packed, plain, payload + OC_LOSSY_PREFIX,
                                      sizeof frame - 200);
    oc_entropy_free(ent);
    struct oc_frame_header fh = { .seq = 77, .sim_time = 1.0, .params_version = 1, .n = n, .tile_size = ts,
                                  .patch_size = 16.0f, .tile_count = 1 };
    oc_frame_header_write(frame, &fh);
    struct oc_tile_header th = { .field = OC_FIELD_HEIGHT, .codec = OC_CODEC_QUANT_LORENZO, .width = side,
                                 .height = side, .bound = (float)(scale / 2), .offset = offset, .scale = scale,
                                 .payload_len = (uint32_t)(OC_LOSSY_PREFIX + clen) };
    oc_tile_header_write(frame + OC_FRAME_HEADER_SIZE, &th);
    size_t len = OC_FRAME_HEADER_SIZE + OC_TILE_HEADER_SIZE + th.payload_len;
    for (int k = 0; k < count; k++) vals[k] = oc_dequant(q[k], offset, scale);
    write_file("v11_crafted.bin", frame, len);
    write_file("v11_crafted.expected.f32", vals, sizeof vals);
    write_file("v11_crafted.input.f32", vals, sizeof vals);
    fprintf(manifest, ",\n    {\"name\":\"v11_crafted\",\"description\":\"hand-built: codes ~1e9, coefficients "
            "127/-128 (clamped predictions, wrapped residuals), %zu escapes of %d bytes\",\"file\":\"v11_crafted.bin\","
            "\"expected\":\"v11_crafted.expected.f32\",\"input\":\"v11_crafted.input.f32\",\n     \"header\":{\"seq\":77,"
            "\"simTime\":1,\"paramsVersion\":1,\"n\":16,\"tileSize\":16,\"patchSize\":16,\"tileCount\":1,\"flags\":0,"
            "\"serverTimeUs\":0},\n     \"tiles\":[\n       {\"field\":\"height\",\"lod\":0,\"codec\":1,\"tileX\":0,"
            "\"tileZ\":0,\"width\":16,\"height\":16,\"bound\":%.9g,\"offset\":0.5,\"scale\":%.17g,\"sampleOffset\":0}]}",
            esc_count, esc_width, th.bound, scale);
}

/* ---- temporal streams (codec 3): frames decoded in order by one decoder ---- */

/* A sea-like field at time t: travelling waves (for the temporal predictor). */
static void wave_field(float *f, int n, double t, double amp, double bias)
{
    for (int z = 0; z < n; z++)
        for (int x = 0; x < n; x++) {
            double a = 2 * M_PI * x / n, b = 2 * M_PI * z / n;
            double v = amp * (0.6 * sin(a + 0.3 - 1.1 * t) + 0.3 * sin(2 * a + 3 * b + 1.1 - 2.3 * t)
                              + 0.1 * cos(5 * b - 4 * a - 3.7 * t));
            f[(size_t)z * n + x] = (float)(bias + v);
        }
}

#define S_N 16
#define S_TS 8
#define S_TICKS 12
#define S_SEQ0 100
struct s_layer { enum oc_field field; int lod; float bound; struct oc_stream *st; };
static struct s_layer s_layers[2] = { { OC_FIELD_HEIGHT, 0, 0.01f, NULL }, { OC_FIELD_DX, 1, 0.0001f, NULL } };
static float s_fields[S_TICKS][2][S_N * S_N];

/* The frame a receiver gets at tick k: the shared tiles, or this tick's keyframe tiles. */
static void stream_frame(struct oc_encoder *e, int k, int keyframes, struct oc_buf *buf)
{
    const int grid = S_N / S_TS;
    struct oc_frame_header fh = { .seq = S_SEQ0 + (uint64_t)k, .sim_time = k / 30.0, .params_version = 3,
                                  .n = S_N, .tile_size = S_TS, .patch_size = 16.0f,
                                  .tile_count = (uint16_t)(2 * grid * grid), .server_time_us = 1763719200000000ull };
    buf->len = 0;
    oc_buf_reserve(buf, OC_FRAME_HEADER_SIZE);
    oc_frame_header_write(buf->data, &fh);
    buf->len = OC_FRAME_HEADER_SIZE;
    for (int l = 0; l < 2; l++)
        for (int tz = 0; tz < grid; tz++)
            for (int tx = 0; tx < grid; tx++) {
                const uint8_t *p;
                size_t len;
                int rc = keyframes ? oc_stream_keyframe_tile(s_layers[l].st, e, tx, tz, &p, &len)
                                   : oc_stream_tile(s_layers[l].st, tx, tz, &p, &len);
                if (rc) { fprintf(stderr, "stream tile: %s\n", oc_strerror(rc)); exit(1); }
                oc_buf_reserve(buf, len);
                memcpy(buf->data + buf->len, p, len);
                buf->len += len;
            }
}

struct s_out { const char *name; struct oc_decoder *d; int nframes; };
static int first_stream = 1;

static void s_begin(struct s_out *o, const char *name, const char *desc)
{
    o->name = name;
    o->d = oc_decoder_new();
    o->nframes = 0;
    fprintf(manifest, "%s\n    {\"name\":\"%s\",\"description\":\"%s\",\"frames\":[", first_stream ? "" : ",", name, desc);
    first_stream = 0;
}

static void s_end(struct s_out *o)
{
    fprintf(manifest, "]}");
    oc_decoder_free(o->d);
}

/* One frame of a stream: decode it with the stream's decoder; want = NULL (must decode:
 * expected and input written) or the error it must give. */
static void s_frame_n(struct s_out *o, const uint8_t *data, size_t len, int k, int n, int ts);
static void s_frame(struct s_out *o, const uint8_t *data, size_t len, int k, const char *want)
{
    if (!want) { s_frame_n(o, data, len, k, S_N, S_TS); return; }
    char fn[256];
    snprintf(fn, sizeof fn, "%s_%02d.bin", o->name, o->nframes);
    write_file(fn, data, len);
    fprintf(manifest, "%s\n      {\"file\":\"%s\"", o->nframes ? "," : "", fn);
    float expected[2 * S_N * S_N];
    struct { float *dst; size_t at; } ctx = { expected, 0 };
    struct oc_frame_header fh;
    int rc = oc_decode_frame(o->d, data, len, &fh, decode_cb, &ctx);
    if (want) {
        const char *got = rc == OC_E_REFERENCE ? "reference" : rc == OC_E_CORRUPT ? "corrupt" : "?";
        if (strcmp(got, want)) { fprintf(stderr, "%s frame %d: %s, want %s\n", o->name, o->nframes, oc_strerror(rc), want); exit(1); }
        fprintf(manifest, ",\"error\":\"%s\"}", want);
        o->nframes++;
        return;
    }
    fprintf(stderr, "%s frame %d: unreachable\n", o->name, o->nframes);
    exit(1);
}

/* A frame of a stream that must decode (fields n x n, tiles ts): expected and input written. */
static void s_frame_n(struct s_out *o, const uint8_t *data, size_t len, int k, int n, int ts)
{
    char fn[256];
    snprintf(fn, sizeof fn, "%s_%02d.bin", o->name, o->nframes);
    write_file(fn, data, len);
    fprintf(manifest, "%s\n      {\"file\":\"%s\"", o->nframes ? "," : "", fn);
    float expected[2 * S_N * S_N], input[2 * S_N * S_N];
    struct { float *dst; size_t at; } ctx = { expected, 0 };
    struct oc_frame_header fh;
    int rc = oc_decode_frame(o->d, data, len, &fh, decode_cb, &ctx);
    if (rc) { fprintf(stderr, "%s frame %d: %s\n", o->name, o->nframes, oc_strerror(rc)); exit(1); }
    /* Tiles and inputs in frame order. */
    fprintf(manifest, ",\"expected\":\"%s_%02d.expected.f32\",\"input\":\"%s_%02d.input.f32\",\"seq\":%llu,\"tiles\":[",
            o->name, o->nframes, o->name, o->nframes, (unsigned long long)fh.seq);
    size_t pos = OC_FRAME_HEADER_SIZE, at = 0;
    for (int t = 0; t < fh.tile_count; t++) {
        const uint8_t *th = data + pos;
        int field = th[0], lod = th[1], codec = th[2], tx = th[4] | th[5] << 8, tz = th[6] | th[7] << 8;
        int side = ts >> lod, step = 1 << lod, l = field == OC_FIELD_HEIGHT ? 0 : 1;
        uint32_t plen;
        memcpy(&plen, th + 32, 4);
        const uint8_t *pl = th + OC_TILE_HEADER_SIZE;
        fprintf(manifest, "%s{\"field\":\"%s\",\"lod\":%d,\"codec\":%d,\"tileX\":%d,\"tileZ\":%d,\"width\":%d,"
                "\"sampleOffset\":%zu", t ? "," : "", oc_field_name((enum oc_field)field), lod, codec, tx, tz, side, at);
        if (codec == OC_CODEC_TEMPORAL) {
            uint64_t ref;
            memcpy(&ref, pl + 16, 8);
            fprintf(manifest, ",\"depth\":%d,\"packing\":%d,\"refSeq\":%llu", pl[0], pl[1], (unsigned long long)ref);
        }
        fprintf(manifest, "}");
        for (int j = 0; j < side; j++)
            for (int i = 0; i < side; i++)
                input[at + (size_t)j * side + i] =
                    s_fields[k][l][((size_t)tz * ts + (size_t)j * step) * n + (size_t)tx * ts + (size_t)i * step];
        at += (size_t)side * side;
        pos += OC_TILE_HEADER_SIZE + plen;
    }
    fprintf(manifest, "]}");
    snprintf(fn, sizeof fn, "%s_%02d.expected.f32", o->name, o->nframes); write_file(fn, expected, sizeof(float) * at);
    snprintf(fn, sizeof fn, "%s_%02d.input.f32", o->name, o->nframes); write_file(fn, input, sizeof(float) * at);
    o->nframes++;
}

static void emit_streams(void)
{
    struct oc_encoder *e = oc_encoder_new();
    /* Grid refinement 1 (one valid code per sample): the vectors and the worked example of
     * §8.2 predate it; a refined stream is the same format (tests/test_proto.c decodes one). */
    for (int l = 0; l < 2; l++) {
        s_layers[l].st = oc_stream_new(S_N, S_TS, s_layers[l].lod, s_layers[l].field, s_layers[l].bound);
        oc_stream_set_grid_refine(s_layers[l].st, 1);
    }
    struct s_out chain, join, broken, mismatch, badcoef;
    struct oc_buf buf = { 0 }, frames[S_TICKS];
    memset(frames, 0, sizeof frames);
    /* Receiver B joins at tick 2 and misses tick 7 (latest-frame-wins): it gets this tick's
     * keyframe tiles until it has held the layer for `need` consecutive ticks. */
    int run_b = 0, last_b = -2;
    struct oc_buf bframes[S_TICKS];
    int bticks[S_TICKS], nb = 0;
    memset(bframes, 0, sizeof bframes);
    for (int k = 0; k < S_TICKS; k++) {
        for (int l = 0; l < 2; l++) {
            wave_field(s_fields[k][l], S_N, k / 30.0 * 4, l ? 0.7 : 1.5, l ? 0.1 : 0);
            if (oc_stream_encode(s_layers[l].st, e, s_fields[k][l], S_SEQ0 + (uint64_t)k)) { fprintf(stderr, "stream encode\n"); exit(1); }
        }
        stream_frame(e, k, 0, &frames[k]);
        if (k >= 2 && k != 7) {
            int need = oc_stream_need(s_layers[0].st) > oc_stream_need(s_layers[1].st) ? oc_stream_need(s_layers[0].st)
                                                                                       : oc_stream_need(s_layers[1].st);
            run_b = last_b == k - 1 ? run_b : 0;
            stream_frame(e, k, run_b < need, &bframes[nb]);
            bticks[nb++] = k;
            run_b++;
            last_b = k;
        }
    }
    s_begin(&chain, "s01_chain", "a receiver that keeps up: keyframe, then predicted tiles of depth 1, 2, 3, 4 (height 1 cm, pair packing; dx LOD 1 at 0.1 mm, byte packing)");
    for (int k = 0; k < S_TICKS; k++) s_frame(&chain, frames[k].data, frames[k].len, k, NULL);
    s_end(&chain);
    s_begin(&join, "s02_join_skip", "a receiver that joins at seq 102 and misses seq 107: keyframe tiles (codec 1 on the chain's grid) until it holds 4 consecutive ticks, then the shared predicted tiles; same samples as s01 at equal seq");
    for (int i = 0; i < nb; i++) s_frame(&join, bframes[i].data, bframes[i].len, bticks[i], NULL);
    s_end(&join);
    s_begin(&broken, "s03_broken_chain", "seq 102 missing: the predicted tiles of seq 103 name it as a reference, a decoder reports reference (and again for 104, whose reference 103 was rejected)");
    s_frame(&broken, frames[0].data, frames[0].len, 0, NULL);
    s_frame(&broken, frames[1].data, frames[1].len, 1, NULL);
    s_frame(&broken, frames[3].data, frames[3].len, 3, "reference");
    s_frame(&broken, frames[4].data, frames[4].len, 4, "reference");
    s_end(&broken);
    s_begin(&mismatch, "s04_grid_mismatch", "seq 101 with the first tile's offset changed by one ulp: its reference is on another grid (reference); the rejected frame changes nothing, the intact seq 101 then decodes");
    s_frame(&mismatch, frames[0].data, frames[0].len, 0, NULL);
    oc_buf_reserve(&buf, frames[1].len);
    memcpy(buf.data, frames[1].data, frames[1].len);
    buf.data[OC_FRAME_HEADER_SIZE + 16] ^= 1;
    s_frame(&mismatch, buf.data, frames[1].len, 1, "reference");
    s_frame(&mismatch, frames[1].data, frames[1].len, 1, NULL);
    s_end(&mismatch);
    s_begin(&badcoef, "s05_bad_prefix", "seq 101 (depth 1) with a d1 coefficient, then with depth 5: corrupt (checked before the references)");
    s_frame(&badcoef, frames[0].data, frames[0].len, 0, NULL);
    memcpy(buf.data, frames[1].data, frames[1].len);
    buf.data[OC_FRAME_HEADER_SIZE + OC_TILE_HEADER_SIZE + 24] = 1;
    s_frame(&badcoef, buf.data, frames[1].len, 1, "corrupt");
    memcpy(buf.data, frames[1].data, frames[1].len);
    buf.data[OC_FRAME_HEADER_SIZE + OC_TILE_HEADER_SIZE] = 5;
    s_frame(&badcoef, buf.data, frames[1].len, 1, "corrupt");
    s_end(&badcoef);
    /* The worked example of PROTOCOL.md §8.2: one 4x4 height tile, keyframe then depth 1 and 2. */
    {
        struct oc_stream *tiny = oc_stream_new(4, 4, 0, OC_FIELD_HEIGHT, 0.01f);
        oc_stream_set_grid_refine(tiny, 1);
        struct s_out ex;
        s_begin(&ex, "s06_tiny", "the PROTOCOL.md worked example: a 4x4 height tile at 1 cm, keyframe (seq 7), then depth 1 (seq 8) and depth 2 (seq 9)");
        for (int k = 0; k < 3; k++) {
            wave_field(s_fields[k][0], 4, k * 0.2, 1.0, 0);
            if (oc_stream_encode(tiny, e, s_fields[k][0], 7 + (uint64_t)k)) exit(1);
            const uint8_t *p;
            size_t len;
            oc_stream_tile(tiny, 0, 0, &p, &len);
            struct oc_frame_header fh = { .seq = 7 + (uint64_t)k, .sim_time = k * 0.2, .params_version = 1, .n = 4,
                                          .tile_size = 4, .patch_size = 4.0f, .tile_count = 1 };
            buf.len = 0;
            oc_buf_reserve(&buf, OC_FRAME_HEADER_SIZE + len);
            oc_frame_header_write(buf.data, &fh);
            memcpy(buf.data + OC_FRAME_HEADER_SIZE, p, len);
            s_frame_n(&ex, buf.data, OC_FRAME_HEADER_SIZE + len, k, 4, 4);
        }
        s_end(&ex);
        oc_stream_free(tiny);
    }
    for (int k = 0; k < S_TICKS; k++) { oc_buf_free(&frames[k]); oc_buf_free(&bframes[k]); }
    oc_buf_free(&buf);
    for (int l = 0; l < 2; l++) oc_stream_free(s_layers[l].st);
    oc_encoder_free(e);
}

static int first_bad = 1;
static void bad(const char *name, const char *desc, const uint8_t *p, size_t len, const char *err)
{
    char fn[256];
    snprintf(fn, sizeof fn, "%s.bin", name);
    write_file(fn, p, len);
    fprintf(manifest, "%s\n    {\"name\":\"%s\",\"description\":\"%s\",\"file\":\"%s\",\"error\":\"%s\"}",
            first_bad ? "" : ",", name, desc, fn, err);
    first_bad = 0;
}

int main(int argc, char **argv)
{
    if (argc != 2) { fprintf(stderr, "usage: gen_vectors DIR\n"); return 2; }
    dir = argv[1];
    char path[512];
    snprintf(path, sizeof path, "%s/manifest.json", dir);
    if (!(manifest = fopen(path, "w"))) { perror(path); return 1; }
    fprintf(manifest, "{\"protocol\":%d,\"subprotocol\":\"%s\",\n \"note\":\"generated by proto/tools/gen_vectors.c "
            "(make proto-vectors); expected = exact decoded float32 samples, all tiles in frame order\",\n"
            " \"vectors\":[", OC_PROTO_VERSION, OC_SUBPROTOCOL);

    float *h8 = make_field(8, 0.5, 0, 0);
    float *h16 = make_field(16, 1.0, 0, 0);
    float *h64 = make_field(64, 1.5, 0.002, 0);
    float *d32 = make_field(32, 0.7, 0, 0.1), *j32 = make_field(32, 0.3, 0, 1.0);
    float *h128 = make_field(128, 2.0, 0.001, -0.3);
    float *noise64 = make_field(64, 0.1, 0.5, 0);
    float *konst = malloc(sizeof(float) * 16 * 16), *huge = make_field(16, 1.0, 0, 0);
    for (int i = 0; i < 256; i++) konst[i] = 0.25f;
    huge[5] = 3e9f; huge[17] = -2e9f;

    struct oc_buf tiny = { 0 }, big = { 0 };
    { struct tile_req r[] = { { h8, 0, 0, 0, 0, 0.01f, 1, 0 } };
      emit("v01_tiny_lossy", "n=8, one 4x4 height tile, bound 1 cm (the PROTOCOL.md worked example)", 8, 4, r, 1, &tiny); }
    { struct tile_req r[] = { { h16, 0, 0, 0, 0, 0, 0, 0 }, { h16, 1, 1, 0, 0, 0, 0, 0 } };
      emit("v02_raw", "raw float32 (bound 0), two of four tiles", 16, 8, r, 2, NULL); }
    { struct tile_req r[] = { { h64, 0, 0, 0, 0, 0.001f, 1, 0 }, { h64, 1, 0, 0, 0, 0.001f, 1, 0 },
                              { h64, 0, 1, 0, 0, 0.001f, 1, 0 }, { h64, 1, 1, 0, 0, 0.001f, 1, 0 } };
      emit("v03_height_1mm", "all tiles of a 64x64 height field, bound 1 mm, deflate", 64, 32, r, 4, &big); }
    { struct tile_req r[] = { { d32, 1, 0, 0, 1, 0.01f, 1, 0 }, { d32, 1, 0, 0, 2, 0.005f, 1, 0 },
                              { j32, 1, 0, 0, 3, 0.001f, 1, 0 }, { j32, 1, 0, 0, 4, 0.001f, 1, 0 },
                              { j32, 1, 0, 0, 5, 0.01f, 1, 0 } };
      emit("v04_fields", "dx, dz, slope_x, slope_z, jacobian of one tile at several bounds", 32, 16, r, 5, NULL); }
    { struct tile_req r[] = { { h64, 1, 1, 0, 0, 0.005f, 1, 0 }, { h64, 1, 1, 1, 0, 0.005f, 1, 0 },
                              { h64, 1, 1, 2, 0, 0.005f, 1, 0 }, { h64, 1, 1, 3, 0, 0.005f, 1, 0 },
                              { h64, 1, 1, 4, 0, 0.005f, 1, 0 } };
      emit("v05_lods", "one tile at LOD 0..4 (32, 16, 8, 4, 2 samples per side)", 64, 32, r, 5, NULL); }
    { struct tile_req r[] = { { h128, 0, 3, 0, 0, 0.01f, 1, 0 }, { h128, 2, 1, 0, 0, 0.01f, 1, 0 },
                              { h128, 3, 3, 1, 1, 0.01f, 1, 0 } };
      emit("v06_partial", "3 of 16 tiles (a region), mixed LOD", 128, 32, r, 3, NULL); }
    { struct tile_req r[] = { { konst, 0, 0, 0, 0, 0.001f, 1, 0 } };
      emit("v07_constant", "constant tile: every residual after the first is 0", 16, 16, r, 1, NULL); }
    { struct tile_req r[] = { { h64, 0, 0, 0, 0, 0.001f, 2, 0 }, { h64, 1, 1, 1, 0, 0.01f, 2, 0 } };
      emit("v08_zstd", "codec 2 (zstd entropy coder)", 64, 32, r, 2, NULL); }
    { struct tile_req r[] = { { huge, 0, 0, 0, 0, 0.001f, 1, 0 } };
      emit("v09_huge_range", "range 5e9 at bound 1 mm: codes would not fit, falls back to raw", 16, 16, r, 1, NULL); }
    { struct tile_req r[] = { { noise64, 0, 0, 0, 0, 0.001f, 1, 0 }, { noise64, 1, 0, 0, 0, 0.05f, 1, 0 } };
      emit("v10_noise", "white noise: many escaped residuals (stream B)", 64, 32, r, 2, NULL); }
    { struct tile_req r[] = { { h64, 1, 0, 0, 0, 0.01f, 1, 0 }, { noise64, 1, 0, 1, 0, 0.001f, 1, 1 },
                              { h16, 0, 0, 1, 0, 0.001f, 1, 2 }, { noise64, 1, 0, 1, 3, 0.001f, 1, 1 } };
      emit("v12_cascades", "cascades: the same tile (1, 0) of cascade 0 (LOD 0), 1 (LOD 1, height and slope_x) "
           "and 2 (LOD 1), cascade in the tile flags", 64, 32, r, 4, NULL); }
    { /* floating bodies in the header (PROTOCOL.md §3.5): decoders that know nothing of them skip the section */
      static const struct oc_body_record bodies[] = {
          { .id = 5, .kind = 1, .flags = 0, .pos = { 12.5f, -0.25f, -3.0f }, .quat = { 1, 0, 0, 0 },
            .vel = { 0.125f, -0.5f, 0 } },
          { .id = 12, .kind = 3, .flags = 2, .throttle = 64, .rudder = -25, .pos = { 10.0f, 0.375f, -20.0f },
            .quat = { 0.70710677f, 0, -0.70710677f, 0 }, .vel = { -4.0f, 0.0625f, 0.5f } },
          { .id = 4294967295u, .kind = 4, .flags = 3, .throttle = -127, .rudder = 127, .pos = { -2500, 1.5f, 2500 },
            .quat = { 0.5f, 0.5f, -0.5f, 0.5f }, .vel = { 0, 0, 0 } },
      };
      struct tile_req r[] = { { h16, 0, 0, 0, 0, 0.001f, 1, 0 } };
      emit_bodies = bodies;
      emit_nbodies = 3;
      emit("v13_bodies", "a BODY section of three floating bodies in the frame header (header_size 208), "
           "then one tile", 16, 16, r, 1, NULL);
      emit_nbodies = 0; }
    emit_crafted();
    fprintf(manifest, "\n ],\n \"bad\":[");

    uint8_t tmp[4096];
    bad("bad_short_header", "20 bytes of a frame header", big.data, 20, "truncated");
    bad("bad_truncated_payload", "valid frame cut inside the last payload", big.data, big.len - 7, "truncated");
    bad("bad_truncated_tile_header", "frame cut inside a tile header", big.data, OC_FRAME_HEADER_SIZE + 17, "truncated");
    memcpy(tmp, tiny.data, tiny.len); tmp[0] = 'X';
    bad("bad_magic", "first byte changed", tmp, tiny.len, "magic");
    memcpy(tmp, tiny.data, tiny.len); tmp[4] = 2;
    bad("bad_version", "version 2", tmp, tiny.len, "version");
    memcpy(tmp, tiny.data, tiny.len); tmp[28] = 0x00; tmp[29] = 0x10;   /* n = 4096 */
    bad("bad_oversized", "n = 4096 > OC_MAX_N", tmp, tiny.len, "too_large");
    memcpy(tmp, tiny.data, tiny.len); tmp[28] = 12; tmp[29] = 0;        /* n = 12 */
    bad("bad_n_not_pow2", "n = 12", tmp, tiny.len, "corrupt");
    memcpy(tmp, tiny.data, tiny.len); tmp[OC_FRAME_HEADER_SIZE + 4] = 2; /* tile_x = 2 of 2 */
    bad("bad_tile_outside", "tile_x outside the grid", tmp, tiny.len, "corrupt");
    memcpy(tmp, tiny.data, tiny.len); tmp[OC_FRAME_HEADER_SIZE + 8] = 8;  /* width 8 != 4 */
    bad("bad_tile_width", "width inconsistent with tile_size >> lod", tmp, tiny.len, "corrupt");
    memcpy(tmp, tiny.data, tiny.len); tmp[36] = 2;                       /* tile_count 2, only 1 present */
    bad("bad_tile_count", "tile_count says 2, one tile present", tmp, tiny.len, "truncated");
    memcpy(tmp, tiny.data, tiny.len); tmp[tiny.len] = 0;
    bad("bad_trailing", "one byte after the last tile", tmp, tiny.len + 1, "corrupt");
    memcpy(tmp, tiny.data, tiny.len); tmp[OC_FRAME_HEADER_SIZE + OC_TILE_HEADER_SIZE] = 7; /* esc_width 7 */
    bad("bad_esc_width", "lossy prefix esc_width 7", tmp, tiny.len, "corrupt");
    memcpy(tmp, tiny.data, tiny.len); tmp[OC_FRAME_HEADER_SIZE + 2] = 9;  /* codec 9 */
    bad("bad_codec", "unknown codec 9", tmp, tiny.len, "corrupt");
    memcpy(tmp, tiny.data, tiny.len); tmp[OC_FRAME_HEADER_SIZE + 32] += 1;   /* payload_len + 1 */
    bad("bad_payload_len", "payload_len one byte longer than the frame", tmp, tiny.len, "truncated");
    memcpy(tmp, tiny.data, tiny.len); tmp[OC_FRAME_HEADER_SIZE + OC_TILE_HEADER_SIZE + OC_LOSSY_PREFIX] |= 0x06; /* BTYPE 3 */
    bad("bad_deflate", "deflate block type 3 (invalid)", tmp, tiny.len, "corrupt");
    fprintf(manifest, "\n ],\n \"streams\":[");
    emit_streams();
    fprintf(manifest, "\n ]\n}\n");
    fclose(manifest);
    oc_buf_free(&tiny); oc_buf_free(&big);
    free(h8); free(h16); free(h64); free(d32); free(j32); free(h128); free(noise64); free(konst); free(huge);
    return 0;
}

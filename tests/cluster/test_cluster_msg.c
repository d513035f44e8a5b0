/* test_cluster_msg.c — unit tests of the cluster module's pure parts:
 * subjects, the layer-part format (OCNL) and its splitting/reassembly, the
 * envelope format (OCNE), and the demand table's expiry. No NATS here
 * (tests/cluster/test_cluster_nats.c has the integration test). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cluster/cluster.h"
#include "layer_gen.h"

#include "../common/check.h"

/* ---- subjects ---- */

static void test_subjects(void)
{
    check_section = "subjects";
    const char *good[] = { "oceand", "sea-1", "eu.west.sea_2", "A", NULL };
    const char *bad[] = { "", ".", "a.", ".a", "a..b", "a*", "a.>", "a b", "sea\n", "s\xc3\xa9", NULL };
    for (int i = 0; good[i]; i++)
        CHECK(cl_prefix_valid(good[i]), "prefix \"%s\" should be valid", good[i]);
    for (int i = 0; bad[i]; i++)
        CHECK(!cl_prefix_valid(bad[i]), "prefix \"%s\" should be invalid", bad[i]);
    char longp[CL_PREFIX_MAX + 2];
    memset(longp, 'a', sizeof longp - 1);
    longp[sizeof longp - 1] = 0;
    CHECK(!cl_prefix_valid(longp), "a %zu-character prefix should be invalid", strlen(longp));
    CHECK(cl_prefix_valid(longp + 1), "a %d-character prefix should be valid", CL_PREFIX_MAX);

    char s[CL_SUBJECT_MAX];
    CHECK(cl_subject_layer(s, sizeof s, "sea", cl_key(0, 0, 2)) == 0 && strcmp(s, "sea.frame.0.height.0.2") == 0,
          "layer subject: %s", s);
    CHECK(cl_subject_layer(s, sizeof s, "sea", cl_key_cascade(2, 0, 1, 4)) == 0 &&
          strcmp(s, "sea.frame.2.height.1.4") == 0, "cascade 2 layer subject: %s", s);
    CHECK(cl_subject(s, sizeof s, "eu.sea", CL_SUBJ_DEMAND) == 0 && strcmp(s, "eu.sea.demand") == 0, "demand: %s", s);
    CHECK(cl_subject(s, sizeof s, "eu.sea", CL_SUBJ_CTL) == 0 && strcmp(s, "eu.sea.ctl") == 0, "ctl: %s", s);
    CHECK(cl_subject(s, sizeof s, "eu.sea", CL_SUBJ_QUERY) == 0 && strcmp(s, "eu.sea.query") == 0, "query: %s", s);
    CHECK(cl_subject(s, sizeof s, "eu.sea", CL_SUBJ_PROBE) == 0 && strcmp(s, "eu.sea.probe") == 0, "probe: %s", s);
    CHECK(cl_subject(s, sizeof s, "eu.sea", CL_SUBJ_BODIES) == 0 && strcmp(s, "eu.sea.bodies") == 0, "bodies: %s", s);
    CHECK(cl_subject(s, sizeof s, "eu.sea", (enum cl_subject)(CL_SUBJ_BODIES + 1)) == CL_E_ARG, "unknown subject");
    CHECK(cl_probe_stream_subject("_INBOX.abc.17", s, sizeof s) == 0 && strcmp(s, "_INBOX.abc.p") == 0,
          "probe stream: %s", s);
    CHECK(cl_probe_stream_subject("nodot", s, sizeof s) == CL_E_ARG, "probe stream of a subject without a dot");
    CHECK(cl_probe_stream_subject(".x", s, sizeof s) == CL_E_ARG, "probe stream of an empty inbox");
    CHECK(cl_probe_stream_subject("_INBOX.abc.17", s, 8) == CL_E_TOO_LARGE, "probe stream: small buffer");
    CHECK(cl_subject(s, sizeof s, "a*", CL_SUBJ_CTL) == CL_E_ARG, "bad prefix accepted");
    CHECK(cl_subject_layer(s, sizeof s, "sea", CL_KEYS) == CL_E_ARG, "key out of range accepted");
    CHECK(cl_subject_layer(s, sizeof s, "sea", -1) == CL_E_ARG, "negative key accepted");
    CHECK(cl_subject_layer(s, 10, "sea", 0) == CL_E_TOO_LARGE, "small buffer not reported");

    /* every key of every cascade round-trips through its subject, and all subjects differ */
    int ok = 1;
    for (int c = 0; c < CL_CASCADES; c++)
        for (int f = 0; f < CL_FIELDS; f++)
            for (int l = 0; l < CL_LODS; l++)
                for (int b = 0; b < CL_BOUNDS; b++) {
                    int k = cl_key_cascade(c, f, l, b);
                    cl_subject_layer(s, sizeof s, "x.y", k);
                    if (cl_subject_layer_parse(s, "x.y") != k || cl_key_which_cascade(k) != c ||
                        cl_key_field(k) != f || cl_key_lod(k) != l || cl_key_bound(k) != b)
                        ok = 0;
                }
    CHECK(ok, "some layer subject does not parse back to its key");
    const char *bad_subj[] = { "x.y.frame.0.height.0", "x.y.frame.0.height.0.2.3", "x.y.frame.0.sky.0.0",
                               "x.y.frame.0.height.5.0", "x.y.frame.0.height.0.5", "x.y.frames.0.height.0.0",
                               "x.z.frame.0.height.0.0", "x.y.frame.0.height.00.0", "x.y.frame.height.0.0",
                               "x.y.frame.4.height.0.0", "x.y.frame.01.height.0.0", "x.y.frame.-1.height.0.0", NULL };
    for (int i = 0; bad_subj[i]; i++)
        CHECK(cl_subject_layer_parse(bad_subj[i], "x.y") < 0, "subject %s should not parse", bad_subj[i]);
    CHECK(cl_key_cascade(CL_CASCADES - 1, CL_FIELDS - 1, CL_LODS - 1, CL_BOUNDS - 1) == CL_KEYS - 1, "keys not dense");
}

/* ---- layer parts ---- */

static void test_part_roundtrip(void)
{
    check_section = "layer part round trip";
    struct gen_layer g;
    CHECK(gen_layer_make(&g, 64, 16, 3, 1, 2, 42, 300, 1) == 0, "gen");
    g.info.frame_flags = 0;
    g.info.layer_flags = 1;
    cl_bit_set(g.info.encoded, cl_key(0, 0, 0), true); /* another layer encoded the same tick */
    int total = 16;
    size_t size = cl_layer_part_size(total, g.len);
    uint8_t *msg = malloc(size);
    long w = cl_layer_part_write(msg, size, &g.info, 0, total, g.data, g.tile_off);
    CHECK(w == (long)size, "write returned %ld, expected %zu", w, size);
    CHECK(cl_layer_part_write(msg, size - 1, &g.info, 0, total, g.data, g.tile_off) == CL_E_TOO_LARGE,
          "a short buffer must be refused");
    CHECK(memcmp(msg, "OCNL", 4) == 0, "magic");
    struct cl_layer_part p;
    int rc = cl_layer_part_parse(msg, size, &p);
    CHECK(rc == 0, "parse: %s", cl_strerror(rc));
    if (rc == 0) {
        CHECK(p.tile_first == 0 && p.tile_count == total && p.data_len == g.len, "part geometry");
        CHECK(memcmp(p.data, g.data, g.len) == 0, "tile bytes");
        for (int i = 0; i <= total; i++)
            CHECK(cl_part_off(&p, i) == g.tile_off[i], "offset %d", i);
        struct cl_assembler *a = cl_assembler_new();
        struct cl_layer *l = NULL;
        CHECK(cl_assembler_add(a, &p, &l) == 1 && l, "a whole-layer part completes at once");
        if (l) {
            CHECK(gen_layer_equal(&g, l), "assembled layer differs");
            CHECK(cl_bit(l->info.encoded, cl_key(0, 0, 0)), "encoded bitmap lost");
        }
        cl_layer_free(l);
        cl_assembler_free(a);
    }

    /* every truncation is refused, never read past */
    int trunc_ok = 1;
    for (size_t n = 0; n < size; n++) {
        uint8_t *c = malloc(n ? n : 1);
        memcpy(c, msg, n);
        if (cl_layer_part_parse(c, n, &p) >= 0)
            trunc_ok = 0;
        free(c);
    }
    CHECK(trunc_ok, "a truncated part parsed");
    /* one byte too many */
    uint8_t *longer = malloc(size + 1);
    memcpy(longer, msg, size);
    longer[size] = 0;
    CHECK(cl_layer_part_parse(longer, size + 1, &p) == CL_E_CORRUPT, "a trailing byte must be refused");
    free(longer);
    free(msg);
    gen_layer_free(&g);
}

/* Rewrites one header/offset/tile field and expects the parser's error. */
static void expect_bad(const char *what, void (*mutate)(uint8_t *msg), int want)
{
    struct gen_layer g;
    gen_layer_make(&g, 32, 16, 0, 0, 1, 7, 50, 9);
    size_t size = cl_layer_part_size(4, g.len);
    uint8_t *msg = malloc(size);
    cl_layer_part_write(msg, size, &g.info, 0, 4, g.data, g.tile_off);
    mutate(msg);
    struct cl_layer_part p;
    int rc = cl_layer_part_parse(msg, size, &p);
    CHECK(rc == want, "%s: got %d (%s), want %d", what, rc, cl_strerror(rc), want);
    free(msg);
    gen_layer_free(&g);
}
static void m_magic(uint8_t *m) { m[3] = 'X'; }
static void m_version(uint8_t *m) { m[4] = 1; } /* version 1: cascade 0 only, 32-byte bitmaps */
static void m_hsize(uint8_t *m) { m[6] = CL_LAYER_HEADER_SIZE - 1; }
static void m_field(uint8_t *m) { m[38] = CL_FIELDS; }
static void m_lod(uint8_t *m) { m[39] = CL_LODS; }
static void m_bound(uint8_t *m) { m[40] = CL_BOUNDS; }
static void m_tps(uint8_t *m) { m[42] = 3; }
static void m_n(uint8_t *m) { m[28] = 48; } /* 48 / tile_size 16 = 3 tiles per side, header says 2 */
static void m_tile_count(uint8_t *m) { m[46] = 5; }
static void m_tile_first(uint8_t *m) { m[44] = 1; }
static void m_reserved(uint8_t *m) { m[63] = 1; } /* need without shared tiles */
static void m_cascade(uint8_t *m) { m[60] = 1; }      /* cascade 1 of 1 */
static void m_ncascades0(uint8_t *m) { m[61] = 0; }
static void m_ncascades5(uint8_t *m) { m[61] = 5; }
static void m_encoded_lod(uint8_t *m) { m[62] = CL_LODS; }
static void m_encoded(uint8_t *m) { memset(m + 64, 0, CL_KEY_BYTES); }
static void m_encoded_high(uint8_t *m) { m[64 + CL_KEY_BYTES - 1] = 0x80; }
static void m_simtime(uint8_t *m) { memset(m + 16, 0xff, 8); } /* NaN */
static void m_patch(uint8_t *m) { memset(m + 32, 0, 4); }
#define HS CL_LAYER_HEADER_SIZE
static void m_off0(uint8_t *m) { m[HS] = 1; }
static void m_off_order(uint8_t *m) { m[HS + 4] = 0; m[HS + 5] = 0; m[HS + 6] = 0; m[HS + 7] = 0; }
static void m_tile_field(uint8_t *m) { m[HS + 5 * 4] = 1; } /* first tile's header says field 1 */
static void m_tile_lod(uint8_t *m) { m[HS + 5 * 4 + 1] = 1; } /* ... lod 1 (the layer's encoded_lod is 0) */
static void m_tile_cascade(uint8_t *m) { m[HS + 5 * 4 + 3] = 1; } /* ... cascade 1 (flags bits 0-1) */
static void m_tile_len(uint8_t *m) { m[HS + 5 * 4 + 32] ^= 1; }
static void m_layer_flags(uint8_t *m) { m[41] = 8; }
static void m_intra_alone(uint8_t *m) { m[41] = CL_LAYER_INTRA; } /* intra section flag without the shared one */
static void m_need_shared(uint8_t *m) { m[41] = CL_LAYER_SHARED; m[63] = CL_LAYER_MAX_NEED + 1; }
static void m_epoch0(uint8_t *m) { memset(m + 64 + CL_KEY_BYTES, 0, 8); }

static void test_part_rejects(void)
{
    check_section = "layer part rejects";
    expect_bad("magic", m_magic, CL_E_MAGIC);
    expect_bad("version", m_version, CL_E_VERSION);
    expect_bad("header size", m_hsize, CL_E_CORRUPT);
    expect_bad("field", m_field, CL_E_CORRUPT);
    expect_bad("lod", m_lod, CL_E_CORRUPT);
    expect_bad("bound", m_bound, CL_E_CORRUPT);
    expect_bad("tiles per side", m_tps, CL_E_CORRUPT);
    expect_bad("n", m_n, CL_E_CORRUPT);
    expect_bad("tile count", m_tile_count, CL_E_CORRUPT);
    expect_bad("tile first + count beyond the layer", m_tile_first, CL_E_CORRUPT);
    expect_bad("reserved", m_reserved, CL_E_CORRUPT);
    expect_bad("cascade not in force", m_cascade, CL_E_CORRUPT);
    expect_bad("0 cascades", m_ncascades0, CL_E_CORRUPT);
    expect_bad("5 cascades", m_ncascades5, CL_E_CORRUPT);
    expect_bad("encoded_lod beyond the LODs", m_encoded_lod, CL_E_CORRUPT);
    expect_bad("own key not in encoded", m_encoded, CL_E_CORRUPT);
    expect_bad("key bit beyond CL_KEYS", m_encoded_high, CL_E_CORRUPT);
    expect_bad("sim_time NaN", m_simtime, CL_E_CORRUPT);
    expect_bad("patch_size 0", m_patch, CL_E_CORRUPT);
    expect_bad("first offset not 0", m_off0, CL_E_CORRUPT);
    expect_bad("offsets out of order", m_off_order, CL_E_CORRUPT);
    expect_bad("tile header field", m_tile_field, CL_E_CORRUPT);
    expect_bad("tile header lod", m_tile_lod, CL_E_CORRUPT);
    expect_bad("tile header cascade", m_tile_cascade, CL_E_CORRUPT);
    expect_bad("tile payload_len", m_tile_len, CL_E_CORRUPT);
    expect_bad("layer flags", m_layer_flags, CL_E_CORRUPT);
    expect_bad("intra section flag alone", m_intra_alone, CL_E_CORRUPT);
    expect_bad("need beyond 4", m_need_shared, CL_E_CORRUPT);
    expect_bad("epoch 0", m_epoch0, CL_E_CORRUPT);
}

/* Split into parts that fit max_payload, reassemble: identical layer. */
static void test_split_assemble(void)
{
    check_section = "split and reassemble";
    struct gen_layer g;
    gen_layer_make(&g, 256, 32, 5, 2, 4, 100, 4000, 3); /* 64 tiles, ~130 KB */
    int total = 64;
    size_t maxp = 16384;
    struct cl_assembler *a = cl_assembler_new();
    struct cl_layer *out = NULL;
    int parts = 0, completes = 0;
    uint8_t *buf = malloc(maxp);
    for (int first = 0; first < total;) {
        int k = cl_layer_part_tiles(g.tile_off, first, total, maxp);
        CHECK(k >= 1, "no tile fits at %d", first);
        if (k < 1)
            break;
        /* k is the most that fits: one more would not */
        if (first + k < total)
            CHECK(cl_layer_part_size(k + 1, g.tile_off[first + k + 1] - g.tile_off[first]) > maxp,
                  "part at %d could hold more tiles", first);
        long w = cl_layer_part_write(buf, maxp, &g.info, first, k, g.data, g.tile_off);
        CHECK(w > 0 && (size_t)w <= maxp, "part write %ld", w);
        struct cl_layer_part p;
        CHECK(cl_layer_part_parse(buf, (size_t)w, &p) == 0, "part parse");
        int rc = cl_assembler_add(a, &p, &out);
        CHECK(rc == (first + k == total ? 1 : 0), "assembler returned %d at tile %d", rc, first);
        completes += rc == 1;
        parts++;
        first += k;
    }
    CHECK(parts > 5, "only %d parts: the test wants a real split", parts);
    CHECK(completes == 1 && out && gen_layer_equal(&g, out), "reassembled layer differs");
    cl_layer_free(out);
    CHECK(cl_assembler_dropped(a) == 0, "nothing should be dropped");

    /* a lost middle part: the layer is dropped (counted), nothing completes */
    out = NULL;
    int k0 = cl_layer_part_tiles(g.tile_off, 0, total, maxp);
    int k1 = cl_layer_part_tiles(g.tile_off, k0, total, maxp);
    struct cl_layer_part p;
    long w = cl_layer_part_write(buf, maxp, &g.info, 0, k0, g.data, g.tile_off);
    cl_layer_part_parse(buf, (size_t)w, &p);
    CHECK(cl_assembler_add(a, &p, &out) == 0, "first part");
    w = cl_layer_part_write(buf, maxp, &g.info, k0 + k1, cl_layer_part_tiles(g.tile_off, k0 + k1, total, maxp),
                            g.data, g.tile_off);
    cl_layer_part_parse(buf, (size_t)w, &p);
    CHECK(cl_assembler_add(a, &p, &out) == CL_E_CORRUPT && !out, "a gap must not be accepted");
    CHECK(cl_assembler_dropped(a) == 1, "the broken layer is counted: %llu",
          (unsigned long long)cl_assembler_dropped(a));

    /* a new seq before the old layer completed: old dropped, new goes on */
    w = cl_layer_part_write(buf, maxp, &g.info, 0, k0, g.data, g.tile_off);
    cl_layer_part_parse(buf, (size_t)w, &p);
    cl_assembler_add(a, &p, &out);
    g.info.seq++;
    w = cl_layer_part_write(buf, maxp, &g.info, 0, k0, g.data, g.tile_off);
    cl_layer_part_parse(buf, (size_t)w, &p);
    CHECK(cl_assembler_add(a, &p, &out) == 0, "new layer starts");
    CHECK(cl_assembler_dropped(a) == 2, "superseded layer counted");
    /* a continuation with a different header (another seq) is refused */
    g.info.seq++;
    w = cl_layer_part_write(buf, maxp, &g.info, k0, k1, g.data, g.tile_off);
    cl_layer_part_parse(buf, (size_t)w, &p);
    CHECK(cl_assembler_add(a, &p, &out) == CL_E_CORRUPT, "mixed seq parts accepted");

    /* a tile larger than max_payload cannot be sent */
    CHECK(cl_layer_part_tiles(g.tile_off, 0, total, 100) == 0, "an oversized tile must give 0");
    free(buf);
    cl_assembler_free(a);
    gen_layer_free(&g);
}

/* The finer cascades (PROTOCOL.md §4.1): same field, LOD and bound in two
 * cascades are two layers, assembled side by side (parts interleaved) and
 * collected into one frame, cascade 0's first. */
static void test_cascades(void)
{
    check_section = "cascades";
    struct gen_layer g0, g2;
    gen_layer_make(&g0, 128, 16, 0, 1, 4, 50, 900, 11);
    gen_layer_make(&g2, 128, 16, 0, 1, 4, 50, 900, 12);
    gen_layer_cascade(&g0, 0, 3);
    gen_layer_cascade(&g2, 2, 3);
    const int k0 = cl_key_cascade(0, 0, 1, 4), k2 = cl_key_cascade(2, 0, 1, 4);
    CHECK(cl_info_key(&g2.info) == k2 && k2 != k0, "cascade 2's key");
    cl_bit_set(g0.info.encoded, k2, true); /* both encoded this tick */
    cl_bit_set(g2.info.encoded, k0, true);
    const size_t maxp = 8192;
    const int total = 64;
    uint8_t *buf = malloc(maxp);
    struct cl_assembler *a = cl_assembler_new();
    struct cl_layer *got[2] = { NULL, NULL };
    int first[2] = { 0, 0 }, parts = 0;
    struct gen_layer *gs[2] = { &g0, &g2 };
    while (first[0] < total || first[1] < total)
        for (int i = 0; i < 2; i++) {
            if (first[i] >= total)
                continue;
            int k = cl_layer_part_tiles(gs[i]->tile_off, first[i], total, maxp);
            long w = cl_layer_part_write(buf, maxp, &gs[i]->info, first[i], k, gs[i]->data, gs[i]->tile_off);
            struct cl_layer_part p;
            int rc = w > 0 ? cl_layer_part_parse(buf, (size_t)w, &p) : (int)w;
            CHECK(rc == 0, "cascade %d part at %d: %s", gs[i]->info.cascade, first[i], cl_strerror(rc));
            if (rc != 0)
                goto out;
            struct cl_layer *l = NULL;
            rc = cl_assembler_add(a, &p, &l);
            CHECK(rc == (first[i] + k == total ? 1 : 0), "assembler: %d", rc);
            if (l)
                got[i] = l;
            first[i] += k;
            parts++;
        }
    CHECK(parts > 4 && cl_assembler_dropped(a) == 0, "interleaved parts dropped a layer (%d parts)", parts);
    CHECK(got[0] && gen_layer_equal(&g0, got[0]), "cascade 0 layer differs");
    CHECK(got[1] && gen_layer_equal(&g2, got[1]) && got[1]->info.cascade == 2 && got[1]->info.ncascades == 3,
          "cascade 2 layer differs");
    if (got[0] && got[1]) {
        uint8_t want[CL_KEY_BYTES] = { 0 };
        cl_bit_set(want, k0, true);
        cl_bit_set(want, k2, true);
        struct cl_collector *c = cl_collector_new();
        struct cl_frame_set *out[2] = { NULL, NULL };
        CHECK(cl_collector_add(c, got[1], want, out) == 0, "cascade 2 alone is not the frame");
        CHECK(cl_collector_add(c, got[0], want, out) == 1 && out[0]->nlayers == 2 && !out[0]->partial &&
              out[0]->layers[0]->info.cascade == 0 && out[0]->layers[1]->info.cascade == 2 &&
              out[0]->hdr.ncascades == 3, "one frame of both cascades, cascade 0 first");
        got[0] = got[1] = NULL;
        cl_frame_set_free(out[0]);
        cl_collector_free(c);
    }
out:
    cl_layer_free(got[0]);
    cl_layer_free(got[1]);
    cl_assembler_free(a);
    free(buf);
    gen_layer_free(&g0);
    gen_layer_free(&g2);
}

/* ---- envelopes ---- */

static void test_envelope(void)
{
    check_section = "envelope";
    const char *body = "{\"type\":\"set\",\"params\":{\"wind_speed\":12}}";
    size_t size = cl_envelope_size("edge-a", "c17", strlen(body));
    uint8_t *m = malloc(size);
    long w = cl_envelope_write(m, size, CL_KIND_CTL, "edge-a", "c17", body, strlen(body));
    CHECK(w == (long)size, "write %ld", w);
    struct cl_envelope e;
    int rc = cl_envelope_parse(m, size, &e);
    CHECK(rc == 0 && e.kind == CL_KIND_CTL && strcmp(e.origin, "edge-a") == 0 && strcmp(e.by, "c17") == 0 &&
          e.body_len == strlen(body) && memcmp(e.body, body, e.body_len) == 0, "round trip (rc %d)", rc);
    int trunc_ok = 1;
    for (size_t n = 0; n < size; n++)
        if (cl_envelope_parse(m, n, &e) >= 0)
            trunc_ok = 0;
    CHECK(trunc_ok, "a truncated envelope parsed");
    m[5] = 0;
    CHECK(cl_envelope_parse(m, size, &e) == CL_E_CORRUPT, "kind 0 accepted");
    m[5] = CL_KIND_BODY_SECTION + 1;
    CHECK(cl_envelope_parse(m, size, &e) == CL_E_CORRUPT, "kind %d accepted", CL_KIND_BODY_SECTION + 1);
    m[5] = CL_KIND_PROBE_DATA;
    CHECK(cl_envelope_parse(m, size, &e) == 0 && e.kind == CL_KIND_PROBE_DATA, "kind PROBE_DATA refused");
    m[5] = CL_KIND_BODIES;
    CHECK(cl_envelope_parse(m, size, &e) == 0 && e.kind == CL_KIND_BODIES, "kind BODIES refused");
    m[5] = CL_KIND_BODY_SECTION;
    CHECK(cl_envelope_parse(m, size, &e) == 0 && e.kind == CL_KIND_BODY_SECTION, "kind BODY_SECTION refused");
    m[5] = CL_KIND_CTL;
    m[12] = ' ';
    CHECK(cl_envelope_parse(m, size, &e) == CL_E_CORRUPT, "a space in origin accepted");
    m[12] = 'e';
    m[4] = 1;
    CHECK(cl_envelope_parse(m, size, &e) == CL_E_VERSION, "version 1 (32-byte demand bitmaps) accepted");
    m[4] = CL_ENV_VERSION;
    m[8] = (uint8_t)(m[8] - 1);
    CHECK(cl_envelope_parse(m, size, &e) == CL_E_CORRUPT, "a byte after the body accepted");
    free(m);

    uint8_t small[64];
    CHECK(cl_envelope_write(small, sizeof small, CL_KIND_HELLO, "edge a", "", NULL, 0) == CL_E_ARG,
          "a name with a space written");
    char longname[70];
    memset(longname, 'x', sizeof longname - 1);
    longname[sizeof longname - 1] = 0;
    CHECK(cl_envelope_write(small, sizeof small, CL_KIND_HELLO, longname, "", NULL, 0) == CL_E_ARG,
          "a 69-character name written");
    CHECK(cl_envelope_write(small, sizeof small, CL_KIND_HELLO, "e", "", NULL, 0) == CL_ENV_HEADER + 1,
          "an empty body");

    uint8_t bits[CL_KEY_BYTES] = { 0 }, back[CL_KEY_BYTES];
    cl_bit_set(bits, 5, true);
    cl_bit_set(bits, CL_KEYS - 1, true);
    uint8_t db[CL_DEMAND_BODY];
    cl_demand_body_write(db, 3000, bits);
    uint32_t ttl = 0;
    CHECK(cl_demand_body_parse(db, sizeof db, &ttl, back) == 0 && ttl == 3000 && memcmp(bits, back, sizeof bits) == 0,
          "demand body round trip");
    CHECK(cl_demand_body_parse(db, sizeof db - 1, &ttl, back) == CL_E_TRUNCATED, "short demand body");
    db[4 + CL_KEY_BYTES - 1] = 0x80;
    CHECK(cl_demand_body_parse(db, sizeof db, &ttl, back) == CL_E_CORRUPT, "key beyond CL_KEYS accepted");
}

/* ---- demand table ---- */

static void keys(uint8_t bits[CL_KEY_BYTES], int a, int b)
{
    memset(bits, 0, CL_KEY_BYTES);
    if (a >= 0)
        cl_bit_set(bits, a, true);
    if (b >= 0)
        cl_bit_set(bits, b, true);
}

static void test_demand(void)
{
    check_section = "demand table";
    struct cl_demand *d = cl_demand_new(2);
    uint8_t a[CL_KEY_BYTES], b[CL_KEY_BYTES], u[CL_KEY_BYTES], empty[CL_KEY_BYTES] = { 0 };
    keys(a, 1, 2);
    keys(b, 2, 9);
    CHECK(cl_demand_union(d, 0, u) == 0 && memcmp(u, empty, sizeof u) == 0, "new table is empty");
    CHECK(cl_demand_update(d, "A", a, 3, 0) == 0, "A");
    CHECK(cl_demand_update(d, "B", b, 3, 1) == 0, "B");
    CHECK(cl_demand_union(d, 2, u) == 2 && cl_bit(u, 1) && cl_bit(u, 2) && cl_bit(u, 9) && !cl_bit(u, 3),
          "union of A and B");
    /* a third edge does not fit while both live */
    CHECK(cl_demand_update(d, "C", a, 3, 2) == CL_E_FULL, "table of 2 took a third edge");
    /* A stops heartbeating: gone at t = 3 (its expiry), B stays until 4 */
    CHECK(cl_demand_union(d, 3.0, u) == 1 && !cl_bit(u, 1) && cl_bit(u, 2) && cl_bit(u, 9), "A expired");
    CHECK(cl_demand_update(d, "C", a, 3, 3.0) == 0, "C takes A's slot after expiry");
    /* B refreshes: expiry moves */
    CHECK(cl_demand_update(d, "B", b, 3, 3.5) == 0, "B refresh");
    CHECK(cl_demand_union(d, 5.0, u) == 2, "B refreshed and C live at 5");
    /* an empty set removes the edge at once */
    CHECK(cl_demand_update(d, "C", empty, 3, 5.0) == 0, "C leaves");
    CHECK(cl_demand_union(d, 5.0, u) == 1 && !cl_bit(u, 1) && cl_bit(u, 9), "C left at once");
    CHECK(cl_demand_union(d, 6.5, u) == 0 && memcmp(u, empty, sizeof u) == 0, "all expired: nothing to encode");
    /* ttl clamped */
    CHECK(cl_demand_update(d, "D", a, 1e9, 0) == 0, "D");
    CHECK(cl_demand_union(d, CL_DEMAND_TTL_MAX - 0.01, u) == 1, "D live just before the max ttl");
    CHECK(cl_demand_union(d, CL_DEMAND_TTL_MAX + 0.01, u) == 0, "D's ttl was not clamped to %g", CL_DEMAND_TTL_MAX);
    CHECK(cl_demand_update(d, "E", a, 0, 0) == 0 && cl_demand_union(d, CL_DEMAND_TTL_MIN / 2, u) == 1 &&
          cl_demand_union(d, CL_DEMAND_TTL_MIN + 0.01, u) == 0, "ttl 0 not clamped to the minimum");
    CHECK(cl_demand_update(d, "", a, 1, 0) == CL_E_ARG, "empty edge name accepted");
    cl_demand_free(d);
}

/* ---- frame collector ---- */

/* A complete layer of key (field, lod, 0) at seq; encoded = the keys in enc[]. */
static struct cl_layer *mk_layer(int field, uint64_t seq, const int *enc, int nenc)
{
    struct gen_layer g;
    gen_layer_make(&g, 32, 16, field, 0, 0, seq, 20, seq * 7 + (uint64_t)field);
    memset(g.info.encoded, 0, CL_KEY_BYTES);
    for (int i = 0; i < nenc; i++)
        cl_bit_set(g.info.encoded, enc[i], true);
    struct cl_layer *l = malloc(sizeof *l);
    l->info = g.info;
    l->data = g.data;
    l->len = g.len;
    l->tile_off = g.tile_off;
    return l;
}

static void test_collector(void)
{
    check_section = "frame collector";
    const int A = cl_key(0, 0, 0), B = cl_key(1, 0, 0), C = cl_key(2, 0, 0), D = cl_key(3, 0, 0);
    const int abc[] = { A, B, C }, ab[] = { A, B };
    uint8_t want[CL_KEY_BYTES] = { 0 };
    cl_bit_set(want, A, true);
    cl_bit_set(want, B, true);
    cl_bit_set(want, D, true); /* wanted, but the sim never encodes it: not waited for */
    struct cl_collector *c = cl_collector_new();
    struct cl_frame_set *out[2] = { NULL, NULL };

    /* B first, then A: complete at A; C (encoded, not wanted) not waited for */
    CHECK(cl_collector_add(c, mk_layer(1, 1, abc, 3), want, out) == 0, "one of two layers is not a frame");
    CHECK(cl_collector_add(c, mk_layer(0, 1, abc, 3), want, out) == 1, "A and B make frame 1");
    CHECK(out[0] && !out[0]->partial && out[0]->hdr.seq == 1 && out[0]->nlayers == 2 &&
          out[0]->layers[0]->info.field == 0 && out[0]->layers[1]->info.field == 1, "frame 1: two layers in key order");
    cl_frame_set_free(out[0]);

    /* B of seq 2 lost: A of seq 3 hands out frame 2 as partial */
    CHECK(cl_collector_add(c, mk_layer(0, 2, ab, 2), want, out) == 0, "A@2 waits for B@2");
    int n = cl_collector_add(c, mk_layer(0, 3, ab, 2), want, out);
    CHECK(n == 1 && out[0]->partial && out[0]->hdr.seq == 2 && out[0]->nlayers == 1, "frame 2 partial (n=%d)", n);
    if (n >= 1)
        cl_frame_set_free(out[0]);
    /* a late B of seq 2 is stale */
    CHECK(cl_collector_add(c, mk_layer(1, 2, ab, 2), want, out) == CL_E_CORRUPT, "a stale layer accepted");
    /* a second A of seq 3 is a duplicate */
    CHECK(cl_collector_add(c, mk_layer(0, 3, ab, 2), want, out) == CL_E_CORRUPT, "a duplicate layer accepted");
    /* B of seq 3 with another params_version does not belong to frame 3 */
    struct cl_layer *odd = mk_layer(1, 3, ab, 2);
    odd->info.params_version++;
    CHECK(cl_collector_add(c, odd, want, out) == CL_E_CORRUPT, "a layer with another frame header accepted");
    CHECK(cl_collector_add(c, mk_layer(1, 3, ab, 2), want, out) == 1 && !out[0]->partial && out[0]->nlayers == 2,
          "frame 3 complete");
    cl_frame_set_free(out[0]);

    /* the only viewer of B leaves while frame 4 waits for B: complete now */
    CHECK(cl_collector_add(c, mk_layer(0, 4, ab, 2), want, out) == 0, "A@4 waits");
    CHECK(cl_collector_check(c, want) == NULL, "still waiting for B");
    cl_bit_set(want, B, false);
    struct cl_frame_set *f = cl_collector_check(c, want);
    CHECK(f && f->hdr.seq == 4 && !f->partial, "frame 4 complete once B is no longer wanted");
    cl_frame_set_free(f);

    /* two frames out of one call: 5 (waiting for B until B's viewer left), then 6 */
    cl_bit_set(want, B, true);
    cl_collector_add(c, mk_layer(0, 5, ab, 2), want, out);
    cl_bit_set(want, B, false);
    const int a_only[] = { A };
    n = cl_collector_add(c, mk_layer(0, 6, a_only, 1), want, out);
    CHECK(n == 2 && out[0]->hdr.seq == 5 && !out[0]->partial && out[1]->hdr.seq == 6 && !out[1]->partial,
          "frame 5 (complete for today's want) then 6 (n=%d)", n);
    for (int i = 0; i < n && i < 2; i++)
        cl_frame_set_free(out[i]);

    struct cl_collector_stats st;
    cl_collector_stats(c, &st);
    CHECK(st.frames == 6 && st.partial == 1 && st.stale == 1 && st.mismatched == 2,
          "stats: %llu frames, %llu partial, %llu stale, %llu mismatched", (unsigned long long)st.frames,
          (unsigned long long)st.partial, (unsigned long long)st.stale, (unsigned long long)st.mismatched);
    /* a pending frame is freed with the collector (valgrind/ASan check the leak) */
    cl_bit_set(want, B, true);
    cl_collector_add(c, mk_layer(0, 9, ab, 2), want, out);
    cl_collector_free(c);
}

/* A publisher that starts a layer in every slot and never finishes one
 * (a malicious or broken sim on NATS): what the assembler holds stays under
 * its budget; older incomplete layers make room for a newer one, which
 * still completes (test-hostile's third battery; the default budget is
 * CL_MAX_ASSEMBLY_BYTES, here 4 MiB so that the test stays small). */
static void test_assembler_budget(void)
{
    check_section = "assembler budget";
    const size_t budget = 4u << 20, maxp = 65536;
    struct cl_assembler *a = cl_assembler_new();
    cl_assembler_set_budget(a, budget);
    uint8_t *buf = malloc(maxp);
    int refused = 0, over = 0;
    for (int f = 0; f < CL_FIELDS; f++)
        for (int lod = 0; lod < CL_LODS; lod++)
            for (int b = 0; b < CL_BOUNDS; b++) {
                struct gen_layer g;
                gen_layer_make(&g, 256, 16, f, lod, b, 7, 2000, (uint64_t)(f * 100 + lod * 10 + b));
                int k = cl_layer_part_tiles(g.tile_off, 0, 256, maxp);
                long w = cl_layer_part_write(buf, maxp, &g.info, 0, k, g.data, g.tile_off);
                struct cl_layer_part p;
                struct cl_layer *out = NULL;
                CHECK(w > 0 && cl_layer_part_parse(buf, (size_t)w, &p) == 0, "part");
                int rc = cl_assembler_add(a, &p, &out);
                CHECK(rc == 0 || rc == CL_E_TOO_LARGE, "first part of a key: %d", rc);
                refused += rc == CL_E_TOO_LARGE;
                over += cl_assembler_held(a) > budget;
                gen_layer_free(&g);
            }
    CHECK(!over, "held more than the budget after %d parts", over);
    CHECK(refused > 0, "175 incomplete layers of ~128 KiB fit in 4 MiB?");
    /* a newer layer (the sim moved on) still gets through, whole */
    struct gen_layer g;
    gen_layer_make(&g, 256, 16, 0, 0, 0, 8, 2000, 99);
    struct cl_layer *out = NULL;
    int done = 0;
    for (int first = 0; first < 256;) {
        int k = cl_layer_part_tiles(g.tile_off, first, 256, maxp);
        long w = cl_layer_part_write(buf, maxp, &g.info, first, k, g.data, g.tile_off);
        struct cl_layer_part p;
        cl_layer_part_parse(buf, (size_t)w, &p);
        int rc = cl_assembler_add(a, &p, &out);
        CHECK(rc >= 0, "newer layer refused at tile %d: %d", first, rc);
        done += rc == 1;
        CHECK(cl_assembler_held(a) <= budget, "held %zu over the budget", cl_assembler_held(a));
        first += k;
    }
    CHECK(done == 1 && out && gen_layer_equal(&g, out), "the newer layer did not complete intact");
    cl_layer_free(out);
    gen_layer_free(&g);
    free(buf);
    cl_assembler_free(a);
}


/* A temporal layer (cluster.h, "Sections"): intra tiles, then the shared
 * tiles of its stream, each section with its own buffer and offsets; parts
 * never span the two; the edge gets 2 x tps^2 tiles back in order. Layers
 * of one seq from two sim processes (epochs) are never one frame. */
static void test_sections(void)
{
    check_section = "temporal sections";
    struct gen_layer g, sh;
    gen_layer_make(&g, 128, 32, 0, 1, 2, 77, 2000, 5);   /* 16 intra tiles */
    gen_layer_make(&sh, 128, 32, 0, 1, 2, 77, 600, 6);   /* 16 shared tiles (codec 3 in real life) */
    struct cl_layer_info info = g.info;
    info.layer_flags = CL_LAYER_SHARED | CL_LAYER_INTRA;
    info.need = 3;
    int sec = 16;
    CHECK(cl_layer_sections(&info) == 2 && cl_layer_tiles(&info) == 32, "sections %d tiles %d",
          cl_layer_sections(&info), cl_layer_tiles(&info));
    size_t maxp = 8192;
    uint8_t *buf = malloc(maxp);
    CHECK(cl_layer_part_write(buf, maxp, &info, sec - 1, 2, g.data, g.tile_off) == CL_E_ARG,
          "a part across the two sections was written");
    struct cl_assembler *a = cl_assembler_new();
    struct cl_layer *out = NULL;
    int parts = 0;
    for (int first = 0; first < 2 * sec;) {
        const struct gen_layer *s = first < sec ? &g : &sh;
        int local = first % sec;
        int k = cl_layer_part_tiles(s->tile_off, local, sec, maxp);
        CHECK(k >= 1, "no tile fits at %d", first);
        if (k < 1)
            break;
        long w = cl_layer_part_write(buf, maxp, &info, first, k, s->data, s->tile_off);
        CHECK(w > 0, "part write %ld at %d", w, first);
        struct cl_layer_part p;
        int rc = cl_layer_part_parse(buf, (size_t)w, &p);
        CHECK(rc == 0 && p.tile_first == first && p.info.need == 3 && p.info.epoch == g.info.epoch,
              "part parse %d at %d", rc, first);
        if (rc)
            break;
        if (first == 0) { /* the same part claiming to run across the sections */
            uint8_t *c = malloc((size_t)w);
            memcpy(c, buf, (size_t)w);
            c[44] = (uint8_t)(sec - 1); /* tile_first */
            struct cl_layer_part q;
            CHECK(k < 2 || cl_layer_part_parse(c, (size_t)w, &q) == CL_E_CORRUPT, "a part across sections parsed");
            c[44] = 0;
            c[41] = 0; /* intra only: 16 tiles in all */
            c[63] = 0;
            CHECK(cl_layer_part_parse(c, (size_t)w, &q) == 0 && cl_layer_tiles(&q.info) == sec, "intra-only part");
            free(c);
        }
        rc = cl_assembler_add(a, &p, &out);
        CHECK(rc == (first + k == 2 * sec ? 1 : 0), "assembler %d at %d", rc, first);
        parts++;
        first += k;
    }
    CHECK(parts >= 4, "only %d parts", parts);
    CHECK(out && out->len == g.len + sh.len && out->tile_off[2 * sec] == out->len, "assembled layer size");
    if (out) {
        int ok = memcmp(out->data, g.data, g.len) == 0 && memcmp(out->data + g.len, sh.data, sh.len) == 0;
        for (int i = 0; i <= sec; i++)
            ok &= out->tile_off[i] == g.tile_off[i] && out->tile_off[sec + i] == g.len + sh.tile_off[i];
        CHECK(ok, "the sections' tiles or offsets differ after reassembly");
        CHECK(out->info.need == 3 && cl_info_has_intra(&out->info) && cl_info_has_shared(&out->info), "flags");
    }
    /* shared tiles only: one section */
    struct cl_layer_info only = info;
    only.layer_flags = CL_LAYER_SHARED;
    CHECK(cl_layer_sections(&only) == 1 && !cl_info_has_intra(&only), "shared-only layer");
    long w = cl_layer_part_write(buf, maxp, &only, 0, 1, sh.data, sh.tile_off);
    struct cl_layer_part p;
    CHECK(w > 0 && cl_layer_part_parse(buf, (size_t)w, &p) == 0 && cl_info_has_shared(&p.info), "shared-only part");
    /* a temporal layer is never at a coarser LOD than its key */
    struct cl_layer_info coarse = only;
    coarse.encoded_lod = 2;
    CHECK(!cl_layer_info_valid(&coarse), "a degraded temporal layer accepted");
    free(buf);

    /* the same seq from another sim process: not part of this frame */
    struct cl_collector *c = cl_collector_new();
    uint8_t want[CL_KEY_BYTES] = { 0 };
    cl_bit_set(want, cl_key(0, 1, 2), true);
    cl_bit_set(want, cl_key(1, 1, 2), true);
    struct gen_layer o;
    gen_layer_make(&o, 128, 32, 1, 1, 2, 77, 100, 8);
    o.info.epoch = g.info.epoch + 1;
    cl_bit_set(o.info.encoded, cl_key(0, 1, 2), true);
    cl_bit_set(out->info.encoded, cl_key(1, 1, 2), true);
    struct cl_frame_set *fs[2];
    CHECK(cl_collector_add(c, out, want, fs) == 0, "half a frame handed out");
    struct cl_layer *ol = malloc(sizeof *ol);
    ol->info = o.info;
    ol->len = o.len;
    ol->data = o.data;
    ol->tile_off = o.tile_off;
    o.data = NULL;
    o.tile_off = NULL;
    CHECK(cl_collector_add(c, ol, want, fs) == CL_E_CORRUPT, "a layer of another epoch joined the frame");
    struct cl_collector_stats st;
    cl_collector_stats(c, &st);
    CHECK(st.mismatched == 1, "mismatched %llu", (unsigned long long)st.mismatched);
    cl_collector_free(c);
    cl_assembler_free(a);
    gen_layer_free(&o);
    gen_layer_free(&g);
    gen_layer_free(&sh);
}

/* The edge's demand with the temporal codec: keys, stream, wish. */
static void test_demand_ex(void)
{
    check_section = "demand with stream and wish";
    struct cl_demand_bits b, back;
    memset(&b, 0, sizeof b);
    cl_bit_set(b.keys, 3, true);
    cl_bit_set(b.keys, 40, true);
    cl_bit_set(b.stream, 40, true);
    cl_bit_set(b.wish, 3, true);
    uint8_t db[CL_DEMAND_BODY_EX];
    cl_demand_body_write_ex(db, 2500, &b);
    uint32_t ttl = 0;
    CHECK(cl_demand_body_parse_ex(db, sizeof db, &ttl, &back) == 0 && ttl == 2500 &&
          memcmp(&b, &back, sizeof b) == 0, "round trip");
    CHECK(cl_demand_body_parse_ex(db, sizeof db - 1, &ttl, &back) == CL_E_TRUNCATED, "short body");
    CHECK(cl_demand_body_parse_ex(db, CL_DEMAND_BODY + 1, &ttl, &back) == CL_E_TRUNCATED, "odd length");
    uint8_t longer[CL_DEMAND_BODY_EX + 1];
    memcpy(longer, db, sizeof db);
    longer[sizeof db] = 0;
    CHECK(cl_demand_body_parse_ex(longer, sizeof longer, &ttl, &back) == CL_E_CORRUPT, "trailing byte");
    db[4 + CL_KEY_BYTES + 1] |= 1; /* stream key 8: not demanded */
    CHECK(cl_demand_body_parse_ex(db, sizeof db, &ttl, &back) == CL_E_CORRUPT, "stream outside keys");
    cl_demand_body_write_ex(db, 2500, &b);
    db[4 + 2 * CL_KEY_BYTES + 2] |= 1; /* wish key 16: not demanded */
    CHECK(cl_demand_body_parse_ex(db, sizeof db, &ttl, &back) == CL_E_CORRUPT, "wish outside keys");
    /* a keys-only body (an edge that does not stream): every key intra */
    uint8_t old[CL_DEMAND_BODY];
    cl_demand_body_write(old, 1000, b.keys);
    CHECK(cl_demand_body_parse_ex(old, sizeof old, &ttl, &back) == 0 && memcmp(back.keys, b.keys, CL_KEY_BYTES) == 0 &&
          memcmp(back.wish, b.keys, CL_KEY_BYTES) == 0 && !cl_bit(back.stream, 40), "keys-only body");

    struct cl_demand *d = cl_demand_new(4);
    struct cl_demand_bits e2, u;
    memset(&e2, 0, sizeof e2);
    cl_bit_set(e2.keys, 40, true);
    cl_bit_set(e2.wish, 40, true);
    CHECK(cl_demand_update_ex(d, "a", &b, 3, 0) == 0 && cl_demand_update_ex(d, "b", &e2, 1, 0) == 0, "update");
    CHECK(cl_demand_union_ex(d, 0.5, &u) == 2 && cl_bit(u.stream, 40) && cl_bit(u.wish, 40) && cl_bit(u.wish, 3) &&
          cl_bit(u.keys, 3), "union of two edges");
    CHECK(cl_demand_union_ex(d, 2, &u) == 1 && !cl_bit(u.wish, 40) && cl_bit(u.stream, 40), "b expired: its wish too");
    cl_demand_free(d);
}

int main(void)
{
    test_subjects();
    test_part_roundtrip();
    test_part_rejects();
    test_split_assemble();
    test_cascades();
    test_assembler_budget();
    test_envelope();
    test_demand();
    test_collector();
    test_sections();
    test_demand_ex();
    return check_done();
}

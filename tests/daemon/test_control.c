/* test_control — unit tests of server/control.c (pure JSON control logic)
 * and server/config.c precedence, plus a small fuzz loop: random mutations
 * of valid messages must never crash and must leave the params unchanged
 * unless accepted. Prints "N passed, M failed". */
#include <fcntl.h>
#include <inttypes.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "body_msg.h"
#include "capacity.h"
#include "config.h"
#include "control.h"
#include "fileio.h"
#include "log.h"
#include "oc_proto.h"
#include "ocean.h"
#include "render_msg.h"
#include "sea_msg.h"
#include "state.h"

#include "../common/check.h"
#include "../common/sea_fixture.h"

static const struct ctl_limits lim = { .tick_rate = 30, .max_memory_mb = 256 };

/* Parse a set and apply it to defaults; returns the error code or "ok". */
static const char *try_set(const char *text, struct ocean_params *out, uint64_t *changed, struct ctl_error *e)
{
    struct ctl_msg m;
    cJSON *id = NULL;
    struct ocean_params p;
    params_defaults(&p);
    if (control_parse(text, strlen(text), &m, &id, e) != 0) {
        cJSON_Delete(id);
        return e->code;
    }
    if (m.type != CTL_SET) {
        ctl_msg_free(&m);
        return "not_set";
    }
    int rc = control_apply_params(m.params, &p, &lim, out, changed, e);
    ctl_msg_free(&m);
    return rc ? e->code : "ok";
}

static void test_sets(void)
{
    static const struct { const char *text, *code, *param; } cases[] = {
        { "{\"type\":\"set\",\"params\":{\"wind_speed\":20}}", "ok", "" },
        { "{\"type\":\"set\",\"params\":{\"wind_speed\":\"x\"}}", "bad_type", "wind_speed" },
        { "{\"type\":\"set\",\"params\":{\"wind_speed\":1e999}}", "bad_type", "wind_speed" },
        { "{\"type\":\"set\",\"params\":{\"wind_speed\":-1}}", "out_of_range", "wind_speed" },
        { "{\"type\":\"set\",\"params\":{\"resolution\":3000}}", "out_of_range", "resolution" },
        { "{\"type\":\"set\",\"params\":{\"resolution\":96}}", "out_of_range", "resolution" },
        { "{\"type\":\"set\",\"params\":{\"resolution\":2048}}", "invalid", "resolution" },
        { "{\"type\":\"set\",\"params\":{\"resolution\":64.5}}", "bad_type", "resolution" },
        { "{\"type\":\"set\",\"params\":{\"spectrum\":\"phillips\",\"paused\":true}}", "ok", "" },
        { "{\"type\":\"set\",\"params\":{\"spectrum\":3}}", "bad_type", "spectrum" },
        { "{\"type\":\"set\",\"params\":{\"paused\":0}}", "bad_type", "paused" },
        { "{\"type\":\"set\",\"params\":{\"nope\":0}}", "unknown_param", "nope" },
        { "{\"type\":\"set\",\"params\":{\"wind_speed\":NaN}}", "bad_json", "" },
        { "{\"type\":\"set\"}", "bad_message", "" },
        { "{\"type\":7}", "bad_message", "" },
        { "{\"type\":\"set\",\"id\":{\"a\":1},\"params\":{}}", "bad_message", "" },
        { "\"set\"", "bad_json", "" },
        { "{\"type\":\"jump\"}", "unknown_type", "" },
        { "", "bad_json", "" },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        struct ocean_params out;
        uint64_t changed = 0;
        struct ctl_error e = { 0 };
        const char *code = try_set(cases[i].text, &out, &changed, &e);
        CHECK(strcmp(code, cases[i].code) == 0, "%s -> %s (%s), want %s", cases[i].text, code, e.message, cases[i].code);
        if (strcmp(code, "ok") != 0 && cases[i].param[0])
            CHECK(strcmp(e.param, cases[i].param) == 0, "%s: param %s", cases[i].text, e.param);
    }
    /* All or nothing, and the changed mask. */
    struct ocean_params p, out;
    params_defaults(&p);
    out = p;
    uint64_t changed = 0;
    struct ctl_error e;
    cJSON *obj = cJSON_Parse("{\"wind_speed\":21,\"amplitude\":-5}");
    CHECK(control_apply_params(obj, &p, &lim, &out, &changed, &e) != 0, "mixed set accepted");
    CHECK(memcmp(&out, &p, sizeof p) == 0, "rejected set changed the output");
    cJSON_Delete(obj);
    obj = cJSON_Parse("{\"wind_speed\":21,\"seed\":1}");
    CHECK(control_apply_params(obj, &p, &lim, &out, &changed, &e) == 0, "valid set rejected: %s", e.message);
    const struct param_def *ws = param_find("wind_speed");
    CHECK(out.wind_speed == 21 && changed == (1ull << (ws - param_table)), "changed mask %llx", (unsigned long long)changed);
    cJSON_Delete(obj);
}

/* "once" on the requests that change the sea: 8..64 printable ASCII characters. */
static void test_once(void)
{
    static const struct { const char *text; const char *code; const char *once; } cases[] = {
        { "{\"type\":\"set\",\"params\":{},\"once\":\"0123456789abcdef\"}", NULL, "0123456789abcdef" },
        { "{\"type\":\"pause\",\"once\":\"aaaaaaaa\"}", NULL, "aaaaaaaa" },
        { "{\"type\":\"set\",\"params\":{}}", NULL, NULL },
        { "{\"type\":\"set\",\"params\":{},\"once\":\"short\"}", "bad_message", NULL },
        { "{\"type\":\"set\",\"params\":{},\"once\":12345678}", "bad_message", NULL },
        { "{\"type\":\"set\",\"params\":{},\"once\":\"with space in it\"}", "bad_message", NULL },
        { "{\"type\":\"resume\",\"once\":\"\u00e9\u00e9\u00e9\u00e9\u00e9\u00e9\u00e9\u00e9\"}", "bad_message", NULL },
        { "{\"type\":\"set\",\"params\":{},\"once\":\"xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx\"}", "bad_message", NULL },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        struct ctl_msg m;
        struct ctl_error e;
        cJSON *id = NULL;
        int rc = control_parse(cases[i].text, strlen(cases[i].text), &m, &id, &e);
        cJSON_Delete(id);
        if (cases[i].code) {
            CHECK(rc != 0 && strcmp(e.code, cases[i].code) == 0, "%s: rc %d", cases[i].text, rc);
            continue;
        }
        CHECK(rc == 0, "%s refused: %s", cases[i].text, rc ? e.message : "");
        if (rc == 0) {
            CHECK(cases[i].once ? m.once && strcmp(m.once, cases[i].once) == 0 : m.once == NULL, "%s: once %s",
                  cases[i].text, m.once ? m.once : "(none)");
            ctl_msg_free(&m);
        }
    }
}

static void test_subscribe(void)
{
    struct subscription cur, out;
    subscription_default(&cur, 30);
    struct ctl_error e;
    cJSON *m = cJSON_Parse("{\"type\":\"subscribe\",\"fields\":[\"jacobian\",\"height\"],\"lod\":1,"
                           "\"tiles\":[[0,1],[3,2]],\"bound\":0.001,\"max_rate\":100}");
    CHECK(control_apply_subscribe(m, &cur, &lim, &out, &e) == 0, "subscribe rejected: %s", e.message);
    CHECK(out.fields == (OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_JACOBIAN)) && out.lod == 1 &&
              !out.all_tiles && out.ntiles == 2 && out.tiles[1][0] == 3 && out.tiles[1][1] == 2 &&
              out.bound_index == 1 && out.max_rate == 30,
          "normalised subscription");
    char *s = control_print(control_subscribed_msg(&out, NULL));
    CHECK(strstr(s, "\"fields\":[\"height\",\"jacobian\"]") && strstr(s, "\"bound\":0.001") && strstr(s, "\"max_rate\":30"),
          "subscribed text %s", s);
    free(s);
    cJSON_Delete(m);
    /* "fields": [] is no frames at all (a control connection): no cascade either. */
    m = cJSON_Parse("{\"fields\":[]}");
    CHECK(control_apply_subscribe(m, &cur, &lim, &out, &e) == 0 && out.fields == 0 && out.ncascades == 1 &&
              !subscription_has_frames(&out), "fields [] is not a subscription to no frames");
    s = control_print(control_subscribed_msg(&out, NULL));
    CHECK(s && strstr(s, "\"fields\":[]"), "subscribed text %s", s ? s : "(null)");
    free(s);
    cJSON_Delete(m);
    CHECK(subscription_has_frames(&cur), "the default subscription has no frames");
    const char *bad[] = { "{\"fields\":[],\"cascades\":[]}", "{\"cascades\":[{\"fields\":[]}]}",
                          "{\"fields\":[\"spray\"]}", "{\"lod\":5}", "{\"lod\":1.5}",
                          "{\"bound\":0.002}", "{\"max_rate\":0}", "{\"tiles\":\"some\"}", "{\"tiles\":[[0,40]]}",
                          "{\"tiles\":[[0]]}", "{\"field_lod\":[2]}", "{\"field_lod\":{\"spray\":1}}",
                          "{\"field_lod\":{\"foam\":5}}", "{\"field_lod\":{\"foam\":\"2\"}}",
                          "{\"field_lod\":{\"foam\":0.5}}" };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        m = cJSON_Parse(bad[i]);
        out = cur;
        CHECK(control_apply_subscribe(m, &cur, &lim, &out, &e) != 0 && strcmp(e.code, "bad_subscription") == 0,
              "%s accepted", bad[i]);
        cJSON_Delete(m);
    }
}

/* Per-field LOD: foam coarser than the heights; fields not named follow "lod";
 * {} clears the map; subscribed shows it only when some field has its own. */
static void test_subscribe_field_lod(void)
{
    struct subscription cur, out;
    subscription_default(&cur, 30);
    struct ctl_error e;
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        CHECK(subscription_lod(&cur, f) == 0, "default LOD of field %d", f);
    char *s = control_print(control_subscribed_msg(&cur, NULL));
    CHECK(s && !strstr(s, "field_lod"), "default subscription shows field_lod: %s", s ? s : "(null)");
    free(s);
    cJSON *m = cJSON_Parse("{\"type\":\"subscribe\",\"fields\":[\"height\",\"foam\"],\"lod\":1,\"field_lod\":{\"foam\":3}}");
    CHECK(control_apply_subscribe(m, &cur, &lim, &out, &e) == 0, "field_lod rejected: %s", e.message);
    CHECK(subscription_lod(&out, OCEAN_FOAM) == 3 && subscription_lod(&out, OCEAN_HEIGHT) == 1, "foam %d height %d",
          subscription_lod(&out, OCEAN_FOAM), subscription_lod(&out, OCEAN_HEIGHT));
    s = control_print(control_subscribed_msg(&out, NULL));
    CHECK(s && strstr(s, "\"field_lod\":{\"foam\":3}"), "subscribed text %s", s ? s : "(null)");
    free(s);
    cJSON_Delete(m);
    /* A later lod moves the other fields, not foam; {} clears. */
    cur = out;
    m = cJSON_Parse("{\"type\":\"subscribe\",\"lod\":0}");
    CHECK(control_apply_subscribe(m, &cur, &lim, &out, &e) == 0 && subscription_lod(&out, OCEAN_FOAM) == 3 &&
              subscription_lod(&out, OCEAN_HEIGHT) == 0, "lod 0 after field_lod");
    cJSON_Delete(m);
    cur = out;
    m = cJSON_Parse("{\"type\":\"subscribe\",\"field_lod\":{}}");
    CHECK(control_apply_subscribe(m, &cur, &lim, &out, &e) == 0 && subscription_lod(&out, OCEAN_FOAM) == 0, "{} clears");
    cJSON_Delete(m);
    /* A refused map changes nothing. */
    cur = out;
    m = cJSON_Parse("{\"type\":\"subscribe\",\"lod\":2,\"field_lod\":{\"foam\":1,\"spray\":1}}");
    CHECK(control_apply_subscribe(m, &cur, &lim, &out, &e) != 0 && strcmp(e.code, "bad_subscription") == 0 &&
              strstr(e.message, "spray"), "unknown field in field_lod accepted");
    cJSON_Delete(m);
}

/* D1 (docs/reliability.md): the whole message must be exactly one JSON
 * value, with no raw control bytes, no invalid \u escapes and no \u0000 (which
 * would truncate names: "set\u0000x" must not act as "set"). */
static void test_strict_json(void)
{
    static const struct { const char *text; size_t len; const char *code; } cases[] = {
        { "{\"type\":\"ping\",\"id\":1} trailing", 0, "bad_json" },
        { "{\"type\":\"set\",\"id\":2,\"params\":{\"wind_speed\":21}}}", 0, "bad_json" },
        { "{\"type\":\"set\",\"id\":3,\"params\":{\"wind_speed\":22}} {\"type\":\"set\"}", 0, "bad_json" },
        { "{\"type\":\"ping\"\0,\"id\":4}", 23, "bad_json" },          /* raw NUL between tokens */
        { "{\"type\":\"ping\",\"id\":4}\0", 23, "bad_json" },          /* raw NUL after the value */
        { "{\"type\":\"ping\",\x01\"id\":4}", 0, "bad_json" },         /* raw control byte */
        { "{\"type\":\"pi\x1fng\"}", 0, "bad_json" },                   /* raw control byte in a string */
        { "{\"type\":\"ping\",\"id\":5,\"x\":\"\\uZZZZ\"}", 0, "bad_json" },
        { "{\"type\":\"ping\",\"id\":5,\"x\":\"\\u12\"}", 0, "bad_json" },
        { "{\"type\":\"ping\",\"x\":\"\\u", 0, "bad_json" },
        { "{\"type\":\"set\\u0000x\",\"id\":6,\"params\":{\"wind_speed\":23}}", 0, "bad_json" },
        { "{\"type\":\"set\",\"id\":7,\"params\":{\"spectrum\":\"phillips\\u0000junk\"}}", 0, "bad_json" },
        { "{\"type\":\"set\",\"id\":8,\"params\":{\"wind_speed\\u0000x\":13}}", 0, "bad_json" },
        { "{\"type\":\"subscribe\",\"id\":9,\"fields\":[\"height\\u0000junk\"]}", 0, "bad_json" },
        /* still fine: whitespace around, escapes that are not NUL, an escaped backslash before "u0000" */
        { " \t\r\n{\"type\":\"ping\",\"id\":10} \r\n\t ", 0, "ok" },
        { "{\"type\":\"p\\u0069ng\",\"x\":\"\\\\u0000 \\n \\u00e9\"}", 0, "ok" },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        size_t len = cases[i].len ? cases[i].len : strlen(cases[i].text);
        struct ctl_msg m;
        struct ctl_error e = { 0 };
        cJSON *id = NULL;
        int rc = control_parse(cases[i].text, len, &m, &id, &e);
        cJSON_Delete(id);
        const char *code = rc ? e.code : "ok";
        CHECK(strcmp(code, cases[i].code) == 0, "strict JSON case %zu (%.60s): %s (%s), want %s", i, cases[i].text,
              code, e.message, cases[i].code);
        if (rc == 0) {
            CHECK(m.type == CTL_PING, "case %zu: type %d, want ping", i, (int)m.type);
            ctl_msg_free(&m);
        }
    }
}

/* D3: duplicate tiles are dropped, so no subscription asks for more than the
 * whole grid; 1024 copies of [0,0] normalise to one tile. */
static void test_subscribe_dedupe(void)
{
    struct subscription cur, *out = malloc(sizeof *out);
    subscription_default(&cur, 30);
    struct ctl_error e;
    size_t cap = 32 + 1024 * 8;
    char *text = malloc(cap);
    size_t off = (size_t)snprintf(text, cap, "{\"type\":\"subscribe\",\"tiles\":[");
    for (int i = 0; i < 1024; i++)
        off += (size_t)snprintf(text + off, cap - off, "%s[0,0]", i ? "," : "");
    snprintf(text + off, cap - off, "]}");
    cJSON *m = cJSON_Parse(text);
    CHECK(m && control_apply_subscribe(m, &cur, &lim, out, &e) == 0, "1024 x [0,0] rejected: %s", e.message);
    CHECK(!out->all_tiles && out->ntiles == 1 && out->tiles[0][0] == 0 && out->tiles[0][1] == 0,
          "1024 x [0,0] normalised to %d tiles, want 1", out->ntiles);
    cJSON_Delete(m);
    m = cJSON_Parse("{\"tiles\":[[1,2],[3,4],[1,2],[2,1],[3,4],[31,31],[31,31]]}");
    CHECK(control_apply_subscribe(m, &cur, &lim, out, &e) == 0, "subscribe with duplicates rejected: %s", e.message);
    CHECK(out->ntiles == 4 && out->tiles[0][0] == 1 && out->tiles[0][1] == 2 && out->tiles[1][0] == 3 &&
              out->tiles[2][0] == 2 && out->tiles[2][1] == 1 && out->tiles[3][0] == 31,
          "duplicates: %d tiles, want 4 in first-seen order", out->ntiles);
    char *s = control_print(control_subscribed_msg(out, NULL));
    CHECK(s && strstr(s, "\"tiles\":[[1,2],[3,4],[2,1],[31,31]]"), "subscribed text %s", s ? s : "(null)");
    free(s);
    cJSON_Delete(m);
    free(text);
    free(out);
}

static void test_token_equal(void)
{
    CHECK(control_token_equal("s3cret", "s3cret"), "same token refused");
    CHECK(!control_token_equal("s3cres", "s3cret"), "last byte differs: accepted");
    CHECK(!control_token_equal("s3cre", "s3cret"), "prefix accepted");
    CHECK(!control_token_equal("s3cretX", "s3cret"), "longer accepted");
    CHECK(!control_token_equal("", "s3cret"), "empty accepted");
    CHECK(!control_token_equal("S3CRET", "s3cret"), "case-changed accepted");
}

static void test_builders(void)
{
    struct ocean_params p;
    params_defaults(&p);
    struct subscription sub;
    subscription_default(&sub, 30);
    struct hello_info h = { "c1", true, &p, 3, 30, 64, &sub, NULL, 8, NULL };
    char *s = control_print(control_hello_msg(&h));
    cJSON *j = cJSON_Parse(s);
    CHECK(j && cJSON_GetArraySize(cJSON_GetObjectItem(j, "schema")) == (int)param_count, "hello schema");
    CHECK(strcmp(cJSON_GetStringValue(cJSON_GetObjectItem(cJSON_GetObjectItem(j, "params"), "spectrum")),
                 param_enum_name(param_find("spectrum"), p.spectrum)) == 0, "enum as string");
    CHECK(cJSON_IsBool(cJSON_GetObjectItem(cJSON_GetObjectItem(j, "params"), "paused")), "bool as bool");
    /* The params object round-trips through control_apply_params unchanged. */
    struct ocean_params back;
    uint64_t changed = 1;
    struct ctl_error e;
    CHECK(control_apply_params(cJSON_GetObjectItem(j, "params"), &p, &lim, &back, &changed, &e) == 0 && changed == 0,
          "params round trip");
    cJSON_Delete(j);
    free(s);
    cJSON *id = cJSON_CreateNumber(5);
    s = control_print(control_params_msg(&p, 4, 1ull << 2, "c2", id));
    CHECK(strstr(s, "\"changed\":[\"") && strstr(s, "\"by\":\"c2\"") && strstr(s, "\"id\":5"), "params msg %s", s);
    free(s);
    cJSON_Delete(id);
}

static void test_state_and_config(void)
{
    char dir[] = "/tmp/oceand-ctl-XXXXXX";
    if (!mkdtemp(dir)) {
        CHECK(0, "mkdtemp");
        return;
    }
    char state[128], cfg[128], err[256];
    snprintf(state, sizeof state, "%s/state.json", dir);
    snprintf(cfg, sizeof cfg, "%s/c.json", dir);
    struct ocean_params p;
    params_defaults(&p);
    p.wind_speed = 7;
    p.seed = 42;
    CHECK(state_save(state, &p, 9, 12.5, NULL, NULL, err, sizeof err) == 0, "state_save: %s", err);
    FILE *f = fopen(cfg, "w");
    fputs("{\"wind_speed\": 8, \"port\": 9999}", f);
    fclose(f);
    char *argv[] = { "oceand", "--state-file", state, "--config", cfg, "--tick-rate=15", "--choppiness", "2", NULL };
    struct daemon_config dc;
    struct config_result res;
    struct ocean_params q;
    CHECK(config_load(8, argv, &dc, &q, &res, err, sizeof err) == 0, "config_load: %s", err);
    CHECK(q.seed == 42 && q.wind_speed == 8 && q.choppiness == 2 && dc.port == 9999 && dc.tick_rate == 15 &&
              res.params_version == 9 && res.sim_time == 12.5,
          "precedence: seed %d wind %g chop %g port %d", q.seed, q.wind_speed, q.choppiness, dc.port);
    CHECK(dc.tile_size == 128, "default tile size %d, want 128", dc.tile_size);
    f = fopen(cfg, "w");
    fputs("{\"wind_speed\": 8}\n{\"port\": 1}", f);
    fclose(f);
    char *trailing[] = { "oceand", "--state-file", "none", "--config", cfg, NULL };
    CHECK(config_load(5, trailing, &dc, &q, &res, err, sizeof err) != 0, "config file with trailing data accepted");
    char *bad[] = { "oceand", "--state-file", "none", "--port", "70000", NULL };
    CHECK(config_load(5, bad, &dc, &q, &res, err, sizeof err) != 0, "port 70000 accepted");
    char *half_tls[] = { "oceand", "--state-file", "none", "--tls-cert", "/x/cert.pem", NULL };
    CHECK(config_load(5, half_tls, &dc, &q, &res, err, sizeof err) != 0 && strstr(err, "tls"),
          "--tls-cert without --tls-key accepted");
    char *tls[] = { "oceand", "--state-file", "none", "--tls-cert", "/x/cert.pem", "--tls-key=/x/key.pem", NULL };
    CHECK(config_load(6, tls, &dc, &q, &res, err, sizeof err) == 0 && strcmp(dc.tls_cert, "/x/cert.pem") == 0 &&
              strcmp(dc.tls_key, "/x/key.pem") == 0,
          "TLS flags: %s", err);
    unlink(state);
    unlink(cfg);
    rmdir(dir);
}

/* ---- stderr capture: the daemon's warnings are part of the contract ---- */

static char captured[16384];
static int capture_fd = -1, saved_stderr = -1;

static void capture_begin(void)
{
    char tmpl[] = "/tmp/oceand-ctl-log-XXXXXX";
    fflush(stderr);
    capture_fd = mkstemp(tmpl);
    unlink(tmpl);
    saved_stderr = dup(STDERR_FILENO);
    dup2(capture_fd, STDERR_FILENO);
}

static const char *capture_end(void)
{
    fflush(stderr);
    dup2(saved_stderr, STDERR_FILENO);
    close(saved_stderr);
    lseek(capture_fd, 0, SEEK_SET);
    ssize_t n = read(capture_fd, captured, sizeof captured - 1);
    captured[n > 0 ? n : 0] = '\0';
    close(capture_fd);
    return captured;
}

static void write_text(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

/* One validation path. The same fault gets the same reason from
 * the JSON `set`, the config file and the command line, and each reason maps
 * to one documented wire code. */
static void test_one_validation_path(void)
{
    static const struct { enum param_error r; const char *code; } map[] = {
        { PARAM_ERR_UNKNOWN, "unknown_param" }, { PARAM_ERR_TYPE, "bad_type" },
        { PARAM_ERR_NOT_FINITE, "bad_type" },   { PARAM_ERR_NOT_INTEGER, "bad_type" },
        { PARAM_ERR_RANGE, "out_of_range" },    { PARAM_ERR_NOT_POW2, "out_of_range" },
        { PARAM_ERR_BAD_ENUM, "out_of_range" }, { PARAM_ERR_TOO_LONG, "out_of_range" },
        { PARAM_ERR_INVALID, "invalid" },
    };
    for (size_t i = 0; i < sizeof map / sizeof map[0]; i++)
        CHECK(strcmp(control_error_code(map[i].r), map[i].code) == 0, "param_error %d -> %s, want %s",
              (int)map[i].r, control_error_code(map[i].r), map[i].code);
    /* Spec gap (PROTOCOL.md §7.2): a bad enum name, a non-power-of-two N and a
     * fractional int, over JSON. */
    static const struct { const char *text, *code, *words; } cases[] = {
        { "{\"type\":\"set\",\"params\":{\"spectrum\":\"bretschneider\"}}", "out_of_range", "not one of" },
        { "{\"type\":\"set\",\"params\":{\"resolution\":100}}", "out_of_range", "power of two" },
        { "{\"type\":\"set\",\"params\":{\"seed\":2.5}}", "bad_type", "whole number" },
        { "{\"type\":\"set\",\"params\":{\"resolution\":4096}}", "out_of_range", "out of range" },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        struct ocean_params out;
        struct ctl_error e = { 0 };
        const char *code = try_set(cases[i].text, &out, NULL, &e);
        CHECK(strcmp(code, cases[i].code) == 0 && strstr(e.message, cases[i].words), "%s -> %s (%s), want %s (%s)",
              cases[i].text, code, e.message, cases[i].code, cases[i].words);
    }
    /* The same reasons through config_load: flag and config file. */
    char dir[] = "/tmp/oceand-ctl-XXXXXX";
    if (!mkdtemp(dir)) {
        CHECK(0, "mkdtemp");
        return;
    }
    char cfg[128], err[512];
    snprintf(cfg, sizeof cfg, "%s/c.json", dir);
    struct daemon_config dc;
    struct config_result res;
    struct ocean_params q;
    static const struct { const char *flag, *value, *json, *words; } same[] = {
        { "--resolution", "100", "{\"resolution\": 100}", "power of two" },
        { "--seed", "2.5", "{\"seed\": 2.5}", "whole number" },
        { "--spectrum", "bretschneider", "{\"spectrum\": \"bretschneider\"}", "not one of" },
        { "--port", "70000", "{\"port\": 70000}", "out of range" },
        { "--log-level", "loud", "{\"log_level\": \"loud\"}", "not one of" },
        { "--tick-rate", "fast", "{\"tick_rate\": \"fast\"}", "" },
    };
    for (size_t i = 0; i < sizeof same / sizeof same[0]; i++) {
        char *argv[] = { "oceand", "--state-file", "none", (char *)same[i].flag, (char *)same[i].value, NULL };
        int rc = config_load(5, argv, &dc, &q, &res, err, sizeof err);
        CHECK(rc != 0 && strstr(err, same[i].words), "%s %s: rc %d, \"%s\"", same[i].flag, same[i].value, rc, err);
        write_text(cfg, same[i].json);
        char *argv2[] = { "oceand", "--state-file", "none", "--config", cfg, NULL };
        rc = config_load(5, argv2, &dc, &q, &res, err, sizeof err);
        CHECK(rc != 0 && strstr(err, same[i].words), "config %s: rc %d, \"%s\"", same[i].json, rc, err);
    }
    /* Daemon options and sea parameters share the JSON typing of a `set`. */
    write_text(cfg, "{\"log_level\": \"debug\", \"bind\": \"0.0.0.0\", \"tick_rate\": 12.5, \"paused\": true}");
    char *ok[] = { "oceand", "--state-file", "none", "--config", cfg, NULL };
    CHECK(config_load(5, ok, &dc, &q, &res, err, sizeof err) == 0 && dc.log_level == OLOG_DEBUG &&
              strcmp(dc.bind, "0.0.0.0") == 0 && dc.tick_rate == 12.5 && q.paused,
          "config file with options and parameters: %s", err);
    /* A secret is never echoed in an error. */
    char long_token[300];
    memset(long_token, 'k', sizeof long_token - 1);
    long_token[sizeof long_token - 1] = '\0';
    char *tok[] = { "oceand", "--state-file", "none", "--control-token", long_token, NULL };
    CHECK(config_load(5, tok, &dc, &q, &res, err, sizeof err) != 0 && !strstr(err, "kkkkkkkk"),
          "too long a token: \"%s\"", err);
    unlink(cfg);
    rmdir(dir);
}

/* An echoed id is capped at CTL_MAX_ID_BYTES of JSON. */
static void test_id_cap(void)
{
    char id[CTL_MAX_ID_BYTES + 64], text[CTL_MAX_ID_BYTES + 128];
    struct ctl_msg m;
    struct ctl_error e;
    cJSON *id_out = NULL;
    /* "..." with 254 characters: 256 bytes of JSON, the most allowed. */
    memset(id, 'a', CTL_MAX_ID_BYTES - 2);
    id[CTL_MAX_ID_BYTES - 2] = '\0';
    snprintf(text, sizeof text, "{\"type\":\"ping\",\"id\":\"%s\"}", id);
    CHECK(control_parse(text, strlen(text), &m, &id_out, &e) == 0, "id of %d bytes refused: %s", CTL_MAX_ID_BYTES,
          e.message);
    if (m.root)
        ctl_msg_free(&m);
    strcat(id, "a");
    snprintf(text, sizeof text, "{\"type\":\"ping\",\"id\":\"%s\"}", id);
    int rc = control_parse(text, strlen(text), &m, &id_out, &e);
    CHECK(rc != 0 && strcmp(e.code, "bad_message") == 0 && id_out == NULL,
          "id of %d bytes: rc %d code %s, echoed %s", CTL_MAX_ID_BYTES + 1, rc, rc ? e.code : "-", id_out ? "yes" : "no");
    cJSON_Delete(id_out);
    /* Escapes count as printed: 60 "\n" are 120 bytes, 200 of them 400. */
    char esc[1024] = "{\"type\":\"ping\",\"id\":\"";
    for (int i = 0; i < 200; i++)
        strcat(esc, "\\n");
    strcat(esc, "\"}");
    id_out = NULL;
    rc = control_parse(esc, strlen(esc), &m, &id_out, &e);
    CHECK(rc != 0 && strcmp(e.code, "bad_message") == 0 && id_out == NULL, "escaped long id accepted");
    cJSON_Delete(id_out);
    /* A long id on an unknown type is not echoed either. */
    char big[2048];
    memset(id, 'b', sizeof id - 1);
    id[sizeof id - 1] = '\0';
    snprintf(big, sizeof big, "{\"type\":\"jump\",\"id\":\"%s\"}", id);
    id_out = NULL;
    rc = control_parse(big, strlen(big), &m, &id_out, &e);
    CHECK(rc != 0 && id_out == NULL, "long id echoed on an error");
    cJSON_Delete(id_out);
}

/* Spec gap: pong.server_time_us is an exact integer, never 1e+15. */
static void test_pong_integer(void)
{
    static const struct { uint64_t us; const char *text; } cases[] = {
        { 1000000000000000ull, "\"server_time_us\":1000000000000000" },
        { 1763719200123456ull, "\"server_time_us\":1763719200123456" },
        { 9007199254740993ull, "\"server_time_us\":9007199254740993" },
        { UINT64_MAX, "\"server_time_us\":18446744073709551615" },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char *s = control_print(control_pong_msg(NULL, NULL, cases[i].us));
        const char *at = s ? strstr(s, cases[i].text) : NULL;
        CHECK(at && at[strlen(cases[i].text)] == '}', "pong %s, want %s", s ? s : "(null)", cases[i].text);
        free(s);
    }
}

/* Spec gap: the `codec` member of subscribe is a coded error, not ignored. */
static void test_subscribe_codec(void)
{
    struct subscription cur, *out = malloc(sizeof *out);
    subscription_default(&cur, 30);
    struct ctl_error e;
    static const struct { const char *text; int ok; } cases[] = {
        { "{\"codec\":1}", 1 }, { "{\"codec\":2}", 0 }, { "{\"codec\":0}", 0 }, { "{\"codec\":\"zstd\"}", 0 },
        { "{\"codec\":1.5}", 0 },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        cJSON *m = cJSON_Parse(cases[i].text);
        int rc = control_apply_subscribe(m, &cur, &lim, out, &e);
        CHECK(cases[i].ok ? rc == 0 : rc != 0 && strcmp(e.code, "bad_subscription") == 0, "%s: rc %d", cases[i].text, rc);
        cJSON_Delete(m);
    }
    free(out);
}

/* Spec gap: the live hello has the shape of proto/vectors/control/01_hello.json
 * (every member, schema row by row, paused included); descriptions are free
 * text and not compared. */
static void strip_descriptions(cJSON *hello)
{
    cJSON *row;
    cJSON_ArrayForEach(row, cJSON_GetObjectItem(hello, "schema"))
        cJSON_DeleteItemFromObject(row, "description");
}

static void test_hello_matches_vector(void)
{
    char *text, err[256];
    size_t len;
    if (file_read_all("proto/vectors/control/01_hello.json", 1 << 20, &text, &len, err, sizeof err) != 0) {
        CHECK(0, "vector: %s (run from the repository root)", err);
        return;
    }
    cJSON *want = cJSON_Parse(text);
    free(text);
    struct ocean_params p;
    params_defaults(&p);
    struct subscription sub;
    subscription_default(&sub, 30);
    struct hello_info h = { "c7-k3qf", true, &p, 12, 30, 64, &sub, NULL, 8, NULL };
    cJSON *have = control_hello_msg(&h);
    strip_descriptions(want);
    strip_descriptions(have);
    const cJSON *ws = cJSON_GetObjectItem(want, "schema"), *hs = cJSON_GetObjectItem(have, "schema");
    for (int i = 0; i < cJSON_GetArraySize(hs); i++) {
        const cJSON *a = cJSON_GetArrayItem(hs, i), *b = cJSON_GetArrayItem(ws, i);
        if (!cJSON_Compare(a, b, 1)) {
            char *x = cJSON_PrintUnformatted(a), *y = cJSON_PrintUnformatted(b);
            CHECK(0, "schema row %d: live %s, vector %s", i, x, y ? y : "(missing)");
            free(x);
            free(y);
        }
    }
    CHECK(want && cJSON_Compare(have, want, 1), "hello differs from 01_hello.json beyond the descriptions");
    cJSON_Delete(want);
    cJSON_Delete(have);
}

/* Spec gap (PROTOCOL.md §6.1): under 8 bytes a binary message is `truncated`
 * whatever its bytes; `magic` needs the 8 bytes of magic + version. */
static void test_short_frames(void)
{
    static const uint8_t ocn[8] = { 'O', 'C', 'N', 'F', 1, 0, 48, 0 }, junk[8] = "XYZWXYZ";
    struct oc_frame_header h;
    for (size_t len = 0; len < 8; len++) {
        CHECK(oc_frame_header_read(ocn, len, &h) == OC_E_TRUNCATED, "%zu bytes of OCNF: not truncated", len);
        CHECK(oc_frame_header_read(junk, len, &h) == OC_E_TRUNCATED, "%zu junk bytes: not truncated", len);
    }
    CHECK(oc_frame_header_read(junk, 8, &h) == OC_E_MAGIC, "8 junk bytes: not magic");
    CHECK(oc_frame_header_read(ocn, 8, &h) == OC_E_TRUNCATED, "8 bytes of a header: not truncated");
}

/* A config file over 16 MiB is refused, not cut; a FIFO as the config or state file is refused at once (it used to block
 * start-up forever: the alarm turns a hang into a failure). */
static void test_config_file_limits(void)
{
    char dir[] = "/tmp/oceand-ctl-XXXXXX";
    if (!mkdtemp(dir)) {
        CHECK(0, "mkdtemp");
        return;
    }
    char cfg[128], fifo[128], err[512];
    snprintf(cfg, sizeof cfg, "%s/big.json", dir);
    snprintf(fifo, sizeof fifo, "%s/fifo", dir);
    /* A valid object, blanks up to exactly 16 MiB, then a stray byte: cut at
     * 16 MiB it would be accepted. */
    FILE *f = fopen(cfg, "w");
    const char *obj = "{\"wind_speed\": 8}";
    fputs(obj, f);
    static char blanks[1 << 16];
    memset(blanks, ' ', sizeof blanks);
    size_t left = (16u << 20) - strlen(obj);
    while (left > 0) {
        size_t k = left < sizeof blanks ? left : sizeof blanks;
        fwrite(blanks, 1, k, f);
        left -= k;
    }
    fputc('x', f);
    fclose(f);
    struct daemon_config dc;
    struct config_result res;
    struct ocean_params q;
    char *big[] = { "oceand", "--state-file", "none", "--config", cfg, NULL };
    int rc = config_load(5, big, &dc, &q, &res, err, sizeof err);
    CHECK(rc != 0 && strstr(err, "16 MiB"), "config file over 16 MiB: rc %d, \"%s\"", rc, err);
    truncate(cfg, 16u << 20); /* exactly 16 MiB: the object and blanks */
    rc = config_load(5, big, &dc, &q, &res, err, sizeof err);
    CHECK(rc == 0 && q.wind_speed == 8, "config file of exactly 16 MiB: rc %d, \"%s\"", rc, err);
    unlink(cfg);

    CHECK(mkfifo(fifo, 0600) == 0, "mkfifo");
    alarm(20);
    char *cfg_fifo[] = { "oceand", "--state-file", "none", "--config", fifo, NULL };
    rc = config_load(5, cfg_fifo, &dc, &q, &res, err, sizeof err);
    CHECK(rc != 0 && strstr(err, "not a regular file") && strstr(err, "FIFO"), "FIFO config: rc %d, \"%s\"", rc, err);
    char *state_fifo[] = { "oceand", "--state-file", fifo, NULL };
    rc = config_load(3, state_fifo, &dc, &q, &res, err, sizeof err);
    CHECK(rc != 0 && strstr(err, "not a regular file"), "FIFO state file: rc %d, \"%s\"", rc, err);
    char *state_dir[] = { "oceand", "--state-file", dir, NULL };
    rc = config_load(3, state_dir, &dc, &q, &res, err, sizeof err);
    CHECK(rc != 0 && strstr(err, "directory"), "directory as state file: rc %d, \"%s\"", rc, err);
    alarm(0);
    unlink(fifo);
    rmdir(dir);
}

/* Bad saved values are warned about and fall back;
 * none stops the daemon. */
static void test_state_values(void)
{
    char dir[] = "/tmp/oceand-ctl-XXXXXX";
    if (!mkdtemp(dir)) {
        CHECK(0, "mkdtemp");
        return;
    }
    char state[128], err[512];
    snprintf(state, sizeof state, "%s/state.json", dir);
    struct daemon_config dc;
    struct config_result res;
    struct ocean_params q;
    char *argv[] = { "oceand", "--state-file", state, "--max-memory-mb", "64", NULL };

    /* A saved N above the memory cap: warn, fall back to the default N. */
    write_text(state, "{\"params\":{\"resolution\":2048,\"wind_speed\":7},\"params_version\":3,\"sim_time\":5}");
    capture_begin();
    int rc = config_load(5, argv, &dc, &q, &res, err, sizeof err);
    const char *log = capture_end();
    CHECK(rc == 0 && q.resolution == 256 && q.wind_speed == 7 && res.params_version == 3,
          "saved N=2048 over a 64 MB cap: rc %d (%s), N %d", rc, rc ? err : "", q.resolution);
    CHECK(strstr(log, "resolution 2048") != NULL, "no warning about the saved resolution: %s", log);
    /* ... but the same N on the command line is still an error. */
    char *cli[] = { "oceand", "--state-file", "none", "--max-memory-mb", "64", "--resolution", "2048", NULL };
    CHECK(config_load(7, cli, &dc, &q, &res, err, sizeof err) != 0, "N=2048 over the cap from the command line accepted");

    static const struct { const char *file; double sim_time; uint32_t version; const char *warning; } cases[] = {
        { "{\"params\":{},\"params_version\":12,\"sim_time\":1e15}", 0, 12, "sim_time" },
        { "{\"params\":{},\"params_version\":12,\"sim_time\":1e9}", OCEAN_TIME_MAX, 12, NULL },
        { "{\"params\":{},\"params_version\":12,\"sim_time\":1000000000.5}", 0, 12, "sim_time" },
        { "{\"params\":{},\"params_version\":12,\"sim_time\":-1}", 0, 12, "sim_time" },
        { "{\"params\":{},\"params_version\":12,\"sim_time\":\"soon\"}", 0, 12, "sim_time" },
        /* The last version a running daemon can reach (sets stop there) loads again; beyond it, no. */
        { "{\"params\":{},\"params_version\":4294967295,\"sim_time\":2}", 2, 4294967295u, NULL },
        { "{\"params\":{},\"params_version\":4294967296,\"sim_time\":2}", 2, 0, "params_version" },
        { "{\"params\":{},\"params_version\":4294967294,\"sim_time\":2}", 2, 4294967294u, NULL },
        { "{\"params\":{},\"params_version\":1e30,\"sim_time\":2}", 2, 0, "params_version" },
        { "{\"params\":{},\"params_version\":-7,\"sim_time\":2}", 2, 0, "params_version" },
        { "{\"params\":{},\"params_version\":7.5,\"sim_time\":2}", 2, 0, "params_version" },
        { "{\"params\":{},\"params_version\":7,\"sim_time\":2}\nnot json", 2, 7, "trailing data" },
        { "{\"params\":{},\"params_version\":7,\"sim_time\":2}\n \n", 2, 7, NULL },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        write_text(state, cases[i].file);
        capture_begin();
        rc = config_load(5, argv, &dc, &q, &res, err, sizeof err);
        log = capture_end();
        CHECK(rc == 0 && res.state_loaded && res.sim_time == cases[i].sim_time && res.params_version == cases[i].version,
              "state %s: rc %d, sim_time %.17g, version %u", cases[i].file, rc, res.sim_time, res.params_version);
        if (cases[i].warning)
            CHECK(strstr(log, cases[i].warning) != NULL, "state %s: no warning about %s (log: %s)", cases[i].file,
                  cases[i].warning, log);
        else
            CHECK(log[0] == '\0', "state %s: unexpected warning %s", cases[i].file, log);
    }
    unlink(state);
    rmdir(dir);
}

/* Random mutations of valid messages: no crash, and a rejected set leaves
 * the output untouched (run under ASan by test-daemon-asan). */
static void fuzz(void)
{
    static const char *seeds[] = {
        "{\"type\":\"set\",\"id\":1,\"params\":{\"wind_speed\":20,\"spectrum\":\"jonswap\",\"resolution\":128}}",
        "{\"type\":\"subscribe\",\"fields\":[\"height\",\"dx\"],\"lod\":2,\"tiles\":[[0,0],[1,2]],\"bound\":0.01}",
        "{\"type\":\"ping\",\"id\":\"x\",\"t\":12.5}",
    };
    const char alphabet[] = "{}[]\",:0123456789.eE-+truefalsnul \\u";
    srand(1234);
    struct ocean_params p;
    params_defaults(&p);
    struct subscription sub;
    subscription_default(&sub, 30);
    int accepted = 0;
    for (int it = 0; it < 20000; it++) {
        char buf[512];
        snprintf(buf, sizeof buf, "%s", seeds[it % 3]);
        size_t len = strlen(buf);
        for (int k = rand() % 4 + 1; k > 0; k--) {
            size_t pos = (size_t)rand() % len;
            int op = rand() % 3;
            if (op == 0)
                buf[pos] = alphabet[rand() % (sizeof alphabet - 1)];
            else if (op == 1 && len > 1)
                memmove(buf + pos, buf + pos + 1, len-- - pos);
            else if (len + 1 < sizeof buf) {
                memmove(buf + pos + 1, buf + pos, len++ - pos + 1);
                buf[pos] = alphabet[rand() % (sizeof alphabet - 1)];
            }
        }
        struct ctl_msg m;
        struct ctl_error e;
        cJSON *id = NULL;
        if (control_parse(buf, len, &m, &id, &e) != 0) {
            cJSON_Delete(id);
            continue;
        }
        struct ocean_params out = p;
        struct subscription so = sub;
        if (m.type == CTL_SET) {
            if (control_apply_params(m.params, &p, &lim, &out, NULL, &e) == 0)
                accepted++;
            else if (memcmp(&out, &p, sizeof p) != 0)
                CHECK(0, "rejected set modified output: %s", buf);
        } else if (m.type == CTL_SUBSCRIBE) {
            control_apply_subscribe(m.root, &sub, &lim, &so, &e);
        }
        ctl_msg_free(&m);
    }
    CHECK(accepted > 0, "fuzz never produced a valid set");
}

/* capacity.c: the plan of a tick (docs/daemon.md, "Capacity"), from a model
 * with fixed numbers: behaviour only, no clock. */
/* The one rule per counter and clock (control.h) that the state file, the
 * cluster's record and the edge's hello share: the limits the running daemon
 * reaches are inside, anything else (NaN too) outside. */
static void test_counter_limits(void)
{
    static const struct { const char *json; bool version_ok; uint32_t version; bool time_ok; bool exact_ok; } cases[] = {
        { "0", true, 0, true, true },
        { "4294967295", true, 4294967295u, false, true },
        { "4294967296", false, 0, false, true },
        { "1e9", true, 1000000000u, true, true },
        { "1000000000.5", false, 0, false, false },
        { "7.5", false, 0, true, false },
        { "-1", false, 0, false, false },
        { "9007199254740992", false, 0, false, true },
        { "9007199254740994", false, 0, false, false },
        { "1e400", false, 0, false, false },
        { "\"7\"", false, 0, false, false },
        { "null", false, 0, false, false },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        cJSON *j = cJSON_Parse(cases[i].json);
        uint32_t v = 77;
        double t = -5;
        uint64_t w = 0;
        bool vok = control_json_version(j, &v), tok = control_json_sim_time(j, &t);
        bool wok = control_json_whole(j, CTL_JSON_EXACT_MAX, &w);
        CHECK(vok == cases[i].version_ok && v == (vok ? cases[i].version : 77u), "version of %s: %d %u", cases[i].json,
              vok, v);
        CHECK(tok == cases[i].time_ok && (tok || t == -5), "sim_time of %s: %d %g", cases[i].json, tok, t);
        CHECK(wok == cases[i].exact_ok, "whole number of %s: %d", cases[i].json, wok);
        cJSON_Delete(j);
    }
    cJSON nan_item = { .type = cJSON_Number, .valuedouble = NAN };
    uint32_t v;
    double t;
    uint64_t w;
    CHECK(!control_json_version(&nan_item, &v) && !control_json_sim_time(&nan_item, &t) &&
          !control_json_whole(&nan_item, CTL_JSON_EXACT_MAX, &w), "NaN passed a limit");
    CHECK(ocean_time_clamp(OCEAN_TIME_MAX + 30.5) == OCEAN_TIME_MAX && ocean_time_clamp(-1) == 0 &&
          ocean_time_clamp(NAN) == 0 && ocean_time_clamp(12.5) == 12.5, "ocean_time_clamp");
}

static void test_capacity_plan(void)
{
    struct cost_model m = {
        .period_s = 1.0 / 30, .budget_s = 0.8 / 30, .n0 = 256, .step1_s = 0.001, .step6_s = 0.003,
        .step_scale = 1, .enc_s_per_sample = 1e-9, .max_memory_mb = 256, .cores = 2,
    };
    int demand[LAYER_KEYS_ALL] = { 0 };
    struct plan p;
    const int n = 256, ts = 128, g0 = plan_group(0, 3), g2 = plan_group(2, 3);
    for (int f = 0; f < 3; f++)
        demand[layer_key(f, 0, 3)] = 1;           /* h, dx, dz at lod 0, 1 cm */
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(!plan_degraded(&p, g0) && p.rate[g0] == 1 && p.lod[g0] == 0, "fits but degraded: lod %d rate %g", p.lod[g0], p.rate[g0]);
    /* a sample cap below the demand: the largest group goes one LOD coarser, the small one stays */
    demand[layer_key(0, 2, 3)] = 1;               /* height at lod 2 */
    m.encode_budget = 3L * n * n - 1;
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(p.lod[g0] == 1 && p.rate[g0] == 1 && !plan_degraded(&p, g2) && p.reason[0], "cap: lod %d rate %g, small %d",
          p.lod[g0], p.rate[g0], plan_degraded(&p, g2));
    /* a cap nothing fits at any LOD: rates go down, never to zero */
    m.encode_budget = 10;
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(p.rate[g0] > 0 && p.rate[g0] < 1 && p.lod[g0] > 1, "tiny cap: lod %d rate %g", p.lod[g0], p.rate[g0]);
    /* the step alone longer than the budget: every group at a lower rate, same for all */
    m.encode_budget = 0;
    m.step_scale = 20;                             /* step of 3 fields: 20 * 2 ms = 40 ms > 26.7 */
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(p.rate[g0] < 1 && p.rate[g0] == p.rate[g2] && p.rate[g0] >= (float)m.period_s, "step-bound: rates %g %g",
          p.rate[g0], p.rate[g2]);
    m.step_scale = 1;
    /* the transient penalty (ticks the producer could not start on time) degrades the plan the
     * same way, but the admission budget follows the measured costs only */
    long admit_before = cost_encode_budget(&m, n);
    m.penalty = 20;
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(p.rate[g0] < 1 && p.rate[g0] == p.rate[g2], "penalty: rates %g %g", p.rate[g0], p.rate[g2]);
    CHECK(cost_encode_budget(&m, n) == admit_before, "penalty changed the admission budget: %ld vs %ld",
          cost_encode_budget(&m, n), admit_before);
    m.penalty = 0; /* 0 or 1: none */
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(!plan_degraded(&p, g0), "no penalty, still degraded");
    /* admission budget: --encode-budget wins; else at least six fields at full N */
    CHECK(cost_encode_budget(&m, n) >= 6L * n * n, "derived admission budget %ld", cost_encode_budget(&m, n));
    m.encode_budget = 1234;
    CHECK(cost_encode_budget(&m, n) == 1234, "--encode-budget ignored");
    /* announcement: max_resolution is the largest N control_fits_memory accepts */
    struct capacity_info ci;
    capacity_info_fill(&m, n, &ci);
    int top = 0;
    for (int z = 16; z <= 2048; z *= 2)
        if (control_fits_memory(z, (int)param_find("cascades")->def, 256)) /* at the default cascades */
            top = z;
    CHECK(ci.max_resolution == top && ci.nsizes > 0 && ci.sizes[ci.nsizes - 1].n == 2048, "max_resolution %d want %d",
          ci.max_resolution, top);
    for (int i = 0; i < ci.nsizes; i++)
        CHECK(ci.sizes[i].fits_memory == control_fits_memory(ci.sizes[i].n, (int)param_find("cascades")->def, 256), "fits_memory of %d", ci.sizes[i].n);
}

/* capacity.c: a sample at LOD L is priced and learned as 2^L samples of LOD 0
 * (group_work). One figure per sample at every LOD learned 4.4 ns at LOD 1
 * against 1.86 at LOD 0 (N = 1024, six fields, intra), priced LOD 0 from it,
 * and a group degraded once never came back. Fixed numbers: behaviour only. */
static void test_capacity_lod_work(void)
{
    struct cost_model m = {
        .period_s = 1.0 / 30, .budget_s = 0.8 / 30, .n0 = 1024, .step1_s = 0.002, .step6_s = 0.012,
        .step_scale = 1, .enc_s_per_sample = 2e-9, .max_memory_mb = 2048, .cores = 2,
    };
    const int n = 1024, ts = 128, g0 = plan_group(0, 3);
    int demand[LAYER_KEYS_ALL] = { 0 };
    for (int f = 0; f < 6; f++)
        demand[layer_key(f, 0, 3)] = 1; /* six fields, lod 0, 1 cm, intra */
    struct plan p;
    /* 6 n^2 x 2 ns = 12.6 ms + a 12 ms step: fits at full detail */
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(!plan_degraded(&p, g0), "six fields at 2 ns/sample: lod %d rate %g (%s)", p.lod[g0], p.rate[g0], p.reason);
    /* served at lod 1 (say it was degraded under load): its frames count twice their samples */
    p.lod[g0] = 1;
    long samples[CAP_CODECS];
    plan_samples(&p, n, NULL, samples);
    CHECK(samples[CAP_INTRA] == 2L * 6 * (n / 2) * (n / 2) && samples[CAP_TEMPORAL] == 0, "lod 1 work %ld, want %ld",
          samples[CAP_INTRA], 2L * 6 * (n / 2) * (n / 2));
    /* lod 1 frames that take 2^1 x samples x the figure leave it as it is, so lod 0 still fits
     * (with samples counted once they read as 4 ns: 25 ms at lod 0, never back) */
    struct cost_model l = m;
    for (int i = 0; i < 50; i++)
        cost_learn_encode(&l, samples, 2.0 * 6 * (n / 2) * (n / 2) * 2e-9);
    CHECK(fabs(l.enc_s_per_sample - 2e-9) < 1e-12, "lod 1 frames moved the lod 0 figure: %g", l.enc_s_per_sample);
    capacity_plan(&l, n, ts, demand, NULL, 1.0, &p);
    CHECK(!plan_degraded(&p, g0), "back at full detail after lod 1 frames: lod %d (%s)", p.lod[g0], p.reason);
    /* and a real slowdown at lod 1 still teaches it: 1.5x there is 1.5x at lod 0 */
    for (int i = 0; i < 50; i++)
        cost_learn_encode(&l, samples, 1.5 * 2.0 * 6 * (n / 2) * (n / 2) * 2e-9);
    CHECK(fabs(l.enc_s_per_sample - 3e-9) < 0.05e-9, "1.5x slower at lod 1: %g, want 3e-9", l.enc_s_per_sample);
    capacity_plan(&l, n, ts, demand, NULL, 1.0, &p);
    CHECK(p.lod[g0] == 1, "six fields at 3 ns/sample (19 + 12 ms): lod %d (%s)", p.lod[g0], p.reason);
}

/* The re-plan's band (capacity.h): the plan in force is dropped only past
 * CAP_KEEP_SCALE of the budget, a better one is taken only under
 * CAP_RECOVER_SCALE. N = 1024 six fields whose frame costs 2 % over the
 * budget stays at full detail; 10 % over degrades; coming back needs 20 %
 * headroom. Fixed numbers: behaviour only. */
static void test_capacity_band(void)
{
    const int n = 1024, ts = 128, g0 = plan_group(0, 3);
    const double budget = 0.8 / 30, step = 0.012, samples = 6.0 * n * n;
    struct cost_model m = {
        .period_s = 1.0 / 30, .budget_s = budget, .n0 = 1024, .step1_s = 0.002, .step6_s = step,
        .step_scale = 1, .max_memory_mb = 2048, .cores = 2,
    };
    int demand[LAYER_KEYS_ALL] = { 0 };
    for (int f = 0; f < 6; f++)
        demand[layer_key(f, 0, 3)] = 1;
    struct plan p;
    CHECK(CAP_RECOVER_SCALE < 1 && CAP_KEEP_SCALE > 1, "band %g..%g", CAP_RECOVER_SCALE, CAP_KEEP_SCALE);
    m.enc_s_per_sample = (1.02 * budget - step) / samples; /* 2 % over */
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(p.lod[g0] == 1, "2 %% over the budget, planned afresh: lod %d", p.lod[g0]);
    capacity_plan(&m, n, ts, demand, NULL, CAP_KEEP_SCALE, &p);
    CHECK(!plan_degraded(&p, g0), "2 %% over the budget, in force: lod %d rate %g (%s)", p.lod[g0], p.rate[g0], p.reason);
    m.enc_s_per_sample = (1.10 * budget - step) / samples; /* 10 % over */
    capacity_plan(&m, n, ts, demand, NULL, CAP_KEEP_SCALE, &p);
    CHECK(p.lod[g0] == 1, "10 %% over the budget, in force: lod %d", p.lod[g0]);
    m.enc_s_per_sample = (0.90 * budget - step) / samples; /* 10 % under: fits, but no recovery */
    capacity_plan(&m, n, ts, demand, NULL, CAP_RECOVER_SCALE, &p);
    CHECK(p.lod[g0] == 1, "10 %% under the budget, recovering: lod %d", p.lod[g0]);
    m.enc_s_per_sample = (0.78 * budget - step) / samples; /* 22 % under */
    capacity_plan(&m, n, ts, demand, NULL, CAP_RECOVER_SCALE, &p);
    CHECK(!plan_degraded(&p, g0), "22 %% under the budget, recovering: lod %d (%s)", p.lod[g0], p.reason);
}

/* capacity.c: the encode cost per codec, what a degraded message says, and
 * learning from frames (N = 1024 h/dx/dz temporal: a group degraded to lod 1
 * is sent intra, measured the cheap codec, predicted that lod 0 fit, went
 * back and degraded again every 3.5 s). Fixed numbers: behaviour only. */
static void test_capacity_codecs(void)
{
    struct cost_model m = {
        .period_s = 1.0 / 30, .budget_s = 0.8 / 30, .n0 = 1024, .step1_s = 0.002, .step6_s = 0.011,
        .step_scale = 1, .enc_s_per_sample = 3.5e-9, .max_memory_mb = 2048, .cores = 2,
    };
    const int n = 1024, ts = 128, g0 = plan_group(0, 3);
    int demand[LAYER_KEYS_ALL] = { 0 }, tdemand[LAYER_KEYS_ALL] = { 0 };
    for (int f = 0; f < 3; f++)
        demand[layer_key(f, 0, 3)] = tdemand[layer_key(f, 0, 3)] = 1; /* h, dx, dz, lod 0, 1 cm, temporal */
    struct plan p;
    /* intra: 3 n^2 x 3.5 ns = 11 ms + a 5.6 ms step fits */
    capacity_plan(&m, n, ts, demand, NULL, 1.0, &p);
    CHECK(!plan_degraded(&p, g0) && !p.temporal[g0], "intra fits but degraded: lod %d", p.lod[g0]);
    /* temporal, not measured yet: the prior (x2, 22 ms + 5.6) does not fit; intra at lod 0 does:
     * the codec rung, the same detail and rate (it used to go to lod 1) */
    capacity_plan(&m, n, ts, demand, tdemand, 1.0, &p);
    CHECK(p.temporal[g0] && p.lod[g0] == 0 && p.rate[g0] == 1 && plan_intra(&p, g0), "temporal prior: lod %d rate %g intra %d",
          p.lod[g0], p.rate[g0], plan_intra(&p, g0));
    CHECK(!plan_degraded(&p, g0) && plan_degraded_for(&p, g0, true) && !plan_degraded_for(&p, g0, false),
          "codec rung: degraded %d, for temporal %d, for intra %d", plan_degraded(&p, g0), plan_degraded_for(&p, g0, true),
          plan_degraded_for(&p, g0, false));
    /* the reason gives the demand at full detail, over the budget in samples at its codec's cost,
     * and what fits intra (over the demand: that is why the rung is enough) */
    long wanted = -1, budget = -1, intra_fit = -1;
    const char *w = strstr(p.reason, "samples per tick wanted, budget "), *wi = strstr(p.reason, "ns/sample), intra ");
    CHECK(w && wi && sscanf(p.reason, "intra codec: N=1024, %ld samples", &wanted) == 1 &&
          sscanf(w, "samples per tick wanted, budget %ld", &budget) == 1 &&
          sscanf(wi, "ns/sample), intra %ld", &intra_fit) == 1, "reason: %s", p.reason);
    CHECK(wanted == 3L * n * n && budget < wanted && budget > 3L * (n / 2) * (n / 2) && intra_fit >= wanted,
          "reason reads under budget: wanted %ld budget %ld intra %ld (%s)", wanted, budget, intra_fit, p.reason);
    /* the rung's frames are intra: only they count, and cheap intra frames do not
     * talk the temporal codec back into fitting (the old flapping) */
    long samples[CAP_CODECS];
    plan_samples(&p, n, NULL, samples);
    CHECK(samples[CAP_INTRA] == 3L * n * n && samples[CAP_TEMPORAL] == 0, "plan_samples %ld %ld",
          samples[CAP_INTRA], samples[CAP_TEMPORAL]);
    /* a plan of the same value with fewer samples on the rung is another plan */
    struct plan t = p;
    t.intra[g0] = false;
    CHECK(!plan_same(&t, &p) && plan_value(&t, n) == plan_value(&p, n) && plan_intra_value(&t, n) == 0 &&
          plan_intra_value(&p, n) == 3.0 * n * n, "plan_intra_value %g %g", plan_intra_value(&t, n), plan_intra_value(&p, n));
    /* all six fields: neither codec fits at lod 0 (6 n^2 x 3.5 ns = 22 ms + an 11 ms step): one LOD
     * coarser, intra there (no codec rung: a coarser LOD is intra anyway) */
    for (int f = 3; f < 6; f++)
        demand[layer_key(f, 0, 3)] = tdemand[layer_key(f, 0, 3)] = 1;
    capacity_plan(&m, n, ts, demand, tdemand, 1.0, &p);
    CHECK(p.lod[g0] == 1 && p.rate[g0] == 1 && !plan_intra(&p, g0) && plan_degraded(&p, g0) &&
          strncmp(p.reason, "coarser LOD: ", 13) == 0, "six fields: lod %d rate %g intra %d (%s)", p.lod[g0], p.rate[g0],
          plan_intra(&p, g0), p.reason);
    for (int f = 3; f < 6; f++)
        demand[layer_key(f, 0, 3)] = tdemand[layer_key(f, 0, 3)] = 0;
    /* --encode-budget caps samples, which no codec changes: under it, the rung is skipped */
    struct cost_model c = m;
    c.encode_budget = 3L * n * n - 1;
    capacity_plan(&c, n, ts, demand, tdemand, 1.0, &p);
    CHECK(p.lod[g0] == 1 && !plan_intra(&p, g0), "sample cap: lod %d intra %d", p.lod[g0], plan_intra(&p, g0));
    /* --temporal-budget caps the temporal samples: the rung, even when the time fits */
    c.encode_budget = 0;
    c.enc_temporal_s = c.enc_s_per_sample * 1.2; /* 13 ms + 5.6: fits */
    capacity_plan(&c, n, ts, demand, tdemand, 1.0, &p);
    CHECK(p.lod[g0] == 0 && !plan_intra(&p, g0) && !p.reason[0], "temporal fits: lod %d intra %d", p.lod[g0], plan_intra(&p, g0));
    c.temporal_budget = 3L * n * n - 1;
    capacity_plan(&c, n, ts, demand, tdemand, 1.0, &p);
    CHECK(p.lod[g0] == 0 && p.rate[g0] == 1 && plan_intra(&p, g0), "temporal cap: lod %d intra %d", p.lod[g0], plan_intra(&p, g0));
    bool due[PLAN_GROUPS] = { false };
    plan_samples(&p, n, due, samples);
    CHECK(samples[CAP_INTRA] == 0 && samples[CAP_TEMPORAL] == 0, "plan_samples with nothing due");
    struct cost_model l = m;
    long intra_frame[CAP_CODECS] = { 3L * 512 * 512, 0 };
    for (int i = 0; i < 50; i++)
        cost_learn_encode(&l, intra_frame, 2e-9 * (double)intra_frame[CAP_INTRA]);
    CHECK(fabs(l.enc_s_per_sample - 2e-9) < 0.05e-9 && l.enc_temporal_s == 0, "intra frames: %g %g",
          l.enc_s_per_sample, l.enc_temporal_s);
    l.enc_temporal_s = 9e-9; /* measured before the degrade */
    capacity_plan(&l, n, ts, demand, tdemand, 0.8, &p);
    CHECK(p.lod[g0] == 0 && plan_intra(&p, g0), "recovery predicted from intra frames: lod %d intra %d", p.lod[g0],
          plan_intra(&p, g0));
    /* forgetting the temporal figure (the probe): back to the prior x the current intra figure,
     * which fits (3 n^2 x 4 ns = 12.6 ms + 5.6 < 21.3) */
    cost_forget_temporal(&l);
    CHECK(l.enc_temporal_s == 0 && fabs(cost_encode_codec_s(&l, CAP_TEMPORAL) - CAP_TEMPORAL_PRIOR * l.enc_s_per_sample) < 1e-15,
          "forget: %g", cost_encode_codec_s(&l, CAP_TEMPORAL));
    capacity_plan(&l, n, ts, demand, tdemand, 0.8, &p);
    CHECK(!plan_degraded(&p, g0) && !plan_intra(&p, g0), "probe plan still degraded: lod %d intra %d", p.lod[g0],
          plan_intra(&p, g0));
    /* learning: a cold temporal frame (7x the prediction) counts as twice it at most */
    long temporal_frame[CAP_CODECS] = { 0, 3L * n * n };
    double prior = cost_encode_codec_s(&l, CAP_TEMPORAL);
    cost_learn_encode(&l, temporal_frame, 7 * prior * (double)temporal_frame[CAP_TEMPORAL]);
    CHECK(l.enc_temporal_s > prior && l.enc_temporal_s <= 1.1 * prior * (1 + 1e-9), "cold frame: %g (prior %g)",
          l.enc_temporal_s, prior);
    CHECK(fabs(l.enc_s_per_sample - 2e-9) < 0.05e-9, "a temporal frame moved the intra figure: %g", l.enc_s_per_sample);
    /* steady frames: the figure converges on what they cost; faster ones come down quickly */
    for (int i = 0; i < 100; i++)
        cost_learn_encode(&l, temporal_frame, 7e-9 * (double)temporal_frame[CAP_TEMPORAL]);
    CHECK(fabs(l.enc_temporal_s - 7e-9) < 0.1e-9, "steady: %g", l.enc_temporal_s);
    cost_learn_encode(&l, temporal_frame, 3e-9 * (double)temporal_frame[CAP_TEMPORAL]);
    CHECK(l.enc_temporal_s < 6.1e-9, "down: %g", l.enc_temporal_s);
    /* a mixed frame: both figures by the frame's ratio to the prediction */
    l.enc_s_per_sample = 2e-9;
    l.enc_temporal_s = 4e-9;
    long mixed[CAP_CODECS] = { 1000000, 1000000 };
    cost_learn_encode(&l, mixed, 1.5 * 6e-9 * 1e6);
    CHECK(fabs(l.enc_s_per_sample / l.enc_temporal_s - 0.5) < 1e-9 && l.enc_s_per_sample > 2e-9, "mixed: %g %g",
          l.enc_s_per_sample, l.enc_temporal_s);
    /* the announcement's estimate: the step and the temporal codec at lod 0 */
    struct capacity_info ci;
    capacity_info_fill(&l, n, &ci);
    for (int i = 0; i < ci.nsizes; i++)
        if (ci.sizes[i].n == 1024)
            CHECK(fabs(ci.sizes[i].est_ms[2] - (cost_step_s(&l, 1024, 3) + l.enc_temporal_s * 3 * 1024 * 1024) * 1e3) < 1e-3,
                  "est_ms at 1024: %g", ci.sizes[i].est_ms[2]);
}

/* capacity.c: the codec rung with two temporal groups, and the announcement
 * of both codecs. A 0.1 ms step, intra 3.5 ns/sample, temporal 7: fixed
 * numbers, behaviour only. */
static void test_capacity_codec_rung(void)
{
    struct cost_model m = {
        .period_s = 1.0 / 30, .budget_s = 0.8 / 30, .n0 = 1024, .step1_s = 0.0001, .step6_s = 0.0001,
        .step_scale = 1, .enc_s_per_sample = 3.5e-9, .enc_temporal_s = 7e-9, .max_memory_mb = 2048, .cores = 2,
    };
    const int n = 1024, ts = 128, ga = plan_group(0, 3), gb = plan_group(1, 3);
    int demand[LAYER_KEYS_ALL] = { 0 }, tdemand[LAYER_KEYS_ALL] = { 0 };
    for (int f = 0; f < 6; f++) /* A: six fields at lod 0 (6.3 M samples); B: height at lod 1 (0.26 M) */
        demand[layer_key(f, 0, 3)] = tdemand[layer_key(f, 0, 3)] = 1;
    demand[layer_key(0, 1, 3)] = tdemand[layer_key(0, 1, 3)] = 1;
    struct plan p;
    /* all temporal: 6.55 M x 7 ns = 46 ms. A intra (the most expensive): 22 + 1.8 ms fits; B stays temporal */
    capacity_plan(&m, n, ts, demand, tdemand, 1.0, &p);
    CHECK(plan_intra(&p, ga) && !plan_intra(&p, gb) && p.lod[ga] == 0 && p.lod[gb] == 1 && p.rate[ga] == 1 &&
          p.rate[gb] == 1, "two groups: intra %d %d, lod %d %d", plan_intra(&p, ga), plan_intra(&p, gb), p.lod[ga], p.lod[gb]);
    long samples[CAP_CODECS];
    plan_samples(&p, n, NULL, samples);
    CHECK(samples[CAP_INTRA] == 6L * n * n && samples[CAP_TEMPORAL] == 2L * (n / 2) * (n / 2), "two groups: work %ld %ld",
          samples[CAP_INTRA], samples[CAP_TEMPORAL]);
    /* the temporal samples capped under B's: both intra, still at full detail */
    m.temporal_budget = 100000;
    capacity_plan(&m, n, ts, demand, tdemand, 1.0, &p);
    CHECK(plan_intra(&p, ga) && plan_intra(&p, gb) && p.lod[ga] == 0 && p.lod[gb] == 1, "temporal cap: intra %d %d, lod %d %d",
          plan_intra(&p, ga), plan_intra(&p, gb), p.lod[ga], p.lod[gb]);
    m.temporal_budget = 0;
    /* B with h, dx, dz (0.79 M samples at lod 1, priced as 1.6 M of lod 0): neither rung of the codec
     * is enough (A intra 22 + B 11 ms; B intra 22 + 5.5), so A goes one LOD coarser (3.1 M: 11 ms);
     * then B fits temporal again and goes back (11 + 11 ms) */
    for (int f = 1; f < 3; f++)
        demand[layer_key(f, 1, 3)] = tdemand[layer_key(f, 1, 3)] = 1;
    capacity_plan(&m, n, ts, demand, tdemand, 1.0, &p);
    CHECK(p.lod[ga] == 1 && !plan_intra(&p, ga) && !plan_intra(&p, gb) && p.lod[gb] == 1 && p.rate[ga] == 1 &&
          p.rate[gb] == 1 && plan_degraded(&p, ga) && !plan_degraded(&p, gb),
          "coarser A, B back to temporal: lod %d %d intra %d %d (%s)", p.lod[ga], p.lod[gb], plan_intra(&p, ga),
          plan_intra(&p, gb), p.reason);
    for (int f = 1; f < 3; f++)
        demand[layer_key(f, 1, 3)] = tdemand[layer_key(f, 1, 3)] = 0;
    /* the announcement at 1024: temporal 7.3 ms a field, 3 fit; intra 3.7 ms a field, 6 fit */
    struct capacity_info ci;
    capacity_info_fill(&m, n, &ci);
    int seen = 0;
    for (int i = 0; i < ci.nsizes; i++) {
        const struct capacity_size *z = &ci.sizes[i];
        long b = (long)floor(ci.budget_ms * 100 + 0.5);
        int tf = 0, ff = 0;
        for (int f = 0; f < 6; f++) {
            CHECK(z->est_intra_ms[f] < z->est_ms[f], "est_intra_ms %g >= est_ms %g at %d", z->est_intra_ms[f], z->est_ms[f], z->n);
            tf += (long)floor(z->est_ms[f] * 100 + 0.5) <= b;
            ff += (long)floor(fmin(z->est_ms[f], z->est_intra_ms[f]) * 100 + 0.5) <= b;
        }
        CHECK(z->temporal_fields == tf && z->full_rate_fields == ff, "N=%d: temporal_fields %d (%d) full_rate_fields %d (%d)",
              z->n, z->temporal_fields, tf, z->full_rate_fields, ff);
        if (z->n == 1024) {
            seen++;
            CHECK(z->temporal_fields == 3 && z->full_rate_fields == 6, "1024: temporal %d full %d", z->temporal_fields,
                  z->full_rate_fields);
        }
    }
    CHECK(seen == 1, "1024 not announced");
    /* the operator's caps: --temporal-budget of two fields at 1024, --encode-budget of five */
    m.temporal_budget = 2L * n * n;
    m.encode_budget = 5L * n * n;
    capacity_info_fill(&m, n, &ci);
    for (int i = 0; i < ci.nsizes; i++)
        if (ci.sizes[i].n == 1024)
            CHECK(ci.sizes[i].temporal_fields == 2 && ci.sizes[i].full_rate_fields == 5, "1024 capped: temporal %d full %d",
                  ci.sizes[i].temporal_fields, ci.sizes[i].full_rate_fields);
}

/* Display names (PROTOCOL.md §7.1 `name`): what is accepted and refused,
 * by control_check_name and through control_parse (`name`, and `set`'s
 * optional "name"); a refused name is bad_name with the id kept. */
static void test_display_names(void)
{
    struct ctl_error e;
    static const char *const good[] = {"", "Ana", "Zo\xc3\xab", "\xe6\xb5\xb7", "a b", "x-y_z.1",
                                       "\xf0\x9f\x8c\x8a wave", /* U+1F30A: 4 bytes */
                                       "12345678901234567890123456789012"};
    for (size_t i = 0; i < sizeof good / sizeof good[0]; i++)
        CHECK(control_check_name(good[i], &e) == 0, "good name %zu refused: %s", i, e.message);
    char cjk32[CTL_NAME_BYTES], cjk33[CTL_NAME_BYTES + 3];
    cjk32[0] = cjk33[0] = 0;
    for (int i = 0; i < 32; i++)
        strcat(cjk32, "\xe6\xb5\xb7");
    snprintf(cjk33, sizeof cjk33, "%s\xe6\xb5\xb7", cjk32);
    CHECK(control_check_name(cjk32, &e) == 0 && strlen(cjk32) == 96, "32 CJK characters (96 bytes) refused");
    CHECK(control_check_name(cjk33, &e) != 0 && strcmp(e.code, "bad_name") == 0, "33 CJK characters accepted");
    static const char *const bad[] = {
        "123456789012345678901234567890123", "<b>", "a&b", "a\"b", "a'b", "a>b", "tab\there", "\x7f",
        "\xc2\x85",                 /* U+0085 NEL (C1) */
        "\xe2\x80\xae" "abc",       /* U+202E right-to-left override */
        "zero\xe2\x80\x8bwidth",    /* U+200B */
        "\xef\xbb\xbf" "bom",       /* U+FEFF */
        "\xee\x80\x80",             /* U+E000 private use */
        "\xc0\xaf",                 /* overlong '/' */
        "\xed\xa0\x80",             /* a surrogate, U+D800 */
        "\xf4\x90\x80\x80",         /* above U+10FFFF */
        "\xe6\xb5",                 /* truncated sequence */
        "\xff", " lead", "trail ", " ",
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        CHECK(control_check_name(bad[i], &e) != 0 && strcmp(e.code, "bad_name") == 0, "bad name %zu accepted", i);

    struct ctl_msg m;
    cJSON *id = NULL;
    const char *ok = "{\"type\":\"name\",\"id\":9,\"name\":\"Ana\"}";
    CHECK(control_parse(ok, strlen(ok), &m, &id, &e) == 0 && m.type == CTL_NAME && m.name && strcmp(m.name, "Ana") == 0,
          "name message not parsed");
    char *t = control_print(control_named_msg(m.name, m.id));
    CHECK(t && strcmp(t, "{\"type\":\"named\",\"id\":9,\"name\":\"Ana\"}") == 0, "named: %s", t ? t : "(null)");
    free(t);
    ctl_msg_free(&m);
    const char *set_named = "{\"type\":\"set\",\"params\":{\"wind_speed\":3},\"name\":\"Bo\"}";
    CHECK(control_parse(set_named, strlen(set_named), &m, &id, &e) == 0 && m.type == CTL_SET && m.name &&
              strcmp(m.name, "Bo") == 0, "set with a name not parsed");
    ctl_msg_free(&m);
    const char *set_plain = "{\"type\":\"set\",\"params\":{\"wind_speed\":3}}";
    CHECK(control_parse(set_plain, strlen(set_plain), &m, &id, &e) == 0 && m.name == NULL, "set without a name has one");
    ctl_msg_free(&m);
    static const char *const refused[] = {
        "{\"type\":\"name\",\"id\":7,\"name\":\"<i>\"}", "{\"type\":\"name\",\"id\":7,\"name\":3}",
        "{\"type\":\"name\",\"id\":7}", "{\"type\":\"set\",\"id\":7,\"params\":{},\"name\":\"a&b\"}",
        "{\"type\":\"set\",\"id\":7,\"params\":{},\"name\":[\"x\"]}",
        "{\"type\":\"name\",\"id\":7,\"name\":\"\\u202e\"}",
    };
    for (size_t i = 0; i < sizeof refused / sizeof refused[0]; i++) {
        id = NULL;
        int rc = control_parse(refused[i], strlen(refused[i]), &m, &id, &e);
        /* a numeric id is kept as its text (test_exact_ids) */
        CHECK(rc != 0 && strcmp(e.code, "bad_name") == 0 && cJSON_IsRaw(id) && strcmp(id->valuestring, "7") == 0,
              "%s: rc %d code %s", refused[i], rc, rc ? e.code : "-");
        cJSON_Delete(id);
    }
}

/* `render` (PROTOCOL.md §7.5): times, layers, refusals and the cost in units. */
static void test_render(void)
{
    static const struct { const char *text, *code, *param; } cases[] = {
        { "{\"type\":\"render\",\"start\":100.5,\"fps\":24,\"frames\":240,\"fields\":[\"height\",\"dx\"]}", "ok", "" },
        { "{\"type\":\"render\",\"fps\":24,\"frames\":2,\"fields\":[\"height\"]}", "bad_render", "start" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":0,\"frames\":2,\"fields\":[\"height\"]}", "bad_render", "fps" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":1001,\"frames\":2,\"fields\":[\"height\"]}", "bad_render", "fps" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":24,\"frames\":2.5,\"fields\":[\"height\"]}", "bad_render", "frames" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":24,\"frames\":0,\"fields\":[\"height\"]}", "bad_render", "frames" },
        { "{\"type\":\"render\",\"start\":-1,\"fps\":24,\"frames\":2,\"fields\":[\"height\"]}", "bad_render", "start" },
        { "{\"type\":\"render\",\"start\":1e9,\"fps\":1,\"frames\":2,\"fields\":[\"height\"]}", "bad_render", "frames" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":24,\"frames\":2}", "bad_render", "fields" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":24,\"frames\":2,\"fields\":[\"nope\"]}", "bad_render", "" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":24,\"frames\":2,\"fields\":[\"height\"],\"temporal\":true}", "bad_render", "temporal" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":24,\"frames\":2,\"fields\":[\"height\"],\"max_rate\":5}", "bad_render", "max_rate" },
        { "{\"type\":\"render\",\"start\":0,\"fps\":24,\"frames\":2,\"fields\":[\"height\"],\"bound\":0.002}", "bad_render", "" },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        struct ctl_msg m;
        struct ctl_error e = { 0 };
        cJSON *id = NULL;
        CHECK(control_parse(cases[i].text, strlen(cases[i].text), &m, &id, &e) == 0 && m.type == CTL_RENDER,
              "%s does not parse as a render", cases[i].text);
        struct render_req *r = malloc(sizeof *r);
        const char *code = render_parse(m.root, &lim, r, &e) == 0 ? "ok" : e.code;
        CHECK(strcmp(code, cases[i].code) == 0, "%s -> %s (%s), want %s", cases[i].text, code, e.message, cases[i].code);
        if (strcmp(code, "ok") != 0 && cases[i].param[0])
            CHECK(strcmp(e.param, cases[i].param) == 0, "%s: param %s", cases[i].text, e.param);
        if (i == 0) {
            CHECK(r->frames == 240 && r->start == 100.5 && r->fps == 24 && !r->sub.temporal, "parsed values");
            CHECK(render_time(r, 0) == 100.5 && fabs(render_time(r, 239) - (100.5 + 239.0 / 24)) < 1e-9, "times");
            CHECK(render_frame_units(r, 256, 3) == 2 && render_frame_units(r, 512, 3) == 8, "units: %g",
                  render_frame_units(r, 256, 3));
        }
        free(r);
        ctl_msg_free(&m);
    }
    /* Cascades count their fields; those not in force do not. */
    const char *t = "{\"type\":\"render\",\"start\":0,\"fps\":24,\"frames\":1,\"fields\":[\"height\",\"dx\",\"dz\","
                    "\"slope_x\",\"slope_z\",\"jacobian\"],\"cascades\":[{\"fields\":[\"height\",\"dx\",\"dz\",\"slope_x\","
                    "\"slope_z\"]},{\"fields\":[\"height\",\"dx\",\"dz\",\"slope_x\",\"slope_z\"]}]}";
    struct ctl_msg m;
    struct ctl_error e = { 0 };
    struct render_req *r = malloc(sizeof *r);
    CHECK(control_parse(t, strlen(t), &m, NULL, &e) == 0 && render_parse(m.root, &lim, r, &e) == 0, "bake render: %s",
          e.message);
    CHECK(render_frame_units(r, 256, 3) == 16 && render_frame_units(r, 256, 1) == 6, "bake units %g",
          render_frame_units(r, 256, 3));
    free(r);
    ctl_msg_free(&m);
    struct ctl_msg c;
    CHECK(control_parse("{\"type\":\"render_cancel\"}", 24, &c, NULL, &e) == 0 && c.type == CTL_RENDER_CANCEL,
          "render_cancel");
    ctl_msg_free(&c);
}

/* ---- ids echoed as sent; every file loader as strict as a message ---- */

/* The "id" of a reply as printed, e.g. `9007199254740993` of {"id":9007199254740993,...}. */
static const char *printed_id(const char *reply, char *out, size_t cap)
{
    const char *p = strstr(reply, "\"id\":");
    size_t n = 0;
    if (p)
        for (p += 5; *p && *p != ',' && *p != '}' && n + 1 < cap; p++)
            out[n++] = *p;
    out[n] = '\0';
    return out;
}

/* cJSON holds numbers as doubles: 2^53 + 1 came back as 9.00719925474099e+15,
 * 1e400 as null. Every reply built from a parsed message's id (or from a
 * refused one's) prints the id's own text; a number that is not RFC 8259
 * JSON (cJSON takes "01") is refused rather than echoed as invalid JSON. */
static void test_exact_ids(void)
{
    static const char *const ids[] = { "9007199254740993", "9223372036854775807", "18446744073709551615",
                                       "-9223372036854775809", "123456789012345678901234567890", "1e400", "-1e400",
                                       "1.0", "1E+2", "-0", "0.1", "2.5e-3", "7" };
    for (size_t i = 0; i < sizeof ids / sizeof ids[0]; i++) {
        char text[256], got[128];
        struct ctl_msg m;
        struct ctl_error e;
        cJSON *bad = NULL;
        /* the id anywhere among the members, once with an escaped name ("\u0069d" is "id") */
        snprintf(text, sizeof text, i % 2 ? "{\"type\":\"ping\",\"x\":[1,{\"id\":2}],\"id\":%s}"
                                          : "{\"\\u0069d\" : %s , \"type\":\"ping\"}", ids[i]);
        CHECK(control_parse(text, strlen(text), &m, &bad, &e) == 0, "%s: %s", text, e.message);
        if (!m.root)
            continue;
        char *pong = control_print(control_pong_msg(m.id, m.t, 1));
        CHECK(pong && strcmp(printed_id(pong, got, sizeof got), ids[i]) == 0, "pong id %s, want %s", got, ids[i]);
        free(pong);
        /* a ping's "t" is echoed as sent too */
        struct ctl_msg tm;
        snprintf(text, sizeof text, "{\"type\":\"ping\",\"t\":%s}", ids[i]);
        CHECK(control_parse(text, strlen(text), &tm, NULL, &e) == 0, "%s: %s", text, e.message);
        if (tm.root) {
            pong = control_print(control_pong_msg(tm.id, tm.t, 1));
            const char *tt = pong ? strstr(pong, "\"t\":") : NULL;
            CHECK(tt && strncmp(tt + 4, ids[i], strlen(ids[i])) == 0 && tt[4 + strlen(ids[i])] == ',',
                  "pong %s, want t %s", pong ? pong : "-", ids[i]);
            free(pong);
            ctl_msg_free(&tm);
        }
        struct ctl_error oops = { .code = "invalid", .message = "x" };
        char *err = control_print(control_error_msg(&oops, m.id));
        CHECK(err && strcmp(printed_id(err, got, sizeof got), ids[i]) == 0, "error id %s, want %s", got, ids[i]);
        free(err);
        ctl_msg_free(&m);
        /* a refused message echoes it as sent too */
        snprintf(text, sizeof text, "{\"type\":\"jump\",\"id\":%s}", ids[i]);
        CHECK(control_parse(text, strlen(text), &m, &bad, &e) != 0 && bad, "%s: no id for the error", text);
        err = control_print(control_error_msg(&e, bad));
        CHECK(err && strcmp(printed_id(err, got, sizeof got), ids[i]) == 0, "unknown_type id %s, want %s", got, ids[i]);
        free(err);
        cJSON_Delete(bad);
        cJSON *rid = control_message_id(text, strlen(text));
        err = control_print(control_error_msg(&e, rid));
        CHECK(err && strcmp(printed_id(err, got, sizeof got), ids[i]) == 0, "refusal id %s, want %s", got, ids[i]);
        free(err);
        cJSON_Delete(rid);
    }
    static const char *const not_json[] = { "01", "-01", "1.", "1.e5", "00", "1e", "-" };
    for (size_t i = 0; i < sizeof not_json / sizeof not_json[0]; i++) {
        char text[128];
        snprintf(text, sizeof text, "{\"type\":\"ping\",\"id\":%s}", not_json[i]);
        struct ctl_msg m;
        struct ctl_error e;
        cJSON *bad = NULL;
        int rc = control_parse(text, strlen(text), &m, &bad, &e);
        CHECK(rc != 0 && strcmp(e.code, "bad_json") == 0 && bad == NULL, "id %s: rc %d code %s, echoed %s",
              not_json[i], rc, rc ? e.code : "-", bad ? "yes" : "no");
        if (rc == 0)
            ctl_msg_free(&m);
        cJSON_Delete(bad);
    }
}

static void write_bytes(const char *path, const char *bytes, size_t len)
{
    FILE *f = fopen(path, "wb");
    if (f) {
        fwrite(bytes, 1, len, f);
        fclose(f);
    }
}

/* A NUL in the config or state file cut strings: the token "abc\u0000def..."
 * acted as "abc", a saved "phillips\u0000junk" as phillips. Both files now
 * go through the control path's scan: the config file is refused (the daemon
 * does not start), the state file is ignored with a warning (as any bad
 * one), naming the NUL either way. */
static void test_files_strict(void)
{
    char dir[] = "/tmp/oceand-ctl-XXXXXX";
    if (!mkdtemp(dir)) {
        CHECK(0, "mkdtemp");
        return;
    }
    char cfg[128], state[128], err[512];
    snprintf(cfg, sizeof cfg, "%s/c.json", dir);
    snprintf(state, sizeof state, "%s/state.json", dir);
    struct daemon_config dc;
    struct config_result res;
    struct ocean_params q;
    static const char escaped[] = "{\"control_token\":\"abc\\u0000defghijklmnopqrstuvwxyz0123456789\"}";
    static const char raw[] = "{\"control_token\":\"abc\0defghijklmnopqrstuvwxyz0123456789\"}";
    static const char whole[] = "{\"control_token\":\"abcdefghijklmnopqrstuvwxyz0123456789\"}";
    char *argv[] = { "oceand", "--state-file", "none", "--config", cfg, NULL };
    write_bytes(cfg, escaped, sizeof escaped - 1);
    CHECK(config_load(5, argv, &dc, &q, &res, err, sizeof err) != 0 && strstr(err, "NUL") && strstr(err, "bad_json"),
          "config with \\u0000 in the token: %s (token \"%s\")", err, dc.control_token);
    write_bytes(cfg, raw, sizeof raw - 1);
    CHECK(config_load(5, argv, &dc, &q, &res, err, sizeof err) != 0 && strstr(err, "0x00"),
          "config with a raw NUL in the token: %s (token \"%s\")", err, dc.control_token);
    write_bytes(cfg, whole, sizeof whole - 1); /* the case can fail: the same file without the NUL loads */
    CHECK(config_load(5, argv, &dc, &q, &res, err, sizeof err) == 0 &&
              strcmp(dc.control_token, "abcdefghijklmnopqrstuvwxyz0123456789") == 0,
          "config without the NUL: %s", err);
    CHECK(config_apply_text(&dc, &q, escaped, sizeof escaped - 1, err, sizeof err) != 0, "config_apply_text took \\u0000");

    static const char st_escaped[] = "{\"params\":{\"spectrum\":\"phillips\\u0000-not-a-spectrum\",\"wind_speed\":13},"
                                     "\"params_version\":5,\"sim_time\":3}";
    static const char st_raw[] = "{\"params\":{\"spectrum\":\"phillips\0-not-a-spectrum\",\"wind_speed\":13},"
                                 "\"params_version\":5,\"sim_time\":3}";
    static const char st_good[] = "{\"params\":{\"spectrum\":\"phillips\",\"wind_speed\":13},\"params_version\":5,"
                                  "\"sim_time\":3}";
    char *sargv[] = { "oceand", "--state-file", state, NULL };
    struct ocean_params defs;
    params_defaults(&defs);
    const struct { const char *bytes; size_t len; const char *says; } bad[] = {
        { st_escaped, sizeof st_escaped - 1, "NUL" },
        { st_raw, sizeof st_raw - 1, "0x00" },
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        write_bytes(state, bad[i].bytes, bad[i].len);
        capture_begin();
        int rc = config_load(3, sargv, &dc, &q, &res, err, sizeof err);
        const char *log = capture_end();
        CHECK(rc == 0 && !res.state_loaded && q.spectrum == defs.spectrum && q.wind_speed == defs.wind_speed &&
                  res.params_version == 0,
              "state %zu with a NUL: rc %d, loaded %d, spectrum %d, wind %g, version %u", i, rc, res.state_loaded,
              q.spectrum, q.wind_speed, res.params_version);
        CHECK(strstr(log, "ignoring saved state") && strstr(log, bad[i].says) && strstr(log, "bad_json"),
              "state %zu with a NUL: the warning does not say why: %s", i, log);
    }
    write_bytes(state, st_good, sizeof st_good - 1);
    CHECK(config_load(3, sargv, &dc, &q, &res, err, sizeof err) == 0 && res.state_loaded &&
              q.spectrum == SPECTRUM_PHILLIPS && q.wind_speed == 13,
          "the same state without the NUL: %s", err);
    unlink(cfg);
    unlink(state);
    rmdir(dir);
}

/* Floating bodies: the request parser's codes (PROTOCOL.md §7.6), the BODY
 * section's round trip (§3.5), the bodies in the state file. */
static void test_bodies(void)
{
    static const struct { const char *text, *code, *param; } cases[] = {
        { "{\"type\":\"launch\",\"kind\":\"boat\",\"x\":10,\"z\":-20,\"heading\":450}", "ok", "" },
        { "{\"type\":\"launch\",\"kind\":\"boat\",\"x\":2500,\"z\":-2500}", "ok", "" },
        { "{\"type\":\"launch\",\"kind\":\"boat\",\"x\":2500.001,\"z\":0}", "out_of_range", "x" },
        { "{\"type\":\"launch\",\"kind\":\"boat\",\"x\":0,\"z\":-1e6}", "out_of_range", "z" },
        { "{\"type\":\"launch\",\"kind\":\"Boat\",\"x\":0,\"z\":0}", "unknown_kind", "kind" },
        { "{\"type\":\"launch\",\"kind\":[],\"x\":0,\"z\":0}", "bad_type", "kind" },
        { "{\"type\":\"launch\",\"x\":0,\"z\":0}", "bad_message", "kind" },
        { "{\"type\":\"launch\",\"kind\":\"ball\",\"z\":0}", "bad_message", "x" },
        { "{\"type\":\"launch\",\"kind\":\"ball\",\"x\":true,\"z\":0}", "bad_type", "x" },
        { "{\"type\":\"launch\",\"kind\":\"ball\",\"x\":1e999,\"z\":0}", "bad_type", "x" },
        { "{\"type\":\"launch\",\"kind\":\"ball\",\"x\":0,\"z\":0,\"heading\":\"north\"}", "bad_type", "heading" },
        { "{\"type\":\"launch\",\"kind\":\"ball\",\"x\":0,\"z\":0,\"token\":7}", "bad_message", "token" },
        { "{\"type\":\"steer\",\"body\":12,\"throttle\":0.5,\"rudder\":-0.2}", "ok", "" },
        { "{\"type\":\"steer\",\"body\":12}", "ok", "" },
        { "{\"type\":\"steer\",\"body\":12,\"throttle\":-1,\"rudder\":1}", "ok", "" },
        { "{\"type\":\"steer\",\"body\":12,\"throttle\":1.0001}", "out_of_range", "throttle" },
        { "{\"type\":\"steer\",\"body\":12,\"rudder\":-2}", "out_of_range", "rudder" },
        { "{\"type\":\"steer\",\"body\":12,\"rudder\":-1e999}", "bad_type", "rudder" },
        { "{\"type\":\"steer\",\"body\":12,\"throttle\":null}", "bad_type", "throttle" },
        { "{\"type\":\"steer\",\"throttle\":0}", "bad_message", "body" },
        { "{\"type\":\"steer\",\"body\":\"12\"}", "bad_type", "body" },
        { "{\"type\":\"steer\",\"body\":12.5}", "bad_type", "body" },
        { "{\"type\":\"steer\",\"body\":0}", "out_of_range", "body" },
        { "{\"type\":\"steer\",\"body\":4294967296}", "out_of_range", "body" },
        { "{\"type\":\"remove\",\"body\":4294967295}", "ok", "" },
        { "{\"type\":\"remove\"}", "bad_message", "body" },
        { "{\"type\":\"claim\",\"body\":3,\"resume\":\"0123456789abcdef0123456789abcdef\"}", "ok", "" },
        { "{\"type\":\"claim\",\"body\":3,\"resume\":\"0123456789ABCDEF0123456789abcdef\"}", "bad_message", "resume" },
        { "{\"type\":\"claim\",\"body\":3,\"resume\":\"0123456789abcdef0123456789abcde\"}", "bad_message", "resume" },
        { "{\"type\":\"claim\",\"body\":3}", "bad_message", "resume" },
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        struct ctl_msg m;
        struct ctl_error e = { 0 };
        CHECK(control_parse(cases[i].text, strlen(cases[i].text), &m, NULL, &e) == 0 &&
                  (m.type == CTL_LAUNCH || m.type == CTL_STEER || m.type == CTL_REMOVE || m.type == CTL_CLAIM),
              "%s does not parse as a body request", cases[i].text);
        struct body_req r;
        const char *code = body_parse(m.root, m.type, &r, &e) == 0 ? "ok" : e.code;
        CHECK(strcmp(code, cases[i].code) == 0, "%s -> %s (%s), want %s", cases[i].text, code, e.message, cases[i].code);
        if (strcmp(code, "ok") != 0)
            CHECK(strcmp(e.param, cases[i].param) == 0, "%s: param \"%s\", want \"%s\"", cases[i].text, e.param,
                  cases[i].param);
        if (i == 0)
            CHECK(r.kind == body_kind_find("boat") && r.x == 10 && r.z == -20 && r.heading == 90, "launch values");
        if (i == 12)
            CHECK(r.body == 12 && r.has_throttle && r.has_rudder && r.throttle == 0.5 && r.rudder == -0.2, "steer");
        if (i == 13)
            CHECK(!r.has_throttle && !r.has_rudder, "a steer of nothing");
        ctl_msg_free(&m);
    }
    /* The replies print and carry what they should. */
    cJSON *id = cJSON_CreateNumber(7);
    char *t = control_print(body_launched_msg(id, 12, "0123456789abcdef0123456789abcdef"));
    CHECK(t && strcmp(t, "{\"type\":\"launched\",\"id\":7,\"body\":12,\"resume\":\"0123456789abcdef0123456789abcdef\"}") == 0,
          "launched: %s", t);
    free(t);
    struct body_entry be = { .body = 12, .kind = body_kind_find("boat"), .owner = "c7-k3qf", .name = "Ana" };
    struct body_gone_entry bg = { .body = 5, .reason = "sunk" };
    t = control_print(bodies_msg(99, 1, &be, 1, &bg));
    CHECK(t && strcmp(t, "{\"type\":\"bodies\",\"seq\":99,\"bodies\":[{\"body\":12,\"kind\":\"boat\",\"owner\":\"c7-k3qf\","
                         "\"name\":\"Ana\",\"adrift\":false}],\"removed\":[{\"body\":5,\"reason\":\"sunk\"}]}") == 0,
          "bodies: %s", t);
    free(t);
    cJSON_Delete(id);
    /* proto/vectors/control: each request parses, each reply is what the builders make. */
    static const char *const requests[] = { "16_launch.json", "18_steer.json", "20_remove.json", "22_claim.json" };
    for (size_t i = 0; i < sizeof requests / sizeof requests[0]; i++) {
        char vpath[128], verr[256], *vt;
        size_t vlen;
        snprintf(vpath, sizeof vpath, "proto/vectors/control/%s", requests[i]);
        if (file_read_all(vpath, 1 << 16, &vt, &vlen, verr, sizeof verr) != 0) {
            CHECK(0, "vector: %s", verr);
            continue;
        }
        struct ctl_msg m;
        struct ctl_error ve;
        struct body_req r;
        CHECK(control_parse(vt, vlen, &m, NULL, &ve) == 0 && body_parse(m.root, m.type, &r, &ve) == 0, "%s: %s",
              requests[i], ve.message);
        ctl_msg_free(&m);
        free(vt);
    }
    cJSON *vid[4] = { cJSON_CreateNumber(1), cJSON_CreateNumber(2), cJSON_CreateNumber(3), cJSON_CreateNumber(4) };
    struct body_entry ve12 = { .body = 12, .kind = body_kind_find("boat"), .owner = "c7-k3qf", .name = "Ana" };
    struct body_gone_entry vg5 = { .body = 5, .reason = "sunk" };
    struct { const char *file; cJSON *msg; } replies[] = {
        { "17_launched.json", body_launched_msg(vid[0], 12, "9f86d081884c7d659a2feaa0c55ad015") },
        { "19_steered.json", body_ack_msg("steered", vid[1], 12) },
        { "21_removed.json", body_ack_msg("removed", vid[2], 12) },
        { "23_claimed.json", body_ack_msg("claimed", vid[3], 12) },
        { "24_bodies.json", bodies_msg(4711, 1, &ve12, 1, &vg5) },
    };
    for (size_t i = 0; i < sizeof replies / sizeof replies[0]; i++) {
        char vpath[128], verr[256], *vt;
        size_t vlen;
        snprintf(vpath, sizeof vpath, "proto/vectors/control/%s", replies[i].file);
        cJSON *want = file_read_all(vpath, 1 << 16, &vt, &vlen, verr, sizeof verr) == 0 ? cJSON_Parse(vt) : NULL;
        CHECK(want && cJSON_Compare(want, replies[i].msg, 1), "%s is not what the server sends", replies[i].file);
        if (want)
            free(vt);
        cJSON_Delete(want);
        cJSON_Delete(replies[i].msg);
    }
    for (int i = 0; i < 4; i++)
        cJSON_Delete(vid[i]);
    cJSON *kinds = body_kinds_array();
    CHECK(cJSON_GetArraySize(kinds) == BODY_KIND_COUNT, "body_kinds rows");
    cJSON_Delete(kinds);

    /* The BODY section: written, read back exactly; a frame without one has none. */
    struct oc_body_record rec[3] = {
        { .id = 1, .kind = 0, .flags = 0, .throttle = 0, .rudder = 0, .pos = { 1, -2, 3 }, .quat = { 1, 0, 0, 0 } },
        { .id = 12, .kind = 3, .flags = OC_BODY_FLAG_POWERED, .throttle = 64, .rudder = -25, .pos = { -10.5f, 0.25f, 2500 },
          .quat = { 0.7071f, 0, -0.7071f, 0 }, .vel = { 0.5f, -0.1f, 4 } },
        { .id = 4294967295u, .kind = 4, .flags = OC_BODY_FLAG_ADRIFT | OC_BODY_FLAG_POWERED, .throttle = -127, .rudder = 127 },
    };
    size_t hs = OC_FRAME_HEADER_SIZE + oc_body_section_size(3);
    CHECK(hs % 8 == 0 && oc_body_section_size(3) == 16 + 3 * 48, "section size");
    uint8_t frame[OC_FRAME_HEADER_SIZE + 16 + 3 * 48];
    struct oc_frame_header fh = { .seq = 5, .n = 64, .tile_size = 64, .patch_size = 100 };
    oc_frame_header_write(frame, &fh);
    frame[6] = (uint8_t)hs;
    frame[7] = (uint8_t)(hs >> 8);
    oc_body_section_write(frame + OC_FRAME_HEADER_SIZE, rec, 3);
    struct oc_body_record back[3];
    CHECK(oc_body_section_read(frame, sizeof frame, back, 3) == 3, "read the section");
    for (int i = 0; i < 3; i++)
        CHECK(back[i].id == rec[i].id && back[i].kind == rec[i].kind && back[i].flags == rec[i].flags &&
                  back[i].throttle == rec[i].throttle && back[i].rudder == rec[i].rudder &&
                  memcmp(back[i].pos, rec[i].pos, sizeof rec[i].pos) == 0 &&
                  memcmp(back[i].quat, rec[i].quat, sizeof rec[i].quat) == 0 &&
                  memcmp(back[i].vel, rec[i].vel, sizeof rec[i].vel) == 0,
              "record %d changed on the way", i);
    CHECK(oc_body_section_read(frame, sizeof frame - 1, back, 3) == OC_E_TRUNCATED, "a cut header");
    CHECK(oc_body_section_read(frame, sizeof frame, NULL, 0) == 3, "count only");
    frame[52] = 4; /* count 4 in a section of 3 */
    CHECK(oc_body_section_read(frame, sizeof frame, back, 3) == OC_E_CORRUPT, "more records than header_size holds");
    frame[52] = 3;
    oc_frame_header_write(frame, &fh); /* header_size 48 again: no section */
    CHECK(oc_body_section_read(frame, sizeof frame, back, 3) == 0, "a 48-byte header has no bodies");

    /* The state file: every body exactly, and a bad entry refuses them all. */
    char dir[] = "/tmp/oceand-test-bodies-XXXXXX";
    CHECK(mkdtemp(dir) != NULL, "mkdtemp");
    char path[128], err[300];
    snprintf(path, sizeof path, "%s/state.json", dir);
    struct ocean_params p;
    params_defaults(&p);
    struct state_body sb[2] = {
        { .st = { .id = 3, .kind = body_kind_find("ball"), .pos = { 0.1, -0.3333333333333333, 1e-17 },
                  .quat = { 1, 0, 0, 0 }, .vel = { 1.0 / 3, 0, 0 }, .omega = { 0, 2e-300, 0 } },
          .owner = "c7-k3qf", .name = "Ana", .resume = "0123456789abcdef0123456789abcdef" },
        { .st = { .id = 9, .kind = body_kind_find("ship"), .pos = { -2500, 0, 2500 }, .quat = { 0.6, 0, 0.8, 0 },
                  .control = { 0.75, -1 } },
          .owner = "c1-x82m", .resume = "ffffffffffffffffffffffffffffffff" },
    };
    struct state_bodies in = { .n = 2, .cap = 2, .next_id = 12, .b = sb }, out;
    CHECK(state_save(path, &p, 1, 2.5, &in, NULL, err, sizeof err) == 0, "state_save: %s", err);
    CHECK(state_load_bodies(path, &out, err, sizeof err) == 1 && out.n == 2 && out.next_id == 12, "load: %s", err);
    for (int i = 0; i < 2; i++)
        CHECK(memcmp(&out.b[i].st, &sb[i].st, sizeof sb[i].st) == 0 && strcmp(out.b[i].owner, sb[i].owner) == 0 &&
                  strcmp(out.b[i].name, sb[i].name) == 0 && strcmp(out.b[i].resume, sb[i].resume) == 0,
              "body %d is not the one saved", i);
    state_bodies_free(&out);
    sb[1].st.kind = NULL; /* saved with an unknown kind's name below */
    static const char *const bad[] = {
        "\"kind\":\"ship\"", "\"kind\":\"submarine\"",
        "\"throttle\":0.75", "\"throttle\":1.5",
        "\"owner\":\"c1-x82m\"", "\"owner\":\"c1 x82m\"",
        "\"resume\":\"ffffffffffffffffffffffffffffffff\"", "\"resume\":\"fff\"",
        "\"id\":9", "\"id\":3",
    };
    sb[1].st.kind = body_kind_find("ship");
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i += 2) {
        CHECK(state_save(path, &p, 1, 2.5, &in, NULL, err, sizeof err) == 0, "state_save: %s", err);
        char *text;
        size_t len;
        CHECK(file_read_all(path, 1 << 20, &text, &len, err, sizeof err) == 0, "read back");
        /* cJSON prints "key":<tab>value: compare without the blanks. */
        char *flat = malloc(len + 1), *o = flat;
        for (size_t k = 0; k < len; k++)
            if (text[k] != '\t' && text[k] != '\n')
                *o++ = text[k];
        *o = 0;
        free(text);
        char *at = strstr(flat, bad[i]);
        const char *last = NULL;
        for (char *q = at; q; q = strstr(q + 1, bad[i]))
            last = q; /* the second body's member */
        CHECK(last != NULL, "%s not in the saved file", bad[i]);
        size_t off = (size_t)(last - flat);
        FILE *f = fopen(path, "w");
        fprintf(f, "%.*s%s%s", (int)off, flat, bad[i + 1], flat + off + strlen(bad[i]));
        fclose(f);
        free(flat);
        CHECK(state_load_bodies(path, &out, err, sizeof err) == -1 && out.n == 0 && strstr(err, "bad_body"),
              "%s accepted (%s)", bad[i + 1], err);
    }
    unlink(path);
    rmdir(dir);
}

/* The sea document: JSON -> struct -> JSON -> struct is exact in both forms,
 * the state file keeps it, and the summary has the agreed shape. */
static void test_sea_doc(void)
{
    static struct sea_spectrum in, back, loaded; /* 83 kB each */
    char err[256];
    for (int form = 0; form < 2; form++) {
        sea_fixture_fill(&in, &sea_fixture_default, form ? SEA_FORM_SPECTRUM2D : SEA_FORM_MOMENTS, 72);
        snprintf(in.source, sizeof in.source, "NDBC 46026");
        snprintf(in.time, sizeof in.time, "2026-12-01T20:40:00Z");
        in.depth = form ? 0 : 52;
        in.tail = SEA_TAIL_WIND;
        char msg[200];
        CHECK(sea_spectrum_check(&in, msg, sizeof msg) == SEA_OK, "fixture: %s", msg);
        char *text = control_print(sea_doc_json(&in));
        CHECK(text != NULL, "sea_doc_json");
        struct ctl_error e;
        cJSON *doc = cJSON_Parse(text);
        free(text);
        memset(&back, 0x55, sizeof back);
        CHECK(sea_doc_parse(doc, &back, &e) == 0, "form %d back: %s %s", form, e.code, e.message);
        cJSON_Delete(doc);
        int nd = form ? in.directions : 0;
        bool same = back.form == in.form && back.bands == in.bands && back.directions == in.directions &&
                    back.depth == in.depth && back.tail == in.tail && !strcmp(back.source, in.source) &&
                    !memcmp(back.frequency, in.frequency, sizeof(double) * in.bands) &&
                    !memcmp(back.bandwidth, in.bandwidth, sizeof(double) * in.bands);
        if (!form)
            same = same && !memcmp(back.energy, in.energy, sizeof(double) * in.bands) &&
                   !memcmp(back.a2, in.a2, sizeof(double) * in.bands);
        for (int i = 0; same && i < in.bands; i++)
            same = !memcmp(back.energy2d[i], in.energy2d[i], sizeof(double) * nd);
        CHECK(same, "form %d: the document does not read back exactly", form);
        /* The summary: the agreed members, the polar plot at most 32 x 36. */
        cJSON *sum = sea_summary_json(&in, NULL, 7);
        const char *keys[] = { "version", "source", "time", "hs_m", "tp_s", "dir_from_deg", "spread_deg", "captured",
                               "fit_note", "depth_m", "convention", "polar" };
        for (size_t k = 0; k < sizeof keys / sizeof *keys; k++)
            CHECK(cJSON_GetObjectItemCaseSensitive(sum, keys[k]) != NULL, "summary lacks %s", keys[k]);
        const cJSON *pol = cJSON_GetObjectItemCaseSensitive(sum, "polar");
        const cJSON *rows = cJSON_GetObjectItemCaseSensitive(pol, "e");
        CHECK(cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(pol, "f_hz")) == 32 &&
                  cJSON_GetArraySize(rows) == 32 && cJSON_GetArraySize(cJSON_GetArrayItem(rows, 0)) == 36,
              "polar %d rows", cJSON_GetArraySize(rows));
        double hs = cJSON_GetObjectItemCaseSensitive(sum, "hs_m")->valuedouble;
        CHECK(fabs(hs - 4 * sqrt(sea_spectrum_m0(&in))) < 1e-3 * hs, "hs_m %g", hs);
        CHECK(cJSON_IsNull(cJSON_GetObjectItemCaseSensitive(sum, form ? "depth_m" : "captured")), "nulls");
        cJSON_Delete(sum);
    }
    /* The state file keeps the sea; a file without one has none. */
    char dir[] = "/tmp/oceand-sea-XXXXXX", path[128];
    CHECK(mkdtemp(dir) != NULL, "mkdtemp");
    snprintf(path, sizeof path, "%s/state.json", dir);
    struct ocean_params p;
    params_defaults(&p);
    p.spectrum = SPECTRUM_MEASURED;
    CHECK(state_save(path, &p, 3, 1.5, NULL, &in, err, sizeof err) == 0, "state_save with a sea: %s", err);
    CHECK(state_load_sea(path, &loaded, err, sizeof err) == 1 && loaded.bands == in.bands &&
              loaded.directions == in.directions && !memcmp(loaded.energy2d[3], in.energy2d[3], sizeof(double) * in.directions),
          "the saved sea: %s", err);
    CHECK(state_save(path, &p, 4, 1.5, NULL, NULL, err, sizeof err) == 0 && state_load_sea(path, &loaded, err, sizeof err) == 0,
          "a state file without a sea");
    unlink(path);
    rmdir(dir);
    /* A bad document is refused with the library's code, naming the place. */
    char *text = control_print(sea_doc_json(&in)); /* as a client sends it */
    cJSON *doc = cJSON_Parse(text);
    free(text);
    cJSON *row = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(doc, "energy"), 9);
    cJSON_ReplaceItemInArray(row, 11, cJSON_CreateNumber(-1e-6));
    struct ctl_error e = { .code = "none" };
    CHECK(sea_doc_parse(doc, &back, &e) == -1 && !strcmp(e.code, "sea_negative") && !strcmp(e.param, "energy[9][11]"),
          "negative energy: %s %s (%s)", e.code, e.param, e.message);
    cJSON_Delete(doc);
}

int main(void)
{
    test_capacity_plan();
    test_capacity_codecs();
    test_capacity_lod_work();
    test_capacity_band();
    test_capacity_codec_rung();
    test_sets();
    test_once();
    test_subscribe();
    test_subscribe_field_lod();
    test_strict_json();
    test_subscribe_dedupe();
    test_token_equal();
    test_builders();
    test_state_and_config();
    test_sea_doc();
    test_one_validation_path();
    test_id_cap();
    test_pong_integer();
    test_subscribe_codec();
    test_hello_matches_vector();
    test_short_frames();
    test_config_file_limits();
    test_state_values();
    test_counter_limits();
    test_display_names();
    test_render();
    test_exact_ids();
    test_files_strict();
    test_bodies();
    fuzz();
    return check_done();
}

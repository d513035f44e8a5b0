/* control.c — parse and validate JSON control messages and names; the
 * subscriptions are in subscription.c, the replies in replies.c.
 * See control.h; the wire contract is proto/PROTOCOL.md. */
#include "control.h"
#include "control_internal.h"

#include <ctype.h>
#include <inttypes.h>
#include <math.h>
#include <stdatomic.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "oc_proto.h"
#include "ocean.h"

/* The library's field numbering is the wire's (frames carry ocean_field
 * values as oc_field ids), and so are the LOD limit and the mask width.
 * Checked here, the one daemon file that sees both headers: the library may
 * not include protocol headers. */
#define SAME_NUMBER(a, b) ((int)(a) == (int)(b))
_Static_assert(SAME_NUMBER(OCEAN_HEIGHT, OC_FIELD_HEIGHT) && SAME_NUMBER(OCEAN_DX, OC_FIELD_DX) &&
                   SAME_NUMBER(OCEAN_DZ, OC_FIELD_DZ) && SAME_NUMBER(OCEAN_SLOPE_X, OC_FIELD_SLOPE_X) &&
                   SAME_NUMBER(OCEAN_SLOPE_Z, OC_FIELD_SLOPE_Z) && SAME_NUMBER(OCEAN_JACOBIAN, OC_FIELD_JACOBIAN) &&
                   SAME_NUMBER(OCEAN_FOAM, OC_FIELD_FOAM),
               "ocean_field and oc_field must number the fields alike");
_Static_assert(SAME_NUMBER(OCEAN_FIELD_COUNT, OC_FIELD_COUNT), "ocean_field and oc_field must have the same fields");
_Static_assert(CTL_MAX_LOD == OC_MAX_LOD, "CTL_MAX_LOD must be the wire's OC_MAX_LOD");
_Static_assert(PARAM_COUNT <= 64, "the `changed` masks (uint64_t) have one bit per parameter");

const float ctl_bounds[CTL_BOUND_COUNT] = { 0.0f, 0.001f, 0.005f, 0.01f, 0.05f };

int ctl_fail(struct ctl_error *e, const char *code, const char *param, const char *fmt, ...)
{
    va_list ap;
    e->code = code;
    snprintf(e->param, sizeof e->param, "%s", param ? param : "");
    va_start(ap, fmt);
    vsnprintf(e->message, sizeof e->message, fmt, ap);
    va_end(ap);
    return -1;
}

static bool is_scalar(const cJSON *j)
{
    /* raw: a number kept as its text (keep_number_text) */
    return cJSON_IsString(j) || cJSON_IsNumber(j) || cJSON_IsRaw(j) || cJSON_IsBool(j) || cJSON_IsNull(j);
}

/* JSON's four blanks (RFC 8259), not isspace(): that also takes \v and \f. */
static bool is_json_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; }

/* What cJSON 1.7 lets through but RFC 8259 (or we) do not: raw control bytes
 * (cJSON skips them as whitespace, even NUL), "\u" without four hex digits
 * (decoded as 0) and "\u0000" (cJSON hands out C strings, so a NUL would
 * silently truncate a name: "set\u0000x" would act as "set"). A backslash
 * outside a string fails the parse anyway, so one flat scan is enough. */
int control_json_prescan(const char *text, size_t len, struct ctl_error *e)
{
    for (size_t i = 0; i < len; i++) {
        unsigned char c = (unsigned char)text[i];
        if (c < 0x20 && !is_json_space((char)c))
            return ctl_fail(e, "bad_json", NULL, "raw control byte 0x%02x at offset %zu", c, i);
        if (c != '\\')
            continue;
        if (i + 1 < len && text[i + 1] == 'u') {
            if (i + 6 > len)
                return ctl_fail(e, "bad_json", NULL, "truncated \\u escape at offset %zu", i);
            if (!isxdigit((unsigned char)text[i + 2]) || !isxdigit((unsigned char)text[i + 3]) ||
                !isxdigit((unsigned char)text[i + 4]) || !isxdigit((unsigned char)text[i + 5]))
                return ctl_fail(e, "bad_json", NULL, "invalid \\u escape at offset %zu", i);
            if (memcmp(text + i + 2, "0000", 4) == 0)
                return ctl_fail(e, "bad_json", NULL, "\\u0000 (NUL) in a string at offset %zu is not accepted", i);
            i += 5;
        } else {
            i++; /* skip the escaped character, so "\\\\u0000" is a backslash then text */
        }
    }
    return 0;
}

/* Whether the id prints in at most CTL_MAX_ID_BYTES. cJSON prints into our
 * stack buffer and fails when it does not fit (it wants 5 spare bytes), so
 * a huge id costs no allocation. */
static bool id_fits(const cJSON *id)
{
    char buf[CTL_MAX_ID_BYTES + 6];
    return cJSON_PrintPreallocated((cJSON *)id, buf, (int)sizeof buf, 0) && strlen(buf) <= CTL_MAX_ID_BYTES;
}

/* ---- the request id (and a ping's t), exactly as sent ----
 * cJSON holds a number as a double, so 9007199254740993 would come back as
 * 9.00719925474099e+15 and 1e400 as null. A numeric id is therefore echoed
 * from its own text: the scan below finds the top-level member in the
 * message (text cJSON has accepted, so it only has to find where values
 * end) and the member becomes a raw cJSON node holding that text. */

/* cJSON's whitespace: every byte up to 0x20 (stays in step with its parse). */
static const char *skip_blank(const char *s, const char *end)
{
    while (s < end && (unsigned char)*s <= 0x20)
        s++;
    return s;
}

/* s at a string's opening quote: just past its closing one. */
static const char *skip_string(const char *s, const char *end)
{
    for (s++; s < end && *s != '"'; s++)
        if (*s == '\\' && s + 1 < end)
            s++; /* the escaped character, which may be a quote */
    return s < end ? s + 1 : end;
}

/* s at a value: just past it. */
static const char *skip_value(const char *s, const char *end)
{
    if (s < end && *s == '"')
        return skip_string(s, end);
    if (s < end && (*s == '{' || *s == '[')) {
        int depth = 0;
        while (s < end) {
            if (*s == '"') {
                s = skip_string(s, end);
                continue;
            }
            if (*s == '{' || *s == '[')
                depth++;
            else if ((*s == '}' || *s == ']') && --depth == 0)
                return s + 1;
            s++;
        }
        return end;
    }
    while (s < end && (unsigned char)*s > 0x20 && *s != ',' && *s != '}' && *s != ']')
        s++; /* a number, true, false or null */
    return s;
}

/* s at a member name's opening quote: whether it reads `want` (a short ASCII
 * name) once decoded (cJSON compares decoded names: "\u0069d" is "id" too);
 * *after = past it. */
static bool name_is(const char *s, const char *end, const char *want, const char **after)
{
    char got[8];
    const size_t wlen = strlen(want); /* < sizeof got */
    size_t n = 0;
    bool fits = true;
    const char *p = s + 1;
    while (p < end && *p != '"') {
        char c = *p++;
        if (c == '\\' && p < end) {
            char esc = *p++;
            c = '\x01'; /* \" \\ \/ \b \f \n \r \t decode to no letter, and the names are letters... */
            if (esc == 'u' && end - p >= 4) {
                char hex[5] = { p[0], p[1], p[2], p[3], 0 };
                long v = strtol(hex, NULL, 16);
                c = v > 0 && v < 0x80 ? (char)v : '\x01'; /* ...but a \u00XX may be one */
                p += 4;
            }
        }
        if (n < wlen)
            got[n] = c;
        fits = ++n <= wlen;
    }
    *after = p < end ? p + 1 : end;
    return fits && n == wlen && memcmp(got, want, wlen) == 0;
}

/* The text of the first top-level member `name`'s value (as cJSON's lookup
 * finds the first), or false when the object has none. */
static bool find_member_text(const char *text, size_t len, const char *name, const char **tok, size_t *toklen)
{
    const char *end = text + len, *p = skip_blank(text, end);
    if (p >= end || *p != '{')
        return false;
    p = skip_blank(p + 1, end);
    while (p < end && *p == '"') {
        const char *after;
        bool match = name_is(p, end, name, &after);
        p = skip_blank(after, end);
        if (p >= end || *p != ':')
            return false;
        p = skip_blank(p + 1, end);
        const char *v = p;
        p = skip_value(p, end);
        if (match) {
            *tok = v;
            *toklen = (size_t)(p - v);
            return true;
        }
        p = skip_blank(p, end);
        if (p >= end || *p != ',')
            return false;
        p = skip_blank(p + 1, end);
    }
    return false;
}

/* RFC 8259's number: -? (0 | [1-9][0-9]*) (. [0-9]+)? ([eE] [+-]? [0-9]+)?.
 * cJSON also takes "01", "1." and ".5"-like forms; echoed verbatim they
 * would make the reply invalid JSON, so such an id is refused. */
static bool is_json_number(const char *s, size_t len)
{
    size_t i = 0;
    if (i < len && s[i] == '-')
        i++;
    if (i < len && s[i] == '0')
        i++;
    else if (i < len && s[i] >= '1' && s[i] <= '9')
        while (i < len && isdigit((unsigned char)s[i]))
            i++;
    else
        return false;
    if (i < len && s[i] == '.') {
        size_t d = ++i;
        while (i < len && isdigit((unsigned char)s[i]))
            i++;
        if (i == d)
            return false;
    }
    if (i < len && (s[i] == 'e' || s[i] == 'E')) {
        i++;
        if (i < len && (s[i] == '+' || s[i] == '-'))
            i++;
        size_t d = i;
        while (i < len && isdigit((unsigned char)s[i]))
            i++;
        if (i == d)
            return false;
    }
    return i == len;
}

/* A numeric member `name` of root (parsed from text) replaced by a raw node
 * of its own text, so every reply that copies it prints it as sent. 0, or -1
 * with e filled (bad_json: not an RFC 8259 number). */
static int keep_number_text(cJSON *root, const char *text, size_t len, const char *name, struct ctl_error *e)
{
    if (!cJSON_IsNumber(cJSON_GetObjectItemCaseSensitive(root, name)))
        return 0;
    const char *tok;
    size_t toklen;
    if (!find_member_text(text, len, name, &tok, &toklen))
        return ctl_fail(e, "internal", NULL, "the \"%s\" number was not found in the message", name);
    if (!is_json_number(tok, toklen))
        return ctl_fail(e, "bad_json", NULL, "\"%s\" %.*s is not a JSON number (RFC 8259)", name,
                        toklen > 40 ? 40 : (int)toklen, tok);
    char *raw = malloc(toklen + 1);
    if (!raw)
        return ctl_fail(e, "internal", NULL, "out of memory");
    memcpy(raw, tok, toklen);
    raw[toklen] = '\0';
    cJSON *node = cJSON_CreateRaw(raw);
    free(raw);
    if (!node || !cJSON_ReplaceItemInObjectCaseSensitive(root, name, node)) {
        cJSON_Delete(node);
        return ctl_fail(e, "internal", NULL, "out of memory");
    }
    return 0;
}

cJSON *control_parse_object(const char *text, size_t len, struct ctl_error *e)
{
    if (control_json_prescan(text, len, e) != 0)
        return NULL;
    /* The whole text must be one JSON value: cJSON stops after the first
     * value, so check what follows it ourselves (require_null_terminated
     * would need a NUL inside len, which the wire does not give us). */
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithLengthOpts(text, len, &end, 0);
    if (!root) {
        ctl_fail(e, "bad_json", NULL, "not valid JSON");
        return NULL;
    }
    while (end && end < text + len && is_json_space(*end))
        end++;
    if (end != text + len) {
        cJSON_Delete(root);
        ctl_fail(e, "bad_json", NULL, "trailing data after the JSON value (offset %zu)",
                 end ? (size_t)(end - text) : (size_t)0);
        return NULL;
    }
    if (!cJSON_IsObject(root)) {
        cJSON_Delete(root);
        ctl_fail(e, "bad_json", NULL, "not a JSON object");
        return NULL;
    }
    return root;
}

cJSON *control_message_id(const char *text, size_t len)
{
    struct ctl_error e;
    cJSON *root = control_parse_object(text, len, &e);
    if (!root || keep_number_text(root, text, len, "id", &e) != 0) {
        cJSON_Delete(root);
        return NULL;
    }
    cJSON *id = cJSON_DetachItemFromObjectCaseSensitive(root, "id");
    cJSON_Delete(root);
    return id;
}

int control_parse(const char *text, size_t len, struct ctl_msg *m, cJSON **id_out, struct ctl_error *e)
{
    memset(m, 0, sizeof *m);
    if (id_out)
        *id_out = NULL;
    cJSON *root = control_parse_object(text, len, e);
    if (!root)
        return -1;
    if (keep_number_text(root, text, len, "id", e) != 0) { /* not echoed: it is what is wrong */
        cJSON_Delete(root);
        return -1;
    }
    const cJSON *id = cJSON_GetObjectItemCaseSensitive(root, "id");
    if (id && !is_scalar(id)) {
        cJSON_Delete(root);
        return ctl_fail(e, "bad_message", NULL, "\"id\" must be a JSON scalar");
    }
    if (id && !id_fits(id)) {
        /* Not echoed: the cap exists so that replies stay small. */
        cJSON_Delete(root);
        return ctl_fail(e, "bad_message", NULL, "\"id\" longer than %d bytes of JSON", CTL_MAX_ID_BYTES);
    }
    const cJSON *type = cJSON_GetObjectItemCaseSensitive(root, "type");
    const char *ts = cJSON_GetStringValue(type);
    int rc = 0;
    if (!ts) {
        rc = ctl_fail(e, "bad_message", NULL, "missing or non-string \"type\"");
    } else if (strcmp(ts, "set") == 0) {
        m->type = CTL_SET;
        m->params = cJSON_GetObjectItemCaseSensitive(root, "params");
        if (!cJSON_IsObject(m->params))
            rc = ctl_fail(e, "bad_message", NULL, "\"set\" needs a \"params\" object");
        const cJSON *tok = cJSON_GetObjectItemCaseSensitive(root, "token");
        if (tok && !cJSON_IsString(tok))
            rc = ctl_fail(e, "bad_message", NULL, "\"token\" must be a string");
        m->token = cJSON_GetStringValue(tok);
    } else if (strcmp(ts, "sea") == 0) {
        m->type = CTL_SEA; /* sea_doc_parse (sea_msg.c) checks the document */
        m->sea = cJSON_GetObjectItemCaseSensitive(root, "sea");
        if (!cJSON_IsObject(m->sea))
            rc = ctl_fail(e, "bad_message", "sea", "\"sea\" needs a \"sea\" document (an object)");
        const cJSON *tok = cJSON_GetObjectItemCaseSensitive(root, "token");
        if (tok && !cJSON_IsString(tok))
            rc = ctl_fail(e, "bad_message", NULL, "\"token\" must be a string");
        m->token = cJSON_GetStringValue(tok);
    } else if (strcmp(ts, "name") == 0) {
        m->type = CTL_NAME;
        const cJSON *nm = cJSON_GetObjectItemCaseSensitive(root, "name");
        if (!cJSON_IsString(nm))
            rc = ctl_fail(e, "bad_name", NULL, "\"name\" needs a \"name\" string (\"\" for none)");
        else if (control_check_name(nm->valuestring, e) != 0)
            rc = -1;
        m->name = cJSON_GetStringValue(nm);
    } else if (strcmp(ts, "subscribe") == 0) {
        m->type = CTL_SUBSCRIBE;
    } else if (strcmp(ts, "pause") == 0) {
        m->type = CTL_PAUSE;
    } else if (strcmp(ts, "resume") == 0) {
        m->type = CTL_RESUME;
    } else if (strcmp(ts, "query") == 0) {
        m->type = CTL_QUERY;
    } else if (strcmp(ts, "probe") == 0) {
        m->type = CTL_PROBE;
    } else if (strcmp(ts, "render") == 0) {
        m->type = CTL_RENDER;
    } else if (strcmp(ts, "render_cancel") == 0) {
        m->type = CTL_RENDER_CANCEL;
    } else if (strcmp(ts, "launch") == 0 || strcmp(ts, "steer") == 0 || strcmp(ts, "remove") == 0 ||
               strcmp(ts, "claim") == 0) {
        /* Floating bodies (PROTOCOL.md §7.6): body_parse checks the members. */
        m->type = ts[0] == 'l' ? CTL_LAUNCH : ts[0] == 's' ? CTL_STEER : ts[0] == 'r' ? CTL_REMOVE : CTL_CLAIM;
    } else if (strcmp(ts, "ping") == 0) {
        m->type = CTL_PING;
        const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "t");
        if (t && !cJSON_IsNumber(t))
            rc = ctl_fail(e, "bad_message", NULL, "\"t\" must be a number");
        else if (t) /* echoed in pong as sent, like the id */
            rc = keep_number_text(root, text, len, "t", e);
        m->t = cJSON_GetObjectItemCaseSensitive(root, "t");
    } else {
        rc = ctl_fail(e, "unknown_type", NULL, "unknown message type \"%.40s\"", ts);
    }
    if (!rc && (m->type == CTL_SET || m->type == CTL_PAUSE || m->type == CTL_RESUME || m->type == CTL_SEA)) {
        /* Optional on the requests that change the sea: the sender's display name. */
        const cJSON *nm = cJSON_GetObjectItemCaseSensitive(root, "name");
        if (nm && !cJSON_IsString(nm))
            rc = ctl_fail(e, "bad_name", NULL, "\"name\" must be a string");
        else if (nm && control_check_name(nm->valuestring, e) != 0)
            rc = -1;
        m->name = cJSON_GetStringValue(nm);
    }
    if (!rc && (m->type == CTL_SET || m->type == CTL_PAUSE || m->type == CTL_RESUME || m->type == CTL_SEA)) {
        const cJSON *once = cJSON_GetObjectItemCaseSensitive(root, "once");
        const char *k = cJSON_GetStringValue(once);
        size_t klen = k ? strlen(k) : 0;
        bool printable = k != NULL;
        for (size_t i = 0; printable && i < klen; i++)
            printable = k[i] > 0x20 && k[i] < 0x7f;
        if (once && (!printable || klen < CTL_ONCE_MIN || klen > CTL_ONCE_MAX))
            rc = ctl_fail(e, "bad_message", NULL, "\"once\" must be a string of %d to %d printable ASCII characters",
                          CTL_ONCE_MIN, CTL_ONCE_MAX);
        m->once = k;
    }
    if (rc) {
        if (id_out && id)
            *id_out = cJSON_Duplicate(id, 1);
        cJSON_Delete(root);
        return rc;
    }
    m->root = root;
    m->id = id;
    return 0;
}

void ctl_msg_free(struct ctl_msg *m)
{
    cJSON_Delete(m->root);
    memset(m, 0, sizeof *m);
}

/* ocean_memory_bytes(n, 1) for power-of-two n, remembered: it counts the
 * spectrum's rings with an O(N^2) pass and a fresh table (milliseconds at
 * N = 2048), too slow to repeat for every hello's capacity announcement on
 * the lws thread (test-hostile connections_500 lost 12-20 frames of its
 * observer per burst of 99 hellos). Pure function of n: any thread may fill
 * a slot, a race only computes the same value twice. */
static _Atomic size_t memory_bytes_cache[32];

static size_t memory_bytes(int n)
{
    int lg = 0;
    while (lg < 31 && (1 << lg) < n)
        lg++;
    if (n < 2 || (1 << lg) != n)
        return ocean_memory_bytes(n, 1);
    size_t b = atomic_load_explicit(&memory_bytes_cache[lg], memory_order_relaxed);
    if (!b) {
        b = ocean_memory_bytes(n, 1);
        atomic_store_explicit(&memory_bytes_cache[lg], b, memory_order_relaxed);
    }
    return b;
}

double control_memory_mb(int n, int cascades)
{
    /* While a new N is being built the old simulation still runs, so two
     * exist at once (one grid per cascade, and from its first eased change on
     * each cascade's easing buffer); plus up to three frames in flight of one raw field, and
     * the encoder's six fields (frame_job.c: the arrays it took from the library
     * while the next step writes into the library's). */
    const double c = cascades > 1 ? cascades : 1;
    double bytes = 2.0 * c * (double)memory_bytes(n) + c * (double)ocean_ease_memory_bytes(n) +
                   (3.0 + 6.0) * 4.0 * (double)n * (double)n;
    return bytes / 1048576.0;
}

bool control_fits_memory(int n, int cascades, int max_memory_mb)
{
    return control_memory_mb(n, cascades) <= (double)max_memory_mb;
}

const char *control_error_code(enum param_error r)
{
    switch (r) {
    case PARAM_OK: break;
    case PARAM_ERR_UNKNOWN: return "unknown_param";
    case PARAM_ERR_TYPE:
    case PARAM_ERR_NOT_FINITE:
    case PARAM_ERR_NOT_INTEGER: return "bad_type";
    case PARAM_ERR_RANGE:
    case PARAM_ERR_NOT_POW2:
    case PARAM_ERR_BAD_ENUM:
    case PARAM_ERR_TOO_LONG: return "out_of_range";
    case PARAM_ERR_INVALID: return "invalid";
    }
    return "internal";
}

int control_set_json(void *base, const struct param_def *d, const cJSON *item, struct ctl_error *e)
{
    char err[sizeof e->message];
    enum param_error r;
    /* Only the JSON type is checked here; the value is params.c's business. */
    switch (d->type) {
    case PARAM_INT:
    case PARAM_FLOAT:
        if (!cJSON_IsNumber(item))
            return ctl_fail(e, "bad_type", d->name, "%s must be a number", d->name);
        r = setting_set_number(base, d, item->valuedouble, err, sizeof err);
        break;
    case PARAM_ENUM:
    case PARAM_STRING:
        if (!cJSON_IsString(item))
            return ctl_fail(e, "bad_type", d->name, "%s must be a string", d->name);
        r = setting_set_text(base, d, item->valuestring, err, sizeof err);
        break;
    case PARAM_BOOL:
        if (!cJSON_IsBool(item))
            return ctl_fail(e, "bad_type", d->name, "%s must be true or false", d->name);
        r = setting_set_number(base, d, cJSON_IsTrue(item) ? 1 : 0, err, sizeof err);
        break;
    default:
        return ctl_fail(e, "internal", d->name, "unknown parameter type");
    }
    if (r != PARAM_OK)
        return ctl_fail(e, control_error_code(r), d->name, "%s", err);
    return 0;
}

int control_apply_params(const cJSON *obj, const struct ocean_params *cur, const struct ctl_limits *lim,
                         struct ocean_params *out, uint64_t *changed, struct ctl_error *e)
{
    if (!cJSON_IsObject(obj))
        return ctl_fail(e, "bad_message", NULL, "\"params\" must be an object");
    struct ocean_params p = *cur;
    const cJSON *item;
    cJSON_ArrayForEach(item, obj) {
        const struct param_def *d = item->string ? param_find(item->string) : NULL;
        if (!d)
            return ctl_fail(e, "unknown_param", item->string, "unknown parameter \"%.40s\"",
                        item->string ? item->string : "");
        if (!(d->flags & PARAM_LIVE))
            return ctl_fail(e, "invalid", d->name, "%s is read at start-up only", d->name);
        if (control_set_json(&p, d, item, e) != 0)
            return -1;
    }
    char err[160];
    bool have_sea = !lim || lim->have_sea;
    if (p.spectrum == SPECTRUM_MEASURED && !have_sea)
        return ctl_fail(e, "no_sea", "spectrum",
                        "spectrum: measured needs a measured sea: send one first (a `sea` message)");
    if (params_validate_sea(&p, have_sea, err, sizeof err) != 0)
        return ctl_fail(e, "invalid", NULL, "%s", err);
    if (lim && !control_fits_memory(p.resolution, p.cascades, lim->max_memory_mb))
        return ctl_fail(e, "invalid", "resolution", "resolution %d exceeds the memory cap of %d MB (with %d cascade%s)",
                    p.resolution, lim->max_memory_mb, p.cascades, p.cascades > 1 ? "s" : "");
    *out = p;
    if (changed)
        *changed = params_diff(cur, &p);
    return 0;
}

bool control_token_equal(const char *given, const char *secret)
{
    /* Constant time in the content: always walk the whole secret, never stop
     * at the first difference (only the secret's length shows in the timing).
     * Hand-written: OpenSSL's CRYPTO_memcmp does this, but the daemon does not
     * link libcrypto itself (only libwebsockets may, and only with TLS built in). */
    size_t lg = strlen(given), ls = strlen(secret);
    unsigned char diff = (unsigned char)(lg != ls);
    for (size_t i = 0; i < ls; i++)
        diff |= (unsigned char)((i < lg ? (unsigned char)given[i] : 0u) ^ (unsigned char)secret[i]);
    return diff == 0;
}

/* One code point of strict UTF-8 (no overlong forms, no surrogates, at
 * most U+10FFFF) at s: its length, or 0 if invalid. Hand-written: cJSON
 * passes bytes through unchecked, and the check is a dozen lines. */
static int utf8_next(const unsigned char *s, uint32_t *cp)
{
    unsigned char c = s[0];
    int len = c < 0x80 ? 1 : (c & 0xe0) == 0xc0 ? 2 : (c & 0xf0) == 0xe0 ? 3 : (c & 0xf8) == 0xf0 ? 4 : 0;
    if (!len)
        return 0;
    uint32_t v = len == 1 ? c : c & (0x7fu >> len);
    for (int i = 1; i < len; i++) {
        if ((s[i] & 0xc0) != 0x80)
            return 0; /* also stops at the NUL */
        v = v << 6 | (s[i] & 0x3fu);
    }
    static const uint32_t least[5] = {0, 0, 0x80, 0x800, 0x10000};
    if (v < least[len] || v > 0x10ffff || (v >= 0xd800 && v <= 0xdfff))
        return 0;
    *cp = v;
    return len;
}

/* The format characters, general category Cf: invisible, they join,
 * reorder or hide the text around them (bidi marks, tag characters that
 * spell text nobody sees). Unicode 15.1, extracted/DerivedGeneralCategory.txt
 * (https://www.unicode.org/Public/15.1.0/ucd/extracted/DerivedGeneralCategory.txt),
 * every "; Cf" line. */
static const uint32_t format_chars[][2] = {
    {0x00ad, 0x00ad},   {0x0600, 0x0605},   {0x061c, 0x061c},   {0x06dd, 0x06dd},   {0x070f, 0x070f},
    {0x0890, 0x0891},   {0x08e2, 0x08e2},   {0x180e, 0x180e},   {0x200b, 0x200f},   {0x202a, 0x202e},
    {0x2060, 0x2064},   {0x2066, 0x206f},   {0xfeff, 0xfeff},   {0xfff9, 0xfffb},   {0x110bd, 0x110bd},
    {0x110cd, 0x110cd}, {0x13430, 0x1343f}, {0x1bca0, 0x1bca3}, {0x1d173, 0x1d17a}, {0xe0001, 0xe0001},
    {0xe0020, 0xe007f},
};

/* Characters a name may not hold although they are valid UTF-8: controls
 * (Cc), format characters (Cf, above), line and paragraph separators,
 * private use, noncharacters, and the unassigned rest of U+2060-U+206F. */
static bool name_char_refused(uint32_t c)
{
    for (size_t i = 0; i < sizeof format_chars / sizeof format_chars[0]; i++)
        if (c >= format_chars[i][0] && c <= format_chars[i][1])
            return true;
    return c < 0x20 || (c >= 0x7f && c < 0xa0) || (c >= 0x2028 && c <= 0x2029) || (c >= 0x2060 && c <= 0x206f) ||
           (c >= 0xe000 && c <= 0xf8ff) || (c >= 0xfff0 && c <= 0xffff) || (c & 0xfffe) == 0xfffe ||
           (c >= 0xfdd0 && c <= 0xfdef) || c >= 0xf0000;
}

bool control_valid_utf8(const char *s, size_t len)
{
    const unsigned char *p = (const unsigned char *)s, *end = p + len;
    uint32_t c;
    while (p < end) {
        if (*p == 0)
            return false; /* a NUL would cut the text where it is copied as a C string */
        if (*p < 0x80) {
            p++;
            continue;
        }
        /* s need not be NUL-terminated: a sequence cut by its end is refused
         * before utf8_next reads past it. */
        int need = (*p & 0xe0) == 0xc0 ? 2 : (*p & 0xf0) == 0xe0 ? 3 : (*p & 0xf8) == 0xf0 ? 4 : 0;
        if (!need || end - p < need)
            return false;
        int n = utf8_next(p, &c);
        if (!n)
            return false;
        p += n;
    }
    return true;
}

/* Unicode White_Space that a name may hold (PropList.txt; the controls
 * among them are refused anyway). */
static bool name_char_space(uint32_t c)
{
    return c == 0x20 || c == 0xa0 || c == 0x1680 || (c >= 0x2000 && c <= 0x200a) || c == 0x202f || c == 0x205f ||
           c == 0x3000;
}

/* Whether the name reads as one of the page's own words: the web page says
 * "you set ..." for the reader's own changes and "the server" for changes
 * nobody named (web/src/panel.js, who()), so a peer named "You" would pass
 * its changes off as the reader's. Compared case-insensitively, with the
 * spaces of any kind at either end dropped and runs of them as one. */
static bool name_reserved(const char *s)
{
    static const char *const reserved[] = {"you", "the server"};
    char norm[CTL_NAME_MAX_CHARS + 1];
    size_t n = 0;
    bool gap = false;
    uint32_t c;
    for (const unsigned char *p = (const unsigned char *)s; *p;) {
        int len = utf8_next(p, &c);
        if (!len)
            return false;
        p += len;
        if (name_char_space(c)) {
            gap = n > 0;
            continue;
        }
        if (c >= 0x80 || n + 2 >= sizeof norm)
            return false; /* not ASCII: none of the words */
        if (gap)
            norm[n++] = ' ';
        gap = false;
        norm[n++] = (char)(c >= 'A' && c <= 'Z' ? c + 32 : c);
    }
    norm[n] = 0;
    for (size_t i = 0; i < sizeof reserved / sizeof reserved[0]; i++)
        if (strcmp(norm, reserved[i]) == 0)
            return true;
    return false;
}

int control_check_name(const char *s, struct ctl_error *e)
{
    const unsigned char *p = (const unsigned char *)s;
    size_t chars = 0;
    uint32_t c = 0;
    while (*p) {
        int len = utf8_next(p, &c);
        if (!len)
            return ctl_fail(e, "bad_name", NULL, "name is not valid UTF-8 (byte %zu)", (size_t)(p - (const unsigned char *)s));
        if (++chars > CTL_NAME_MAX_CHARS)
            return ctl_fail(e, "bad_name", NULL, "name longer than %d characters", CTL_NAME_MAX_CHARS);
        if (c < 0x80 && strchr("<>&\"'", (int)c))
            return ctl_fail(e, "bad_name", NULL, "name may not contain %c (no markup: < > & \" ')", (int)c);
        if (name_char_refused(c))
            return ctl_fail(e, "bad_name", NULL, "name may not contain U+%04X (control or invisible formatting character)", (unsigned)c);
        if (chars == 1 && c == ' ')
            return ctl_fail(e, "bad_name", NULL, "name may not start with a space");
        p += len;
    }
    if (chars && c == ' ')
        return ctl_fail(e, "bad_name", NULL, "name may not end with a space");
    if (name_reserved(s))
        return ctl_fail(e, "bad_name", NULL, "\"%s\" is reserved: the page uses it for its own words", s);
    return 0;
}

bool control_json_whole(const cJSON *item, double max, uint64_t *out)
{
    if (!cJSON_IsNumber(item))
        return false;
    double v = item->valuedouble;
    /* Written so that NaN fails every test. */
    if (!(v >= 0 && v <= max && v == floor(v)))
        return false;
    *out = (uint64_t)v;
    return true;
}

bool control_json_version(const cJSON *item, uint32_t *out)
{
    uint64_t v;
    if (!control_json_whole(item, (double)CTL_VERSION_MAX, &v))
        return false;
    *out = (uint32_t)v;
    return true;
}

bool control_json_sim_time(const cJSON *item, double *out)
{
    if (!cJSON_IsNumber(item) || !(item->valuedouble >= 0 && item->valuedouble <= OCEAN_TIME_MAX))
        return false;
    *out = item->valuedouble;
    return true;
}

/* The type of a JSON message, and whether its `points` is a non-empty array. */
void control_reply_type(const char *text, size_t len, char *type, size_t cap, char *code, size_t ccap, bool *points)
{
    type[0] = code[0] = '\0';
    *points = false;
    struct ctl_error e; /* read as a relay reads it: a "probing\u0000x" is no type at all */
    cJSON *root = control_parse_object(text, len, &e);
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "type");
    const cJSON *c = cJSON_GetObjectItemCaseSensitive(root, "code");
    const cJSON *p = cJSON_GetObjectItemCaseSensitive(root, "points");
    if (cJSON_IsString(t))
        snprintf(type, cap, "%s", t->valuestring);
    if (cJSON_IsString(c))
        snprintf(code, ccap, "%s", c->valuestring);
    *points = cJSON_IsArray(p) && cJSON_GetArraySize(p) > 0;
    cJSON_Delete(root);
}

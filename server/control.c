/* control.c — parse/validate JSON control messages, build JSON replies.
 * See control.h; the wire contract is proto/PROTOCOL.md. */
#include "control.h"

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

static int fail(struct ctl_error *e, const char *code, const char *param, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static int fail(struct ctl_error *e, const char *code, const char *param, const char *fmt, ...)
{
    va_list ap;
    e->code = code;
    snprintf(e->param, sizeof e->param, "%s", param ? param : "");
    va_start(ap, fmt);
    vsnprintf(e->message, sizeof e->message, fmt, ap);
    va_end(ap);
    return -1;
}

void subscription_default(struct subscription *s, double tick_rate)
{
    memset(s, 0, sizeof *s);
    s->fields = OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX) | OCEAN_FIELD_BIT(OCEAN_DZ);
    s->lod = 0;
    memset(s->field_lod, -1, sizeof s->field_lod);
    s->bound_index = 3; /* 0.01 m */
    s->max_rate = tick_rate;
    s->all_tiles = true;
    s->ncascades = 1;
}

_Static_assert(CTL_MAX_CASCADES == OCEAN_MAX_CASCADES, "subscriptions address every cascade");

unsigned subscription_cascade(const struct subscription *s, int c, int *lod, int *bound_index)
{
    if (c == 0) {
        *lod = s->lod;
        *bound_index = s->bound_index;
        return s->fields;
    }
    if (c < 0 || c >= s->ncascades || c >= CTL_MAX_CASCADES)
        return 0;
    *lod = s->cascade[c].lod;
    *bound_index = s->cascade[c].bound_index;
    return s->cascade[c].fields;
}

static bool is_scalar(const cJSON *j)
{
    return cJSON_IsString(j) || cJSON_IsNumber(j) || cJSON_IsBool(j) || cJSON_IsNull(j);
}

/* JSON's four blanks (RFC 8259), not isspace(): that also takes \v and \f. */
static bool is_json_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; }

/* What cJSON 1.7 lets through but RFC 8259 (or we) do not: raw control bytes
 * (cJSON skips them as whitespace, even NUL), "\u" without four hex digits
 * (decoded as 0) and "\u0000" (cJSON hands out C strings, so a NUL would
 * silently truncate a name: "set\u0000x" would act as "set"). A backslash
 * outside a string fails the parse anyway, so one flat scan is enough. */
static int prescan(const char *text, size_t len, struct ctl_error *e)
{
    for (size_t i = 0; i < len; i++) {
        unsigned char c = (unsigned char)text[i];
        if (c < 0x20 && !is_json_space((char)c))
            return fail(e, "bad_json", NULL, "raw control byte 0x%02x at offset %zu", c, i);
        if (c != '\\')
            continue;
        if (i + 1 < len && text[i + 1] == 'u') {
            if (i + 6 > len)
                return fail(e, "bad_json", NULL, "truncated \\u escape at offset %zu", i);
            if (!isxdigit((unsigned char)text[i + 2]) || !isxdigit((unsigned char)text[i + 3]) ||
                !isxdigit((unsigned char)text[i + 4]) || !isxdigit((unsigned char)text[i + 5]))
                return fail(e, "bad_json", NULL, "invalid \\u escape at offset %zu", i);
            if (memcmp(text + i + 2, "0000", 4) == 0)
                return fail(e, "bad_json", NULL, "\\u0000 (NUL) in a string is not accepted");
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

int control_parse(const char *text, size_t len, struct ctl_msg *m, cJSON **id_out, struct ctl_error *e)
{
    memset(m, 0, sizeof *m);
    if (id_out)
        *id_out = NULL;
    if (prescan(text, len, e) != 0)
        return -1;
    /* The whole message must be one JSON value: cJSON stops after the first
     * value, so check what follows it ourselves (require_null_terminated
     * would need a NUL inside len, which the wire does not give us). */
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithLengthOpts(text, len, &end, 0);
    if (!root)
        return fail(e, "bad_json", NULL, "message is not valid JSON");
    while (end && end < text + len && is_json_space(*end))
        end++;
    if (end != text + len) {
        cJSON_Delete(root);
        return fail(e, "bad_json", NULL, "trailing data after the JSON value (offset %zu)",
                    end ? (size_t)(end - text) : (size_t)0);
    }
    if (!cJSON_IsObject(root)) {
        cJSON_Delete(root);
        return fail(e, "bad_json", NULL, "message is not a JSON object");
    }
    const cJSON *id = cJSON_GetObjectItemCaseSensitive(root, "id");
    if (id && !is_scalar(id)) {
        cJSON_Delete(root);
        return fail(e, "bad_message", NULL, "\"id\" must be a JSON scalar");
    }
    if (id && !id_fits(id)) {
        /* Not echoed: the cap exists so that replies stay small. */
        cJSON_Delete(root);
        return fail(e, "bad_message", NULL, "\"id\" longer than %d bytes of JSON", CTL_MAX_ID_BYTES);
    }
    const cJSON *type = cJSON_GetObjectItemCaseSensitive(root, "type");
    const char *ts = cJSON_GetStringValue(type);
    int rc = 0;
    if (!ts) {
        rc = fail(e, "bad_message", NULL, "missing or non-string \"type\"");
    } else if (strcmp(ts, "set") == 0) {
        m->type = CTL_SET;
        m->params = cJSON_GetObjectItemCaseSensitive(root, "params");
        if (!cJSON_IsObject(m->params))
            rc = fail(e, "bad_message", NULL, "\"set\" needs a \"params\" object");
        const cJSON *tok = cJSON_GetObjectItemCaseSensitive(root, "token");
        if (tok && !cJSON_IsString(tok))
            rc = fail(e, "bad_message", NULL, "\"token\" must be a string");
        m->token = cJSON_GetStringValue(tok);
    } else if (strcmp(ts, "name") == 0) {
        m->type = CTL_NAME;
        const cJSON *nm = cJSON_GetObjectItemCaseSensitive(root, "name");
        if (!cJSON_IsString(nm))
            rc = fail(e, "bad_name", NULL, "\"name\" needs a \"name\" string (\"\" for none)");
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
    } else if (strcmp(ts, "ping") == 0) {
        m->type = CTL_PING;
        const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "t");
        if (t && !cJSON_IsNumber(t))
            rc = fail(e, "bad_message", NULL, "\"t\" must be a number");
        m->has_t = t != NULL;
        m->t = t ? t->valuedouble : 0;
    } else {
        rc = fail(e, "unknown_type", NULL, "unknown message type \"%.40s\"", ts);
    }
    if (!rc && (m->type == CTL_SET || m->type == CTL_PAUSE || m->type == CTL_RESUME)) {
        /* Optional on the requests that change the sea: the sender's display name. */
        const cJSON *nm = cJSON_GetObjectItemCaseSensitive(root, "name");
        if (nm && !cJSON_IsString(nm))
            rc = fail(e, "bad_name", NULL, "\"name\" must be a string");
        else if (nm && control_check_name(nm->valuestring, e) != 0)
            rc = -1;
        m->name = cJSON_GetStringValue(nm);
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

bool control_fits_memory(int n, int cascades, int max_memory_mb)
{
    /* While a new N is being built the old simulation still runs, so two
     * exist at once (one grid per cascade, and from its first eased change on
     * each cascade's easing buffer); plus up to three frames in flight of one raw field, and
     * the encoder's six fields (frame.c: the arrays it took from the library
     * while the next step writes into the library's). */
    const double c = cascades > 1 ? cascades : 1;
    double bytes = 2.0 * c * (double)memory_bytes(n) + c * (double)ocean_ease_memory_bytes(n) +
                   (3.0 + 6.0) * 4.0 * (double)n * (double)n;
    return bytes <= (double)max_memory_mb * 1048576.0;
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
            return fail(e, "bad_type", d->name, "%s must be a number", d->name);
        r = setting_set_number(base, d, item->valuedouble, err, sizeof err);
        break;
    case PARAM_ENUM:
    case PARAM_STRING:
        if (!cJSON_IsString(item))
            return fail(e, "bad_type", d->name, "%s must be a string", d->name);
        r = setting_set_text(base, d, item->valuestring, err, sizeof err);
        break;
    case PARAM_BOOL:
        if (!cJSON_IsBool(item))
            return fail(e, "bad_type", d->name, "%s must be true or false", d->name);
        r = setting_set_number(base, d, cJSON_IsTrue(item) ? 1 : 0, err, sizeof err);
        break;
    default:
        return fail(e, "internal", d->name, "unknown parameter type");
    }
    if (r != PARAM_OK)
        return fail(e, control_error_code(r), d->name, "%s", err);
    return 0;
}

int control_apply_params(const cJSON *obj, const struct ocean_params *cur, const struct ctl_limits *lim,
                         struct ocean_params *out, uint64_t *changed, struct ctl_error *e)
{
    if (!cJSON_IsObject(obj))
        return fail(e, "bad_message", NULL, "\"params\" must be an object");
    struct ocean_params p = *cur;
    const cJSON *item;
    cJSON_ArrayForEach(item, obj) {
        const struct param_def *d = item->string ? param_find(item->string) : NULL;
        if (!d)
            return fail(e, "unknown_param", item->string, "unknown parameter \"%.40s\"",
                        item->string ? item->string : "");
        if (!(d->flags & PARAM_LIVE))
            return fail(e, "invalid", d->name, "%s is read at start-up only", d->name);
        if (control_set_json(&p, d, item, e) != 0)
            return -1;
    }
    char err[160];
    if (params_validate(&p, err, sizeof err) != 0)
        return fail(e, "invalid", NULL, "%s", err);
    if (lim && !control_fits_memory(p.resolution, p.cascades, lim->max_memory_mb))
        return fail(e, "invalid", "resolution", "resolution %d exceeds the memory cap of %d MB (with %d cascade%s)",
                    p.resolution, lim->max_memory_mb, p.cascades, p.cascades > 1 ? "s" : "");
    uint64_t mask = 0;
    for (size_t i = 0; i < param_count; i++)
        if (param_get(&p, &param_table[i]) != param_get(cur, &param_table[i]))
            mask |= 1ull << i;
    *out = p;
    if (changed)
        *changed = mask;
    return 0;
}

/* fields, lod and bound of a subscription (or of one cascade of it): the
 * members given replace *fields, *lod, *bound_index; field_lod (cascade 0
 * only, else NULL) the per-field LODs. */
static int parse_layer(const cJSON *msg, unsigned *fields, int *lod, signed char field_lod[OCEAN_FIELD_COUNT],
                       int *bound_index, struct ctl_error *e)
{
    const cJSON *j;
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "fields"))) {
        if (!cJSON_IsArray(j) || cJSON_GetArraySize(j) == 0)
            return fail(e, "bad_subscription", NULL, "\"fields\" must be a non-empty array of names");
        unsigned mask = 0;
        const cJSON *f;
        cJSON_ArrayForEach(f, j) {
            const char *name = cJSON_GetStringValue(f);
            int k = -1;
            for (int i = 0; name && i < OCEAN_FIELD_COUNT; i++)
                if (strcmp(name, ocean_field_name((enum ocean_field)i)) == 0)
                    k = i;
            if (k < 0)
                return fail(e, "bad_subscription", NULL, "unknown field \"%.40s\"", name ? name : "?");
            mask |= OCEAN_FIELD_BIT(k);
        }
        *fields = mask;
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "lod"))) {
        if (!cJSON_IsNumber(j) || j->valuedouble != floor(j->valuedouble) || j->valuedouble < 0 ||
            j->valuedouble > CTL_MAX_LOD)
            return fail(e, "bad_subscription", NULL, "\"lod\" must be an integer 0..%d", CTL_MAX_LOD);
        *lod = (int)j->valuedouble;
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "field_lod"))) {
        /* Per-field LOD (e.g. foam coarser than the heights); replaces the
         * previous map, {} clears it. Fields not named follow "lod". */
        if (!field_lod)
            return fail(e, "bad_subscription", NULL, "\"field_lod\" is a member of the subscription, not of a cascade");
        if (!cJSON_IsObject(j))
            return fail(e, "bad_subscription", NULL, "\"field_lod\" must be an object {\"field\": lod}");
        signed char map[OCEAN_FIELD_COUNT];
        memset(map, -1, sizeof map);
        const cJSON *f;
        cJSON_ArrayForEach(f, j) {
            int k = -1;
            for (int i = 0; f->string && i < OCEAN_FIELD_COUNT; i++)
                if (strcmp(f->string, ocean_field_name((enum ocean_field)i)) == 0)
                    k = i;
            if (k < 0)
                return fail(e, "bad_subscription", NULL, "\"field_lod\": unknown field \"%.40s\"",
                            f->string ? f->string : "?");
            if (!cJSON_IsNumber(f) || f->valuedouble != floor(f->valuedouble) || f->valuedouble < 0 ||
                f->valuedouble > CTL_MAX_LOD)
                return fail(e, "bad_subscription", NULL, "\"field_lod\": the LOD of %s must be an integer 0..%d",
                            ocean_field_name((enum ocean_field)k), CTL_MAX_LOD);
            map[k] = (signed char)f->valuedouble;
        }
        memcpy(field_lod, map, sizeof map);
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "bound"))) {
        int k = -1;
        for (int i = 0; cJSON_IsNumber(j) && i < CTL_BOUND_COUNT; i++)
            if (fabs(j->valuedouble - ctl_bounds[i]) <= 1e-9 + 1e-6 * ctl_bounds[i])
                k = i;
        if (k < 0)
            return fail(e, "bad_subscription", NULL, "\"bound\" must be one of 0, 0.001, 0.005, 0.01, 0.05");
        *bound_index = k;
    }
    return 0;
}

int control_apply_subscribe(const cJSON *msg, const struct subscription *cur, const struct ctl_limits *lim,
                            struct subscription *out, struct ctl_error *e)
{
    struct subscription tmp; /* ~4 KB: fine on the stack */
    memcpy(&tmp, cur, sizeof tmp);
    const cJSON *j;
    if (parse_layer(msg, &tmp.fields, &tmp.lod, tmp.field_lod, &tmp.bound_index, e) != 0)
        return -1;
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "cascades"))) {
        /* The finer cascades 1, 2, ...: each {fields, lod, bound}, any member
         * omitted taken from cascade 0's (the top level's, as now in force). */
        if (!cJSON_IsArray(j) || cJSON_GetArraySize(j) > CTL_MAX_CASCADES - 1)
            return fail(e, "bad_subscription", NULL, "\"cascades\" must be an array of at most %d objects "
                        "{fields, lod, bound} for cascades 1..%d", CTL_MAX_CASCADES - 1, CTL_MAX_CASCADES - 1);
        int c = 1;
        const cJSON *item;
        cJSON_ArrayForEach(item, j) {
            if (!cJSON_IsObject(item))
                return fail(e, "bad_subscription", NULL, "\"cascades\"[%d] must be an object {fields, lod, bound}", c - 1);
            struct cascade_sub cs = {tmp.fields, tmp.lod, tmp.bound_index};
            if (parse_layer(item, &cs.fields, &cs.lod, NULL, &cs.bound_index, e) != 0)
                return -1;
            tmp.cascade[c++] = cs;
        }
        for (int k = c; k < CTL_MAX_CASCADES; k++)
            memset(&tmp.cascade[k], 0, sizeof tmp.cascade[k]);
        tmp.ncascades = c;
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "max_rate"))) {
        if (!cJSON_IsNumber(j) || !isfinite(j->valuedouble) || j->valuedouble <= 0)
            return fail(e, "bad_subscription", NULL, "\"max_rate\" must be a positive number");
        tmp.max_rate = j->valuedouble > lim->tick_rate ? lim->tick_rate : j->valuedouble;
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "temporal"))) {
        if (!cJSON_IsBool(j))
            return fail(e, "bad_subscription", NULL, "\"temporal\" must be true or false");
        tmp.temporal = cJSON_IsTrue(j);
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "codec"))) {
        /* One encoding per layer is shared by every client, so a client
         * cannot pick the entropy coder: codec 1 is the only one to ask for
         * (codec 0 comes with bound 0); zstd (2) is refused, not ignored. */
        if (!cJSON_IsNumber(j) || j->valuedouble != 1)
            return fail(e, "bad_subscription", NULL,
                        "\"codec\": only 1 (DEFLATE) can be asked for; raw float32 is \"bound\":0, "
                        "and this server does not send codec 2 (zstd)");
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "tiles"))) {
        const char *s = cJSON_GetStringValue(j);
        if (s && strcmp(s, "all") == 0) {
            tmp.all_tiles = true;
            tmp.ntiles = 0;
        } else if (cJSON_IsArray(j) && cJSON_GetArraySize(j) > 0 && cJSON_GetArraySize(j) <= CTL_MAX_TILES) {
            /* Duplicates are dropped: the normalised list names each tile at
             * most once, so a subscription never asks for more than the whole
             * grid ("all"), whatever the client lists (tile [0,0] x 1024 would
             * otherwise make every frame 1024 copies of one tile). */
            uint32_t seen[32] = { 0 }; /* bit tx of seen[tz] */
            int k = 0;
            const cJSON *t;
            cJSON_ArrayForEach(t, j) {
                const cJSON *x = cJSON_GetArrayItem(t, 0), *z = cJSON_GetArrayItem(t, 1);
                if (!cJSON_IsArray(t) || cJSON_GetArraySize(t) != 2 || !cJSON_IsNumber(x) || !cJSON_IsNumber(z) ||
                    x->valuedouble != floor(x->valuedouble) || z->valuedouble != floor(z->valuedouble) ||
                    x->valuedouble < 0 || z->valuedouble < 0 || x->valuedouble >= 32 || z->valuedouble >= 32)
                    return fail(e, "bad_subscription", NULL, "\"tiles\" must be \"all\" or [[tx,tz],...] with 0 <= t < 32");
                unsigned tx = (unsigned)x->valuedouble, tz = (unsigned)z->valuedouble;
                if (seen[tz] & (1u << tx))
                    continue;
                seen[tz] |= 1u << tx;
                tmp.tiles[k][0] = (uint16_t)tx;
                tmp.tiles[k][1] = (uint16_t)tz;
                k++;
            }
            tmp.all_tiles = false;
            tmp.ntiles = k;
        } else {
            return fail(e, "bad_subscription", NULL, "\"tiles\" must be \"all\" or a non-empty list of [tx,tz]");
        }
    }
    memcpy(out, &tmp, sizeof tmp);
    return 0;
}

/* ---- builders ---- */

static cJSON *param_value_json(const struct ocean_params *p, const struct param_def *d)
{
    double v = param_get(p, d);
    switch (d->type) {
    case PARAM_ENUM: {
        const char *name = param_enum_name(d, (int)v);
        return cJSON_CreateString(name ? name : "");
    }
    case PARAM_BOOL:
        return cJSON_CreateBool(v != 0);
    default:
        return cJSON_CreateNumber(v);
    }
}

cJSON *control_params_object(const struct ocean_params *p)
{
    cJSON *o = cJSON_CreateObject();
    for (size_t i = 0; i < param_count; i++)
        cJSON_AddItemToObject(o, param_table[i].name, param_value_json(p, &param_table[i]));
    return o;
}

static const char *type_name(enum param_type t)
{
    return t == PARAM_INT ? "int" : t == PARAM_FLOAT ? "float" : t == PARAM_ENUM ? "enum" : "bool";
}

cJSON *control_schema(void)
{
    struct ocean_params defs;
    params_defaults(&defs);
    cJSON *a = cJSON_CreateArray();
    for (size_t i = 0; i < param_count; i++) {
        const struct param_def *d = &param_table[i];
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "name", d->name);
        cJSON_AddStringToObject(o, "type", type_name(d->type));
        cJSON_AddStringToObject(o, "unit", d->unit ? d->unit : "");
        if (d->type == PARAM_INT || d->type == PARAM_FLOAT) {
            cJSON_AddNumberToObject(o, "min", d->min);
            cJSON_AddNumberToObject(o, "max", d->max);
        }
        if (d->type == PARAM_ENUM) {
            cJSON *c = cJSON_AddArrayToObject(o, "choices");
            for (int k = 0; d->choices && d->choices[k]; k++)
                cJSON_AddItemToArray(c, cJSON_CreateString(d->choices[k]));
        }
        cJSON_AddItemToObject(o, "default", param_value_json(&defs, d));
        if (d->flags & PARAM_POW2)
            cJSON_AddTrueToObject(o, "pow2");
        if (d->flags & PARAM_REPLAN)
            cJSON_AddTrueToObject(o, "replan");
        if (d->flags & PARAM_PLAYBACK)
            cJSON_AddTrueToObject(o, "playback");
        cJSON_AddStringToObject(o, "description", d->description ? d->description : "");
        /* For people (the panel): a row without UI text falls back to its name. */
        const struct param_ui *ui = param_ui(d);
        cJSON_AddStringToObject(o, "label", ui ? ui->label : d->name);
        cJSON_AddStringToObject(o, "group", param_group_name(ui ? ui->group : PARAM_GROUP_ADVANCED));
        cJSON_AddStringToObject(o, "help", ui ? ui->help : "");
        cJSON_AddItemToArray(a, o);
    }
    return a;
}

cJSON *control_subscription_object(const struct subscription *s)
{
    cJSON *o = cJSON_CreateObject();
    cJSON *f = cJSON_AddArrayToObject(o, "fields");
    for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
        if (s->fields & OCEAN_FIELD_BIT(i))
            cJSON_AddItemToArray(f, cJSON_CreateString(ocean_field_name((enum ocean_field)i)));
    cJSON_AddNumberToObject(o, "lod", s->lod);
    cJSON *fl = NULL; /* only when some field has its own LOD */
    for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
        if (s->field_lod[i] >= 0) {
            if (!fl)
                fl = cJSON_AddObjectToObject(o, "field_lod");
            cJSON_AddNumberToObject(fl, ocean_field_name((enum ocean_field)i), s->field_lod[i]);
        }
    if (s->all_tiles) {
        cJSON_AddStringToObject(o, "tiles", "all");
    } else {
        /* Printed here, not as cJSON numbers: cJSON 1.7.15 prints every
         * number with %.15g and reads it back with sscanf, so 1024 tiles cost
         * ~0.5 ms per `subscribed` (a stranger's 20 subscribes a second were
         * 10 ms of the service thread). Integers below 32: 8 bytes a tile. */
        char *raw = malloc(8 * (size_t)s->ntiles + 3);
        if (raw) {
            size_t n = 0;
            raw[n++] = '[';
            for (int i = 0; i < s->ntiles; i++)
                n += (size_t)sprintf(raw + n, "%s[%u,%u]", i ? "," : "", (unsigned)s->tiles[i][0] % 100u,
                                     (unsigned)s->tiles[i][1] % 100u);
            raw[n++] = ']';
            raw[n] = 0;
            cJSON_AddRawToObject(o, "tiles", raw);
            free(raw);
        }
    }
    /* Print the bound as the client wrote it (0.01, not 0.00999999977). */
    static const double bound_text[CTL_BOUND_COUNT] = { 0, 0.001, 0.005, 0.01, 0.05 };
    cJSON_AddNumberToObject(o, "bound", bound_text[s->bound_index]);
    cJSON_AddNumberToObject(o, "max_rate", s->max_rate);
    cJSON_AddBoolToObject(o, "temporal", s->temporal);
    if (s->ncascades > 1) { /* only when asked for: a client that knows no cascades sees what it always saw */
        cJSON *cs = cJSON_AddArrayToObject(o, "cascades");
        for (int c = 1; c < s->ncascades && c < CTL_MAX_CASCADES; c++) {
            cJSON *co = cJSON_CreateObject();
            cJSON *cf = cJSON_AddArrayToObject(co, "fields");
            for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
                if (s->cascade[c].fields & OCEAN_FIELD_BIT(i))
                    cJSON_AddItemToArray(cf, cJSON_CreateString(ocean_field_name((enum ocean_field)i)));
            cJSON_AddNumberToObject(co, "lod", s->cascade[c].lod);
            cJSON_AddNumberToObject(co, "bound", bound_text[s->cascade[c].bound_index]);
            cJSON_AddItemToArray(cs, co);
        }
    }
    return o;
}

/* "cascade_patch_sizes": the side of each cascade's patch in force, m. */
static void add_cascade_patches(cJSON *o, const struct ocean_params *p)
{
    cJSON *a = cJSON_AddArrayToObject(o, "cascade_patch_sizes");
    for (int c = 0; c < p->cascades && c < CTL_MAX_CASCADES; c++)
        cJSON_AddItemToArray(a, cJSON_CreateNumber(ocean_cascade_patch(p->patch_size, c)));
}

static void add_id(cJSON *o, const cJSON *id)
{
    if (id)
        cJSON_AddItemToObject(o, "id", cJSON_Duplicate(id, 1));
}

cJSON *control_error_msg(const struct ctl_error *e, const cJSON *id)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "error");
    cJSON_AddStringToObject(o, "code", e->code ? e->code : "internal");
    cJSON_AddStringToObject(o, "message", e->message);
    add_id(o, id);
    if (e->param[0])
        cJSON_AddStringToObject(o, "param", e->param);
    return o;
}

cJSON *control_params_msg(const struct ocean_params *p, uint32_t version, uint64_t changed,
                          const char *by, const cJSON *id)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "params");
    cJSON_AddItemToObject(o, "params", control_params_object(p));
    cJSON_AddNumberToObject(o, "params_version", version);
    add_cascade_patches(o, p);
    cJSON *c = cJSON_AddArrayToObject(o, "changed");
    for (size_t i = 0; i < param_count; i++)
        if (changed & (1ull << i))
            cJSON_AddItemToArray(c, cJSON_CreateString(param_table[i].name));
    if (by)
        cJSON_AddStringToObject(o, "by", by);
    add_id(o, id);
    return o;
}

cJSON *control_subscribed_msg(const struct subscription *s, const cJSON *id)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "subscribed");
    add_id(o, id);
    cJSON_AddItemToObject(o, "subscription", control_subscription_object(s));
    return o;
}

cJSON *control_pong_msg(const cJSON *id, bool has_t, double t, uint64_t server_time_us)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "pong");
    add_id(o, id);
    if (has_t)
        cJSON_AddNumberToObject(o, "t", t);
    /* An exact integer, never "1.7637192001234e+15": cJSON prints numbers
     * as doubles (%.15g/%.17g), so print it ourselves and add it raw. */
    char us[24];
    snprintf(us, sizeof us, "%" PRIu64, server_time_us);
    cJSON_AddRawToObject(o, "server_time_us", us);
    return o;
}

cJSON *control_hello_msg(const struct hello_info *h)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "hello");
    cJSON_AddNumberToObject(o, "protocol", 1);
    cJSON_AddStringToObject(o, "server", "oceand/0.1");
    cJSON_AddStringToObject(o, "client_id", h->client_id);
    cJSON_AddStringToObject(o, "role", h->controller ? "controller" : "viewer");
    cJSON_AddItemToObject(o, "params", control_params_object(h->params));
    cJSON_AddNumberToObject(o, "params_version", h->params_version);
    add_cascade_patches(o, h->params);
    cJSON_AddItemToObject(o, "schema", control_schema());
    cJSON *f = cJSON_AddArrayToObject(o, "fields");
    for (int i = 0; i < OCEAN_FIELD_COUNT; i++)
        cJSON_AddItemToArray(f, cJSON_CreateString(ocean_field_name((enum ocean_field)i)));
    int lods[CTL_MAX_LOD + 1];
    for (int i = 0; i <= CTL_MAX_LOD; i++)
        lods[i] = i;
    cJSON_AddItemToObject(o, "lods", cJSON_CreateIntArray(lods, CTL_MAX_LOD + 1));
    static const double bounds[CTL_BOUND_COUNT] = { 0, 0.001, 0.005, 0.01, 0.05 };
    cJSON_AddItemToObject(o, "bounds", cJSON_CreateDoubleArray(bounds, CTL_BOUND_COUNT));
    cJSON_AddNumberToObject(o, "tick_rate", h->tick_rate);
    cJSON_AddNumberToObject(o, "tile_size", h->tile_size);
    cJSON_AddNumberToObject(o, "ease_ticks", h->ease_ticks);
    cJSON_AddItemToObject(o, "subscription", control_subscription_object(h->sub));
    if (h->capacity)
        cJSON_AddItemToObject(o, "capacity", control_capacity_object(h->capacity));
    return o;
}

cJSON *control_degraded_msg(bool active, int subscribed_lod, int lod, int codec, double rate, const char *reason)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "degraded");
    cJSON_AddBoolToObject(o, "active", active);
    cJSON_AddNumberToObject(o, "subscribed_lod", subscribed_lod);
    cJSON_AddNumberToObject(o, "lod", lod);
    cJSON_AddNumberToObject(o, "codec", codec);
    cJSON_AddNumberToObject(o, "rate", floor(rate * 100 + 0.5) / 100);
    cJSON_AddStringToObject(o, "reason", reason ? reason : "");
    return o;
}

static double round2(double v) { return floor(v * 100 + 0.5) / 100; }

cJSON *control_capacity_object(const struct capacity_info *c)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "max_resolution", c->max_resolution);
    cJSON_AddNumberToObject(o, "memory_cap_mb", c->memory_cap_mb);
    cJSON_AddNumberToObject(o, "cores", c->cores);
    cJSON_AddNumberToObject(o, "tick_ms", round2(c->tick_ms));
    cJSON_AddNumberToObject(o, "budget_ms", round2(c->budget_ms));
    cJSON_AddNumberToObject(o, "encode_budget", (double)c->encode_budget);
    cJSON *a = cJSON_AddArrayToObject(o, "resolutions");
    for (int i = 0; i < c->nsizes && i < CAPACITY_MAX_SIZES; i++) {
        const struct capacity_size *z = &c->sizes[i];
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "n", z->n);
        cJSON_AddBoolToObject(e, "fits_memory", z->fits_memory);
        double ms[6];
        for (int k = 0; k < 6; k++)
            ms[k] = round2(z->est_ms[k]);
        cJSON_AddItemToObject(e, "est_ms", cJSON_CreateDoubleArray(ms, 6));
        for (int k = 0; k < 6; k++)
            ms[k] = round2(z->est_intra_ms[k]);
        cJSON_AddItemToObject(e, "est_intra_ms", cJSON_CreateDoubleArray(ms, 6));
        cJSON_AddNumberToObject(e, "full_rate_fields", z->full_rate_fields);
        cJSON_AddNumberToObject(e, "temporal_fields", z->temporal_fields);
        cJSON_AddItemToArray(a, e);
    }
    return o;
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

/* Characters a name may not hold although they are valid UTF-8: controls,
 * and the invisible ones that could make a name look like another or
 * reorder the text around it. */
static bool name_char_refused(uint32_t c)
{
    return c < 0x20 || (c >= 0x7f && c < 0xa0) || c == 0xad || (c >= 0x200b && c <= 0x200f) ||
           (c >= 0x2028 && c <= 0x202e) || (c >= 0x2060 && c <= 0x206f) || c == 0xfeff ||
           (c >= 0xe000 && c <= 0xf8ff) || (c >= 0xfff0 && c <= 0xffff) || (c & 0xfffe) == 0xfffe ||
           (c >= 0xfdd0 && c <= 0xfdef) || c >= 0xf0000;
}

int control_check_name(const char *s, struct ctl_error *e)
{
    const unsigned char *p = (const unsigned char *)s;
    size_t chars = 0;
    uint32_t c = 0;
    while (*p) {
        int len = utf8_next(p, &c);
        if (!len)
            return fail(e, "bad_name", NULL, "name is not valid UTF-8 (byte %zu)", (size_t)(p - (const unsigned char *)s));
        if (++chars > CTL_NAME_MAX_CHARS)
            return fail(e, "bad_name", NULL, "name longer than %d characters", CTL_NAME_MAX_CHARS);
        if (c < 0x80 && strchr("<>&\"'", (int)c))
            return fail(e, "bad_name", NULL, "name may not contain %c (no markup: < > & \" ')", (int)c);
        if (name_char_refused(c))
            return fail(e, "bad_name", NULL, "name may not contain U+%04X (control or invisible character)", (unsigned)c);
        if (chars == 1 && c == ' ')
            return fail(e, "bad_name", NULL, "name may not start with a space");
        p += len;
    }
    if (chars && c == ' ')
        return fail(e, "bad_name", NULL, "name may not end with a space");
    return 0;
}

cJSON *control_named_msg(const char *name, const cJSON *id)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "named");
    add_id(o, id);
    cJSON_AddStringToObject(o, "name", name);
    return o;
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

char *control_print(cJSON *msg)
{
    char *s = msg ? cJSON_PrintUnformatted(msg) : NULL;
    cJSON_Delete(msg);
    return s;
}

/* body_msg.c — parse the body requests, build the body messages
 * (body_msg.h, PROTOCOL.md §7.6). */
#include "body_msg.h"
#include "control_internal.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static const char *const hull_names[] = { "cylinder", "sphere", "box", "ship" };

int body_kind_index(const struct body_kind *k)
{
    const struct body_kind *t = body_kinds();
    for (int i = 0; i < BODY_KIND_COUNT; i++)
        if (&t[i] == k)
            return i;
    return -1;
}

/* A required or optional number member: bad_message when required and
 * missing, bad_type when not a finite number. 1 = present, 0 = absent. */
static int number(const cJSON *root, const char *name, bool required, double *out, struct ctl_error *e)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(root, name);
    if (!v) {
        if (required)
            return ctl_fail(e, "bad_message", name, "\"%s\" is required (a number)", name);
        return 0;
    }
    if (!cJSON_IsNumber(v))
        return ctl_fail(e, "bad_type", name, "\"%s\" must be a number", name);
    if (!isfinite(v->valuedouble))
        return ctl_fail(e, "bad_type", name, "\"%s\" is not finite", name);
    *out = v->valuedouble;
    return 1;
}

/* "body": a whole number 1..2^32-1. */
static int body_id(const cJSON *root, uint32_t *out, struct ctl_error *e)
{
    double v = 0;
    int rc = number(root, "body", true, &v, e);
    if (rc < 0)
        return -1;
    if (v != floor(v))
        return ctl_fail(e, "bad_type", "body", "\"body\" must be a whole number (a body id)");
    if (v < 1 || v > (double)UINT32_MAX)
        return ctl_fail(e, "out_of_range", "body", "\"body\" must be a body id, 1..%u", UINT32_MAX);
    *out = (uint32_t)v;
    return 0;
}

/* Throttle or rudder: optional, -1..1. */
static int steering(const cJSON *root, const char *name, bool *has, double *out, struct ctl_error *e)
{
    int rc = number(root, name, false, out, e);
    if (rc < 0)
        return -1;
    *has = rc == 1;
    if (*has && (*out < -1 || *out > 1))
        return ctl_fail(e, "out_of_range", name, "\"%s\" %g is outside [-1, 1]", name, *out);
    return 0;
}

static int launch(const cJSON *root, struct body_req *r, struct ctl_error *e)
{
    const cJSON *kind = cJSON_GetObjectItemCaseSensitive(root, "kind");
    if (!kind)
        return ctl_fail(e, "bad_message", "kind", "\"launch\" needs a \"kind\" (a name from hello.body_kinds)");
    if (!cJSON_IsString(kind))
        return ctl_fail(e, "bad_type", "kind", "\"kind\" must be a string");
    r->kind = body_kind_find(kind->valuestring);
    if (!r->kind || body_kind_index(r->kind) < 0)
        return ctl_fail(e, "unknown_kind", "kind", "no body kind \"%.40s\" (hello.body_kinds lists them)",
                        kind->valuestring);
    if (number(root, "x", true, &r->x, e) < 0 || number(root, "z", true, &r->z, e) < 0)
        return -1;
    if (fabs(r->x) > BODY_WORLD_HALF_M || fabs(r->z) > BODY_WORLD_HALF_M)
        return ctl_fail(e, "out_of_range", fabs(r->x) > BODY_WORLD_HALF_M ? "x" : "z",
                        "(%g, %g) is outside the world: |x| and |z| at most %g m", r->x, r->z, BODY_WORLD_HALF_M);
    if (number(root, "heading", false, &r->heading, e) < 0)
        return -1;
    /* Any finite bearing names a direction: folded into [0, 360). */
    r->heading = fmod(r->heading, 360.0);
    if (r->heading < 0)
        r->heading += 360.0;
    if (r->heading >= 360.0)
        r->heading = 0;
    return 0;
}

static int resume_key(const cJSON *root, char out[BODY_RESUME_CHARS + 1], struct ctl_error *e)
{
    const cJSON *k = cJSON_GetObjectItemCaseSensitive(root, "resume");
    const char *s = cJSON_GetStringValue(k);
    bool ok = s && strlen(s) == BODY_RESUME_CHARS;
    for (int i = 0; ok && i < BODY_RESUME_CHARS; i++)
        ok = (s[i] >= '0' && s[i] <= '9') || (s[i] >= 'a' && s[i] <= 'f');
    if (!ok)
        return ctl_fail(e, "bad_message", "resume", "\"resume\" must be the %d hex digits `launched` gave",
                        BODY_RESUME_CHARS);
    memcpy(out, s, BODY_RESUME_CHARS + 1);
    return 0;
}

int body_parse(const cJSON *root, enum ctl_type type, struct body_req *r, struct ctl_error *e)
{
    memset(r, 0, sizeof *r);
    r->type = type;
    const cJSON *tok = cJSON_GetObjectItemCaseSensitive(root, "token");
    if (tok && !cJSON_IsString(tok))
        return ctl_fail(e, "bad_message", "token", "\"token\" must be a string");
    r->token = cJSON_GetStringValue(tok);
    switch (type) {
    case CTL_LAUNCH:
        return launch(root, r, e);
    case CTL_STEER:
        if (body_id(root, &r->body, e) < 0 || steering(root, "throttle", &r->has_throttle, &r->throttle, e) < 0 ||
            steering(root, "rudder", &r->has_rudder, &r->rudder, e) < 0)
            return -1;
        return 0;
    case CTL_REMOVE:
        return body_id(root, &r->body, e);
    case CTL_CLAIM:
        if (body_id(root, &r->body, e) < 0)
            return -1;
        return resume_key(root, r->resume, e);
    default:
        return ctl_fail(e, "bad_message", NULL, "not a body request");
    }
}

static cJSON *typed(const char *type, const cJSON *id)
{
    cJSON *m = cJSON_CreateObject();
    cJSON_AddStringToObject(m, "type", type);
    if (id)
        cJSON_AddItemToObject(m, "id", cJSON_Duplicate(id, 1));
    return m;
}

cJSON *body_launched_msg(const cJSON *id, uint32_t body, const char *resume)
{
    cJSON *m = typed("launched", id);
    cJSON_AddNumberToObject(m, "body", body);
    cJSON_AddStringToObject(m, "resume", resume);
    return m;
}

cJSON *body_ack_msg(const char *type, const cJSON *id, uint32_t body)
{
    cJSON *m = typed(type, id);
    cJSON_AddNumberToObject(m, "body", body);
    return m;
}

cJSON *body_list_array(int n, const struct body_entry *b)
{
    cJSON *arr = cJSON_CreateArray();
    for (int i = 0; i < n; i++) {
        cJSON *o = cJSON_CreateObject();
        cJSON_AddNumberToObject(o, "body", b[i].body);
        cJSON_AddStringToObject(o, "kind", b[i].kind ? b[i].kind->name : "");
        cJSON_AddStringToObject(o, "owner", b[i].owner ? b[i].owner : "");
        cJSON_AddStringToObject(o, "name", b[i].name ? b[i].name : "");
        cJSON_AddBoolToObject(o, "adrift", b[i].adrift);
        cJSON_AddItemToArray(arr, o);
    }
    return arr;
}

cJSON *bodies_msg(uint64_t seq, int n, const struct body_entry *b, int ngone, const struct body_gone_entry *g)
{
    cJSON *m = typed("bodies", NULL);
    cJSON_AddNumberToObject(m, "seq", (double)seq);
    cJSON_AddItemToObject(m, "bodies", body_list_array(n, b));
    cJSON *gone = cJSON_AddArrayToObject(m, "removed");
    for (int i = 0; i < ngone; i++) {
        cJSON *o = cJSON_CreateObject();
        cJSON_AddNumberToObject(o, "body", g[i].body);
        cJSON_AddStringToObject(o, "reason", g[i].reason);
        cJSON_AddItemToArray(gone, o);
    }
    return m;
}

cJSON *body_kinds_array(void)
{
    cJSON *arr = cJSON_CreateArray();
    const struct body_kind *t = body_kinds();
    for (int i = 0; i < BODY_KIND_COUNT; i++) {
        const struct body_kind *k = &t[i];
        cJSON *o = cJSON_CreateObject();
        cJSON_AddStringToObject(o, "name", k->name);
        cJSON_AddStringToObject(o, "label", k->label);
        cJSON_AddStringToObject(o, "description", k->description);
        cJSON_AddStringToObject(o, "hull", (unsigned)k->hull < 4 ? hull_names[k->hull] : "unknown");
        cJSON_AddNumberToObject(o, "length", k->length);
        cJSON_AddNumberToObject(o, "beam", k->beam);
        cJSON_AddNumberToObject(o, "height", k->height);
        cJSON_AddNumberToObject(o, "mass", k->mass);
        cJSON_AddNumberToObject(o, "draft", k->draft);
        cJSON_AddNumberToObject(o, "kg", body_kind_kg(k));
        cJSON_AddBoolToObject(o, "powered", k->powered);
        cJSON_AddNumberToObject(o, "top_speed", k->top_speed);
        cJSON_AddNumberToObject(o, "turning_diameter", k->turning_diameter);
        cJSON_AddItemToArray(arr, o);
    }
    return arr;
}

cJSON *body_limits_object(const struct body_limits *l)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "per_session", l->per_session);
    cJSON_AddNumberToObject(o, "max_bodies", l->max_bodies);
    cJSON_AddNumberToObject(o, "launch_rate", l->launch_rate);
    cJSON_AddNumberToObject(o, "grace", l->grace_s);
    return o;
}

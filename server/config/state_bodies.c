/* state_bodies.c — the floating bodies in the state file (state.h):
 *   "bodies": {"next_id": 13, "list": [{"id": 12, "kind": "boat",
 *     "pos": [x, y, z], "quat": [w, x, y, z], "vel": [...], "omega": [...],
 *     "throttle": t, "rudder": r, "owner": "c7-k3qf", "name": "Ana",
 *     "resume": "<32 hex digits>"}, ...]}
 * Doubles are written as %.17g, so a restart continues the same motion bit
 * for bit. The loader is strict: one bad entry refuses them all. */
#include "state.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fileio.h"

#define STATE_MAX_BYTES (1u << 20) /* as state.c: ~300 bytes a body, 1024 bodies at most */

void state_bodies_free(struct state_bodies *b)
{
    free(b->b);
    *b = (struct state_bodies){ 0 };
}

int state_bodies_copy(struct state_bodies *dst, const struct state_bodies *src)
{
    if (src->n > dst->cap) {
        struct state_body *nb = realloc(dst->b, (size_t)src->n * sizeof *nb);
        if (!nb)
            return -1;
        dst->b = nb;
        dst->cap = src->n;
    }
    if (src->n)
        memcpy(dst->b, src->b, (size_t)src->n * sizeof *dst->b);
    dst->n = src->n;
    dst->next_id = src->next_id;
    return 0;
}

static cJSON *exact(double v)
{
    char buf[32];
    snprintf(buf, sizeof buf, "%.17g", v);
    return cJSON_CreateRaw(buf);
}

static cJSON *exact_array(const double *v, int n)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; i < n; i++)
        cJSON_AddItemToArray(a, exact(v[i]));
    return a;
}

cJSON *state_bodies_json(const struct state_bodies *b)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "next_id", (double)b->next_id);
    cJSON *list = cJSON_AddArrayToObject(o, "list");
    for (int i = 0; i < b->n; i++) {
        const struct state_body *e = &b->b[i];
        cJSON *j = cJSON_CreateObject();
        cJSON_AddNumberToObject(j, "id", e->st.id);
        cJSON_AddStringToObject(j, "kind", e->st.kind->name);
        cJSON_AddItemToObject(j, "pos", exact_array(e->st.pos, 3));
        cJSON_AddItemToObject(j, "quat", exact_array(e->st.quat, 4));
        cJSON_AddItemToObject(j, "vel", exact_array(e->st.vel, 3));
        cJSON_AddItemToObject(j, "omega", exact_array(e->st.omega, 3));
        cJSON_AddItemToObject(j, "throttle", exact(e->st.control.throttle));
        cJSON_AddItemToObject(j, "rudder", exact(e->st.control.rudder));
        cJSON_AddStringToObject(j, "owner", e->owner);
        cJSON_AddStringToObject(j, "name", e->name);
        cJSON_AddStringToObject(j, "resume", e->resume);
        if (e->origin[0])
            cJSON_AddStringToObject(j, "origin", e->origin);
        cJSON_AddItemToArray(list, j);
    }
    return o;
}

static int bad(char *err, size_t errlen, int i, const char *fmt, ...) __attribute__((format(printf, 4, 5)));
static int bad(char *err, size_t errlen, int i, const char *fmt, ...)
{
    char what[200];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    if (i >= 0)
        snprintf(err, errlen, "bad_body: bodies.list[%d]: %s", i, what);
    else
        snprintf(err, errlen, "bad_body: bodies: %s", what);
    return -1;
}

/* An array of exactly n finite numbers. */
static bool numbers(const cJSON *a, int n, double *out)
{
    if (!cJSON_IsArray(a) || cJSON_GetArraySize(a) != n)
        return false;
    int i = 0;
    const cJSON *v;
    cJSON_ArrayForEach(v, a)
    {
        if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble))
            return false;
        out[i++] = v->valuedouble;
    }
    return true;
}

static bool whole(const cJSON *v, double lo, double hi)
{
    return cJSON_IsNumber(v) && v->valuedouble >= lo && v->valuedouble <= hi && v->valuedouble == floor(v->valuedouble);
}

static int entry(const cJSON *j, int i, struct state_body *e, char *err, size_t errlen)
{
    memset(e, 0, sizeof *e);
    if (!cJSON_IsObject(j))
        return bad(err, errlen, i, "not an object");
    const cJSON *id = cJSON_GetObjectItemCaseSensitive(j, "id");
    if (!whole(id, 1, UINT32_MAX))
        return bad(err, errlen, i, "\"id\" must be a whole number 1..%u", UINT32_MAX);
    e->st.id = (uint32_t)id->valuedouble;
    const char *kind = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(j, "kind"));
    if (!kind || !(e->st.kind = body_kind_find(kind)))
        return bad(err, errlen, i, "\"kind\" is not a kind of the table");
    if (!numbers(cJSON_GetObjectItemCaseSensitive(j, "pos"), 3, e->st.pos) ||
        !numbers(cJSON_GetObjectItemCaseSensitive(j, "quat"), 4, e->st.quat) ||
        !numbers(cJSON_GetObjectItemCaseSensitive(j, "vel"), 3, e->st.vel) ||
        !numbers(cJSON_GetObjectItemCaseSensitive(j, "omega"), 3, e->st.omega))
        return bad(err, errlen, i, "\"pos\", \"quat\", \"vel\" and \"omega\" must be arrays of 3, 4, 3 and 3 finite numbers");
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(j, "throttle"), *r = cJSON_GetObjectItemCaseSensitive(j, "rudder");
    if (!cJSON_IsNumber(t) || !cJSON_IsNumber(r) || !(fabs(t->valuedouble) <= 1) || !(fabs(r->valuedouble) <= 1))
        return bad(err, errlen, i, "\"throttle\" and \"rudder\" must be numbers in [-1, 1]");
    e->st.control = (struct body_control){ t->valuedouble, r->valuedouble };
    const char *owner = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(j, "owner"));
    bool ok = owner && strlen(owner) < sizeof e->owner;
    for (size_t k = 0; ok && owner[k]; k++)
        ok = owner[k] > 0x20 && owner[k] < 0x7f;
    if (!ok)
        return bad(err, errlen, i, "\"owner\" must be a client id (printable ASCII, at most %zu bytes)",
                   sizeof e->owner - 1);
    snprintf(e->owner, sizeof e->owner, "%s", owner);
    const char *name = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(j, "name"));
    struct ctl_error ce;
    if (!name || control_check_name(name, &ce) != 0)
        return bad(err, errlen, i, "\"name\" must be a display name (PROTOCOL.md §7.1 `name`)");
    snprintf(e->name, sizeof e->name, "%s", name);
    const char *resume = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(j, "resume"));
    ok = resume && strlen(resume) == 32;
    for (int k = 0; ok && k < 32; k++)
        ok = (resume[k] >= '0' && resume[k] <= '9') || (resume[k] >= 'a' && resume[k] <= 'f');
    if (!ok)
        return bad(err, errlen, i, "\"resume\" must be 32 lowercase hex digits");
    memcpy(e->resume, resume, 33);
    const cJSON *origin = cJSON_GetObjectItemCaseSensitive(j, "origin");
    const char *o = cJSON_GetStringValue(origin);
    ok = !origin || (o && strlen(o) < sizeof e->origin);
    for (size_t k = 0; ok && o && o[k]; k++)
        ok = o[k] > 0x20 && o[k] < 0x7f;
    if (!ok)
        return bad(err, errlen, i, "\"origin\" must be an edge's name (printable ASCII, at most %zu bytes)",
                   sizeof e->origin - 1);
    if (o)
        snprintf(e->origin, sizeof e->origin, "%s", o);
    return 0;
}

int state_load_bodies(const char *path, struct state_bodies *out, char *err, size_t errlen)
{
    *out = (struct state_bodies){ 0 };
    char *buf;
    size_t len;
    int rc = file_read_all(path, STATE_MAX_BYTES, &buf, &len, err, errlen);
    if (rc == -1 && errno == ENOENT)
        return 0;
    if (rc != 0)
        return 0; /* state_load reported the file already */
    cJSON *root = cJSON_ParseWithLength(buf, len);
    free(buf);
    const cJSON *bodies = cJSON_GetObjectItemCaseSensitive(root, "bodies");
    if (!bodies) {
        cJSON_Delete(root);
        return 0;
    }
    rc = state_bodies_parse(bodies, out, err, errlen);
    cJSON_Delete(root);
    return rc == 0 ? 1 : -1;
}

int state_bodies_parse(const cJSON *bodies, struct state_bodies *out, char *err, size_t errlen)
{
    *out = (struct state_bodies){ 0 };
    int rc;
    const cJSON *next = cJSON_GetObjectItemCaseSensitive(bodies, "next_id");
    const cJSON *list = cJSON_GetObjectItemCaseSensitive(bodies, "list");
    if (!cJSON_IsObject(bodies) || !whole(next, 1, (double)STATE_IDS_EXHAUSTED) || !cJSON_IsArray(list))
        return bad(err, errlen, -1, "must be {\"next_id\": 1..2^32, \"list\": [...]}");
    int n = cJSON_GetArraySize(list);
    struct state_bodies b = { .next_id = (uint64_t)next->valuedouble };
    if (n > 0 && !(b.b = calloc((size_t)n, sizeof *b.b))) {
        snprintf(err, errlen, "bad_body: out of memory");
        return -1;
    }
    b.cap = n;
    const cJSON *j;
    rc = 0;
    cJSON_ArrayForEach(j, list)
    {
        if (entry(j, b.n, &b.b[b.n], err, errlen) != 0) {
            rc = -1;
            break;
        }
        for (int k = 0; k < b.n; k++)
            if (b.b[k].st.id == b.b[b.n].st.id) {
                rc = bad(err, errlen, b.n, "id %u appears twice", b.b[b.n].st.id);
                break;
            }
        if (rc < 0)
            break;
        if (b.b[b.n].st.id >= b.next_id) /* ids only grow: the next is past every saved one */
            b.next_id = (uint64_t)b.b[b.n].st.id + 1;
        b.n++;
    }
    if (rc < 0) {
        state_bodies_free(&b);
        return -1;
    }
    *out = b;
    return 0;
}

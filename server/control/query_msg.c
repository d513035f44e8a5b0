/* query_msg.c — parse `query` / `probe`, build `query_result`, `probe_data`
 * and `probing` (query_msg.h, PROTOCOL.md §7.4). */
#include "query_msg.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int fail(struct ctl_error *e, const char *code, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static int fail(struct ctl_error *e, const char *code, const char *fmt, ...)
{
    va_list ap;
    e->code = code;
    e->param[0] = '\0';
    va_start(ap, fmt);
    vsnprintf(e->message, sizeof e->message, fmt, ap);
    va_end(ap);
    return -1;
}

/* "points": [[x, z], ...], 1..max entries (0 allowed when allow_empty),
 * each exactly two finite numbers. code is the message's error code. */
static int parse_points(const cJSON *root, const char *code, int max, bool allow_empty, double (*xz)[2], int *n,
                        struct ctl_error *e)
{
    const cJSON *pts = cJSON_GetObjectItemCaseSensitive(root, "points");
    if (!cJSON_IsArray(pts))
        return fail(e, code, "\"points\" must be an array of [x, z] pairs");
    int count = cJSON_GetArraySize(pts);
    if (count > max)
        return fail(e, "too_many_points", "%d points; at most %d", count, max);
    if (count == 0 && !allow_empty)
        return fail(e, code, "\"points\" is empty");
    int i = 0;
    const cJSON *p;
    cJSON_ArrayForEach(p, pts)
    {
        const cJSON *x = cJSON_GetArrayItem(p, 0), *z = cJSON_GetArrayItem(p, 1);
        if (!cJSON_IsArray(p) || cJSON_GetArraySize(p) != 2 || !cJSON_IsNumber(x) || !cJSON_IsNumber(z))
            return fail(e, code, "point %d must be [x, z], two numbers", i);
        if (!isfinite(x->valuedouble) || !isfinite(z->valuedouble))
            return fail(e, code, "point %d is not finite", i);
        xz[i][0] = x->valuedouble;
        xz[i][1] = z->valuedouble;
        i++;
    }
    *n = i;
    return 0;
}

int query_parse(const cJSON *root, struct query_req *q, struct ctl_error *e)
{
    q->n = 0;
    q->has_time = false;
    q->time = 0;
    if (parse_points(root, "bad_query", QUERY_MAX_POINTS, false, q->xz, &q->n, e) != 0)
        return -1;
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "time");
    if (t && !cJSON_IsNull(t)) {
        if (!cJSON_IsNumber(t))
            return fail(e, "bad_query", "\"time\" must be a number (s of sim time)");
        if (!isfinite(t->valuedouble))
            return fail(e, "bad_query", "\"time\" is not finite");
        q->has_time = true;
        q->time = t->valuedouble;
    }
    return 0;
}

int probe_parse(const cJSON *root, int max_points, struct probe_req *p, struct ctl_error *e)
{
    p->n = 0;
    if (max_points > PROBE_MAX_POINTS)
        max_points = PROBE_MAX_POINTS;
    return parse_points(root, "bad_probe", max_points, true, p->xz, &p->n, e);
}

static cJSON *pair(double a, double b)
{
    double v[2] = { a, b };
    return cJSON_CreateDoubleArray(v, 2);
}

cJSON *query_result_msg(const cJSON *id, double sim_time, uint32_t params_version, int n,
                        const struct ocean_point *pts)
{
    cJSON *m = cJSON_CreateObject();
    cJSON_AddStringToObject(m, "type", "query_result");
    if (id)
        cJSON_AddItemToObject(m, "id", cJSON_Duplicate(id, 1));
    cJSON_AddNumberToObject(m, "sim_time", sim_time);
    cJSON_AddNumberToObject(m, "params_version", params_version);
    cJSON *arr = cJSON_AddArrayToObject(m, "points");
    for (int i = 0; i < n; i++) {
        const struct ocean_point *p = &pts[i];
        cJSON *o = cJSON_CreateObject();
        cJSON_AddNumberToObject(o, "height", p->height);
        cJSON_AddItemToObject(o, "displacement", pair(p->displacement[0], p->displacement[1]));
        cJSON_AddItemToObject(o, "normal", cJSON_CreateDoubleArray(p->normal, 3));
        cJSON_AddNumberToObject(o, "vertical_velocity", p->vertical_velocity);
        cJSON_AddNumberToObject(o, "vertical_acceleration", p->vertical_acceleration);
        cJSON_AddItemToObject(o, "source", pair(p->source[0], p->source[1]));
        cJSON_AddNumberToObject(o, "jacobian", p->jacobian);
        cJSON_AddBoolToObject(o, "converged", p->converged != 0);
        cJSON_AddItemToArray(arr, o);
    }
    return m;
}

char *probe_data_text(uint64_t seq, double sim_time, uint32_t params_version, int n, const struct probe_value *v)
{
    /* Built with snprintf, not cJSON: one per client per tick, and fixed
     * decimals (0.1 mm, 1e-5) keep it short. ~70 bytes per point. */
    size_t cap = 128 + (size_t)n * 96;
    char *buf = malloc(cap);
    if (!buf)
        return NULL;
    int len = snprintf(buf, cap, "{\"type\":\"probe_data\",\"seq\":%llu,\"sim_time\":%.17g,\"params_version\":%u,\"points\":[",
                       (unsigned long long)seq, sim_time, params_version);
    for (int i = 0; i < n && len > 0 && (size_t)len < cap; i++) {
        const struct probe_value *p = &v[i];
        len += snprintf(buf + len, cap - (size_t)len, "%s[%.4f,%.4f,%.4f,%.5f,%.5f,%.5f,%.4f,%.4f]", i ? "," : "",
                        p->height, p->dx, p->dz, p->normal[0], p->normal[1], p->normal[2], p->vertical_velocity,
                        p->vertical_acceleration);
    }
    if (len < 0 || (size_t)len + 3 > cap) {
        free(buf);
        return NULL;
    }
    memcpy(buf + len, "]}", 3);
    return buf;
}

cJSON *probing_msg(const cJSON *id, int n, const double (*xz)[2])
{
    cJSON *m = cJSON_CreateObject();
    cJSON_AddStringToObject(m, "type", "probing");
    if (id)
        cJSON_AddItemToObject(m, "id", cJSON_Duplicate(id, 1));
    cJSON *arr = cJSON_AddArrayToObject(m, "points");
    for (int i = 0; i < n; i++)
        cJSON_AddItemToArray(arr, pair(xz[i][0], xz[i][1]));
    return m;
}

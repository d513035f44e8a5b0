/* replies.c — the JSON messages the daemon sends (PROTOCOL.md §7):
 * hello, params, errors, pong, degraded, capacity, named. */
#include "control.h"

#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "control_internal.h"
#include "layer_key.h"
#include "oc_proto.h"
#include "ocean.h"

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

cJSON *control_pong_msg(const cJSON *id, const cJSON *t, uint64_t server_time_us)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "pong");
    add_id(o, id);
    if (t)
        cJSON_AddItemToObject(o, "t", cJSON_Duplicate(t, 1));
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
    cJSON_AddItemToObject(o, "sea", h->sea ? cJSON_CreateRaw(h->sea) : cJSON_CreateNull()); /* PROTOCOL.md §7.8 */
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

cJSON *control_named_msg(const char *name, const cJSON *id)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "named");
    add_id(o, id);
    cJSON_AddStringToObject(o, "name", name);
    return o;
}

char *control_print(cJSON *msg)
{
    char *s = msg ? cJSON_PrintUnformatted(msg) : NULL;
    cJSON_Delete(msg);
    return s;
}

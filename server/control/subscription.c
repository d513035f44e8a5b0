/* subscription.c — what a client subscribes to (PROTOCOL.md §6): defaults,
 * the `subscribe` message checked onto a subscription, its echo, and the
 * layer keys it asks for. */
#include "control.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "control_internal.h"
#include "layer_key.h"
#include "oc_proto.h"
#include "ocean.h"

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

void subscription_none(struct subscription *s)
{
    s->fields = 0;
    s->ncascades = 1;
    memset(&s->cascade[1], 0, sizeof s->cascade - sizeof s->cascade[0]);
}

bool subscription_has_frames(const struct subscription *s)
{
    int lod, bound_index;
    for (int c = 0; c < s->ncascades && c < CTL_MAX_CASCADES; c++)
        if (subscription_cascade(s, c, &lod, &bound_index))
            return true;
    return false;
}

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

/* fields, lod and bound of a subscription (or of one cascade of it): the
 * members given replace *fields, *lod, *bound_index; field_lod (cascade 0
 * only, else NULL) the per-field LODs. */
static int parse_layer(const cJSON *msg, unsigned *fields, int *lod, signed char field_lod[OCEAN_FIELD_COUNT],
                       int *bound_index, struct ctl_error *e)
{
    const cJSON *j;
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "fields"))) {
        /* [] is "no frames" at the top level (control_apply_subscribe), never in a cascade. */
        if (!cJSON_IsArray(j) || (cJSON_GetArraySize(j) == 0 && !field_lod))
            return ctl_fail(e, "bad_subscription", NULL, "\"fields\" must be a non-empty array of names");
        unsigned mask = 0;
        const cJSON *f;
        cJSON_ArrayForEach(f, j) {
            const char *name = cJSON_GetStringValue(f);
            int k = -1;
            for (int i = 0; name && i < OCEAN_FIELD_COUNT; i++)
                if (strcmp(name, ocean_field_name((enum ocean_field)i)) == 0)
                    k = i;
            if (k < 0)
                return ctl_fail(e, "bad_subscription", NULL, "unknown field \"%.40s\"", name ? name : "?");
            mask |= OCEAN_FIELD_BIT(k);
        }
        *fields = mask;
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "lod"))) {
        if (!cJSON_IsNumber(j) || j->valuedouble != floor(j->valuedouble) || j->valuedouble < 0 ||
            j->valuedouble > CTL_MAX_LOD)
            return ctl_fail(e, "bad_subscription", NULL, "\"lod\" must be an integer 0..%d", CTL_MAX_LOD);
        *lod = (int)j->valuedouble;
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "field_lod"))) {
        /* Per-field LOD (e.g. foam coarser than the heights); replaces the
         * previous map, {} clears it. Fields not named follow "lod". */
        if (!field_lod)
            return ctl_fail(e, "bad_subscription", NULL, "\"field_lod\" is a member of the subscription, not of a cascade");
        if (!cJSON_IsObject(j))
            return ctl_fail(e, "bad_subscription", NULL, "\"field_lod\" must be an object {\"field\": lod}");
        signed char map[OCEAN_FIELD_COUNT];
        memset(map, -1, sizeof map);
        const cJSON *f;
        cJSON_ArrayForEach(f, j) {
            int k = -1;
            for (int i = 0; f->string && i < OCEAN_FIELD_COUNT; i++)
                if (strcmp(f->string, ocean_field_name((enum ocean_field)i)) == 0)
                    k = i;
            if (k < 0)
                return ctl_fail(e, "bad_subscription", NULL, "\"field_lod\": unknown field \"%.40s\"",
                            f->string ? f->string : "?");
            if (!cJSON_IsNumber(f) || f->valuedouble != floor(f->valuedouble) || f->valuedouble < 0 ||
                f->valuedouble > CTL_MAX_LOD)
                return ctl_fail(e, "bad_subscription", NULL, "\"field_lod\": the LOD of %s must be an integer 0..%d",
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
            return ctl_fail(e, "bad_subscription", NULL, "\"bound\" must be one of 0, 0.001, 0.005, 0.01, 0.05");
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
    /* "fields": [] subscribes to no frames at all: a session for control
     * messages only (a second connection that keeps replies off the frame
     * stream's TCP queue, PROTOCOL.md §1.2). No finer cascade then either. */
    if (!tmp.fields && cJSON_GetObjectItemCaseSensitive(msg, "cascades"))
        return ctl_fail(e, "bad_subscription", NULL, "\"cascades\" need top-level \"fields\": with \"fields\": [] there are no frames");
    if (!tmp.fields)
        subscription_none(&tmp);
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "cascades"))) {
        /* The finer cascades 1, 2, ...: each {fields, lod, bound}, any member
         * omitted taken from cascade 0's (the top level's, as now in force). */
        if (!cJSON_IsArray(j) || cJSON_GetArraySize(j) > CTL_MAX_CASCADES - 1)
            return ctl_fail(e, "bad_subscription", NULL, "\"cascades\" must be an array of at most %d objects "
                        "{fields, lod, bound} for cascades 1..%d", CTL_MAX_CASCADES - 1, CTL_MAX_CASCADES - 1);
        int c = 1;
        const cJSON *item;
        cJSON_ArrayForEach(item, j) {
            if (!cJSON_IsObject(item))
                return ctl_fail(e, "bad_subscription", NULL, "\"cascades\"[%d] must be an object {fields, lod, bound}", c - 1);
            /* Foam is one field of the whole sea, made for cascade 0 only: a
             * finer cascade's frame never has it, and a client whose layers
             * a frame lacks gets no frame at all (not even cascade 0's).
             * Named, it is refused; inherited from the top level, left out. */
            struct cascade_sub cs = {tmp.fields & ~OCEAN_FIELD_BIT(OCEAN_FOAM), tmp.lod, tmp.bound_index};
            if (parse_layer(item, &cs.fields, &cs.lod, NULL, &cs.bound_index, e) != 0)
                return -1;
            if (cs.fields & OCEAN_FIELD_BIT(OCEAN_FOAM))
                return ctl_fail(e, "bad_subscription", NULL, "\"cascades\"[%d]: foam exists for cascade 0 only "
                                "(the top-level \"fields\"), not for cascade %d", c - 1, c);
            if (!cs.fields)
                return ctl_fail(e, "bad_subscription", NULL, "\"cascades\"[%d] has no fields: foam, the only one "
                                "inherited from the top level, exists for cascade 0 only", c - 1);
            tmp.cascade[c++] = cs;
        }
        for (int k = c; k < CTL_MAX_CASCADES; k++)
            memset(&tmp.cascade[k], 0, sizeof tmp.cascade[k]);
        tmp.ncascades = c;
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "max_rate"))) {
        if (!cJSON_IsNumber(j) || !isfinite(j->valuedouble) || j->valuedouble <= 0)
            return ctl_fail(e, "bad_subscription", NULL, "\"max_rate\" must be a positive number");
        tmp.max_rate = j->valuedouble > lim->tick_rate ? lim->tick_rate : j->valuedouble;
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "temporal"))) {
        if (!cJSON_IsBool(j))
            return ctl_fail(e, "bad_subscription", NULL, "\"temporal\" must be true or false");
        tmp.temporal = cJSON_IsTrue(j);
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "adapt"))) {
        if (!cJSON_IsBool(j))
            return ctl_fail(e, "bad_subscription", NULL, "\"adapt\" must be true or false");
        tmp.pinned = !cJSON_IsTrue(j);
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "parts"))) {
        if (!cJSON_IsBool(j))
            return ctl_fail(e, "bad_subscription", NULL, "\"parts\" must be true or false");
        tmp.parts = cJSON_IsTrue(j);
    }
    if ((j = cJSON_GetObjectItemCaseSensitive(msg, "codec"))) {
        /* One encoding per layer is shared by every client, so a client
         * cannot pick the entropy coder: codec 1 is the only one to ask for
         * (codec 0 comes with bound 0); zstd (2) is refused, not ignored. */
        if (!cJSON_IsNumber(j) || j->valuedouble != 1)
            return ctl_fail(e, "bad_subscription", NULL,
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
                    return ctl_fail(e, "bad_subscription", NULL, "\"tiles\" must be \"all\" or [[tx,tz],...] with 0 <= t < 32");
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
            return ctl_fail(e, "bad_subscription", NULL, "\"tiles\" must be \"all\" or a non-empty list of [tx,tz]");
        }
    }
    memcpy(out, &tmp, sizeof tmp);
    return 0;
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
    if (s->pinned) /* the default (adapt) is not written: replies stay as they were for clients that never pin */
        cJSON_AddBoolToObject(o, "adapt", false);
    if (s->parts) /* likewise: only a client that asked for parts sees the member */
        cJSON_AddBoolToObject(o, "parts", true);
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

void subscription_layer_keys(const struct subscription *sub, int counts[LAYER_KEYS_ALL], int delta)
{
    for (int c = 0; c < CTL_MAX_CASCADES; c++) {
        int lod = 0, bound_index = 0;
        unsigned fields = subscription_cascade(sub, c, &lod, &bound_index);
        for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
            if (fields & OCEAN_FIELD_BIT(f))
                counts[layer_key_cascade(c, f, c == 0 ? subscription_lod(sub, f) : lod, bound_index)] += delta;
    }
}

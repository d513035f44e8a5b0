/* render_msg.c — `render` checked member by member (PROTOCOL.md §7.5). The
 * layers are those of a subscription, so subscribe's own checks
 * (control_apply_subscribe) decide fields, lod, field_lod, bound, cascades
 * and tiles; only the code of its refusals differs. */
#include "render_msg.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "control_internal.h"

static int number(const cJSON *root, const char *name, double *v, struct ctl_error *e)
{
    const cJSON *j = cJSON_GetObjectItemCaseSensitive(root, name);
    if (!j)
        return ctl_fail(e, "bad_render", name, "\"render\" needs \"%s\"", name);
    if (!cJSON_IsNumber(j) || !isfinite(j->valuedouble))
        return ctl_fail(e, "bad_render", name, "\"%s\" must be a finite number", name);
    *v = j->valuedouble;
    return 0;
}

int render_parse(const cJSON *root, const struct ctl_limits *lim, struct render_req *r, struct ctl_error *e)
{
    memset(r, 0, sizeof *r);
    double frames;
    if (number(root, "start", &r->start, e) || number(root, "fps", &r->fps, e) || number(root, "frames", &frames, e))
        return -1;
    if (r->start < 0 || r->start > OCEAN_TIME_MAX)
        return ctl_fail(e, "bad_render", "start", "\"start\" must be within [0, %g] s", OCEAN_TIME_MAX);
    if (!(r->fps > 0) || r->fps > RENDER_MAX_FPS)
        return ctl_fail(e, "bad_render", "fps", "\"fps\" must be in (0, %g]", RENDER_MAX_FPS);
    if (frames != floor(frames) || frames < 1 || frames > RENDER_MAX_FRAMES)
        return ctl_fail(e, "bad_render", "frames", "\"frames\" must be an integer 1..%d", RENDER_MAX_FRAMES);
    r->frames = (long)frames;
    if (render_time(r, r->frames - 1) > OCEAN_TIME_MAX)
        return ctl_fail(e, "bad_render", "frames", "the last frame's time is past %g s", OCEAN_TIME_MAX);
    if (!cJSON_GetObjectItemCaseSensitive(root, "fields"))
        return ctl_fail(e, "bad_render", "fields", "\"render\" needs \"fields\"");
    /* Members of a live subscription that a render has no use for. */
    static const char *const live_only[] = { "max_rate", "adapt", "parts" };
    for (size_t i = 0; i < sizeof live_only / sizeof live_only[0]; i++)
        if (cJSON_GetObjectItemCaseSensitive(root, live_only[i]))
            return ctl_fail(e, "bad_render", live_only[i], "\"%s\" is for subscribe, not render", live_only[i]);
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "temporal");
    if (t && !cJSON_IsFalse(t))
        return ctl_fail(e, "bad_render", "temporal", "a render's frames are intra (codec 0 or 1): \"temporal\" "
                                                      "may only be false");
    struct subscription base;
    subscription_default(&base, lim->tick_rate);
    if (control_apply_subscribe(root, &base, lim, &r->sub, e) != 0) {
        e->code = "bad_render";
        return -1;
    }
    if (!r->sub.fields) /* "no frames" is a live session's choice; a render is its frames */
        return ctl_fail(e, "bad_render", "fields", "\"fields\" must be a non-empty array of names");
    return 0;
}

double render_frame_units(const struct render_req *r, int n, int cascades)
{
    double scale = (double)n / 256.0 * (double)n / 256.0, units = 0;
    for (int c = 0; c < cascades && c < r->sub.ncascades; c++) {
        int lod, bi;
        unsigned f = subscription_cascade(&r->sub, c, &lod, &bi);
        units += __builtin_popcount(f);
    }
    return units * scale;
}

cJSON *render_rendering_msg(const cJSON *id, const struct render_req *r, uint32_t params_version, int n,
                            int cascades, double units)
{
    cJSON *m = cJSON_CreateObject();
    cJSON_AddStringToObject(m, "type", "rendering");
    if (id)
        cJSON_AddItemToObject(m, "id", cJSON_Duplicate(id, 1));
    cJSON_AddNumberToObject(m, "frames", (double)r->frames);
    cJSON_AddNumberToObject(m, "start", r->start);
    cJSON_AddNumberToObject(m, "fps", r->fps);
    cJSON_AddNumberToObject(m, "params_version", params_version);
    cJSON_AddNumberToObject(m, "n", n);
    cJSON_AddNumberToObject(m, "cascades", cascades < r->sub.ncascades ? cascades : r->sub.ncascades);
    cJSON_AddNumberToObject(m, "units", round(units * 100) / 100);
    cJSON *sub = control_subscription_object(&r->sub);
    cJSON_DeleteItemFromObjectCaseSensitive(sub, "max_rate"); /* a live subscription's, not a render's */
    cJSON_DeleteItemFromObjectCaseSensitive(sub, "temporal");
    cJSON_DeleteItemFromObjectCaseSensitive(sub, "adapt");
    cJSON_AddItemToObject(m, "layers", sub);
    return m;
}

cJSON *render_rendered_msg(const cJSON *id, long frames, const char *reason)
{
    cJSON *m = cJSON_CreateObject();
    cJSON_AddStringToObject(m, "type", "rendered");
    if (id)
        cJSON_AddItemToObject(m, "id", cJSON_Duplicate(id, 1));
    cJSON_AddNumberToObject(m, "frames", (double)frames);
    if (reason)
        cJSON_AddStringToObject(m, "reason", reason);
    return m;
}

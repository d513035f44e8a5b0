/* fuzz_control.c — libFuzzer target: one JSON control message through the
 * whole control path the daemon runs (parse -> validate -> new state ->
 * reply), checking the invariants a hostile client must not break. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "control.h"
#include "render_msg.h"

static void check(int ok)
{
    if (!ok)
        abort(); /* libFuzzer records the input as a crash */
}

/* Every value in the table's range, every cross rule satisfied. */
static void check_params(const struct ocean_params *p)
{
    for (size_t i = 0; i < param_count; i++) {
        double v = param_get(p, &param_table[i]);
        check(v == v && v >= param_table[i].min && v <= param_table[i].max);
    }
    char err[256];
    check(params_validate(p, err, sizeof err) == 0);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct ctl_limits lim = { .tick_rate = 30, .max_memory_mb = 512 };
    struct ocean_params cur, before, next;
    params_defaults(&cur);
    before = cur;

    struct ctl_msg m;
    struct ctl_error e = { 0 };
    cJSON *id = NULL;
    if (control_parse((const char *)data, size, &m, &id, &e) != 0) {
        check(e.code != NULL && e.message[0] != '\0');
        free(control_print(control_error_msg(&e, id)));
        cJSON_Delete(id);
        return 0;
    }
    if (cJSON_IsRaw(m.id)) { /* a numeric id kept as its text: a JSON number, so every reply stays JSON */
        cJSON *num = cJSON_Parse(m.id->valuestring);
        check(cJSON_IsNumber(num));
        cJSON_Delete(num);
    }
    if (m.once) { /* the key a change is applied once under: 8..64 printable ASCII */
        size_t k = strlen(m.once);
        check(k >= CTL_ONCE_MIN && k <= CTL_ONCE_MAX);
        for (size_t i = 0; i < k; i++)
            check(m.once[i] > 0x20 && m.once[i] < 0x7f);
    }
    if (m.type == CTL_SET) {
        uint64_t changed = 0;
        if (control_apply_params(m.params, &cur, &lim, &next, &changed, &e) == 0) {
            check_params(&next);
            free(control_print(control_params_msg(&next, 2, changed, "c1", m.id)));
        } else {
            check(e.code != NULL);
            free(control_print(control_error_msg(&e, m.id)));
        }
        check(memcmp(&cur, &before, sizeof cur) == 0); /* all or nothing */
    } else if (m.type == CTL_SUBSCRIBE) {
        struct subscription *s = malloc(2 * sizeof *s);
        check(s != NULL);
        subscription_default(&s[0], lim.tick_rate);
        if (control_apply_subscribe(m.root, &s[0], &lim, &s[1], &e) == 0) {
            check(s[1].lod >= 0 && s[1].lod <= CTL_MAX_LOD);
            /* No top-level fields is "no frames" (a control connection): no cascade either. */
            check(s[1].fields != 0 || (s[1].ncascades == 1 && !subscription_has_frames(&s[1])));
            check(s[1].ncascades >= 1 && s[1].ncascades <= CTL_MAX_CASCADES);
            check(s[1].bound_index >= 0 && s[1].bound_index < CTL_BOUND_COUNT);
            check(s[1].max_rate > 0 && s[1].max_rate <= lim.tick_rate);
            check(s[1].all_tiles || (s[1].ntiles >= 0 && s[1].ntiles <= CTL_MAX_TILES));
            free(control_print(control_subscribed_msg(&s[1], m.id)));
        }
        free(s);
    } else if (m.type == CTL_RENDER) {
        struct render_req *r = malloc(sizeof *r);
        check(r != NULL);
        if (render_parse(m.root, &lim, r, &e) == 0) {
            check(r->frames >= 1 && r->frames <= RENDER_MAX_FRAMES && r->fps > 0 && r->fps <= RENDER_MAX_FPS);
            check(r->start >= 0 && render_time(r, r->frames - 1) <= OCEAN_TIME_MAX && !r->sub.temporal);
            check(r->sub.fields != 0 && r->sub.lod >= 0 && r->sub.lod <= CTL_MAX_LOD);
            check(r->sub.bound_index >= 0 && r->sub.bound_index < CTL_BOUND_COUNT);
            double u = render_frame_units(r, 256, 4);
            check(u >= 1 && u <= 25);
            free(control_print(render_rendering_msg(m.id, r, 3, 256, 3, u * (double)r->frames)));
            free(control_print(render_rendered_msg(m.id, r->frames, NULL)));
        } else {
            check(e.code != NULL && !strcmp(e.code, "bad_render") && e.message[0] != '\0');
            free(control_print(control_error_msg(&e, m.id)));
        }
        free(r);
    } else if (m.type == CTL_PING) {
        free(control_print(control_pong_msg(m.id, m.t, 1)));
    }
    if (m.name) { /* a `name`, or a set's: checked, so it fits a session's buffer */
        check(strlen(m.name) < CTL_NAME_BYTES && control_check_name(m.name, &e) == 0);
        free(control_print(control_named_msg(m.name, m.id)));
    }
    ctl_msg_free(&m);
    return 0;
}

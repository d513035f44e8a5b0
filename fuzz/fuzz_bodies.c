/* fuzz_bodies.c — libFuzzer target: one body request (`launch`, `steer`,
 * `remove`, `claim`) through what the daemon does with it on the lws thread
 * (control_parse -> body_parse -> reply), and the same bytes as a frame whose
 * header may carry a BODY section (oc_body_section_read): whatever the input,
 * errors are coded, a request accepted is within the protocol's ranges,
 * replies print, and the section reader never reads past the input. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "body_msg.h"
#include "control.h"
#include "oc_proto.h"

static void check(int ok)
{
    if (!ok)
        abort();
}

static void section(const uint8_t *data, size_t size)
{
    /* The input as the header of a frame: a valid 48-byte header in front,
     * header_size from the input's first two bytes, the rest as the section. */
    static uint8_t buf[OC_FRAME_HEADER_SIZE + 4096];
    if (size < 2 || size - 2 > sizeof buf - OC_FRAME_HEADER_SIZE)
        return;
    struct oc_frame_header h = { .seq = 1, .n = 64, .tile_size = 64, .patch_size = 100 };
    oc_frame_header_write(buf, &h);
    size_t hs = (size_t)data[0] | (size_t)data[1] << 8;
    buf[6] = (uint8_t)hs;
    buf[7] = (uint8_t)(hs >> 8);
    size_t len = OC_FRAME_HEADER_SIZE + size - 2;
    memcpy(buf + OC_FRAME_HEADER_SIZE, data + 2, size - 2);
    static struct oc_body_record rec[OC_BODY_MAX_RECORDS];
    int n = oc_body_section_read(buf, len, rec, OC_BODY_MAX_RECORDS);
    check(n == OC_E_TRUNCATED || n == OC_E_CORRUPT || (n >= 0 && n <= 65535));
    if (n > 0)
        check(OC_FRAME_HEADER_SIZE + oc_body_section_size(n) <= hs && hs <= len);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    section(data, size);
    struct ctl_msg m;
    struct ctl_error e = { 0 };
    cJSON *id = NULL;
    if (control_parse((const char *)data, size, &m, &id, &e) != 0) {
        cJSON_Delete(id);
        return 0;
    }
    if (m.type == CTL_LAUNCH || m.type == CTL_STEER || m.type == CTL_REMOVE || m.type == CTL_CLAIM) {
        struct body_req r;
        if (body_parse(m.root, m.type, &r, &e) != 0) {
            check(e.code && e.message[0]);
            free(control_print(control_error_msg(&e, m.id)));
        } else if (m.type == CTL_LAUNCH) {
            check(r.kind && body_kind_index(r.kind) >= 0);
            check(fabs(r.x) <= BODY_WORLD_HALF_M && fabs(r.z) <= BODY_WORLD_HALF_M);
            check(r.heading >= 0 && r.heading < 360);
            char *t = control_print(body_launched_msg(m.id, 1, "0123456789abcdef0123456789abcdef"));
            check(t != NULL);
            free(t);
        } else {
            check(r.body >= 1);
            if (m.type == CTL_STEER)
                check((!r.has_throttle || fabs(r.throttle) <= 1) && (!r.has_rudder || fabs(r.rudder) <= 1));
            if (m.type == CTL_CLAIM)
                check(strlen(r.resume) == BODY_RESUME_CHARS);
            char *t = control_print(body_ack_msg("steered", m.id, r.body));
            check(t != NULL);
            free(t);
        }
    }
    ctl_msg_free(&m);
    return 0;
}

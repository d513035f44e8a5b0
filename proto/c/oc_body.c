/* oc_body.c — the BODY header extension of a frame (PROTOCOL.md §3.5): the
 * bodies' state of the frame's tick, 48 bytes a body. */
#include "oc_internal.h"

#include <string.h>

void oc_body_section_write(uint8_t *dst, const struct oc_body_record *r, int count)
{
    memcpy(dst, OC_BODY_TAG, 4);
    oc_put_u16(dst + 4, (uint16_t)count);
    oc_put_u16(dst + 6, OC_BODY_RECORD_SIZE);
    memset(dst + 8, 0, 8);
    for (int i = 0; i < count; i++) {
        uint8_t *p = dst + OC_BODY_SECTION_HEAD + (size_t)i * OC_BODY_RECORD_SIZE;
        oc_put_u32(p, r[i].id);
        p[4] = r[i].kind;
        p[5] = r[i].flags;
        p[6] = (uint8_t)r[i].throttle;
        p[7] = (uint8_t)r[i].rudder;
        for (int k = 0; k < 3; k++)
            oc_put_f32(p + 8 + 4 * k, r[i].pos[k]);
        for (int k = 0; k < 4; k++)
            oc_put_f32(p + 20 + 4 * k, r[i].quat[k]);
        for (int k = 0; k < 3; k++)
            oc_put_f32(p + 36 + 4 * k, r[i].vel[k]);
    }
}

int oc_body_section_read(const uint8_t *frame, size_t len, struct oc_body_record *out, int max)
{
    struct oc_frame_header h;
    size_t hs = 0;
    int rc = oc_frame_header_parse(frame, len, &h, &hs);
    if (rc != OC_OK)
        return rc;
    const uint8_t *p = frame + OC_FRAME_HEADER_SIZE;
    size_t room = hs - OC_FRAME_HEADER_SIZE;
    if (room < OC_BODY_SECTION_HEAD || memcmp(p, OC_BODY_TAG, 4) != 0)
        return 0; /* no section (or one a later version defines): no bodies */
    int count = oc_get_u16(p + 4);
    size_t rsize = oc_get_u16(p + 6);
    /* A larger record is a compatible extension: its first 48 bytes are ours. */
    if (rsize < OC_BODY_RECORD_SIZE || rsize % 8)
        return OC_E_CORRUPT;
    if ((size_t)count * rsize > room - OC_BODY_SECTION_HEAD)
        return OC_E_CORRUPT;
    for (int i = 0; out && i < count && i < max; i++) {
        const uint8_t *q = p + OC_BODY_SECTION_HEAD + (size_t)i * rsize;
        struct oc_body_record *r = &out[i];
        r->id = oc_get_u32(q);
        r->kind = q[4];
        r->flags = q[5];
        r->throttle = (int8_t)q[6];
        r->rudder = (int8_t)q[7];
        for (int k = 0; k < 3; k++)
            r->pos[k] = oc_get_f32(q + 8 + 4 * k);
        for (int k = 0; k < 4; k++)
            r->quat[k] = oc_get_f32(q + 20 + 4 * k);
        for (int k = 0; k < 3; k++)
            r->vel[k] = oc_get_f32(q + 36 + 4 * k);
    }
    return count;
}

/* edge_bodies.c — BODY sections from the sim into an edge's frames (edge_bodies.h). */
#include "edge_bodies.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "oc_proto.h"

struct edge_bodies {
    struct body_snap *snap[EDGE_BODY_SECTIONS]; /* ring by seq % EDGE_BODY_SECTIONS; NULL = none */
    struct cl_frame_set *held[EDGE_HELD_SETS];
    int nheld;
};

struct edge_bodies *edge_bodies_new(void) { return calloc(1, sizeof(struct edge_bodies)); }

void edge_bodies_free(struct edge_bodies *eb)
{
    if (!eb)
        return;
    for (int i = 0; i < EDGE_BODY_SECTIONS; i++)
        body_snap_unref(eb->snap[i]);
    for (int i = 0; i < eb->nheld; i++)
        cl_frame_set_free(eb->held[i]);
    free(eb);
}

static uint16_t u16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }

int edge_bodies_add_section(struct edge_bodies *eb, const uint8_t *data, size_t len)
{
    if (len < 8 + OC_BODY_SECTION_HEAD)
        return -1;
    uint64_t seq = 0;
    for (int i = 0; i < 8; i++)
        seq |= (uint64_t)data[i] << (8 * i);
    const uint8_t *sec = data + 8;
    size_t slen = len - 8;
    int count = u16(sec + 4);
    /* Exactly what the sim writes: it goes into clients' frame headers as it is. */
    if (memcmp(sec, "BODY", 4) != 0 || count < 1 || count > OC_BODY_MAX_RECORDS ||
        u16(sec + 6) != OC_BODY_RECORD_SIZE || slen != oc_body_section_size(count))
        return -1;
    size_t head = (sizeof(struct body_snap) + 15) & ~(size_t)15;
    struct body_snap *b = calloc(1, head + slen);
    if (!b)
        return -1;
    atomic_init(&b->refs, 1);
    b->seq = seq;
    b->count = count;
    b->section = (uint8_t *)b + head;
    b->section_len = slen;
    memcpy(b->section, sec, slen);
    struct body_snap **slot = &eb->snap[seq % EDGE_BODY_SECTIONS];
    body_snap_unref(*slot);
    *slot = b;
    return 0;
}

struct body_snap *edge_bodies_for(struct edge_bodies *eb, uint64_t seq)
{
    struct body_snap *b = eb->snap[seq % EDGE_BODY_SECTIONS];
    if (!b || b->seq != seq)
        return NULL;
    body_snap_ref(b);
    return b;
}

int edge_bodies_hold(struct edge_bodies *eb, struct cl_frame_set *set)
{
    if (eb->nheld == EDGE_HELD_SETS)
        return -1;
    eb->held[eb->nheld++] = set;
    return 0;
}

struct cl_frame_set *edge_bodies_next_held(struct edge_bodies *eb)
{
    if (!eb->nheld)
        return NULL;
    struct cl_frame_set *s = eb->held[0];
    memmove(eb->held, eb->held + 1, (size_t)(eb->nheld - 1) * sizeof *eb->held);
    eb->nheld--;
    return s;
}

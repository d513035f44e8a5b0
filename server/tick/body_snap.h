/* body_snap.h — the floating bodies of one tick, as the producer leaves them
 * (server/tick/body_tick.c): every body's full state (for the state file and
 * the lws thread's table) and the BODY header extension the tick's frame
 * carries (PROTOCOL.md §3.5). Immutable once published and ref-counted like a
 * frame (atomic counts), so whichever thread drops the last reference frees it. */
#ifndef OCEAND_BODY_SNAP_H
#define OCEAND_BODY_SNAP_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "bodies.h"

struct body_snap {
    atomic_int refs;
    uint64_t seq;               /* the tick */
    double sim_time;
    uint64_t next_id;           /* body_world_next_id, 2^32 once ids are exhausted: saved so that ids are never reused */
    int count;
    struct body_state *states;  /* count, ascending id */
    uint8_t *section;           /* the BODY section (oc_body_section_write), NULL when count = 0 */
    size_t section_len;         /* its bytes, 0 when count = 0 (the frame header stays 48 bytes) */
};

void body_snap_ref(struct body_snap *b);
void body_snap_unref(struct body_snap *b); /* NULL is fine */

#endif

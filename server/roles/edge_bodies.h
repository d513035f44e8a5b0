/* edge_bodies.h — the floating bodies' BODY sections on an edge (PROTOCOL.md
 * §3.5 through a cluster, docs/scaling.md): the sim publishes each tick's
 * section before that tick's layers (CL_KIND_BODY_SECTION); the edge keeps
 * the last few and puts the one of a frame's seq into that frame's header,
 * so its clients see every body on the waves of the same tick. A frame
 * collected during one dispatch is held until the dispatch is through (its
 * section may be queued behind its layers when the inbox replaced a layer
 * in place). Lws thread only. */
#ifndef OCEAND_EDGE_BODIES_H
#define OCEAND_EDGE_BODIES_H

#include <stddef.h>
#include <stdint.h>

#include "body_snap.h"
#include "cluster.h"

#define EDGE_BODY_SECTIONS 8  /* ticks of sections kept */
#define EDGE_HELD_SETS 8      /* frames held in one dispatch (more: published at once) */

struct edge_bodies;
struct edge_bodies *edge_bodies_new(void);
void edge_bodies_free(struct edge_bodies *eb);
/* One CL_KIND_BODY_SECTION body (u64 seq + section), checked: a whole
 * section of 1 .. OC_BODY_MAX_RECORDS records of 48 bytes. 0, or -1 (dropped). */
int edge_bodies_add_section(struct edge_bodies *eb, const uint8_t *data, size_t len);
/* The section of tick seq as a body_snap for a frame (a new reference;
 * count and section only), or NULL: no bodies in that tick, or not here. */
struct body_snap *edge_bodies_for(struct edge_bodies *eb, uint64_t seq);
/* Hold set until edge_bodies_next_held: 0 (now the holder's), -1 full (publish it now). */
int edge_bodies_hold(struct edge_bodies *eb, struct cl_frame_set *set);
/* The oldest held set (the caller's), NULL when none is left. */
struct cl_frame_set *edge_bodies_next_held(struct edge_bodies *eb);

#endif

/* role_link.h — what role_sim.c and role_edge.c share: the link's options
 * from the daemon's configuration, and its counters for /metrics. */
#ifndef OCEAND_ROLE_LINK_H
#define OCEAND_ROLE_LINK_H

#include <stddef.h>

struct cJSON;

#include "cluster.h"
#include "config.h"
#include "frame.h"
#include "sim_thread.h"

/* The layer keys of the cluster module and of the daemon are one numbering. */
_Static_assert(CL_FIELDS == OCEAN_FIELD_COUNT && CL_LODS == CTL_MAX_LOD + 1 && CL_BOUNDS == CTL_BOUND_COUNT,
               "cluster layer keys match the daemon's");
_Static_assert(CL_CASCADES == OCEAN_MAX_CASCADES && CL_CASCADE_KEYS == LAYER_KEYS && CL_KEYS == LAYER_KEYS_ALL,
               "cluster layer keys match the daemon's, every cascade included");
_Static_assert(CL_KEY_BYTES == SIM_DEMAND_BYTES, "the sim's remote demand bitmap is the cluster's");

/* cfg from --nats, --nats-prefix, --nats-name, --nats-creds, --nats-tls-*. */
void role_link_config(const struct daemon_config *dc, enum cl_role role, struct cl_config *cfg);
/* Prometheus lines of the link's counters; returns bytes written. */
size_t role_link_metrics(struct cl_link *l, char *buf, size_t cap);
/* Adds "layers":["height.0.2","c1.height.1.4",...] for a key bitmap to obj
 * (field.lod.bound_index; a finer cascade's prefixed with c<cascade>.). */
void role_keys_json(const uint8_t bits[CL_KEY_BYTES], struct cJSON *obj);
/* The same under another member name ("streams": the keys edges stream). */
void role_keys_json_as(const uint8_t bits[CL_KEY_BYTES], struct cJSON *obj, const char *member);

#endif

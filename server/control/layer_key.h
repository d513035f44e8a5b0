/* layer_key.h — the numbering of layers: one key per (cascade, field, LOD,
 * bound) combination, and the keys a subscription asks for. Demand is
 * counted per key (lws thread), frames hold one layer per wanted key (tick),
 * and the cluster names layers by key: one definition for all of them. */
#ifndef OCEAND_LAYER_KEY_H
#define OCEAND_LAYER_KEY_H

#include "control.h"
#include "ocean.h"

/* A layer key: one (cascade, field, LOD, bound index) combination.
 * Subscriptions are counted per key (demand); a frame holds one layer per
 * key that had demand when it was built. Cascade 0's keys are
 * 0..LAYER_KEYS-1; cascade c's are c * LAYER_KEYS + the same, up to
 * LAYER_KEYS_ALL - 1 (server/cluster's CL_KEYS, role_link.h). */
#define LAYER_KEYS (OCEAN_FIELD_COUNT * (CTL_MAX_LOD + 1) * CTL_BOUND_COUNT)
#define LAYER_KEYS_ALL (LAYER_KEYS * OCEAN_MAX_CASCADES)
static inline int layer_key(int field, int lod, int bound_index)
{
    return (field * (CTL_MAX_LOD + 1) + lod) * CTL_BOUND_COUNT + bound_index;
}
static inline int layer_key_cascade(int cascade, int field, int lod, int bound_index)
{
    return cascade * LAYER_KEYS + layer_key(field, lod, bound_index);
}
static inline int layer_key_field(int key) { return key % LAYER_KEYS / ((CTL_MAX_LOD + 1) * CTL_BOUND_COUNT); }
static inline int layer_key_lod(int key) { return (key / CTL_BOUND_COUNT) % (CTL_MAX_LOD + 1); }
static inline int layer_key_bound(int key) { return key % CTL_BOUND_COUNT; }
static inline int layer_key_which_cascade(int key) { return key / LAYER_KEYS; }

/* Add delta to counts[k] for every layer key k that sub asks for (every
 * cascade; cascade 0's fields at their own LOD). The one mapping from a
 * subscription to its layers: admission, demand and the remote demand use it. */
void subscription_layer_keys(const struct subscription *sub, int counts[LAYER_KEYS_ALL], int delta);

#endif

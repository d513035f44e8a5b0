/* frame_want.c — which layers a tick builds, from the plan in force, the
 * groups due this tick and the demand: a pure function, so that what the
 * tick asks of the producer can be read (and tested) in one place. */
#include "tick_internal.h"

static uint16_t saturate16(int v) { return (uint16_t)(v < 0 ? 0 : v > 65535 ? 65535 : v); }

void frame_want_build(const struct plan *plan, const bool due[PLAN_GROUPS], const struct demand_snapshot *d,
                      unsigned probe_fields, struct frame_want *want)
{
    for (int k = 0; k < LAYER_KEYS_ALL; k++) {
        int g = plan_group(layer_key_lod(k), layer_key_bound(k));
        if (d->demand[k] <= 0 || !due[g])
            continue;
        want->fields |= OCEAN_FIELD_BIT(layer_key_field(k));
        want->cfields[layer_key_which_cascade(k)] |= OCEAN_FIELD_BIT(layer_key_field(k));
        want->lod[want->nkeys] = plan->lod[g];
        want->keys[want->nkeys++] = (uint16_t)k;
        /* Temporal layers (PROTOCOL.md §5.9): a stream when a temporal client wants
         * the key; intra tiles for clients that are not temporal (edges included),
         * and this tick's keyframes for temporal ones that lack the references. */
        int temporal = d->tdemand[k];
        bool edge = (d->remote[k >> 3] >> (k & 7)) & 1;
        int key_want = d->key_want[k];
        want->temporal[k] = temporal > 0;
        want->intra[k] = d->demand[k] > temporal || edge || key_want > 0;
        if (plan_intra(plan, g)) { /* the codec rung: intra tiles for everyone, no stream (its state is dropped) */
            want->temporal[k] = 0;
            want->intra[k] = 1;
        }
        want->kclients[k] = saturate16(key_want);
        /* who takes this layer every tick: the stream's grid refinement (layer_stream.h) */
        want->tclients[k] = saturate16(temporal);
        want->iclients[k] = edge ? 65535 : saturate16(d->demand[k] > temporal ? d->demand[k] - temporal : 0);
    }
    if (!want->nkeys && !probe_fields)
        return;
    want->fields |= probe_fields; /* stepped for the probes, not encoded unless a layer wants them */
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++) /* probes sum every cascade in force */
        want->cfields[c] |= probe_fields;
}

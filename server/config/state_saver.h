/* state_saver.h — keeps the state file (state.h) in step with the parameters
 * the simulation applies: a listener for applied changes (net_on_params) and
 * a flush the service loop calls after every wake-up. At most one write a
 * second: a file write per slider move is too many. Used on one thread (the
 * lws service thread); main.c wires it up. */
#ifndef OCEAND_STATE_SAVER_H
#define OCEAND_STATE_SAVER_H

#include <stdbool.h>
#include <stdint.h>

#include "params.h"

struct state_saver {
    const char *path;           /* "" = do not save */
    struct ocean_params params; /* latest applied */
    uint32_t version;
    bool dirty;                 /* params changed since the last save */
    double saved_t;             /* mono_now() of the last save */
};

void state_saver_init(struct state_saver *sv, const char *path, const struct ocean_params *p, uint32_t version);
/* The listener: record an applied change (a net_params_fn). */
void state_saver_on_params(void *saver, const struct ocean_params *p, uint32_t version);
/* Save if a change is unsaved and the last save is at least 1 s old; or, with
 * force (shutdown), now whatever the state. sim_time: the clock to store. */
void state_saver_flush(struct state_saver *sv, double sim_time, bool force);

#endif

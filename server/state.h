/* state.h — save the sea parameters so that a restart continues the same sea.
 * File: {"params":{...},"params_version":N,"sim_time":t}. Saved atomically
 * (write a temporary file, fsync, rename over the old one). */
#ifndef OCEAND_STATE_H
#define OCEAND_STATE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "params.h"

int state_save(const char *path, const struct ocean_params *p, uint32_t version, double sim_time,
               char *err, size_t errlen);
/* Returns 1 if loaded, 0 if the file does not exist (p untouched), -1 on a
 * bad file (p untouched, err says why). */
/* Saving on parameter changes: a listener for the changes the sim applied
 * (net_on_params), and a flush the service loop calls after every wake-up.
 * At most one write a second: a file write per slider move is too many.
 * Used on one thread (the lws service thread). */
struct state_saver {
    const char *path;           /* "" = do not save */
    struct ocean_params params; /* latest applied */
    uint32_t version;
    bool dirty;                 /* params changed since the last save */
    double saved_t;             /* mono_now() of the last save */
};
void state_saver_init(struct state_saver *sv, const char *path, const struct ocean_params *p, uint32_t version);
/* The listener: record an applied change (net_params_fn). */
void state_saver_on_params(void *saver, const struct ocean_params *p, uint32_t version);
/* Save if a change is unsaved and the last save is at least 1 s old, or
 * now whatever the state if force (shutdown). sim_time: the clock to store. */
void state_saver_flush(struct state_saver *sv, double sim_time, bool force);

int state_load(const char *path, struct ocean_params *p, uint32_t *version, double *sim_time,
               char *err, size_t errlen);

#endif

/* state.h — save the sea parameters so that a restart continues the same sea.
 * File: {"params":{...},"params_version":N,"sim_time":t}. Saved atomically
 * (write a temporary file, fsync, rename over the old one). */
#ifndef OCEAND_STATE_H
#define OCEAND_STATE_H

#include <stddef.h>
#include <stdint.h>

#include "params.h"

int state_save(const char *path, const struct ocean_params *p, uint32_t version, double sim_time,
               char *err, size_t errlen);
/* Returns 1 if loaded, 0 if the file does not exist (p untouched), -1 on a
 * bad file (p untouched, err says why), -2 if path is not a regular file (a
 * FIFO, a directory: refused without reading, err says why). A params_version
 * or sim_time out of range (control_json_version, control_json_sim_time: the
 * running daemon's own limits) and data after the object are logged as
 * warnings; the bad value falls back to 0. */
int state_load(const char *path, struct ocean_params *p, uint32_t *version, double *sim_time,
               char *err, size_t errlen);

#endif

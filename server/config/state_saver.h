/* state_saver.h — the state file (state.h) as the durable record of the
 * sea: the simulation's persist hook (sim_config.persist) writes it, with
 * fsync and rename, on the builder thread BEFORE a batch of sets is applied
 * and acknowledged, so no acknowledged set is lost by a crash (docs/scaling.md
 * "Failure model"). A mutex: the builder saves, main saves the clock once
 * more at shutdown. main.c wires it up. */
#ifndef OCEAND_STATE_SAVER_H
#define OCEAND_STATE_SAVER_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include "params.h"
#include "state.h"

struct state_saver {
    const char *path;           /* "" = do not save */
    pthread_mutex_t lock;       /* one save at a time; guards the fields below */
    struct ocean_params params; /* the last saved (or restored) */
    uint32_t version;
    struct state_bodies bodies; /* the bodies as the lws thread last handed them (state_saver_set_bodies) */
    struct sea_spectrum *sea;   /* the measured sea last saved (malloc'd), or NULL */
};

/* sea: the measured sea restored with p (copied), or NULL. */
void state_saver_init(struct state_saver *sv, const char *path, const struct ocean_params *p, uint32_t version,
                      const struct sea_spectrum *sea);
void state_saver_destroy(struct state_saver *sv);
/* sim_config.persist: saves now (write, fsync, rename, fsync of the
 * folder); 0, or -1 with err (nothing was replaced). */
int state_saver_persist(void *saver, const struct ocean_params *p, uint32_t version, double sim_time,
                        const struct sea_spectrum *sea, char *err, size_t errlen);
/* The floating bodies every later save writes (a copy; any thread). */
void state_saver_set_bodies(struct state_saver *sv, const struct state_bodies *b);
/* At shutdown: the last saved state with the final clock. */
void state_saver_final(struct state_saver *sv, double sim_time);

#endif

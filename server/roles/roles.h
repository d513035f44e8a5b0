/* roles.h — `oceand --role sim` and `--role edge` (docs/scaling.md):
 * the glue between the daemon (sim thread, net) and the NATS link of
 * server/cluster/. `--role all` uses none of this. main.c calls these on
 * its own thread (the lws service thread). */
#ifndef OCEAND_ROLES_H
#define OCEAND_ROLES_H

#include <stddef.h>

#include "config.h"
#include "net.h"
#include "sim_thread.h"

/* sim: opens the link (connecting in the background), sets the sim_config
 * hooks (remote demand, publish each frame) and the net hooks (requests
 * from edges, params events, /healthz, /metrics). Call before sim_start;
 * close after sim_stop and before net_destroy. NULL with err on bad options. */
struct role_sim;
struct role_sim *role_sim_open(const struct daemon_config *dc, struct net *n, struct sim_config *sc,
                               char *err, size_t errlen);
void role_sim_close(struct role_sim *r);
/* After sim_start: the lease thread (role_lease.h) with the state the sim
 * started from; 0 or an errno. r NULL: nothing. */
int role_sim_attach(struct role_sim *r, struct sim *sim, const struct ocean_params *p, uint32_t version,
                    const struct sea_spectrum *sea);
/* Before sim_stop: stops the lease thread, releasing the lease if held. */
void role_sim_detach(struct role_sim *r);

/* edge: opens the link and sets the net hooks (demand, forwarding, frames
 * rebuilt from the sim's layers, hello cache, status banner). Close before
 * net_destroy. */
struct role_edge;
struct role_edge *role_edge_open(const struct daemon_config *dc, struct net *n, char *err, size_t errlen);
void role_edge_close(struct role_edge *r);

#endif

/* net.h — libwebsockets front end: HTTP (web client, /healthz, /metrics) and
 * the "oceand.v1" WebSocket protocol, on one port, serviced by one thread. */
#ifndef OCEAND_NET_H
#define OCEAND_NET_H

#include <stddef.h>
#include <stdint.h>

#include "config.h"
#include "params.h"

struct net;
struct sim;

/* Creates the lws context and starts listening. */
struct net *net_create(const struct daemon_config *dc, const struct ocean_params *p, uint32_t version,
                       char *err, size_t errlen);
/* The simulation to take frames and events from; set once, after sim_start. */
void net_attach_sim(struct net *n, struct sim *s);
/* Wake the service thread (lws_cancel_service): safe from any thread. */
void net_wake(void *net);
/* Service events; returns < 0 when the context is gone. */
int net_service(struct net *n);
int net_port(const struct net *n);
/* Save the parameter state now (at shutdown). */
void net_save_state(struct net *n);
void net_destroy(struct net *n);

#endif

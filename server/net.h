/* net.h — libwebsockets front end: HTTP (web client, /healthz, /metrics) and
 * the "oceand.v1" WebSocket protocol, on one port, serviced by one thread
 * (the one that calls net_service). The code is in server/net/. */
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
/* The simulation to take frames and answers from; set once, after sim_start
 * (and to NULL after sim_stop). */
void net_attach_sim(struct net *n, struct sim *s);
/* The point-query service (query_worker.h); set once after sim_start, NULL before it is freed. */
struct query_service;
void net_attach_queries(struct net *n, struct query_service *q);
/* Called on the service thread for every parameter change the sim applied. */
typedef void (*net_params_fn)(void *user, const struct ocean_params *p, uint32_t version);
void net_on_params(struct net *n, net_params_fn fn, void *user);
/* Wake the service thread (lws_cancel_service): safe from any thread. */
void net_wake(void *net);
/* Service events; returns < 0 when the context is gone. */
int net_service(struct net *n);
int net_port(const struct net *n);
void net_destroy(struct net *n);

#endif

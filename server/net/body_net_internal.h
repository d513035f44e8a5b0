/* body_net_internal.h — what the two halves of the lws thread's bodies share:
 * body_net.c (the requests, the answers, the list and the state file) and
 * body_owners.c (owners coming and going, the grace, and a cluster's side:
 * edges' clients, a take-over, an edge adopting the sim's list). All of it on
 * the lws thread; the book is n->bodies (net_internal.h). */
#ifndef BODY_NET_INTERNAL_H
#define BODY_NET_INTERNAL_H

#include "net_internal.h"
#include "sim_thread.h"

/* the book */
struct body_own *body_find(struct net *n, uint32_t id);
struct body_own *body_add(struct net *n, uint32_t id);
void body_gone(struct net *n, uint32_t id, const char *reason, uint64_t seq);
int body_owned_by(const struct net *n, uint64_t serial);

/* to the sim */
struct sim_body_cmd *body_cmd_new(enum sim_body_op op, uint32_t body);
void body_submit_own(struct net *n, struct sim_body_cmd *c);
void body_set_adrift(struct net *n, uint32_t id, bool adrift, bool stop);

/* clients of edges (sim role), known by edge and client id */
struct body_remote *body_rc_find(struct net *n, uint64_t serial);
struct body_remote *body_rc_find_by(struct net *n, const char *origin, const char *by);
struct body_remote *body_rc_get(struct net *n, const char *origin, const char *by);
void body_rc_gone(struct net *n, struct body_remote *r);

/* owners (body_owners.c) */
void body_owner_left(struct net *n, uint64_t serial);
void body_grace_expiry(struct net *n, double now);

/* the `bodies` message to everyone, when the list or an owner changed (body_net.c) */
void body_net_flush(struct net *n);

#endif

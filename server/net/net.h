/* net.h — libwebsockets front end: HTTP (web client, /healthz, /metrics) and
 * the "oceand.v1" WebSocket protocol, on one port, serviced by one thread
 * (the one that calls net_service). The code is in server/net/. */
#ifndef OCEAND_NET_H
#define OCEAND_NET_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include <cjson/cJSON.h>

#include "config.h"
#include "params.h"

struct net;
struct sim;
struct cJSON;

/* Creates the lws context and starts listening. */
struct net *net_create(const struct daemon_config *dc, const struct ocean_params *p, uint32_t version,
                       char *err, size_t errlen);
/* The simulation to take frames and answers from; set once, after sim_start
 * (and to NULL after sim_stop). */
void net_attach_sim(struct net *n, struct sim *s);
/* The point-query service (query_worker.h); set once after sim_start, NULL before it is freed. */
struct query_service;
void net_attach_queries(struct net *n, struct query_service *q);
/* The render workers (render_worker.h), standalone and edge alike; set once
 * before the service loop, NULL before they are freed. */
struct render_service;
void net_attach_renders(struct net *n, struct render_service *r);
/* The state saver (state_saver.h) the floating bodies are handed to for every
 * later save, and the bodies a restart put back (sim_bodies_restored: all
 * of them). Before the service loop. */
struct state_saver;
struct state_bodies;
void net_attach_saver(struct net *n, struct state_saver *sv);
void net_bodies_restore(struct net *n, const struct state_bodies *b);
/* Called on the service thread for every parameter change the sim applied. */
typedef void (*net_params_fn)(void *user, const struct ocean_params *p, uint32_t version);
void net_on_params(struct net *n, net_params_fn fn, void *user);
/* Wake the service thread (lws_cancel_service): safe from any thread. */
void net_wake(void *net);
/* Service events; returns < 0 when the context is gone. */
int net_service(struct net *n);
int net_port(const struct net *n);
void net_destroy(struct net *n);

/* ---- cluster roles (docs/scaling.md; server/roles/role_sim.c, server/roles/role_edge.c) ----
 * Hooks for daemons whose simulation is elsewhere (edge) or whose clients
 * are elsewhere (sim). All run on the service thread. --role all sets none. */
struct frame;
struct net_cluster_hooks {
    void *user;
    bool no_viewers;                                   /* sim: refuse WebSocket upgrades */
    void (*on_wake)(void *user);                       /* every wake-up (cl_link_dispatch) */
    /* edge: instead of sim_demand (and sim_demand_temporal: temporal = the
     * subscription takes the temporal codec). It and `keyframes` only count,
     * as the sim's counters do: they run while a client's subscription is
     * half changed, so they never call back into the net (no frame published
     * from them; defer it to on_wake). */
    void (*demand)(void *user, int layer_key, int delta, bool temporal);
    /* edge: instead of sim_want_keyframes: delta clients of the layer lack
     * the references of its shared tiles (PROTOCOL.md §5.9) */
    void (*keyframes)(void *user, int layer_key, int delta);
    /* edge: a set / pause / resume that passed the size, rate limit and
     * token checks, to be answered later with net_send_text(serial) */
    void (*forward)(void *user, uint64_t serial, const char *client_id, const void *id_json,
                    const char *text, size_t len);
    /* edge: a `query` that passed the rate limit and the local checks (query_parse),
     * to be answered later with net_send_text(serial): the sim's answer or an error */
    void (*forward_query)(void *user, uint64_t serial, const char *client_id, const void *id_json,
                          const char *text, size_t len);
    /* edge: a `probe` that passed the rate limit and probe_parse, to be
     * answered with net_send_text(serial); its probe_data with net_send_probe_data */
    void (*forward_probe)(void *user, uint64_t serial, const char *client_id, const void *id_json,
                          const char *text, size_t len);
    /* edge: client `serial` disconnected (its probe, if any, ends) */
    void (*client_gone)(void *user, uint64_t serial);
    /* sim: one probe_data text of a remote probe (net_remote_probe) */
    void (*on_probe_data)(void *user, uint64_t serial, const char *text);
    /* sim: an applied set's `params` event (no id), who caused it */
    void (*on_params_event)(void *user, const char *text, const char *origin, const char *by);
    /* sim: a `bodies` message (PROTOCOL.md §7.6) for every edge's clients */
    void (*on_bodies_event)(void *user, const char *text);
    /* sim: the bodies and their owners now (as the state file saves them),
     * handed on at most every BODY_KEEP_EVERY_S and at each change: the
     * standby's copy (role_lease.h). Only for the call. */
    void (*on_bodies_state)(void *user, const struct state_bodies *sb);
    /* /healthz: returns "ok" or "degraded" and adds its members ("role",
     * "cluster", "layers", ...) to the object obj (a cJSON object: the
     * answer is built whole, so it is valid JSON whatever its size) */
    const char *(*health)(void *user, struct cJSON *obj);
    /* /metrics: appends Prometheus lines; returns bytes written */
    size_t (*metrics)(void *user, char *buf, size_t cap);
};
void net_set_cluster(struct net *n, const struct net_cluster_hooks *h);
/* edge: frame f (a new reference is taken) replaces the newest one (latest wins). */
void net_publish_frame(struct net *n, struct frame *f);
/* edge: the sim's frames now count from another seq (a restarted or standby
 * sim, seq_guard.h): every client takes the next frame, whatever its seq,
 * and starts its temporal history again. */
void net_stream_restart(struct net *n);
/* edge: the frames from now on come from another sim process (another
 * epoch, cluster.h): no client keeps temporal references across it, so
 * each takes keyframe tiles next, whatever the seq. */
void net_stream_new_chains(struct net *n);
/* A message from a sim in another process, before an edge uses or relays
 * it: at most cap bytes, strict UTF-8 without NUL (a browser must fail a
 * socket that receives anything else), a JSON object whose "type" is one
 * of types (NULL-terminated). The parsed object, or NULL: then it is
 * dropped. Anyone on the NATS prefix can publish, so nothing from there
 * goes to a client unchecked. */
cJSON *net_sim_message(const char *text, size_t len, size_t cap, const char *const types[]);
#define NET_SIM_PARAMS_MAX (64u << 10)   /* a params event is ~2 kB, ~12 kB with a measured sea's summary */
#define NET_SIM_HELLO_MAX (64u << 10)    /* hello with the schema and capacity is ~12 kB */
#define NET_SIM_REPLY_MAX (1u << 20)     /* a query_result of the most points a query may ask */

/* The tick rate in force (the sim's, adopted from its hello on an edge). */
double net_tick_rate(const struct net *n);
/* edge: one JSON text to the client with this serial (if still connected). */
void net_send_text(struct net *n, uint64_t serial, const char *text);
/* edge: adopt the sim's hello (params, params_version, tick_rate, tile_size)
 * for the hello of new clients; existing clients get `params` if the
 * version moved. Returns 0 or -1 (not a hello). */
int net_adopt_hello(struct net *n, const char *text, size_t len);
/* edge: a `params` event from the sim: adopt it and send it to every
 * client but the one whose client_id is skip_client (NULL = none). */
int net_broadcast_params(struct net *n, const char *text, size_t len, const char *skip_client);
/* edge: the cluster state for clients, as a {"type":"status",...} text sent
 * to all now and to each new client after hello; NULL = healthy (sent once
 * to all as given in ok_text, then nothing for new clients). */
void net_set_status(struct net *n, const char *text, const char *ok_text);
/* sim: a control message (set / pause / resume text) from a client of
 * another daemon, validated and applied exactly like a local one; reply(ctx,
 * text) is called exactly once: the error or `params` with the request's id
 * (text NULL = dropped unanswered, at shutdown). */
typedef void (*net_reply_fn)(void *ctx, const char *text);
void net_remote_control(struct net *n, const char *origin, const char *by, const char *text, size_t len,
                        net_reply_fn reply, void *ctx);
/* sim: a `query` (its JSON text) from a client of another daemon, checked and
 * queued exactly like a local one (PROTOCOL.md §7.4); reply(ctx, text) is
 * called exactly once: `query_result` or an error with the request's id, later,
 * from the query workers' results (text NULL = dropped unanswered, at shutdown). */
void net_remote_query(struct net *n, const char *text, size_t len, net_reply_fn reply, void *ctx);
/* sim: a serial for a remote probe (never a session's nor a remote query's). */
uint64_t net_remote_serial(struct net *n);
/* sim: a `probe` (its JSON text) of a client of another daemon, set under
 * `serial` exactly like a local one (PROTOCOL.md §7.4); its probe_data go to
 * the on_probe_data hook. Returns the answer text (malloc'd: `probing` or an
 * error with the request's id, NULL when out of memory) and in *npoints the
 * points now probed, or -1 when it failed (then nothing changed). */
char *net_remote_probe(struct net *n, uint64_t serial, const char *text, size_t len, int *npoints);
/* sim: the remote probe under serial ends. */
void net_remote_probe_gone(struct net *n, uint64_t serial);
/* edge: one probe_data text to client `serial`, unless it is 16 messages behind (it misses the tick). */
void net_send_probe_data(struct net *n, uint64_t serial, const char *text);
/* sim: edge `origin` lists the clients of its that sent body requests and
 * are still connected: {"type":"owners","clients":[{"by":id,"name":n},...]}.
 * A client of that edge not listed is gone (its bodies are adrift, §7.6);
 * one whose edge lists nobody for BODY_OWNERS_EXPIRE_S is gone too. */
void net_remote_owners(struct net *n, const char *origin, const char *text, size_t len);
#define BODY_OWNERS_PERIOD_S 2.0
#define BODY_OWNERS_EXPIRE_S 7.0
/* edge: the owners message for the sim when it is due (a body user left or
 * renamed itself, or BODY_OWNERS_PERIOD_S passed), malloc'd; NULL = nothing to send. */
char *net_body_owners(struct net *n, double now);
/* edge: the sim refused a launch of client serial as too_many_bodies: its
 * launch is given back to its --launch-rate bucket, as a local refusal
 * never takes it (at most a full bucket). */
void net_body_refused(struct net *n, uint64_t serial);
/* edge: a `bodies` message from the sim: the list this edge's hellos carry,
 * relayed to every client. -1 = not a valid `bodies` (dropped). */
int net_adopt_bodies(struct net *n, const char *text, size_t len);
/* sim: a standby that took over: every body of sb where it was, its owners
 * (clients of edges, by origin) keep it; the world's bodies are replaced. */
void net_bodies_take_over(struct net *n, const struct state_bodies *sb);
/* sim: answers every remote request still waiting with NULL (before the link closes). */
void net_drop_remote_requests(struct net *n);
/* sim: the hello the sim would send (client_id ""), malloc'd; for edges. */
char *net_hello_text(struct net *n);
/* The seq of the newest frame this daemon handed out (0 = none). */
uint64_t net_latest_seq(const struct net *n);

#endif

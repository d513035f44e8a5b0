/* role_sim.c — `oceand --role sim`: the simulation of a cluster. It ticks
 * and encodes as --role all does, but for the layers the edges demand
 * (their heartbeats, through the NATS link), publishes each encoded layer
 * once on NATS, answers the edges' set / pause / resume (validated by the
 * same code as a local client's, server/net/dispatch.c), their clients'
 * point queries and probes (the same query workers as a local client's,
 * probe_data streamed to the edge) and hello
 * requests, and publishes every params event. No viewers connect to it.
 * Threads: the hooks on_frame / remote_demand run on the tick thread and
 * only queue (cl_sim_publish_layer, cl_sim_demand); the rest runs on the
 * lws thread inside cl_link_dispatch. */
#include "roles.h"

#include "clock.h"

#include <cjson/cJSON.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "body_snap.h"
#include "log.h"
#include "metrics.h"
#include "role_lease.h"
#include "role_link.h"

#define STATUS_PERIOD 0.25 /* s between updates of the heartbeat body (the link sends it at its own rate) */

/* A probe of a client of an edge (PROTOCOL.md §7.4 through an edge,
 * docs/scaling.md): set in the query workers under a serial of its own; its
 * probe_data go to the edge's stream subject. Forgotten when the edge stops
 * its keepalives for CL_PROBE_EXPIRE_S. Lws thread only. */
struct rprobe {
    struct rprobe *next;
    uint64_t serial;
    char origin[CL_NAME_MAX], by[CL_NAME_MAX];
    char stream[CL_SUBJECT_MAX];
    double seen;                                  /* mono time of its last request or keepalive */
};

struct role_sim {
    struct net *net;
    struct cl_link *link;
    struct rprobe *probes;
    double probes_t;                              /* when expiry was last checked */
    double status_t;                              /* lws: when the heartbeat body was last set */
    struct role_lease *lease;                     /* standby and the JetStream record (role_lease.h) */
    int (*file_persist)(void *, const struct ocean_params *, uint32_t, double, const struct sea_spectrum *, char *,
                        size_t);
    void *file_user;                              /* the state file's persist hook (main.c), called after JetStream */
    _Atomic uint64_t demand[CL_KEY_BYTES / 8];    /* tick writes (last union), lws reads (/healthz) */
    _Atomic uint64_t streams[CL_KEY_BYTES / 8];   /* the same for the keys edges stream (temporal codec) */
    atomic_uint_least64_t layers_encoded;         /* tick writes, lws reads (/metrics) */
};

/* ---- tick thread ---- */

static void sim_remote_demand(void *user, uint8_t bits[], uint8_t stream[], uint8_t wish[])
{
    struct role_sim *r = user;
    struct cl_demand_bits u;
    cl_sim_demand_ex(r->link, &u);
    for (int i = 0; i < CL_KEY_BYTES / 8; i++) {
        uint64_t w;
        memcpy(&w, u.keys + 8 * i, 8);
        atomic_store(&r->demand[i], w);
        memcpy(&w, u.stream + 8 * i, 8);
        atomic_store(&r->streams[i], w);
    }
    if (!role_lease_acting(r->lease))
        return; /* a standby encodes nothing */
    for (int i = 0; i < SIM_DEMAND_BYTES && i < CL_KEY_BYTES; i++) {
        bits[i] |= u.keys[i];
        stream[i] |= u.stream[i];
        wish[i] |= u.wish[i];
    }
}

static void release_frame(void *ctx) { frame_unref(ctx); }

/* CL_KIND_BODY_SECTION: u64 seq (little-endian) + the BODY section (PROTOCOL.md §3.5). */
static void publish_section(struct role_sim *r, uint64_t seq, const struct body_snap *b)
{
    size_t len = 8 + b->section_len;
    uint8_t *buf = malloc(len);
    if (!buf)
        return;
    for (int i = 0; i < 8; i++)
        buf[i] = (uint8_t)(seq >> (8 * i));
    memcpy(buf + 8, b->section, b->section_len);
    int rc = cl_sim_publish_bodies(r->link, CL_KIND_BODY_SECTION, buf, len);
    if (rc != CL_OK && rc != CL_E_NOT_CONNECTED)
        LOGW("cluster: publishing the bodies failed: %s", cl_strerror(rc));
    free(buf);
}

/* Each layer of the frame on its subject; the frame stays alive (one
 * reference per layer) until the pump has sent it. */
static void sim_on_frame(void *user, struct frame *f)
{
    struct role_sim *r = user;
    if (!role_lease_acting(r->lease))
        return;
    struct cl_layer_info info = {
        .seq = f->hdr.seq, .sim_time = f->hdr.sim_time, .params_version = f->hdr.params_version,
        .n = f->hdr.n, .tile_size = f->hdr.tile_size, .patch_size = f->hdr.patch_size,
        .frame_flags = f->hdr.flags, .server_time_us = f->hdr.server_time_us,
        .tiles_per_side = (uint16_t)f->tiles_per_side, .ncascades = (uint8_t)f->ncascades,
    };
    /* The tick's bodies go first: an edge puts them in the frame its layers make (role_edge.c). */
    if (f->bodies && f->bodies->count > 0)
        publish_section(r, f->hdr.seq, f->bodies);
    /* Every cascade: the layer keys of the cluster are the daemon's (role_link.h). */
    for (int i = 0; i < f->nlayers; i++) {
        const struct layer *l = &f->layers[i];
        if (l->tile_off || l->shared_off)
            cl_bit_set(info.encoded, layer_key_cascade(l->cascade, l->field, l->lod, l->bound_index), true);
    }
    for (int i = 0; i < f->nlayers; i++) {
        const struct layer *l = &f->layers[i];
        if (!l->tile_off && !l->shared_off)
            continue;
        info.field = l->field;
        info.lod = l->lod;
        info.bound_index = l->bound_index;
        info.cascade = l->cascade;
        info.encoded_lod = l->encoded_lod;
        /* Sections (cluster.h): this tick's intra (keyframe) tiles when some
         * edge needs them, then the stream's shared tiles of a temporal layer;
         * both encoded once, whatever the number of edges. */
        const uint8_t *data[2] = { NULL, NULL };
        size_t len[2] = { 0, 0 };
        const uint32_t *off[2] = { NULL, NULL };
        int n = 0;
        if (l->tile_off) {
            data[n] = l->buf.data;
            len[n] = l->buf.len;
            off[n++] = l->tile_off;
        }
        info.layer_flags = 0;
        info.need = 0;
        if (l->shared_off) {
            info.layer_flags = (uint8_t)(CL_LAYER_SHARED | (l->tile_off ? CL_LAYER_INTRA : 0));
            info.need = l->need;
            data[n] = l->shared.data;
            len[n] = l->shared.len;
            off[n++] = l->shared_off;
        }
        frame_ref(f);
        int rc = cl_sim_publish_layer_sections(r->link, &info, data, len, off, release_frame, f);
        if (rc == CL_OK)
            atomic_fetch_add(&r->layers_encoded, 1);
        else if (rc != CL_E_NOT_CONNECTED)
            LOGW("cluster: publishing a layer failed: %s", cl_strerror(rc));
    }
}

/* ---- lws thread ---- */

/* The request and its link travel together through net_remote_control. */
struct pending_reply {
    struct cl_link *link;
    struct cl_request *req;
};

static void answer(void *ctx, const char *text)
{
    struct pending_reply *p = ctx;
    cl_request_reply(p->link, p->req, text, text ? strlen(text) : 0);
    free(p);
}

static struct rprobe *rprobe_find(struct role_sim *r, const char *origin, const char *by)
{
    for (struct rprobe *p = r->probes; p; p = p->next)
        if (strcmp(p->origin, origin) == 0 && strcmp(p->by, by) == 0)
            return p;
    return NULL;
}

static void rprobe_remove(struct role_sim *r, struct rprobe *gone)
{
    for (struct rprobe **pp = &r->probes; *pp; pp = &(*pp)->next)
        if (*pp == gone) {
            *pp = gone->next;
            free(gone);
            return;
        }
}

/* A PROBE request: with a body, the client's `probe` (set as a local
 * client's, answered with the sim's `probing` or error); with none, the
 * edge's keepalive of a probe it has (answered `probing`, or error
 * `unknown_probe` when this sim does not know it: restarted, or expired;
 * the edge then sends the probe again). */
static void sim_probe(struct role_sim *r, struct cl_request *req)
{
    static const char alive[] = "{\"type\":\"probing\",\"keepalive\":true}";
    static const char unknown[] = "{\"type\":\"error\",\"code\":\"unknown_probe\",\"message\":\"this simulation "
                                  "has no such probe: send it again\"}";
    char stream[CL_SUBJECT_MAX];
    if (!req->by[0] || !req->origin[0] || cl_probe_stream_subject(req->reply_to, stream, sizeof stream) != CL_OK) {
        static const char bad[] = "{\"type\":\"error\",\"code\":\"bad_message\",\"message\":\"a probe needs its "
                                  "edge, client and reply inbox\"}";
        cl_request_reply(r->link, req, bad, strlen(bad));
        return;
    }
    struct rprobe *p = rprobe_find(r, req->origin, req->by);
    if (req->len == 0) { /* keepalive */
        if (p) {
            p->seen = mono_now();
            snprintf(p->stream, sizeof p->stream, "%s", stream);
        }
        cl_request_reply(r->link, req, p ? alive : unknown, strlen(p ? alive : unknown));
        return;
    }
    bool fresh = !p;
    if (fresh && !(p = calloc(1, sizeof *p))) {
        cl_request_reply(r->link, req, NULL, 0); /* the edge times it out: unavailable */
        return;
    }
    if (fresh) {
        p->serial = net_remote_serial(r->net);
        snprintf(p->origin, sizeof p->origin, "%s", req->origin);
        snprintf(p->by, sizeof p->by, "%s", req->by);
        p->next = r->probes;
        r->probes = p;
    }
    int npoints;
    char *answer = net_remote_probe(r->net, p->serial, req->body, req->len, &npoints);
    if (npoints > 0) {
        p->seen = mono_now();
        snprintf(p->stream, sizeof p->stream, "%s", stream);
    } else if (npoints == 0 || fresh) {
        rprobe_remove(r, p); /* ended, or a failed first probe (nothing was set) */
    }
    cl_request_reply(r->link, req, answer, answer ? strlen(answer) : 0);
    free(answer);
}

static void sim_on_probe_data(void *user, uint64_t serial, const char *text)
{
    struct role_sim *r = user;
    for (struct rprobe *p = r->probes; p; p = p->next)
        if (p->serial == serial) {
            cl_sim_publish_probe_data(r->link, p->stream, p->by, text, strlen(text));
            return;
        }
}

static void expire_probes(struct role_sim *r, double now)
{
    for (struct rprobe **pp = &r->probes; *pp;) {
        struct rprobe *p = *pp;
        if (now - p->seen > CL_PROBE_EXPIRE_S) {
            LOGI("cluster: probe of %s on %s expired (no keepalive)", p->by, p->origin);
            net_remote_probe_gone(r->net, p->serial);
            *pp = p->next;
            free(p);
        } else {
            pp = &p->next;
        }
    }
}

static void sim_on_request(void *user, struct cl_request *req)
{
    struct role_sim *r = user;
    if (!role_lease_acting(r->lease)) { /* the active sim answers; the edge times out if there is none */
        cl_request_reply(r->link, req, NULL, 0);
        return;
    }
    if (req->kind == CL_KIND_PROBE) {
        sim_probe(r, req);
        return;
    }
    if (req->kind == CL_KIND_CTL && !req->by[0]) { /* the edge's own: who of its clients is still there */
        net_remote_owners(r->net, req->origin, req->body, req->len);
        cl_request_reply(r->link, req, "{}", 2);
        return;
    }
    if (req->kind == CL_KIND_HELLO) {
        char *hello = net_hello_text(r->net);
        cl_request_reply(r->link, req, hello, hello ? strlen(hello) : 0);
        free(hello);
        return;
    }
    struct pending_reply *p = malloc(sizeof *p);
    if (!p) {
        cl_request_reply(r->link, req, NULL, 0);
        return;
    }
    p->link = r->link;
    p->req = req;
    if (req->kind == CL_KIND_QUERY) /* answered when the query workers are done */
        net_remote_query(r->net, req->body, req->len, answer, p);
    else
        net_remote_control(r->net, req->origin, req->by, req->body, req->len, answer, p);
}

static void sim_on_state(void *user, enum cl_event ev)
{
    LOGI("cluster: NATS %s", cl_event_name(ev));
}

static void sim_on_params_event(void *user, const char *text, const char *origin, const char *by)
{
    struct role_sim *r = user;
    int rc = cl_sim_publish_params(r->link, origin, by, text, strlen(text));
    if (rc != CL_OK)
        LOGW("cluster: publishing params failed: %s (edges catch up at their next hello)", cl_strerror(rc));
}

static void sim_on_bodies_event(void *user, const char *text)
{
    struct role_sim *r = user;
    if (!role_lease_acting(r->lease))
        return;
    int rc = cl_sim_publish_bodies(r->link, CL_KIND_BODIES, text, strlen(text));
    if (rc != CL_OK && rc != CL_E_NOT_CONNECTED)
        LOGW("cluster: publishing `bodies` failed: %s (edges catch up at the next change or hello)", cl_strerror(rc));
}

static void sim_on_bodies_state(void *user, const struct state_bodies *sb)
{
    struct role_sim *r = user;
    if (role_lease_state(r->lease) == LEASE_ACTIVE) /* a standby's own bodies never reach the record */
        role_lease_set_bodies(r->lease, sb);
}

static void sim_on_wake(void *user)
{
    struct role_sim *r = user;
    struct state_bodies sb;
    if (role_lease_take_bodies(r->lease, &sb)) { /* a take-over: the bodies in the world before any request */
        net_bodies_take_over(r->net, &sb);
        state_bodies_free(&sb);
    }
    cl_link_dispatch(r->link);
    double now = mono_now();
    if (now - r->probes_t >= 0.5) {
        r->probes_t = now;
        expire_probes(r, now);
    }
    if (now - r->status_t >= STATUS_PERIOD) {
        r->status_t = now;
        char st[160];
        int len = snprintf(st, sizeof st, "{\"params_version\":%u,\"ticks\":%llu}",
                           (unsigned)atomic_load(&g_metrics.params_version),
                           (unsigned long long)atomic_load(&g_metrics.ticks));
        cl_sim_set_status(r->link, st, (size_t)len);
    }
}

static const char *sim_health(void *user, cJSON *obj)
{
    struct role_sim *r = user;
    struct cl_stats st;
    cl_link_stats(r->link, &st);
    bool up = cl_link_connected(r->link);
    uint8_t bits[CL_KEY_BYTES];
    for (int i = 0; i < CL_KEY_BYTES / 8; i++) {
        uint64_t w = atomic_load(&r->demand[i]);
        memcpy(bits + 8 * i, &w, 8);
    }
    cJSON_AddStringToObject(obj, "role", "sim");
    cJSON_AddStringToObject(obj, "cluster", up ? "ok" : "nats_unavailable");
    cJSON_AddNumberToObject(obj, "edges", st.demand_edges);
    cJSON_AddStringToObject(obj, "lease", role_lease_state_name(role_lease_state(r->lease)));
    cJSON_AddStringToObject(obj, "instance", cl_link_instance(r->link));
    role_keys_json(bits, obj);
    for (int i = 0; i < CL_KEY_BYTES / 8; i++) {
        uint64_t w = atomic_load(&r->streams[i]);
        memcpy(bits + 8 * i, &w, 8);
    }
    role_keys_json_as(bits, obj, "streams");
    return up ? "ok" : "degraded";
}

static size_t sim_metrics(void *user, char *buf, size_t cap)
{
    struct role_sim *r = user;
    size_t off = role_link_metrics(r->link, buf, cap);
    if (off < cap)
        off += (size_t)snprintf(buf + off, cap - off, "# HELP oceand_cluster_layers_encoded_total layers encoded for edges\n"
                                "# TYPE oceand_cluster_layers_encoded_total counter\noceand_cluster_layers_encoded_total %llu\n",
                                (unsigned long long)atomic_load(&r->layers_encoded));
    return off < cap ? off : (cap ? cap - 1 : 0);
}

/* sim_config.persist: the JetStream record first (the copy a standby
 * takes over from; a lost lease refuses the change), then the state file. */
static int sim_persist(void *user, const struct ocean_params *p, uint32_t version, double sim_time,
                       const struct sea_spectrum *sea, char *err, size_t errlen)
{
    struct role_sim *r = user;
    if (role_lease_persist(r->lease, p, version, sim_time, sea, err, errlen) != 0)
        return -1;
    return r->file_persist ? r->file_persist(r->file_user, p, version, sim_time, sea, err, errlen) : 0;
}

int role_sim_attach(struct role_sim *r, struct sim *sim, const struct ocean_params *p, uint32_t version,
                    const struct sea_spectrum *sea)
{
    return r ? role_lease_start(r->lease, sim, p, version, sea) : 0;
}

void role_sim_detach(struct role_sim *r)
{
    if (r)
        role_lease_stop(r->lease);
}

struct role_sim *role_sim_open(const struct daemon_config *dc, struct net *n, struct sim_config *sc,
                               char *err, size_t errlen)
{
    struct role_sim *r = calloc(1, sizeof *r);
    if (!r) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    r->net = n;
    struct cl_config cfg;
    role_link_config(dc, CL_ROLE_SIM, &cfg);
    cfg.wake = net_wake;
    cfg.wake_user = n;
    cfg.user = r;
    cfg.h.on_state = sim_on_state;
    cfg.h.on_request = sim_on_request;
    cfg.standby = true; /* silent until the lease says this sim acts (role_lease.c) */
    char lerr[256];
    r->link = cl_link_open(&cfg, lerr, sizeof lerr);
    if (!r->link) {
        snprintf(err, errlen, "NATS: %s", lerr);
        free(r);
        return NULL;
    }
    /* Edges keep their clients across a restart of the sim: seq must not go
     * back, or they would wait for it to catch up. A tick runs at most once a
     * period, so wall-clock periods since 1970 are always ahead of the last run's seq. */
    sc->start_seq = (uint64_t)((double)unix_us() * 1e-6 * dc->tick_rate);
    if (!(r->lease = role_lease_new(r->link, dc->tick_rate))) {
        snprintf(err, errlen, "out of memory");
        cl_link_close(r->link);
        free(r);
        return NULL;
    }
    role_lease_on_bodies(r->lease, net_wake, n);
    r->file_persist = sc->persist;
    r->file_user = sc->persist_user;
    sc->persist = sim_persist;
    sc->persist_user = r;
    sc->remote_demand = sim_remote_demand;
    sc->on_frame = sim_on_frame;
    sc->cluster_user = r;
    struct net_cluster_hooks h = {
        .user = r, .no_viewers = true, .on_wake = sim_on_wake, .on_params_event = sim_on_params_event,
        .on_probe_data = sim_on_probe_data, .on_bodies_event = sim_on_bodies_event,
        .on_bodies_state = sim_on_bodies_state,
        .health = sim_health, .metrics = sim_metrics,
    };
    net_set_cluster(n, &h);
    LOGI("cluster: role sim as %s (prefix %s)", cl_link_name(r->link),
         dc->nats_prefix[0] ? dc->nats_prefix : CL_DEFAULT_PREFIX);
    return r;
}

void role_sim_close(struct role_sim *r)
{
    if (!r)
        return;
    net_drop_remote_requests(r->net); /* they hold cl_requests of this link */
    struct net_cluster_hooks none = { .no_viewers = true };
    net_set_cluster(r->net, &none);
    role_lease_free(r->lease); /* before the link: it may release the lease */
    cl_link_close(r->link);
    while (r->probes) { /* the query service is freed after this: nothing to tell it */
        struct rprobe *p = r->probes;
        r->probes = p->next;
        free(p);
    }
    free(r);
}

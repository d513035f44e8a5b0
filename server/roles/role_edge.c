/* role_edge.c — `oceand --role edge`: serves viewers (HTTP, web client,
 * WebSocket, exactly as --role all) from a simulation in another process.
 * It subscribes (through the NATS link's demand) to the layers its own
 * clients want, rebuilds frames from them (cl_collector: the layers of one
 * seq) and hands them to the usual latest-frame-wins fan-out; it forwards
 * set / pause / resume to the sim after the local size, rate and token
 * checks, and `query` after the rate limit and the query's own checks (at
 * most EDGE_QUERIES_* in flight), and relays the answers; it keeps the
 * sim's hello for new clients. Floating bodies: their requests go to the
 * sim like a set (body_net.c checks them first), their `bodies` lists are
 * relayed, each tick's BODY section goes into the frame of that tick
 * (edge_bodies.c), and the sim hears which of our clients are still here.
 * Stateless: nothing here outlives the process. Everything runs on the lws
 * thread (hooks and cl_link_dispatch handlers). */
#include "roles.h"

#include <cjson/cJSON.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "control.h"
#include "log.h"
#include "role_link.h"
#include "edge_bodies.h"
#include "seq_guard.h"

enum edge_state { EDGE_UNKNOWN, EDGE_OK, EDGE_SIM_DOWN, EDGE_NATS_DOWN };
static const char *const state_name[] = { "unknown", "ok", "sim_unavailable", "nats_unavailable" };

/* A client's probe that the sim accepted (non-empty): kept alive, and sent
 * again to a sim that does not know it (restarted). */
struct eprobe {
    struct eprobe *next;
    uint64_t serial;
    char client[CL_NAME_MAX];
    char *text;                   /* the client's `probe` message */
    size_t len;
    bool in_flight;               /* a keepalive or resend is on its way */
};

/* A request on its way to the sim: a client's control message or query, or hello. */
struct forward {
    struct forward *prev, *next;  /* in role_edge.forwards (freed at close if never answered) */
    struct role_edge *r;
    bool hello;
    bool own;                     /* the edge's own (the owners list): its answer goes to nobody */
    bool query;                   /* counted in role_edge.queries (queries and clients' probes) */
    enum { FW_NONE, FW_PROBE, FW_KEEPALIVE, FW_RESEND, FW_END } probe;
    bool gone;                    /* its client disconnected meanwhile */
    char client[CL_NAME_MAX];     /* probes: the client's id */
    char *text;                   /* FW_PROBE: the client's probe, kept if the sim accepts it */
    size_t len;
    uint64_t serial;              /* the client that sent it */
    cJSON *id;                    /* its request id (for our own `unavailable` error), or NULL */
};

struct role_edge {
    struct net *net;
    struct cl_link *link;
    struct cl_collector *collector;
    struct seq_guard seq;         /* which layers' seqs follow the sim's stream */
    double refused_log_t;         /* when a refused layer was last logged */
    int count[CL_KEYS];           /* clients' subscriptions per layer key */
    int tcount[CL_KEYS];          /* those that take the temporal codec */
    int kcount[CL_KEYS];          /* temporal clients short of references (fanout_want_keyframes) */
    uint8_t want[CL_KEY_BYTES];   /* keys with count > 0: what we subscribe to */
    bool recheck;                 /* a key left want: the pending frame may be complete now (check_pending) */
    struct cl_demand_bits demand; /* what the sim hears: want, and which keys stream / need keyframes */
    uint64_t epoch;               /* the sim process of the last frame published (cluster.h); 0 = none yet */
    uint64_t new_chains;          /* times the epoch changed under the clients (/metrics) */
    uint64_t frames;              /* frames handed to the fan-out (frame.index) */
    enum edge_state state;
    struct forward *forwards;
    int queries;                  /* forwards that are queries or clients' probes */
    struct eprobe *probes;        /* clients' probes the sim accepted */
    double keepalive_t;           /* when the probes' keepalives were last sent */
    struct edge_bodies *bodies;   /* the last ticks' BODY sections, and frames waiting for theirs */
    bool hello_needed;            /* ask the sim for hello (again) at the next chance */
    bool hello_in_flight;
    double hello_t;               /* when it was last asked */
};

/* ---- frames ---- */

/* One layer's sections (cluster.h) as the fan-out's struct layer: intra
 * tiles in buf/tile_off, the stream's shared tiles in shared/shared_off
 * (adopting the layer's buffers where it can). -1 when out of memory. */
static int adopt_layer(struct layer *l, struct cl_layer *cl)
{
    int sec = cl->info.tiles_per_side * cl->info.tiles_per_side;
    bool intra = cl_info_has_intra(&cl->info), shared = cl_info_has_shared(&cl->info);
    if (intra && shared) { /* the shared tiles follow the intra ones: copied out */
        uint32_t base = cl->tile_off[sec];
        size_t n = cl->len - base;
        uint8_t *data = malloc(n ? n : 1);
        uint32_t *off = malloc(sizeof *off * ((size_t)sec + 1));
        if (!data || !off) {
            free(data);
            free(off);
            return -1;
        }
        memcpy(data, cl->data + base, n);
        for (int i = 0; i <= sec; i++)
            off[i] = cl->tile_off[sec + i] - base;
        l->shared = (struct oc_buf){ .data = data, .len = n, .cap = n };
        l->shared_off = off;
        l->buf = (struct oc_buf){ .data = cl->data, .len = base, .cap = cl->len };
        l->tile_off = cl->tile_off; /* its first sec + 1 entries */
    } else if (shared) {
        l->shared = (struct oc_buf){ .data = cl->data, .len = cl->len, .cap = cl->len };
        l->shared_off = cl->tile_off;
    } else {
        l->buf = (struct oc_buf){ .data = cl->data, .len = cl->len, .cap = cl->len };
        l->tile_off = cl->tile_off;
    }
    l->need = shared ? cl->info.need : 0;
    cl->data = NULL;
    cl->tile_off = NULL;
    return 0;
}

/* A collected frame (layers of one seq) as a struct frame, adopting the
 * layers' buffers. */
static void publish_set(struct role_edge *r, struct cl_frame_set *set)
{
    struct frame *f = frame_new(set->nlayers);
    if (!f)
        return;
    if (set->hdr.epoch != r->epoch) {
        /* Another sim process (a take-over, a restart): its chains are not the
         * ones our clients hold, whatever the seqs say. */
        if (r->epoch) {
            LOGI("cluster: frames from another simulation process now: every temporal client takes keyframes");
            r->new_chains++;
            net_stream_new_chains(r->net);
        }
        r->epoch = set->hdr.epoch;
    }
    const struct cl_layer_info *h = &set->hdr;
    f->hdr = (struct oc_frame_header){
        .seq = h->seq, .sim_time = h->sim_time, .params_version = h->params_version, .n = h->n,
        .tile_size = h->tile_size, .patch_size = h->patch_size, .flags = h->frame_flags,
        .server_time_us = h->server_time_us,
    };
    f->tiles_per_side = h->tiles_per_side;
    f->ncascades = h->ncascades;
    f->index = r->frames++;
    f->bodies = edge_bodies_for(r->bodies, h->seq); /* the tick's bodies, in its header (PROTOCOL.md §3.5) */
    for (int i = 0; i < set->nlayers; i++) {
        struct cl_layer *cl = set->layers[i];
        struct layer *l = &f->layers[f->nlayers++];
        l->field = cl->info.field;
        l->lod = cl->info.lod;
        l->bound_index = cl->info.bound_index;
        l->cascade = cl->info.cascade;
        l->encoded_lod = cl->info.encoded_lod;
        if (adopt_layer(l, cl) != 0) {
            f->nlayers--; /* this layer is missing from the frame: its clients skip it */
            memset(l, 0, sizeof *l);
        }
    }
    net_publish_frame(r->net, f);
    frame_unref(f);
}

static void publish_held(struct role_edge *r)
{
    struct cl_frame_set *set;
    while ((set = edge_bodies_next_held(r->bodies))) {
        publish_set(r, set);
        cl_frame_set_free(set);
    }
}

static void edge_on_layer(void *user, struct cl_layer *layer)
{
    struct role_edge *r = user;
    double now = mono_now();
    switch (seq_guard_check(&r->seq, layer->info.seq, now, net_tick_rate(r->net))) {
    case SEQ_REFUSE:
        if (now - r->refused_log_t >= 10) {
            r->refused_log_t = now;
            LOGW("cluster: a layer of seq %llu is outside the sim's stream (at seq %llu): refused (%llu so far)",
                 (unsigned long long)layer->info.seq, (unsigned long long)r->seq.last,
                 (unsigned long long)r->seq.refused);
        }
        cl_layer_free(layer);
        return;
    case SEQ_RESTART:
        publish_held(r); /* the old timeline's frames go out before it restarts */
        LOGW("cluster: the sim's frames count from seq %llu now (a restarted or another sim): the stream restarts",
             (unsigned long long)layer->info.seq);
        cl_collector_reset(r->collector);
        net_stream_restart(r->net);
        break;
    case SEQ_ACCEPT:
        break;
    }
    struct cl_frame_set *out[2];
    int k = cl_collector_add(r->collector, layer, r->want, out);
    for (int i = 0; i < k; i++) /* published after this dispatch: its BODY section may come behind it */
        if (edge_bodies_hold(r->bodies, out[i]) != 0) {
            publish_set(r, out[i]);
            cl_frame_set_free(out[i]);
        }
}

static void edge_on_bodies(void *user, bool is_section, const char *data, size_t len)
{
    struct role_edge *r = user;
    if (is_section) {
        if (edge_bodies_add_section(r->bodies, (const uint8_t *)data, len) != 0)
            LOGD("cluster: a BODY section that is not one (%zu bytes): dropped", len);
    } else if (net_adopt_bodies(r->net, data, len) != 0) {
        LOGW("cluster: a `bodies` message from the simulation that does not parse (%zu bytes): dropped", len);
    }
}

/* The demand the sim hears for key (cluster.h, cl_demand_bits): the key
 * while any client subscribes to it; its stream while a temporal one does;
 * keyframe (intra) tiles while a client is not temporal or lacks references. */
static void key_bits(struct role_edge *r, int key)
{
    cl_bit_set(r->demand.keys, key, r->count[key] > 0);
    cl_bit_set(r->demand.stream, key, r->count[key] > 0 && r->tcount[key] > 0);
    cl_bit_set(r->demand.wish, key, r->count[key] > 0 && (r->count[key] > r->tcount[key] || r->kcount[key] > 0));
}

static void edge_demand(void *user, int key, int delta, bool temporal)
{
    struct role_edge *r = user;
    if (key < 0 || key >= CL_KEYS)
        return;
    bool before = r->count[key] > 0;
    r->count[key] += delta;
    if (temporal)
        r->tcount[key] += delta;
    bool after = r->count[key] > 0;
    key_bits(r, key);
    cl_bit_set(r->want, key, after);
    cl_edge_set_demand_ex(r->link, &r->demand); /* subscribes and heartbeats at the pump's next round */
    if (before && !after) {
        /* Nobody wants the key any more: the pending frame may need no more
         * layers. Handed out at the wake-up, never from here: this hook runs
         * while a client's subscription is half changed (the ladder's step
         * counts the new layers before it serves them), and a frame
         * published now would reach that client's fan-out with the old
         * layers still in s->eff: it wished for their keyframes instead of
         * the new ones', and waited for keyframe tiles the sim never made. */
        r->recheck = true;
        net_wake(r->net);
    }
}

/* The pending frame, when a key left the wanted set since the last wake-up
 * (edge_demand) and it lacks no other layer now. */
static void check_pending(struct role_edge *r)
{
    if (!r->recheck)
        return;
    r->recheck = false;
    struct cl_frame_set *done = cl_collector_check(r->collector, r->want);
    if (done) {
        publish_set(r, done);
        cl_frame_set_free(done);
    }
}

static void edge_keyframes(void *user, int key, int delta)
{
    struct role_edge *r = user;
    if (key < 0 || key >= CL_KEYS)
        return;
    r->kcount[key] += delta;
    key_bits(r, key);
    cl_edge_set_demand_ex(r->link, &r->demand); /* the sim makes keyframe tiles from its next tick on */
}

/* ---- requests ---- */

static struct forward *forward_new(struct role_edge *r, bool hello, uint64_t serial, const cJSON *id)
{
    struct forward *fw = calloc(1, sizeof *fw);
    if (!fw)
        return NULL;
    fw->r = r;
    fw->hello = hello;
    fw->serial = serial;
    fw->id = id ? cJSON_Duplicate(id, 1) : NULL;
    fw->next = r->forwards;
    if (r->forwards)
        r->forwards->prev = fw;
    r->forwards = fw;
    return fw;
}

static void forward_free(struct forward *fw)
{
    if (fw->query)
        fw->r->queries--;
    if (fw->prev)
        fw->prev->next = fw->next;
    else
        fw->r->forwards = fw->next;
    if (fw->next)
        fw->next->prev = fw->prev;
    cJSON_Delete(fw->id);
    free(fw->text);
    free(fw);
}

static struct eprobe *eprobe_find(struct role_edge *r, uint64_t serial)
{
    for (struct eprobe *p = r->probes; p; p = p->next)
        if (p->serial == serial)
            return p;
    return NULL;
}

static void eprobe_drop(struct role_edge *r, uint64_t serial)
{
    for (struct eprobe **pp = &r->probes; *pp; pp = &(*pp)->next)
        if ((*pp)->serial == serial) {
            struct eprobe *p = *pp;
            *pp = p->next;
            free(p->text);
            free(p);
            return;
        }
}

static void send_unavailable(struct role_edge *r, uint64_t serial, const cJSON *id, int status)
{
    struct ctl_error e = { .code = "unavailable" };
    snprintf(e.message, sizeof e.message, "simulation unavailable (%s); try again", cl_strerror(status));
    char *text = control_print(control_error_msg(&e, id));
    if (text)
        net_send_text(r->net, serial, text);
    free(text);
}

static void send_probe_request(struct role_edge *r, int kind, uint64_t serial, const char *client, const char *text,
                               size_t len);

/* The sim's answer to a client's request, to that client: only a message of
 * a type such a request is answered with, checked as net_sim_message does;
 * anything else is answered `unavailable` (a rogue or broken answerer). */
static void relay(struct role_edge *r, uint64_t serial, const cJSON *id, const char *text, size_t len)
{
    static const char *const types[] = { "params", "error", "query_result", "probing", "probe_data",
                                         "launched", "steered", "removed", "claimed", NULL };
    cJSON *ok = net_sim_message(text, len, NET_SIM_REPLY_MAX, types);
    if (!ok) {
        LOGW("cluster: an answer from the simulation is not a valid message (%zu bytes); not relayed", len);
        send_unavailable(r, serial, id, CL_E_CORRUPT);
        return;
    }
    cJSON_Delete(ok);
    char *copy = malloc(len + 1);
    if (copy) {
        memcpy(copy, text, len);
        copy[len] = '\0';
        net_send_text(r->net, serial, copy);
        free(copy);
    }
}

/* The sim's answer to a probe request of any kind (or status: none came). */
static void on_probe_reply(struct role_edge *r, struct forward *fw, int status, const char *text, size_t len)
{
    struct eprobe *p = eprobe_find(r, fw->serial);
    if (p && (fw->probe == FW_KEEPALIVE || fw->probe == FW_RESEND))
        p->in_flight = false;
    char type[32], code[32];
    bool points = false;
    if (status == 0)
        control_reply_type(text, len, type, sizeof type, code, sizeof code, &points);
    switch (fw->probe) {
    case FW_PROBE:
        if (status != 0) {
            send_unavailable(r, fw->serial, fw->id, status);
        } else if (fw->gone) { /* its client left while the sim set it: end it there too */
            if (strcmp(type, "probing") == 0 && points)
                send_probe_request(r, FW_END, fw->serial, fw->client, NULL, 0);
        } else {
            relay(r, fw->serial, fw->id, text, len);
            if (strcmp(type, "probing") == 0 && !points) {
                eprobe_drop(r, fw->serial);
            } else if (strcmp(type, "probing") == 0) {
                if (!p && (p = calloc(1, sizeof *p))) {
                    p->serial = fw->serial;
                    snprintf(p->client, sizeof p->client, "%s", fw->client);
                    p->next = r->probes;
                    r->probes = p;
                }
                if (p) {
                    free(p->text);
                    p->text = fw->text;
                    p->len = fw->len;
                    fw->text = NULL;
                }
            }
        }
        break;
    case FW_KEEPALIVE:
        if (status == 0 && p && strcmp(code, "unknown_probe") == 0) { /* a new sim: probe again */
            p->in_flight = true;
            send_probe_request(r, FW_RESEND, p->serial, p->client, p->text, p->len);
        } else if (status == 0 && p && strcmp(type, "error") == 0) {
            relay(r, p->serial, NULL, text, len);
            eprobe_drop(r, p->serial);
        }
        break;
    case FW_RESEND:
        if (status == 0 && p && strcmp(type, "error") == 0) { /* e.g. busy on the new sim: the probe has ended */
            relay(r, p->serial, NULL, text, len);
            eprobe_drop(r, p->serial);
        }
        break;
    default:
        break;
    }
}

static void on_reply(void *ctx, int status, const char *text, size_t len)
{
    struct forward *fw = ctx;
    struct role_edge *r = fw->r;
    if (fw->probe != FW_NONE) {
        on_probe_reply(r, fw, status, text, len);
    } else if (fw->hello) {
        r->hello_in_flight = false;
        if (status == 0 && net_adopt_hello(r->net, text, len) == 0) {
            r->hello_needed = false;
            LOGI("cluster: hello from the sim (params_version in force now)");
        } else {
            LOGD("cluster: no hello from the sim: %s (asking again)", status ? cl_strerror(status) : "bad hello");
        }
    } else if (fw->own) {
        /* the owners list: nothing to tell anyone */
    } else if (status == 0) {
        char type[32], code[32];
        bool points;
        control_reply_type(text, len, type, sizeof type, code, sizeof code, &points);
        if (fw->id || strcmp(type, "steered") != 0) /* a steer without an id is answered only when it fails */
            relay(r, fw->serial, fw->id, text, len);
        if (strcmp(code, "too_many_bodies") == 0) /* refused before it took a launch: the bucket keeps it */
            net_body_refused(r->net, fw->serial);
    } else {
        send_unavailable(r, fw->serial, fw->id, status);
    }
    forward_free(fw);
}

/* One hello request at a time; retried (every HELLO_RETRY s, from the
 * wake-ups) until one succeeds, so the cache catches up after any outage. */
#define HELLO_RETRY 0.5
static void request_hello(struct role_edge *r)
{
    r->hello_needed = true;
    if (r->hello_in_flight)
        return;
    struct forward *fw = forward_new(r, true, 0, NULL);
    if (!fw)
        return;
    r->hello_t = mono_now();
    r->hello_in_flight = true;
    if (cl_edge_request(r->link, CL_KIND_HELLO, "", "", 0, on_reply, fw) != CL_OK) {
        r->hello_in_flight = false;
        forward_free(fw);
    }
}

static void edge_forward(void *user, uint64_t serial, const char *client_id, const void *id_json,
                         const char *text, size_t len)
{
    struct role_edge *r = user;
    struct forward *fw = forward_new(r, false, serial, id_json);
    if (!fw) {
        send_unavailable(r, serial, id_json, CL_E_NOMEM);
        return;
    }
    int rc = cl_edge_request(r->link, CL_KIND_CTL, client_id, text, len, on_reply, fw);
    if (rc != CL_OK) {
        send_unavailable(r, serial, id_json, rc);
        forward_free(fw);
    }
}

/* Point queries and probes (PROTOCOL.md §7.4) go to the sim, whose answer
 * is relayed as it is. In flight at most EDGE_QUERIES_PER_CLIENT per client
 * and EDGE_QUERIES_TOTAL for the edge: a query costs the sim milliseconds
 * and the edge a pending entry until answered or timed out (5 s). */
#define EDGE_QUERIES_PER_CLIENT 4
#define EDGE_QUERIES_TOTAL 64
static bool over_bounds(struct role_edge *r, uint64_t serial, const void *id_json)
{
    int mine = 0;
    for (struct forward *fw = r->forwards; fw; fw = fw->next)
        mine += fw->query && fw->serial == serial;
    if (mine < EDGE_QUERIES_PER_CLIENT && r->queries < EDGE_QUERIES_TOTAL)
        return false;
    struct ctl_error e = { .code = "busy" };
    snprintf(e.message, sizeof e.message,
             "%d queries and probes %s on their way to the simulation through this edge (at most %d per client, "
             "%d in all); try again when one is answered", mine >= EDGE_QUERIES_PER_CLIENT ? mine : r->queries,
             mine >= EDGE_QUERIES_PER_CLIENT ? "of this client are" : "are", EDGE_QUERIES_PER_CLIENT,
             EDGE_QUERIES_TOTAL);
    char *out = control_print(control_error_msg(&e, id_json));
    if (out)
        net_send_text(r->net, serial, out);
    free(out);
    return true;
}

static void edge_forward_query(void *user, uint64_t serial, const char *client_id, const void *id_json,
                               const char *text, size_t len)
{
    struct role_edge *r = user;
    if (over_bounds(r, serial, id_json))
        return;
    struct forward *fw = forward_new(r, false, serial, id_json);
    if (!fw) {
        send_unavailable(r, serial, id_json, CL_E_NOMEM);
        return;
    }
    fw->query = true;
    r->queries++;
    int rc = cl_edge_request(r->link, CL_KIND_QUERY, client_id, text, len, on_reply, fw);
    if (rc != CL_OK) {
        send_unavailable(r, serial, id_json, rc);
        forward_free(fw);
    }
}

/* A probe request of the edge's own (keepalive: no body; resend; end: an
 * empty probe): answered in on_probe_reply, never to a client directly. */
static void send_probe_request(struct role_edge *r, int kind, uint64_t serial, const char *client, const char *text,
                               size_t len)
{
    static const char end[] = "{\"type\":\"probe\",\"points\":[]}";
    struct forward *fw = forward_new(r, false, serial, NULL);
    if (!fw)
        return;
    fw->probe = kind;
    snprintf(fw->client, sizeof fw->client, "%s", client);
    if (kind == FW_END) {
        text = end;
        len = strlen(end);
    } else if (kind == FW_KEEPALIVE) {
        text = "";
        len = 0;
    }
    if (cl_edge_request(r->link, CL_KIND_PROBE, client, text, len, on_reply, fw) != CL_OK) {
        struct eprobe *p = eprobe_find(r, serial);
        if (p)
            p->in_flight = false;
        forward_free(fw);
    }
}

static void edge_forward_probe(void *user, uint64_t serial, const char *client_id, const void *id_json,
                               const char *text, size_t len)
{
    struct role_edge *r = user;
    if (over_bounds(r, serial, id_json))
        return;
    struct forward *fw = forward_new(r, false, serial, id_json);
    char *copy = malloc(len ? len : 1);
    if (!fw || !copy) {
        free(copy);
        if (fw)
            forward_free(fw);
        send_unavailable(r, serial, id_json, CL_E_NOMEM);
        return;
    }
    memcpy(copy, text, len);
    fw->text = copy;
    fw->len = len;
    fw->query = true;
    fw->probe = FW_PROBE;
    snprintf(fw->client, sizeof fw->client, "%s", client_id);
    r->queries++;
    int rc = cl_edge_request(r->link, CL_KIND_PROBE, client_id, text, len, on_reply, fw);
    if (rc != CL_OK) {
        send_unavailable(r, serial, id_json, rc);
        forward_free(fw);
    }
}

/* Every CL_PROBE_KEEPALIVE_S: one keepalive per live probe (none while one
 * is on its way), so the sim keeps it, or tells us it lost it. */
static void probe_keepalives(struct role_edge *r, double now)
{
    if (!r->probes || now - r->keepalive_t < CL_PROBE_KEEPALIVE_S || !cl_link_connected(r->link))
        return;
    r->keepalive_t = now;
    for (struct eprobe *p = r->probes; p; p = p->next)
        if (!p->in_flight) {
            p->in_flight = true;
            send_probe_request(r, FW_KEEPALIVE, p->serial, p->client, NULL, 0);
        }
}

static void edge_on_probe_data(void *user, const char *by, const char *text, size_t len)
{
    struct role_edge *r = user;
    static const char *const types[] = { "probe_data", NULL };
    cJSON *ok = net_sim_message(text, len, NET_SIM_REPLY_MAX, types);
    if (!ok)
        return; /* not a probe_data the sim would send: never relayed */
    cJSON_Delete(ok);
    for (struct eprobe *p = r->probes; p; p = p->next)
        if (strcmp(p->client, by) == 0) {
            net_send_probe_data(r->net, p->serial, text);
            return;
        }
}

static void edge_client_gone(void *user, uint64_t serial)
{
    struct role_edge *r = user;
    for (struct forward *fw = r->forwards; fw; fw = fw->next)
        if (fw->serial == serial && !fw->hello)
            fw->gone = true;
    struct eprobe *p = eprobe_find(r, serial);
    if (p) {
        send_probe_request(r, FW_END, serial, p->client, NULL, 0); /* else the sim lets it expire */
        eprobe_drop(r, serial);
    }
}

/* ---- state ---- */

static void update_state(struct role_edge *r)
{
    enum edge_state s = !cl_link_connected(r->link) ? EDGE_NATS_DOWN : !cl_link_sim_up(r->link) ? EDGE_SIM_DOWN : EDGE_OK;
    if (s == r->state)
        return;
    bool first = r->state == EDGE_UNKNOWN;
    r->state = s;
    if (s == EDGE_OK)
        LOGI("cluster: simulation available");
    else
        LOGW("cluster: simulation unavailable (%s): clients stay connected, frames resume when it is back",
             s == EDGE_NATS_DOWN ? "no connection to NATS" : "no heartbeat from the sim");
    char text[256];
    snprintf(text, sizeof text, "{\"type\":\"status\",\"state\":\"%s\",\"message\":\"%s\"}", state_name[s],
             s == EDGE_OK ? "simulation available"
                          : s == EDGE_NATS_DOWN ? "simulation unavailable (message bus down, reconnecting)"
                                                : "simulation unavailable");
    net_set_status(r->net, s == EDGE_OK ? NULL : text, first ? NULL : text);
}

static void edge_on_state(void *user, enum cl_event ev)
{
    struct role_edge *r = user;
    LOGI("cluster: %s", cl_event_name(ev));
    if (ev == CL_EV_CONNECTED || ev == CL_EV_RECONNECTED || ev == CL_EV_SIM_UP || ev == CL_EV_SIM_NEW) {
        request_hello(r); /* the sim may have moved on (or restarted) meanwhile */
        r->keepalive_t = 0; /* and may have lost our probes: ask now */
    }
    update_state(r);
}

static void edge_on_params(void *user, const char *origin, const char *by, const char *text, size_t len)
{
    struct role_edge *r = user;
    /* Our own client got this event as the reply to its request (with its id). */
    bool ours = strcmp(origin, cl_link_name(r->link)) == 0 && by[0];
    if (net_broadcast_params(r->net, text, len, ours ? by : NULL) != 0)
        LOGW("cluster: ignoring a params event that does not parse");
}

/* Which of our clients that asked for bodies are still here, for the sim
 * (PROTOCOL.md §7.6 through an edge): when one leaves, and every
 * BODY_OWNERS_PERIOD_S (the sim counts a client gone whose edge falls silent). */
static void send_owners(struct role_edge *r, double now)
{
    if (!cl_link_connected(r->link) || !cl_link_sim_up(r->link))
        return;
    char *text = net_body_owners(r->net, now);
    if (!text)
        return;
    struct forward *fw = forward_new(r, false, 0, NULL);
    if (fw) {
        fw->own = true;
        if (cl_edge_request(r->link, CL_KIND_CTL, "", text, strlen(text), on_reply, fw) != CL_OK)
            forward_free(fw);
    }
    free(text);
}

static void edge_on_wake(void *user)
{
    struct role_edge *r = user;
    check_pending(r);
    cl_link_dispatch(r->link);
    publish_held(r);
    double now = mono_now();
    send_owners(r, now);
    if (r->hello_needed && !r->hello_in_flight && cl_link_connected(r->link) && now - r->hello_t >= HELLO_RETRY)
        request_hello(r);
    probe_keepalives(r, now);
}

static const char *edge_health(void *user, cJSON *obj)
{
    struct role_edge *r = user;
    update_state(r);
    cJSON_AddStringToObject(obj, "role", "edge");
    cJSON_AddStringToObject(obj, "cluster", state_name[r->state]);
    role_keys_json(r->want, obj);
    role_keys_json_as(r->demand.stream, obj, "streams");
    return r->state == EDGE_OK ? "ok" : "degraded";
}

static size_t edge_metrics(void *user, char *buf, size_t cap)
{
    struct role_edge *r = user;
    size_t off = role_link_metrics(r->link, buf, cap);
    struct cl_collector_stats cs;
    cl_collector_stats(r->collector, &cs);
    if (off < cap)
        off += (size_t)snprintf(buf + off, cap - off,
                                "# TYPE oceand_cluster_frames_total counter\noceand_cluster_frames_total %llu\n"
                                "# TYPE oceand_cluster_frames_partial_total counter\noceand_cluster_frames_partial_total %llu\n"
                                "# TYPE oceand_cluster_sim_up gauge\noceand_cluster_sim_up %d\n"
                                "# HELP oceand_cluster_layers_refused_total layers whose seq does not follow the sim's "
                                "stream (seq_guard.h)\n"
                                "# TYPE oceand_cluster_layers_refused_total counter\noceand_cluster_layers_refused_total %llu\n"
                                "# HELP oceand_cluster_new_chains_total frames from another sim process than the "
                                "last: temporal clients took keyframes\n"
                                "# TYPE oceand_cluster_new_chains_total counter\noceand_cluster_new_chains_total %llu\n",
                                (unsigned long long)cs.frames, (unsigned long long)cs.partial,
                                r->state == EDGE_OK ? 1 : 0, (unsigned long long)r->seq.refused,
                                (unsigned long long)r->new_chains);
    return off < cap ? off : (cap ? cap - 1 : 0);
}

struct role_edge *role_edge_open(const struct daemon_config *dc, struct net *n, char *err, size_t errlen)
{
    struct role_edge *r = calloc(1, sizeof *r);
    if (!r || !(r->collector = cl_collector_new()) || !(r->bodies = edge_bodies_new())) {
        if (r)
            cl_collector_free(r->collector);
        free(r);
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    r->net = n;
    struct cl_config cfg;
    role_link_config(dc, CL_ROLE_EDGE, &cfg);
    cfg.wake = net_wake;
    cfg.wake_user = n;
    cfg.user = r;
    cfg.h.on_state = edge_on_state;
    cfg.h.on_layer = edge_on_layer;
    cfg.h.on_params = edge_on_params;
    cfg.h.on_probe_data = edge_on_probe_data;
    cfg.h.on_bodies = edge_on_bodies;
    char lerr[256];
    r->link = cl_link_open(&cfg, lerr, sizeof lerr);
    if (!r->link) {
        snprintf(err, errlen, "NATS: %s", lerr);
        cl_collector_free(r->collector);
        edge_bodies_free(r->bodies);
        free(r);
        return NULL;
    }
    struct net_cluster_hooks h = {
        .user = r, .on_wake = edge_on_wake, .demand = edge_demand, .keyframes = edge_keyframes, .forward = edge_forward,
        .forward_query = edge_forward_query, .forward_probe = edge_forward_probe, .client_gone = edge_client_gone,
        .health = edge_health, .metrics = edge_metrics,
    };
    net_set_cluster(n, &h);
    update_state(r);
    request_hello(r);
    LOGI("cluster: role edge as %s (prefix %s)", cl_link_name(r->link),
         dc->nats_prefix[0] ? dc->nats_prefix : CL_DEFAULT_PREFIX);
    return r;
}

void role_edge_close(struct role_edge *r)
{
    if (!r)
        return;
    struct net_cluster_hooks none = { 0 };
    net_set_cluster(r->net, &none);
    cl_link_close(r->link); /* drops unanswered requests without calling back: free them here */
    while (r->forwards)
        forward_free(r->forwards);
    while (r->probes)
        eprobe_drop(r, r->probes->serial);
    cl_collector_free(r->collector);
    edge_bodies_free(r->bodies);
    free(r);
}

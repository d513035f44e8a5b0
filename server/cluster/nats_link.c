/* nats_link.c — the cluster link over the NATS C client (libnats): connect
 * with credentials/TLS, reconnect with backoff, one pump thread that does
 * every write to NATS, and one locked inbox drained by cl_link_dispatch on
 * the caller's thread. The threading contract is at the top of cluster.h. */
#include "cluster.h"

#include <errno.h>
#include <nats/nats.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define PUMP_TICK_S 0.05          /* the pump checks timeouts at least this often */
#define CLOSE_WAIT_S 5.0          /* how long close waits for the NATS callbacks to end */

static double mono_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static struct timespec mono_abs(double t)
{
    struct timespec ts;
    ts.tv_sec = (time_t)t;
    ts.tv_nsec = (long)((t - (double)ts.tv_sec) * 1e9);
    if (ts.tv_nsec >= 1000000000L) {
        ts.tv_sec++;
        ts.tv_nsec -= 1000000000L;
    }
    return ts;
}

/* ---- queues ---- */

enum out_type { OUT_LAYER, OUT_MSG };
struct out_item {
    struct out_item *next;
    enum out_type type;
    size_t bytes;                   /* counted against outbox_max_bytes */
    /* OUT_LAYER */
    struct cl_layer_info info;
    const uint8_t *data;
    const uint32_t *tile_off;
    void (*release)(void *);
    void *ctx;
    /* OUT_MSG */
    char subject[CL_SUBJECT_MAX];
    char reply[CL_SUBJECT_MAX];     /* "" = none */
    uint8_t *buf;
};

enum in_type { IN_STATE, IN_REQUEST, IN_LAYER, IN_PARAMS, IN_REPLY, IN_PROBE_DATA };
struct in_event {
    struct in_event *next;
    enum in_type type;
    enum cl_event ev;
    struct cl_request *req;
    struct cl_layer *layer;
    char origin[CL_NAME_MAX], by[CL_NAME_MAX];
    char *text;
    size_t len;
    int status;
    cl_reply_fn done;
    void *ctx;
};

struct pending {
    struct pending *next;
    uint64_t id;
    double deadline;
    cl_reply_fn done;
    void *ctx;
};

enum sub_kind { SUB_CTL, SUB_HELLO, SUB_DEMAND, SUB_PARAMS, SUB_STATUS, SUB_INBOX, SUB_LAYER, SUB_QUERY, SUB_PROBE, SUB_KINDS };
struct sub_ctx {
    struct cl_link *l;
    enum sub_kind kind;
};

struct cl_link {
    struct cl_config cfg;
    char prefix[CL_PREFIX_MAX + 1], name[CL_NAME_MAX];
    char subj[SUB_KINDS][CL_SUBJECT_MAX];
    char inbox[CL_SUBJECT_MAX];     /* edge: replies come to inbox.<id> */
    struct sub_ctx sctx[SUB_KINDS];
    natsOptions *opts;
    natsConnection *nc;
    natsSubscription *subs[SUB_KINDS];
    natsSubscription *layer_subs[CL_KEYS]; /* pump thread only */
    unsigned rng;                   /* reconnect jitter (reconnect thread only) */

    /* outbox and everything the pump works from */
    pthread_mutex_t out_lock;
    pthread_cond_t out_cond;
    struct out_item *out_head, **out_tail;
    size_t out_bytes;
    bool stop;
    uint8_t want[CL_KEY_BYTES];     /* edge: layers its clients want */
    bool want_changed;              /* edge: resubscribe and heartbeat now */
    char *status_text;              /* sim: heartbeat body */
    size_t status_len;
    struct pending *pending;        /* edge: requests waiting for a reply */
    uint64_t next_id;
    pthread_t pump;
    bool pump_started;

    /* inbox */
    pthread_mutex_t in_lock;
    struct in_event *in_head, **in_tail;
    int in_count;
    struct in_event *layer_ev[CL_KEYS]; /* the queued layer event of each key */
    struct cl_assembler *assembler;
    bool sim_up;
    double sim_last_seen;

    struct cl_demand *demand;       /* sim */
    atomic_bool connected;
    atomic_bool sim_up_flag;

    /* close: wait until NATS has finished calling us */
    pthread_mutex_t close_lock;
    pthread_cond_t close_cond;
    int subs_live;
    bool closed_cb;

    struct cl_stats st;             /* updated with __atomic builtins */
};

#define STAT_ADD(l, f, n) __atomic_fetch_add(&(l)->st.f, (uint64_t)(n), __ATOMIC_RELAXED)

const char *cl_event_name(enum cl_event ev)
{
    switch (ev) {
    case CL_EV_CONNECTED: return "connected";
    case CL_EV_DISCONNECTED: return "disconnected";
    case CL_EV_RECONNECTED: return "reconnected";
    case CL_EV_CLOSED: return "closed";
    case CL_EV_SIM_UP: return "sim_up";
    case CL_EV_SIM_DOWN: return "sim_down";
    }
    return "unknown";
}

const char *cl_link_name(const struct cl_link *l) { return l->name; }
bool cl_link_connected(struct cl_link *l) { return atomic_load(&l->connected); }
bool cl_link_sim_up(struct cl_link *l) { return atomic_load(&l->sim_up_flag); }

void cl_link_stats(struct cl_link *l, struct cl_stats *out)
{
#define LOAD(f) out->f = __atomic_load_n(&l->st.f, __ATOMIC_RELAXED);
    LOAD(layers_published) LOAD(parts_published) LOAD(bytes_published) LOAD(layers_dropped_outbox)
    LOAD(layers_dropped_offline) LOAD(layers_too_large) LOAD(parts_received) LOAD(layers_received)
    LOAD(layers_dropped_incomplete) LOAD(layers_dropped_inbox) LOAD(bad_messages) LOAD(requests_sent)
    LOAD(replies_received) LOAD(request_timeouts) LOAD(no_responders) LOAD(requests_received)
    LOAD(requests_dropped) LOAD(events_dropped) LOAD(disconnects) LOAD(reconnects) LOAD(demand_edges)
#undef LOAD
    if (l->assembler) {
        pthread_mutex_lock(&l->in_lock);
        out->layers_dropped_incomplete = cl_assembler_dropped(l->assembler);
        pthread_mutex_unlock(&l->in_lock);
    }
}

/* ---- inbox (NATS and pump threads push, the caller's thread drains) ---- */

static void event_free(struct in_event *e)
{
    if (!e)
        return;
    if (e->req) {
        free(e->req->body);
        free(e->req);
    }
    cl_layer_free(e->layer);
    free(e->text);
    free(e);
}

/* Appends e (or drops it when the inbox is full) and wakes the caller's
 * thread if the inbox was empty. Takes ownership. */
static void push_event(struct cl_link *l, struct in_event *e)
{
    bool wake = false, dropped = false;
    pthread_mutex_lock(&l->in_lock);
    if (l->in_count >= CL_INBOX_MAX && e->type != IN_STATE && e->type != IN_REPLY) {
        dropped = true; /* the dispatching thread is this far behind: shed load */
    } else {
        wake = l->in_head == NULL;
        e->next = NULL;
        *l->in_tail = e;
        l->in_tail = &e->next;
        l->in_count++;
    }
    pthread_mutex_unlock(&l->in_lock);
    if (dropped) {
        if (e->type == IN_REQUEST)
            STAT_ADD(l, requests_dropped, 1);
        else
            STAT_ADD(l, events_dropped, 1);
        event_free(e);
    }
    if (wake && l->cfg.wake)
        l->cfg.wake(l->cfg.wake_user);
}

static void push_state(struct cl_link *l, enum cl_event ev)
{
    struct in_event *e = calloc(1, sizeof *e);
    if (!e)
        return;
    e->type = IN_STATE;
    e->ev = ev;
    push_event(l, e);
}

static void push_reply(struct cl_link *l, cl_reply_fn done, void *ctx, int status, const uint8_t *text, size_t len)
{
    struct in_event *e = calloc(1, sizeof *e);
    if (!e)
        return;
    e->type = IN_REPLY;
    e->done = done;
    e->ctx = ctx;
    e->status = status;
    if (text) {
        e->text = malloc(len + 1);
        if (!e->text) {
            e->status = CL_E_NOMEM;
        } else {
            memcpy(e->text, text, len);
            e->text[len] = 0;
            e->len = len;
        }
    }
    push_event(l, e);
}

int cl_link_dispatch(struct cl_link *l)
{
    pthread_mutex_lock(&l->in_lock);
    struct in_event *e = l->in_head;
    l->in_head = NULL;
    l->in_tail = &l->in_head;
    l->in_count = 0;
    memset(l->layer_ev, 0, sizeof l->layer_ev);
    pthread_mutex_unlock(&l->in_lock);
    int n = 0;
    const struct cl_handlers *h = &l->cfg.h;
    void *u = l->cfg.user;
    while (e) {
        struct in_event *next = e->next;
        switch (e->type) {
        case IN_STATE:
            if (h->on_state)
                h->on_state(u, e->ev);
            break;
        case IN_REQUEST:
            if (h->on_request) {
                h->on_request(u, e->req);
                e->req = NULL; /* the handler answers it with cl_request_reply */
            }
            break;
        case IN_LAYER:
            if (h->on_layer) {
                h->on_layer(u, e->layer);
                e->layer = NULL;
            }
            break;
        case IN_PARAMS:
            if (h->on_params)
                h->on_params(u, e->origin, e->by, e->text, e->len);
            break;
        case IN_REPLY:
            if (e->done)
                e->done(e->ctx, e->status, e->text, e->len);
            break;
        case IN_PROBE_DATA:
            if (h->on_probe_data)
                h->on_probe_data(u, e->by, e->text, e->len);
            break;
        }
        event_free(e);
        e = next;
        n++;
    }
    return n;
}

/* ---- NATS callbacks (NATS library threads) ---- */

static void on_disconnected(natsConnection *nc, void *closure)
{
    struct cl_link *l = closure;
    atomic_store(&l->connected, false);
    STAT_ADD(l, disconnects, 1);
    push_state(l, CL_EV_DISCONNECTED);
}

static void kick_pump_demand(struct cl_link *l)
{
    if (l->cfg.role != CL_ROLE_EDGE)
        return;
    pthread_mutex_lock(&l->out_lock);
    l->want_changed = true; /* send our demand now: the sim may have lost it */
    pthread_cond_signal(&l->out_cond);
    pthread_mutex_unlock(&l->out_lock);
}

static void on_reconnected(natsConnection *nc, void *closure)
{
    struct cl_link *l = closure;
    atomic_store(&l->connected, true);
    STAT_ADD(l, reconnects, 1);
    push_state(l, CL_EV_RECONNECTED);
    kick_pump_demand(l);
}

static void on_connected(natsConnection *nc, void *closure)
{
    struct cl_link *l = closure;
    atomic_store(&l->connected, true);
    push_state(l, CL_EV_CONNECTED);
    kick_pump_demand(l);
}

static void on_closed(natsConnection *nc, void *closure)
{
    struct cl_link *l = closure;
    atomic_store(&l->connected, false);
    push_state(l, CL_EV_CLOSED);
    pthread_mutex_lock(&l->close_lock);
    l->closed_cb = true;
    pthread_cond_broadcast(&l->close_cond);
    pthread_mutex_unlock(&l->close_lock);
}

static void on_sub_complete(void *closure)
{
    struct cl_link *l = closure;
    pthread_mutex_lock(&l->close_lock);
    l->subs_live--;
    pthread_cond_broadcast(&l->close_cond);
    pthread_mutex_unlock(&l->close_lock);
}

static void on_async_error(natsConnection *nc, natsSubscription *sub, natsStatus err, void *closure)
{
    struct cl_link *l = closure;
    if (err == NATS_SLOW_CONSUMER)
        STAT_ADD(l, events_dropped, 1); /* the NATS library dropped inbound messages */
}

/* Exponential backoff with +-20 % jitter, from reconnect_min_s to reconnect_max_s. */
static int64_t reconnect_delay(natsConnection *nc, int attempts, void *closure)
{
    struct cl_link *l = closure;
    double d = l->cfg.reconnect_min_s;
    for (int i = 1; i < attempts && d < l->cfg.reconnect_max_s; i++)
        d *= 2;
    if (d > l->cfg.reconnect_max_s)
        d = l->cfg.reconnect_max_s;
    d *= 0.8 + 0.4 * (double)(rand_r(&l->rng) % 1001) / 1000.0;
    return (int64_t)(d * 1000);
}

static void handle_request(struct cl_link *l, natsMsg *msg, enum cl_kind want)
{
    struct cl_envelope env;
    const char *reply = natsMsg_GetReply(msg);
    if (cl_envelope_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &env) != 0 ||
        env.kind != want || !reply || !reply[0] || strlen(reply) >= CL_SUBJECT_MAX) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    struct in_event *e = calloc(1, sizeof *e);
    struct cl_request *r = calloc(1, sizeof *r);
    char *body = malloc((size_t)env.body_len + 1);
    if (!e || !r || !body) {
        free(e);
        free(r);
        free(body);
        STAT_ADD(l, requests_dropped, 1);
        return;
    }
    r->kind = env.kind;
    strcpy(r->origin, env.origin);
    strcpy(r->by, env.by);
    memcpy(body, env.body, env.body_len);
    body[env.body_len] = 0;
    r->body = body;
    r->len = env.body_len;
    strcpy(r->reply_to, reply);
    e->type = IN_REQUEST;
    e->req = r;
    STAT_ADD(l, requests_received, 1);
    push_event(l, e);
}

static void handle_demand(struct cl_link *l, natsMsg *msg)
{
    struct cl_envelope env;
    uint32_t ttl_ms;
    uint8_t bits[CL_KEY_BYTES];
    if (cl_envelope_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &env) != 0 ||
        env.kind != CL_KIND_DEMAND || !env.origin[0] ||
        cl_demand_body_parse(env.body, env.body_len, &ttl_ms, bits) != 0) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    if (cl_demand_update(l->demand, env.origin, bits, ttl_ms / 1000.0, mono_now()) != 0)
        STAT_ADD(l, bad_messages, 1); /* table full: this edge's demand is not counted */
}

/* A new event of this type carrying a NUL-terminated copy of env's body;
 * NULL (counted as dropped) when out of memory. */
static struct in_event *event_with_body(struct cl_link *l, const struct cl_envelope *env, enum in_type type)
{
    struct in_event *e = calloc(1, sizeof *e);
    char *text = malloc((size_t)env->body_len + 1);
    if (!e || !text) {
        free(e);
        free(text);
        STAT_ADD(l, events_dropped, 1);
        return NULL;
    }
    memcpy(text, env->body, env->body_len);
    text[env->body_len] = 0;
    e->type = type;
    e->text = text;
    e->len = env->body_len;
    return e;
}

static void handle_params(struct cl_link *l, natsMsg *msg)
{
    struct cl_envelope env;
    if (cl_envelope_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &env) != 0 ||
        env.kind != CL_KIND_PARAMS) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    struct in_event *e = event_with_body(l, &env, IN_PARAMS);
    if (!e)
        return;
    strcpy(e->origin, env.origin);
    strcpy(e->by, env.by);
    push_event(l, e);
}

static void handle_status(struct cl_link *l, natsMsg *msg)
{
    struct cl_envelope env;
    if (cl_envelope_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &env) != 0 ||
        env.kind != CL_KIND_STATUS) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    pthread_mutex_lock(&l->in_lock);
    l->sim_last_seen = mono_now();
    bool up = !l->sim_up;
    l->sim_up = true;
    pthread_mutex_unlock(&l->in_lock);
    if (up) {
        atomic_store(&l->sim_up_flag, true);
        push_state(l, CL_EV_SIM_UP);
        kick_pump_demand(l); /* a restarted sim knows no demand yet */
    }
}

static void handle_probe_data(struct cl_link *l, natsMsg *msg)
{
    struct cl_envelope env;
    if (cl_envelope_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &env) != 0 ||
        env.kind != CL_KIND_PROBE_DATA || !env.by[0]) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    struct in_event *e = event_with_body(l, &env, IN_PROBE_DATA);
    if (!e)
        return;
    strcpy(e->by, env.by);
    push_event(l, e);
}

static void handle_reply(struct cl_link *l, natsMsg *msg)
{
    const char *subj = natsMsg_GetSubject(msg);
    size_t il = strlen(l->inbox);
    char *end;
    if (strncmp(subj, l->inbox, il) != 0 || subj[il] != '.') {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    if (strcmp(subj + il + 1, "p") == 0) { /* the sim's probe_data for our clients */
        handle_probe_data(l, msg);
        return;
    }
    errno = 0;
    unsigned long long id = strtoull(subj + il + 1, &end, 10);
    if (errno || *end) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    int status = 0;
    struct cl_envelope env;
    memset(&env, 0, sizeof env);
    if (natsMsg_IsNoResponders(msg)) {
        status = CL_E_NO_RESPONDERS;
        STAT_ADD(l, no_responders, 1);
    } else if (cl_envelope_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &env) != 0 ||
               env.kind != CL_KIND_REPLY) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    pthread_mutex_lock(&l->out_lock);
    struct pending *p = NULL;
    for (struct pending **pp = &l->pending; *pp; pp = &(*pp)->next)
        if ((*pp)->id == id) {
            p = *pp;
            *pp = p->next;
            break;
        }
    pthread_mutex_unlock(&l->out_lock);
    if (!p)
        return; /* timed out already, or a duplicate answer */
    if (status == 0)
        STAT_ADD(l, replies_received, 1);
    push_reply(l, p->done, p->ctx, status, status == 0 ? env.body : NULL, env.body_len);
    free(p);
}

static void handle_layer(struct cl_link *l, natsMsg *msg)
{
    struct cl_layer_part part;
    if (cl_layer_part_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &part) != 0) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    STAT_ADD(l, parts_received, 1);
    struct cl_layer *layer = NULL;
    struct in_event *e = NULL;
    bool wake = false;
    pthread_mutex_lock(&l->in_lock);
    int rc = cl_assembler_add(l->assembler, &part, &layer);
    if (rc == 1) {
        int key = cl_info_key(&layer->info);
        struct in_event *q = l->layer_ev[key];
        if (q) {
            /* latest layer wins: the lws thread has not taken the older one yet */
            cl_layer_free(q->layer);
            q->layer = layer;
            STAT_ADD(l, layers_dropped_inbox, 1);
        } else if ((e = calloc(1, sizeof *e))) {
            e->type = IN_LAYER;
            e->layer = layer;
            wake = l->in_head == NULL;
            *l->in_tail = e;
            l->in_tail = &e->next;
            l->in_count++;
            l->layer_ev[key] = e;
        } else {
            cl_layer_free(layer);
            STAT_ADD(l, events_dropped, 1);
        }
        STAT_ADD(l, layers_received, 1);
    }
    pthread_mutex_unlock(&l->in_lock);
    if (rc < 0)
        STAT_ADD(l, bad_messages, 1);
    if (wake && l->cfg.wake)
        l->cfg.wake(l->cfg.wake_user);
}

static void on_msg(natsConnection *nc, natsSubscription *sub, natsMsg *msg, void *closure)
{
    struct sub_ctx *c = closure;
    struct cl_link *l = c->l;
    switch (c->kind) {
    case SUB_CTL: handle_request(l, msg, CL_KIND_CTL); break;
    case SUB_HELLO: handle_request(l, msg, CL_KIND_HELLO); break;
    case SUB_QUERY: handle_request(l, msg, CL_KIND_QUERY); break;
    case SUB_PROBE: handle_request(l, msg, CL_KIND_PROBE); break;
    case SUB_DEMAND: handle_demand(l, msg); break;
    case SUB_PARAMS: handle_params(l, msg); break;
    case SUB_STATUS: handle_status(l, msg); break;
    case SUB_INBOX: handle_reply(l, msg); break;
    case SUB_LAYER: handle_layer(l, msg); break;
    case SUB_KINDS: break;
    }
    natsMsg_Destroy(msg);
}

/* ---- subscriptions ---- */

static natsSubscription *subscribe(struct cl_link *l, const char *subject, enum sub_kind kind)
{
    natsSubscription *sub = NULL;
    if (natsConnection_Subscribe(&sub, l->nc, subject, on_msg, &l->sctx[kind]) != NATS_OK)
        return NULL;
    pthread_mutex_lock(&l->close_lock);
    l->subs_live++;
    pthread_mutex_unlock(&l->close_lock);
    if (natsSubscription_SetOnCompleteCB(sub, on_sub_complete, l) != NATS_OK) {
        /* without the callback close could not wait for it: count it gone */
        pthread_mutex_lock(&l->close_lock);
        l->subs_live--;
        pthread_mutex_unlock(&l->close_lock);
    }
    return sub;
}

static void unsubscribe(natsSubscription **sub)
{
    if (!*sub)
        return;
    natsSubscription_Unsubscribe(*sub);
    natsSubscription_Destroy(*sub);
    *sub = NULL;
}

/* Pump thread: make the layer subscriptions match want. */
static void sync_layer_subs(struct cl_link *l, const uint8_t want[CL_KEY_BYTES])
{
    for (int k = 0; k < CL_KEYS; k++) {
        bool on = cl_bit(want, k);
        if (on && !l->layer_subs[k]) {
            char subj[CL_SUBJECT_MAX];
            if (cl_subject_layer(subj, sizeof subj, l->prefix, k) == 0)
                l->layer_subs[k] = subscribe(l, subj, SUB_LAYER);
        } else if (!on && l->layer_subs[k]) {
            unsubscribe(&l->layer_subs[k]);
        }
    }
}

/* ---- the pump ---- */

static void publish_msg(struct cl_link *l, struct out_item *it)
{
    natsStatus s = it->reply[0]
        ? natsConnection_PublishRequest(l->nc, it->subject, it->reply, it->buf, (int)it->bytes)
        : natsConnection_Publish(l->nc, it->subject, it->buf, (int)it->bytes);
    if (s == NATS_OK)
        STAT_ADD(l, bytes_published, it->bytes);
}

static void publish_layer(struct cl_link *l, struct out_item *it, uint8_t **scratch, size_t *scap)
{
    if (natsConnection_Status(l->nc) != NATS_CONN_STATUS_CONNECTED) {
        STAT_ADD(l, layers_dropped_offline, 1); /* a stale layer is worth nothing after reconnecting */
        return;
    }
    char subj[CL_SUBJECT_MAX];
    if (cl_subject_layer(subj, sizeof subj, l->prefix, cl_info_key(&it->info)) != 0)
        return;
    int64_t maxp = natsConnection_GetMaxPayload(l->nc);
    if (maxp <= 0)
        maxp = 1 << 20;
    int total = it->info.tiles_per_side * it->info.tiles_per_side;
    for (int first = 0; first < total;) {
        int k = cl_layer_part_tiles(it->tile_off, first, total, (size_t)maxp);
        if (k == 0) {
            STAT_ADD(l, layers_too_large, 1);
            return;
        }
        size_t size = cl_layer_part_size(k, it->tile_off[first + k] - it->tile_off[first]);
        if (size > *scap) {
            uint8_t *p = realloc(*scratch, size);
            if (!p)
                return;
            *scratch = p;
            *scap = size;
        }
        long w = cl_layer_part_write(*scratch, *scap, &it->info, first, k, it->data, it->tile_off);
        if (w < 0 || natsConnection_Publish(l->nc, subj, *scratch, (int)w) != NATS_OK) {
            STAT_ADD(l, layers_dropped_offline, 1);
            return;
        }
        STAT_ADD(l, parts_published, 1);
        STAT_ADD(l, bytes_published, w);
        first += k;
    }
    STAT_ADD(l, layers_published, 1);
}

static void item_free(struct out_item *it)
{
    if (it->type == OUT_LAYER && it->release)
        it->release(it->ctx);
    free(it->buf);
    free(it);
}

static void send_envelope(struct cl_link *l, const char *subject, const char *reply, enum cl_kind kind,
                          const char *by, const void *body, size_t len)
{
    uint8_t stackbuf[512];
    size_t size = cl_envelope_size(l->name, by, len);
    uint8_t *buf = size <= sizeof stackbuf ? stackbuf : malloc(size);
    if (!buf)
        return;
    long w = cl_envelope_write(buf, size, kind, l->name, by, body, len);
    if (w > 0) {
        natsStatus s = reply ? natsConnection_PublishRequest(l->nc, subject, reply, buf, (int)w)
                             : natsConnection_Publish(l->nc, subject, buf, (int)w);
        if (s == NATS_OK)
            STAT_ADD(l, bytes_published, w);
    }
    if (buf != stackbuf)
        free(buf);
}

static void *pump_main(void *arg)
{
    struct cl_link *l = arg;
    uint8_t *scratch = NULL;
    size_t scap = 0;
    double next_hb = 0;
    bool sent_empty = false;
    pthread_mutex_lock(&l->out_lock);
    while (!l->stop) {
        double now = mono_now();
        if (!l->out_head && !l->want_changed && now < next_hb) {
            double until = next_hb < now + PUMP_TICK_S ? next_hb : now + PUMP_TICK_S;
            struct timespec ts = mono_abs(until);
            pthread_cond_timedwait(&l->out_cond, &l->out_lock, &ts);
            now = mono_now();
        }
        struct out_item *items = l->out_head;
        l->out_head = NULL;
        l->out_tail = &l->out_head;
        l->out_bytes = 0;
        bool changed = l->want_changed;
        l->want_changed = false;
        uint8_t want[CL_KEY_BYTES];
        memcpy(want, l->want, sizeof want);
        char *status = NULL;
        size_t status_len = l->status_len;
        if (l->cfg.role == CL_ROLE_SIM && now >= next_hb && l->status_text && (status = malloc(status_len + 1)))
            memcpy(status, l->status_text, status_len + 1);
        /* requests past their deadline */
        struct pending *expired = NULL;
        for (struct pending **pp = &l->pending; *pp;) {
            if ((*pp)->deadline <= now) {
                struct pending *p = *pp;
                *pp = p->next;
                p->next = expired;
                expired = p;
            } else {
                pp = &(*pp)->next;
            }
        }
        pthread_mutex_unlock(&l->out_lock);

        while (items) {
            struct out_item *next = items->next;
            if (items->type == OUT_LAYER)
                publish_layer(l, items, &scratch, &scap);
            else
                publish_msg(l, items);
            item_free(items);
            items = next;
        }
        if (l->cfg.role == CL_ROLE_EDGE) {
            if (changed)
                sync_layer_subs(l, want);
            if (changed || now >= next_hb) {
                bool any = false;
                for (int i = 0; i < CL_KEY_BYTES; i++)
                    any |= want[i] != 0;
                /* an empty set is announced once (the sim forgets us at once), not every period */
                if (any || changed || !sent_empty) {
                    uint8_t body[CL_DEMAND_BODY];
                    cl_demand_body_write(body, (uint32_t)(l->cfg.demand_ttl_s * 1000), want);
                    send_envelope(l, l->subj[SUB_DEMAND], NULL, CL_KIND_DEMAND, "", body, sizeof body);
                    sent_empty = !any;
                }
                next_hb = now + l->cfg.heartbeat_s;
            }
            pthread_mutex_lock(&l->in_lock);
            bool down = l->sim_up && now - l->sim_last_seen > l->cfg.sim_timeout_s;
            if (down)
                l->sim_up = false;
            pthread_mutex_unlock(&l->in_lock);
            if (down) {
                atomic_store(&l->sim_up_flag, false);
                push_state(l, CL_EV_SIM_DOWN);
            }
        } else if (now >= next_hb) {
            send_envelope(l, l->subj[SUB_STATUS], NULL, CL_KIND_STATUS, "", status ? status : "{}",
                          status ? status_len : 2);
            next_hb = now + l->cfg.heartbeat_s;
        }
        free(status);
        while (expired) {
            struct pending *next = expired->next;
            STAT_ADD(l, request_timeouts, 1);
            push_reply(l, expired->done, expired->ctx, CL_E_TIMEOUT, NULL, 0);
            free(expired);
            expired = next;
        }
        pthread_mutex_lock(&l->out_lock);
    }
    pthread_mutex_unlock(&l->out_lock);
    free(scratch);
    return NULL;
}

/* Appends to the outbox; a layer beyond outbox_max_bytes pushes out the
 * oldest queued layers (released after the lock is dropped). */
static void push_out(struct cl_link *l, struct out_item *it)
{
    struct out_item *dropped = NULL;
    pthread_mutex_lock(&l->out_lock);
    if (it->type == OUT_LAYER) {
        for (struct out_item **pp = &l->out_head; *pp && l->out_bytes + it->bytes > l->cfg.outbox_max_bytes;) {
            if ((*pp)->type == OUT_LAYER) {
                struct out_item *d = *pp;
                *pp = d->next;
                l->out_bytes -= d->bytes;
                d->next = dropped;
                dropped = d;
            } else {
                pp = &(*pp)->next;
            }
        }
        /* repair the tail after removals */
        l->out_tail = &l->out_head;
        while (*l->out_tail)
            l->out_tail = &(*l->out_tail)->next;
    }
    it->next = NULL;
    *l->out_tail = it;
    l->out_tail = &it->next;
    l->out_bytes += it->bytes;
    pthread_cond_signal(&l->out_cond);
    pthread_mutex_unlock(&l->out_lock);
    while (dropped) {
        struct out_item *next = dropped->next;
        STAT_ADD(l, layers_dropped_outbox, 1);
        item_free(dropped);
        dropped = next;
    }
}

static int push_envelope(struct cl_link *l, const char *subject, const char *reply, enum cl_kind kind,
                         const char *by, const void *body, size_t len)
{
    if (strlen(subject) >= CL_SUBJECT_MAX || (reply && strlen(reply) >= CL_SUBJECT_MAX))
        return CL_E_ARG;
    size_t size = cl_envelope_size(l->name, by, len);
    struct out_item *it = calloc(1, sizeof *it);
    uint8_t *buf = malloc(size);
    long w = it && buf ? cl_envelope_write(buf, size, kind, l->name, by, body, len) : CL_E_NOMEM;
    if (w < 0) {
        free(it);
        free(buf);
        return (int)w;
    }
    it->type = OUT_MSG;
    it->buf = buf;
    it->bytes = (size_t)w;
    strcpy(it->subject, subject);
    if (reply)
        strcpy(it->reply, reply);
    push_out(l, it);
    return CL_OK;
}

/* ---- public API ---- */

int cl_sim_publish_layer(struct cl_link *l, const struct cl_layer_info *info, const uint8_t *data, size_t len,
                         const uint32_t *tile_off, void (*release)(void *ctx), void *ctx)
{
    int total = info ? info->tiles_per_side * info->tiles_per_side : 0;
    if (!l || l->cfg.role != CL_ROLE_SIM || !cl_layer_info_valid(info) || !tile_off || total < 1 ||
        tile_off[0] != 0 || tile_off[total] != len || len > CL_MAX_LAYER_BYTES) {
        if (release)
            release(ctx);
        return CL_E_ARG;
    }
    struct out_item *it = calloc(1, sizeof *it);
    if (!it) {
        if (release)
            release(ctx);
        return CL_E_NOMEM;
    }
    it->type = OUT_LAYER;
    it->info = *info;
    it->data = data;
    it->tile_off = tile_off;
    it->bytes = len;
    it->release = release;
    it->ctx = ctx;
    push_out(l, it);
    return CL_OK;
}

int cl_sim_publish_params(struct cl_link *l, const char *origin, const char *by, const char *text, size_t len)
{
    if (!l || l->cfg.role != CL_ROLE_SIM)
        return CL_E_ARG;
    /* origin is the edge that caused the change: the envelope's origin field */
    size_t size = cl_envelope_size(origin, by, len);
    struct out_item *it = calloc(1, sizeof *it);
    uint8_t *buf = malloc(size);
    long w = it && buf ? cl_envelope_write(buf, size, CL_KIND_PARAMS, origin, by, text, len) : CL_E_NOMEM;
    if (w < 0) {
        free(it);
        free(buf);
        return (int)w;
    }
    it->type = OUT_MSG;
    it->buf = buf;
    it->bytes = (size_t)w;
    strcpy(it->subject, l->subj[SUB_PARAMS]);
    push_out(l, it);
    return CL_OK;
}

void cl_sim_set_status(struct cl_link *l, const char *text, size_t len)
{
    char *copy = malloc(len + 1);
    if (!copy)
        return;
    memcpy(copy, text, len);
    copy[len] = 0;
    pthread_mutex_lock(&l->out_lock);
    free(l->status_text);
    l->status_text = copy;
    l->status_len = len;
    pthread_mutex_unlock(&l->out_lock);
}

int cl_sim_demand(struct cl_link *l, uint8_t out[CL_KEY_BYTES])
{
    if (!l->demand) {
        memset(out, 0, CL_KEY_BYTES);
        return 0;
    }
    int n = cl_demand_union(l->demand, mono_now(), out);
    __atomic_store_n(&l->st.demand_edges, n, __ATOMIC_RELAXED);
    return n;
}

void cl_request_reply(struct cl_link *l, struct cl_request *req, const char *text, size_t len)
{
    if (!req)
        return;
    if (text)
        push_envelope(l, req->reply_to, NULL, CL_KIND_REPLY, req->by, text, len);
    free(req->body);
    free(req);
}

int cl_edge_set_demand(struct cl_link *l, const uint8_t bits[CL_KEY_BYTES])
{
    if (!l || l->cfg.role != CL_ROLE_EDGE)
        return CL_E_ARG;
    for (int k = CL_KEYS; k < CL_KEY_BYTES * 8; k++)
        if (cl_bit(bits, k))
            return CL_E_ARG;
    pthread_mutex_lock(&l->out_lock);
    if (memcmp(l->want, bits, CL_KEY_BYTES) != 0) {
        memcpy(l->want, bits, CL_KEY_BYTES);
        l->want_changed = true;
        pthread_cond_signal(&l->out_cond);
    }
    pthread_mutex_unlock(&l->out_lock);
    return CL_OK;
}

int cl_sim_publish_probe_data(struct cl_link *l, const char *stream, const char *by, const char *text, size_t len)
{
    if (!l || l->cfg.role != CL_ROLE_SIM || !stream || !by || !by[0])
        return CL_E_ARG;
    pthread_mutex_lock(&l->out_lock);
    bool full = l->out_bytes > l->cfg.outbox_max_bytes;
    pthread_mutex_unlock(&l->out_lock);
    if (full || !atomic_load(&l->connected)) {
        STAT_ADD(l, events_dropped, 1);
        return full ? CL_E_FULL : CL_E_NOT_CONNECTED;
    }
    return push_envelope(l, stream, NULL, CL_KIND_PROBE_DATA, by, text, len);
}

int cl_edge_request(struct cl_link *l, enum cl_kind kind, const char *by, const char *body, size_t len,
                    cl_reply_fn done, void *ctx)
{
    if (!l || l->cfg.role != CL_ROLE_EDGE || (kind != CL_KIND_CTL && kind != CL_KIND_HELLO && kind != CL_KIND_QUERY &&
                                             kind != CL_KIND_PROBE))
        return CL_E_ARG;
    STAT_ADD(l, requests_sent, 1);
    if (!atomic_load(&l->connected)) {
        push_reply(l, done, ctx, CL_E_NOT_CONNECTED, NULL, 0); /* answered at the next dispatch */
        return CL_OK;
    }
    struct pending *p = calloc(1, sizeof *p);
    if (!p)
        return CL_E_NOMEM;
    p->done = done;
    p->ctx = ctx;
    pthread_mutex_lock(&l->out_lock);
    p->id = ++l->next_id;
    p->deadline = mono_now() + (kind == CL_KIND_QUERY ? l->cfg.query_timeout_s : l->cfg.request_timeout_s);
    p->next = l->pending;
    l->pending = p;
    pthread_mutex_unlock(&l->out_lock);
    char reply[CL_SUBJECT_MAX + 24]; /* push_envelope refuses one over CL_SUBJECT_MAX */
    snprintf(reply, sizeof reply, "%s.%llu", l->inbox, (unsigned long long)p->id);
    enum sub_kind sk = kind == CL_KIND_CTL ? SUB_CTL : kind == CL_KIND_HELLO ? SUB_HELLO
                     : kind == CL_KIND_QUERY ? SUB_QUERY : SUB_PROBE;
    int rc = push_envelope(l, l->subj[sk], reply, kind, by, body, len);
    if (rc != CL_OK) {
        pthread_mutex_lock(&l->out_lock);
        for (struct pending **pp = &l->pending; *pp; pp = &(*pp)->next)
            if (*pp == p) {
                *pp = p->next;
                break;
            }
        pthread_mutex_unlock(&l->out_lock);
        free(p);
    }
    return rc;
}

static void set_err(char *err, size_t errlen, const char *what, natsStatus s)
{
    const char *detail = nats_GetLastError(NULL);
    snprintf(err, errlen, "%s: %s%s%s", what, natsStatus_GetText(s), detail && *detail ? ": " : "",
             detail ? detail : "");
}

static void default_name(char *out, size_t cap, enum cl_role role)
{
    char host[64] = "host";
    gethostname(host, sizeof host - 1);
    host[sizeof host - 1] = 0;
    snprintf(out, cap, "%s-%.40s-%ld", role == CL_ROLE_SIM ? "sim" : "edge", host, (long)getpid());
    for (char *p = out; *p; p++)
        if (*p < 0x21 || *p > 0x7e)
            *p = '_';
}

static void link_free(struct cl_link *l)
{
    for (int i = 0; i < SUB_KINDS; i++)
        if (l->subs[i])
            natsSubscription_Destroy(l->subs[i]);
    for (int k = 0; k < CL_KEYS; k++)
        if (l->layer_subs[k])
            natsSubscription_Destroy(l->layer_subs[k]);
    if (l->nc)
        natsConnection_Destroy(l->nc);
    if (l->opts)
        natsOptions_Destroy(l->opts);
    while (l->out_head) {
        struct out_item *n = l->out_head->next;
        item_free(l->out_head);
        l->out_head = n;
    }
    while (l->in_head) {
        struct in_event *n = l->in_head->next;
        event_free(l->in_head);
        l->in_head = n;
    }
    while (l->pending) {
        struct pending *n = l->pending->next;
        free(l->pending);
        l->pending = n;
    }
    cl_assembler_free(l->assembler);
    cl_demand_free(l->demand);
    free(l->status_text);
    pthread_mutex_destroy(&l->out_lock);
    pthread_cond_destroy(&l->out_cond);
    pthread_mutex_destroy(&l->in_lock);
    pthread_mutex_destroy(&l->close_lock);
    pthread_cond_destroy(&l->close_cond);
    free(l);
}

#define TRY(call, what)                                                                                       \
    do {                                                                                                      \
        natsStatus s_ = (call);                                                                               \
        if (s_ != NATS_OK) {                                                                                  \
            set_err(err, errlen, what, s_);                                                                   \
            goto fail;                                                                                        \
        }                                                                                                     \
    } while (0)

struct cl_link *cl_link_open(const struct cl_config *cfg, char *err, size_t errlen)
{
    const char *prefix = cfg->prefix ? cfg->prefix : CL_DEFAULT_PREFIX;
    if (!cfg->url || !cfg->url[0]) {
        snprintf(err, errlen, "no NATS URL given (--nats nats://HOST:4222)");
        return NULL;
    }
    if (!cl_prefix_valid(prefix)) {
        snprintf(err, errlen, "invalid NATS subject prefix \"%s\": dot-separated tokens of A-Z a-z 0-9 _ -, "
                 "at most %d characters", prefix, CL_PREFIX_MAX);
        return NULL;
    }
    bool name_ok = !cfg->name || (cfg->name[0] && strlen(cfg->name) < CL_NAME_MAX);
    for (const char *p = cfg->name; name_ok && p && *p; p++)
        name_ok = *p >= 0x21 && *p <= 0x7e; /* what an envelope's origin may hold */
    if (!name_ok) {
        snprintf(err, errlen, "invalid cluster name: 1..%d printable characters without spaces", CL_NAME_MAX - 1);
        return NULL;
    }
    if (!cfg->tls_cert != !cfg->tls_key) {
        snprintf(err, errlen, "--nats-tls-cert and --nats-tls-key go together");
        return NULL;
    }
    struct cl_link *l = calloc(1, sizeof *l);
    if (!l) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    l->cfg = *cfg;
    struct cl_config *c = &l->cfg;
    if (c->heartbeat_s <= 0)
        c->heartbeat_s = c->role == CL_ROLE_SIM ? 0.5 : 1.0;
    if (c->demand_ttl_s <= 0)
        c->demand_ttl_s = 3.0;
    if (c->sim_timeout_s <= 0)
        c->sim_timeout_s = 2.0;
    if (c->request_timeout_s <= 0)
        c->request_timeout_s = 2.0;
    if (c->query_timeout_s <= 0)
        c->query_timeout_s = 5.0;
    if (c->reconnect_min_s <= 0)
        c->reconnect_min_s = 0.1;
    if (c->reconnect_max_s < c->reconnect_min_s)
        c->reconnect_max_s = c->reconnect_min_s > 2.0 ? c->reconnect_min_s : 2.0;
    if (!c->outbox_max_bytes)
        c->outbox_max_bytes = 64u << 20;
    snprintf(l->prefix, sizeof l->prefix, "%s", prefix);
    if (cfg->name)
        snprintf(l->name, sizeof l->name, "%s", cfg->name);
    else
        default_name(l->name, sizeof l->name, c->role);
    c->prefix = l->prefix;
    c->name = l->name;
    c->url = c->creds_file = c->tls_ca = c->tls_cert = c->tls_key = NULL; /* not kept: used below only */
    l->rng = (unsigned)getpid() ^ (unsigned)(uintptr_t)l;
    pthread_mutex_init(&l->out_lock, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&l->out_cond, &ca);
    pthread_condattr_destroy(&ca);
    pthread_mutex_init(&l->in_lock, NULL);
    pthread_mutex_init(&l->close_lock, NULL);
    pthread_cond_init(&l->close_cond, NULL);
    l->out_tail = &l->out_head;
    l->in_tail = &l->in_head;
    for (int i = 0; i < SUB_KINDS; i++)
        l->sctx[i] = (struct sub_ctx){ .l = l, .kind = (enum sub_kind)i };
    cl_subject(l->subj[SUB_CTL], CL_SUBJECT_MAX, l->prefix, CL_SUBJ_CTL);
    cl_subject(l->subj[SUB_HELLO], CL_SUBJECT_MAX, l->prefix, CL_SUBJ_HELLO);
    cl_subject(l->subj[SUB_QUERY], CL_SUBJECT_MAX, l->prefix, CL_SUBJ_QUERY);
    cl_subject(l->subj[SUB_PROBE], CL_SUBJECT_MAX, l->prefix, CL_SUBJ_PROBE);
    cl_subject(l->subj[SUB_DEMAND], CL_SUBJECT_MAX, l->prefix, CL_SUBJ_DEMAND);
    cl_subject(l->subj[SUB_PARAMS], CL_SUBJECT_MAX, l->prefix, CL_SUBJ_PARAMS);
    cl_subject(l->subj[SUB_STATUS], CL_SUBJECT_MAX, l->prefix, CL_SUBJ_STATUS);
    if (c->role == CL_ROLE_SIM && !(l->demand = cl_demand_new(1024))) {
        snprintf(err, errlen, "out of memory");
        goto fail;
    }
    if (c->role == CL_ROLE_EDGE && !(l->assembler = cl_assembler_new())) {
        snprintf(err, errlen, "out of memory");
        goto fail;
    }

    TRY(natsOptions_Create(&l->opts), "NATS options");
    natsOptions *o = l->opts;
    TRY(natsOptions_SetURL(o, cfg->url), "NATS URL");
    TRY(natsOptions_SetName(o, l->name), "NATS name");
    if (cfg->creds_file)
        TRY(natsOptions_SetUserCredentialsFromFiles(o, cfg->creds_file, NULL), "--nats-creds");
    if (cfg->tls_ca || cfg->tls_cert) {
        TRY(natsOptions_SetSecure(o, true), "NATS TLS");
        if (cfg->tls_ca)
            TRY(natsOptions_LoadCATrustedCertificates(o, cfg->tls_ca), "--nats-tls-ca");
        if (cfg->tls_cert)
            TRY(natsOptions_LoadCertificatesChain(o, cfg->tls_cert, cfg->tls_key), "--nats-tls-cert/--nats-tls-key");
    }
    TRY(natsOptions_SetTimeout(o, 2000), "NATS connect timeout");
    TRY(natsOptions_SetWriteDeadline(o, 2000), "NATS write deadline");
    /* a dead server (not just a closed socket) is noticed within ~6 s */
    TRY(natsOptions_SetPingInterval(o, 2000), "NATS ping interval");
    TRY(natsOptions_SetMaxPingsOut(o, 2), "NATS pings out");
    TRY(natsOptions_SetAllowReconnect(o, true), "NATS reconnect");
    TRY(natsOptions_SetMaxReconnect(o, -1), "NATS reconnect"); /* forever */
    TRY(natsOptions_SetCustomReconnectDelay(o, reconnect_delay, l), "NATS backoff");
    TRY(natsOptions_SetRetryOnFailedConnect(o, true, on_connected, l), "NATS retry");
    TRY(natsOptions_SetDisconnectedCB(o, on_disconnected, l), "NATS callbacks");
    TRY(natsOptions_SetReconnectedCB(o, on_reconnected, l), "NATS callbacks");
    TRY(natsOptions_SetClosedCB(o, on_closed, l), "NATS callbacks");
    TRY(natsOptions_SetErrorHandler(o, on_async_error, l), "NATS callbacks");
    /* one delivery thread for all our subscriptions (an edge may hold 150),
     * which also keeps the publisher's order across subjects */
    TRY(natsOptions_UseGlobalMessageDelivery(o, true), "NATS delivery");

    natsStatus s = natsConnection_Connect(&l->nc, o);
    if (s == NATS_OK) {
        atomic_store(&l->connected, true);
        push_state(l, CL_EV_CONNECTED);
    } else if (s != NATS_NOT_YET_CONNECTED) {
        set_err(err, errlen, "NATS connect", s);
        goto fail;
    }
    if (c->role == CL_ROLE_SIM) {
        if (!(l->subs[SUB_CTL] = subscribe(l, l->subj[SUB_CTL], SUB_CTL)) ||
            !(l->subs[SUB_HELLO] = subscribe(l, l->subj[SUB_HELLO], SUB_HELLO)) ||
            !(l->subs[SUB_QUERY] = subscribe(l, l->subj[SUB_QUERY], SUB_QUERY)) ||
            !(l->subs[SUB_PROBE] = subscribe(l, l->subj[SUB_PROBE], SUB_PROBE)) ||
            !(l->subs[SUB_DEMAND] = subscribe(l, l->subj[SUB_DEMAND], SUB_DEMAND))) {
            set_err(err, errlen, "NATS subscribe", NATS_ERR);
            goto fail_conn;
        }
    } else {
        natsInbox *inbox = NULL;
        TRY(natsInbox_Create(&inbox), "NATS inbox");
        snprintf(l->inbox, sizeof l->inbox, "%s", inbox);
        natsInbox_Destroy(inbox);
        char wild[CL_SUBJECT_MAX + 4];
        snprintf(wild, sizeof wild, "%s.*", l->inbox);
        if (!(l->subs[SUB_PARAMS] = subscribe(l, l->subj[SUB_PARAMS], SUB_PARAMS)) ||
            !(l->subs[SUB_STATUS] = subscribe(l, l->subj[SUB_STATUS], SUB_STATUS)) ||
            !(l->subs[SUB_INBOX] = subscribe(l, wild, SUB_INBOX))) {
            set_err(err, errlen, "NATS subscribe", NATS_ERR);
            goto fail_conn;
        }
    }
    if (pthread_create(&l->pump, NULL, pump_main, l) != 0) {
        snprintf(err, errlen, "cannot start the NATS pump thread");
        goto fail_conn;
    }
    l->pump_started = true;
    return l;

fail_conn:
    cl_link_close(l);
    return NULL;
fail:
    if (l->nc) {
        cl_link_close(l);
        return NULL;
    }
    link_free(l);
    return NULL;
}

void cl_link_close(struct cl_link *l)
{
    if (!l)
        return;
    if (l->pump_started) {
        pthread_mutex_lock(&l->out_lock);
        l->stop = true;
        pthread_cond_signal(&l->out_cond);
        pthread_mutex_unlock(&l->out_lock);
        pthread_join(l->pump, NULL);
    }
    if (l->nc) {
        natsConnection_Close(l->nc);
        /* Wait until NATS has called on_closed and finished every
         * subscription's handler: after that nothing refers to l. */
        double until = mono_now() + CLOSE_WAIT_S;
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        ts.tv_sec += (time_t)CLOSE_WAIT_S;
        pthread_mutex_lock(&l->close_lock);
        while ((!l->closed_cb || l->subs_live > 0) && mono_now() < until)
            if (pthread_cond_timedwait(&l->close_cond, &l->close_lock, &ts) == ETIMEDOUT)
                break;
        pthread_mutex_unlock(&l->close_lock);
    }
    link_free(l);
}

void cl_library_shutdown(void)
{
    nats_CloseAndWait(2000);
}

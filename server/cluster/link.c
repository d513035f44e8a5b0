/* link.c — the cluster link's lifecycle over the NATS C client (libnats):
 * options (credentials, TLS, deadlines), connect in the background and
 * reconnect with backoff, the connection-state callbacks, subscriptions and
 * the routing of delivered messages, and a close that waits until NATS has
 * stopped calling us. The threading contract is at the top of cluster.h;
 * who touches which field is in link_internal.h. */
#include "link_internal.h"

#include <errno.h>
#include <sys/random.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define CLOSE_WAIT_S 5.0          /* how long close waits for the NATS callbacks to end */

const char *cl_event_name(enum cl_event ev)
{
    switch (ev) {
    case CL_EV_CONNECTED: return "connected";
    case CL_EV_DISCONNECTED: return "disconnected";
    case CL_EV_RECONNECTED: return "reconnected";
    case CL_EV_CLOSED: return "closed";
    case CL_EV_SIM_UP: return "sim_up";
    case CL_EV_SIM_DOWN: return "sim_down";
    case CL_EV_SIM_NEW: return "sim_new";
    }
    return "unknown";
}

const char *cl_link_name(const struct cl_link *l) { return l->name; }
const char *cl_link_instance(const struct cl_link *l) { return l->instance; }
uint64_t cl_link_epoch(const struct cl_link *l) { return l->epoch; }
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

/* ---- connection events (NATS library threads) ---- */

static void on_disconnected(natsConnection *nc, void *closure)
{
    struct cl_link *l = closure;
    atomic_store(&l->connected, false);
    STAT_ADD(l, disconnects, 1);
    link_push_state(l, CL_EV_DISCONNECTED);
}

static void on_reconnected(natsConnection *nc, void *closure)
{
    struct cl_link *l = closure;
    atomic_store(&l->connected, true);
    STAT_ADD(l, reconnects, 1);
    link_push_state(l, CL_EV_RECONNECTED);
    link_kick_demand(l);
}

static void on_connected(natsConnection *nc, void *closure)
{
    struct cl_link *l = closure;
    atomic_store(&l->connected, true);
    link_push_state(l, CL_EV_CONNECTED);
    link_kick_demand(l);
}

static void on_closed(natsConnection *nc, void *closure)
{
    struct cl_link *l = closure;
    atomic_store(&l->connected, false);
    link_push_state(l, CL_EV_CLOSED);
    pthread_mutex_lock(&l->close_lock);
    l->closed_cb = true;
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

/* ---- subscriptions ---- */

/* NATS delivery thread: every subscription of the link comes here. */
static void on_msg(natsConnection *nc, natsSubscription *sub, natsMsg *msg, void *closure)
{
    struct sub_ctx *c = closure;
    struct cl_link *l = c->l;
    switch (c->kind) {
    case SUB_CTL: link_on_request(l, msg, CL_KIND_CTL); break;
    case SUB_HELLO: link_on_request(l, msg, CL_KIND_HELLO); break;
    case SUB_QUERY: link_on_request(l, msg, CL_KIND_QUERY); break;
    case SUB_PROBE: link_on_request(l, msg, CL_KIND_PROBE); break;
    case SUB_DEMAND: link_on_demand(l, msg); break;
    case SUB_PARAMS: link_on_params(l, msg); break;
    case SUB_BODIES: link_on_bodies(l, msg); break;
    case SUB_STATUS: link_on_status(l, msg); break;
    case SUB_INBOX: link_on_reply(l, msg); break;
    case SUB_LAYER: link_on_layer(l, msg); break;
    case SUB_KINDS: break;
    }
    natsMsg_Destroy(msg);
}

static void on_sub_complete(void *closure)
{
    struct cl_link *l = closure;
    pthread_mutex_lock(&l->close_lock);
    l->subs_live--;
    pthread_cond_broadcast(&l->close_cond);
    pthread_mutex_unlock(&l->close_lock);
}

natsSubscription *link_subscribe(struct cl_link *l, const char *subject, enum sub_kind kind)
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

void link_unsubscribe(natsSubscription **sub)
{
    if (!*sub)
        return;
    natsSubscription_Unsubscribe(*sub);
    natsSubscription_Destroy(*sub);
    *sub = NULL;
}

/* open: the role's subscriptions (an edge's replies and probe data come to
 * <inbox>.*); false when one fails. */
static bool subscribe_role(struct cl_link *l)
{
    static const enum sub_kind sim[] = { SUB_DEMAND, SUB_CTL, SUB_HELLO, SUB_QUERY, SUB_PROBE };
    static const enum sub_kind edge[] = { SUB_PARAMS, SUB_STATUS, SUB_INBOX, SUB_BODIES };
    bool is_sim = l->cfg.role == CL_ROLE_SIM;
    const enum sub_kind *kinds = is_sim ? sim : edge;
    /* A silent sim takes requests only once it acts (the pump subscribes them then). */
    size_t n = is_sim ? (l->cfg.standby ? 1 : sizeof sim / sizeof *sim) : sizeof edge / sizeof *edge;
    char wild[CL_SUBJECT_MAX + 4];
    snprintf(wild, sizeof wild, "%s.*", l->inbox);
    for (size_t i = 0; i < n; i++) {
        const char *subject = kinds[i] == SUB_INBOX ? wild : l->subj[kinds[i]];
        if (!(l->subs[kinds[i]] = link_subscribe(l, subject, kinds[i])))
            return false;
    }
    return true;
}

/* ---- open and close ---- */

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

/* The options cl_link_open refuses before it allocates anything; true if fine. */
static bool config_valid(const struct cl_config *cfg, const char *prefix, char *err, size_t errlen)
{
    if (!cfg->url || !cfg->url[0]) {
        snprintf(err, errlen, "no NATS URL given (--nats nats://HOST:4222)");
        return false;
    }
    if (!cl_prefix_valid(prefix)) {
        snprintf(err, errlen, "invalid NATS subject prefix \"%s\": dot-separated tokens of A-Z a-z 0-9 _ -, "
                 "at most %d characters", prefix, CL_PREFIX_MAX);
        return false;
    }
    bool name_ok = !cfg->name || (cfg->name[0] && strlen(cfg->name) < CL_NAME_MAX);
    for (const char *p = cfg->name; name_ok && p && *p; p++)
        name_ok = *p >= 0x21 && *p <= 0x7e; /* what an envelope's origin may hold */
    if (!name_ok) {
        snprintf(err, errlen, "invalid cluster name: 1..%d printable characters without spaces", CL_NAME_MAX - 1);
        return false;
    }
    if (!cfg->tls_cert != !cfg->tls_key) {
        snprintf(err, errlen, "--nats-tls-cert and --nats-tls-key go together");
        return false;
    }
    return true;
}

/* The documented defaults for every 0 in cluster.h's struct cl_config. */
static void config_defaults(struct cl_config *c)
{
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
        link_item_free(l->out_head);
        l->out_head = n;
    }
    while (l->in_head) {
        struct in_event *n = l->in_head->next;
        link_event_free(l->in_head);
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
    if (!config_valid(cfg, prefix, err, errlen))
        return NULL;
    struct cl_link *l = calloc(1, sizeof *l);
    if (!l) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    l->cfg = *cfg;
    struct cl_config *c = &l->cfg;
    config_defaults(c);
    snprintf(l->prefix, sizeof l->prefix, "%s", prefix);
    if (cfg->name)
        snprintf(l->name, sizeof l->name, "%s", cfg->name);
    else
        default_name(l->name, sizeof l->name, c->role);
    c->prefix = l->prefix;
    c->name = l->name;
    c->url = c->creds_file = c->tls_ca = c->tls_cert = c->tls_key = NULL; /* not kept: used below only */
    l->rng = (unsigned)getpid() ^ (unsigned)(uintptr_t)l;
    atomic_store(&l->standby, cfg->standby); /* before the pump's first heartbeat */
    /* Random, not the pid or the name: a restarted sim may get both again. */
    uint64_t id = 0;
    if (getrandom(&id, sizeof id, GRND_NONBLOCK) != (ssize_t)sizeof id)
        id = ((uint64_t)time(NULL) << 32) ^ (uint64_t)getpid() ^ (uint64_t)(uintptr_t)l;
    if (!id)
        id = 1; /* the layers' epoch is never 0 */
    l->epoch = id;
    snprintf(l->instance, sizeof l->instance, "%016llx", (unsigned long long)id);
    pthread_mutex_init(&l->out_lock, NULL);
    /* the pump waits with deadlines on the monotonic clock */
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
    cl_subject(l->subj[SUB_BODIES], CL_SUBJECT_MAX, l->prefix, CL_SUBJ_BODIES);
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
        link_push_state(l, CL_EV_CONNECTED);
    } else if (s != NATS_NOT_YET_CONNECTED) {
        set_err(err, errlen, "NATS connect", s);
        goto fail;
    }
    if (c->role == CL_ROLE_EDGE) {
        natsInbox *inbox = NULL;
        TRY(natsInbox_Create(&inbox), "NATS inbox");
        snprintf(l->inbox, sizeof l->inbox, "%s", inbox);
        natsInbox_Destroy(inbox);
    }
    if (!subscribe_role(l)) {
        set_err(err, errlen, "NATS subscribe", NATS_ERR);
        goto fail_conn;
    }
    if (link_pump_start(l) != 0) {
        snprintf(err, errlen, "cannot start the NATS pump thread");
        goto fail_conn;
    }
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
    link_pump_stop(l);
    if (l->nc) {
        natsConnection_Close(l->nc);
        /* Wait until NATS has called on_closed and finished every
         * subscription's handler: after that nothing refers to l. */
        double until = link_now() + CLOSE_WAIT_S;
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        ts.tv_sec += (time_t)CLOSE_WAIT_S;
        pthread_mutex_lock(&l->close_lock);
        while ((!l->closed_cb || l->subs_live > 0) && link_now() < until)
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

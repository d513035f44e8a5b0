/* dispatch.c — control messages from clients (PROTOCOL.md §7): the rate
 * limit, set / pause / resume, subscribe, ping; and the answers to sets that
 * come back from the simulation, broadcast as `params` or returned to the
 * sender as an error.
 *
 * A set is checked here against `view` (the applied parameters plus every
 * set still on its way), sent to the sim with an opaque tag, and remembered
 * as a struct request until the sim answers that tag. */
#include "net_internal.h"

#include "clock.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "metrics.h"
#include "query_worker.h"
#include "sim_thread.h"

/* ---- subscriptions and demand ---- */

void dispatch_demand(struct net *n, const struct subscription *sub, int delta)
{
    if (!n->sim && !n->cluster.demand)
        return;
    int keys[LAYER_KEYS_ALL] = { 0 };
    subscription_layer_keys(sub, keys, 1);
    for (int key = 0; key < LAYER_KEYS_ALL; key++)
        if (keys[key]) {
            if (n->cluster.demand) /* edge: the sim is elsewhere */
                n->cluster.demand(n->cluster.user, key, delta, sub->temporal);
            else {
                sim_demand(n->sim, key, delta);
                if (sub->temporal) /* the temporal codec: every cascade's layers */
                    sim_demand_temporal(n->sim, key, delta);
            }
        }
}

/* ---- sets in flight ---- */

static struct request *request_of(lws_dll2_t *d) { return lws_container_of(d, struct request, list); }

static void respond(struct session *s, const struct remote *rm, cJSON *msg)
{
    if (s) {
        session_queue_json(s, msg);
        return;
    }
    char *text = control_print(msg);
    rm->reply(rm->ctx, text ? text : "{\"type\":\"error\",\"code\":\"internal\",\"message\":\"out of memory\"}");
    free(text);
}

void dispatch_respond_error(struct session *s, const struct remote *rm, const struct ctl_error *e, const cJSON *id)
{
    if (s) {
        session_send_error(s, e, id);
        return;
    }
    atomic_fetch_add(&g_metrics.control_errors, 1);
    respond(NULL, rm, control_error_msg(e, id));
}

static void request_free(struct request *r)
{
    lws_dll2_remove(&r->list);
    cJSON_Delete(r->id);
    free(r);
}

void dispatch_free_requests(struct net *n)
{
    while (n->requests.head) {
        struct request *r = request_of(n->requests.head);
        if (r->reply)
            r->reply(r->reply_ctx, NULL); /* dropped unanswered: the edge times it out */
        request_free(r);
    }
}

static struct remote_query *remote_query_of(lws_dll2_t *d) { return lws_container_of(d, struct remote_query, list); }

void net_drop_remote_requests(struct net *n)
{
    body_net_drop_remote(n);
    while (n->remote_queries.head) {
        struct remote_query *rq = remote_query_of(n->remote_queries.head);
        lws_dll2_remove(&rq->list);
        rq->reply(rq->reply_ctx, NULL);
        free(rq);
    }
    for (lws_dll2_t *d = lws_dll2_get_head(&n->requests), *next; d; d = next) {
        next = d->next;
        struct request *r = request_of(d);
        if (r->reply) {
            r->reply(r->reply_ctx, NULL);
            request_free(r);
        }
    }
}

/* view = applied + every set not answered yet, in order: what the sim will
 * have once they are applied, so the next set is checked on that. */
static void rebuild_view(struct net *n)
{
    n->view = n->applied;
    for (lws_dll2_t *d = lws_dll2_get_head(&n->requests); d; d = d->next)
        n->view = params_with(&n->view, &request_of(d)->values, request_of(d)->mask);
}

/* `params` names who caused it: the client id, and the display name if any. */
static cJSON *with_name(cJSON *m, const char *name)
{
    if (m && name && name[0])
        cJSON_AddStringToObject(m, "by_name", name);
    return m;
}

/* name: the message's own checked "name" (applied with the set), or NULL. */
/* A change of N rebuilds the grids and FFT plans (seconds at N = 2048) and
 * costs every viewer frames while it lasts: one at a time for the whole
 * daemon, and after a slow one (over REPLAN_SLOW_S to build) the next waits
 * as long as it took, so that a controller flipping N keeps the sea
 * rebuilding at most half of the time; the others get `busy` at once, with
 * the wait. A quick rebuild (small N) is not held: a person stepping
 * through sizes never waits. */
#define REPLAN_SLOW_S 1.0
static bool replan_allowed(struct net *n, struct session *s, const struct remote *rm, uint64_t changed,
                           const cJSON *id)
{
    if (!(changed & params_mask(PARAM_REPLAN)))
        return true;
    double wait = n->replan_t > 0 ? n->replan_t + n->replan_hold - mono_now() : 0;
    if (n->replans_in_flight <= 0 && wait <= 0)
        return true;
    struct ctl_error e = { .code = "busy" };
    snprintf(e.param, sizeof e.param, "resolution");
    if (n->replans_in_flight > 0)
        snprintf(e.message, sizeof e.message, "the grid is being rebuilt for another resolution; try again when it is applied");
    else
        snprintf(e.message, sizeof e.message, "the grid was just rebuilt for a new resolution; try again in %.1f s",
                 wait);
    dispatch_respond_error(s, rm, &e, id);
    return false;
}

static const struct ctl_error once_duplicate = {
    .code = "duplicate", .message = "this \"once\" was received already, on another connection: applied once"
};

/* Has a set/pause/resume with this "once" key come in within NET_ONCE_TTL_S?
 * If not, remember it (in the oldest slot). A client that sends one change
 * on both its connections (PROTOCOL.md §1.2) has it applied once, whichever
 * copy a lost packet delays. Kept where sets are applied: a --role all
 * daemon, or the sim of a cluster for every edge's clients (the key rides
 * in the forwarded text), so two copies through two edges count as one. */
static bool once_seen(struct net *n, const char *key)
{
    double now = mono_now();
    for (int i = 0; i < NET_ONCE_SLOTS; i++)
        if (n->once[i].key[0] && now - n->once[i].t < NET_ONCE_TTL_S && strcmp(n->once[i].key, key) == 0)
            return true;
    struct once_seen *o = &n->once[n->once_next];
    n->once_next = (n->once_next + 1) % NET_ONCE_SLOTS;
    snprintf(o->key, sizeof o->key, "%s", key);
    o->t = now;
    return false;
}

/* A checked change: out is the view after it, changed the rows it changes,
 * sea a new measured sea (taken: freed whatever happens) or NULL. */
void dispatch_submit_change(struct net *n, struct session *s, const struct remote *rm, const struct ocean_params *out,
                            uint64_t changed, const char *name, const cJSON *id, struct sea_spectrum *sea)
{
    if (!replan_allowed(n, s, rm, changed, id)) {
        free(sea);
        return;
    }
    if (name && s) {
        snprintf(s->name, sizeof s->name, "%s", name);
        body_net_renamed(n, s); /* its bodies show the new name */
    }
    const char *by_name = name ? name : s ? s->name : "";
    if (!changed && !sea) {
        respond(s, rm, with_name(control_params_msg(&n->view, n->applied_version, 0, s ? s->client_id : rm->by, id),
                                 by_name));
        return;
    }
    struct sim_set *set = calloc(1, sizeof *set);
    struct request *r = calloc(1, sizeof *r);
    cJSON *idc = id ? cJSON_Duplicate(id, 1) : NULL;
    if (!set || !r || (id && !idc)) {
        free(set);
        free(r);
        free(sea);
        cJSON_Delete(idc);
        struct ctl_error oom = { .code = "internal", .message = "out of memory" };
        dispatch_respond_error(s, rm, &oom, id);
        return;
    }
    r->tag = set->tag = ++n->next_tag;
    if (s) {
        r->serial = s->serial;
        snprintf(r->by, sizeof r->by, "%s", s->client_id);
    } else {
        r->reply = rm->reply;
        r->reply_ctx = rm->ctx;
        snprintf(r->by, sizeof r->by, "%s", rm->by);
        snprintf(r->origin, sizeof r->origin, "%s", rm->origin);
    }
    snprintf(r->by_name, sizeof r->by_name, "%s", by_name);
    r->id = idc;
    r->values = set->values = *out;
    r->mask = set->mask = changed;
    set->sea = sea;
    r->sea = sea != NULL;
    n->seas_in_flight += r->sea;
    lws_dll2_add_tail(&r->list, &n->requests);
    if (changed & params_mask(PARAM_REPLAN))
        n->replans_in_flight++;
    n->view = *out;
    sim_submit(n->sim, set);
}

/* ---- answers from the sim ---- */

/* `params` for one applied set; with tile_size when N changed, since the
 * tile side follows N below the configured size (hello has it too). */
static cJSON *params_msg(struct net *n, const struct ocean_params *p, uint32_t version, uint64_t changed,
                         const char *by, const char *by_name, const cJSON *id, bool sea)
{
    cJSON *m = with_name(control_params_msg(p, version, changed, by, id), by_name);
    if (m && sea) /* a new measured sea, or a new grid under it: its summary */
        sea_net_add(n, m);
    if (m && (changed & params_mask(PARAM_REPLAN))) {
        cJSON_AddNumberToObject(m, "tile_size", net_tile_size(n));
        net_capacity_add(n, m); /* the encode budget follows N; ~1.5 kB, so only then */
    }
    return m;
}

/* What the other clients are told about the sets applied at one tick
 * boundary: ONE `params` for all of them (the last one's values, version
 * and sender; `changed` = every parameter any of them changed). One per set
 * made K controllers, each within its rate limit, send K x 20 `params` a
 * second to every client: 100 of them filled a well-behaved client's reply
 * queue until it was cut off (1008; test-hostile params_fanout). */
struct fanout_params {
    bool any;
    struct ocean_params params;
    uint32_t version;
    uint64_t changed;
    bool sea;                      /* one of them changed the sea's summary */
    uint64_t serial;               /* the last set's sender, if local (it has its own reply) */
    bool local;
    char by[64], origin[64];
    char by_name[CTL_NAME_BYTES];
};

static void answer(struct net *n, const struct sim_set *a, struct fanout_params *fp)
{
    n->applied = a->params; /* in force after this set, applied or refused */
    n->applied_version = a->version;
    bool sea = a->status == SIM_SET_APPLIED && a->sea_summary;
    if (sea) { /* a new sea, or a new grid under it: the summary from now on */
        free(n->sea_summary);
        n->sea_summary = a->sea_summary;
        ((struct sim_set *)a)->sea_summary = NULL; /* n has it now */
    }
    if (a->adopt) /* a take-over (sim_adopt): nobody asked; edges ask hello of the new sim */
        return;
    struct request *r = NULL;
    for (lws_dll2_t *d = lws_dll2_get_head(&n->requests); d && !r; d = d->next)
        if (request_of(d)->tag == a->tag)
            r = request_of(d);
    if (!r) {
        LOGE("answer for an unknown set (tag %llu)", (unsigned long long)a->tag);
        return;
    }
    struct session *origin = r->reply ? NULL : session_find(n, r->serial);
    struct remote rm = { .origin = r->origin, .by = r->by, .reply = r->reply, .ctx = r->reply_ctx };
    if (r->mask & params_mask(PARAM_REPLAN))
        n->replans_in_flight--;
    n->seas_in_flight -= r->sea;
    if (a->status == SIM_SET_APPLIED) {
        if (a->changed & params_mask(PARAM_REPLAN)) {
            n->trim_due = mono_now() + TRIM_DELAY_S;
            n->replan_t = mono_now();
            n->replan_hold = a->build_s > REPLAN_SLOW_S ? a->build_s : 0;
        }
        if (n->on_params)
            n->on_params(n->on_params_user, &n->applied, n->applied_version);
        fp->any = true;
        fp->params = a->params;
        fp->version = a->version;
        fp->changed |= a->changed;
        fp->sea |= sea;
        fp->serial = r->serial;
        fp->local = !r->reply;
        snprintf(fp->by, sizeof fp->by, "%s", r->by);
        snprintf(fp->origin, sizeof fp->origin, "%s", r->origin);
        snprintf(fp->by_name, sizeof fp->by_name, "%s", r->by_name);
        cJSON *mine = params_msg(n, &a->params, a->version, a->changed, r->by, r->by_name, r->id, sea || r->sea);
        if (origin)
            session_queue_json(origin, mine);
        else if (r->reply)
            respond(NULL, &rm, mine);
        else
            cJSON_Delete(mine);
    } else if (origin || r->reply) {
        struct ctl_error e = { .code = a->status == SIM_SET_INVALID         ? "invalid"
                                       : a->status == SIM_SET_VERSION_LIMIT ? "version_limit"
                                                                            : "internal" }; /* out of memory, not saved */
        snprintf(e.message, sizeof e.message, "%s", a->message);
        dispatch_respond_error(origin, &rm, &e, r->id);
    }
    r->reply = NULL;
    request_free(r);
}

void dispatch_answers(struct net *n)
{
    struct sim_set *a = sim_take_answers(n->sim);
    if (!a)
        return;
    struct fanout_params fp = { 0 };
    while (a) {
        struct sim_set *next = a->next;
        answer(n, a, &fp);
        sim_set_free(a);
        a = next;
    }
    rebuild_view(n);
    if (!fp.any)
        return;
    /* To everyone but the last set's sender, whose own reply said it all. */
    char *all = control_print(params_msg(n, &fp.params, fp.version, fp.changed, fp.by, fp.by_name, NULL, fp.sea));
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next)
        if (!(fp.local && session_of(d)->serial == fp.serial))
            session_queue_text(session_of(d), all, false);
    if (all && n->cluster.on_params_event) /* sim role: to every edge's clients */
        n->cluster.on_params_event(n->cluster.user, all, fp.origin, fp.by);
    free(all);
}

/* ---- messages ---- */

#define RATE_LIMITED_ID_MAX 256 /* bytes of a string (or number) id echoed in rate_limited (no amplification) */
#define REFUSED_PARSE_MAX 1024  /* bytes of a refused message parsed for its id: no more work than a unit */
#define BUDGET_BURST_S 0.1      /* --control-budget: a burst of at most 0.1 s of it (3 ticks at 30 Hz), */
#define BUDGET_DEBT_S 1.0       /* and a debt of at most 1 s of it (fair shares spent past it) */
#define SHARE_BURST_S 1.0       /* a client's fair share: 1 s of it saved up, */
#define SHARE_MIN 4.0           /* and at least 4 units (a few sets in a row) */

/* The request id of a message we will not otherwise parse (rate_limited,
 * busy): §7 promises it in every error a request causes. A detached copy, or
 * NULL for no id, a non-scalar one, a string over RATE_LIMITED_ID_MAX, or a
 * message over REFUSED_PARSE_MAX (a refusal must cost less than a parse). */
static cJSON *request_id(const char *text, size_t len)
{
    if (!text || len > REFUSED_PARSE_MAX)
        return NULL;
    cJSON *id = control_message_id(text, len); /* a number as sent, as in every other reply */
    bool echo = id && !cJSON_IsArray(id) && !cJSON_IsObject(id) &&
                !((cJSON_IsString(id) || cJSON_IsRaw(id)) && strlen(id->valuestring) > RATE_LIMITED_ID_MAX);
    if (!echo) {
        cJSON_Delete(id);
        return NULL;
    }
    return id;
}

/* What a message costs, in control units: 1, plus 1 per full KiB. Parsing
 * (and echoing) is linear in the bytes, and the bytes are known before any
 * parse: a 1024-tile subscribe (10 KB, 0.5 ms) costs 11, a ping 1. */
static double message_cost(size_t len) { return 1.0 + (double)(len / 1024); }

/* A token bucket: refill at rate up to cap since *t, at time now. */
static void refill(double *tokens, double *t, double rate, double cap, double now)
{
    *tokens += (now - *t) * rate;
    if (*tokens > cap)
        *tokens = cap;
    *t = now;
}

static void refuse(struct session *s, const char *code, const char *message, const char *text, size_t len)
{
    struct ctl_error e = { .code = code };
    snprintf(e.message, sizeof e.message, "%s", message);
    cJSON *id = request_id(text, len);
    session_send_error(s, &e, id);
    cJSON_Delete(id);
}

/* Charge a message to the client's own bucket, then to the budget of all
 * clients (PROTOCOL.md §1.1). Every message from a client, text or binary,
 * is charged (each costs the daemon a reply). The buckets may go into debt
 * by one message (so a message of any allowed size can pass), and are
 * checked for one unit. false = refused, dropped unread:
 *  - rate_limited: the client's own bucket (--control-rate/--control-burst)
 *    is empty: a flooding client meets this first;
 *  - busy: the client is within its own limit but --control-budget (all
 *    clients together) is spent, and so is its fair share of it (budget ÷
 *    clients connected, a bucket of its own): whoever sends little, such as
 *    a controller's occasional `set`, still gets through while others flood.
 * In the long run all clients together get --control-budget units a second:
 * the fair shares (the budget in sum) are charged to it too, and what they
 * spend past it is a debt it repays first. */
bool dispatch_take_token(struct net *n, struct session *s, const char *text, size_t len)
{
    atomic_fetch_add(&g_metrics.control_messages, 1);
    double now = mono_now(), cost = message_cost(len);
    refill(&s->tokens, &s->tokens_t, n->dc.control_rate, n->dc.control_burst, now);
    if (s->tokens < 1) {
        char m[96];
        snprintf(m, sizeof m, "more than %g control units per second (a message: 1 + 1 per KiB)", n->dc.control_rate);
        atomic_fetch_add(&g_metrics.control_rate_limited, 1);
        refuse(s, "rate_limited", m, text, len);
        return false;
    }
    s->tokens -= cost;

    double budget = n->dc.control_budget, fair = budget / (n->sessions.count ? n->sessions.count : 1);
    if (n->budget_t == 0) { /* first message since start */
        n->budget = budget * BUDGET_BURST_S;
        n->budget_t = now;
    }
    refill(&n->budget, &n->budget_t, budget, budget * BUDGET_BURST_S, now);
    double share_cap = fair * SHARE_BURST_S > SHARE_MIN ? fair * SHARE_BURST_S : SHARE_MIN;
    refill(&s->share, &s->share_t, fair, share_cap, now);
    if (n->budget < 1 && s->share < 1) {
        atomic_fetch_add(&g_metrics.control_busy, 1);
        refuse(s, "busy", "the control budget of all clients is spent (--control-budget): try again", text, len);
        return false;
    }
    /* Both are charged, whichever let it pass: what the fair shares let
     * through past an empty budget is owed by the budget (up to 1 s of it),
     * so in the long run all clients together get the budget, no more. */
    n->budget -= cost;
    s->share -= cost;
    if (n->budget < -budget * BUDGET_DEBT_S)
        n->budget = -budget * BUDGET_DEBT_S;
    if (s->share < -share_cap - cost)
        s->share = -share_cap - cost;
    atomic_fetch_add(&g_metrics.control_units, (uint64_t)cost);
    return true;
}

/* ---- point queries and probes (query_worker.c does the work) ---- */

static void dispatch_query(struct net *n, struct session *s, const cJSON *root, const cJSON *id, const char *text,
                           size_t len)
{
    struct ctl_error e;
    struct query_req *r = malloc(sizeof *r); /* 4 kB of points: not on the stack */
    if (r && n->cluster.forward_query) { /* edge: the sim answers; bad ones are refused here */
        if (query_parse(root, r, &e) != 0)
            session_send_error(s, &e, id);
        else
            n->cluster.forward_query(n->cluster.user, s->serial, s->client_id, id, text, len);
    } else if (!r || !n->queries) {
        struct ctl_error oom = { .code = "internal", .message = "point queries are not available" };
        session_send_error(s, &oom, id);
    } else if (query_parse(root, r, &e) != 0 ||
               query_submit(n->queries, s->serial, id, r, n->sim ? sim_time_now(n->sim) : 0, &e) != 0) {
        session_send_error(s, &e, id);
    }
    free(r);
}

/* Parse a control message that came from a remote peer (an edge): counted
 * like a local one; a parse error is answered to the peer. 0 = m filled. */
static int remote_parse(const struct remote *rm, const char *text, size_t len, struct ctl_msg *m)
{
    atomic_fetch_add(&g_metrics.control_messages, 1);
    struct ctl_error e;
    cJSON *bad_id = NULL;
    if (control_parse(text, len, m, &bad_id, &e) != 0) {
        dispatch_respond_error(NULL, rm, &e, bad_id);
        cJSON_Delete(bad_id);
        return -1;
    }
    return 0;
}

void net_remote_query(struct net *n, const char *text, size_t len, net_reply_fn reply, void *ctx)
{
    struct remote rm = { .origin = "", .by = "", .reply = reply, .ctx = ctx };
    struct ctl_msg m;
    if (remote_parse(&rm, text, len, &m) != 0)
        return;
    struct ctl_error e;
    struct query_req *r = malloc(sizeof *r);
    struct remote_query *rq = calloc(1, sizeof *rq);
    if (m.type != CTL_QUERY) {
        struct ctl_error f = { .code = "bad_message", .message = "only query goes to the simulation's query workers" };
        dispatch_respond_error(NULL, &rm, &f, m.id);
    } else if (!r || !rq || !n->queries || !n->sim) {
        struct ctl_error f = { .code = "internal", .message = "point queries are not available" };
        dispatch_respond_error(NULL, &rm, &f, m.id);
    } else if (query_parse(m.root, r, &e) == 0) {
        rq->serial = net_remote_serial(n);
        rq->reply = reply;
        rq->reply_ctx = ctx;
        if (query_submit(n->queries, rq->serial, m.id, r, sim_time_now(n->sim), &e) == 0) {
            lws_dll2_add_tail(&rq->list, &n->remote_queries);
            rq = NULL; /* answered from dispatch_query_results */
        } else {
            dispatch_respond_error(NULL, &rm, &e, m.id);
        }
    } else {
        dispatch_respond_error(NULL, &rm, &e, m.id);
    }
    free(rq);
    free(r);
    ctl_msg_free(&m);
}

static void dispatch_probe(struct net *n, struct session *s, const cJSON *root, const cJSON *id, const char *text,
                           size_t len)
{
    struct ctl_error e;
    struct probe_req *p = malloc(sizeof *p);
    if (p && n->cluster.forward_probe) { /* edge: the sim probes; bad ones are refused here */
        if (probe_parse(root, n->dc.probe_max_points, p, &e) != 0)
            session_send_error(s, &e, id);
        else
            n->cluster.forward_probe(n->cluster.user, s->serial, s->client_id, id, text, len);
    } else if (!p || !n->queries) {
        struct ctl_error oom = { .code = "internal", .message = "probes are not available" };
        session_send_error(s, &oom, id);
    } else if (probe_parse(root, n->dc.probe_max_points, p, &e) != 0 ||
               query_probe_set(n->queries, s->serial, p, &e) != 0) {
        session_send_error(s, &e, id);
    } else {
        session_queue_json(s, probing_msg(id, p->n, (const double(*)[2])p->xz));
    }
    free(p);
}

uint64_t net_remote_serial(struct net *n) { return NET_REMOTE_SERIAL | ++n->next_remote; }

char *net_remote_probe(struct net *n, uint64_t serial, const char *text, size_t len, int *npoints)
{
    *npoints = -1;
    atomic_fetch_add(&g_metrics.control_messages, 1);
    struct ctl_msg m;
    struct ctl_error e;
    cJSON *bad_id = NULL, *answer;
    if (control_parse(text, len, &m, &bad_id, &e) != 0) {
        atomic_fetch_add(&g_metrics.control_errors, 1);
        answer = control_error_msg(&e, bad_id);
        cJSON_Delete(bad_id);
        return control_print(answer);
    }
    struct probe_req *p = malloc(sizeof *p);
    if (m.type != CTL_PROBE) {
        struct ctl_error f = { .code = "bad_message", .message = "only probe goes to the simulation's probes" };
        answer = control_error_msg(&f, m.id);
    } else if (!p || !n->queries) {
        struct ctl_error f = { .code = "internal", .message = "probes are not available" };
        answer = control_error_msg(&f, m.id);
    } else if (probe_parse(m.root, n->dc.probe_max_points, p, &e) != 0 ||
               query_probe_set(n->queries, serial, p, &e) != 0) {
        answer = control_error_msg(&e, m.id);
    } else {
        answer = probing_msg(m.id, p->n, (const double(*)[2])p->xz);
        *npoints = p->n;
    }
    if (*npoints < 0)
        atomic_fetch_add(&g_metrics.control_errors, 1);
    free(p);
    ctl_msg_free(&m);
    return control_print(answer);
}

void net_remote_probe_gone(struct net *n, uint64_t serial) { query_client_gone(n->queries, serial); }

void dispatch_query_results(struct net *n)
{
    struct query_out *o = query_take_results(n->queries);
    while (o) {
        struct query_out *next = o->next;
        if (o->serial & NET_REMOTE_SERIAL) { /* sim role: an edge's client asked */
            if (o->probe && n->cluster.on_probe_data)
                n->cluster.on_probe_data(n->cluster.user, o->serial, o->text);
            for (lws_dll2_t *d = lws_dll2_get_head(&n->remote_queries); d && !o->probe; d = d->next) {
                struct remote_query *rq = remote_query_of(d);
                if (rq->serial == o->serial) {
                    lws_dll2_remove(&rq->list);
                    rq->reply(rq->reply_ctx, o->text);
                    free(rq);
                    break;
                }
            }
            query_out_free(o);
            o = next;
            continue;
        }
        struct session *s = session_find(n, o->serial);
        if (s && s->wsi && !s->closing && !(o->probe && s->tq.count >= NET_PROBE_QUEUE_MAX))
            session_queue_text(s, o->text, false);
        query_out_free(o);
        o = next;
    }
}

/* set / pause / resume: a set is checked against the view; pause and
 * resume change the playback flag and nothing else. */
static void submit_control(struct net *n, struct session *s, const struct remote *rm, const struct ctl_msg *m)
{
    struct ocean_params out = n->view;
    if (m->type == CTL_SEA) {
        sea_net_submit(n, s, rm, m); /* sea_net.c */
    } else if (m->type == CTL_SET) {
        struct ctl_error e;
        uint64_t changed;
        struct ctl_limits lim = n->lim;
        lim.have_sea = sea_net_attached(n); /* spectrum "measured" needs one */
        if (control_apply_params(m->params, &n->view, &lim, &out, &changed, &e) != 0) {
            dispatch_respond_error(s, rm, &e, m->id);
            return;
        }
        dispatch_submit_change(n, s, rm, &out, changed, m->name, m->id, NULL);
    } else {
        out.paused = m->type == CTL_PAUSE;
        dispatch_submit_change(n, s, rm, &out, params_diff(&n->view, &out), m->name, m->id, NULL);
    }
}

void net_remote_control(struct net *n, const char *origin, const char *by, const char *text, size_t len,
                        net_reply_fn reply, void *ctx)
{
    struct remote rm = { .origin = origin, .by = by, .reply = reply, .ctx = ctx };
    struct ctl_msg m;
    if (remote_parse(&rm, text, len, &m) != 0)
        return;
    bool body = m.type == CTL_LAUNCH || m.type == CTL_STEER || m.type == CTL_REMOVE || m.type == CTL_CLAIM;
    if (n->sim && body) {
        body_net_remote(n, origin, by, &m, reply, ctx); /* body_net.c: who owns what is decided here */
    } else if (!n->sim || (m.type != CTL_SET && m.type != CTL_PAUSE && m.type != CTL_RESUME && m.type != CTL_SEA)) {
        struct ctl_error f = { .code = "bad_message",
                               .message = "only set, sea, pause, resume and body requests go to the simulation" };
        dispatch_respond_error(NULL, &rm, &f, m.id);
    } else if (m.once && once_seen(n, m.once)) { /* the client's other copy came first, through any edge */
        dispatch_respond_error(NULL, &rm, &once_duplicate, m.id);
    } else {
        submit_control(n, NULL, &rm, &m); /* the token was checked where the client is (its edge) */
    }
    ctl_msg_free(&m);
}

void dispatch_message(struct net *n, struct session *s, const char *text, size_t len)
{
    if (!dispatch_take_token(n, s, text, len))
        return;

    struct ctl_msg m;
    struct ctl_error e;
    cJSON *bad_id = NULL;
    if (control_parse(text, len, &m, &bad_id, &e) != 0) {
        session_send_error(s, &e, bad_id);
        cJSON_Delete(bad_id);
        return;
    }
    switch (m.type) {
    case CTL_SET:
    case CTL_SEA:
    case CTL_PAUSE:
    case CTL_RESUME: {
        if (!s->controller && !(m.token && n->dc.control_token[0] && control_token_equal(m.token, n->dc.control_token))) {
            struct ctl_error f = { .code = "forbidden", .message = "this client may not change parameters (token needed)" };
            session_send_error(s, &f, m.id);
            break;
        }
        /* Its copy on the client's other connection came first. On an edge the
         * sim decides (net_remote_control): the two copies may reach two edges. */
        if (m.once && !n->cluster.forward && once_seen(n, m.once)) {
            session_send_error(s, &once_duplicate, m.id);
            break;
        }
        if (n->cluster.forward) { /* edge: the sim validates and applies it */
            /* Checked here first against the sim's parameters as this edge
             * knows them: a set refused here never reaches the sim, and its
             * `name` is not taken (neither changes when a set is refused). */
            struct ocean_params out;
            if (m.type == CTL_SET && control_apply_params(m.params, &n->view, NULL, &out, NULL, &e) != 0) {
                session_send_error(s, &e, m.id);
                break;
            }
            if (m.type == CTL_SEA && sea_net_check(m.sea, &e) != 0) {
                session_send_error(s, &e, m.id);
                break;
            }
            /* The sim knows this client only by its id: carry its display
             * name in the message (`name` on the set) unless it has one. */
            char *named = NULL;
            if (s->name[0] && !m.name && cJSON_AddStringToObject(m.root, "name", s->name))
                named = cJSON_PrintUnformatted(m.root);
            if (m.name)
                snprintf(s->name, sizeof s->name, "%s", m.name);
            n->cluster.forward(n->cluster.user, s->serial, s->client_id, m.id, named ? named : text,
                               named ? strlen(named) : len);
            free(named);
            break;
        }
        submit_control(n, s, NULL, &m);
        break;
    }
    case CTL_SUBSCRIBE: {
        /* ~4 kB each (tile list): not on the stack. [0] the new one, [1] what was served. */
        struct subscription *ns = malloc(2 * sizeof *ns);
        if (!ns)
            break;
        if (control_apply_subscribe(m.root, &s->sub, &n->lim, ns, &e) != 0 || !net_capacity_admit(n, s, ns, &e)) {
            session_send_error(s, &e, m.id);
        } else {
            /* Demand follows what is served: the new subscription at the
             * ladder's rung (ladder.c), counted before the old one goes. */
            fanout_want_keyframes(n, s, false); /* counted with the old subscription */
            ns[1] = s->eff;
            s->sub = ns[0];
            ladder_subscribed(n, s); /* s->eff from s->sub */
            dispatch_demand(n, &s->eff, +1);
            dispatch_demand(n, &ns[1], -1);
            fanout_subscribed(n, s); /* temporal: keyframes from the next frame on (PROTOCOL.md §5.9) */
            session_queue_json(s, control_subscribed_msg(&s->sub, m.id));
            ladder_announce(n, s);
            net_capacity_tell(n, s);
        }
        free(ns);
        break;
    }
    case CTL_PING:
        session_queue_json(s, control_pong_msg(m.id, m.t, unix_us()));
        break;
    case CTL_NAME: /* anyone may name themselves: the name only labels their own changes */
        snprintf(s->name, sizeof s->name, "%s", m.name);
        session_queue_json(s, control_named_msg(s->name, m.id));
        body_net_renamed(n, s); /* its bodies show the new name */
        break;
    case CTL_QUERY:
        dispatch_query(n, s, m.root, m.id, text, len);
        break;
    case CTL_PROBE:
        dispatch_probe(n, s, m.root, m.id, text, len);
        break;
    case CTL_RENDER: /* standalone and edge alike: the sea is a function of the params in force */
        renders_dispatch(n, s, m.root, m.id);
        break;
    case CTL_RENDER_CANCEL:
        renders_cancel(n, s);
        break;
    case CTL_LAUNCH:
    case CTL_STEER:
    case CTL_REMOVE:
    case CTL_CLAIM: /* floating bodies (body_net.c) */
        body_net_dispatch(n, s, &m, text, len);
        break;
    }
    ctl_msg_free(&m);
}

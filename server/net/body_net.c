/* body_net.c — floating bodies on the lws thread (PROTOCOL.md §7.6): the
 * requests (launch, steer, remove, claim) checked against who owns what and
 * the limits, handed to the sim (sim_body_submit) and answered when it hands
 * them back; the owners' comings and goings (a body waits --body-grace for a
 * claim, then drifts unpowered as long again, then is removed); the `bodies`
 * message to everyone when the list or an owner changes; hello's members;
 * the bodies handed to the state saver. The physics runs on the producer
 * (server/tick/body_tick.c); nothing here waits for it. */
#include "body_net_internal.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "log.h"
#include "metrics.h"
#include "sim_thread.h"
#include "state_saver.h"

#define BODY_SAVE_EVERY_S 1.0   /* a changed set of bodies is saved at most this often (an fsync each) */
#define BODY_KEEP_EVERY_S 0.5   /* their motion is handed to the saver this often (saved with the next save) */
#define BODY_REPLICA_EVERY_S 0.1 /* ... and to a cluster's record this often (written at each renewal) */

/* ---- the book ---- */

struct body_own *body_find(struct net *n, uint32_t id)
{
    struct body_book *k = &n->bodies;
    int lo = 0, hi = k->n - 1;
    while (lo <= hi) {
        int mid = (lo + hi) / 2;
        if (k->b[mid].id == id)
            return &k->b[mid];
        if (k->b[mid].id < id)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return NULL;
}

/* Insert in id order; NULL out of memory. */
struct body_own *body_add(struct net *n, uint32_t id)
{
    struct body_book *k = &n->bodies;
    if (k->n == k->cap) {
        int cap = k->cap ? 2 * k->cap : 16;
        struct body_own *nb = realloc(k->b, (size_t)cap * sizeof *nb);
        if (!nb)
            return NULL;
        k->b = nb;
        k->cap = cap;
    }
    int i = k->n;
    while (i > 0 && k->b[i - 1].id > id)
        i--;
    memmove(&k->b[i + 1], &k->b[i], (size_t)(k->n - i) * sizeof *k->b);
    k->n++;
    memset(&k->b[i], 0, sizeof k->b[i]);
    k->b[i].id = id;
    return &k->b[i];
}

void body_gone(struct net *n, uint32_t id, const char *reason, uint64_t seq)
{
    struct body_book *k = &n->bodies;
    struct body_own *b = body_find(n, id);
    if (!b)
        return;
    int i = (int)(b - k->b);
    memmove(&k->b[i], &k->b[i + 1], (size_t)(k->n - i - 1) * sizeof *k->b);
    k->n--;
    if (k->ngone == k->gone_cap) {
        int cap = k->gone_cap ? 2 * k->gone_cap : 16;
        struct body_gone_entry *ng = realloc(k->gone, (size_t)cap * sizeof *ng);
        if (ng) {
            k->gone = ng;
            k->gone_cap = cap;
        }
    }
    if (k->ngone < k->gone_cap) /* out of memory: the list still says it is gone */
        k->gone[k->ngone++] = (struct body_gone_entry){ .body = id, .reason = reason };
    int r = strcmp(reason, "sunk") == 0 ? 1 : strcmp(reason, "abandoned") == 0 ? 2 : 0;
    atomic_fetch_add(&g_metrics.body_removed[r], 1);
    k->dirty = k->save_due = true;
    k->seq = seq;
}

int body_owned_by(const struct net *n, uint64_t serial)
{
    int c = 0;
    for (int i = 0; i < n->bodies.n; i++)
        c += n->bodies.b[i].owner == serial;
    return c;
}

/* ---- to the sim ---- */

struct sim_body_cmd *body_cmd_new(enum sim_body_op op, uint32_t body)
{
    struct sim_body_cmd *c = calloc(1, sizeof *c);
    if (c) {
        c->op = op;
        c->body = body;
    }
    return c;
}

/* The daemon's own request (nobody is answered): the adrift flag, or a removal. */
void body_submit_own(struct net *n, struct sim_body_cmd *c)
{
    if (!c) {
        LOGE("bodies: out of memory: a request of the daemon's own is lost");
        return;
    }
    sim_body_submit(n->sim, c);
}

void body_set_adrift(struct net *n, uint32_t id, bool adrift, bool stop)
{
    struct sim_body_cmd *c = body_cmd_new(SIM_BODY_ADRIFT, id);
    if (c) {
        c->adrift = adrift;
        c->stop = stop;
    }
    body_submit_own(n, c);
}

/* ---- who asked ---- */

/* The sender of a request: a local client (s), or, in a cluster's sim, a
 * client of an edge (rc, answered exactly once through reply). */
struct who {
    struct session *s;
    struct body_remote *rc;
    net_reply_fn reply;
    void *ctx;
};

static uint64_t who_serial(const struct who *w) { return w->s ? w->s->serial : w->rc ? w->rc->serial : 0; }
static const char *who_client(const struct who *w) { return w->s ? w->s->client_id : w->rc ? w->rc->by : ""; }
static const char *who_name(const struct who *w) { return w->s ? w->s->name : w->rc ? w->rc->name : ""; }

static int *who_launching(struct who *w)
{
    static int none;
    return w->s ? &w->s->launching : w->rc ? &w->rc->launching : &none;
}

/* msg (deleted) to the sender: queued for a local client; a remote one's answer. */
static void who_send(struct who *w, cJSON *msg)
{
    if (w->s) {
        session_queue_json(w->s, msg);
        return;
    }
    char *text = control_print(msg);
    if (w->reply)
        w->reply(w->ctx, text ? text : "{\"type\":\"error\",\"code\":\"internal\",\"message\":\"out of memory\"}");
    w->reply = NULL;
    free(text);
}

static void fail(struct who *w, const char *code, const char *param, const cJSON *id, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static void fail(struct who *w, const char *code, const char *param, const cJSON *id, const char *fmt, ...)
{
    struct ctl_error e = { .code = code };
    snprintf(e.param, sizeof e.param, "%s", param ? param : "");
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e.message, sizeof e.message, fmt, ap);
    va_end(ap);
    if (w->s) {
        session_send_error(w->s, &e, id);
        return;
    }
    atomic_fetch_add(&g_metrics.control_errors, 1);
    who_send(w, control_error_msg(&e, id));
}

/* ---- clients of edges (sim role) ---- */

#define BODY_REMOTE_MAX 4096 /* clients of edges with bodies or requests at once */

struct body_remote *body_rc_find(struct net *n, uint64_t serial)
{
    for (int i = 0; serial && i < n->bodies.nrc; i++)
        if (n->bodies.rc[i].serial == serial)
            return &n->bodies.rc[i];
    return NULL;
}

struct body_remote *body_rc_find_by(struct net *n, const char *origin, const char *by)
{
    for (int i = 0; i < n->bodies.nrc; i++)
        if (strcmp(n->bodies.rc[i].by, by) == 0 && strcmp(n->bodies.rc[i].origin, origin) == 0)
            return &n->bodies.rc[i];
    return NULL;
}

/* The entry of (origin, by), made if new; NULL when full or out of memory. */
struct body_remote *body_rc_get(struct net *n, const char *origin, const char *by)
{
    struct body_book *k = &n->bodies;
    struct body_remote *r = body_rc_find_by(n, origin, by);
    if (r)
        return r;
    if (k->nrc >= BODY_REMOTE_MAX || strlen(by) >= sizeof r->by || strlen(origin) >= sizeof r->origin)
        return NULL;
    if (k->nrc == k->rc_cap) {
        int cap = k->rc_cap ? 2 * k->rc_cap : 16;
        struct body_remote *nr = realloc(k->rc, (size_t)cap * sizeof *nr);
        if (!nr)
            return NULL;
        k->rc = nr;
        k->rc_cap = cap;
    }
    r = &k->rc[k->nrc++];
    memset(r, 0, sizeof *r);
    r->serial = net_remote_serial(n);
    snprintf(r->origin, sizeof r->origin, "%s", origin);
    snprintf(r->by, sizeof r->by, "%s", by);
    r->seen = mono_now();
    return r;
}


/* Its edge says it is gone (or fell silent): its bodies wait for a claim. */
void body_rc_gone(struct net *n, struct body_remote *r)
{
    body_owner_left(n, r->serial);
    struct body_book *k = &n->bodies;
    *r = k->rc[--k->nrc];
}

/* ---- to the sim ---- */

/* A client's request for the sim, answered to its sender (id copied for the answer);
 * NULL, with the sender told `internal`, on no memory. */
static struct sim_body_cmd *client_cmd(struct net *n, struct who *w, enum sim_body_op op, uint32_t body,
                                       const cJSON *id)
{
    struct body_book *k = &n->bodies;
    struct sim_body_cmd *c = body_cmd_new(op, body);
    cJSON *idc = id ? cJSON_Duplicate(id, 1) : NULL;
    if (w->rc && c && k->nwait == k->wait_cap) {
        int cap = k->wait_cap ? 2 * k->wait_cap : 16;
        struct body_wait *nw = realloc(k->wait, (size_t)cap * sizeof *nw);
        if (nw) {
            k->wait = nw;
            k->wait_cap = cap;
        }
    }
    if (!c || (id && !idc) || (w->rc && k->nwait == k->wait_cap)) {
        free(c);
        cJSON_Delete(idc);
        fail(w, "internal", NULL, id, "out of memory");
        return NULL;
    }
    c->serial = who_serial(w);
    c->reply_id = idc;
    c->reply = true;
    if (w->rc) { /* answered from answer(), through the edge */
        c->ticket = ++k->next_ticket;
        k->wait[k->nwait++] = (struct body_wait){ .ticket = c->ticket, .reply = w->reply, .ctx = w->ctx };
        w->reply = NULL;
    }
    return c;
}

/* The waiting remote answer of ticket, taken out of the list. */
static bool take_wait(struct net *n, uint64_t ticket, struct body_wait *out)
{
    struct body_book *k = &n->bodies;
    for (int i = 0; ticket && i < k->nwait; i++)
        if (k->wait[i].ticket == ticket) {
            *out = k->wait[i];
            memmove(&k->wait[i], &k->wait[i + 1], (size_t)(k->nwait - i - 1) * sizeof *k->wait);
            k->nwait--;
            return true;
        }
    return false;
}

/* ---- requests ---- */

/* 128 random bits as 32 hex digits. */
static void resume_key(char out[33])
{
    uint8_t r[16];
    if (getrandom(r, sizeof r, 0) != (ssize_t)sizeof r) {
        /* No entropy at all is a broken system; the clock keeps keys distinct, not secret. */
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        for (size_t i = 0; i < sizeof r; i++)
            r[i] = (uint8_t)((uint64_t)ts.tv_nsec * 2654435761u >> (i % 8 * 4) ^ (uint64_t)getpid() << i);
    }
    for (size_t i = 0; i < sizeof r; i++)
        snprintf(out + 2 * i, 3, "%02x", r[i]);
}

/* --launch-rate: a bucket of launch_rate launches, refilled over a minute. */
static bool launch_allowed(struct net *n, struct session *s, double now)
{
    double cap = n->dc.launch_rate;
    if (s->launch_t == 0)
        s->launch_tokens = cap;
    else
        s->launch_tokens = fmin(cap, s->launch_tokens + (now - s->launch_t) * cap / 60.0);
    s->launch_t = now;
    return s->launch_tokens >= 1;
}

static bool rate_ok(struct net *n, struct session *s, const cJSON *id)
{
    if (launch_allowed(n, s, mono_now()))
        return true;
    fail(&(struct who){ .s = s }, "rate_limited", NULL, id, "more than %g launches a minute (--launch-rate)",
         n->dc.launch_rate);
    return false;
}

static void launch(struct net *n, struct who *w, const struct body_req *r, const cJSON *id)
{
    int mine = body_owned_by(n, who_serial(w)) + *who_launching(w);
    if (mine >= n->dc.bodies_per_session) {
        fail(w, "too_many_bodies", NULL, id, "this client owns %d bodies already (at most %d: --bodies-per-session)",
             mine, n->dc.bodies_per_session);
        return;
    }
    if (n->bodies.n + n->bodies.launching >= n->dc.max_bodies) {
        fail(w, "too_many_bodies", NULL, id, "the world holds %d bodies already (at most %d: --max-bodies)",
             n->bodies.n + n->bodies.launching, n->dc.max_bodies);
        return;
    }
    /* A client of an edge: its edge keeps the bucket (as it checks the token). */
    if (w->s && !rate_ok(n, w->s, id))
        return;
    struct sim_body_cmd *c = client_cmd(n, w, SIM_BODY_LAUNCH, 0, id);
    if (!c)
        return;
    if (w->s)
        w->s->launch_tokens -= 1;
    c->kind = r->kind;
    c->x = r->x;
    c->z = r->z;
    c->heading = r->heading;
    resume_key(c->resume);
    (*who_launching(w))++;
    n->bodies.launching++;
    sim_body_submit(n->sim, c);
}

/* A body the client may steer or remove: it exists and it owns it. */
static struct body_own *mine(struct net *n, struct who *w, uint32_t body, const cJSON *id)
{
    struct body_own *b = body_find(n, body);
    if (!b || b->removing) {
        fail(w, "no_such_body", "body", id, "no body %u", body);
        return NULL;
    }
    if (b->owner != who_serial(w)) {
        fail(w, "not_owner", "body", id, "body %u belongs to %s", body, b->owner_id[0] ? b->owner_id : "someone else");
        return NULL;
    }
    return b;
}

static void steer(struct net *n, struct who *w, const struct body_req *r, const cJSON *id)
{
    if (!mine(n, w, r->body, id))
        return;
    struct sim_body_cmd *c = client_cmd(n, w, SIM_BODY_STEER, r->body, id);
    if (!c)
        return;
    c->control = (struct body_control){ r->throttle, r->rudder };
    c->has_throttle = r->has_throttle;
    c->has_rudder = r->has_rudder;
    /* A steer without an id is answered only when it fails; a remote one
     * always (its edge waits, and relays only a failure). */
    c->reply = id != NULL || c->ticket;
    sim_body_submit(n->sim, c);
}

static void remove_body(struct net *n, struct who *w, const struct body_req *r, const cJSON *id)
{
    struct body_own *b = mine(n, w, r->body, id);
    if (!b)
        return;
    struct sim_body_cmd *c = client_cmd(n, w, SIM_BODY_REMOVE, r->body, id);
    if (!c)
        return;
    c->reason = "removed";
    b->removing = true;
    sim_body_submit(n->sim, c);
}

static void claim(struct net *n, struct who *w, const struct body_req *r, const cJSON *id)
{
    struct body_own *b = body_find(n, r->body);
    if (!b || b->removing) {
        fail(w, "no_such_body", "body", id, "no body %u", r->body);
        return;
    }
    if (!control_token_equal(r->resume, b->resume)) {
        fail(w, "not_owner", "resume", id, "that is not body %u's resume key", r->body);
        return;
    }
    if (b->owner == who_serial(w)) { /* claimed twice: nothing changes */
        who_send(w, body_ack_msg("claimed", id, b->id));
        return;
    }
    if (!b->owner && b->left_t > 0 && mono_now() - b->left_t > n->dc.body_grace) {
        fail(w, "not_owner", "body", id, "body %u was abandoned: its owner was gone for more than %g s", r->body,
             n->dc.body_grace);
        return;
    }
    int count = body_owned_by(n, who_serial(w)) + *who_launching(w);
    if (count >= n->dc.bodies_per_session) {
        fail(w, "too_many_bodies", NULL, id, "this client owns %d bodies already (at most %d: --bodies-per-session)",
             count, n->dc.bodies_per_session);
        return;
    }
    /* The key proves it: a reload takes its body back even before the old
     * connection is seen to be gone. */
    bool was_adrift = !b->owner;
    b->owner = who_serial(w);
    snprintf(b->owner_id, sizeof b->owner_id, "%s", who_client(w));
    snprintf(b->name, sizeof b->name, "%s", who_name(w));
    b->left_t = 0;
    b->stopped = false;
    if (was_adrift)
        body_set_adrift(n, b->id, false, false);
    n->bodies.dirty = n->bodies.save_due = true;
    n->bodies.seq = sim_seq(n->sim);
    who_send(w, body_ack_msg("claimed", id, b->id));
}


static void apply_request(struct net *n, struct who *w, const struct ctl_msg *m, const struct body_req *r)
{
    switch (m->type) {
    case CTL_LAUNCH: launch(n, w, r, m->id); break;
    case CTL_STEER: steer(n, w, r, m->id); break;
    case CTL_REMOVE: remove_body(n, w, r, m->id); break;
    case CTL_CLAIM: claim(n, w, r, m->id); break;
    default: break;
    }
}

/* An edge: checked here as a local request would be (the message, the
 * token, the launch bucket), then the sim decides (who owns what, the
 * limits), carrying the client's display name. */
static void edge_request(struct net *n, struct session *s, const struct ctl_msg *m, const char *text, size_t len)
{
    if (m->type == CTL_LAUNCH && !rate_ok(n, s, m->id))
        return;
    if (m->type == CTL_LAUNCH)
        s->launch_tokens -= 1;
    if (!s->body_user) {
        s->body_user = true;
        n->bodies.owners_due = true;
    }
    char *named = NULL;
    if (s->name[0] && !cJSON_HasObjectItem(m->root, "name") && cJSON_AddStringToObject(m->root, "name", s->name))
        named = cJSON_PrintUnformatted(m->root);
    n->cluster.forward(n->cluster.user, s->serial, s->client_id, m->id, named ? named : text,
                       named ? strlen(named) : len);
    free(named);
}

void body_net_dispatch(struct net *n, struct session *s, const struct ctl_msg *m, const char *text, size_t len)
{
    struct body_req r;
    struct ctl_error e;
    struct who w = { .s = s };
    if (!n->sim && !n->cluster.forward) {
        fail(&w, "unavailable", NULL, m->id, "floating bodies are not served by this daemon (--role %s)", n->dc.role);
        return;
    }
    if (body_parse(m->root, m->type, &r, &e) != 0) {
        session_send_error(s, &e, m->id);
        return;
    }
    if (!s->controller && !(r.token && n->dc.control_token[0] && control_token_equal(r.token, n->dc.control_token))) {
        fail(&w, "forbidden", NULL, m->id, "this client may not launch or steer bodies (token needed)");
        return;
    }
    if (!n->sim) {
        edge_request(n, s, m, text, len);
        return;
    }
    apply_request(n, &w, m, &r);
    body_net_flush(n);
}

void body_net_remote(struct net *n, const char *origin, const char *by, const struct ctl_msg *m, net_reply_fn reply,
                     void *ctx)
{
    struct who w = { .reply = reply, .ctx = ctx };
    struct body_req r;
    struct ctl_error e;
    if (body_parse(m->root, m->type, &r, &e) != 0) { /* the edge checked it: a peer of its own */
        atomic_fetch_add(&g_metrics.control_errors, 1);
        who_send(&w, control_error_msg(&e, m->id));
        return;
    }
    if (!by[0] || !(w.rc = body_rc_get(n, origin, by))) {
        fail(&w, by[0] ? "busy" : "bad_message", NULL, m->id, "%s",
             by[0] ? "too many clients of edges use bodies at once" : "a body request needs its client");
        return;
    }
    const char *name = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(m->root, "name"));
    struct ctl_error ne;
    if (name && control_check_name(name, &ne) == 0)
        snprintf(w.rc->name, sizeof w.rc->name, "%s", name);
    w.rc->seen = mono_now();
    apply_request(n, &w, m, &r); /* the token was checked where the client is (its edge) */
    if (w.reply) /* every path answers; this is the net under it */
        fail(&w, "internal", NULL, m->id, "not answered");
    body_net_flush(n);
}

void body_net_drop_remote(struct net *n)
{
    struct body_book *k = &n->bodies;
    for (int i = 0; i < k->nwait; i++)
        k->wait[i].reply(k->wait[i].ctx, NULL);
    k->nwait = 0;
}

/* ---- answers from the sim ---- */

static const char *error_code(enum body_error e)
{
    switch (e) {
    case BODY_ERR_KIND: return "unknown_kind";
    case BODY_ERR_NOT_FINITE: return "bad_type";
    case BODY_ERR_RANGE: return "out_of_range";
    case BODY_ERR_FULL: return "too_many_bodies";
    case BODY_ERR_NOT_FOUND: return "no_such_body";
    default: return "internal";
    }
}

static void answer(struct net *n, struct sim_body_cmd *c)
{
    struct body_wait wt;
    struct who w = { 0 };
    if (c->ticket && take_wait(n, c->ticket, &wt)) {
        w.rc = body_rc_find(n, c->serial);
        w.reply = wt.reply;
        w.ctx = wt.ctx;
    } else if (!c->ticket && c->serial) {
        w.s = session_find(n, c->serial);
        if (w.s && (!w.s->wsi || w.s->closing))
            w.s = NULL;
    }
    bool told = w.s || w.reply;   /* someone hears the answer */
    bool owner = w.s || w.rc;     /* someone may own the body */
    const cJSON *id = c->reply_id;
    if (c->op == SIM_BODY_LAUNCH) {
        n->bodies.launching--;
        if (owner)
            (*who_launching(&w))--;
    }
    if (c->op == SIM_BODY_RESTORE) { /* a take-over's bodies are in (or were refused: the world kept its own) */
        n->bodies.restoring = false;
        n->bodies.restored_seq = c->seq;
        if (c->status != BODY_OK)
            LOGE("bodies: the bodies taken over were refused (%s)", body_error_name(c->status));
        return;
    }
    if (c->status != BODY_OK) {
        if (c->op == SIM_BODY_REMOVE) {
            struct body_own *b = body_find(n, c->body);
            if (b)
                b->removing = false;
        }
        if (told && c->op != SIM_BODY_ADRIFT)
            fail(&w, error_code(c->status), c->op == SIM_BODY_LAUNCH ? NULL : "body", id, "%s refused: %s",
                 c->op == SIM_BODY_LAUNCH ? "launch" : c->op == SIM_BODY_STEER ? "steer" : "remove",
                 body_error_name(c->status));
        return;
    }
    switch (c->op) {
    case SIM_BODY_LAUNCH: {
        atomic_fetch_add(&g_metrics.body_launches, 1);
        struct body_own *b = body_add(n, c->body);
        if (!b) { /* out of memory: the body may not stay unowned and unknown */
            body_submit_own(n, body_cmd_new(SIM_BODY_REMOVE, c->body));
            if (told)
                fail(&w, "internal", NULL, id, "out of memory");
            return;
        }
        b->kind = c->kind;
        memcpy(b->resume, c->resume, sizeof b->resume);
        if (owner) {
            b->owner = who_serial(&w);
            snprintf(b->owner_id, sizeof b->owner_id, "%s", who_client(&w));
            snprintf(b->name, sizeof b->name, "%s", who_name(&w));
        } else { /* its sender left before the answer: it waits for nobody (the key was never handed out) */
            b->left_t = mono_now() - n->dc.body_grace;
            body_set_adrift(n, b->id, true, false);
        }
        if (told)
            who_send(&w, body_launched_msg(id, b->id, b->resume));
        n->bodies.dirty = n->bodies.save_due = true;
        n->bodies.seq = c->seq;
        break;
    }
    case SIM_BODY_STEER:
        if (told && c->reply)
            who_send(&w, body_ack_msg("steered", id, c->body));
        break;
    case SIM_BODY_REMOVE:
        body_gone(n, c->body, c->reason ? c->reason : "removed", c->seq);
        if (told && c->reply)
            who_send(&w, body_ack_msg("removed", id, c->body));
        break;
    case SIM_BODY_GONE:
        body_gone(n, c->body, "sunk", c->seq);
        break;
    case SIM_BODY_ADRIFT:
    case SIM_BODY_RESTORE:
        break;
    }
    if (w.reply) /* a remote request answered on no path above */
        w.reply(w.ctx, "{\"type\":\"error\",\"code\":\"internal\",\"message\":\"not answered\"}");
}

/* ---- the list, to everyone ---- */

static struct body_entry *entries(struct net *n)
{
    struct body_entry *e = calloc(n->bodies.n ? (size_t)n->bodies.n : 1, sizeof *e);
    for (int i = 0; e && i < n->bodies.n; i++) {
        const struct body_own *b = &n->bodies.b[i];
        e[i] = (struct body_entry){ .body = b->id, .kind = b->kind, .owner = b->owner_id, .name = b->name,
                                    .adrift = b->owner == 0 };
    }
    return e;
}

void body_net_flush(struct net *n)
{
    struct body_book *k = &n->bodies;
    if (!k->dirty)
        return;
    struct body_entry *e = entries(n);
    if (!e)
        return; /* out of memory: the next change tries again */
    char *text = control_print(bodies_msg(k->seq, k->n, e, k->ngone, k->gone));
    free(e);
    if (!text)
        return;
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next)
        session_queue_text(session_of(d), text, false);
    if (n->cluster.on_bodies_event) /* a cluster's sim: every edge's clients */
        n->cluster.on_bodies_event(n->cluster.user, text);
    free(text);
    k->dirty = false;
    k->ngone = 0;
}

cJSON *body_net_hello(struct net *n, cJSON *hello)
{
    if (!hello)
        return NULL;
    struct body_limits l = { .per_session = n->dc.bodies_per_session, .max_bodies = n->dc.max_bodies,
                             .launch_rate = n->dc.launch_rate, .grace_s = n->dc.body_grace };
    cJSON_AddItemToObject(hello, "body_kinds", body_kinds_array());
    cJSON_AddItemToObject(hello, "body_limits", body_limits_object(&l));
    cJSON_AddNumberToObject(hello, "world_half_size", BODY_WORLD_HALF_M);
    struct body_entry *e = entries(n);
    cJSON_AddItemToObject(hello, "bodies", body_list_array(e ? n->bodies.n : 0, e));
    free(e);
    return hello;
}

/* ---- the state file ---- */

/* Hand the newest bodies, with their owners, to the state saver (the next
 * save writes them), and ask for a save when the set changed. */
static void keep(struct net *n, double now)
{
    struct body_book *k = &n->bodies;
    /* A cluster's sim hands them to its standby's record more often (each
     * renewal writes the newest); not before a take-over's bodies are in. */
    bool replica = n->cluster.on_bodies_state && k->snap && !k->restoring && k->snap->seq >= k->restored_seq &&
                   now - k->replica_t >= BODY_REPLICA_EVERY_S;
    bool file = n->saver && k->snap && (k->save_due || now - k->kept_t >= BODY_KEEP_EVERY_S);
    if (!replica && !file)
        return;
    struct state_bodies sb = { .next_id = k->snap->next_id };
    sb.b = calloc(k->snap->count ? (size_t)k->snap->count : 1, sizeof *sb.b);
    if (!sb.b)
        return;
    for (int i = 0; i < k->snap->count; i++) {
        const struct body_own *b = body_find(n, k->snap->states[i].id);
        if (!b) /* launched a moment ago: its answer comes with the next wake */
            continue;
        struct state_body *e = &sb.b[sb.n++];
        e->st = k->snap->states[i];
        snprintf(e->owner, sizeof e->owner, "%s", b->owner_id);
        snprintf(e->name, sizeof e->name, "%s", b->name);
        memcpy(e->resume, b->resume, sizeof e->resume);
        const struct body_remote *r = body_rc_find(n, b->owner);
        if (r)
            snprintf(e->origin, sizeof e->origin, "%s", r->origin);
    }
    sb.cap = sb.n;
    if (replica) {
        n->cluster.on_bodies_state(n->cluster.user, &sb);
        k->replica_t = now;
    }
    if (!file) {
        free(sb.b);
        return;
    }
    state_saver_set_bodies(n->saver, &sb);
    free(sb.b);
    k->kept_t = now;
    if (k->save_due && now - k->saved_t >= BODY_SAVE_EVERY_S) {
        k->save_due = false;
        k->saved_t = now;
        sim_save_now(n->sim); /* the builder writes it: no fsync on this thread */
    }
}

void body_net_wake(struct net *n)
{
    if (!n->sim)
        return;
    for (struct sim_body_cmd *c = sim_body_take_answers(n->sim), *next; c; c = next) {
        next = c->next;
        answer(n, c);
        cJSON_Delete(c->reply_id);
        free(c->states);
        free(c);
    }
    struct body_snap *snap = sim_bodies_latest(n->sim);
    if (snap && (!n->bodies.snap || snap->seq > n->bodies.snap->seq)) {
        body_snap_unref(n->bodies.snap);
        n->bodies.snap = snap;
    } else {
        body_snap_unref(snap);
    }
    double now = mono_now();
    body_grace_expiry(n, now);
    keep(n, now);
    body_net_flush(n);
}

void body_net_free(struct net *n)
{
    body_net_drop_remote(n);
    body_snap_unref(n->bodies.snap);
    free(n->bodies.b);
    free(n->bodies.gone);
    free(n->bodies.rc);
    free(n->bodies.wait);
    n->bodies = (struct body_book){ 0 };
}

/* ---- start-up ---- */

void net_attach_saver(struct net *n, struct state_saver *sv) { n->saver = sv; }

void net_bodies_restore(struct net *n, const struct state_bodies *sb)
{
    double now = mono_now();
    for (int i = 0; i < sb->n; i++) {
        struct body_own *b = body_add(n, sb->b[i].st.id);
        if (!b)
            return;
        b->kind = sb->b[i].st.kind;
        snprintf(b->owner_id, sizeof b->owner_id, "%s", sb->b[i].owner);
        snprintf(b->name, sizeof b->name, "%s", sb->b[i].name);
        memcpy(b->resume, sb->b[i].resume, sizeof b->resume);
        b->left_t = now; /* every owner has to claim its body again, within the grace */
    }
}

/* body_net.c — floating bodies on the lws thread (PROTOCOL.md §7.6): the
 * requests (launch, steer, remove, claim) checked against who owns what and
 * the limits, handed to the sim (sim_body_submit) and answered when it hands
 * them back; the owners' comings and goings (a body waits --body-grace for a
 * claim, then drifts unpowered as long again, then is removed); the `bodies`
 * message to everyone when the list or an owner changes; hello's members;
 * the bodies handed to the state saver. The physics runs on the producer
 * (server/tick/body_tick.c); nothing here waits for it. */
#include "net_internal.h"

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

/* ---- the book ---- */

static struct body_own *find(struct net *n, uint32_t id)
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
static struct body_own *add(struct net *n, uint32_t id)
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

static void gone(struct net *n, uint32_t id, const char *reason, uint64_t seq)
{
    struct body_book *k = &n->bodies;
    struct body_own *b = find(n, id);
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

static int owned_by(const struct net *n, uint64_t serial)
{
    int c = 0;
    for (int i = 0; i < n->bodies.n; i++)
        c += n->bodies.b[i].owner == serial;
    return c;
}

/* ---- to the sim ---- */

static struct sim_body_cmd *cmd_new(enum sim_body_op op, uint32_t body)
{
    struct sim_body_cmd *c = calloc(1, sizeof *c);
    if (c) {
        c->op = op;
        c->body = body;
    }
    return c;
}

/* The daemon's own request (nobody is answered): the adrift flag, or a removal. */
static void submit_own(struct net *n, struct sim_body_cmd *c)
{
    if (!c) {
        LOGE("bodies: out of memory: a request of the daemon's own is lost");
        return;
    }
    sim_body_submit(n->sim, c);
}

static void set_adrift(struct net *n, uint32_t id, bool adrift, bool stop)
{
    struct sim_body_cmd *c = cmd_new(SIM_BODY_ADRIFT, id);
    if (c) {
        c->adrift = adrift;
        c->stop = stop;
    }
    submit_own(n, c);
}

/* ---- requests ---- */

static void fail(struct session *s, const char *code, const char *param, const cJSON *id, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
static void fail(struct session *s, const char *code, const char *param, const cJSON *id, const char *fmt, ...)
{
    struct ctl_error e = { .code = code };
    snprintf(e.param, sizeof e.param, "%s", param ? param : "");
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e.message, sizeof e.message, fmt, ap);
    va_end(ap);
    session_send_error(s, &e, id);
}

/* A client's request for the sim, answered to its sender (id copied for the answer);
 * NULL, with the sender told `internal`, on no memory. */
static struct sim_body_cmd *client_cmd(struct session *s, enum sim_body_op op, uint32_t body, const cJSON *id)
{
    struct sim_body_cmd *c = cmd_new(op, body);
    cJSON *idc = id ? cJSON_Duplicate(id, 1) : NULL;
    if (!c || (id && !idc)) {
        free(c);
        cJSON_Delete(idc);
        fail(s, "internal", NULL, id, "out of memory");
        return NULL;
    }
    c->serial = s->serial;
    c->reply_id = idc;
    c->reply = true;
    return c;
}

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

static void launch(struct net *n, struct session *s, const struct body_req *r, const cJSON *id)
{
    int mine = owned_by(n, s->serial) + s->launching;
    if (mine >= n->dc.bodies_per_session) {
        fail(s, "too_many_bodies", NULL, id, "this client owns %d bodies already (at most %d: --bodies-per-session)",
             mine, n->dc.bodies_per_session);
        return;
    }
    if (n->bodies.n + n->bodies.launching >= n->dc.max_bodies) {
        fail(s, "too_many_bodies", NULL, id, "the world holds %d bodies already (at most %d: --max-bodies)",
             n->bodies.n + n->bodies.launching, n->dc.max_bodies);
        return;
    }
    if (!launch_allowed(n, s, mono_now())) {
        fail(s, "rate_limited", NULL, id, "more than %g launches a minute (--launch-rate)", n->dc.launch_rate);
        return;
    }
    struct sim_body_cmd *c = client_cmd(s, SIM_BODY_LAUNCH, 0, id);
    if (!c)
        return;
    s->launch_tokens -= 1;
    c->kind = r->kind;
    c->x = r->x;
    c->z = r->z;
    c->heading = r->heading;
    resume_key(c->resume);
    s->launching++;
    n->bodies.launching++;
    sim_body_submit(n->sim, c);
}

/* A body the client may steer or remove: it exists and it owns it. */
static struct body_own *mine(struct net *n, struct session *s, uint32_t body, const cJSON *id)
{
    struct body_own *b = find(n, body);
    if (!b || b->removing) {
        fail(s, "no_such_body", "body", id, "no body %u", body);
        return NULL;
    }
    if (b->owner != s->serial) {
        fail(s, "not_owner", "body", id, "body %u belongs to %s", body, b->owner_id[0] ? b->owner_id : "someone else");
        return NULL;
    }
    return b;
}

static void steer(struct net *n, struct session *s, const struct body_req *r, const cJSON *id)
{
    if (!mine(n, s, r->body, id))
        return;
    struct sim_body_cmd *c = client_cmd(s, SIM_BODY_STEER, r->body, id);
    if (!c)
        return;
    c->control = (struct body_control){ r->throttle, r->rudder };
    c->has_throttle = r->has_throttle;
    c->has_rudder = r->has_rudder;
    c->reply = id != NULL; /* a steer without an id is answered only when it fails */
    sim_body_submit(n->sim, c);
}

static void remove_body(struct net *n, struct session *s, const struct body_req *r, const cJSON *id)
{
    struct body_own *b = mine(n, s, r->body, id);
    if (!b)
        return;
    struct sim_body_cmd *c = client_cmd(s, SIM_BODY_REMOVE, r->body, id);
    if (!c)
        return;
    c->reason = "removed";
    b->removing = true;
    sim_body_submit(n->sim, c);
}

static void claim(struct net *n, struct session *s, const struct body_req *r, const cJSON *id)
{
    struct body_own *b = find(n, r->body);
    if (!b || b->removing) {
        fail(s, "no_such_body", "body", id, "no body %u", r->body);
        return;
    }
    if (!control_token_equal(r->resume, b->resume)) {
        fail(s, "not_owner", "resume", id, "that is not body %u's resume key", r->body);
        return;
    }
    if (b->owner == s->serial) { /* claimed twice: nothing changes */
        session_queue_json(s, body_ack_msg("claimed", id, b->id));
        return;
    }
    if (!b->owner && b->left_t > 0 && mono_now() - b->left_t > n->dc.body_grace) {
        fail(s, "not_owner", "body", id, "body %u was abandoned: its owner was gone for more than %g s", r->body,
             n->dc.body_grace);
        return;
    }
    int count = owned_by(n, s->serial) + s->launching;
    if (count >= n->dc.bodies_per_session) {
        fail(s, "too_many_bodies", NULL, id, "this client owns %d bodies already (at most %d: --bodies-per-session)",
             count, n->dc.bodies_per_session);
        return;
    }
    /* The key proves it: a reload takes its body back even before the old
     * connection is seen to be gone. */
    bool was_adrift = !b->owner;
    b->owner = s->serial;
    snprintf(b->owner_id, sizeof b->owner_id, "%s", s->client_id);
    snprintf(b->name, sizeof b->name, "%s", s->name);
    b->left_t = 0;
    b->stopped = false;
    if (was_adrift)
        set_adrift(n, b->id, false, false);
    n->bodies.dirty = n->bodies.save_due = true;
    n->bodies.seq = sim_seq(n->sim);
    session_queue_json(s, body_ack_msg("claimed", id, b->id));
}

static void body_net_flush(struct net *n);

void body_net_dispatch(struct net *n, struct session *s, const struct ctl_msg *m)
{
    struct body_req r;
    struct ctl_error e;
    if (!n->sim) { /* an edge: bodies are not relayed through a cluster yet */
        fail(s, "unavailable", NULL, m->id, "floating bodies are not served by this daemon (--role %s)", n->dc.role);
        return;
    }
    if (body_parse(m->root, m->type, &r, &e) != 0) {
        session_send_error(s, &e, m->id);
        return;
    }
    if (!s->controller && !(r.token && n->dc.control_token[0] && control_token_equal(r.token, n->dc.control_token))) {
        fail(s, "forbidden", NULL, m->id, "this client may not launch or steer bodies (token needed)");
        return;
    }
    switch (m->type) {
    case CTL_LAUNCH: launch(n, s, &r, m->id); break;
    case CTL_STEER: steer(n, s, &r, m->id); break;
    case CTL_REMOVE: remove_body(n, s, &r, m->id); break;
    case CTL_CLAIM: claim(n, s, &r, m->id); break;
    default: break;
    }
    body_net_flush(n);
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
    struct session *s = c->serial ? session_find(n, c->serial) : NULL;
    if (s && (!s->wsi || s->closing))
        s = NULL;
    const cJSON *id = c->reply_id;
    if (c->op == SIM_BODY_LAUNCH) {
        n->bodies.launching--;
        if (s)
            s->launching--;
    }
    if (c->status != BODY_OK) {
        if (c->op == SIM_BODY_REMOVE) {
            struct body_own *b = find(n, c->body);
            if (b)
                b->removing = false;
        }
        if (s && c->op != SIM_BODY_ADRIFT)
            fail(s, error_code(c->status), c->op == SIM_BODY_LAUNCH ? NULL : "body", id, "%s refused: %s",
                 c->op == SIM_BODY_LAUNCH ? "launch" : c->op == SIM_BODY_STEER ? "steer" : "remove",
                 body_error_name(c->status));
        return;
    }
    switch (c->op) {
    case SIM_BODY_LAUNCH: {
        atomic_fetch_add(&g_metrics.body_launches, 1);
        struct body_own *b = add(n, c->body);
        if (!b) { /* out of memory: the body may not stay unowned and unknown */
            submit_own(n, cmd_new(SIM_BODY_REMOVE, c->body));
            if (s)
                fail(s, "internal", NULL, id, "out of memory");
            return;
        }
        b->kind = c->kind;
        memcpy(b->resume, c->resume, sizeof b->resume);
        if (s) {
            b->owner = s->serial;
            snprintf(b->owner_id, sizeof b->owner_id, "%s", s->client_id);
            snprintf(b->name, sizeof b->name, "%s", s->name);
            session_queue_json(s, body_launched_msg(id, b->id, b->resume));
        } else { /* its sender left before the answer: it waits for nobody (the key was never handed out) */
            b->left_t = mono_now() - n->dc.body_grace;
            set_adrift(n, b->id, true, false);
        }
        n->bodies.dirty = n->bodies.save_due = true;
        n->bodies.seq = c->seq;
        break;
    }
    case SIM_BODY_STEER:
        if (s && c->reply)
            session_queue_json(s, body_ack_msg("steered", id, c->body));
        break;
    case SIM_BODY_REMOVE:
        gone(n, c->body, c->reason ? c->reason : "removed", c->seq);
        if (s && c->reply)
            session_queue_json(s, body_ack_msg("removed", id, c->body));
        break;
    case SIM_BODY_GONE:
        gone(n, c->body, "sunk", c->seq);
        break;
    case SIM_BODY_ADRIFT:
        break;
    }
}

/* ---- owners ---- */

void body_net_session_gone(struct net *n, struct session *s)
{
    double now = mono_now();
    for (int i = 0; i < n->bodies.n; i++) {
        struct body_own *b = &n->bodies.b[i];
        if (b->owner != s->serial)
            continue;
        b->owner = 0;
        b->left_t = now;
        set_adrift(n, b->id, true, false);
        n->bodies.dirty = true;
        n->bodies.seq = sim_seq(n->sim);
    }
}

void body_net_renamed(struct net *n, struct session *s)
{
    for (int i = 0; i < n->bodies.n; i++) {
        struct body_own *b = &n->bodies.b[i];
        if (b->owner != s->serial || strcmp(b->name, s->name) == 0)
            continue;
        snprintf(b->name, sizeof b->name, "%s", s->name);
        n->bodies.dirty = n->bodies.save_due = true;
        n->bodies.seq = n->sim ? sim_seq(n->sim) : 0;
    }
    body_net_flush(n);
}

/* A body whose owner is gone: after the grace it drifts unpowered, after
 * twice the grace it is removed (reason "abandoned"). */
static void grace(struct net *n, double now)
{
    for (int i = 0; i < n->bodies.n; i++) {
        struct body_own *b = &n->bodies.b[i];
        if (b->owner || b->left_t <= 0 || b->removing)
            continue;
        if (!b->stopped && now - b->left_t >= n->dc.body_grace) {
            b->stopped = true;
            set_adrift(n, b->id, true, true);
        }
        if (now - b->left_t >= 2 * n->dc.body_grace) {
            struct sim_body_cmd *c = cmd_new(SIM_BODY_REMOVE, b->id);
            if (c) {
                c->reason = "abandoned";
                b->removing = true;
            }
            submit_own(n, c);
        }
    }
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

static void body_net_flush(struct net *n)
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
    if (!n->saver || !k->snap)
        return;
    if (!k->save_due && now - k->kept_t < BODY_KEEP_EVERY_S)
        return;
    struct state_bodies sb = { .next_id = k->snap->next_id };
    sb.b = calloc(k->snap->count ? (size_t)k->snap->count : 1, sizeof *sb.b);
    if (!sb.b)
        return;
    for (int i = 0; i < k->snap->count; i++) {
        const struct body_own *b = find(n, k->snap->states[i].id);
        if (!b) /* launched a moment ago: its answer comes with the next wake */
            continue;
        struct state_body *e = &sb.b[sb.n++];
        e->st = k->snap->states[i];
        snprintf(e->owner, sizeof e->owner, "%s", b->owner_id);
        snprintf(e->name, sizeof e->name, "%s", b->name);
        memcpy(e->resume, b->resume, sizeof e->resume);
    }
    sb.cap = sb.n;
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
    grace(n, now);
    keep(n, now);
    body_net_flush(n);
}

void body_net_free(struct net *n)
{
    body_snap_unref(n->bodies.snap);
    free(n->bodies.b);
    free(n->bodies.gone);
    n->bodies = (struct body_book){ 0 };
}

/* ---- start-up ---- */

void net_attach_saver(struct net *n, struct state_saver *sv) { n->saver = sv; }

void net_bodies_restore(struct net *n, const struct state_bodies *sb)
{
    double now = mono_now();
    for (int i = 0; i < sb->n; i++) {
        struct body_own *b = add(n, sb->b[i].st.id);
        if (!b)
            return;
        b->kind = sb->b[i].st.kind;
        snprintf(b->owner_id, sizeof b->owner_id, "%s", sb->b[i].owner);
        snprintf(b->name, sizeof b->name, "%s", sb->b[i].name);
        memcpy(b->resume, sb->b[i].resume, sizeof b->resume);
        b->left_t = now; /* every owner has to claim its body again, within the grace */
    }
}

/* body_owners.c — floating bodies' owners on the lws thread (PROTOCOL.md
 * §7.6): sessions that leave or rename themselves, the grace after which an
 * unclaimed body drifts and then goes, and a cluster's side of it: the
 * clients of edges (their edges' owners lists), a standby's take-over of the
 * bodies, and an edge adopting the sim's list and limits. The requests and
 * answers are body_net.c's. */
#include "body_net_internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "log.h"
#include "state_saver.h"

/* ---- owners ---- */

void body_owner_left(struct net *n, uint64_t serial)
{
    double now = mono_now();
    for (int i = 0; serial && i < n->bodies.n; i++) {
        struct body_own *b = &n->bodies.b[i];
        if (b->owner != serial)
            continue;
        b->owner = 0;
        b->left_t = now;
        body_set_adrift(n, b->id, true, false);
        n->bodies.dirty = true;
        n->bodies.seq = sim_seq(n->sim);
    }
}

void body_net_session_gone(struct net *n, struct session *s)
{
    if (!n->sim) { /* an edge: the sim hears it with the next owners message */
        n->bodies.owners_due |= s->body_user;
        s->body_user = false;
        return;
    }
    body_owner_left(n, s->serial);
}

void body_net_renamed(struct net *n, struct session *s)
{
    if (!n->sim) {
        n->bodies.owners_due |= s->body_user;
        return;
    }
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

/* sim role: clients of edges whose edge has not listed them for
 * BODY_OWNERS_EXPIRE_S (the edge died, or lost the sim) are gone. */
static void remote_expiry(struct net *n, double now)
{
    for (int i = n->bodies.nrc - 1; i >= 0; i--)
        if (now - n->bodies.rc[i].seen > BODY_OWNERS_EXPIRE_S && !n->bodies.rc[i].launching)
            body_rc_gone(n, &n->bodies.rc[i]);
}

void net_remote_owners(struct net *n, const char *origin, const char *text, size_t len)
{
    struct ctl_error e;
    cJSON *root = control_parse_object(text, len, &e);
    const cJSON *list = cJSON_GetObjectItemCaseSensitive(root, "clients");
    if (!n->sim || !cJSON_IsArray(list)) {
        cJSON_Delete(root);
        return;
    }
    double now = mono_now();
    for (int i = n->bodies.nrc - 1; i >= 0; i--) {
        struct body_remote *r = &n->bodies.rc[i];
        if (strcmp(r->origin, origin) != 0)
            continue;
        const cJSON *c, *hit = NULL;
        cJSON_ArrayForEach(c, list)
        {
            const char *by = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(c, "by"));
            if (by && strcmp(by, r->by) == 0) {
                hit = c;
                break;
            }
        }
        if (!hit) {
            if (!r->launching) /* a launch on its way keeps it until its answer */
                body_rc_gone(n, r);
            continue;
        }
        r->seen = now;
        const char *name = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(hit, "name"));
        if (name && strcmp(name, r->name) != 0 && control_check_name(name, &e) == 0) {
            snprintf(r->name, sizeof r->name, "%s", name);
            for (int k = 0; k < n->bodies.n; k++)
                if (n->bodies.b[k].owner == r->serial) {
                    snprintf(n->bodies.b[k].name, sizeof n->bodies.b[k].name, "%s", name);
                    n->bodies.dirty = n->bodies.save_due = true;
                    n->bodies.seq = sim_seq(n->sim);
                }
        }
    }
    cJSON_Delete(root);
    body_net_flush(n);
}

char *net_body_owners(struct net *n, double now)
{
    struct body_book *k = &n->bodies;
    if (!k->owners_due && now - k->owners_t < BODY_OWNERS_PERIOD_S)
        return NULL;
    cJSON *o = cJSON_CreateObject();
    cJSON *list = cJSON_AddArrayToObject(o, "clients");
    cJSON_AddStringToObject(o, "type", "owners");
    int count = 0;
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d && list; d = d->next) {
        struct session *s = session_of(d);
        if (!s->body_user || !s->wsi || s->closing)
            continue;
        cJSON *c = cJSON_CreateObject();
        cJSON_AddStringToObject(c, "by", s->client_id);
        cJSON_AddStringToObject(c, "name", s->name);
        cJSON_AddItemToArray(list, c);
        count++;
    }
    bool send = count > 0 || k->owners_any; /* one empty list tells the sim the last one left */
    char *text = send ? control_print(o) : (cJSON_Delete(o), NULL);
    if (send && !text)
        return NULL; /* out of memory: tried again at the next wake */
    k->owners_due = false;
    k->owners_t = now;
    k->owners_any = count > 0;
    return text;
}

/* A body whose owner is gone: after the grace it drifts unpowered, after
 * twice the grace it is removed (reason "abandoned"). */
void body_grace_expiry(struct net *n, double now)
{
    remote_expiry(n, now);
    for (int i = 0; i < n->bodies.n; i++) {
        struct body_own *b = &n->bodies.b[i];
        if (b->owner || b->left_t <= 0 || b->removing)
            continue;
        if (!b->stopped && now - b->left_t >= n->dc.body_grace) {
            b->stopped = true;
            body_set_adrift(n, b->id, true, true);
        }
        if (now - b->left_t >= 2 * n->dc.body_grace) {
            struct sim_body_cmd *c = body_cmd_new(SIM_BODY_REMOVE, b->id);
            if (c) {
                c->reason = "abandoned";
                b->removing = true;
            }
            body_submit_own(n, c);
        }
    }
}

/* ---- a cluster ---- */

void net_bodies_take_over(struct net *n, const struct state_bodies *sb)
{
    struct body_book *k = &n->bodies;
    if (!n->sim)
        return;
    struct sim_body_cmd *c = body_cmd_new(SIM_BODY_RESTORE, 0);
    size_t bytes = (size_t)sb->n * (sizeof *c->states + 1);
    if (c && !(c->states = malloc(bytes ? bytes : 1))) {
        free(c);
        c = NULL;
    }
    if (!c) {
        LOGE("bodies: out of memory taking the bodies over: the world keeps its own");
        return;
    }
    c->adrift_flags = (uint8_t *)(c->states + sb->n);
    c->nstates = sb->n;
    /* Ids never go back: past every id the record or this sim issued. */
    c->next_id = sb->next_id;
    if (k->snap && k->snap->next_id > c->next_id)
        c->next_id = k->snap->next_id;
    /* The book anew: the sessions of this daemon own nothing (a sim has
     * none); a client of an edge keeps its body while its edge lists it. */
    body_net_drop_remote(n);
    k->n = k->nrc = k->launching = 0;
    double now = mono_now();
    for (int i = 0; i < sb->n; i++) {
        const struct state_body *e = &sb->b[i];
        c->states[i] = e->st;
        struct body_own *b = body_add(n, e->st.id);
        struct body_remote *r = e->origin[0] && e->owner[0] ? body_rc_get(n, e->origin, e->owner) : NULL;
        c->adrift_flags[i] = !r;
        if (!b)
            continue;
        b->kind = e->st.kind;
        snprintf(b->owner_id, sizeof b->owner_id, "%s", e->owner);
        snprintf(b->name, sizeof b->name, "%s", e->name);
        memcpy(b->resume, e->resume, sizeof b->resume);
        if (r) {
            snprintf(r->name, sizeof r->name, "%s", e->name);
            b->owner = r->serial;
        } else {
            b->left_t = now; /* adrift: its owner claims it within the grace */
        }
    }
    k->restoring = true;
    k->dirty = k->save_due = true;
    k->seq = sim_seq(n->sim);
    sim_body_submit(n->sim, c);
    LOGI("bodies: %d floating bodies taken over", sb->n);
    body_net_flush(n);
}

/* edge: one entry of the sim's list into the book (checked: it goes to clients). */
static int adopt_entry(struct net *n, const cJSON *j)
{
    const cJSON *id = cJSON_GetObjectItemCaseSensitive(j, "body");
    const char *kind = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(j, "kind"));
    const char *owner = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(j, "owner"));
    const char *name = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(j, "name"));
    const cJSON *adrift = cJSON_GetObjectItemCaseSensitive(j, "adrift");
    struct ctl_error e;
    const struct body_kind *k = kind ? body_kind_find(kind) : NULL;
    if (!cJSON_IsNumber(id) || id->valuedouble < 1 || id->valuedouble > UINT32_MAX || !k || !owner ||
        strlen(owner) >= sizeof n->bodies.b->owner_id || !name || control_check_name(name, &e) != 0 ||
        !cJSON_IsBool(adrift) || body_find(n, (uint32_t)id->valuedouble))
        return -1;
    struct body_own *b = body_add(n, (uint32_t)id->valuedouble);
    if (!b)
        return -1;
    b->kind = k;
    snprintf(b->owner_id, sizeof b->owner_id, "%s", owner);
    snprintf(b->name, sizeof b->name, "%s", name);
    b->owner = cJSON_IsTrue(adrift) ? 0 : 1; /* an edge knows owners by id only: 1 = somebody */
    return 0;
}

static int adopt_list(struct net *n, const cJSON *list)
{
    if (!cJSON_IsArray(list) || cJSON_GetArraySize(list) > BODY_MAX_WORLD)
        return -1;
    n->bodies.n = 0;
    const cJSON *j;
    cJSON_ArrayForEach(j, list)
        if (adopt_entry(n, j) != 0) {
            n->bodies.n = 0; /* all or nothing: the next list tries again */
            return -1;
        }
    return 0;
}

void net_body_refused(struct net *n, uint64_t serial)
{
    struct session *s = session_find(n, serial);
    if (s && s->launch_t > 0)
        s->launch_tokens = fmin(n->dc.launch_rate, s->launch_tokens + 1);
}

int net_adopt_bodies(struct net *n, const char *text, size_t len)
{
    static const char *const types[] = { "bodies", NULL };
    cJSON *root = net_sim_message(text, len, NET_SIM_REPLY_MAX, types);
    int rc = root ? adopt_list(n, cJSON_GetObjectItemCaseSensitive(root, "bodies")) : -1;
    cJSON_Delete(root);
    if (rc != 0)
        return -1;
    return net_relay_sim_text(n, text, len, NULL);
}

int body_net_adopt_hello(struct net *n, const cJSON *hello)
{
    const cJSON *l = cJSON_GetObjectItemCaseSensitive(hello, "body_limits");
    const cJSON *ps = cJSON_GetObjectItemCaseSensitive(l, "per_session");
    const cJSON *mb = cJSON_GetObjectItemCaseSensitive(l, "max_bodies");
    const cJSON *lr = cJSON_GetObjectItemCaseSensitive(l, "launch_rate");
    const cJSON *gr = cJSON_GetObjectItemCaseSensitive(l, "grace");
    /* The sim's limits, told to this edge's clients; the launch rate is kept here. */
    if (cJSON_IsNumber(ps) && ps->valuedouble >= 0 && ps->valuedouble <= 1024)
        n->dc.bodies_per_session = ps->valueint;
    if (cJSON_IsNumber(mb) && mb->valuedouble >= 1 && mb->valuedouble <= 1024)
        n->dc.max_bodies = mb->valueint;
    if (cJSON_IsNumber(lr) && lr->valuedouble > 0 && lr->valuedouble <= 1e6)
        n->dc.launch_rate = lr->valuedouble;
    if (cJSON_IsNumber(gr) && gr->valuedouble >= 0.1 && gr->valuedouble <= 86400)
        n->dc.body_grace = gr->valuedouble;
    const cJSON *list = cJSON_GetObjectItemCaseSensitive(hello, "bodies");
    return list ? adopt_list(n, list) : 0;
}

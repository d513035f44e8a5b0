/* link_request.c — requests and replies: an edge asks the sim (ctl, hello,
 * query, probe) with NATS request/reply. Each request gets a reply subject
 * <edge inbox>.<id> and waits in the pending list until its reply, a
 * no-responders answer (no sim) or its deadline: its callback runs exactly
 * once, in cl_link_dispatch. The sim sees each as a struct cl_request and
 * answers it once with cl_request_reply, whenever it likes. */
#include "link_internal.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- sim side ---- */

void link_on_request(struct cl_link *l, natsMsg *msg, enum cl_kind want)
{
    struct cl_envelope env;
    const char *reply = natsMsg_GetReply(msg);
    if (!link_msg_envelope(msg, want, &env) || !reply || !reply[0] || strlen(reply) >= CL_SUBJECT_MAX) {
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
    link_push_event(l, e);
}

void cl_request_reply(struct cl_link *l, struct cl_request *req, const char *text, size_t len)
{
    if (!req)
        return;
    if (text)
        link_push_envelope(l, req->reply_to, NULL, CL_KIND_REPLY, l->name, req->by, text, len);
    free(req->body);
    free(req);
}

/* ---- edge side ---- */

/* out_lock held: unlinks and returns the pending request with this id, or NULL. */
static struct pending *pending_take(struct cl_link *l, uint64_t id)
{
    for (struct pending **pp = &l->pending; *pp; pp = &(*pp)->next)
        if ((*pp)->id == id) {
            struct pending *p = *pp;
            *pp = p->next;
            return p;
        }
    return NULL;
}

int cl_edge_request(struct cl_link *l, enum cl_kind kind, const char *by, const char *body, size_t len,
                    cl_reply_fn done, void *ctx)
{
    if (!l || l->cfg.role != CL_ROLE_EDGE || (kind != CL_KIND_CTL && kind != CL_KIND_HELLO && kind != CL_KIND_QUERY &&
                                             kind != CL_KIND_PROBE))
        return CL_E_ARG;
    STAT_ADD(l, requests_sent, 1);
    if (!atomic_load(&l->connected)) {
        link_push_reply(l, done, ctx, CL_E_NOT_CONNECTED, NULL, 0); /* answered at the next dispatch */
        return CL_OK;
    }
    struct pending *p = calloc(1, sizeof *p);
    if (!p)
        return CL_E_NOMEM;
    p->done = done;
    p->ctx = ctx;
    pthread_mutex_lock(&l->out_lock);
    uint64_t id = p->id = ++l->next_id;
    p->deadline = link_now() + (kind == CL_KIND_QUERY ? l->cfg.query_timeout_s : l->cfg.request_timeout_s);
    p->next = l->pending;
    l->pending = p;
    pthread_mutex_unlock(&l->out_lock);
    char reply[CL_SUBJECT_MAX + 24]; /* link_push_envelope refuses one over CL_SUBJECT_MAX */
    snprintf(reply, sizeof reply, "%s.%llu", l->inbox, (unsigned long long)id);
    enum sub_kind sk = kind == CL_KIND_CTL ? SUB_CTL : kind == CL_KIND_HELLO ? SUB_HELLO
                     : kind == CL_KIND_QUERY ? SUB_QUERY : SUB_PROBE;
    int rc = link_push_envelope(l, l->subj[sk], reply, kind, l->name, by, body, len);
    if (rc != CL_OK) {
        pthread_mutex_lock(&l->out_lock);
        struct pending *mine = pending_take(l, id);
        pthread_mutex_unlock(&l->out_lock);
        if (!mine) /* the time-out sweep took it first and has answered done: one answer, one free */
            return CL_OK;
        free(mine);
    }
    return rc;
}

void link_on_reply(struct cl_link *l, natsMsg *msg)
{
    const char *subj = natsMsg_GetSubject(msg);
    size_t il = strlen(l->inbox);
    char *end;
    if (strncmp(subj, l->inbox, il) != 0 || subj[il] != '.') {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    if (strcmp(subj + il + 1, "p") == 0) { /* the sim's probe_data for our clients */
        link_on_probe_data(l, msg);
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
    } else if (!link_msg_envelope(msg, CL_KIND_REPLY, &env)) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    pthread_mutex_lock(&l->out_lock);
    struct pending *p = pending_take(l, id);
    pthread_mutex_unlock(&l->out_lock);
    if (!p)
        return; /* timed out already, or a duplicate answer */
    if (status == 0)
        STAT_ADD(l, replies_received, 1);
    link_push_reply(l, p->done, p->ctx, status, status == 0 ? env.body : NULL, env.body_len);
    free(p);
}

struct pending *link_requests_expired(struct cl_link *l, double now)
{
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
    return expired;
}

void link_requests_time_out(struct cl_link *l, struct pending *expired)
{
    while (expired) {
        struct pending *next = expired->next;
        STAT_ADD(l, request_timeouts, 1);
        link_push_reply(l, expired->done, expired->ctx, CL_E_TIMEOUT, NULL, 0);
        free(expired);
        expired = next;
    }
}

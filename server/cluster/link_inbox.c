/* link_inbox.c — the link's inbox: NATS and pump threads queue events, the
 * daemon's thread runs their handlers in cl_link_dispatch, so no handler
 * ever runs on a NATS thread. Bounded: CL_INBOX_MAX events, and one layer
 * per key (the newest). */
#include "link_internal.h"

#include <stdlib.h>
#include <string.h>

void link_event_free(struct in_event *e)
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

/* in_lock held: appends e; true when the inbox was empty (wake the caller). */
static bool append_locked(struct cl_link *l, struct in_event *e)
{
    bool was_empty = l->in_head == NULL;
    e->next = NULL;
    *l->in_tail = e;
    l->in_tail = &e->next;
    l->in_count++;
    return was_empty;
}

void link_wake(struct cl_link *l)
{
    if (l->cfg.wake)
        l->cfg.wake(l->cfg.wake_user);
}

void link_push_event(struct cl_link *l, struct in_event *e)
{
    bool woke = false, dropped = false;
    pthread_mutex_lock(&l->in_lock);
    /* never shed state changes (the daemon's view would stay wrong) or replies (promised exactly once) */
    if (l->in_count >= CL_INBOX_MAX && e->type != IN_STATE && e->type != IN_REPLY)
        dropped = true; /* the dispatching thread is this far behind: shed load */
    else
        woke = append_locked(l, e);
    pthread_mutex_unlock(&l->in_lock);
    if (dropped) {
        if (e->type == IN_REQUEST)
            STAT_ADD(l, requests_dropped, 1);
        else
            STAT_ADD(l, events_dropped, 1);
        link_event_free(e);
    }
    if (woke)
        link_wake(l);
}

void link_push_state(struct cl_link *l, enum cl_event ev)
{
    struct in_event *e = calloc(1, sizeof *e);
    if (!e)
        return;
    e->type = IN_STATE;
    e->ev = ev;
    link_push_event(l, e);
}

void link_push_reply(struct cl_link *l, cl_reply_fn done, void *ctx, int status, const uint8_t *text, size_t len)
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
    link_push_event(l, e);
}

struct in_event *link_event_with_body(struct cl_link *l, const struct cl_envelope *env, enum in_type type)
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

bool link_inbox_put_layer(struct cl_link *l, struct cl_layer *layer)
{
    int key = cl_info_key(&layer->info);
    struct in_event *q = l->layer_ev[key];
    if (q) {
        /* latest layer wins: the lws thread has not taken the older one yet */
        cl_layer_free(q->layer);
        q->layer = layer;
        STAT_ADD(l, layers_dropped_inbox, 1);
        return false;
    }
    struct in_event *e = calloc(1, sizeof *e);
    if (!e) {
        cl_layer_free(layer);
        STAT_ADD(l, events_dropped, 1);
        return false;
    }
    e->type = IN_LAYER;
    e->layer = layer;
    l->layer_ev[key] = e;
    return append_locked(l, e);
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
        case IN_BODIES:
        case IN_BODY_SECTION:
            if (h->on_bodies)
                h->on_bodies(u, e->type == IN_BODY_SECTION, e->text, e->len);
            break;
        }
        link_event_free(e);
        e = next;
        n++;
    }
    return n;
}

/* link_heartbeat.c — heartbeats both ways and what they keep alive. The
 * sim publishes its status every heartbeat_s: an edge sees the sim up at the
 * first one and down after sim_timeout_s without. An edge publishes its
 * demand (the layers its clients want, with an expiry) every heartbeat_s and
 * at once when it changes, reconnects or sees a sim come up; the sim's
 * demand table forgets an edge at that expiry. The edge's layer
 * subscriptions follow its demand. Plain NATS publishes, no JetStream: a
 * lost heartbeat is replaced by the next. */
#include "link_internal.h"

#include <stdlib.h>
#include <string.h>

/* ---- sim side ---- */

void cl_sim_set_standby(struct cl_link *l, bool standby)
{
    atomic_store(&l->standby, standby);
    pthread_mutex_lock(&l->out_lock);
    pthread_cond_signal(&l->out_cond); /* the pump (un)subscribes the requests now */
    pthread_mutex_unlock(&l->out_lock);
}

/* pump: a standby is not subscribed to the request subjects, so while no
 * sim acts an edge's request gets "no responders" at once instead of
 * waiting for its timeout, and a standby never sees them. */
static void sync_request_subs(struct cl_link *l)
{
    static const enum sub_kind req[] = { SUB_CTL, SUB_HELLO, SUB_QUERY, SUB_PROBE };
    bool on = !atomic_load(&l->standby), added = false;
    for (size_t i = 0; i < sizeof req / sizeof *req; i++) {
        natsSubscription **sub = &l->subs[req[i]];
        if (on && !*sub)
            added |= (*sub = link_subscribe(l, l->subj[req[i]], req[i])) != NULL; /* NULL: again next round */
        else if (!on && *sub)
            link_unsubscribe(sub);
    }
    if (added) /* the server has them before the first heartbeat tells the edges we act */
        natsConnection_FlushTimeout(l->nc, 1000);
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

void link_on_demand(struct cl_link *l, natsMsg *msg)
{
    struct cl_envelope env;
    uint32_t ttl_ms;
    struct cl_demand_bits bits;
    if (!link_msg_envelope(msg, CL_KIND_DEMAND, &env) || !env.origin[0] ||
        cl_demand_body_parse_ex(env.body, env.body_len, &ttl_ms, &bits) != 0) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    if (cl_demand_update_ex(l->demand, env.origin, &bits, ttl_ms / 1000.0, link_now()) != 0)
        STAT_ADD(l, bad_messages, 1); /* table full: this edge's demand is not counted */
}

int cl_sim_demand_ex(struct cl_link *l, struct cl_demand_bits *out)
{
    if (!l->demand) {
        memset(out, 0, sizeof *out);
        return 0;
    }
    int n = cl_demand_union_ex(l->demand, link_now(), out);
    __atomic_store_n(&l->st.demand_edges, n, __ATOMIC_RELAXED);
    return n;
}

int cl_sim_demand(struct cl_link *l, uint8_t out[CL_KEY_BYTES])
{
    struct cl_demand_bits b;
    int n = cl_sim_demand_ex(l, &b);
    memcpy(out, b.keys, CL_KEY_BYTES);
    return n;
}

/* ---- edge side ---- */

int cl_edge_set_demand_ex(struct cl_link *l, const struct cl_demand_bits *b)
{
    if (!l || l->cfg.role != CL_ROLE_EDGE || !b)
        return CL_E_ARG;
    for (int k = CL_KEYS; k < CL_KEY_BYTES * 8; k++)
        if (cl_bit(b->keys, k))
            return CL_E_ARG;
    for (int i = 0; i < CL_KEY_BYTES; i++)
        if ((b->stream[i] & ~b->keys[i]) || (b->wish[i] & ~b->keys[i]))
            return CL_E_ARG;
    pthread_mutex_lock(&l->out_lock);
    if (memcmp(&l->want, b, sizeof *b) != 0) {
        l->want = *b;
        l->want_changed = true;
        pthread_cond_signal(&l->out_cond);
    }
    pthread_mutex_unlock(&l->out_lock);
    return CL_OK;
}

int cl_edge_set_demand(struct cl_link *l, const uint8_t bits[CL_KEY_BYTES])
{
    if (!bits)
        return CL_E_ARG;
    struct cl_demand_bits b;
    memcpy(b.keys, bits, CL_KEY_BYTES);
    memset(b.stream, 0, CL_KEY_BYTES);
    memcpy(b.wish, bits, CL_KEY_BYTES);
    return cl_edge_set_demand_ex(l, &b);
}

void link_kick_demand(struct cl_link *l)
{
    if (l->cfg.role != CL_ROLE_EDGE)
        return;
    pthread_mutex_lock(&l->out_lock);
    l->want_changed = true; /* send our demand now: the sim may have lost it */
    pthread_cond_signal(&l->out_cond);
    pthread_mutex_unlock(&l->out_lock);
}

void link_on_status(struct cl_link *l, natsMsg *msg)
{
    struct cl_envelope env;
    if (!link_msg_envelope(msg, CL_KIND_STATUS, &env)) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    /* Another sim process (restarted within sim_timeout_s, or a standby
     * that took over) may hold another sea than our hello says. */
    bool fresh = l->sim_instance[0] && strcmp(l->sim_instance, env.by) != 0;
    snprintf(l->sim_instance, sizeof l->sim_instance, "%s", env.by);
    pthread_mutex_lock(&l->in_lock);
    l->sim_last_seen = link_now();
    bool up = !l->sim_up;
    l->sim_up = true;
    pthread_mutex_unlock(&l->in_lock);
    if (up) {
        atomic_store(&l->sim_up_flag, true);
        link_push_state(l, CL_EV_SIM_UP);
    } else if (fresh) {
        link_push_state(l, CL_EV_SIM_NEW);
    }
    if (up || fresh)
        link_kick_demand(l); /* a restarted sim knows no demand yet */
}

/* pump: make the layer subscriptions match want. */
static void sync_layer_subs(struct cl_link *l, const uint8_t want[CL_KEY_BYTES])
{
    for (int k = 0; k < CL_KEYS; k++) {
        bool on = cl_bit(want, k);
        if (on && !l->layer_subs[k]) {
            char subj[CL_SUBJECT_MAX];
            if (cl_subject_layer(subj, sizeof subj, l->prefix, k) == 0)
                l->layer_subs[k] = link_subscribe(l, subj, SUB_LAYER);
        } else if (!on && l->layer_subs[k]) {
            link_unsubscribe(&l->layer_subs[k]);
        }
    }
}

/* pump: the demand heartbeat when due or changed, then the sim's liveness. */
static void edge_beat(struct cl_link *l, struct link_beat *b, double now)
{
    if (b->changed)
        sync_layer_subs(l, b->want.keys);
    if (b->changed || now >= b->next) {
        bool any = false;
        for (int i = 0; i < CL_KEY_BYTES; i++)
            any |= b->want.keys[i] != 0;
        /* an empty set is announced once (the sim forgets us at once), not every period */
        if (any || b->changed || !b->sent_empty) {
            uint8_t body[CL_DEMAND_BODY_EX];
            cl_demand_body_write_ex(body, (uint32_t)(l->cfg.demand_ttl_s * 1000), &b->want);
            link_send_envelope(l, l->subj[SUB_DEMAND], CL_KIND_DEMAND, "", body, sizeof body);
            b->sent_empty = !any;
        }
        b->next = now + l->cfg.heartbeat_s;
    }
    pthread_mutex_lock(&l->in_lock);
    bool down = l->sim_up && now - l->sim_last_seen > l->cfg.sim_timeout_s;
    if (down)
        l->sim_up = false;
    pthread_mutex_unlock(&l->in_lock);
    if (down) {
        atomic_store(&l->sim_up_flag, false);
        link_push_state(l, CL_EV_SIM_DOWN);
    }
}

/* ---- the pump's round ---- */

void link_beat_take(struct cl_link *l, struct link_beat *b, double now)
{
    b->changed = l->want_changed;
    l->want_changed = false;
    b->want = l->want;
    b->status = NULL;
    b->status_len = l->status_len;
    /* a copy: cl_sim_set_status may replace the text while the pump sends it */
    if (l->cfg.role == CL_ROLE_SIM && now >= b->next && l->status_text && (b->status = malloc(b->status_len + 1)))
        memcpy(b->status, l->status_text, b->status_len + 1);
}

void link_beat_send(struct cl_link *l, struct link_beat *b, double now)
{
    if (l->cfg.role == CL_ROLE_EDGE) {
        edge_beat(l, b, now);
        free(b->status);
        b->status = NULL;
        return;
    }
    sync_request_subs(l);
    if (now >= b->next) {
        if (!atomic_load(&l->standby)) /* the deadline moves on either way: the pump sleeps until it */
            link_send_envelope(l, l->subj[SUB_STATUS], CL_KIND_STATUS, l->instance, b->status ? b->status : "{}",
                               b->status ? b->status_len : 2);
        b->next = now + l->cfg.heartbeat_s;
    }
    free(b->status);
    b->status = NULL;
}

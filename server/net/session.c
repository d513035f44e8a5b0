/* session.c — the "oceand.v1" WebSocket protocol: a session's lifecycle,
 * receiving (fragments, size cap), the write schedule (JSON queue before
 * frames), and the simulation's wake-up.
 *
 * The tick thread only publishes and calls lws_cancel_service; lws then
 * calls this protocol with LWS_CALLBACK_EVENT_WAIT_CANCELLED on the service
 * thread, where we take the newest frame and the answers to sets and ask
 * the clients that have something to send for a writable callback. Each
 * writable callback does one lws_write. */
#include "net_internal.h"

#include "clock.h"

#include <malloc.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "log.h"
#include "metrics.h"
#include "query_worker.h"
#include "sim_thread.h"

/* ---- JSON send queue ---- */

/* Bytes a queued message costs us: the message, lws' headroom, the node. */
static size_t text_cost(size_t len) { return sizeof(struct text) + LWS_PRE + len; }

/* Stop serving a client and close it with `status`: its queue is freed now
 * (the memory is the point), the close frame goes out when the socket takes
 * it, and a backstop timeout hangs up a client that never reads. */
void session_cut_off(struct session *s, int status, const char *reason)
{
    while (s->tq.head) {
        struct text *t = lws_container_of(s->tq.head, struct text, list);
        lws_dll2_remove(&t->list);
        free(t);
    }
    s->tq_bytes = 0;
    /* Up to --output-limit-kb just went back to malloc, in pieces the size
     * of replies: hand it back to the system too (rare: once per client cut off). */
    malloc_trim(0);
    if (s->closing)
        return;
    s->closing = status;
    s->close_reason = reason;
    lws_set_timeout(s->wsi, PENDING_TIMEOUT_CLOSE_SEND, CUT_OFF_GRACE_S);
    lws_callback_on_writable(s->wsi);
}

void session_queue_text(struct session *s, const char *msg, bool front)
{
    if (!msg || (s->closing && !front))
        return;
    size_t len = strlen(msg);
    /* Replies are bounded in bytes as well as in number, like redis'
     * client-output-buffer-limit: a client this far behind is not reading. */
    if (s->tq.count >= MAX_TEXT_QUEUE || s->tq_bytes + text_cost(len) > s->output_limit) {
        atomic_fetch_add(&g_metrics.closed_output_limit, 1);
        LOGW("client %s: %u replies (%zu bytes) not read: closing it (1008, --output-limit-kb)", s->client_id,
             (unsigned)s->tq.count, s->tq_bytes);
        session_cut_off(s, LWS_CLOSE_STATUS_POLICY_VIOLATION, "reply queue over limit");
        return;
    }
    struct text *t = malloc(sizeof *t + LWS_PRE + len);
    if (!t)
        return;
    memset(&t->list, 0, sizeof t->list);
    t->len = len;
    memcpy(t->data + LWS_PRE, msg, len);
    if (front)
        lws_dll2_add_head(&t->list, &s->tq);
    else
        lws_dll2_add_tail(&t->list, &s->tq);
    s->tq_bytes += text_cost(len);
    lws_callback_on_writable(s->wsi);
}

void session_queue_json(struct session *s, cJSON *msg)
{
    char *text = control_print(msg);
    session_queue_text(s, text, false);
    free(text);
}

void session_send_error(struct session *s, const struct ctl_error *e, const cJSON *id)
{
    atomic_fetch_add(&g_metrics.control_errors, 1);
    session_queue_json(s, control_error_msg(e, id));
}

static int write_text(struct session *s)
{
    struct text *t = lws_container_of(lws_dll2_get_head(&s->tq), struct text, list);
    lws_dll2_remove(&t->list);
    s->tq_bytes -= text_cost(t->len);
    int w = lws_write(s->wsi, t->data + LWS_PRE, t->len, LWS_WRITE_TEXT);
    bool short_write = w < (int)t->len;
    free(t);
    if (short_write)
        return -1;
    atomic_fetch_add(&g_metrics.text_sent, 1);
    return 1;
}

/* The per-start part of every client id: 4 characters of Crockford's base32
 * (lower case: no i, l, o, u), drawn at random when the daemon starts, so that
 * "c1" of this start is not "c1" of the last one (nor of another edge): ids are
 * "c<serial>-<tag>", e.g. "c7-k3qf" (1 in 2^20 that two starts share a tag). */
void net_instance_tag(char *out, size_t cap)
{
    static const char abc[] = "0123456789abcdefghjkmnpqrstvwxyz";
    uint32_t r = 0;
    if (getrandom(&r, sizeof r, GRND_NONBLOCK) != (ssize_t)sizeof r) {
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        r = (uint32_t)ts.tv_nsec ^ (uint32_t)ts.tv_sec * 2654435761u ^ (uint32_t)getpid() << 12;
    }
    size_t k = 0;
    for (; k < 4 && k + 1 < cap; k++, r >>= 5)
        out[k] = abc[r & 31];
    if (cap)
        out[k] = 0;
}

struct session *session_find(struct net *n, uint64_t serial)
{
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next)
        if (session_of(d)->serial == serial)
            return session_of(d);
    return NULL;
}

/* ---- lifecycle ---- */

static void session_open(struct net *n, struct session *s, struct lws *wsi)
{
    memset(s, 0, sizeof *s);
    s->wsi = wsi;
    /* Frames go out in chunks smaller than the loopback MSS: without
     * TCP_NODELAY, Nagle + delayed ACK would hold every second chunk ~40 ms. */
    int one = 1;
    setsockopt(lws_get_socket_fd(wsi), IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    /* A fixed send buffer instead of autotuning (up to 4 MB): latest
     * frame wins only works if the kernel cannot queue dozens of frames. */
    int sndbuf = n->dc.send_buffer_kb * 1024;
    setsockopt(lws_get_socket_fd(wsi), SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof sndbuf);
    s->output_limit = (size_t)n->dc.output_limit_kb * 1024;
    s->serial = ++n->next_serial;
    snprintf(s->client_id, sizeof s->client_id, "c%llu-%s", (unsigned long long)s->serial, n->instance_tag);
    s->controller = n->dc.control_token[0] == 0;
    s->tokens = n->dc.control_burst;
    s->tokens_t = mono_now();
    s->share = 1; /* its first message passes the budget (fair share: dispatch_take_token) */
    s->share_t = s->tokens_t;
    /* Never a frame from before this tick: after an idle period the last
     * frame built may be minutes old (PROTOCOL.md §3.1). */
    s->first_seq = n->sim ? sim_seq(n->sim) : net_latest_seq(n);
    subscription_default(&s->sub, n->dc.tick_rate);
    /* ws://host/?frames=0: a connection for control messages only, with no
     * frame ever queued ahead of its replies (PROTOCOL.md §1.2). */
    char arg[16];
    const char *frames = lws_get_urlarg_by_name(wsi, "frames=", arg, (int)sizeof arg);
    if (frames && strcmp(frames, "0") == 0)
        subscription_none(&s->sub);
    ladder_open(n, s); /* s->eff = s->sub: the first rung until the link says otherwise */
    dispatch_demand(n, &s->eff, +1);
    lws_dll2_add_tail(&s->list, &n->sessions);
    atomic_store(&g_metrics.clients, (int)n->sessions.count);
    struct hello_info h = {
        .client_id = s->client_id, .controller = s->controller, .params = &n->applied,
        .params_version = n->applied_version, .tick_rate = n->dc.tick_rate,
        .tile_size = net_tile_size(n), .sub = &s->sub, .ease_ticks = n->dc.ease_ticks,
    };
    struct capacity_info ci;
    if (n->sim) {
        sim_capacity(n->sim, &ci);
        h.capacity = &ci;
    }
    h.sea = n->sea_summary; /* the measured sea's summary, or null */
    session_queue_json(s, body_net_hello(n, net_hello_capacity(n, control_hello_msg(&h)))); /* edge: the sim's capacity */
    if (n->status_text)
        session_queue_text(s, n->status_text, false); /* cluster trouble: the banner at once */
    net_capacity_tell(n, s);
    LOGD("client %s connected (%d now)", s->client_id, (int)n->sessions.count);
}

static void session_close(struct net *n, struct session *s)
{
    lws_dll2_remove(&s->list);
    atomic_store(&g_metrics.clients, (int)n->sessions.count);
    LOGD("client %s gone (%d left)", s->client_id, (int)n->sessions.count);
    fanout_want_keyframes(n, s, false);
    dispatch_demand(n, &s->eff, -1);
    query_client_gone(n->queries, s->serial);
    if (n->sim)
        body_net_session_gone(n, s); /* its bodies wait for a claim (--body-grace) */
    renders_session_free(n, s);
    if (n->cluster.client_gone) /* edge: its probe at the sim ends */
        n->cluster.client_gone(n->cluster.user, s->serial);
    while (s->tq.head) {
        struct text *t = lws_container_of(s->tq.head, struct text, list);
        lws_dll2_remove(&t->list);
        free(t);
    }
    s->tq_bytes = 0;
    fanout_session_free(s);
    free(s->rx);
    s->rx = NULL;
    s->wsi = NULL;
}

/* A message over --max-message: too_large, then close 1009. Called at the
 * first byte over the limit; the rest is never buffered. */
static void close_too_large(struct net *n, struct session *s)
{
    atomic_fetch_add(&g_metrics.closed_too_large, 1);
    struct ctl_error e = { .code = "too_large" };
    snprintf(e.message, sizeof e.message, "message larger than %d bytes", n->dc.max_message);
    atomic_fetch_add(&g_metrics.control_errors, 1);
    char *text = control_print(control_error_msg(&e, NULL));
    session_queue_text(s, text, true);
    free(text);
    s->closing = LWS_CLOSE_STATUS_MESSAGE_TOO_LARGE;
    s->close_reason = "message too large";
    free(s->rx);
    s->rx = NULL;
    s->rx_len = 0;
    /* Keep reading (and discarding) the rest: closing a socket with unread
     * input makes the kernel send RST, and the client would never see our 1009. */
    lws_set_timeout(s->wsi, PENDING_TIMEOUT_CLOSE_SEND, 5); /* backstop if it never reads */
    lws_callback_on_writable(s->wsi);
}

/* ---- receive ---- */

static int on_receive(struct net *n, struct session *s, struct lws *wsi, const char *in, size_t len)
{
    if (s->closing || rx_guard_tripped(lws_get_socket_fd(wsi)))
        return 0; /* the empty frame rx_guard put in place of an unmasked one */
    bool message_end = lws_is_final_fragment(wsi) && !lws_remaining_packet_payload(wsi);
    if (lws_frame_is_binary(wsi)) {
        /* Binary data is not part of the protocol, but it costs a reply:
         * it is charged to the rate limit and capped like text. */
        if (!s->rx_binary) {
            s->rx_binary = true;
            s->rx_binary_len = 0;
            if (len + lws_remaining_packet_payload(wsi) <= (size_t)n->dc.max_message &&
                dispatch_take_token(n, s, NULL, 0)) {
                struct ctl_error e = { .code = "bad_message", .message = "binary messages are not accepted from clients" };
                session_send_error(s, &e, NULL);
            }
        }
        s->rx_binary_len += len;
        if (s->rx_binary_len + lws_remaining_packet_payload(wsi) > (size_t)n->dc.max_message) {
            close_too_large(n, s);
            return 0;
        }
        if (message_end)
            s->rx_binary = false;
        return 0;
    }
    if (s->rx_len + len > (size_t)n->dc.max_message) {
        close_too_large(n, s);
        return 0;
    }
    if (lws_is_first_fragment(wsi) && message_end && s->rx_len == 0) {
        dispatch_message(n, s, in, len); /* common case: no copy */
        return 0;
    }
    char *nb = realloc(s->rx, s->rx_len + len + 1);
    if (!nb)
        return -1;
    s->rx = nb;
    memcpy(s->rx + s->rx_len, in, len);
    s->rx_len += len;
    if (message_end) {
        dispatch_message(n, s, s->rx, s->rx_len);
        s->rx_len = 0;
    }
    return 0;
}

/* ---- write schedule: one lws_write per writable callback ---- */

/* The frame in progress first (a message cannot interleave with its
 * fragments: a live one, or a rendered one), then one queued JSON message,
 * then the next of the client's render (renders.c), then a newer frame. */
static int on_writable(struct net *n, struct session *s)
{
    int rc;
    if (!s->cur && s->rq && s->rq_sent > 0 && !s->closing) {
        rc = renders_write(n, s);
    } else if ((!s->cur || s->part_left == 0) && s->tq.count) { /* before a frame, or between its parts */
        rc = write_text(s);
    } else if (!s->cur && s->closing) {
        lws_close_reason(s->wsi, (enum lws_close_status)s->closing, (unsigned char *)s->close_reason,
                         strlen(s->close_reason));
        return -1;
    } else if (!s->cur && s->rq) {
        rc = renders_write(n, s);
    } else {
        rc = fanout_write(n, s);
    }
    if (rc < 0)
        return -1;
    /* Keep going while there is more: the rest of the frame, a message, or a
     * newer frame that arrived meanwhile (no need to wait for the next wake-up). */
    if (rc > 0 && (s->cur || s->tq.count || s->rq || s->closing || fanout_want_write(n, s)))
        lws_callback_on_writable(s->wsi);
    return 0;
}

/* The tick thread published a frame and/or answers: take them, and wake
 * the clients that now have something to send. */
static void on_sim_wakeup(struct net *n)
{
    if (n && n->cluster.on_wake)
        n->cluster.on_wake(n->cluster.user); /* cluster messages (NATS link) */
    if (n)
        fanout_police(n);
    if (n)
        renders_take(n); /* an edge renders too */
    if (!n || !n->sim)
        return;
    fanout_take_latest(n);
    if (sim_take_trim(n->sim) && n->trim_due == 0)
        n->trim_due = mono_now(); /* temporal streams were freed: give their pages back */
    dispatch_answers(n);
    body_net_wake(n); /* before the writes: a new body's `bodies` goes out ahead of its first frame */
    dispatch_query_results(n);
    net_capacity_wake(n);
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
        struct session *s = session_of(d);
        if (s->tq.count || fanout_want_write(n, s))
            lws_callback_on_writable(s->wsi);
    }
    if (n->trim_due > 0 && mono_now() >= n->trim_due) {
        /* The builder freed the grids of the old N by now. glibc keeps them
         * on the heap (its mmap threshold grew past their size at the first
         * free), so RSS would stay at the largest N ever used: return the
         * free pages to the system. Once per change of N, on this thread,
         * never on the tick. */
        n->trim_due = 0;
        malloc_trim(0);
    }
}

int cb_ws(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    struct net *n = net_of(wsi);
    struct session *s = user;
    switch (reason) {
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION:
        return upgrade_allowed(n, wsi) ? 0 : 1;
    case LWS_CALLBACK_ESTABLISHED:
        session_open(n, s, wsi);
        return 0;
    case LWS_CALLBACK_CLOSED:
        rx_guard_forget(lws_get_socket_fd(wsi));
        if (s && s->wsi)
            session_close(n, s);
        return 0;
    case LWS_CALLBACK_RECEIVE:
        return on_receive(n, s, wsi, in, len);
    case LWS_CALLBACK_SERVER_WRITEABLE:
        return on_writable(n, s);
    case LWS_CALLBACK_TIMER: /* a frame held for the link (ladder_hold_frame) */
        if (s && s->wsi && !s->closing)
            lws_callback_on_writable(wsi);
        return 0;
    case LWS_CALLBACK_EVENT_WAIT_CANCELLED:
        on_sim_wakeup(n);
        return 0;
    default:
        return 0;
    }
}

/* net.c — lws protocols: HTTP static files + /healthz + /metrics, and the
 * "oceand.v1" WebSocket protocol with latest-frame-wins fan-out.
 *
 * Everything here runs on the lws service thread. The sim thread only
 * publishes frames/events and calls lws_cancel_service; on
 * LWS_CALLBACK_EVENT_WAIT_CANCELLED we pick them up and ask every client
 * for a writable callback. Each client then sends the newest frame, in
 * chunks copied into its own LWS_PRE-prefixed buffer, or skips frames it
 * was too slow for. */
#include "net.h"

#include "clock.h"

#include <libwebsockets.h>
#include <math.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>

#include "control.h"
#include "log.h"
#include "metrics.h"
#include "sim_thread.h"
#include "state.h"

#define CHUNK_SIZE (32 * 1024)    /* bytes per lws_write of a frame */
#define MAX_TEXT_QUEUE 256        /* a client this far behind on JSON is not reading: drop it */

struct text {
    struct text *next;
    size_t len;
    unsigned char data[];         /* LWS_PRE bytes, then the message */
};

struct session {
    struct session *next, **prevp; /* in net->sessions */
    struct lws *wsi;
    uint64_t serial;
    char client_id[24];
    bool controller;
    struct subscription sub;

    /* receive */
    char *rx;
    size_t rx_len;
    bool rx_binary;               /* inside a binary message (fragments of it follow) */
    size_t rx_binary_len;         /* its bytes so far: --max-message applies to it too */
    int closing;                  /* close status to send once the queue drains, 0 = none */
    double tokens, tokens_t;      /* control-message rate limit (token bucket) */

    /* transmit: JSON queue */
    struct text *tq, **tq_tail;
    int tq_len;

    /* transmit: the frame being sent */
    struct frame *cur;
    uint8_t hdr[OC_FRAME_HEADER_SIZE];
    const struct layer *layers[OCEAN_FIELD_COUNT];
    uint16_t tiles[CTL_MAX_TILES];
    int ntiles;
    size_t total, sent;
    int hdr_off, fi, ti;
    size_t off;
    uint64_t last_seq;
    double last_frame_t;
    unsigned char *chunk;         /* LWS_PRE + CHUNK_SIZE */
};

struct http_session {
    unsigned char *body;          /* LWS_PRE + len */
    size_t len;
};

struct net {
    struct lws_context *ctx;
    struct daemon_config dc;
    struct ctl_limits lim;
    struct sim *sim;
    struct frame *latest;
    struct session *sessions;
    int nclients;
    uint64_t next_serial;
    struct ocean_params view;     /* applied + accepted-but-pending sets */
    struct ocean_params applied;
    uint32_t applied_version;
    bool state_dirty;
    double state_saved_t;
    bool placeholder;
    int port;
    lws_retry_bo_t retry;
    struct lws_http_mount m_files, m_health, m_metrics;
    struct lws_protocols protocols[3];
};

static struct net *net_of(struct lws *wsi) { return lws_context_user(lws_get_context(wsi)); }

/* ---- JSON queue ---- */

static void queue_text(struct session *s, const char *msg, bool front)
{
    if (!msg)
        return;
    if (s->tq_len >= MAX_TEXT_QUEUE) {
        /* Not reading its messages: cut it loose rather than grow without bound. */
        lws_set_timeout(s->wsi, PENDING_TIMEOUT_USER_OK, LWS_TO_KILL_ASYNC);
        return;
    }
    size_t len = strlen(msg);
    struct text *t = malloc(sizeof *t + LWS_PRE + len);
    if (!t)
        return;
    t->len = len;
    memcpy(t->data + LWS_PRE, msg, len);
    if (front) {
        t->next = s->tq;
        s->tq = t;
        if (s->tq_tail == &s->tq)
            s->tq_tail = &t->next;
    } else {
        t->next = NULL;
        *s->tq_tail = t;
        s->tq_tail = &t->next;
    }
    s->tq_len++;
    lws_callback_on_writable(s->wsi);
}

static void queue_json(struct session *s, cJSON *msg)
{
    char *text = control_print(msg);
    queue_text(s, text, false);
    free(text);
}

static void send_error(struct session *s, const struct ctl_error *e, const cJSON *id)
{
    atomic_fetch_add(&g_metrics.control_errors, 1);
    queue_json(s, control_error_msg(e, id));
}

/* ---- subscriptions and demand ---- */

static void demand(struct net *n, const struct subscription *sub, int delta)
{
    if (!n->sim)
        return;
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        if (sub->fields & OCEAN_FIELD_BIT(f))
            sim_demand(n->sim, sim_demand_key(f, sub->lod, sub->bound_index), delta);
}

/* ---- state ---- */

void net_save_state(struct net *n)
{
    if (!n->dc.state_file[0])
        return;
    char err[300];
    double t = n->sim ? sim_time_now(n->sim) : 0;
    if (state_save(n->dc.state_file, &n->applied, n->applied_version, t, err, sizeof err) != 0)
        LOGW("%s", err);
    n->state_dirty = false;
    n->state_saved_t = mono_now();
}

/* ---- events from the sim: params broadcast ---- */

static struct session *find_session(struct net *n, uint64_t serial)
{
    for (struct session *s = n->sessions; s; s = s->next)
        if (s->serial == serial)
            return s;
    return NULL;
}

static void handle_events(struct net *n)
{
    struct sim_event *e = sim_take_events(n->sim);
    while (e) {
        struct sim_event *next = e->next;
        struct session *origin = find_session(n, e->origin);
        if (e->failed) {
            n->view = e->params; /* resync with what is really in force */
            if (origin)
                send_error(origin, &e->err, e->id);
        } else {
            n->applied = e->params;
            n->applied_version = e->version;
            n->state_dirty = true;
            char *all = control_print(control_params_msg(&e->params, e->version, e->changed, e->by, NULL));
            for (struct session *s = n->sessions; s; s = s->next)
                if (s != origin)
                    queue_text(s, all, false);
            free(all);
            if (origin)
                queue_json(origin, control_params_msg(&e->params, e->version, e->changed, e->by, e->id));
        }
        sim_event_free(e);
        e = next;
    }
    if (n->state_dirty && mono_now() - n->state_saved_t >= 1.0)
        net_save_state(n); /* at most once a second: a file write per slider move is too many */
}

/* ---- control messages ---- */

static void submit_set(struct net *n, struct session *s, const cJSON *params, const cJSON *id)
{
    struct ctl_error e;
    struct ocean_params out;
    uint64_t changed;
    if (control_apply_params(params, &n->view, &n->lim, &out, &changed, &e) != 0) {
        send_error(s, &e, id);
        return;
    }
    if (!changed) {
        queue_json(s, control_params_msg(&n->view, n->applied_version, 0, s->client_id, id));
        return;
    }
    struct sim_set *set = calloc(1, sizeof *set);
    if (!set) {
        struct ctl_error oom = { .code = "internal", .message = "out of memory" };
        send_error(s, &oom, id);
        return;
    }
    set->values = out;
    set->mask = changed;
    set->origin = s->serial;
    memcpy(set->by, s->client_id, sizeof set->by);
    set->id = id ? cJSON_Duplicate(id, 1) : NULL;
    n->view = out;
    sim_submit(n->sim, set);
}

/* Charge one message to the client's token bucket (every message from a
 * client, text or binary, costs the daemon a reply). false = over the limit:
 * the client got rate_limited and the message is to be dropped. */
static bool take_token(struct net *n, struct session *s)
{
    atomic_fetch_add(&g_metrics.control_messages, 1);
    double now = mono_now();
    s->tokens += (now - s->tokens_t) * n->dc.control_rate;
    if (s->tokens > n->dc.control_burst)
        s->tokens = n->dc.control_burst;
    s->tokens_t = now;
    if (s->tokens < 1) {
        struct ctl_error e = { .code = "rate_limited" };
        snprintf(e.message, sizeof e.message, "more than %g control messages per second", n->dc.control_rate);
        send_error(s, &e, NULL);
        return false;
    }
    s->tokens -= 1;
    return true;
}

static void handle_message(struct net *n, struct session *s, const char *text, size_t len)
{
    if (!take_token(n, s))
        return;

    struct ctl_msg m;
    struct ctl_error e;
    cJSON *bad_id = NULL;
    if (control_parse(text, len, &m, &bad_id, &e) != 0) {
        send_error(s, &e, bad_id);
        cJSON_Delete(bad_id);
        return;
    }
    switch (m.type) {
    case CTL_SET:
    case CTL_PAUSE:
    case CTL_RESUME: {
        if (!s->controller && !(m.token && n->dc.control_token[0] && control_token_equal(m.token, n->dc.control_token))) {
            struct ctl_error f = { .code = "forbidden", .message = "this client may not change parameters (token needed)" };
            send_error(s, &f, m.id);
            break;
        }
        if (m.type == CTL_SET) {
            submit_set(n, s, m.params, m.id);
        } else {
            cJSON *p = cJSON_CreateObject();
            cJSON_AddBoolToObject(p, "paused", m.type == CTL_PAUSE);
            submit_set(n, s, p, m.id);
            cJSON_Delete(p);
        }
        break;
    }
    case CTL_SUBSCRIBE: {
        struct subscription *ns = malloc(sizeof *ns);
        if (!ns)
            break;
        if (control_apply_subscribe(m.root, &s->sub, &n->lim, ns, &e) != 0) {
            send_error(s, &e, m.id);
        } else {
            demand(n, ns, +1);
            demand(n, &s->sub, -1);
            s->sub = *ns;
            queue_json(s, control_subscribed_msg(&s->sub, m.id));
        }
        free(ns);
        break;
    }
    case CTL_PING:
        queue_json(s, control_pong_msg(m.id, m.has_t, m.t, unix_us()));
        break;
    }
    ctl_msg_free(&m);
}

/* ---- frame sending ---- */

/* Prepare s->cur = f for this client: header, layers, tile list. false if the
 * frame lacks a layer this client needs (its subscription just changed). */
static bool begin_frame(struct session *s, struct frame *f)
{
    int tps = f->tiles_per_side;
    int nf = 0;
    for (int fi = 0; fi < OCEAN_FIELD_COUNT; fi++) {
        s->layers[fi] = NULL;
        if (!(s->sub.fields & OCEAN_FIELD_BIT(fi)))
            continue;
        s->layers[fi] = frame_layer(f, fi, s->sub.lod, s->sub.bound_index);
        if (!s->layers[fi])
            return false;
        nf++;
    }
    s->ntiles = 0;
    if (s->sub.all_tiles) {
        for (int i = 0; i < tps * tps; i++)
            s->tiles[s->ntiles++] = (uint16_t)i;
    } else {
        for (int i = 0; i < s->sub.ntiles; i++)
            if (s->sub.tiles[i][0] < tps && s->sub.tiles[i][1] < tps)
                s->tiles[s->ntiles++] = (uint16_t)(s->sub.tiles[i][1] * tps + s->sub.tiles[i][0]);
    }
    struct oc_frame_header h = f->hdr;
    h.tile_count = (uint16_t)(nf * s->ntiles);
    oc_frame_header_write(s->hdr, &h);
    s->total = OC_FRAME_HEADER_SIZE;
    for (int fi = 0; fi < OCEAN_FIELD_COUNT; fi++)
        for (int i = 0; s->layers[fi] && i < s->ntiles; i++)
            s->total += s->layers[fi]->tile_off[s->tiles[i] + 1] - s->layers[fi]->tile_off[s->tiles[i]];
    frame_ref(f);
    s->cur = f;
    s->sent = 0;
    s->hdr_off = 0;
    s->fi = 0;
    s->ti = 0;
    s->off = 0;
    return true;
}

/* Copy the next bytes of the client's frame into dst. */
static size_t fill(struct session *s, unsigned char *dst, size_t cap)
{
    size_t n = 0;
    if (s->hdr_off < OC_FRAME_HEADER_SIZE) {
        size_t take = OC_FRAME_HEADER_SIZE - (size_t)s->hdr_off;
        if (take > cap)
            take = cap;
        memcpy(dst, s->hdr + s->hdr_off, take);
        s->hdr_off += (int)take;
        n += take;
    }
    while (n < cap && s->fi < OCEAN_FIELD_COUNT) {
        const struct layer *l = s->layers[s->fi];
        if (!l || s->ti >= s->ntiles) {
            s->fi++;
            s->ti = 0;
            s->off = 0;
            continue;
        }
        int tile = s->tiles[s->ti];
        size_t start = l->tile_off[tile], size = l->tile_off[tile + 1] - start;
        size_t take = size - s->off;
        if (take > cap - n)
            take = cap - n;
        memcpy(dst + n, l->buf.data + start + s->off, take);
        n += take;
        s->off += take;
        if (s->off == size) {
            s->ti++;
            s->off = 0;
        }
    }
    return n;
}

static int send_chunk(struct net *n, struct session *s)
{
    if (!s->chunk && !(s->chunk = malloc(LWS_PRE + CHUNK_SIZE)))
        return -1;
    size_t len = fill(s, s->chunk + LWS_PRE, CHUNK_SIZE);
    bool first = s->sent == 0, last = s->sent + len >= s->total;
    int flags = lws_write_ws_flags(LWS_WRITE_BINARY, first, last);
    if (lws_write(s->wsi, s->chunk + LWS_PRE, len, (enum lws_write_protocol)flags) < (int)len)
        return -1;
    s->sent += len;
    if (last) {
        atomic_fetch_add(&g_metrics.frames_sent, 1);
        atomic_fetch_add(&g_metrics.bytes_sent, s->total);
        frame_unref(s->cur);
        s->cur = NULL;
    }
    (void)n;
    return 0;
}

/* One lws_write per writable callback: continue a frame, else a JSON
 * message, else start the newest frame if there is one we have not sent. */
static int on_writable(struct net *n, struct session *s)
{
    if (s->cur) {
        if (send_chunk(n, s) != 0)
            return -1;
        /* Keep going: the rest of this frame, a JSON message, or a newer frame
         * that arrived meanwhile (no need to wait for the next tick's wake-up). */
        if (s->cur || s->tq || s->closing || (n->latest && n->latest->hdr.seq > s->last_seq))
            lws_callback_on_writable(s->wsi);
        return 0;
    }
    if (s->tq) {
        struct text *t = s->tq;
        s->tq = t->next;
        if (!s->tq)
            s->tq_tail = &s->tq;
        s->tq_len--;
        int w = lws_write(s->wsi, t->data + LWS_PRE, t->len, LWS_WRITE_TEXT);
        bool short_write = w < (int)t->len;
        free(t);
        if (short_write)
            return -1;
        atomic_fetch_add(&g_metrics.text_sent, 1);
        lws_callback_on_writable(s->wsi);
        return 0;
    }
    if (s->closing) {
        lws_close_reason(s->wsi, (enum lws_close_status)s->closing, (unsigned char *)"message too large", 17);
        return -1;
    }
    struct frame *f = n->latest;
    if (!f || f->hdr.seq <= s->last_seq)
        return 0;
    double now = mono_now();
    /* max_rate: wait until a period has (almost) passed; half a tick of slack absorbs jitter. */
    if (s->sub.max_rate < n->dc.tick_rate && now - s->last_frame_t < 1.0 / s->sub.max_rate - 0.5 / n->dc.tick_rate)
        return 0;
    if (!begin_frame(s, f))
        return 0;
    s->last_seq = f->hdr.seq;
    s->last_frame_t = now;
    if (send_chunk(n, s) != 0)
        return -1;
    if (s->cur || s->tq)
        lws_callback_on_writable(s->wsi);
    return 0;
}

/* Frame `old` is replaced by the newer `seq` (latest frame wins): every
 * client that did not start sending `old` skips it, and every client skips
 * the frames in between, which the sim published while this thread was
 * busy and nobody ever saw. Counted here, as it happens, so that a client
 * that stopped reading shows up in the metrics at once; per client the
 * count equals the holes in the seq numbers it receives. */
static void count_skipped(struct net *n, uint64_t old, uint64_t seq)
{
    uint64_t unseen = seq > old + 1 ? seq - old - 1 : 0;
    for (struct session *s = n->sessions; s; s = s->next) {
        if (!s->last_seq || s->last_seq >= seq)
            continue; /* no frame yet (holes count from the first frame on) */
        uint64_t k = unseen + (s->last_seq < old ? 1 : 0);
        if (k)
            atomic_fetch_add(s->sub.max_rate < n->dc.tick_rate ? &g_metrics.dropped_rate : &g_metrics.dropped_slow, k);
    }
}

/* ---- origin check ---- */

static bool origin_allowed(struct net *n, struct lws *wsi)
{
    char origin[256], host[256];
    if (strcmp(n->dc.allowed_origins, "*") == 0)
        return true;
    if (lws_hdr_copy(wsi, origin, sizeof origin, WSI_TOKEN_ORIGIN) <= 0)
        return true; /* not a browser: the Origin check protects browsers' users */
    if (n->dc.allowed_origins[0] == 0) {
        if (lws_hdr_copy(wsi, host, sizeof host, WSI_TOKEN_HOST) <= 0)
            return false;
        const char *o = strstr(origin, "://");
        return o && strcmp(o + 3, host) == 0;
    }
    char list[sizeof n->dc.allowed_origins];
    snprintf(list, sizeof list, "%s", n->dc.allowed_origins);
    char *save = NULL;
    for (char *tok = strtok_r(list, ", ", &save); tok; tok = strtok_r(NULL, ", ", &save))
        if (strcmp(tok, origin) == 0)
            return true;
    return false;
}

/* ---- the WebSocket protocol ---- */

/* A message over --max-message: too_large, then close 1009. Called at the
 * first byte over the limit; the rest is never buffered. */
static void close_too_large(struct net *n, struct session *s)
{
    atomic_fetch_add(&g_metrics.closed_too_large, 1);
    struct ctl_error e = { .code = "too_large" };
    snprintf(e.message, sizeof e.message, "message larger than %d bytes", n->dc.max_message);
    atomic_fetch_add(&g_metrics.control_errors, 1);
    char *text = control_print(control_error_msg(&e, NULL));
    queue_text(s, text, true);
    free(text);
    s->closing = LWS_CLOSE_STATUS_MESSAGE_TOO_LARGE;
    free(s->rx);
    s->rx = NULL;
    s->rx_len = 0;
    /* Keep reading (and discarding) the rest: closing a socket with unread
     * input makes the kernel send RST, and the client would never see our 1009. */
    lws_set_timeout(s->wsi, PENDING_TIMEOUT_CLOSE_SEND, 5); /* backstop if it never reads */
    lws_callback_on_writable(s->wsi);
}

static void session_free(struct net *n, struct session *s)
{
    demand(n, &s->sub, -1);
    while (s->tq) {
        struct text *t = s->tq->next;
        free(s->tq);
        s->tq = t;
    }
    frame_unref(s->cur);
    s->cur = NULL;
    free(s->chunk);
    free(s->rx);
    s->chunk = NULL;
    s->rx = NULL;
}

static int cb_ws(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    struct net *n = net_of(wsi);
    struct session *s = user;
    switch (reason) {
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION:
        if (n->nclients >= n->dc.max_clients) {
            atomic_fetch_add(&g_metrics.rejected_full, 1);
            LOGW("refusing a client: already %d (--max-clients)", n->nclients);
            return 1;
        }
        if (!origin_allowed(n, wsi)) {
            atomic_fetch_add(&g_metrics.rejected_origin, 1);
            LOGW("refusing a client: Origin not allowed");
            return 1;
        }
        return 0;

    case LWS_CALLBACK_ESTABLISHED: {
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
        s->serial = ++n->next_serial;
        snprintf(s->client_id, sizeof s->client_id, "c%llu", (unsigned long long)s->serial);
        s->controller = n->dc.control_token[0] == 0;
        s->tq_tail = &s->tq;
        s->tokens = n->dc.control_burst;
        s->tokens_t = mono_now();
        subscription_default(&s->sub, n->dc.tick_rate);
        demand(n, &s->sub, +1);
        s->next = n->sessions;
        if (n->sessions)
            n->sessions->prevp = &s->next;
        s->prevp = &n->sessions;
        n->sessions = s;
        n->nclients++;
        atomic_store(&g_metrics.clients, n->nclients);
        struct hello_info h = {
            .client_id = s->client_id, .controller = s->controller, .params = &n->applied,
            .params_version = n->applied_version, .tick_rate = n->dc.tick_rate,
            .tile_size = n->dc.tile_size, .sub = &s->sub,
        };
        queue_json(s, control_hello_msg(&h));
        LOGD("client %s connected (%d now)", s->client_id, n->nclients);
        return 0;
    }

    case LWS_CALLBACK_CLOSED:
        if (!s->wsi)
            return 0;
        *s->prevp = s->next;
        if (s->next)
            s->next->prevp = s->prevp;
        n->nclients--;
        atomic_store(&g_metrics.clients, n->nclients);
        LOGD("client %s gone (%d left)", s->client_id, n->nclients);
        session_free(n, s);
        s->wsi = NULL;
        return 0;

    case LWS_CALLBACK_RECEIVE: {
        if (s->closing)
            return 0;
        bool message_end = lws_is_final_fragment(wsi) && !lws_remaining_packet_payload(wsi);
        if (lws_frame_is_binary(wsi)) {
            /* Binary data is not part of the protocol, but it costs a reply:
             * it is charged to the rate limit and capped like text. */
            if (!s->rx_binary) {
                s->rx_binary = true;
                s->rx_binary_len = 0;
                if (len + lws_remaining_packet_payload(wsi) <= (size_t)n->dc.max_message && take_token(n, s)) {
                    struct ctl_error e = { .code = "bad_message", .message = "binary messages are not accepted from clients" };
                    send_error(s, &e, NULL);
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
        if (lws_is_first_fragment(wsi) && lws_is_final_fragment(wsi) && !lws_remaining_packet_payload(wsi) &&
            s->rx_len == 0) {
            handle_message(n, s, in, len); /* common case: no copy */
            return 0;
        }
        char *nb = realloc(s->rx, s->rx_len + len + 1);
        if (!nb)
            return -1;
        s->rx = nb;
        memcpy(s->rx + s->rx_len, in, len);
        s->rx_len += len;
        if (message_end) {
            handle_message(n, s, s->rx, s->rx_len);
            s->rx_len = 0;
        }
        return 0;
    }

    case LWS_CALLBACK_SERVER_WRITEABLE:
        return on_writable(n, s);

    default:
        return 0;
    }
}

/* ---- HTTP: /healthz, /metrics, placeholder page ---- */

static const char placeholder_html[] =
    "<!doctype html><meta charset=utf-8><title>oceand</title>"
    "<h1>oceand is running</h1><p>The web client is not built (no index.html in the web root). "
    "Run <code>make</code> to bundle it into <code>build/web</code>.</p>"
    "<p>WebSocket: subprotocol <code>oceand.v1</code> on this port. "
    "<a href=/metrics>/metrics</a> · <a href=/healthz>/healthz</a></p>\n";

static int cb_http(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    struct net *n = net_of(wsi);
    struct http_session *hs = user;
    switch (reason) {
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION:
        LOGD("refusing a WebSocket without subprotocol %s", OC_SUBPROTOCOL);
        return 1;
    case LWS_CALLBACK_HTTP: {
        char uri[256] = "";
        lws_hdr_copy(wsi, uri, sizeof uri, WSI_TOKEN_GET_URI);
        const char *type = "text/plain; charset=utf-8";
        int status = HTTP_STATUS_OK;
        char *body = NULL;
        size_t blen = 0;
        if (strcmp(uri, "/healthz") == 0) {
            body = malloc(LWS_PRE + 256);
            if (body)
                blen = (size_t)snprintf(body + LWS_PRE, 256, "{\"status\":\"ok\",\"clients\":%d,\"params_version\":%u,\"ticks\":%llu}\n",
                                        n->nclients, n->applied_version, (unsigned long long)atomic_load(&g_metrics.ticks));
            type = "application/json";
        } else if (strcmp(uri, "/metrics") == 0) {
            size_t cap = 16384;
            body = malloc(LWS_PRE + cap);
            if (body)
                blen = metrics_render(body + LWS_PRE, cap);
            type = "text/plain; version=0.0.4; charset=utf-8";
        } else if (n->placeholder && (strcmp(uri, "/") == 0 || strcmp(uri, "/index.html") == 0)) {
            body = malloc(LWS_PRE + sizeof placeholder_html);
            if (body)
                memcpy(body + LWS_PRE, placeholder_html, blen = sizeof placeholder_html - 1);
            type = "text/html; charset=utf-8";
        } else {
            return lws_return_http_status(wsi, HTTP_STATUS_NOT_FOUND, NULL) ? -1 : lws_http_transaction_completed(wsi);
        }
        if (!body)
            return -1;
        hs->body = (unsigned char *)body;
        hs->len = blen;
        unsigned char hdr[LWS_PRE + 512], *start = hdr + LWS_PRE, *p = start, *end = hdr + sizeof hdr - 1;
        if (lws_add_http_common_headers(wsi, (unsigned)status, type, blen, &p, end) ||
            lws_add_http_header_by_token(wsi, WSI_TOKEN_HTTP_CACHE_CONTROL, (const unsigned char *)"no-store", 8, &p, end) ||
            lws_finalize_write_http_header(wsi, start, &p, end))
            return 1;
        lws_callback_on_writable(wsi);
        return 0;
    }
    case LWS_CALLBACK_HTTP_WRITEABLE: {
        if (!hs || !hs->body)
            break;
        int w = lws_write(wsi, hs->body + LWS_PRE, hs->len, LWS_WRITE_HTTP_FINAL);
        free(hs->body);
        hs->body = NULL;
        if (w < (int)hs->len)
            return -1;
        if (lws_http_transaction_completed(wsi))
            return -1;
        return 0;
    }
    case LWS_CALLBACK_CLOSED_HTTP:
        if (hs) {
            free(hs->body);
            hs->body = NULL;
        }
        break;
    case LWS_CALLBACK_EVENT_WAIT_CANCELLED:
        /* Woken by the sim thread: take the newest frame and the events. */
        if (n && n->sim) {
            struct frame *f = sim_latest(n->sim);
            if (f != n->latest) {
                if (n->latest)
                    count_skipped(n, n->latest->hdr.seq, f->hdr.seq);
                frame_unref(n->latest);
                n->latest = f;
            } else {
                frame_unref(f);
            }
            handle_events(n);
            lws_callback_on_writable_all_protocol(n->ctx, &n->protocols[1]);
        }
        return 0;
    default:
        break;
    }
    return lws_callback_http_dummy(wsi, reason, user, in, len);
}

/* ---- lifecycle ---- */

struct net *net_create(const struct daemon_config *dc, const struct ocean_params *p, uint32_t version,
                       char *err, size_t errlen)
{
    struct net *n = calloc(1, sizeof *n);
    if (!n) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    n->dc = *dc;
    n->lim.tick_rate = dc->tick_rate;
    n->lim.max_memory_mb = dc->max_memory_mb;
    n->view = n->applied = *p;
    n->applied_version = version;
    n->state_saved_t = mono_now();

    n->protocols[0] = (struct lws_protocols){ .name = "http", .callback = cb_http,
                                              .per_session_data_size = sizeof(struct http_session) };
    n->protocols[1] = (struct lws_protocols){ .name = OC_SUBPROTOCOL, .callback = cb_ws,
                                              .per_session_data_size = sizeof(struct session),
                                              .rx_buffer_size = 4096,
                                              /* else lws sends rx_buffer_size bytes per POLLOUT */
                                              .tx_packet_size = CHUNK_SIZE };

    char index[600];
    struct stat st;
    snprintf(index, sizeof index, "%s/index.html", dc->web_root);
    n->placeholder = stat(index, &st) != 0;
    if (n->placeholder)
        LOGW("no %s: serving a placeholder page at /", index);
    n->m_metrics = (struct lws_http_mount){ .mountpoint = "/metrics", .mountpoint_len = 8, .protocol = "http",
                                            .origin_protocol = LWSMPRO_CALLBACK };
    n->m_health = (struct lws_http_mount){ .mount_next = &n->m_metrics, .mountpoint = "/healthz", .mountpoint_len = 8,
                                           .protocol = "http", .origin_protocol = LWSMPRO_CALLBACK };
    if (n->placeholder)
        n->m_files = (struct lws_http_mount){ .mount_next = &n->m_health, .mountpoint = "/", .mountpoint_len = 1,
                                              .protocol = "http", .origin_protocol = LWSMPRO_CALLBACK };
    else
        n->m_files = (struct lws_http_mount){ .mount_next = &n->m_health, .mountpoint = "/", .mountpoint_len = 1,
                                              .origin = n->dc.web_root, .def = "index.html",
                                              .origin_protocol = LWSMPRO_FILE };

    n->retry.secs_since_valid_ping = (uint16_t)dc->ping_interval;
    n->retry.secs_since_valid_hangup = (uint16_t)dc->idle_timeout;

    struct lws_context_creation_info info;
    memset(&info, 0, sizeof info);
    info.port = dc->port;
    info.iface = dc->bind;
    info.protocols = n->protocols;
    info.mounts = &n->m_files;
    info.user = n;
    info.retry_and_idle_policy = &n->retry;
    info.options = LWS_SERVER_OPTION_DISABLE_IPV6 | LWS_SERVER_OPTION_VALIDATE_UTF8;
    if (dc->tls_cert[0]) {
        /* https/wss on the same port (lws' OpenSSL backend). Plain http/ws
         * connections to it fail the TLS handshake: no
         * LWS_SERVER_OPTION_ALLOW_NON_SSL_ON_SSL_PORT. */
        info.options |= LWS_SERVER_OPTION_DO_SSL_GLOBAL_INIT;
        info.ssl_cert_filepath = n->dc.tls_cert;
        info.ssl_private_key_filepath = n->dc.tls_key;
    }
    info.extensions = NULL; /* no permessage-deflate: frames are compressed already */
    info.timeout_secs = 10;
    info.pt_serv_buf_size = CHUNK_SIZE + LWS_PRE + 64; /* lws' scratch for partial sends and reads */
    n->ctx = lws_create_context(&info);
    if (!n->ctx) {
        if (dc->tls_cert[0])
            snprintf(err, errlen, "cannot listen on %s:%d with TLS (port in use, bad --bind, or unreadable / "
                     "mismatched --tls-cert %s / --tls-key %s?)", dc->bind, dc->port, dc->tls_cert, dc->tls_key);
        else
            snprintf(err, errlen, "cannot listen on %s:%d (in use, or bad --bind?)", dc->bind, dc->port);
        free(n);
        return NULL;
    }
    struct lws_vhost *vh = lws_get_vhost_by_name(n->ctx, "default");
    n->port = vh ? lws_get_vhost_listen_port(vh) : dc->port;
    return n;
}

void net_attach_sim(struct net *n, struct sim *s) { n->sim = s; }
void net_wake(void *net) { lws_cancel_service(((struct net *)net)->ctx); }
int net_service(struct net *n) { return lws_service(n->ctx, 0); }
int net_port(const struct net *n) { return n->port; }

void net_destroy(struct net *n)
{
    if (!n)
        return;
    lws_context_destroy(n->ctx); /* closes every client: CLOSED frees sessions */
    frame_unref(n->latest);
    free(n);
}

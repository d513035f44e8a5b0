/* renders.c — exact-time renders on the network side (PROTOCOL.md §7.5):
 * `render` and `render_cancel` handed to the render workers
 * (server/query/render_worker.c, which step and encode), and what they
 * produce — whole frames, then `rendered` — sent to their client in order.
 *
 * Each client has one render queue (session.rq), fed from the workers'
 * results after a wake-up. Its frames go out between live frames (never
 * inside one: a WebSocket message cannot interleave with another's
 * fragments), in chunks from the client's own buffer like live frames; the
 * last byte of each gives the worker room for the next (render_frame_sent),
 * so a client holds at most RENDER_WINDOW frames here. */
#include "net_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "metrics.h"
#include "render_worker.h"

void renders_dispatch(struct net *n, struct session *s, const cJSON *root, const cJSON *id)
{
    struct ctl_error e = { 0 };
    struct render_req *r = malloc(sizeof *r); /* a subscription's tile list: not on the stack */
    double units = 0;
    if (!r) {
        e.code = "internal";
        snprintf(e.message, sizeof e.message, "out of memory");
    } else if (render_parse(root, &n->lim, r, &e) != 0) {
        /* e filled */
    } else if (!n->renders) {
        e.code = "unavailable";
        snprintf(e.message, sizeof e.message, "this daemon has no render workers");
    } else if (n->applied.spectrum == SPECTRUM_MEASURED) {
        /* A render rebuilds the sea from the parameters alone; a measured sea is not carried to the workers. */
        e.code = "invalid";
        snprintf(e.message, sizeof e.message, "renders of a measured sea are not supported: set another spectrum");
    } else if (render_submit(n->renders, s->serial, id, r, &n->applied, n->applied_version, &units, &e) == 0) {
        session_queue_json(s, render_rendering_msg(id, r, n->applied_version, n->applied.resolution,
                                                   n->applied.cascades, units));
        free(r);
        return;
    }
    session_send_error(s, &e, id);
    free(r);
}

/* Frames of s's render not started yet are dropped; the one being sent
 * finishes (its message is half written). The closing messages stay. */
static void drop_frames(struct session *s)
{
    struct render_out **pp = &s->rq, *last = NULL;
    while (*pp) {
        struct render_out *o = *pp;
        if (o->frame && !(o == s->rq && s->rq_sent > 0)) {
            *pp = o->next;
            o->next = NULL;
            render_out_free(o);
            s->rq_frames--;
            continue;
        }
        last = o;
        pp = &o->next;
    }
    s->rq_tail = last;
}

void renders_cancel(struct net *n, struct session *s)
{
    if (n->renders && render_cancel(n->renders, s->serial)) {
        /* Frames posted before the cancel and not taken yet would come after
         * the drop and be sent after a gap: take them first. None is posted
         * after render_cancel returns. */
        renders_take(n);
        drop_frames(s);
    }
}

void renders_session_free(struct net *n, struct session *s)
{
    if (n->renders)
        render_cancel(n->renders, s->serial);
    render_out_free(s->rq);
    s->rq = s->rq_tail = NULL;
    s->rq_frames = 0;
    s->rq_sent = 0;
}

void renders_take(struct net *n)
{
    if (!n->renders)
        return;
    struct render_out *o = render_take_results(n->renders);
    while (o) {
        struct render_out *next = o->next;
        o->next = NULL;
        struct session *s = session_find(n, o->serial);
        if (!s || !s->wsi || s->closing) {
            render_out_free(o); /* its client went: render_cancel ended the render */
        } else {
            if (s->rq_tail)
                s->rq_tail->next = o;
            else
                s->rq = o;
            s->rq_tail = o;
            s->rq_frames += o->frame;
            lws_callback_on_writable(s->wsi);
        }
        o = next;
    }
}

/* One lws_write of s's render queue: a text message whole, or the next
 * chunk of a frame. 1 = written, -1 = close. */
int renders_write(struct net *n, struct session *s)
{
    struct render_out *o = s->rq;
    if (!s->chunk && !(s->chunk = malloc(LWS_PRE + CHUNK_SIZE)))
        return -1;
    size_t len;
    int flags;
    if (!o->frame) {
        /* `rendered` counts the frames written whole, here, not those the worker made */
        if (render_out_print(o, o->render == s->rq_render ? s->rq_written : 0) != 0)
            return -1;
        unsigned char *buf = o->len <= CHUNK_SIZE ? s->chunk : malloc(LWS_PRE + o->len);
        if (!buf)
            return -1;
        memcpy(buf + LWS_PRE, o->data, o->len);
        int w = lws_write(s->wsi, buf + LWS_PRE, o->len, LWS_WRITE_TEXT);
        if (buf != s->chunk)
            free(buf);
        if (w < (int)o->len)
            return -1;
        atomic_fetch_add(&g_metrics.text_sent, 1);
        len = o->len;
        s->rq_sent = o->len;
    } else {
        len = o->len - s->rq_sent;
        if (len > CHUNK_SIZE)
            len = CHUNK_SIZE;
        memcpy(s->chunk + LWS_PRE, o->data + s->rq_sent, len);
        flags = lws_write_ws_flags(LWS_WRITE_BINARY, s->rq_sent == 0, s->rq_sent + len >= o->len);
        if (lws_write(s->wsi, s->chunk + LWS_PRE, len, (enum lws_write_protocol)flags) < (int)len)
            return -1;
        s->rq_sent += len;
    }
    if (s->rq_sent >= o->len) {
        if (o->frame) {
            atomic_fetch_add(&g_metrics.bytes_sent, o->len);
            if (s->rq_render != o->render) { /* the first frame of a new render */
                s->rq_render = o->render;
                s->rq_written = 0;
            }
            s->rq_written++;
            s->rq_frames--;
            if (n->renders)
                render_frame_sent(n->renders, o);
        }
        s->rq = o->next;
        if (!s->rq)
            s->rq_tail = NULL;
        o->next = NULL;
        render_out_free(o);
        s->rq_sent = 0;
    }
    return 1;
}

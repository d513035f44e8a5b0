/* link_pump.c — the outbox and the pump thread. The pump is the only
 * thread that writes to NATS: a slow or dead server (write deadline 2 s)
 * blocks it alone, never the tick or the lws thread, which only append to
 * the outbox. Each round it drains the outbox, sends the heartbeat that is
 * due (link_heartbeat.c) and times out requests (link_request.c). */
#include "link_internal.h"

#include <stdlib.h>
#include <string.h>

#define PUMP_TICK_S 0.05          /* the pump checks timeouts at least this often */

static struct timespec mono_abs(double t)
{
    struct timespec ts;
    ts.tv_sec = (time_t)t;
    ts.tv_nsec = (long)((t - (double)ts.tv_sec) * 1e9);
    if (ts.tv_nsec >= 1000000000L) {
        ts.tv_sec++;
        ts.tv_nsec -= 1000000000L;
    }
    return ts;
}

void link_item_free(struct out_item *it)
{
    if (it->type == OUT_LAYER && it->release)
        it->release(it->ctx);
    free(it->buf);
    free(it);
}

/* pump: one message as it is (reply NULL: none); counts the bytes sent. */
static void publish(struct cl_link *l, const char *subject, const char *reply, const uint8_t *buf, size_t len)
{
    natsStatus s = reply ? natsConnection_PublishRequest(l->nc, subject, reply, buf, (int)len)
                         : natsConnection_Publish(l->nc, subject, buf, (int)len);
    if (s == NATS_OK)
        STAT_ADD(l, bytes_published, len);
}

void link_send_envelope(struct cl_link *l, const char *subject, enum cl_kind kind, const char *by, const void *body,
                        size_t len)
{
    uint8_t stackbuf[512];
    size_t size = cl_envelope_size(l->name, by, len);
    uint8_t *buf = size <= sizeof stackbuf ? stackbuf : malloc(size);
    if (!buf)
        return;
    long w = cl_envelope_write(buf, size, kind, l->name, by, body, len);
    if (w > 0)
        publish(l, subject, NULL, buf, (size_t)w);
    if (buf != stackbuf)
        free(buf);
}

static void *pump_main(void *arg)
{
    struct cl_link *l = arg;
    uint8_t *scratch = NULL;        /* one layer part at a time */
    size_t scap = 0;
    struct link_beat beat = { 0 };
    pthread_mutex_lock(&l->out_lock);
    while (!l->stop) {
        double now = link_now();
        if (!l->out_head && !l->want_changed && now < beat.next) {
            double until = beat.next < now + PUMP_TICK_S ? beat.next : now + PUMP_TICK_S;
            struct timespec ts = mono_abs(until);
            pthread_cond_timedwait(&l->out_cond, &l->out_lock, &ts);
            now = link_now();
        }
        struct out_item *items = l->out_head;
        l->out_head = NULL;
        l->out_tail = &l->out_head;
        l->out_bytes = 0;
        link_beat_take(l, &beat, now);
        struct pending *expired = link_requests_expired(l, now);
        pthread_mutex_unlock(&l->out_lock);

        while (items) {
            struct out_item *next = items->next;
            if (items->type == OUT_LAYER)
                link_publish_layer(l, items, &scratch, &scap);
            else
                publish(l, items->subject, items->reply[0] ? items->reply : NULL, items->buf, items->bytes);
            link_item_free(items);
            items = next;
        }
        link_beat_send(l, &beat, now);
        link_requests_time_out(l, expired);
        pthread_mutex_lock(&l->out_lock);
    }
    pthread_mutex_unlock(&l->out_lock);
    free(scratch);
    return NULL;
}

int link_pump_start(struct cl_link *l)
{
    int rc = pthread_create(&l->pump, NULL, pump_main, l);
    if (rc == 0)
        l->pump_started = true;
    return rc;
}

void link_pump_stop(struct cl_link *l)
{
    if (!l->pump_started)
        return;
    pthread_mutex_lock(&l->out_lock);
    l->stop = true;
    pthread_cond_signal(&l->out_cond);
    pthread_mutex_unlock(&l->out_lock);
    pthread_join(l->pump, NULL);
}

void link_push_out(struct cl_link *l, struct out_item *it)
{
    struct out_item *dropped = NULL;
    pthread_mutex_lock(&l->out_lock);
    if (it->type == OUT_LAYER) {
        /* latest wins: a layer the pump has not sent yet is older than this one */
        for (struct out_item **pp = &l->out_head; *pp && l->out_bytes + it->bytes > l->cfg.outbox_max_bytes;) {
            if ((*pp)->type == OUT_LAYER) {
                struct out_item *d = *pp;
                *pp = d->next;
                l->out_bytes -= d->bytes;
                d->next = dropped;
                dropped = d;
            } else {
                pp = &(*pp)->next;
            }
        }
        /* repair the tail after removals */
        l->out_tail = &l->out_head;
        while (*l->out_tail)
            l->out_tail = &(*l->out_tail)->next;
    }
    it->next = NULL;
    *l->out_tail = it;
    l->out_tail = &it->next;
    l->out_bytes += it->bytes;
    pthread_cond_signal(&l->out_cond);
    pthread_mutex_unlock(&l->out_lock);
    /* released outside the lock: release() is the daemon's code */
    while (dropped) {
        struct out_item *next = dropped->next;
        STAT_ADD(l, layers_dropped_outbox, 1);
        link_item_free(dropped);
        dropped = next;
    }
}

int link_push_envelope(struct cl_link *l, const char *subject, const char *reply, enum cl_kind kind,
                       const char *origin, const char *by, const void *body, size_t len)
{
    if (strlen(subject) >= CL_SUBJECT_MAX || (reply && strlen(reply) >= CL_SUBJECT_MAX))
        return CL_E_ARG;
    size_t size = cl_envelope_size(origin, by, len);
    struct out_item *it = calloc(1, sizeof *it);
    uint8_t *buf = malloc(size);
    long w = it && buf ? cl_envelope_write(buf, size, kind, origin, by, body, len) : CL_E_NOMEM;
    if (w < 0) {
        free(it);
        free(buf);
        return (int)w;
    }
    it->type = OUT_MSG;
    it->buf = buf;
    it->bytes = (size_t)w;
    strcpy(it->subject, subject);
    if (reply)
        strcpy(it->reply, reply);
    link_push_out(l, it);
    return CL_OK;
}

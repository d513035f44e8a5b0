/* link_stream.c — what the sim streams to the edges: layers (split into
 * parts that fit the server's max_payload, reassembled on the edge),
 * params events, and probe data for one edge's clients. The sim's side
 * only queues (the pump publishes); the edge's side parses on the NATS
 * delivery thread and queues for cl_link_dispatch. */
#include "link_internal.h"

#include <stdlib.h>
#include <string.h>

/* ---- sim side ---- */

int cl_sim_publish_layer_sections(struct cl_link *l, const struct cl_layer_info *info, const uint8_t *const data[2],
                                  const size_t len[2], const uint32_t *const tile_off[2], void (*release)(void *ctx),
                                  void *ctx)
{
    struct cl_layer_info in = { 0 };
    if (info) {
        in = *info;
        if (!in.epoch && l)
            in.epoch = l->epoch;
    }
    int sec = info ? in.tiles_per_side * in.tiles_per_side : 0, nsec = info ? cl_layer_sections(&in) : 0;
    bool ok = l && l->cfg.role == CL_ROLE_SIM && cl_layer_info_valid(&in) && sec >= 1 && data && len && tile_off;
    size_t bytes = 0;
    for (int i = 0; ok && i < nsec; i++) {
        ok = tile_off[i] && tile_off[i][0] == 0 && tile_off[i][sec] == len[i] && len[i] <= CL_MAX_LAYER_BYTES &&
             (data[i] || !len[i]);
        bytes += ok ? len[i] : 0;
    }
    if (!ok) {
        if (release)
            release(ctx);
        return CL_E_ARG;
    }
    struct out_item *it = calloc(1, sizeof *it);
    if (!it) {
        if (release)
            release(ctx);
        return CL_E_NOMEM;
    }
    it->type = OUT_LAYER;
    it->info = in;
    it->data = data[0];
    it->tile_off = tile_off[0];
    if (nsec > 1) {
        it->data2 = data[1];
        it->tile_off2 = tile_off[1];
    }
    it->bytes = bytes;
    it->release = release;
    it->ctx = ctx;
    link_push_out(l, it);
    return CL_OK;
}

int cl_sim_publish_layer(struct cl_link *l, const struct cl_layer_info *info, const uint8_t *data, size_t len,
                         const uint32_t *tile_off, void (*release)(void *ctx), void *ctx)
{
    if (info && cl_info_has_shared(info)) { /* one section only: intra tiles */
        if (release)
            release(ctx);
        return CL_E_ARG;
    }
    const uint8_t *d[2] = { data, NULL };
    size_t n[2] = { len, 0 };
    const uint32_t *o[2] = { tile_off, NULL };
    return cl_sim_publish_layer_sections(l, info, d, n, o, release, ctx);
}

void link_publish_layer(struct cl_link *l, const struct out_item *it, uint8_t **scratch, size_t *scap)
{
    if (natsConnection_Status(l->nc) != NATS_CONN_STATUS_CONNECTED) {
        STAT_ADD(l, layers_dropped_offline, 1); /* a stale layer is worth nothing after reconnecting */
        return;
    }
    char subj[CL_SUBJECT_MAX];
    if (cl_subject_layer(subj, sizeof subj, l->prefix, cl_info_key(&it->info)) != 0)
        return;
    int64_t maxp = natsConnection_GetMaxPayload(l->nc);
    if (maxp <= 0)
        maxp = 1 << 20;
    int sec = it->info.tiles_per_side * it->info.tiles_per_side, total = cl_layer_tiles(&it->info);
    for (int first = 0; first < total;) {
        /* parts never span two sections: each has its own buffer and offsets */
        const uint8_t *data = first < sec ? it->data : it->data2;
        const uint32_t *off = first < sec ? it->tile_off : it->tile_off2;
        int local = first % sec;
        int k = cl_layer_part_tiles(off, local, sec, (size_t)maxp);
        if (k == 0) {
            STAT_ADD(l, layers_too_large, 1);
            return;
        }
        size_t size = cl_layer_part_size(k, off[local + k] - off[local]);
        if (size > *scap) {
            uint8_t *p = realloc(*scratch, size);
            if (!p)
                return;
            *scratch = p;
            *scap = size;
        }
        long w = cl_layer_part_write(*scratch, *scap, &it->info, first, k, data, off);
        if (w < 0 || natsConnection_Publish(l->nc, subj, *scratch, (int)w) != NATS_OK) {
            STAT_ADD(l, layers_dropped_offline, 1);
            return;
        }
        STAT_ADD(l, parts_published, 1);
        STAT_ADD(l, bytes_published, w);
        first += k;
    }
    STAT_ADD(l, layers_published, 1);
}

int cl_sim_publish_params(struct cl_link *l, const char *origin, const char *by, const char *text, size_t len)
{
    if (!l || l->cfg.role != CL_ROLE_SIM)
        return CL_E_ARG;
    /* origin is the edge that caused the change: the envelope's origin field */
    return link_push_envelope(l, l->subj[SUB_PARAMS], NULL, CL_KIND_PARAMS, origin, by, text, len);
}

int cl_sim_publish_bodies(struct cl_link *l, enum cl_kind kind, const void *data, size_t len)
{
    if (!l || l->cfg.role != CL_ROLE_SIM || (kind != CL_KIND_BODIES && kind != CL_KIND_BODY_SECTION))
        return CL_E_ARG;
    return link_push_envelope(l, l->subj[SUB_BODIES], NULL, kind, l->name, "", data, len);
}

int cl_sim_publish_probe_data(struct cl_link *l, const char *stream, const char *by, const char *text, size_t len)
{
    if (!l || l->cfg.role != CL_ROLE_SIM || !stream || !by || !by[0])
        return CL_E_ARG;
    pthread_mutex_lock(&l->out_lock);
    bool full = l->out_bytes > l->cfg.outbox_max_bytes;
    pthread_mutex_unlock(&l->out_lock);
    if (full || !atomic_load(&l->connected)) {
        STAT_ADD(l, events_dropped, 1);
        return full ? CL_E_FULL : CL_E_NOT_CONNECTED;
    }
    return link_push_envelope(l, stream, NULL, CL_KIND_PROBE_DATA, l->name, by, text, len);
}

/* ---- edge side ---- */

void link_on_layer(struct cl_link *l, natsMsg *msg)
{
    struct cl_layer_part part;
    if (cl_layer_part_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &part) != 0) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    STAT_ADD(l, parts_received, 1);
    struct cl_layer *layer = NULL;
    bool wake = false;
    /* in_lock also guards the assembler: cl_link_stats reads its drop count */
    pthread_mutex_lock(&l->in_lock);
    int rc = cl_assembler_add(l->assembler, &part, &layer);
    if (rc == 1) {
        wake = link_inbox_put_layer(l, layer);
        STAT_ADD(l, layers_received, 1);
    }
    pthread_mutex_unlock(&l->in_lock);
    if (rc < 0)
        STAT_ADD(l, bad_messages, 1);
    if (wake)
        link_wake(l);
}

/* NATS delivery, edge: an envelope of `kind` whose text goes to the daemon
 * as an event of `type`. */
static void queue_text(struct cl_link *l, natsMsg *msg, enum cl_kind kind, enum in_type type)
{
    struct cl_envelope env;
    /* probe data is for one client of ours: without one it is for nobody */
    if (!link_msg_envelope(msg, kind, &env) || (kind == CL_KIND_PROBE_DATA && !env.by[0])) {
        STAT_ADD(l, bad_messages, 1);
        return;
    }
    struct in_event *e = link_event_with_body(l, &env, type);
    if (!e)
        return;
    strcpy(e->origin, env.origin);
    strcpy(e->by, env.by);
    link_push_event(l, e);
}

void link_on_params(struct cl_link *l, natsMsg *msg) { queue_text(l, msg, CL_KIND_PARAMS, IN_PARAMS); }
void link_on_probe_data(struct cl_link *l, natsMsg *msg) { queue_text(l, msg, CL_KIND_PROBE_DATA, IN_PROBE_DATA); }

void link_on_bodies(struct cl_link *l, natsMsg *msg)
{
    const uint8_t *d = (const uint8_t *)natsMsg_GetData(msg);
    bool section = natsMsg_GetDataLength(msg) > 5 && d[5] == CL_KIND_BODY_SECTION;
    queue_text(l, msg, section ? CL_KIND_BODY_SECTION : CL_KIND_BODIES, section ? IN_BODY_SECTION : IN_BODIES);
}

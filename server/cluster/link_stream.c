/* link_stream.c — what the sim streams to the edges: layers (split into
 * parts that fit the server's max_payload, reassembled on the edge),
 * params events, and probe data for one edge's clients. The sim's side
 * only queues (the pump publishes); the edge's side parses on the NATS
 * delivery thread and queues for cl_link_dispatch. */
#include "link_internal.h"

#include <stdlib.h>
#include <string.h>

/* ---- sim side ---- */

int cl_sim_publish_layer(struct cl_link *l, const struct cl_layer_info *info, const uint8_t *data, size_t len,
                         const uint32_t *tile_off, void (*release)(void *ctx), void *ctx)
{
    int total = info ? info->tiles_per_side * info->tiles_per_side : 0;
    if (!l || l->cfg.role != CL_ROLE_SIM || !cl_layer_info_valid(info) || !tile_off || total < 1 ||
        tile_off[0] != 0 || tile_off[total] != len || len > CL_MAX_LAYER_BYTES) {
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
    it->info = *info;
    it->data = data;
    it->tile_off = tile_off;
    it->bytes = len;
    it->release = release;
    it->ctx = ctx;
    link_push_out(l, it);
    return CL_OK;
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
    int total = it->info.tiles_per_side * it->info.tiles_per_side;
    for (int first = 0; first < total;) {
        int k = cl_layer_part_tiles(it->tile_off, first, total, (size_t)maxp);
        if (k == 0) {
            STAT_ADD(l, layers_too_large, 1);
            return;
        }
        size_t size = cl_layer_part_size(k, it->tile_off[first + k] - it->tile_off[first]);
        if (size > *scap) {
            uint8_t *p = realloc(*scratch, size);
            if (!p)
                return;
            *scratch = p;
            *scap = size;
        }
        long w = cl_layer_part_write(*scratch, *scap, &it->info, first, k, it->data, it->tile_off);
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

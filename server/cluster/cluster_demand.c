/* cluster_demand.c — the sim's demand table: which layers the edges want,
 * each entry living until its edge's announced expiry. A fixed array
 * (max_edges entries, linear scan): a few hundred edges at most, updated
 * once a second each, so a hash table would buy nothing. */
#include "cluster.h"

#include <pthread.h>
#include <stdlib.h>
#include <string.h>

struct entry {
    char edge[CL_NAME_MAX];      /* "" = free */
    struct cl_demand_bits bits;
    double expires;
};

struct cl_demand {
    pthread_mutex_t lock;
    int max;
    struct entry *e;
};

struct cl_demand *cl_demand_new(int max_edges)
{
    if (max_edges < 1)
        return NULL;
    struct cl_demand *d = calloc(1, sizeof *d);
    if (!d)
        return NULL;
    d->e = calloc((size_t)max_edges, sizeof *d->e);
    if (!d->e) {
        free(d);
        return NULL;
    }
    d->max = max_edges;
    pthread_mutex_init(&d->lock, NULL);
    return d;
}

void cl_demand_free(struct cl_demand *d)
{
    if (!d)
        return;
    pthread_mutex_destroy(&d->lock);
    free(d->e);
    free(d);
}

static bool empty(const uint8_t bits[CL_KEY_BYTES])
{
    for (int i = 0; i < CL_KEY_BYTES; i++)
        if (bits[i])
            return false;
    return true;
}

int cl_demand_update_ex(struct cl_demand *d, const char *edge, const struct cl_demand_bits *bits, double ttl,
                        double now)
{
    if (!d || !edge || !edge[0] || strlen(edge) >= CL_NAME_MAX || !bits || !(ttl == ttl))
        return CL_E_ARG;
    if (ttl < CL_DEMAND_TTL_MIN)
        ttl = CL_DEMAND_TTL_MIN;
    if (ttl > CL_DEMAND_TTL_MAX)
        ttl = CL_DEMAND_TTL_MAX;
    int rc = CL_OK;
    pthread_mutex_lock(&d->lock);
    struct entry *slot = NULL, *free_slot = NULL;
    for (int i = 0; i < d->max; i++) {
        struct entry *e = &d->e[i];
        if (e->edge[0] && e->expires <= now)
            e->edge[0] = 0; /* expired: reuse */
        if (e->edge[0] && strcmp(e->edge, edge) == 0)
            slot = e;
        else if (!e->edge[0] && !free_slot)
            free_slot = e;
    }
    if (empty(bits->keys)) {
        if (slot)
            slot->edge[0] = 0; /* the edge has no viewers left: forget it now */
    } else {
        if (!slot && free_slot) {
            slot = free_slot;
            strcpy(slot->edge, edge);
        }
        if (slot) {
            slot->bits = *bits;
            slot->expires = now + ttl;
        } else {
            rc = CL_E_FULL;
        }
    }
    pthread_mutex_unlock(&d->lock);
    return rc;
}

int cl_demand_update(struct cl_demand *d, const char *edge, const uint8_t bits[CL_KEY_BYTES], double ttl, double now)
{
    if (!bits)
        return CL_E_ARG;
    struct cl_demand_bits b;
    memcpy(b.keys, bits, CL_KEY_BYTES);
    memset(b.stream, 0, CL_KEY_BYTES);
    memcpy(b.wish, bits, CL_KEY_BYTES);
    return cl_demand_update_ex(d, edge, &b, ttl, now);
}

int cl_demand_union_ex(struct cl_demand *d, double now, struct cl_demand_bits *out)
{
    memset(out, 0, sizeof *out);
    int live = 0;
    pthread_mutex_lock(&d->lock);
    for (int i = 0; i < d->max; i++) {
        struct entry *e = &d->e[i];
        if (!e->edge[0])
            continue;
        if (e->expires <= now) {
            e->edge[0] = 0;
            continue;
        }
        live++;
        for (int b = 0; b < CL_KEY_BYTES; b++) {
            out->keys[b] |= e->bits.keys[b];
            out->stream[b] |= e->bits.stream[b];
            out->wish[b] |= e->bits.wish[b];
        }
    }
    pthread_mutex_unlock(&d->lock);
    return live;
}

int cl_demand_union(struct cl_demand *d, double now, uint8_t out[CL_KEY_BYTES])
{
    struct cl_demand_bits b;
    int live = cl_demand_union_ex(d, now, &b);
    memcpy(out, b.keys, CL_KEY_BYTES);
    return live;
}

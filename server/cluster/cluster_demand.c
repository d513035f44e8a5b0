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
    uint8_t bits[CL_KEY_BYTES];
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

int cl_demand_update(struct cl_demand *d, const char *edge, const uint8_t bits[CL_KEY_BYTES], double ttl, double now)
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
    if (empty(bits)) {
        if (slot)
            slot->edge[0] = 0; /* the edge has no viewers left: forget it now */
    } else {
        if (!slot && free_slot) {
            slot = free_slot;
            strcpy(slot->edge, edge);
        }
        if (slot) {
            memcpy(slot->bits, bits, CL_KEY_BYTES);
            slot->expires = now + ttl;
        } else {
            rc = CL_E_FULL;
        }
    }
    pthread_mutex_unlock(&d->lock);
    return rc;
}

int cl_demand_union(struct cl_demand *d, double now, uint8_t out[CL_KEY_BYTES])
{
    memset(out, 0, CL_KEY_BYTES);
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
        for (int b = 0; b < CL_KEY_BYTES; b++)
            out[b] |= e->bits[b];
    }
    pthread_mutex_unlock(&d->lock);
    return live;
}

/* encode_pool.c — see encode_pool.h: an instance of the program's one work
 * pool (server/common/pool.h) running one job at a time. */
#include "encode_pool.h"

#include <stdlib.h>

#include "pool.h"

struct encode_pool {
    struct pool *pool;
    struct pool_job job;          /* the frame being encoded (pool.h: finished before it is reused) */
    /* The job's callbacks: written by encode_pool_start before the job is
     * queued, read by the pool's threads while it runs. */
    void (*fn)(void *, int, int);
    void (*done)(void *);
    void *ctx;
};

static void run_range(void *arg, int i0, int i1, int worker)
{
    const struct encode_pool *p = arg;
    for (int i = i0; i < i1; i++)
        p->fn(p->ctx, i, worker);
}

static void run_done(void *arg)
{
    const struct encode_pool *p = arg;
    p->done(p->ctx);
}

struct encode_pool *encode_pool_new(int threads)
{
    struct encode_pool *p = calloc(1, sizeof *p);
    if (!p)
        return NULL;
    p->pool = pool_new(threads < 1 ? 1 : threads);
    if (!p->pool) {
        free(p);
        return NULL;
    }
    return p;
}

void encode_pool_free(struct encode_pool *p)
{
    if (!p)
        return;
    encode_pool_wait(p);
    pool_free(p->pool);
    free(p);
}

int encode_pool_threads(const struct encode_pool *p) { return pool_threads(p->pool); }

void encode_pool_start(struct encode_pool *p, int items, void (*fn)(void *, int, int), void (*done)(void *), void *ctx)
{
    if (items <= 0) {
        done(ctx);
        return;
    }
    pool_wait(p->pool, &p->job); /* the previous job: finished before its callbacks are replaced */
    p->fn = fn;
    p->done = done;
    p->ctx = ctx;
    pool_start(p->pool, &p->job, items, run_range, run_done, p);
}

void encode_pool_wait(struct encode_pool *p) { pool_wait(p->pool, &p->job); }

bool encode_pool_busy(struct encode_pool *p) { return pool_busy(p->pool, &p->job); }

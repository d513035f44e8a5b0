/* pool.h — the program's one work pool: persistent threads that run jobs of
 * numbered items. Shared by the simulation library (server/sim/) and the
 * daemon; depends on nothing but pthreads and C11 atomics (the model is
 * zstd's lib/common/pool.c, with items handed out from an atomic counter).
 *
 * A job is `items` calls fn(ctx, i, i + 1, worker), i in [0, items). Items
 * are handed out one at a time from a shared counter, so a thread that the
 * (shared) machine deschedules holds up only the item it took; which thread
 * runs an item must never change its result. Jobs wait in a FIFO queue;
 * threads work on the queue's first job only.
 *
 * Worker numbers: the pool's threads are 1..threads; a caller that helps
 * (pool_for, pool_wait) is 0. So per-worker scratch needs threads + 1
 * slots, and at most one caller may help on a pool at a time.
 *
 * Two ways to use it:
 *   pool_for    a parallel-for: the caller is worker 0, takes items too and
 *               returns when all are done (the simulation's step).
 *   pool_start  an asynchronous job in a struct pool_job the caller owns: it
 *               returns at once; the thread that finishes the last item
 *               runs done(ctx); pool_wait helps with the items left (or
 *               sleeps if none are left) until the job is finished (the
 *               daemon's encodes; the point-query service).
 *
 * Threading contract: pool_new/pool_free on one thread, with no job running
 * or waiting to be waited for. pool_for and pool_wait may be called by one
 * thread at a time per pool (they act as worker 0); pool_start and
 * pool_busy from any thread. A job is "finished" when every item has run,
 * done has returned and no pool thread is inside it any more: only then
 * may its struct pool_job be started again or freed. */
#ifndef OCEAND_POOL_H
#define OCEAND_POOL_H

#include <stdatomic.h>
#include <stdbool.h>

struct pool;

typedef void pool_fn(void *ctx, int i0, int i1, int worker);

/* One job. Fields are pool.c's: zero it (or use pool_start on it) and
 * leave it alone. Writers and readers:
 *   fn, done, ctx, items, limit: pool_start / pool_for, before the job is
 *     queued (under the pool's lock); read by every thread that joins it.
 *   next, left: atomics, every thread inside the job (taking and finishing items).
 *   queued_next, queued, busy, completed, active: under the pool's lock. */
struct pool_job {
    pool_fn *fn;
    void (*done)(void *ctx);
    void *ctx;
    int items;
    int limit;                 /* only workers below this number join (pool_for's `threads`) */
    atomic_int next;           /* next item to hand out */
    atomic_int left;           /* items not finished (only with done): who brings it to 0 runs done */
    struct pool_job *queued_next;
    bool queued;               /* in the queue: threads may still join it */
    bool busy;                 /* started and not finished */
    bool completed;            /* every item run and done returned */
    int active;                /* threads inside (joined, not left yet) */
};

/* A pool of `threads` (>= 1) threads; NULL when none could be started or
 * out of memory (then callers run everything themselves: pool_for accepts
 * a NULL pool). */
struct pool *pool_new(int threads);
/* Runs the jobs still queued, then stops and joins the threads. NULL is fine. */
void pool_free(struct pool *p);
/* Threads the pool runs (not counting a helping caller); 0 for NULL. */
int pool_threads(const struct pool *p);

/* Parallel-for: fn(ctx, i, i + 1, worker) for every i in [0, items) on the
 * caller (worker 0) and pool threads numbered below `threads`. Returns when
 * every item is done. A pool thread that wakes after the caller has handed
 * out the last item does not join, and the caller waits only for the
 * threads that joined. p may be NULL, and threads <= 1 or items <= 1 run
 * everything on the caller as fn(ctx, 0, items, 0). */
void pool_for(struct pool *p, int threads, int items, pool_fn *fn, void *ctx);

/* Queue job j (not busy: never started, or finished; if it is still busy
 * this waits until it is finished). done may be NULL. items <= 0, or p
 * NULL: the items (if any) and done run at once, on the caller, and j
 * stays not busy. */
void pool_start(struct pool *p, struct pool_job *j, int items, pool_fn *fn, void (*done)(void *ctx), void *ctx);
/* Until j is finished: the caller takes j's items left (as worker 0), then
 * sleeps until the threads inside have left. At once if j is not busy. */
void pool_wait(struct pool *p, struct pool_job *j);
/* Whether j is started and not finished. */
bool pool_busy(struct pool *p, struct pool_job *j);

#endif

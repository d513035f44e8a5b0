/* encode_pool.h — the daemon's frame-encoding threads.
 *
 * A persistent pool that runs one job at a time, asynchronously: the
 * producer (producer.c) starts the encode of tick t and goes on to step
 * tick t+1 while the pool works. Items are handed out one at a time from a
 * shared counter (a descheduled worker on a shared machine does not hold the
 * others up); which worker encodes an item never changes the bytes.
 *
 * Why not the simulation library's pool: it lives inside struct ocean
 * (server/sim/ocean_internal.h), which the daemon may not include, and it is
 * busy with the step exactly when we want to encode in parallel with it. */
#ifndef OCEAND_ENCODE_POOL_H
#define OCEAND_ENCODE_POOL_H

#include <stdbool.h>

struct encode_pool;

/* threads >= 1 worker threads. NULL when out of memory or threads. */
struct encode_pool *encode_pool_new(int threads);
/* Waits for the current job, then stops the workers. NULL is fine. */
void encode_pool_free(struct encode_pool *p);
int encode_pool_threads(const struct encode_pool *p);

/* Start a job: fn(ctx, item, worker) for every item in [0, items), worker in
 * 0..threads (threads = the caller helping in encode_pool_wait). When the
 * last item is done, done(ctx) runs on the thread that finished it, then
 * the job counts as finished. The previous job must be finished
 * (encode_pool_wait). items == 0 runs done at once, on the caller. */
void encode_pool_start(struct encode_pool *p, int items, void (*fn)(void *ctx, int item, int worker),
                       void (*done)(void *ctx), void *ctx);
/* Until the current job (if any) is finished; the caller takes items too
 * (as worker `threads`) instead of sleeping. */
void encode_pool_wait(struct encode_pool *p);
bool encode_pool_busy(struct encode_pool *p);

#endif

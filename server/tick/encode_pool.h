/* encode_pool.h — the daemon's frame-encoding threads.
 *
 * A persistent pool that runs one job at a time, asynchronously: the
 * producer (producer.c) starts the encode of tick t and goes on to step
 * tick t+1 while the pool works. Items are handed out one at a time from a
 * shared counter (a descheduled worker on a shared machine does not hold the
 * others up); which worker encodes an item never changes the bytes.
 *
 * An instance of the program's one work pool (server/common/pool.h), as is
 * the simulation library's. A pool of its own because the library's is busy
 * with the step exactly when we want to encode in parallel with it. */
#ifndef OCEAND_ENCODE_POOL_H
#define OCEAND_ENCODE_POOL_H

#include <stdbool.h>

struct encode_pool;

/* threads >= 1 worker threads (fewer if not all could start: encode_pool_threads).
 * NULL when out of memory or no thread could start. */
struct encode_pool *encode_pool_new(int threads);
/* Waits for the current job, then stops the workers. NULL is fine. */
void encode_pool_free(struct encode_pool *p);
int encode_pool_threads(const struct encode_pool *p);

/* Start a job: fn(ctx, item, worker) for every item in [0, items), worker in
 * 0..threads (0 = the caller helping in encode_pool_wait). When the
 * last item is done, done(ctx) runs on the thread that finished it, then
 * the job counts as finished. The previous job must be finished
 * (encode_pool_wait). items == 0 runs done at once, on the caller. */
void encode_pool_start(struct encode_pool *p, int items, void (*fn)(void *ctx, int item, int worker),
                       void (*done)(void *ctx), void *ctx);
/* Until the current job (if any) is finished; the caller takes items too
 * (as worker 0) instead of sleeping. */
void encode_pool_wait(struct encode_pool *p);
bool encode_pool_busy(struct encode_pool *p);

#endif

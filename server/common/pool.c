/* pool.c — see pool.h. One mutex and two condition variables per pool;
 * items come from an atomic counter, so taking one costs no lock. The lock
 * is taken only to join a job, to leave it and to queue one. */
#include "pool.h"

#include <limits.h>
#include <pthread.h>
#include <stdlib.h>

struct pool_thread {
    struct pool *p;
    int id;                    /* 1..threads (0 is a helping caller) */
    pthread_t tid;
};

struct pool {
    pthread_mutex_t lock;
    pthread_cond_t work;       /* a job queued, or stop */
    pthread_cond_t finished;   /* a job finished */
    struct pool_job *head, *tail; /* under lock: the queue */
    bool stop;                 /* under lock */
    int started;               /* threads running; written before any job */
    struct pool_thread *thread;
};

/* Every item handed out. Lock held (items is stable while the job is busy). */
static bool exhausted(struct pool_job *j)
{
    return atomic_load_explicit(&j->next, memory_order_relaxed) >= j->items;
}

/* Out of the queue, so that no thread joins it any more. Lock held. */
static void unqueue(struct pool *p, struct pool_job *j)
{
    if (!j->queued)
        return;
    struct pool_job **at = &p->head, *prev = NULL;
    while (*at != j) {
        prev = *at;
        at = &prev->queued_next;
    }
    *at = j->queued_next;
    if (p->tail == j)
        p->tail = prev;
    j->queued_next = NULL;
    j->queued = false;
}

/* Take and run items until none is left. With a done callback: true on the
 * thread that finished the last one (its acquire sees every other item's
 * writes: done may read them). Without one nobody needs to know (pool_for:
 * the last thread out finishes the job), so no counter is touched per item. */
static bool run_items(struct pool_job *j, int worker)
{
    const bool counted = j->done != NULL;
    for (int i; (i = atomic_fetch_add_explicit(&j->next, 1, memory_order_relaxed)) < j->items;) {
        j->fn(j->ctx, i, i + 1, worker);
        if (counted && atomic_fetch_sub_explicit(&j->left, 1, memory_order_acq_rel) == 1)
            return true;
    }
    return false;
}

/* After run_items on a joined job: done (on the thread that finished the last
 * item, without the lock: it may be long), then leave. The last thread out
 * of a completed job finishes it; without done, the last thread out (every
 * item is handed out, and each thread out has finished those it took). The
 * lock orders the items' writes before the finish. Called without the
 * lock, returns with it. */
static void depart(struct pool *p, struct pool_job *j, bool last)
{
    if (last && j->done)
        j->done(j->ctx);
    pthread_mutex_lock(&p->lock);
    if (last)
        j->completed = true;
    unqueue(p, j); /* run_items returned: every item is handed out */
    if (--j->active == 0 && (j->completed || !j->done)) {
        j->busy = false; /* from here on the pool does not touch j */
        pthread_cond_broadcast(&p->finished);
    }
}

static void *thread_main(void *arg)
{
    const struct pool_thread *t = arg;
    struct pool *p = t->p;
    const int id = t->id;
    pthread_mutex_lock(&p->lock);
    for (;;) {
        struct pool_job *j = p->head;
        if (j && exhausted(j)) { /* a latecomer: the items went to others */
            unqueue(p, j);
            continue;
        }
        if (j && id < j->limit) {
            j->active++;
            pthread_mutex_unlock(&p->lock);
            depart(p, j, run_items(j, id));
            continue;
        }
        if (p->stop && !j)
            break;
        pthread_cond_wait(&p->work, &p->lock);
    }
    pthread_mutex_unlock(&p->lock);
    return NULL;
}

struct pool *pool_new(int threads)
{
    if (threads < 1)
        return NULL;
    struct pool *p = calloc(1, sizeof *p);
    if (!p)
        return NULL;
    p->thread = calloc((size_t)threads, sizeof *p->thread);
    if (!p->thread) {
        free(p);
        return NULL;
    }
    pthread_mutex_init(&p->lock, NULL);
    pthread_cond_init(&p->work, NULL);
    pthread_cond_init(&p->finished, NULL);
    for (int i = 0; i < threads; i++) {
        struct pool_thread *t = &p->thread[p->started];
        t->p = p;
        t->id = p->started + 1;
        if (pthread_create(&t->tid, NULL, thread_main, t) != 0)
            break; /* fewer threads: still correct */
        p->started++;
    }
    if (p->started == 0) {
        pool_free(p);
        return NULL; /* callers then run everything themselves */
    }
    return p;
}

void pool_free(struct pool *p)
{
    if (!p)
        return;
    pthread_mutex_lock(&p->lock);
    p->stop = true;
    pthread_cond_broadcast(&p->work);
    pthread_mutex_unlock(&p->lock);
    for (int i = 0; i < p->started; i++)
        pthread_join(p->thread[i].tid, NULL);
    pthread_cond_destroy(&p->finished);
    pthread_cond_destroy(&p->work);
    pthread_mutex_destroy(&p->lock);
    free(p->thread);
    free(p);
}

int pool_threads(const struct pool *p)
{
    return p ? p->started : 0;
}

/* Queue j; lock held. Waits for j to be finished first. */
static void submit_locked(struct pool *p, struct pool_job *j, int items, pool_fn *fn, void (*done)(void *),
                          void *ctx, int limit)
{
    while (j->busy)
        pthread_cond_wait(&p->finished, &p->lock);
    j->fn = fn;
    j->done = done;
    j->ctx = ctx;
    j->items = items;
    j->limit = limit;
    atomic_store_explicit(&j->next, 0, memory_order_relaxed); /* published by the unlock */
    atomic_store_explicit(&j->left, items, memory_order_relaxed);
    j->busy = true;
    j->completed = false;
    j->active = 0;
    j->queued = true;
    j->queued_next = NULL;
    if (p->tail)
        p->tail->queued_next = j;
    else
        p->head = j;
    p->tail = j;
    pthread_cond_broadcast(&p->work);
}

/* The caller helps with j as worker 0 if items are left; returns with the
 * lock held, j finished. Lock held on entry. */
static void help_and_wait(struct pool *p, struct pool_job *j)
{
    if (j->queued && !exhausted(j)) {
        j->active++;
        pthread_mutex_unlock(&p->lock);
        depart(p, j, run_items(j, 0));
    }
    while (j->busy)
        pthread_cond_wait(&p->finished, &p->lock);
}

void pool_for(struct pool *p, int threads, int items, pool_fn *fn, void *ctx)
{
    if (!p || threads <= 1 || items <= 1) {
        fn(ctx, 0, items, 0);
        return;
    }
    struct pool_job j = {0};
    pthread_mutex_lock(&p->lock);
    submit_locked(p, &j, items, fn, NULL, ctx, threads);
    help_and_wait(p, &j); /* the caller joins in the same critical section */
    pthread_mutex_unlock(&p->lock);
}

void pool_start(struct pool *p, struct pool_job *j, int items, pool_fn *fn, void (*done)(void *ctx), void *ctx)
{
    if (items <= 0 || !p) {
        if (items > 0)
            fn(ctx, 0, items, 0); /* no threads: the caller does the work */
        if (done)
            done(ctx);
        return;
    }
    pthread_mutex_lock(&p->lock);
    submit_locked(p, j, items, fn, done, ctx, INT_MAX);
    pthread_mutex_unlock(&p->lock);
}

void pool_wait(struct pool *p, struct pool_job *j)
{
    if (!p)
        return;
    pthread_mutex_lock(&p->lock);
    help_and_wait(p, j);
    pthread_mutex_unlock(&p->lock);
}

bool pool_busy(struct pool *p, struct pool_job *j)
{
    if (!p)
        return false;
    pthread_mutex_lock(&p->lock);
    bool b = j->busy;
    pthread_mutex_unlock(&p->lock);
    return b;
}

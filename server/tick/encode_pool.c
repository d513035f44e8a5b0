/* encode_pool.c — see encode_pool.h. A mutex and two condition variables;
 * items come from an atomic counter so taking one costs no lock. */
#include "encode_pool.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>

struct encode_pool {
    int threads;
    pthread_t *tid;
    int started;
    pthread_mutex_t lock;
    pthread_cond_t work;          /* a job started, or stop */
    pthread_cond_t finished;      /* a job finished */
    bool stop;                    /* under lock */
    unsigned long gen;            /* under lock: jobs started so far */
    bool busy;                    /* under lock: a job started and not finished */
    int active;                   /* under lock: threads inside run_items (a new job waits for 0,
                                     so no straggler can read the next job's counter as its own) */
    /* The job in progress: written by encode_pool_start before gen moves (under lock). */
    int items;
    void (*fn)(void *, int, int);
    void (*done)(void *);
    void *ctx;
    atomic_int next;              /* next item to hand out */
    atomic_int left;              /* items not finished yet */
};

/* Take and run items until none are left; the thread finishing the last one
 * completes the job. */
static void run_items(struct encode_pool *p, int worker)
{
    for (;;) {
        int i = atomic_fetch_add(&p->next, 1);
        if (i >= p->items)
            return;
        p->fn(p->ctx, i, worker);
        if (atomic_fetch_sub(&p->left, 1) == 1) {
            p->done(p->ctx);
            pthread_mutex_lock(&p->lock);
            p->busy = false;
            pthread_cond_broadcast(&p->finished);
            pthread_mutex_unlock(&p->lock);
            return;
        }
    }
}

struct worker_arg { struct encode_pool *p; int index; };

static void *worker_main(void *arg)
{
    struct encode_pool *p = ((struct worker_arg *)arg)->p;
    int index = ((struct worker_arg *)arg)->index;
    free(arg);
    unsigned long seen = 0;
    pthread_mutex_lock(&p->lock);
    for (;;) {
        while (!p->stop && p->gen == seen)
            pthread_cond_wait(&p->work, &p->lock);
        if (p->stop)
            break;
        seen = p->gen;
        p->active++;
        pthread_mutex_unlock(&p->lock);
        run_items(p, index);
        pthread_mutex_lock(&p->lock);
        if (--p->active == 0)
            pthread_cond_broadcast(&p->finished);
    }
    pthread_mutex_unlock(&p->lock);
    return NULL;
}

struct encode_pool *encode_pool_new(int threads)
{
    if (threads < 1)
        threads = 1;
    struct encode_pool *p = calloc(1, sizeof *p);
    if (!p)
        return NULL;
    p->threads = threads;
    p->tid = calloc((size_t)threads, sizeof *p->tid);
    pthread_mutex_init(&p->lock, NULL);
    pthread_cond_init(&p->work, NULL);
    pthread_cond_init(&p->finished, NULL);
    if (!p->tid) {
        encode_pool_free(p);
        return NULL;
    }
    for (int i = 0; i < threads; i++) {
        struct worker_arg *a = malloc(sizeof *a);
        if (!a)
            break;
        a->p = p;
        a->index = i;
        if (pthread_create(&p->tid[i], NULL, worker_main, a) != 0) {
            free(a);
            break;
        }
        p->started++;
    }
    if (p->started == 0) {
        encode_pool_free(p);
        return NULL;
    }
    return p;
}

void encode_pool_free(struct encode_pool *p)
{
    if (!p)
        return;
    encode_pool_wait(p);
    pthread_mutex_lock(&p->lock);
    p->stop = true;
    pthread_cond_broadcast(&p->work);
    pthread_mutex_unlock(&p->lock);
    for (int i = 0; i < p->started; i++)
        pthread_join(p->tid[i], NULL);
    pthread_cond_destroy(&p->finished);
    pthread_cond_destroy(&p->work);
    pthread_mutex_destroy(&p->lock);
    free(p->tid);
    free(p);
}

int encode_pool_threads(const struct encode_pool *p) { return p->threads; }

void encode_pool_start(struct encode_pool *p, int items, void (*fn)(void *, int, int), void (*done)(void *), void *ctx)
{
    if (items <= 0) {
        done(ctx);
        return;
    }
    pthread_mutex_lock(&p->lock);
    while (p->busy || p->active)
        pthread_cond_wait(&p->finished, &p->lock);
    p->items = items;
    p->fn = fn;
    p->done = done;
    p->ctx = ctx;
    atomic_store(&p->next, 0);
    atomic_store(&p->left, items);
    p->busy = true;
    p->gen++;
    pthread_cond_broadcast(&p->work);
    pthread_mutex_unlock(&p->lock);
}

void encode_pool_wait(struct encode_pool *p)
{
    pthread_mutex_lock(&p->lock);
    bool busy = p->busy;
    if (busy)
        p->active++;
    pthread_mutex_unlock(&p->lock);
    if (busy)
        run_items(p, p->threads);
    pthread_mutex_lock(&p->lock);
    if (busy && --p->active == 0)
        pthread_cond_broadcast(&p->finished);
    while (p->busy || p->active)
        pthread_cond_wait(&p->finished, &p->lock);
    pthread_mutex_unlock(&p->lock);
}

bool encode_pool_busy(struct encode_pool *p)
{
    pthread_mutex_lock(&p->lock);
    bool b = p->busy || p->active;
    pthread_mutex_unlock(&p->lock);
    return b;
}

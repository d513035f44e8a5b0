/* bench_time.h — the clocks and the median of the C benchmarks (header-only:
 * each benchmark is one translation unit).
 *
 * Wall time is CLOCK_MONOTONIC. CPU time is what a figure "per core" needs on
 * a shared machine, where wall time also counts the time other processes
 * hold the core: process CPU (all threads) or the calling thread's alone. */
#ifndef OCEAND_BENCH_TIME_H
#define OCEAND_BENCH_TIME_H

#include <stdlib.h>
#include <time.h>

static inline double clock_s(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static inline double now_s(void) { return clock_s(CLOCK_MONOTONIC); }
static inline double now_ms(void) { return clock_s(CLOCK_MONOTONIC) * 1e3; }
static inline double cpu_ms(void) { return clock_s(CLOCK_PROCESS_CPUTIME_ID) * 1e3; }
static inline double thread_cpu_s(void) { return clock_s(CLOCK_THREAD_CPUTIME_ID); }

static inline int bench_cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The median of v[0..n-1], n >= 1; sorts v in place. For an even n it is the
 * mean of the two middle values, so that it does not lean on either. */
static inline double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, bench_cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

#endif

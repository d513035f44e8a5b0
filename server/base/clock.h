/* clock.h — the daemon's two clocks: monotonic seconds for scheduling and
 * measuring, Unix microseconds for timestamps that clients compare with
 * their own wall clock (frame latency). */
#ifndef OCEAND_CLOCK_H
#define OCEAND_CLOCK_H

#include <stdint.h>
#include <time.h>

static inline double mono_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static inline uint64_t unix_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

#endif

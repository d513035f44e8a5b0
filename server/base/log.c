/* log.c — levelled logging to stderr (one line per call, atomic enough for
 * our two threads because each line is formatted first and written once). */
#include "log.h"

#include <libwebsockets.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static enum log_level current = OLOG_INFO;
const char *const log_level_names[] = { "error", "warn", "info", "debug", NULL };

int log_level_from_name(const char *name)
{
    for (int i = 0; i < 4; i++)
        if (strcmp(name, log_level_names[i]) == 0)
            return i;
    return -1;
}

const char *log_level_name(enum log_level l) { return log_level_names[l]; }
void log_set_level(enum log_level l) { current = l; }
enum log_level log_get_level(void) { return current; }

/* Lines a stranger can cause (a refused upgrade logs one, lws adds its own)
 * must not fill the disk, nor block the thread that logs them: stderr is
 * often a pipe (systemd, `| tee`), and a full pipe blocks write(2), here the
 * lws service thread (test-hostile log_flood: 600 refusals stopped every
 * client's frames). So lines up to info share a token bucket of
 * LOG_RATE_LINES a second (burst LOG_BURST_LINES), and a line is dropped
 * when stderr cannot take it now (poll; O_NONBLOCK would change the file
 * description the parent shares). Both are counted (log_dropped, /metrics)
 * and the next line written says how many were suppressed. debug is not
 * limited: the operator asked for every line. */
#define LOG_RATE_LINES 10.0
#define LOG_BURST_LINES 100.0

static pthread_mutex_t bucket_lock = PTHREAD_MUTEX_INITIALIZER;
static double bucket = LOG_BURST_LINES, bucket_t; /* under bucket_lock */
static unsigned long long suppressed;             /* under bucket_lock: since the last line written */
static atomic_ullong dropped_rate, dropped_blocked;

unsigned long long log_dropped(bool blocked) { return atomic_load(blocked ? &dropped_blocked : &dropped_rate); }

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* May a line of level l go out now? *before: lines suppressed since the
 * last one written (to be reported first). */
static bool log_admit(enum log_level l, unsigned long long *before)
{
    *before = 0;
    if (l == OLOG_DEBUG)
        return true;
    pthread_mutex_lock(&bucket_lock);
    double t = now_s();
    if (bucket_t > 0)
        bucket += (t - bucket_t) * LOG_RATE_LINES;
    if (bucket > LOG_BURST_LINES)
        bucket = LOG_BURST_LINES;
    bucket_t = t;
    bool ok = bucket >= 1;
    if (ok) {
        bucket -= 1;
        *before = suppressed;
        suppressed = 0;
    } else {
        suppressed++;
    }
    pthread_mutex_unlock(&bucket_lock);
    if (!ok)
        atomic_fetch_add(&dropped_rate, 1);
    return ok;
}

/* Write one line if stderr can take it without blocking. */
static void emit(const char *line, size_t len)
{
    struct pollfd p = { .fd = STDERR_FILENO, .events = POLLOUT };
    if (poll(&p, 1, 0) == 1 && (p.revents & POLLOUT)) {
        ssize_t w = write(STDERR_FILENO, line, len);
        (void)w;
    } else {
        atomic_fetch_add(&dropped_blocked, 1);
    }
}

static void vlog(enum log_level l, const char *prefix, const char *fmt, va_list ap)
{
    unsigned long long before;
    if (!log_admit(l, &before))
        return;
    char line[1024];
    struct timespec ts;
    struct tm tm;
    clock_gettime(CLOCK_REALTIME, &ts);
    gmtime_r(&ts.tv_sec, &tm);
    char hms[16];
    strftime(hms, sizeof hms, "%H:%M:%S", &tm);
    int n;
    if (before) {
        n = snprintf(line, sizeof line, "%s.%03ld %-5s log: %llu lines suppressed (more than %g a second)\n", hms,
                     ts.tv_nsec / 1000000, log_level_names[OLOG_WARN], before, LOG_RATE_LINES);
        if (n > 0 && (size_t)n < sizeof line)
            emit(line, (size_t)n);
    }
    n = snprintf(line, sizeof line, "%s.%03ld %-5s %s", hms, ts.tv_nsec / 1000000, log_level_names[l], prefix);
    if (n < 0 || (size_t)n >= sizeof line)
        return;
    int m = vsnprintf(line + n, sizeof line - (size_t)n, fmt, ap);
    size_t len = m < 0 ? (size_t)n : (size_t)n + (size_t)m;
    if (len > sizeof line - 2)
        len = sizeof line - 2;
    while (len > 0 && line[len - 1] == '\n')
        len--;
    line[len++] = '\n';
    emit(line, len);
}

void log_msg(enum log_level l, const char *fmt, ...)
{
    if (l > current)
        return;
    va_list ap;
    va_start(ap, fmt);
    vlog(l, "", fmt, ap);
    va_end(ap);
}

static void lws_emit(int lws_level, const char *line)
{
    enum log_level l = lws_level == LLL_ERR ? OLOG_ERROR : lws_level == LLL_WARN ? OLOG_WARN
                     : lws_level == LLL_NOTICE ? OLOG_INFO : OLOG_DEBUG;
    log_msg(l, "lws: %s", line);
}

void log_route_lws(void)
{
    /* lws is chatty at NOTICE; keep it quiet unless we are debugging. */
    int mask = LLL_ERR;
    if (current >= OLOG_WARN)
        mask |= LLL_WARN;
    if (current >= OLOG_DEBUG)
        mask |= LLL_NOTICE | LLL_INFO;
    lws_set_log_level(mask, lws_emit);
}

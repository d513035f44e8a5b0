/* log.c — levelled logging to stderr (one line per call, atomic enough for
 * our two threads because each line is formatted first and written once). */
#include "log.h"

#include <libwebsockets.h>
#include <stdarg.h>
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

static void vlog(enum log_level l, const char *prefix, const char *fmt, va_list ap)
{
    char line[1024];
    struct timespec ts;
    struct tm tm;
    clock_gettime(CLOCK_REALTIME, &ts);
    gmtime_r(&ts.tv_sec, &tm);
    char hms[16];
    strftime(hms, sizeof hms, "%H:%M:%S", &tm);
    int n = snprintf(line, sizeof line, "%s.%03ld %-5s %s", hms, ts.tv_nsec / 1000000, log_level_names[l], prefix);
    if (n < 0 || (size_t)n >= sizeof line)
        return;
    int m = vsnprintf(line + n, sizeof line - (size_t)n, fmt, ap);
    size_t len = m < 0 ? (size_t)n : (size_t)n + (size_t)m;
    if (len > sizeof line - 2)
        len = sizeof line - 2;
    while (len > 0 && line[len - 1] == '\n')
        len--;
    line[len++] = '\n';
    ssize_t w = write(STDERR_FILENO, line, len);
    (void)w;
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

/* log.h — levelled logging to stderr, shared by every daemon module.
 * libwebsockets' own log lines are routed through here too (see log_route_lws). */
#ifndef OCEAND_LOG_H
#define OCEAND_LOG_H

#include <stdbool.h>

/* OLOG_, not LOG_: <syslog.h> defines LOG_INFO and LOG_DEBUG as macros. */
enum log_level { OLOG_ERROR, OLOG_WARN, OLOG_INFO, OLOG_DEBUG };
/* "error", "warn", "info", "debug", NULL: indexed by enum log_level (the
 * choices of the log_level option). */
extern const char *const log_level_names[];

/* Parse "error", "warn", "info", "debug"; -1 if unknown. */
int  log_level_from_name(const char *name);
const char *log_level_name(enum log_level l);
void log_set_level(enum log_level l);
enum log_level log_get_level(void);
/* Route lws logging through log_msg: errors/warnings only unless debug. */
void log_route_lws(void);

/* Lines not written: over the rate limit (10 a second, burst 100, levels up
 * to info), or (blocked) because stderr could not take them without waiting. */
unsigned long long log_dropped(bool blocked);

void log_msg(enum log_level l, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
#define LOGE(...) log_msg(OLOG_ERROR, __VA_ARGS__)
#define LOGW(...) log_msg(OLOG_WARN, __VA_ARGS__)
#define LOGI(...) log_msg(OLOG_INFO, __VA_ARGS__)
#define LOGD(...) log_msg(OLOG_DEBUG, __VA_ARGS__)

#endif

/* log.h — levelled logging to stderr, shared by every daemon module.
 * libwebsockets' own log lines are routed through here too (see log_route_lws). */
#ifndef OCEAND_LOG_H
#define OCEAND_LOG_H

enum log_level { LOG_ERROR, LOG_WARN, LOG_INFO, LOG_DEBUG };

/* Parse "error", "warn", "info", "debug"; -1 if unknown. */
int  log_level_from_name(const char *name);
const char *log_level_name(enum log_level l);
void log_set_level(enum log_level l);
enum log_level log_get_level(void);
/* Route lws logging through log_msg: errors/warnings only unless debug. */
void log_route_lws(void);

void log_msg(enum log_level l, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
#define LOGE(...) log_msg(LOG_ERROR, __VA_ARGS__)
#define LOGW(...) log_msg(LOG_WARN, __VA_ARGS__)
#define LOGI(...) log_msg(LOG_INFO, __VA_ARGS__)
#define LOGD(...) log_msg(LOG_DEBUG, __VA_ARGS__)

#endif

/* control_internal.h — what the files of server/control/ share. */
#ifndef OCEAND_CONTROL_INTERNAL_H
#define OCEAND_CONTROL_INTERNAL_H

#include "control.h"

/* Fill e (code, the parameter concerned or NULL, a message) and return -1. */
int ctl_fail(struct ctl_error *e, const char *code, const char *param, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

#endif

/* state.c — atomic save / restore of the parameters (see state.h). */
#include "state.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "control.h"

int state_save(const char *path, const struct ocean_params *p, uint32_t version, double sim_time,
               char *err, size_t errlen)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddItemToObject(o, "params", control_params_object(p));
    cJSON_AddNumberToObject(o, "params_version", version);
    cJSON_AddNumberToObject(o, "sim_time", sim_time);
    char *text = cJSON_Print(o);
    cJSON_Delete(o);
    if (!text) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    char tmp[600];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
        snprintf(err, errlen, "%s: %s", tmp, strerror(errno));
        free(text);
        return -1;
    }
    size_t len = strlen(text), off = 0;
    int rc = 0;
    while (off < len) {
        ssize_t w = write(fd, text + off, len - off);
        if (w < 0 && errno == EINTR)
            continue;
        if (w <= 0) {
            rc = -1;
            break;
        }
        off += (size_t)w;
    }
    if (rc == 0 && write(fd, "\n", 1) != 1)
        rc = -1;
    if (rc == 0 && fsync(fd) != 0)
        rc = -1;
    if (close(fd) != 0)
        rc = -1;
    free(text);
    if (rc == 0 && rename(tmp, path) != 0)
        rc = -1;
    if (rc != 0) {
        snprintf(err, errlen, "saving %s: %s", path, strerror(errno));
        unlink(tmp);
    }
    return rc;
}

int state_load(const char *path, struct ocean_params *p, uint32_t *version, double *sim_time,
               char *err, size_t errlen)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        if (errno == ENOENT)
            return 0;
        snprintf(err, errlen, "%s: %s", path, strerror(errno));
        return -1;
    }
    char buf[16384];
    size_t len = fread(buf, 1, sizeof buf, f);
    fclose(f);
    cJSON *root = cJSON_ParseWithLength(buf, len);
    const cJSON *params = cJSON_GetObjectItemCaseSensitive(root, "params");
    if (!cJSON_IsObject(params)) {
        snprintf(err, errlen, "%s: not a state file (no \"params\" object)", path);
        cJSON_Delete(root);
        return -1;
    }
    struct ctl_error e;
    struct ocean_params np;
    if (control_apply_params(params, p, NULL, &np, NULL, &e) != 0) {
        snprintf(err, errlen, "%s: %s", path, e.message);
        cJSON_Delete(root);
        return -1;
    }
    *p = np;
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(root, "params_version");
    if (version)
        *version = cJSON_IsNumber(v) && v->valuedouble >= 0 && v->valuedouble < 4e9 ? (uint32_t)v->valuedouble : 0;
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "sim_time");
    if (sim_time)
        *sim_time = cJSON_IsNumber(t) && isfinite(t->valuedouble) && t->valuedouble >= 0 ? t->valuedouble : 0;
    cJSON_Delete(root);
    return 1;
}

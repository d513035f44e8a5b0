/* state.c — atomic save / restore of the parameters (see state.h). */
#include "state.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "control.h"
#include "fileio.h"
#include "log.h"
#include "ocean.h"

int state_save(const char *path, const struct ocean_params *p, uint32_t version, double sim_time,
               const struct state_bodies *bodies, const struct sea_spectrum *sea, char *err, size_t errlen)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddItemToObject(o, "params", control_params_object(p));
    cJSON_AddNumberToObject(o, "params_version", version);
    cJSON_AddNumberToObject(o, "sim_time", sim_time);
    if (bodies && (bodies->n > 0 || bodies->next_id > 1))
        cJSON_AddItemToObject(o, "bodies", state_bodies_json(bodies)); /* state_bodies.c */
    if (sea && !cJSON_AddItemToObject(o, "sea", state_sea_json(sea))) { /* state_sea.c */
        cJSON_Delete(o);
        snprintf(err, errlen, "out of memory (the measured sea)");
        return -1;
    }
    char *text = cJSON_Print(o);
    cJSON_Delete(o);
    if (!text) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    char tmp[600];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    /* Never written through: a symlink planted at the temporary name (by
     * whoever may write in that folder) made us overwrite its target with
     * the state (test-hostile state_file_attacks). Remove what is there (a
     * stale one, or a link: unlink does not follow it), then create it
     * afresh; O_EXCL refuses one planted again meanwhile (the save fails). */
    unlink(tmp);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
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
    /* The rename itself must reach the disk before the change is acknowledged. */
    if (rc == 0) {
        char dir[600];
        snprintf(dir, sizeof dir, "%s", path);
        char *slash = strrchr(dir, '/');
        if (slash)
            *(slash == dir ? slash + 1 : slash) = '\0';
        int dfd = open(slash ? dir : ".", O_RDONLY | O_DIRECTORY | O_CLOEXEC);
        if (dfd >= 0) {
            fsync(dfd);
            close(dfd);
        }
    }
    if (rc != 0) {
        snprintf(err, errlen, "saving %s: %s", path, strerror(errno));
        unlink(tmp);
    }
    return rc;
}

/* A state file is about 1 KB; anything near this is not ours. */
#define STATE_MAX_BYTES (1u << 20)

int state_load(const char *path, struct ocean_params *p, uint32_t *version, double *sim_time,
               char *err, size_t errlen)
{
    char *buf;
    size_t len;
    int rc = file_read_all(path, STATE_MAX_BYTES, &buf, &len, err, errlen);
    if (rc == -1 && errno == ENOENT)
        return 0;
    if (rc != 0)
        return rc;
    /* Under the control path's strict scan: a NUL (raw or \u0000) would cut
     * a string where cJSON hands it out ("phillips\u0000x" read as phillips). */
    struct ctl_error pe;
    if (control_json_prescan(buf, len, &pe) != 0) {
        snprintf(err, errlen, "%s: not a state file (%s: %s)", path, pe.code, pe.message);
        free(buf);
        return -1;
    }
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithLengthOpts(buf, len, &end, 0);
    const cJSON *params = cJSON_GetObjectItemCaseSensitive(root, "params");
    if (!cJSON_IsObject(params)) {
        snprintf(err, errlen, "%s: not a state file (no \"params\" object)", path);
        cJSON_Delete(root);
        free(buf);
        return -1;
    }
    /* We write one object and a newline: anything else after it was added. */
    while (end && end < buf + len && (*end == ' ' || *end == '\t' || *end == '\n' || *end == '\r'))
        end++;
    if (end && end < buf + len)
        LOGW("%s: %zu bytes of trailing data after the state object; ignored", path, (size_t)(buf + len - end));
    free(buf);
    struct ctl_error e;
    struct ocean_params np;
    if (control_apply_params(params, p, NULL, &np, NULL, &e) != 0) {
        snprintf(err, errlen, "%s: %s", path, e.message);
        cJSON_Delete(root);
        return -1;
    }
    *p = np;
    /* The same rules as the running daemon's (control.h): every version it
     * can reach, up to CTL_VERSION_MAX (where sets stop), and every clock
     * time, up to OCEAN_TIME_MAX (where the clock stops), load again. */
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(root, "params_version");
    uint32_t ver = 0;
    if (v && !control_json_version(v, &ver))
        LOGW("%s: params_version is not a whole number in 0..%u; starting from 0", path, CTL_VERSION_MAX);
    if (version)
        *version = ver;
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "sim_time");
    double st = 0;
    if (t && !control_json_sim_time(t, &st))
        LOGW("%s: sim_time is not a number in [0, %.0f] s; starting from 0", path, OCEAN_TIME_MAX);
    if (sim_time)
        *sim_time = st;
    cJSON_Delete(root);
    return 1;
}

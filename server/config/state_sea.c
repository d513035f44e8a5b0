/* state_sea.c — the measured sea in the state file (state.h): the "sea"
 * member is the document as the `sea` message carries it (sea_msg.c), so a
 * restart takes it through the same check as a client's. */
#include "state.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>

#include "fileio.h"
#include "sea_msg.h"

#define STATE_SEA_MAX_BYTES (1u << 20) /* as state_load: a sea is at most ~100 kB */

cJSON *state_sea_json(const struct sea_spectrum *sea) { return sea_doc_json(sea); }

int state_load_sea(const char *path, struct sea_spectrum *out, char *err, size_t errlen)
{
    char *buf;
    size_t len;
    int rc = file_read_all(path, STATE_SEA_MAX_BYTES, &buf, &len, err, errlen);
    if (rc != 0)
        return 0; /* no file, or state_load reported it already */
    struct ctl_error e;
    cJSON *root = control_parse_object(buf, len, &e);
    free(buf);
    const cJSON *doc = cJSON_GetObjectItemCaseSensitive(root, "sea");
    if (!doc || cJSON_IsNull(doc)) {
        cJSON_Delete(root);
        return 0;
    }
    struct sea_spectrum *s = malloc(sizeof *s);
    if (!s) {
        cJSON_Delete(root);
        snprintf(err, errlen, "the measured sea: out of memory");
        return -1;
    }
    rc = sea_doc_parse(doc, s, &e);
    cJSON_Delete(root);
    if (rc != 0) {
        snprintf(err, errlen, "the measured sea (%s): %s", e.code, e.message);
        free(s);
        return -1;
    }
    *out = *s;
    free(s);
    return 1;
}

/* role_lease_sea.c — the measured sea in the simulation's JetStream record
 * (role_lease.c): the "sea" member is the document as the `sea` message and
 * the state file carry it (sea_msg.c), so a standby takes it through the same
 * check. Its own file: other parts of the record grow beside it. */
#include "role_lease.h"

#include <cjson/cJSON.h>
#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "sea_msg.h"

int lease_record_add_sea(cJSON *rec, const struct sea_spectrum *sea)
{
    if (!sea)
        return 0; /* no member: no sea */
    cJSON *doc = sea_doc_json(sea);
    if (!doc || !cJSON_AddItemToObject(rec, "sea", doc)) {
        cJSON_Delete(doc);
        return -1;
    }
    return 0;
}

int lease_record_sea(const cJSON *rec, struct sea_spectrum **out)
{
    *out = NULL;
    const cJSON *doc = cJSON_GetObjectItemCaseSensitive(rec, "sea");
    if (!doc || cJSON_IsNull(doc))
        return 0;
    struct sea_spectrum *s = malloc(sizeof *s);
    struct ctl_error e;
    if (!s)
        return -1;
    if (sea_doc_parse(doc, s, &e) != 0) {
        LOGW("cluster: the record's measured sea is refused (%s): %s", e.code, e.message);
        free(s);
        return -1;
    }
    *out = s;
    return 0;
}

bool lease_sea_differs(const struct sea_spectrum *a, const struct sea_spectrum *b)
{
    if (!a || !b)
        return a != b;
    return memcmp(a, b, sizeof *a) != 0;
}

int lease_keep_sea(struct sea_spectrum **kept, const struct sea_spectrum *sea)
{
    if (!sea) {
        free(*kept);
        *kept = NULL;
        return 0;
    }
    if (!lease_sea_differs(*kept, sea))
        return 0;
    struct sea_spectrum *c = *kept ? *kept : malloc(sizeof *c);
    if (!c)
        return -1;
    *c = *sea;
    *kept = c;
    return 0;
}

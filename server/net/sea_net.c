/* sea_net.c — a measured sea over the wire (PROTOCOL.md §7.8): the `sea`
 * request checked against the view and handed to the sim like a set (its
 * parameters: spectrum "measured" and the sea's depth), and its summary in
 * hello and params. */
#include "net_internal.h"

#include <stdlib.h>

#include "sea_msg.h"

#define SEA_DEFAULT_DEPTH 1000.0 /* m: a document whose depth is null is deep water (the parameter's default) */

bool sea_net_attached(const struct net *n) { return n->sea_summary || n->seas_in_flight > 0; }

int sea_net_check(const cJSON *doc, struct ctl_error *e)
{
    struct sea_spectrum *sea = malloc(sizeof *sea); /* 83 kB: not on the lws stack */
    if (!sea) {
        *e = (struct ctl_error){ .code = "internal", .message = "out of memory" };
        return -1;
    }
    int rc = sea_doc_parse(doc, sea, e);
    free(sea);
    return rc;
}

void sea_net_submit(struct net *n, struct session *s, const struct remote *rm, const struct ctl_msg *m)
{
    struct ctl_error e;
    struct sea_spectrum *sea = malloc(sizeof *sea);
    if (!sea) {
        e = (struct ctl_error){ .code = "internal", .message = "out of memory" };
        dispatch_respond_error(s, rm, &e, m->id);
        return;
    }
    if (sea_doc_parse(m->sea, sea, &e) != 0) {
        free(sea);
        dispatch_respond_error(s, rm, &e, m->id);
        return;
    }
    /* A sea is shown as soon as it is sent, in the water it was measured in. */
    struct ocean_params out = n->view;
    out.spectrum = SPECTRUM_MEASURED;
    out.depth = sea->depth > 0 ? sea->depth : SEA_DEFAULT_DEPTH;
    dispatch_submit_change(n, s, rm, &out, params_diff(&n->view, &out), m->name, m->id, sea);
}

void sea_net_add(const struct net *n, cJSON *msg)
{
    cJSON *raw = n->sea_summary ? cJSON_CreateRaw(n->sea_summary) : cJSON_CreateNull();
    if (raw && !cJSON_AddItemToObject(msg, "sea", raw))
        cJSON_Delete(raw);
}

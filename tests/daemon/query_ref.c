/* query_ref — the library's exact point query, for the daemon tests to
 * compare `query_result` with.
 *
 *   query_ref REQUEST.json
 * REQUEST.json: {"params": {...}, "time": t, "points": [[x, z], ...]}
 * (params as in hello/params; missing ones take their defaults).
 * Prints one JSON object: {"points": [{"height":…, "displacement":[…],
 * "normal":[…], "vertical_velocity":…, "vertical_acceleration":…}, …]}. */
#include <stdio.h>
#include <stdlib.h>

#include "control.h"
#include "ocean.h"
#include "query_msg.h"

#include "../common/slurp.h"

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: query_ref REQUEST.json\n");
        return 2;
    }
    size_t len = 0;
    char *text = slurp(argv[1], &len);
    cJSON *root = text ? cJSON_ParseWithLength(text, len) : NULL;
    free(text);
    struct ocean_params defs, p;
    params_defaults(&defs);
    struct ctl_error e;
    struct query_req *q = malloc(sizeof *q);
    if (!root || !q || control_apply_params(cJSON_GetObjectItemCaseSensitive(root, "params"), &defs, NULL, &p, NULL, &e) != 0 ||
        query_parse(root, q, &e) != 0 || !q->has_time) {
        fprintf(stderr, "query_ref: %s: %s\n", argv[1], root ? e.message : "cannot read JSON");
        return 2;
    }
    char err[200];
    struct ocean_options opt = { .threads = 1, .wisdom_path = NULL, .plan_rigor = 0 };
    struct ocean *o = ocean_create(&p, &opt, err, sizeof err);
    struct ocean_point *pts = calloc((size_t)q->n, sizeof *pts);
    if (!o || !pts || ocean_query(o, q->time, (const double(*)[2])q->xz, q->n, pts) != 0) {
        fprintf(stderr, "query_ref: %s\n", o ? "query failed" : err);
        return 2;
    }
    char *out = control_print(query_result_msg(NULL, q->time, 0, q->n, pts));
    puts(out);
    free(out);
    free(pts);
    free(q);
    ocean_free(o);
    cJSON_Delete(root);
    return 0;
}

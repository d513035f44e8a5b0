/* tap_query.c — --query (one query_result) and --probe (probe_data per tick, JSON or CSV). */
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tap.h"

static cJSON *points_json(const struct opts *o)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; i < o->npoints; i++) cJSON_AddItemToArray(a, cJSON_CreateDoubleArray(o->points[i], 2));
    return a;
}

void send_points(struct session *s, const char *type, int id)
{
    cJSON *j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "type", type);
    cJSON_AddNumberToObject(j, "id", id);
    cJSON_AddItemToObject(j, "points", points_json(s->o));
    if (id == ID_QUERY && s->o->has_time) cJSON_AddNumberToObject(j, "time", s->o->time);
    send_json(s, j);
}

/* One probe_data message: as it came (JSON), or one CSV row per point. */
void print_probe(struct session *s, cJSON *msg, const char *text, size_t len)
{
    if (!s->o->csv) {
        printf("%.*s\n", (int)len, text);
    } else {
        if (!s->csv_header_done) {
            puts("seq,sim_time,params_version,point,x,z,height,dx,dz,nx,ny,nz,vertical_velocity,vertical_acceleration");
            s->csv_header_done = 1;
        }
        cJSON *seq = cJSON_GetObjectItemCaseSensitive(msg, "seq"), *t = cJSON_GetObjectItemCaseSensitive(msg, "sim_time");
        cJSON *v = cJSON_GetObjectItemCaseSensitive(msg, "params_version"), *pts = cJSON_GetObjectItemCaseSensitive(msg, "points");
        int i = 0;
        cJSON *p, *x;
        cJSON_ArrayForEach(p, pts) {
            if (i >= s->o->npoints) break;
            printf("%.0f,%.17g,%.0f,%d,%.10g,%.10g", cJSON_GetNumberValue(seq), cJSON_GetNumberValue(t),
                   cJSON_GetNumberValue(v), i, s->o->points[i][0], s->o->points[i][1]);
            cJSON_ArrayForEach(x, p) printf(",%.10g", cJSON_GetNumberValue(x));
            putchar('\n');
            i++;
        }
    }
    fflush(stdout);
    if (s->o->ticks > 0 && ++s->ticks_done >= s->o->ticks) finish(s, EXIT_OK);
}


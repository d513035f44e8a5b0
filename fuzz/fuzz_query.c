/* fuzz_query.c — libFuzzer target: one `query` or `probe` message through
 * what the daemon does with it on the lws thread (control_parse ->
 * query_parse / probe_parse -> reply), then the probe path (probe_eval) at
 * the parsed points on a small grid: whatever the input, errors are coded,
 * replies print, and probe values are finite. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "control.h"
#include "probe.h"
#include "query_msg.h"

static void check(int ok)
{
    if (!ok)
        abort();
}

#define GN 16
static float gh[GN * GN], gdx[GN * GN], gdz[GN * GN];

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (gh[1] == 0) /* a small choppy sea: two waves */
        for (int z = 0; z < GN; z++)
            for (int x = 0; x < GN; x++) {
                double a = 2 * M_PI * x / GN, b = 2 * M_PI * 3 * z / GN;
                gh[z * GN + x] = (float)(0.5 * cos(a) + 0.2 * cos(a + b));
                gdx[z * GN + x] = (float)(-0.4 * sin(a));
                gdz[z * GN + x] = (float)(-0.3 * sin(b));
            }
    struct ctl_msg m;
    struct ctl_error e = { 0 };
    cJSON *id = NULL;
    if (control_parse((const char *)data, size, &m, &id, &e) != 0) {
        cJSON_Delete(id);
        return 0;
    }
    static struct query_req q;
    static struct probe_req p;
    if (m.type == CTL_QUERY) {
        if (query_parse(m.root, &q, &e) != 0) {
            check(e.code && e.message[0]);
            free(control_print(control_error_msg(&e, m.id)));
        } else {
            check(q.n >= 1 && q.n <= QUERY_MAX_POINTS && (!q.has_time || isfinite(q.time)));
            static struct ocean_point pts[QUERY_MAX_POINTS];
            for (int i = 0; i < q.n; i++)
                check(isfinite(q.xz[i][0]) && isfinite(q.xz[i][1]));
            char *t = control_print(query_result_msg(m.id, q.time, 1, q.n, pts));
            check(t != NULL);
            free(t);
        }
    } else if (m.type == CTL_PROBE) {
        if (probe_parse(m.root, 8, &p, &e) != 0) {
            check(e.code && e.message[0]);
        } else {
            check(p.n >= 0 && p.n <= 8);
            /* two cascades (the same grids on incommensurate patches): the summed path */
            struct probe_grids g = { .n = GN, .ncasc = 2, .patch = { 20.0, 20.0 / 3.543 }, .h = { gh, gh },
                                     .dx = { gdx, gdx }, .dz = { gdz, gdz } };
            struct probe_value v[8];
            for (int i = 0; i < p.n; i++) {
                double guess[2] = { p.xz[i][0], p.xz[i][1] };
                probe_eval(&g, p.xz[i][0], p.xz[i][1], guess, &v[i]);
                check(isfinite(v[i].height) && isfinite(v[i].normal[1]) && isfinite(guess[0]) && isfinite(guess[1]));
            }
            char *t = probe_data_text(1, 0.5, 1, p.n, v);
            check(t != NULL);
            free(t);
            free(control_print(probing_msg(m.id, p.n, (const double(*)[2])p.xz)));
        }
    }
    ctl_msg_free(&m);
    return 0;
}

/* test_probe — accuracy of the probes' cheap path (server/probe.c: Lanczos-3
 * on a tick's grids, Newton on the interpolated displacement, derivatives from
 * the last three ticks) against the library's exact query, at the daemon's
 * defaults (N = 256) with choppiness 0, 1 and 2. Prints one JSON line per
 * case with the errors (docs/query.md quotes them); fails when they exceed
 * the documented accuracy. Also checks the probe message and its parser. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "control.h"
#include "ocean.h"
#include "probe.h"
#include "query_msg.h"

#include "../common/check.h"

#define NPTS 200
#define DT (1.0 / 30.0)

/* Documented accuracy at N = 256 defaults (docs/query.md). */
struct limits {
    double height_max, height_rms, normal_deg, vel_max, acc_max, acc_rms;
};

static void accuracy(double choppiness, const struct limits *lim)
{
    struct ocean_params p;
    params_defaults(&p);
    p.choppiness = choppiness;
    struct ocean_options opt = { .threads = 1, .wisdom_path = NULL, .plan_rigor = 0 };
    char err[200];
    struct ocean *o = ocean_create(&p, &opt, err, sizeof err);
    CHECK(o, "ocean_create: %s", err);
    if (!o)
        return;
    static double xz[NPTS][2], guess[NPTS][2], hist[NPTS][3];
    static struct probe_value v[NPTS];
    static struct ocean_point ex[NPTS];
    srand(7);
    for (int i = 0; i < NPTS; i++) {
        double r1 = rand() / (double)RAND_MAX, r2 = rand() / (double)RAND_MAX;
        /* any real coordinates: some far away and negative */
        double far = i % 4 == 0 ? -1e6 : i % 4 == 1 ? 3.3e5 : 0;
        xz[i][0] = far + r1 * p.patch_size;
        xz[i][1] = -far + r2 * p.patch_size;
        guess[i][0] = xz[i][0];
        guess[i][1] = xz[i][1];
    }
    const double t = 100.0, times[3] = { t, t - DT, t - 2 * DT };
    for (int k = 2; k >= 0; k--) { /* three ticks, oldest first, like the daemon */
        CHECK(ocean_step(o, times[k], OCEAN_ALL_FIELDS) == 0, "step");
        struct probe_grids g = { .n = p.resolution, .ncasc = ocean_cascades(o) };
        for (int c = 0; c < g.ncasc; c++) { /* every cascade, as the daemon's query_tick copies them */
            g.patch[c] = ocean_cascade_patch(p.patch_size, c);
            g.h[c] = ocean_cascade_field(o, c, OCEAN_HEIGHT);
            g.dx[c] = ocean_cascade_field(o, c, OCEAN_DX);
            g.dz[c] = ocean_cascade_field(o, c, OCEAN_DZ);
        }
        for (int i = 0; i < NPTS; i++) {
            probe_eval(&g, xz[i][0], xz[i][1], guess[i], &v[i]);
            hist[i][k] = v[i].height;
        }
    }
    CHECK(ocean_query(o, t, (const double(*)[2])xz, NPTS, ex) == 0, "exact query");
    /* The method's own floor: the same quadratic through the exact heights
     * of the three ticks (what the history can give at best). */
    static struct ocean_point ex1[NPTS], ex2[NPTS];
    CHECK(ocean_query(o, times[1], (const double(*)[2])xz, NPTS, ex1) == 0, "exact query");
    CHECK(ocean_query(o, times[2], (const double(*)[2])xz, NPTS, ex2) == 0, "exact query");
    double fss = 0;
    for (int i = 0; i < NPTS; i++) {
        double hh[3] = { ex[i].height, ex1[i].height, ex2[i].height }, fv, fa;
        probe_derivatives(hh, times, &fv, &fa);
        fss += (fa - ex[i].vertical_acceleration) * (fa - ex[i].vertical_acceleration);
    }
    double hmax = 0, hss = 0, nmax = 0, vmax = 0, amax = 0, vrms = 0, vss = 0, ass = 0, arms = 0;
    for (int i = 0; i < NPTS; i++) {
        double dh = fabs(v[i].height - ex[i].height);
        hmax = fmax(hmax, dh);
        hss += dh * dh;
        double dot = v[i].normal[0] * ex[i].normal[0] + v[i].normal[1] * ex[i].normal[1] + v[i].normal[2] * ex[i].normal[2];
        nmax = fmax(nmax, acos(fmin(1.0, dot)) * 180 / M_PI);
        double vel, acc;
        probe_derivatives(hist[i], times, &vel, &acc);
        vmax = fmax(vmax, fabs(vel - ex[i].vertical_velocity));
        amax = fmax(amax, fabs(acc - ex[i].vertical_acceleration));
        vss += (vel - ex[i].vertical_velocity) * (vel - ex[i].vertical_velocity);
        ass += (acc - ex[i].vertical_acceleration) * (acc - ex[i].vertical_acceleration);
        arms += ex[i].vertical_acceleration * ex[i].vertical_acceleration;
        vrms += ex[i].vertical_velocity * ex[i].vertical_velocity;
    }
    double hrms = sqrt(hss / NPTS);
    printf("{\"test\": \"probe_accuracy\", \"N\": %d, \"choppiness\": %g, \"points\": %d, \"height_err_max_mm\": %.2f, "
           "\"height_err_rms_mm\": %.2f, \"normal_err_max_deg\": %.3f, \"vvel_err_max\": %.4f, \"vvel_rms\": %.3f, "
           "\"vvel_err_rms\": %.4f, \"vacc_err_max\": %.4f, \"vacc_err_rms\": %.4f, \"vacc_rms\": %.3f, "
           "\"vacc_err_rms_of_exact_history\": %.4f}\n",
           p.resolution, choppiness, NPTS, hmax * 1e3, hrms * 1e3, nmax, vmax, sqrt(vrms / NPTS), sqrt(vss / NPTS),
           amax, sqrt(ass / NPTS), sqrt(arms / NPTS), sqrt(fss / NPTS));
    CHECK(hmax <= lim->height_max, "chop %g: height error %.4f m > %.4f", choppiness, hmax, lim->height_max);
    CHECK(hrms <= lim->height_rms, "chop %g: height rms error %.4f m > %.4f", choppiness, hrms, lim->height_rms);
    CHECK(nmax <= lim->normal_deg, "chop %g: normal error %.3f deg > %.3f", choppiness, nmax, lim->normal_deg);
    CHECK(vmax <= lim->vel_max, "chop %g: velocity error %.4f > %.4f", choppiness, vmax, lim->vel_max);
    CHECK(amax <= lim->acc_max, "chop %g: acceleration error %.4f > %.4f", choppiness, amax, lim->acc_max);
    CHECK(sqrt(ass / NPTS) <= lim->acc_rms, "chop %g: acceleration rms error %.4f > %.4f", choppiness,
          sqrt(ass / NPTS), lim->acc_rms);
    ocean_free(o);
}

static void messages(void)
{
    struct ctl_error e;
    static struct query_req q;
    static struct probe_req pr;
    const char *bad[] = {
        "{\"points\":[]}", "{\"points\":5}", "{}", "{\"points\":[[1]]}", "{\"points\":[[1,2,3]]}",
        "{\"points\":[[1,\"2\"]]}", "{\"points\":[[1e999,2]]}", "{\"points\":[[1,2]],\"time\":\"now\"}",
        "{\"points\":[[1,2]],\"time\":-1e999}", "{\"points\":[{\"x\":1}]}",
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        cJSON *j = cJSON_Parse(bad[i]);
        CHECK(j && query_parse(j, &q, &e) == -1 && strcmp(e.code, "bad_query") == 0, "accepted %s", bad[i]);
        cJSON_Delete(j);
    }
    cJSON *big = cJSON_CreateObject(), *arr = cJSON_AddArrayToObject(big, "points");
    for (int i = 0; i < QUERY_MAX_POINTS + 1; i++) {
        double xy[2] = { i, -i };
        cJSON_AddItemToArray(arr, cJSON_CreateDoubleArray(xy, 2));
    }
    CHECK(query_parse(big, &q, &e) == -1 && strcmp(e.code, "too_many_points") == 0, "257 points accepted");
    cJSON_DeleteItemFromArray(arr, 0);
    CHECK(query_parse(big, &q, &e) == 0 && q.n == QUERY_MAX_POINTS && !q.has_time && q.xz[0][0] == 1, "256 points");
    CHECK(probe_parse(big, 16, &pr, &e) == -1 && strcmp(e.code, "too_many_points") == 0, "probe over its cap");
    cJSON_Delete(big);
    cJSON *ok = cJSON_Parse("{\"points\":[[-1e12,3.5]],\"time\":12.25}");
    CHECK(query_parse(ok, &q, &e) == 0 && q.n == 1 && q.has_time && q.time == 12.25 && q.xz[0][0] == -1e12, "good");
    cJSON_Delete(ok);
    cJSON *none = cJSON_Parse("{\"points\":[]}");
    CHECK(probe_parse(none, 16, &pr, &e) == 0 && pr.n == 0, "empty probe = unsubscribe");
    cJSON_Delete(none);
    struct probe_value pv[2] = { { 1.23456, -0.5, 0.25, { 0, 1, 0 }, 0.1, -0.2 }, { 0, 0, 0, { 0, 1, 0 }, 0, 0 } };
    char *txt = probe_data_text(42, 1.5, 7, 2, pv);
    cJSON *j = cJSON_Parse(txt);
    const cJSON *pts = cJSON_GetObjectItem(j, "points");
    CHECK(j && cJSON_GetArraySize(pts) == 2 && cJSON_GetObjectItem(j, "seq")->valuedouble == 42 &&
              fabs(cJSON_GetArrayItem(cJSON_GetArrayItem(pts, 0), 0)->valuedouble - 1.2346) < 1e-9,
          "probe_data round trip: %s", txt);
    cJSON_Delete(j);
    free(txt);
}

int main(void)
{
    messages();
    /* Limits: the measured errors (docs/query.md) with headroom. The
     * acceleration's are the method's own (the quadratic through the exact
     * heights of the same three ticks is as far off): the finer cascades'
     * waves have periods down to 0.45 s, 13 ticks. A probe of cascade 0
     * alone fails the height limits (1.3 cm rms off the sea). */
    struct limits l0 = { 0.022, 0.0075, 4.5, 0.12, 1.0, 0.35 };
    struct limits l1 = { 0.022, 0.0075, 5.0, 0.12, 4.0, 0.75 };
    struct limits l2 = { 0.040, 0.0090, 5.0, 0.26, 14.0, 2.2 };
    accuracy(0, &l0);
    accuracy(1, &l1);
    accuracy(2, &l2);
    return check_done();
}

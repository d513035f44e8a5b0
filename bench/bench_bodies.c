/* bench_bodies.c — cost of stepping floating bodies (server/sim/bodies*.c).
 *
 * Usage: bench_bodies     (make bench-bodies-step)
 * One JSON object per line on stdout, one thread, medians over ticks:
 *   {"bench":"load","loadavg_1m":..}  the machine's load when the run started;
 *   {"bench":"bodies_step","bodies":64,"sampler":"grid3",...}
 *       64 bodies of the five kinds in turn (powered ones under way and
 *       turning), stepped at 30 Hz (body_world_step with dt = 1/30 s: 4
 *       substeps), on a sea sampled as the daemon would: bilinear lookups
 *       of height and dhdt in three periodic 256 x 256 float grids (the
 *       cascades, 256 m, 72 m and 20 m) summed per point;
 *       us_per_tick, us_per_body_tick (wall), cpu_us_per_body_tick (this
 *       thread's CPU), points_per_tick (sea samples asked for);
 *   {"bench":"bodies_step","sampler":"still",...}
 *       the same bodies in still water (no sampler): the bodies' own share.
 * The machine may be shared: compare rows of one run, not across runs. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "bodies.h"

#include "bench_time.h"

enum { GRID_N = 256, CASCADES = 3, BODIES = 64, TICKS = 600, WARMUP = 60 };

struct grid_sea {
    float *height[CASCADES], *dhdt[CASCADES];
    double side[CASCADES];
    long points;
};

/* Bilinear lookup in a periodic N x N grid of side L at world (x, z). */
static double lookup(const float *g, double side, double x, double z)
{
    double fx = x / side * GRID_N, fz = z / side * GRID_N;
    double ix = floor(fx), iz = floor(fz), ax = fx - ix, az = fz - iz;
    int x0 = (int)((long)ix & (GRID_N - 1)), z0 = (int)((long)iz & (GRID_N - 1));
    int x1 = (x0 + 1) & (GRID_N - 1), z1 = (z0 + 1) & (GRID_N - 1);
    double a = g[z0 * GRID_N + x0], b = g[z0 * GRID_N + x1], c = g[z1 * GRID_N + x0], d = g[z1 * GRID_N + x1];
    return (1 - az) * ((1 - ax) * a + ax * b) + az * ((1 - ax) * c + ax * d);
}

static int grid_sample(void *ctx, double t, int n, const double (*xz)[2], double *height, double *dhdt)
{
    struct grid_sea *s = ctx;
    for (int i = 0; i < n; i++) {
        height[i] = dhdt[i] = 0;
        for (int c = 0; c < CASCADES; c++) {
            height[i] += lookup(s->height[c], s->side[c], xz[i][0], xz[i][1]);
            dhdt[i] += lookup(s->dhdt[c], s->side[c], xz[i][0], xz[i][1]);
        }
    }
    s->points += n;
    return 0;
}

/* A few waves per cascade, frozen: the cost is the lookup, not the sea. */
static void grid_fill(struct grid_sea *s)
{
    for (int c = 0; c < CASCADES; c++) {
        s->side[c] = 256.0 / pow(3.543, c);
        s->height[c] = malloc(sizeof(float) * GRID_N * GRID_N);
        s->dhdt[c] = malloc(sizeof(float) * GRID_N * GRID_N);
        for (int iz = 0; iz < GRID_N; iz++)
            for (int ix = 0; ix < GRID_N; ix++) {
                double x = 2 * M_PI * ix / GRID_N, z = 2 * M_PI * iz / GRID_N, a = 0.8 / (c + 1);
                s->height[c][iz * GRID_N + ix] = (float)(a * (cos(3 * x + z) + 0.5 * sin(2 * x - 5 * z)));
                s->dhdt[c][iz * GRID_N + ix] = (float)(a * (sin(3 * x + z) - 0.5 * cos(2 * x - 5 * z)));
            }
    }
}

static void run(const char *name, struct grid_sea *gs)
{
    struct body_world *w = body_world_new(BODIES);
    struct body_sea sea = {grid_sample, gs};
    for (int i = 0; i < BODIES; i++) {
        uint32_t id;
        body_launch(w, &body_kinds()[i % BODY_KIND_COUNT], 40.0 * (i % 8) - 160, 40.0 * (i / 8) - 160, 45.0 * i, &id);
        struct body_control c = {1, (i % 3 - 1) * 0.5};
        body_steer(w, id, &c);
    }
    double wall[TICKS], cpu[TICKS], t = 0;
    long points0 = 0;
    for (int k = 0; k < WARMUP + TICKS; k++) {
        if (k == WARMUP && gs)
            points0 = gs->points;
        t += 1.0 / 30;
        double w0 = now_s(), c0 = thread_cpu_s();
        body_world_step(w, gs ? &sea : NULL, t, 1.0 / 30, NULL, NULL, 0);
        if (k >= WARMUP) {
            wall[k - WARMUP] = (now_s() - w0) * 1e6;
            cpu[k - WARMUP] = (thread_cpu_s() - c0) * 1e6;
        }
    }
    double mw = median(wall, TICKS), mc = median(cpu, TICKS);
    printf("{\"bench\":\"bodies_step\",\"bodies\":%d,\"sampler\":\"%s\",\"tick_hz\":30,\"substeps\":4,\"ticks\":%d,"
           "\"us_per_tick\":%.1f,\"us_per_body_tick\":%.3f,\"cpu_us_per_body_tick\":%.3f,\"points_per_tick\":%.0f,"
           "\"bodies_left\":%d}\n",
           BODIES, name, TICKS, mw, mw / BODIES, mc / BODIES, gs ? (double)(gs->points - points0) / TICKS : 0.0,
           body_world_count(w));
    body_world_free(w);
}

int main(void)
{
    double load[1] = {-1};
    if (getloadavg(load, 1) < 1)
        load[0] = -1;
    printf("{\"bench\":\"load\",\"loadavg_1m\":%.2f}\n", load[0]);
    struct grid_sea gs = {0};
    grid_fill(&gs);
    run("grid3", &gs);
    run("still", NULL);
    for (int c = 0; c < CASCADES; c++) {
        free(gs.height[c]);
        free(gs.dhdt[c]);
    }
    return 0;
}

/* bench_wakes.c — what the wakes layer (server/sim/wakes.c) adds to a tick:
 * wakes_step for 8 boats moving at 30 Hz, one JSON object per line.
 *
 * Cases: the 8 boats far apart (8 regions, the worst case) and in one
 * group (sharing regions); 1 and 2 threads; the default n = 128 with and
 * without displacement, FFTW_MEASURE plans (and once FFTW_ESTIMATE's, as
 * the tests plan); no bodies at all. Each case steps 10 s of sim
 * time to warm up, then times TICKS ticks: median and 90th percentile of
 * the wall time per tick, and the process CPU time per tick (all
 * threads). The target: <= 3 ms a tick on 2 cores for 8 boats, on top of
 * the daemon's sea at N = 256 (docs/simulation.md, "Wakes"). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "bench_time.h"
#include "wakes.h"

#define TICKS 300
#define HZ    30.0

static void run(const char *layout, int threads, int displacement, int boats, int rigor)
{
    struct wakes_options o = {.threads = threads, .displacement = displacement, .plan_rigor = rigor};
    char err[128];
    struct wakes *w = wakes_new(&o, err, sizeof err);
    if (!w) {
        fprintf(stderr, "bench_wakes: %s\n", err);
        exit(1);
    }
    struct wake_source s[8];
    double spread = layout[0] == 'f' ? 600 : 40; /* far apart / one group */
    for (int i = 0; i < boats; i++)
        s[i] = (struct wake_source){.id = (uint32_t)i + 1, .length = 12, .beam = 4, .mass = 6000};
    double wall[TICKS], cpu0 = 0;
    int warm = (int)(10 * HZ), regions = 0;
    for (int k = 0; k < warm + TICKS; k++) {
        double t = k / HZ;
        for (int i = 0; i < boats; i++) { /* each on its own 60 m circle at 6 m/s */
            double a = 0.1 * t + i, cx = spread * ((i % 4) - 1.5), cz = spread * ((i / 4) - 0.5);
            s[i].x = cx + 60 * cos(a);
            s[i].z = cz + 60 * sin(a);
            s[i].vx = -6 * sin(a);
            s[i].vz = 6 * cos(a);
            s[i].heading_deg = atan2(-s[i].vx, s[i].vz) * 180 / 3.14159265358979;
        }
        if (k == warm)
            cpu0 = cpu_ms();
        double t0 = now_ms();
        wakes_step(w, 1 / HZ, boats, s, NULL, 0);
        if (k >= warm)
            wall[k - warm] = now_ms() - t0;
        regions = wakes_region_count(w);
    }
    double cpu = (cpu_ms() - cpu0) / TICKS;
    double med = median(wall, TICKS), p90 = wall[(int)(0.9 * TICKS)];
    printf("{\"bench\":\"wakes_step\",\"boats\":%d,\"layout\":\"%s\",\"regions\":%d,\"n\":128,\"threads\":%d,"
           "\"displacement\":%s,\"plans\":\"%s\",\"tick_hz\":30,\"ticks\":%d,\"median_ms\":%.3f,\"p90_ms\":%.3f,\"cpu_ms_per_tick\":%.3f}\n",
           boats, boats ? layout : "none", regions, threads, displacement ? "true" : "false", rigor ? "measure" : "estimate", TICKS, med, p90, cpu);
    fflush(stdout);
    wakes_free(w);
}

int main(void)
{
    for (int th = 1; th <= 2; th++) {
        run("far", th, 0, 8, 1);
        run("far", th, 1, 8, 1);
        run("group", th, 0, 8, 1);
    }
    run("far", 1, 0, 8, 0);
    run("far", 1, 0, 0, 1);
    double load[3];
    if (getloadavg(load, 3) > 0)
        printf("{\"bench\":\"load\",\"loadavg_1m\":%.2f}\n", load[0]);
    return 0;
}

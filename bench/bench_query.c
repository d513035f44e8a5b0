/* bench_query.c — cost of exact point queries (server/sim/ocean_query.c).
 *
 * Usage: bench_query     (make bench-query)
 * One JSON object per line on stdout, medians over repetitions, one thread,
 * for the sea of 1 cascade and of the default 3 (every row has "cascades";
 * a query sums all cascades' modes):
 *   {"bench":"load","loadavg_1m":..}  the machine's load when the run started;
 *   {"bench":"query_snapshot","N":..,"modes":..,"ms":..}
 *       ocean_surface_new: copying and pruning the amplitudes (once per
 *       parameter change);
 *   {"bench":"query","N":..,"points":..,"ms":..,"cpu_ms":..,"us_per_point":..,"newton_steps":..}
 *       ocean_surface_query for 1, 16 and 256 random points of the default
 *       sea (choppiness 1), including the per-call time setup (one
 *       sin/cos per mode) and the Newton inversion (mean steps per point);
 *   {"bench":"probe_tick","N":..,"points":16,...}
 *       the 16 points one tick later, warm-started from the previous
 *       sources (ocean_surface_query_from), as a probe subscription would;
 *   {"bench":"query_vs_step","N":..,"step_ms":..,"points_per_step":..}
 *       how many points cost as much as one full FFT step of the grid;
 *   {"bench":"query_cascade_ratio","N":..,"modes_ratio":..,"cpu_ratio":..}
 *       3 cascades against 1, this run: modes and CPU per point (256 points).
 * The machine may be shared: compare rows of one run, not across runs. */
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>
#include <time.h>

#include "ocean_internal.h"

#include "bench_time.h"

int main(void)
{
    const int sizes[] = {256, 512}, counts[] = {1, 16, 256}, cascades[] = {1, 3};
    double load[1] = {-1};
    if (getloadavg(load, 1) < 1)
        load[0] = -1;
    printf("{\"bench\":\"load\",\"loadavg_1m\":%.2f}\n", load[0]);
    for (size_t si = 0; si < sizeof sizes / sizeof sizes[0]; si++) {
        double cpu_pp[2] = {0}, modes[2] = {0};
        for (int ki = 0; ki < 2; ki++) {
            struct ocean_params p;
            params_defaults(&p);
            p.resolution = sizes[si];
            p.cascades = cascades[ki];
            char err[256];
            struct ocean_options opt = {1, NULL, 0};
            struct ocean *o = ocean_create(&p, &opt, err, sizeof err);
            if (!o) {
                fprintf(stderr, "bench_query: %s\n", err);
                return 1;
            }
            enum { REPS = 7 };
            double v[REPS];
            struct ocean_surface *s = NULL;
            for (int r = 0; r < REPS; r++) {
                double t0 = now_ms();
                struct ocean_surface *x = ocean_surface_new(o, err, sizeof err);
                v[r] = now_ms() - t0;
                ocean_surface_free(s);
                s = x;
            }
            modes[ki] = ocean_surface_modes(s);
            printf("{\"bench\":\"query_snapshot\",\"N\":%d,\"cascades\":%d,\"modes\":%d,\"ms\":%.3f}\n",
                   p.resolution, p.cascades, ocean_surface_modes(s), median(v, REPS));
            fflush(stdout);
            double per_point = 0;
            for (size_t ci = 0; ci < sizeof counts / sizeof counts[0]; ci++) {
                int count = counts[ci], reps = count >= 256 ? 3 : REPS;
                double(*xz)[2] = malloc((size_t)count * sizeof *xz);
                struct ocean_point *out = malloc((size_t)count * sizeof *out);
                srand(7);
                for (int i = 0; i < count; i++) {
                    xz[i][0] = (2.0 * rand() / RAND_MAX - 1) * p.patch_size;
                    xz[i][1] = (2.0 * rand() / RAND_MAX - 1) * p.patch_size;
                }
                long steps = 0;
                double cpu[REPS];
                for (int r = 0; r < reps; r++) {
                    double t0 = now_ms(), c0 = cpu_ms();
                    ocean_surface_query(s, 10.0 + r, (const double(*)[2])xz, count, out);
                    v[r] = now_ms() - t0;
                    cpu[r] = cpu_ms() - c0;
                    for (int i = 0; i < count; i++)
                        steps += out[i].iterations;
                }
                double ms = median(v, reps);
                per_point = ms / count;
                double cms = median(cpu, reps);
                if (count == 256)
                    cpu_pp[ki] = cms / count;
                if (count == 16) {
                    /* A probe: the same points one tick (1/30 s) later, started
                     * from the sources the previous tick returned. */
                    double(*guess)[2] = malloc((size_t)count * sizeof *guess);
                    long wsteps = 0;
                    double wv[REPS], wc[REPS];
                    for (int r = 0; r < REPS; r++) {
                        ocean_surface_query(s, 20.0 + r, (const double(*)[2])xz, count, out);
                        for (int i = 0; i < count; i++) {
                            guess[i][0] = out[i].source[0];
                            guess[i][1] = out[i].source[1];
                        }
                        double t0 = now_ms(), c0 = cpu_ms();
                        ocean_surface_query_from(s, 20.0 + r + 1.0 / 30, (const double(*)[2])xz,
                                                 (const double(*)[2])guess, count, out);
                        wv[r] = now_ms() - t0;
                        wc[r] = cpu_ms() - c0;
                        for (int i = 0; i < count; i++)
                            wsteps += out[i].iterations;
                    }
                    double wms = median(wv, REPS), wcms = median(wc, REPS);
                    printf("{\"bench\":\"probe_tick\",\"N\":%d,\"cascades\":%d,\"points\":%d,\"ms\":%.3f,"
                           "\"cpu_ms\":%.3f,\"cpu_us_per_point\":%.1f,\"newton_steps\":%.2f}\n",
                           p.resolution, p.cascades, count, wms, wcms, 1e3 * wcms / count,
                           (double)wsteps / ((double)count * REPS));
                    free(guess);
                }
                printf("{\"bench\":\"query\",\"N\":%d,\"cascades\":%d,\"points\":%d,\"ms\":%.3f,\"cpu_ms\":%.3f,"
                       "\"us_per_point\":%.1f,\"cpu_us_per_point\":%.1f,\"newton_steps\":%.2f}\n",
                       p.resolution, p.cascades, count, ms, cms, 1e3 * ms / count, 1e3 * cms / count,
                       (double)steps / ((double)count * reps));
                fflush(stdout);
                free(xz);
                free(out);
            }
            for (int r = 0; r < REPS; r++) {
                double t0 = now_ms();
                ocean_step(o, 1.0 + r, OCEAN_ALL_FIELDS);
                v[r] = now_ms() - t0;
            }
            double step = median(v, REPS);
            printf("{\"bench\":\"query_vs_step\",\"N\":%d,\"cascades\":%d,\"step_ms\":%.3f,\"points_per_step\":%.1f}\n",
                   p.resolution, p.cascades, step, step / per_point);
            ocean_surface_free(s);
            ocean_free(o);
        }
        printf("{\"bench\":\"query_cascade_ratio\",\"N\":%d,\"modes_ratio\":%.3f,\"cpu_ratio\":%.3f}\n", sizes[si],
               modes[1] / modes[0], cpu_pp[1] / cpu_pp[0]);
        fflush(stdout);
    }
    return 0;
}

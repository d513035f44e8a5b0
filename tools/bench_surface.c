/* bench_surface — cost and accuracy of ocean-tap's summed surface (tap_surface.c).
 *
 * Synthetic cascades shaped like the server's (PROTOCOL.md §4.1): cascade 0 holds
 * wavenumbers up to N/2 - 1 of its grid, the finer ones up to N/4 - 1 (streamed at
 * LOD 1: N/2 samples a side), patches L / 3.543^c, amplitudes falling as k^-2. The
 * exact sum is evaluated mode by mode at 256 of the output points. One JSON object per
 * line: grid side M, whether the grid lies on cascade 0's nodes, the interpolation,
 * milliseconds per field (median of the repeats) and the error against the exact sum
 * relative to the signal's rms.
 *
 *   build/bench-surface [N]        (make bench-tap-surface) */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <fftw3.h>

#include "tap_surface.h"

#define NC 3
#define NPTS 256
#define REPS 7

struct mode { double kx, kz, a, b; }; /* a cos + b sin of (kx x + kz z) */

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

static double urand(unsigned long long *s)
{
    *s = *s * 6364136223846793005ULL + 1442695040888963407ULL;
    return (double)(*s >> 11) / 9007199254740992.0;
}

static int cmp(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

int main(int argc, char **argv)
{
    int n = argc > 1 ? atoi(argv[1]) : 256;
    if (n < 16 || n > 2048 || (n & (n - 1))) { fprintf(stderr, "N must be a power of two 16..2048\n"); return 1; }
    double L0 = 256, period[NC];
    int side[NC];
    float *grid[NC];
    struct mode *modes[NC];
    int nmodes[NC];
    unsigned long long seed = 12345;
    for (int c = 0; c < NC; c++) {
        period[c] = L0 / pow(3.543, c);
        side[c] = c == 0 ? n : n / 2;
        int top = c == 0 ? n / 2 - 1 : n / 4 - 1;
        modes[c] = malloc(sizeof(struct mode) * (size_t)(2 * top + 1) * (2 * top + 1));
        nmodes[c] = 0;
        for (int mz = -top; mz <= top; mz++)
            for (int mx = 0; mx <= top; mx++) {
                if (mx == 0 && mz <= 0) continue; /* one of each +-k pair */
                double k = hypot(mx, mz);
                double amp = 0.3 / (k * k) / (1 + c);
                modes[c][nmodes[c]++] = (struct mode){2 * M_PI * mx / period[c], 2 * M_PI * mz / period[c],
                                                      amp * (urand(&seed) - 0.5), amp * (urand(&seed) - 0.5)};
            }
        /* The grid from the same modes by one inverse FFT: a cos + b sin = Re((a - ib) e^{i phase}). */
        int sd = side[c], hc = sd / 2 + 1;
        fftwf_complex *spec = fftwf_alloc_complex((size_t)sd * hc);
        grid[c] = fftwf_alloc_real((size_t)sd * sd);
        memset(spec, 0, sizeof(fftwf_complex) * (size_t)sd * hc);
        fftwf_plan p = fftwf_plan_dft_c2r_2d(sd, sd, spec, grid[c], FFTW_ESTIMATE);
        for (int k = 0; k < nmodes[c]; k++) {
            int mx = (int)lround(modes[c][k].kx * period[c] / (2 * M_PI));
            int mz = (int)lround(modes[c][k].kz * period[c] / (2 * M_PI));
            double re = modes[c][k].a / 2, im = -modes[c][k].b / 2;
            int row = (mz % sd + sd) % sd;
            spec[(size_t)row * hc + mx][0] += (float)re;
            spec[(size_t)row * hc + mx][1] += (float)im;
            if (mx == 0) { /* the conjugate partner lives in the half spectrum too */
                int crow = (sd - row) % sd;
                spec[(size_t)crow * hc][0] += (float)re;
                spec[(size_t)crow * hc][1] -= (float)im;
            }
        }
        fftwf_execute(p);
        fftwf_destroy_plan(p);
        fftwf_free(spec);
    }
    struct tap_cascade_grid g[NC];
    for (int c = 0; c < NC; c++) g[c] = (struct tap_cascade_grid){grid[c], side[c], period[c]};
    struct tap_surface *s = tap_surface_new();
    struct { int m; double x0, z0, size; const char *where; } cases[] = {
        {n, 0, 0, L0, "nodes"}, {n, -37.3, 12.1, 100, "anywhere"}, {2 * n, 0, 0, L0, "anywhere"}};
    for (size_t ci = 0; ci < sizeof cases / sizeof cases[0]; ci++)
        for (int bil = 0; bil < 2; bil++) {
            int m = cases[ci].m;
            float *out = malloc(sizeof(float) * (size_t)m * m);
            double t[REPS];
            for (int r = 0; r < REPS; r++) {
                double t0 = now_ms();
                tap_surface_grid(s, g, NC, m, cases[ci].x0, cases[ci].z0, cases[ci].size, bil, out);
                t[r] = now_ms() - t0;
            }
            qsort(t, REPS, sizeof t[0], cmp);
            double se = 0, ss = 0, mx = 0;
            unsigned long long ps = 99;
            for (int p = 0; p < NPTS; p++) {
                int i = (int)(urand(&ps) * m), j = (int)(urand(&ps) * m);
                double x = cases[ci].x0 + i * cases[ci].size / m, z = cases[ci].z0 + j * cases[ci].size / m, v = 0;
                for (int c = 0; c < NC; c++)
                    for (int k = 0; k < nmodes[c]; k++) {
                        double ph = modes[c][k].kx * x + modes[c][k].kz * z;
                        v += modes[c][k].a * cos(ph) + modes[c][k].b * sin(ph);
                    }
                double e = out[(size_t)j * m + i] - v;
                se += e * e;
                ss += v * v;
                mx = fabs(e) > mx ? fabs(e) : mx;
            }
            printf("{\"bench\":\"tap_surface\",\"n\":%d,\"cascades\":%d,\"m\":%d,\"grid\":\"%s\",\"interp\":\"%s\","
                   "\"ms_per_field\":%.3f,\"err_rms_rel\":%.3g,\"err_max_rel\":%.3g}\n",
                   n, NC, m, cases[ci].where, bil ? "bilinear" : "spectral", t[REPS / 2], sqrt(se / ss),
                   mx / sqrt(ss / NPTS));
            free(out);
        }
    tap_surface_free(s);
    for (int c = 0; c < NC; c++) { fftwf_free(grid[c]); free(modes[c]); }
    return 0;
}

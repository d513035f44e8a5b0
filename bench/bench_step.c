/* bench_step.c — how long a simulation step takes, and how much of it is FFTW.
 *
 * Usage: bench_step [WISDOM_FILE [GROUP]]   (make bench-step passes build/fftw-wisdom;
 * GROUP = step, parts, pack, layout, reconfigure or dft runs only that one)
 * One JSON object per line on stdout, medians over repetitions:
 *   {"bench":"step","N":..,"threads":..,"step_ms":..,"fftw_ms":..,"ratio":..}
 *     for threads = 1, 2, 4, ... up to the online cores (the scaling curve);
 *     a full step (all six fields: 8 real transforms) vs, in the same
 *     process and interleaved with it, the bare FFTW executes that step runs
 *     (same plans, arrays and threads); also the step's process CPU time
 *     (all threads) and its fastest repetition, since the machine is shared;
 *     fftw_cpu_ms and cpu_ratio: the same with process CPU time (on a busy
 *     shared machine the least noisy ratio);
 *   {"bench":"step_parts",...}   one thread: what each part of our own work
 *     costs (step without it), the foam, and the Jacobian terms written as
 *     whole fields instead of in cache (bench_parts);
 *   {"bench":"pack_vs_c2r",...}  the transforms of a full step done our way
 *     (split c2r), as 8 plain 2-D c2r, and as 4 c2c carrying two real
 *     fields each (plus the de-interleave packing needs);
 *   {"bench":"z_to_rows",...}    one spectrum's z + row pass with the
 *     transposition as FFTW's rank-0 copy, as our own copy, or folded into
 *     FFTW's strided transforms (column-major or row-major in between);
 *   {"bench":"reconfigure",...}  a parameter change at the same N: ms and
 *     cpu_ms of ocean_reconfigure, prepare_ms + commit_ms of the builder's
 *     path, and create_ms of a whole new ocean (the old builder path);
 *   {"bench":"dft_vs_fft",...}   the thesis's Table IV.1: brute-force DFT vs
 *     FFT step, all fields, one thread.
 * Plans use FFTW_MEASURE with the wisdom file, as the daemon does. */
#include <malloc.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "ocean_internal.h"

#include "bench_time.h"

static int reps_for(int n)
{
    return n <= 64 ? 200 : n <= 128 ? 100 : n <= 256 ? 40 : n <= 512 ? 20 : n <= 1024 ? 11 : 7;
}

/* One cascade unless asked: the step/FFTW ratio is about one grid, and
 * ocean_step steps every cascade in force (with the default 3 the `step`
 * rows read 3.3-3.8: three grids' steps against one grid's FFTW). */
static struct ocean *make_cascades(int n, int threads, const char *wisdom, int rigor, int cascades)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = n;
    p.cascades = cascades;
    struct ocean_options opt = {threads, wisdom, rigor};
    char err[256];
    struct ocean *o = ocean_create(&p, &opt, err, sizeof err);
    if (!o)
        fprintf(stderr, "bench_step: N=%d: %s\n", n, err);
    return o;
}

static struct ocean *make(int n, int threads, const char *wisdom, int rigor)
{
    return make_cascades(n, threads, wisdom, rigor, 1);
}

static void bench_step(int n, int threads, const char *wisdom)
{
    struct ocean *o = make(n, threads, wisdom, 1);
    if (!o)
        return;
    int reps = reps_for(n);
    double *st = malloc(reps * sizeof *st), *ft = malloc(reps * sizeof *ft), *sc = malloc(reps * sizeof *sc),
           *fc = malloc(reps * sizeof *fc);
    double best = 1e300;
    ocean_step(o, 0.5, OCEAN_ALL_FIELDS); /* warm caches and pages */
    for (int r = 0; r < reps; r++) {
        double c0 = cpu_ms(), t0 = now_ms();
        ocean_step(o, 1.0 + r * 0.033, OCEAN_ALL_FIELDS);
        double t1 = now_ms(), c1 = cpu_ms();
        ocean_fft_only(o, OCEAN_ALL_FIELDS);
        double t2 = now_ms(), c2 = cpu_ms();
        st[r] = t1 - t0;
        ft[r] = t2 - t1;
        best = st[r] < best ? st[r] : best;
        sc[r] = c1 - c0;
        fc[r] = c2 - c1;
    }
    double s = median(st, reps), f = median(ft, reps), c = median(sc, reps), fcpu = median(fc, reps);
    printf("{\"bench\":\"step\",\"N\":%d,\"threads\":%d,\"fields\":\"all\",\"step_ms\":%.3f,\"fftw_ms\":%.3f,"
           "\"ratio\":%.3f,\"step_cpu_ms\":%.3f,\"fftw_cpu_ms\":%.3f,\"cpu_ratio\":%.3f,\"step_min_ms\":%.3f,"
           "\"reps\":%d}\n", n, threads, s, f, s / f, c, fcpu, c / fcpu, best, reps);
    free(sc);
    free(fc);
    fflush(stdout);
    free(st);
    free(ft);
    ocean_free(o);
}

/* Two ways of one part of the step, alternated step by step on one ocean
 * (the order swapped every repetition), so that both see the same moments
 * of a shared machine; six fields, wall time, medians. `ratio`: ours / the
 * other way, `pair_ratio`: the median of the per-repetition ratios.
 *   store: the z pass's copy and the row pass's output, ordinary stores
 *     (FFTW's copy plan, FFTW writing the rows: OCEAN_STORE_FFTW) against
 *     our streaming stores (OCEAN_STORE_STREAMING; the step streams the
 *     copy from OCEAN_STREAM_STORE_FROM_N, "used", and the output from
 *     OCEAN_STREAM_OUT_FROM_N: at 512 this group overstates the step's gain);
 *   rows: the row pass, FFTW's c2r (OCEAN_ROWS_C2R) against our
 *     half-length split (row_pretwiddle + row_half_plan; used at every N). */
static void bench_two_ways(int n, int threads, const char *wisdom, const char *name, unsigned fftw_way,
                           unsigned our_way, bool used)
{
    struct ocean *o = make(n, threads, wisdom, 1);
    if (!o)
        return;
    const unsigned six = OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM);
    const unsigned how[2] = {fftw_way, our_way};
    int reps = 4 * reps_for(n) + 1;
    double *t[2], *ratio = malloc(reps * sizeof *ratio);
    for (int k = 0; k < 2; k++)
        t[k] = malloc(reps * sizeof *t[k]);
    ocean_step_parts(o, 0.5, six, how[0]);
    ocean_step_parts(o, 0.6, six, how[1]);
    for (int r = 0; r < reps; r++) {
        for (int i = 0; i < 2; i++) {
            int k = i ^ (r & 1);
            double t0 = now_ms();
            ocean_step_parts(o, 1.0 + r * 0.033, six, how[k]);
            t[k][r] = now_ms() - t0;
        }
        ratio[r] = t[1][r] / t[0][r];
    }
    double f = median(t[0], reps), ours = median(t[1], reps), pr = median(ratio, reps);
    printf("{\"bench\":\"%s\",\"N\":%d,\"threads\":%d,\"fields\":\"six\",\"fftw_way_ms\":%.3f,"
           "\"our_way_ms\":%.3f,\"ratio\":%.3f,\"pair_ratio\":%.3f,\"used\":%s,\"reps\":%d}\n",
           name, n, threads, f, ours, ours / f, pr, used ? "true" : "false", reps);
    fflush(stdout);
    for (int k = 0; k < 2; k++)
        free(t[k]);
    free(ratio);
    ocean_free(o);
}

/* The transforms of a full step, three ways, same FFTW_MEASURE rigor:
 *  - ours: 5 z passes + 8 row c2r, tiled (ocean_fft_only, see ocean_step.c);
 *  - 8 plain 2-D c2r of N x N, one per real field;
 *  - packing: real fields A, B as the spectrum A~ + i B~ of one full N x N
 *    c2c (A in the real, B in the imaginary part of the result), 4 of
 *    them, plus the split into 8 float arrays that packing needs. */
static void bench_pack(int n, int threads, const char *wisdom)
{
    struct ocean *o = make(n, threads, wisdom, 1);
    if (!o)
        return;
    size_t nn = (size_t)n * n;
    fftwf_complex *in[4], *out = fftwf_malloc(nn * sizeof *out);
    for (int i = 0; i < 4; i++)
        in[i] = fftwf_malloc(nn * sizeof *in[i]);
    float *real = fftwf_malloc(8 * nn * sizeof(float));
    ocean_fftw_lock();
    if (wisdom)
        fftwf_import_wisdom_from_filename(wisdom);
    fftwf_plan_with_nthreads(threads);
    fftwf_plan c2c = fftwf_plan_dft_2d(n, n, in[0], out, FFTW_BACKWARD, FFTW_MEASURE | FFTW_DESTROY_INPUT);
    fftwf_plan c2r = fftwf_plan_dft_c2r_2d(n, n, in[0], real, FFTW_MEASURE);
    if (wisdom)
        fftwf_export_wisdom_to_filename(wisdom);
    ocean_fftw_unlock();
    for (int i = 0; i < 4; i++)
        memset(in[i], 0, nn * sizeof *in[i]);
    int reps = reps_for(n);
    double *pt = malloc(reps * sizeof *pt), *ct = malloc(reps * sizeof *ct), *ft = malloc(reps * sizeof *ft),
           *rt = malloc(reps * sizeof *rt);
    ocean_step(o, 0.5, OCEAN_ALL_FIELDS);
    for (int r = 0; r < reps; r++) {
        double t0 = now_ms();
        for (int i = 0; i < 4; i++) {
            fftwf_execute_dft(c2c, in[i], out);
            float *a = real + (size_t)(2 * i) * nn, *b = a + nn;
            const float *z = (const float *)out;
            for (size_t j = 0; j < nn; j++) {
                a[j] = z[2 * j];
                b[j] = z[2 * j + 1];
            }
        }
        double t1 = now_ms();
        for (int i = 0; i < 4; i++)
            fftwf_execute_dft(c2c, in[i], out);
        double t2 = now_ms();
        ocean_fft_only(o, OCEAN_ALL_FIELDS);
        double t3 = now_ms();
        for (int i = 0; i < 8; i++)
            fftwf_execute_dft_c2r(c2r, in[i / 2], real + (size_t)i * nn);
        double t4 = now_ms();
        pt[r] = t1 - t0;
        ft[r] = t2 - t1;
        ct[r] = t3 - t2;
        rt[r] = t4 - t3;
    }
    double p = median(pt, reps), f = median(ft, reps), c = median(ct, reps), r2 = median(rt, reps);
    printf("{\"bench\":\"pack_vs_c2r\",\"N\":%d,\"threads\":%d,\"split_c2r_ms\":%.3f,\"c2r_2d_x8_ms\":%.3f,"
           "\"c2c_2d_x4_ms\":%.3f,\"c2c_2d_x4_split_ms\":%.3f}\n", n, threads, c, r2, f, p);
    fflush(stdout);
    ocean_fftw_lock();
    fftwf_destroy_plan(c2c);
    fftwf_destroy_plan(c2r);
    ocean_fftw_unlock();
    for (int i = 0; i < 4; i++)
        fftwf_free(in[i]);
    fftwf_free(out);
    fftwf_free(real);
    free(pt);
    free(ct);
    free(ft);
    free(rt);
    ocean_free(o);
}

/* Why the transposition between the z and the row pass is an FFTW rank-0
 * plan (ocean_grid.c, store_plan), and why the spectrum between the passes is
 * block-major. One spectrum's two passes (N/2 columns, N rows), one
 * thread, process CPU time, four ways:
 *   ours:      z pass in place on a contiguous tile, then the copy into the
 *              block-major spectrum (FFTW rank-0 guru plan), then the row
 *              c2r reading blocks of 8 interleaved rows;
 *   ours with the copy as our own loop (memcpy of 8 complex per column),
 *              the alternative to the FFTW copy plan; copy_only_* time the copy alone;
 *   colmajor:  FFTW's z pass out of place straight into a column-major
 *              spectrum, row c2r reading it with input stride N;
 *   rowmajor:  FFTW's z pass out of place into a row-major spectrum (output
 *              stride N/2+1), row c2r over contiguous rows.
 * The last two put the whole transposition inside FFTW's transforms. */
static void bench_layout(int n, const char *wisdom)
{
    const int T = 16, B = OCEAN_ROW_BLOCK, nh = n / 2 + 1, sd = ocean_tile_dist(n);
    float *tile = fftwf_malloc(sizeof(float) * 2 * T * sd);
    fftwf_complex *col = fftwf_malloc(sizeof(fftwf_complex) * (size_t)n * nh);
    float *out = fftwf_malloc(sizeof(float) * (size_t)n * n);
    unsigned fl = FFTW_MEASURE;
    fftwf_iodim store_dims[3] = {{T, sd, B}, {n / B, B, nh * B}, {B, 1, 1}};
    ocean_fftw_init();
    ocean_fftw_lock();
    if (wisdom)
        fftwf_import_wisdom_from_filename(wisdom);
    fftwf_plan_with_nthreads(1);
    fftwf_plan z_in = fftwf_plan_many_dft(1, &n, T, (fftwf_complex *)tile, NULL, 1, sd, (fftwf_complex *)tile, NULL,
                                          1, sd, FFTW_BACKWARD, fl);
    fftwf_plan copy = fftwf_plan_guru_dft(0, NULL, 3, store_dims, (fftwf_complex *)tile, col, FFTW_BACKWARD, fl);
    fftwf_plan r_blk = fftwf_plan_many_dft_c2r(1, &n, B, col, NULL, B, 1, out, NULL, 1, n, fl);
    fftwf_plan z_cm = fftwf_plan_many_dft(1, &n, T, (fftwf_complex *)tile, NULL, 1, sd, col, NULL, 1, n,
                                          FFTW_BACKWARD, fl);
    fftwf_plan r_cm = fftwf_plan_many_dft_c2r(1, &n, B, col, NULL, n, 1, out, NULL, 1, n, fl);
    fftwf_plan z_rm = fftwf_plan_many_dft(1, &n, T, (fftwf_complex *)tile, NULL, 1, sd, col, NULL, nh, 1,
                                          FFTW_BACKWARD, fl);
    fftwf_plan r_rm = fftwf_plan_many_dft_c2r(1, &n, B, col, NULL, 1, nh, out, NULL, 1, n, fl);
    if (wisdom)
        fftwf_export_wisdom_to_filename(wisdom);
    ocean_fftw_unlock();
    memset(tile, 0, sizeof(float) * 2 * T * sd);
    memset(col, 0, sizeof(fftwf_complex) * (size_t)n * nh);
    int reps = reps_for(n);
    double *v[6];
    for (int i = 0; i < 6; i++)
        v[i] = malloc(reps * sizeof(double));
    for (int r = 0; r < reps; r++) {
        double c0 = cpu_ms();
        for (int tl = 0; tl < n / 2 / T; tl++) {
            fftwf_execute_dft(z_in, (fftwf_complex *)tile, (fftwf_complex *)tile);
            fftwf_execute_dft(copy, (fftwf_complex *)tile, col + (size_t)tl * T * B);
        }
        for (int b = 0; b < n / B; b++)
            fftwf_execute_dft_c2r(r_blk, col + (size_t)b * nh * B, out + (size_t)b * B * n);
        double c1 = cpu_ms();
        for (int tl = 0; tl < n / 2 / T; tl++) {
            fftwf_execute_dft(z_in, (fftwf_complex *)tile, (fftwf_complex *)tile);
            for (int b = 0; b < n / B; b++) {
                float *dst = (float *)col + 2 * (((size_t)b * nh + tl * T) * B);
                for (int j = 0; j < T; j++)
                    memcpy(dst + 2 * j * B, tile + 2 * ((size_t)j * sd + b * B), 2 * B * sizeof(float));
            }
        }
        for (int b = 0; b < n / B; b++)
            fftwf_execute_dft_c2r(r_blk, col + (size_t)b * nh * B, out + (size_t)b * B * n);
        double c2 = cpu_ms();
        for (int tl = 0; tl < n / 2 / T; tl++)
            fftwf_execute_dft(z_cm, (fftwf_complex *)tile, col + (size_t)tl * T * n);
        for (int b = 0; b < n / B; b++)
            fftwf_execute_dft_c2r(r_cm, col + (size_t)b * B, out + (size_t)b * B * n);
        double c3 = cpu_ms();
        for (int tl = 0; tl < n / 2 / T; tl++)
            fftwf_execute_dft(z_rm, (fftwf_complex *)tile, col + tl * T);
        for (int b = 0; b < n / B; b++)
            fftwf_execute_dft_c2r(r_rm, col + (size_t)b * B * nh, out + (size_t)b * B * n);
        double c4 = cpu_ms();
        for (int tl = 0; tl < n / 2 / T; tl++)
            fftwf_execute_dft(copy, (fftwf_complex *)tile, col + (size_t)tl * T * B);
        double c5 = cpu_ms();
        for (int tl = 0; tl < n / 2 / T; tl++)
            for (int b = 0; b < n / B; b++) {
                float *dst = (float *)col + 2 * (((size_t)b * nh + tl * T) * B);
                for (int j = 0; j < T; j++)
                    memcpy(dst + 2 * j * B, tile + 2 * ((size_t)j * sd + b * B), 2 * B * sizeof(float));
            }
        double c6 = cpu_ms();
        v[0][r] = c1 - c0;
        v[1][r] = c2 - c1;
        v[2][r] = c3 - c2;
        v[3][r] = c4 - c3;
        v[4][r] = c5 - c4;
        v[5][r] = c6 - c5;
    }
    printf("{\"bench\":\"z_to_rows\",\"N\":%d,\"threads\":1,\"ours_fftw_copy_cpu_ms\":%.3f,"
           "\"ours_own_copy_cpu_ms\":%.3f,\"colmajor_cpu_ms\":%.3f,\"rowmajor_cpu_ms\":%.3f,"
           "\"copy_only_fftw_cpu_ms\":%.3f,\"copy_only_own_cpu_ms\":%.3f}\n", n, median(v[0], reps),
           median(v[1], reps), median(v[2], reps), median(v[3], reps), median(v[4], reps), median(v[5], reps));
    fflush(stdout);
    for (int i = 0; i < 6; i++)
        free(v[i]);
    ocean_fftw_lock();
    fftwf_plan plans[] = {z_in, copy, r_blk, z_cm, r_cm, z_rm, r_rm};
    for (size_t i = 0; i < sizeof plans / sizeof plans[0]; i++)
        fftwf_destroy_plan(plans[i]);
    ocean_fftw_unlock();
    fftwf_free(tile);
    fftwf_free(col);
    fftwf_free(out);
}

/* A parameter change at the same N (wind speed, alternating), three ways:
 * ocean_reconfigure on the stepping thread (its pool), ocean_prepare (what
 * a builder thread runs; its own workers) followed by the O(1)
 * ocean_commit, and a whole new ocean_create with the same wisdom (what
 * the daemon's builder did per batch before ocean_prepare existed). */
static void bench_reconfigure(int n, int threads, const char *wisdom)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = n;
    p.cascades = 1; /* as make() */
    struct ocean *o = make(n, threads, wisdom, 1);
    if (!o)
        return;
    int reps = n <= 256 ? 21 : n <= 512 ? 11 : 7;
    double *rt = malloc(reps * sizeof *rt), *rc = malloc(reps * sizeof *rc), *pt = malloc(reps * sizeof *pt),
           *ct = malloc(reps * sizeof *ct), *commit = malloc(reps * sizeof *commit);
    char err[256];
    ocean_step(o, 0.5, OCEAN_ALL_FIELDS);
    for (int r = 0; r < reps; r++) {
        p.wind_speed = r % 2 ? 10.0 : 12.0;
        double c0 = cpu_ms(), t0 = now_ms();
        ocean_reconfigure(o, &p, err, sizeof err);
        double t1 = now_ms(), c1 = cpu_ms();
        p.wind_speed = r % 2 ? 11.0 : 13.0;
        struct ocean_prepared *pr = ocean_prepare(o, &p, err, sizeof err);
        double t2 = now_ms();
        ocean_commit(o, pr);
        double t3 = now_ms();
        ocean_prepared_free(pr);
        double t4 = now_ms();
        struct ocean *fresh = make(n, threads, wisdom, 1);
        double t5 = now_ms();
        ocean_free(fresh);
        rt[r] = t1 - t0;
        rc[r] = c1 - c0;
        pt[r] = t2 - t1;
        commit[r] = t3 - t2;
        ct[r] = t5 - t4;
    }
    printf("{\"bench\":\"reconfigure\",\"N\":%d,\"threads\":%d,\"change\":\"wind_speed\",\"ms\":%.3f,"
           "\"cpu_ms\":%.3f,\"prepare_ms\":%.3f,\"commit_ms\":%.4f,\"create_ms\":%.3f,\"reps\":%d}\n", n, threads,
           median(rt, reps), median(rc, reps), median(pt, reps), median(commit, reps), median(ct, reps), reps);
    fflush(stdout);
    free(rt);
    free(rc);
    free(pt);
    free(ct);
    free(commit);
    ocean_free(o);
}

static void bench_dft(int n, const char *wisdom)
{
    struct ocean *o = make(n, 1, wisdom, 1);
    if (!o)
        return;
    int dreps = n <= 16 ? 21 : n <= 32 ? 5 : n <= 64 ? 3 : 1, freps = 201;
    double *dt = malloc(dreps * sizeof *dt), *ft = malloc(freps * sizeof *ft);
    for (int r = 0; r < dreps; r++) {
        double t0 = now_ms();
        ocean_step_dft(o, 1.0 + r, OCEAN_ALL_FIELDS);
        dt[r] = now_ms() - t0;
    }
    for (int r = 0; r < freps; r++) {
        double t0 = now_ms();
        ocean_step_fft(o, 1.0 + r, OCEAN_ALL_FIELDS);
        ft[r] = now_ms() - t0;
    }
    double d = median(dt, dreps), f = median(ft, freps);
    printf("{\"bench\":\"dft_vs_fft\",\"N\":%d,\"threads\":1,\"fields\":\"all\",\"dft_ms\":%.3f,\"fft_ms\":%.4f,"
           "\"speedup\":%.0f,\"dft_reps\":%d}\n", n, d, f, d / f, dreps);
    fflush(stdout);
    free(dt);
    free(ft);
    ocean_free(o);
}

/* Cascades: step CPU time for 1..4 cascades (every cascade stepped with the
 * fields a client draws: height, dx, dz, slopes), interleaved per
 * repetition so that the shared machine's load hits all counts alike. */
static void bench_cascades(int n, const char *wisdom)
{
    struct ocean *o[OCEAN_MAX_CASCADES];
    int reps = reps_for(n);
    const unsigned fields = OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX) | OCEAN_FIELD_BIT(OCEAN_DZ) |
                            OCEAN_FIELD_BIT(OCEAN_SLOPE_X) | OCEAN_FIELD_BIT(OCEAN_SLOPE_Z);
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++) {
        struct ocean_params p;
        params_defaults(&p);
        p.resolution = n;
        p.cascades = c + 1;
        struct ocean_options opt = {1, wisdom, 1};
        char err[256];
        o[c] = ocean_create(&p, &opt, err, sizeof err);
        if (!o[c]) {
            fprintf(stderr, "bench_step: cascades %d: %s\n", c + 1, err);
            for (int k = 0; k < c; k++)
                ocean_free(o[k]);
            return;
        }
        ocean_step(o[c], 0.5, fields);
    }
    double *cpu = malloc((size_t)reps * OCEAN_MAX_CASCADES * sizeof *cpu);
    for (int r = 0; r < reps; r++)
        for (int c = 0; c < OCEAN_MAX_CASCADES; c++) {
            double c0 = cpu_ms();
            ocean_step(o[c], 1.0 + r * 0.033, fields);
            cpu[c * reps + r] = cpu_ms() - c0;
        }
    double one = median(cpu, reps);
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++) {
        double m = median(cpu + c * reps, reps);
        printf("{\"bench\":\"cascades\",\"N\":%d,\"threads\":1,\"cascades\":%d,\"fields\":\"height,dx,dz,slopes\","
               "\"step_cpu_ms\":%.3f,\"vs_one\":%.2f,\"reps\":%d}\n", n, c + 1, m, m / one, reps);
        ocean_free(o[c]);
    }
    fflush(stdout);
    free(cpu);
}

/* Where a step's time beyond FFTW's goes, one thread, process CPU time,
 * all variants interleaved per repetition on the same ocean:
 *   step (all fields and foam), fftw (only the FFTW executes); fill,
 *   spectra, factors, jacobian: what the six-field step (no foam) loses
 *   without that part of our own work (ocean_step_parts); foam: the step
 *   minus the six-field step; terms_whole: the step with the Jacobian's
 *   three terms written as whole N x N fields and combined afterwards (the
 *   simple layout) instead of in the worker's cache-sized
 *   scratch. The parts are differences of two timings: on a shared machine
 *   the fastest repetition of each variant (min) is the least noisy, so
 *   the parts use that; step/fftw also give medians. own_sum: the parts'
 *   sum; the rest of step - fftw is cache our passes take from FFTW's. */
static void bench_parts(int n, const char *wisdom)
{
    struct ocean *o = make(n, 1, wisdom, 1);
    if (!o)
        return;
    if (ocean_keep_jacobian_terms(o) != 0) {
        ocean_free(o);
        return;
    }
    float *whole[3]; /* toggled: the whole-field terms only in V_WHOLE */
    for (int k = 0; k < 3; k++) {
        whole[k] = o->g->jac[k];
        o->g->jac[k] = NULL;
    }
    enum { V_STEP, V_NOFOAM, V_FFTW, V_FILL, V_SPECTRA, V_FACTORS, V_JAC, V_WHOLE, V_COUNT };
    static const unsigned skip[V_COUNT] = {0, 0, OCEAN_SKIP_ALL, OCEAN_SKIP_FILL, OCEAN_SKIP_SPECTRA,
                                           OCEAN_SKIP_FACTORS, OCEAN_SKIP_JACOBIAN, 0};
    const unsigned six = OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM);
    int reps = 2 * reps_for(n) + 1;
    double *v[V_COUNT], lo[V_COUNT];
    for (int k = 0; k < V_COUNT; k++) {
        v[k] = malloc(reps * sizeof *v[k]);
        lo[k] = 1e300;
    }
    ocean_step(o, 0.5, OCEAN_ALL_FIELDS);
    for (int r = 0; r < reps; r++) {
        double t = 1.0 + r * 0.033;
        for (int k = 0; k < V_COUNT; k++) {
            for (int j = 0; j < 3; j++)
                o->g->jac[j] = k == V_WHOLE ? whole[j] : NULL;
            double c0 = cpu_ms();
            if (k == V_STEP || k == V_WHOLE)
                ocean_step(o, t, OCEAN_ALL_FIELDS);
            else
                ocean_step_parts(o, t, six, skip[k]);
            v[k][r] = cpu_ms() - c0;
            lo[k] = v[k][r] < lo[k] ? v[k][r] : lo[k];
        }
    }
    for (int j = 0; j < 3; j++)
        o->g->jac[j] = whole[j];
    double ms = median(v[V_STEP], reps), mf = median(v[V_FFTW], reps), mw = median(v[V_WHOLE], reps);
    double nf = lo[V_NOFOAM], part[5] = {nf - lo[V_FILL], nf - lo[V_SPECTRA], nf - lo[V_FACTORS], nf - lo[V_JAC],
                                         lo[V_STEP] - nf};
    printf("{\"bench\":\"step_parts\",\"N\":%d,\"threads\":1,\"step_cpu_ms\":%.3f,\"fftw_cpu_ms\":%.3f,"
           "\"cpu_ratio\":%.3f,\"terms_whole_cpu_ms\":%.3f,\"terms_whole_ratio\":%.3f,\"min_step_ms\":%.3f,"
           "\"min_fftw_ms\":%.3f,\"min_ratio\":%.3f,\"min_terms_whole_ratio\":%.3f,\"fill_ms\":%.3f,"
           "\"spectra_ms\":%.3f,\"factors_ms\":%.3f,\"jacobian_ms\":%.3f,\"foam_ms\":%.3f,\"own_sum_ms\":%.3f,"
           "\"own_ms\":%.3f,\"reps\":%d}\n",
           n, ms, mf, ms / mf, mw, mw / mf, lo[V_STEP], lo[V_FFTW], lo[V_STEP] / lo[V_FFTW], lo[V_WHOLE] / lo[V_FFTW],
           part[0], part[1], part[2], part[3], part[4], part[0] + part[1] + part[2] + part[3] + part[4],
           lo[V_STEP] - lo[V_FFTW], reps);
    fflush(stdout);
    for (int k = 0; k < V_COUNT; k++)
        free(v[k]);
    ocean_free(o);
}

/* What one `set` of the wind costs the daemon's builder at N (load.py's
 * client sends one every 0.3 s after the previous is answered): ocean_prepare
 * of every cascade in force, the query snapshot of the prepared state, the
 * commit and freeing the old state; process CPU (the builder's prepare pool
 * has `threads` threads) and wall, medians. malloc as the daemon sets it up
 * (sim_start: fixed 128 KB mmap threshold, so each amplitude array is a
 * fresh mapping whose pages the kernel clears on first touch). */
static void bench_set(int n, int cascades, const char *wisdom)
{
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = n;
    p.cascades = cascades;
    struct ocean_options opt = {2, wisdom, 1};
    char err[256];
    struct ocean *o = ocean_create(&p, &opt, err, sizeof err);
    if (!o) {
        fprintf(stderr, "bench_step: N=%d: %s\n", n, err);
        return;
    }
    enum { REPS = 7 };
    double pw[REPS], pc[REPS], sw[REPS], sc[REPS], tw[REPS], tc[REPS];
    for (int r = 0; r < REPS; r++) {
        p.wind_speed = r % 2 ? 11.0 : 12.0;
        double c0 = cpu_ms(), t0 = now_ms();
        struct ocean_prepared *pr = ocean_prepare(o, &p, err, sizeof err);
        double t1 = now_ms(), c1 = cpu_ms();
        struct ocean_surface *surf = pr ? ocean_prepared_surface(o, pr, err, sizeof err) : NULL;
        double t2 = now_ms(), c2 = cpu_ms();
        if (pr)
            ocean_commit(o, pr);
        ocean_prepared_free(pr);
        ocean_surface_free(surf);
        double t3 = now_ms(), c3 = cpu_ms();
        pw[r] = t1 - t0;
        pc[r] = c1 - c0;
        sw[r] = t2 - t1;
        sc[r] = c2 - c1;
        tw[r] = t3 - t0;
        tc[r] = c3 - c0;
    }
    printf("{\"bench\":\"capacity_set\",\"N\":%d,\"cascades\":%d,\"threads\":2,\"prepare_ms\":%.2f,"
           "\"prepare_cpu_ms\":%.2f,\"snapshot_ms\":%.2f,\"snapshot_cpu_ms\":%.2f,\"total_ms\":%.2f,"
           "\"total_cpu_ms\":%.2f,\"reps\":%d}\n", n, cascades, median(pw, REPS), median(pc, REPS), median(sw, REPS),
           median(sc, REPS), median(tw, REPS), median(tc, REPS), REPS);
    fflush(stdout);
    ocean_free(o);
}

/* The capacity rows (bench/load.py --capacity, docs/daemon.md): the step exactly as
 * the daemon's producer runs it for one client's fields (cascade 0 only,
 * ocean_step_cascades, no foam unless asked; default parameters, so three
 * cascades exist but only cascade 0 is stepped), against the bare FFTW
 * executes of those fields (ocean_fft_only: same plans, arrays, threads),
 * interleaved, on 1 and 2 threads. The tick's CPU budget on this machine is
 * cores x period (2 x 33.3 ms at 30 Hz): fftw_share_of_budget says how much
 * of it FFTW alone takes at 30 frames/s, before any fill or encode. */
static void bench_rows(const char *wisdom)
{
    const unsigned H = OCEAN_FIELD_BIT(OCEAN_HEIGHT),
                   HDD = H | OCEAN_FIELD_BIT(OCEAN_DX) | OCEAN_FIELD_BIT(OCEAN_DZ),
                   SIX = OCEAN_ALL_FIELDS & ~OCEAN_FIELD_BIT(OCEAN_FOAM);
    static const struct { int n; unsigned fields; const char *name; } rows[] = {
        {512, 0, "six"}, {1024, 0, "h,dx,dz"}, {1024, 0, "six"}, {2048, 0, "height"}, {2048, 0, "h,dx,dz"},
    };
    const unsigned masks[] = {SIX, HDD, SIX, H, HDD};
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    const double budget_cpu_ms = (double)cores * 1000.0 / 30.0;
    for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++)
        for (int threads = 1; threads <= 2; threads++) {
            struct ocean *o = make_cascades(rows[i].n, threads, wisdom, 1, 3); /* the daemon's default */
            if (!o)
                continue;
            unsigned f[OCEAN_MAX_CASCADES] = {masks[i]};
            int reps = 2 * reps_for(rows[i].n) + 1;
            double *sw = malloc(reps * sizeof *sw), *sc = malloc(reps * sizeof *sc), *fw = malloc(reps * sizeof *fw),
                   *fc = malloc(reps * sizeof *fc);
            ocean_step_cascades(o, 0.5, f, OCEAN_MAX_CASCADES);
            for (int r = 0; r < reps; r++) {
                double c0 = cpu_ms(), t0 = now_ms();
                ocean_step_cascades(o, 1.0 + r * 0.033, f, OCEAN_MAX_CASCADES);
                double t1 = now_ms(), c1 = cpu_ms();
                ocean_fft_only(o, masks[i]);
                double t2 = now_ms(), c2 = cpu_ms();
                sw[r] = t1 - t0;
                sc[r] = c1 - c0;
                fw[r] = t2 - t1;
                fc[r] = c2 - c1;
            }
            double msw = median(sw, reps), msc = median(sc, reps), mfw = median(fw, reps), mfc = median(fc, reps);
            printf("{\"bench\":\"capacity_row\",\"N\":%d,\"fields\":\"%s\",\"threads\":%d,\"step_ms\":%.3f,"
                   "\"step_cpu_ms\":%.3f,\"fftw_ms\":%.3f,\"fftw_cpu_ms\":%.3f,\"cpu_ratio\":%.3f,"
                   "\"step_min_ms\":%.3f,\"fftw_min_ms\":%.3f,\"budget_cpu_ms\":%.1f,"
                   "\"fftw_share_of_budget\":%.3f,\"step_share_of_budget\":%.3f,\"reps\":%d}\n",
                   rows[i].n, rows[i].name, threads, msw, msc, mfw, mfc, msc / mfc, sw[0], fw[0], budget_cpu_ms,
                   mfc / budget_cpu_ms, msc / budget_cpu_ms, reps);
            fflush(stdout);
            free(sw);
            free(sc);
            free(fw);
            free(fc);
            ocean_free(o);
        }
}

int main(int argc, char **argv)
{
    if (argc > 1 && argv[1][0] == '-') { /* it is a path: "--help" once became a wisdom file of that name */
        fprintf(stderr, "usage: bench_step [WISDOM_FILE|\"\"] [step|parts|store|rows_half|pack|layout|reconfigure|dft|cascades]\n");
        return argv[1][1] == 'h' || !strcmp(argv[1], "--help") ? 0 : 2;
    }
    const char *wisdom = argc > 1 && *argv[1] ? argv[1] : NULL;
    const char *only = argc > 2 ? argv[2] : NULL; /* one group: step, parts, store, rows_half, pack, layout, reconfigure, dft, cascades */
#define WANT(name) (!only || strcmp(only, name) == 0)
    /* The machine is shared: say how busy it was. */
    double load[3] = {0, 0, 0};
    FILE *la = fopen("/proc/loadavg", "r");
    if (la) {
        if (fscanf(la, "%lf %lf %lf", &load[0], &load[1], &load[2]) != 3)
            load[0] = -1;
        fclose(la);
    }
    printf("{\"bench\":\"env\",\"cpus\":%ld,\"loadavg_1min\":%.2f,\"wisdom\":\"%s\"}\n",
           sysconf(_SC_NPROCESSORS_ONLN), load[0], wisdom ? wisdom : "");
    /* Thread scaling: 1, 2, 4, ... up to the machine's cores (at least 1 and 2). */
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    int max_threads = cores > 2 ? (cores < OCEAN_MAX_THREADS ? (int)cores : OCEAN_MAX_THREADS) : 2;
    for (int n = 64; n <= 2048 && WANT("step"); n *= 2)
        for (int threads = 1; threads <= max_threads; threads *= 2)
            bench_step(n, threads, wisdom);
    for (int n = 256; n <= 2048 && WANT("parts"); n *= 2)
        bench_parts(n, wisdom);
    for (int n = 256; n <= 2048 && WANT("store"); n *= 2)
        for (int threads = 1; threads <= 2; threads++)
            bench_two_ways(n, threads, wisdom, "store", OCEAN_STORE_FFTW, OCEAN_STORE_STREAMING,
                           n >= OCEAN_STREAM_STORE_FROM_N);
    for (int n = 64; n <= 2048 && WANT("rows_half"); n *= 2)
        for (int threads = 1; threads <= 2; threads++)
            bench_two_ways(n, threads, wisdom, "rows_half", OCEAN_ROWS_C2R, 0, true);
    for (int n = 256; n <= 1024 && WANT("pack"); n *= 4)
        for (int threads = 1; threads <= 2; threads++)
            bench_pack(n, threads, wisdom);
    for (int n = 256; n <= 2048 && WANT("layout"); n *= 2)
        bench_layout(n, wisdom);
    for (int n = 256; n <= 1024 && WANT("reconfigure"); n *= 2)
        for (int threads = 1; threads <= 2; threads++)
            bench_reconfigure(n, threads, wisdom);
    for (int n = 16; n <= 128 && WANT("dft"); n *= 2)
        bench_dft(n, wisdom);
    for (int n = 256; n <= 512 && WANT("cascades"); n *= 2)
        bench_cascades(n, wisdom);
    if (WANT("rows"))
        bench_rows(wisdom);
    if (WANT("rows") || WANT("sets")) {
        mallopt(M_MMAP_THRESHOLD, 128 * 1024); /* as sim_start (server/sim_thread.c) */
        mallopt(M_TRIM_THRESHOLD, 256 * 1024);
        for (int n = 512; n <= 2048; n *= 2)
            for (int c = 1; c <= 3; c += 2)
                bench_set(n, c, wisdom);
    }
    return 0;
}

/* ocean_internal.h — the inside of struct ocean, shared by ocean*.c, the
 * tests and the benchmark. Not part of the daemon's contract (ocean.h). */
#ifndef OCEAND_OCEAN_INTERNAL_H
#define OCEAND_OCEAN_INTERNAL_H

#include <complex.h>
#include <fftw3.h>

#include "ocean.h"
#include "ocean_spectrum.h"

/* The real fields that go through an inverse FFT. Output fields map onto
 * them; the Jacobian needs three (dDx/dx, dDz/dz, dDx/dz = dDz/dx). */
enum ocean_transform { TR_H, TR_DX, TR_DZ, TR_SX, TR_SZ, TR_JXX, TR_JZZ, TR_JXZ, TR_COUNT };

/* The 2-D inverse FFT is done as two 1-D passes: along z (columns, one per
 * kx), then along x (rows, c2r). A factor that depends on kx only commutes
 * with the z pass, so the eight fields need only five z passes, over these
 * spectra (constants folded in); the kx factor is applied before the row pass:
 *   COL_H       h~              -> height (1), slope_x (i kx)
 *   COL_KZ      i kz h~         -> slope_z (1)
 *   COL_INVK    lambda h~/k     -> Dx (i kx), dDx/dx (-kx^2)
 *   COL_KZINVK  i lambda kz h~/k -> Dz (1), dDx/dz (i kx)
 *   COL_KZ2INVK -lambda kz^2 h~/k -> dDz/dz (1) */
enum ocean_column { COL_H, COL_KZ, COL_INVK, COL_KZINVK, COL_KZ2INVK, COL_COUNT };
#define OCEAN_ROW_BLOCK 16   /* rows per c2r batch: a block stays in cache */
#define OCEAN_MAX_THREADS 64
#define OCEAN_THREADS_FROM_N 256 /* smaller grids run on one thread: faster */

/* Everything whose size depends on N: made together, swapped together. */
struct ocean_grid {
    int n, nh;                 /* N, N/2 + 1 (columns of the half spectrum) */
    size_t modes;              /* n * nh */
    /* Per mode of the half spectrum (row iz = kz index, column ix = kx index
     * 0..N/2), from h~0(k) = p and conj(h~0(-k)) = m:
     *   hr = a c + b s, hi = d c - e s, with c, s = cos, sin(w t)
     * a = pr + mr, b = pi - mi, d = pi + mi, e = pr - mr. */
    float *a, *b, *d, *e;
    double *omega;             /* rad/s, per mode */
    float *kx, *kz;            /* rad/m, per column / per row (layout formula) */
    float *col[COL_COUNT];     /* half spectra (N rows x nh), interleaved complex */
    float *out[OCEAN_FIELD_COUNT];
    float *jac[3];             /* dDx/dx, dDz/dz, dDx/dz before combining */
    float *rowbuf;             /* per worker: OCEAN_ROW_BLOCK rows of c2r input */
    int workers;               /* rowbuf slots */
    fftwf_plan col_plan;       /* in place, N-point c2c along z, nh of them (FFTW threads) */
    fftwf_plan row_plan;       /* OCEAN_ROW_BLOCK N-point c2r along x (one thread each) */
};

struct ocean {
    struct ocean_params p;
    struct ocean_options opt;  /* opt.wisdom_path points at our own copy */
    char *wisdom_path;
    struct spectrum_model model;
    struct ocean_grid *g;
};

/* Transforms needed for an OCEAN_FIELD_BIT mask. */
unsigned ocean_transforms_for(unsigned fields);

/* The FFT path and the brute-force path, whatever p.transform says. */
int ocean_step_fft(struct ocean *o, double t, unsigned fields);
int ocean_step_dft(struct ocean *o, double t, unsigned fields);
/* Only the FFTW executes the step for these fields would run, on whatever
 * the buffers hold (benchmark). */
void ocean_fft_only(struct ocean *o, unsigned fields);

/* Reference spectrum of transform tr at time t over the full N x N grid,
 * out[iz*N + ix] for k = (kx(ix), kz(iz)), computed in double from the
 * spectrum model (independently of the fast path's stored amplitudes). */
void ocean_reference_spectrum(const struct ocean *o, double t, enum ocean_transform tr,
                              double complex *out);
/* Time at which the phases are evaluated: t, or t wrapped into
 * [0, loop_period) so that a looping sea is exactly periodic. */
double ocean_phase_time(const struct ocean *o, double t);
/* out[JACOBIAN] = (1 + dDx/dx)(1 + dDz/dz) - (dDx/dz)^2 from g->jac, rows [r0, r1). */
void ocean_combine_jacobian_rows(struct ocean_grid *g, int r0, int r1);
/* Output array that transform tr lands in. */
float *ocean_transform_dest(struct ocean_grid *g, enum ocean_transform tr);
/* Run fn(ctx, row0, row1, worker) over rows [0, rows) on `threads`
 * threads; worker is 0..threads-1, distinct per concurrent call. */
void ocean_parallel_rows(int threads, int rows, void (*fn)(void *ctx, int r0, int r1, int worker), void *ctx);

/* Wavenumber of index i on an N grid of side L: 2 pi (i - N [i > N/2]) / L. */
double ocean_wavenumber(int i, int n, double patch);

/* ocean_fftw.c: once-per-process FFTW threads setup and the lock that
 * serialises planning and wisdom I/O (FFTW's planner is global state). */
void ocean_fftw_init(void);
void ocean_fftw_lock(void);
void ocean_fftw_unlock(void);

#endif

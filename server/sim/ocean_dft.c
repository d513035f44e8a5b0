/* ocean_dft.c — the brute-force path: the same sums, evaluated directly.
 *
 * field(x, z) = sum over all N*N wavenumbers k of F~(k) e^{i(kx x + kz z)},
 * O(N^4), in double precision from a spectrum computed afresh from the
 * model (double sin/cos, amplitudes recomputed). It is the reference the
 * tests hold the FFT path to, the thesis's "DFT" switch, and the DFT
 * column of the benchmark. */
#include <math.h>
#include <stdlib.h>

#include "ocean_internal.h"

void ocean_reference_spectrum(const struct ocean *o, double t, enum ocean_transform tr,
                              double complex *out)
{
    ocean_reference_spectrum_of(o, o->g, &o->model, t, tr, out);
}

void ocean_reference_spectrum_of(const struct ocean *o, const struct ocean_grid *g, const struct spectrum_model *m,
                                 double t, enum ocean_transform tr, double complex *out)
{
    const int n = g->n;
    /* Not wrapped into the loop period, unlike the FFT path: the reference
     * is the plain definition, so the tests see whether wrapping is exact. */
    const double L = m->patch, lam = o->p.choppiness, tt = t;
    for (int iz = 0; iz < n; iz++) {
        for (int ix = 0; ix < n; ix++) {
            double complex *dst = &out[(size_t)iz * n + ix];
            if (ix == n / 2 || iz == n / 2) { /* Nyquist: zero, as on the FFT path */
                *dst = 0;
                continue;
            }
            int mx = ix > n / 2 ? ix - n : ix, mz = iz > n / 2 ? iz - n : iz;
            double kx = ocean_wavenumber(ix, n, L), kz = ocean_wavenumber(iz, n, L);
            double k = hypot(kx, kz);
            double w = spectrum_mode_omega(m, k);
            double complex e = cexp(-I * w * tt);
            double complex h = spectrum_h0(m, mx, mz) * e + conj(spectrum_h0(m, -mx, -mz)) * conj(e);
            double ik = displacement_over_k(k, m->depth); /* coth(kd)/k */
            switch (tr) {
            case TR_H: *dst = h; break;
            case TR_DX: *dst = I * lam * kx * ik * h; break;
            case TR_DZ: *dst = I * lam * kz * ik * h; break;
            case TR_SX: *dst = I * kx * h; break;
            case TR_SZ: *dst = I * kz * h; break;
            case TR_JXX: *dst = -lam * kx * kx * ik * h; break;
            case TR_JZZ: *dst = -lam * kz * kz * ik * h; break;
            case TR_JXZ: *dst = -lam * kx * kz * ik * h; break;
            default: *dst = 0; break;
            }
        }
    }
}

int ocean_step_dft(struct ocean *o, double t, unsigned fields)
{
    return ocean_step_dft_grid(o, o->g, &o->model, t, fields);
}

int ocean_step_dft_grid(struct ocean *o, struct ocean_grid *g, const struct spectrum_model *m, double t,
                        unsigned fields)
{
    const int n = g->n;
    const size_t nn = (size_t)n * n;
    unsigned tm = ocean_transforms_for(fields);
    double complex *spec = malloc(nn * sizeof *spec);
    double complex *w = malloc((size_t)n * sizeof *w);
    /* The Jacobian's three terms: the whole fields if a test keeps them
     * (ocean_keep_jacobian_terms), else a temporary (N <= 64 here). */
    float *tmp = g->jac[0] ? NULL : malloc(3 * nn * sizeof *tmp);
    float *jac[3];
    for (int i = 0; i < 3; i++)
        jac[i] = g->jac[0] ? g->jac[i] : tmp ? tmp + i * nn : NULL;
    if (!spec || !w || !jac[0]) {
        free(spec);
        free(w);
        free(tmp);
        return -1;
    }
    /* e^{i kx x} = e^{2 pi i mx ix / N}: a table indexed by mx*ix mod N. */
    for (int j = 0; j < n; j++)
        w[j] = cexp(2.0 * M_PI * I * j / n);
    for (int tr = 0; tr < TR_COUNT; tr++) {
        if (!(tm & (1u << tr)))
            continue;
        ocean_reference_spectrum_of(o, g, m, t, tr, spec);
        float *dst = tr == TR_JXX ? jac[0] : tr == TR_JZZ ? jac[1] : tr == TR_JXZ ? jac[2]
                   : ocean_transform_dest(g, tr);
        for (int z = 0; z < n; z++) {
            for (int x = 0; x < n; x++) {
                double complex sum = 0;
                for (int kz = 0; kz < n; kz++) {
                    const double complex *row = spec + (size_t)kz * n;
                    int phase_z = kz * z;
                    for (int kx = 0; kx < n; kx++)
                        sum += row[kx] * w[(kx * x + phase_z) & (n - 1)];
                }
                dst[(size_t)z * n + x] = (float)creal(sum);
            }
        }
    }
    if (fields & OCEAN_FIELD_BIT(OCEAN_JACOBIAN))
        ocean_combine_jacobian(g->out[OCEAN_JACOBIAN], jac[0], jac[1], jac[2], nn);
    free(spec);
    free(w);
    free(tmp);
    return 0;
}

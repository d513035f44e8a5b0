/* tap_surface.h — the whole sea from the streamed cascades, on a grid of the
 * user's choosing (PROTOCOL.md §4.1: heights, displacements and slopes add).
 *
 * Each cascade's grid holds a periodic, band-limited signal (no wave at or
 * above its Nyquist wavenumber), so zero-padding its spectrum (FFTW) gives the
 * exact signal on a grid TAP_SURFACE_UPSAMPLE times finer; between those nodes
 * a Catmull-Rom cubic reads it. Output points that are nodes of a cascade's own
 * grid take its samples as they are. The same method as the Python package
 * (proto/python/oceand/surface.py); error against `query`: docs/query.md. */
#ifndef OCEAND_TAP_SURFACE_H
#define OCEAND_TAP_SURFACE_H

#define TAP_SURFACE_UPSAMPLE 4
#define TAP_SURFACE_MAX_FINE 4096 /* side cap of an upsampled grid */

struct tap_surface;

struct tap_surface *tap_surface_new(void);
void tap_surface_free(struct tap_surface *s);

/* One cascade's grid of one field: side*side floats (row = z) over a square
 * patch of side `period` metres. */
struct tap_cascade_grid {
    const float *data;
    int side;
    double period;
};

/* out[j*m + i] = sum over the ncasc grids at (x0 + i*size/m, z0 + j*size/m).
 * bilinear != 0: plain bilinear on the streamed grids instead (to compare).
 * Returns 0, or -1 when out of memory. */
int tap_surface_grid(struct tap_surface *s, const struct tap_cascade_grid *g, int ncasc, int m, double x0, double z0,
                     double size, int bilinear, float *out);

#endif

/* probe.h — the cheap path for probes: surface values at a world point from
 * one tick's height/dx/dz grids of every cascade, by Lanczos-3 (6 x 6 taps)
 * interpolation of each, summed, and Newton inversion of the summed
 * interpolated displacement. Pure (no threads).
 * Accuracy against the exact query (ocean_surface_query): tests/daemon/test_probe.c
 * measures it; docs/query.md has the figures. */
#ifndef OCEAND_PROBE_H
#define OCEAND_PROBE_H

#include <stdint.h>

#include "ocean.h"
#include "query_msg.h"

/* One tick's grids of every cascade c < ncasc (PROTOCOL.md §4.1): N*N
 * row-major each, sample (ix, iz) of cascade c at x = ix L_c/N, z = iz L_c/N.
 * The surface is their sum: heights, displacements and slopes add. */
struct probe_grids {
    int n, ncasc;
    double patch[OCEAN_MAX_CASCADES];                                  /* L_c, m */
    const float *h[OCEAN_MAX_CASCADES], *dx[OCEAN_MAX_CASCADES], *dz[OCEAN_MAX_CASCADES];
};

/* Values at the world point (x, z): height, displacement and normal of the
 * surface point that lands on (x, z), the cascades summed. *guess is the source (x0, z0) to start
 * Newton from (the previous tick's answer; pass the point itself when there
 * is none) and receives the new source. Velocity and acceleration are left
 * to the caller (they need the point's history: probe_derivatives). Returns
 * the Newton steps taken. */
int probe_eval(const struct probe_grids *g, double x, double z, double guess[2], struct probe_value *out);

/* Vertical velocity and acceleration at the newest of three samples h[0]
 * (now), h[1], h[2] (older) taken at times t[0] > t[1] > t[2]: derivatives
 * of the quadratic through them (second order in the tick for v, first for a). */
void probe_derivatives(const double h[3], const double t[3], double *v, double *a);

#endif

/* wakes.h — the layer of dynamic waves that bodies make (no networking).
 *
 * A struct wakes is linear water waves forced by moving pressure patches
 * (each body's footprint), added by the caller to the spectral sea. It is
 * not periodic: it lives in world coordinates, in square regions that
 * follow the bodies (one region per cluster of bodies, bodies far apart get
 * regions of their own), each a grid of n x n samples with an absorbing
 * sponge along its edges, so that what leaves a region is gone, never
 * wrapped. Inside a region every Fourier mode turns exactly at
 * w(k) = sqrt(g k tanh(k D)) over any dt (deep and finite depth alike), and
 * the forcing held over a step is integrated exactly, so a step is
 * unconditionally stable and, with no forcing, the energy never grows
 * (docs/simulation.md, "Wakes").
 *
 * Frames as the sea's and the bodies' (bodies.h): y up, north = +z,
 * east = -x, headings in compass degrees clockwise from north.
 *
 * Threads: one thread at a time per struct wakes; wakes_step may use the
 * layer's own worker threads (options.threads). Deterministic: the same
 * options, steps and sources give the same fields bit for bit, whatever
 * the thread count. */
#ifndef OCEAND_WAKES_H
#define OCEAND_WAKES_H

#include <stddef.h>
#include <stdint.h>

#define WAKES_WORLD_HALF_M 2500.0 /* |x|, |z| <= this: where regions may be (the bodies' world) */
#define WAKES_MAX_REGIONS  64     /* most regions one layer holds */
#define WAKES_STEP_MAX_S   1.0    /* longest dt one wakes_step takes */
#define WAKES_LINGER_S     120.0  /* s a region keeps stepping after its last body left it */
#define WAKES_FOAM_TAU     4.0    /* s, e-folding time of the wake's foam */

struct wakes_options {
    double depth;    /* m, water depth (> 0; >= 1e4 counts as deep); 0 = deep */
    int n;           /* samples along a region's side: a power of two, 32..1024; 0 = 128 */
    double cell;     /* m between samples, 0.05..50; 0 = chosen per region from the length of
                      * the body that opens it (a power of two near length / 6, 0.25..8 m) */
    int sponge;      /* samples of absorbing layer along each edge, 4..n/4; 0 = n/8 */
    int max_regions; /* 1..WAKES_MAX_REGIONS; 0 = 16 */
    int threads;     /* worker threads for a step (regions run in parallel), >= 1; 0 = 1 */
    int displacement; /* nonzero: also keep the horizontal displacement (two more transforms a step) */
    int plan_rigor;  /* 0 = FFTW_ESTIMATE (tests: quick, deterministic plans), 1 = FFTW_MEASURE
                      * (a daemon: planned once at wakes_new, about a second, faster steps) */
};

/* One body as the layer sees it in a step: where it is at the end of the
 * step and how it moves (its footprint swept over the step runs from
 * (x, z) - (vx, vz) dt to (x, z)). The footprint is a smooth patch of
 * pressure p0 exp(-pi (a^2 / length^2 + c^2 / beam^2)) (a along the bow, c
 * across), whose integral, mass * g, is the body's weight:
 * p0 = mass g / (length beam). */
struct wake_source {
    uint32_t id;        /* >= 1; the same body keeps its id (and its region) from step to step */
    double x, z;        /* m, world position */
    double vx, vz;      /* m/s, world velocity over the water */
    double heading_deg; /* compass bearing of the bow */
    double length;      /* m, along the bow, > 0 */
    double beam;        /* m, across, > 0 */
    double mass;        /* kg, >= 0 */
};

/* The layer at one world point (wakes_sample). */
struct wakes_point {
    double height;           /* m, positive up */
    double slope_x, slope_z; /* dh/dx, dh/dz */
    double dx, dz;           /* m, horizontal displacement (0 unless options.displacement) */
    double dhdt;             /* m/s, the height's change over the last step / its dt */
    double foam;             /* 0..1, whitewater the wake left (stern turbulence, steep crests) */
};

/* One region, read-only, valid until the next wakes_step or wakes_free.
 * Sample (ix, iz) of a field is at index iz * n + ix and at world
 * (x0 + ix cell, z0 + iz cell). */
struct wakes_region {
    uint32_t id;            /* >= 1, unique in the layer, never reused */
    int n;
    double cell, x0, z0;
    int sponge;             /* samples of the absorbing edge */
    int sources;            /* bodies forcing it in the last step */
    const float *height, *slope_x, *slope_z, *foam;
    const float *dx, *dz;   /* NULL unless options.displacement */
};

struct wakes;

/* NULL with a message in err on bad options or no memory. */
struct wakes *wakes_new(const struct wakes_options *opt, char *err, size_t errlen);
void wakes_free(struct wakes *w);

/* Advance the layer by dt (0 < dt <= WAKES_STEP_MAX_S) s, forced by the
 * n sources (ids distinct). A source is "uncovered" when it is outside
 * the world's bounds or no region could hold it (max_regions reached, or
 * its footprint too large for a region of its cell size): it
 * forces nothing this step, and its id is written to uncovered[] (up to
 * max_uncovered; the count returned is all of them). A body that comes back
 * is covered again. Returns -1 with nothing changed on bad input: dt out of
 * range or not finite, n < 0, src NULL with n > 0, a source with id 0, a
 * repeated id, a value not finite, length or beam <= 0 or mass < 0. */
int wakes_step(struct wakes *w, double dt, int n, const struct wake_source *src, uint32_t *uncovered,
               int max_uncovered);

/* The layer at n world points (bilinear between samples, regions summed;
 * 0 where no region is). */
void wakes_sample(const struct wakes *w, int n, const double (*xz)[2], struct wakes_point *out);

/* The layer's wave energy per unit water density, m^5/s^2 (times the
 * density, J): g/2 * sum over regions and samples of (h^2 + q^2) cell^2,
 * where q is the height's quadrature partner (docs). */
double wakes_energy(const struct wakes *w);

/* Sim time stepped so far, s; regions alive; region i (0 .. count-1, in
 * ascending id order) or -1. */
double wakes_time(const struct wakes *w);
int wakes_region_count(const struct wakes *w);
int wakes_region_get(const struct wakes *w, int i, struct wakes_region *out);

#endif

/* sea_model.h — a checked sea document made ready for the amplitudes: its
 * frequency cells and one directional table per band, in the sea's world
 * frame. Immutable once made, so any thread may read it (the amplitude pass,
 * the DFT reference, sea_capture). Inside the library only. */
#ifndef OCEAND_SEA_MODEL_H
#define OCEAND_SEA_MODEL_H

#include "sea_spectrum.h"

/* D(alpha) samples per band over the circle: 0.5 degrees, read with linear
 * interpolation (a measured band is rarely narrower than 5 degrees). */
#define SEA_TABLE 720

/* Which part of the sea a frequency falls in (sea_model_frequency): a band
 * 0 .. bands-1, the power tail (bands: it uses the last band's D), or: */
enum { SEA_BAND_NONE = -1, SEA_BAND_WIND = -2 };

struct sea_model {
    struct sea_spectrum doc;           /* the document as it was given (ocean_sea hands it out) */
    int bands;
    enum sea_tail tail;
    /* Band i's energy E_i df_i spread evenly over its cell [lo, hi): the
     * cells meet half way between band centres (the outer ends at
     * f -/+ df/2), so m0 = the document's sum E df exactly, and bands whose
     * bandwidths overlap or leave gaps (WAVEWATCH III's f (1.1 - 1/1.1) / 2)
     * neither count energy twice nor leave holes. */
    double lo[SEA_MAX_BANDS], hi[SEA_MAX_BANDS];
    double density[SEA_MAX_BANDS];     /* m^2/Hz over the cell */
    /* D per radian at compass "from" direction alpha = j * 360 / SEA_TABLE
     * degrees, [SEA_TABLE] = [0]; its trapezoid sum over the circle is 1. */
    float dir[SEA_MAX_BANDS][SEA_TABLE + 1];
};

/* The model of a checked sea (sea_spectrum_check first). NULL without memory. */
struct sea_model *sea_model_new(const struct sea_spectrum *s);
void sea_model_free(struct sea_model *m);

/* The one-sided frequency spectrum S(f), m^2/Hz, at f Hz, and the part of
 * the sea it comes from (*band: a band, `bands` for the power tail,
 * SEA_BAND_WIND or SEA_BAND_NONE with 0). */
double sea_model_frequency(const struct sea_model *m, double f, int *band);

/* D (per radian) of band `band` (`bands`: the last one) for a wave
 * travelling along (kx, kz) in the world frame: it comes from compass
 * bearing atan2(kz, kx) + 90 degrees (north = +z, east = -x). */
double sea_model_direction(const struct sea_model *m, int band, double kx, double kz);

/* Wavenumber k (rad/m) of angular frequency w (rad/s) in depth d:
 * w^2 = g k tanh(k d), solved by Newton's method. */
double sea_wavenumber(double w, double depth);

#endif

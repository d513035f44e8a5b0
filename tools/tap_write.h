/* tap_write.h — ocean-tap's output files: one decoded field of one frame.
 *
 * Formats:
 *   npy   NumPy .npy v1.0, '<f4', C order, shape (rows, cols): np.load() opens it
 *   raw   little-endian float32 samples, row-major
 *   pgm   binary PGM (P5), values normalised min..max of this field, 16-bit (pgm) or 8-bit (pgm8);
 *         the comment line also carries seq, sim_time and params_version
 *   exr   Blender ocean bakes, whole frames: tap_exr.h
 * Every file gets a .json sidecar (same name, .json for the extension) with
 * the frame header: seq, sim_time, params_version, n, lod, patch_size, bound. 
 * Functions return 0, or -1 with errno set (a write or open failed). */
#ifndef OCEAND_TAP_WRITE_H
#define OCEAND_TAP_WRITE_H

#include <stdint.h>

enum tap_format { TAP_NPY, TAP_RAW, TAP_PGM16, TAP_PGM8, TAP_EXR };

/* Parse "npy", "raw", "pgm" (16-bit), "pgm8", "exr"; -1 if unknown. */
int tap_format_from_name(const char *name);
/* File extension of the main file: "npy", "f32", "pgm", "exr". */
const char *tap_format_ext(enum tap_format f);

/* What the sidecar records about one field of one frame. */
struct tap_meta {
    const char *field;
    uint64_t seq;
    double sim_time;
    uint32_t params_version;
    int n, lod;                 /* full resolution and LOD: side = n >> lod */
    float patch_size, bound;
    uint64_t server_time_us;
    int cascade;                /* PROTOCOL.md §4.1: 0..3, or TAP_CASCADE_SUM for the summed surface */
    double origin_x, origin_z;  /* world position of sample [0][0] (0 for a cascade's own grid) */
};
#define TAP_CASCADE_SUM (-1)

/* Write side*side floats (row-major, row = z) to path, and its sidecar
 * next to it with ".json" in place of the extension. Not for TAP_EXR. */
int tap_write_field(enum tap_format fmt, const char *path, const float *data, int side,
                    const struct tap_meta *meta);

#endif

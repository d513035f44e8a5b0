/* tap_write.h — ocean-tap's output files: one decoded field of one frame.
 *
 * Formats:
 *   npy   NumPy .npy v1.0, '<f4', C order, shape (rows, cols): np.load() opens it
 *   raw   little-endian float32 samples, row-major, plus a .json sidecar with shape and metadata
 *   pgm   binary PGM (P5), values normalised min..max of this field, 16-bit (pgm) or 8-bit (pgm8)
 * Functions return 0, or -1 with errno set (a write or open failed). */
#ifndef OCEAND_TAP_WRITE_H
#define OCEAND_TAP_WRITE_H

#include <stdint.h>

enum tap_format { TAP_NPY, TAP_RAW, TAP_PGM16, TAP_PGM8 };

/* Parse "npy", "raw", "pgm" (16-bit), "pgm8"; -1 if unknown. */
int tap_format_from_name(const char *name);
/* File extension of the main file: "npy", "f32", "pgm". */
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
};

/* Write side*side floats (row-major, row = z) to path (the sidecar, for raw,
 * goes next to it with ".json" in place of the extension). */
int tap_write_field(enum tap_format fmt, const char *path, const float *data, int side,
                    const struct tap_meta *meta);

#endif

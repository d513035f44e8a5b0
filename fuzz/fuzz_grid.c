/* fuzz_grid.c — libFuzzer target: the grid assembler of the C library
 * (oc_grid_*, oc_proto.h) must take any byte string as a frame, and any
 * sequence of them, without touching memory outside its grids, whatever the
 * cascades, fields and LODs it is asked to keep.
 *
 * Input: 2 bytes of choices (byte 0: the field mask of cascade 0, byte 1: its
 * LOD in bits 0-2 and in bits 3-7 which finer cascades to keep at LOD 1), then
 * one frame, or "OCSQ" and length-prefixed frames as fuzz_frame.c reads them. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "oc_proto.h"

/* Read every sample of every grid so ASan sees any out-of-bounds or unset output. */
static void touch(const struct oc_grid *g)
{
    volatile float sink = 0;
    for (int c = 0; c < OC_MAX_CASCADES; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            int side = 0;
            float bound = 0;
            const float *d = oc_grid_field(g, c, (enum oc_field)f, &side, &bound);
            if (!d) continue;
            if (side <= 0 || side > OC_MAX_N) abort();
            for (size_t i = 0; i < (size_t)side * side; i++) sink += d[i];
        }
    (void)sink;
}

static void add(struct oc_grid *g, const uint8_t *data, size_t size)
{
    uint8_t *copy = malloc(size ? size : 1); /* exact size: ASan sees reads past the frame */
    if (!copy) abort();
    memcpy(copy, data, size);
    struct oc_frame_header fh;
    int rc = oc_grid_add(g, copy, size, &fh);
    if (rc > 0 || oc_strerror(rc) == NULL) abort();
    if (oc_grid_complete(g)) touch(g);
    free(copy);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 2) return 0;
    unsigned fields = data[0] & ((1u << OC_FIELD_COUNT) - 1);
    int lod = data[1] & 7;
    struct oc_grid *g = oc_grid_new(fields ? fields : 1u, lod > OC_MAX_LOD ? OC_MAX_LOD : lod);
    if (!g) abort();
    for (int c = 1; c < OC_MAX_CASCADES; c++)
        if (data[1] >> (2 + c) & 1 && oc_grid_want(g, c, fields ? fields : 1u, 1) != 0) abort();
    if (oc_grid_want(g, OC_MAX_CASCADES, 1u, 0) == 0 || oc_grid_want(g, 1, 1u, OC_MAX_LOD + 1) == 0) abort();
    data += 2;
    size -= 2;
    if (size < 4 || memcmp(data, "OCSQ", 4) != 0) {
        add(g, data, size);
    } else {
        size_t pos = 4;
        while (size - pos >= 4) {
            uint32_t len = (uint32_t)data[pos] | (uint32_t)data[pos + 1] << 8 | (uint32_t)data[pos + 2] << 16 |
                           (uint32_t)data[pos + 3] << 24;
            pos += 4;
            if (len > size - pos) len = (uint32_t)(size - pos);
            add(g, data + pos, len);
            pos += len;
        }
    }
    touch(g);
    oc_grid_free(g);
    return 0;
}

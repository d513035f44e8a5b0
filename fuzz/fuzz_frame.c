/* fuzz_frame.c — libFuzzer target: the binary frame decoder must reject or
 * decode any byte string without reading outside it. */
#include <stdint.h>
#include <stdlib.h>

#include "oc_proto.h"

static struct oc_decoder *dec;

/* Touch every decoded sample so ASan sees any out-of-bounds output. */
static int on_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th,
                   const float *samples)
{
    volatile float sink = 0;
    size_t count = (size_t)th->width * th->height;
    if (th->width == 0 || th->height == 0 || th->width > fh->n || th->height > fh->n)
        abort();
    for (size_t i = 0; i < count; i++)
        sink += samples[i];
    (void)sink;
    ++*(size_t *)user;
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (!dec && !(dec = oc_decoder_new()))
        abort();
    struct oc_frame_header fh;
    size_t tiles = 0;
    int rc = oc_decode_frame(dec, data, size, &fh, on_tile, &tiles);
    if (rc == OC_OK && tiles != fh.tile_count)
        abort();
    if (rc > 0 || oc_strerror(rc) == NULL)
        abort();
    return 0;
}

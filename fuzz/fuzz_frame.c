/* fuzz_frame.c — libFuzzer target: the binary frame decoder must reject or
 * decode any byte string without reading outside it, with and without the
 * reference state that predicted tiles (codec 3) use.
 *
 * Input: one frame, or "OCSQ" followed by frames each prefixed by its u32
 * little-endian length: a stream decoded in order by one decoder, so mutated
 * predicted frames meet real references (seeds: fuzz/corpus/frame/seq_*). */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

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

static void decode_one(const uint8_t *data, size_t size)
{
    struct oc_frame_header fh;
    size_t tiles = 0;
    int rc = oc_decode_frame(dec, data, size, &fh, on_tile, &tiles);
    if (rc == OC_OK && tiles != fh.tile_count)
        abort();
    if (rc > 0 || rc < OC_E_REFERENCE || oc_strerror(rc) == NULL)
        abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (!dec && !(dec = oc_decoder_new()))
        abort();
    oc_decoder_reset(dec);                       /* every input starts without references */
    oc_decoder_set_history_limit(dec, (size_t)64 << 20);
    if (size < 4 || memcmp(data, "OCSQ", 4) != 0) {
        decode_one(data, size);
        return 0;
    }
    size_t pos = 4;
    while (size - pos >= 4) {
        uint32_t len = (uint32_t)data[pos] | (uint32_t)data[pos + 1] << 8 | (uint32_t)data[pos + 2] << 16
                       | (uint32_t)data[pos + 3] << 24;
        pos += 4;
        if (len > size - pos) len = (uint32_t)(size - pos);
        /* an exact-size copy: ASan sees any read past the frame */
        uint8_t *frame = malloc(len ? len : 1);
        if (!frame) abort();
        memcpy(frame, data + pos, len);
        decode_one(frame, len);
        free(frame);
        pos += len;
    }
    return 0;
}

/* fuzz_inflate.c — libFuzzer target, differential: the web client's raw DEFLATE decoder
 * (proto/wasm/oc_inflate.c, run in the browser as WebAssembly) must give zlib's verdict and
 * zlib's bytes on any input, and never read or write outside its buffers.
 * Input: u16 LE output capacity, then the stream. Accepted = zlib reaches the end of the
 * stream with every input byte consumed and at most `cap` bytes out. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "oc_inflate.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 2) return 0;
    size_t cap = (size_t)data[0] | (size_t)data[1] << 8;
    const uint8_t *in = data + 2;
    size_t in_len = size - 2;
    /* exact-size heap copies: ASan catches any access past either */
    uint8_t *src = malloc(in_len ? in_len : 1), *out = malloc(cap ? cap : 1), *ref = malloc(cap + 1);
    void *scratch = malloc(oc_inflate_scratch_size());
    if (!src || !out || !ref || !scratch) abort();
    if (in_len) memcpy(src, in, in_len);
    long n = oc_inflate_raw(src, in_len, out, cap, scratch);

    z_stream z;
    memset(&z, 0, sizeof z);
    if (inflateInit2(&z, -15) != Z_OK) abort();
    z.next_in = src;
    z.avail_in = (uInt)in_len;
    z.next_out = ref;
    z.avail_out = (uInt)cap + 1;   /* one byte more: a longer stream shows up */
    int zrc = inflate(&z, Z_FINISH);
    int z_ok = zrc == Z_STREAM_END && z.avail_in == 0 && z.total_out <= cap;
    if ((n >= 0) != z_ok) abort();
    if (n >= 0 && ((size_t)n != z.total_out || memcmp(out, ref, (size_t)n))) abort();
    if (n < 0 && n != OC_INFLATE_CORRUPT && n != OC_INFLATE_TRUNCATED && n != OC_INFLATE_TOO_LONG
        && n != OC_INFLATE_TRAILING)
        abort();
    inflateEnd(&z);
    free(src);
    free(out);
    free(ref);
    free(scratch);
    return 0;
}

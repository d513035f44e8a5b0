/* oc_inflate.h — raw DEFLATE decoder of the browser client's WebAssembly module
 * (oc_inflate.c; loaded by proto/js/oc_wasm.js). Freestanding: no libc. */
#ifndef OC_INFLATE_H
#define OC_INFLATE_H

#include <stddef.h>
#include <stdint.h>

#define OC_INFLATE_CORRUPT   (-1)   /* not a valid DEFLATE stream */
#define OC_INFLATE_TRUNCATED (-2)   /* the input ends inside the stream */
#define OC_INFLATE_TOO_LONG  (-3)   /* more than `cap` bytes of output */
#define OC_INFLATE_TRAILING  (-4)   /* bytes after the last block */

/* Inflate the raw DEFLATE stream in[0..in_len) into out[0..cap): the number of bytes
 * written, or one of the negative codes above. scratch: oc_inflate_scratch_size() bytes,
 * 8-byte aligned. */
long oc_inflate_raw(const uint8_t *in, size_t in_len, uint8_t *out, size_t cap, void *scratch);
size_t oc_inflate_scratch_size(void);

#endif

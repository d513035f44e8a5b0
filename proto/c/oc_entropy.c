/* oc_entropy.c — the two standard entropy coders a lossy tile may use:
 * codec 1 = raw DEFLATE (RFC 1951) via libdeflate, codec 2 = zstd frame.
 * Decoders insist on exact sizes both ways: a payload must inflate to exactly
 * the expected byte count and be consumed to its last byte. */
#include "oc_internal.h"

#include <libdeflate.h>
#include <stdlib.h>
#include <zstd.h>

struct oc_entropy {
    struct libdeflate_compressor *dc;
    int dc_level;
    struct libdeflate_decompressor *dd;
    ZSTD_CCtx *zc;
    ZSTD_DCtx *zd;
};

struct oc_entropy *oc_entropy_new(void)
{
    return calloc(1, sizeof(struct oc_entropy));
}

void oc_entropy_free(struct oc_entropy *c)
{
    if (!c) return;
    libdeflate_free_compressor(c->dc);
    libdeflate_free_decompressor(c->dd);
    ZSTD_freeCCtx(c->zc);
    ZSTD_freeDCtx(c->zd);
    free(c);
}

size_t oc_entropy_bound(int codec, size_t n)
{
    if (codec == OC_CODEC_QUANT_LORENZO_ZSTD) return ZSTD_compressBound(n);
    /* libdeflate's documented worst case for any level; computed without a compressor. */
    return n + n / 8 + 5 * (n / 10000 + 1) + 64;
}

size_t oc_entropy_compress(struct oc_entropy *c, int codec, int level, const uint8_t *src, size_t n,
                           uint8_t *dst, size_t cap)
{
    if (codec == OC_CODEC_QUANT_LORENZO_ZSTD) {
        if (!c->zc && !(c->zc = ZSTD_createCCtx())) return 0;
        size_t r = ZSTD_compressCCtx(c->zc, dst, cap, src, n, level);
        return ZSTD_isError(r) ? 0 : r;
    }
    if (!c->dc || c->dc_level != level) {
        libdeflate_free_compressor(c->dc);
        c->dc = libdeflate_alloc_compressor(level);
        c->dc_level = level;
        if (!c->dc) return 0;
    }
    return libdeflate_deflate_compress(c->dc, src, n, dst, cap);
}

int oc_entropy_decompress(struct oc_entropy *c, int codec, const uint8_t *src, size_t srclen,
                          uint8_t *dst, size_t n)
{
    if (codec == OC_CODEC_QUANT_LORENZO_ZSTD) {
        if (!c->zd && !(c->zd = ZSTD_createDCtx())) return OC_E_NOMEM;
        /* One frame that declares its size, exactly n, and nothing after it. */
        if (ZSTD_getFrameContentSize(src, srclen) != (unsigned long long)n) return OC_E_CORRUPT;
        if (ZSTD_findFrameCompressedSize(src, srclen) != srclen) return OC_E_CORRUPT;
        size_t r = ZSTD_decompressDCtx(c->zd, dst, n, src, srclen);
        return (!ZSTD_isError(r) && r == n) ? OC_OK : OC_E_CORRUPT;
    }
    if (!c->dd && !(c->dd = libdeflate_alloc_decompressor())) return OC_E_NOMEM;
    size_t in_used = 0, out_len = 0;
    enum libdeflate_result r =
        libdeflate_deflate_decompress_ex(c->dd, src, srclen, dst, n, &in_used, &out_len);
    return (r == LIBDEFLATE_SUCCESS && out_len == n && in_used == srclen) ? OC_OK : OC_E_CORRUPT;
}

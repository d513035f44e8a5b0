/* oc_entropy.c — the two standard entropy coders a lossy tile may use:
 * codec 1 = raw DEFLATE (RFC 1951), codec 2 = zstd frame.
 * Decoders insist on exact sizes both ways: a payload must inflate to exactly
 * the expected byte count and be consumed to its last byte.
 *
 * Codec 1 at level 1 (the default) is written here as ONE DEFLATE block of
 * literals only (no LZ77 matches): dynamic Huffman, or fixed Huffman / stored
 * when smaller. Why not libdeflate level 1: the residual bytes are noise-like,
 * LZ77 finds only short matches that cost more than the literals they replace
 * (N=256 height at 1 cm: 3.78 -> 3.35 bits/sample; at 1 mm equal within 0.03 %),
 * and its match finder took ~60 % of the encode time. Any inflater reads the
 * result (it is plain RFC 1951). Levels 2..12 still go to libdeflate. */
#include "oc_internal.h"

#include <libdeflate.h>
#include <stdlib.h>
#include <string.h>
#include <zstd.h>

#define LIT_SYMS 257   /* literals 0..255 + end-of-block; no length codes are used */
#define FIXED_SYMS 288

struct oc_entropy {
    struct libdeflate_compressor *dc;
    int dc_level;
    struct libdeflate_decompressor *dd;
    ZSTD_CCtx *zc;
    ZSTD_DCtx *zd;
    uint16_t fixed_code[FIXED_SYMS];   /* the fixed Huffman code of RFC 1951 §3.2.6, bit-reversed */
    uint8_t fixed_len[FIXED_SYMS];
};

static void huf_codes(const uint8_t *len, int n, uint16_t *code);

struct oc_entropy *oc_entropy_new(void)
{
    struct oc_entropy *c = calloc(1, sizeof(struct oc_entropy));
    if (!c) return NULL;
    for (int s = 0; s < FIXED_SYMS; s++) c->fixed_len[s] = s < 144 ? 8 : s < 256 ? 9 : s < 280 ? 7 : 8;
    huf_codes(c->fixed_len, FIXED_SYMS, c->fixed_code);
    return c;
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
    /* libdeflate's documented worst case for any level (it also covers the stored
     * blocks the Huffman-only writer falls back to); computed without a compressor. */
    return n + n / 8 + 5 * (n / 10000 + 1) + 64;
}

/* ---- Huffman-only DEFLATE ---- */

/* Huffman code lengths of freq[0..n) (zero frequency = unused, length 0),
 * none longer than maxlen. Two-queue construction on the sorted leaves; when
 * the tree is too deep, halve the frequencies (keeping them nonzero) and
 * rebuild: that ends at worst with equal weights, depth ceil(log2 n) <= maxlen. */
static void huf_lengths(const uint32_t *freq_in, int n, int maxlen, uint8_t *len)
{
    uint32_t f[FIXED_SYMS];
    uint16_t leaf[FIXED_SYMS], tmp[FIXED_SYMS];
    uint64_t w[FIXED_SYMS];
    int parent[2 * FIXED_SYMS], depth[2 * FIXED_SYMS];
    memcpy(f, freq_in, sizeof(uint32_t) * (size_t)n);
    for (;;) {
        int m = 0;
        uint32_t fbits = 0;
        for (int s = 0; s < n; s++) {
            len[s] = 0;
            if (f[s]) { leaf[m++] = (uint16_t)s; fbits |= f[s]; }
        }
        if (m < 2) {   /* a single symbol still needs a complete code: give it and a partner one bit */
            int s = m ? leaf[0] : 0;
            len[s] = 1;
            len[s == 0 ? 1 : 0] = 1;
            return;
        }
        /* Leaves by increasing frequency (ties by symbol): LSD radix sort, 8 bits a pass. */
        for (int shift = 0; shift < 32 && (fbits >> shift); shift += 8) {
            int cnt[257] = { 0 };
            for (int i = 0; i < m; i++) cnt[((f[leaf[i]] >> shift) & 255) + 1]++;
            for (int d = 0; d < 256; d++) cnt[d + 1] += cnt[d];
            for (int i = 0; i < m; i++) tmp[cnt[(f[leaf[i]] >> shift) & 255]++] = leaf[i];
            memcpy(leaf, tmp, sizeof(uint16_t) * (size_t)m);
        }
        /* Two queues: nodes 0..m-1 are the sorted leaves, m.. the internal nodes in creation order. */
        int li = 0, ii = 0;
        for (int ni = 0; ni < m - 1; ni++) {
            int pick[2];
            uint64_t sum = 0;
            for (int t = 0; t < 2; t++) {
                if (li < m && (ii >= ni || f[leaf[li]] <= w[ii])) { sum += f[leaf[li]]; pick[t] = li++; }
                else { sum += w[ii]; pick[t] = m + ii++; }
            }
            w[ni] = sum;
            parent[pick[0]] = parent[pick[1]] = m + ni;
        }
        int root = 2 * m - 2, maxd = 0;
        depth[root] = 0;
        for (int v = root - 1; v >= 0; v--) {
            depth[v] = depth[parent[v]] + 1;
            if (v < m && depth[v] > maxd) maxd = depth[v];
        }
        if (maxd <= maxlen) {
            for (int v = 0; v < m; v++) len[leaf[v]] = (uint8_t)depth[v];
            return;
        }
        for (int s = 0; s < n; s++)
            if (f[s]) f[s] = (f[s] >> 1) | 1;
    }
}

static inline unsigned rev16(unsigned x)
{
    x = ((x & 0x5555u) << 1) | ((x >> 1) & 0x5555u);
    x = ((x & 0x3333u) << 2) | ((x >> 2) & 0x3333u);
    x = ((x & 0x0f0fu) << 4) | ((x >> 4) & 0x0f0fu);
    return ((x & 0x00ffu) << 8) | ((x >> 8) & 0x00ffu);
}

/* Canonical codes (RFC 1951 §3.2.2) for the lengths, bit-reversed because
 * DEFLATE sends Huffman codes most significant bit first into an LSB-first stream. */
static void huf_codes(const uint8_t *len, int n, uint16_t *code)
{
    int count[16] = { 0 }, next[16];
    for (int s = 0; s < n; s++) count[len[s]]++;
    count[0] = 0;
    for (int b = 1, c = 0; b < 16; b++) { c = (c + count[b - 1]) << 1; next[b] = c; }
    for (int s = 0; s < n; s++) {
        code[s] = len[s] ? (uint16_t)(rev16((unsigned)next[len[s]]++) >> (16 - len[s])) : 0;
    }
}

/* LSB-first bit writer. The caller has checked that the whole block fits, and
 * only completed bits are stored, so it never writes past the block's size. */
struct bitw { uint8_t *p; uint64_t buf; int n; };
static inline void bw_put(struct bitw *w, uint32_t bits, int len)
{
    w->buf |= (uint64_t)bits << w->n;
    w->n += len;
    if (w->n >= 32) {
        w->p[0] = (uint8_t)w->buf; w->p[1] = (uint8_t)(w->buf >> 8);
        w->p[2] = (uint8_t)(w->buf >> 16); w->p[3] = (uint8_t)(w->buf >> 24);
        w->p += 4; w->buf >>= 32; w->n -= 32;
    }
}
static inline void bw_flush(struct bitw *w)
{
    for (; w->n > 0; w->n -= 8) { *w->p++ = (uint8_t)w->buf; w->buf >>= 8; }
    w->n = 0;
}

/* The literals. After a flush fewer than 8 bits are pending, so three codes
 * (3 x 15 bits) always fit the 64-bit buffer: the loop stores all 8 bytes and
 * keeps the whole ones, with no branch on the bit count (a data-dependent
 * branch there mispredicted on these short, noise-like codes). Each symbol's
 * code and length come from one table entry. The 8-byte store needs 8 bytes
 * of room in [p, end); the last few literals go through bw_put, which stores
 * only completed bytes. */
static void put_literals(struct bitw *w, const uint8_t *src, size_t n, const uint16_t *code, const uint8_t *len,
                         const uint8_t *end)
{
    uint32_t entry[256];
    for (int s = 0; s < 256; s++) entry[s] = code[s] | (uint32_t)len[s] << 16;
    uint64_t buf = w->buf;
    int nb = w->n;
    uint8_t *p = w->p;
    for (; nb >= 8; nb -= 8) { *p++ = (uint8_t)buf; buf >>= 8; }
    size_t k = 0;
    for (; k + 3 <= n && end - p >= 8; k += 3) {
        uint32_t a = entry[src[k]], b = entry[src[k + 1]], c = entry[src[k + 2]];
        buf |= (uint64_t)(a & 0xffff) << nb; nb += (int)(a >> 16);
        buf |= (uint64_t)(b & 0xffff) << nb; nb += (int)(b >> 16);
        buf |= (uint64_t)(c & 0xffff) << nb; nb += (int)(c >> 16);
        for (int i = 0; i < 8; i++) p[i] = (uint8_t)(buf >> (8 * i));   /* one 8-byte store */
        p += nb >> 3;
        buf >>= nb & ~7;
        nb &= 7;
    }
    w->buf = buf; w->n = nb; w->p = p;
    for (; k < n; k++) bw_put(w, code[src[k]], len[src[k]]);
}

/* Run-length code the code lengths (symbols 16, 17, 18 of RFC 1951 §3.2.7). */
static int cl_rle(const uint8_t *lens, int n, uint8_t *sym, uint8_t *extra)
{
    int m = 0;
    for (int i = 0; i < n;) {
        int v = lens[i], r = 1;
        while (i + r < n && lens[i + r] == v) r++;
        i += r;
        if (v == 0) {
            while (r >= 11) { int t = r < 138 ? r : 138; sym[m] = 18; extra[m++] = (uint8_t)(t - 11); r -= t; }
            if (r >= 3) { sym[m] = 17; extra[m++] = (uint8_t)(r - 3); r = 0; }
        } else {
            sym[m] = (uint8_t)v; extra[m++] = 0; r--;
            while (r >= 3) { int t = r < 6 ? r : 6; sym[m] = 16; extra[m++] = (uint8_t)(t - 3); r -= t; }
        }
        for (; r > 0; r--) { sym[m] = (uint8_t)v; extra[m++] = 0; }
    }
    return m;
}

void oc_byte_hist_add(const uint8_t *src, size_t n, uint32_t out[256])
{
    /* Four tables: consecutive equal bytes would serialise one counter. */
    uint32_t hist[4][256] = { { 0 } };
    size_t k = 0;
    for (; k + 4 <= n; k += 4) { hist[0][src[k]]++; hist[1][src[k + 1]]++; hist[2][src[k + 2]]++; hist[3][src[k + 3]]++; }
    for (; k < n; k++) hist[0][src[k]]++;
    for (int s = 0; s < 256; s++) out[s] += hist[0][s] + hist[1][s] + hist[2][s] + hist[3][s];
}

/* hist: src's byte histogram, or NULL to count it here. */
static size_t huffman_only(const struct oc_entropy *c, const uint8_t *src, size_t n, const uint32_t *hist,
                           uint8_t *dst, size_t cap)
{
    static const uint8_t cl_order[19] = { 16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15 };
    static const uint8_t cl_extra[19] = { [16] = 2, [17] = 3, [18] = 7 };
    uint32_t freq[LIT_SYMS];
    if (hist) memcpy(freq, hist, sizeof(uint32_t) * 256);
    else {
        memset(freq, 0, sizeof(uint32_t) * 256);
        oc_byte_hist_add(src, n, freq);
    }
    freq[256] = 1;

    /* Dynamic block: literal/length code + 2 one-bit distance codes (never used;
     * two keep the code complete, as zlib does), then the code-length code. */
    uint8_t lens[LIT_SYMS + 2];
    uint16_t code[LIT_SYMS];
    huf_lengths(freq, LIT_SYMS, 15, lens);
    lens[LIT_SYMS] = lens[LIT_SYMS + 1] = 1;
    uint8_t rle_sym[LIT_SYMS + 2], rle_extra[LIT_SYMS + 2];
    int nrle = cl_rle(lens, LIT_SYMS + 2, rle_sym, rle_extra);
    uint32_t cl_freq[19] = { 0 };
    for (int i = 0; i < nrle; i++) cl_freq[rle_sym[i]]++;
    uint8_t cl_len[19];
    uint16_t cl_code[19];
    huf_lengths(cl_freq, 19, 7, cl_len);
    huf_codes(cl_len, 19, cl_code);
    int hclen = 19;
    while (hclen > 4 && cl_len[cl_order[hclen - 1]] == 0) hclen--;
    uint64_t dyn_bits = 3 + 5 + 5 + 4 + 3 * (uint64_t)hclen, fix_bits = 3;
    for (int i = 0; i < nrle; i++) dyn_bits += cl_len[rle_sym[i]] + cl_extra[rle_sym[i]];
    for (int s = 0; s < LIT_SYMS; s++) {
        dyn_bits += (uint64_t)freq[s] * lens[s];
        fix_bits += (uint64_t)freq[s] * c->fixed_len[s];
    }
    size_t dyn = (size_t)((dyn_bits + 7) / 8), fix = (size_t)((fix_bits + 7) / 8);
    size_t stored = n + 5 * (n / 65535 + (n % 65535 != 0 || n == 0));

    if (stored <= dyn && stored <= fix) {   /* incompressible: stored blocks of <= 65535 bytes */
        if (stored > cap) return 0;
        uint8_t *p = dst;
        size_t at = 0;
        do {
            size_t len = n - at < 65535 ? n - at : 65535;
            p[0] = at + len == n;      /* BFINAL on the last, BTYPE 00; the rest of the byte is padding */
            p[1] = (uint8_t)len; p[2] = (uint8_t)(len >> 8);
            p[3] = (uint8_t)~len; p[4] = (uint8_t)(~len >> 8);
            memcpy(p + 5, src + at, len);
            p += 5 + len;
            at += len;
        } while (at < n);
        return (size_t)(p - dst);
    }
    struct bitw w = { .p = dst };
    if (fix < dyn) {
        if (fix > cap) return 0;
        bw_put(&w, 1, 1);              /* BFINAL */
        bw_put(&w, 1, 2);              /* BTYPE 01: fixed Huffman */
        put_literals(&w, src, n, c->fixed_code, c->fixed_len, dst + cap);
        bw_put(&w, c->fixed_code[256], c->fixed_len[256]);
        bw_flush(&w);
        return (size_t)(w.p - dst);
    }
    if (dyn > cap) return 0;
    huf_codes(lens, LIT_SYMS, code);
    bw_put(&w, 1, 1);                  /* BFINAL */
    bw_put(&w, 2, 2);                  /* BTYPE 10: dynamic Huffman */
    bw_put(&w, LIT_SYMS - 257, 5);     /* HLIT */
    bw_put(&w, 2 - 1, 5);              /* HDIST */
    bw_put(&w, (uint32_t)hclen - 4, 4);
    for (int i = 0; i < hclen; i++) bw_put(&w, cl_len[cl_order[i]], 3);
    for (int i = 0; i < nrle; i++) {
        bw_put(&w, cl_code[rle_sym[i]], cl_len[rle_sym[i]]);
        if (cl_extra[rle_sym[i]]) bw_put(&w, rle_extra[i], cl_extra[rle_sym[i]]);
    }
    put_literals(&w, src, n, code, lens, dst + cap);
    bw_put(&w, code[256], lens[256]);
    bw_flush(&w);
    return (size_t)(w.p - dst);
}

size_t oc_entropy_compress_hist(struct oc_entropy *c, int codec, int level, const uint8_t *src, size_t n,
                                const uint32_t hist[256], uint8_t *dst, size_t cap)
{
    if (codec == OC_CODEC_QUANT_LORENZO && level == 1) return huffman_only(c, src, n, hist, dst, cap);
    return oc_entropy_compress(c, codec, level, src, n, dst, cap);
}

size_t oc_entropy_compress(struct oc_entropy *c, int codec, int level, const uint8_t *src, size_t n,
                           uint8_t *dst, size_t cap)
{
    if (codec == OC_CODEC_QUANT_LORENZO && level == 1) return huffman_only(c, src, n, NULL, dst, cap);
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

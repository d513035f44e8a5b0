/* oc_inflate.c — raw DEFLATE (RFC 1951) decoder for the browser client, built to
 * WebAssembly by the Makefile (clang --target=wasm32, wasm-ld) and natively for its
 * differential fuzzer (fuzz/fuzz_inflate.c: same output and verdict as zlib).
 * Hand-written because no DEFLATE decoder ships in a Debian package as source to build for
 * wasm32 (zlib and libdeflate come as host binaries), and fflate (JavaScript) spends most of
 * its time on our ~1 kB tiles rebuilding 32k-entry tables per block (3.0 ms per N = 256 frame
 * against 0.3 here, docs/web.md). Tables are zlib-sized: a 10-bit direct table plus a canonical
 * slow path (the scheme of stb_image's zlib). Strict like zlib: over-subscribed or incomplete
 * code sets (but a lone length-1 code), a missing end-of-block code, bad stored lengths,
 * distances before the start, output past the capacity, input that runs out and bytes after
 * the last block are all errors.
 * No libc: freestanding C11 (memory.copy/fill come from -mbulk-memory in the wasm build). */
#include "oc_inflate.h"

#define FAST_BITS 10
#define FAST_MASK ((1u << FAST_BITS) - 1)

struct huff {
    uint16_t fast[1 << FAST_BITS];   /* (length << 9) | symbol (symbols < 512); 0 = not in the fast table */
    uint16_t firstcode[16];
    int32_t maxcode[17];
    uint16_t firstsymbol[16];
    uint8_t size[288];
    uint16_t value[288];
};

struct inflater {
    const uint8_t *in;
    size_t in_len, pos;
    uint64_t bits;
    int nbits;
    uint8_t *out;
    size_t cap, n;
    struct huff lit, dist, clen;
};

static int bit_reverse(int v, int bits)
{
    int r = 0;
    for (int i = 0; i < bits; i++) { r = (r << 1) | (v & 1); v >>= 1; }
    return r;
}

/* 0 = ok; -1 = not a valid code set. kind: 0 code lengths, 1 literal/length, 2 distance. */
static int build(struct huff *z, const uint8_t *lens, int num, int kind)
{
    int sizes[17] = { 0 }, next_code[16];
    for (int i = 0; i < (1 << FAST_BITS); i++) z->fast[i] = 0;
    for (int i = 0; i < num; i++) sizes[lens[i]]++;
    sizes[0] = 0;
    int max = 0;
    for (int i = 1; i < 16; i++) if (sizes[i]) max = i;
    /* zlib's rules: over-subscribed never; incomplete only a lone code of length 1 in the
     * literal/length or distance code (or no code at all, which fails when a symbol is read). */
    int left = 1;
    for (int i = 1; i < 16; i++) {
        left <<= 1;
        left -= sizes[i];
        if (left < 0) return -1;
    }
    if (left > 0 && max > 0 && (kind == 0 || max != 1)) return -1;
    int code = 0, k = 0;
    for (int i = 1; i < 16; i++) {
        next_code[i] = code;
        z->firstcode[i] = (uint16_t)code;
        z->firstsymbol[i] = (uint16_t)k;
        code += sizes[i];
        z->maxcode[i] = code << (16 - i);
        code <<= 1;
        k += sizes[i];
    }
    z->maxcode[16] = 0x10000;
    for (int i = 0; i < num; i++) {
        int s = lens[i];
        if (!s) continue;
        int c = next_code[s] - z->firstcode[s] + z->firstsymbol[s];
        z->size[c] = (uint8_t)s;
        z->value[c] = (uint16_t)i;
        if (s <= FAST_BITS) {
            uint16_t fv = (uint16_t)((s << 9) | i);
            for (int j = bit_reverse(next_code[s], s); j < (1 << FAST_BITS); j += 1 << s) z->fast[j] = fv;
        }
        next_code[s]++;
    }
    return 0;
}

/* At least 57 bits in the buffer; past the input, zero bytes (counted by pos > in_len). */
static inline void refill(struct inflater *f)
{
    while (f->nbits <= 56) {
        uint64_t b = f->pos < f->in_len ? f->in[f->pos] : 0;
        f->pos++;
        f->bits |= b << f->nbits;
        f->nbits += 8;
    }
}

static inline uint32_t take(struct inflater *f, int n)
{
    uint32_t v = (uint32_t)(f->bits & ((1ull << n) - 1));
    f->bits >>= n;
    f->nbits -= n;
    return v;
}

/* Bytes of input actually consumed: those read into the buffer minus whole unread ones. */
static inline int overran(const struct inflater *f)
{
    return f->pos - (size_t)(f->nbits >> 3) > f->in_len;
}

/* One symbol; -1 = no such code. Needs >= 15 bits buffered. */
static inline int decode(struct inflater *f, const struct huff *z)
{
    uint32_t b = z->fast[f->bits & FAST_MASK];
    if (b) {
        take(f, (int)(b >> 9));
        return (int)(b & 511);
    }
    int k = bit_reverse((int)(f->bits & 0xffff), 16), s;
    for (s = FAST_BITS + 1; s < 16; s++) if (k < z->maxcode[s]) break;
    if (s >= 16) return -1;
    int c = (k >> (16 - s)) - z->firstcode[s] + z->firstsymbol[s];
    if (c < 0 || c >= 288 || z->size[c] != s) return -1;
    take(f, s);
    return z->value[c];
}

static const uint16_t LEN_BASE[29] = { 3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31,
                                       35, 43, 51, 59, 67, 83, 99, 115, 131, 163, 195, 227, 258 };
static const uint8_t LEN_EXTRA[29] = { 0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2,
                                       3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0 };
static const uint16_t DIST_BASE[30] = { 1, 2, 3, 4, 5, 7, 9, 13, 17, 25, 33, 49, 65, 97, 129, 193,
                                        257, 385, 513, 769, 1025, 1537, 2049, 3073, 4097, 6145,
                                        8193, 12289, 16385, 24577 };
static const uint8_t DIST_EXTRA[30] = { 0, 0, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6,
                                        7, 7, 8, 8, 9, 9, 10, 10, 11, 11, 12, 12, 13, 13 };

/* The literal/length loop keeps the bit buffer in locals and refills it 7 bytes at a
 * time while the input lasts (one 64-bit load), else byte by byte with zeros past the end. */
static inline uint64_t load_le64(const uint8_t *p)
{
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) v = (v << 8) | p[i];   /* one unaligned load after -O2 */
    return v;
}

#define REFILL()                                                                  \
    do {                                                                          \
        if (pos + 8 <= in_len) {                                                  \
            bits |= load_le64(in + pos) << nbits;                                 \
            pos += (size_t)((63 - nbits) >> 3);                                   \
            nbits |= 56;                                                          \
        } else {                                                                  \
            while (nbits <= 56) {                                                 \
                bits |= (uint64_t)(pos < in_len ? in[pos] : 0) << nbits;          \
                pos++;                                                            \
                nbits += 8;                                                       \
            }                                                                     \
        }                                                                         \
    } while (0)

static int block(struct inflater *f)
{
    uint8_t *out = f->out;
    const uint8_t *in = f->in;
    const size_t in_len = f->in_len, cap = f->cap;
    size_t n = f->n, pos = f->pos;
    uint64_t bits = f->bits;
    int nbits = f->nbits, rc = 0;
    const uint16_t *fast = f->lit.fast;
    for (;;) {
        if (nbits < 15) {
            REFILL();
            if (pos > in_len + 16) { rc = OC_INFLATE_TRUNCATED; break; }
        }
        int sym;
        uint32_t b = fast[bits & FAST_MASK];
        if (b) {
            bits >>= b >> 9;
            nbits -= (int)(b >> 9);
            sym = (int)(b & 511);
        } else {
            f->bits = bits; f->nbits = nbits;
            sym = decode(f, &f->lit);
            bits = f->bits; nbits = f->nbits;
            if (sym < 0) { rc = OC_INFLATE_CORRUPT; break; }
        }
        if (sym < 256) {
            if (n >= cap) { rc = OC_INFLATE_TOO_LONG; break; }
            out[n++] = (uint8_t)sym;
            continue;
        }
        if (sym == 256) break;
        sym -= 257;
        if (sym >= 29) { rc = OC_INFLATE_CORRUPT; break; }
        REFILL();
        size_t len = LEN_BASE[sym] + (size_t)(bits & ((1u << LEN_EXTRA[sym]) - 1));
        bits >>= LEN_EXTRA[sym];
        nbits -= LEN_EXTRA[sym];
        f->bits = bits; f->nbits = nbits;
        int ds = decode(f, &f->dist);            /* 5 + 15 bits <= 57 buffered */
        bits = f->bits; nbits = f->nbits;
        if (ds < 0 || ds >= 30) { rc = OC_INFLATE_CORRUPT; break; }
        REFILL();
        size_t dist = DIST_BASE[ds] + (size_t)(bits & ((1u << DIST_EXTRA[ds]) - 1));
        bits >>= DIST_EXTRA[ds];
        nbits -= DIST_EXTRA[ds];
        if (dist > n) { rc = OC_INFLATE_CORRUPT; break; }
        if (len > cap - n) { rc = OC_INFLATE_TOO_LONG; break; }
        const uint8_t *from = out + n - dist;
        uint8_t *to = out + n;
        if (dist == 1) {
            uint8_t v = from[0];
            for (size_t i = 0; i < len; i++) to[i] = v;
        } else {
            for (size_t i = 0; i < len; i++) to[i] = from[i];   /* overlapping: in order */
        }
        n += len;
    }
    f->n = n;
    f->pos = pos;
    f->bits = bits;
    f->nbits = nbits;
    return rc;
}

static int fixed_tables(struct inflater *f)
{
    uint8_t lens[288];
    for (int i = 0; i < 288; i++) lens[i] = (uint8_t)(i < 144 ? 8 : i < 256 ? 9 : i < 280 ? 7 : 8);
    if (build(&f->lit, lens, 288, 1)) return OC_INFLATE_CORRUPT;
    for (int i = 0; i < 32; i++) lens[i] = 5;          /* 30 and 31 complete the code; invalid in a block */
    if (build(&f->dist, lens, 32, 2)) return OC_INFLATE_CORRUPT;
    return 0;
}

static int dynamic_tables(struct inflater *f)
{
    static const uint8_t ORDER[19] = { 16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15 };
    refill(f);
    int hlit = (int)take(f, 5) + 257, hdist = (int)take(f, 5) + 1, hclen = (int)take(f, 4) + 4;
    if (hlit > 286 || hdist > 30) return OC_INFLATE_CORRUPT;
    uint8_t cl[19] = { 0 }, lens[286 + 30];
    for (int i = 0; i < hclen; i++) {
        refill(f);
        cl[ORDER[i]] = (uint8_t)take(f, 3);
    }
    if (build(&f->clen, cl, 19, 0)) return OC_INFLATE_CORRUPT;
    int n = 0;
    while (n < hlit + hdist) {
        refill(f);
        if (f->pos > f->in_len + 16) return OC_INFLATE_TRUNCATED;
        int c = decode(f, &f->clen);
        if (c < 0) return OC_INFLATE_CORRUPT;
        int rep, val;
        if (c < 16) { lens[n++] = (uint8_t)c; continue; }
        if (c == 16) {
            if (n == 0) return OC_INFLATE_CORRUPT;
            rep = 3 + (int)take(f, 2);
            val = lens[n - 1];
        } else if (c == 17) {
            rep = 3 + (int)take(f, 3);
            val = 0;
        } else {
            rep = 11 + (int)take(f, 7);
            val = 0;
        }
        if (rep > hlit + hdist - n) return OC_INFLATE_CORRUPT;
        while (rep--) lens[n++] = (uint8_t)val;
    }
    if (lens[256] == 0) return OC_INFLATE_CORRUPT;   /* no end-of-block code */
    if (build(&f->lit, lens, hlit, 1) || build(&f->dist, lens + hlit, hdist, 2)) return OC_INFLATE_CORRUPT;
    return 0;
}

long oc_inflate_raw(const uint8_t *in, size_t in_len, uint8_t *out, size_t cap, void *scratch)
{
    struct inflater *f = scratch;
    f->in = in;
    f->in_len = in_len;
    f->pos = 0;
    f->bits = 0;
    f->nbits = 0;
    f->out = out;
    f->cap = cap;
    f->n = 0;
    int final;
    do {
        refill(f);
        final = (int)take(f, 1);
        int type = (int)take(f, 2), rc;
        if (type == 0) {
            take(f, f->nbits & 7);                 /* to a byte boundary */
            uint32_t len = take(f, 16), nlen = take(f, 16);
            if ((len ^ 0xffff) != nlen) return OC_INFLATE_CORRUPT;
            /* whole bytes still buffered come first, then the input itself */
            while (len && f->nbits >= 8) {
                if (f->n >= cap) return OC_INFLATE_TOO_LONG;
                out[f->n++] = (uint8_t)take(f, 8);
                len--;
            }
            if (overran(f)) return OC_INFLATE_TRUNCATED;
            if (len > in_len - f->pos) return OC_INFLATE_TRUNCATED;
            if (len > cap - f->n) return OC_INFLATE_TOO_LONG;
            for (uint32_t i = 0; i < len; i++) out[f->n + i] = in[f->pos + i];
            f->n += len;
            f->pos += len;
            rc = 0;
        } else if (type == 1) {
            rc = fixed_tables(f);
            if (!rc) rc = block(f);
        } else if (type == 2) {
            rc = dynamic_tables(f);
            if (!rc) rc = block(f);
        } else {
            rc = OC_INFLATE_CORRUPT;
        }
        if (rc) return rc;
        if (overran(f)) return OC_INFLATE_TRUNCATED;
    } while (!final);
    /* Every byte of the input is part of the stream (the last one's unused bits aside). */
    if (f->pos - (size_t)(f->nbits >> 3) != in_len) return OC_INFLATE_TRAILING;
    return (long)f->n;
}

size_t oc_inflate_scratch_size(void) { return sizeof(struct inflater); }

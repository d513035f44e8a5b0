/* tap_exr.c — see tap_exr.h. OpenEXR 3.1's C API (OpenEXRCore, Debian
 * libopenexr-dev) writes the files: header, attributes, chunk table. The
 * chunks' ZIP compression is done here, with libdeflate, and handed to
 * exr_write_scanline_chunk: OpenEXR 3.1 compresses with zlib, which took
 * most of a bake frame's time. A ZIP chunk is the standard one (OpenEXR's
 * internal_zip.c): the chunk's pixels as little-endian halves, line by line
 * and channel by channel in the header's order, their bytes split into the
 * low bytes then the high bytes, each byte replaced by its difference to the
 * one before + 128, all in one zlib stream; stored as they were when that is
 * not smaller. Half floats come from Imath's C function, or from the F16C
 * instructions (the same rounding: to nearest, ties to even) where the CPU
 * has them. */
#include "tap_exr.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <half.h>
#include <libdeflate.h>
#include <openexr.h>

#if defined(__x86_64__) && defined(__GNUC__)
#include <cpuid.h>
#include <immintrin.h>
#define TAP_EXR_F16C 1
#endif

/* DEFLATE level of the ZIP chunks: readers do not care, and half floats of a
 * sea compress little better at higher levels. */
#ifndef TAP_EXR_ZIP_LEVEL
#define TAP_EXR_ZIP_LEVEL 1
#endif

#define HALF_ONE 0x3c00u /* 1.0 */

static int exr_fail(exr_result_t rv, const char *what, const char *path, char *err, size_t errlen)
{
    snprintf(err, errlen, "%.400s: %s: %s", path, what, exr_get_default_error_message(rv)); /* err: 512 bytes */
    return -1;
}

/* ---- float -> half, rows flipped ------------------------------------------ */

#ifdef TAP_EXR_F16C
__attribute__((target("avx,f16c"))) static void halves_f16c(uint16_t *dst, const float *src, int n)
{
    int i = 0;
    for (; i + 8 <= n; i += 8)
        _mm_storeu_si128((__m128i *)(dst + i),
                         _mm256_cvtps_ph(_mm256_loadu_ps(src + i), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
    for (; i < n; i++) dst[i] = imath_float_to_half(src[i]);
}

/* F16C and AVX, and the OS saving the AVX registers. */
static int have_f16c(void)
{
    unsigned a, b, c, d;
    if (!__get_cpuid(1, &a, &b, &c, &d)) return 0;
    if (!(c & bit_F16C) || !(c & bit_AVX) || !(c & bit_OSXSAVE)) return 0;
    unsigned lo, hi;
    __asm__("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
    return (lo & 6) == 6;
}

static pthread_once_t f16c_once = PTHREAD_ONCE_INIT;
static int f16c;
static void f16c_probe(void) { f16c = have_f16c(); }
#endif

static void halves(uint16_t *dst, const float *src, int n)
{
#ifdef TAP_EXR_F16C
    pthread_once(&f16c_once, f16c_probe);
    if (f16c) { halves_f16c(dst, src, n); return; }
#endif
    for (int i = 0; i < n; i++) dst[i] = imath_float_to_half(src[i]);
}

/* A side x side float plane as halves in the file's order: scanline y = grid row side-1-y
 * (Blender's bottom-up images). */
static void half_plane(uint16_t *dst, const float *src, int side)
{
    for (int y = 0; y < side; y++) halves(dst + (size_t)y * side, src + (size_t)(side - 1 - y) * side, side);
}

/* ---- one file ------------------------------------------------------------- */

/* Low and high bytes of n halves, in blocks of 16 (vector code at -O2). */
static void split_bytes(uint8_t *restrict lo, uint8_t *restrict hi, const uint16_t *restrict src, int n)
{
    int i = 0;
    for (; i + 16 <= n; i += 16)
        for (int j = 0; j < 16; j++) {
            lo[i + j] = (uint8_t)src[i + j];
            hi[i + j] = (uint8_t)(src[i + j] >> 8);
        }
    for (; i < n; i++) {
        lo[i] = (uint8_t)src[i];
        hi[i] = (uint8_t)(src[i] >> 8);
    }
}

/* A ZIP chunk: `split` holds the low bytes of its n halves, then their high
 * bytes; filt (2n bytes) receives the filtered bytes, out (cap bytes) the zlib
 * stream. Returns its length, 0 when it does not fit.
 *
 * The low bytes of smooth data are noise that DEFLATE spends half its time on
 * and shrinks by a few per cent: where fewer than half of them predict
 * exactly (a constant channel, foam's zeros), the stream is one stored block
 * of the low bytes followed by the high bytes compressed (a zlib stream may
 * mix block types; the high bytes do not refer back into the low ones).
 * Either way a standard ZIP chunk, read by any OpenEXR. */
static size_t zip_chunk(struct libdeflate_compressor *z, const uint8_t *restrict split, uint8_t *restrict filt,
                        size_t n, uint8_t *out, size_t cap)
{
    size_t total = 2 * n, same = 0, len, i = 1;
    filt[0] = split[0];
    /* in blocks of 16: the compiler makes vector code of them at -O2 */
    for (; i + 16 <= total; i += 16)
        for (int j = 0; j < 16; j++) filt[i + j] = (uint8_t)(split[i + j] - split[i + j - 1] + 128);
    for (; i < total; i++) filt[i] = (uint8_t)(split[i] - split[i - 1] + 128);
    for (i = 0; i < n; i += 8) same += filt[i] == 128; /* a sample of the low bytes */
    if (cap < 2 + 5 + n + 4) return 0;
    out[0] = 0x78; /* zlib: deflate, 32 KB window, fastest (what libdeflate's level 1 writes) */
    out[1] = 0x01;
    size_t pos = 2;
    if (16 * same >= n || n > 65535) { /* half of the n/8 sampled */
        len = libdeflate_deflate_compress(z, filt, total, out + pos, cap - pos - 4);
    } else {
        out[pos++] = 0x00; /* BFINAL 0, BTYPE 00 (stored), to the byte boundary */
        out[pos++] = (uint8_t)n;
        out[pos++] = (uint8_t)(n >> 8);
        out[pos++] = (uint8_t)~n;
        out[pos++] = (uint8_t)(~n >> 8);
        memcpy(out + pos, filt, n);
        pos += n;
        len = libdeflate_deflate_compress(z, filt + n, n, out + pos, cap - pos - 4);
    }
    if (!len) return 0;
    pos += len;
    uint32_t a = libdeflate_adler32(1, filt, total);
    out[pos++] = (uint8_t)(a >> 24);
    out[pos++] = (uint8_t)(a >> 16);
    out[pos++] = (uint8_t)(a >> 8);
    out[pos++] = (uint8_t)a;
    return pos;
}


/* One RGBA half image from half planes in file order (NULL = constant 1). */
static int write_halves(const char *path, int side, const uint16_t *const rgba[4], const char *const *attrs,
                        struct libdeflate_compressor *z, char *err, size_t errlen)
{
    static const char *const names[4] = {"R", "G", "B", "A"};
    exr_context_t f = NULL;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    int part = 0, r = -1;
    uint8_t *buf = NULL;
    exr_result_t rv = exr_start_write(&f, path, EXR_INTERMEDIATE_TEMP_FILE, &init);
    if (rv != EXR_ERR_SUCCESS) return exr_fail(rv, "cannot create", path, err, errlen);
    if ((rv = exr_add_part(f, "", EXR_STORAGE_SCANLINE, &part)) ||
        (rv = exr_initialize_required_attr_simple(f, part, side, side, EXR_COMPRESSION_ZIP))) {
        exr_fail(rv, "header", path, err, errlen);
        goto out;
    }
    for (int c = 0; c < 4; c++)
        if ((rv = exr_add_channel(f, part, names[c], EXR_PIXEL_HALF, EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1))) {
            exr_fail(rv, "channel", path, err, errlen);
            goto out;
        }
    for (int i = 0; attrs && attrs[i]; i += 2)
        if ((rv = exr_attr_set_string(f, part, attrs[i], attrs[i + 1]))) {
            exr_fail(rv, "attribute", path, err, errlen);
            goto out;
        }
    if ((rv = exr_write_header(f))) {
        exr_fail(rv, "write header", path, err, errlen);
        goto out;
    }
    /* The header's channel order (sorted by name: A B G R). */
    const exr_attr_chlist_t *chl = NULL;
    const uint16_t *plane[4];
    if ((rv = exr_get_channels(f, part, &chl)) || chl->num_channels != 4) {
        exr_fail(rv ? rv : EXR_ERR_INVALID_ATTR, "channels", path, err, errlen);
        goto out;
    }
    for (int k = 0; k < 4; k++) {
        int c = 0;
        while (c < 3 && strcmp(chl->entries[k].name.str, names[c])) c++;
        plane[k] = rgba[c];
    }
    int32_t lines = 1;
    exr_get_scanlines_per_chunk(f, part, &lines);
    size_t most = (size_t)lines * 4 * side, cap = 2 * most + 64 + libdeflate_deflate_compress_bound(z, 2 * most);
    buf = malloc(2 * most + 2 * most + cap); /* split bytes, filtered bytes, the chunk */
    if (!buf) {
        snprintf(err, errlen, "out of memory");
        goto out;
    }
    uint8_t *split = buf, *filt = buf + 2 * most, *chunk = filt + 2 * most;
    for (int y = 0; y < side; y += lines) {
        int nl = side - y < lines ? side - y : lines;
        size_t n = (size_t)nl * 4 * side, k = 0; /* halves in this chunk */
        uint8_t *lo = split, *hi = split + n;
        for (int l = 0; l < nl; l++)
            for (int c = 0; c < 4; c++, k += side) {
                const uint16_t *src = plane[c] ? plane[c] + (size_t)(y + l) * side : NULL;
                if (!src) {
                    memset(lo + k, HALF_ONE & 0xff, side);
                    memset(hi + k, HALF_ONE >> 8, side);
                    continue;
                }
                split_bytes(lo + k, hi + k, src, side);
            }
        size_t len = zip_chunk(z, split, filt, n, chunk, cap);
        if (len == 0 || len >= 2 * n) { /* stored as it is: little-endian halves */
            for (size_t i = 0; i < n; i++) {
                chunk[2 * i] = lo[i];
                chunk[2 * i + 1] = hi[i];
            }
            len = 2 * n;
        }
        if ((rv = exr_write_scanline_chunk(f, part, y, chunk, len))) {
            exr_fail(rv, "chunk", path, err, errlen);
            goto out;
        }
    }
    r = 0;
out:
    rv = exr_finish(&f); /* with a temp file: renamed into place only on success */
    if (r == 0 && rv != EXR_ERR_SUCCESS)
        r = exr_fail(rv, "finish", path, err, errlen);
    free(buf);
    return r;
}

/* ---- a bake frame ----------------------------------------------------------- */

struct bake_ctx {
    const char *dir;
    int frame, side;
    const struct tap_exr_fields *fl;
    const char *const *attrs;     /* the shared attributes, after oceand_field's pair */
    uint16_t *h;                  /* 7 half planes: dx height dz nx ny nz foam */
};

struct bake_half {
    struct bake_ctx *b;
    int which;                    /* 0: disp and vdisp; 1: normal and foam */
    int rc;
    char err[512];
};

enum { P_DX, P_H, P_DZ, P_NX, P_NY, P_NZ, P_FOAM, P_COUNT };

static int bake_file(struct bake_half *w, struct libdeflate_compressor *z, const char *kind,
                     const uint16_t *const rgba[4])
{
    const struct bake_ctx *b = w->b;
    char path[4096];
    if (snprintf(path, sizeof path, "%s/%s_%04d.exr", b->dir, kind, b->frame) >= (int)sizeof path) {
        snprintf(w->err, sizeof w->err, "path too long");
        return -1;
    }
    const char *attrs[20] = {"oceand_field", kind};
    for (int i = 0; b->attrs[i] && i < 16; i++) attrs[2 + i] = b->attrs[i];
    return write_halves(path, b->side, rgba, attrs, z, w->err, sizeof w->err);
}

/* One of the two halves of a frame's work: its planes, then its two files. */
static void *bake_half_run(void *arg)
{
    struct bake_half *w = arg;
    const struct bake_ctx *b = w->b;
    const struct tap_exr_fields *fl = b->fl;
    int side = b->side;
    size_t count = (size_t)side * side;
    uint16_t *P[P_COUNT];
    for (int k = 0; k < P_COUNT; k++) P[k] = b->h + (size_t)k * count;
    struct libdeflate_compressor *z = libdeflate_alloc_compressor(TAP_EXR_ZIP_LEVEL);
    if (!z) {
        snprintf(w->err, sizeof w->err, "out of memory");
        w->rc = -1;
        return NULL;
    }
    if (w->which == 0) {
        half_plane(P[P_DX], fl->dx, side);
        half_plane(P[P_H], fl->height, side);
        half_plane(P[P_DZ], fl->dz, side);
        /* vdisp: the displacement in Blender's axes (X = x, Y = z, Z = height) for
         * a Displace modifier in RGB to XYZ mode (tools/blender/oceand_bake.py). */
        const uint16_t *disp[4] = {P[P_DX], P[P_H], P[P_DZ], NULL}, *vdisp[4] = {P[P_DX], P[P_DZ], P[P_H], NULL};
        w->rc = bake_file(w, z, "disp", disp);
        if (!w->rc) w->rc = bake_file(w, z, "vdisp", vdisp);
    } else {
        float *row = malloc(4 * (size_t)side * sizeof *row);
        if (!row) {
            snprintf(w->err, sizeof w->err, "out of memory");
            w->rc = -1;
        } else {
            float *nx = row, *ny = nx + side, *nz = ny + side, *foam = nz + side;
            for (int y = 0; y < side; y++) {
                size_t g = (size_t)(side - 1 - y) * side, o = (size_t)y * side; /* file scanline y = grid row side-1-y */
                for (int x = 0; x < side; x++) {
                    /* Blender's baked normal: the undisplaced surface's, y up. */
                    double sx = fl->slope_x[g + x], sz = fl->slope_z[g + x], l = sqrt(sx * sx + 1 + sz * sz);
                    nx[x] = (float)(-sx / l);
                    ny[x] = (float)(1 / l);
                    nz[x] = (float)(-sz / l);
                    float j = 1.0f - fl->jacobian[g + x];
                    foam[x] = j < 0 ? 0 : j > 1 ? 1 : j;
                }
                halves(P[P_NX] + o, nx, side);
                halves(P[P_NY] + o, ny, side);
                halves(P[P_NZ] + o, nz, side);
                halves(P[P_FOAM] + o, foam, side);
            }
            free(row);
            const uint16_t *normal[4] = {P[P_NX], P[P_NY], P[P_NZ], NULL};
            const uint16_t *foam4[4] = {P[P_FOAM], P[P_FOAM], P[P_FOAM], NULL};
            w->rc = bake_file(w, z, "normal", normal);
            if (!w->rc) w->rc = bake_file(w, z, "foam", foam4);
        }
    }
    libdeflate_free_compressor(z);
    return NULL;
}

int tap_exr_bake(const char *dir, int frame, int side, const struct tap_exr_fields *fl, const struct tap_meta *m,
                 int cascades, char *err, size_t errlen)
{
    size_t count = (size_t)side * side;
    uint16_t *h = malloc(P_COUNT * count * sizeof *h);
    if (!h) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    char seq[32], t[40], pv[16], L[32], ox[40], oz[40], nc[8];
    snprintf(seq, sizeof seq, "%llu", (unsigned long long)m->seq);
    snprintf(t, sizeof t, "%.17g", m->sim_time);
    snprintf(pv, sizeof pv, "%u", (unsigned)m->params_version);
    snprintf(L, sizeof L, "%.9g", (double)m->patch_size);
    snprintf(ox, sizeof ox, "%.17g", m->origin_x);
    snprintf(oz, sizeof oz, "%.17g", m->origin_z);
    snprintf(nc, sizeof nc, "%d", cascades);
    const char *attrs[] = {"oceand_seq", seq, "oceand_sim_time", t, "oceand_params_version", pv,
                           "oceand_patch_size", L, "oceand_origin_x", ox, "oceand_origin_z", oz,
                           "oceand_cascades", nc, NULL};
    struct bake_ctx b = {.dir = dir, .frame = frame, .side = side, .fl = fl, .attrs = attrs, .h = h};
    /* Two threads, each its planes and two files (the halves, ZIP and the normals
     * are most of a bake frame's time). */
    struct bake_half w[2] = {{.b = &b, .which = 0}, {.b = &b, .which = 1}};
    pthread_t th;
    int threaded = pthread_create(&th, NULL, bake_half_run, &w[1]) == 0;
    bake_half_run(&w[0]);
    if (!threaded) bake_half_run(&w[1]);
    else pthread_join(th, NULL);
    free(h);
    for (int k = 0; k < 2; k++)
        if (w[k].rc) {
            snprintf(err, errlen, "%s", w[k].err);
            return -1;
        }
    char path[4096];
    snprintf(path, sizeof path, "%s/frame_%04d.json", dir, frame);
    FILE *f = fopen(path, "w");
    if (!f) {
        snprintf(err, errlen, "%s: %s", path, strerror(errno));
        return -1;
    }
    int ok = fprintf(f,
                     "{\n  \"frame\": %d,\n  \"files\": [\"disp_%04d.exr\", \"normal_%04d.exr\", \"foam_%04d.exr\", "
                     "\"vdisp_%04d.exr\"],\n"
                     "  \"seq\": %s,\n  \"sim_time\": %s,\n  \"params_version\": %s,\n  \"n\": %d,\n  \"lod\": %d,\n"
                     "  \"side\": %d,\n  \"patch_size\": %s,\n  \"origin\": [%s, %s],\n  \"cascades\": %d,\n"
                     "  \"bound\": %.9g,\n  \"server_time_us\": %llu,\n"
                     "  \"layout\": \"blender ocean bake: half RGBA, ZIP, first scanline = last row (z = side-1)\"\n}\n",
                     frame, frame, frame, frame, frame, seq, t, pv, m->n, m->lod, side, L, ox, oz, cascades,
                     (double)m->bound,
                     (unsigned long long)m->server_time_us) > 0;
    if (fclose(f) != 0 || !ok) {
        snprintf(err, errlen, "%s: write failed", path);
        return -1;
    }
    return 0;
}

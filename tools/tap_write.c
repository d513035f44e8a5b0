/* tap_write.c — see tap_write.h. Little-endian hosts only (x86, arm64):
 * float32 samples are written as they lie in memory. */
#include "tap_write.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

_Static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "ocean-tap writes float32 as little-endian");

int tap_format_from_name(const char *name)
{
    if (!strcmp(name, "npy")) return TAP_NPY;
    if (!strcmp(name, "raw")) return TAP_RAW;
    if (!strcmp(name, "pgm") || !strcmp(name, "pgm16")) return TAP_PGM16;
    if (!strcmp(name, "pgm8")) return TAP_PGM8;
    if (!strcmp(name, "exr")) return TAP_EXR;
    return -1;
}

const char *tap_format_ext(enum tap_format f)
{
    switch (f) {
    case TAP_NPY: return "npy";
    case TAP_RAW: return "f32";
    case TAP_EXR: return "exr";
    default: return "pgm";
    }
}

/* Close f and report the first error of the write sequence, keeping errno. */
static int finish(FILE *f, int ok)
{
    int saved = errno;
    if (fclose(f) != 0 && ok) return -1;
    if (!ok) { errno = saved ? saved : EIO; return -1; }
    return 0;
}

/* NumPy format v1.0: magic, version, u16 header length, a Python dict literal
 * padded with spaces and ended by '\n' so that the data starts 64-aligned. */
static int write_npy(const char *path, const float *data, int side)
{
    char dict[128];
    int len = snprintf(dict, sizeof dict,
                       "{'descr': '<f4', 'fortran_order': False, 'shape': (%d, %d), }", side, side);
    int total = 10 + len + 1;
    int pad = (64 - total % 64) % 64;
    char header[256];
    memcpy(header, "\x93NUMPY\x01\x00", 8);
    int hlen = len + pad + 1;
    header[8] = (char)(hlen & 0xff);
    header[9] = (char)(hlen >> 8);
    memcpy(header + 10, dict, (size_t)len);
    memset(header + 10 + len, ' ', (size_t)pad);
    header[10 + len + pad] = '\n';

    FILE *f = fopen(path, "wb");
    if (!f) return -1;
    size_t count = (size_t)side * (size_t)side;
    int ok = fwrite(header, 1, (size_t)(10 + hlen), f) == (size_t)(10 + hlen) &&
             fwrite(data, sizeof(float), count, f) == count;
    return finish(f, ok);
}

/* Sidecar of every output file: same name, ".json" in place of the
 * extension, with the frame's header (seq, sim_time, params_version, ...). */
static int write_sidecar(const char *path, const char *format, const char *dtype, int side, const struct tap_meta *m,
                         const char *extra)
{
    char json[4096];
    const char *dot = strrchr(path, '.');
    size_t stem = dot ? (size_t)(dot - path) : strlen(path);
    if (stem + 6 > sizeof json) { errno = ENAMETOOLONG; return -1; }
    memcpy(json, path, stem);
    strcpy(json + stem, ".json");
    const char *base = strrchr(path, '/');
    base = base ? base + 1 : path;
    char casc[16];
    if (m->cascade == TAP_CASCADE_SUM) snprintf(casc, sizeof casc, "\"sum\"");
    else snprintf(casc, sizeof casc, "%d", m->cascade);
    FILE *f = fopen(json, "w");
    if (!f) return -1;
    int ok = fprintf(f,
                 "{\n  \"file\": \"%s\",\n  \"format\": \"%s\",\n  \"dtype\": \"%s\",\n"
                 "  \"byte_order\": \"%s\",\n"
                 "  \"shape\": [%d, %d],\n  \"order\": \"row-major, rows are z, columns are x\",\n"
                 "  \"field\": \"%s\",\n  \"seq\": %llu,\n  \"sim_time\": %.17g,\n"
                 "  \"params_version\": %u,\n  \"n\": %d,\n  \"lod\": %d,\n"
                 "  \"patch_size\": %.9g,\n  \"spacing\": %.9g,\n  \"bound\": %.9g,\n"
                 "  \"server_time_us\": %llu,\n  \"cascade\": %s,\n  \"origin\": [%.17g, %.17g]%s\n}\n",
                 base, format, dtype, strcmp(dtype, "uint16") ? "little" : "big", side, side, m->field,
                 (unsigned long long)m->seq, m->sim_time,
                 (unsigned)m->params_version, m->n, m->lod, (double)m->patch_size,
                 (double)m->patch_size / side, (double)m->bound,
                 (unsigned long long)m->server_time_us, casc, m->origin_x, m->origin_z, extra ? extra : "") > 0;
    return finish(f, ok);
}

static int write_raw(const char *path, const float *data, int side, const struct tap_meta *m)
{
    FILE *f = fopen(path, "wb");
    if (!f) return -1;
    size_t count = (size_t)side * (size_t)side;
    int ok = fwrite(data, sizeof(float), count, f) == count;
    if (finish(f, ok) != 0) return -1;
    return write_sidecar(path, "raw", "float32", side, m, NULL);
}

/* PGM P5: maxval 255 (one byte) or 65535 (two bytes, big-endian as the
 * format requires). The min/max used for normalising go in a comment. */
static int write_pgm(const char *path, const float *data, int side, int bits, const struct tap_meta *m)
{
    size_t count = (size_t)side * (size_t)side;
    float lo = INFINITY, hi = -INFINITY;
    for (size_t i = 0; i < count; i++) {
        if (data[i] < lo) lo = data[i];
        if (data[i] > hi) hi = data[i];
    }
    double range = hi > lo ? (double)hi - lo : 1.0;
    unsigned maxval = bits == 8 ? 255u : 65535u;
    size_t bpp = bits == 8 ? 1 : 2;
    unsigned char *px = malloc(count * bpp);
    if (!px) return -1;
    for (size_t i = 0; i < count; i++) {
        unsigned v = (unsigned)lround(((double)data[i] - lo) / range * maxval);
        if (bpp == 1) px[i] = (unsigned char)v;
        else { px[2 * i] = (unsigned char)(v >> 8); px[2 * i + 1] = (unsigned char)(v & 0xff); }
    }
    FILE *f = fopen(path, "wb");
    if (!f) { free(px); return -1; }
    int ok = fprintf(f, "P5\n# min=%.9g max=%.9g seq=%llu sim_time=%.17g params_version=%u\n%d %d\n%u\n",
                     (double)lo, (double)hi, (unsigned long long)m->seq, m->sim_time, (unsigned)m->params_version,
                     side, side, maxval) > 0 &&
             fwrite(px, bpp, count, f) == count;
    free(px);
    if (finish(f, ok) != 0) return -1;
    char extra[128];
    snprintf(extra, sizeof extra, ",\n  \"min\": %.9g,\n  \"max\": %.9g,\n  \"maxval\": %u", (double)lo, (double)hi,
             maxval);
    return write_sidecar(path, bits == 8 ? "pgm8" : "pgm", bits == 8 ? "uint8" : "uint16", side, m, extra);
}

int tap_write_field(enum tap_format fmt, const char *path, const float *data, int side,
                    const struct tap_meta *meta)
{
    errno = 0;
    switch (fmt) {
    case TAP_NPY:
        if (write_npy(path, data, side) != 0) return -1;
        return write_sidecar(path, "npy", "float32", side, meta, NULL);
    case TAP_RAW: return write_raw(path, data, side, meta);
    case TAP_PGM16: return write_pgm(path, data, side, 16, meta);
    case TAP_PGM8: return write_pgm(path, data, side, 8, meta);
    case TAP_EXR: break; /* whole frames: tap_exr_bake */
    }
    errno = EINVAL;
    return -1;
}

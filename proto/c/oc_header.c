/* oc_header.c — frame/tile header (de)serialisation, names, error strings,
 * growable buffer. Every read checks its length first (PROTOCOL.md §3). */
#include "oc_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static const char *const field_names[OC_FIELD_COUNT] = {
    "height", "dx", "dz", "slope_x", "slope_z", "jacobian", "foam",
};

const char *oc_strerror(int err)
{
    switch (err) {
    case OC_OK: return "ok";
    case OC_E_TRUNCATED: return "truncated: input shorter than its headers say";
    case OC_E_MAGIC: return "bad magic: not an oceand frame";
    case OC_E_VERSION: return "unsupported protocol version";
    case OC_E_CORRUPT: return "corrupt: inconsistent header fields or payload";
    case OC_E_TOO_LARGE: return "too large: dimensions beyond protocol limits";
    case OC_E_NOMEM: return "out of memory";
    case OC_E_ARG: return "invalid argument";
    case OC_E_REFERENCE: return "reference missing: a predicted tile names frames this decoder has not decoded";
    default: return "unknown error";
    }
}

const char *oc_field_name(enum oc_field f)
{
    return (unsigned)f < OC_FIELD_COUNT ? field_names[f] : "unknown";
}

int oc_field_from_name(const char *name)
{
    for (int i = 0; name && i < OC_FIELD_COUNT; i++)
        if (strcmp(name, field_names[i]) == 0) return i;
    return -1;
}

int oc_buf_reserve(struct oc_buf *b, size_t extra)
{
    if (extra > SIZE_MAX - b->len) return OC_E_NOMEM;
    size_t need = b->len + extra;
    if (need <= b->cap) return OC_OK;
    size_t cap = b->cap ? b->cap : 4096;
    while (cap < need) cap = cap > SIZE_MAX / 2 ? need : cap * 2;
    uint8_t *p = realloc(b->data, cap);
    if (!p) return OC_E_NOMEM;
    b->data = p;
    b->cap = cap;
    return OC_OK;
}

void oc_buf_free(struct oc_buf *b)
{
    free(b->data);
    b->data = NULL;
    b->len = b->cap = 0;
}

/* ---- little-endian primitives (explicit bytes: no alignment or host-order assumptions) */
void oc_put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
void oc_put_u32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i));
}
void oc_put_u64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++) p[i] = (uint8_t)(v >> (8 * i));
}
void oc_put_f32(uint8_t *p, float v) { uint32_t u; memcpy(&u, &v, 4); oc_put_u32(p, u); }
void oc_put_f64(uint8_t *p, double v) { uint64_t u; memcpy(&u, &v, 8); oc_put_u64(p, u); }
uint16_t oc_get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
uint32_t oc_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
uint64_t oc_get_u64(const uint8_t *p) { return (uint64_t)oc_get_u32(p) | (uint64_t)oc_get_u32(p + 4) << 32; }
float oc_get_f32(const uint8_t *p) { uint32_t u = oc_get_u32(p); float v; memcpy(&v, &u, 4); return v; }
double oc_get_f64(const uint8_t *p) { uint64_t u = oc_get_u64(p); double v; memcpy(&v, &u, 8); return v; }

static int is_pow2(unsigned v) { return v && !(v & (v - 1)); }

void oc_frame_header_write(uint8_t dst[OC_FRAME_HEADER_SIZE], const struct oc_frame_header *h)
{
    memcpy(dst, OC_MAGIC, 4);
    oc_put_u16(dst + 4, OC_PROTO_VERSION);
    oc_put_u16(dst + 6, OC_FRAME_HEADER_SIZE);
    oc_put_u64(dst + 8, h->seq);
    oc_put_f64(dst + 16, h->sim_time);
    oc_put_u32(dst + 24, h->params_version);
    oc_put_u16(dst + 28, h->n);
    oc_put_u16(dst + 30, h->tile_size);
    oc_put_f32(dst + 32, h->patch_size);
    oc_put_u16(dst + 36, h->tile_count);
    oc_put_u16(dst + 38, h->flags);
    oc_put_u64(dst + 40, h->server_time_us);
}

int oc_frame_header_parse(const uint8_t *src, size_t len, struct oc_frame_header *h, size_t *hsize)
{
    if (!src || len < 8) return OC_E_TRUNCATED;
    if (memcmp(src, OC_MAGIC, 4) != 0) return OC_E_MAGIC;
    if (oc_get_u16(src + 4) != OC_PROTO_VERSION) return OC_E_VERSION;
    size_t hs = oc_get_u16(src + 6);
    /* Larger headers are a compatible extension: readers skip the extra bytes. */
    if (hs < OC_FRAME_HEADER_SIZE || hs % 8) return OC_E_CORRUPT;
    if (len < hs) return OC_E_TRUNCATED;
    struct oc_frame_header t;
    t.seq = oc_get_u64(src + 8);
    t.sim_time = oc_get_f64(src + 16);
    t.params_version = oc_get_u32(src + 24);
    t.n = oc_get_u16(src + 28);
    t.tile_size = oc_get_u16(src + 30);
    t.patch_size = oc_get_f32(src + 32);
    t.tile_count = oc_get_u16(src + 36);
    t.flags = oc_get_u16(src + 38);
    t.server_time_us = oc_get_u64(src + 40);
    if (t.n > OC_MAX_N) return OC_E_TOO_LARGE;
    if (!is_pow2(t.n) || !is_pow2(t.tile_size) || t.tile_size > t.n) return OC_E_CORRUPT;
    if (!isfinite(t.sim_time) || !isfinite(t.patch_size) || !(t.patch_size > 0)) return OC_E_CORRUPT;
    *h = t;
    if (hsize) *hsize = hs;
    return OC_OK;
}

int oc_frame_header_read(const uint8_t *src, size_t len, struct oc_frame_header *h)
{
    return oc_frame_header_parse(src, len, h, NULL);
}

void oc_tile_header_write(uint8_t *dst, const struct oc_tile_header *t)
{
    dst[0] = t->field; dst[1] = t->lod; dst[2] = t->codec; dst[3] = t->flags;
    oc_put_u16(dst + 4, t->tile_x);
    oc_put_u16(dst + 6, t->tile_z);
    oc_put_u16(dst + 8, t->width);
    oc_put_u16(dst + 10, t->height);
    oc_put_f32(dst + 12, t->bound);
    oc_put_f64(dst + 16, t->offset);
    oc_put_f64(dst + 24, t->scale);
    oc_put_u32(dst + 32, t->payload_len);
    oc_put_u32(dst + 36, 0);
}

int oc_tile_header_parse(const uint8_t *src, size_t len, const struct oc_frame_header *fh,
                         struct oc_tile_header *t)
{
    if (len < OC_TILE_HEADER_SIZE) return OC_E_TRUNCATED;
    t->field = src[0]; t->lod = src[1]; t->codec = src[2]; t->flags = src[3];
    t->tile_x = oc_get_u16(src + 4);
    t->tile_z = oc_get_u16(src + 6);
    t->width = oc_get_u16(src + 8);
    t->height = oc_get_u16(src + 10);
    t->bound = oc_get_f32(src + 12);
    t->offset = oc_get_f64(src + 16);
    t->scale = oc_get_f64(src + 24);
    t->payload_len = oc_get_u32(src + 32);
    if (t->field >= OC_FIELD_COUNT) return OC_E_CORRUPT;
    if (t->lod > OC_MAX_LOD) return OC_E_CORRUPT;
    unsigned side = (unsigned)fh->tile_size >> t->lod;
    if (side == 0 || t->width != side || t->height != side) return OC_E_CORRUPT;
    unsigned grid = (unsigned)fh->n / fh->tile_size;
    if (t->tile_x >= grid || t->tile_z >= grid) return OC_E_CORRUPT;
    if (!isfinite(t->bound) || t->bound < 0) return OC_E_CORRUPT;
    switch (t->codec) {
    case OC_CODEC_RAW_F32:
        break;
    case OC_CODEC_QUANT_LORENZO:
    case OC_CODEC_QUANT_LORENZO_ZSTD:
    case OC_CODEC_TEMPORAL:
        if (!isfinite(t->offset) || !isfinite(t->scale) || !(t->scale > 0)) return OC_E_CORRUPT;
        break;
    default:
        return OC_E_CORRUPT;
    }
    if (t->payload_len > len - OC_TILE_HEADER_SIZE) return OC_E_TRUNCATED;
    return OC_OK;
}

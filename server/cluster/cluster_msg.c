/* cluster_msg.c — the two binary message formats of the cluster (layer
 * parts "OCNL", envelopes "OCNE" and the demand body they carry) and the
 * module's error texts. Pure: no NATS, no threads, no globals; fuzzed by
 * fuzz/fuzz_cluster.c. Formats are described in cluster.h and
 * docs/scaling.md. Hand-written because they are two fixed little-endian
 * headers, like proto/c's frame header (a schema library would add a
 * dependency for 20 fields). */
#include "cluster.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "oc_proto.h"

_Static_assert(CL_FIELDS == OC_FIELD_COUNT, "cluster field count follows the protocol");
_Static_assert(CL_LODS == OC_MAX_LOD + 1, "cluster LOD count follows the protocol");
_Static_assert(CL_KEYS <= CL_KEY_BYTES * 8, "key bitmap too small");

const char *cl_strerror(int err)
{
    switch (err) {
    case CL_OK: return "ok";
    case CL_E_TRUNCATED: return "truncated: shorter than its headers say";
    case CL_E_MAGIC: return "bad magic: not a cluster message";
    case CL_E_VERSION: return "unsupported cluster message version";
    case CL_E_CORRUPT: return "corrupt: inconsistent fields";
    case CL_E_TOO_LARGE: return "too large";
    case CL_E_NOMEM: return "out of memory";
    case CL_E_ARG: return "invalid argument";
    case CL_E_FULL: return "table or queue full";
    case CL_E_NOT_CONNECTED: return "not connected to NATS";
    case CL_E_TIMEOUT: return "no reply in time";
    case CL_E_NO_RESPONDERS: return "no responders: the simulation is not running";
    case CL_E_NATS: return "NATS error";
    case CL_E_LOST: return "another simulation holds the lease";
    case CL_E_NO_JETSTREAM: return "no JetStream on the NATS server";
    default: return "unknown error";
    }
}

/* ---- little-endian helpers (explicit bytes: no alignment assumptions) ---- */
static void put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i)); }
static void put64(uint8_t *p, uint64_t v) { for (int i = 0; i < 8; i++) p[i] = (uint8_t)(v >> (8 * i)); }
static void putf32(uint8_t *p, float v) { uint32_t u; memcpy(&u, &v, 4); put32(p, u); }
static void putf64(uint8_t *p, double v) { uint64_t u; memcpy(&u, &v, 8); put64(p, u); }
static uint16_t get16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }
static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static uint64_t get64(const uint8_t *p) { return (uint64_t)get32(p) | (uint64_t)get32(p + 4) << 32; }
static float getf32(const uint8_t *p) { uint32_t u = get32(p); float v; memcpy(&v, &u, 4); return v; }
static double getf64(const uint8_t *p) { uint64_t u = get64(p); double v; memcpy(&v, &u, 8); return v; }

/* ---- layer parts ---- */

uint32_t cl_part_off(const struct cl_layer_part *p, int i) { return get32(p->off + 4 * (size_t)i); }

size_t cl_layer_part_size(int tile_count, size_t data_len)
{
    return CL_LAYER_HEADER_SIZE + 4 * ((size_t)tile_count + 1) + data_len;
}

/* The fields every part must satisfy on its own (writer and reader). */
static int info_check(const struct cl_layer_info *h)
{
    if (h->n < 1 || h->n > OC_MAX_N || h->tile_size < 1 || h->tile_size > h->n || h->n % h->tile_size)
        return CL_E_CORRUPT;
    if (h->tiles_per_side != h->n / h->tile_size || h->tiles_per_side > CL_MAX_TILES_PER_SIDE)
        return CL_E_CORRUPT;
    if (h->field >= CL_FIELDS || h->lod >= CL_LODS || h->bound_index >= CL_BOUNDS || (h->tile_size >> h->lod) < 1)
        return CL_E_CORRUPT;
    if (!isfinite(h->sim_time) || !isfinite(h->patch_size) || !(h->patch_size > 0) ||
        (h->layer_flags & ~(1 | CL_LAYER_SHARED | CL_LAYER_INTRA)))
        return CL_E_CORRUPT;
    if ((h->layer_flags & CL_LAYER_INTRA) && !(h->layer_flags & CL_LAYER_SHARED))
        return CL_E_CORRUPT;
    if (h->need > CL_LAYER_MAX_NEED || (h->need && !(h->layer_flags & CL_LAYER_SHARED)) || !h->epoch)
        return CL_E_CORRUPT;
    if ((h->layer_flags & CL_LAYER_SHARED) && h->encoded_lod != h->lod)
        return CL_E_CORRUPT; /* a temporal layer is never degraded to a coarser LOD (frame_job.c) */
    if (h->ncascades < 1 || h->ncascades > CL_CASCADES || h->cascade >= h->ncascades)
        return CL_E_CORRUPT;
    if (h->encoded_lod < h->lod || h->encoded_lod >= CL_LODS || (h->tile_size >> h->encoded_lod) < 1)
        return CL_E_CORRUPT;
    if (!cl_bit(h->encoded, cl_info_key(h)))
        return CL_E_CORRUPT; /* a layer the sim says it did not encode */
    for (int k = CL_KEYS; k < CL_KEY_BYTES * 8; k++)
        if (cl_bit(h->encoded, k))
            return CL_E_CORRUPT;
    return CL_OK;
}

/* Tile framing as the WebSocket frame will carry it: field, encoded lod,
 * cascade, and header + payload_len == the span the offsets give it. */
static int tile_check(const uint8_t *t, uint32_t span, const struct cl_layer_info *h)
{
    if (span < OC_TILE_HEADER_SIZE || t[0] != h->field || t[1] != h->encoded_lod || t[3] != h->cascade)
        return CL_E_CORRUPT;
    if ((uint64_t)OC_TILE_HEADER_SIZE + get32(t + 32) != span)
        return CL_E_CORRUPT;
    return CL_OK;
}

bool cl_layer_info_valid(const struct cl_layer_info *info) { return info && info_check(info) == CL_OK; }

long cl_layer_part_write(uint8_t *dst, size_t cap, const struct cl_layer_info *info,
                         int tile_first, int tile_count, const uint8_t *data, const uint32_t *tile_off)
{
    if (!dst || !info || !tile_off || (!data && tile_off[0] != 0))
        return CL_E_ARG;
    int rc = info_check(info);
    if (rc)
        return CL_E_ARG;
    int total = cl_layer_tiles(info), sec = info->tiles_per_side * info->tiles_per_side;
    if (tile_first < 0 || tile_count < 1 || tile_first > total - tile_count ||
        tile_first / sec != (tile_first + tile_count - 1) / sec)
        return CL_E_ARG; /* beyond the layer, or across two sections */
    int local = tile_first % sec;
    tile_off += local; /* the section's offsets, from this part's first tile on */
    uint32_t base = tile_off[0], end = tile_off[tile_count];
    if (end < base || end - base > CL_MAX_LAYER_BYTES)
        return CL_E_ARG;
    size_t size = cl_layer_part_size(tile_count, end - base);
    if (size > cap)
        return CL_E_TOO_LARGE;
    uint8_t *p = dst;
    memcpy(p, CL_LAYER_MAGIC, 4);
    put16(p + 4, CL_LAYER_VERSION);
    put16(p + 6, CL_LAYER_HEADER_SIZE);
    put64(p + 8, info->seq);
    putf64(p + 16, info->sim_time);
    put32(p + 24, info->params_version);
    put16(p + 28, info->n);
    put16(p + 30, info->tile_size);
    putf32(p + 32, info->patch_size);
    put16(p + 36, info->frame_flags);
    p[38] = info->field;
    p[39] = info->lod;
    p[40] = info->bound_index;
    p[41] = info->layer_flags;
    put16(p + 42, info->tiles_per_side);
    put16(p + 44, (uint16_t)tile_first);
    put16(p + 46, (uint16_t)tile_count);
    put64(p + 48, info->server_time_us);
    put32(p + 56, end - base);
    p[60] = info->cascade;
    p[61] = info->ncascades;
    p[62] = info->encoded_lod;
    p[63] = info->need;
    memcpy(p + 64, info->encoded, CL_KEY_BYTES);
    put64(p + 64 + CL_KEY_BYTES, info->epoch);
    uint8_t *off = p + CL_LAYER_HEADER_SIZE;
    for (int i = 0; i <= tile_count; i++) {
        uint32_t a = tile_off[i];
        if (a < base || a > end || (i > 0 && a < tile_off[i - 1]))
            return CL_E_ARG;
        put32(off + 4 * i, a - base);
    }
    if (end > base)
        memcpy(off + 4 * ((size_t)tile_count + 1), data + base, end - base);
    return (long)size;
}

int cl_layer_part_tiles(const uint32_t *tile_off, int tile_first, int tiles_total, size_t max_payload)
{
    int n = 0;
    while (tile_first + n < tiles_total &&
           cl_layer_part_size(n + 1, (size_t)tile_off[tile_first + n + 1] - tile_off[tile_first]) <= max_payload &&
           n < 65535)
        n++;
    return n;
}

int cl_layer_part_parse(const uint8_t *msg, size_t len, struct cl_layer_part *out)
{
    if (!msg || !out)
        return CL_E_ARG;
    if (len < 8)
        return CL_E_TRUNCATED;
    if (memcmp(msg, CL_LAYER_MAGIC, 4) != 0)
        return CL_E_MAGIC;
    if (get16(msg + 4) != CL_LAYER_VERSION)
        return CL_E_VERSION;
    size_t hs = get16(msg + 6);
    if (hs < CL_LAYER_HEADER_SIZE)
        return CL_E_CORRUPT;
    if (len < hs)
        return CL_E_TRUNCATED;
    struct cl_layer_part p;
    memset(&p, 0, sizeof p);
    struct cl_layer_info *h = &p.info;
    h->seq = get64(msg + 8);
    h->sim_time = getf64(msg + 16);
    h->params_version = get32(msg + 24);
    h->n = get16(msg + 28);
    h->tile_size = get16(msg + 30);
    h->patch_size = getf32(msg + 32);
    h->frame_flags = get16(msg + 36);
    h->field = msg[38];
    h->lod = msg[39];
    h->bound_index = msg[40];
    h->layer_flags = msg[41];
    h->tiles_per_side = get16(msg + 42);
    p.tile_first = get16(msg + 44);
    p.tile_count = get16(msg + 46);
    h->server_time_us = get64(msg + 48);
    p.data_len = get32(msg + 56);
    h->cascade = msg[60];
    h->ncascades = msg[61];
    h->encoded_lod = msg[62];
    h->need = msg[63];
    memcpy(h->encoded, msg + 64, CL_KEY_BYTES);
    h->epoch = get64(msg + 64 + CL_KEY_BYTES);
    int rc = info_check(h);
    if (rc)
        return rc;
    int total = cl_layer_tiles(h), sec = h->tiles_per_side * h->tiles_per_side;
    if (p.tile_count < 1 || p.tile_first >= total || p.tile_count > total - p.tile_first ||
        p.tile_first / sec != (p.tile_first + p.tile_count - 1) / sec)
        return CL_E_CORRUPT; /* beyond the layer, or across its sections */
    if (p.data_len > CL_MAX_LAYER_BYTES)
        return CL_E_TOO_LARGE;
    size_t offs = 4 * ((size_t)p.tile_count + 1);
    if (len - hs < offs || len - hs - offs < p.data_len)
        return CL_E_TRUNCATED;
    if (len - hs - offs != p.data_len)
        return CL_E_CORRUPT; /* bytes after the last tile */
    p.off = msg + hs;
    p.data = msg + hs + offs;
    if (cl_part_off(&p, 0) != 0 || cl_part_off(&p, p.tile_count) != p.data_len)
        return CL_E_CORRUPT;
    for (int i = 0; i < p.tile_count; i++) {
        uint32_t a = cl_part_off(&p, i), b = cl_part_off(&p, i + 1);
        if (b < a || b > p.data_len)
            return CL_E_CORRUPT;
        if ((rc = tile_check(p.data + a, b - a, h)))
            return rc;
    }
    *out = p;
    return CL_OK;
}

void cl_layer_free(struct cl_layer *l)
{
    if (!l)
        return;
    free(l->data);
    free(l->tile_off);
    free(l);
}

/* ---- envelopes ---- */

static bool name_ok(const char *s, size_t len)
{
    if (len >= CL_NAME_MAX)
        return false;
    for (size_t i = 0; i < len; i++)
        if (s[i] < 0x21 || s[i] > 0x7e)
            return false;
    return true;
}

size_t cl_envelope_size(const char *origin, const char *by, size_t body_len)
{
    return CL_ENV_HEADER + (origin ? strlen(origin) : 0) + (by ? strlen(by) : 0) + body_len;
}

long cl_envelope_write(uint8_t *dst, size_t cap, enum cl_kind kind, const char *origin, const char *by,
                       const void *body, size_t body_len)
{
    origin = origin ? origin : "";
    by = by ? by : "";
    size_t ol = strlen(origin), bl = strlen(by);
    if (!dst || kind < CL_KIND_CTL || kind > CL_KIND_BODY_SECTION || !name_ok(origin, ol) || !name_ok(by, bl) ||
        body_len > CL_BODY_MAX || (body_len && !body))
        return CL_E_ARG;
    size_t size = CL_ENV_HEADER + ol + bl + body_len;
    if (size > cap)
        return CL_E_TOO_LARGE;
    memcpy(dst, CL_ENV_MAGIC, 4);
    dst[4] = CL_ENV_VERSION;
    dst[5] = (uint8_t)kind;
    dst[6] = (uint8_t)ol;
    dst[7] = (uint8_t)bl;
    put32(dst + 8, (uint32_t)body_len);
    memcpy(dst + CL_ENV_HEADER, origin, ol);
    memcpy(dst + CL_ENV_HEADER + ol, by, bl);
    if (body_len)
        memcpy(dst + CL_ENV_HEADER + ol + bl, body, body_len);
    return (long)size;
}

int cl_envelope_parse(const uint8_t *msg, size_t len, struct cl_envelope *out)
{
    if (!msg || !out)
        return CL_E_ARG;
    if (len < CL_ENV_HEADER)
        return CL_E_TRUNCATED;
    if (memcmp(msg, CL_ENV_MAGIC, 4) != 0)
        return CL_E_MAGIC;
    if (msg[4] != CL_ENV_VERSION)
        return CL_E_VERSION;
    unsigned kind = msg[5];
    size_t ol = msg[6], bl = msg[7];
    uint32_t body_len = get32(msg + 8);
    if (kind < CL_KIND_CTL || kind > CL_KIND_BODY_SECTION)
        return CL_E_CORRUPT;
    if (body_len > CL_BODY_MAX)
        return CL_E_TOO_LARGE;
    size_t need = CL_ENV_HEADER + ol + bl + (size_t)body_len;
    if (len < need)
        return CL_E_TRUNCATED;
    if (len > need)
        return CL_E_CORRUPT;
    const char *o = (const char *)msg + CL_ENV_HEADER, *b = o + ol;
    if (!name_ok(o, ol) || !name_ok(b, bl))
        return CL_E_CORRUPT;
    out->kind = (enum cl_kind)kind;
    memcpy(out->origin, o, ol);
    out->origin[ol] = 0;
    memcpy(out->by, b, bl);
    out->by[bl] = 0;
    out->body = msg + CL_ENV_HEADER + ol + bl;
    out->body_len = body_len;
    return CL_OK;
}

void cl_demand_body_write(uint8_t dst[CL_DEMAND_BODY], uint32_t ttl_ms, const uint8_t bits[CL_KEY_BYTES])
{
    put32(dst, ttl_ms);
    memcpy(dst + 4, bits, CL_KEY_BYTES);
}

int cl_demand_body_parse(const uint8_t *body, size_t len, uint32_t *ttl_ms, uint8_t bits[CL_KEY_BYTES])
{
    if (!body || len < CL_DEMAND_BODY)
        return CL_E_TRUNCATED;
    if (len != CL_DEMAND_BODY)
        return CL_E_CORRUPT;
    for (int k = CL_KEYS; k < CL_KEY_BYTES * 8; k++)
        if (cl_bit(body + 4, k))
            return CL_E_CORRUPT;
    *ttl_ms = get32(body);
    memcpy(bits, body + 4, CL_KEY_BYTES);
    return CL_OK;
}

void cl_demand_body_write_ex(uint8_t dst[CL_DEMAND_BODY_EX], uint32_t ttl_ms, const struct cl_demand_bits *b)
{
    put32(dst, ttl_ms);
    memcpy(dst + 4, b->keys, CL_KEY_BYTES);
    memcpy(dst + 4 + CL_KEY_BYTES, b->stream, CL_KEY_BYTES);
    memcpy(dst + 4 + 2 * CL_KEY_BYTES, b->wish, CL_KEY_BYTES);
}

int cl_demand_body_parse_ex(const uint8_t *body, size_t len, uint32_t *ttl_ms, struct cl_demand_bits *out)
{
    if (!body || len < CL_DEMAND_BODY)
        return CL_E_TRUNCATED;
    if (len == CL_DEMAND_BODY) { /* keys only: every layer intra */
        int rc = cl_demand_body_parse(body, len, ttl_ms, out->keys);
        if (rc == CL_OK) {
            memset(out->stream, 0, CL_KEY_BYTES);
            memcpy(out->wish, out->keys, CL_KEY_BYTES);
        }
        return rc;
    }
    if (len < CL_DEMAND_BODY_EX)
        return CL_E_TRUNCATED;
    if (len != CL_DEMAND_BODY_EX)
        return CL_E_CORRUPT;
    const uint8_t *k = body + 4, *st = k + CL_KEY_BYTES, *w = st + CL_KEY_BYTES;
    for (int kk = CL_KEYS; kk < CL_KEY_BYTES * 8; kk++)
        if (cl_bit(k, kk))
            return CL_E_CORRUPT;
    for (int i = 0; i < CL_KEY_BYTES; i++)
        if ((st[i] & ~k[i]) || (w[i] & ~k[i]))
            return CL_E_CORRUPT; /* a layer streamed or wished for that is not demanded */
    *ttl_ms = get32(body);
    memcpy(out->keys, k, CL_KEY_BYTES);
    memcpy(out->stream, st, CL_KEY_BYTES);
    memcpy(out->wish, w, CL_KEY_BYTES);
    return CL_OK;
}

/* oc_decode.c — frame decoder. Validates every header field and length
 * before touching the bytes it describes; allocates only after the sizes
 * are known to be within protocol limits.
 *
 * The decoder also keeps, per tile, the codes of the last OC_TEMPORAL_MAX_DEPTH + 1
 * lossy frames it decoded: the references of predicted tiles (codec 3). A
 * frame's tiles are staged ("pending") and become references only when the
 * whole frame has decoded, so a rejected frame leaves the references as they were. */
#include "oc_internal.h"

#include <stdlib.h>
#include <string.h>

#define HIST_SLOTS (OC_TEMPORAL_MAX_DEPTH + 1)
#define DEFAULT_HISTORY_LIMIT ((size_t)256 << 20)

enum { SLOT_EMPTY, SLOT_VALID, SLOT_PENDING };
struct hist_slot {
    uint64_t seq;
    double offset, scale;
    float bound;
    int state;
    int32_t *codes;          /* count codes, allocated on first use */
};
struct hist_entry {
    uint64_t key;            /* 0 = unused table cell */
    uint32_t count;
    struct hist_slot slot[HIST_SLOTS];
};
struct pending { struct hist_entry *entry; int slot; };

struct oc_decoder {
    struct oc_entropy *ent;
    size_t cap;       /* samples the scratch arrays hold */
    float *samples;
    int32_t *q;
    uint32_t *zz, *zz2, *pred;
    uint8_t *packed;
    /* references, an open-addressing table keyed by tile identity */
    struct hist_entry *tab;
    size_t tab_cap, tab_used, hist_bytes, hist_limit;
    struct pending *pend;
    size_t npend, pend_cap;
};

struct oc_decoder *oc_decoder_new(void)
{
    struct oc_decoder *d = calloc(1, sizeof *d);
    if (!d) return NULL;
    d->hist_limit = DEFAULT_HISTORY_LIMIT;
    if (!(d->ent = oc_entropy_new())) {
        oc_entropy_free(d->ent);
        free(d);
        return NULL;
    }
    return d;
}

void oc_decoder_reset(struct oc_decoder *d)
{
    if (!d) return;
    for (size_t i = 0; i < d->tab_cap; i++)
        for (int s = 0; s < HIST_SLOTS; s++) free(d->tab[i].slot[s].codes);
    free(d->tab);
    d->tab = NULL;
    d->tab_cap = d->tab_used = d->hist_bytes = 0;
    d->npend = 0;
}

void oc_decoder_set_history_limit(struct oc_decoder *d, size_t bytes)
{
    if (d) d->hist_limit = bytes;
}

void oc_decoder_free(struct oc_decoder *d)
{
    if (!d) return;
    oc_decoder_reset(d);
    oc_entropy_free(d->ent);
    free(d->samples); free(d->q); free(d->zz); free(d->zz2); free(d->pred); free(d->packed);
    free(d->pend);
    free(d);
}

static int reserve_scratch(struct oc_decoder *d, size_t count)
{
    if (count <= d->cap) return OC_OK;
    free(d->samples); free(d->q); free(d->zz); free(d->zz2); free(d->pred); free(d->packed);
    d->samples = malloc(count * sizeof(float));
    d->q = malloc(count * sizeof(int32_t));
    d->zz = malloc(count * sizeof(uint32_t));
    d->zz2 = malloc((count + 2) * sizeof(uint32_t));
    d->pred = malloc(count * sizeof(uint32_t));
    d->packed = malloc(count * 6 + 8);
    if (!d->samples || !d->q || !d->zz || !d->zz2 || !d->pred || !d->packed) {
        free(d->samples); free(d->q); free(d->zz); free(d->zz2); free(d->pred); free(d->packed);
        d->samples = NULL; d->q = NULL; d->zz = NULL; d->zz2 = NULL; d->pred = NULL; d->packed = NULL;
        d->cap = 0;
        return OC_E_NOMEM;
    }
    d->cap = count;
    return OC_OK;
}

/* ---- reference table ---- */

static int log2u(unsigned v) { int l = 0; while (v > 1) { v >>= 1; l++; } return l; }

static uint64_t tile_key(const struct oc_frame_header *fh, const struct oc_tile_header *th)
{
    /* field 3 bits, lod 3 bits, cascade 2 bits (flags & OC_TILE_CASCADE_MASK) */
    return 1 + ((uint64_t)th->field | (uint64_t)(th->lod & 7) << 3 | (uint64_t)(th->flags & OC_TILE_CASCADE_MASK) << 6
                | (uint64_t)log2u(fh->n) << 8
                | (uint64_t)log2u(fh->tile_size) << 12 | (uint64_t)th->tile_x << 16 | (uint64_t)th->tile_z << 32);
}

static struct hist_entry *find_entry(struct oc_decoder *d, uint64_t key, int create)
{
    if (!d->tab_cap) return NULL;
    size_t mask = d->tab_cap - 1;
    for (size_t i = (size_t)(key * 0x9E3779B97F4A7C15ull >> 20) & mask;; i = (i + 1) & mask) {
        if (d->tab[i].key == key) return &d->tab[i];
        if (!d->tab[i].key) {
            if (!create || (d->tab_used + 1) * 2 > d->tab_cap) return NULL;   /* full: not kept */
            d->tab[i].key = key;
            d->tab_used++;
            return &d->tab[i];
        }
    }
}

/* Room for `more` new entries without growing during a frame (entry pointers stay
 * valid). The table counts against the history limit; when it cannot grow, new
 * tiles are simply not kept (their successors report OC_E_REFERENCE). */
static int reserve_entries(struct oc_decoder *d, size_t more)
{
    if ((d->tab_used + more) * 2 <= d->tab_cap) return OC_OK;
    size_t cap = d->tab_cap ? d->tab_cap : 64;
    while ((d->tab_used + more) * 2 > cap) cap *= 2;
    size_t old_bytes = d->tab_cap * sizeof *d->tab;
    if (d->hist_bytes - old_bytes + cap * sizeof *d->tab > d->hist_limit) return OC_OK;
    struct hist_entry *old = d->tab;
    size_t old_cap = d->tab_cap;
    d->tab = calloc(cap, sizeof *d->tab);
    if (!d->tab) { d->tab = old; return OC_E_NOMEM; }
    d->tab_cap = cap;
    d->tab_used = 0;
    d->hist_bytes += cap * sizeof *d->tab - old_bytes;
    for (size_t i = 0; i < old_cap; i++)
        if (old[i].key) *find_entry(d, old[i].key, 1) = old[i];
    free(old);
    return OC_OK;
}

/* Stage the codes just decoded (d->q) as this frame's reference for the tile.
 * Not kept when over the memory limit: a later predicted tile then reports OC_E_REFERENCE. */
static int stage_codes(struct oc_decoder *d, const struct oc_frame_header *fh, const struct oc_tile_header *th,
                       const int refs_used[HIST_SLOTS])
{
    const size_t count = (size_t)th->width * th->height;
    struct hist_entry *en = find_entry(d, tile_key(fh, th), 1);
    if (!en) return OC_OK;
    if (en->count != count) {              /* new entry (or impossible size change): start empty */
        for (int s = 0; s < HIST_SLOTS; s++) {
            if (en->slot[s].codes) d->hist_bytes -= (size_t)en->count * 4;
            free(en->slot[s].codes);
            memset(&en->slot[s], 0, sizeof en->slot[s]);
        }
        en->count = (uint32_t)count;
    }
    /* An empty slot, else the oldest valid one; never one this tile read as a reference
     * (with 5 slots and at most 4 references there is always one). */
    int victim = -1;
    for (int s = 0; s < HIST_SLOTS && victim < 0; s++)
        if (en->slot[s].state == SLOT_EMPTY && !refs_used[s]) victim = s;
    for (int s = 0; s < HIST_SLOTS && victim < 0; s++)
        if (en->slot[s].state == SLOT_VALID && !refs_used[s]) victim = s;
    if (victim >= 0 && en->slot[victim].state == SLOT_VALID)
        for (int s = 0; s < HIST_SLOTS; s++)
            if (en->slot[s].state == SLOT_VALID && !refs_used[s] && en->slot[s].seq < en->slot[victim].seq) victim = s;
    if (victim < 0) return OC_OK;
    struct hist_slot *sl = &en->slot[victim];
    if (!sl->codes) {
        if (d->hist_bytes + count * 4 > d->hist_limit) { sl->state = SLOT_EMPTY; return OC_OK; }
        if (!(sl->codes = malloc(count * 4))) return OC_E_NOMEM;
        d->hist_bytes += count * 4;
    }
    if (d->npend == d->pend_cap) {
        size_t cap = d->pend_cap ? 2 * d->pend_cap : 64;
        struct pending *p = realloc(d->pend, cap * sizeof *p);
        if (!p) return OC_E_NOMEM;
        d->pend = p;
        d->pend_cap = cap;
    }
    memcpy(sl->codes, d->q, count * 4);
    sl->seq = fh->seq;
    sl->offset = th->offset;
    sl->scale = th->scale;
    sl->bound = th->bound;
    sl->state = SLOT_PENDING;
    d->pend[d->npend++] = (struct pending){ en, victim };
    return OC_OK;
}

static void finish_frame(struct oc_decoder *d, int ok)
{
    for (size_t i = 0; i < d->npend; i++)
        d->pend[i].entry->slot[d->pend[i].slot].state = ok ? SLOT_VALID : SLOT_EMPTY;
    d->npend = 0;
}

/* ---- payloads ---- */

/* Codec 1/2 after the entropy stage: residuals -> codes -> samples. */
static int decode_intra(struct oc_decoder *d, const struct oc_tile_header *th, const uint8_t *p)
{
    const size_t count = (size_t)th->width * th->height;   /* <= OC_MAX_N^2, validated */
    if (th->payload_len < OC_LOSSY_PREFIX) return OC_E_CORRUPT;
    int esc_width = p[0];
    size_t esc_count = oc_get_u32(p + 4);
    if (esc_width > 4 || p[1] || p[2] || p[3] || p[14] || p[15]) return OC_E_CORRUPT;
    if (esc_count > count || (esc_count == 0) != (esc_width == 0)) return OC_E_CORRUPT;
    int8_t coef[OC_PRED_COEFS];
    memcpy(coef, p + 8, OC_PRED_COEFS);
    size_t plain = count + esc_count * (size_t)esc_width;   /* <= 5 * count: fits the scratch */
    int rc = oc_entropy_decompress(d->ent, th->codec, p + OC_LOSSY_PREFIX, th->payload_len - OC_LOSSY_PREFIX,
                                   d->packed, plain);
    if (rc) return rc;
    if ((rc = oc_unpack_escapes(d->packed, count, esc_count, esc_width, d->zz))) return rc;
    oc_unpredict(d->zz, th->width, th->height, coef, d->q);
    return OC_OK;
}

/* Codec 3: prefix, references (OC_E_REFERENCE before anything else is read), entropy stage,
 * unpacking, temporal prediction. refs_used[] marks the history slots it read. */
static int decode_temporal(struct oc_decoder *d, const struct oc_frame_header *fh, const struct oc_tile_header *th,
                           const uint8_t *p, int refs_used[HIST_SLOTS])
{
    const size_t count = (size_t)th->width * th->height, npairs = (count + 1) / 2;
    if (th->payload_len < OC_TEMPORAL_PREFIX) return OC_E_CORRUPT;
    int depth = p[0], packing = p[1], esc_width = p[2];
    size_t esc_count = oc_get_u32(p + 4), pair_esc = oc_get_u32(p + 8);
    uint64_t ref_seq = oc_get_u64(p + 16);
    int16_t coef[OC_TEMPORAL_COEFS];
    for (int k = 0; k < OC_TEMPORAL_COEFS; k++) coef[k] = (int16_t)oc_get_u16(p + 24 + 2 * k);
    if (depth < 1 || depth > OC_TEMPORAL_MAX_DEPTH || packing > 1 || esc_width > 4 || p[3]) return OC_E_CORRUPT;
    if (oc_get_u32(p + 12)) return OC_E_CORRUPT;
    for (int k = 24 + 2 * OC_TEMPORAL_COEFS; k < OC_TEMPORAL_PREFIX; k++) if (p[k]) return OC_E_CORRUPT;
    unsigned mask = oc_temporal_coef_mask(depth);
    for (int k = 0; k < OC_TEMPORAL_COEFS; k++) if (coef[k] && !(mask & (1u << k))) return OC_E_CORRUPT;
    if ((esc_count == 0) != (esc_width == 0)) return OC_E_CORRUPT;
    size_t plain;
    if (packing == 0) {
        if (pair_esc || esc_count > count) return OC_E_CORRUPT;
        plain = count + esc_count * (size_t)esc_width;
    } else {
        if (pair_esc > npairs || esc_count > 2 * pair_esc) return OC_E_CORRUPT;
        plain = npairs + 2 * pair_esc + esc_count * (size_t)esc_width;   /* <= 6 * count + 6 */
    }
    /* The references: frames ref_seq, ref_seq - 1, ... of this tile, on this grid. */
    const int32_t *refs[OC_TEMPORAL_MAX_DEPTH];
    struct hist_entry *en = find_entry(d, tile_key(fh, th), 0);
    if (!en || en->count != count || ref_seq < (uint64_t)(depth - 1)) return OC_E_REFERENCE;
    for (int i = 0; i < depth; i++) {
        int found = -1;
        for (int s = 0; s < HIST_SLOTS && found < 0; s++) {
            const struct hist_slot *sl = &en->slot[s];
            if (sl->state == SLOT_VALID && sl->seq == ref_seq - (uint64_t)i && sl->offset == th->offset
                && sl->scale == th->scale && sl->bound == th->bound)
                found = s;
        }
        if (found < 0) return OC_E_REFERENCE;
        refs[i] = en->slot[found].codes;
        refs_used[found] = 1;
    }
    int rc = oc_entropy_decompress(d->ent, OC_CODEC_QUANT_LORENZO, p + OC_TEMPORAL_PREFIX,
                                   th->payload_len - OC_TEMPORAL_PREFIX, d->packed, plain);
    if (rc) return rc;
    if (packing == 0) rc = oc_unpack_escapes(d->packed, count, esc_count, esc_width, d->zz);
    else rc = oc_unpack_pairs(d->packed, plain, count, pair_esc, esc_count, esc_width, d->zz, d->zz2);
    if (rc) return rc;
    const int w = th->width, h = th->height;
    uint32_t *q = (uint32_t *)d->q;
    for (int j = 0; j < h; j++) {
        oc_temporal_predict_row(refs, depth, w, h, j, coef, d->pred);
        const uint32_t *zz = d->zz + (size_t)j * w;
        uint32_t *row = q + (size_t)j * w;
        for (int i = 0; i < w; i++) row[i] = d->pred[i] + ((zz[i] >> 1) ^ (0u - (zz[i] & 1)));
    }
    return OC_OK;
}

static int decode_payload(struct oc_decoder *d, const struct oc_frame_header *fh, const struct oc_tile_header *th,
                          const uint8_t *p)
{
    const size_t count = (size_t)th->width * th->height;   /* <= OC_MAX_N^2, validated */
    int rc = reserve_scratch(d, count);
    if (rc) return rc;
    if (th->codec == OC_CODEC_RAW_F32) {
        if (th->payload_len != count * 4) return OC_E_CORRUPT;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
        memcpy(d->samples, p, count * 4); /* little-endian float32: the wire's layout */
#else
        for (size_t k = 0; k < count; k++) d->samples[k] = oc_get_f32(p + 4 * k);
#endif
        return OC_OK;
    }
    int refs_used[HIST_SLOTS] = { 0 };
    rc = th->codec == OC_CODEC_TEMPORAL ? decode_temporal(d, fh, th, p, refs_used) : decode_intra(d, th, p);
    if (rc) return rc;
    for (size_t k = 0; k < count; k++) d->samples[k] = oc_dequant(d->q[k], th->offset, th->scale);
    return stage_codes(d, fh, th, refs_used);
}

int oc_decode_frame(struct oc_decoder *d, const uint8_t *data, size_t len,
                    struct oc_frame_header *fh, oc_tile_fn fn, void *user)
{
    if (!d || !fh) return OC_E_ARG;
    size_t first = 0;
    int rc = oc_frame_header_parse(data, len, fh, &first);
    if (rc) return rc;
    /* Pass 1: every tile header and length, so that a truncated or inconsistent
     * frame is rejected before any tile reaches the callback. */
    struct oc_tile_header th;
    size_t pos = first;
    for (unsigned t = 0; t < fh->tile_count; t++) {
        if ((rc = oc_tile_header_parse(data + pos, len - pos, fh, &th))) return rc;
        pos += OC_TILE_HEADER_SIZE + th.payload_len;
    }
    if (pos != len) return OC_E_CORRUPT;
    if ((rc = reserve_entries(d, fh->tile_count))) return rc;
    /* Pass 2: payloads, in order. */
    pos = first;
    for (unsigned t = 0; t < fh->tile_count; t++) {
        oc_tile_header_parse(data + pos, len - pos, fh, &th);
        pos += OC_TILE_HEADER_SIZE;
        if ((rc = decode_payload(d, fh, &th, data + pos))) break;
        pos += th.payload_len;
        if (fn && (rc = fn(user, fh, &th, d->samples))) break;
    }
    finish_frame(d, rc == OC_OK);
    return rc;
}

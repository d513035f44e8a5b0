/* oc_stream.c — temporal streams: the encoder side of codec 3 (PROTOCOL.md §5.9).
 *
 * One stream per layer (field, lod, bound). Each tile of the layer keeps a
 * chain: a quantisation grid (offset, scale) fixed at the chain's keyframe and
 * the codes of its last OC_TEMPORAL_MAX_DEPTH + 1 ticks. Codes are a pure
 * function of the sample values and the grid, so the keyframe of a tick
 * (intra, codec 1) and its predicted tile (codec 3) give a receiver the same
 * codes: a receiver that got either can follow the chain on the next tick.
 * That is what lets the daemon encode one shared predicted frame per layer and
 * tick, plus at most one keyframe of the same tick for all receivers that lack
 * references (joined, skipped, throttled). */
#include "oc_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define RING (OC_TEMPORAL_MAX_DEPTH + 1)
/* Closed-loop quantisation with a choice (measured in docs/codec.md, "Grid refinement"):
 * a chain's grid is `refine` times finer than the bound needs, so every sample has
 * several codes within the bound; a predicted sample whose prediction is one of them
 * takes it (residual 0), any other its rounded code (oc_temporal_snap_row). The
 * references then follow the smooth extrapolation instead of carrying rounding noise,
 * and the residuals shrink (N = 256, 1 cm, height+dx+dz: 27.7 -> 21.4 kB a frame at 3). */
/* New grids leave room for values 4x today's magnitude before the float32 margin
 * (PROTOCOL.md §5.5 step 2) runs out; beyond that the tile starts a new chain. */
#define GRID_HEADROOM 4.0

struct stream_tile {
    int hist;                 /* consecutive ticks (up to the last encoded) with codes on the grid */
    double offset, scale;     /* the chain's grid */
    int32_t *ring[RING];      /* codes; ring[head] = the last encoded tick */
    int32_t *lap[RING];       /* their Laplacians (codes stay below OC_TEMPORAL_CODE_MAX) */
    int depth;                /* this tick: references used by the shared tile, 0 = keyframe or raw */
    int key_ready;            /* this tick's keyframe is in key (or is the shared tile) */
    int failed;               /* this tick's encode of the tile failed (oc_stream_end resets the stream) */
    int done;                 /* this tick's shared tile is encoded (its keyframe may be asked for) */
    struct oc_buf shared, key;
    unsigned kind;            /* this tick's shared tile: TILE_KEY, TILE_PREDICTED, TILE_CHANGE_INTRA bits,
                                 counted by oc_stream_end when the whole tick encoded */
    uint64_t n_demand_key;    /* keyframes made on demand (per tile: concurrent callers never share it) */
};
enum { TILE_KEY = 1, TILE_PREDICTED = 2, TILE_CHANGE_INTRA = 4 };

struct oc_stream {
    int n, tile_size, lod, side, grid;
    enum oc_field field;
    float bound;
    int interval, refine;
    int changed;              /* the sea changed since the last encode (oc_stream_sea_changed) */
    int consecutive;          /* this tick follows the last encoded one (oc_stream_begin) */
    uint64_t seq, ticks;
    int encoded;              /* oc_stream_encode succeeded at least once since the last reset */
    int head, need;
    struct stream_tile *tiles;
    struct oc_stream_stats stats; /* oc_stream_end's counts; demand_key_tiles summed from the tiles */
};

static int is_pow2(int v) { return v > 0 && !(v & (v - 1)); }

struct oc_stream *oc_stream_new(int n, int tile_size, int lod, enum oc_field field, float bound)
{
    if (n > OC_MAX_N || !is_pow2(n) || !is_pow2(tile_size) || tile_size > n) return NULL;
    if (lod < 0 || lod > OC_MAX_LOD || (tile_size >> lod) == 0) return NULL;
    if ((unsigned)field >= OC_FIELD_COUNT || !isfinite(bound) || bound < 0) return NULL;
    struct oc_stream *s = calloc(1, sizeof *s);
    if (!s) return NULL;
    s->n = n; s->tile_size = tile_size; s->lod = lod; s->field = field; s->bound = bound;
    s->side = tile_size >> lod;
    s->grid = n / tile_size;
    s->interval = OC_STREAM_KEYFRAME_INTERVAL;
    s->refine = OC_STREAM_GRID_REFINE(bound);
    s->tiles = calloc((size_t)s->grid * s->grid, sizeof *s->tiles);
    if (!s->tiles) { free(s); return NULL; }
    return s;
}

void oc_stream_free(struct oc_stream *s)
{
    if (!s) return;
    for (int t = 0; t < s->grid * s->grid; t++) {
        for (int r = 0; r < RING; r++) { free(s->tiles[t].ring[r]); free(s->tiles[t].lap[r]); }
        oc_buf_free(&s->tiles[t].shared);
        oc_buf_free(&s->tiles[t].key);
    }
    free(s->tiles);
    free(s);
}

void oc_stream_set_keyframe_interval(struct oc_stream *s, int ticks)
{
    if (s) s->interval = ticks > 0 ? ticks : 0;
}

void oc_stream_set_grid_refine(struct oc_stream *s, int refine)
{
    if (s && refine >= 1 && refine <= OC_STREAM_GRID_REFINE_MAX && refine != s->refine) {
        s->refine = refine;
        oc_stream_reset(s);
    }
}

void oc_stream_sea_changed(struct oc_stream *s)
{
    if (s) s->changed = 1;
}

void oc_stream_reset(struct oc_stream *s)
{
    if (!s) return;
    for (int t = 0; t < s->grid * s->grid; t++) {
        s->tiles[t].hist = 0;
        s->tiles[t].depth = 0;
        s->tiles[t].key_ready = 0;
        s->tiles[t].failed = 0;
        s->tiles[t].done = 0;
        s->tiles[t].shared.len = 0;
        s->tiles[t].key.len = 0;
    }
    s->encoded = 0;
    s->need = 0;
}

/* Order-0 entropy of a byte histogram, in bits: the packing choice's size estimate. */
static double entropy_bits(const uint32_t hist[256], size_t total)
{
    double bits = 0;
    for (int b = 0; b < 256; b++)
        if (hist[b]) bits += hist[b] * log2((double)total / hist[b]);
    return bits;
}

/* Does code c reconstruct v within the bound (exactly as a decoder does, §5.4)? */
static inline int fits(int32_t c, float v, double offset, double scale, double bound)
{
    return fabs((double)oc_dequant(c, offset, scale) - (double)v) <= bound;
}

/* The code nearest to p that meets the bound, starting from c, which does. */
static inline int32_t snap(int32_t c, int32_t p, float v, double offset, double scale, double bound)
{
    if (c == p || fits(p, v, offset, scale, bound)) return p;
    while (c != p) {
        int32_t next = c + (p > c ? 1 : -1);
        if (!fits(next, v, offset, scale, bound)) break;
        c = next;
    }
    return c;
}

/* Residuals of q against the temporal prediction, each code first moved to its
 * prediction where that is within the bound (q is updated: the codes a decoder gets), the
 * smaller packing (estimated from the byte histograms), DEFLATE; appends tile header +
 * codec 3 payload. vals = the tile's samples. */
static int append_temporal(struct oc_encoder *e, struct oc_tile_header *th, int32_t *q, const float *vals,
                           const int32_t *const *refs, const int32_t *const *laps, int depth, uint64_t ref_seq,
                           struct oc_buf *out)
{
    const int w = th->width, h = th->height;
    const size_t count = (size_t)w * h, npairs = (count + 1) / 2;
    int rc = oc_enc_reserve(e, count);
    if (rc) return rc;
    int16_t coef[OC_TEMPORAL_COEFS];
    oc_temporal_fit(refs, laps, depth, q, w, h, coef);
    uint32_t pred[OC_MAX_N];   /* one row of predictions */
    for (int j = 0; j < h; j++) {
        oc_temporal_predict_row_cached(refs, laps, depth, w, j, coef, pred);
        int32_t *qr = q + (size_t)j * w;
        const float *vr = vals + (size_t)j * w;
        uint32_t *z = e->zz + (size_t)j * w;
        oc_temporal_snap_row(qr, pred, vr, w, th->offset, th->scale, th->bound);
        for (int i = 0; i < w; i++) {
            uint32_t r = (uint32_t)qr[i] - pred[i];
            z[i] = (r << 1) ^ (0u - (r >> 31));
        }
    }
    /* Which packing: byte per sample or pairs, by the order-0 entropy of the bytes each gives.
     * The pair bytes are written first (at packed) and histogrammed; the byte-per-sample
     * histogram follows from theirs (a pair byte 15*z1 + z2 holds both values) plus the
     * escaped pairs' values, so the bytes (at packed + count) are written only if chosen. */
    uint8_t *const pb = e->packed, *const cb = e->packed + count;
    oc_pair_bytes(e->zz, count, pb);
    uint32_t h1[256] = { 0 }, hp[256] = { 0 }, h2[256];
    oc_byte_hist_add(pb, npairs, hp);
    memcpy(h2, hp, sizeof h2);
    for (int z1 = 0; z1 < OC_PAIR_LIMIT; z1++)
        for (int z2 = 0; z2 < OC_PAIR_LIMIT; z2++) {
            h1[z1] += hp[OC_PAIR_LIMIT * z1 + z2];
            h1[z2] += hp[OC_PAIR_LIMIT * z1 + z2];
        }
    if ((count & 1) && pb[npairs - 1] != 255) h1[0]--;     /* the odd count's padding value is no sample */
    const size_t n2 = npairs + 2 * (size_t)hp[255];
    size_t wide2 = 0;
    if (hp[255])       /* the escaped pairs: their two values, each a byte in the estimate */
        for (const uint8_t *x = pb, *end = pb + npairs; (x = memchr(x, 255, (size_t)(end - x))) != NULL; x++) {
            const size_t p = (size_t)(x - pb);
            const int real2 = 2 * p + 1 < count;
            const uint32_t z1 = e->zz[2 * p], z2 = real2 ? e->zz[2 * p + 1] : 0;
            h2[z1 < 255 ? z1 : 255]++;
            h2[z2 < 255 ? z2 : 255]++;
            wide2 += (z1 >= 255) + (z2 >= 255);
            h1[z1 < 255 ? z1 : 255]++;
            if (real2) h1[z2 < 255 ? z2 : 255]++;
        }
    const size_t wide1 = h1[255];
    const int pairs = entropy_bits(h2, n2) + 16.0 * wide2 < entropy_bits(h1, count) + 16.0 * wide1;
    int esc_width;
    size_t esc_count, pair_esc = 0, plain;
    const uint8_t *src;
    uint32_t *hist;
    if (pairs) {
        plain = oc_pack_pair_escapes(e->zz, count, pb, e->esc, &pair_esc, &esc_count, &esc_width);
        oc_byte_hist_add(pb + npairs, plain - npairs, hp);
        src = pb;
        hist = hp;
    } else {
        esc_count = oc_pack_escapes(e->zz, count, cb, e->esc, &esc_width);
        plain = count + esc_count * (size_t)esc_width;
        oc_byte_hist_add(cb + count, plain - count, h1);
        src = cb;
        hist = h1;
    }
    size_t cap = OC_TEMPORAL_PREFIX + oc_entropy_bound(OC_CODEC_QUANT_LORENZO, plain);
    if ((rc = oc_buf_reserve(out, OC_TILE_HEADER_SIZE + cap))) return rc;
    uint8_t *payload = out->data + out->len + OC_TILE_HEADER_SIZE;
    memset(payload, 0, OC_TEMPORAL_PREFIX);
    payload[0] = (uint8_t)depth;
    payload[1] = (uint8_t)pairs;
    payload[2] = (uint8_t)esc_width;
    oc_put_u32(payload + 4, (uint32_t)esc_count);
    oc_put_u32(payload + 8, (uint32_t)pair_esc);
    oc_put_u64(payload + 16, ref_seq);
    for (int k = 0; k < OC_TEMPORAL_COEFS; k++) oc_put_u16(payload + 24 + 2 * k, (uint16_t)coef[k]);
    size_t clen = oc_entropy_compress_hist(e->ent, OC_CODEC_QUANT_LORENZO, 1, src, plain, hist,
                                           payload + OC_TEMPORAL_PREFIX, cap - OC_TEMPORAL_PREFIX);
    if (clen == 0) return OC_E_NOMEM;
    th->codec = OC_CODEC_TEMPORAL;
    th->payload_len = (uint32_t)(OC_TEMPORAL_PREFIX + clen);
    oc_tile_header_write(out->data + out->len, th);
    out->len += OC_TILE_HEADER_SIZE + th->payload_len;
    return OC_OK;
}

static inline int64_t floor_div64(int64_t x) { return x < 0 ? ~(~x >> 6) : x >> 6; }

/* Intra (codec 1) on the chain's grid with each code moved, in decoding order, to the
 * valid code nearest its spatial prediction (§5.3, coefficients fitted on the rounded
 * codes q, which this replaces). */
static int intra_snapped(struct oc_encoder *e, struct oc_tile_header *th, int32_t *q, struct oc_buf *out)
{
    const int w = th->width, h = th->height;
    const float *v = e->vals;
    int8_t c[OC_PRED_COEFS];
    oc_predict_fit(q, w, h, c);
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            const size_t k = (size_t)j * w + i;
            int64_t p;
            if (j == 0) p = i == 0 ? 0 : q[k - 1];
            else if (i == 0) p = q[k - w];
            else if (j >= 2 && w >= 4 && i >= 2 && i <= w - 2)
                p = floor_div64((int64_t)c[0] * q[k - 1] + (int64_t)c[1] * q[k - w] + (int64_t)c[2] * q[k - w - 1]
                                + (int64_t)c[3] * q[k - w + 1] + (int64_t)c[4] * q[k - 2] + (int64_t)c[5] * q[k - 2 * (size_t)w] + 32);
            else p = (int64_t)q[k - 1] + q[k - w] - q[k - w - 1];
            p = p < INT32_MIN ? INT32_MIN : p > INT32_MAX ? INT32_MAX : p;   /* only steers the choice */
            q[k] = snap(q[k], (int32_t)p, v[k], th->offset, th->scale, th->bound);
        }
    /* The residuals must use the coefficients the choice was made with. */
    return oc_enc_append_intra(e, th, q, c, 0, out);
}

/* Intra (codec 1) on the chain's grid with codes that are multiples of `refine` (the
 * coarse grid's codes) and the Lorenzo predictor, whose predictions of such codes are
 * multiples too: it costs what the coarse grid's Lorenzo intra costs. 0 = not every
 * sample has such a code within the bound (then nothing is written). */
static int intra_coarse(struct oc_encoder *e, struct oc_tile_header *th, int refine, int32_t *q, struct oc_buf *out,
                        int *ok)
{
    const size_t count = (size_t)th->width * th->height;
    const double coarse = th->scale * refine;
    *ok = 0;
    for (size_t k = 0; k < count; k++) {
        const float v = e->vals[k];
        double x = nearbyint(((double)v - th->offset) / coarse);
        if (!(fabs(x) * refine < OC_TEMPORAL_CODE_MAX)) return OC_OK;
        int32_t c = (int32_t)x * refine;
        if (!fits(c, v, th->offset, th->scale, th->bound)) {
            if (fits(c - refine, v, th->offset, th->scale, th->bound)) c -= refine;
            else if (fits(c + refine, v, th->offset, th->scale, th->bound)) c += refine;
            else return OC_OK;
        }
        q[k] = c;
    }
    int rc = oc_enc_append_intra(e, th, q, oc_lorenzo_coef, 0, out);
    *ok = rc == OC_OK;
    return rc;
}

/* The smallest intra tile of this tick on the chain's grid (th: offset, scale set) whose
 * codes start from the rounded codes in e->q: `cur` gets its codes, `out` the tile. When
 * `out` already holds a tile (the predicted one, codes in cur), it is kept unless an
 * intra one is smaller. Returns 0 or an OC_E_*; *intra = the intra one was kept. */
static int smallest_intra(struct oc_stream *s, struct oc_encoder *e, struct oc_tile_header *th, int32_t *cur,
                          struct oc_buf *out, int *intra)
{
    const size_t count = (size_t)th->width * th->height;
    *intra = 0;
    if (e->cand_cap < count) {
        free(e->cand_q);
        e->cand_cap = 0;
        if (!(e->cand_q = malloc(sizeof(int32_t) * count))) return OC_E_NOMEM;
        e->cand_cap = count;
    }
    int have = out->len > 0, rc;
    /* 1: the rounded codes snapped to the spatial prediction */
    memcpy(e->cand_q, e->q, count * sizeof(int32_t));
    e->cand.len = 0;
    if ((rc = intra_snapped(e, th, e->cand_q, &e->cand))) return rc;
    if (!have || e->cand.len < out->len) {
        out->len = 0;
        if ((rc = oc_buf_reserve(out, e->cand.len))) return rc;
        memcpy(out->data, e->cand.data, e->cand.len);
        out->len = e->cand.len;
        memcpy(cur, e->cand_q, count * sizeof(int32_t));
        have = 1;
        *intra = 1;
    }
    /* 2: the coarse grid's codes with Lorenzo */
    int ok;
    e->cand.len = 0;
    if (s->refine > 1 && (rc = intra_coarse(e, th, s->refine, e->cand_q, &e->cand, &ok))) return rc;
    if (s->refine > 1 && ok && e->cand.len < out->len) {
        out->len = 0;
        memcpy(out->data, e->cand.data, e->cand.len);   /* smaller than what out holds */
        out->len = e->cand.len;
        memcpy(cur, e->cand_q, count * sizeof(int32_t));
        *intra = 1;
    }
    return OC_OK;
}

/* Encode one tile of this tick into t->shared. */
static int encode_tile(struct oc_stream *s, struct oc_encoder *e, const float *field_data, int tx, int tz,
                       int consecutive, int periodic)
{
    struct stream_tile *t = &s->tiles[tz * s->grid + tx];
    const size_t count = (size_t)s->side * s->side;
    t->shared.len = 0;
    t->key.len = 0;
    t->key_ready = 0;
    t->depth = 0;
    t->kind = 0;
    float vmin, vmax;
    int rc = oc_enc_gather(e, field_data, s->n, s->tile_size, tx, tz, s->lod, &vmin, &vmax);
    if (rc) return rc;
    for (int r = 0; r < RING; r++) {
        if (!t->ring[r] && !(t->ring[r] = malloc(count * sizeof(int32_t)))) return OC_E_NOMEM;
        if (!t->lap[r] && !(t->lap[r] = malloc(count * sizeof(int32_t)))) return OC_E_NOMEM;
    }
    struct oc_tile_header th = {
        .field = (uint8_t)s->field, .lod = (uint8_t)s->lod, .tile_x = (uint16_t)tx, .tile_z = (uint16_t)tz,
        .width = (uint16_t)s->side, .height = (uint16_t)s->side, .bound = s->bound,
    };
    int32_t *cur = t->ring[s->head];   /* this tick's slot: no reference of it */
    /* The rounded codes on the fine grid (within bound / refine, so within the bound):
     * straight into cur, unless a changed sea's intra candidates need them after the
     * predicted tile has moved cur's codes (then in e->q, and copied). */
    int32_t *rounded = s->changed ? e->q : cur;
    const double fine_bound = (double)s->bound / s->refine;
    if (s->bound > 0 && consecutive && !periodic && t->hist > 0
        && oc_enc_quantise_on(e, rounded, count, vmin, vmax, fine_bound, t->offset, t->scale)
        && oc_max_abs(rounded, count) < (uint32_t)(OC_TEMPORAL_CODE_MAX - s->refine)) {
        /* Predicted from the previous ticks of the chain. */
        const int32_t *refs[OC_TEMPORAL_MAX_DEPTH], *laps[OC_TEMPORAL_MAX_DEPTH];
        int depth = t->hist < OC_TEMPORAL_MAX_DEPTH ? t->hist : OC_TEMPORAL_MAX_DEPTH;
        for (int i = 0; i < depth; i++) {
            refs[i] = t->ring[(s->head + RING - 1 - i) % RING];
            laps[i] = t->lap[(s->head + RING - 1 - i) % RING];
        }
        if (rounded != cur) memcpy(cur, rounded, count * sizeof(int32_t));
        th.offset = t->offset;
        th.scale = t->scale;
        if ((rc = append_temporal(e, &th, cur, e->vals, refs, laps, depth, s->seq - 1, &t->shared))) return rc;
        t->depth = depth;
        t->hist++;
        if (s->changed) {
            /* The sea changed (same phases, new amplitudes): the jump is a new sea's worth of
             * detail, which the spatial predictor may code in fewer bytes. Either way the
             * chain goes on (an intra tile on its grid is a reference like any other), so
             * the next ticks predict from the full depth at once. */
            int intra;
            th.bound = s->bound;
            if ((rc = smallest_intra(s, e, &th, cur, &t->shared, &intra))) return rc;
            if (intra) {
                t->depth = 0;
                t->key_ready = 1;
                t->kind |= TILE_CHANGE_INTRA;
            }
        }
        if (t->depth) t->kind |= TILE_PREDICTED;
        oc_temporal_laplacian(cur, s->side, s->side, t->lap[s->head]);
        return OC_OK;
    }
    /* Keyframe on a new grid (or raw when the tile cannot be quantised). */
    t->kind |= TILE_KEY;
    t->key_ready = 1;
    if (s->bound == 0 || !oc_enc_quantise_new(e, count, vmin, vmax, fine_bound, GRID_HEADROOM, &th.offset, &th.scale)
        || oc_max_abs(e->q, count) >= (uint32_t)(OC_TEMPORAL_CODE_MAX - s->refine)) {
        t->hist = 0;
        return oc_enc_append_raw(&t->shared, &th, e->vals, count);
    }
    t->offset = th.offset;
    t->scale = th.scale;
    t->hist = 1;
    int intra;
    if ((rc = smallest_intra(s, e, &th, cur, &t->shared, &intra))) return rc;
    oc_temporal_laplacian(cur, s->side, s->side, t->lap[s->head]);
    return OC_OK;
}

int oc_stream_begin(struct oc_stream *s, uint64_t seq)
{
    if (!s) return OC_E_ARG;
    s->consecutive = s->encoded && seq == s->seq + 1;
    s->seq = seq;
    s->head = (s->head + 1) % RING;
    s->need = 0;
    s->encoded = 0;
    for (int k = 0; k < s->grid * s->grid; k++) s->tiles[k].done = 0;
    return OC_OK;
}

int oc_stream_tile_count(const struct oc_stream *s) { return s ? s->grid * s->grid : 0; }

int oc_stream_encode_tiles(struct oc_stream *s, struct oc_encoder *e, const float *field_data, int first, int count)
{
    const int ntiles = oc_stream_tile_count(s);
    if (!s || !e || !field_data || first < 0 || count < 0 || first + count > ntiles) return OC_E_ARG;
    for (int k = first; k < first + count; k++) {
        /* Periodic keyframes are staggered over the tiles, so no tick carries them all. */
        int periodic = s->interval > 0 && (s->ticks + (uint64_t)k * s->interval / ntiles) % s->interval == 0
                       && s->ticks > 0;
        int rc = encode_tile(s, e, field_data, k % s->grid, k / s->grid, s->consecutive, periodic);
        if (rc) {
            s->tiles[k].failed = 1;
            return rc;
        }
        s->tiles[k].done = 1;
    }
    return OC_OK;
}

int oc_stream_end(struct oc_stream *s)
{
    if (!s) return OC_E_ARG;
    const int ntiles = s->grid * s->grid;
    int failed = 0;
    for (int k = 0; k < ntiles; k++) {
        failed |= s->tiles[k].failed;
        s->tiles[k].failed = 0;
        if (s->tiles[k].depth > s->need) s->need = s->tiles[k].depth;
    }
    if (failed) { oc_stream_reset(s); return OC_E_ARG; }
    for (int k = 0; k < ntiles; k++) {
        const unsigned kind = s->tiles[k].kind;
        s->stats.key_tiles += (kind & TILE_KEY) != 0;
        s->stats.predicted_tiles += (kind & TILE_PREDICTED) != 0;
        s->stats.change_intra_tiles += (kind & TILE_CHANGE_INTRA) != 0;
    }
    s->encoded = 1;
    s->changed = 0;
    s->ticks++;
    s->stats.ticks++;
    return OC_OK;
}

int oc_stream_encode(struct oc_stream *s, struct oc_encoder *e, const float *field_data, uint64_t seq)
{
    if (!s || !e || !field_data) return OC_E_ARG;
    oc_stream_begin(s, seq);
    int rc = oc_stream_encode_tiles(s, e, field_data, 0, oc_stream_tile_count(s));
    int end = oc_stream_end(s);     /* resets the stream when a tile failed */
    return rc ? rc : end;
}

int oc_stream_need(const struct oc_stream *s)
{
    return s ? s->need : 0;
}

static struct stream_tile *tile_at(const struct oc_stream *s, int tx, int tz)
{
    if (!s || !s->encoded || tx < 0 || tz < 0 || tx >= s->grid || tz >= s->grid) return NULL;
    return &s->tiles[tz * s->grid + tx];
}

int oc_stream_tile(const struct oc_stream *s, int tile_x, int tile_z, const uint8_t **data, size_t *len)
{
    struct stream_tile *t = tile_at(s, tile_x, tile_z);
    if (!t || !data || !len) return OC_E_ARG;
    *data = t->shared.data;
    *len = t->shared.len;
    return OC_OK;
}

int oc_stream_keyframe_tile(struct oc_stream *s, struct oc_encoder *e, int tile_x, int tile_z,
                            const uint8_t **data, size_t *len)
{
    /* After oc_stream_end, or before it for a tile whose range is encoded (the encode pool
     * makes a range's keyframes on the thread that encoded it) */
    struct stream_tile *t = s && tile_x >= 0 && tile_z >= 0 && tile_x < s->grid && tile_z < s->grid
                            && s->tiles[tile_z * s->grid + tile_x].done ? &s->tiles[tile_z * s->grid + tile_x] : NULL;
    if (!t || !data || !len) return OC_E_ARG;
    if (t->key_ready) {                 /* the shared tile is this tick's keyframe, or it was made already */
        *data = t->depth == 0 ? t->shared.data : t->key.data;
        *len = t->depth == 0 ? t->shared.len : t->key.len;
        return OC_OK;
    }
    if (!e) return OC_E_ARG;            /* NULL: only one made already */
    struct oc_tile_header th = {
        .field = (uint8_t)s->field, .lod = (uint8_t)s->lod, .tile_x = (uint16_t)tile_x, .tile_z = (uint16_t)tile_z,
        .width = (uint16_t)s->side, .height = (uint16_t)s->side, .bound = s->bound,
        .offset = t->offset, .scale = t->scale,
    };
    t->key.len = 0;
    int rc = oc_enc_append_intra(e, &th, t->ring[s->head], NULL, 0, &t->key);
    if (rc) return rc;
    t->key_ready = 1;
    t->n_demand_key++;
    *data = t->key.data;
    *len = t->key.len;
    return OC_OK;
}

void oc_stream_stats(const struct oc_stream *s, struct oc_stream_stats *out)
{
    if (!s || !out) return;
    *out = s->stats;
    for (int k = 0; k < s->grid * s->grid; k++)
        out->demand_key_tiles += s->tiles[k].n_demand_key;
}

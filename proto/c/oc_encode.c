/* oc_encode.c — tile encoder: gather (with LOD stride), quantise to the
 * bound with an exact guarantee, then the integer pipeline and entropy coder.
 * The encoder owns its scratch buffers and reuses them from tile to tile. */
#include "oc_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>


struct oc_encoder *oc_encoder_new(void)
{
    struct oc_encoder *e = calloc(1, sizeof *e);
    if (!e) return NULL;
    e->ent = oc_entropy_new();
    if (!e->ent) { free(e); return NULL; }
    e->codec = OC_CODEC_QUANT_LORENZO;
    return e;
}

void oc_encoder_free(struct oc_encoder *e)
{
    if (!e) return;
    oc_entropy_free(e->ent);
    free(e->vals); free(e->q); free(e->zz); free(e->esc); free(e->packed);
    free(e->cand_q); oc_buf_free(&e->cand);
    free(e);
}

void oc_encoder_force_predictor(struct oc_encoder *e, const int8_t *coef)
{
    e->force = coef != NULL;
    if (coef) memcpy(e->forced, coef, OC_PRED_COEFS);
}

int oc_encoder_set_codec(struct oc_encoder *e, enum oc_codec codec, int level)
{
    if (!e || (codec != OC_CODEC_QUANT_LORENZO && codec != OC_CODEC_QUANT_LORENZO_ZSTD)) return OC_E_ARG;
    if (level < 0 || level > (codec == OC_CODEC_QUANT_LORENZO ? 12 : 19)) return OC_E_ARG;
    e->codec = codec;
    e->level = level;
    return OC_OK;
}

int oc_enc_reserve(struct oc_encoder *e, size_t count)
{
    if (count <= e->cap) return OC_OK;
    free(e->vals); free(e->q); free(e->zz); free(e->esc); free(e->packed);
    e->vals = malloc(count * sizeof(float));
    e->q = malloc(count * sizeof(int32_t));
    e->zz = malloc(count * sizeof(uint32_t));
    e->esc = malloc((2 * count + 2) * sizeof(uint32_t));   /* pair packing: escapes + the escaped pairs' values */
    e->packed = malloc(count * 6 + 8);
    if (!e->vals || !e->q || !e->zz || !e->esc || !e->packed) {
        free(e->vals); free(e->q); free(e->zz); free(e->esc); free(e->packed);
        e->vals = NULL; e->q = NULL; e->zz = NULL; e->esc = NULL; e->packed = NULL;
        e->cap = 0;
        return OC_E_NOMEM;
    }
    e->cap = count;
    return OC_OK;
}

static int is_pow2(int v) { return v > 0 && !(v & (v - 1)); }

/* Round to nearest (ties to even) for |x| < 2^51 without a libm call, so the
 * loop vectorises. Any rounding is valid: the decoder only sees q. */
static inline double round_d(double x)
{
    return (x + 0x1.8p52) - 0x1.8p52;
}

/* One quantisation pass; returns nonzero if some sample misses the bound.
 * Cloned for AVX2 where the compiler supports it: the SSE2 baseline cannot
 * vectorise the double -> int32 conversion, AVX2 runs the loop ~3x faster.
 * The miss flag is 64 bits wide, as wide as a double's compare mask: an int
 * flag made GCC narrow every mask to int lanes (four shuffles per 8 samples). */
OC_VECTOR_CLONES
static int quantise_pass(const float *restrict v, int32_t *restrict q, size_t count, double offset,
                         double scale, double bound)
{
    const double inv = 1.0 / scale;
    int64_t bad = 0;
    for (size_t k = 0; k < count; k++) {
        /* r is the code as a double (|r| < 2^31): the same value oc_dequant would
         * convert back from the int32, without the extra conversion. */
        double r = round_d(((double)v[k] - offset) * inv);
        double err = fabs((double)(float)(offset + r * scale) - (double)v[k]);
        q[k] = (int32_t)r;
        bad |= -(int64_t)(err > bound);
    }
    return bad != 0;
}

/* Quantise vals to codes whose reconstruction float32(offset + q*scale) is
 * within bound of every input, on a new grid. Returns 1 if done, 0 if the tile must go raw. */
int oc_enc_quantise_new(struct oc_encoder *e, size_t count, float vmin, float vmax, double bound, double headroom,
                        double *offset_out, double *scale_out)
{
    const float *v = e->vals;
    int32_t *q = e->q;
    /* headroom > 1 (temporal chains): later frames on the same grid may reach
     * headroom times today's magnitude and still get the float32 margin right. */
    double maxabs = headroom * fmax(fabs((double)vmin), fabs((double)vmax)) + bound;
    /* Rounding the reconstruction to float32 moves it by up to half an ulp:
     * take that off the budget, plus a sliver for double rounding. */
    double half_ulp = maxabs * 0x1p-24 + 0x1p-149;
    double eff = bound - half_ulp;
    if (!(eff > bound * 0x1p-8)) return 0;           /* bound below float32 resolution */
    double scale = 2.0 * eff * (1.0 - 0x1p-20);
    double half_range = 0.5 * ((double)vmax - (double)vmin);
    double offset = (double)vmin + half_range;
    for (int attempt = 0; attempt < 8; attempt++, scale *= 1.0 - 0x1p-6) {
        if (half_range / scale > 0x1p30) return 0;      /* codes would not fit int32 comfortably */
        int bad = quantise_pass(v, q, count, offset, scale, bound);
        if (!bad) goto done;
        /* Rare: a sample at the edge of its bin. Try the neighbouring codes. */
        bad = 0;
        for (size_t k = 0; k < count && !bad; k++) {
            if (fabs((double)oc_dequant(q[k], offset, scale) - (double)v[k]) <= bound) continue;
            if (fabs((double)oc_dequant(q[k] - 1, offset, scale) - (double)v[k]) <= bound) q[k] -= 1;
            else if (fabs((double)oc_dequant(q[k] + 1, offset, scale) - (double)v[k]) <= bound) q[k] += 1;
            else bad = 1;                              /* shrink the scale and redo */
        }
        if (!bad) goto done;
    }
    return 0;
done:
    *offset_out = offset;
    *scale_out = scale;
    return 1;
}

/* Quantise vals on a given grid (a temporal chain's) into q (count codes): 1 if every
 * sample meets the bound with codes below 2^30 in magnitude, 0 if the grid no longer fits. */
int oc_enc_quantise_on(struct oc_encoder *e, int32_t *q, size_t count, float vmin, float vmax, double bound,
                       double offset, double scale)
{
    if (fmax(fabs((double)vmax - offset), fabs((double)vmin - offset)) / scale > 0x1p30) return 0;
    if (!quantise_pass(e->vals, q, count, offset, scale, bound)) return 1;
    for (size_t k = 0; k < count; k++) {
        const float v = e->vals[k];
        if (fabs((double)oc_dequant(q[k], offset, scale) - (double)v) <= bound) continue;
        if (fabs((double)oc_dequant(q[k] - 1, offset, scale) - (double)v) <= bound) q[k] -= 1;
        else if (fabs((double)oc_dequant(q[k] + 1, offset, scale) - (double)v) <= bound) q[k] += 1;
        else return 0;
    }
    return 1;
}

/* Min, max and finiteness through an order-preserving integer key of the
 * float bits: integer min/max vectorise, float ones (NaN rules) do not. */
static inline int32_t float_key(uint32_t u) { return (int32_t)(u ^ ((0u - (u >> 31)) & 0x7fffffffu)); }
static inline float key_float(int32_t k)
{
    uint32_t u = (uint32_t)k ^ ((0u - ((uint32_t)k >> 31)) & 0x7fffffffu);
    float f;
    memcpy(&f, &u, 4);
    return f;
}

OC_VECTOR_CLONES
int oc_enc_scan_range(const float *restrict v, size_t count, float *vmin, float *vmax)
{
    int32_t lo = INT32_MAX, hi = INT32_MIN;
    uint32_t nonfinite = 0;
    for (size_t k = 0; k < count; k++) {
        uint32_t u;
        memcpy(&u, v + k, 4);
        nonfinite |= (u & 0x7f800000u) == 0x7f800000u;
        int32_t key = float_key(u);
        lo = key < lo ? key : lo;
        hi = key > hi ? key : hi;
    }
    *vmin = key_float(lo);
    *vmax = key_float(hi);
    return nonfinite != 0;
}

int oc_enc_append_raw(struct oc_buf *out, struct oc_tile_header *th, const float *vals, size_t count)
{
    th->codec = OC_CODEC_RAW_F32;
    th->bound = 0;
    th->offset = 0;
    th->scale = 0;
    th->payload_len = (uint32_t)(count * 4);
    int rc = oc_buf_reserve(out, OC_TILE_HEADER_SIZE + count * 4);
    if (rc) return rc;
    uint8_t *p = out->data + out->len;
    oc_tile_header_write(p, th);
    p += OC_TILE_HEADER_SIZE;
    for (size_t k = 0; k < count; k++) oc_put_f32(p + 4 * k, vals[k]);
    out->len += OC_TILE_HEADER_SIZE + count * 4;
    return OC_OK;
}

/* Gather tile (tile_x, tile_z) of field_data at its LOD stride into e->vals
 * (side*side samples) and find its range; OC_E_ARG on NaN/Inf. */
int oc_enc_gather(struct oc_encoder *e, const float *field_data, int n, int tile_size, int tile_x, int tile_z,
                  int lod, float *vmin, float *vmax)
{
    const int side = tile_size >> lod, step = 1 << lod;
    const size_t count = (size_t)side * side;
    int rc = oc_enc_reserve(e, count);
    if (rc) return rc;
    for (int j = 0; j < side; j++) {
        const float *row = field_data + ((size_t)tile_z * tile_size + (size_t)j * step) * n
                           + (size_t)tile_x * tile_size;
        float *dst = e->vals + (size_t)j * side;
        if (step == 1) memcpy(dst, row, sizeof(float) * side);
        else for (int i = 0; i < side; i++) dst[i] = row[(size_t)i * step];
    }
    return oc_enc_scan_range(e->vals, count, vmin, vmax) ? OC_E_ARG : OC_OK;
}

/* Append the intra (codec 1/2) tile of codes q with th's grid. coef: the predictor
 * coefficients to use, or NULL for the encoder's (fitted, or forced by the test hook).
 * allow_raw: send codec 0 when the lossy payload is not smaller (never for chain
 * keyframes, whose codes the receiver must keep). */
int oc_enc_append_intra(struct oc_encoder *e, struct oc_tile_header *th, const int32_t *q,
                        const int8_t *coef_in, int allow_raw, struct oc_buf *out)
{
    const int side = th->width;
    const size_t count = (size_t)side * side;
    int rc = oc_enc_reserve(e, count);
    if (rc) return rc;
    th->codec = (uint8_t)e->codec;
    int8_t coef[OC_PRED_COEFS];
    uint32_t maxabs = oc_max_abs(q, count);
    if (coef_in) memcpy(coef, coef_in, OC_PRED_COEFS);
    else if (e->force) memcpy(coef, e->forced, OC_PRED_COEFS);
    else oc_predict_fit_m(q, side, side, maxabs, coef);
    oc_predict_residuals_m(q, side, side, maxabs, coef, e->zz);
    int esc_width;
    size_t esc_count = oc_pack_escapes(e->zz, count, e->packed, e->esc, &esc_width);
    size_t plain = count + esc_count * (size_t)esc_width;
    size_t cap = OC_LOSSY_PREFIX + oc_entropy_bound(e->codec, plain);
    if ((rc = oc_buf_reserve(out, OC_TILE_HEADER_SIZE + cap))) return rc;
    uint8_t *payload = out->data + out->len + OC_TILE_HEADER_SIZE;
    memset(payload, 0, OC_LOSSY_PREFIX);
    payload[0] = (uint8_t)esc_width;
    oc_put_u32(payload + 4, (uint32_t)esc_count);
    memcpy(payload + 8, coef, OC_PRED_COEFS);
    /* Level 0 = default = 1: for codec 1 that is the Huffman-only DEFLATE writer
     * (oc_entropy.c), for codec 2 zstd level 1; codec 1 levels 2..12 use libdeflate. */
    int level = e->level ? e->level : 1;
    size_t clen = oc_entropy_compress(e->ent, e->codec, level, e->packed, plain, payload + OC_LOSSY_PREFIX,
                                      cap - OC_LOSSY_PREFIX);
    if (clen == 0) return OC_E_NOMEM;
    if (allow_raw && OC_LOSSY_PREFIX + clen >= count * 4)   /* incompressible: raw is smaller and exact */
        return oc_enc_append_raw(out, th, e->vals, count);
    th->payload_len = (uint32_t)(OC_LOSSY_PREFIX + clen);
    oc_tile_header_write(out->data + out->len, th);
    out->len += OC_TILE_HEADER_SIZE + th->payload_len;
    return OC_OK;
}

int oc_encode_tile(struct oc_encoder *e, const float *field_data, int n, int tile_size,
                   int tile_x, int tile_z, int lod, enum oc_field field, float bound,
                   struct oc_buf *out)
{
    if (!e || !field_data || !out) return OC_E_ARG;
    if (n > OC_MAX_N) return OC_E_TOO_LARGE;
    if (!is_pow2(n) || !is_pow2(tile_size) || tile_size > n) return OC_E_ARG;
    if (lod < 0 || lod > OC_MAX_LOD || (tile_size >> lod) == 0) return OC_E_ARG;
    if (tile_x < 0 || tile_z < 0 || tile_x >= n / tile_size || tile_z >= n / tile_size) return OC_E_ARG;
    if ((unsigned)field >= OC_FIELD_COUNT) return OC_E_ARG;
    if (!isfinite(bound) || bound < 0) return OC_E_ARG;

    const int side = tile_size >> lod;
    const size_t count = (size_t)side * side;
    float vmin, vmax;
    int rc = oc_enc_gather(e, field_data, n, tile_size, tile_x, tile_z, lod, &vmin, &vmax);
    if (rc) return rc;

    struct oc_tile_header th = {
        .field = (uint8_t)field, .lod = (uint8_t)lod, .codec = (uint8_t)e->codec, .flags = 0,
        .tile_x = (uint16_t)tile_x, .tile_z = (uint16_t)tile_z,
        .width = (uint16_t)side, .height = (uint16_t)side, .bound = bound,
    };
    if (bound == 0 || !oc_enc_quantise_new(e, count, vmin, vmax, bound, 1.0, &th.offset, &th.scale))
        return oc_enc_append_raw(out, &th, e->vals, count);
    return oc_enc_append_intra(e, &th, e->q, NULL, 1, out);
}

int oc_encode_tile_cascade(struct oc_encoder *e, const float *field_data, int n, int tile_size,
                           int tile_x, int tile_z, int lod, enum oc_field field, float bound, int cascade,
                           struct oc_buf *out)
{
    if (cascade < 0 || cascade >= OC_MAX_CASCADES || !out) return OC_E_ARG;
    size_t at = out->len;
    int rc = oc_encode_tile(e, field_data, n, tile_size, tile_x, tile_z, lod, field, bound, out);
    if (rc == 0)
        out->data[at + 3] = (uint8_t)cascade; /* tile header flags, bits 0-1 */
    return rc;
}

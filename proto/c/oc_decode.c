/* oc_decode.c — frame decoder. Validates every header field and length
 * before touching the bytes it describes; allocates only after the sizes
 * are known to be within protocol limits. */
#include "oc_internal.h"

#include <stdlib.h>
#include <string.h>

struct oc_decoder {
    struct oc_entropy *ent;
    size_t cap;       /* samples the scratch arrays hold */
    float *samples;
    int32_t *q;
    uint32_t *zz;
    uint8_t *packed;
};

struct oc_decoder *oc_decoder_new(void)
{
    struct oc_decoder *d = calloc(1, sizeof *d);
    if (!d) return NULL;
    if (!(d->ent = oc_entropy_new())) { free(d); return NULL; }
    return d;
}

void oc_decoder_free(struct oc_decoder *d)
{
    if (!d) return;
    oc_entropy_free(d->ent);
    free(d->samples); free(d->q); free(d->zz); free(d->packed);
    free(d);
}

static int reserve_scratch(struct oc_decoder *d, size_t count)
{
    if (count <= d->cap) return OC_OK;
    free(d->samples); free(d->q); free(d->zz); free(d->packed);
    d->samples = malloc(count * sizeof(float));
    d->q = malloc(count * sizeof(int32_t));
    d->zz = malloc(count * sizeof(uint32_t));
    d->packed = malloc(count * 5);
    if (!d->samples || !d->q || !d->zz || !d->packed) {
        free(d->samples); free(d->q); free(d->zz); free(d->packed);
        d->samples = NULL; d->q = NULL; d->zz = NULL; d->packed = NULL;
        d->cap = 0;
        return OC_E_NOMEM;
    }
    d->cap = count;
    return OC_OK;
}

static int decode_payload(struct oc_decoder *d, const struct oc_tile_header *th, const uint8_t *p)
{
    const size_t count = (size_t)th->width * th->height;   /* <= OC_MAX_N^2, validated */
    int rc = reserve_scratch(d, count);
    if (rc) return rc;
    if (th->codec == OC_CODEC_RAW_F32) {
        if (th->payload_len != count * 4) return OC_E_CORRUPT;
        for (size_t k = 0; k < count; k++) d->samples[k] = oc_get_f32(p + 4 * k);
        return OC_OK;
    }
    /* Lossy: 16-byte prefix, then the entropy-coded streams A and B. */
    if (th->payload_len < OC_LOSSY_PREFIX) return OC_E_CORRUPT;
    int esc_width = p[0];
    size_t esc_count = oc_get_u32(p + 4);
    if (esc_width > 4 || p[1] || p[2] || p[3] || p[14] || p[15]) return OC_E_CORRUPT;
    if (esc_count > count || (esc_count == 0) != (esc_width == 0)) return OC_E_CORRUPT;
    int8_t coef[OC_PRED_COEFS];
    memcpy(coef, p + 8, OC_PRED_COEFS);
    size_t plain = count + esc_count * (size_t)esc_width;   /* <= 5 * count: fits the scratch */
    rc = oc_entropy_decompress(d->ent, th->codec, p + OC_LOSSY_PREFIX, th->payload_len - OC_LOSSY_PREFIX,
                               d->packed, plain);
    if (rc) return rc;
    if ((rc = oc_unpack_escapes(d->packed, count, esc_count, esc_width, d->zz))) return rc;
    oc_unpredict(d->zz, th->width, th->height, coef, d->q);
    for (size_t k = 0; k < count; k++) d->samples[k] = oc_dequant(d->q[k], th->offset, th->scale);
    return OC_OK;
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
    /* Pass 2: payloads, in order. */
    pos = first;
    for (unsigned t = 0; t < fh->tile_count; t++) {
        oc_tile_header_parse(data + pos, len - pos, fh, &th);
        pos += OC_TILE_HEADER_SIZE;
        if ((rc = decode_payload(d, &th, data + pos))) return rc;
        pos += th.payload_len;
        if (fn && (rc = fn(user, fh, &th, d->samples))) return rc;
    }
    return OC_OK;
}

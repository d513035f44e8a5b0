/* oc_internal.h — helpers shared by the proto/c modules (not a public API). */
#ifndef OCEAND_OC_INTERNAL_H
#define OCEAND_OC_INTERNAL_H

#include "oc_proto.h"

#include <stdint.h>

/* Hot loops get an AVX2 clone picked at load time (GCC ifunc); elsewhere plain C. */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define OC_VECTOR_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define OC_VECTOR_CLONES
#endif

/* Little-endian scalar access (oc_header.c). */
void oc_put_u16(uint8_t *p, uint16_t v);
void oc_put_u32(uint8_t *p, uint32_t v);
void oc_put_u64(uint8_t *p, uint64_t v);
void oc_put_f32(uint8_t *p, float v);
void oc_put_f64(uint8_t *p, double v);
uint16_t oc_get_u16(const uint8_t *p);
uint32_t oc_get_u32(const uint8_t *p);
uint64_t oc_get_u64(const uint8_t *p);
float oc_get_f32(const uint8_t *p);
double oc_get_f64(const uint8_t *p);

/* Parse + validate a frame header; *hsize = bytes to skip to the first tile. */
int oc_frame_header_parse(const uint8_t *src, size_t len, struct oc_frame_header *h, size_t *hsize);
void oc_tile_header_write(uint8_t *dst, const struct oc_tile_header *t);
/* Parse + validate a tile header against its frame; checks payload_len <= len - 40. */
int oc_tile_header_parse(const uint8_t *src, size_t len, const struct oc_frame_header *fh,
                         struct oc_tile_header *t);

/* Lossy payload (codec 1 and 2), PROTOCOL.md §5.5: a 16-byte prefix
 *   0 u8 esc_width (0..4)   1 u8 0   2 u16 0   4 u32 esc_count
 *   8 i8 coef[6] (W, N, NW, NE, WW, NN; units of 1/64)   14 u16 0
 * then the entropy-coded bytes: count bytes of stream A + esc_count*esc_width bytes of stream B. */
#define OC_LOSSY_PREFIX 16
#define OC_PRED_COEFS 6
extern const int8_t oc_lorenzo_coef[OC_PRED_COEFS];

/* The integer pipeline (oc_transform.c). q and zz are w*h, row-major. */
void oc_predict_fit(const int32_t *q, int w, int h, int8_t coef[OC_PRED_COEFS]);
void oc_predict_residuals(const int32_t *q, int w, int h, const int8_t coef[OC_PRED_COEFS], uint32_t *zz);
/* The same two with max |q| already known (the encoder computes it once per tile). */
uint32_t oc_max_abs(const int32_t *q, size_t count);
void oc_predict_fit_m(const int32_t *q, int w, int h, uint32_t maxabs, int8_t coef[OC_PRED_COEFS]);
void oc_predict_residuals_m(const int32_t *q, int w, int h, uint32_t maxabs, const int8_t coef[OC_PRED_COEFS],
                            uint32_t *zz);
void oc_unpredict(const uint32_t *zz, int w, int h, const int8_t coef[OC_PRED_COEFS], int32_t *q);
/* out must hold 5*count bytes; esc_scratch count values. Returns esc_count. */
size_t oc_pack_escapes(const uint32_t *zz, size_t count, uint8_t *out, uint32_t *esc_scratch, int *esc_width);
/* in holds count + esc_count*esc_width bytes; OC_E_CORRUPT if the escapes disagree. */
int oc_unpack_escapes(const uint8_t *in, size_t count, size_t esc_count, int esc_width, uint32_t *zz);
/* value = float32(offset + q*scale), computed in double: the normative reconstruction. */
static inline float oc_dequant(int32_t q, double offset, double scale)
{
    return (float)(offset + (double)q * scale);
}

/* The encoder (oc_encode.c); its pieces are shared with the temporal streams (oc_stream.c). */
struct oc_encoder {
    struct oc_entropy *ent;
    int codec, level;
    size_t cap;        /* samples the scratch arrays hold */
    float *vals;       /* gathered samples */
    int32_t *q;        /* quantised codes */
    uint32_t *zz;      /* zigzagged prediction residuals */
    uint32_t *esc;     /* escaped residuals */
    uint8_t *packed;   /* streams A + B, input of the entropy coder */
    int8_t forced[OC_PRED_COEFS];
    int force;         /* test hook: use forced[] instead of fitting */
    /* A temporal stream's intra candidates (oc_stream.c): here, not in the stream, so
     * threads encoding different tiles of one stream, each with its own encoder, share
     * no scratch. */
    int32_t *cand_q;   /* a candidate's codes (cand_cap samples) */
    size_t cand_cap;
    struct oc_buf cand; /* a candidate tile */
};

int oc_enc_reserve(struct oc_encoder *e, size_t count);
int oc_enc_scan_range(const float *v, size_t count, float *vmin, float *vmax);   /* nonzero: NaN/Inf */
int oc_enc_gather(struct oc_encoder *e, const float *field_data, int n, int tile_size, int tile_x, int tile_z,
                  int lod, float *vmin, float *vmax);
int oc_enc_quantise_new(struct oc_encoder *e, size_t count, float vmin, float vmax, double bound, double headroom,
                        double *offset, double *scale);
int oc_enc_quantise_on(struct oc_encoder *e, int32_t *q, size_t count, float vmin, float vmax, double bound,
                       double offset, double scale);
int oc_enc_append_raw(struct oc_buf *out, struct oc_tile_header *th, const float *vals, size_t count);
/* coef: the predictor coefficients, or NULL for the encoder's (fitted, or the test hook's). */
int oc_enc_append_intra(struct oc_encoder *e, struct oc_tile_header *th, const int32_t *q,
                        const int8_t *coef, int allow_raw, struct oc_buf *out);

/* Temporal prediction (codec 3, oc_temporal.c), PROTOCOL.md §5.6-5.8.
 * Payload prefix, 40 bytes:
 *   0 u8 depth (1..4)  1 u8 packing (0 bytes, 1 pairs)  2 u8 esc_width  3 u8 0
 *   4 u32 esc_count    8 u32 pair_esc_count             12 u32 0
 *   16 u64 ref_seq     24 i16 coef[7] (d1, d2, d3, L(d1), L(d2), L(d3), L(q1); units of 1/4096)  38 u16 0 */
#define OC_TEMPORAL_PREFIX 40
#define OC_TEMPORAL_MAX_DEPTH 4
#define OC_TEMPORAL_COEFS 7
#define OC_PAIR_LIMIT 15        /* a pair byte holds two zigzag values below 15: 15*z1 + z2 */
#define OC_TEMPORAL_CODE_MAX (1 << 27)   /* encoder chains keep |codes| below this (int32 Laplacians) */
/* Coefficients a tile of this depth may use (others must be 0): bit k = coef k. */
unsigned oc_temporal_coef_mask(int depth);
/* Predictions (mod 2^32) of row j from the references refs[0..depth) (the codes of
 * frames ref_seq, ref_seq-1, ...; w*h each), for any int32 codes (the decoder). */
void oc_temporal_predict_row(const int32_t *const *refs, int depth, int w, int h, int j,
                             const int16_t coef[OC_TEMPORAL_COEFS], uint32_t *pred);
/* Encoder side: Laplacians of a reference (|q| < OC_TEMPORAL_CODE_MAX), predictions of row j
 * from the references and their Laplacians, and the least-squares coefficients for codes q. */
void oc_temporal_laplacian(const int32_t *q, int w, int h, int32_t *L);
/* Encoder: each code of a row moved to the code within the bound nearest its prediction. */
void oc_temporal_snap_row(int32_t *q, const uint32_t *pred, const float *v, int w, double offset, double scale,
                          double bound);
void oc_temporal_predict_row_cached(const int32_t *const *refs, const int32_t *const *laps, int depth, int w, int j,
                                    const int16_t coef[OC_TEMPORAL_COEFS], uint32_t *pred);
void oc_temporal_fit(const int32_t *const *refs, const int32_t *const *laps, int depth, const int32_t *q, int w,
                     int h, int16_t coef[OC_TEMPORAL_COEFS]);
/* Pair packing (packing 1): out gets (count+1)/2 pair bytes, then the escaped pairs'
 * values packed as oc_pack_escapes does. out must hold 6*count+8 bytes; esc_scratch 2*count values.
 * Returns the plain length; sets the counts. */
size_t oc_pack_pairs(const uint32_t *zz, size_t count, uint8_t *out, uint32_t *esc_scratch,
                     size_t *pair_esc_count, size_t *esc_count, int *esc_width);
/* The same in two steps: the (count+1)/2 pair bytes (255 = escaped pair), then, with
 * those in out, the escaped pairs' values after them. */
void oc_pair_bytes(const uint32_t *zz, size_t count, uint8_t *out);
size_t oc_pack_pair_escapes(const uint32_t *zz, size_t count, uint8_t *out, uint32_t *esc_scratch,
                            size_t *pair_esc_count, size_t *esc_count, int *esc_width);
/* Inverse; plain_len is checked against the counts. OC_E_CORRUPT on any inconsistency. */
int oc_unpack_pairs(const uint8_t *in, size_t plain_len, size_t count, size_t pair_esc_count, size_t esc_count,
                    int esc_width, uint32_t *zz, uint32_t *scratch);

/* Test hook (gen_vectors): force predictor coefficients instead of fitting; NULL = fit. */
void oc_encoder_force_predictor(struct oc_encoder *e, const int8_t *coef);

/* Entropy coders (oc_entropy.c). One context per encoder/decoder. */
struct oc_entropy;
struct oc_entropy *oc_entropy_new(void);
void oc_entropy_free(struct oc_entropy *c);
size_t oc_entropy_bound(int codec, size_t n);
/* Returns compressed size, or 0 on failure. */
size_t oc_entropy_compress(struct oc_entropy *c, int codec, int level, const uint8_t *src, size_t n,
                           uint8_t *dst, size_t cap);
/* The same with the byte histogram of src already counted (hist[b] = bytes equal to b). */
size_t oc_entropy_compress_hist(struct oc_entropy *c, int codec, int level, const uint8_t *src, size_t n,
                                const uint32_t hist[256], uint8_t *dst, size_t cap);
/* hist += the byte histogram of src. */
void oc_byte_hist_add(const uint8_t *src, size_t n, uint32_t hist[256]);
/* Decompress exactly n bytes consuming exactly srclen bytes; OC_E_CORRUPT otherwise. */
int oc_entropy_decompress(struct oc_entropy *c, int codec, const uint8_t *src, size_t srclen,
                          uint8_t *dst, size_t n);

#endif

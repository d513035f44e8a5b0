/* oc_proto.h — oceand wire protocol v1: binary frames and the tile codec.
 * Pure data transformation: no networking, no simulation, no globals.
 * The normative description is proto/PROTOCOL.md; this is its C binding.
 *
 * A binary frame = frame header (OC_FRAME_HEADER_SIZE bytes) followed by
 * tile_count tiles, each = tile header (OC_TILE_HEADER_SIZE) + payload.
 * All integers and floats little-endian.
 *
 * Frame header, 48 bytes:
 *   0  u32 magic 'O','C','N','F'      24 u32 params_version
 *   4  u16 version (1)                28 u16 n            (samples per side)
 *   6  u16 header_size (48)           30 u16 tile_size    (samples per tile side at LOD 0)
 *   8  u64 seq                        32 f32 patch_size   (m)
 *   16 f64 sim_time (s)               36 u16 tile_count   (tiles in this frame)
 *                                     38 u16 flags        (0)
 *                                     40 u64 server_time_us (unix µs when encoded)
 * Tile header, 40 bytes:
 *   0 u8 field  1 u8 lod  2 u8 codec  3 u8 flags(0)
 *   4 u16 tile_x  6 u16 tile_z  8 u16 width  10 u16 height   (samples in this tile at this LOD)
 *   12 f32 bound (max abs error, 0 for lossless)
 *   16 f64 offset  24 f64 scale   (value = float32(offset + q*scale), computed in f64)
 *   32 u32 payload_len  36 u32 reserved(0)
 * Tile (tx, tz) at LOD l covers samples ix = tx*tile_size + i*2^l,
 * iz = tz*tile_size + j*2^l, for i < width, j < height; width = tile_size>>l. */
#ifndef OCEAND_OC_PROTO_H
#define OCEAND_OC_PROTO_H

#include <stddef.h>
#include <stdint.h>

#define OC_MAGIC            "OCNF"
#define OC_PROTO_VERSION    1
#define OC_SUBPROTOCOL      "oceand.v1"
#define OC_FRAME_HEADER_SIZE 48
#define OC_TILE_HEADER_SIZE  40
#define OC_MAX_N            2048
#define OC_MAX_LOD          4

enum oc_field {
    OC_FIELD_HEIGHT = 0, OC_FIELD_DX = 1, OC_FIELD_DZ = 2,
    OC_FIELD_SLOPE_X = 3, OC_FIELD_SLOPE_Z = 4, OC_FIELD_JACOBIAN = 5,
    OC_FIELD_FOAM = 6,
    OC_FIELD_COUNT
};

enum oc_codec {
    OC_CODEC_RAW_F32 = 0,   /* payload = width*height float32, lossless */
    OC_CODEC_QUANT_LORENZO = 1, /* quantise to bound, predict (Lorenzo at tile borders, fitted
                                   6-neighbour predictor inside), zigzag, escape packing, raw
                                   DEFLATE (RFC 1951); the default. Bit-exact rules: PROTOCOL.md §5 */
    OC_CODEC_QUANT_LORENZO_ZSTD = 2, /* proto area addition: same pipeline, zstd frame as the entropy coder */
    /* 3.. reserved: temporal prediction */
};

/* Errors: negative return values. */
enum oc_error {
    OC_OK = 0,
    OC_E_TRUNCATED = -1,   /* input shorter than its headers say */
    OC_E_MAGIC = -2,       /* not an oceand frame */
    OC_E_VERSION = -3,     /* protocol version not supported */
    OC_E_CORRUPT = -4,     /* inconsistent header fields or payload */
    OC_E_TOO_LARGE = -5,   /* dimensions beyond protocol limits */
    OC_E_NOMEM = -6,
    OC_E_ARG = -7,         /* invalid argument to an encoder function */
};
const char *oc_strerror(int err);
const char *oc_field_name(enum oc_field f); /* "height","dx","dz","slope_x","slope_z","jacobian" */
int oc_field_from_name(const char *name);   /* -1 if unknown */

struct oc_frame_header {
    uint64_t seq;
    double   sim_time;
    uint32_t params_version;
    uint16_t n;
    uint16_t tile_size;
    float    patch_size;
    uint16_t tile_count;
    uint16_t flags;
    uint64_t server_time_us;
};

struct oc_tile_header {
    uint8_t  field, lod, codec, flags;
    uint16_t tile_x, tile_z, width, height;
    float    bound;
    double   offset, scale;
    uint32_t payload_len;
};

/* Growable byte buffer. */
struct oc_buf { uint8_t *data; size_t len, cap; };
int  oc_buf_reserve(struct oc_buf *b, size_t extra);
void oc_buf_free(struct oc_buf *b);

void oc_frame_header_write(uint8_t dst[OC_FRAME_HEADER_SIZE], const struct oc_frame_header *h);
int  oc_frame_header_read(const uint8_t *src, size_t len, struct oc_frame_header *h);

/* Encoder: owns compressor state and scratch; one per thread. */
struct oc_encoder;
struct oc_encoder *oc_encoder_new(void);
void oc_encoder_free(struct oc_encoder *e);
/* proto area addition: choose the lossy codec (OC_CODEC_QUANT_LORENZO, the
 * default, or OC_CODEC_QUANT_LORENZO_ZSTD) and the entropy coder level
 * (0 = default: Huffman-only DEFLATE block / zstd 1; 2..12: libdeflate level). OC_E_ARG on an unknown codec. */
int oc_encoder_set_codec(struct oc_encoder *e, enum oc_codec codec, int level);

/* Append one encoded tile (tile header + payload) to out. field_data is the
 * full n*n field, row-major; bound > 0 selects the lossy codec with
 * max |decoded - input| <= bound, bound == 0 stores raw float32. */
int oc_encode_tile(struct oc_encoder *e, const float *field_data, int n, int tile_size,
                   int tile_x, int tile_z, int lod, enum oc_field field, float bound,
                   struct oc_buf *out);
/* The tile is sent raw float32 (codec 0, lossless) instead when bound == 0,
 * when the codes would not fit in int32 (huge dynamic range for the bound),
 * when the bound is below float32 resolution of the values, or when the
 * lossy payload would not be smaller than raw. Non-finite input: OC_E_ARG. */

/* Decoder: walks a whole frame, checking every length before reading. */
struct oc_decoder;
struct oc_decoder *oc_decoder_new(void);
void oc_decoder_free(struct oc_decoder *d);
/* Called for each tile with its decoded samples (width*height floats, row-major). */
typedef int (*oc_tile_fn)(void *user, const struct oc_frame_header *fh,
                          const struct oc_tile_header *th, const float *samples);
int oc_decode_frame(struct oc_decoder *d, const uint8_t *data, size_t len,
                    struct oc_frame_header *fh, oc_tile_fn fn, void *user);
/* Returns OC_OK, a negative OC_E_* (bytes after the last tile: OC_E_CORRUPT),
 * or the first nonzero value fn returned (decoding stops there). fn may be NULL. */

#endif

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
 *                                     38 u16 flags        (bit 0 rendered, bit 1 part: more follow)
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
#define OC_FRAME_FLAG_RENDERED 0x0001u /* the answer to a render (PROTOCOL.md §7.5) */
#define OC_FRAME_FLAG_PART 0x0002u     /* more tiles of this tick follow in the next message (§3.4) */
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
    OC_CODEC_TEMPORAL = 3,  /* predicted from the same tile's codes in the previous 1..4 frames
                               (same quantisation grid), residuals pair-packed, raw DEFLATE.
                               Needs a decoder that kept those frames: PROTOCOL.md §5.6-5.9 */
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
    OC_E_REFERENCE = -8,   /* a predicted tile (codec 3) names reference frames the decoder does
                              not hold (missed, not yet received, other grid): wait for a keyframe */
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
    uint8_t  field, lod, codec, flags;   /* flags bits 0-1: the cascade (PROTOCOL.md §3.2); others 0 */
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

/* The BODY header extension (PROTOCOL.md §3.5): the floating bodies' state
 * of the frame's tick, at offset 48 of the frame header (header_size =
 * 48 + OC_BODY_SECTION_HEAD + count * OC_BODY_RECORD_SIZE). A frame without
 * it (header_size 48, or another tag) has no bodies; readers that do not know
 * it skip it with the rest of the header (§3.1). */
#define OC_BODY_TAG            "BODY"
#define OC_BODY_SECTION_HEAD   16   /* u8[4] tag, u16 count, u16 record_size, u8[8] reserved */
#define OC_BODY_RECORD_SIZE    48
#define OC_BODY_MAX_RECORDS    1364 /* (65535 - 48 - 16) / 48: header_size is a u16 */
#define OC_BODY_FLAG_ADRIFT    0x01u /* no session owns it now: its owner is gone */
#define OC_BODY_FLAG_POWERED   0x02u /* its kind has thrust and a rudder */
struct oc_body_record {
    uint32_t id;
    uint8_t  kind;            /* index into hello.body_kinds */
    uint8_t  flags;           /* OC_BODY_FLAG_* */
    int8_t   throttle, rudder; /* x 127, -127..127 */
    float    pos[3];          /* m, world, centre of mass */
    float    quat[4];         /* w, x, y, z: body -> world */
    float    vel[3];          /* m/s */
};
/* Bytes of a section of count records (a multiple of 8). */
static inline size_t oc_body_section_size(int count)
{
    return OC_BODY_SECTION_HEAD + (size_t)count * OC_BODY_RECORD_SIZE;
}
/* Write the section (oc_body_section_size(count) bytes) into dst. */
void oc_body_section_write(uint8_t *dst, const struct oc_body_record *r, int count);
/* Read the BODY section of a frame message (or of its header alone: len
 * bytes from the frame start). Returns the number of records (0: the frame
 * has none) and writes at most max of them to out (out may be NULL to count);
 * OC_E_TRUNCATED / OC_E_CORRUPT on a bad frame header or a section that does
 * not fit header_size, OC_E_MAGIC / OC_E_VERSION as oc_frame_header_read. */
int oc_body_section_read(const uint8_t *frame, size_t len, struct oc_body_record *out, int max);

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

/* The same, for cascade `cascade` (0..3) of a multi-cascade sea: the tile
 * header's flags carry the cascade index (PROTOCOL.md §3.2, §4.1). */
#define OC_TILE_CASCADE_MASK 3u
#define OC_MAX_CASCADES 4
static inline int oc_tile_cascade(const struct oc_tile_header *th) { return th->flags & OC_TILE_CASCADE_MASK; }
int oc_encode_tile_cascade(struct oc_encoder *e, const float *field_data, int n, int tile_size,
                           int tile_x, int tile_z, int lod, enum oc_field field, float bound, int cascade,
                           struct oc_buf *out);

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
 * or the first nonzero value fn returned (decoding stops there). fn may be NULL.
 *
 * The decoder keeps the codes of the lossy tiles (codec 1, 2, 3) of the last
 * frames per tile (field, lod, tile_x, tile_z, n, tile_size): the references
 * of predicted tiles (codec 3). So one decoder per stream, frames in order.
 * A frame that fails (any error, or fn returning nonzero) adds nothing to that
 * history; a predicted tile whose references are missing fails with
 * OC_E_REFERENCE before any sample is produced. */
void oc_decoder_reset(struct oc_decoder *d);   /* forget every reference */
/* Cap on the memory kept for references (codes and their table), in bytes (default
 * 256 MiB; 0 keeps nothing: an intra-only client). Tiles that do not fit are not
 * kept (their successors then fail with OC_E_REFERENCE). */
void oc_decoder_set_history_limit(struct oc_decoder *d, size_t bytes);

/* ---- Temporal streams (encoder side of codec 3), PROTOCOL.md §5.9 ----
 * One oc_stream per layer = (field, lod, bound) of a field of side n cut into
 * tile_size tiles. Each tick the owner calls oc_stream_encode once with the
 * new field: it quantises every tile on the layer's grid and encodes the
 * shared frame (each tile predicted from the previous ticks, or a keyframe).
 * A receiver that lacks the references of this tick's shared tiles gets the
 * keyframe tiles of the same tick instead (oc_stream_keyframe_tile): encoded
 * on first request, once per tick, identical codes, so a receiver continues
 * the shared chain from the next tick on. Nothing here depends on the number
 * of receivers. */
struct oc_stream;
struct oc_stream *oc_stream_new(int n, int tile_size, int lod, enum oc_field field, float bound);
void oc_stream_free(struct oc_stream *s);
/* A periodic keyframe every `ticks` frames (0 = only when needed). Default OC_STREAM_KEYFRAME_INTERVAL. */
#define OC_STREAM_KEYFRAME_INTERVAL 300
void oc_stream_set_keyframe_interval(struct oc_stream *s, int ticks);
/* Grid refinement r: a chain quantises on a grid r times finer than the bound needs, and
 * a predicted sample whose prediction is within the bound takes it (residual 0; docs/codec.md,
 * "Grid refinement"). 1 = the coarse grid (one valid code per sample). Default, by
 * measurement: 3 for bounds >= 0.5 mm (every bound a subscription offers), else 1.
 * Changing it resets the stream. */
#define OC_STREAM_GRID_REFINE(bound) ((bound) >= 0.0005f ? 3 : 1)
#define OC_STREAM_GRID_REFINE_MAX 8
void oc_stream_set_grid_refine(struct oc_stream *s, int refine);
/* Forget the chain: the next oc_stream_encode writes keyframes on a new grid. */
void oc_stream_reset(struct oc_stream *s);
/* The sea changed but keeps its phases (e.g. wind or amplitude, not the seed): the next
 * oc_stream_encode keeps the chains and sends each tile predicted or intra on the
 * chain's grid, whichever is smaller; the ticks after it predict at full depth. */
void oc_stream_sea_changed(struct oc_stream *s);
/* Encode this tick's shared frame of the layer. field_data = the full n*n field,
 * seq = the frame's seq. A seq that does not follow the previous call's by 1
 * starts a new chain (keyframes). Non-finite input: OC_E_ARG (stream reset). */
int oc_stream_encode(struct oc_stream *s, struct oc_encoder *e, const float *field_data, uint64_t seq);
/* The same in three parts, so that several threads can encode one layer:
 * oc_stream_begin (one thread), then oc_stream_encode_tiles on ranges of tiles
 * (tile k = tile_z * (n / tile_size) + tile_x) that together cover every tile
 * once, concurrently on disjoint ranges, each with its own encoder, in any
 * order, then oc_stream_end (one thread, after every range returned). The
 * bytes do not depend on the split or the order. A range that fails makes
 * oc_stream_end reset the stream and return an error; oc_stream_end returns
 * OC_OK otherwise. oc_stream_keyframe_tile may likewise run concurrently for
 * distinct tiles (each with its own encoder), for a tile as soon as its range
 * is encoded, until the next oc_stream_begin. */
int oc_stream_begin(struct oc_stream *s, uint64_t seq);
int oc_stream_encode_tiles(struct oc_stream *s, struct oc_encoder *e, const float *field_data, int first, int count);
int oc_stream_end(struct oc_stream *s);
int oc_stream_tile_count(const struct oc_stream *s);
/* Ticks of history a receiver needs for this tick's shared tiles: it must have
 * received this layer (the same tiles, shared or keyframe) in each of the
 * ticks seq-1 ... seq-need. 0 = the shared frame is all keyframes (or raw). */
int oc_stream_need(const struct oc_stream *s);
/* This tick's shared tile (tile header + payload): a pointer into the stream, valid until the next encode. */
int oc_stream_tile(const struct oc_stream *s, int tile_x, int tile_z, const uint8_t **data, size_t *len);
/* This tick's keyframe tile, encoded on first request (then cached until the next encode;
 * e may be NULL to fetch one already made: OC_E_ARG if it was not). */
int oc_stream_keyframe_tile(struct oc_stream *s, struct oc_encoder *e, int tile_x, int tile_z,
                            const uint8_t **data, size_t *len);
/* Counters for metrics and benchmarks: shared tiles encoded as keyframes, keyframe tiles made on demand. */
/* change_intra_tiles: shared tiles sent intra on their chain's grid after oc_stream_sea_changed. */
struct oc_stream_stats { uint64_t ticks, key_tiles, predicted_tiles, demand_key_tiles, change_intra_tiles; };
void oc_stream_stats(const struct oc_stream *s, struct oc_stream_stats *out);

/* Grids: the tiles of frames put together into whole fields, per cascade
 * (PROTOCOL.md §4, §4.1). Each wanted field of each wanted cascade is a
 * (n >> lod)^2 float grid, row-major (row = z); a cascade's grid covers its own
 * patch (cascade_patch_sizes of hello). The grid decodes with a decoder of its
 * own (so frames of one stream, in order). A frame is complete when it carried
 * every tile of every wanted field of every wanted cascade at its LOD: a frame
 * served at a coarser LOD (degraded, §7.2) is not, and the grids then still
 * hold an earlier frame. A change of n or tile_size starts empty grids. The
 * cascades add up only as surfaces (each at x mod L_c): to sum them on another
 * grid, resample each (tools/tap_surface.c does it spectrally). */
struct oc_grid;
/* Cascade 0's fields (bit mask of enum oc_field) at lod. NULL: out of memory. */
struct oc_grid *oc_grid_new(unsigned fields, int lod);
void oc_grid_free(struct oc_grid *g);
/* Also (or no longer: fields 0) assemble cascade 1..3 with its own fields and
 * LOD (a finer cascade loses nothing at LOD 1, §4.1). 0, or -1 for bad values. */
int oc_grid_want(struct oc_grid *g, int cascade, unsigned fields, int lod);
/* Decode one binary message into the grids: 0 or a negative OC_E_*. */
int oc_grid_add(struct oc_grid *g, const uint8_t *data, size_t len, struct oc_frame_header *fh);
int oc_grid_complete(const struct oc_grid *g);
/* Cascade c's grid of field f (side*side floats), NULL when not wanted or not
 * yet shaped; *bound = the error bound of its latest tile (0 = lossless). */
const float *oc_grid_field(const struct oc_grid *g, int cascade, enum oc_field f, int *side, float *bound);

#endif

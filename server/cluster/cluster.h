/* cluster.h — one simulation, many edge daemons, over NATS, so that the
 * viewers a sea can serve are not bounded by one daemon's network and CPU.
 *
 * The transport between `oceand --role sim` and `oceand --role edge`: the
 * subject scheme, the binary message formats, the demand table, and a NATS
 * link that publishes and receives them. No physics and no libwebsockets:
 * layers are opaque encoded tiles, control messages opaque JSON text. The
 * design, subjects and failure states are in docs/scaling.md.
 *
 * ---- Threads (to be merged into docs/threads.md) --------------------------
 * A link (struct cl_link) runs on three kinds of threads:
 *
 *   NATS library threads  read the socket, deliver messages (one shared
 *                         delivery thread for all of a link's subscriptions,
 *                         so delivery order is the publisher's order) and
 *                         report connection events. Our callbacks there only
 *                         parse, take a short mutex and append to a queue;
 *                         they never call back into the daemon.
 *   the link's pump       one pthread per link. It is the only thread that
 *                         writes to NATS: it drains the outbox (layers, params
 *                         events, replies, requests), sends heartbeats (sim:
 *                         status; edge: demand), changes the edge's layer
 *                         subscriptions, and times out requests. A slow or
 *                         dead NATS server blocks at most this thread (write
 *                         deadline 2 s), never the tick or the lws thread.
 *   the caller's threads  the tick thread calls cl_sim_publish_layer and
 *                         cl_sim_demand (a mutex held for a copy of 128 bytes
 *                         per edge: no I/O, no waiting on the network); the
 *                         lws thread calls everything else, including
 *                         cl_link_dispatch.
 *
 * Data into the daemon crosses through one locked inbox per link: every
 * handler in struct cl_handlers runs inside cl_link_dispatch, on the thread
 * that calls it (the lws thread), never on a NATS thread. When the inbox
 * goes from empty to non-empty the link calls cfg.wake(cfg.wake_user) from
 * the NATS or pump thread; the daemon passes a function that calls
 * lws_cancel_service, exactly as the sim thread does today, and calls
 * cl_link_dispatch on LWS_CALLBACK_EVENT_WAIT_CANCELLED.
 * Bounded everywhere: the outbox drops the oldest layers beyond
 * outbox_max_bytes (latest wins), the inbox keeps only the newest complete
 * layer of each (field, LOD, bound) and at most CL_INBOX_MAX other events;
 * every drop is counted in struct cl_stats.
 * Which thread writes and which reads each field of a link, and under which
 * lock, is in link_internal.h; the link's files are link*.c, one concern
 * each (lifecycle, inbox, pump, stream, requests, heartbeats).
 *
 * ---- Subjects (PREFIX is --nats-prefix, default "oceand") ----------------
 *   PREFIX.frame.<c>.<field>.<lod>.<bound>  sim -> edges: layer parts (OCNL) of cascade c,
 *                                       e.g. oceand.frame.0.height.0.2
 *   PREFIX.params                       sim -> edges: params events (OCNE kind PARAMS)
 *   PREFIX.status                       sim -> edges: sim heartbeat (OCNE kind STATUS; by = the sim
 *                                       process's instance id, cl_link_instance)
 *   PREFIX.ctl                          edge -> sim request/reply: set, pause, resume (OCNE CTL -> REPLY)
 *   PREFIX.hello                        edge -> sim request/reply: current params + schema (OCNE HELLO -> REPLY)
 *   PREFIX.demand                       edges -> sim: demand heartbeats with expiry (OCNE DEMAND: keys,
 *                                       and which of them stream and which need keyframes now)
 *   PREFIX.query                        edge -> sim request/reply: a client's point query (OCNE QUERY -> REPLY)
 *   PREFIX.probe                        edge -> sim request/reply: a client's probe (OCNE PROBE -> REPLY),
 *                                       repeated as a keepalive; the sim then streams
 *   <edge inbox>.p                      sim -> edge: probe_data of its clients' probes (OCNE PROBE_DATA)
 * Several seas share one NATS cluster by using different prefixes.
 */
#ifndef OCEAND_CLUSTER_H
#define OCEAND_CLUSTER_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* ---- layer keys --------------------------------------------------------
 * A layer is one field of one cascade at one LOD and one error bound. Its
 * key is the same number as the daemon's layer_key_cascade (the daemon
 * checks the constants agree at compile time): cascade 0's keys first. */
#define CL_FIELDS    7   /* OC_FIELD_COUNT */
#define CL_LODS      5   /* OC_MAX_LOD + 1 */
#define CL_BOUNDS    5   /* CTL_BOUND_COUNT */
#define CL_CASCADES  4   /* OCEAN_MAX_CASCADES; tile-header flags bits 0-1 */
#define CL_CASCADE_KEYS (CL_FIELDS * CL_LODS * CL_BOUNDS)
#define CL_KEYS      (CL_CASCADES * CL_CASCADE_KEYS)
#define CL_KEY_BYTES 128 /* bitmaps of keys: 1024 bits (700 used), room to grow */
/* Cascade 0's key. */
static inline int cl_key(int field, int lod, int bound_index)
{
    return (field * CL_LODS + lod) * CL_BOUNDS + bound_index;
}
static inline int cl_key_cascade(int cascade, int field, int lod, int bound_index)
{
    return cascade * CL_CASCADE_KEYS + cl_key(field, lod, bound_index);
}
static inline int cl_key_which_cascade(int key) { return key / CL_CASCADE_KEYS; }
static inline int cl_key_field(int key) { return key % CL_CASCADE_KEYS / (CL_LODS * CL_BOUNDS); }
static inline int cl_key_lod(int key) { return key / CL_BOUNDS % CL_LODS; }
static inline int cl_key_bound(int key) { return key % CL_BOUNDS; }
static inline bool cl_bit(const uint8_t bits[CL_KEY_BYTES], int key)
{
    return (bits[key >> 3] >> (key & 7)) & 1;
}
static inline void cl_bit_set(uint8_t bits[CL_KEY_BYTES], int key, bool on)
{
    if (on)
        bits[key >> 3] = (uint8_t)(bits[key >> 3] | (1u << (key & 7)));
    else
        bits[key >> 3] = (uint8_t)(bits[key >> 3] & ~(1u << (key & 7)));
}

/* Errors: negative return values. */
enum cl_error {
    CL_OK = 0,
    CL_E_TRUNCATED = -1,     /* shorter than its headers say */
    CL_E_MAGIC = -2,         /* not one of our messages */
    CL_E_VERSION = -3,       /* format version not supported */
    CL_E_CORRUPT = -4,       /* inconsistent fields */
    CL_E_TOO_LARGE = -5,     /* beyond the format's limits */
    CL_E_NOMEM = -6,
    CL_E_ARG = -7,           /* invalid argument */
    CL_E_FULL = -8,          /* a bounded table or queue is full */
    CL_E_NOT_CONNECTED = -9, /* no NATS connection at the moment */
    CL_E_TIMEOUT = -10,      /* no reply in time */
    CL_E_NO_RESPONDERS = -11,/* nobody serves the subject: the sim is not running */
    CL_E_NATS = -12,         /* the NATS library refused (message in the log / err text) */
    CL_E_LOST = -13,         /* the sim's record was written by another sim: it holds the lease now */
    CL_E_NO_JETSTREAM = -14, /* the NATS server has no JetStream (or no bucket could be made) */
};
const char *cl_strerror(int err);

/* ---- subjects ------------------------------------------------------------ */
#define CL_PREFIX_MAX  64
#define CL_SUBJECT_MAX 128
#define CL_DEFAULT_PREFIX "oceand"
/* A prefix is 1..64 characters: dot-separated non-empty tokens of
 * [A-Za-z0-9_-] (no wildcards, no spaces). */
bool cl_prefix_valid(const char *prefix);
enum cl_subject { CL_SUBJ_PARAMS, CL_SUBJ_STATUS, CL_SUBJ_CTL, CL_SUBJ_HELLO, CL_SUBJ_DEMAND, CL_SUBJ_QUERY, CL_SUBJ_PROBE,
                  CL_SUBJ_BODIES };
int cl_subject(char *out, size_t cap, const char *prefix, enum cl_subject which);
/* The subject of layer key `key` (cl_key_cascade). */
int cl_subject_layer(char *out, size_t cap, const char *prefix, int key);
/* Inverse of cl_subject_layer: the key, or a negative CL_E_*. */
int cl_subject_layer_parse(const char *subject, const char *prefix);

/* ---- layer parts (OCNL) ---------------------------------------------------
 * One NATS message carries tiles [tile_first, tile_first + tile_count) of
 * one layer at one tick: a whole layer when it fits the server's
 * max_payload, else consecutive parts. Little-endian:
 *   0  "OCNL"            38 u8  field          48 u64 server_time_us
 *   4  u16 version (2)   39 u8  lod            56 u32 data_len
 *   6  u16 header_size   40 u8  bound_index    60 u8  cascade (0..ncascades-1)
 *   8  u64 seq           41 u8  layer_flags    61 u8  ncascades (1..4: in force)
 *   16 f64 sim_time      42 u16 tiles_per_side 62 u8  encoded_lod (lod..4: of its tiles)
 *   24 u32 params_version 44 u16 tile_first    63 u8  need (0..4; 0 unless SHARED)
 *   28 u16 n             46 u16 tile_count     64 u8[128] encoded: keys the
 *   30 u16 tile_size                                  sim encoded this tick
 *   32 f32 patch_size                          192 u64 epoch: the sim process
 *   36 u16 frame_flags                                 (its instance id, != 0)
 *   200 u32 off[tile_count + 1]: tile i of the part is data[off[i], off[i+1])
 *      then data_len bytes: the tiles as on the WebSocket (tile header + payload;
 *      its flags byte is the cascade, its lod byte encoded_lod)
 * Bytes 8..47 carry the fields of the WebSocket frame header, so an edge
 * rebuilds byte-identical frames.
 * Sections (layer_flags): a layer's tiles are numbered 0 .. sections x
 * tiles_per_side^2 - 1: first its intra tiles (codec 1/0, decodable alone:
 * for a temporal layer this tick's keyframe tiles) when it has them, then,
 * with CL_LAYER_SHARED, its stream's shared tiles (codec 3 and the chains'
 * keyframes, PROTOCOL.md §5.9), which need the `need` previous ticks of the
 * same epoch. A layer without CL_LAYER_SHARED has its intra tiles only;
 * one with it has intra tiles too exactly when CL_LAYER_INTRA is set.
 * Predicted tiles reference the frames of one sim process: an edge never
 * lets a viewer's references span two epochs (a take-over, a restart).
 * Versions 1 and 2 (intra only, no epoch) are not read any more: sim and
 * edges upgrade together. */
#define CL_LAYER_MAGIC       "OCNL"
#define CL_LAYER_VERSION     3
#define CL_LAYER_HEADER_SIZE (64 + CL_KEY_BYTES + 8)
#define CL_LAYER_SHARED      0x02 /* layer_flags: the shared tiles of the layer's stream follow */
#define CL_LAYER_INTRA       0x04 /* with CL_LAYER_SHARED: intra (keyframe) tiles come first */
#define CL_LAYER_MAX_NEED    4    /* PROTOCOL.md §5.6: depth 1..4 */
#define CL_MAX_TILES_PER_SIDE 256
#define CL_MAX_LAYER_BYTES   (64u << 20)

struct cl_layer_info {
    uint64_t seq;
    double sim_time;
    uint32_t params_version;
    uint16_t n, tile_size;
    float patch_size;
    uint16_t frame_flags;
    uint64_t server_time_us;
    uint8_t field, lod, bound_index, layer_flags;
    uint8_t cascade, ncascades, encoded_lod;
    uint8_t need;           /* CL_LAYER_SHARED: ticks of history the shared tiles need */
    uint16_t tiles_per_side;
    uint8_t encoded[CL_KEY_BYTES];
    uint64_t epoch;         /* the sim process that encoded it (cl_link_epoch); not 0 */
};
/* Which sections a layer carries (cl_layer_sections: 1 or 2), and whether
 * it has intra tiles (first section) and shared tiles (last section). */
static inline bool cl_info_has_intra(const struct cl_layer_info *i)
{
    return !(i->layer_flags & CL_LAYER_SHARED) || (i->layer_flags & CL_LAYER_INTRA);
}
static inline bool cl_info_has_shared(const struct cl_layer_info *i) { return i->layer_flags & CL_LAYER_SHARED; }
static inline int cl_layer_sections(const struct cl_layer_info *i)
{
    return (cl_info_has_intra(i) ? 1 : 0) + (cl_info_has_shared(i) ? 1 : 0);
}
/* Tiles of a whole layer: sections x tiles_per_side^2. */
static inline int cl_layer_tiles(const struct cl_layer_info *i)
{
    return cl_layer_sections(i) * i->tiles_per_side * i->tiles_per_side;
}
/* The layer's key (cl_key_cascade). */
static inline int cl_info_key(const struct cl_layer_info *i)
{
    return cl_key_cascade(i->cascade, i->field, i->lod, i->bound_index);
}

/* A parsed part: pointers into the message, valid while it lives. */
struct cl_layer_part {
    struct cl_layer_info info;
    uint16_t tile_first, tile_count;
    const uint8_t *off;     /* tile_count + 1 little-endian u32 (unaligned) */
    const uint8_t *data;
    uint32_t data_len;
};
uint32_t cl_part_off(const struct cl_layer_part *p, int i);
/* Checks every field and every tile's framing (OC tile header: field,
 * encoded_lod, flags == cascade, 40 + payload_len == its span). Returns 0 or a negative CL_E_*. */
int cl_layer_part_parse(const uint8_t *msg, size_t len, struct cl_layer_part *out);
/* Bytes of a part with tile_count tiles and data_len bytes of tiles. */
size_t cl_layer_part_size(int tile_count, size_t data_len);
/* Writes tiles [tile_first, tile_first + tile_count) of a whole layer
 * into dst; returns the bytes written or a negative CL_E_*. The tiles must
 * lie in one section (cl_layer_sections): data and tile_off[tps^2 + 1]
 * (absolute offsets into data) are that section's, indexed by the tile's
 * number within it (tile_first mod tps^2). */
long cl_layer_part_write(uint8_t *dst, size_t cap, const struct cl_layer_info *info,
                         int tile_first, int tile_count, const uint8_t *data, const uint32_t *tile_off);
/* How many tiles from tile_first fit one message of at most max_payload
 * bytes (at least 1 unless that one tile does not fit: then 0). */
int cl_layer_part_tiles(const uint32_t *tile_off, int tile_first, int tiles_total, size_t max_payload);

/* A whole layer (assembled on the edge). data/tile_off are malloc'd; the
 * daemon may take them over (set to NULL) before cl_layer_free. */
struct cl_layer {
    struct cl_layer_info info;
    uint8_t *data;
    size_t len;
    uint32_t *tile_off;     /* cl_layer_tiles + 1 offsets into data (every section's tiles) */
};
void cl_layer_free(struct cl_layer *l);

/* Reassembles parts into whole layers, one slot per key. Parts of one layer
 * come in order (NATS keeps a publisher's order per subscription); a part
 * that does not continue the slot's layer, or a new layer before the old one
 * is complete, drops the incomplete one (counted). Not thread-safe. */
struct cl_assembler;
/* Bytes held by all incomplete layers together (data + tile offsets): a
 * publisher that starts a layer in every slot and never finishes one would
 * otherwise hold CL_KEYS x CL_MAX_LAYER_BYTES (11 GiB). Over it, slots of
 * older seqs are dropped first, then the part (CL_E_TOO_LARGE, counted).
 * A sim publishes a layer's parts one after another, so it needs one. */
#define CL_MAX_ASSEMBLY_BYTES ((size_t)2 * CL_MAX_LAYER_BYTES)
struct cl_assembler *cl_assembler_new(void);
void cl_assembler_set_budget(struct cl_assembler *a, size_t bytes); /* default CL_MAX_ASSEMBLY_BYTES */
size_t cl_assembler_held(const struct cl_assembler *a);
void cl_assembler_free(struct cl_assembler *a);
/* Returns 1 and a complete layer in *out (caller frees), 0 when more parts
 * are needed, or a negative CL_E_* (the part is ignored). */
int cl_assembler_add(struct cl_assembler *a, const struct cl_layer_part *p, struct cl_layer **out);
uint64_t cl_assembler_dropped(const struct cl_assembler *a);

/* Groups an edge's complete layers into frames: all layers of one seq. A
 * frame is complete when every layer the edge wants (want) and the sim
 * encoded at that seq (info.encoded) has arrived. A layer of a newer seq
 * hands out the older frame as it is (partial: some layer was lost or
 * superseded; counted) so a lost layer never stalls the stream; an older
 * seq is dropped. Layers of one seq must agree on the frame header fields.
 * Not thread-safe (the lws thread owns it). */
struct cl_frame_set {
    struct cl_layer_info hdr;          /* frame fields (seq .. server_time_us, encoded) of its layers */
    int nlayers;
    struct cl_layer *layers[CL_KEYS];  /* in key order, NULL-free up to nlayers */
    bool partial;
};
void cl_frame_set_free(struct cl_frame_set *f);
struct cl_collector;
struct cl_collector *cl_collector_new(void);
void cl_collector_free(struct cl_collector *c);
/* Takes the layer. Returns how many frames it wrote to out[0..1] (0, 1 or
 * 2: the older partial one, then the completed new one), or a negative
 * CL_E_* (the layer is freed). The caller frees each frame. */
int cl_collector_add(struct cl_collector *c, struct cl_layer *l, const uint8_t want[CL_KEY_BYTES],
                     struct cl_frame_set *out[2]);
/* The pending frame if it is complete for want now (a viewer left), else NULL. */
struct cl_frame_set *cl_collector_check(struct cl_collector *c, const uint8_t want[CL_KEY_BYTES]);
struct cl_collector_stats { uint64_t frames, partial, stale, mismatched; };
void cl_collector_stats(const struct cl_collector *c, struct cl_collector_stats *out);
/* Drop the frame being collected (the stream restarted under another seq). */
void cl_collector_reset(struct cl_collector *c);
/* Whether the fields of one layer are consistent (what cl_layer_part_write checks). */
bool cl_layer_info_valid(const struct cl_layer_info *info);

/* ---- envelopes (OCNE): everything that is not a layer ---------------------
 *   0 "OCNE"  4 u8 version (1)  5 u8 kind  6 u8 origin_len  7 u8 by_len
 *   8 u32 body_len  12 origin, by, body (exactly; nothing after)
 * origin = the daemon that sent it (edge or sim name); by = the WebSocket
 * client it acts for ("" if none). Both printable ASCII, at most 63 bytes. */
#define CL_ENV_MAGIC    "OCNE"
#define CL_ENV_VERSION  2   /* 2: 128-byte key bitmaps in DEMAND, kinds QUERY, PROBE, PROBE_DATA */
#define CL_ENV_HEADER   12
#define CL_NAME_MAX     64   /* incl. NUL */
#define CL_BODY_MAX     (1u << 20)
/* The JetStream record's largest value: the parameters (~2 kB), a measured sea (the largest
 * the check allows is ~200 kB) and the bodies (LEASE_BODIES_MAX_BYTES) together, within
 * NATS's default max_payload (1 MiB). */
#define CL_KV_VALUE_MAX (512u << 10)
enum cl_kind {
    CL_KIND_CTL = 1,     /* edge -> sim request: a client's set/pause/resume JSON */
    CL_KIND_HELLO = 2,   /* edge -> sim request: body empty */
    CL_KIND_REPLY = 3,   /* sim -> edge: the JSON answer */
    CL_KIND_PARAMS = 4,  /* sim -> edges: params event JSON; origin/by = who caused it */
    CL_KIND_STATUS = 5,  /* sim -> edges: heartbeat; body = JSON status text */
    CL_KIND_DEMAND = 6,  /* edge -> sim: body = u32 ttl_ms + u8[CL_KEY_BYTES] keys (+ stream + wish) */
    CL_KIND_QUERY = 7,   /* edge -> sim request: a client's `query` JSON (answered by REPLY) */
    CL_KIND_PROBE = 8,   /* edge -> sim request: a client's `probe` JSON (REPLY: `probing` or an error);
                            sent again unchanged every CL_PROBE_KEEPALIVE_S while the probe lasts */
    CL_KIND_PROBE_DATA = 9, /* sim -> edge, on <the edge's reply inbox>.p: one `probe_data` JSON; by = the client */
    CL_KIND_BODIES = 10,    /* sim -> edges, on <prefix>.bodies: a `bodies` JSON (PROTOCOL.md §7.6) */
    CL_KIND_BODY_SECTION = 11, /* sim -> edges, on <prefix>.bodies: u64 seq (LE) + the tick's BODY section
                                  (PROTOCOL.md §3.5; none = 0 bodies), published before that tick's layers */
};
struct cl_envelope {
    enum cl_kind kind;
    char origin[CL_NAME_MAX], by[CL_NAME_MAX];
    const uint8_t *body;    /* into the message */
    uint32_t body_len;
};
int cl_envelope_parse(const uint8_t *msg, size_t len, struct cl_envelope *out);
size_t cl_envelope_size(const char *origin, const char *by, size_t body_len);
long cl_envelope_write(uint8_t *dst, size_t cap, enum cl_kind kind, const char *origin, const char *by,
                       const void *body, size_t body_len);
#define CL_DEMAND_BODY (4 + CL_KEY_BYTES)
void cl_demand_body_write(uint8_t dst[CL_DEMAND_BODY], uint32_t ttl_ms, const uint8_t bits[CL_KEY_BYTES]);
int cl_demand_body_parse(const uint8_t *body, size_t len, uint32_t *ttl_ms, uint8_t bits[CL_KEY_BYTES]);
/* An edge's demand with the temporal codec (docs/scaling.md, "Temporal
 * layers through edges"): body = u32 ttl_ms + keys + stream + wish, three
 * bitmaps of CL_KEY_BYTES:
 *   keys    the layers its viewers subscribe to (as CL_DEMAND_BODY's);
 *   stream  those some viewer takes with the temporal codec: the sim encodes
 *           their stream (codec 3) and publishes its shared tiles;
 *   wish    those that need intra (keyframe) tiles at the next ticks: a viewer
 *           that is not temporal, or a temporal one short of references (new,
 *           after a gap, a step of its ladder, a new sim).
 * stream and wish are subsets of keys. A body of CL_DEMAND_BODY bytes (an
 * edge that does not stream) parses as stream = none, wish = keys. */
#define CL_DEMAND_BODY_EX (4 + 3 * CL_KEY_BYTES)
struct cl_demand_bits {
    uint8_t keys[CL_KEY_BYTES], stream[CL_KEY_BYTES], wish[CL_KEY_BYTES];
};
void cl_demand_body_write_ex(uint8_t dst[CL_DEMAND_BODY_EX], uint32_t ttl_ms, const struct cl_demand_bits *b);
/* Either length; CL_E_CORRUPT for keys beyond CL_KEYS or stream / wish outside keys. */
int cl_demand_body_parse_ex(const uint8_t *body, size_t len, uint32_t *ttl_ms, struct cl_demand_bits *out);

/* ---- demand table (sim side) ----------------------------------------------
 * Edge name -> (keys, expiry). The sim encodes the union of the live
 * entries; an edge that stops heartbeating drops out at its expiry, one
 * that sends an empty set drops out at once. Thread-safe (one mutex); time
 * is passed in (monotonic seconds) so expiry is testable without sleeping. */
#define CL_DEMAND_TTL_MIN 0.2
#define CL_DEMAND_TTL_MAX 60.0
struct cl_demand;
struct cl_demand *cl_demand_new(int max_edges);
void cl_demand_free(struct cl_demand *d);
/* ttl is clamped to [CL_DEMAND_TTL_MIN, CL_DEMAND_TTL_MAX]. CL_E_FULL when
 * max_edges live edges are known already; CL_E_ARG for an empty name. */
int cl_demand_update(struct cl_demand *d, const char *edge, const uint8_t bits[CL_KEY_BYTES], double ttl, double now);
/* Drops expired entries, writes the union of the others; returns how many are live. */
int cl_demand_union(struct cl_demand *d, double now, uint8_t out[CL_KEY_BYTES]);
/* The same with the temporal bitmaps (cl_demand_bits): cl_demand_update's
 * bits count as keys = wish = bits, stream = none. */
int cl_demand_update_ex(struct cl_demand *d, const char *edge, const struct cl_demand_bits *b, double ttl, double now);
int cl_demand_union_ex(struct cl_demand *d, double now, struct cl_demand_bits *out);

/* ---- the NATS link ------------------------------------------------------- */
enum cl_role { CL_ROLE_SIM, CL_ROLE_EDGE };
enum cl_event {
    CL_EV_CONNECTED,     /* first connection made (also after a failed first try) */
    CL_EV_DISCONNECTED,  /* lost NATS; reconnecting with backoff */
    CL_EV_RECONNECTED,
    CL_EV_CLOSED,        /* gave up or closed: final */
    CL_EV_SIM_UP,        /* edge: sim heartbeats arrive (again) */
    CL_EV_SIM_DOWN,      /* edge: none for sim_timeout_s */
    CL_EV_SIM_NEW,       /* edge: heartbeats from another sim process than before (a restart shorter
                            than sim_timeout_s, or a standby that took over): ask hello again */
};
const char *cl_event_name(enum cl_event ev);

/* A request that reached the sim. Answer it exactly once, from any thread,
 * with cl_request_reply (which frees it), now or later (a `set` is answered
 * when the tick applies it). */
struct cl_request {
    enum cl_kind kind;       /* CL_KIND_CTL, CL_KIND_HELLO, CL_KIND_QUERY or CL_KIND_PROBE */
    char origin[CL_NAME_MAX];/* the edge */
    char by[CL_NAME_MAX];    /* the client on that edge */
    char *body;              /* NUL-terminated copy (JSON text for CTL) */
    size_t len;
    char reply_to[CL_SUBJECT_MAX];
};

struct cl_handlers {
    void (*on_state)(void *user, enum cl_event ev);
    /* sim role */
    void (*on_request)(void *user, struct cl_request *req);
    /* edge role: the layer is the handler's (cl_layer_free it) */
    void (*on_layer)(void *user, struct cl_layer *layer);
    void (*on_params)(void *user, const char *origin, const char *by, const char *text, size_t len);
    /* edge role: a `probe_data` message for client `by` (PROBE_DATA) */
    void (*on_probe_data)(void *user, const char *by, const char *text, size_t len);
    /* edge role: a `bodies` JSON (BODIES), or a tick's BODY section (BODY_SECTION, is_section) */
    void (*on_bodies)(void *user, bool is_section, const char *data, size_t len);
};

/* Probes through an edge: the edge repeats each live probe request this
 * often; the sim forgets a remote probe not heard of for CL_PROBE_EXPIRE_S
 * (the edge or its client is gone). */
#define CL_PROBE_KEEPALIVE_S 2.0
#define CL_PROBE_EXPIRE_S 7.0
/* The subject the sim streams an edge's probe_data to, from the reply
 * subject of that edge's PROBE request ("<inbox>.<id>" -> "<inbox>.p").
 * CL_E_ARG if reply_to has no '.', CL_E_TOO_LARGE if out is too small. */
int cl_probe_stream_subject(const char *reply_to, char *out, size_t cap);

/* Called for each request the edge sent: status 0 with the sim's reply text,
 * or CL_E_TIMEOUT / CL_E_NO_RESPONDERS / CL_E_NOT_CONNECTED (text NULL).
 * Exactly once, inside cl_link_dispatch, unless the link is closed first. */
typedef void (*cl_reply_fn)(void *ctx, int status, const char *text, size_t len);

struct cl_config {
    enum cl_role role;
    const char *url;            /* "nats://127.0.0.1:4222", comma-separated list allowed */
    const char *prefix;         /* NULL = CL_DEFAULT_PREFIX */
    const char *name;           /* this daemon in origin fields; NULL = "<role>-<host>-<pid>" */
    const char *creds_file;     /* --nats-creds (JWT + NKey seed file), or NULL */
    const char *tls_ca;         /* --nats-tls-ca: trust these CAs (implies TLS) */
    const char *tls_cert, *tls_key; /* --nats-tls-cert/-key: client certificate (both or neither) */
    double heartbeat_s;         /* edge demand / sim status period; 0 = 1.0 (edge) / 0.5 (sim) */
    double demand_ttl_s;        /* edge: expiry it announces; 0 = 3 */
    double sim_timeout_s;       /* edge: sim down after this long without status; 0 = 2 */
    double request_timeout_s;   /* edge: 0 = 2 */
    double query_timeout_s;     /* edge: for QUERY requests (the sim's workers may queue them); 0 = 5 */
    double reconnect_min_s, reconnect_max_s; /* backoff; 0 = 0.1, 2 */
    size_t outbox_max_bytes;    /* 0 = 64 MiB */
    bool standby;               /* sim: start silent (no STATUS) until cl_sim_set_standby(l, false) */
    void (*wake)(void *user);   /* called from NATS/pump threads when there is something to dispatch */
    void *wake_user;
    struct cl_handlers h;
    void *user;                 /* passed to the handlers */
};

struct cl_stats {
    uint64_t layers_published, parts_published, bytes_published;
    uint64_t layers_dropped_outbox;   /* outbox over outbox_max_bytes: oldest layer dropped */
    uint64_t layers_dropped_offline;  /* not connected when the pump got to it */
    uint64_t layers_too_large;        /* a tile larger than the server's max_payload */
    uint64_t parts_received, layers_received, layers_dropped_incomplete, layers_dropped_inbox;
    uint64_t bad_messages;            /* failed to parse: ignored */
    uint64_t requests_sent, replies_received, request_timeouts, no_responders;
    uint64_t requests_received, requests_dropped;
    uint64_t events_dropped;          /* inbox full */
    uint64_t disconnects, reconnects;
    int demand_edges;                 /* sim: live edges at the last cl_sim_demand */
};

#define CL_INBOX_MAX 4096

struct cl_link;
/* Connects in the background: returns a link even when NATS is not up yet
 * (state events tell when it is). NULL and err only for bad options. */
struct cl_link *cl_link_open(const struct cl_config *cfg, char *err, size_t errlen);
/* Stops the pump, closes the connection, waits for the NATS callbacks to
 * finish, releases queued layers and drops pending requests silently. */
void cl_link_close(struct cl_link *l);
/* Runs the queued handlers on the calling thread; returns how many. */
int cl_link_dispatch(struct cl_link *l);
bool cl_link_connected(struct cl_link *l);
bool cl_link_sim_up(struct cl_link *l);   /* edge */
const char *cl_link_name(const struct cl_link *l);
/* Sim: this process's random id (16 hex digits), sent as `by` of every
 * STATUS heartbeat: edges tell a new sim process from the old one by it. */
const char *cl_link_instance(const struct cl_link *l);
/* The same id as a number (never 0): the epoch of the layers a sim publishes. */
uint64_t cl_link_epoch(const struct cl_link *l);
void cl_link_stats(struct cl_link *l, struct cl_stats *out);
/* After every link is closed, at exit: lets the NATS library free its globals. */
void cl_library_shutdown(void);

/* Sim role. The layer's bytes stay the caller's until release(ctx) is
 * called (on the pump thread, or at once on error): the tick thread neither
 * copies nor waits. Returns 0 or a negative CL_E_*. */
int cl_sim_publish_layer(struct cl_link *l, const struct cl_layer_info *info, const uint8_t *data, size_t len,
                         const uint32_t *tile_off, void (*release)(void *ctx), void *ctx);
/* The same for a layer of one or two sections (info->layer_flags,
 * cl_layer_sections): data[i], len[i], tile_off[i] (tiles_per_side^2 + 1
 * offsets) of section i. info->epoch 0 = this link's (cl_link_epoch). */
int cl_sim_publish_layer_sections(struct cl_link *l, const struct cl_layer_info *info, const uint8_t *const data[2],
                                  const size_t len[2], const uint32_t *const tile_off[2], void (*release)(void *ctx),
                                  void *ctx);
int cl_sim_publish_params(struct cl_link *l, const char *origin, const char *by, const char *text, size_t len);
/* The floating bodies for the edges (CL_KIND_BODIES: a `bodies` JSON;
 * CL_KIND_BODY_SECTION: u64 seq + BODY section), queued in order with the
 * layers: a tick's section goes out before its layers. */
int cl_sim_publish_bodies(struct cl_link *l, enum cl_kind kind, const void *data, size_t len);
void cl_sim_set_status(struct cl_link *l, const char *text, size_t len);  /* body of the next heartbeats */
/* A standby sim sends no STATUS (edges must not take it for the active one)
 * and is not subscribed to the request subjects (ctl, hello, query, probe):
 * with no sim acting, requests get "no responders" at once. */
void cl_sim_set_standby(struct cl_link *l, bool standby);
int cl_sim_demand(struct cl_link *l, uint8_t out[CL_KEY_BYTES]);          /* tick thread; returns live edges */
int cl_sim_demand_ex(struct cl_link *l, struct cl_demand_bits *out);      /* the same with stream and wish */
/* text NULL: drop without answering. */
void cl_request_reply(struct cl_link *l, struct cl_request *req, const char *text, size_t len);
/* One probe_data text for client `by` of the edge whose stream subject is
 * `stream` (cl_probe_stream_subject). Dropped (counted in events_dropped)
 * while the outbox holds more than outbox_max_bytes: probes are per tick,
 * the next one replaces it. */
int cl_sim_publish_probe_data(struct cl_link *l, const char *stream, const char *by, const char *text, size_t len);

/* ---- the sim's record in JetStream (durability, hot standby) ---------------
 * One key, "sim", in the KV bucket OCEAND_<prefix> ('.' -> '_'; file
 * storage, history 1): the active sim's lease and the sea's state, as text
 * the daemon composes. Every write is a compare-and-set on the revision the
 * writer last saw (etcd-style: a revision is never reused), so a sim that
 * lost the lease (a standby took over while it was stalled or cut off)
 * learns it at its next write (CL_E_LOST) and never overwrites the newer
 * record. Each call blocks for a JetStream request (at most timeout_ms): the
 * sim makes them on its builder and lease threads, never on tick or lws.
 * Thread-safe (one mutex per bucket handle). */
struct cl_kv;
/* Binds the bucket, making it if missing. CL_E_NOT_CONNECTED,
 * CL_E_NO_JETSTREAM, or CL_E_NATS (err says why). */
int cl_kv_open(struct cl_link *l, int timeout_ms, struct cl_kv **out, char *err, size_t errlen);
void cl_kv_close(struct cl_kv *kv);
/* The record now: 1 with a malloc'd NUL-terminated copy and its revision,
 * 0 when there is none, or a negative CL_E_*. */
int cl_kv_read(struct cl_kv *kv, char **text, size_t *len, uint64_t *rev);
/* Become the holder: create the record (seen = 0) or replace the revision
 * seen (a holder that stopped renewing). CL_OK, or CL_E_LOST (someone else
 * wrote it first). Later writes are checked against this one. */
int cl_kv_claim(struct cl_kv *kv, uint64_t seen, const char *text, size_t len);
/* Replace our own last write (renewal, a new state). CL_E_LOST when
 * another sim wrote the record since (or we never claimed it). */
int cl_kv_write(struct cl_kv *kv, const char *text, size_t len);

/* Edge role. */
int cl_edge_set_demand(struct cl_link *l, const uint8_t bits[CL_KEY_BYTES]); /* subscribes + heartbeats now */
/* The same with stream and wish (cl_demand_bits): subscribes to b->keys; a
 * change of any bitmap is announced at the pump's next round (coalesced). */
int cl_edge_set_demand_ex(struct cl_link *l, const struct cl_demand_bits *b);
/* Ask the sim. CL_OK: done(ctx, ...) runs exactly once, in cl_link_dispatch
 * (a reply, no responders, not connected, or the deadline). Anything else:
 * done never runs and the caller keeps ctx. */
int cl_edge_request(struct cl_link *l, enum cl_kind kind, const char *by, const char *body, size_t len,
                    cl_reply_fn done, void *ctx);

#endif

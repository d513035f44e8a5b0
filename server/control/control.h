/* control.h — the JSON control protocol (proto/PROTOCOL.md §7).
 *
 * Pure: parses and validates client messages against the parameter table
 * and builds the server's JSON replies. No networking, no threads, no
 * globals, so it can be unit-tested and fuzzed on its own. */
#ifndef OCEAND_CONTROL_H
#define OCEAND_CONTROL_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "ocean.h"
#include "params.h"

#define CTL_MAX_TILES 1024            /* 32 x 32: tile coordinates are 0..31 (no duplicates kept) */
#define CTL_BOUND_COUNT 5
extern const float ctl_bounds[CTL_BOUND_COUNT]; /* 0 = lossless, then lossy bounds (m) */
#define CTL_MAX_LOD 4                 /* = OC_MAX_LOD (checked in control.c) */
#define CTL_MAX_ID_BYTES 256          /* a request "id" longer than this, as JSON, is bad_message */

/* One error reply: code from the spec, human message, parameter at fault. */
struct ctl_error {
    const char *code;       /* "bad_json", "out_of_range", ... (static string) */
    char message[200];
    char param[48];         /* "" when no single parameter is at fault */
};

/* What a client wants to receive. */
#define CTL_MAX_CASCADES 4            /* = OCEAN_MAX_CASCADES (checked in control.c) */
struct cascade_sub {
    unsigned fields;        /* OCEAN_FIELD_BIT mask, never 0 */
    int lod;                /* 0..CTL_MAX_LOD */
    int bound_index;        /* index into ctl_bounds */
};
struct subscription {
    unsigned fields;        /* cascade 0: OCEAN_FIELD_BIT mask, never 0 */
    int lod;                /* 0..CTL_MAX_LOD */
    signed char field_lod[OCEAN_FIELD_COUNT]; /* cascade 0, per field: its own LOD, or -1: `lod` (subscribe "field_lod") */
    int bound_index;        /* index into ctl_bounds */
    int ncascades;          /* cascades asked for: 1 (cascade 0 only, the default) .. CTL_MAX_CASCADES */
    struct cascade_sub cascade[CTL_MAX_CASCADES]; /* [1 .. ncascades-1]: the finer cascades ([0] unused) */
    double max_rate;        /* frames per second, 0 < r <= tick rate */
    bool temporal;          /* accepts codec 3 (predicted tiles, PROTOCOL.md §5.9); default false */
    bool pinned;            /* "adapt": false: served as asked whatever the link (no quality ladder) */
    bool parts;             /* "parts": true: a tick's frame may come as several messages (PROTOCOL.md §3.4) */
    bool all_tiles;
    int ntiles;             /* when !all_tiles */
    uint16_t tiles[CTL_MAX_TILES][2];
};

/* Limits the validator enforces beyond the parameter table. */
struct ctl_limits {
    double tick_rate;       /* max_rate ceiling and default */
    int max_memory_mb;      /* simulation memory cap, decides the largest N */
    bool have_sea;          /* a measured sea is attached: spectrum "measured" may be set */
};

enum ctl_type { CTL_SET, CTL_SUBSCRIBE, CTL_PAUSE, CTL_RESUME, CTL_PING,
                CTL_QUERY, CTL_PROBE /* members checked by query_msg.c */, CTL_NAME,
                CTL_RENDER /* members checked by render_msg.c */, CTL_RENDER_CANCEL,
                CTL_LAUNCH, CTL_STEER, CTL_REMOVE, CTL_CLAIM /* floating bodies: members checked by body_msg.c */,
                CTL_SEA /* a measured sea: the document checked by sea_msg.c */ };

/* Display names (PROTOCOL.md §7.1 `name`): at most CTL_NAME_MAX_CHARS code
 * points of printable Unicode, UTF-8; CTL_NAME_BYTES holds any valid one. */
#define CTL_NAME_MAX_CHARS 32
#define CTL_NAME_BYTES (4 * CTL_NAME_MAX_CHARS + 1)

struct ctl_msg {
    enum ctl_type type;
    cJSON *root;            /* owned: the parsed message */
    const cJSON *id;        /* inside root, or NULL; a number is a raw node of its text as sent
                             * (cJSON's double would change 2^53 + 1), so copies print it exactly */
    const cJSON *params;    /* CTL_SET: the "params" object */
    const char *token;      /* CTL_SET, CTL_SEA: optional "token", or NULL */
    const cJSON *sea;       /* CTL_SEA: the "sea" document, inside root */
    const cJSON *t;         /* CTL_PING: "t" to echo, inside root (a raw node of its text), or NULL */
    const char *name;       /* CTL_NAME, or a `set`'s optional "name": a checked display name
                             * ("" = none), inside root; NULL when not given */
    const char *once;       /* CTL_SET/PAUSE/RESUME: optional "once" (a checked key), inside root, or NULL */
};

/* "once" on set/pause/resume (PROTOCOL.md §7.1): the same request sent on two
 * connections is applied once. CTL_ONCE_MIN..CTL_ONCE_MAX printable ASCII characters. */
#define CTL_ONCE_MIN 8
#define CTL_ONCE_MAX 64

void subscription_default(struct subscription *s, double tick_rate);
/* No frames at all ("fields": []): a session for control messages only. */
void subscription_none(struct subscription *s);
bool subscription_has_frames(const struct subscription *s);
/* The fields, LOD and bound a subscription asks for cascade c: 0 fields
 * when it does not ask for that cascade. For cascade 0, *lod is the
 * subscription's LOD; a field may override it (subscription_lod). */
unsigned subscription_cascade(const struct subscription *s, int c, int *lod, int *bound_index);
/* The LOD field f of cascade 0 is sent at: its own ("field_lod") or the subscription's. */
static inline int subscription_lod(const struct subscription *s, int f)
{
    return s->field_lod[f] >= 0 ? s->field_lod[f] : s->lod;
}

/* Parse one text message. On success returns 0 and fills m (free with
 * ctl_msg_free). On failure returns -1, fills e, and *id_out (if not NULL)
 * receives a detached copy of the message's "id" for the error reply
 * (caller frees with cJSON_Delete). */
int control_parse(const char *text, size_t len, struct ctl_msg *m, cJSON **id_out, struct ctl_error *e);
void ctl_msg_free(struct ctl_msg *m);

/* The one strict reading of JSON text, for every parser of JSON from the
 * wire or a file (control messages, the config and state files, cluster
 * records): raw control bytes (NUL included), a "\u" without four hex
 * digits and "\u0000" are refused, since cJSON would skip or decode them and
 * its C strings would then cut the text at the NUL. Returns 0, or -1 with e
 * filled (code bad_json, the message names what and where). */
int control_json_prescan(const char *text, size_t len, struct ctl_error *e);
/* text[0..len) as one JSON object and nothing but whitespace after it,
 * under control_json_prescan: the object (cJSON_Delete), or NULL with e filled (bad_json). */
cJSON *control_parse_object(const char *text, size_t len, struct ctl_error *e);
/* The "id" of a message not otherwise parsed (a refusal), as control_parse
 * keeps it: a detached copy (cJSON_Delete) that prints as sent, or NULL
 * (none, or the message is not a strict JSON object). */
cJSON *control_message_id(const char *text, size_t len);
/* A message's type and code ("" when none), and whether its `points` is a non-empty
 * array: what an edge reads of the sim's answer before it relays it. */
void control_reply_type(const char *text, size_t len, char *type, size_t cap, char *code, size_t ccap, bool *points);

/* Apply a JSON object of parameters onto *cur, all or nothing: every member
 * is checked (name, JSON type, range, power of two), then the whole set
 * (params_validate_sea, memory cap). With lim, spectrum "measured" needs
 * lim->have_sea (else code no_sea); without (an edge's early check, a
 * loader), the sim or the loader decides whether a sea is attached. On success *out = new params and
 * *changed = bit i set for param_table[i] whose value differs. */
int control_apply_params(const cJSON *obj, const struct ocean_params *cur, const struct ctl_limits *lim,
                         struct ocean_params *out, uint64_t *changed, struct ctl_error *e);

/* One JSON value onto one setting of either table (a sea parameter, or a
 * daemon option of server/config/config.c), base being the struct the table's
 * offsets point into. Only the JSON type is checked here (numbers for int
 * and float, strings for enum and string, booleans for bool); the value is
 * checked by params.c's setters. Returns 0, or -1 with e filled and *base
 * unchanged. */
int control_set_json(void *base, const struct param_def *d, const cJSON *item, struct ctl_error *e);
/* The wire error code (PROTOCOL.md §7.2) of a params.c refusal. */
const char *control_error_code(enum param_error r);

/* Merge the members of a "subscribe" message onto *cur into *out. */
int control_apply_subscribe(const cJSON *msg, const struct subscription *cur, const struct ctl_limits *lim,
                            struct subscription *out, struct ctl_error *e);

/* Whether the daemon's simulation at resolution n with `cascades` grids fits max_memory_mb: two
 * simulations (ocean_memory_bytes, the running one and one being built)
 * plus the frames in flight. */
bool control_fits_memory(int n, int cascades, int max_memory_mb);
/* The memory that check counts, in MB. */
double control_memory_mb(int n, int cascades);

/* JSON builders; all return a cJSON tree the caller prints and deletes. */
cJSON *control_params_object(const struct ocean_params *p);
cJSON *control_schema(void);
cJSON *control_subscription_object(const struct subscription *s);
cJSON *control_error_msg(const struct ctl_error *e, const cJSON *id);
cJSON *control_params_msg(const struct ocean_params *p, uint32_t version, uint64_t changed,
                          const char *by, const cJSON *id);
cJSON *control_subscribed_msg(const struct subscription *s, const cJSON *id);
/* t: the ping's "t" (ctl_msg.t), echoed as sent; NULL = none */
cJSON *control_pong_msg(const cJSON *id, const cJSON *t, uint64_t server_time_us);
/* What this daemon can do (server/tick/capacity.h): announced in hello and
 * params as "capacity" (PROTOCOL.md). */
#define CAPACITY_MAX_SIZES 8
struct capacity_info {
    int max_resolution;         /* largest N the memory cap allows */
    int memory_cap_mb;
    int cores;
    double tick_ms, budget_ms;  /* tick period, and the share of it a frame may take */
    long encode_budget;         /* samples per tick that may be encoded at the current N */
    int nsizes;
    struct capacity_size {
        int n;
        bool fits_memory;
        double est_ms[6];       /* estimated frame time with 1..6 fields at LOD 0, temporal codec */
        double est_intra_ms[6]; /* the same with the intra codec (the plan's codec rung) */
        int full_rate_fields;   /* most fields (LOD 0) that fit the budget at the tick rate, either codec */
        int temporal_fields;    /* most fields (LOD 0) that fit it with the temporal codec */
    } sizes[CAPACITY_MAX_SIZES];
};
cJSON *control_capacity_object(const struct capacity_info *c);
/* `degraded`: how a client's subscription is served now (active = coarser
 * LOD, fewer frames, or the intra codec (1) where the temporal one (3) was
 * asked; false = as asked again). */
cJSON *control_degraded_msg(bool active, int subscribed_lod, int lod, int codec, double rate, const char *reason);

struct hello_info {
    const char *client_id;
    bool controller;
    const struct ocean_params *params;
    uint32_t params_version;
    double tick_rate;
    int tile_size;
    const struct subscription *sub;
    const struct capacity_info *capacity; /* NULL = not announced */
    int ease_ticks;                       /* amplitude-only changes ease in over this many ticks */
    const char *sea;                      /* the measured sea's summary (JSON text, sea_summary_json), or NULL:
                                           * "sea": null */
};
cJSON *control_hello_msg(const struct hello_info *h);

/* Token check for `set`/`pause`/`resume`, in constant time (no early exit
 * at the first wrong byte). */
bool control_token_equal(const char *given, const char *secret);

/* Whether s may be a display name: valid UTF-8, at most CTL_NAME_MAX_CHARS
 * code points, none of them a control or invisible formatting character
 * (C0, C1, bidi overrides, zero-width, private use, noncharacters) or
 * markup (< > & " '), no space at either end; "" (no name) is allowed.
 * Returns 0, or -1 with e filled (code "bad_name"). */
int control_check_name(const char *s, struct ctl_error *e);
/* Whether s[0..len) is strict UTF-8 with no NUL: what a WebSocket text
 * frame may carry (RFC 6455 §8.1). */
bool control_valid_utf8(const char *s, size_t len);
/* {"type":"named","id":...,"name":"..."}: the display name now in force. */
cJSON *control_named_msg(const char *name, const cJSON *id);

/* Print and delete: returns malloc'd text (free()), NULL on no memory. */
char *control_print(cJSON *msg);

/* The counters and the clock that cross a file or the wire have ONE rule
 * each, for what is loaded (state file, the cluster's record, the sim's
 * hello) and for what the daemon reaches while running, so whatever it
 * saves it can restore (PROTOCOL.md §7.7):
 * - params_version: a u32 in every frame header; a set that would take it
 *   past CTL_VERSION_MAX is refused (`version_limit`), never wrapped;
 * - sim_time: [0, OCEAN_TIME_MAX]; the clock stops there (ocean.h);
 * - integers kept in JSON (seq and wall_us in the record): at most 2^53,
 *   the largest a JSON number (a double) holds exactly. */
#define CTL_VERSION_MAX UINT32_MAX
#define CTL_JSON_EXACT_MAX 9007199254740992.0
/* A whole number in [0, max] into *out; false (out untouched) for anything
 * else: not a number, negative, fractional, NaN, beyond max. */
bool control_json_whole(const cJSON *item, double max, uint64_t *out);
/* A params_version as saved or sent: control_json_whole up to CTL_VERSION_MAX. */
bool control_json_version(const cJSON *item, uint32_t *out);
/* A sim time the clock can be at: a number in [0, OCEAN_TIME_MAX]. */
bool control_json_sim_time(const cJSON *item, double *out);

#endif

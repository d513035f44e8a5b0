/* body_msg.h — the JSON of floating bodies (proto/PROTOCOL.md §7.6): parse
 * and validate `launch`, `steer`, `remove` and `claim`; build `launched`,
 * `steered`, `removed`, `claimed`, `bodies`, and hello's `body_kinds` and
 * `body_limits`. Pure like control.c (no threads, no globals): unit-tested and
 * fuzzed on its own. The kinds come from the library's one table (bodies.h),
 * which drives validation, hello and the web panel alike. */
#ifndef OCEAND_BODY_MSG_H
#define OCEAND_BODY_MSG_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stdint.h>

#include "bodies.h"
#include "control.h"

#define BODY_RESUME_CHARS 32   /* a resume key: 32 lowercase hex digits (128 random bits) */

/* A checked body request. */
struct body_req {
    enum ctl_type type;              /* CTL_LAUNCH, CTL_STEER, CTL_REMOVE or CTL_CLAIM */
    const struct body_kind *kind;    /* launch: a row of body_kinds() */
    double x, z;                     /* launch: m, world, within +-BODY_WORLD_HALF_M */
    double heading;                  /* launch: degrees clockwise from north, 0 <= h < 360 (default 0) */
    uint32_t body;                   /* steer, remove, claim: the body's id, >= 1 */
    bool has_throttle, has_rudder;   /* steer: which members were given */
    double throttle, rudder;         /* steer: -1..1 */
    char resume[BODY_RESUME_CHARS + 1]; /* claim */
    const char *token;               /* optional "token", inside the message, or NULL */
};

/* Check the members of a message control_parse typed CTL_LAUNCH, CTL_STEER,
 * CTL_REMOVE or CTL_CLAIM. Codes: bad_message (a required member missing, a
 * malformed resume key or token), bad_type (a member of the wrong JSON type,
 * not finite, a body id that is not a whole number), unknown_kind,
 * out_of_range (a point outside the world's bounds, steering outside -1..1,
 * a body id outside 1..2^32-1). Returns 0, or -1 with e filled (e->param
 * names the member at fault). */
int body_parse(const cJSON *root, enum ctl_type type, struct body_req *r, struct ctl_error *e);

/* The index of a kind in body_kinds() (the `kind` byte of a body record), or -1. */
int body_kind_index(const struct body_kind *k);

/* Replies to the sender. */
cJSON *body_launched_msg(const cJSON *id, uint32_t body, const char *resume);
/* type: "steered", "removed" or "claimed". */
cJSON *body_ack_msg(const char *type, const cJSON *id, uint32_t body);

/* `bodies` (to everyone; also hello's "bodies" member): the full list, and
 * what left since the previous message. */
struct body_entry {
    uint32_t body;
    const struct body_kind *kind;
    const char *owner;               /* the owner's client id ("" = none) */
    const char *name;                /* its display name ("" = none) */
    bool adrift;                     /* no session owns it now */
};
struct body_gone_entry {
    uint32_t body;
    const char *reason;              /* "removed", "sunk" or "abandoned" */
};
cJSON *body_list_array(int n, const struct body_entry *b);
cJSON *bodies_msg(uint64_t seq, int n, const struct body_entry *b, int ngone, const struct body_gone_entry *g);

/* hello's `body_kinds` (every row of the table) and `body_limits`. */
cJSON *body_kinds_array(void);
struct body_limits {
    int per_session, max_bodies;
    double launch_rate;              /* launches per minute per session */
    double grace_s;                  /* --body-grace */
};
cJSON *body_limits_object(const struct body_limits *l);

#endif

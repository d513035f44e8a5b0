/* role_lease.h — the hot standby of `--role sim` (docs/scaling.md, "Standby
 * and durability"). The active sim holds a lease on its record in JetStream
 * (cluster.h: cl_kv_*), renewed every LEASE_RENEW_S and carrying the sea's
 * state (parameters, version, sim time and seq at a wall-clock time). A
 * second sim on the same prefix waits as a standby: it follows the record
 * (its own simulation adopts each new state, so a take-over builds
 * nothing) and takes the lease when the record has not changed for
 * LEASE_EXPIRE_S by its own clock, or at once when the holder released it
 * (SIGTERM). Every write is a compare-and-set, so a holder that was stalled
 * or cut off past its lease learns at its next write that it lost it, steps
 * down and answers nothing more: two sims never both act. Without JetStream
 * on the NATS server the sim runs alone ("solo"), with its state file only.
 * Threads: one lease thread (blocking JetStream calls); role_lease_persist
 * runs on the sim's builder thread; the rest on any thread. */
#ifndef OCEAND_ROLE_LEASE_H
#define OCEAND_ROLE_LEASE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "cluster.h"
#include "sim_thread.h"
#include "state.h"

#define LEASE_RENEW_S 0.25  /* the holder rewrites the record this often */
#define LEASE_EXPIRE_S 1.0  /* a record unchanged this long (by the standby's clock): its holder is gone */
#define LEASE_SAFE_S 0.75   /* the holder acts only this long after its last successful write (by its own
                               clock): a holder that was stalled goes silent before a standby may take over */

enum lease_state { LEASE_STARTING, LEASE_SOLO, LEASE_STANDBY, LEASE_ACTIVE };

struct role_lease;
struct role_lease *role_lease_new(struct cl_link *link, double tick_rate);
/* Starts the lease thread with the state the sim started from. */
/* sea: the measured sea with p (copied), or NULL. */
int role_lease_start(struct role_lease *ls, struct sim *sim, const struct ocean_params *p, uint32_t version,
                     const struct sea_spectrum *sea);
/* Stops the thread (before sim_stop) and releases the lease if held. */
void role_lease_stop(struct role_lease *ls);
void role_lease_free(struct role_lease *ls);
/* Whether this sim acts (publishes, answers): active, or solo. */
bool role_lease_acting(struct role_lease *ls);
enum lease_state role_lease_state(struct role_lease *ls);
const char *role_lease_state_name(enum lease_state s);
/* sim_config.persist's JetStream half (builder thread): the record with this
 * state, before the change is applied. 0, or -1 with err: not connected,
 * or the lease was lost (this sim steps down). Solo and standby: 0. */
int role_lease_persist(struct role_lease *ls, const struct ocean_params *p, uint32_t version, double sim_time,
                       const struct sea_spectrum *sea, char *err, size_t errlen);

/* The record's measured sea (role_lease_sea.c): the "sea" member, the
 * document as the `sea` message carries it. */
struct cJSON;
int lease_record_add_sea(struct cJSON *rec, const struct sea_spectrum *sea);   /* NULL: no member; -1 no memory */
int lease_record_sea(const struct cJSON *rec, struct sea_spectrum **out);      /* 0 (*out malloc'd or NULL), -1 bad */
bool lease_sea_differs(const struct sea_spectrum *a, const struct sea_spectrum *b);
int lease_keep_sea(struct sea_spectrum **kept, const struct sea_spectrum *sea); /* *kept = a copy of sea (NULL: none) */

/* ---- the floating bodies in the record (role_lease_bodies.c) ----
 * The lws thread hands the newest bodies over (copied); every record write
 * carries them while the record stays within LEASE_BODIES_MAX_BYTES of
 * them: about 100 bodies (--max-bodies 64 by default). The bucket's values
 * (CL_KV_VALUE_MAX, 512 KB) hold them beside the largest measured sea. A standby takes the bodies of each record it follows (the
 * holder's, at least as new as its own state: an older record brings no
 * bodies back); a take-over restores the newest it took:
 * role_lease_take_bodies hands them out once (1; *out is the caller's to
 * free), after the wake function set by role_lease_on_bodies was called. */
#define LEASE_BODIES_MAX_BYTES (48u << 10)
void role_lease_set_bodies(struct role_lease *ls, const struct state_bodies *sb);
void role_lease_on_bodies(struct role_lease *ls, void (*wake)(void *), void *user);
int role_lease_take_bodies(struct role_lease *ls, struct state_bodies *out);
/* role_lease.c's side */
struct lease_bodies;
struct lease_bodies *role_lease_bodies(struct role_lease *ls);
struct lease_bodies *lease_bodies_new(void);
void lease_bodies_free(struct lease_bodies *lb);
void lease_bodies_add(struct lease_bodies *lb, struct cJSON *record);
int lease_bodies_from_record(struct lease_bodies *lb, const char *text, size_t len);
void lease_bodies_commit(struct lease_bodies *lb);
bool lease_bodies_have(struct lease_bodies *lb);      /* bodies taken from a record are waiting */

#endif

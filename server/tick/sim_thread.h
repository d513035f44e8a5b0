/* sim_thread.h — the fixed-rate tick thread, the builder thread, and what
 * crosses between them and the network (lws) thread. docs/threads.md has
 * the whole threading contract.
 *
 * A tick (the tick thread, a clock on absolute deadlines): apply the
 * parameters the builder prepared -> plan which subscription groups are due
 * and at which LOD (capacity.h) -> hand the frame to the producer thread,
 * which steps the ocean for those fields, copies them out and starts their
 * encode on the encode pool (frame_job.c, encode_pool.h) -> the pool's last
 * thread publishes the frame and wakes the network thread. The encode of
 * tick t runs while the producer steps tick t+1.
 * Parameter sets are built off the tick path by the builder (a new ocean
 * for the batch: spectrum, and FFT plans for a new N) and swapped in at the
 * next tick boundary. The mutex is held only to swap pointers and move list
 * heads: the network thread never waits for a step or an encode, and the
 * sim never waits for a socket. */
#ifndef OCEAND_SIM_THREAD_H
#define OCEAND_SIM_THREAD_H

#include <stdbool.h>
#include <stdint.h>

#include "bodies.h"
#include "body_snap.h"
#include "capacity.h"
#include "frame.h"
#include "ocean.h"
#include "query_worker.h"
#include "sea_spectrum.h"

/* What became of a set. The network thread maps it to a wire error code. */
enum sim_set_status {
    SIM_SET_QUEUED,         /* not answered yet */
    SIM_SET_APPLIED,
    SIM_SET_INVALID,        /* refused at apply time: whole-set check or the build refused it */
    SIM_SET_NO_MEMORY,      /* the build ran out of memory; nothing changed */
    SIM_SET_NOT_SAVED,      /* it could not be made durable (sim_config.persist failed); nothing changed */
    SIM_SET_VERSION_LIMIT,  /* params_version is at CTL_VERSION_MAX: no number left for it; nothing changed */
};

/* A parameter change accepted by the network thread. The same object comes
 * back from sim_take_answers with its outcome, so answering needs no
 * allocation: every submitted set is answered exactly once. */
struct sim_set {
    struct sim_set *next;
    /* Written by the network thread before sim_submit, read by the builder. */
    uint64_t tag;               /* opaque: the network side maps it back to the request */
    struct ocean_params values; /* the network thread's view after this set */
    uint64_t mask;              /* param_table bits this set changes */
    struct sea_spectrum *sea;   /* a `sea`: the new measured sea (malloc'd, checked, owned; sim_set_free
                                 * frees it), in force from this set on; NULL = the sea stays */
    /* Written by the builder and tick threads, read by the network thread
     * after sim_take_answers hands the set back. */
    enum sim_set_status status;
    char message[200];          /* why, when not applied */
    struct ocean_params params; /* in force after this set (applied or not) */
    uint32_t version;           /* params_version in force after it */
    uint64_t changed;           /* param_table bits that differ from before it */
    double build_s;             /* seconds the builder took to prepare its batch (0 = nothing built) */
    char *sea_summary;          /* the last applied set of a batch that changed the sea or what the grid
                                 * holds of it: the summary (sea_summary_json, printed; malloc'd), else NULL */
    /* Builder and tick threads only. */
    struct ocean_params prev;   /* the params this set was checked on top of */
    /* sim_adopt (tag 0): the state another sim left. values are whole
     * parameters; the version and clock replace this sim's own. */
    bool adopt;
    uint32_t adopt_version;
    double adopt_time;          /* sim time at adopt_wall_us (Unix µs) */
    uint64_t adopt_wall_us;
    uint64_t adopt_seq;         /* seq at adopt_wall_us: seq goes on from at least there */
};
void sim_set_free(struct sim_set *set);


struct sim;

/* ---- floating bodies (bodies.h, PROTOCOL.md §7.6; docs/threads.md) ----
 * The producer owns the world: it steps it right after ocean_step, on that
 * tick's grids. Requests cross like sets: the lws thread appends them under
 * the lock (sim_body_submit), the producer applies them at the start of its
 * next tick's bodies step, and hands each back with its outcome
 * (sim_body_take_answers); bodies that sank come back the same way, as
 * SIM_BODY_GONE answers nobody asked for. The same object makes the whole
 * round trip. */
enum sim_body_op {
    SIM_BODY_LAUNCH,            /* kind, x, z, heading -> body */
    SIM_BODY_STEER,             /* body, control (has_throttle / has_rudder: the others keep theirs) */
    SIM_BODY_REMOVE,            /* body */
    SIM_BODY_ADRIFT,            /* body: the record's adrift flag = adrift; stop: controls to 0 as well */
    SIM_BODY_GONE,              /* answer only: body sank (body_world_step removed it) */
    SIM_BODY_RESTORE,           /* states replace every body (a standby took over): adrift_flags, next_id */
};
struct sim_body_cmd {
    struct sim_body_cmd *next;
    enum sim_body_op op;
    /* Written by lws before sim_body_submit, read by the producer. */
    const struct body_kind *kind;
    double x, z, heading;
    uint32_t body;              /* the body (a launch: its new id, from the producer) */
    struct body_control control;
    bool has_throttle, has_rudder;
    bool adrift, stop;
    /* Written by the producer, read by lws after sim_body_take_answers. */
    enum body_error status;
    uint64_t seq;               /* the tick it was applied at */
    /* lws only (the sim never reads them): who asked and how to answer. */
    uint64_t serial;            /* the sender's session, 0 = the daemon itself (grace, abandonment) */
    void *reply_id;             /* a cJSON copy of the request's id, or NULL */
    bool reply;                 /* answer success too (launch, remove, a steer that had an id) */
    struct body_state *states;  /* SIM_BODY_RESTORE: nstates, then adrift_flags[nstates] in the same block (freed with it) */
    uint8_t *adrift_flags;
    int nstates;
    uint64_t next_id;           /* SIM_BODY_RESTORE: no id below it is issued again */
    uint64_t ticket;            /* lws only: a client of an edge waits for the answer under it (body_net.c), 0 = none */
    char resume[33];            /* launch: the resume key handed out with `launched` */
    const char *reason;         /* remove: "removed" or "abandoned" */
};
void sim_body_submit(struct sim *s, struct sim_body_cmd *c);  /* takes ownership */
struct sim_body_cmd *sim_body_take_answers(struct sim *s);    /* in order applied; caller frees each */
struct body_snap *sim_bodies_latest(struct sim *s);           /* the last tick's bodies (new reference), or NULL */
/* How many saved bodies sim_start put back (sim_config.restore): all of them, or 0 when one was refused. */
int sim_bodies_restored(struct sim *s);

struct sim_config {
    double tick_rate;
    int tile_size;              /* configured; frames use frame_tile_size(tile_size, N) */
    int keyframe_interval;      /* temporal layers: periodic keyframe every this many ticks (0 = none) */
    int ease_ticks;             /* amplitude-only changes ease in over this many ticks (0 = at once) */
    size_t stream_budget;       /* bytes the temporal layers' encoder state may take; beyond it, intra */
    struct ocean_options opts;
    double start_time;          /* sim time to resume from */
    int nice;                   /* of the tick thread; 0 = leave as is */
    uint32_t start_version;
    int encode_threads;         /* threads that encode (pool + the producer helping), >= 1 */
    long encode_budget;         /* --encode-budget: samples per tick at most, 0 = derived */
    long temporal_budget;       /* --temporal-budget: samples per tick at most with the temporal codec, 0 = derived */
    int max_memory_mb;          /* for the capacity announcement */
    int cores;                  /* same */
    uint64_t start_seq;         /* seq of the tick before the first (0; --role sim: from the wall clock,
                                   so that seq never goes back when the sim restarts under its edges) */
    void (*wake)(void *user);   /* called after every tick and every frame (lws_cancel_service) */
    void *wake_user;
    struct query_service *queries; /* point queries and probes (query_worker.h), NULL = none */
    /* --role sim (server/roles/role_sim.c); NULL otherwise. remote_demand runs on
     * the tick thread, on_frame on the encode thread that publishes the
     * frame (one at a time, in seq order); neither may block: remote_demand ORs the layer keys other
     * daemons want into bits (SIM_DEMAND_BYTES, bit k = layer key k) before
     * the demand snapshot, those of them some edge streams (temporal codec:
     * the key counts as one temporal subscriber and gets intra tiles only
     * while wished for) into stream, and those an edge needs keyframe
     * (intra) tiles of at the next ticks into wish (cl_demand_bits);
     * on_frame sees each frame right after it is published (frame_ref it
     * to keep it). */
    void (*remote_demand)(void *user, uint8_t bits[], uint8_t stream[], uint8_t wish[]);
    void (*on_frame)(void *user, struct frame *f);
    void *cluster_user;
    /* Durability: no acknowledged set is lost. Called on the builder thread
     * with what will be in force once a batch is applied (parameters, the
     * version after its last set, the clock), BEFORE the tick applies it:
     * so before any frame carries that version and before anyone is told.
     * It may block (write + fsync + rename, a JetStream put): the builder is
     * the one thread that may wait for a disk or NATS. Nonzero refuses the
     * batch's sets (SIM_SET_NOT_SAVED: nothing changes). Also called by
     * sim_save_now. sea: the measured sea in force with them, or NULL
     * (none attached). NULL = nothing is kept. */
    int (*persist)(void *user, const struct ocean_params *p, uint32_t version, double sim_time,
                   const struct sea_spectrum *sea, char *err, size_t errlen);
    void *persist_user;
    /* Floating bodies: the world's capacity (--max-bodies) and the bodies a
     * restart puts back (the state file; copied by sim_start: all or none). */
    int max_bodies;
    const struct body_state *restore;
    int nrestore;
    uint64_t restore_next_id;   /* ids below it are never issued again (2^32: none is; 0 = no rule) */
    /* The measured sea a restart (or a take-over) puts back with the parameters: checked, copied
     * by sim_start; NULL = none. */
    const struct sea_spectrum *sea;
};
#define SIM_DEMAND_BYTES 128        /* bitmap of layer keys (every cascade) handed to remote_demand */
_Static_assert(LAYER_KEYS_ALL <= SIM_DEMAND_BYTES * 8, "layer keys fit the remote demand bitmap");

struct sim;
/* Creates the ocean (may take a while at large N) and starts the tick
 * thread and the builder thread.
 * SIGINT/SIGTERM are blocked in both. Returns NULL with err on failure.
 * Test-only: with OCEAND_TEST_FAIL_BUILD_SEED=S in the environment, a build
 * whose parameters have seed S takes 0.5 s and then fails as if out of
 * memory (tests/daemon/test_daemon.py uses it; never set it in production). */
struct sim *sim_start(const struct ocean_params *p, const struct sim_config *cfg, char *err, size_t errlen);
void sim_stop(struct sim *s);

/* Network side (any one thread). */
void sim_submit(struct sim *s, struct sim_set *set);        /* takes ownership */
struct sim_set *sim_take_answers(struct sim *s);            /* sets with their outcome, in submission
                                                               order; caller frees each */
struct frame *sim_latest(struct sim *s);                     /* this tick's frame (new reference), or
                                                               NULL when the last tick built none */
uint64_t sim_seq(struct sim *s);                             /* seq of the last tick run */
void sim_demand(struct sim *s, int layer_key, int delta);   /* subscriptions in force */
/* Temporal layers (PROTOCOL.md §5.9): the subscriptions that take codec 3
 * (counted in sim_demand too), and the clients of a layer that lack the
 * references of its shared tiles and so need this tick's keyframe tiles. A
 * layer gets keyframe (intra) tiles in a tick when it has a subscriber that
 * is not temporal, a remote one (edges), or a key-wanting client. */
void sim_demand_temporal(struct sim *s, int layer_key, int delta);
void sim_want_keyframes(struct sim *s, int layer_key, int delta);
double sim_time_now(struct sim *s);
/* Ask the builder to persist the state in force with the current clock
 * (SIGHUP); returns at once. */
void sim_save_now(struct sim *s);
/* The summary (JSON text, malloc'd: the caller frees it) of the measured sea
 * sim_start put back (sim_config.sea), once; NULL when none. Later changes
 * come with their sets (sim_set.sea_summary). lws thread. */
char *sim_sea_summary(struct sim *s);
/* Take over the state another sim left (a hot standby, server/roles/):
 * these parameters (built off the tick like a set), this version, and the
 * clock extrapolated from (sim_time, seq) at wall_us; seq never goes back.
 * Not persisted (it comes from the durable record). Answered with tag 0
 * (sim_take_answers). Any thread; returns at once; -1 out of memory. */
/* sea: the measured sea of that state when it differs from the one in force (copied), or NULL. */
int sim_adopt(struct sim *s, const struct ocean_params *p, uint32_t version, double sim_time, uint64_t wall_us,
              uint64_t seq, const struct sea_spectrum *sea);
/* Whether the pipeline freed memory (temporal streams) since the last call:
 * the lws thread then returns the free pages to the system (malloc_trim). */
bool sim_take_trim(struct sim *s);
/* What this daemon can do at the N in force (capacity.h), for hello/params. */
void sim_capacity(struct sim *s, struct capacity_info *out);
/* The plan in force (which subscription groups are degraded, and how) and
 * its generation (+1 per change). */
uint32_t sim_plan(struct sim *s, struct plan *out);
/* Whether replacing subscription old (NULL = none) by want keeps the
 * distinct layers within the encode budget; need and budget in samples per
 * tick. Layers somebody already gets are free. Call on the thread that
 * changes demand (sim_demand), before changing it. */
bool sim_admit(struct sim *s, const struct subscription *old, const struct subscription *want, long *need, long *budget);

#endif

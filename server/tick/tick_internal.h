/* tick_internal.h — what the files of server/tick/ share: struct sim, whose
 * fields each say which thread writes and which reads them, and the steps
 * of the pipeline that live in different files.
 *
 *   sim_thread.c    start, stop, and the calls the network thread makes
 *   tick.c          the tick thread: the clock and tick()'s named steps
 *   plan_governor.c re-planning from the demand (hysteresis, recovery probes)
 *   frame_want.c    which layers a tick builds (a pure function)
 *   producer.c      the producer thread (step, hand the fields over) and
 *                   the encode pool's completion (publish)
 *   builder.c       the builder thread (parameter sets prepared off the tick
 *                   path) and their application at a tick boundary
 *   calibrate.c     the start-up measurement of the cost model
 * docs/threads.md has the whole contract. */
#ifndef OCEAND_TICK_INTERNAL_H
#define OCEAND_TICK_INTERNAL_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "capacity.h"
#include "encode_pool.h"
#include "frame_job.h"
#include "layer_stream.h"
#include "sim_thread.h"


/* A batch of sets the builder has prepared for one tick boundary. */
struct built {
    struct ocean_prepared *prepared; /* the new state for the ocean in force (ocean_prepare:
                                        new amplitudes, or a new grid and plans for a new N),
                                        or NULL when only playback changed */
    struct ocean_params params;   /* in force after the batch */
    struct sim_set *sets;         /* in order; each has ->prev, or a failed ->status */
    struct ocean_surface *surface; /* query snapshot of the prepared state (made by the builder), or NULL */
    const struct sea_spectrum *sea; /* the new measured sea prepared (its set owns it), or NULL */
};
/* The summary of a sea as JSON text (builder.c; malloc'd, NULL on no memory). */
char *sim_sea_summary_text(const struct sea_spectrum *sea, const struct sea_capture *cap, uint32_t version);

/* Each field says which thread writes it and which reads it ("tick",
 * "builder", "lws" = the network thread; docs/threads.md). */
struct sim {
    struct sim_config cfg;        /* sim_start writes; all read, never written after */
    pthread_t thread, builder;    /* sim_start writes; sim_stop reads */
    bool builder_started;         /* sim_start writes; sim_stop reads */
    atomic_bool stop;             /* sim_stop writes; tick and builder read */
    int test_fail_seed;           /* sim_start writes (OCEAND_TEST_FAIL_BUILD_SEED, -1 = none); builder reads */

    struct ocean *ocean;          /* sim_start writes the pointer, never changed after; the producer steps
                                   * it while prod_busy/prod_has_job, the tick commits into it only while
                                   * the producer is idle (handed over under the lock); the builder runs
                                   * ocean_prepare against it (allowed while it is stepped, ocean.h),
                                   * never while a commit runs (ready_full is cleared after the commit) */
    struct ocean_params params;   /* tick only: the parameters in force */
    uint32_t version;             /* tick only: params_version in force */
    double sim_time;              /* tick only: the clock (copied to now_time) */
    uint64_t seq;                 /* tick only: ticks run (PROTOCOL.md §3.3: +1 per tick, frame or not) */
    struct plan plan;             /* tick only: the plan in force (capacity.h) */
    int lower_ticks;              /* tick only: a less degraded plan seen for this many ticks in a row */
    int hold_ticks;               /* tick only: ...needed before it is taken (hysteresis; doubles when a
                                     recovery is undone soon after, update_plan) */
    int since_change;             /* tick only: ticks since the plan in force was taken */
    bool recovered;               /* tick only: the plan in force was a recovery (less degraded, same demand) */
    uint64_t grace_seq;           /* tick only: jobs queued before this seq (a new demand's or plan's
                                     first half second) neither raise the penalty nor teach the model */
    double credit[PLAN_GROUPS];   /* tick only: a group is encoded when its credit reaches 1 */
    bool had_demand;              /* tick only: last tick had subscribers */

    pthread_t producer;           /* sim_start writes; sim_stop joins */
    bool producer_started;        /* sim_start writes; sim_stop reads */
    struct encode_pool *pool;     /* sim_start creates; producer starts/waits jobs; sim_stop frees */
    struct frame_job *job;        /* producer fills it, the pool encodes it, the pool's last thread
                                     finishes it (encode_done); one job at a time (encode_pool) */
    uint64_t published;           /* encode_done only (jobs are serial): frames published, for struct frame.index */
    double job_t_tick, job_t_enc; /* producer writes before the job starts; encode_done reads */
    long job_samples;             /* same */
    long job_codec_samples[CAP_CODECS]; /* same: the plan's samples per codec (capacity.h) */
    bool job_cold;                /* same: queued within the grace (prod_job.cold) */
    /* Measuring at start-up (sim_start, before the threads). */
    bool measure_done;
    struct layer_streams streams; /* the temporal layers' encoder state: used by frame_job_begin (producer)
                                     and one encode thread per layer, one job at a time (encode_pool) */
    bool reset_streams;           /* tick only: a new sea (seed, patch, depth, loop, N): the next job resets the streams */
    bool release_due;             /* tick only: nobody is subscribed any more: the streams' memory should go */
    bool sea_changed;             /* tick only: same phases, new amplitudes: the next job keeps the chains (codec.md) */

    /* builder only: the params of the newest state built (applied, or
     * waiting in `ready`): the base the next batch is checked against. */
    struct ocean_params build_base;
    uint32_t build_version;       /* builder only: the version persisted for build_base (>= the tick's) */
    struct sea_spectrum *build_sea; /* builder only: the measured sea with build_base (malloc'd), or NULL */
    char *start_sea_summary;      /* sim_start writes; lws takes it once (sim_sea_summary) */

    /* floating bodies (body_tick.c) */
    struct body_sim *bodies;          /* producer only (sim_start creates it before the threads, sim_stop frees) */
    struct body_snap *job_bodies;     /* producer writes before the encode starts; encode_done puts it on the frame */
    int bodies_restored;              /* sim_start writes; lws reads (sim_bodies_restored) */

    pthread_mutex_t lock;             /* guards the fields below up to the atomics */
    pthread_cond_t cond;              /* tick and lws signal, builder waits */
    struct frame *latest;             /* tick writes (publish); lws reads (sim_latest) */
    bool builder_busy;                /* builder writes; sim_stop reads */
    struct sim_set *pending, **pending_tail;  /* lws appends (sim_submit); builder takes */
    struct built ready;               /* builder writes; tick takes at a tick boundary */
    bool ready_full;                  /* builder sets, tick clears */
    bool save_wanted;                 /* lws sets (sim_save_now), builder clears */
    struct ocean_prepared *to_free;   /* tick writes (the state a commit swapped out); builder frees it */
    struct sim_set *answers, **answers_tail;  /* tick appends; lws takes (sim_take_answers) */
    pthread_cond_t prod_cond;         /* tick signals, producer waits */
    bool prod_busy;                   /* producer: stepping a frame or waiting for the encode before
                                         it (set when it takes a job, cleared once the frame's
                                         encode has started: the next step may overlap it) */
    bool prod_has_job;                /* tick sets (a job queued, one deep), producer clears */
    struct prod_job {                 /* tick writes, producer reads */
        double sim_time, t_tick;
        uint64_t seq;
        uint32_t version;
        float patch_size;
        long codec_samples[CAP_CODECS]; /* the plan's samples per codec on this tick (cost model) */
        bool cold;                      /* queued before grace_seq: its costs are not learned */
        bool release_streams;           /* no frame: free every temporal stream (nobody is subscribed) */
        struct frame_want want;
    } pj;
    uint64_t penalized_seq;           /* tick: the queued job (seq) the penalty was last raised for... */
    int penalized_ticks;              /* ...and on how many ticks */
    struct sim_body_cmd *body_cmds, **body_cmds_tail;       /* lws appends (sim_body_submit); producer takes */
    struct sim_body_cmd *body_answers, **body_answers_tail; /* producer appends; lws takes (sim_body_take_answers) */
    struct body_snap *bodies_latest;  /* producer writes (each tick with bodies); lws reads (sim_bodies_latest) */
    struct cost_model model;          /* producer and encode_done update (EWMA); tick and lws read */
    struct plan plan_pub;             /* tick writes; lws reads (sim_plan) */
    uint32_t plan_gen;                /* +1 per change of plan_pub */

    atomic_int demand[LAYER_KEYS_ALL]; /* atomic: lws writes (subscriptions); tick reads */
    atomic_int tdemand[LAYER_KEYS_ALL]; /* atomic: lws writes (temporal subscriptions, also in demand); tick reads */
    atomic_int key_want[LAYER_KEYS_ALL]; /* atomic: lws writes (temporal clients lacking references); tick reads */
    _Atomic double now_time;          /* atomic: tick writes; lws reads (state file) */
    atomic_uint_least64_t now_seq;    /* atomic: tick writes; lws reads (a new client's first frame) */
    atomic_int now_n;                 /* atomic: tick writes; lws reads (capacity at the N in force) */
    atomic_bool trim_wanted;          /* atomic: producer sets after freeing streams; lws takes (sim_take_trim) */
    atomic_int body_count;            /* atomic: producer writes (bodies in the world); tick reads (step the sea for them) */
};

/* What the tick reads of the demand at one moment: local subscriptions
 * (lws writes the counters) and the keys other daemons want (--role sim). */
struct demand_snapshot {
    int demand[LAYER_KEYS_ALL];   /* subscriptions per key, remote keys counted as 1 */
    int tdemand[LAYER_KEYS_ALL];  /* temporal subscriptions per key (also in demand) */
    int key_want[LAYER_KEYS_ALL]; /* temporal clients lacking the references of the shared tiles */
    uint8_t remote[SIM_DEMAND_BYTES]; /* bit k: an edge wants key k intra every tick (one that streams
                                         it counts in tdemand, and in key_want while it wishes for keyframes) */
    bool any;                     /* some key has demand */
};

/* frame_want.c: the layers due this tick at their planned LOD, and per key
 * whether a stream, intra tiles or keyframes are wanted. A pure function of
 * its inputs. probe_fields are stepped on every cascade, never encoded. */
void frame_want_build(const struct plan *plan, const bool due[PLAN_GROUPS], const struct demand_snapshot *d,
                      unsigned probe_fields, struct frame_want *want);

/* plan_governor.c (tick thread): re-plan from the demand; publishes a change. */
void plan_update(struct sim *s, const int demand[LAYER_KEYS_ALL], const int tdemand[LAYER_KEYS_ALL], int n, int ts);

/* builder.c */
void *builder_main(void *arg);          /* the builder thread */
void apply_prepared(struct sim *s);     /* tick thread, producer idle: swap in what the builder prepared */

/* producer.c */
void *producer_main(void *arg);         /* the producer thread */
void publish(struct sim *s, struct frame *f); /* the newest frame replaces the previous one (any thread) */
void encode_item(void *ctx, int item, int worker); /* encode pool: one item of s->job */

/* body_tick.c: the floating bodies, stepped by the producer. */
struct body_sim *body_sim_new(const struct sim_config *cfg, int *restored, char *err, size_t errlen);
void body_sim_free(struct body_sim *b);
/* Whether this tick steps bodies: the world holds some, or requests wait.
 * Tick thread, with s->lock held (it reads body_cmds). */
bool body_wanted_locked(struct sim *s);
/* The fields the bodies read, added to a tick's want (every cascade's
 * height, cascade 0's displacement). */
void body_want(struct frame_want *w);
/* Producer, right after ocean_step of pj: apply the waiting requests, step
 * the world on this tick's grids, publish the tick's bodies; returns a new
 * reference to them for the tick's frame (NULL: no bodies). */
struct body_snap *body_tick(struct sim *s, const struct prod_job *pj);
void body_cmds_free(struct sim_body_cmd *c); /* a list, with the lws side's id copies */

/* tick.c */
void *tick_main(void *arg);             /* the tick thread */

/* calibrate.c (sim_start, before the threads): the cost model's start-up figures. */
void calibrate_cost_model(struct sim *s);

#endif

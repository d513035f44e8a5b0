/* link_internal.h — what the files of the NATS link (link*.c) share: the
 * link itself, its queues and the functions each file offers the others.
 * Not for the daemon: it sees cluster.h only.
 *
 * Threads, as in cluster.h: NATS = the library's callback threads (message
 * delivery, connection events, reconnect delay); pump = the link's own
 * thread, the only one that writes to NATS; caller = the daemon's threads
 * (tick thread: cl_sim_publish_layer, cl_sim_demand; lws thread: the rest);
 * open/close = the thread in cl_link_open / cl_link_close, alone with the
 * link before the pump and the connection start and after they have ended.
 * Each field below says who writes it and who reads it, and under which
 * lock. Every internal function's comment names the thread it runs on. */
#ifndef OCEAND_CLUSTER_LINK_INTERNAL_H
#define OCEAND_CLUSTER_LINK_INTERNAL_H

#include "cluster.h"

#include <nats/nats.h>
#include <pthread.h>
#include <stdatomic.h>
#include <time.h>

/* ---- outbox: what the pump is to write (link_pump.c) ---- */

enum out_type { OUT_LAYER, OUT_MSG };
struct out_item {
    struct out_item *next;
    enum out_type type;
    size_t bytes;                   /* counted against outbox_max_bytes */
    /* OUT_LAYER: the caller's bytes, borrowed until release(ctx) */
    struct cl_layer_info info;
    const uint8_t *data;            /* first section (cl_layer_sections) */
    const uint32_t *tile_off;
    const uint8_t *data2;           /* second section, if any */
    const uint32_t *tile_off2;
    void (*release)(void *);
    void *ctx;
    /* OUT_MSG: an encoded envelope */
    char subject[CL_SUBJECT_MAX];
    char reply[CL_SUBJECT_MAX];     /* "" = none */
    uint8_t *buf;
};

/* ---- inbox: what cl_link_dispatch hands to the daemon (link_inbox.c) ---- */

enum in_type { IN_STATE, IN_REQUEST, IN_LAYER, IN_PARAMS, IN_REPLY, IN_PROBE_DATA, IN_BODIES, IN_BODY_SECTION };
struct in_event {
    struct in_event *next;
    enum in_type type;
    enum cl_event ev;               /* IN_STATE */
    struct cl_request *req;         /* IN_REQUEST */
    struct cl_layer *layer;         /* IN_LAYER */
    char origin[CL_NAME_MAX], by[CL_NAME_MAX];
    char *text;                     /* NUL-terminated body */
    size_t len;
    int status;                     /* IN_REPLY */
    cl_reply_fn done;
    void *ctx;
};

/* An edge's request waiting for its reply (link_request.c). */
struct pending {
    struct pending *next;
    uint64_t id;                    /* the last token of its reply subject */
    double deadline;                /* monotonic seconds */
    cl_reply_fn done;
    void *ctx;
};

/* What a subscription delivers: on_msg (link.c) routes by it. */
enum sub_kind {
    SUB_CTL, SUB_HELLO, SUB_DEMAND, SUB_PARAMS, SUB_STATUS, SUB_INBOX, SUB_LAYER, SUB_QUERY, SUB_PROBE, SUB_BODIES, SUB_KINDS
};
struct sub_ctx {
    struct cl_link *l;
    enum sub_kind kind;
};

struct cl_link {
    /* Set by open, read-only until close: every thread reads them. */
    struct cl_config cfg;           /* defaults filled in; url and credentials not kept */
    char prefix[CL_PREFIX_MAX + 1], name[CL_NAME_MAX];
    char instance[CL_NAME_MAX];     /* this process's random id (sim: in every STATUS) */
    uint64_t epoch;                 /* the same id as a number (sim: in every layer); set at open */
    char subj[SUB_KINDS][CL_SUBJECT_MAX];
    char inbox[CL_SUBJECT_MAX];     /* edge: replies come to inbox.<id>, probe data to inbox.p */
    struct sub_ctx sctx[SUB_KINDS];
    natsOptions *opts;
    natsConnection *nc;             /* the library locks it: the pump publishes, open/pump subscribe */
    natsSubscription *subs[SUB_KINDS]; /* open subscribes, close destroys; a sim's request subjects
                                          (CTL, HELLO, QUERY, PROBE): the pump (un)subscribes them */

    natsSubscription *layer_subs[CL_KEYS]; /* edge: pump only (close after the pump has ended) */
    unsigned rng;                   /* reconnect jitter: NATS reconnect thread only */

    /* out_lock: the outbox and everything else the pump works from. */
    pthread_mutex_t out_lock;
    pthread_cond_t out_cond;        /* signalled when there is work for the pump */
    struct out_item *out_head, **out_tail; /* caller threads append, pump drains */
    size_t out_bytes;               /* caller threads add, pump zeroes on draining */
    bool stop;                      /* close sets, pump reads */
    struct cl_demand_bits want;     /* edge: lws thread writes (cl_edge_set_demand_ex), pump reads */
    bool want_changed;              /* edge: lws and NATS threads set, pump clears: resubscribe and heartbeat now */
    char *status_text;              /* sim: caller writes (cl_sim_set_status), pump copies: heartbeat body */
    size_t status_len;
    struct pending *pending;        /* edge: lws adds, NATS delivery (reply) and pump (timeout) take */
    uint64_t next_id;               /* edge: lws thread */
    pthread_t pump;                 /* open starts it, close joins it */
    bool pump_started;

    /* in_lock: the inbox and what the NATS delivery thread keeps. */
    pthread_mutex_t in_lock;
    struct in_event *in_head, **in_tail; /* NATS, pump (and caller) threads append, dispatch drains */
    int in_count;
    struct in_event *layer_ev[CL_KEYS]; /* edge: each key's queued layer; NATS delivery sets, dispatch clears */
    struct cl_assembler *assembler; /* edge: NATS delivery thread; cl_link_stats reads its drop count */
    bool sim_up;                    /* edge: NATS delivery sets (status), pump clears (timeout) */
    double sim_last_seen;           /* edge: NATS delivery writes, pump reads */
    char sim_instance[CL_NAME_MAX]; /* edge: NATS delivery only: the instance of the last STATUS */

    struct cl_demand *demand;       /* sim: its own mutex; NATS delivery updates, tick thread reads the union */
    atomic_bool connected;          /* NATS connection callbacks (and open) write, any thread reads */
    atomic_bool sim_up_flag;        /* edge: sim_up without in_lock: NATS delivery sets, pump clears, any reads */
    atomic_bool standby;            /* sim: the caller sets (cl_sim_set_standby), pump reads: no STATUS */

    /* close_lock: close waits until NATS has finished calling us. */
    pthread_mutex_t close_lock;
    pthread_cond_t close_cond;
    int subs_live;                  /* open and pump add (subscribe), NATS removes (on complete) */
    bool closed_cb;                 /* NATS sets (on_closed), close waits for it */

    struct cl_stats st;             /* any thread, with __atomic builtins; cl_link_stats reads */
};

#define STAT_ADD(l, f, n) __atomic_fetch_add(&(l)->st.f, (uint64_t)(n), __ATOMIC_RELAXED)

static inline double link_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* The message as an envelope of this kind (false: not one, a bad message). */
static inline bool link_msg_envelope(natsMsg *msg, enum cl_kind kind, struct cl_envelope *env)
{
    return cl_envelope_parse((const uint8_t *)natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), env) == 0 &&
           env->kind == kind;
}

/* ---- link.c: lifecycle and subscriptions ---- */
/* open or pump: subscribes subject, delivering to on_msg as `kind`; NULL on failure. */
natsSubscription *link_subscribe(struct cl_link *l, const char *subject, enum sub_kind kind);
void link_unsubscribe(natsSubscription **sub);                 /* pump */

/* ---- link_inbox.c (any thread unless said) ---- */
void link_event_free(struct in_event *e);
/* Appends e (or drops it, counted, when the inbox is full) and wakes the
 * caller's thread if the inbox was empty. Takes ownership. */
void link_push_event(struct cl_link *l, struct in_event *e);
void link_push_state(struct cl_link *l, enum cl_event ev);
void link_push_reply(struct cl_link *l, cl_reply_fn done, void *ctx, int status, const uint8_t *text, size_t len);
/* A new event of this type carrying a NUL-terminated copy of env's body;
 * NULL (counted as dropped) when out of memory. */
struct in_event *link_event_with_body(struct cl_link *l, const struct cl_envelope *env, enum in_type type);
/* Tells the daemon there is something to dispatch (cfg.wake). */
void link_wake(struct cl_link *l);
/* NATS delivery, in_lock held: queues a complete layer, replacing the one of
 * its key still queued. Takes the layer; true if the caller must wake. */
bool link_inbox_put_layer(struct cl_link *l, struct cl_layer *layer);

/* ---- link_pump.c: the outbox and the pump thread ---- */
int link_pump_start(struct cl_link *l);   /* open: 0 or an errno */
void link_pump_stop(struct cl_link *l);   /* close: returns once the pump has ended */
void link_item_free(struct out_item *it);  /* any thread: releases a layer's bytes to the daemon */
/* caller threads: appends to the outbox, dropping the oldest layers beyond outbox_max_bytes. */
void link_push_out(struct cl_link *l, struct out_item *it);
/* caller threads: queues an envelope from `origin` (reply NULL: none). 0 or a negative CL_E_*. */
int link_push_envelope(struct cl_link *l, const char *subject, const char *reply, enum cl_kind kind,
                       const char *origin, const char *by, const void *body, size_t len);
/* pump: publishes an envelope from this link now, not through the outbox. */
void link_send_envelope(struct cl_link *l, const char *subject, enum cl_kind kind, const char *by, const void *body,
                        size_t len);

/* ---- link_stream.c: layers, params events and probe data, sim -> edges ---- */
/* pump: one queued layer, in parts that fit the server's max_payload (scratch reused). */
void link_publish_layer(struct cl_link *l, const struct out_item *it, uint8_t **scratch, size_t *scap);
void link_on_layer(struct cl_link *l, natsMsg *msg);       /* NATS delivery, edge */
void link_on_params(struct cl_link *l, natsMsg *msg);      /* NATS delivery, edge */
void link_on_bodies(struct cl_link *l, natsMsg *msg);      /* NATS delivery, edge */
void link_on_probe_data(struct cl_link *l, natsMsg *msg);  /* NATS delivery, edge */

/* ---- link_request.c: requests and replies, edge -> sim -> edge ---- */
void link_on_request(struct cl_link *l, natsMsg *msg, enum cl_kind want); /* NATS delivery, sim */
void link_on_reply(struct cl_link *l, natsMsg *msg);                      /* NATS delivery, edge */
/* pump, out_lock held: takes the requests past their deadline. */
struct pending *link_requests_expired(struct cl_link *l, double now);
/* pump, no lock: answers and frees them (CL_E_TIMEOUT). */
void link_requests_time_out(struct cl_link *l, struct pending *expired);

/* ---- link_heartbeat.c: heartbeats, demand and liveness ---- */
/* The pump's heartbeat state, and what it takes under out_lock each round. */
struct link_beat {
    double next;                    /* when the next heartbeat is due */
    bool sent_empty;                /* edge: an empty demand was announced (once is enough) */
    bool changed;                   /* edge: want changed or the sim must hear it now */
    struct cl_demand_bits want;
    char *status;                   /* sim: a copy of the status text when a heartbeat is due */
    size_t status_len;
};
void link_beat_take(struct cl_link *l, struct link_beat *b, double now); /* pump, out_lock held */
void link_beat_send(struct cl_link *l, struct link_beat *b, double now); /* pump, no lock */
void link_kick_demand(struct cl_link *l);                   /* NATS: edge, announce demand now */
void link_on_status(struct cl_link *l, natsMsg *msg);       /* NATS delivery, edge */
void link_on_demand(struct cl_link *l, natsMsg *msg);       /* NATS delivery, sim */

#endif

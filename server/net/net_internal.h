/* net_internal.h — what the files of server/net/ share. Not for the rest of
 * the daemon, which uses ../net.h.
 *
 * Every function and field here belongs to the lws service thread (the one
 * that calls net_service), unless its comment says otherwise; nothing here is
 * locked. Data from the simulation arrives only through sim_latest,
 * sim_take_answers and sim_seq (server/tick/sim_thread.h), on that thread, after
 * lws_cancel_service woke it (LWS_CALLBACK_EVENT_WAIT_CANCELLED in
 * session.c). docs/threads.md has the whole contract.
 *
 *   context.c   lws context, protocol table, mounts; net_create/destroy
 *   upgrade.c   who may open a WebSocket (Origin, --max-clients)
 *   session.c   the oceand.v1 protocol: session lifecycle, receive, write
 *               scheduling, JSON send queue, the sim's wake-up
 *   dispatch.c  control messages: rate limit, set/subscribe/ping, and the
 *               answers to sets coming back from the sim
 *   fanout.c    frames: latest-frame-wins hand-over, per-client slicing
 *   http.c      /healthz, /metrics, placeholder page
 *   cluster.c   the hooks of --role sim|edge (net.h): frames, hello and
 *               params from another daemon */
#ifndef OCEAND_NET_INTERNAL_H
#define OCEAND_NET_INTERNAL_H

#include <cjson/cJSON.h>
#include <libwebsockets.h>
#include <stdbool.h>
#include <stdint.h>

#include "body_msg.h"
#include "capacity.h"
#include "config.h"
#include "control.h"
#include "frame.h"
#include "net.h"
#include "oc_proto.h"

#define CHUNK_SIZE (64 * 1024)    /* bytes per lws_write of a frame, at most: ladder_chunk writes about one tick of the link */
#define NET_RING 18               /* recent frames kept for temporal clients a few ticks behind (fanout.c) */
#define NET_RING_MAX_BYTES ((size_t)16 << 20) /* ...and their bytes at most (large N: fewer frames) */
#define NET_ONCE_SLOTS 256        /* "once" keys remembered: a flood of keys pushes out the oldest */
#define NET_ONCE_TTL_S 30.0       /* ...for this long: far past any TCP retransmission */
#define LAG_MAX 15                /* ticks a temporal client may run behind the newest frame to keep its chain:
                                   * its 4 keyframe ticks at ~3x a shared frame's bytes, on a link that fits the shared ones */
#define LADDER_MAX_RUNGS 12
#define MAX_TEXT_QUEUE 256        /* a client this far behind on JSON is not reading: drop it */
#define TRIM_DELAY_S 0.5          /* after a change of N: time for the builder to free the old grids */
#define CUT_OFF_GRACE_S 10        /* a client cut off (1008) that does not read its close frame: hung up after */
#define FD_RESERVE_MIN 16         /* descriptors kept free below RLIMIT_NOFILE (plus 1/64 of it) */

/* One queued JSON message. */
struct text {
    lws_dll2_t list;              /* in session.tq */
    size_t len;                   /* bytes of the message */
    unsigned char data[];         /* LWS_PRE bytes, then the message */
};

/* The link estimate and quality ladder of one client (ladder.c, PROTOCOL.md
 * §7.2 `link`). lws thread only. */
struct ladder {
    int rung, nrungs;             /* rung in force (0 = as asked), rungs of this subscription */
    double open_t;                /* when the client connected */
    double changed_t;             /* mono time of the last change of rung */
    double stalled_t;             /* the last window in which nothing was taken (a stall), 0 = none */
    double up_t;                  /* ...of the last step up (a step down soon after it is a failed probe) */
    double hold;                  /* seconds without congestion before the next probe up */
    double win_t;                 /* start of the current evaluation window */
    int win_ticks, win_skips;     /* frames published / ticks this client lost, in the window */
    int win_lag;                  /* largest lag (ticks behind the newest frame) seen in the window */
    int win_lag_min;              /* ...and the smallest: > 0 at every tick = it never caught up in the window */
    int win_full;                 /* ticks at which its socket held about a queue's worth unsent: the link (or
                                   * the reader) was the bottleneck, not this daemon being late */
    int calm;                     /* windows in a row without congestion */
    int prev_lag;                 /* win_lag of the window before */
    int prev_lag_min;             /* win_lag_min of the window before */
    double rate_bps;              /* link estimate (bytes/s): TCP_INFO delivery rate, recent non-app-limited max */
    double rate_t;                /* when rate_bps was last raised by a sample */
    double cap_bps, cap_t;        /* the last sample of a full pipe (not app-limited): the link, measured */
    double pace_bps;              /* SO_MAX_PACING_RATE in force (bytes/s), 0 = none */
    double min_rtt_ms;            /* the kernel's minimum RTT: the path without queues */
    bool held;                    /* the next frame waits for bytes in flight to leave (ladder_hold_frame) */
    double rtt_ms;                /* smoothed RTT */
    uint32_t notsent;             /* bytes written and not sent yet, last sample */
    uint32_t lowat;               /* TCP_NOTSENT_LOWAT in force */
    double bits_t, bits_i;        /* bits per sample of shared (temporal) and keyframe/intra frames, EWMA */
    double bits_r[LADDER_MAX_RUNGS]; /* ...of shared frames per rung, 0 = never seen */
    double done_t;                /* when the last frame's last byte was handed to the kernel */
    uint64_t frame_samples;       /* samples of the frame in progress */
    bool frame_shared;            /* ...and whether all its tiles were shared (temporal) ones */
    bool told;                    /* a `link` message went out for this subscription */
    char why[112];                /* reason of the last change, for `link` */
};

/* One WebSocket client: lws' per-session data of the oceand.v1 protocol.
 * Every field is written and read on the lws thread only (session.c,
 * dispatch.c, fanout.c); no other thread ever sees a session. */
struct session {
    lws_dll2_t list;              /* in net.sessions; detached = not (or no longer) established */
    struct lws *wsi;              /* NULL once closed */
    uint64_t serial;              /* unique for the daemon's life; requests find their sender by it */
    char client_id[32];           /* "c<serial>-<instance tag>": hello.client_id, params.by (PROTOCOL.md §4.1) */
    char name[CTL_NAME_BYTES];    /* display name (`name`, or a set's "name"), "" = none: params.by_name */
    bool controller;              /* may set without a token */
    struct subscription sub;      /* as asked (`subscribed`) */
    struct subscription eff;      /* as served: sub at the ladder's rung; counted in the sim's demand */
    struct ladder lad;            /* ladder.c */

    /* receive */
    char *rx;                     /* a text message being assembled from fragments */
    size_t rx_len;                /* its bytes so far */
    bool rx_binary;               /* inside a binary message (fragments of it follow) */
    size_t rx_binary_len;         /* its bytes so far: --max-message applies to it too */
    int closing;                  /* close status to send once the queue drains, 0 = none */
    const char *close_reason;     /* its reason text (static) */
    double tokens, tokens_t;      /* control-message rate limit (token bucket, in units) and its last refill */
    double share, share_t;        /* its fair share of --control-budget (bucket of budget / clients) */

    /* transmit: JSON queue (sent before any new frame) */
    lws_dll2_owner_t tq;          /* struct text, oldest first; tq.count = messages */
    size_t tq_bytes;              /* their cost in bytes (messages + nodes) */
    size_t output_limit;          /* --output-limit-kb in bytes: over it the client is closed (1008) */

    /* transmit: the frame being sent (fanout.c) */
    struct frame *cur;            /* one reference while sending, else NULL */
    struct oc_frame_header fhdr;  /* its header; each part's copy has the part's tile count and flag */
    uint8_t hdr[OC_FRAME_HEADER_SIZE]; /* the header of the part being sent */
    const struct layer *layers[OCEAN_MAX_CASCADES * OCEAN_FIELD_COUNT]; /* [cascade * FIELDS + field], NULL = not sent */
    const uint8_t *lbuf[OCEAN_MAX_CASCADES * OCEAN_FIELD_COUNT];  /* per slot: the tiles this client gets (buf or shared) */
    const uint32_t *loff[OCEAN_MAX_CASCADES * OCEAN_FIELD_COUNT]; /* ... and their offsets */
    uint16_t tiles[CTL_MAX_TILES]; /* the frame's tiles this client gets, in order */
    int ntiles;
    size_t sent;                  /* bytes of this client's frame (all its parts) sent so far */
    size_t part_left;             /* bytes of the part being sent not written yet; 0 = between parts */
    bool part_more;               /* the part being sent is not the frame's last */
    int hdr_off, fi, ti;          /* position: the part's header bytes, field, tile... */
    size_t off;                   /* ...and byte within the tile */
    uint64_t first_seq;           /* frames older than this are never sent (tick at join) */
    uint64_t last_seq;            /* seq of the last frame started, 0 = none yet */
    uint64_t last_index;          /* its frame.index */
    uint64_t counted_index;       /* frames up to this index are counted as sent or skipped */
    double last_frame_t;          /* when it started (max_rate) */
    double progress_t;            /* when a byte of the frame in progress was last written (stall rule) */
    /* temporal layers (codec 3, PROTOCOL.md §5.9; fanout.c) */
    uint64_t hist_seq;            /* seq of the last frame started under this subscription, 0 = none */
    int hist;                     /* consecutive ticks received, up to hist_seq */
    bool key_wanted;              /* counted in the sim's key_want for the subscription's layers */
    uint64_t waited_seq;          /* last frame skipped for want of keyframe tiles (counted once) */
    unsigned char *chunk;         /* LWS_PRE + CHUNK_SIZE (live and rendered frames) */
    /* transmit: its render's frames and closing message, in order (renders.c) */
    struct render_out *rq, *rq_tail; /* oldest first; a frame is sent whole before anything else */
    int rq_frames;                /* frames in rq (at most RENDER_WINDOW: the worker waits for room) */
    size_t rq_sent;               /* bytes of rq's head written, 0 = not started */
    uint64_t rq_render;           /* the render whose frames rq_written counts */
    long rq_written;              /* its frames written whole: what its `rendered` says */
    /* floating bodies (body_net.c) */
    int launching;                /* its launches not answered yet (they count against --bodies-per-session) */
    double launch_tokens, launch_t; /* --launch-rate bucket and its last refill (0 = never: full) */
    bool body_user;               /* edge: it sent a body request (its edge tells the sim while it is here) */
    const uint8_t *ext;           /* the BODY section of the frame being sent (its header extension), or NULL */
    size_t ext_len, ext_off;      /* its bytes in the part being sent (only the first part), and sent so far */
};

/* One floating body as the lws thread knows it (body_net.c): who owns it. */
struct body_own {
    uint32_t id;
    const struct body_kind *kind;
    uint64_t owner;               /* serial of the session that owns it, 0 = none connected */
    char owner_id[32];            /* the owner's client id (the last one it had) */
    char name[CTL_NAME_BYTES];    /* its display name, "" = none */
    char resume[33];              /* the key that claims it back */
    double left_t;                /* mono time its owner went, 0 while owned */
    bool stopped;                 /* the grace passed: its controls were zeroed (it drifts) */
    bool removing;                /* a remove is on its way to the sim */
};
/* Every body the lws thread knows of, and what the clients were told. */
/* sim role: a client of an edge that asked for bodies (body_net.c): the
 * owner the sim knows, kept while its edge lists it (net_remote_owners). */
struct body_remote {
    uint64_t serial;              /* a remote serial (net_remote_serial): the owner of its bodies */
    char origin[64];              /* its edge */
    char by[32];                  /* its client id there (as body_own.owner_id) */
    char name[CTL_NAME_BYTES];
    int launching;
    double seen;                  /* mono time its edge last listed it */
};
/* sim role: a client of an edge waiting for the answer of a request the sim thread applies. */
struct body_wait {
    uint64_t ticket;
    net_reply_fn reply;
    void *ctx;
};
struct body_book {
    struct body_own *b;           /* ascending id */
    struct body_remote *rc;       /* sim role: clients of edges (BODY_REMOTE_MAX at most) */
    int nrc, rc_cap;
    struct body_wait *wait;       /* sim role: requests of edges' clients in the sim thread */
    int nwait, wait_cap;
    uint64_t next_ticket;
    bool owners_due;              /* edge: tell the sim who is here (net_body_owners) now */
    double owners_t;              /* edge: when it was last told */
    bool owners_any;              /* edge: the last list was not empty */
    double replica_t;             /* sim role: when the bodies were last handed to the record (on_bodies_state) */
    bool restoring;               /* sim role: a take-over's bodies are on their way to the sim thread */
    uint64_t restored_seq;        /* ... and the tick they were in from (older snapshots are not handed on) */
    int n, cap;
    int launching;                /* launches submitted and not answered (they count against --max-bodies) */
    struct body_gone_entry *gone; /* left since the last `bodies` message */
    int ngone, gone_cap;
    bool dirty;                   /* the list changed: `bodies` to everyone (body_net_flush) */
    uint64_t seq;                 /* the tick of the last change */
    struct body_snap *snap;       /* the newest bodies taken from the sim (one reference), or NULL */
    double kept_t;                /* when they were last handed to the state saver */
    bool save_due;                /* the set of bodies changed since the last save */
    double saved_t;               /* when the last save was asked for */
};

/* A set sent to the sim and not answered yet: the sim knows it only by tag. */
struct session;
/* Who gets the answers to a set: a local client (s), or, in the sim role,
 * a client of another daemon (rm). */
struct remote {
    const char *origin, *by;
    net_reply_fn reply;
    void *ctx;
};
void dispatch_respond_error(struct session *s, const struct remote *rm, const struct ctl_error *e, const cJSON *id);
/* A checked change: out is the view after it, changed the rows it changes,
 * sea a new measured sea (taken: freed whatever happens) or NULL. */
struct sea_spectrum;
void dispatch_submit_change(struct net *n, struct session *s, const struct remote *rm, const struct ocean_params *out,
                            uint64_t changed, const char *name, const cJSON *id, struct sea_spectrum *sea);

/* Measured seas (sea_net.c): the `sea` request and the summary. */
struct ctl_msg;
bool sea_net_attached(const struct net *n);      /* a sea in force or on its way: "measured" may be set */
int sea_net_check(const cJSON *doc, struct ctl_error *e); /* an edge's early check of a document */
void sea_net_submit(struct net *n, struct session *s, const struct remote *rm, const struct ctl_msg *m);
void sea_net_add(const struct net *n, cJSON *msg); /* "sea": the summary, or null */

struct request {
    lws_dll2_t list;              /* in net.requests, in submission order */
    uint64_t tag;
    uint64_t serial;              /* sender's session serial (it may be gone by the answer) */
    char by[64];                  /* sender's client id */
    char by_name[CTL_NAME_BYTES]; /* sender's display name at the time, "" = none */
    net_reply_fn reply;           /* sim role: a remote request, answered through reply(reply_ctx) */
    void *reply_ctx;
    char origin[64];              /* ... from this daemon (the edge) */
    cJSON *id;                    /* owned copy of the request id, or NULL */
    struct ocean_params values;   /* what the set asked for (mask of params)... */
    uint64_t mask;                /* ...replayed onto the applied params to rebuild the view */
    bool sea;                     /* it brings a measured sea */
};

/* sim role: a `query` from a client of an edge, in the query workers under
 * a serial of its own (NET_REMOTE_SERIAL set: never a session's), answered
 * through reply(reply_ctx) when the result comes back. */
#define NET_REMOTE_SERIAL (1ull << 63)
#define NET_PROBE_QUEUE_MAX 16 /* JSON messages queued: a client this far behind misses probe ticks */
struct remote_query {
    lws_dll2_t list;              /* in net.remote_queries */
    uint64_t serial;
    net_reply_fn reply;
    void *reply_ctx;
};

/* Per-connection data of the HTTP protocol. */
struct http_session {
    unsigned char *body;          /* LWS_PRE + len */
    size_t len;
};

/* The network side. Every field is written and read on the lws thread only
 * (by net_create before the service loop starts, then in lws callbacks),
 * except where its comment names another thread. */
struct net {
    struct lws_context *ctx;      /* net_create writes; lws reads; the tick reads it in net_wake (lws_cancel_service) */
    lws_sorted_usec_list_t beat;  /* lws only: a wake-up every NET_BEAT_MS, so the loop sees a signal's flag */
    struct daemon_config dc;      /* read-only after net_create */
    struct ctl_limits lim;        /* read-only after net_create */
    struct sim *sim;              /* main writes (net_attach_sim) outside the service loop; lws reads */
    struct query_service *queries; /* main writes (net_attach_queries) outside the loop; lws reads (query, probe) */
    struct render_service *renders; /* main writes (net_attach_renders) outside the loop; lws reads (render) */
    struct frame *latest;         /* newest frame taken from the sim (one reference), or NULL */
    struct frame *ring[NET_RING]; /* the newest frames, oldest first (one reference each; latest is the last) */
    int nring;
    uint64_t seen_index;          /* frame.index of the last frame taken (skip counting) */
    uint64_t seen_seq;            /* its seq */
    bool seen_any;                /* a frame was taken at least once */
    lws_dll2_owner_t sessions;    /* struct session; .count = connected clients */
    uint64_t next_serial;         /* last session serial handed out */
    char instance_tag[8];         /* 4 random letters/digits drawn at start: in every client id */
    lws_dll2_owner_t requests;    /* struct request: sets sent to the sim, not answered yet */
    struct once_seen {            /* lws only: the "once" keys of recent changes (once_seen, dispatch.c) */
        char key[CTL_ONCE_MAX + 1];
        double t;
    } once[NET_ONCE_SLOTS];
    int once_next;                /* lws only: the slot the next key takes (oldest first) */
    uint64_t next_tag;            /* last struct sim_set tag handed out */
    struct ocean_params applied;  /* in force (from the sim's answers) */
    uint32_t applied_version;     /* its params_version */
    struct ocean_params view;     /* applied + every pending request: what the next set is checked on */
    char *sea_summary;            /* the measured sea in force: its summary (JSON text, malloc'd) for hello
                                     and params, or NULL (none attached) */
    int seas_in_flight;           /* requests that bring a sea, not answered yet */
    net_params_fn on_params;      /* main writes (net_on_params) before the loop: applied-change listener */
    void *on_params_user;         /* its argument (main's state saver, used on this thread) */
    double trim_due;              /* mono time to malloc_trim after a change of N, 0 = none */
    double police_t;              /* when fanout_police last ran */
    int replans_in_flight;        /* sets that change N submitted and not answered yet */
    double replan_t;              /* mono time the last change of N was applied, 0 = never */
    double replan_hold;           /* ...and how long it took to build: the next waits as long */
    double budget, budget_t;      /* --control-budget: units left for all clients together, last refill (lws thread) */
    bool placeholder;             /* no index.html in the web root */
    int port;                     /* the port really listened on (--port 0) */
    int fd_limit;                 /* RLIMIT_NOFILE at start */
    int fd_ceiling;               /* accepted fds at or above this are closed at once (a reserve below fd_limit) */
    long fd_warned;               /* time of the last "out of descriptors" warning (one a second) */
    lws_retry_bo_t retry;         /* ping / hang-up policy, read by lws */
    struct lws_http_mount m_files, m_health, m_metrics; /* read by lws */
    struct lws_protocols protocols[3]; /* [0] http, [1] oceand.v1, [2] terminator; read by lws */
    struct plan told;             /* the sim's plan the clients were last told about (capacity.c) */
    uint32_t told_gen;            /* its generation, 0 = none yet */
    /* Cluster roles (net.h, cluster.c); all zero for --role all. */
    struct net_cluster_hooks cluster; /* main writes (net_set_cluster) before the loop */
    char *status_text;            /* edge: {"type":"status",...} for new clients, NULL = healthy */
    cJSON *sim_capacity;          /* edge: the sim's `capacity` (its hello, params of a new N) for hello, or NULL */
    lws_dll2_owner_t remote_queries; /* sim: struct remote_query, queries of edges' clients in the workers */
    uint64_t next_remote;         /* sim: last remote query / probe serial handed out (net_remote_serial) */
    uint64_t published;           /* edge: frames handed to net_publish_frame (frame.index) */
    struct body_book bodies;      /* floating bodies and their owners (body_net.c) */
    struct state_saver *saver;    /* main writes (net_attach_saver) before the loop; the bodies are handed to it */
};

static inline struct net *net_of(struct lws *wsi) { return lws_context_user(lws_get_context(wsi)); }
static inline struct session *session_of(lws_dll2_t *d) { return lws_container_of(d, struct session, list); }
/* The tile side in use at the applied resolution (hello, params). */
static inline int net_tile_size(const struct net *n) { return frame_tile_size(n->dc.tile_size, n->applied.resolution); }

/* upgrade.c */
bool net_host_name_allowed(const struct daemon_config *dc, const char *host); /* a Host header value */
bool net_host_allowed(struct net *n, struct lws *wsi);      /* the request's Host */
int upgrade_confirm(struct net *n, struct lws *wsi, const char *upgrade); /* 0 = go on, 1 = refused (answered) */
bool upgrade_allowed(struct net *n, struct lws *wsi);

/* rx_guard.c: RFC 6455 §5.1 masking, which lws 4.1 does not check, and a client's end of
 * stream, on which lws 4.1 can spin (plain sockets) */
void rx_guard_start(void);                                   /* net_create, plain ws only */
void rx_guard_stop(void);
void rx_guard_accept(int fd);                                /* a new client connection */
bool rx_guard_in_sync(int fd);                               /* at the upgrade */
void rx_guard_forget(int fd);                                /* the connection is closing */
void rx_guard_upgrade_refused(int fd);                       /* refused with an HTTP answer: back to heads */
bool rx_guard_tripped(int fd);                               /* an unmasked frame was replaced by close 1002 */

/* session.c */
int cb_ws(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len);
void session_queue_text(struct session *s, const char *msg, bool front);
void session_queue_json(struct session *s, cJSON *msg);   /* prints and deletes msg */
void session_send_error(struct session *s, const struct ctl_error *e, const cJSON *id);
struct session *session_find(struct net *n, uint64_t serial);
void net_instance_tag(char *out, size_t cap);   /* the 4-character per-start part of client ids */

/* dispatch.c */
bool dispatch_take_token(struct net *n, struct session *s, const char *text, size_t len);
void dispatch_message(struct net *n, struct session *s, const char *text, size_t len);
void dispatch_answers(struct net *n);                        /* the sim's answers to sets */
void dispatch_demand(struct net *n, const struct subscription *sub, int delta);
void dispatch_free_requests(struct net *n);
void dispatch_query_results(struct net *n);                  /* answers of the query workers */

/* fanout.c */
void fanout_take_latest(struct net *n);                      /* after a wake-up */
void fanout_set_latest(struct net *n, struct frame *f);      /* takes f's reference (NULL = none) */
bool fanout_want_write(const struct net *n, const struct session *s); /* a frame is ready for s */
int fanout_write(struct net *n, struct session *s);          /* one lws_write of a frame */
void fanout_session_free(struct session *s);
void fanout_police(struct net *n);                           /* also each client's ladder, ~10 Hz */
void fanout_free_ring(struct net *n);
/* Close s with status (1008) after dropping its queued replies; a client
 * that never reads is hung up by a timeout (session.c). */
void session_cut_off(struct session *s, int status, const char *reason);                           /* close clients that do not read (stalled, pinned) */
/* Temporal clients: the subscription in s->sub is new (join, subscribe):
 * no history, keyframes wanted. fanout_want_keyframes(false) before the
 * subscription changes or the session goes, so the counts stay balanced. */
void fanout_subscribed(struct net *n, struct session *s);
void fanout_want_keyframes(struct net *n, struct session *s, bool want);

/* renders.c: exact-time renders (render_worker.h does the work) */
struct render_out;
void renders_dispatch(struct net *n, struct session *s, const cJSON *root, const cJSON *id); /* `render` */
void renders_cancel(struct net *n, struct session *s);      /* `render_cancel` */
void renders_take(struct net *n);                            /* after a wake-up: the workers' output */
int renders_write(struct net *n, struct session *s);         /* one lws_write of s->rq */
void renders_session_free(struct net *n, struct session *s); /* the client is gone: its render ends */

/* ladder.c: per-client link estimate and quality ladder */
void ladder_open(struct net *n, struct session *s);          /* after the socket is set up */
void ladder_subscribed(struct net *n, struct session *s);    /* s->sub changed: rebuild s->eff at the rung in force */
void ladder_announce(struct net *n, struct session *s);      /* after `subscribed`: `link` if the rung is not 0 */
void ladder_tick(struct net *n, struct session *s, const struct frame *f, int lost, int lag); /* a frame was published */
void ladder_frame_done(struct net *n, struct session *s, size_t bytes);
void ladder_police(struct net *n, struct session *s, double now);  /* ~10 Hz: estimate, decide */
size_t ladder_chunk(const struct session *s);                 /* bytes to hand to one lws_write */
int ladder_hold_frame(struct session *s);                    /* µs to wait before starting a frame, 0 = now */
/* tcp_probe.c: TCP_INFO without netinet/tcp.h's truncated struct */
struct tcp_probe { double delivery_bps, rtt_ms, min_rtt_ms; uint32_t notsent, inflight; bool app_limited, ok; };
void tcp_probe_read(int fd, struct tcp_probe *p);
void tcp_probe_lowat(int fd, uint32_t bytes);
void tcp_probe_pacing(int fd, double bytes_per_s); /* 0 = no limit */

/* capacity.c: capacity in hello/params, `busy`, `degraded` (server/tick/capacity.h) */
void net_capacity_add(struct net *n, cJSON *msg);            /* "capacity" member into msg */
bool net_capacity_admit(struct net *n, struct session *s, const struct subscription *want, struct ctl_error *e);
void net_capacity_tell(struct net *n, struct session *s);    /* `degraded` if s's group is degraded now */
void net_capacity_wake(struct net *n);                       /* after a wake-up: tell plan changes */

/* body_net.c: floating bodies (PROTOCOL.md §7.6): requests, owners, `bodies` */
/* launch/steer/remove/claim (text: the message, forwarded as it is by an edge) */
void body_net_dispatch(struct net *n, struct session *s, const struct ctl_msg *m, const char *text, size_t len);
void body_net_wake(struct net *n);                           /* after a wake-up: answers, grace, the sim's bodies */
cJSON *body_net_hello(struct net *n, cJSON *hello);          /* body_kinds, body_limits, world_half_size, bodies */
void body_net_session_gone(struct net *n, struct session *s); /* its bodies wait for a claim */
void body_net_renamed(struct net *n, struct session *s);     /* its bodies carry its new name */
void body_net_free(struct net *n);
/* sim role: a launch / steer / remove / claim of a client of an edge, answered through reply exactly once */
void body_net_remote(struct net *n, const char *origin, const char *by, const struct ctl_msg *m, net_reply_fn reply,
                     void *ctx);
void body_net_drop_remote(struct net *n);                    /* answers every waiting remote request with NULL */
int body_net_adopt_hello(struct net *n, const cJSON *hello); /* edge: the sim's bodies and limits */

/* http.c */
int cb_http(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len);

/* remote_sim.c: an edge's hello gets the sim's capacity (the sim's own has it from sim_capacity). */
cJSON *net_hello_capacity(struct net *n, cJSON *hello);

/* remote_sim.c: a checked message from the sim to every client but skip_client (NULL: none). */
int net_relay_sim_text(struct net *n, const char *text, size_t len, const char *skip_client);

#endif

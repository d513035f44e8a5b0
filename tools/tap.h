/* tap.h — ocean-tap's internals, shared by its verbs (one file each, as mosquitto
 * splits its handlers):
 *   tap_main.c     options, usage, the connection loop, dispatch to a verb
 *   tap_session.c  the session: hello -> set -> ... stages, control messages, libwebsockets
 *   tap_watch.c    frames (subscribe, the file writer thread), --watch, --stats
 *   tap_query.c    --query and --probe
 *   tap_bake.c     sums of the cascades and Blender bakes (--format exr, --bake)
 *   tap_sea.c      `ocean-tap sea SOURCE`: measured seas (sea.h readers)
 *   tap_body.c     floating bodies: --launch, --body/--resume, --follow, --bodies
 * Not an API: one program's files. */
#ifndef OCEAND_TAP_H
#define OCEAND_TAP_H

#include <cjson/cJSON.h>
#include <libwebsockets.h>
#include <pthread.h>
#include <signal.h>
#include <stddef.h>
#include <stdint.h>

#include "oc_proto.h"
#include "tap_exr.h"
#include "tap_surface.h"
#include "tap_write.h"

enum exit_code {
    EXIT_OK = 0,
    EXIT_USAGE = 1,       /* bad command line */
    EXIT_CONNECT = 2,     /* could not connect or WebSocket handshake failed */
    EXIT_PROTOCOL = 3,    /* malformed message or frame from the server */
    EXIT_REJECTED = 4,    /* server answered a set/subscribe with an error */
    EXIT_OUTPUT = 5,      /* could not write an output file */
    EXIT_TIMEOUT = 6,     /* no answer / no frame within --timeout */
    EXIT_CLOSED = 7,      /* server closed the connection before we were done */
    EXIT_BODY_GONE = 9,   /* the followed body left the sea (sunk, abandoned, removed) */
    EXIT_INTERRUPTED = 130, /* Ctrl-C before the first frame / answer (shell convention) */
};

#define MAX_SETS 64
#define ID_SET 1
#define ID_SUBSCRIBE 2
#define ID_QUIET 3     /* watch only: the smallest subscription there is */
#define ID_QUERY 4
#define ID_PROBE 5
#define ID_RENDER 6
#define ID_LAUNCH 7    /* the body requests (tap_body.c) */
#define ID_CLAIM 8
#define ID_STEER 9
#define ID_REMOVE 10
/* The `render` request (exact-time frames for bakes, PROTOCOL.md §7.5): its
 * frames carry this bit in the frame header's flags and their index k in
 * seq; sim_time = start + k / fps. */
#define RENDER_FRAME_FLAG 1u
#define WRITER_QUEUE 4                      /* complete frames waiting for the file writer, at most */
#define WRITER_BYTES ((size_t)256 << 20)    /* ... and their copies' bytes, at most (one frame always) */
#define MAX_POINTS 256 /* of --query / --probe (the server caps probes lower) */
#define RX_CHUNK (1 << 16) /* bytes of a message lws hands over at a time, and of one socket read */
struct opts {
    char url[1024];
    long frames;          /* -1 = not given */
    unsigned fields;
    int lod;
    double bound;         /* < 0 = not given */
    int max_rate;         /* 0 = not given */
    int intra;            /* --intra: no codec 3 (subscribe "temporal": false) */
    const char *out_dir;
    int format;
    int stats, watch, verbose;
    const char *sets[MAX_SETS];
    int nsets;
    const char *token;
    double timeout;
    int query, probe, csv;  /* --query / --probe given; --csv */
    double points[MAX_POINTS][2];
    int npoints;
    int has_time;
    double time;          /* --time */
    long ticks;           /* --ticks, 0 = until Ctrl-C */
    int cascades;         /* --cascades: 1 = cascade 0 only, -1 = all the server runs */
    int sum_m;            /* --sum M, 0 = not given, -1 = the default (N >> lod) */
    int has_area;
    double area[3];       /* --sum-area X,Z,S */
    int bilinear;         /* --interp bilinear */
    int bake;             /* --bake: exact-time frames through the render request */
    double fps, start;    /* --fps, --start */
    int has_start;
    /* floating bodies (tap_body.c) */
    const char *launch_kind; /* --launch KIND */
    double at[2];         /* --at X,Z */
    double heading;       /* --heading, degrees clockwise from north */
    double throttle, rudder;
    int has_throttle, has_rudder, has_at;
    unsigned long body;   /* --body ID, 0 = not given */
    const char *resume;   /* --resume KEY */
    int follow, list_bodies, keep;
};

struct job;

enum stage { ST_HELLO, ST_SET, ST_SUBSCRIBE, ST_QUERY, ST_PROBE, ST_RENDER, ST_BODY, ST_STEER, ST_REMOVE, ST_RUN, ST_DONE };

struct stats {
    double t0, last_report;
    long frames_at_report;
    unsigned long long bytes, bytes_at_report;
    double *lat_ms;       /* per frame: receive time - server_time_us */
    size_t nlat, caplat;
};

struct session {
    struct opts *o;
    enum stage stage;
    int exit_code;
    int want_frames;
    cJSON *schema;        /* hello.schema, to type --set values */
    struct oc_buf msg;    /* the message being reassembled */
    char *outq[4];        /* text messages waiting for WRITEABLE */
    int noutq;
    struct oc_grid *grid;   /* the subscribed fields, assembled from tiles */
    long frames_done;
    double resync_t;      /* when we last resubscribed after a missing reference */
    long ticks_done;      /* probe_data lines printed */
    double last_activity;
    double last_frame;    /* when the last complete frame (or the subscription's answer) came:
                             messages alone do not count, or a subscription served at a
                             coarser LOD, whose frames we cannot write, would wait for ever */
    int degraded_lod;     /* the LOD the server serves us at while degraded, else -1 */
    int ncasc;            /* cascades received: 1 + finer ones (from --cascades and the hello) */
    double patch[OC_MAX_CASCADES]; /* L_c from hello/params cascade_patch_sizes */
    struct writer {       /* the file writer (below) */
        pthread_t th;
        int started, closing;
        pthread_mutex_t mu;
        pthread_cond_t cv_put, cv_get;
        struct job *q[WRITER_QUEUE];
        int head, count;
        int err_code;
        char err[600];
        struct tap_surface *surface; /* the writer's own: */
        float *sum_buf;               /* --sum: fields on the sum grid */
        size_t sum_bytes;             /* ... its size */
    } wr;
    int csv_header_done;
    struct stats st;
    struct lws *wsi;
    uint32_t body_id;     /* the body we launched, claimed, steer or follow */
    int own;              /* ... ours: removed at the end unless --keep */
    int body_code;        /* the exit code once the removal is answered */
    uint64_t last_seq;    /* the last tick followed */
    char client_id[64];   /* hello's: the owner of what we launch */
};
struct job {
    struct oc_frame_header fh;
    long number;                  /* 1, 2, ...: the bake's frame number */
    int ncasc;
    double patch[OC_MAX_CASCADES];
    float *data[OC_MAX_CASCADES][OC_FIELD_COUNT];
    int side[OC_MAX_CASCADES][OC_FIELD_COUNT];
    float bound[OC_MAX_CASCADES][OC_FIELD_COUNT];
};

extern volatile sig_atomic_t interrupted;
extern struct lws_context *g_ctx;

/* tap_main.c */
void usage(FILE *to);
int usage_error(const char *fmt, ...);
/* tap_session.c */
double now_s(void);
double wall_us(void);
void finish(struct session *s, int code);
void fail(struct session *s, int code, const char *fmt, ...);
void send_json(struct session *s, cJSON *j);
void advance(struct session *s);
int callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len);
void on_signal(int sig);
void tick(lws_sorted_usec_list_t *sul);
extern lws_sorted_usec_list_t tick_sul;
int connect_server(struct session *s, struct lws_context *ctx);
/* tap_watch.c */
unsigned fine_fields(const struct opts *o);
int fine_lod(const struct opts *o);
void send_subscribe(struct session *s);
void send_quiet_subscribe(struct session *s);
void on_binary(struct session *s, const uint8_t *data, size_t len);
const float *job_field(const struct job *j, int c, int f, int *side, float *bound);
void wfail(struct session *s, int code, const char *fmt, ...);
int writer_error(struct session *s, char *msg, size_t len);
void writer_close(struct session *s);
void report_stats(struct session *s, double t, int final);
/* tap_query.c */
void send_points(struct session *s, const char *type, int id);
void print_probe(struct session *s, cJSON *msg, const char *text, size_t len);
/* tap_bake.c */
struct sum_grid { int m; double x0, z0, size; };
struct sum_grid sum_geometry(const struct session *s, const struct job *j);
int sum_field(struct session *s, const struct job *j, const struct sum_grid *sg, enum oc_field f,
              int only0, float *out, float *bound);
float *sum_buffers(struct session *s, int m, int count);
int write_bake(struct session *s, const struct job *j);
void print_error(cJSON *msg, const char *what);
/* tap_body.c */
int body_mode(const struct opts *o);
void body_hello(struct session *s, cJSON *hello);
void body_start(struct session *s);
void finish_body(struct session *s, int code);
int body_interrupt(struct session *s);
int body_on_text(struct session *s, cJSON *msg, const char *t);
void body_on_frame(struct session *s, const uint8_t *data, size_t len);
/* tap_sea.c: `ocean-tap sea ...` (argv[0] = "sea") */
int tap_sea_main(int argc, char **argv);
/* tap_sea_send.c: the documents to the daemon at url, a forecast at its times / speed. An exit code. */
struct sea_doc;
int tap_sea_send(const char *url, const struct sea_doc *docs, int n, double speed, const char *token,
                 const char *tail, double timeout);

#endif

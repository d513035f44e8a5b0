/* ocean-tap — a command-line client of oceand for scripts and pipelines.
 *
 *   ocean-tap ws://host:8080 --frames 100 --fields height,dx,dz --lod 1 \
 *             --bound 0.001 --out DIR --format npy|raw|pgm|pgm8|exr
 *   ocean-tap ws://host:8080 --set wind_speed=20 --set spectrum=jonswap
 *   ocean-tap ws://host:8080 --watch
 *   ocean-tap ws://host:8080 --probe "10,20;-5,3.5" --ticks 300
 *   ocean-tap ws://host:8080 --query "10,20;1e6,-3" [--time T]
 *
 * One WebSocket connection (libwebsockets client, subprotocol oceand.v1),
 * JSON control messages (cJSON) and binary frames decoded by the project's
 * own decoder (proto/c). The steps run in order: hello -> set (if any) ->
 * subscribe (if frames are wanted) -> frames / watch. See usage() for the
 * exit codes a script can rely on. */
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <getopt.h>
#include <libwebsockets.h>
#include <malloc.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

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
    EXIT_INTERRUPTED = 130, /* Ctrl-C before the first frame / answer (shell convention) */
};

#define MAX_SETS 64
#define ID_SET 1
#define ID_SUBSCRIBE 2
#define ID_QUIET 3     /* watch only: the smallest subscription there is */
#define ID_QUERY 4
#define ID_PROBE 5
#define ID_RENDER 6
/* The `render` request (exact-time frames for bakes, PROTOCOL.md §7.5): its
 * frames carry this bit in the frame header's flags and their index k in
 * seq; sim_time = start + k / fps. */
#define RENDER_FRAME_FLAG 1u
#define WRITER_QUEUE 4                      /* complete frames waiting for the file writer, at most */
#define WRITER_BYTES ((size_t)256 << 20)    /* ... and their copies' bytes, at most (one frame always) */
#define MAX_POINTS 256 /* of --query / --probe (the server caps probes lower) */
#define RX_CHUNK (1 << 16) /* bytes of a message lws hands over at a time, and of one socket read */

static void usage(FILE *to)
{
    fprintf(to,
        "usage: ocean-tap URL [options]\n"
        "  URL                 ws://host:port[/path] of an oceand server (wss:// for TLS)\n"
        "Frames:\n"
        "  --frames N          receive N complete frames, then exit (0 = until Ctrl-C,\n"
        "                      the default when only --out or --stats is given)\n"
        "  --fields LIST       comma-separated: height,dx,dz,slope_x,slope_z,jacobian\n"
        "                      (default height,dx,dz)\n"
        "  --lod L             level of detail 0..4: fields are (N/2^L)^2 samples (default 0)\n"
        "  --bound B           max abs error of the lossy codec, one of the server's bounds;\n"
        "                      0 = lossless float32 (default: the server's, 0.01)\n"
        "  --max-rate HZ       at most HZ frames per second\n"
        "  --intra             intra-only frames (each decodable alone); default: the\n"
        "                      temporal codec (codec 3, ~2.5x fewer bytes), which needs\n"
        "                      every frame in order (a gap is resynchronised by itself)\n"
        "  --out DIR           write every frame, one file per field: DIR/<field>-<seq>.<ext>\n"
        "  --format F          npy (default; numpy.load), raw (float32), pgm (16-bit\n"
        "                      greyscale, min..max), pgm8 (8-bit); each file gets a .json\n"
        "                      sidecar with seq, sim_time and params_version.\n"
        "                      exr: a Blender ocean-modifier bake, DIR/disp_NNNN.exr,\n"
        "                      normal_NNNN.exr, foam_NNNN.exr (+ frame_NNNN.json), frames\n"
        "                      numbered 1, 2, ...; subscribes to all six fields\n"
        "Cascades (PROTOCOL.md §4.1; the default sea has 3, and the whole sea is their sum):\n"
        "  --cascades K|all    also receive the finer cascades 1..K-1 (all: every one the\n"
        "                      server runs) with the same fields, at lod max(--lod, 1) (a finer\n"
        "                      cascade loses nothing at lod 1) and bound 0.001 (0 with --bound 0);\n"
        "                      files DIR/<field>-c<k>-<seq>.<ext>, sidecar patch_size = its L_k.\n"
        "                      Without it: cascade 0 only, 1-3 cm of height off the sea\n"
        "  --sum M             also write the sum of the cascades of height, dx, dz, slope_x,\n"
        "                      slope_z on an M x M grid: DIR/<field>-sum-<seq>.<ext>; with\n"
        "                      --format exr the bake is that sum (default M: N >> lod)\n"
        "  --sum-area X,Z,S    the grid's square: origin (X, Z), side S metres (default\n"
        "                      0,0,patch_size); point [j][i] at (X + i*S/M, Z + j*S/M)\n"
        "  --interp I          between grid nodes: spectral (default; exact signal on a 4x\n"
        "                      finer grid, then cubic: ~0.1 mm from query) or bilinear (on\n"
        "                      the streamed grids: ~14 mm rms off; docs/query.md)\n"
        "Exact-time bakes (the render request, PROTOCOL.md §7.5; an older daemon answers\n"
        "unknown_type, a busy one busy: exit 4):\n"
        "  --bake --fps F --start T --frames K   frames at sim times T + k/F, k = 0..K-1,\n"
        "                      rendered by the server for the parameters in force, every\n"
        "                      one, in order; written like --out/--format (EXR frame k+1)\n"
        "  --stats             print frames/s, bytes and latency (each second to stderr,\n"
        "                      summary on stdout at exit)\n"
        "Control:\n"
        "  --set NAME=VALUE    change a sea parameter (repeatable, applied together);\n"
        "                      waits for the server's answer, prints the new params_version\n"
        "  --token T           control token, when the server requires one\n"
        "  --watch             print every params broadcast, one JSON line each (without\n"
        "                      --frames/--out/--stats it subscribes to almost nothing)\n"
        "Points (PROTOCOL.md §7.4):\n"
        "  --query \"X,Z;X,Z...\"  exact surface values at these world points (metres):\n"
        "                      prints the server's query_result as one JSON line\n"
        "  --time T            ... at sim time T (within the server's window; default now)\n"
        "  --probe \"X,Z;X,Z...\"  the probe values of these points with every tick: one\n"
        "                      JSON line (probe_data) per tick, or CSV with --csv\n"
        "  --csv               --probe as CSV, a header row then one row per point and tick:\n"
        "                      seq,sim_time,params_version,point,x,z,height,\n"
        "                      dx,dz,nx,ny,nz,vertical_velocity,vertical_acceleration\n"
        "  --ticks N           stop after N probe ticks (default: until Ctrl-C)\n"
        "Other:\n"
        "  --timeout S         give up after S seconds without an expected answer or, with\n"
        "                      --frames N, a complete frame at the asked LOD (default 10)\n"
        "  -v, --verbose       libwebsockets notices on stderr\n"
        "  -h, --help          this text\n"
        "Without --frames/--out/--stats/--set/--watch, prints the server's hello as JSON.\n"
        "Exit codes: 0 ok, 1 usage, 2 connect failed, 3 protocol error,\n"
        "  4 server rejected the request (its error code is printed), 5 output write failed,\n"
        "  6 timeout, 7 connection closed by the server, 130 interrupted before the\n"
        "  stream started (Ctrl-C during a stream or --watch exits 0).\n");
}

/* ---- options ------------------------------------------------------------ */

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
};

/* "x,z;x,z;..." -> o->points. */
static int parse_points(const char *text, struct opts *o)
{
    const char *p = text;
    o->npoints = 0;
    while (*p) {
        char *end;
        double x = strtod(p, &end);
        if (end == p || *end != ',') return -1;
        p = end + 1;
        double z = strtod(p, &end);
        if (end == p || (*end && *end != ';') || o->npoints == MAX_POINTS) return -1;
        o->points[o->npoints][0] = x;
        o->points[o->npoints][1] = z;
        o->npoints++;
        p = *end ? end + 1 : end;
    }
    return o->npoints ? 0 : -1;
}

static int parse_fields(const char *list, unsigned *mask)
{
    char buf[256];
    snprintf(buf, sizeof buf, "%s", list);
    *mask = 0;
    for (char *save = NULL, *tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        int f = oc_field_from_name(tok);
        if (f < 0) return -1;
        *mask |= 1u << f;
    }
    return *mask ? 0 : -1;
}

static int usage_error(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("ocean-tap: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputs("\n(ocean-tap --help for usage)\n", stderr);
    va_end(ap);
    return EXIT_USAGE;
}

/* Returns -1 to continue, or an exit code. */
static int parse_args(int argc, char **argv, struct opts *o)
{
    static const struct option longs[] = {
        {"frames", required_argument, 0, 'n'}, {"fields", required_argument, 0, 'f'},
        {"lod", required_argument, 0, 'l'},    {"bound", required_argument, 0, 'b'},
        {"max-rate", required_argument, 0, 'r'}, {"out", required_argument, 0, 'o'},
        {"format", required_argument, 0, 'F'}, {"stats", no_argument, 0, 's'},
        {"set", required_argument, 0, 'S'},   {"token", required_argument, 0, 'T'},
        {"watch", no_argument, 0, 'w'},       {"timeout", required_argument, 0, 't'},
        {"verbose", no_argument, 0, 'v'},     {"help", no_argument, 0, 'h'},
        {"query", required_argument, 0, 'Q'}, {"probe", required_argument, 0, 'P'},
        {"time", required_argument, 0, 'I'},  {"ticks", required_argument, 0, 'K'},
        {"csv", no_argument, 0, 'C'},         {"intra", no_argument, 0, 'A'},
        {"cascades", required_argument, 0, 'c'}, {"sum", required_argument, 0, 'M'},
        {"sum-area", required_argument, 0, 'a'}, {"interp", required_argument, 0, 'i'},
        {"bake", no_argument, 0, 'B'},        {"fps", required_argument, 0, 'p'},
        {"start", required_argument, 0, 'z'},
        {0, 0, 0, 0}};
    *o = (struct opts){.frames = -1, .fields = 7u, .bound = -1, .format = TAP_NPY, .timeout = 10, .cascades = 1};
    int c;
    char *end;
    while ((c = getopt_long(argc, argv, "vh", longs, NULL)) != -1) {
        switch (c) {
        case 'n':
            o->frames = strtol(optarg, &end, 10);
            if (*end || o->frames < 0) return usage_error("--frames needs a count >= 0");
            break;
        case 'f':
            if (parse_fields(optarg, &o->fields)) return usage_error("unknown field in --fields %s", optarg);
            break;
        case 'l':
            o->lod = (int)strtol(optarg, &end, 10);
            if (*end || o->lod < 0 || o->lod > OC_MAX_LOD) return usage_error("--lod must be 0..%d", OC_MAX_LOD);
            break;
        case 'b':
            o->bound = strtod(optarg, &end);
            if (*end || !(o->bound >= 0)) return usage_error("--bound needs a number >= 0");
            break;
        case 'r':
            o->max_rate = (int)strtol(optarg, &end, 10);
            if (*end || o->max_rate <= 0) return usage_error("--max-rate needs a number > 0");
            break;
        case 'A': o->intra = 1; break;
        case 'o': o->out_dir = optarg; break;
        case 'F':
            o->format = tap_format_from_name(optarg);
            if (o->format < 0) return usage_error("--format must be npy, raw, pgm, pgm8 or exr");
            break;
        case 's': o->stats = 1; break;
        case 'S':
            if (!strchr(optarg, '=') || optarg[0] == '=') return usage_error("--set needs NAME=VALUE");
            if (o->nsets == MAX_SETS) return usage_error("too many --set");
            o->sets[o->nsets++] = optarg;
            break;
        case 'T': o->token = optarg; break;
        case 'w': o->watch = 1; break;
        case 't':
            o->timeout = strtod(optarg, &end);
            if (*end || !(o->timeout > 0)) return usage_error("--timeout needs seconds > 0");
            break;
        case 'v': o->verbose = 1; break;
        case 'Q': case 'P':
            if (parse_points(optarg, o)) return usage_error("--%s needs \"X,Z;X,Z...\" (1..%d points)",
                                                            c == 'Q' ? "query" : "probe", MAX_POINTS);
            if (c == 'Q') o->query = 1; else o->probe = 1;
            break;
        case 'I':
            o->time = strtod(optarg, &end);
            if (*end || !*optarg) return usage_error("--time needs seconds of sim time");
            o->has_time = 1;
            break;
        case 'K':
            o->ticks = strtol(optarg, &end, 10);
            if (*end || o->ticks < 0) return usage_error("--ticks needs a count >= 0");
            break;
        case 'C': o->csv = 1; break;
        case 'c':
            if (!strcmp(optarg, "all")) { o->cascades = -1; break; }
            o->cascades = (int)strtol(optarg, &end, 10);
            if (*end || o->cascades < 1 || o->cascades > OC_MAX_CASCADES)
                return usage_error("--cascades needs all or a count 1..%d", OC_MAX_CASCADES);
            break;
        case 'M':
            o->sum_m = (int)strtol(optarg, &end, 10);
            if (*end || o->sum_m < 1 || o->sum_m > 8192) return usage_error("--sum needs a grid side 1..8192");
            break;
        case 'a':
            if (sscanf(optarg, "%lf,%lf,%lf", &o->area[0], &o->area[1], &o->area[2]) != 3 || !(o->area[2] > 0) ||
                !isfinite(o->area[0]) || !isfinite(o->area[1]) || !isfinite(o->area[2]))
                return usage_error("--sum-area needs X,Z,SIZE (metres, SIZE > 0)");
            o->has_area = 1;
            break;
        case 'B': o->bake = 1; break;
        case 'p':
            o->fps = strtod(optarg, &end);
            if (*end || !(o->fps > 0 && o->fps <= 1000)) return usage_error("--fps needs frames per second in (0, 1000]");
            break;
        case 'z':
            o->start = strtod(optarg, &end);
            if (*end || !*optarg || !isfinite(o->start) || o->start < 0)
                return usage_error("--start needs a sim time in seconds >= 0");
            o->has_start = 1;
            break;
        case 'i':
            if (!strcmp(optarg, "bilinear")) o->bilinear = 1;
            else if (strcmp(optarg, "spectral")) return usage_error("--interp must be spectral or bilinear");
            break;
        case 'h': usage(stdout); return EXIT_OK;
        default: return usage_error("unknown option");
        }
    }
    /* The bake needs the six fields it writes from; not foam (its foam is 1 - jacobian). */
    if (o->format == TAP_EXR) o->fields = ((1u << OC_FIELD_COUNT) - 1u) & ~(1u << OC_FIELD_FOAM);
    if (o->bake && !(o->fps > 0 && o->has_start && o->frames > 0 && o->out_dir))
        return usage_error("--bake needs --fps F, --start T, --frames K and --out DIR");
    if (!o->bake && (o->fps > 0 || o->has_start)) return usage_error("--fps and --start are for --bake");
    if (o->bake && (o->max_rate || o->stats || o->watch))
        return usage_error("--bake does not mix with --max-rate, --stats or --watch");
    if ((o->sum_m || o->has_area) && o->cascades == 1)
        return usage_error("--sum/--sum-area add up cascades: give --cascades too");
    if (o->has_area && !o->sum_m) o->sum_m = -1;
    /* Cascade 0 holds waves up to its Nyquist: its LOD 1+ grids alias them, and no
     * interpolation between their nodes can give them back. */
    if (o->sum_m && o->lod > 0 && (o->has_area || o->sum_m > 0))
        fprintf(stderr, "ocean-tap: warning: with --lod %d cascade 0's short waves are aliased: the sum is "
                        "right only at the nodes of its LOD grid (use --lod 0 for other grids)\n", o->lod);
    if (o->format == TAP_EXR && o->cascades != 1 && !o->sum_m) o->sum_m = -1; /* a bake of the whole sea */
    if (o->query && o->probe) return usage_error("--query and --probe: one at a time");
    if ((o->query || o->probe) && (o->frames >= 0 || o->out_dir || o->stats || o->watch))
        return usage_error("--query/--probe do not mix with frames (--frames/--out/--stats) or --watch");
    if (o->has_time && !o->query) return usage_error("--time is for --query");
    if (optind != argc - 1) return usage_error(optind >= argc ? "missing URL" : "one URL only");
    if (strlen(argv[optind]) >= sizeof o->url - 8) return usage_error("URL too long");
    snprintf(o->url, sizeof o->url, "%s%s", strstr(argv[optind], "://") ? "" : "ws://", argv[optind]);
    return -1;
}

/* ---- session state ------------------------------------------------------ */

struct job;

enum stage { ST_HELLO, ST_SET, ST_SUBSCRIBE, ST_QUERY, ST_PROBE, ST_RENDER, ST_RUN, ST_DONE };

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
};

static volatile sig_atomic_t interrupted;
static struct lws_context *g_ctx;

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double wall_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return ts.tv_sec * 1e6 + ts.tv_nsec * 1e-3;
}

static void finish(struct session *s, int code)
{
    if (s->stage == ST_DONE) return;
    s->stage = ST_DONE;
    s->exit_code = code;
}

/* Report the first failure only: later ones are its consequences. */
static void fail(struct session *s, int code, const char *fmt, ...)
{
    if (s->stage == ST_DONE) return;
    va_list ap;
    va_start(ap, fmt);
    fputs("ocean-tap: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    finish(s, code);
}

/* Queue a JSON message (takes ownership of j) and ask lws for a write slot. */
static void send_json(struct session *s, cJSON *j)
{
    char *text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
    if (!text || s->noutq == (int)(sizeof s->outq / sizeof s->outq[0])) {
        free(text);
        fail(s, EXIT_PROTOCOL, "out of memory");
        return;
    }
    s->outq[s->noutq++] = text;
    lws_callback_on_writable(s->wsi);
}

/* ---- requests ----------------------------------------------------------- */

static const char *schema_type(struct session *s, const char *name)
{
    cJSON *p;
    cJSON_ArrayForEach(p, s->schema) {
        cJSON *n = cJSON_GetObjectItemCaseSensitive(p, "name");
        if (cJSON_IsString(n) && !strcmp(n->valuestring, name)) {
            cJSON *t = cJSON_GetObjectItemCaseSensitive(p, "type");
            return cJSON_IsString(t) ? t->valuestring : NULL;
        }
    }
    return NULL;
}

/* The JSON value of a --set: typed by the server's schema. A value that does
 * not fit its type is sent as a string, so the server (the one authority on
 * parameters) answers with its documented error code. */
static cJSON *set_value(struct session *s, const char *name, const char *text)
{
    const char *type = schema_type(s, name);
    char *end;
    if (type && !strcmp(type, "bool")) {
        if (!strcmp(text, "true")) return cJSON_CreateTrue();
        if (!strcmp(text, "false")) return cJSON_CreateFalse();
        return cJSON_CreateString(text);
    }
    if (type && !strcmp(type, "enum")) return cJSON_CreateString(text);
    double v = strtod(text, &end);
    if (*text && !*end) return cJSON_CreateNumber(v);
    return cJSON_CreateString(text);
}

static void send_set(struct session *s)
{
    cJSON *j = cJSON_CreateObject(), *params = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "type", "set");
    cJSON_AddNumberToObject(j, "id", ID_SET);
    for (int i = 0; i < s->o->nsets; i++) {
        const char *eq = strchr(s->o->sets[i], '=');
        char name[128];
        snprintf(name, sizeof name, "%.*s", (int)(eq - s->o->sets[i]), s->o->sets[i]);
        cJSON_DeleteItemFromObjectCaseSensitive(params, name); /* last --set of a name wins */
        cJSON_AddItemToObject(params, name, set_value(s, name, eq + 1));
    }
    cJSON_AddItemToObject(j, "params", params);
    if (s->o->token) cJSON_AddStringToObject(j, "token", s->o->token);
    send_json(s, j);
}

/* Fields of the finer cascades: foam is cascade 0's only; a bake sums the
 * finer cascades and takes the Jacobian (which does not add) from cascade 0. */
static unsigned fine_fields(const struct opts *o)
{
    return o->fields & ~(1u << OC_FIELD_FOAM) & (o->format == TAP_EXR ? ~(1u << OC_FIELD_JACOBIAN) : ~0u);
}
static int fine_lod(const struct opts *o) { return o->lod > 1 ? o->lod : 1; }

/* cascade_patch_sizes of a hello or params message into s->patch. */
static void read_patch_sizes(struct session *s, cJSON *msg)
{
    cJSON *ps = cJSON_GetObjectItemCaseSensitive(msg, "cascade_patch_sizes"), *v;
    int c = 0;
    cJSON_ArrayForEach(v, ps) {
        if (c < OC_MAX_CASCADES && cJSON_IsNumber(v)) s->patch[c] = v->valuedouble;
        c++;
    }
}

static void send_subscribe(struct session *s)
{
    cJSON *j = cJSON_CreateObject(), *fields = cJSON_CreateArray();
    int render = s->stage == ST_RENDER;
    cJSON_AddStringToObject(j, "type", render ? "render" : "subscribe");
    cJSON_AddNumberToObject(j, "id", render ? ID_RENDER : ID_SUBSCRIBE);
    if (render) {
        cJSON_AddNumberToObject(j, "start", s->o->start);
        cJSON_AddNumberToObject(j, "fps", s->o->fps);
        cJSON_AddNumberToObject(j, "frames", (double)s->o->frames);
    }
    for (int f = 0; f < OC_FIELD_COUNT; f++)
        if (s->o->fields & (1u << f)) cJSON_AddItemToArray(fields, cJSON_CreateString(oc_field_name(f)));
    cJSON_AddItemToObject(j, "fields", fields);
    cJSON_AddNumberToObject(j, "lod", s->o->lod);
    if (s->o->bound >= 0) cJSON_AddNumberToObject(j, "bound", s->o->bound);
    if (!render) {
        cJSON_AddStringToObject(j, "tiles", "all");
        if (s->o->max_rate > 0) cJSON_AddNumberToObject(j, "max_rate", s->o->max_rate);
        cJSON_AddBoolToObject(j, "temporal", !s->o->intra); /* PROTOCOL.md §5.9 */
    }
    /* The finer cascades (§4.1): same fields but foam (cascade 0's only), at LOD
     * 1 or coarser (they hold nothing LOD 1 drops) and 1 mm, their heights being
     * centimetres; lossless stays lossless. */
    cJSON *casc = s->ncasc > 1 ? cJSON_AddArrayToObject(j, "cascades") : NULL;
    for (int c = 1; c < s->ncasc; c++) {
        cJSON *e = cJSON_CreateObject(), *ef = cJSON_AddArrayToObject(e, "fields");
        for (int f = 0; f < OC_FIELD_COUNT; f++)
            if (fine_fields(s->o) & (1u << f)) cJSON_AddItemToArray(ef, cJSON_CreateString(oc_field_name(f)));
        cJSON_AddNumberToObject(e, "lod", fine_lod(s->o));
        cJSON_AddNumberToObject(e, "bound", s->o->bound == 0 ? 0 : 0.001);
        cJSON_AddItemToArray(casc, e);
    }
    send_json(s, j);
}

/* A watcher wants no frames, but a subscription cannot be empty: ask for one
 * 4x4-sample tile of one field, once a second (about 100 bytes/s). */
static void send_quiet_subscribe(struct session *s)
{
    cJSON *j = cJSON_CreateObject(), *tiles = cJSON_CreateArray(), *t00 = cJSON_CreateArray();
    cJSON_AddStringToObject(j, "type", "subscribe");
    cJSON_AddNumberToObject(j, "id", ID_QUIET);
    cJSON *fields = cJSON_AddArrayToObject(j, "fields");
    cJSON_AddItemToArray(fields, cJSON_CreateString("height"));
    cJSON_AddNumberToObject(j, "lod", OC_MAX_LOD);
    cJSON_AddItemToArray(t00, cJSON_CreateNumber(0));
    cJSON_AddItemToArray(t00, cJSON_CreateNumber(0));
    cJSON_AddItemToArray(tiles, t00);
    cJSON_AddItemToObject(j, "tiles", tiles);
    cJSON_AddNumberToObject(j, "max_rate", 1);
    send_json(s, j);
}

static cJSON *points_json(const struct opts *o)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; i < o->npoints; i++) cJSON_AddItemToArray(a, cJSON_CreateDoubleArray(o->points[i], 2));
    return a;
}

static void send_points(struct session *s, const char *type, int id)
{
    cJSON *j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "type", type);
    cJSON_AddNumberToObject(j, "id", id);
    cJSON_AddItemToObject(j, "points", points_json(s->o));
    if (id == ID_QUERY && s->o->has_time) cJSON_AddNumberToObject(j, "time", s->o->time);
    send_json(s, j);
}

/* One probe_data message: as it came (JSON), or one CSV row per point. */
static void print_probe(struct session *s, cJSON *msg, const char *text, size_t len)
{
    if (!s->o->csv) {
        printf("%.*s\n", (int)len, text);
    } else {
        if (!s->csv_header_done) {
            puts("seq,sim_time,params_version,point,x,z,height,dx,dz,nx,ny,nz,vertical_velocity,vertical_acceleration");
            s->csv_header_done = 1;
        }
        cJSON *seq = cJSON_GetObjectItemCaseSensitive(msg, "seq"), *t = cJSON_GetObjectItemCaseSensitive(msg, "sim_time");
        cJSON *v = cJSON_GetObjectItemCaseSensitive(msg, "params_version"), *pts = cJSON_GetObjectItemCaseSensitive(msg, "points");
        int i = 0;
        cJSON *p, *x;
        cJSON_ArrayForEach(p, pts) {
            if (i >= s->o->npoints) break;
            printf("%.0f,%.17g,%.0f,%d,%.10g,%.10g", cJSON_GetNumberValue(seq), cJSON_GetNumberValue(t),
                   cJSON_GetNumberValue(v), i, s->o->points[i][0], s->o->points[i][1]);
            cJSON_ArrayForEach(x, p) printf(",%.10g", cJSON_GetNumberValue(x));
            putchar('\n');
            i++;
        }
    }
    fflush(stdout);
    if (s->o->ticks > 0 && ++s->ticks_done >= s->o->ticks) finish(s, EXIT_OK);
}

/* Move on from the stage just completed to the next one that applies. */
static void advance(struct session *s)
{
    if (s->stage <= ST_SET && s->o->query) { s->stage = ST_QUERY; send_points(s, "query", ID_QUERY); return; }
    if (s->stage <= ST_SET && s->o->probe) {
        s->stage = ST_PROBE;
        send_quiet_subscribe(s); /* the frames of the default subscription are not wanted */
        send_points(s, "probe", ID_PROBE);
        return;
    }
    if (s->stage == ST_PROBE) { s->stage = ST_RUN; s->st.t0 = s->st.last_report = now_s(); return; }
    if (s->stage == ST_HELLO && s->o->nsets) { s->stage = ST_SET; send_set(s); return; }
    if (s->stage <= ST_SET && s->o->bake) {
        s->stage = ST_RENDER;
        send_quiet_subscribe(s); /* live frames are not wanted while the server renders ours */
        send_subscribe(s);
        return;
    }
    if (s->stage == ST_RENDER) { s->stage = ST_RUN; s->st.t0 = s->st.last_report = s->last_frame = now_s(); return; }
    if (s->stage <= ST_SET && s->want_frames) { s->stage = ST_SUBSCRIBE; send_subscribe(s); return; }
    if (s->stage <= ST_SUBSCRIBE && (s->want_frames || s->o->watch)) {
        s->stage = ST_RUN;
        s->st.t0 = s->st.last_report = s->last_frame = now_s();
        if (!s->want_frames) send_quiet_subscribe(s);
        return;
    }
    finish(s, EXIT_OK);
}

/* ---- incoming messages -------------------------------------------------- */

static int id_is(cJSON *msg, int id)
{
    cJSON *j = cJSON_GetObjectItemCaseSensitive(msg, "id");
    return cJSON_IsNumber(j) && j->valuedouble == id;
}

static void print_error(cJSON *msg, const char *what)
{
    cJSON *code = cJSON_GetObjectItemCaseSensitive(msg, "code");
    cJSON *text = cJSON_GetObjectItemCaseSensitive(msg, "message");
    cJSON *param = cJSON_GetObjectItemCaseSensitive(msg, "param");
    fprintf(stderr, "ocean-tap: %s: error %s%s%s: %s\n", what,
            cJSON_IsString(code) ? code->valuestring : "?",
            cJSON_IsString(param) ? " param=" : "", cJSON_IsString(param) ? param->valuestring : "",
            cJSON_IsString(text) ? text->valuestring : "");
}

static void on_text(struct session *s, const char *text, size_t len)
{
    cJSON *msg = cJSON_ParseWithLength(text, len);
    cJSON *type = cJSON_GetObjectItemCaseSensitive(msg, "type");
    if (!cJSON_IsString(type)) {
        fail(s, EXIT_PROTOCOL, "server sent a control message without a type: %.*s", (int)(len > 200 ? 200 : len), text);
        cJSON_Delete(msg);
        return;
    }
    const char *t = type->valuestring;
    if (!strcmp(t, "hello") && s->stage == ST_HELLO) {
        cJSON *proto = cJSON_GetObjectItemCaseSensitive(msg, "protocol");
        if (!cJSON_IsNumber(proto) || proto->valueint != OC_PROTO_VERSION) {
            fail(s, EXIT_PROTOCOL, "server speaks protocol %d, ocean-tap speaks %d",
                 cJSON_IsNumber(proto) ? proto->valueint : -1, OC_PROTO_VERSION);
        } else {
            s->schema = cJSON_DetachItemFromObjectCaseSensitive(msg, "schema");
            read_patch_sizes(s, msg);
            cJSON *np = cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(msg, "params"), "cascades");
            int have = cJSON_IsNumber(np) && np->valueint >= 1 && np->valueint <= OC_MAX_CASCADES ? np->valueint : 1;
            s->ncasc = s->o->cascades < 0 || s->o->cascades > have ? have : s->o->cascades;
            if (s->o->cascades > have)
                fprintf(stderr, "ocean-tap: the server runs %d cascade%s: receiving %d\n", have, have > 1 ? "s" : "", have);
            for (int c = 1; s->grid && c < s->ncasc; c++)
                oc_grid_want(s->grid, c, fine_fields(s->o), fine_lod(s->o));
            if (!s->o->nsets && !s->want_frames && !s->o->watch && !s->o->query && !s->o->probe) {
                /* Info mode: the hello without the long schema, one line. */
                char *out = cJSON_PrintUnformatted(msg);
                if (out) puts(out);
                free(out);
            }
            advance(s);
        }
    } else if (!strcmp(t, "params")) {
        read_patch_sizes(s, msg);
        if (s->o->watch) {
            char *out = cJSON_PrintUnformatted(msg);
            if (out) { puts(out); fflush(stdout); }
            free(out);
        }
        if (s->stage == ST_SET && id_is(msg, ID_SET)) {
            cJSON *v = cJSON_GetObjectItemCaseSensitive(msg, "params_version");
            cJSON *changed = cJSON_GetObjectItemCaseSensitive(msg, "changed"), *c;
            if (!s->o->watch) {
                printf("params_version=%.0f changed=", cJSON_IsNumber(v) ? v->valuedouble : -1.0);
                int first = 1;
                cJSON_ArrayForEach(c, changed) if (cJSON_IsString(c)) {
                    printf("%s%s", first ? "" : ",", c->valuestring);
                    first = 0;
                }
                putchar('\n');
                fflush(stdout);
            }
            advance(s);
        }
    } else if (!strcmp(t, "subscribed")) {
        if (s->stage == ST_SUBSCRIBE) {
            cJSON *sub = cJSON_GetObjectItemCaseSensitive(msg, "subscription");
            cJSON *lod = cJSON_GetObjectItemCaseSensitive(sub, "lod");
            if (cJSON_IsNumber(lod) && lod->valueint != s->o->lod)
                fail(s, EXIT_PROTOCOL, "server chose lod %d, asked for %d", lod->valueint, s->o->lod);
            else
                advance(s);
        }
    } else if (!strcmp(t, "degraded") && s->want_frames) {
        /* Say why frames stop being written: at a coarser LOD they do not fill our grids. */
        cJSON *active = cJSON_GetObjectItemCaseSensitive(msg, "active"), *lod = cJSON_GetObjectItemCaseSensitive(msg, "lod");
        cJSON *reason = cJSON_GetObjectItemCaseSensitive(msg, "reason");
        s->degraded_lod = cJSON_IsTrue(active) && cJSON_IsNumber(lod) ? lod->valueint : -1;
        if (cJSON_IsTrue(active))
            fprintf(stderr, "ocean-tap: the server serves this subscription degraded (lod %d%s): %s\n",
                    cJSON_IsNumber(lod) ? lod->valueint : -1,
                    cJSON_IsNumber(lod) && lod->valueint != s->o->lod ? ", frames not written until it is back" : "",
                    cJSON_IsString(reason) ? reason->valuestring : "no reason given");
        else
            fprintf(stderr, "ocean-tap: the server serves this subscription in full again\n");
    } else if (!strcmp(t, "query_result") && s->stage == ST_QUERY && id_is(msg, ID_QUERY)) {
        printf("%.*s\n", (int)len, text);
        fflush(stdout);
        finish(s, EXIT_OK);
    } else if (!strcmp(t, "rendering") && s->stage == ST_RENDER && id_is(msg, ID_RENDER)) {
        advance(s);
    } else if (!strcmp(t, "rendered") && s->o->bake && id_is(msg, ID_RENDER)) {
        if (s->frames_done < s->o->frames)
            fail(s, EXIT_PROTOCOL, "the server ended the render after %ld of %ld frames", s->frames_done, s->o->frames);
    } else if (!strcmp(t, "probing") && s->stage == ST_PROBE && id_is(msg, ID_PROBE)) {
        advance(s);
    } else if (!strcmp(t, "probe_data") && s->stage == ST_RUN && s->o->probe) {
        print_probe(s, msg, text, len);
    } else if (!strcmp(t, "error")) {
        if (s->o->bake && id_is(msg, ID_RENDER)) {
            cJSON *code = cJSON_GetObjectItemCaseSensitive(msg, "code");
            print_error(msg, "render rejected");
            if (cJSON_IsString(code) && !strcmp(code->valuestring, "unknown_type"))
                fprintf(stderr, "ocean-tap: this server has no render request (exact-time frames); "
                                "bake from the stream instead: --format exr without --bake\n");
            finish(s, EXIT_REJECTED);
        } else if ((s->stage == ST_QUERY && id_is(msg, ID_QUERY)) || (s->stage == ST_PROBE && id_is(msg, ID_PROBE))) {
            print_error(msg, s->stage == ST_QUERY ? "query rejected" : "probe rejected");
            finish(s, EXIT_REJECTED);
        } else if (s->stage == ST_SET && (id_is(msg, ID_SET) || !cJSON_GetObjectItem(msg, "id"))) {
            print_error(msg, "set rejected");
            finish(s, EXIT_REJECTED);
        } else if (s->stage == ST_SUBSCRIBE && (id_is(msg, ID_SUBSCRIBE) || !cJSON_GetObjectItem(msg, "id"))) {
            print_error(msg, "subscribe rejected");
            finish(s, EXIT_REJECTED);
        } else if (!id_is(msg, ID_QUIET)) { /* a server that refuses the quiet subscription still works */
            print_error(msg, "server");
        }
    }
    /* pong and unknown types: nothing to do (unknown members are ignored by the spec). */
    cJSON_Delete(msg);
}

/* ---- the writer thread ----------------------------------------------------
 * Files are written by a thread of their own, from copies of complete frames,
 * so that the connection is read while a frame is being written: a client that
 * stops reading misses ticks (the server sends the latest frame only). */

struct job {
    struct oc_frame_header fh;
    long number;                  /* 1, 2, ...: the bake's frame number */
    int ncasc;
    double patch[OC_MAX_CASCADES];
    float *data[OC_MAX_CASCADES][OC_FIELD_COUNT];
    int side[OC_MAX_CASCADES][OC_FIELD_COUNT];
    float bound[OC_MAX_CASCADES][OC_FIELD_COUNT];
};

static const float *job_field(const struct job *j, int c, int f, int *side, float *bound)
{
    if (c < 0 || c >= OC_MAX_CASCADES || f < 0 || f >= OC_FIELD_COUNT || !j->data[c][f]) return NULL;
    *side = j->side[c][f];
    *bound = j->bound[c][f];
    return j->data[c][f];
}

static void job_free(struct job *j)
{
    if (!j) return;
    for (int c = 0; c < OC_MAX_CASCADES; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) free(j->data[c][f]);
    free(j);
}

/* The writer's first failure: kept for the main thread, which reports it. */
static void wfail(struct session *s, int code, const char *fmt, ...)
{
    pthread_mutex_lock(&s->wr.mu);
    if (!s->wr.err_code) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(s->wr.err, sizeof s->wr.err, fmt, ap);
        va_end(ap);
        s->wr.err_code = code;
    }
    pthread_mutex_unlock(&s->wr.mu);
}

static int write_frame(struct session *s, const struct job *j);

static void *writer_main(void *arg)
{
    struct session *s = arg;
    pthread_mutex_lock(&s->wr.mu);
    for (;;) {
        while (!s->wr.count && !s->wr.closing) pthread_cond_wait(&s->wr.cv_get, &s->wr.mu);
        if (!s->wr.count) break;
        struct job *j = s->wr.q[s->wr.head];
        s->wr.head = (s->wr.head + 1) % WRITER_QUEUE;
        s->wr.count--;
        int failed = s->wr.err_code != 0;
        pthread_cond_signal(&s->wr.cv_put);
        pthread_mutex_unlock(&s->wr.mu);
        if (!failed) write_frame(s, j); /* after a failure: drain, write nothing more */
        job_free(j);
        pthread_mutex_lock(&s->wr.mu);
    }
    pthread_mutex_unlock(&s->wr.mu);
    return NULL;
}

/* Copy the complete frame in the grids and queue it; waits while the queue is
 * full (its depth keeps the copies under WRITER_BYTES). */
static int writer_put(struct session *s, const struct oc_frame_header *fh)
{
    struct job *j = calloc(1, sizeof *j);
    if (!j) return -1;
    j->fh = *fh;
    j->number = s->frames_done;
    j->ncasc = s->ncasc > 0 ? s->ncasc : 1;
    memcpy(j->patch, s->patch, sizeof j->patch);
    size_t bytes = 0;
    for (int c = 0; c < j->ncasc; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            int side;
            float bound;
            const float *d = oc_grid_field(s->grid, c, f, &side, &bound);
            if (!d) continue;
            size_t n = (size_t)side * side * sizeof(float);
            if (!(j->data[c][f] = malloc(n))) { job_free(j); return -1; }
            memcpy(j->data[c][f], d, n);
            j->side[c][f] = side;
            j->bound[c][f] = bound;
            bytes += n;
        }
    int depth = bytes ? (int)(WRITER_BYTES / bytes) : WRITER_QUEUE;
    depth = depth < 1 ? 1 : depth > WRITER_QUEUE ? WRITER_QUEUE : depth;
    pthread_mutex_lock(&s->wr.mu);
    if (!s->wr.started) {
        if (pthread_create(&s->wr.th, NULL, writer_main, s) != 0) {
            pthread_mutex_unlock(&s->wr.mu);
            job_free(j);
            return -1;
        }
        s->wr.started = 1;
    }
    while (s->wr.count >= depth) pthread_cond_wait(&s->wr.cv_put, &s->wr.mu);
    s->wr.q[(s->wr.head + s->wr.count) % WRITER_QUEUE] = j;
    s->wr.count++;
    pthread_cond_signal(&s->wr.cv_get);
    pthread_mutex_unlock(&s->wr.mu);
    return 0;
}

/* The writer's failure, if any: code (0 = none) and message. */
static int writer_error(struct session *s, char *msg, size_t len)
{
    pthread_mutex_lock(&s->wr.mu);
    int code = s->wr.err_code;
    if (code) snprintf(msg, len, "%s", s->wr.err);
    pthread_mutex_unlock(&s->wr.mu);
    return code;
}

/* Write what is queued, then stop the thread. */
static void writer_close(struct session *s)
{
    pthread_mutex_lock(&s->wr.mu);
    s->wr.closing = 1;
    pthread_cond_signal(&s->wr.cv_get);
    int started = s->wr.started;
    pthread_mutex_unlock(&s->wr.mu);
    if (started) pthread_join(s->wr.th, NULL);
    s->wr.started = 0;
}

/* The --sum grid: side, origin and extent (default: cascade 0's patch). */
struct sum_grid { int m; double x0, z0, size; };

static struct sum_grid sum_geometry(const struct session *s, const struct job *j)
{
    int side = 0;
    float b;
    job_field(j, 0, OC_FIELD_HEIGHT, &side, &b);
    if (!side) side = j->fh.n >> s->o->lod;
    struct sum_grid g = {s->o->sum_m > 0 ? s->o->sum_m : side, 0, 0, j->fh.patch_size};
    if (s->o->has_area) { g.x0 = s->o->area[0]; g.z0 = s->o->area[1]; g.size = s->o->area[2]; }
    return g;
}

/* Field f summed over the received cascades (or cascade 0 alone: only0) on
 * the sum grid, into out (m*m floats). Returns 0, 1 when a cascade lacks the
 * field, -1 on failure. */
static int sum_field(struct session *s, const struct job *j, const struct sum_grid *sg, enum oc_field f,
                     int only0, float *out, float *bound)
{
    struct tap_cascade_grid g[OC_MAX_CASCADES];
    int nc = only0 ? 1 : j->ncasc;
    *bound = 0;
    for (int c = 0; c < nc; c++) {
        float b = 0;
        g[c].data = job_field(j, c, f, &g[c].side, &b);
        g[c].period = c == 0 ? j->fh.patch_size : j->patch[c];
        if (!g[c].data) return 1;
        if (!(g[c].period > 0)) {
            wfail(s, EXIT_PROTOCOL, "the server did not say the patch size of cascade %d", c);
            return -1;
        }
        *bound += b;
    }
    if (!s->wr.surface && !(s->wr.surface = tap_surface_new())) { wfail(s, EXIT_OUTPUT, "out of memory"); return -1; }
    if (tap_surface_grid(s->wr.surface, g, nc, sg->m, sg->x0, sg->z0, sg->size, s->o->bilinear, out) != 0) {
        wfail(s, EXIT_OUTPUT, "out of memory for the %dx%d sum", sg->m, sg->m);
        return -1;
    }
    return 0;
}

/* Room for count fields on the m x m sum grid, kept from frame to frame. */
static float *sum_buffers(struct session *s, int m, int count)
{
    size_t bytes = (size_t)count * m * m * sizeof(float);
    if (bytes <= s->wr.sum_bytes) return s->wr.sum_buf;
    free(s->wr.sum_buf);
    s->wr.sum_buf = malloc(bytes);
    s->wr.sum_bytes = s->wr.sum_buf ? bytes : 0;
    if (!s->wr.sum_buf) wfail(s, EXIT_OUTPUT, "out of memory for the %dx%d sum", m, m);
    return s->wr.sum_buf;
}

/* --format exr: one Blender bake frame (tap_exr.h) from the six fields: cascade
 * 0's grids, or with --cascades the sum of the cascades on the --sum grid. */
static int write_bake(struct session *s, const struct job *j)
{
    const struct oc_frame_header *fh = &j->fh;
    const float *f[OC_FIELD_COUNT];
    int side = 0;
    float bound = 0, b;
    double x0 = 0, z0 = 0, size = fh->patch_size;
    if (s->o->sum_m) {
        struct sum_grid sg = sum_geometry(s, j);
        float *buf = sum_buffers(s, sg.m, 6);
        if (!buf) return -1;
        static const enum oc_field order[6] = {OC_FIELD_HEIGHT, OC_FIELD_DX, OC_FIELD_DZ, OC_FIELD_SLOPE_X,
                                               OC_FIELD_SLOPE_Z, OC_FIELD_JACOBIAN};
        for (int k = 0; k < 6; k++) {
            float *out = buf + (size_t)k * sg.m * sg.m;
            /* The Jacobian does not add across cascades (§4.1): cascade 0's, for the foam. */
            if (sum_field(s, j, &sg, order[k], order[k] == OC_FIELD_JACOBIAN, out, &b) != 0) {
                wfail(s, EXIT_PROTOCOL, "the frame lacks %s", oc_field_name(order[k]));
                return -1;
            }
            f[order[k]] = out;
            bound = b > bound ? b : bound;
        }
        side = sg.m;
        x0 = sg.x0;
        z0 = sg.z0;
        size = sg.size;
    } else {
        for (int i = 0; i < OC_FIELD_COUNT; i++) {
            f[i] = job_field(j, 0, i, &side, &b);
            bound = b > bound ? b : bound;
        }
    }
    struct tap_exr_fields ef = {f[OC_FIELD_HEIGHT], f[OC_FIELD_DX], f[OC_FIELD_DZ],
                                f[OC_FIELD_SLOPE_X], f[OC_FIELD_SLOPE_Z], f[OC_FIELD_JACOBIAN]};
    struct tap_meta m = {.field = "bake", .seq = fh->seq, .sim_time = fh->sim_time,
                         .params_version = fh->params_version, .n = fh->n, .lod = s->o->lod,
                         .patch_size = (float)size, .bound = bound, .server_time_us = fh->server_time_us,
                         .cascade = s->o->sum_m ? TAP_CASCADE_SUM : 0, .origin_x = x0, .origin_z = z0};
    char err[512];
    if (tap_exr_bake(s->o->out_dir, (int)j->number, side, &ef, &m, j->ncasc, err, sizeof err) != 0) {
        wfail(s, EXIT_OUTPUT, "cannot write the bake: %s", err);
        return -1;
    }
    return 0;
}

static int write_one(struct session *s, const char *path, const float *data, int side, const struct tap_meta *m)
{
    if (tap_write_field(s->o->format, path, data, side, m) != 0) {
        wfail(s, EXIT_OUTPUT, "cannot write %s: %s", path, strerror(errno));
        return -1;
    }
    return 0;
}

static int write_frame(struct session *s, const struct job *j)
{
    const struct oc_frame_header *fh = &j->fh;
    if (s->o->format == TAP_EXR) return write_bake(s, j);
    unsigned long long seq = (unsigned long long)fh->seq;
    for (int c = 0; c < j->ncasc; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            int side;
            float bound;
            const float *data = job_field(j, c, f, &side, &bound);
            if (!data) continue;
            char path[4096];
            /* Cascade 0 keeps the names of a one-cascade sea. */
            if (c == 0)
                snprintf(path, sizeof path, "%s/%s-%08llu.%s", s->o->out_dir, oc_field_name(f), seq,
                         tap_format_ext(s->o->format));
            else
                snprintf(path, sizeof path, "%s/%s-c%d-%08llu.%s", s->o->out_dir, oc_field_name(f), c, seq,
                         tap_format_ext(s->o->format));
            struct tap_meta m = {.field = oc_field_name(f), .seq = fh->seq, .sim_time = fh->sim_time,
                                 .params_version = fh->params_version, .n = fh->n,
                                 .lod = c == 0 ? s->o->lod : fine_lod(s->o),
                                 .patch_size = (float)(c == 0 ? fh->patch_size : j->patch[c]), .bound = bound,
                                 .server_time_us = fh->server_time_us, .cascade = c};
            if (write_one(s, path, data, side, &m) != 0) return -1;
        }
    if (!s->o->sum_m) return 0;
    struct sum_grid sg = sum_geometry(s, j);
    float *buf = sum_buffers(s, sg.m, 1);
    if (!buf) return -1;
    static const enum oc_field summed[5] = {OC_FIELD_HEIGHT, OC_FIELD_DX, OC_FIELD_DZ, OC_FIELD_SLOPE_X,
                                            OC_FIELD_SLOPE_Z};
    for (int k = 0; k < 5; k++) {
        float bound;
        int r = sum_field(s, j, &sg, summed[k], 0, buf, &bound);
        if (r < 0) return -1;
        if (r > 0) continue; /* not subscribed */
        char path[4096];
        snprintf(path, sizeof path, "%s/%s-sum-%08llu.%s", s->o->out_dir, oc_field_name(summed[k]), seq,
                 tap_format_ext(s->o->format));
        struct tap_meta m = {.field = oc_field_name(summed[k]), .seq = fh->seq, .sim_time = fh->sim_time,
                             .params_version = fh->params_version, .n = fh->n, .lod = 0,
                             .patch_size = (float)sg.size, .bound = bound, .server_time_us = fh->server_time_us,
                             .cascade = TAP_CASCADE_SUM, .origin_x = sg.x0, .origin_z = sg.z0};
        if (write_one(s, path, buf, sg.m, &m) != 0) return -1;
    }
    return 0;
}

static void report_stats(struct session *s, double t, int final)
{
    struct stats *st = &s->st;
    double dt = t - (final ? st->t0 : st->last_report);
    long frames = final ? s->frames_done : s->frames_done - st->frames_at_report;
    unsigned long long bytes = final ? st->bytes : st->bytes - st->bytes_at_report;
    if (dt <= 0) dt = 1e-9;
    if (final) {
        /* Latency percentiles over all frames (sorted copy). */
        double p50 = 0, p95 = 0, mx = 0;
        if (st->nlat) {
            double *v = st->lat_ms;
            for (size_t i = 1; i < st->nlat; i++) /* insertion sort: counts are small */
                for (size_t k = i; k > 0 && v[k - 1] > v[k]; k--) { double x = v[k]; v[k] = v[k - 1]; v[k - 1] = x; }
            p50 = v[st->nlat / 2];
            p95 = v[(size_t)((st->nlat - 1) * 0.95)];
            mx = v[st->nlat - 1];
        }
        printf("frames=%ld seconds=%.3f fps=%.2f bytes=%llu bytes_per_frame=%.0f mbit_per_s=%.3f "
               "latency_ms_p50=%.2f latency_ms_p95=%.2f latency_ms_max=%.2f\n",
               frames, dt, frames / dt, bytes, frames ? (double)bytes / frames : 0.0,
               bytes * 8 / dt / 1e6, p50, p95, mx);
        fflush(stdout);
    } else {
        fprintf(stderr, "ocean-tap: %ld frames, %.1f fps, %.3f Mbit/s\n", s->frames_done,
                frames / dt, bytes * 8 / dt / 1e6);
        st->last_report = t;
        st->frames_at_report = s->frames_done;
        st->bytes_at_report = st->bytes;
    }
}

static void on_binary(struct session *s, const uint8_t *data, size_t len)
{
    if (s->stage != ST_RUN || !s->want_frames) return; /* frames of the default subscription */
    struct oc_frame_header fh;
    if (s->o->bake) {
        /* Only the rendered frames, every one, in order, at exactly start + k/fps. */
        if (len < 40 || !((data[38] | data[39] << 8) & RENDER_FRAME_FLAG)) return;
    }
    int r = oc_grid_add(s->grid, data, len, &fh);
    if (r == OC_E_REFERENCE) {
        /* A predicted frame whose references we lack (we missed one): subscribing
         * again makes the server send keyframes next (PROTOCOL.md §5.9). Once a
         * second at most: frames already on their way fail the same way. */
        double t = now_s();
        if (t - s->resync_t >= 1.0) {
            s->resync_t = t;
            fprintf(stderr, "ocean-tap: frame %llu lacks its references: resubscribing\n",
                    (unsigned long long)fh.seq);
            send_subscribe(s);
        }
        return;
    }
    if (r) {
        fail(s, EXIT_PROTOCOL, "bad binary frame (%zu bytes): %s", len, oc_strerror(r));
        return;
    }
    if (s->o->bake) {
        double want = s->o->start + (double)s->frames_done / s->o->fps;
        if (fh.seq != (uint64_t)s->frames_done || !oc_grid_complete(s->grid) || fabs(fh.sim_time - want) > 1e-6) {
            fail(s, EXIT_PROTOCOL, "render frame %llu at sim time %.9f: expected frame %ld, complete, at %.9f",
                 (unsigned long long)fh.seq, fh.sim_time, s->frames_done, want);
            return;
        }
    }
    if (!oc_grid_complete(s->grid)) return; /* not every tile of every field at our LOD (degraded, or before
                                                  the subscription took effect): nothing new to write */
    s->frames_done++;
    s->last_frame = now_s();
    s->st.bytes += len;
    if (s->st.nlat == s->st.caplat) {
        size_t cap = s->st.caplat ? 2 * s->st.caplat : 256;
        double *p = realloc(s->st.lat_ms, cap * sizeof *p);
        if (p) { s->st.lat_ms = p; s->st.caplat = cap; }
    }
    if (s->st.nlat < s->st.caplat) s->st.lat_ms[s->st.nlat++] = (wall_us() - (double)fh.server_time_us) / 1e3;
    if (s->o->out_dir && writer_put(s, &fh) != 0) {
        fail(s, EXIT_OUTPUT, "out of memory for a frame's copy");
        return;
    }
    if (s->o->frames > 0 && s->frames_done >= s->o->frames) finish(s, EXIT_OK);
}

/* ---- libwebsockets ------------------------------------------------------ */

static int callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    struct session *s = lws_context_user(lws_get_context(wsi));
    switch (reason) {
    case LWS_CALLBACK_CLIENT_CONNECTION_ERROR:
        fail(s, EXIT_CONNECT, "cannot connect to %s: %s", s->o->url, in ? (const char *)in : "unknown error");
        s->wsi = NULL;
        break;
    case LWS_CALLBACK_CLIENT_ESTABLISHED:
        s->last_activity = now_s();
        break;
    case LWS_CALLBACK_CLIENT_RECEIVE:
        s->last_activity = now_s();
        if (lws_is_first_fragment(wsi)) s->msg.len = 0;
        if (oc_buf_reserve(&s->msg, len) != 0) { fail(s, EXIT_PROTOCOL, "out of memory"); break; }
        memcpy(s->msg.data + s->msg.len, in, len);
        s->msg.len += len;
        if (!lws_is_final_fragment(wsi)) break;
        if (lws_frame_is_binary(wsi)) on_binary(s, s->msg.data, s->msg.len);
        else on_text(s, (const char *)s->msg.data, s->msg.len);
        break;
    case LWS_CALLBACK_CLIENT_WRITEABLE:
        if (s->noutq) {
            char *text = s->outq[0];
            size_t n = strlen(text);
            unsigned char *buf = malloc(LWS_PRE + n);
            if (!buf) { fail(s, EXIT_PROTOCOL, "out of memory"); break; }
            memcpy(buf + LWS_PRE, text, n);
            int w = lws_write(wsi, buf + LWS_PRE, n, LWS_WRITE_TEXT);
            free(buf);
            free(text);
            memmove(s->outq, s->outq + 1, (size_t)--s->noutq * sizeof s->outq[0]);
            if (w < (int)n) { fail(s, EXIT_CLOSED, "write to server failed"); return -1; }
            if (s->noutq) lws_callback_on_writable(wsi);
        }
        break;
    case LWS_CALLBACK_WS_PEER_INITIATED_CLOSE:
        if (s->stage != ST_DONE) {
            int code = len >= 2 ? ((const unsigned char *)in)[0] << 8 | ((const unsigned char *)in)[1] : 0;
            fail(s, EXIT_CLOSED, "server closed the connection (code %d%s%.*s)", code,
                 len > 2 ? ": " : "", (int)(len > 2 ? len - 2 : 0), (const char *)in + 2);
        }
        break;
    case LWS_CALLBACK_CLIENT_CLOSED:
        if (s->stage != ST_DONE) fail(s, EXIT_CLOSED, "connection closed by the server");
        s->wsi = NULL;
        break;
    default:
        break;
    }
    return 0;
}

static void on_signal(int sig)
{
    (void)sig;
    interrupted = 1;
    if (g_ctx) lws_cancel_service(g_ctx);
}

/* Wakes the service loop ten times a second to check timeouts and signals. */
static lws_sorted_usec_list_t tick_sul;
static void tick(lws_sorted_usec_list_t *sul)
{
    lws_sul_schedule(g_ctx, 0, sul, tick, 100 * LWS_US_PER_MS);
}

static int connect_server(struct session *s, struct lws_context *ctx)
{
    char url[sizeof s->o->url], path[sizeof s->o->url + 1];
    const char *scheme, *host, *p;
    int port;
    snprintf(url, sizeof url, "%s", s->o->url);
    if (lws_parse_uri(url, &scheme, &host, &port, &p) || !*host) {
        fprintf(stderr, "ocean-tap: cannot parse URL %s\n", s->o->url);
        return EXIT_USAGE;
    }
    int tls = !strcmp(scheme, "wss") || !strcmp(scheme, "https");
    if (!tls && strcmp(scheme, "ws") && strcmp(scheme, "http")) {
        fprintf(stderr, "ocean-tap: URL must start with ws:// or wss://\n");
        return EXIT_USAGE;
    }
    snprintf(path, sizeof path, "/%s", p);
    struct lws_client_connect_info ci = {
        .context = ctx, .address = host, .port = port, .path = path, .host = host,
        .origin = host, .protocol = OC_SUBPROTOCOL, .ssl_connection = tls ? LCCSCF_USE_SSL : 0,
        .ietf_version_or_minus_one = -1, .pwsi = &s->wsi,
    };
    if (!lws_client_connect_via_info(&ci) && s->stage != ST_DONE) {
        fprintf(stderr, "ocean-tap: cannot connect to %s\n", s->o->url);
        return EXIT_CONNECT;
    }
    return s->stage == ST_DONE ? s->exit_code : -1;
}

int main(int argc, char **argv)
{
    struct opts o;
    int r = parse_args(argc, argv, &o);
    if (r >= 0) return r;
    /* A frame's copies, sums and images are megabytes, freed and made again
     * every frame: from the heap, not each a fresh mapping the kernel zeroes. */
    mallopt(M_MMAP_THRESHOLD, 32 << 20);
    mallopt(M_TRIM_THRESHOLD, 64 << 20);
    struct session s = {.o = &o, .degraded_lod = -1};
    pthread_mutex_init(&s.wr.mu, NULL);
    pthread_cond_init(&s.wr.cv_put, NULL);
    pthread_cond_init(&s.wr.cv_get, NULL);
    s.want_frames = o.frames >= 0 || o.out_dir || o.stats;
    if (o.frames < 0) o.frames = 0;
    if (o.out_dir) {
        if (mkdir(o.out_dir, 0777) != 0 && errno != EEXIST) {
            fprintf(stderr, "ocean-tap: cannot create %s: %s\n", o.out_dir, strerror(errno));
            return EXIT_OUTPUT;
        }
    }
    if (s.want_frames && !(s.grid = oc_grid_new(o.fields, o.lod))) {
        fprintf(stderr, "ocean-tap: out of memory\n");
        return EXIT_PROTOCOL;
    }

    lws_set_log_level(o.verbose ? LLL_ERR | LLL_WARN | LLL_NOTICE : LLL_ERR, NULL);
    static const struct lws_protocols protocols[] = {
        {OC_SUBPROTOCOL, callback, 0, RX_CHUNK, 0, NULL, 0}, {NULL, NULL, 0, 0, 0, NULL, 0}};
    /* pt_serv_buf_size: what one read of the socket takes. lws's default, 4 KB,
     * costs a poll and a read per 4 KB of a bake's megabytes a frame. */
    /* TLS (and its certificate store, tens of milliseconds to load) only for wss:// and https:// */
    int tls = !strncmp(o.url, "wss:", 4) || !strncmp(o.url, "https:", 6);
    struct lws_context_creation_info info = {
        .port = CONTEXT_PORT_NO_LISTEN, .protocols = protocols, .gid = (gid_t)-1, .uid = (uid_t)-1,
        .options = tls ? LWS_SERVER_OPTION_DO_SSL_GLOBAL_INIT : 0, .user = &s, .pt_serv_buf_size = RX_CHUNK,
    };
    struct lws_context *ctx = lws_create_context(&info);
    if (!ctx) {
        fprintf(stderr, "ocean-tap: cannot create the libwebsockets context\n");
        return EXIT_CONNECT;
    }
    g_ctx = ctx;
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    tick(&tick_sul);

    s.last_activity = now_s();
    r = connect_server(&s, ctx);
    while (r < 0 && s.stage != ST_DONE) {
        lws_service(ctx, 100);
        double t = now_s();
        char werr[600];
        int wcode = writer_error(&s, werr, sizeof werr);
        if (wcode) {
            fail(&s, wcode, "%s", werr);
            break;
        }
        if (interrupted) {
            /* Ctrl-C ends a stream or watch normally; anything else is cut short. */
            finish(&s, s.stage == ST_RUN ? EXIT_OK : EXIT_INTERRUPTED);
            break;
        }
        if (o.stats && s.stage == ST_RUN && t - s.st.last_report >= 1.0) report_stats(&s, t, 0);
        /* A pure watch may be silent for ever; everything else expects traffic. */
        int expecting = s.stage != ST_RUN || s.want_frames || o.probe;
        /* With --frames N, receiving frames we cannot write (a coarser LOD while degraded)
         * is no progress; an open-ended recording waits for the server to serve it again. */
        int counting = s.stage == ST_RUN && s.want_frames && o.frames > 0;
        double since = counting ? t - s.last_frame : t - s.last_activity;
        if (expecting && since > o.timeout) {
            const char *what = s.stage == ST_HELLO ? "the server's hello"
                             : s.stage == ST_SET ? "the answer to set"
                             : s.stage == ST_SUBSCRIBE ? "the answer to subscribe"
                             : s.stage == ST_QUERY ? "the answer to query"
                             : s.stage == ST_PROBE ? "the answer to probe"
                             : s.stage == ST_RENDER ? "the answer to render"
                             : o.probe ? "the next probe tick" : "the next complete frame";
            if (counting && s.degraded_lod >= 0 && s.degraded_lod != o.lod)
                fail(&s, EXIT_TIMEOUT, "timed out after %.1f s waiting for %s: the server serves this "
                     "subscription at lod %d, not the lod %d asked for (--timeout for longer, or ask for lod %d)",
                     o.timeout, what, s.degraded_lod, o.lod, s.degraded_lod);
            else
                fail(&s, EXIT_TIMEOUT, "timed out after %.1f s waiting for %s", o.timeout, what);
        }
    }
    if (r < 0) r = s.exit_code;
    /* The frames still queued are written before the exit code is known. */
    writer_close(&s);
    char werr[600];
    int wcode = writer_error(&s, werr, sizeof werr);
    if (wcode && (r == EXIT_OK || r == EXIT_INTERRUPTED)) {
        fprintf(stderr, "ocean-tap: %s\n", werr);
        r = wcode;
    }
    if (o.stats && s.want_frames && s.st.t0 > 0) report_stats(&s, now_s(), 1);

    lws_sul_cancel(&tick_sul);
    lws_context_destroy(ctx);
    g_ctx = NULL;
    for (int i = 0; i < s.noutq; i++) free(s.outq[i]);
    cJSON_Delete(s.schema);
    oc_buf_free(&s.msg);
    oc_grid_free(s.grid);
    tap_surface_free(s.wr.surface);
    free(s.wr.sum_buf);
    pthread_mutex_destroy(&s.wr.mu);
    pthread_cond_destroy(&s.wr.cv_put);
    pthread_cond_destroy(&s.wr.cv_get);
    free(s.st.lat_ms);
    return r;
}

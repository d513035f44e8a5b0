/* ocean-tap — a command-line client of oceand for scripts and pipelines.
 *
 *   ocean-tap ws://host:8080 --frames 100 --fields height,dx,dz --lod 1 \
 *             --bound 0.001 --out DIR --format npy|raw|pgm|pgm8|exr
 *   ocean-tap ws://host:8080 --set wind_speed=20 --set spectrum=jonswap
 *   ocean-tap ws://host:8080 --watch
 *   ocean-tap ws://host:8080 --probe "10,20;-5,3.5" --ticks 300
 *   ocean-tap ws://host:8080 --query "10,20;1e6,-3" [--time T]
 *   ocean-tap ws://host:8080 --launch boat --at 10,-20 --throttle 0.5 --follow
 *   ocean-tap sea SOURCE --print          (a measured sea: tap_sea.c)
 *
 * One WebSocket connection (libwebsockets client, subprotocol oceand.v1),
 * JSON control messages (cJSON) and binary frames decoded by the project's
 * own decoder (proto/c). The steps run in order: hello -> set (if any) ->
 * subscribe (if frames are wanted) -> frames / watch. See usage() for the
 * exit codes a script can rely on. This file: options and the main loop;
 * tap.h says where the rest is. */
#include <cjson/cJSON.h>
#include <errno.h>
#include <getopt.h>
#include <malloc.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "tap.h"

void usage(FILE *to)
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
        "Floating bodies (PROTOCOL.md §3.5, §7.6; tap_body.c):\n"
        "  --launch KIND       launch a body (a name of hello's body_kinds: spar, ball, dinghy,\n"
        "                      boat, ship) at --at X,Z (m; north = +z, east = -x), bow toward\n"
        "                      --heading DEG (clockwise from north, default 0); prints\n"
        "                      {\"launched\":ID,\"resume\":KEY,\"owner\":CLIENT_ID} (stderr with --csv)\n"
        "  --body ID           act on body ID: with --resume KEY claim it back (within the\n"
        "                      grace); without, steer it (only its owner may: exit 4 not_owner)\n"
        "                      or --follow it\n"
        "  --throttle T        -1 (astern) .. 1 (full ahead), once the body is ours\n"
        "  --rudder R          -1 (full to port) .. 1 (full to starboard)\n"
        "  --follow            one line per tick from the frame header's records: JSON, or with\n"
        "                      --csv seq,sim_time,id,x,y,z,heading,pitch,roll,speed (degrees,\n"
        "                      heading compass, pitch bow up +, roll port up +; speed m/s\n"
        "                      horizontal); --ticks N stops after N ticks, else Ctrl-C\n"
        "  --keep              leave our body on the sea at the end (default: it is removed)\n"
        "  --bodies            print the bodies now (hello), one JSON line each, and exit\n"
        "Other:\n"
        "  --timeout S         give up after S seconds without an expected answer or, with\n"
        "                      --frames N, a complete frame at the asked LOD (default 10)\n"
        "  -v, --verbose       libwebsockets notices on stderr\n"
        "  -h, --help          this text\n"
        "Without --frames/--out/--stats/--set/--watch, prints the server's hello as JSON.\n"
        "Measured seas: ocean-tap sea SOURCE --print (NDBC, CDIP, WAVEWATCH III; ocean-tap sea --help)\n"
        "Exit codes: 0 ok, 1 usage, 2 connect failed, 3 protocol error,\n"
        "  4 server rejected the request (its error code is printed), 5 output write failed,\n"
        "  6 timeout, 7 connection closed by the server, 130 interrupted before the\n"
        "  stream started (Ctrl-C during a stream or --watch exits 0); ocean-tap sea: 8, the\n"
        "  source is unreadable or not a valid sea; 9 the followed body left the sea (sunk,\n"
        "  abandoned).\n");
}

/* ---- options ------------------------------------------------------------ */

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

int usage_error(const char *fmt, ...)
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
        {"launch", required_argument, 0, 1000}, {"at", required_argument, 0, 1001},
        {"heading", required_argument, 0, 1002}, {"throttle", required_argument, 0, 1003},
        {"rudder", required_argument, 0, 1004}, {"body", required_argument, 0, 1005},
        {"resume", required_argument, 0, 1006}, {"follow", no_argument, 0, 1007},
        {"bodies", no_argument, 0, 1008},     {"keep", no_argument, 0, 1009},
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
        case 1000: o->launch_kind = optarg; break;
        case 1001:
            if (sscanf(optarg, "%lf,%lf%c", &o->at[0], &o->at[1], &(char){0}) != 2 ||
                !isfinite(o->at[0]) || !isfinite(o->at[1]))
                return usage_error("--at needs X,Z (metres)");
            o->has_at = 1;
            break;
        case 1002:
            o->heading = strtod(optarg, &end);
            if (*end || !*optarg || !isfinite(o->heading)) return usage_error("--heading needs degrees");
            break;
        case 1003: case 1004: {
            double v = strtod(optarg, &end);
            if (*end || !*optarg || !(v >= -1 && v <= 1))
                return usage_error("--%s needs a number in -1..1", c == 1003 ? "throttle" : "rudder");
            if (c == 1003) { o->throttle = v; o->has_throttle = 1; } else { o->rudder = v; o->has_rudder = 1; }
            break;
        }
        case 1005:
            o->body = strtoul(optarg, &end, 10);
            if (*end || !*optarg || o->body < 1 || o->body > 0xffffffffUL) return usage_error("--body needs an id >= 1");
            break;
        case 1006: o->resume = optarg; break;
        case 1007: o->follow = 1; break;
        case 1008: o->list_bodies = 1; break;
        case 1009: o->keep = 1; break;
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
    if (o->launch_kind && o->body) return usage_error("--launch or --body: one at a time");
    if (o->launch_kind && !o->has_at) return usage_error("--launch needs --at X,Z");
    if (!o->launch_kind && (o->has_at || o->heading != 0)) return usage_error("--at and --heading are for --launch");
    if (o->resume && !o->body) return usage_error("--resume needs --body ID");
    if (!o->launch_kind && !o->body && (o->has_throttle || o->has_rudder || o->follow || o->keep))
        return usage_error("--throttle, --rudder, --follow and --keep need --launch or --body");
    if (o->list_bodies && (o->launch_kind || o->body)) return usage_error("--bodies lists: no --launch or --body");
    if (body_mode(o) && (o->query || o->probe || o->frames >= 0 || o->out_dir || o->stats || o->watch || o->bake))
        return usage_error("the body options do not mix with frames, --query/--probe, --watch or --bake");
    if (optind != argc - 1) return usage_error(optind >= argc ? "missing URL" : "one URL only");
    if (strlen(argv[optind]) >= sizeof o->url - 8) return usage_error("URL too long");
    snprintf(o->url, sizeof o->url, "%s%s", strstr(argv[optind], "://") ? "" : "ws://", argv[optind]);
    return -1;
}

/* ---- session state ------------------------------------------------------ */

int main(int argc, char **argv)
{
    /* Verbs other than the stream's: `ocean-tap sea SOURCE ...` (tap_sea.c). */
    if (argc >= 2 && !strcmp(argv[1], "sea")) return tap_sea_main(argc - 1, argv + 1);
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
        if (interrupted && body_interrupt(&s)) {
            interrupted = 0; /* our body is being removed: a second Ctrl-C cuts it short */
            continue;
        }
        if (interrupted) {
            /* Ctrl-C ends a stream or watch normally; anything else is cut short. */
            finish(&s, s.stage == ST_RUN ? EXIT_OK : EXIT_INTERRUPTED);
            break;
        }
        if (o.stats && s.stage == ST_RUN && t - s.st.last_report >= 1.0) report_stats(&s, t, 0);
        /* A pure watch may be silent for ever; everything else expects traffic. */
        int expecting = s.stage != ST_RUN || s.want_frames || o.probe || o.follow;
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
                             : s.stage == ST_BODY ? (o.launch_kind ? "the answer to launch" : "the answer to claim")
                             : s.stage == ST_STEER ? "the answer to steer"
                             : s.stage == ST_REMOVE ? "the answer to remove"
                             : o.follow ? "the body's next record"
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

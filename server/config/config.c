/* config.c — defaults <- saved state <- --config FILE <- CLI flags (see config.h). */
#include "config.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "control.h"
#include "fileio.h"
#include "log.h"
#include "state.h"

/* The daemon's own options: rows of the same shape as the sea parameters'
 * table (server/sim/params.c), checked by the same setters, with offsets into
 * struct daemon_config. All are read at start-up only (PARAM_RESTART). */
#define OPT(name_, type_, field_, min_, max_, def_, choices_, flags_, help_)                          \
    { .name = name_, .type = type_, .unit = "", .min = min_, .max = max_, .def = def_,                \
      .choices = choices_, .description = help_, .offset = offsetof(struct daemon_config, field_),   \
      .flags = (flags_) | PARAM_RESTART }
#define OPT_STR(name_, field_, def_, flags_, help_)                                                   \
    { .name = name_, .type = PARAM_STRING, .unit = "", .description = help_,                         \
      .offset = offsetof(struct daemon_config, field_), .flags = (flags_) | PARAM_RESTART,           \
      .size = sizeof(((struct daemon_config *)0)->field_), .def_text = def_ }
static const struct param_def opt_table[] = {
    OPT("port", PARAM_INT, port, 0, 65535, 8080, NULL, 0, "TCP port for HTTP and WebSocket (0 = any free port)"),
    OPT_STR("bind", bind, "127.0.0.1", 0, "address to listen on (0.0.0.0 = all interfaces)"),
    OPT_STR("web_root", web_root, "build/web", 0, "directory served at / (the web client)"),
    OPT("tick_rate", PARAM_FLOAT, tick_rate, 1, 240, 30, NULL, 0, "simulation steps per second"),
    OPT("log_level", PARAM_ENUM, log_level, 0, 3, OLOG_INFO, log_level_names, 0, "error, warn, info or debug"),
    OPT_STR("state_file", state_file, "", 0, "where parameters are saved and restored "
      "(default $XDG_STATE_HOME/oceand-state.json, else build/oceand-state.json; \"none\" = off)"),
    OPT("max_clients", PARAM_INT, max_clients, 1, 100000, 512, NULL, 0, "WebSocket clients at once; more are refused"),
    OPT("max_message", PARAM_INT, max_message, 256, 16777216, 65536, NULL, 0, "largest JSON message in bytes; larger closes with 1009"),
    OPT("control_rate", PARAM_FLOAT, control_rate, 0.1, 10000, 20, NULL, 0, "control units per second per client "
        "(sustained); a message costs 1 unit + 1 per full KiB; over it: rate_limited"),
    OPT("control_burst", PARAM_INT, control_burst, 1, 10000, 40, NULL, 0, "control units per client in a burst"),
    OPT("control_budget", PARAM_FLOAT, control_budget, 10, 1e7, 2000, NULL, 0, "control units per second, all "
        "clients together (each still gets budget / clients); over it: busy"),
    OPT("ping_interval", PARAM_INT, ping_interval, 1, 3600, 20, NULL, 0, "seconds of silence before the server pings"),
    OPT("idle_timeout", PARAM_INT, idle_timeout, 2, 7200, 60, NULL, 0, "seconds of silence before the server hangs up"),
    OPT_STR("allowed_origins", allowed_origins, "", 0, "WebSocket Origins allowed: \"\" = same host "
      "or none, \"*\" = any, else comma-separated list like http://example.org:8080"),
    OPT_STR("control_token", control_token, "", PARAM_SECRET, "if set, `set` needs this token (others are viewers)"),
    OPT_STR("tls_cert", tls_cert, "", 0, "PEM certificate file: serve https/wss instead of http/ws "
      "on the same port (needs --tls-key)"),
    OPT_STR("tls_key", tls_key, "", 0, "PEM private key file of --tls-cert"),
    OPT("fft_threads", PARAM_INT, fft_threads, 0, 64, 0, NULL, 0, "worker threads for the simulation step and for "
      "rebuilding the spectrum after a change (0 = one per core, every core)"),
    OPT("encode_threads", PARAM_INT, encode_threads, 0, 64, 0, NULL, 0, "threads that encode frames, pipelined "
      "with the next step (0 = one per core)"),
    OPT("encode_budget", PARAM_INT, encode_budget, 0, 1 << 30, 0, NULL, 0, "samples encoded per tick at most, over "
      "all distinct layers (0 = derived from the tick time measured at start-up); a subscription beyond it gets `busy`"),
    OPT("temporal_budget", PARAM_INT, temporal_budget, 0, 1 << 30, 0, NULL, 0, "samples encoded per tick at most "
      "with the temporal codec (codec 3), over all subscription groups with temporal clients (0 = derived from the "
      "measured costs only); a group beyond it is sent intra at its own LOD: the same detail, more bytes"),
    OPT("plan_rigor", PARAM_INT, plan_rigor, 0, 1, 1, NULL, 0, "1 = FFTW_MEASURE (faster steps; the first plan of "
      "each N takes a moment, then it is cached in --wisdom-file), 0 = FFTW_ESTIMATE"),
    OPT_STR("wisdom_file", wisdom_file, "auto", 0, "FFTW wisdom cache: \"auto\" = "
      "$XDG_CACHE_HOME/oceand/fftw-wisdom, else ~/.cache/oceand/fftw-wisdom; \"none\" = no cache"),
    OPT("keyframe_interval", PARAM_INT, keyframe_interval, 0, 100000, 300, NULL, 0, "temporal codec (codec 3): "
      "each tile starts a new chain (keyframe) every this many ticks, staggered; 0 = only when needed "
      "(clients without the references get keyframes on demand either way; docs/codec.md has the measurement)"),
    OPT("ease_ticks", PARAM_INT, ease_ticks, 0, 300, 8, NULL, 0, "a change of the wave amplitudes alone (wind, "
      "amplitude, spectrum, fetch, ...) eases the sea from the old amplitudes to the new over this many ticks "
      "(linear; 0 = at once; N above 1024: at once; docs/simulation.md \"Easing\" has the measurement)"),
    OPT("send_buffer_kb", PARAM_INT, send_buffer_kb, 16, 65536, 512, NULL, 0, "kernel send buffer per client (KiB): "
      "small keeps a slow client's queue, and so its latency, short"),
    OPT("sim_nice", PARAM_INT, sim_nice, -20, 19, 0, NULL, 0, "nice value of the tick thread; below 0 (needs "
      "CAP_SYS_NICE) keeps the tick on time on a busy machine"),
    OPT("query_threads", PARAM_INT, query_threads, 1, 16, 1, NULL, 0, "worker threads for point queries and probes"),
    OPT("query_window", PARAM_FLOAT, query_window, 0, 60, 5, NULL, 0, "seconds of sim time before now that a "
        "query's \"time\" may ask for"),
    OPT("query_budget", PARAM_FLOAT, query_budget, 1, 1e6, 1000, NULL, 0, "exact query points per second, all "
        "clients together, counted at N = 256 and one cascade (a point costs in proportion to the modes it sums: "
        "(N/256)^2, times 1.4 with 3 cascades); over it: busy"),
    OPT("query_queue", PARAM_INT, query_queue, 1, 4096, 64, NULL, 0, "queries waiting at most; more: busy"),
    OPT("probe_max_points", PARAM_INT, probe_max_points, 1, 64, 16, NULL, 0, "probe points per client"),
    OPT("probe_max_total", PARAM_INT, probe_max_total, 1, 100000, 2048, NULL, 0, "probe points, all clients together"),
    OPT("render_workers", PARAM_INT, render_workers, 1, 16, 1, NULL, 0, "worker threads for exact-time renders "
        "(`render`, bakes): renders that run at once, each on a simulation of its own with one FFT thread"),
    OPT("render_budget", PARAM_FLOAT, render_budget, 1, 1e6, 1000, NULL, 0, "render units per second, all renders "
        "together (a unit: one field of one cascade of one frame at N = 256, (N/256)^2 at other N; a bake frame of "
        "6 + 5 + 5 fields over 3 cascades costs 16): the renders are paced to it"),
    OPT("render_max_units", PARAM_FLOAT, render_max_units, 1, 1e9, 65536, NULL, 0, "render units accepted and not "
        "yet rendered, all renders together; a render that would pass it: busy (one that alone passes it: bad_render)"),
    OPT("render_nice", PARAM_INT, render_nice, 0, 19, 5, NULL, 0, "nice value of the render threads: above the "
        "tick's, so that renders take what the live sea leaves"),
    OPT("max_memory_mb", PARAM_INT, max_memory_mb, 0, 1 << 20, 0, NULL, 0, "memory cap for the simulation; limits N "
      "(0 = a quarter of the machine's memory: MemTotal or the cgroup limit, whichever is lower)"),
    OPT_STR("role", role, "all", 0, "all = one process (no NATS); sim = simulate and publish on NATS "
      "(serves /healthz and /metrics, no viewers); edge = serve viewers from the sim over NATS (docs/scaling.md)"),
    OPT_STR("nats", nats_url, "", PARAM_SECRET, "NATS server URL(s) (may hold user:password) for --role sim|edge, e.g. nats://127.0.0.1:4222"),
    OPT_STR("nats_prefix", nats_prefix, "oceand", 0, "NATS subject prefix (several seas can share one NATS)"),
    OPT_STR("nats_name", nats_name, "", 0, "this daemon's name on NATS (\"\" = <role>-<host>-<pid>)"),
    OPT_STR("nats_creds", nats_creds, "", 0, "NATS credentials file (JWT + NKey seed)"),
    OPT_STR("nats_tls_ca", nats_tls_ca, "", 0, "PEM CA file to verify the NATS server (implies TLS)"),
    OPT_STR("nats_tls_cert", nats_tls_cert, "", 0, "PEM client certificate for NATS (with --nats-tls-key)"),
    OPT_STR("nats_tls_key", nats_tls_key, "", 0, "PEM private key of --nats-tls-cert"),
    OPT_STR("server_name", server_name, "", 0, "Host names the daemon answers to besides localhost and the "
      "--bind address (comma list, e.g. ocean.example.org); other Host headers get 421 (DNS rebinding); \"*\" = any"),
    OPT("output_limit_kb", PARAM_INT, output_limit_kb, 16, 1 << 20, 1024, NULL, 0, "JSON replies queued for one "
      "client (KiB); a client over it is closed with 1008 (it is not reading)"),
    OPT("bodies_per_session", PARAM_INT, bodies_per_session, 0, 1024, 4, NULL, 0, "floating bodies one client may own "
        "at once; more: too_many_bodies"),
    OPT("max_bodies", PARAM_INT, max_bodies, 1, 1024, 64, NULL, 0, "floating bodies in the world at once (each adds "
        "48 bytes to every frame); more: too_many_bodies"),
    OPT("launch_rate", PARAM_FLOAT, launch_rate, 1, 600, 12, NULL, 0, "launches per minute per client (a bucket of "
        "that many, refilled over a minute); more: rate_limited"),
    OPT("body_grace", PARAM_FLOAT, body_grace, 0.1, 86400, 60, NULL, 0, "seconds a body waits for its owner to "
        "come back (claim with its resume key) before it drifts unpowered; as long again and it is removed"),
};

#undef OPT
#undef OPT_STR
static const size_t opt_count = sizeof opt_table / sizeof opt_table[0];

static const struct param_def *opt_find(const char *name)
{
    for (size_t i = 0; i < opt_count; i++)
        if (opt_table[i].name[0] == name[0] && strcmp(opt_table[i].name, name) == 0)
            return &opt_table[i];
    return NULL;
}

/* Option or parameter from a JSON value (config file): the same JSON rules
 * as a `set` (control_set_json), onto dc or p. */
static int set_from_json(struct daemon_config *dc, struct ocean_params *p, const cJSON *item, char *err, size_t errlen)
{
    const struct param_def *d = opt_find(item->string);
    void *base = dc;
    if (!d) {
        d = param_find(item->string);
        base = p;
    }
    if (!d) {
        snprintf(err, errlen, "unknown setting \"%.60s\"", item->string);
        return -1;
    }
    struct ctl_error e;
    if (control_set_json(base, d, item, &e) != 0) {
        snprintf(err, errlen, "%s", e.message);
        return -1;
    }
    return 0;
}

/* Flags are parsed by hand, not with getopt_long: its option list would be
 * built from both tables at run time, and it does not take --wind_speed and
 * --wind-speed alike. "--name" -> "name", dashes to underscores, up to '='. */
static void norm_name(char *dst, size_t n, const char *src)
{
    size_t i = 0;
    for (; src[i] && src[i] != '=' && i + 1 < n; i++)
        dst[i] = src[i] == '-' ? '_' : src[i];
    dst[i] = 0;
}

void config_usage(FILE *out, const char *argv0)
{
    fprintf(out,
            "usage: %s [--config FILE] [--OPTION VALUE | --OPTION=VALUE]...\n"
            "Simulates an FFT ocean and streams it over WebSocket (subprotocol oceand.v1);\n"
            "serves the web client, /healthz and /metrics over HTTP on the same port.\n"
            "Settings, lowest precedence first: defaults, saved state, --config FILE (JSON object\n"
            "with the names below), command-line flags. Dashes and underscores are interchangeable.\n\n"
            "Daemon options:\n  --config FILE\n      JSON file of options and sea parameters\n",
            argv0);
    for (size_t i = 0; i < opt_count; i++) {
        char n[64];
        snprintf(n, sizeof n, "%s", opt_table[i].name);
        for (char *c = n; *c; c++)
            if (*c == '_')
                *c = '-';
        char def[64];
        setting_default_text(&opt_table[i], def, sizeof def);
        fprintf(out, "  --%s (default \"%s\")\n      %s\n", n, def, opt_table[i].description);
    }
    fprintf(out, "\nSea parameters (also settable live with a JSON `set`):\n");
    for (size_t i = 0; i < param_count; i++) {
        const struct param_def *d = &param_table[i];
        char n[64], range[160] = "";
        snprintf(n, sizeof n, "%s", d->name);
        for (char *c = n; *c; c++)
            if (*c == '_')
                *c = '-';
        if (d->type == PARAM_ENUM) {
            size_t off = 0;
            for (int k = 0; d->choices && d->choices[k] && off < sizeof range; k++)
                off += (size_t)snprintf(range + off, sizeof range - off, "%s%s", k ? "|" : "", d->choices[k]);
        } else if (d->type == PARAM_BOOL) {
            snprintf(range, sizeof range, "true|false");
        } else {
            snprintf(range, sizeof range, "%g..%g%s%s%s", d->min, d->max, d->unit && *d->unit ? " " : "",
                     d->unit ? d->unit : "", (d->flags & PARAM_POW2) ? ", power of two" : "");
        }
        char def[64];
        setting_default_text(d, def, sizeof def);
        fprintf(out, "  --%s (%s, default %s)\n      %s\n", n, range, def, d->description ? d->description : "");
    }
    fprintf(out, "\n  -h, --help  this text\n");
}

/* The value of flag i: "--x=v" or "--x v". Advances *i past a separate value. */
static const char *flag_value(int argc, char **argv, int *i)
{
    const char *eq = strchr(argv[*i], '=');
    if (eq)
        return eq + 1;
    if (*i + 1 < argc) {
        (*i)++;
        return argv[*i];
    }
    return NULL;
}

/* One JSON object and nothing but whitespace after it, read as strictly as
 * a control message (a NUL would cut a string: "abc\u0000def" as the token
 * "abc"). Returns the object, or NULL with a message naming `what`. */
static cJSON *parse_config_text(const char *text, size_t len, const char *what, char *err, size_t errlen)
{
    struct ctl_error e;
    cJSON *cfg = control_parse_object(text, len, &e);
    if (!cfg)
        snprintf(err, errlen, "%s: not a config file (%s: %s)", what, e.code, e.message);
    return cfg;
}

/* Every member of a config object onto dc / p (state_file was used already). */
static int apply_config_object(struct daemon_config *dc, struct ocean_params *p, const cJSON *cfg,
                               char *err, size_t errlen)
{
    const cJSON *item;
    cJSON_ArrayForEach(item, cfg) {
        if (strcmp(item->string, "state_file") == 0)
            continue;
        if (set_from_json(dc, p, item, err, errlen) != 0)
            return -1;
    }
    return 0;
}

int config_apply_text(struct daemon_config *dc, struct ocean_params *p, const char *text, size_t len,
                      char *err, size_t errlen)
{
    struct daemon_config dc2 = *dc;
    struct ocean_params p2 = *p;
    cJSON *cfg = parse_config_text(text, len, "config", err, errlen);
    if (!cfg)
        return -1;
    int rc = apply_config_object(&dc2, &p2, cfg, err, errlen);
    cJSON_Delete(cfg);
    if (rc == 0 && params_validate(&p2, err, errlen) != 0)
        rc = -1;
    if (rc == 0) {
        *dc = dc2;
        *p = p2;
    }
    return rc;
}

/* "auto" puts the FFTW wisdom in the user's cache directory, so a restart
 * (and every later daemon of this user) skips FFTW_MEASURE's planning;
 * "none" or "" = no cache. The directory itself is made by main. */
static void resolve_wisdom_path(struct daemon_config *dc)
{
    if (strcmp(dc->wisdom_file, "none") == 0) {
        dc->wisdom_file[0] = '\0';
        return;
    }
    if (strcmp(dc->wisdom_file, "auto") != 0)
        return;
    const char *xdg = getenv("XDG_CACHE_HOME"), *home = getenv("HOME");
    int n = -1;
    if (xdg && *xdg)
        n = snprintf(dc->wisdom_file, sizeof dc->wisdom_file, "%s/oceand/fftw-wisdom", xdg);
    else if (home && *home)
        n = snprintf(dc->wisdom_file, sizeof dc->wisdom_file, "%s/.cache/oceand/fftw-wisdom", home);
    if (n < 0 || (size_t)n >= sizeof dc->wisdom_file) { /* none, or cut: another file */
        if (n > 0)
            LOGW("$XDG_CACHE_HOME or $HOME is too long for the FFTW wisdom file's path: no wisdom cache");
        dc->wisdom_file[0] = '\0';
    }
}

/* A quarter of what the machine (or its cgroup) gives us, at least 256 MB:
 * the simulation's share of a box that runs other things too. */
int config_default_memory_mb(void)
{
    double total = 0;
    FILE *f = fopen("/proc/meminfo", "r");
    if (f) {
        char line[128];
        while (fgets(line, sizeof line, f))
            if (sscanf(line, "MemTotal: %lf kB", &total) == 1)
                break;
        fclose(f);
        total *= 1024.0;
    }
    static const char *const cgroup_limits[] = { "/sys/fs/cgroup/memory.max",
                                                 "/sys/fs/cgroup/memory/memory.limit_in_bytes" };
    for (size_t i = 0; i < sizeof cgroup_limits / sizeof cgroup_limits[0]; i++) {
        FILE *c = fopen(cgroup_limits[i], "r");
        double lim = 0;
        if (c && fscanf(c, "%lf", &lim) == 1 && lim > 0 && (total <= 0 || lim < total))
            total = lim; /* "max" (no limit) does not parse as a number */
        if (c)
            fclose(c);
    }
    double mb = total / 4.0 / 1048576.0;
    return mb < 256 ? 256 : mb > (1 << 20) ? (1 << 20) : (int)mb;
}
/* A config file larger than this is refused, not truncated. */
#define CONFIG_MAX_BYTES (16u << 20)

int config_load(int argc, char **argv, struct daemon_config *dc, struct ocean_params *p,
                struct config_result *res, char *err, size_t errlen)
{
    memset(dc, 0, sizeof *dc);
    memset(res, 0, sizeof *res);
    params_defaults(p);
    for (size_t i = 0; i < opt_count; i++)
        setting_set_default(dc, &opt_table[i]);
    dc->tile_size = 128; /* tiles are min(128, N): meets the 6.5 bits/sample target at N=256, encodes faster than 64 */

    /* Pass 1: --help, --config and --state-file decide what else to read. */
    const char *config_path = NULL, *state_cli = NULL;
    for (int i = 1; i < argc; i++) {
        char name[64];
        if (strcmp(argv[i], "-h") == 0 || strcmp(argv[i], "--help") == 0) {
            res->help = true;
            return 0;
        }
        if (strncmp(argv[i], "--", 2) != 0) {
            snprintf(err, errlen, "unexpected argument \"%s\" (see --help)", argv[i]);
            return -1;
        }
        norm_name(name, sizeof name, argv[i] + 2);
        const char *v = flag_value(argc, argv, &i);
        if (!v) {
            snprintf(err, errlen, "--%s needs a value", name);
            return -1;
        }
        if (strcmp(name, "config") == 0)
            config_path = v;
        else if (strcmp(name, "state_file") == 0)
            state_cli = v;
    }
    cJSON *cfg = NULL;
    if (config_path) {
        char *text;
        size_t len;
        if (file_read_all(config_path, CONFIG_MAX_BYTES, &text, &len, err, errlen) != 0)
            return -1;
        cfg = parse_config_text(text, len, config_path, err, errlen);
        free(text);
        if (!cfg)
            return -1;
        snprintf(dc->config_file, sizeof dc->config_file, "%s", config_path);
    }

    /* Where the state lives: flag > config file > $XDG_STATE_HOME > build/. */
    const char *sf = state_cli ? state_cli : cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(cfg, "state_file"));
    const char *xdg = getenv("XDG_STATE_HOME");
    /* A path that does not fit is refused, never cut: the cut one names
     * another file, which the daemon would then write (test-hostile
     * absurd_command_lines). */
    if (sf && strlen(sf) >= sizeof dc->state_file) {
        snprintf(err, errlen, "state_file: value too long (%zu bytes, at most %zu)", strlen(sf),
                 sizeof dc->state_file - 1);
        cJSON_Delete(cfg);
        return -1;
    }
    if (sf)
        snprintf(dc->state_file, sizeof dc->state_file, "%s", strcmp(sf, "none") == 0 ? "" : sf);
    else if (xdg && *xdg && strlen(xdg) + sizeof "/oceand-state.json" > sizeof dc->state_file) {
        LOGW("$XDG_STATE_HOME is too long (%zu bytes) for the state file's path: state not saved "
             "(give --state-file)", strlen(xdg));
        dc->state_file[0] = '\0';
    } else if (xdg && *xdg)
        snprintf(dc->state_file, sizeof dc->state_file, "%s/oceand-state.json", xdg);
    else
        snprintf(dc->state_file, sizeof dc->state_file, "build/oceand-state.json");

    int rc = 0;
    /* Whether the resolution and the cascades in force come from the saved
     * state (not overridden by the config file or a flag): a saved pair that
     * does not fit the memory cap set below is not used (as any bad saved
     * value), while the same from the command line is an error. */
    const int resolution_before_state = p->resolution, cascades_before_state = p->cascades;
    bool resolution_from_state = false, cascades_from_state = false;
    if (dc->state_file[0]) {
        char serr[256];
        int s = state_load(dc->state_file, p, &res->params_version, &res->sim_time, serr, sizeof serr);
        if (s == -2) {
            /* Not something we wrote (a FIFO, a directory...): a misconfigured
             * path, refused rather than read, waited on, or replaced. */
            snprintf(err, errlen, "state file %s; choose another --state-file (or \"none\")", serr);
            cJSON_Delete(cfg);
            return -1;
        }
        if (s < 0)
            LOGW("ignoring saved state: %s", serr);  /* a corrupt state file must not stop the daemon */
        res->state_loaded = s > 0;
        resolution_from_state = s > 0 && p->resolution != resolution_before_state;
        cascades_from_state = s > 0 && p->cascades != cascades_before_state;
    }
    if (cJSON_GetObjectItemCaseSensitive(cfg, "resolution"))
        resolution_from_state = false;
    if (cJSON_GetObjectItemCaseSensitive(cfg, "cascades"))
        cascades_from_state = false;
    rc = apply_config_object(dc, p, cfg, err, errlen);
    cJSON_Delete(cfg);
    if (rc)
        return -1;

    /* Pass 2: the flags themselves, last word. */
    for (int i = 1; i < argc; i++) {
        char name[64];
        const char *flag = argv[i];
        norm_name(name, sizeof name, flag + 2);
        const char *v = flag_value(argc, argv, &i);
        if (strcmp(name, "config") == 0 || strcmp(name, "state_file") == 0)
            continue;
        const struct param_def *d = opt_find(name);
        void *base = dc;
        if (!d) {
            d = param_find(name);
            base = p;
        }
        if (!d) {
            snprintf(err, errlen, "unknown option %s (see --help)", flag);
            return -1;
        }
        if (base == p && strcmp(d->name, "resolution") == 0)
            resolution_from_state = false;
        if (base == p && strcmp(d->name, "cascades") == 0)
            cascades_from_state = false;
        char perr[200];
        if (setting_set_text(base, d, v, perr, sizeof perr) != PARAM_OK) {
            snprintf(err, errlen, "--%s: %s", name, perr);
            return -1;
        }
    }
    if (!dc->tls_cert[0] != !dc->tls_key[0]) {
        snprintf(err, errlen, "--tls-cert and --tls-key go together (one of them is missing)");
        return -1;
    }
    if (strcmp(dc->role, "all") != 0 && strcmp(dc->role, "sim") != 0 && strcmp(dc->role, "edge") != 0) {
        snprintf(err, errlen, "--role: \"%s\" is not all, sim or edge", dc->role);
        return -1;
    }
    if (strcmp(dc->role, "all") != 0 && !dc->nats_url[0]) {
        snprintf(err, errlen, "--role %s needs --nats URL (e.g. nats://127.0.0.1:4222)", dc->role);
        return -1;
    }
    resolve_wisdom_path(dc);
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    if (dc->fft_threads == 0) /* every core (docs/simulation.md, "Threads") */
        dc->fft_threads = cores < 1 ? 1 : cores > 64 ? 64 : (int)cores;
    if (dc->encode_threads == 0)
        dc->encode_threads = cores < 1 ? 1 : cores > 64 ? 64 : (int)cores;
    const bool cap_default = dc->max_memory_mb == 0;
    if (cap_default)
        dc->max_memory_mb = config_default_memory_mb();
    char verr[200];
    /* spectrum "measured" from the state file comes with its sea (main.c
     * loads it, and falls back to jonswap when it cannot). */
    if (params_validate_sea(p, res->state_loaded, verr, sizeof verr) != 0) {
        snprintf(err, errlen, "parameters: %s", verr);
        return -1;
    }
    if (!control_fits_memory(p->resolution, p->cascades, dc->max_memory_mb) &&
        (resolution_from_state || cascades_from_state)) {
        /* A live `set` of the same is refused; at start-up the largest fit
         * is used instead (the saved N halved, then the saved cascades
         * fewer), and the log says so: never the saved values unchecked. */
        const int saved_n = p->resolution, saved_c = p->cascades;
        const double need = control_memory_mb(saved_n, saved_c);
        while (resolution_from_state && p->resolution / 2 >= 16 &&
               !control_fits_memory(p->resolution, p->cascades, dc->max_memory_mb))
            p->resolution /= 2;
        while (cascades_from_state && p->cascades > 1 &&
               !control_fits_memory(p->resolution, p->cascades, dc->max_memory_mb))
            p->cascades--;
        if (control_fits_memory(p->resolution, p->cascades, dc->max_memory_mb))
            LOGW("saved state: resolution %d with %d cascade%s needs %.0f MB, over the memory cap of %d MB (%s); "
                 "using resolution %d with %d cascade%s", saved_n, saved_c, saved_c > 1 ? "s" : "", need,
                 dc->max_memory_mb, cap_default ? "a quarter of this machine's memory; see --max-memory-mb" : "--max-memory-mb",
                 p->resolution, p->cascades, p->cascades > 1 ? "s" : "");
        if (params_validate_sea(p, res->state_loaded, verr, sizeof verr) != 0) {
            snprintf(err, errlen, "parameters: %s", verr);
            return -1;
        }
    }
    if (!control_fits_memory(p->resolution, p->cascades, dc->max_memory_mb)) {
        snprintf(err, errlen, "resolution %d exceeds --max-memory-mb %d", p->resolution, dc->max_memory_mb);
        return -1;
    }
    return 0;
}

/* config.c — defaults <- saved state <- --config FILE <- CLI flags (see config.h). */
#include "config.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "control.h"
#include "log.h"
#include "state.h"

enum opt_kind { OPT_INT, OPT_FLOAT, OPT_STR, OPT_LOGLEVEL };

/* The daemon's own options (the sea parameters live in params.c). */
struct opt_def {
    const char *name;
    enum opt_kind kind;
    size_t offset, size;
    double min, max;
    const char *def;
    const char *help;
};

#define O(f) offsetof(struct daemon_config, f), sizeof(((struct daemon_config *)0)->f)
static const struct opt_def opt_table[] = {
    { "port", OPT_INT, O(port), 0, 65535, "8080", "TCP port for HTTP and WebSocket (0 = any free port)" },
    { "bind", OPT_STR, O(bind), 0, 0, "127.0.0.1", "address to listen on (0.0.0.0 = all interfaces)" },
    { "web_root", OPT_STR, O(web_root), 0, 0, "build/web", "directory served at / (the web client)" },
    { "tick_rate", OPT_FLOAT, O(tick_rate), 1, 240, "30", "simulation steps per second" },
    { "log_level", OPT_LOGLEVEL, O(log_level), 0, 3, "info", "error, warn, info or debug" },
    { "state_file", OPT_STR, O(state_file), 0, 0, "", "where parameters are saved and restored "
      "(default $XDG_STATE_HOME/oceand-state.json, else build/oceand-state.json; \"none\" = off)" },
    { "max_clients", OPT_INT, O(max_clients), 1, 100000, "512", "WebSocket clients at once; more are refused" },
    { "max_message", OPT_INT, O(max_message), 256, 16777216, "65536", "largest JSON message in bytes; larger closes with 1009" },
    { "control_rate", OPT_FLOAT, O(control_rate), 0.1, 10000, "20", "control messages per second per client (sustained)" },
    { "control_burst", OPT_INT, O(control_burst), 1, 10000, "40", "control messages per client in a burst" },
    { "ping_interval", OPT_INT, O(ping_interval), 1, 3600, "20", "seconds of silence before the server pings" },
    { "idle_timeout", OPT_INT, O(idle_timeout), 2, 7200, "60", "seconds of silence before the server hangs up" },
    { "allowed_origins", OPT_STR, O(allowed_origins), 0, 0, "", "WebSocket Origins allowed: \"\" = same host "
      "or none, \"*\" = any, else comma-separated list like http://example.org:8080" },
    { "control_token", OPT_STR, O(control_token), 0, 0, "", "if set, `set` needs this token (others are viewers)" },
    { "tls_cert", OPT_STR, O(tls_cert), 0, 0, "", "PEM certificate file: serve https/wss instead of http/ws "
      "on the same port (needs --tls-key)" },
    { "tls_key", OPT_STR, O(tls_key), 0, 0, "", "PEM private key file of --tls-cert" },
    { "fft_threads", OPT_INT, O(fft_threads), 0, 64, "0", "worker threads for the simulation step and for "
      "rebuilding the spectrum after a change (0 = one per core, every core)" },
    { "encode_threads", OPT_INT, O(encode_threads), 0, 64, "0", "threads that encode frames, pipelined with the "
      "next step (0 = one per core)" },
    { "encode_budget", OPT_INT, O(encode_budget), 0, 1 << 30, "0", "samples encoded per tick at most, over all "
      "distinct layers (0 = derived from the tick time measured at start-up); a subscription beyond it gets `busy`" },
    { "plan_rigor", OPT_INT, O(plan_rigor), 0, 1, "1", "1 = FFTW_MEASURE (faster steps; the first plan of "
      "each N takes a moment, then it is cached in --wisdom-file), 0 = FFTW_ESTIMATE" },
    { "wisdom_file", OPT_STR, O(wisdom_file), 0, 0, "auto", "FFTW wisdom cache: \"auto\" = "
      "$XDG_CACHE_HOME/oceand/fftw-wisdom, else ~/.cache/oceand/fftw-wisdom; \"none\" = no cache" },
    { "send_buffer_kb", OPT_INT, O(send_buffer_kb), 16, 65536, "512", "kernel send buffer per client (KiB): "
      "small keeps a slow client's queue, and so its latency, short" },
    { "sim_nice", OPT_INT, O(sim_nice), -20, 19, "0", "nice value of the tick thread; below 0 (needs "
      "CAP_SYS_NICE) keeps the tick on time on a busy machine" },
    { "max_memory_mb", OPT_INT, O(max_memory_mb), 0, 1 << 20, "0", "memory cap for the simulation; limits N "
      "(0 = a quarter of the machine's memory: MemTotal or the cgroup limit, whichever is lower)" },
};
#undef O
static const size_t opt_count = sizeof opt_table / sizeof opt_table[0];

static const struct opt_def *opt_find(const char *name)
{
    for (size_t i = 0; i < opt_count; i++)
        if (strcmp(opt_table[i].name, name) == 0)
            return &opt_table[i];
    return NULL;
}

static int opt_set_text(struct daemon_config *dc, const struct opt_def *o, const char *text, char *err, size_t errlen)
{
    char *field = (char *)dc + o->offset;
    char *end;
    double v;
    switch (o->kind) {
    case OPT_STR:
        if (strlen(text) >= o->size) {
            snprintf(err, errlen, "%s: value too long", o->name);
            return -1;
        }
        memcpy(field, text, strlen(text) + 1);
        return 0;
    case OPT_LOGLEVEL: {
        int l = log_level_from_name(text);
        if (l < 0) {
            snprintf(err, errlen, "log_level: \"%s\" is not error, warn, info or debug", text);
            return -1;
        }
        *(int *)field = l;
        return 0;
    }
    case OPT_INT:
    case OPT_FLOAT:
        errno = 0;
        v = strtod(text, &end);
        if (errno || end == text || *end || !isfinite(v) || (o->kind == OPT_INT && v != floor(v))) {
            snprintf(err, errlen, "%s: \"%s\" is not a %s", o->name, text, o->kind == OPT_INT ? "whole number" : "number");
            return -1;
        }
        if (v < o->min || v > o->max) {
            snprintf(err, errlen, "%s: %g is outside %g..%g", o->name, v, o->min, o->max);
            return -1;
        }
        if (o->kind == OPT_INT)
            *(int *)field = (int)v;
        else
            *(double *)field = v;
        return 0;
    }
    return -1;
}

/* Option or parameter from a JSON value (config file). */
static int set_from_json(struct daemon_config *dc, struct ocean_params *p, const cJSON *item, char *err, size_t errlen)
{
    const struct opt_def *o = opt_find(item->string);
    if (o) {
        char text[64];
        const char *s = cJSON_GetStringValue(item);
        if (!s && cJSON_IsNumber(item)) {
            snprintf(text, sizeof text, "%.17g", item->valuedouble);
            s = text;
        }
        if (!s) {
            snprintf(err, errlen, "%s: wrong JSON type", o->name);
            return -1;
        }
        return opt_set_text(dc, o, s, err, errlen);
    }
    if (!param_find(item->string)) {
        snprintf(err, errlen, "unknown setting \"%s\"", item->string);
        return -1;
    }
    cJSON *one = cJSON_CreateObject();
    cJSON_AddItemToObject(one, item->string, cJSON_Duplicate(item, 1));
    struct ctl_error e;
    struct ocean_params np;
    int rc = control_apply_params(one, p, NULL, &np, NULL, &e);
    cJSON_Delete(one);
    if (rc) {
        snprintf(err, errlen, "%s", e.message);
        return -1;
    }
    *p = np;
    return 0;
}

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
        fprintf(out, "  --%s (default \"%s\")\n      %s\n", n, opt_table[i].def, opt_table[i].help);
    }
    fprintf(out, "\nSea parameters (also settable live with a JSON `set`):\n");
    struct ocean_params defs;
    params_defaults(&defs);
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
        double v = param_get(&defs, d);
        char def[64];
        if (d->type == PARAM_ENUM)
            snprintf(def, sizeof def, "%s", param_enum_name(d, (int)v) ? param_enum_name(d, (int)v) : "?");
        else if (d->type == PARAM_BOOL)
            snprintf(def, sizeof def, "%s", v ? "true" : "false");
        else
            snprintf(def, sizeof def, "%g", v);
        fprintf(out, "  --%s (%s, default %s)\n      %s\n", n, range, def, d->description ? d->description : "");
    }
    fprintf(out, "\n  -h, --help  this text\n");
}

static int read_file(const char *path, char **text, size_t *len, char *err, size_t errlen)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        snprintf(err, errlen, "%s: %s", path, strerror(errno));
        return -1;
    }
    size_t cap = 1 << 16, n = 0;
    char *buf = malloc(cap);
    size_t r;
    while (buf && (r = fread(buf + n, 1, cap - n, f)) > 0) {
        n += r;
        if (n == cap) {
            if (cap >= (1u << 24))
                break;
            char *nb = realloc(buf, cap *= 2);
            if (!nb) {
                free(buf);
                buf = NULL;
            }
            buf = nb;
        }
    }
    fclose(f);
    if (!buf) {
        snprintf(err, errlen, "%s: out of memory", path);
        return -1;
    }
    *text = buf;
    *len = n;
    return 0;
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

/* One JSON object and nothing but whitespace after it (as for messages).
 * Returns the object, or NULL with a message naming `what`. */
static cJSON *parse_config_text(const char *text, size_t len, const char *what, char *err, size_t errlen)
{
    const char *end = NULL;
    cJSON *cfg = cJSON_ParseWithLengthOpts(text, len, &end, 0);
    while (cfg && end < text + len && (*end == ' ' || *end == '\t' || *end == '\n' || *end == '\r'))
        end++;
    bool trailing = cfg && end != text + len;
    if (!cJSON_IsObject(cfg) || trailing) {
        snprintf(err, errlen, "%s: not a JSON object%s", what, trailing ? " (data after it)" : "");
        cJSON_Delete(cfg);
        return NULL;
    }
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
    if (xdg && *xdg)
        snprintf(dc->wisdom_file, sizeof dc->wisdom_file, "%s/oceand/fftw-wisdom", xdg);
    else if (home && *home)
        snprintf(dc->wisdom_file, sizeof dc->wisdom_file, "%s/.cache/oceand/fftw-wisdom", home);
    else
        dc->wisdom_file[0] = '\0';
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

int config_load(int argc, char **argv, struct daemon_config *dc, struct ocean_params *p,
                struct config_result *res, char *err, size_t errlen)
{
    memset(dc, 0, sizeof *dc);
    memset(res, 0, sizeof *res);
    params_defaults(p);
    for (size_t i = 0; i < opt_count; i++)
        if (opt_set_text(dc, &opt_table[i], opt_table[i].def, err, errlen) != 0)
            return -1;
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
        if (read_file(config_path, &text, &len, err, errlen) != 0)
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
    if (sf)
        snprintf(dc->state_file, sizeof dc->state_file, "%s", strcmp(sf, "none") == 0 ? "" : sf);
    else if (xdg && *xdg)
        snprintf(dc->state_file, sizeof dc->state_file, "%s/oceand-state.json", xdg);
    else
        snprintf(dc->state_file, sizeof dc->state_file, "build/oceand-state.json");

    int rc = 0;
    if (dc->state_file[0]) {
        char serr[256];
        int s = state_load(dc->state_file, p, &res->params_version, &res->sim_time, serr, sizeof serr);
        if (s < 0)
            LOGW("ignoring saved state: %s", serr);  /* a corrupt state file must not stop the daemon */
        res->state_loaded = s > 0;
    }
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
        const struct opt_def *o = opt_find(name);
        const struct param_def *d = o ? NULL : param_find(name);
        if (o) {
            if (opt_set_text(dc, o, v, err, errlen) != 0)
                return -1;
        } else if (d) {
            char perr[200];
            if (param_set_text(p, d, v, perr, sizeof perr) != 0) {
                snprintf(err, errlen, "%s: %s", flag, perr);
                return -1;
            }
        } else {
            snprintf(err, errlen, "unknown option %s (see --help)", flag);
            return -1;
        }
    }
    if (!dc->tls_cert[0] != !dc->tls_key[0]) {
        snprintf(err, errlen, "--tls-cert and --tls-key go together (one of them is missing)");
        return -1;
    }
    resolve_wisdom_path(dc);
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    if (dc->fft_threads == 0) /* every core: the step scales to 16 threads (issue 15) */
        dc->fft_threads = cores < 1 ? 1 : cores > 64 ? 64 : (int)cores;
    if (dc->encode_threads == 0)
        dc->encode_threads = cores < 1 ? 1 : cores > 64 ? 64 : (int)cores;
    if (dc->max_memory_mb == 0)
        dc->max_memory_mb = config_default_memory_mb();
    char verr[200];
    if (params_validate(p, verr, sizeof verr) != 0) {
        snprintf(err, errlen, "parameters: %s", verr);
        return -1;
    }
    if (!control_fits_memory(p->resolution, dc->max_memory_mb)) {
        snprintf(err, errlen, "resolution %d exceeds --max-memory-mb %d", p->resolution, dc->max_memory_mb);
        return -1;
    }
    return 0;
}

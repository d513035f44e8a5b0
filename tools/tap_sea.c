/* tap_sea.c — `ocean-tap sea SOURCE --print`: a measured sea (a buoy's
 * spectrum or a wave forecast) read into the sea document (sea.h) and printed.
 *
 * SOURCE is a file or an http(s):// URL, recognised by its name:
 *   NAME.data_spec | .swdir | .swdir2 | .swr1 | .swr2   NDBC realtime: the other four
 *                                                      beside it, by the same name
 *   IIIIIw2023.txt[.gz] (or d, i, j, k)                NDBC historical: the other four
 *   anything else, by its text: 'WAVEWATCH III SPECTRA' (WW3) or CDIP's OPeNDAP answer
 * or a shortcut: ndbc:46026 (NDBC's realtime files of that station), cdip:100
 * (the newest record of CDIP station 100, two requests: the size, then the record).
 * `ocean-tap sea SOURCE ws://...` sends it to a daemon as `sea` messages (tap_sea_send.c;
 * a forecast plays as a timeline at --speed). */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sea.h"
#include "tap.h"

#define EXIT_SEA 8 /* the source could not be read, or is not a valid sea */

static const char *const RT_EXT[5] = {".data_spec", ".swdir", ".swdir2", ".swr1", ".swr2"};
static const char HIST_LETTER[] = "wdijk";
#define NDBC_RT "https://www.ndbc.noaa.gov/data/realtime2/"
#define CDIP_RT "https://thredds.cdip.ucsd.edu/thredds/dodsC/cdip/realtime/"

/* The shortcuts' servers; OCEAND_SEA_NDBC / OCEAND_SEA_CDIP name others (a mirror, or the
 * test's local server: the shortcuts are tested without leaving the machine). */
static const char *server(const char *env, const char *dflt)
{
    const char *v = getenv(env);
    return v && *v ? v : dflt;
}
#define CDIP_VARS "waveTime%s,waveFrequency,waveBandwidth,waveEnergyDensity%s,waveA1Value%s,waveB1Value%s," \
                  "waveA2Value%s,waveB2Value%s,waveHs%s,waveFlagPrimary%s,metaWaterDepth"

static void sea_usage(FILE *to)
{
    fprintf(to,
        "usage: ocean-tap sea SOURCE --print [--time T] [--point NAME]\n"
        "       ocean-tap sea SOURCE ws://HOST:PORT/ [--speed S] [--token T] [--tail K] [--time T] [--point NAME]\n"
        "  SOURCE  a file or http(s):// URL: NDBC realtime (any of ID.data_spec, .swdir, .swdir2,\n"
        "          .swr1, .swr2: the other four are read beside it), NDBC historical\n"
        "          (IDw2023.txt[.gz] or its d, i, j, k files), a WAVEWATCH III point-spectrum\n"
        "          text file, or CDIP's OPeNDAP .ascii answer; or ndbc:ID, cdip:ID (the public\n"
        "          servers: the newest record)\n"
        "  --print       the sea document as one line of JSON on stdout (a WW3 file: a list, one\n"
        "                per time); a summary per time on stderr (Hs = 4 sqrt(m0), Tp, the\n"
        "                direction waves come from at the peak)\n"
        "  --time T      the record at T (YYYY-MM-DDThh:mm[:ss]Z) instead of the newest\n"
        "  --point NAME  the WW3 output point (default: the first)\n"
        "  ws://...      send it to that daemon (PROTOCOL.md 7.8); a forecast (several times) plays\n"
        "                as the sea's evolution: each time is sent when it comes, at --speed\n"
        "  --speed S     forecast seconds per wall-clock second (default 3600: an hour a second)\n"
        "  --token T     the daemon's control token\n"
        "  --tail K      above the last band: f-4 (the daemon's default), f-5, none, wind\n"
        "Exit codes: 0 ok, 1 usage, 8 the source is unreadable or not a valid sea: the message\n"
        "  says `error CODE: FILE:LINE: band K: ...` (codes: docs/operations.md, Measured seas).\n");
}

static int sea_error(const struct sea_err *e)
{
    char msg[800];
    sea_err_format(e, msg, sizeof msg);
    fprintf(stderr, "ocean-tap: sea: %s\n", msg);
    return EXIT_SEA;
}

static int ends_with(const char *s, const char *tail)
{
    size_t a = strlen(s), b = strlen(tail);
    return a >= b && !strcmp(s + a - b, tail);
}

static const char *base_name(const char *s)
{
    const char *q = strchr(s, '?');
    size_t n = q ? (size_t)(q - s) : strlen(s);
    const char *b = s;
    for (size_t i = 0; i < n; i++) if (s[i] == '/') b = s + i + 1;
    return b;
}

/* The NDBC historical letter's position in "IIIIIw2023.txt[.gz]" (basename), or -1. */
static int hist_letter_at(const char *name)
{
    const char *b = base_name(name);
    size_t n = strlen(b);
    if (!ends_with(b, ".txt") && !ends_with(b, ".txt.gz")) return -1;
    size_t stem = n - (ends_with(b, ".gz") ? 7 : 4);
    if (stem != 10) return -1;
    for (int i = 6; i < 10; i++) if (b[i] < '0' || b[i] > '9') return -1;
    if (!strchr("wdijk", b[5])) return -1;
    return (int)(b - name) + 5;
}

static int load_set(char names[5][2048], struct sea_text t[5], char *bufs[5], struct sea_err *e)
{
    for (int k = 0; k < 5; k++) {
        if (sea_load(names[k], &bufs[k], &t[k].len, e)) return -1;
        t[k].data = bufs[k];
        t[k].name = base_name(names[k]);
    }
    return 0;
}

static void print_doc(const struct sea_doc *d, cJSON *list)
{
    char line[400];
    sea_doc_summary(d, line, sizeof line);
    fprintf(stderr, "%s\n", line);
    if (list) cJSON_AddItemToArray(list, sea_doc_json(d));
}

static int print_json(cJSON *j)
{
    char *text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
    if (!text) { fprintf(stderr, "ocean-tap: sea: out of memory\n"); return EXIT_SEA; }
    puts(text);
    free(text);
    return fflush(stdout) ? EXIT_OUTPUT : EXIT_OK;
}

/* cdip:ID -> the URL of its newest record: the dataset's sizes first (its .dds). */
static int cdip_url(const char *id, char *url, size_t n, struct sea_err *e)
{
    char dds[512], *text;
    size_t len;
    const char *base = server("OCEAND_SEA_CDIP", CDIP_RT);
    snprintf(dds, sizeof dds, "%.400s%.60sp1_rt.nc.dds", base, id);
    if (sea_load(dds, &text, &len, e)) return -1;
    const char *p = strstr(text, "[waveTime = "), *q = strstr(text, "[waveFrequency = ");
    long nt = p ? strtol(p + 12, NULL, 10) : 0, nf = q ? strtol(q + 17, NULL, 10) : 0;
    free(text);
    if (nt < 1 || nf < 1 || nf > SEA_MAX_FREQ)
        return sea_fail(e, "bad_header", dds, 0, 0, "no waveTime and waveFrequency dimensions (1..%d bands) in the "
                        "dataset's description", SEA_MAX_FREQ);
    char ix[32], ixf[64], vars[1024];
    snprintf(ix, sizeof ix, "[%ld]", nt - 1);
    snprintf(ixf, sizeof ixf, "[%ld][0:1:%ld]", nt - 1, nf - 1);
    snprintf(vars, sizeof vars, CDIP_VARS, ix, ixf, ixf, ixf, ixf, ixf, ix, ix);
    snprintf(url, n, "%.400s%.60sp1_rt.nc.ascii?%s", base, id, vars);
    return 0;
}

int tap_sea_main(int argc, char **argv)
{
    static const struct option longs[] = {{"print", no_argument, 0, 'p'}, {"time", required_argument, 0, 't'},
                                          {"point", required_argument, 0, 'P'}, {"help", no_argument, 0, 'h'},
                                          {"speed", required_argument, 0, 'S'}, {"token", required_argument, 0, 'T'},
                                          {"tail", required_argument, 0, 'L'}, {0, 0, 0, 0}};
    int print = 0, c;
    const char *when = NULL, *point = NULL, *token = NULL, *tail = NULL;
    double speed = 3600;
    char *end = NULL;
    optind = 1;
    while ((c = getopt_long(argc, argv, "h", longs, NULL)) != -1) {
        switch (c) {
        case 'p': print = 1; break;
        case 't': when = optarg; break;
        case 'P': point = optarg; break;
        case 'S':
            speed = strtod(optarg, &end);
            if (*end || !(speed > 0 && speed < 1e12)) return usage_error("sea: --speed needs a number > 0");
            break;
        case 'T': token = optarg; break;
        case 'L':
            if (strcmp(optarg, "f-4") && strcmp(optarg, "f-5") && strcmp(optarg, "none") && strcmp(optarg, "wind"))
                return usage_error("sea: --tail is f-4, f-5, none or wind");
            tail = optarg;
            break;
        case 'h': sea_usage(stdout); return EXIT_OK;
        default: return usage_error("sea: unknown option (ocean-tap sea --help)");
        }
    }
    if (optind >= argc) return usage_error("sea: missing SOURCE");
    const char *src = argv[optind], *target = optind + 1 < argc ? argv[optind + 1] : NULL;
    if (optind + 2 < argc) return usage_error("sea: one SOURCE and at most one ws:// URL");
    char canon[24];
    if (when && sea_time_canon(when, canon)) return usage_error("sea: --time needs YYYY-MM-DDThh:mm[:ss]Z");
    if (target && print) return usage_error("sea: --print or a ws:// URL: one of them");
    if (!print && !target) return usage_error("sea: nothing to do: give --print or a ws:// URL");

    struct sea_err e = {0};
    char names[5][2048], *bufs[5] = {0}, station[64] = "";
    struct sea_text t[5] = {{0}};
    struct sea_doc *docs = NULL;
    int rc = EXIT_SEA, n = 0, kind = -1; /* 0 realtime, 1 historical, 2 WW3, 3 CDIP */
    char one[2048];
    snprintf(one, sizeof one, "%s", src);
    if (!strncmp(src, "ndbc:", 5)) {
        snprintf(station, sizeof station, "%.60s", src + 5);
        snprintf(one, sizeof one, "%.1000s%s.data_spec", server("OCEAND_SEA_NDBC", NDBC_RT), station);
    } else if (!strncmp(src, "cdip:", 5)) {
        snprintf(station, sizeof station, "%.60s", src + 5);
        if (cdip_url(station, one, sizeof one, &e)) goto out;
        kind = 3;
    }
    for (int k = 0; k < 5 && kind < 0; k++)
        if (ends_with(one, RT_EXT[k])) {
            size_t stem = strlen(one) - strlen(RT_EXT[k]);
            for (int j = 0; j < 5; j++) snprintf(names[j], sizeof names[j], "%.*s%s", (int)stem, one, RT_EXT[j]);
            if (!station[0]) snprintf(station, sizeof station, "%.*s", (int)(strlen(base_name(one)) - strlen(RT_EXT[k])),
                                      base_name(one));
            kind = 0;
        }
    int at = kind < 0 ? hist_letter_at(one) : -1;
    if (at >= 0) {
        /* NDBC's own server keeps each kind in a folder of its own: .../swden/46026w2023.txt.gz,
         * .../swdir/46026d2023.txt.gz, ...: that folder changes with the letter. */
        static const char *const folder[5] = {"/swden/", "/swdir/", "/swdir2/", "/swr1/", "/swr2/"};
        int kf = (int)(strchr(HIST_LETTER, one[at]) - HIST_LETTER), fl = (int)strlen(folder[kf]);
        int in_folder = at - 5 >= fl && !strncmp(one + at - 5 - fl, folder[kf], (size_t)fl);
        for (int j = 0; j < 5; j++) {
            if (in_folder)
                snprintf(names[j], sizeof names[j], "%.*s%s%s", at - 5 - fl, one, folder[j], one + at - 5);
            else
                snprintf(names[j], sizeof names[j], "%s", one);
            names[j][strlen(names[j]) - strlen(one + at)] = HIST_LETTER[j];
        }
        snprintf(station, sizeof station, "%.5s", one + at - 5);
        kind = 1;
    }
    if (kind == 0 || kind == 1) {
        if (load_set(names, t, bufs, &e)) goto out;
        docs = malloc(sizeof *docs);
        if (!docs) { sea_fail(&e, "io", src, 0, 0, "out of memory"); goto out; }
        n = 1;
        if ((kind ? sea_ndbc_historical : sea_ndbc_realtime)(t, station, when, docs, &e)) goto out;
    } else {
        if (sea_load(one, &bufs[0], &t[0].len, &e)) goto out;
        t[0].data = bufs[0];
        t[0].name = base_name(one);
        if (kind < 0) kind = !strncmp(bufs[0], "'WAVEWATCH III SPECTRA'", 23) ? 2
                           : strstr(bufs[0], "waveEnergyDensity") ? 3 : -1;
        if (kind == 2) {
            if (sea_ww3(&t[0], point, &docs, &n, &e)) goto out;
            if (when) { /* one time of the forecast */
                int keep = -1;
                for (int i = 0; i < n; i++) if (!strcmp(docs[i].time, canon)) keep = i;
                if (keep < 0) { sea_fail(&e, "no_time", t[0].name, 0, 0, "no time %s in the file", canon); goto out; }
                docs[0] = docs[keep];
                n = 1;
            }
        } else if (kind == 3) {
            if (!station[0]) snprintf(station, sizeof station, "%.*s", (int)strcspn(t[0].name, "_.?"), t[0].name);
            docs = malloc(sizeof *docs);
            if (!docs) { sea_fail(&e, "io", src, 0, 0, "out of memory"); goto out; }
            n = 1;
            if (sea_cdip(&t[0], station, when, docs, &e)) goto out;
        } else {
            sea_fail(&e, "bad_header", t[0].name, 1, 0, "not a sea this reader knows (NDBC files are recognised "
                     "by their names, WAVEWATCH III and CDIP by their text)");
            goto out;
        }
    }
    if (target) {
        for (int i = 0; i < n; i++) {
            char line[400];
            sea_doc_summary(&docs[i], line, sizeof line);
            fprintf(stderr, "%s\n", line);
        }
        rc = tap_sea_send(target, docs, n, speed, token, tail, 15.0);
        goto out;
    }
    cJSON *list = kind == 2 ? cJSON_CreateArray() : NULL;
    for (int i = 0; i < n; i++) print_doc(&docs[i], list);
    rc = print_json(list ? list : sea_doc_json(&docs[0]));
out:
    if (e.code[0]) rc = sea_error(&e);
    for (int k = 0; k < 5; k++) free(bufs[k]);
    free(docs);
    return rc;
}

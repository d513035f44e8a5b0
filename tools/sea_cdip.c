/* sea_cdip.c — CDIP's OPeNDAP text answer (a dataset's URL + ".ascii?var,var,...")
 * into a "moments" document.
 *
 * The answer (DAP 2 ASCII): a "Dataset { ... }" description, a line of dashes, then per
 * variable a header and its values, comma separated, arrays of two dimensions one row
 * per line after its index:
 *     waveFrequency[64]                       (or Grid maps: waveEnergyDensity.waveFrequency[64])
 *     0.025, 0.03, ...
 *     waveEnergyDensity.waveEnergyDensity[2][64]
 *     [0], 1.2E-4, ...
 *     metaWaterDepth, 52.0                    (a scalar: on its header line)
 * Read: waveTime (s since 1970), waveFrequency, waveBandwidth (Hz: CDIP gives the widths),
 * waveEnergyDensity (m^2/Hz), waveA1Value, waveB1Value, waveA2Value, waveB2Value
 * (already in the document's frame: from, clockwise from north), and if there
 * waveHs (checked against 4 sqrt(m0)), waveFlagPrimary (1 = good), metaWaterDepth.
 * Fill values (-999) and NaN are missing values: an error. */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "sea.h"

#define MAX_VALUES (1 << 20)

struct var {
    char name[64];
    int nv, cap;
    double *v;
    long *line;
};

enum { V_TIME, V_FREQ, V_BW, V_E, V_A1, V_B1, V_A2, V_B2, V_HS, V_FLAG, V_DEPTH, NVARS };
static const char *const NAMES[NVARS] = {"waveTime", "waveFrequency", "waveBandwidth", "waveEnergyDensity",
                                         "waveA1Value", "waveB1Value", "waveA2Value", "waveB2Value", "waveHs",
                                         "waveFlagPrimary", "metaWaterDepth"};

static int push(struct var *v, double x, long line)
{
    if (v->nv == v->cap) {
        int cap = v->cap ? 2 * v->cap : 64;
        if (cap > MAX_VALUES) return -1;
        double *a = realloc(v->v, (size_t)cap * sizeof *a);
        if (!a) return -1;
        v->v = a;
        long *b = realloc(v->line, (size_t)cap * sizeof *b);
        if (!b) return -1;
        v->line = b;
        v->cap = cap;
    }
    v->v[v->nv] = x;
    v->line[v->nv++] = line;
    return 0;
}

/* Comma-separated numbers of s (after an optional "[i]," index) into v. */
static int values(const char *s, struct var *v, long line, const char *file, struct sea_err *e)
{
    while (*s == '[') { /* row index */
        const char *q = strchr(s, ']');
        if (!q) return sea_fail(e, "bad_number", file, line, 0, "unclosed row index \"%.40s\"", s);
        s = q + 1;
        while (*s == ' ' || *s == ',') s++;
    }
    while (*s) {
        while (*s == ' ' || *s == '\t' || *s == '\r') s++;
        if (!*s) break;
        char *end;
        double x = sea_strtod(s, &end);
        /* OPeNDAP writes a NaN as such: a missing value, not a bad number */
        static const char *const words[4] = {"nan", "NaN", "inf", "Inf"};
        for (int w = 0; w < 4 && end == s; w++)
            if (!strncmp(s, words[w], 3)) {
                x = w < 2 ? NAN : INFINITY;
                end = (char *)s + 3;
            }
        const char *after = end;
        while (*after == ' ' || *after == '\t' || *after == '\r') after++;
        if (end == s || (*after && *after != ','))
            return sea_fail(e, "bad_number", file, line, v->nv + 1, "\"%.40s\" is not a number", s);
        if (push(v, x, line)) return sea_fail(e, "io", file, line, 0, "more than %d values", MAX_VALUES);
        s = *after ? after + 1 : after;
    }
    return 0;
}

/* The variable a header line names: "a.b[...]" is b (a Grid's map, or the array itself when a == b). */
static int which(const char *hdr, char *name, size_t n)
{
    size_t k = strcspn(hdr, "[,");
    const char *dot = memchr(hdr, '.', k);
    const char *s = dot ? dot + 1 : hdr;
    size_t len = (size_t)(hdr + k - s);
    snprintf(name, n, "%.*s", (int)(len < n ? len : n - 1), s);
    for (int i = 0; i < NVARS; i++) if (!strcmp(name, NAMES[i])) return i;
    return -1;
}

static int is_header(const char *s) { return isalpha((unsigned char)*s) != 0; }

static int parse(const struct sea_text *f, struct var vars[NVARS], struct sea_err *e)
{
    size_t pos = 0;
    long no = 0;
    int body = 0, cur = -1, seen_dds = 0;
    char line[65536];
    while (pos < f->len) {
        const char *s = f->data + pos, *nl = memchr(s, '\n', f->len - pos);
        size_t n = nl ? (size_t)(nl - s) : f->len - pos;
        pos += n + (nl ? 1 : 0);
        no++;
        if (n >= sizeof line) return sea_fail(e, "bad_number", f->name, no, 0, "a line of more than %zu bytes",
                                              sizeof line);
        memcpy(line, s, n);
        line[n] = 0;
        char *t = line;
        while (*t == ' ' || *t == '\t') t++;
        size_t tl = strlen(t);
        while (tl && (t[tl - 1] == '\r' || t[tl - 1] == ' ')) t[--tl] = 0;
        if (!body) {
            if (!strncmp(t, "Dataset", 7)) seen_dds = 1;
            if (tl >= 8 && strspn(t, "-") == tl) { body = 1; continue; }
            if (seen_dds) continue;
            body = 1; /* no description: the values alone */
        }
        if (!tl) { cur = -1; continue; }
        if (is_header(t)) {
            char name[64];
            int v = which(t, name, sizeof name);
            cur = -1;
            if (v >= 0 && vars[v].nv == 0) cur = v; /* the first appearance: later ones are maps repeated */
            char *comma = strchr(t, ',');
            if (comma && cur >= 0 && !strchr(t, '[')) { /* a scalar: "name, value" */
                if (values(comma + 1, &vars[cur], no, f->name, e)) return -1;
                cur = -1;
            }
            continue;
        }
        if (cur >= 0 && values(t, &vars[cur], no, f->name, e)) return -1;
    }
    if (!body) return sea_fail(e, "bad_header", f->name, no, 0, "no values after the dataset description");
    return 0;
}

int sea_cdip(const struct sea_text *f, const char *station, const char *want_time, struct sea_doc *d,
             struct sea_err *e)
{
    struct var vars[NVARS];
    memset(vars, 0, sizeof vars);
    int rc = -1;
    char want[24];
    if (want_time && sea_time_canon(want_time, want)) {
        sea_fail(e, "no_time", "", 0, 0, "--time %.40s is not YYYY-MM-DDThh:mm[:ss]Z", want_time);
        goto out;
    }
    if (parse(f, vars, e)) goto out;
    for (int i = 0; i <= V_B2; i++)
        if (!vars[i].nv) {
            sea_fail(e, "bad_header", f->name, 0, 0, "no %s in the answer", NAMES[i]);
            goto out;
        }
    int nt = vars[V_TIME].nv, nf = vars[V_FREQ].nv;
    if (nf > SEA_MAX_FREQ) {
        sea_fail(e, "too_many_bands", f->name, vars[V_FREQ].line[0], SEA_MAX_FREQ + 1, "%d bands (at most %d)", nf,
                 SEA_MAX_FREQ);
        goto out;
    }
    if (vars[V_BW].nv != nf) {
        struct var *b = &vars[V_BW];
        sea_fail(e, b->nv < nf ? "truncated" : "bands_mismatch", f->name, b->line[b->nv - 1], 0,
                 "%d band widths for %d bands", b->nv, nf);
        goto out;
    }
    for (int i = V_E; i <= V_B2; i++) {
        struct var *v = &vars[i];
        if (v->nv != nt * nf) {
            sea_fail(e, v->nv < nt * nf ? "truncated" : "bands_mismatch", f->name, v->line[v->nv - 1],
                     v->nv % nf ? v->nv % nf + 1 : 0, "%s has %d values, %d times x %d bands need %d", NAMES[i],
                     v->nv, nt, nf, nt * nf);
            goto out;
        }
    }
    /* The record: the newest, or the one at want. */
    int t = -1;
    char when[24] = "";
    for (int k = 0; k < nt; k++) {
        double s = vars[V_TIME].v[k];
        if (!(s > -1e11 && s < 1e11)) {
            sea_fail(e, "out_of_range", f->name, vars[V_TIME].line[k], 0, "waveTime %g", s);
            goto out;
        }
        time_t tt = (time_t)llround(s);
        struct tm tm;
        char w[24];
        gmtime_r(&tt, &tm);
        strftime(w, sizeof w, "%Y-%m-%dT%H:%M:%SZ", &tm);
        if (want_time ? !strcmp(w, want) : (t < 0 || s > vars[V_TIME].v[t])) { t = k; snprintf(when, sizeof when, "%s", w); }
    }
    if (t < 0) {
        sea_fail(e, "no_time", f->name, 0, 0, "no record at %s", want);
        goto out;
    }
    if (vars[V_FLAG].nv == nt && vars[V_FLAG].v[t] != 1) {
        sea_fail(e, "flagged", f->name, vars[V_FLAG].line[t], 0, "waveFlagPrimary is %g at %s (1 = good)",
                 vars[V_FLAG].v[t], when);
        goto out;
    }
    memset(d, 0, sizeof *d);
    d->form = SEA_MOMENTS;
    d->nf = nf;
    snprintf(d->source, sizeof d->source, "CDIP %s", station);
    snprintf(d->time, sizeof d->time, "%s", when);
    d->depth = vars[V_DEPTH].nv ? vars[V_DEPTH].v[0] : NAN;
    if (!(d->depth > 0 && d->depth < 20000)) d->depth = NAN; /* fill or nonsense: unknown */
    d->file_hs = vars[V_HS].nv == nt ? vars[V_HS].v[t] : NAN;
    if (isfinite(d->file_hs) && d->file_hs <= -999) d->file_hs = NAN;
    double *out[8] = {NULL, d->freq, d->bw, d->energy, d->a1, d->b1, d->a2, d->b2};
    for (int i = V_FREQ; i <= V_B2; i++)
        for (int k = 0; k < nf; k++) {
            int at = i <= V_BW ? k : t * nf + k;
            double x = vars[i].v[at];
            if (!isfinite(x) || x <= -999) {
                sea_fail(e, "missing", f->name, vars[i].line[at], k + 1, "%s is missing (%g) at %s", NAMES[i], x, when);
                goto out;
            }
            out[i][k] = x;
        }
    rc = sea_doc_check(d, f->name, e);
out:
    for (int i = 0; i < NVARS; i++) {
        free(vars[i].v);
        free(vars[i].line);
    }
    return rc;
}

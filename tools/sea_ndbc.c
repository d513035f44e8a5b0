/* sea_ndbc.c — NDBC's directional wave files into a "moments" sea document.
 *
 * Realtime (45 days, newest row first), one row per time in each of five files:
 *   .data_spec  YYYY MM DD hh mm SepFreq  C11 (f) C11 (f) ...     m^2/Hz
 *   .swdir      YYYY MM DD hh mm  alpha1 (f) ...                  degrees, from
 *   .swdir2     ... alpha2 (f) ...;  .swr1 / .swr2  ... r1 / r2 (f) ... in 0..1
 * Historical ({id}{w,d,i,j,k}{year}.txt): a header "#YY MM DD hh mm .0200 .0325 ..."
 * (older years: no minute column, "YYYY" or "YY"), then one row of values per time.
 * Missing values: MM, 999(.0), and 99 in historical r files; r1, r2 are stored
 * x100 in some historical years (recognised when a value of the row is > 1).
 * A missing direction or r is accepted in a band whose C11 is 0 (NDBC writes
 * 999 there: no energy, no direction; its coefficients are 0); anywhere else it
 * is an error. Only the chosen row of each file is read past its time columns.
 * No file gives band widths: they are derived from neighbouring centres. */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sea.h"

#define MAX_TOK 1024

/* A line of a file, split at white space in a scratch copy. */
struct line {
    long no;
    int cut;        /* longer than buf: refused (sea_line_ok) rather than read in part */
    int ntok;
    char *tok[MAX_TOK];
    char buf[16384];
};

/* Next non-empty line from *pos; 0 at the end. A line longer than the
 * buffer is marked cut (line_ok refuses it); one with more than MAX_TOK
 * tokens holds more than SEA_MAX_FREQ bands, which the band count refuses. */
static int next_line(const struct sea_text *f, size_t *pos, long *lineno, struct line *l)
{
    while (*pos < f->len) {
        const char *s = f->data + *pos, *nl = memchr(s, '\n', f->len - *pos);
        size_t n = nl ? (size_t)(nl - s) : f->len - *pos;
        *pos += n + (nl ? 1 : 0);
        (*lineno)++;
        l->cut = n >= sizeof l->buf;
        if (l->cut) n = sizeof l->buf - 1;
        memcpy(l->buf, s, n);
        l->buf[n] = 0;
        l->no = *lineno;
        l->ntok = 0;
        for (char *save = NULL, *t = strtok_r(l->buf, " \t\r", &save); t && l->ntok < MAX_TOK;
             t = strtok_r(NULL, " \t\r", &save))
            l->tok[l->ntok++] = t;
        if (l->ntok) return 1;
    }
    return 0;
}

static int line_ok(const struct line *l, const char *file, struct sea_err *e)
{
    if (l->cut) return sea_fail(e, "bad_number", file, l->no, 0, "a line of more than %zu bytes", sizeof l->buf - 1);
    return 0;
}

static int parse_num(const char *t, double *v)
{
    char *end;
    if (!*t) return -1;
    *v = sea_strtod(t, &end);
    return *end || end == t || !isfinite(*v) ? -1 : 0;
}

static int parse_int(const char *t, int *v)
{
    char *end;
    if (!*t || strspn(t, "0123456789") != strlen(t)) return -1; /* digits only: no sign, no blanks */
    long x = strtol(t, &end, 10);
    if (*end || end == t || x < 0 || x > 99999) return -1;
    *v = (int)x;
    return 0;
}

/* The time of a row from its ntime leading columns (4: no minute). */
static int row_time(const struct line *l, int ntime, const char *file, char out[24], struct sea_err *e)
{
    int v[5] = {0};
    if (l->ntok < ntime) return sea_fail(e, "truncated", file, l->no, 0, "the row ends in its time columns");
    for (int k = 0; k < ntime; k++)
        if (parse_int(l->tok[k], &v[k]))
            return sea_fail(e, "bad_number", file, l->no, 0, "time column %d is \"%.40s\", not a whole number", k + 1,
                            l->tok[k]);
    if (v[0] < 100) v[0] += 1900; /* the oldest files write two-digit years, all 19xx */
    if (v[1] < 1 || v[1] > 12 || v[2] < 1 || v[2] > 31 || v[3] > 23 || v[4] > 59)
        return sea_fail(e, "out_of_range", file, l->no, 0, "no such time: %d %d %d %d %d", v[0], v[1], v[2], v[3],
                        v[4]);
    snprintf(out, 24, "%04u-%02u-%02uT%02u:%02u:00Z", (unsigned)v[0] % 10000u, (unsigned)v[1] % 100u,
             (unsigned)v[2] % 100u, (unsigned)v[3] % 100u, (unsigned)v[4] % 100u);
    return 0;
}

/* A value token: 1 = missing (MM, >= 999, or == miss99 when set), 0 = *v, -1 = not a number. */
static int value(const char *t, int miss99, double *v)
{
    if (!strcmp(t, "MM")) return 1;
    if (parse_num(t, v)) return -1;
    if (*v >= 999 || (miss99 && *v == 99)) return 1;
    return 0;
}

/* One file's values at the chosen time. */
struct row {
    const char *file;
    long line;
    int n;
    double f[SEA_MAX_FREQ], v[SEA_MAX_FREQ];
    char miss[SEA_MAX_FREQ];
};

/* Realtime pairs "value (freq)" from token `first` on. */
static int rt_pairs(const struct line *l, int first, const char *file, struct row *r, struct sea_err *e)
{
    r->file = file;
    r->line = l->no;
    r->n = 0;
    for (int k = first; k < l->ntok; k += 2) {
        int band = r->n + 1;
        if (r->n == SEA_MAX_FREQ)
            return sea_fail(e, "too_many_bands", file, l->no, band, "more than %d bands", SEA_MAX_FREQ);
        if (k + 1 >= l->ntok)
            return sea_fail(e, "truncated", file, l->no, band, "the row ends after the value \"%.40s\", before its "
                            "frequency", l->tok[k]);
        const char *ft = l->tok[k + 1];
        size_t fl = strlen(ft);
        char fb[64];
        if (fl < 3 || fl >= sizeof fb || ft[0] != '(' || ft[fl - 1] != ')')
            return sea_fail(e, "bad_number", file, l->no, band, "\"%.40s\" is not a frequency \"(0.033)\"", ft);
        memcpy(fb, ft + 1, fl - 2);
        fb[fl - 2] = 0;
        if (parse_num(fb, &r->f[r->n]))
            return sea_fail(e, "bad_number", file, l->no, band, "frequency \"%.40s\" is not a number", ft);
        int m = value(l->tok[k], 0, &r->v[r->n]);
        if (m < 0) return sea_fail(e, "bad_number", file, l->no, band, "\"%.40s\" is not a number", l->tok[k]);
        r->miss[r->n] = (char)m;
        r->n++;
    }
    return 0;
}

/* Shared: five rows -> the document. kind[k]: 0 C11, 1 alpha1, 2 alpha2, 3 r1, 4 r2.
 * hist: r may be stored x100. */
static int combine(struct row r[5], int hist, const char *station, const char *time, struct sea_doc *d,
                   struct sea_err *e)
{
    static const char *const what[5] = {"C11", "alpha1", "alpha2", "r1", "r2"};
    int n = r[0].n;
    if (n < 1) return sea_fail(e, "truncated", r[0].file, r[0].line, 0, "the row has no bands");
    for (int k = 1; k < 5; k++) {
        if (r[k].n < n)
            return sea_fail(e, "truncated", r[k].file, r[k].line, r[k].n + 1, "the row has %d bands, %s has %d",
                            r[k].n, r[0].file, n);
        if (r[k].n > n)
            return sea_fail(e, "bands_mismatch", r[k].file, r[k].line, n + 1, "the row has %d bands, %s has %d",
                            r[k].n, r[0].file, n);
        for (int i = 0; i < n; i++)
            if (fabs(r[k].f[i] - r[0].f[i]) > 5e-5)
                return sea_fail(e, "bands_mismatch", r[k].file, r[k].line, i + 1, "frequency %g Hz, %s has %g Hz",
                                r[k].f[i], r[0].file, r[0].f[i]);
    }
    double scale[5] = {1, 1, 1, 1, 1};
    for (int k = 3; hist && k < 5; k++) {
        double mx = 0;
        for (int i = 0; i < n; i++) if (!r[k].miss[i] && r[k].v[i] > mx) mx = r[k].v[i];
        if (mx > 1) scale[k] = 0.01; /* this year stores r x 100 */
    }
    memset(d, 0, sizeof *d);
    d->form = SEA_MOMENTS;
    d->nf = n;
    d->depth = NAN;
    d->file_hs = NAN;
    snprintf(d->source, sizeof d->source, "NDBC %s", station);
    snprintf(d->time, sizeof d->time, "%s", time);
    for (int i = 0; i < n; i++) {
        d->freq[i] = r[0].f[i];
        if (r[0].miss[i])
            return sea_fail(e, "missing", r[0].file, r[0].line, i + 1, "C11 at %g Hz is missing", r[0].f[i]);
        if (r[0].v[i] < 0)
            return sea_fail(e, "out_of_range", r[0].file, r[0].line, i + 1, "C11 %g < 0", r[0].v[i]);
        d->energy[i] = r[0].v[i];
        double x[5];
        for (int k = 1; k < 5; k++) {
            x[k] = r[k].v[i] * scale[k];
            if (r[k].miss[i] && d->energy[i] != 0)
                return sea_fail(e, "missing", r[k].file, r[k].line, i + 1, "%s at %g Hz is missing and the band has "
                                "energy %g m^2/Hz", what[k], r[k].f[i], d->energy[i]);
            if (r[k].miss[i]) continue;
            if (k <= 2 ? (x[k] < 0 || x[k] > 360) : (x[k] < 0 || x[k] > 1))
                return sea_fail(e, "out_of_range", r[k].file, r[k].line, i + 1, "%s = %g is outside %s", what[k],
                                r[k].v[i], k <= 2 ? "0..360" : hist ? "0..1 (or 0..100)" : "0..1");
        }
        int none = r[1].miss[i] || r[2].miss[i] || r[3].miss[i] || r[4].miss[i];
        if (none) continue; /* a band without energy: coefficients 0 */
        double a1r = x[1] * M_PI / 180, a2r = x[2] * M_PI / 180;
        d->a1[i] = x[3] * cos(a1r);
        d->b1[i] = x[3] * sin(a1r);
        d->a2[i] = x[4] * cos(2 * a2r);
        d->b2[i] = x[4] * sin(2 * a2r);
    }
    sea_bandwidth_from_centres(d->freq, n, d->bw);
    return sea_doc_check(d, r[0].file, e);
}

/* Rows of a file: each line with its time, for choosing. */
struct times {
    int n, cap;
    char (*t)[24];
    long *line;
    size_t *pos;    /* offset of the line, to read it again */
};

static void times_free(struct times *t)
{
    free(t->t);
    free(t->line);
    free(t->pos);
}

/* Every row's time (ntime columns, from the first line that is not a header). */
static int scan_times(const struct sea_text *f, int ntime, struct times *t, struct line *l, struct sea_err *e)
{
    size_t pos = 0;
    long no = 0;
    memset(t, 0, sizeof *t);
    for (;;) {
        size_t at = pos;
        long at_no = no;
        if (!next_line(f, &pos, &no, l)) break;
        if (line_ok(l, f->name, e)) return -1;
        if (l->tok[0][0] == '#' || isalpha((unsigned char)l->tok[0][0])) continue; /* headers */
        if (t->n == t->cap) {
            int cap = t->cap ? 2 * t->cap : 256;
            void *a = realloc(t->t, cap * sizeof *t->t), *b = NULL, *c = NULL;
            if (a) t->t = a;
            if (a) b = realloc(t->line, cap * sizeof *t->line);
            if (b) t->line = b;
            if (b) c = realloc(t->pos, cap * sizeof *t->pos);
            if (c) t->pos = c;
            if (!c) return sea_fail(e, "io", f->name, 0, 0, "out of memory");
            t->cap = cap;
        }
        if (row_time(l, ntime, f->name, t->t[t->n], e)) return -1;
        t->line[t->n] = at_no;
        t->pos[t->n] = at;
        t->n++;
    }
    if (!t->n) return sea_fail(e, "truncated", f->name, no, 0, "no data rows");
    return 0;
}

static int find_time(const struct times *t, const char *when)
{
    for (int i = 0; i < t->n; i++) if (!strcmp(t->t[i], when)) return i;
    return -1;
}

/* The newest time every file has, or want. */
static int choose(const struct sea_text f[5], struct times t[5], const char *want, char out[24], struct sea_err *e)
{
    if (want) {
        for (int k = 0; k < 5; k++)
            if (find_time(&t[k], want) < 0)
                return sea_fail(e, "no_time", f[k].name, 0, 0, "no row at %s", want);
        snprintf(out, 24, "%s", want);
        return 0;
    }
    int best = -1;
    for (int i = 0; i < t[0].n; i++) {
        int all = 1;
        for (int k = 1; k < 5 && all; k++) all = find_time(&t[k], t[0].t[i]) >= 0;
        if (all && (best < 0 || strcmp(t[0].t[i], t[0].t[best]) > 0)) best = i;
    }
    if (best < 0) return sea_fail(e, "no_time", f[0].name, 0, 0, "no time is in all five files");
    snprintf(out, 24, "%s", t[0].t[best]);
    return 0;
}

/* Read the line of file f at row index i of t again. */
static void reread(const struct sea_text *f, const struct times *t, int i, struct line *l)
{
    size_t pos = t->pos[i];
    long no = t->line[i];
    next_line(f, &pos, &no, l);
}

static int want_canon(const char *want, char out[24], struct sea_err *e)
{
    if (want && sea_time_canon(want, out))
        return sea_fail(e, "no_time", "", 0, 0, "--time %.40s is not YYYY-MM-DDThh:mm[:ss]Z", want);
    return 0;
}

int sea_ndbc_realtime(const struct sea_text f[5], const char *station, const char *want_time, struct sea_doc *d,
                      struct sea_err *e)
{
    struct line *l = malloc(sizeof *l);
    struct row *r = malloc(5 * sizeof *r);
    struct times t[5] = {{0}};
    char want[24], when[24];
    int rc = -1;
    if (!l || !r) { sea_fail(e, "io", f[0].name, 0, 0, "out of memory"); goto out; }
    if (want_canon(want_time, want, e)) goto out;
    for (int k = 0; k < 5; k++)
        if (scan_times(&f[k], 5, &t[k], l, e)) goto out;
    if (choose(f, t, want_time ? want : NULL, when, e)) goto out;
    for (int k = 0; k < 5; k++) {
        reread(&f[k], &t[k], find_time(&t[k], when), l);
        int first = 5;
        double sep;
        if (k == 0) { /* SepFreq: the wind sea/swell separation, not a band */
            if (l->ntok < 6) { sea_fail(e, "truncated", f[k].name, l->no, 0, "the row ends before SepFreq"); goto out; }
            if (parse_num(l->tok[5], &sep)) {
                sea_fail(e, "bad_number", f[k].name, l->no, 0, "SepFreq \"%.40s\" is not a number", l->tok[5]);
                goto out;
            }
            first = 6;
        }
        if (rt_pairs(l, first, f[k].name, &r[k], e)) goto out;
    }
    rc = combine(r, 0, station, when, d, e);
out:
    for (int k = 0; k < 5; k++) times_free(&t[k]);
    free(l);
    free(r);
    return rc;
}

/* A historical header: time labels, then the band centres. */
static int hist_header(const struct sea_text *f, struct line *l, int *ntime, double *freq, int *nf, struct sea_err *e)
{
    size_t pos = 0;
    long no = 0;
    if (!next_line(f, &pos, &no, l)) return sea_fail(e, "bad_header", f->name, 1, 0, "the file is empty");
    if (line_ok(l, f->name, e)) return -1;
    int k = 0;
    double v;
    while (k < l->ntok && parse_num(l->tok[k], &v)) k++;
    const char *lab = l->tok[0] + (l->tok[0][0] == '#');
    if (k < 4 || k > 5 || (strcmp(lab, "YY") && strcmp(lab, "YYYY")))
        return sea_fail(e, "bad_header", f->name, l->no, 0, "expected \"#YY MM DD hh [mm] .0200 .0325 ...\", got "
                        "\"%.60s\"", l->tok[0]);
    *ntime = k;
    *nf = 0;
    for (; k < l->ntok; k++) {
        if (*nf == SEA_MAX_FREQ)
            return sea_fail(e, "too_many_bands", f->name, l->no, *nf + 1, "more than %d bands", SEA_MAX_FREQ);
        if (parse_num(l->tok[k], &freq[*nf]))
            return sea_fail(e, "bad_header", f->name, l->no, *nf + 1, "band centre \"%.40s\" is not a number",
                            l->tok[k]);
        (*nf)++;
    }
    if (!*nf) return sea_fail(e, "bad_header", f->name, l->no, 0, "the header names no bands");
    return 0;
}

int sea_ndbc_historical(const struct sea_text f[5], const char *station, const char *want_time, struct sea_doc *d,
                        struct sea_err *e)
{
    struct line *l = malloc(sizeof *l);
    struct row *r = malloc(5 * sizeof *r);
    struct times t[5] = {{0}};
    char want[24], when[24];
    int rc = -1, ntime[5];
    if (!l || !r) { sea_fail(e, "io", f[0].name, 0, 0, "out of memory"); goto out; }
    if (want_canon(want_time, want, e)) goto out;
    for (int k = 0; k < 5; k++) {
        r[k].file = f[k].name;
        if (hist_header(&f[k], l, &ntime[k], r[k].f, &r[k].n, e)) goto out;
        if (scan_times(&f[k], ntime[k], &t[k], l, e)) goto out;
    }
    if (choose(f, t, want_time ? want : NULL, when, e)) goto out;
    for (int k = 0; k < 5; k++) {
        reread(&f[k], &t[k], find_time(&t[k], when), l);
        r[k].line = l->no;
        int have = l->ntok - ntime[k];
        if (have < r[k].n) {
            sea_fail(e, "truncated", f[k].name, l->no, have + 1, "the row has %d values, the header %d bands", have,
                     r[k].n);
            goto out;
        }
        if (have > r[k].n) {
            sea_fail(e, "bands_mismatch", f[k].name, l->no, r[k].n + 1, "the row has %d values, the header %d bands",
                     have, r[k].n);
            goto out;
        }
        for (int i = 0; i < r[k].n; i++) {
            int m = value(l->tok[ntime[k] + i], k >= 3, &r[k].v[i]);
            if (m < 0) {
                sea_fail(e, "bad_number", f[k].name, l->no, i + 1, "\"%.40s\" is not a number", l->tok[ntime[k] + i]);
                goto out;
            }
            r[k].miss[i] = (char)m;
        }
    }
    /* The five headers' bands must agree: combine() compares them as it does realtime rows,
     * but a header is the line to name. */
    for (int k = 1; k < 5; k++)
        for (int i = 0; i < r[k].n && i < r[0].n; i++)
            if (fabs(r[k].f[i] - r[0].f[i]) > 5e-5) {
                sea_fail(e, "bands_mismatch", f[k].name, 1, i + 1, "band centre %g Hz, %s has %g Hz", r[k].f[i],
                         f[0].name, r[0].f[i]);
                goto out;
            }
    for (int k = 1; k < 5; k++)
        if (r[k].n != r[0].n) {
            sea_fail(e, "bands_mismatch", f[k].name, 1, 0, "%d bands, %s has %d", r[k].n, f[0].name, r[0].n);
            goto out;
        }
    rc = combine(r, 1, station, when, d, e);
out:
    for (int k = 0; k < 5; k++) times_free(&t[k]);
    free(l);
    free(r);
    return rc;
}

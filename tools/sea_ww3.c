/* sea_ww3.c — WAVEWATCH III point-spectrum text (ww3_outp) into "spectrum2d" documents.
 *
 *   'WAVEWATCH III SPECTRA'     NF    ND    NP 'grid name'
 *   NF frequencies (Hz), then ND directions (radians), free format over lines
 *   per time:  YYYYMMDD HHMMSS
 *     per point: 'NAME      ' lat lon depth U10 Udir Ucur Ucurdir
 *                NF x ND values of F(f, theta), m^2/(Hz rad), frequency fastest
 * Directions are where waves go TO, written as mod(2.5 pi - theta, 2 pi): the compass
 * bearing (clockwise from north) of the going-to direction. The document's direction is
 * where they come FROM: bearing + 180 deg. Fortran's fixed columns can join numbers
 * ("37.75-122.83"), so numbers are read one after the other (sea_strtod), not split at
 * blanks. Band widths: the file's frequencies are geometric (factor r, 1.1 in WW3's
 * usual set-up) and band i spans f_i (r - 1/r) / 2; otherwise from neighbouring centres. */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sea.h"

struct cur {
    const struct sea_text *f;
    size_t pos;
    long line;       /* of pos */
    long last;       /* of the last number read: where a truncated file is said to end */
};

static void skip_ws(struct cur *c)
{
    while (c->pos < c->f->len && isspace((unsigned char)c->f->data[c->pos])) {
        if (c->f->data[c->pos] == '\n') c->line++;
        c->pos++;
    }
}

/* The next number. 0, 1 at the end of the file, -1 (e set) on a token that is not one. */
static int num(struct cur *c, double *v, int band, struct sea_err *e)
{
    skip_ws(c);
    if (c->pos >= c->f->len) return 1;
    const char *s = c->f->data + c->pos;
    char *end;
    *v = sea_strtod(s, &end);
    size_t k = (size_t)(end - s);
    if (!k || (end < c->f->data + c->f->len && *end && !isspace((unsigned char)*end) && *end != '-' && *end != '+')
        || !isfinite(*v)) {
        int n = 0;
        while (s + n < c->f->data + c->f->len && s[n] && !isspace((unsigned char)s[n]) && n < 40) n++;
        return sea_fail(e, "bad_number", c->f->name, c->line, band, "\"%.*s\" is not a number", n, s);
    }
    c->pos += k;
    c->last = c->line;
    return 0;
}

/* The rest of the current line (after blanks) into buf; 0, or 1 at the end of the file. */
static int rest_of_line(struct cur *c, char *buf, size_t n)
{
    skip_ws(c);
    if (c->pos >= c->f->len) return 1;
    const char *s = c->f->data + c->pos, *nl = memchr(s, '\n', c->f->len - c->pos);
    size_t k = nl ? (size_t)(nl - s) : c->f->len - c->pos;
    snprintf(buf, n, "%.*s", (int)(k < n ? k : n - 1), s);
    c->pos += k;
    return 0;
}

/* 'quoted' at the start of s into out; returns the text after it, NULL if none. */
static const char *quoted(const char *s, char *out, size_t n)
{
    if (*s != '\'') return NULL;
    const char *q = strchr(s + 1, '\'');
    if (!q) return NULL;
    size_t k = (size_t)(q - s - 1);
    while (k && s[k] == ' ') k--; /* names are blank-padded to 10 characters */
    snprintf(out, n, "%.*s", (int)(k < n ? k : n - 1), s + 1);
    return q + 1;
}

static int cmp_dir(const void *a, const void *b)
{
    double x = ((const double *)a)[0], y = ((const double *)b)[0];
    return x < y ? -1 : x > y;
}

int sea_ww3(const struct sea_text *f, const char *point, struct sea_doc **docs, int *n, struct sea_err *e)
{
    struct cur c = {f, 0, 1, 1};
    char line[512], name[64], grid[128];
    *docs = NULL;
    *n = 0;
    if (rest_of_line(&c, line, sizeof line))
        return sea_fail(e, "bad_header", f->name, 1, 0, "the file is empty");
    const char *p = quoted(line, name, sizeof name);
    int nf, nd, np, k = 0;
    if (!p || strcmp(name, "WAVEWATCH III SPECTRA"))
        return sea_fail(e, "bad_header", f->name, 1, 0, "not a WAVEWATCH III spectrum file (no 'WAVEWATCH III "
                        "SPECTRA' at its start)");
    if (sscanf(p, "%d %d %d %n", &nf, &nd, &np, &k) != 3 || !quoted(p + k, grid, sizeof grid))
        return sea_fail(e, "bad_header", f->name, 1, 0, "expected NF ND NP 'grid' after the title");
    if (nf < 1 || nf > SEA_MAX_FREQ || nd < 1 || nd > SEA_MAX_DIR)
        return sea_fail(e, "too_many_bands", f->name, 1, 0, "%d frequencies and %d directions (at most %d and %d)",
                        nf, nd, SEA_MAX_FREQ, SEA_MAX_DIR);
    if (np < 1 || np > 100000) return sea_fail(e, "bad_header", f->name, 1, 0, "%d points", np);
    double freq[SEA_MAX_FREQ], dir[SEA_MAX_DIR][2], bw[SEA_MAX_FREQ];
    for (int i = 0; i < nf + nd; i++) {
        double v;
        int r = num(&c, &v, i < nf ? i + 1 : 0, e);
        if (r > 0) return sea_fail(e, "truncated", f->name, c.last, i < nf ? i + 1 : 0, "the file ends in its %s",
                                   i < nf ? "frequencies" : "directions");
        if (r < 0) return -1;
        if (i < nf) {
            freq[i] = v;
            if (!(v > 0) || (i > 0 && !(v > freq[i - 1])))
                return sea_fail(e, "out_of_range", f->name, c.line, i + 1, "frequency %g Hz: bands must increase "
                                "from > 0", v);
            continue;
        }
        if (v < 0 || v > 2 * M_PI + 1e-6)
            return sea_fail(e, "out_of_range", f->name, c.line, 0, "direction %d is %g rad, outside 0..2 pi",
                            i - nf + 1, v);
        double from = fmod(v * 180 / M_PI + 180, 360);
        if (from >= 360 - 1e-9) from = 0;
        dir[i - nf][0] = from;
        dir[i - nf][1] = i - nf; /* its column in the file */
    }
    qsort(dir, (size_t)nd, sizeof dir[0], cmp_dir);
    for (int j = 1; j < nd; j++)
        if (dir[j][0] - dir[j - 1][0] < 1e-6)
            return sea_fail(e, "out_of_range", f->name, 0, 0, "two directions are the same (%g deg from)", dir[j][0]);
    double ratio = nf > 1 ? pow(freq[nf - 1] / freq[0], 1.0 / (nf - 1)) : 1.1;
    int geometric = 1;
    for (int i = 1; i < nf; i++) geometric &= fabs(freq[i] / freq[i - 1] / ratio - 1) < 5e-3;
    if (geometric)
        for (int i = 0; i < nf; i++) bw[i] = freq[i] * (ratio - 1 / ratio) / 2;
    else
        sea_bandwidth_from_centres(freq, nf, bw);

    int cap = 0;
    for (;;) {
        long tline;
        skip_ws(&c);
        tline = c.line;
        if (rest_of_line(&c, line, sizeof line)) break; /* the end of the file */
        int ymd, hms, used = 0;
        if (sscanf(line, "%8d %6d%n", &ymd, &hms, &used) != 2 || line[used])
            return sea_fail(e, "bad_header", f->name, tline, 0, "expected a time \"YYYYMMDD HHMMSS\", got \"%.40s\"",
                            line);
        char when[24];
        snprintf(line, sizeof line, "%04d-%02d-%02dT%02d:%02d:%02dZ", ymd / 10000, ymd / 100 % 100, ymd % 100,
                 hms / 10000, hms / 100 % 100, hms % 100);
        if (sea_time_canon(line, when))
            return sea_fail(e, "out_of_range", f->name, tline, 0, "no such time: %08d %06d", ymd, hms);
        int found = 0;
        for (int ip = 0; ip < np; ip++) {
            skip_ws(&c);
            long pline = c.line;
            char pname[64];
            if (rest_of_line(&c, line, sizeof line))
                return sea_fail(e, "truncated", f->name, pline, 0, "the file ends before point %d of %s", ip + 1, when);
            const char *after = quoted(line, pname, sizeof pname);
            double ll[3] = {NAN, NAN, NAN}, depth; /* lat lon depth, one after the other */
            int got = 0;
            for (const char *q = after; q && got < 3; got++) {
                char *end;
                while (isspace((unsigned char)*q)) q++;
                ll[got] = sea_strtod(q, &end);
                if (end == q) break;
                q = end;
            }
            depth = ll[2];
            if (got < 3)
                return sea_fail(e, "bad_header", f->name, pline, 0, "expected 'NAME' lat lon depth ..., got \"%.40s\"",
                                line);
            int mine = !found && (!point || !strcmp(point, pname));
            struct sea_doc *d = NULL;
            if (mine) {
                if (*n == SEA_MAX_TIMES)
                    return sea_fail(e, "too_many_bands", f->name, tline, 0, "more than %d times", SEA_MAX_TIMES);
                if (*n == cap) {
                    int ncap = cap ? 2 * cap : 8;
                    struct sea_doc *nd_ = realloc(*docs, (size_t)ncap * sizeof *nd_);
                    if (!nd_) return sea_fail(e, "io", f->name, 0, 0, "out of memory");
                    *docs = nd_;
                    cap = ncap;
                }
                d = &(*docs)[(*n)++];
                memset(d, 0, sizeof *d);
                d->form = SEA_SPECTRUM2D;
                d->nf = nf;
                d->nd = nd;
                d->depth = depth > 0 && depth < 20000 ? depth : NAN;
                d->file_hs = NAN;
                snprintf(d->source, sizeof d->source, "WW3 %s", pname);
                snprintf(d->time, sizeof d->time, "%s", when);
                memcpy(d->freq, freq, sizeof freq);
                memcpy(d->bw, bw, sizeof bw);
                for (int j = 0; j < nd; j++) d->dir[j] = dir[j][0];
                found = 1;
            }
            int col[SEA_MAX_DIR]; /* file column -> sorted index */
            for (int j = 0; j < nd; j++) col[(int)dir[j][1]] = j;
            for (int v = 0; v < nf * nd; v++) {
                double x;
                int r = num(&c, &x, v % nf + 1, e);
                if (r > 0)
                    return sea_fail(e, "truncated", f->name, c.last, v % nf + 1, "the file ends after %d of the %d "
                                    "values of %s at %s", v, nf * nd, pname, when);
                if (r < 0) return -1;
                if (d) d->e2[v % nf][col[v / nf]] = x;
            }
            if (d && sea_doc_check(d, f->name, e)) {
                e->line = pline;
                return -1;
            }
        }
        if (!found) return sea_fail(e, "bad_header", f->name, tline, 0, "no point named \"%s\" at %s", point, when);
    }
    if (!*n) return sea_fail(e, "truncated", f->name, c.line, 0, "no time in the file");
    return 0;
}

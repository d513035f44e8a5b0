/* sea_doc.c — the sea document: its limits, its JSON (cJSON), its summary. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sea.h"

int sea_fail(struct sea_err *e, const char *code, const char *file, long line, int band, const char *fmt, ...)
{
    if (!e || e->code[0]) return -1;
    snprintf(e->code, sizeof e->code, "%s", code);
    snprintf(e->file, sizeof e->file, "%s", file ? file : "");
    e->line = line;
    e->band = band;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e->msg, sizeof e->msg, fmt, ap);
    va_end(ap);
    return -1;
}

void sea_err_format(const struct sea_err *e, char *buf, size_t n)
{
    char where[320] = "", band[32] = "";
    if (e->file[0] && e->line > 0) snprintf(where, sizeof where, "%s:%ld: ", e->file, e->line);
    else if (e->file[0]) snprintf(where, sizeof where, "%s: ", e->file);
    if (e->band > 0) snprintf(band, sizeof band, "band %d: ", e->band);
    snprintf(buf, n, "error %s: %s%s%s", e->code, where, band, e->msg);
}

void sea_bandwidth_from_centres(const double *f, int n, double *bw)
{
    if (n == 1) { bw[0] = f[0] * 0.1; return; } /* one band: nothing to measure it against; 10 % */
    for (int i = 0; i < n; i++) {
        double lo = i > 0 ? (f[i] - f[i - 1]) / 2 : (f[1] - f[0]) / 2;
        double hi = i < n - 1 ? (f[i + 1] - f[i]) / 2 : (f[n - 1] - f[n - 2]) / 2;
        bw[i] = lo + hi;
    }
}

/* Width in radians of each direction of a 2-D spectrum: half the circular gap to each neighbour. */
static void dir_widths(const struct sea_doc *d, double *w)
{
    for (int j = 0; j < d->nd; j++) {
        if (d->nd == 1) { w[j] = 2 * M_PI; break; }
        double prev = d->dir[(j + d->nd - 1) % d->nd], next = d->dir[(j + 1) % d->nd];
        double lo = fmod(d->dir[j] - prev + 360.0, 360.0), hi = fmod(next - d->dir[j] + 360.0, 360.0);
        w[j] = (lo + hi) / 2 * M_PI / 180;
    }
}

/* S(f) of band i: C11, or the 2-D row integrated over direction. */
static double density(const struct sea_doc *d, int i, const double *w)
{
    if (d->form == SEA_MOMENTS) return d->energy[i];
    double s = 0;
    for (int j = 0; j < d->nd; j++) s += d->e2[i][j] * w[j];
    return s;
}

void sea_doc_stats(const struct sea_doc *d, struct sea_stats *st)
{
    double w[SEA_MAX_DIR];
    dir_widths(d, w);
    *st = (struct sea_stats){0};
    double best = -1;
    for (int i = 0; i < d->nf; i++) {
        double s = density(d, i, w);
        st->m0 += s * d->bw[i];
        if (s > best) { best = s; st->peak = i; }
    }
    int p = st->peak;
    st->hs = 4 * sqrt(st->m0);
    st->fp = d->nf ? d->freq[p] : 0;
    st->tp = st->fp > 0 ? 1 / st->fp : 0;
    double sx = 0, sy = 0;
    if (d->form == SEA_MOMENTS) {
        sx = d->a1[p];
        sy = d->b1[p];
    } else {
        for (int j = 0; j < d->nd; j++) {
            sx += d->e2[p][j] * w[j] * cos(d->dir[j] * M_PI / 180);
            sy += d->e2[p][j] * w[j] * sin(d->dir[j] * M_PI / 180);
        }
    }
    st->dir_peak = fmod(atan2(sy, sx) * 180 / M_PI + 360.0, 360.0);
}

void sea_doc_summary(const struct sea_doc *d, char *buf, size_t n)
{
    struct sea_stats st;
    sea_doc_stats(d, &st);
    char hs[64] = "";
    if (isfinite(d->file_hs)) snprintf(hs, sizeof hs, " (the file says %.2f m)", d->file_hs);
    snprintf(buf, n, "%s %s: Hs %.2f m%s, Tp %.2f s, from %.1f deg at the peak (%.4f Hz)", d->source, d->time,
             st.hs, hs, st.tp, st.dir_peak, st.fp);
}

static int bad(const double v) { return !isfinite(v); }

int sea_doc_check(const struct sea_doc *d, const char *file, struct sea_err *e)
{
    if (d->nf < 1 || d->nf > SEA_MAX_FREQ)
        return sea_fail(e, "too_many_bands", file, 0, 0, "%d frequencies (1..%d)", d->nf, SEA_MAX_FREQ);
    if (d->form == SEA_SPECTRUM2D && (d->nd < 1 || d->nd > SEA_MAX_DIR))
        return sea_fail(e, "too_many_bands", file, 0, 0, "%d directions (1..%d)", d->nd, SEA_MAX_DIR);
    for (int i = 0; i < d->nf; i++) {
        if (bad(d->freq[i]) || d->freq[i] <= 0 || (i > 0 && !(d->freq[i] > d->freq[i - 1])))
            return sea_fail(e, "out_of_range", file, 0, i + 1, "frequency %g Hz: bands must increase from > 0",
                            d->freq[i]);
        if (bad(d->bw[i]) || d->bw[i] <= 0)
            return sea_fail(e, "out_of_range", file, 0, i + 1, "band width %g Hz", d->bw[i]);
        if (d->form == SEA_MOMENTS) {
            if (bad(d->energy[i]) || d->energy[i] < 0)
                return sea_fail(e, "out_of_range", file, 0, i + 1, "energy %g m^2/Hz", d->energy[i]);
            const double *c[4] = {d->a1, d->b1, d->a2, d->b2};
            for (int k = 0; k < 4; k++)
                if (bad(c[k][i]) || fabs(c[k][i]) > 1 + 1e-9)
                    return sea_fail(e, "out_of_range", file, 0, i + 1, "%s = %g: |.| <= 1",
                                    (const char *[]){"a1", "b1", "a2", "b2"}[k], c[k][i]);
        } else {
            for (int j = 0; j < d->nd; j++)
                if (bad(d->e2[i][j]) || d->e2[i][j] < 0)
                    return sea_fail(e, "out_of_range", file, 0, i + 1, "energy %g at direction %g",
                                    d->e2[i][j], d->dir[j]);
        }
    }
    for (int j = 0; d->form == SEA_SPECTRUM2D && j < d->nd; j++) {
        if (bad(d->dir[j]) || d->dir[j] < 0 || d->dir[j] >= 360 || (j > 0 && !(d->dir[j] > d->dir[j - 1])))
            return sea_fail(e, "out_of_range", file, 0, 0, "direction %d (%g deg): distinct, in [0, 360)", j + 1,
                            d->dir[j]);
    }
    struct sea_stats st;
    sea_doc_stats(d, &st);
    if (!(st.m0 <= SEA_MAX_M0))
        return sea_fail(e, "out_of_range", file, 0, 0, "m0 = %g m^2 (Hs %.1f m): at most %g m^2", st.m0, st.hs,
                        SEA_MAX_M0);
    if (isfinite(d->file_hs) && d->file_hs > 0 && fabs(st.hs - d->file_hs) > 0.1 * d->file_hs)
        return sea_fail(e, "hs_mismatch", file, 0, 0, "the file's Hs %.3f m, its bands give 4 sqrt(m0) = %.3f m",
                        d->file_hs, st.hs);
    return 0;
}

static cJSON *array(const double *v, int n) { return cJSON_CreateDoubleArray(v, n); }

cJSON *sea_doc_json(const struct sea_doc *d)
{
    cJSON *j = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "form", d->form == SEA_MOMENTS ? "moments" : "spectrum2d");
    cJSON_AddStringToObject(j, "source", d->source);
    cJSON_AddStringToObject(j, "time", d->time);
    if (isfinite(d->depth)) cJSON_AddNumberToObject(j, "depth", d->depth);
    else cJSON_AddNullToObject(j, "depth");
    cJSON_AddItemToObject(j, "frequency", array(d->freq, d->nf));
    cJSON_AddItemToObject(j, "bandwidth", array(d->bw, d->nf));
    if (d->form == SEA_MOMENTS) {
        cJSON_AddItemToObject(j, "energy", array(d->energy, d->nf));
        cJSON_AddItemToObject(j, "a1", array(d->a1, d->nf));
        cJSON_AddItemToObject(j, "b1", array(d->b1, d->nf));
        cJSON_AddItemToObject(j, "a2", array(d->a2, d->nf));
        cJSON_AddItemToObject(j, "b2", array(d->b2, d->nf));
    } else {
        cJSON_AddItemToObject(j, "direction", array(d->dir, d->nd));
        cJSON *rows = cJSON_AddArrayToObject(j, "energy");
        for (int i = 0; i < d->nf; i++) cJSON_AddItemToArray(rows, array(d->e2[i], d->nd));
    }
    return j;
}

double sea_strtod(const char *s, char **end)
{
    const char *p = s + (*s == '+' || *s == '-');
    int digits = 0;
    while (*p >= '0' && *p <= '9') { p++; digits++; }
    if (*p == '.') {
        p++;
        while (*p >= '0' && *p <= '9') { p++; digits++; }
    }
    if (!digits) { *end = (char *)s; return 0; }
    if (*p == 'e' || *p == 'E') {
        const char *q = p + 1 + (p[1] == '+' || p[1] == '-');
        if (*q >= '0' && *q <= '9') {
            while (*q >= '0' && *q <= '9') q++;
            p = q;
        }
    }
    char *e2;
    double v = strtod(s, &e2);
    if (e2 != p) { *end = (char *)s; return 0; } /* cannot happen: strtod reads the same grammar */
    *end = (char *)p;
    return v;
}

int sea_time_canon(const char *in, char out[24])
{
    int y, mo, da, h, mi, s = 0, n = 0;
    if (sscanf(in, "%4d-%2d-%2dT%2d:%2d%n", &y, &mo, &da, &h, &mi, &n) != 5) return -1;
    const char *p = in + n;
    if (*p == ':') {
        int k = 0;
        if (sscanf(p, ":%2d%n", &s, &k) != 1) return -1;
        p += k;
    }
    if (*p == 'Z') p++;
    if (*p || mo < 1 || mo > 12 || da < 1 || da > 31 || h > 23 || mi > 59 || s > 60 || y < 1900 || y > 9999 || h < 0 || mi < 0 ||
        s < 0)
        return -1;
    snprintf(out, 24, "%04u-%02u-%02uT%02u:%02u:%02uZ", (unsigned)y % 10000u, (unsigned)mo % 100u, (unsigned)da % 100u,
             (unsigned)h % 100u, (unsigned)mi % 100u, (unsigned)s % 100u);
    return 0;
}

/* sea_msg.c — the sea document and its summary as JSON (sea_msg.h,
 * PROTOCOL.md §7.8). */
#include "sea_msg.h"
#include "control_internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const tail_names[SEA_TAIL_COUNT] = { "f-4", "f-5", "none", "wind" };
static const char *const directional_names[SEA_DIR_COUNT] = { "mem", "lh", "lh_weighted" };

const char *sea_tail_name(enum sea_tail t) { return (unsigned)t < SEA_TAIL_COUNT ? tail_names[t] : "?"; }
const char *sea_directional_name(enum sea_directional d)
{
    return (unsigned)d < SEA_DIR_COUNT ? directional_names[d] : "?";
}

/* An optional string member into buf (cap bytes, NUL included): "" when absent. */
static int text_member(const cJSON *doc, const char *name, char *buf, size_t cap, struct ctl_error *e)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(doc, name);
    buf[0] = '\0';
    if (!v || cJSON_IsNull(v))
        return 0;
    if (!cJSON_IsString(v))
        return ctl_fail(e, "bad_type", name, "sea: \"%s\" must be a string", name);
    if (strlen(v->valuestring) >= cap)
        return ctl_fail(e, "sea_text", name, "sea: \"%s\" is longer than %zu bytes", name, cap - 1);
    memcpy(buf, v->valuestring, strlen(v->valuestring) + 1);
    return 0;
}

/* An optional name out of a list into *out (left as it is when absent). */
static int choice_member(const cJSON *doc, const char *name, const char *const *names, int count, int *out,
                         struct ctl_error *e)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(doc, name);
    if (!v)
        return 0;
    if (!cJSON_IsString(v))
        return ctl_fail(e, "bad_type", name, "sea: \"%s\" must be a string", name);
    for (int i = 0; i < count; i++)
        if (strcmp(v->valuestring, names[i]) == 0) {
            *out = i;
            return 0;
        }
    return ctl_fail(e, "sea_form", name, "sea: unknown %s \"%.40s\"", name, v->valuestring);
}

/* A required array of numbers of at most max entries into v; its length in *n. */
static int numbers(const cJSON *doc, const char *name, double *v, int max, int *n, struct ctl_error *e)
{
    const cJSON *a = cJSON_GetObjectItemCaseSensitive(doc, name);
    if (!a)
        return ctl_fail(e, "bad_message", name, "sea: \"%s\" is required (an array of numbers)", name);
    if (!cJSON_IsArray(a))
        return ctl_fail(e, "bad_type", name, "sea: \"%s\" must be an array of numbers", name);
    int count = cJSON_GetArraySize(a);
    if (count < 1 || count > max)
        return ctl_fail(e, "sea_size", name, "sea: \"%s\" has %d entries (1..%d)", name, count, max);
    int i = 0;
    const cJSON *x;
    cJSON_ArrayForEach(x, a) {
        if (!cJSON_IsNumber(x))
            return ctl_fail(e, "bad_type", name, "sea: %s[%d] is not a number", name, i);
        v[i++] = x->valuedouble;
    }
    *n = count;
    return 0;
}

/* One more array of a moments document: exactly `bands` entries. */
static int band_numbers(const cJSON *doc, const char *name, double *v, int bands, struct ctl_error *e)
{
    int n = 0;
    if (numbers(doc, name, v, SEA_MAX_BANDS, &n, e) != 0)
        return -1;
    if (n != bands)
        return ctl_fail(e, "sea_size", name, "sea: \"%s\" has %d entries, \"frequency\" %d", name, n, bands);
    return 0;
}

static int energy2d(const cJSON *doc, struct sea_spectrum *s, struct ctl_error *e)
{
    const cJSON *rows = cJSON_GetObjectItemCaseSensitive(doc, "energy");
    if (!rows)
        return ctl_fail(e, "bad_message", "energy", "sea: \"energy\" is required (one row per frequency)");
    if (!cJSON_IsArray(rows))
        return ctl_fail(e, "bad_type", "energy", "sea: \"energy\" must be an array of rows");
    if (cJSON_GetArraySize(rows) != s->bands)
        return ctl_fail(e, "sea_size", "energy", "sea: \"energy\" has %d rows, \"frequency\" %d",
                        cJSON_GetArraySize(rows), s->bands);
    int i = 0;
    const cJSON *row;
    cJSON_ArrayForEach(row, rows) {
        char name[32];
        snprintf(name, sizeof name, "energy[%d]", i);
        if (!cJSON_IsArray(row))
            return ctl_fail(e, "bad_type", name, "sea: %s must be an array of numbers", name);
        if (cJSON_GetArraySize(row) != s->directions)
            return ctl_fail(e, "sea_size", name, "sea: %s has %d entries, \"direction\" %d", name,
                            cJSON_GetArraySize(row), s->directions);
        int j = 0;
        const cJSON *x;
        cJSON_ArrayForEach(x, row) {
            if (!cJSON_IsNumber(x))
                return ctl_fail(e, "bad_type", name, "sea: energy[%d][%d] is not a number", i, j);
            s->energy2d[i][j++] = x->valuedouble;
        }
        i++;
    }
    return 0;
}

/* The library's "... energy[3][5] ..." names the place: the member's name is its first word after "sea: ". */
static void place_of(const char *msg, char *param, size_t cap)
{
    const char *p = strncmp(msg, "sea: ", 5) == 0 ? msg + 5 : msg;
    size_t n = strcspn(p, " =(");
    if (n >= cap)
        n = cap - 1;
    memcpy(param, p, n);
    param[n] = '\0';
}

int sea_doc_parse(const cJSON *doc, struct sea_spectrum *s, struct ctl_error *e)
{
    if (!cJSON_IsObject(doc))
        return ctl_fail(e, "bad_message", "sea", "\"sea\" must be a sea document (an object)");
    const cJSON *form = cJSON_GetObjectItemCaseSensitive(doc, "form");
    if (!form)
        return ctl_fail(e, "bad_message", "form", "sea: \"form\" is required (\"moments\" or \"spectrum2d\")");
    if (!cJSON_IsString(form))
        return ctl_fail(e, "bad_type", "form", "sea: \"form\" must be a string");
    bool two_d = strcmp(form->valuestring, "spectrum2d") == 0;
    if (!two_d && strcmp(form->valuestring, "moments") != 0)
        return ctl_fail(e, "sea_form", "form", "sea: unknown form \"%.40s\" (moments or spectrum2d)",
                        form->valuestring);
    sea_spectrum_init(s, two_d ? SEA_FORM_SPECTRUM2D : SEA_FORM_MOMENTS);
    if (text_member(doc, "source", s->source, sizeof s->source, e) != 0 ||
        text_member(doc, "time", s->time, sizeof s->time, e) != 0)
        return -1;
    const cJSON *depth = cJSON_GetObjectItemCaseSensitive(doc, "depth");
    if (depth && !cJSON_IsNull(depth) && !cJSON_IsNumber(depth))
        return ctl_fail(e, "bad_type", "depth", "sea: \"depth\" must be a number of metres or null");
    s->depth = cJSON_IsNumber(depth) ? depth->valuedouble : 0;
    int tail = (int)s->tail, dir = (int)s->directional;
    if (choice_member(doc, "tail", tail_names, SEA_TAIL_COUNT, &tail, e) != 0 ||
        choice_member(doc, "directional", directional_names, SEA_DIR_COUNT, &dir, e) != 0)
        return -1;
    s->tail = (enum sea_tail)tail;
    s->directional = (enum sea_directional)dir;
    if (numbers(doc, "frequency", s->frequency, SEA_MAX_BANDS, &s->bands, e) != 0 ||
        band_numbers(doc, "bandwidth", s->bandwidth, s->bands, e) != 0)
        return -1;
    if (two_d) {
        if (numbers(doc, "direction", s->direction, SEA_MAX_DIRECTIONS, &s->directions, e) != 0 ||
            energy2d(doc, s, e) != 0)
            return -1;
    } else if (band_numbers(doc, "energy", s->energy, s->bands, e) != 0 ||
               band_numbers(doc, "a1", s->a1, s->bands, e) != 0 || band_numbers(doc, "b1", s->b1, s->bands, e) != 0 ||
               band_numbers(doc, "a2", s->a2, s->bands, e) != 0 || band_numbers(doc, "b2", s->b2, s->bands, e) != 0) {
        return -1;
    }
    char msg[200];
    enum sea_error r = sea_spectrum_check(s, msg, sizeof msg);
    if (r != SEA_OK) {
        ctl_fail(e, sea_error_name(r), NULL, "%s", msg);
        place_of(msg, e->param, sizeof e->param);
        return -1;
    }
    return 0;
}

/* ---- back to JSON ---- */

/* Numbers as the shortest text that reads back to the same double: cJSON's
 * own printing accepts %.15g when it is within an epsilon of the value (one
 * ulp off), and a saved or replicated sea must be the sea that was sent. */
static cJSON *exact_number(double v)
{
    char buf[32];
    for (int digits = 15; digits <= 17; digits++) {
        snprintf(buf, sizeof buf, "%.*g", digits, v);
        if (strtod(buf, NULL) == v)
            break;
    }
    return cJSON_CreateRaw(buf);
}

static cJSON *array(const double *v, int n)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; a && i < n; i++) {
        cJSON *x = exact_number(v[i]);
        if (!x || !cJSON_AddItemToArray(a, x)) {
            cJSON_Delete(x);
            cJSON_Delete(a);
            return NULL;
        }
    }
    return a;
}

cJSON *sea_doc_json(const struct sea_spectrum *s)
{
    cJSON *o = cJSON_CreateObject();
    bool two_d = s->form == SEA_FORM_SPECTRUM2D;
    cJSON_AddStringToObject(o, "form", two_d ? "spectrum2d" : "moments");
    cJSON_AddStringToObject(o, "source", s->source);
    cJSON_AddStringToObject(o, "time", s->time);
    if (s->depth > 0)
        cJSON_AddItemToObject(o, "depth", exact_number(s->depth));
    else
        cJSON_AddNullToObject(o, "depth");
    cJSON_AddStringToObject(o, "tail", sea_tail_name(s->tail));
    cJSON_AddStringToObject(o, "directional", sea_directional_name(s->directional));
    cJSON_AddItemToObject(o, "frequency", array(s->frequency, s->bands));
    cJSON_AddItemToObject(o, "bandwidth", array(s->bandwidth, s->bands));
    if (two_d) {
        cJSON_AddItemToObject(o, "direction", array(s->direction, s->directions));
        cJSON *rows = cJSON_AddArrayToObject(o, "energy");
        for (int i = 0; rows && i < s->bands; i++)
            cJSON_AddItemToArray(rows, array(s->energy2d[i], s->directions));
    } else {
        cJSON_AddItemToObject(o, "energy", array(s->energy, s->bands));
        cJSON_AddItemToObject(o, "a1", array(s->a1, s->bands));
        cJSON_AddItemToObject(o, "b1", array(s->b1, s->bands));
        cJSON_AddItemToObject(o, "a2", array(s->a2, s->bands));
        cJSON_AddItemToObject(o, "b2", array(s->b2, s->bands));
    }
    /* cJSON's adders return NULL (and add nothing) on no memory: one check
     * of the last member would miss an earlier one, so count them. */
    int want = two_d ? 10 : 13;
    if (cJSON_GetArraySize(o) != want) {
        cJSON_Delete(o);
        return NULL;
    }
    return o;
}

/* ---- the summary ---- */

/* v to `digits` significant digits: the summary is for eyes and plots. */
static double round_to(double v, int digits)
{
    if (v == 0 || !isfinite(v))
        return v;
    char buf[40];
    snprintf(buf, sizeof buf, "%.*g", digits, v);
    return strtod(buf, NULL);
}

/* E(f_i, alpha) per radian at `count` compass directions 360 j / count:
 * the 2-D form's table interpolated linearly around the circle (as the
 * simulation reads it), the moments by the sea's own reconstruction. */
static void band_polar(const struct sea_spectrum *s, int i, double *out, int count)
{
    double energy, coef[4];
    sea_spectrum_band(s, i, &energy, coef);
    if (s->form == SEA_FORM_MOMENTS) {
        if (sea_directional_distribution(s->directional, coef[0], coef[1], coef[2], coef[3], out, count) != 0)
            for (int j = 0; j < count; j++)
                out[j] = 1.0 / (2 * M_PI);
        for (int j = 0; j < count; j++)
            out[j] *= energy;
        return;
    }
    int nd = s->directions;
    for (int j = 0; j < count; j++) {
        double a = 360.0 * j / count;
        /* The neighbours below and above a, around the circle (any order of directions). */
        int lo = -1, hi = -1;
        double dlo = 1e9, dhi = 1e9;
        for (int k = 0; k < nd; k++) {
            double below = fmod(a - s->direction[k] + 360.0, 360.0), above = fmod(s->direction[k] - a + 360.0, 360.0);
            if (below < dlo) {
                dlo = below;
                lo = k;
            }
            if (above < dhi) {
                dhi = above;
                hi = k;
            }
        }
        double span = dlo + dhi;
        out[j] = span > 0 ? (s->energy2d[i][lo] * dhi + s->energy2d[i][hi] * dlo) / span : s->energy2d[i][lo];
    }
}

static cJSON *polar(const struct sea_spectrum *s)
{
    int groups = s->bands < SEA_POLAR_BANDS ? s->bands : SEA_POLAR_BANDS;
    double f[SEA_POLAR_BANDS], dirs[SEA_POLAR_DIRECTIONS], row[SEA_POLAR_DIRECTIONS], acc[SEA_POLAR_DIRECTIONS];
    for (int j = 0; j < SEA_POLAR_DIRECTIONS; j++)
        dirs[j] = 360.0 * j / SEA_POLAR_DIRECTIONS;
    cJSON *o = cJSON_CreateObject(), *e = cJSON_CreateArray();
    const double per_deg = M_PI / 180.0;
    for (int g = 0; g < groups; g++) {
        /* Bands [b0, b1) merged: their energies averaged over their widths. */
        int b0 = g * s->bands / groups, b1 = (g + 1) * s->bands / groups;
        double wsum = 0, fsum = 0;
        memset(acc, 0, sizeof acc);
        for (int i = b0; i < b1; i++) {
            band_polar(s, i, row, SEA_POLAR_DIRECTIONS);
            for (int j = 0; j < SEA_POLAR_DIRECTIONS; j++)
                acc[j] += row[j] * s->bandwidth[i];
            wsum += s->bandwidth[i];
            fsum += s->frequency[i] * s->bandwidth[i];
        }
        f[g] = round_to(fsum / wsum, 4);
        for (int j = 0; j < SEA_POLAR_DIRECTIONS; j++)
            row[j] = round_to(acc[j] / wsum * per_deg, 3);
        cJSON_AddItemToArray(e, cJSON_CreateDoubleArray(row, SEA_POLAR_DIRECTIONS));
    }
    cJSON_AddItemToObject(o, "f_hz", cJSON_CreateDoubleArray(f, groups));
    cJSON_AddItemToObject(o, "dir_from_deg", cJSON_CreateDoubleArray(dirs, SEA_POLAR_DIRECTIONS));
    cJSON_AddItemToObject(o, "e", e);
    if (cJSON_GetArraySize(o) != 3 || cJSON_GetArraySize(e) != groups) {
        cJSON_Delete(o);
        return NULL;
    }
    return o;
}

cJSON *sea_summary_json(const struct sea_spectrum *s, const struct sea_capture *cap, uint32_t version)
{
    cJSON *o = cJSON_CreateObject();
    int peak = sea_spectrum_peak_band(s);
    double energy = 0, coef[4] = { 0 };
    if (peak >= 0)
        sea_spectrum_band(s, peak, &energy, coef);
    cJSON_AddNumberToObject(o, "version", version);
    cJSON_AddStringToObject(o, "source", s->source);
    cJSON_AddStringToObject(o, "time", s->time);
    cJSON_AddNumberToObject(o, "hs_m", round_to(4 * sqrt(sea_spectrum_m0(s)), 4));
    if (peak >= 0) {
        cJSON_AddNumberToObject(o, "tp_s", round_to(1.0 / s->frequency[peak], 4));
        cJSON_AddNumberToObject(o, "dir_from_deg", round_to(sea_mean_direction(coef[0], coef[1]), 4));
        cJSON_AddNumberToObject(o, "spread_deg", round_to(sea_kuik_spread(coef[0], coef[1]), 3));
    } else { /* a calm sea has no peak */
        cJSON_AddNullToObject(o, "tp_s");
        cJSON_AddNullToObject(o, "dir_from_deg");
        cJSON_AddNullToObject(o, "spread_deg");
    }
    if (cap)
        cJSON_AddNumberToObject(o, "captured", round_to(cap->share, 3));
    else
        cJSON_AddNullToObject(o, "captured");
    if (cap && !cap->fits && cap->warning[0])
        cJSON_AddStringToObject(o, "fit_note", cap->warning);
    else
        cJSON_AddNullToObject(o, "fit_note");
    if (s->depth > 0)
        cJSON_AddNumberToObject(o, "depth_m", s->depth);
    else
        cJSON_AddNullToObject(o, "depth_m");
    cJSON_AddStringToObject(o, "convention", "from_clockwise_north");
    cJSON_AddStringToObject(o, "tail", sea_tail_name(s->tail));
    cJSON_AddItemToObject(o, "polar", polar(s));
    if (cJSON_GetArraySize(o) != 13 || !cJSON_GetObjectItemCaseSensitive(o, "polar")) {
        cJSON_Delete(o);
        return NULL;
    }
    return o;
}

/* cluster_subject.c — the subject scheme (listed at the top of cluster.h):
 * which NATS subject carries what, under a prefix that lets several seas
 * share one NATS cluster. Pure: no NATS, no threads; fuzzed by
 * fuzz/fuzz_cluster.c (layer subjects). */
#include "cluster.h"

#include <stdio.h>
#include <string.h>

#include "oc_proto.h"

static bool token_char(char c)
{
    return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
}

bool cl_prefix_valid(const char *prefix)
{
    if (!prefix)
        return false;
    size_t len = strlen(prefix);
    if (len == 0 || len > CL_PREFIX_MAX)
        return false;
    bool token_start = true;
    for (size_t i = 0; i < len; i++) {
        if (prefix[i] == '.') {
            if (token_start)
                return false; /* empty token: leading or double dot */
            token_start = true;
        } else if (token_char(prefix[i])) {
            token_start = false;
        } else {
            return false;
        }
    }
    return !token_start; /* no trailing dot */
}

static const char *const subject_names[] = {
    [CL_SUBJ_PARAMS] = "params", [CL_SUBJ_STATUS] = "status", [CL_SUBJ_CTL] = "ctl",
    [CL_SUBJ_HELLO] = "hello", [CL_SUBJ_DEMAND] = "demand", [CL_SUBJ_QUERY] = "query",
    [CL_SUBJ_PROBE] = "probe", [CL_SUBJ_BODIES] = "bodies",
};

int cl_subject(char *out, size_t cap, const char *prefix, enum cl_subject which)
{
    if (!cl_prefix_valid(prefix) || (unsigned)which > CL_SUBJ_BODIES)
        return CL_E_ARG;
    int n = snprintf(out, cap, "%s.%s", prefix, subject_names[which]);
    return n < 0 || (size_t)n >= cap ? CL_E_TOO_LARGE : CL_OK;
}

int cl_subject_layer(char *out, size_t cap, const char *prefix, int key)
{
    if (!cl_prefix_valid(prefix) || key < 0 || key >= CL_KEYS)
        return CL_E_ARG;
    int n = snprintf(out, cap, "%s.frame.%d.%s.%d.%d", prefix, cl_key_which_cascade(key),
                     oc_field_name((enum oc_field)cl_key_field(key)), cl_key_lod(key), cl_key_bound(key));
    return n < 0 || (size_t)n >= cap ? CL_E_TOO_LARGE : CL_OK;
}

int cl_subject_layer_parse(const char *subject, const char *prefix)
{
    if (!subject || !cl_prefix_valid(prefix))
        return CL_E_ARG;
    size_t pl = strlen(prefix);
    if (strncmp(subject, prefix, pl) != 0 || strncmp(subject + pl, ".frame.", 7) != 0)
        return CL_E_CORRUPT;
    const char *f = subject + pl + 7;
    /* "<cascade digit>." first */
    if (f[0] < '0' || f[0] >= '0' + CL_CASCADES || f[1] != '.')
        return CL_E_CORRUPT;
    int cascade = f[0] - '0';
    f += 2;
    const char *dot = strchr(f, '.');
    if (!dot || dot - f >= 16)
        return CL_E_CORRUPT;
    char name[16];
    memcpy(name, f, (size_t)(dot - f));
    name[dot - f] = 0;
    int field = oc_field_from_name(name);
    /* exactly "<digit>.<digit>" after the field name */
    if (field < 0 || dot[1] < '0' || dot[1] > '9' || dot[2] != '.' || dot[3] < '0' || dot[3] > '9' || dot[4])
        return CL_E_CORRUPT;
    int lod = dot[1] - '0', bi = dot[3] - '0';
    if (lod >= CL_LODS || bi >= CL_BOUNDS)
        return CL_E_CORRUPT;
    return cl_key_cascade(cascade, field, lod, bi);
}

int cl_probe_stream_subject(const char *reply_to, char *out, size_t cap)
{
    const char *dot = reply_to ? strrchr(reply_to, '.') : NULL;
    if (!dot || dot == reply_to)
        return CL_E_ARG;
    int n = snprintf(out, cap, "%.*s.p", (int)(dot - reply_to), reply_to);
    return n < 0 || (size_t)n >= cap ? CL_E_TOO_LARGE : CL_OK;
}

/* capacity.c — the cost model, the plan of a tick, the announcement (capacity.h). */
#include "capacity.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "ocean.h"

static double nlogn(int n) { return (double)n * n * log2((double)(n < 2 ? 2 : n)); }

static double penalty(const struct cost_model *m) { return m->penalty > 1 ? m->penalty : 1; }
static double enc_per_sample(const struct cost_model *m) { return m->enc_s_per_sample * penalty(m); }

double cost_step_s(const struct cost_model *m, int n, int nfields)
{
    if (nfields <= 0)
        return 0;
    double at_n0 = m->step1_s + (m->step6_s - m->step1_s) * (nfields - 1) / 5.0;
    return at_n0 * nlogn(n) / nlogn(m->n0) * m->step_scale * penalty(m);
}

double cost_encode_s(const struct cost_model *m, long samples) { return (double)samples * enc_per_sample(m); }

long cost_encode_budget(const struct cost_model *m, int n)
{
    if (m->encode_budget > 0)
        return m->encode_budget;
    struct cost_model measured = *m; /* admission follows the measured costs, not a transient penalty */
    measured.penalty = 1;
    m = &measured;
    double left = m->budget_s - cost_step_s(m, n, OCEAN_FIELD_COUNT);
    double derived = left > 0 && m->enc_s_per_sample > 0 ? left / m->enc_s_per_sample : 0;
    /* At least one client's worth of every field at full resolution: any
     * single subscription is accepted, and served degraded if it must be. */
    double floor_samples = (double)OCEAN_FIELD_COUNT * n * n;
    return (long)fmin(fmax(derived, floor_samples), 2e9);
}

static int popcount(unsigned v)
{
    int c = 0;
    for (; v; v &= v - 1)
        c++;
    return c;
}

static long group_samples(const struct plan *p, int g, int n)
{
    long side = n >> p->lod[g];
    return (long)popcount(p->fields[g]) * side * side;
}

/* A group's encode work in LOD-0 samples: a sample at LOD L counts 2^L. The
 * gather reads every 2^L-th row whole (each of its cache lines), so the bytes
 * read per sample double with each LOD. Measured at N = 1024, six fields,
 * intra, two cores: 1.86, 4.4 and 7.0 ns per sample at LOD 0, 1, 2 (x2.4 and
 * x3.8; 2^L: x2, x4). With one figure per sample at every LOD, the figure
 * learned at LOD 1 priced LOD 0 at 2.4 times its cost, and a group degraded
 * once never came back (N = 1024 with six fields stayed at LOD 1). */
static long group_work(const struct plan *p, int g, int n) { return group_samples(p, g, n) << p->lod[g]; }

static double codec_cost(const struct cost_model *m, int codec)
{
    if (codec == CAP_TEMPORAL)
        return m->enc_temporal_s > 0 ? m->enc_temporal_s
                                     : (m->temporal_ratio > 0 ? m->temporal_ratio : CAP_TEMPORAL_PRIOR) * m->enc_s_per_sample;
    return m->enc_s_per_sample;
}

double cost_encode_codec_s(const struct cost_model *m, int codec) { return codec_cost(m, codec) * penalty(m); }

double cost_ewma(double model, double measured)
{
    double a = measured < model ? 0.25 : 0.1;
    return (1 - a) * model + a * measured;
}

void cost_learn_encode(struct cost_model *m, const long samples[CAP_CODECS], double seconds)
{
    double predicted = 0;
    for (int c = 0; c < CAP_CODECS; c++)
        if (samples[c] > 0)
            predicted += (double)samples[c] * codec_cost(m, c);
    if (!(predicted > 0) || !(seconds > 0))
        return;
    double ratio = fmin(seconds / predicted, 2.0);
    double intra = codec_cost(m, CAP_INTRA), temporal = codec_cost(m, CAP_TEMPORAL);
    if (samples[CAP_INTRA] > 0)
        m->enc_s_per_sample = cost_ewma(intra, intra * ratio);
    if (samples[CAP_TEMPORAL] > 0)
        m->enc_temporal_s = cost_ewma(temporal, temporal * ratio);
}

void cost_forget_temporal(struct cost_model *m) { m->enc_temporal_s = 0; }

static bool own_lod(const struct plan *p, int g) { return p->lod[g] == g / CTL_BOUND_COUNT; }
static bool group_temporal(const struct plan *p, int g) { return p->temporal[g] && own_lod(p, g) && !p->intra[g]; }

void plan_samples(const struct plan *p, int n, const bool *due, long samples[CAP_CODECS])
{
    for (int c = 0; c < CAP_CODECS; c++)
        samples[c] = 0;
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (p->fields[g] && (!due || due[g]))
            samples[group_temporal(p, g) ? CAP_TEMPORAL : CAP_INTRA] += group_work(p, g, n);
}

/* Seconds to encode a group at its planned LOD (every tick). */
static double group_time(const struct cost_model *m, const struct plan *p, int g, int n)
{
    return (double)group_work(p, g, n) * cost_encode_codec_s(m, group_temporal(p, g) ? CAP_TEMPORAL : CAP_INTRA);
}

static bool can_coarsen(const struct plan *p, int g, int ts) { return p->lod[g] < CTL_MAX_LOD && (ts >> (p->lod[g] + 1)) >= 1; }

/* Keep plans from changing for noise: sixths of the tick rate down to a
 * half (30 Hz: 25, 20, 15 frames/s), then 1/k, at least one frame/s. */
static float quantize_rate(double r, double period_s)
{
    double q = r >= 0.5 ? floor(r * 6 + 1e-9) / 6 : 1.0 / ceil(1.0 / fmax(r, 1e-6) - 1e-9);
    if (q < period_s)
        q = period_s;
    return (float)(q > 1 ? 1 : q);
}

void capacity_plan(const struct cost_model *m, int n, int ts, const int demand[LAYER_KEYS_ALL],
                   const int tdemand[LAYER_KEYS_ALL], double budget_scale, struct plan *p)
{
    memset(p, 0, sizeof *p);
    unsigned all = 0;
    /* Cascades: a finer cascade's keys fall in the group of their LOD and
     * bound (the group's fields are a union: a field asked of two cascades
     * in one group is counted once; known approximation). */
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        if (demand[k] > 0) {
            int g = plan_group(layer_key_lod(k), layer_key_bound(k));
            p->fields[g] |= OCEAN_FIELD_BIT(layer_key_field(k));
            p->temporal[g] |= tdemand && tdemand[k] > 0;
            all |= OCEAN_FIELD_BIT(layer_key_field(k));
        }
    for (int g = 0; g < PLAN_GROUPS; g++) {
        p->lod[g] = (unsigned char)(g / CTL_BOUND_COUNT);
        p->rate[g] = 1;
    }
    double budget = m->budget_s * budget_scale;
    double step = cost_step_s(m, n, popcount(all));
    /* What encoding may take per frame: the rest of the budget, and at least a
     * quarter of it even when the step takes it all (then frames come less
     * often than ticks, step 3, rather than at the coarsest LOD). Each group
     * costs what a sample of its codec costs (temporal at its own LOD, else
     * intra: cost_encode_codec_s); --encode-budget caps the samples besides. */
    double left = fmax(budget - step, budget * 0.25);
    double scap = m->encode_budget > 0 ? (double)m->encode_budget : 1e18;

    long total = 0, total_temporal = 0;
    double total_t = 0;
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (p->fields[g]) {
            total += group_samples(p, g, n);
            total_t += group_time(m, p, g, n);
            total_temporal += group_temporal(p, g) ? group_samples(p, g, n) : 0;
        }
    const long wanted = total;
    const double wanted_t = total_t;
    const double tcap = m->temporal_budget > 0 ? (double)m->temporal_budget : 1e18;
    /* The codec rung pays only when intra is the cheaper codec (it is: x1.5-2) */
    const bool intra_cheaper = cost_encode_codec_s(m, CAP_INTRA) < cost_encode_codec_s(m, CAP_TEMPORAL);
    /* 1. While the frame does not fit: a group with temporal clients goes
     *    intra at its own LOD (the codec rung: the same detail and rate,
     *    more bytes), the largest such group first (the most expensive: a
     *    sample of one codec costs the same in every group, so it saves the
     *    most); when none is left, or the samples themselves are over
     *    --encode-budget (which no codec helps), the largest group goes one
     *    LOD coarser (a quarter of the samples each time; its layers go
     *    intra too, frame_job.c). */
    bool rung_codec = false, rung_lod = false, rung_rate = false;
    while ((double)total > scap || (double)total_temporal > tcap || total_t > left) {
        int worst = -1;
        bool codec = (double)total <= scap && (intra_cheaper || (double)total_temporal > tcap);
        for (int g = 0; codec && g < PLAN_GROUPS; g++)
            if (p->fields[g] && group_temporal(p, g) && (worst < 0 || group_samples(p, g, n) > group_samples(p, worst, n)))
                worst = g;
        if (worst < 0) {
            codec = false;
            for (int g = 0; g < PLAN_GROUPS; g++)
                if (p->fields[g] && can_coarsen(p, g, ts) && (worst < 0 || group_samples(p, g, n) > group_samples(p, worst, n)))
                    worst = g;
        }
        if (worst < 0)
            break;
        total -= group_samples(p, worst, n);
        total_t -= group_time(m, p, worst, n);
        total_temporal -= group_temporal(p, worst) ? group_samples(p, worst, n) : 0;
        if (codec) {
            p->intra[worst] = true;
            rung_codec = true;
        } else {
            p->lod[worst]++;
            p->intra[worst] = false; /* a coarser LOD is intra anyway: the codec rung is for full detail */
            rung_lod = true;
        }
        total += group_samples(p, worst, n);
        total_t += group_time(m, p, worst, n);
    }
    /* A group put on the codec rung before another was coarsened may fit
     * temporal again: back, the smallest first (the least it adds). */
    for (bool again = rung_codec && rung_lod; again;) {
        again = false;
        int best = -1;
        for (int g = 0; g < PLAN_GROUPS; g++)
            if (p->fields[g] && p->intra[g] && (best < 0 || group_samples(p, g, n) < group_samples(p, best, n)))
                best = g;
        if (best < 0)
            break;
        double before = group_time(m, p, best, n);
        p->intra[best] = false;
        double t = total_t - before + group_time(m, p, best, n);
        if ((double)(total_temporal + group_samples(p, best, n)) <= tcap && t <= left) {
            total_t = t;
            total_temporal += group_samples(p, best, n);
            again = true;
        } else {
            p->intra[best] = true;
        }
    }
    rung_codec = false;
    for (int g = 0; g < PLAN_GROUPS; g++)
        rung_codec |= p->fields[g] && p->intra[g];
    /* 2. Still too much (every group as coarse as it goes): the largest
     *    groups on fewer ticks. */
    double over_s = (double)total - scap, over_t = total_t - left;
    for (int pass = 0; (over_s > 0 || over_t > 0) && pass < PLAN_GROUPS; pass++) {
        int worst = -1;
        for (int g = 0; g < PLAN_GROUPS; g++)
            if (p->fields[g] && p->rate[g] >= 1 && (worst < 0 || group_samples(p, g, n) > group_samples(p, worst, n)))
                worst = g;
        if (worst < 0)
            break;
        double s = (double)group_samples(p, worst, n), st = group_time(m, p, worst, n);
        double cut = fmax(over_s > 0 ? over_s / s : 0, over_t > 0 && st > 0 ? over_t / st : 0);
        p->rate[worst] = quantize_rate(1.0 - cut, m->period_s);
        over_s -= s * (1.0 - p->rate[worst]);
        over_t -= st * (1.0 - p->rate[worst]);
        rung_rate = true;
    }
    /* 3. The step alone does not fit: every group on fewer ticks (the frame
     *    takes longer than a tick; the producer runs one behind the tick). */
    double frame = step + total_t;
    bool step_bound = false;
    if (frame > budget && step > 0) {
        double r = budget / frame;
        for (int g = 0; g < PLAN_GROUPS; g++)
            if (p->fields[g] && p->rate[g] > r)
                p->rate[g] = quantize_rate(r, m->period_s);
        step_bound = true;
    }
    /* The demand at full detail against the samples that fit the encode
     * budget at what the demanded sizes cost (it used to print the samples
     * left after degrading, which read as under budget); with temporal
     * demand, also what fits intra (the codec rung). */
    if (rung_codec || rung_lod || rung_rate || step_bound) {
        char how[128] = "";
        const char *rungs[] = { rung_codec ? "intra codec" : NULL, rung_lod ? "coarser LOD" : NULL,
                                rung_rate && !step_bound ? "lower rate" : NULL,
                                step_bound ? "lower rate for everyone: the step alone does not fit the tick" : NULL };
        for (size_t i = 0; i < sizeof rungs / sizeof rungs[0]; i++)
            if (rungs[i])
                snprintf(how + strlen(how), sizeof how - strlen(how), "%s%s", how[0] ? ", " : "", rungs[i]);
        double per = wanted > 0 ? wanted_t / (double)wanted : 0;
        double fit = per > 0 ? fmin(left / per, scap) : scap;
        bool any_temporal = false;
        for (int g = 0; g < PLAN_GROUPS; g++)
            any_temporal |= p->fields[g] && p->temporal[g];
        char intra[64] = "";
        double ip = cost_encode_codec_s(m, CAP_INTRA);
        if (any_temporal && ip > 0)
            snprintf(intra, sizeof intra, ", intra %.0f (%.1f ns/sample)", fmin(fmin(left / ip, scap), 2e9), ip * 1e9);
        snprintf(p->reason, sizeof p->reason,
                 "%.100s: N=%d, %ld samples per tick wanted, budget %.0f (encode %.1f ns/sample)%.50s, step %.1f ms of %.1f ms", how,
                 n, wanted, fmin(fit, 2e9), per * 1e9, intra, step * 1e3, budget * 1e3);
    }
}

bool plan_degraded(const struct plan *p, int g)
{
    return p->fields[g] && (p->lod[g] != g / CTL_BOUND_COUNT || p->rate[g] < 1);
}

bool plan_intra(const struct plan *p, int g) { return p->fields[g] && p->temporal[g] && p->intra[g] && own_lod(p, g); }

double plan_intra_value(const struct plan *p, int n)
{
    double v = 0;
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (plan_intra(p, g))
            v += p->rate[g] * (double)group_samples(p, g, n);
    return v;
}

double plan_value(const struct plan *p, int n)
{
    double v = 0;
    for (int g = 0; g < PLAN_GROUPS; g++)
        v += p->rate[g] * (double)group_samples(p, g, n);
    return v;
}

bool plan_same(const struct plan *a, const struct plan *b)
{
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (a->fields[g] != b->fields[g] || a->lod[g] != b->lod[g] || a->rate[g] != b->rate[g] ||
            a->temporal[g] != b->temporal[g] || plan_intra(a, g) != plan_intra(b, g))
            return false;
    return true;
}

void capacity_info_fill(const struct cost_model *m, int n, struct capacity_info *c)
{
    memset(c, 0, sizeof *c);
    c->memory_cap_mb = m->max_memory_mb;
    c->cores = m->cores;
    c->tick_ms = m->period_s * 1e3;
    c->budget_ms = m->budget_s * 1e3;
    c->encode_budget = cost_encode_budget(m, n);
    const struct param_def *d = param_with_flag(PARAM_REPLAN); /* N */
    struct ocean_params defaults;
    params_defaults(&defaults);
    int lo = d ? (int)d->min : 16, hi = d ? (int)d->max : 2048;
    int first = lo;
    while (hi / first >= (1 << CAPACITY_MAX_SIZES)) /* the largest sizes, if the range is wide */
        first *= 2;
    for (int size = first; size <= hi && c->nsizes < CAPACITY_MAX_SIZES; size *= 2) {
        struct capacity_size *z = &c->sizes[c->nsizes++];
        z->n = size;
        /* Memory at the default cascade count (one grid each): the announcement
         * does not follow later changes of `cascades` (set checks them itself). */
        z->fits_memory = control_fits_memory(size, defaults.cascades, m->max_memory_mb);
        if (z->fits_memory)
            c->max_resolution = size;
        /* The ladder's first rungs at lod 0 and the full rate: the temporal
         * codec (what the web client asks for) if it fits, else intra (the
         * codec rung: same detail, more bytes); the samples within the
         * operator's caps (--encode-budget, --temporal-budget) if set.
         * Compared as announced (hundredths of a ms), so that a client
         * checking the counts against est_ms, est_intra_ms and budget_ms
         * agrees at the edge. */
        long budget_cs = (long)floor(c->budget_ms * 100 + 0.5);
        for (int f = 1; f <= 6; f++) {
            double samples = (double)f * size * size, step = cost_step_s(m, size, f);
            z->est_ms[f - 1] = (step + samples * cost_encode_codec_s(m, CAP_TEMPORAL)) * 1e3;
            z->est_intra_ms[f - 1] = (step + samples * cost_encode_codec_s(m, CAP_INTRA)) * 1e3;
            bool in_caps = m->encode_budget <= 0 || samples <= (double)m->encode_budget;
            bool temporal = in_caps && (m->temporal_budget <= 0 || samples <= (double)m->temporal_budget) &&
                            (long)floor(z->est_ms[f - 1] * 100 + 0.5) <= budget_cs;
            bool intra = in_caps && (long)floor(z->est_intra_ms[f - 1] * 100 + 0.5) <= budget_cs;
            if (temporal)
                z->temporal_fields = f;
            if (temporal || intra)
                z->full_rate_fields = f;
        }
    }
}

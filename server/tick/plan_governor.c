/* plan_governor.c — which subscription groups the tick serves at which LOD
 * and rate: capacity_plan (capacity.c) says what fits the budget; this
 * file decides when the plan in force changes (tick thread only). */
#include "tick_internal.h"

#include <limits.h>
#include <math.h>

#include "log.h"
#include "metrics.h"

/* Re-plan from the demand: a more degraded plan as soon as the plan in
 * force no longer fits CAP_KEEP_SCALE of the budget, a less degraded one
 * only after it has held for hold_ticks (3 s at first) with 20 % headroom
 * (CAP_RECOVER_SCALE; hysteresis: clients are told every change). The
 * headroom was 40 %: a plan bound by the step (N = 2048: a step of 20-30 ms
 * against a budget of 26.7) never had it, so once degraded by a slow moment
 * it stayed there (20 frames/s where 25-30 fit). A degrade also needs the
 * value to fall under 90 % of the plan in force.
 *
 * Recovery probe: a group degraded to a coarser LOD is sent intra, so
 * while no temporal layer is encoded the temporal cost figure is not
 * measured again, and one taken under load or from a slow start would keep
 * the group degraded for good. After hold_ticks degraded with no recovery
 * in sight, the plan is computed again with the temporal figure forgotten
 * (the start-up temporal_ratio x the intra figure, which the degraded frames keep
 * current); if that fits with the headroom it is taken (the figure starts
 * afresh) and its frames tell. A recovery undone within PLAN_FAILED_S (the
 * probe, or a recovery the model predicted, did not fit) doubles
 * hold_ticks, up to PLAN_HOLD_MAX_S, so a group that does not fit is tried
 * less and less often; a new demand, or a recovery that holds PLAN_HELD_S,
 * resets it. */
#define PLAN_HOLD_S 3
#define PLAN_HOLD_MAX_S 60
#define PLAN_FAILED_S 5
#define PLAN_HELD_S 10
static bool plan_any_degraded(const struct plan *p)
{
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (plan_degraded(p, g) || plan_intra(p, g))
            return true;
    return false;
}

/* a better than b for the same demand: more detail x rate (plan_value), or
 * as much with fewer samples on the codec rung (temporal clients served
 * intra: same detail, more bytes). Equal values are sums of the same terms. */
static bool plan_better(const struct plan *a, const struct plan *b, int n)
{
    double va = plan_value(a, n), vb = plan_value(b, n);
    return va > vb || (va == vb && plan_intra_value(a, n) < plan_intra_value(b, n));
}

/* a worse than b, to be taken at once: under 90 % of its value (the band
 * against noise), or no more value and more samples on the codec rung (the
 * temporal codec no longer fits: same detail, so no band is needed; the
 * way back still needs the headroom and the hold). */
static bool plan_worse(const struct plan *a, const struct plan *b, int n)
{
    double va = plan_value(a, n), vb = plan_value(b, n);
    return va < 0.9 * vb || (va <= vb && plan_intra_value(a, n) > plan_intra_value(b, n));
}

void plan_update(struct sim *s, const int demand[LAYER_KEYS_ALL], const int tdemand[LAYER_KEYS_ALL], int n, int ts)
{
    const int rate = (int)s->cfg.tick_rate > 0 ? (int)s->cfg.tick_rate : 1;
    if (s->hold_ticks <= 0)
        s->hold_ticks = PLAN_HOLD_S * rate;
    if (s->since_change < INT_MAX)
        s->since_change++;
    pthread_mutex_lock(&s->lock);
    struct cost_model m = s->model;
    pthread_mutex_unlock(&s->lock);
    struct plan now, easy;
    /* The plan in force keeps its place up to CAP_KEEP_SCALE of the budget;
     * a new demand is planned at the budget itself. */
    capacity_plan(&m, n, ts, demand, tdemand, CAP_KEEP_SCALE, &now);
    bool same_demand = true;
    for (int g = 0; g < PLAN_GROUPS; g++)
        same_demand &= now.fields[g] == s->plan.fields[g] && now.temporal[g] == s->plan.temporal[g];
    if (!same_demand)
        capacity_plan(&m, n, ts, demand, tdemand, 1.0, &now);
    struct plan next = s->plan;
    bool probe = false;
    if (!same_demand) {
        next = now;
        s->lower_ticks = 0;
        s->hold_ticks = PLAN_HOLD_S * rate;
    } else if (plan_worse(&now, &s->plan, n)) {
        capacity_plan(&m, n, ts, demand, tdemand, 1.0, &next); /* out of the band: what fits the budget */
        s->lower_ticks = 0;
        if (s->recovered && s->since_change < PLAN_FAILED_S * rate) /* the recovery did not fit */
            s->hold_ticks = s->hold_ticks * 2 < PLAN_HOLD_MAX_S * rate ? s->hold_ticks * 2 : PLAN_HOLD_MAX_S * rate;
    } else {
        capacity_plan(&m, n, ts, demand, tdemand, CAP_RECOVER_SCALE, &easy);
        if (plan_better(&easy, &s->plan, n)) {
            if (++s->lower_ticks >= s->hold_ticks) {
                next = easy;
                s->lower_ticks = 0;
            }
        } else {
            s->lower_ticks = 0;
            long encoded[CAP_CODECS];
            plan_samples(&s->plan, n, NULL, encoded);
            if (s->since_change >= s->hold_ticks && plan_any_degraded(&s->plan) && encoded[CAP_TEMPORAL] == 0 &&
                m.enc_temporal_s > 0) {
                struct cost_model fresh = m;
                cost_forget_temporal(&fresh);
                capacity_plan(&fresh, n, ts, demand, tdemand, CAP_RECOVER_SCALE, &easy);
                if (plan_better(&easy, &s->plan, n)) {
                    next = easy;
                    probe = true;
                } else {
                    s->since_change = 0; /* nothing to try: look again after another hold */
                }
            }
        }
    }
    if (s->recovered && s->since_change >= PLAN_HELD_S * rate && s->hold_ticks != PLAN_HOLD_S * rate)
        s->hold_ticks = PLAN_HOLD_S * rate; /* the recovery held */
    if (!same_demand)
        s->grace_seq = s->seq + (uint64_t)(rate / 2 + 1);
    if (plan_same(&next, &s->plan))
        return;
    if (probe) { /* the temporal figure starts afresh from the probe's frames */
        pthread_mutex_lock(&s->lock);
        cost_forget_temporal(&s->model);
        pthread_mutex_unlock(&s->lock);
    }
    LOGD("plan change at seq %llu: step x%.2f, encode %.2f ns/sample intra, %.2f temporal%s, penalty x%.2f, hold %.0f s%s",
         (unsigned long long)s->seq, m.step_scale, m.enc_s_per_sample * 1e9, cost_encode_codec_s(&m, CAP_TEMPORAL) * 1e9 / fmax(m.penalty, 1),
         m.enc_temporal_s > 0 ? "" : " (prior)", fmax(m.penalty, 1), s->hold_ticks / (double)rate, probe ? ", recovery probe" : "");
    s->recovered = same_demand && plan_better(&next, &s->plan, n);
    s->since_change = 0;
    /* New layers or LODs start with keyframes and cold buffers: their first
     * slow frames must not raise the penalty (tick) and undo the plan */
    s->grace_seq = s->seq + (uint64_t)(rate / 2 + 1);
    int degraded = 0, intra = 0;
    for (int g = 0; g < PLAN_GROUPS; g++) {
        degraded += plan_degraded(&next, g);
        intra += plan_intra(&next, g);
        if ((plan_degraded(&next, g) && !plan_degraded(&s->plan, g)) || (plan_intra(&next, g) && !plan_intra(&s->plan, g)))
            LOGI("degrading lod %d bound %g: encoded at lod %d%s, %g frames/s (%s)", g / CTL_BOUND_COUNT,
                 ctl_bounds[g % CTL_BOUND_COUNT], next.lod[g], plan_intra(&next, g) ? " intra" : "",
                 next.rate[g] * s->cfg.tick_rate, next.reason);
        if (s->credit[g] == 0) /* spread the groups' ticks: equal rates must not all fall on one tick */
            s->credit[g] = fmod(0.618034 * (g + 1), 1.0);
    }
    atomic_store(&g_metrics.degraded_groups, degraded);
    atomic_store(&g_metrics.intra_groups, intra);
    for (int g = 0; g < PLAN_GROUPS; g++)
        if (next.fields[g])
            LOGD("plan: lod %d bound %g: encoded at lod %d%s, %g frames/s (%s)", g / CTL_BOUND_COUNT,
                 ctl_bounds[g % CTL_BOUND_COUNT], next.lod[g], plan_intra(&next, g) ? " intra" : "", next.rate[g] * s->cfg.tick_rate,
                 next.reason[0] ? next.reason : "not degraded");
    s->plan = next;
    pthread_mutex_lock(&s->lock);
    s->plan_pub = next;
    s->plan_gen++;
    pthread_mutex_unlock(&s->lock);
}

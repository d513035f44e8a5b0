/* capacity.c — the network side of server/tick/capacity.h (docs/daemon.md,
 * "Capacity"): the `capacity` member of hello and params, `busy` for a
 * subscription that would push the distinct layers past the encode budget,
 * and `degraded` to the clients whose subscription group the tick serves
 * coarser, less often, or (temporal clients) with the intra codec than asked
 * (PROTOCOL.md §7). lws thread only. */
#include "net_internal.h"

#include <stdio.h>

#include "capacity.h"
#include "metrics.h"
#include "sim_thread.h"

void net_capacity_add(struct net *n, cJSON *msg)
{
    if (!n->sim || !msg)
        return;
    struct capacity_info ci;
    sim_capacity(n->sim, &ci);
    cJSON_AddItemToObject(msg, "capacity", control_capacity_object(&ci));
}

bool net_capacity_admit(struct net *n, struct session *s, const struct subscription *want, struct ctl_error *e)
{
    long need, budget;
    if (!n->sim || sim_admit(n->sim, &s->eff, want, &need, &budget))
        return true;
    atomic_fetch_add(&g_metrics.refused_busy, 1);
    e->code = "busy";
    e->param[0] = 0;
    snprintf(e->message, sizeof e->message,
             "the daemon would encode %ld samples per tick with this subscription; it can encode %ld at N=%d "
             "(choose a coarser lod, fewer fields, or what other clients already get)",
             need, budget, n->applied.resolution);
    return false;
}

/* `degraded` for one client: how its group is served now. A temporal
 * client gets codec 3 tiles only from a group encoded temporal: at its own
 * LOD and not on the codec rung (plan_intra; a coarser LOD is intra too,
 * frame_job.c); it is told the codec either way. */
static void tell(struct net *n, struct session *s, const struct plan *p)
{
    int g = plan_group(s->eff.lod, s->eff.bound_index);
    bool active = plan_degraded_for(p, g, s->eff.temporal);
    double rate = (active ? p->rate[g] : 1.0) * n->dc.tick_rate;
    int lod = active ? p->lod[g] : s->eff.lod;
    int codec = s->eff.temporal && lod == s->eff.lod && !(active && plan_intra(p, g)) ? 3 : 1;
    session_queue_json(s, control_degraded_msg(active, s->sub.lod, lod, codec, rate, active ? p->reason : ""));
    atomic_fetch_add(&g_metrics.degraded_sent, 1);
}

void net_capacity_tell(struct net *n, struct session *s)
{
    if (n->sim && n->told_gen && plan_degraded_for(&n->told, plan_group(s->eff.lod, s->eff.bound_index), s->eff.temporal))
        tell(n, s, &n->told);
}

void net_capacity_wake(struct net *n)
{
    if (!n->sim)
        return;
    struct plan p;
    uint32_t gen = sim_plan(n->sim, &p);
    if (gen == n->told_gen)
        return;
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
        struct session *s = session_of(d);
        int g = plan_group(s->eff.lod, s->eff.bound_index);
        bool t = s->eff.temporal;
        bool was = n->told_gen && plan_degraded_for(&n->told, g, t), is = plan_degraded_for(&p, g, t);
        if (is ? !was || p.lod[g] != n->told.lod[g] || p.rate[g] != n->told.rate[g] ||
                     (t && plan_intra(&p, g) != plan_intra(&n->told, g))
               : was)
            tell(n, s, &p);
    }
    n->told = p;
    n->told_gen = gen;
}

/* seq_guard.c — the edge's belief about frame numbers (seq_guard.h). */
#include "seq_guard.h"

/* Highest seq a stream that had reached `from` at time t0 may show at now:
 * a quarter faster than the clock, plus the jitter allowance. */
static double reach(uint64_t from, double t0, double now, double rate)
{
    double dt = now > t0 ? now - t0 : 0;
    return (double)from + 1.25 * dt * rate + SEQ_AHEAD_S * rate + 2;
}

enum seq_verdict seq_guard_check(struct seq_guard *g, uint64_t seq, double now, double rate)
{
    if (!(rate > 0))
        rate = 30;
    if (!g->last) {
        g->last = seq;
        g->last_t = now;
        return SEQ_ACCEPT;
    }
    double back = SEQ_BACK_S * rate;
    if ((double)seq + back >= (double)g->last && (double)seq <= reach(g->last, g->last_t, now, rate)) {
        if (seq > g->last) {
            g->last = seq;
            g->last_t = now;
        }
        return SEQ_ACCEPT;
    }
    /* Outside the window: part of another timeline, or noise. */
    if (g->cand && seq >= g->cand && (double)seq <= reach(g->cand, g->cand_t, now, rate)) {
        if (seq > g->cand) {
            g->cand = seq;
            g->cand_t = now;
            g->cand_count++;
        }
    } else {
        g->cand = seq;
        g->cand_t0 = g->cand_t = now;
        g->cand_count = 1;
    }
    /* Adopted once it has lasted and kept advancing as a sim would (at
     * least half its ticks seen): a burst, or a few strays, never is. */
    double min_count = SEQ_ADOPT_S * rate / 2 > 3 ? SEQ_ADOPT_S * rate / 2 : 3;
    if (g->cand_t - g->cand_t0 >= SEQ_ADOPT_S && g->cand_count >= min_count) {
        g->last = g->cand;
        g->last_t = now;
        g->cand = 0;
        g->cand_count = 0;
        return SEQ_RESTART;
    }
    g->refused++;
    return SEQ_REFUSE;
}

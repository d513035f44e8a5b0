/* seq_guard.h — which frame numbers an edge believes.
 *
 * An edge rebuilds frames from layers that arrive over NATS, where anyone
 * on the prefix can publish. A layer whose seq is far ahead of the stream
 * (a rogue message, a second sim) would otherwise become the frame being
 * collected, and every real layer behind it would be dropped as stale: the
 * edge, and each viewer that got such a frame, would wait for ever.
 *
 * The rule: the stream's seq advances with time at the sim's tick rate. A
 * seq inside [last - SEQ_BACK_S, last + elapsed + SEQ_AHEAD_S] (in ticks)
 * follows the stream; one outside it is refused, unless layers outside the
 * window keep coming as a stream of their own (increasing, at about the
 * tick rate, for SEQ_ADOPT_S of wall time): then that is the sim's new
 * timeline (a restarted or standby sim whose clock differs) and it is
 * adopted (SEQ_RESTART: the caller drops what it was collecting and tells
 * its clients the stream restarted). A burst of future frames, however
 * many, is never adopted: it does not last. Pure; one thread. */
#ifndef OCEAND_SEQ_GUARD_H
#define OCEAND_SEQ_GUARD_H

#include <stdint.h>

#define SEQ_BACK_S 2.0    /* stragglers up to this old still count as the stream */
#define SEQ_AHEAD_S 0.5   /* delivery jitter: how far ahead of the clock a layer may be */
#define SEQ_ADOPT_S 0.5   /* how long another timeline must last to be adopted */

struct seq_guard {
    uint64_t last;        /* highest seq accepted; 0 = none yet (the first is believed) */
    double last_t;        /* when it was accepted (monotonic s) */
    uint64_t cand;        /* newest seq of a timeline outside the window; 0 = none */
    double cand_t0, cand_t; /* when that timeline's first and newest seq came */
    int cand_count;       /* distinct seqs it has shown */
    uint64_t refused;     /* layers refused, for the metrics */
};

enum seq_verdict {
    SEQ_ACCEPT,           /* follows the stream */
    SEQ_REFUSE,           /* outside the window: drop the layer */
    SEQ_RESTART,          /* another timeline held for SEQ_ADOPT_S: it is the stream now */
};

/* seq of a layer that arrived at `now`, for a sim ticking `rate` times a second. */
enum seq_verdict seq_guard_check(struct seq_guard *g, uint64_t seq, double now, double rate);

#endif

/* ladder.c — a stream that fits each client's link (PROTOCOL.md §7.2 `link`).
 *
 * Per client: an estimate of its link (TCP_INFO: delivery rate, RTT, bytes
 * not sent yet, bytes in flight), a short send queue (TCP_NOTSENT_LOWAT about
 * one tick of the link, so a reply waits behind at most the frame in
 * progress), a bound on what is in flight and on TCP's pacing once the link
 * is measured (ladder_hold_frame: a backlog waits here, not at the
 * bottleneck), and a quality ladder: rungs of (LOD, finer cascades, bound, rate) from the
 * subscription as asked down to a floor. The rung in force makes s->eff,
 * the subscription served and counted in the sim's demand; clients on the
 * same rung share the same layers, so encode work stays shared.
 *
 * Signals, per window of half a second: ticks the client lost (it was
 * still sending an older frame) and how far it runs behind the newest frame
 * (temporal clients keep their chain up to LAG_MAX ticks behind, fanout.c):
 * the most, and the least (behind at every tick: it never caught up).
 * Congested: step down at once, further when the estimate says so. Calm:
 * probe one rung up after `hold` seconds (doubled by each probe that failed,
 * back to the minimum after a long calm), sooner when the estimate says the
 * rung above fits. lws thread only. */
#include "net_internal.h"

#include "clock.h"

#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "metrics.h"
#include "sim_thread.h"

#define WINDOW_S 0.5          /* evaluation window */
#define SETTLE_S 1.0          /* after a change: its keyframes may still cost skips */
#define HOLD_MIN_S 4.0        /* calm before a blind probe up */
#define HOLD_MAX_S 32.0
#define HOLD_RESET_S 20.0     /* calm this long: a failed probe is forgotten */
#define PROBE_FAIL_S 3.0      /* a step down this soon after a step up: the probe failed */
#define LOST_MAX_PCT 15        /* ticks lost in a window beyond which it is congested */
#define BEHIND_S 0.1          /* behind the newest frame by this much at every tick of two windows: congested */
#define FIT 0.8               /* a rung fits when it needs at most this share of the link */
#define LOWAT_MIN 4096u
#define LOWAT_MAX ((uint32_t)CHUNK_SIZE)
#define LOWAT_START (16u * 1024)
#define CAP_FRESH_S 10.0      /* a full-pipe sample this recent is the link */
#define HOLD_RTT_MIN_MS 1.0   /* below this path RTT (loopback, a LAN) no bottleneck queue to keep short without a measurement:
                                 a slow local reader's low samples only throttled it once it read again */
#define HOPELESS_S 60.0       /* no blind probe up to a rung that a full-pipe sample this recent says cannot fit */
#define PACE_GAIN 1.25        /* TCP's pacing rate at most this times the link measured */
#define INFLIGHT_GAIN 1.5     /* bytes in flight at most this times the link measured x the path's RTT, */
#define QUEUE_MAX_S 0.05      /* but at most this much more: what a reply may wait behind at the bottleneck */
#define YOUNG_S 2.0           /* TCP's start-up: its rate samples are not the link's yet */

/* The rungs, finest first. A rung that serves the same as the one before it
 * (e.g. no finer cascades to drop, LOD already 4) is skipped. Finer cascades
 * go first (centimetre waves), then cascade 0's LOD, the bound, and last the
 * rate (below the tick rate a temporal client gets keyframe tiles only). */
static const struct rung_def {
    signed char dlod;         /* cascade 0's LOD + dlod */
    signed char fine;         /* finer cascades: 0 as asked, 1 one LOD coarser, 2 dropped */
    signed char coarse;       /* bound: 1 = the coarsest lossy one */
    signed char rate_div;     /* max_rate = tick_rate / rate_div at most */
} DEFS[] = {
    { 0, 0, 0, 1 }, { 0, 1, 0, 1 }, { 0, 2, 0, 1 }, { 1, 2, 0, 1 }, { 1, 2, 1, 1 }, { 2, 2, 0, 1 },
    { 2, 2, 1, 1 }, { 3, 2, 1, 1 }, { 4, 2, 1, 1 }, { 4, 2, 1, 2 }, { 4, 2, 1, 4 },
};
#define NDEFS ((int)(sizeof DEFS / sizeof DEFS[0]))
_Static_assert(NDEFS <= LADDER_MAX_RUNGS, "rungs");

static int lod_plus(int lod, int d) { return lod + d > CTL_MAX_LOD ? CTL_MAX_LOD : lod + d; }

static void apply_def(const struct subscription *a, const struct rung_def *d, double tick_rate, struct subscription *o)
{
    *o = *a;
    o->lod = lod_plus(a->lod, d->dlod);
    for (int f = 0; f < OCEAN_FIELD_COUNT; f++)
        if (a->field_lod[f] >= 0)
            o->field_lod[f] = (signed char)lod_plus(a->field_lod[f], d->dlod);
    if (d->fine == 1)
        for (int c = 1; c < a->ncascades; c++)
            o->cascade[c].lod = lod_plus(a->cascade[c].lod, 1);
    if (d->fine == 2) {
        o->ncascades = 1;
        memset(&o->cascade[1], 0, sizeof o->cascade - sizeof o->cascade[0]);
    }
    if (d->coarse)
        o->bound_index = CTL_BOUND_COUNT - 1;
    if (o->max_rate > tick_rate / d->rate_div)
        o->max_rate = tick_rate / d->rate_div;
}

static bool same_service(const struct subscription *x, const struct subscription *y)
{
    int kx[LAYER_KEYS_ALL] = { 0 }, ky[LAYER_KEYS_ALL] = { 0 };
    subscription_layer_keys(x, kx, 1);
    subscription_layer_keys(y, ky, 1);
    return x->max_rate == y->max_rate && memcmp(kx, ky, sizeof kx) == 0;
}

/* The rung defs this subscription has (distinct services), into def[]. */
static int rungs_of(const struct subscription *a, double tick_rate, signed char def[LADDER_MAX_RUNGS])
{
    struct subscription prev, cur;
    int n = 0;
    /* Raw float32 (bound 0) asks for exact samples: a checker, not a
     * viewer; no rung of it is exact, so it is served as asked. */
    bool pinned = a->pinned || a->bound_index == 0 || !subscription_has_frames(a); /* nothing to adapt */
    for (int i = 0; i < NDEFS && n < (pinned ? 1 : LADDER_MAX_RUNGS); i++) {
        apply_def(a, &DEFS[i], tick_rate, &cur);
        if (n && same_service(&prev, &cur))
            continue;
        def[n++] = (signed char)i;
        prev = cur;
    }
    return n;
}

static void rung_sub(const struct net *n, const struct subscription *a, int rung, struct subscription *o)
{
    signed char def[LADDER_MAX_RUNGS];
    int nr = rungs_of(a, n->dc.tick_rate, def);
    if (rung >= nr)
        rung = nr - 1;
    apply_def(a, &DEFS[def[rung]], n->dc.tick_rate, o);
}

/* Samples per frame a subscription asks for at the current N. */
static double samples_of(const struct net *n, const struct subscription *s)
{
    int ts = net_tile_size(n), tps = n->applied.resolution / (ts > 0 ? ts : 1);
    int ntiles = 0;
    if (s->all_tiles)
        ntiles = tps * tps;
    else
        for (int i = 0; i < s->ntiles; i++)
            ntiles += s->tiles[i][0] < tps && s->tiles[i][1] < tps;
    int keys[LAYER_KEYS_ALL] = { 0 };
    subscription_layer_keys(s, keys, 1);
    double total = 0;
    for (int k = 0; k < LAYER_KEYS_ALL; k++)
        if (keys[k] && layer_key_which_cascade(k) < n->applied.cascades) {
            int w = ts >> layer_key_lod(k);
            total += (double)ntiles * w * w;
        }
    return total;
}

/* Bytes per second rung r needs, once its stream runs (shared tiles for a
 * temporal client, intra otherwise). */
static double need_bps(const struct net *n, const struct session *s, int rung)
{
    struct subscription o;
    rung_sub(n, &s->sub, rung, &o);
    bool shared = s->sub.temporal && o.max_rate >= n->dc.tick_rate;
    double bits = shared ? s->lad.bits_t : s->lad.bits_i;
    if (shared && rung < LADDER_MAX_RUNGS && s->lad.bits_r[rung] > 0)
        bits = s->lad.bits_r[rung]; /* a coarser LOD predicts less well per sample: what it cost when it ran */
    return samples_of(n, &o) * bits / 8 * o.max_rate;
}

static void tell(struct net *n, struct session *s)
{
    struct ladder *l = &s->lad;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", "link");
    cJSON_AddNumberToObject(o, "rung", l->rung);
    cJSON_AddNumberToObject(o, "rungs", l->nrungs);
    cJSON_AddBoolToObject(o, "adapt", !s->sub.pinned);
    cJSON_AddItemToObject(o, "subscription", control_subscription_object(&s->eff));
    cJSON_AddNumberToObject(o, "link_kbps", floor(l->rate_bps * 8 / 1000 + 0.5));
    cJSON_AddNumberToObject(o, "rtt_ms", floor(l->rtt_ms * 10 + 0.5) / 10);
    cJSON_AddStringToObject(o, "reason", l->why);
    session_queue_json(s, o);
    l->told = true;
    atomic_fetch_add(&g_metrics.link_sent, 1);
}

/* Serve rung r: demand moves from the old layers to the new ones, and a
 * temporal client starts over (keyframe tiles, PROTOCOL.md §5.9). */
static void set_rung(struct net *n, struct session *s, int r, double now)
{
    struct subscription *o = malloc(sizeof *o); /* ~4 kB: not on the stack */
    if (!o)
        return;
    rung_sub(n, &s->sub, r, o);
    if (r < s->lad.rung)
        s->lad.up_t = now;
    s->lad.rung = r;
    s->lad.changed_t = now;
    s->lad.calm = 0;
    if (!same_service(o, &s->eff)) {
        fanout_want_keyframes(n, s, false);
        dispatch_demand(n, o, +1);
        dispatch_demand(n, &s->eff, -1);
        s->eff = *o;
        fanout_subscribed(n, s);
    }
    free(o);
    atomic_fetch_add(&g_metrics.rung_changes, 1);
    tell(n, s);
}

void ladder_open(struct net *n, struct session *s)
{
    struct ladder *l = &s->lad;
    memset(l, 0, sizeof *l);
    l->hold = HOLD_MIN_S;
    l->bits_t = 1.5; /* measured at 1 cm, N = 256 (docs/codec.md); replaced by what this client's frames cost */
    l->bits_i = 4.0;
    l->win_t = l->open_t = mono_now();
    l->win_lag_min = INT_MAX;
    l->changed_t = l->win_t; /* its first keyframes settle like a change's */
    l->lowat = LOWAT_START;
    tcp_probe_lowat(lws_get_socket_fd(s->wsi), l->lowat);
    s->eff = s->sub;
    signed char def[LADDER_MAX_RUNGS];
    l->nrungs = rungs_of(&s->sub, n->dc.tick_rate, def);
}

void ladder_subscribed(struct net *n, struct session *s)
{
    struct ladder *l = &s->lad;
    signed char def[LADDER_MAX_RUNGS];
    l->nrungs = rungs_of(&s->sub, n->dc.tick_rate, def);
    /* A new subscription keeps the rung the link allowed (not its keyframes
     * at full detail on a slow link), unless pinned. */
    if (l->rung >= l->nrungs)
        l->rung = l->nrungs - 1;
    rung_sub(n, &s->sub, l->rung, &s->eff);
}

void ladder_announce(struct net *n, struct session *s)
{
    if (s->lad.told || s->lad.rung) { /* a client that never heard of the ladder hears nothing new */
        snprintf(s->lad.why, sizeof s->lad.why, "subscribed");
        tell(n, s);
    }
}

void ladder_tick(struct net *n, struct session *s, const struct frame *f, int lost, int lag)
{
    struct ladder *l = &s->lad;
    if (f)
        l->win_ticks++;
    if (f && l->held) {
        l->win_full++; /* a frame waits for the link to take what is in flight */
    } else if (f && s->cur) {
        /* Busy with an older frame: is the socket full (the link or the
         * reader is the bottleneck) or waiting for this thread (the daemon
         * is late: a lower rung would not help)? */
        struct tcp_probe p;
        tcp_probe_read(lws_get_socket_fd(s->wsi), &p);
        if (!p.ok || p.notsent >= l->lowat / 2)
            l->win_full++;
    }
    l->win_skips += lost;
    if (lag > l->win_lag)
        l->win_lag = lag;
    if (f && lag < l->win_lag_min)
        l->win_lag_min = lag;
}

void ladder_frame_done(struct net *n, struct session *s, size_t bytes)
{
    struct ladder *l = &s->lad;
    if (l->frame_samples == 0)
        return;
    l->done_t = mono_now();
    double bits = 8.0 * (double)bytes / (double)l->frame_samples;
    double *e = l->frame_shared ? &l->bits_t : &l->bits_i;
    *e += 0.2 * (bits - *e);
    if (l->frame_shared && l->rung < LADDER_MAX_RUNGS) {
        double *r = &l->bits_r[l->rung];
        *r = *r > 0 ? *r + 0.2 * (bits - *r) : bits;
    }
}

size_t ladder_chunk(const struct session *s)
{
    return s->lad.lowat < LOWAT_MIN ? LOWAT_MIN : s->lad.lowat > CHUNK_SIZE ? CHUNK_SIZE : s->lad.lowat;
}

/* A new frame (or part) waits while the bytes in flight and unsent pass
 * about one and a half times what the link holds over the path's RTT: TCP
 * would take them (BBR's window is up to 3 times that while it believes it
 * is starting up) and queue them at the bottleneck, where no reply can
 * overtake them and a drop-tail queue loses them. Held here, a backlog is
 * the ladder's lag (a lower rung gets the room back) and a reply goes first.
 * The link: a recent full-pipe measurement, else the largest recent sample
 * (a lower bound: what is in flight may then grow by half each round trip,
 * so a link that got faster is found; without this, a probe's keyframes
 * after a long calm went out at BBR's start-up rate and queued replies for
 * a quarter of a second at 2 Mbit/s; not on a path of under a millisecond).
 * Returns microseconds to wait (what the excess takes at that rate), 0 to
 * go on; no limit in TCP's start-up. */
int ladder_hold_frame(struct session *s)
{
    struct ladder *l = &s->lad;
    double now = mono_now();
    l->held = false;
    double link = l->cap_bps > 0 && now - l->cap_t < CAP_FRESH_S ? l->cap_bps
                  : now - l->open_t > YOUNG_S && l->min_rtt_ms >= HOLD_RTT_MIN_MS ? l->rate_bps : 0;
    if (link <= 0 || l->min_rtt_ms <= 0)
        return 0;
    struct tcp_probe p;
    tcp_probe_read(lws_get_socket_fd(s->wsi), &p);
    if (!p.ok)
        return 0;
    double rtt_s = l->min_rtt_ms / 1000;
    double budget = link * (rtt_s + fmin((INFLIGHT_GAIN - 1) * rtt_s, QUEUE_MAX_S));
    double floor = 4.0 * (double)ladder_chunk(s);
    double over = (double)p.inflight + p.notsent - (budget > floor ? budget : floor);
    if (over <= 0)
        return 0;
    double us = over / link * 1e6;
    l->held = true;
    return us < 1000 ? 1000 : us > 20000 ? 20000 : (int)us;
}

static void estimate(struct net *n, struct session *s, double now)
{
    struct ladder *l = &s->lad;
    struct tcp_probe p;
    tcp_probe_read(lws_get_socket_fd(s->wsi), &p);
    if (!p.ok)
        return;
    l->rtt_ms = l->rtt_ms > 0 ? l->rtt_ms + 0.25 * (p.rtt_ms - l->rtt_ms) : p.rtt_ms;
    if (p.min_rtt_ms > 0)
        l->min_rtt_ms = p.min_rtt_ms;
    l->notsent = p.notsent;
    /* An app-limited sample is a lower bound of the link (we sent less than
     * it takes); a sample of a full pipe is the link. Keep the larger of the
     * recent ones, and let a full-pipe sample lower it after 2 s. */
    /* TCP's restart after a stall (a retransmission timeout, then slow
     * start) samples less than the link: such a sample may raise the
     * estimate, not lower it (TCP's start-up sets no measurement at all).
     * Its samples once read 0.5 Mbit/s on a 10 Mbit/s link, and the step
     * down after the stall went to the rung that fitted them, rung 7. */
    bool restarting = l->stalled_t > 0 && now - l->stalled_t < YOUNG_S;
    if (p.delivery_bps > 0 && !p.app_limited && now - l->open_t > YOUNG_S &&
        (!restarting || p.delivery_bps > l->cap_bps)) {
        l->cap_bps = p.delivery_bps;
        l->cap_t = now;
    }
    if (p.delivery_bps > 0 &&
        (p.delivery_bps > l->rate_bps || (!p.app_limited && !restarting && now - l->rate_t > 2.0))) {
        l->rate_bps = p.delivery_bps;
        l->rate_t = now;
    }
    /* ...but an app-limited sample can read above the link (ACKs bunched
     * by a repaired loss: 1.46 Mbit/s on a lossy 1 Mbit/s link), and a
     * recent full-pipe one is the link: no more than that. */
    bool measured = l->cap_bps > 0 && now - l->cap_t < CAP_FRESH_S;
    if (measured && l->rate_bps > l->cap_bps)
        l->rate_bps = l->cap_bps;
    /* TCP paces at most a little above the link measured: BBR that never
     * leaves its start-up (the stream is app-limited most of the time) sends
     * a backlog at 2.9 times its estimate, overflows the bottleneck's queue
     * and loses packets by the dozen, and every loss holds what follows it
     * for a round trip. Lifted when no measurement is recent. */
    double pace = measured ? PACE_GAIN * l->cap_bps : 0;
    if ((pace == 0) != (l->pace_bps == 0) || pace > l->pace_bps * 1.1 || pace < l->pace_bps * 0.9) {
        l->pace_bps = pace;
        tcp_probe_pacing(lws_get_socket_fd(s->wsi), pace);
    }
    /* About one tick of the link may wait unsent: a frame that fits the
     * link leaves in its tick, and a reply waits behind no more. */
    if (l->rate_bps > 0) {
        double want = l->rate_bps / n->dc.tick_rate;
        uint32_t w = want < LOWAT_MIN ? LOWAT_MIN : want > LOWAT_MAX ? LOWAT_MAX : (uint32_t)want;
        if (w > l->lowat * 5 / 4 || w < l->lowat * 3 / 4) {
            l->lowat = w;
            tcp_probe_lowat(lws_get_socket_fd(s->wsi), w);
        }
    }
}

void ladder_police(struct net *n, struct session *s, double now)
{
    struct ladder *l = &s->lad;
    estimate(n, s, now);
    if (now - l->win_t < WINDOW_S)
        return;
    int ticks = l->win_ticks, skips = l->win_skips, lag = l->win_lag, full = l->win_full;
    int lag_min = l->win_lag_min == INT_MAX ? 0 : l->win_lag_min;
    l->win_t = now;
    l->win_ticks = l->win_skips = l->win_lag = l->win_full = 0;
    l->win_lag_min = INT_MAX;
    if (l->nrungs <= 1 || ticks < 3)
        return;
    /* A frame waits (in progress, held for what is in flight, or not begun
     * because the socket takes nothing) and no byte left for a window plus
     * the client's own frame interval: a stall (a dead radio link, a page
     * that stopped reading), not a rate. A lower rung would not help and
     * would cost the way back up: skip ticks and wait. */
    bool waiting = s->cur || l->held || fanout_want_write(n, s);
    if (waiting && now - s->progress_t > WINDOW_S + 1.0 / s->eff.max_rate) {
        l->calm = 0;
        l->prev_lag_min = 0; /* the way out of it is judged on its own windows */
        l->stalled_t = now;
        return;
    }
    /* The window a stall ended in and the next: their lost ticks are the
     * stall's, and the client then works off what the stall held back. */
    double since_stall = l->stalled_t > 0 ? now - l->stalled_t : INFINITY;
    if (since_stall < 2 * WINDOW_S + 0.01) {
        l->prev_lag = l->prev_lag_min = 0;
        return;
    }
    /* Lost ticks; or running far behind and not catching up (a client
     * working off its keyframes gets closer window after window); or behind
     * at every tick for two windows: the stream leaves the link too little
     * room to work off a delay (a lost packet holds TCP for a round trip),
     * so the client keeps seeing the sea late. A lower rung is sent from the
     * newest frame on and gets the room back. */
    int behind = (int)(BEHIND_S * n->dc.tick_rate + 0.5);
    if (behind < 2)
        behind = 2;
    bool late = lag_min >= behind && l->prev_lag_min >= behind &&
                since_stall > YOUNG_S; /* after a stall, a client catching up on the ring is behind by design */
    bool congested = full > 0 && (skips * 100 > ticks * LOST_MAX_PCT || late ||
                                  (lag > LAG_MAX / 2 && l->prev_lag > LAG_MAX / 2 && lag >= l->prev_lag));
    l->prev_lag = lag;
    l->prev_lag_min = lag_min;
    bool settling = now - l->changed_t < SETTLE_S;
    if (congested && !settling && l->rung < l->nrungs - 1) {
        if (now - l->up_t < PROBE_FAIL_S)
            l->hold = fmin(l->hold * 2, HOLD_MAX_S);
        int r = l->rung + 1;
        /* Further at once to the first rung the estimate says fits, once TCP's
         * start-up is over (its early samples are not the link's). The
         * estimate is the largest recent sample: one sample of a pipe full for
         * another reason (a busy reader, a lost packet) does not lower it. */
        while (r < l->nrungs - 1 && now - l->open_t > YOUNG_S && since_stall > YOUNG_S && l->rate_bps > 0 &&
               need_bps(n, s, r) > FIT * l->rate_bps)
            r++;
        snprintf(l->why, sizeof l->why, "congestion: %d of %d ticks lost, %d to %d behind; link %.0f kbit/s",
                 skips, ticks, lag_min, lag, l->rate_bps * 8 / 1000);
        set_rung(n, s, r, now);
        return;
    }
    if (congested)
        return;
    l->calm++;
    double calm_s = l->calm * WINDOW_S;
    if (calm_s >= HOLD_RESET_S)
        l->hold = HOLD_MIN_S;
    if (l->rung == 0 || settling)
        return;
    double need = need_bps(n, s, l->rung - 1);
    bool fits = l->rate_bps > 0 && need <= FIT * l->rate_bps;
    /* A blind probe (the estimate is app-limited: we sent less than the
     * link takes) unless a full-pipe sample of the last minute says it
     * cannot fit, with the room a rung needs to work off a delay. */
    double memory = l->min_rtt_ms >= HOLD_RTT_MIN_MS ? HOPELESS_S : CAP_FRESH_S; /* a local reader is slow for its CPU, not a link */
    bool hopeless = l->cap_bps > 0 && now - l->cap_t < memory && need > FIT * l->cap_bps;
    if ((fits && calm_s >= 2.0) || (calm_s >= l->hold && !hopeless)) {
        snprintf(l->why, sizeof l->why, "probe: %.0f kbit/s for the rung above, link %.0f kbit/s%s", need * 8 / 1000,
                 l->rate_bps * 8 / 1000, fits ? "" : " (estimate app-limited)");
        set_rung(n, s, l->rung - 1, now);
    }
}

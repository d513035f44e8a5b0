/* fanout.c — frames to clients, latest frame wins.
 *
 * net.latest is the newest frame the tick thread published. A client sends
 * one frame at a time: its header (with its own tile count) and the byte
 * ranges of the tiles it subscribed to, copied from the shared layers into
 * its own LWS_PRE-prefixed chunk buffer, as a fragmented WebSocket message.
 * A client that is still busy when newer frames arrive skips them: it holds
 * a reference to at most the one frame it is sending, so it never slows the
 * others and memory stays flat. Nothing is encoded per client. */
#include "net_internal.h"

#include "clock.h"

#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "metrics.h"
#include "sim_thread.h"

/* Depth of a codec 3 tile is at most 4 (PROTOCOL.md §5.6): a client that
 * holds 4 consecutive ticks can always take the shared tiles. */
#define TEMPORAL_MAX_NEED 4

void fanout_want_keyframes(struct net *n, struct session *s, bool want)
{
    want = want && s->eff.temporal && (n->sim || n->cluster.keyframes); /* edge: its sim hears it (the wish) */
    if (want == s->key_wanted)
        return;
    int keys[LAYER_KEYS_ALL] = { 0 }; /* the keys dispatch_demand counts as temporal */
    subscription_layer_keys(&s->eff, keys, 1);
    for (int key = 0; key < LAYER_KEYS_ALL; key++)
        if (keys[key]) {
            if (n->sim)
                sim_want_keyframes(n->sim, key, want ? 1 : -1);
            else if (n->cluster.keyframes)
                n->cluster.keyframes(n->cluster.user, key, want ? 1 : -1);
        }
    s->key_wanted = want;
}

void fanout_subscribed(struct net *n, struct session *s)
{
    s->hist = 0;
    s->hist_seq = 0;
    fanout_want_keyframes(n, s, true);
}

/* ---- recent frames ----
 *
 * A temporal client a few ticks behind (a keyframe took longer than a tick
 * on its link) is sent the tick after the last one it got, not the newest:
 * it keeps its chain and takes the small shared tiles while it catches up,
 * instead of skipping to keyframe tiles it can send no faster (the keyframe
 * trap). net.ring keeps the last NET_RING frames for that; a client more
 * than LAG_MAX ticks behind skips to the newest as before. */
static struct frame *ring_find(const struct net *n, uint64_t seq)
{
    for (int i = n->nring - 1; i >= 0; i--)
        if (n->ring[i]->hdr.seq == seq)
            return n->ring[i];
    return NULL;
}

static void ring_clear(struct net *n)
{
    for (int i = 0; i < n->nring; i++)
        frame_unref(n->ring[i]);
    n->nring = 0;
}

static void ring_push(struct net *n, struct frame *f)
{
    frame_ref(f);
    if (n->nring == NET_RING) {
        frame_unref(n->ring[0]);
        memmove(n->ring, n->ring + 1, sizeof n->ring[0] * (NET_RING - 1));
        n->nring--;
    }
    n->ring[n->nring++] = f;
    size_t bytes = 0;
    for (int i = 0; i < n->nring; i++)
        bytes += frame_bytes(n->ring[i]);
    while (n->nring > 1 && bytes > NET_RING_MAX_BYTES) { /* large N: fewer frames kept */
        bytes -= frame_bytes(n->ring[0]);
        frame_unref(n->ring[0]);
        memmove(n->ring, n->ring + 1, sizeof n->ring[0] * (size_t)(n->nring - 1));
        n->nring--;
    }
}

void fanout_free_ring(struct net *n) { ring_clear(n); }

/* s will be sent the tick after its last one, newest being f's seq. */
static bool catching_up(const struct net *n, const struct session *s, uint64_t newest)
{
    return s->eff.temporal && s->eff.max_rate >= n->dc.tick_rate && s->hist_seq && s->hist > 0 &&
           newest <= s->hist_seq + 1 + LAG_MAX && ring_find(n, s->hist_seq + 1);
}

/* Frames up to index upto that s did not get are holes. They tell the
 * ladder about the link only when s was busy sending until then (not when it
 * waited for keyframe tiles or for max_rate). */
static void count_holes(struct net *n, struct session *s, uint64_t upto)
{
    uint64_t done = s->counted_index > s->last_index ? s->counted_index : s->last_index;
    if (upto <= done)
        return;
    uint64_t k = upto - done;
    s->counted_index = upto;
    bool throttled = s->eff.max_rate < n->dc.tick_rate;
    atomic_fetch_add(throttled ? &g_metrics.dropped_rate : &g_metrics.dropped_slow, k);
    bool busy = s->cur || mono_now() - s->lad.done_t < 1.5 / n->dc.tick_rate;
    ladder_tick(n, s, NULL, throttled || !busy ? 0 : (int)k, 0);
}

/* Frame f was published. Per client: the frames it will never get are
 * counted now (a client that stopped reading shows in the metrics at once;
 * per client the count equals the holes in the seq numbers it receives),
 * except for a client still catching up, whose holes are counted when it
 * skips; its ladder sees the tick and its lag; a temporal client that will
 * not get the tick before f loses its chain and wants this tick's keyframe
 * tiles, so that the next frames carry them. */
static void on_publish(struct net *n, const struct frame *f)
{
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
        struct session *s = session_of(d);
        if (!subscription_has_frames(&s->eff))
            continue; /* a control connection: no frames, no holes, nothing for its ladder */
        bool catching = catching_up(n, s, f->hdr.seq);
        if (n->seen_any && s->last_seq && s->last_seq < f->hdr.seq && !catching)
            count_holes(n, s, f->index - 1);
        /* Behind: still sending a frame older than the one before f, or
         * holding the next one while the link takes what is in flight. */
        uint64_t at = s->cur ? s->cur->hdr.seq : s->lad.held ? s->last_seq + 1 : 0;
        int lag = at && f->hdr.seq > at + 1 ? (int)(f->hdr.seq - at - 1) : 0;
        ladder_tick(n, s, f, 0, lag > 1000 ? 1000 : lag);
        if (s->eff.temporal && !s->key_wanted && s->hist_seq + 1 < f->hdr.seq && !catching)
            fanout_want_keyframes(n, s, true);
    }
}

void fanout_take_latest(struct net *n)
{
    fanout_set_latest(n, sim_latest(n->sim));
}

void fanout_set_latest(struct net *n, struct frame *f)
{
    if (f == n->latest) {
        frame_unref(f);
        return;
    }
    bool temporal = false; /* only temporal clients catch up: nobody else needs the ring's memory */
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d && !temporal; d = d->next)
        temporal = session_of(d)->eff.temporal;
    if (f && temporal) {
        ring_push(n, f);
    } else {
        ring_clear(n);
    }
    if (f) {
        on_publish(n, f);
        n->seen_any = true;
        n->seen_index = f->index;
        n->seen_seq = f->hdr.seq;
    }
    frame_unref(n->latest);
    n->latest = f; /* NULL after a tick that built no frame: nothing stale is kept */
}

void net_stream_restart(struct net *n)
{
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
        struct session *s = session_of(d);
        s->last_seq = 0;   /* the next frame is new whatever its seq */
        s->first_seq = 0;
        s->hist = 0;       /* no references across the restart */
        s->hist_seq = 0;
    }
    n->seen_any = false;
    ring_clear(n);
    frame_unref(n->latest);
    n->latest = NULL;
}

void net_stream_new_chains(struct net *n)
{
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
        struct session *s = session_of(d);
        s->hist = 0;       /* references of the other sim's chains: useless now */
        s->hist_seq = 0;
    }
    ring_clear(n);         /* nobody catches up across it */
}

bool fanout_want_write(const struct net *n, const struct session *s)
{
    const struct frame *f = n->latest;
    return f && f->hdr.seq > s->last_seq && f->hdr.seq >= s->first_seq && subscription_has_frames(&s->eff);
}

/* Prepare s->cur = f for this client: header, layers, tile list. false if the
 * frame lacks a layer this client needs (its subscription just changed), or
 * a temporal client lacks the references of a layer's shared tiles and the
 * frame has no keyframe tiles for it (it asked for them: the next frame). */
static bool begin_frame(struct net *n, struct session *s, struct frame *f)
{
    int tps = f->tiles_per_side;
    int nf = 0;
    uint64_t samples_per_tile = 0; /* over the layers: for the ladder's bits per sample */
    /* Ticks this client received in a row up to the one before f (§5.9). */
    int usable = s->hist_seq && s->hist_seq + 1 == f->hdr.seq ? s->hist : 0;
    int nshared = 0;
    for (int c = 0; c < OCEAN_MAX_CASCADES; c++) {
        int lod, bound_index;
        unsigned fields = c < f->ncascades ? subscription_cascade(&s->eff, c, &lod, &bound_index) : 0;
        for (int fi = 0; fi < OCEAN_FIELD_COUNT; fi++) {
            int slot = c * OCEAN_FIELD_COUNT + fi;
            s->layers[slot] = NULL;
            if (!(fields & OCEAN_FIELD_BIT(fi)))
                continue;
            int llod = c == 0 ? subscription_lod(&s->eff, fi) : lod;
            const struct layer *l = frame_layer_cascade(f, c, fi, llod, bound_index);
            if (!l)
                return false;
            int w = f->hdr.tile_size >> llod;
            samples_per_tile += (uint64_t)w * (uint64_t)w;
            if (s->eff.temporal && l->shared_off && usable >= l->need) {
                s->lbuf[slot] = l->shared.data;
                s->loff[slot] = l->shared_off;
                nshared++;
            } else if (l->tile_off) {
                s->lbuf[slot] = l->buf.data;
                s->loff[slot] = l->tile_off;
            } else {
                fanout_want_keyframes(n, s, true);
                if (s->waited_seq != f->hdr.seq)
                    atomic_fetch_add(&g_metrics.frames_waited_keyframe, 1);
                s->waited_seq = f->hdr.seq;
                return false;
            }
            s->layers[slot] = l;
            nf++;
        }
    }
    s->ntiles = 0;
    if (s->eff.all_tiles) {
        for (int i = 0; i < tps * tps; i++)
            s->tiles[s->ntiles++] = (uint16_t)i;
    } else {
        for (int i = 0; i < s->eff.ntiles; i++)
            if (s->eff.tiles[i][0] < tps && s->eff.tiles[i][1] < tps)
                s->tiles[s->ntiles++] = (uint16_t)(s->eff.tiles[i][1] * tps + s->eff.tiles[i][0]);
    }
    s->lad.frame_samples = samples_per_tile * (uint64_t)s->ntiles;
    s->lad.frame_shared = nf > 0 && nshared == nf;
    s->fhdr = f->hdr;
    if (s->eff.temporal) {
        atomic_fetch_add(&g_metrics.sent_shared_tiles, (uint64_t)(nshared * s->ntiles));
        atomic_fetch_add(&g_metrics.sent_key_tiles, (uint64_t)((nf - nshared) * s->ntiles));
        s->hist = usable + 1;
        s->hist_seq = f->hdr.seq;
        fanout_want_keyframes(n, s, s->hist < TEMPORAL_MAX_NEED || s->eff.max_rate < n->dc.tick_rate);
    }
    frame_ref(f);
    s->cur = f;
    /* The tick's bodies: a header extension of its first part (PROTOCOL.md §3.5). */
    s->ext = f->bodies ? f->bodies->section : NULL;
    s->ext_len = f->bodies ? f->bodies->section_len : 0;
    s->sent = 0;
    s->part_left = 0;
    s->hdr_off = 0;
    s->fi = 0;
    s->ti = 0;
    s->off = 0;
    return true;
}

/* Copy the next bytes of the client's frame into dst. */
static size_t fill(struct session *s, unsigned char *dst, size_t cap)
{
    size_t n = 0;
    if (s->hdr_off < OC_FRAME_HEADER_SIZE) {
        size_t take = OC_FRAME_HEADER_SIZE - (size_t)s->hdr_off;
        if (take > cap)
            take = cap;
        memcpy(dst, s->hdr + s->hdr_off, take);
        s->hdr_off += (int)take;
        n += take;
    }
    if (n < cap && s->ext_off < s->ext_len) { /* the header extension (the BODY section) */
        size_t take = s->ext_len - s->ext_off;
        if (take > cap - n)
            take = cap - n;
        memcpy(dst + n, s->ext + s->ext_off, take);
        s->ext_off += take;
        n += take;
    }
    while (n < cap && s->fi < OCEAN_MAX_CASCADES * OCEAN_FIELD_COUNT) {
        if (!s->layers[s->fi] || s->ti >= s->ntiles) {
            s->fi++;
            s->ti = 0;
            s->off = 0;
            continue;
        }
        int tile = s->tiles[s->ti];
        const uint32_t *off = s->loff[s->fi];
        size_t start = off[tile], size = off[tile + 1] - start;
        size_t take = size - s->off;
        if (take > cap - n)
            take = cap - n;
        memcpy(dst + n, s->lbuf[s->fi] + start + s->off, take);
        n += take;
        s->off += take;
        if (s->off == size) {
            s->ti++;
            s->off = 0;
        }
    }
    return n;
}

/* Start the next part of the client's frame at the current tile: as many
 * tiles as fit in `cap` bytes with the header (at least one). A client that
 * subscribed with "parts" gets its frame in parts of about one tick of its
 * link (ladder_chunk), so that a reply waits behind one part, not a whole
 * keyframe (a text message cannot come between the fragments of one binary
 * message); any other client gets the frame as one part (PROTOCOL.md §3.4). */
static void begin_part(struct session *s, size_t cap)
{
    /* Only the first part carries the tick's BODY section (PROTOCOL.md §3.5). */
    if (s->sent > 0)
        s->ext_len = 0;
    s->ext_off = 0;
    size_t bytes = OC_FRAME_HEADER_SIZE + s->ext_len;
    int count = 0;
    bool more = false;
    for (int fi = s->fi, ti = s->ti; fi < OCEAN_MAX_CASCADES * OCEAN_FIELD_COUNT && !more; fi++, ti = 0)
        for (; s->layers[fi] && ti < s->ntiles; ti++) {
            size_t size = s->loff[fi][s->tiles[ti] + 1] - s->loff[fi][s->tiles[ti]];
            if (count && bytes + size > cap) {
                more = true;
                break;
            }
            bytes += size;
            count++;
        }
    struct oc_frame_header h = s->fhdr;
    h.tile_count = (uint16_t)count;
    h.flags = (uint16_t)(h.flags | (more ? OC_FRAME_FLAG_PART : 0));
    oc_frame_header_write(s->hdr, &h);
    if (s->ext_len) { /* header_size (offset 6, u16 LE) covers the extension */
        size_t hs = OC_FRAME_HEADER_SIZE + s->ext_len;
        s->hdr[6] = (uint8_t)hs;
        s->hdr[7] = (uint8_t)(hs >> 8);
    }
    s->hdr_off = 0;
    s->part_left = bytes;
    s->part_more = more;
}

static int send_chunk(struct net *n, struct session *s)
{
    if (!s->chunk && !(s->chunk = malloc(LWS_PRE + CHUNK_SIZE)))
        return -1;
    if (s->part_left == 0)
        begin_part(s, s->eff.parts ? ladder_chunk(s) : SIZE_MAX);
    bool first = s->hdr_off == 0;
    size_t want = ladder_chunk(s);
    size_t len = fill(s, s->chunk + LWS_PRE, want < s->part_left ? want : s->part_left);
    s->part_left -= len;
    bool last = s->part_left == 0;
    int flags = lws_write_ws_flags(LWS_WRITE_BINARY, first, last);
    if (lws_write(s->wsi, s->chunk + LWS_PRE, len, (enum lws_write_protocol)flags) < (int)len)
        return -1;
    s->sent += len;
    s->progress_t = mono_now();
    if (last && !s->part_more) {
        atomic_fetch_add(&g_metrics.frames_sent, 1);
        atomic_fetch_add(&g_metrics.bytes_sent, s->sent);
        ladder_frame_done(n, s, s->sent);
        frame_unref(s->cur);
        s->cur = NULL;
    }
    return 0;
}

/* Continue the frame in progress, or start the newest one if it is newer
 * than the last one sent and the client's max_rate allows. Returns 1 if
 * something was written, 0 if not, -1 to close. */
int fanout_write(struct net *n, struct session *s)
{
    if (s->cur && s->part_left == 0) { /* between parts: the next one waits for the link like a frame */
        int hold = ladder_hold_frame(s);
        if (hold > 0) {
            lws_set_timer_usecs(s->wsi, hold);
            return 0;
        }
    }
    if (!s->cur) {
        if (!fanout_want_write(n, s))
            return 0;
        double now = mono_now();
        /* max_rate: wait until a period has (almost) passed; half a tick of slack absorbs jitter. */
        if (s->eff.max_rate < n->dc.tick_rate && now - s->last_frame_t < 1.0 / s->eff.max_rate - 0.5 / n->dc.tick_rate)
            return 0;
        int hold = ladder_hold_frame(s);
        if (hold > 0) {
            lws_set_timer_usecs(s->wsi, hold); /* LWS_CALLBACK_TIMER asks for the writable callback again */
            return 0;
        }
        struct frame *f = n->latest;
        struct frame *next = catching_up(n, s, f->hdr.seq) ? ring_find(n, s->hist_seq + 1) : NULL;
        if (next && next != f && begin_frame(n, s, next)) {
            f = next;
            atomic_fetch_add(&g_metrics.frames_caught_up, 1);
        } else if (!begin_frame(n, s, f)) {
            return 0;
        }
        if (s->last_seq) /* holes count from the first frame on */
            count_holes(n, s, f->index - 1);
        s->last_seq = f->hdr.seq;
        s->last_index = f->index;
        s->last_frame_t = s->progress_t = now;
    }
    return send_chunk(n, s) == 0 ? 1 : -1;
}

/* ---- clients that do not read ----
 *
 * A client holds one reference to the frame it is sending; one that stops
 * reading would hold it for ever, and each such client a different frame
 * (4.9 MB at N = 256 with every field and cascade). Two rules bound that,
 * whatever the client sends (pings and pongs do not count as reading):
 *   stalled: no byte of its frame taken for --idle-timeout seconds;
 *   pinned:  the frames held by clients, the latest excepted, counted once
 *            each, pass NET_PINNED_MAX bytes (16 MB): the clients holding the
 *            oldest are closed until they fit.
 * Either closes the client with 1008 and lets its frame go at once. */
#define NET_PINNED_MAX ((size_t)16 << 20)
#define POLICE_PERIOD_S 0.1

static void let_go(struct session *s, atomic_uint_least64_t *counter, const char *why)
{
    atomic_fetch_add(counter, 1);
    LOGW("client %s: %s: closing it (1008)", s->client_id, why);
    frame_unref(s->cur); /* nothing more of it will be sent */
    s->cur = NULL;
    session_cut_off(s, LWS_CLOSE_STATUS_POLICY_VIOLATION, "not reading");
}

void fanout_police(struct net *n)
{
    double now = mono_now();
    if (now - n->police_t < POLICE_PERIOD_S)
        return;
    n->police_t = now;
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next)
        if (!session_of(d)->closing)
            ladder_police(n, session_of(d), now);
    size_t pinned = 0;
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
        struct session *s = session_of(d);
        if (!s->cur || s->closing)
            continue;
        if (now - s->progress_t > n->dc.idle_timeout) {
            let_go(s, &g_metrics.closed_stalled, "no byte of its frame taken for --idle-timeout");
            continue;
        }
        if (s->cur == n->latest)
            continue;
        bool counted = false; /* once per frame: clients on the same frame share it */
        for (lws_dll2_t *e = lws_dll2_get_head(&n->sessions); e != d && !counted; e = e->next)
            counted = session_of(e)->cur == s->cur;
        if (!counted)
            pinned += frame_bytes(s->cur);
    }
    while (pinned > NET_PINNED_MAX) {
        struct frame *oldest = NULL;
        for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
            struct session *s = session_of(d);
            if (s->cur && s->cur != n->latest && (!oldest || s->cur->hdr.seq < oldest->hdr.seq))
                oldest = s->cur;
        }
        if (!oldest)
            break;
        pinned -= frame_bytes(oldest);
        for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
            struct session *s = session_of(d);
            if (s->cur == oldest)
                let_go(s, &g_metrics.closed_pinned, "the frames held by clients that do not read are over their budget");
        }
    }
}

void fanout_session_free(struct session *s)
{
    frame_unref(s->cur);
    s->cur = NULL;
    free(s->chunk);
    s->chunk = NULL;
}

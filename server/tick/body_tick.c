/* body_tick.c — the floating bodies in the tick pipeline (bodies.h does the
 * physics). The producer owns the world: right after ocean_step of a tick it
 * applies the requests that came in (sim_body_submit), steps every body on
 * that tick's grids of cascade 0, and publishes the tick's bodies (struct
 * body_snap: full states for the lws thread and the state file, and the BODY
 * section for the tick's frame, PROTOCOL.md §3.5). docs/threads.md has the
 * contract. */
#include "tick_internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

#include "body_msg.h"
#include "clock.h"
#include "log.h"
#include "metrics.h"
#include "oc_proto.h"
#include "probe.h"

/* A body step after a long pause of the producer (a change of N, the
 * machine stalling) integrates at most this much sim time: the bodies then
 * lag the sea's clock by the rest, which nobody sees, instead of one tick
 * paying for hundreds of substeps. */
#define BODY_MAX_STEP_S 0.5
#define BODY_MAX_GONE 64    /* bodies reported sunk per tick (more are still removed, and reported later as gone) */

struct body_sim {
    struct body_world *w;
    double t_last;              /* sim time the bodies were last stepped to */
    bool had_bodies;            /* the last tick published some: an empty world is published once */
    uint32_t *adrift;           /* ids whose owner is gone (the record's adrift flag), unordered */
    int nadrift, capacity;
    /* Cascade 0's height of this tick and of the two before, three N x N
     * planes in one block (plane hist_slot is this tick's, the one after it
     * the oldest): the substeps see the sea move through the ticks, and a
     * tick copies one plane (planes rather than triples side by side: a
     * tick wrote every cache line of those, 0.13 ms of CPU at N = 256,
     * while cascade 0's grids are small enough to stay in the cache). */
    float *hist;
    int hist_slot;
    size_t hist_cap;
    struct probe_grids hist_g;  /* the grid they came from (n, cascade 0's patch) */
    double hist_t[3];           /* the sim times of the three */
    int hist_n;                 /* how many of them are real ticks (1..3; 0 = none kept) */
};

/* ---- snapshots ---- */

void body_snap_ref(struct body_snap *b) { atomic_fetch_add(&b->refs, 1); }

void body_snap_unref(struct body_snap *b)
{
    if (b && atomic_fetch_sub(&b->refs, 1) == 1)
        free(b); /* one block: the struct, its states and its section */
}

/* ---- the network side's calls ---- */

void sim_body_submit(struct sim *s, struct sim_body_cmd *c)
{
    c->next = NULL;
    pthread_mutex_lock(&s->lock);
    *s->body_cmds_tail = c;
    s->body_cmds_tail = &c->next;
    pthread_mutex_unlock(&s->lock);
}

struct sim_body_cmd *sim_body_take_answers(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    struct sim_body_cmd *a = s->body_answers;
    s->body_answers = NULL;
    s->body_answers_tail = &s->body_answers;
    pthread_mutex_unlock(&s->lock);
    return a;
}

struct body_snap *sim_bodies_latest(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    struct body_snap *b = s->bodies_latest;
    if (b)
        body_snap_ref(b);
    pthread_mutex_unlock(&s->lock);
    return b;
}

int sim_bodies_restored(struct sim *s) { return s->bodies_restored; }

bool body_wanted_locked(struct sim *s) { return atomic_load(&s->body_count) > 0 || s->body_cmds; }

/* What the bodies read of a tick: cascade 0's height and displacement, not
 * the finer cascades. Those hold waves of 0.3 to 2 m at the default 256 m
 * patch (PROTOCOL.md §4.1), 1.1 and 0.6 cm RMS at any wind (0.5 m RMS in
 * cascade 0 at 10 m/s), shorter than or as long as the smallest hull, whose
 * columns average them out; stepping them for the bodies alone cost the tick
 * two more inverse FFTs (0.7 ms of a 1.7 ms tick at N = 256 with one viewer
 * of cascade 0) and reading them two thirds of the sampling. A fixed rule,
 * not "whatever was stepped": the bodies' motion must not depend on who
 * watches. */
#define BODY_FIELDS_0 (OCEAN_FIELD_BIT(OCEAN_HEIGHT) | OCEAN_FIELD_BIT(OCEAN_DX) | OCEAN_FIELD_BIT(OCEAN_DZ))

void body_want(struct frame_want *w)
{
    w->cfields[0] |= BODY_FIELDS_0;
    w->fields |= BODY_FIELDS_0;
}

/* ---- the world ---- */

static void adrift_set(struct body_sim *b, uint32_t id, bool on)
{
    for (int i = 0; i < b->nadrift; i++)
        if (b->adrift[i] == id) {
            if (!on)
                b->adrift[i] = b->adrift[--b->nadrift];
            return;
        }
    if (on && b->nadrift < b->capacity)
        b->adrift[b->nadrift++] = id;
}

static bool is_adrift(const struct body_sim *b, uint32_t id)
{
    for (int i = 0; i < b->nadrift; i++)
        if (b->adrift[i] == id)
            return true;
    return false;
}

/* Restore every saved body, or none: a state file with one bad body must
 * not start half a scene. */
static int restore_all(struct body_sim *b, const struct sim_config *cfg, char *err, size_t errlen)
{
    for (int i = 0; i < cfg->nrestore; i++) {
        enum body_error e = body_world_restore(b->w, &cfg->restore[i]);
        if (e != BODY_OK) {
            snprintf(err, errlen, "saved body %u refused (%s)", cfg->restore[i].id, body_error_name(e));
            return -1;
        }
        adrift_set(b, cfg->restore[i].id, true); /* its owner has to claim it again */
    }
    /* Ids are never reused across restarts, even those of bodies removed
     * before it. The library issues ids above every restored one, so a
     * placeholder with the last id issued, removed at once, moves its
     * counter on (bodies.h has no call to set it). */
    uint64_t want = cfg->restore_next_id, next = body_world_next_id(b->w);
    if (want > 1 && next != 0 && next < want) {
        struct body_state ph = { .id = (uint32_t)(want - 1), .kind = &body_kinds()[0], .quat = { 1, 0, 0, 0 } };
        if (body_world_restore(b->w, &ph) == BODY_OK)
            body_remove(b->w, ph.id);
    }
    return 0;
}

struct body_sim *body_sim_new(const struct sim_config *cfg, int *restored, char *err, size_t errlen)
{
    *restored = 0;
    int cap = cfg->max_bodies > 0 ? cfg->max_bodies : 1;
    struct body_sim *b = calloc(1, sizeof *b);
    if (b) {
        b->capacity = cap;
        b->adrift = calloc((size_t)cap, sizeof *b->adrift);
        b->w = body_world_new(cap);
    }
    if (!b || !b->adrift || !b->w) {
        body_sim_free(b);
        snprintf(err, errlen, "out of memory (bodies)");
        return NULL;
    }
    if (cfg->nrestore > cap) {
        LOGW("bodies: the state holds %d bodies, more than --max-bodies %d: none restored", cfg->nrestore, cap);
    } else if (restore_all(b, cfg, err, errlen) != 0) {
        LOGW("bodies: %s: none restored", err);
        body_world_free(b->w);
        b->nadrift = 0;
        if (!(b->w = body_world_new(cap))) {
            body_sim_free(b);
            snprintf(err, errlen, "out of memory (bodies)");
            return NULL;
        }
    } else {
        *restored = cfg->nrestore;
    }
    b->t_last = cfg->start_time;
    return b;
}

void body_sim_free(struct body_sim *b)
{
    if (!b)
        return;
    body_world_free(b->w);
    free(b->adrift);
    free(b->hist);
    free(b);
}

/* ---- the sea the bodies meet ---- */

/* Bilinear interpolation of n x n periodic grids (n a power of two) at grid
 * coordinates (u, v): u along x (columns), v along z (rows). The taps and
 * weights are found once (tap_at) and read from every grid of the same
 * cascade (tap_get): dx and dz, this tick's height and the last one's. */
struct tap {
    int i0, i1;                 /* columns */
    size_t r0, r1;              /* offsets of the two rows */
    double a, c;                /* weights along x and z */
};

/* v clamped to [0, hi] by comparisons: fmin and fmax are calls into libm
 * here (no -ffast-math), and this runs five times per hull point and sample. */
static inline double clamp_grid(double v, double hi) { return v > 0 ? (v < hi ? v : hi) : 0; }

static inline void tap_at(struct tap *t, int n, double u, double v)
{
    /* An offset of whole periods keeps both positive, so the conversion to
     * an integer is the floor (cheaper than floor() on hot paths); points
     * further than 65536 patches out are clamped there (bodies stay within
     * a few km). */
    const double off = (double)n * 65536.0;
    u = clamp_grid(u + off, 2 * off);
    v = clamp_grid(v + off, 2 * off);
    long iu = (long)u, iv = (long)v;
    int m = n - 1, i0 = (int)(iu & m), j0 = (int)(iv & m);
    t->a = u - (double)iu;
    t->c = v - (double)iv;
    t->i0 = i0;
    t->i1 = (i0 + 1) & m;
    t->r0 = (size_t)j0 * (size_t)n;
    t->r1 = (size_t)((j0 + 1) & m) * (size_t)n;
}

static inline double tap_get(const struct tap *t, const float *g)
{
    const float *p0 = g + t->r0, *p1 = g + t->r1;
    double top = p0[t->i0] + t->a * (p0[t->i1] - p0[t->i0]);
    double bot = p1[t->i0] + t->a * (p1[t->i1] - p1[t->i0]);
    return top + t->c * (bot - top);
}

struct sea_ctx {
    const struct probe_grids *g; /* this tick's grids: cascade 0's dx, dz and patch */
    const float *plane[3];       /* cascade 0's heights: now, the tick before, the one before */
    int nt;                      /* how many of the three are real ticks */
    double t[3];                 /* their sim times, newest first */
};

/* Weights of the three ticks' heights for the height at t (w) and for its
 * time derivative (d): the parabola through the three ticks (a line through
 * two, a constant for one), so the water's vertical velocity changes
 * smoothly between substeps and the library sees its acceleration. */
static void time_weights(const struct sea_ctx *c, double t, double w[3], double d[3])
{
    const double *T = c->t;
    w[1] = w[2] = d[0] = d[1] = d[2] = 0;
    w[0] = 1;
    if (c->nt >= 3) {
        double a = (T[0] - T[1]) * (T[0] - T[2]), b = (T[1] - T[0]) * (T[1] - T[2]), e = (T[2] - T[0]) * (T[2] - T[1]);
        w[0] = (t - T[1]) * (t - T[2]) / a;
        w[1] = (t - T[0]) * (t - T[2]) / b;
        w[2] = (t - T[0]) * (t - T[1]) / e;
        d[0] = (2 * t - T[1] - T[2]) / a;
        d[1] = (2 * t - T[0] - T[2]) / b;
        d[2] = (2 * t - T[0] - T[1]) / e;
    } else if (c->nt == 2) {
        double span = T[0] - T[1], f = fmin(fmax((t - T[1]) / span, 0), 1);
        w[0] = f;
        w[1] = 1 - f;
        d[0] = 1 / span;
        d[1] = -1 / span;
    }
}

/* The displaced surface above each world point: bilinear on cascade 0's
 * grids (probe_eval's Lanczos-3 costs 9x the taps, too much for up to 64
 * hull points of each of 64 bodies at every substep), the source point
 * found by two fixed-point steps x0 = x - D(x0) on its displacement
 * (body_want says why cascade 0 alone). In time the height follows the
 * parabola through the last three ticks' heights at the same source point
 * (time_weights), and dhdt is its derivative: the substeps of a step (and
 * its first sample, a substep earlier) lie between those ticks, the water a
 * body sees moves smoothly and consistently with its dhdt, and dhdt changes
 * between substeps, which the library needs for the water's acceleration
 * (an exact time derivative would need more inverse FFTs per tick; the drift
 * of the source point itself is left out, a second-order term). */
static int sea_sample(void *ctx, double t, int n, const double (*xz)[2], double *height, double *dhdt)
{
    const struct sea_ctx *c = ctx;
    const struct probe_grids *g = c->g;
    const int N = g->n;
    double w[3], d[3];
    time_weights(c, t, w, d);
    const double scale = N / g->patch[0];
    for (int i = 0; i < n; i++) {
        const double x = xz[i][0], z = xz[i][1];
        double x0 = x, z0 = z;
        struct tap tp;
        for (int it = 0; it < 2; it++) {
            tap_at(&tp, N, x0 * scale, z0 * scale);
            x0 = x - tap_get(&tp, g->dx[0]);
            z0 = z - tap_get(&tp, g->dz[0]);
        }
        tap_at(&tp, N, x0 * scale, z0 * scale);
        double v0 = tap_get(&tp, c->plane[0]), v1 = tap_get(&tp, c->plane[1]), v2 = tap_get(&tp, c->plane[2]);
        height[i] = w[0] * v0 + w[1] * v1 + w[2] * v2;
        dhdt[i] = d[0] * v0 + d[1] * v1 + d[2] * v2;
    }
    return 0;
}

/* This tick's grids of cascade 0, as the library left them after the step
 * (before the frame job takes them): height, dx and dz must have been
 * stepped (a tick planned before the first request came may not be). */
static bool tick_grids(const struct sim *s, const struct prod_job *pj, struct probe_grids *g)
{
    memset(g, 0, sizeof *g);
    g->n = ocean_resolution(s->ocean);
    g->ncasc = 1;
    if ((pj->want.cfields[0] & BODY_FIELDS_0) != BODY_FIELDS_0)
        return false;
    g->patch[0] = ocean_cascade_patch(pj->patch_size, 0);
    g->h[0] = ocean_cascade_field(s->ocean, 0, OCEAN_HEIGHT);
    g->dx[0] = ocean_cascade_field(s->ocean, 0, OCEAN_DX);
    g->dz[0] = ocean_cascade_field(s->ocean, 0, OCEAN_DZ);
    return g->n > 0 && g->h[0] && g->dx[0] && g->dz[0];
}

/* This tick's heights into the history, over its oldest plane. keep: how
 * many older ticks stay valid (0: the history starts afresh: the first
 * tick, a new grid, a gap; every plane gets this tick's). */
static bool update_history(struct body_sim *b, const struct probe_grids *g, double t, int keep)
{
    size_t side = (size_t)g->n * g->n, need = 3 * side;
    if (b->hist_cap < need) {
        free(b->hist);
        b->hist = malloc(need * sizeof(float));
        b->hist_cap = b->hist ? need : 0;
        keep = 0;
    }
    if (!b->hist) {
        b->hist_n = 0;
        return false;
    }
    int slot = keep > 0 ? (b->hist_slot + 1) % 3 : 0; /* the oldest makes room for this tick */
    for (int k = 0; k < 3; k++)
        if (k == slot || keep == 0)
            memcpy(b->hist + side * (size_t)k, g->h[0], side * sizeof(float));
    b->hist_slot = slot;
    b->hist_t[2] = keep > 0 ? b->hist_t[1] : t;
    b->hist_t[1] = keep > 0 ? b->hist_t[0] : t;
    b->hist_t[0] = t;
    b->hist_n = keep + 1 > 3 ? 3 : keep + 1;
    b->hist_g = *g;
    return true;
}

static bool same_grids(const struct probe_grids *a, const struct probe_grids *b)
{
    return a->n == b->n && a->patch[0] == b->patch[0];
}

/* ---- one tick ---- */

/* A take-over (SIM_BODY_RESTORE): every body of c where it was, in a world
 * of its own; the old world stays when one is refused (all or none). */
static enum body_error restore_world(struct body_sim *b, const struct sim_body_cmd *c, double t)
{
    struct body_world *w = body_world_new(b->capacity);
    if (!w)
        return BODY_ERR_FULL;
    enum body_error e = c->nstates > b->capacity ? BODY_ERR_FULL : BODY_OK;
    for (int i = 0; e == BODY_OK && i < c->nstates; i++)
        e = body_world_restore(w, &c->states[i]);
    uint64_t next = body_world_next_id(w);
    if (e == BODY_OK && c->next_id > 1 && next != 0 && next < c->next_id) { /* as restore_all: ids move on */
        struct body_state ph = { .id = (uint32_t)(c->next_id - 1), .kind = &body_kinds()[0], .quat = { 1, 0, 0, 0 } };
        if (body_world_restore(w, &ph) == BODY_OK)
            body_remove(w, ph.id);
    }
    if (e != BODY_OK) {
        body_world_free(w);
        return e;
    }
    body_world_free(b->w);
    b->w = w;
    b->nadrift = 0;
    for (int i = 0; i < c->nstates; i++)
        if (c->adrift_flags[i])
            adrift_set(b, c->states[i].id, true);
    b->t_last = t; /* the motion goes on from here, not from the record's time */
    return BODY_OK;
}

/* The control now in force of body id (a steer that gives one member keeps the other). */
static bool current_control(const struct body_world *w, uint32_t id, struct body_control *out)
{
    struct body_state st;
    for (int i = 0, n = body_world_count(w); i < n; i++)
        if (body_world_get(w, i, &st) == 0 && st.id == id) {
            *out = st.control;
            return true;
        }
    return false;
}

/* sea: this tick's (a launch settles on it), or NULL when its grids are not all there (still water). */
static void apply(struct body_sim *b, struct sim_body_cmd *c, const struct body_sea *sea, double t)
{
    struct body_control ctl;
    switch (c->op) {
    case SIM_BODY_LAUNCH:
        c->status = sea ? body_launch_on(b->w, c->kind, c->x, c->z, c->heading, sea, t, &c->body)
                        : body_launch(b->w, c->kind, c->x, c->z, c->heading, &c->body);
        break;
    case SIM_BODY_STEER:
        if (!current_control(b->w, c->body, &ctl)) {
            c->status = BODY_ERR_NOT_FOUND;
            break;
        }
        if (c->has_throttle)
            ctl.throttle = c->control.throttle;
        if (c->has_rudder)
            ctl.rudder = c->control.rudder;
        c->status = body_steer(b->w, c->body, &ctl);
        break;
    case SIM_BODY_REMOVE:
        c->status = body_remove(b->w, c->body);
        if (c->status == BODY_OK)
            adrift_set(b, c->body, false);
        break;
    case SIM_BODY_ADRIFT:
        if (!current_control(b->w, c->body, &ctl)) {
            c->status = BODY_ERR_NOT_FOUND;
            break;
        }
        adrift_set(b, c->body, c->adrift);
        c->status = c->stop ? body_steer(b->w, c->body, &(struct body_control){ 0, 0 }) : BODY_OK;
        break;
    case SIM_BODY_GONE:
        c->status = BODY_OK;
        break;
    case SIM_BODY_RESTORE:
        c->status = restore_world(b, c, t);
        break;
    }
}

static int8_t steer_byte(double v)
{
    double r = round(fmin(fmax(v, -1), 1) * 127);
    return (int8_t)r;
}

/* The tick's bodies in one block: the struct, the states, the BODY section. */
static struct body_snap *snapshot(const struct body_sim *b, const struct prod_job *pj)
{
    int n = body_world_count(b->w);
    size_t states = (size_t)n * sizeof(struct body_state), section = n ? oc_body_section_size(n) : 0;
    size_t head = (sizeof(struct body_snap) + 15) & ~(size_t)15;
    struct body_snap *snap = malloc(head + states + section + (size_t)n * sizeof(struct oc_body_record));
    if (!snap)
        return NULL;
    atomic_init(&snap->refs, 1);
    snap->seq = pj->seq;
    snap->sim_time = pj->sim_time;
    uint32_t next = body_world_next_id(b->w);
    snap->next_id = next ? next : (uint64_t)UINT32_MAX + 1; /* 0: the last id was issued */
    snap->count = n;
    snap->states = (struct body_state *)((char *)snap + head);
    snap->section = n ? (uint8_t *)snap->states + states : NULL;
    snap->section_len = section;
    /* The records are built in the block's tail, then written out (the tail
     * is spare room afterwards: freed with the rest). */
    struct oc_body_record *rec = (struct oc_body_record *)((uint8_t *)snap->states + states + section);
    for (int i = 0; i < n; i++) {
        struct body_state *st = &snap->states[i];
        body_world_get(b->w, i, st);
        int kind = body_kind_index(st->kind);
        rec[i] = (struct oc_body_record){
            .id = st->id,
            .kind = (uint8_t)(kind < 0 ? 255 : kind),
            .flags = (uint8_t)((is_adrift(b, st->id) ? OC_BODY_FLAG_ADRIFT : 0) |
                               (st->kind->powered ? OC_BODY_FLAG_POWERED : 0)),
            .throttle = steer_byte(st->control.throttle),
            .rudder = steer_byte(st->control.rudder),
        };
        for (int k = 0; k < 3; k++) {
            rec[i].pos[k] = (float)st->pos[k];
            rec[i].vel[k] = (float)st->vel[k];
        }
        for (int k = 0; k < 4; k++)
            rec[i].quat[k] = (float)st->quat[k];
    }
    if (n)
        oc_body_section_write(snap->section, rec, n);
    return snap;
}

struct body_snap *body_tick(struct sim *s, const struct prod_job *pj)
{
    struct body_sim *b = s->bodies;
    if (!b)
        return NULL;
    pthread_mutex_lock(&s->lock);
    struct sim_body_cmd *cmds = s->body_cmds;
    s->body_cmds = NULL;
    s->body_cmds_tail = &s->body_cmds;
    pthread_mutex_unlock(&s->lock);
    if (!cmds && body_world_count(b->w) == 0 && !b->had_bodies) {
        b->t_last = pj->sim_time;
        return NULL;
    }
    /* The previous frame's encode first (helping it; the producer would wait
     * for it next anyway), so the step below does not compete with the encode
     * threads for the cores, and its time is its own. */
    encode_pool_wait(s->pool);
    double t0 = mono_now();
    if (body_world_count(b->w) == 0)
        b->t_last = pj->sim_time; /* a first body starts now, not where the last one stopped */

    /* This tick's sea, for the launches (a body settles on the waves it is
     * put on) and the step. */
    struct probe_grids g;
    struct sea_ctx ctx = { .g = &g };
    struct body_sea sea = { .sample = sea_sample, .ctx = &ctx };
    bool grids = tick_grids(s, pj, &g), frozen = false;
    if (grids) {
        /* The history goes on only from the bodies' last step (not from a tick
         * long ago, before the world was empty) on the same grids; a tick at
         * the same sim time (paused) adds nothing. Out of memory: no step this
         * tick (the next one is longer). */
        bool goes_on = b->hist_n > 0 && same_grids(&b->hist_g, &g) && b->hist_t[0] == b->t_last;
        frozen = goes_on && b->hist_t[0] >= pj->sim_time;
        if (!frozen)
            grids = update_history(b, &g, pj->sim_time, goes_on ? b->hist_n : 0);
    } else {
        b->hist_n = 0; /* this tick's grids are not all there: the history starts again */
    }
    if (grids) {
        ctx.nt = frozen ? 1 : b->hist_n; /* paused: the water stands still */
        for (int k = 0; k < 3; k++)
            ctx.plane[k] = b->hist + (size_t)g.n * g.n * (size_t)((b->hist_slot + 3 - k) % 3);
        memcpy(ctx.t, b->hist_t, sizeof ctx.t);
    }
    struct sim_body_cmd *answers = cmds, **tail = &answers;
    for (struct sim_body_cmd *c = cmds; c; c = c->next) {
        apply(b, c, grids ? &sea : NULL, pj->sim_time);
        c->seq = pj->seq;
        tail = &c->next;
    }

    if (grids && body_world_count(b->w) > 0) {
        double dt = fmin(fmax(pj->sim_time - b->t_last, 0), BODY_MAX_STEP_S);
        uint32_t ids[BODY_MAX_GONE];
        enum body_gone why[BODY_MAX_GONE];
        /* On the producer alone: spread over the encode pool's threads
         * (body_world_step_part), the step took longer with 200 viewers, whose
         * sending keeps a core busy: a chunk's thread waited for a core. */
        int gone = body_world_step(b->w, &sea, pj->sim_time, dt, ids, why, BODY_MAX_GONE);
        for (int i = 0; i < gone; i++) {
            adrift_set(b, ids[i], false);
            struct sim_body_cmd *c = calloc(1, sizeof *c);
            if (!c) {
                LOGE("bodies: out of memory reporting body %u sunk", ids[i]);
                continue;
            }
            c->op = SIM_BODY_GONE;
            c->body = ids[i];
            c->seq = pj->seq;
            *tail = c;
            tail = &c->next;
        }
        b->t_last = pj->sim_time;
    }

    struct body_snap *snap = snapshot(b, pj);
    int count = body_world_count(b->w);
    b->had_bodies = count > 0;
    atomic_store(&s->body_count, count);
    atomic_store(&g_metrics.bodies, count);
    histogram_observe(&g_metrics.body_step_seconds, mono_now() - t0);
    pthread_mutex_lock(&s->lock);
    struct body_snap *old = s->bodies_latest;
    s->bodies_latest = snap;
    if (snap)
        body_snap_ref(snap); /* one for the frame */
    *s->body_answers_tail = answers;
    if (answers)
        s->body_answers_tail = tail;
    pthread_mutex_unlock(&s->lock);
    body_snap_unref(old);
    if (answers && s->cfg.wake) /* a tick without a frame wakes lws only before its step: say it now */
        s->cfg.wake(s->cfg.wake_user);
    if (snap && !snap->count) {
        body_snap_unref(snap); /* no section for the frame */
        return NULL;
    }
    return snap;
}

void body_cmds_free(struct sim_body_cmd *c)
{
    while (c) {
        struct sim_body_cmd *next = c->next;
        cJSON_Delete(c->reply_id);
        free(c->states);
        free(c);
        c = next;
    }
}

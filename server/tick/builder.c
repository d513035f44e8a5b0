/* builder.c — the builder thread: parameter sets checked and prepared off
 * the tick path (ocean_prepare), and their application at a tick boundary
 * (apply_prepared, on the tick thread while the producer is idle). */
#include "tick_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include "clock.h"
#include "control.h"
#include "log.h"
#include "metrics.h"
#include "sea_msg.h"

static void set_failed(struct sim_set *set, enum sim_set_status status, const char *msg)
{
    set->status = status;
    snprintf(set->message, sizeof set->message, "%s", msg);
}

/* ocean_prepare against the ocean in force, or the test hook's simulated
 * out-of-memory (see sim_thread.h). ocean_prepare only reads what the
 * producer's ocean_step does not change, so it runs while frames are made;
 * it never overlaps a commit (the tick commits before it clears ready_full,
 * and the builder prepares only while ready_full is clear). */
static struct ocean_prepared *build_state(struct sim *s, const struct ocean_params *p,
                                          const struct sea_spectrum *sea, enum sim_set_status *why, char *err,
                                          size_t errlen)
{
    if (s->test_fail_seed >= 0 && p->seed == s->test_fail_seed) {
        usleep(500 * 1000); /* long enough for a test to queue another set behind this one */
        snprintf(err, errlen, "out of memory (test hook OCEAND_TEST_FAIL_BUILD_SEED)");
        *why = SIM_SET_NO_MEMORY;
        return NULL;
    }
    *why = SIM_SET_INVALID;
    return ocean_prepare_sea(s->ocean, p, sea, err, errlen);
}

/* ---- measured seas ---- */

/* What a grid holds of a sea depends on these alone (sea_capture). */
static bool capture_differs(const struct ocean_params *a, const struct ocean_params *b)
{
    return a->resolution != b->resolution || a->patch_size != b->patch_size || a->cascades != b->cascades ||
           a->depth != b->depth || a->small_wave_cutoff != b->small_wave_cutoff;
}

char *sim_sea_summary_text(const struct sea_spectrum *sea, const struct sea_capture *cap, uint32_t version)
{
    return control_print(sea_summary_json(sea, cap, version));
}

/* A batch that brings a new sea, or changes the grid under the sea in force:
 * what the grid holds of it (a pass over every mode: here, not on the tick)
 * and the summary `params` carries, on the batch's last set still queued. */
static void sea_summarise(struct sim *s, struct sim_set *sets, const struct sea_spectrum *new_sea,
                          const struct ocean_params *cur)
{
    const struct sea_spectrum *sea = new_sea ? new_sea : s->build_sea;
    if (!sea || (!new_sea && !capture_differs(&s->build_base, cur)))
        return;
    struct sim_set *last = NULL;
    uint32_t version = s->build_version;
    for (struct sim_set *set = sets; set; set = set->next)
        if (set->status == SIM_SET_QUEUED) {
            last = set;
            version = set->adopt ? set->adopt_version : version + 1;
        }
    if (!last)
        return;
    char err[200];
    struct sea_capture cap;
    bool have_cap = sea_capture(sea, cur, &cap, err, sizeof err) == SEA_OK;
    if (!have_cap)
        LOGW("measured sea: what the grid holds is not known: %s", err);
    free(last->sea_summary);
    last->sea_summary = sim_sea_summary_text(sea, have_cap ? &cap : NULL, version);
}

/* A persisted batch's new sea becomes the builder's (a copy: the set that
 * brought it goes back to the network thread). */
static void keep_sea(struct sim *s, const struct sea_spectrum *sea)
{
    if (!sea)
        return;
    struct sea_spectrum *copy = malloc(sizeof *copy);
    if (!copy) { /* the ocean has it; only a SIGHUP save would miss it */
        LOGE("measured sea: out of memory keeping it for the next save");
        return;
    }
    *copy = *sea;
    free(s->build_sea);
    s->build_sea = copy;
}

/* Check each set of a batch on top of the previous one (all or nothing per
 * set) and prepare ONE new state for the whole batch if any physics changed.
 * Allocates nothing but that state: whatever fails, every set is answered
 * and build_base moves only to what was really prepared. */
static void build_batch(struct sim *s, struct sim_set *sets, struct built *out)
{
    struct ocean_params cur = s->build_base;
    uint32_t version = s->build_version; /* the number each set would take */
    const struct sea_spectrum *new_sea = NULL; /* the batch's last new sea (its set owns it) */
    char err[200];
    for (struct sim_set *set = sets; set; set = set->next) {
        struct ocean_params next = params_with(&cur, &set->values, set->mask);
        bool have_sea = set->sea || new_sea || s->build_sea;
        if (params_validate_sea(&next, have_sea, err, sizeof err) != 0) {
            set_failed(set, SIM_SET_INVALID, err);
            continue;
        }
        /* A version names one sea, and frames carry it as a u32: at the
         * last number sets stop, rather than wrap to numbers already used
         * (PROTOCOL.md §7.7). A take-over brings its own, already durable. */
        if (set->adopt) {
            version = set->adopt_version;
        } else if (version == CTL_VERSION_MAX) {
            snprintf(err, sizeof err, "params_version is at its limit (%u): no change can be numbered any more",
                     CTL_VERSION_MAX);
            set_failed(set, SIM_SET_VERSION_LIMIT, err);
            continue;
        } else {
            version++;
        }
        set->prev = cur;
        cur = next;
        if (set->sea)
            new_sea = set->sea;
    }
    out->prepared = NULL;
    out->surface = NULL;
    out->sea = NULL;
    if (params_physics_differ(&s->build_base, &cur) || new_sea) {
        enum sim_set_status why;
        double t0 = mono_now();
        out->prepared = build_state(s, &cur, new_sea, &why, err, sizeof err);
        for (struct sim_set *set = sets; set; set = set->next)
            set->build_s = mono_now() - t0;
        if (!out->prepared) {
            LOGW("applying parameters failed: %s", err);
            for (struct sim_set *set = sets; set; set = set->next)
                if (set->status == SIM_SET_QUEUED)
                    set_failed(set, why, err);
            cur = s->build_base;
            new_sea = NULL;
        }
        if (out->prepared)
            sea_summarise(s, sets, new_sea, &cur);
        out->sea = out->prepared ? new_sea : NULL;
        if (out->prepared && s->cfg.queries) /* the query snapshot, here rather than on the tick (1-8 ms) */
            out->surface = query_snapshot_prepared(s->cfg.queries, s->ocean, out->prepared);
    }
    s->build_base = cur;
    out->params = cur;
    out->sets = sets;
}

/* What build_base and build_version stand for, with the clock now: a
 * SIGHUP save. The state in force or the one waiting in `ready` (persisted
 * when it was built): either way nothing older than what anyone was told. */
static void persist_now(struct sim *s)
{
    char err[300];
    if (s->cfg.persist &&
        s->cfg.persist(s->cfg.persist_user, &s->build_base, s->build_version, atomic_load(&s->now_time),
                       s->build_sea, err, sizeof err) != 0)
        LOGW("saving the state: %s", err);
}

/* Durability before the ack: the batch's outcome is persisted (write +
 * fsync + rename, or a JetStream put: sim_config.persist) before the tick
 * may apply it, so a version is durable before any frame carries it and a
 * set before its `params` goes out; many sets share one save (group
 * commit). A batch that cannot be saved is refused as a whole and the
 * prepared state dropped: the builder's base goes back to `base`. */
static void persist_batch(struct sim *s, struct built *b, const struct ocean_params *base)
{
    uint32_t v = s->build_version;
    int applying = 0;
    for (struct sim_set *set = b->sets; set; set = set->next) {
        if (set->status != SIM_SET_QUEUED)
            continue;
        if (set->adopt) {
            v = set->adopt_version; /* already durable: the record it came from */
        } else {
            v++;
            applying++;
        }
    }
    if (!applying || !s->cfg.persist) {
        s->build_version = v;
        keep_sea(s, b->sea);
        return;
    }
    char err[300];
    if (s->cfg.persist(s->cfg.persist_user, &b->params, v, atomic_load(&s->now_time), b->sea ? b->sea : s->build_sea,
                       err, sizeof err) == 0) {
        s->build_version = v;
        keep_sea(s, b->sea);
        return;
    }
    LOGW("a parameter change could not be saved, so it is refused: %s", err);
    char msg[200];
    snprintf(msg, sizeof msg, "not saved, nothing changed: %.150s", err);
    for (struct sim_set *set = b->sets; set; set = set->next)
        if (set->status == SIM_SET_QUEUED)
            set_failed(set, SIM_SET_NOT_SAVED, msg);
    if (b->prepared)
        ocean_prepared_free(b->prepared);
    ocean_surface_free(b->surface);
    b->prepared = NULL;
    b->surface = NULL;
    b->sea = NULL;
    b->params = *base;
    s->build_base = *base;
}

void *builder_main(void *arg)
{
    struct sim *s = arg;
    pthread_mutex_lock(&s->lock);
    while (!atomic_load(&s->stop)) {
        if (s->to_free) {
            struct ocean_prepared *old = s->to_free;
            s->to_free = NULL;
            pthread_mutex_unlock(&s->lock);
            ocean_prepared_free(old);
            pthread_mutex_lock(&s->lock);
            continue;
        }
        if (s->save_wanted && (!s->pending || s->ready_full)) {
            s->save_wanted = false;
            pthread_mutex_unlock(&s->lock);
            persist_now(s);
            pthread_mutex_lock(&s->lock);
            continue;
        }
        if (!s->pending || s->ready_full) {
            pthread_cond_wait(&s->cond, &s->lock);
            continue;
        }
        struct sim_set *sets = s->pending;
        s->pending = NULL;
        s->pending_tail = &s->pending;
        s->builder_busy = true;
        s->save_wanted = false; /* the batch's save below carries the clock too */
        pthread_mutex_unlock(&s->lock);

        struct built b;
        struct ocean_params base = s->build_base;
        build_batch(s, sets, &b);
        persist_batch(s, &b, &base);

        pthread_mutex_lock(&s->lock);
        s->builder_busy = false;
        s->ready = b;
        s->ready_full = true;
    }
    pthread_mutex_unlock(&s->lock);
    return NULL;
}

/* A take-over (sim_adopt): the other sim's version, and its clock carried
 * on by the wall-clock time since it was written, so the sea goes on where
 * it was; seq never goes back (edges keep their streams). */
static void adopt_clock(struct sim *s, const struct sim_set *set)
{
    s->version = set->adopt_version;
    double since = ((double)unix_us() - (double)set->adopt_wall_us) * 1e-6;
    if (since < 0)
        since = 0;
    double t = set->adopt_time + (s->params.paused ? 0 : s->params.time_scale * since);
    s->sim_time = ocean_time_clamp(t); /* as the holder's own clock would have: stopped at the limit */
    uint64_t seq = set->adopt_seq + (uint64_t)(since * s->cfg.tick_rate);
    if (seq > s->seq)
        s->seq = seq;
    atomic_store(&s->now_time, s->sim_time);
    atomic_store(&s->now_seq, s->seq);
    s->reset_streams = true;
}

/* At a tick boundary: swap in what the builder prepared, one version per
 * applied set, and hand every set back to the network thread answered. */
void apply_prepared(struct sim *s)
{
    pthread_mutex_lock(&s->lock);
    bool have = s->ready_full;
    struct built b = s->ready;
    pthread_mutex_unlock(&s->lock);
    if (!have)
        return;
    int commit_rc = 0;
    if (b.prepared) {
        /* O(1), and the producer is idle (our caller checked): no step or
         * field reader overlaps it, nor a prepare (ready_full is still set). */
        int n_before = ocean_resolution(s->ocean);
        /* An amplitude-only change eases in over ease_ticks ticks of the clock
         * (docs/simulation.md "Easing"), in sim time: from the previous tick
         * on, so this tick's frame is 1/K of the way. Paused: at once. */
        double dt = b.params.paused ? 0 : b.params.time_scale / s->cfg.tick_rate;
        if (s->sim_time + (s->cfg.ease_ticks - 1) * dt > OCEAN_TIME_MAX)
            dt = 0; /* a ramp the clock would stop in (at its limit) would never end: at once, as paused */
        commit_rc = ocean_commit_eased(s->ocean, b.prepared, s->sim_time - dt, s->cfg.ease_ticks * dt);
        if (commit_rc == 0 && b.surface && ocean_surface_ease(b.surface, s->ocean) != 0)
            LOGW("point queries: the snapshot of version %u misses the easing", (unsigned)(s->version + 1));
        if (commit_rc != 0) {
            /* The builder saved this batch's versions already: they stay unused and
             * the saved version runs ahead of the tick's (skipped, never reused). */
            LOGE("a prepared parameter change no longer fits the simulation; refused");
            for (struct sim_set *set = b.sets; set; set = set->next)
                if (set->status == SIM_SET_QUEUED)
                    set_failed(set, SIM_SET_INVALID, "internal: prepared against another state");
            b.params = s->params;
            ocean_surface_free(b.surface); /* a snapshot of what was not committed */
            b.surface = NULL;
        } else {
            /* A sea with other phases (seed, patch size, depth, loop period) or a new N:
             * the previous frames do not predict it, so every temporal layer starts new
             * chains (keyframes) with the next job. Any other change (wind, amplitude,
             * choppiness, spectrum shape, ...) keeps the phases: the chains go on and each
             * tile of the next frame is predicted or intra on its chain's grid, whichever
             * is smaller (docs/codec.md, "Changes of the sea"). Either way every frame
             * decodes; the split only decides bytes. */
            if (params_diff(&s->params, ocean_get_params(s->ocean)) & params_mask(PARAM_PHASE))
                s->reset_streams = true;
            else
                s->sea_changed = true;
            if (n_before != ocean_resolution(s->ocean)) {
                atomic_fetch_add(&g_metrics.replans, 1);
                LOGI("resolution now %d", ocean_resolution(s->ocean));
            }
        }
    }
    pthread_mutex_lock(&s->lock);
    s->ready_full = false;
    pthread_cond_signal(&s->cond);
    bool slot_free = b.prepared && s->to_free == NULL;
    if (slot_free)
        s->to_free = b.prepared; /* the old state: freeing 10-100 MB is the builder's job, not the tick's */
    pthread_mutex_unlock(&s->lock);
    if (b.prepared && !slot_free)
        ocean_prepared_free(b.prepared);
    struct sim_set *last = NULL;
    uint32_t version_before = s->version;
    for (struct sim_set *set = b.sets; set; set = set->next) {
        if (set->status == SIM_SET_QUEUED) {
            struct ocean_params before = s->params;
            s->params = params_with(&set->prev, &set->values, set->mask);
            if (set->adopt)
                adopt_clock(s, set);
            else
                s->version++;
            atomic_fetch_add(&g_metrics.param_changes, 1);
            set->status = SIM_SET_APPLIED;
            set->changed = params_diff(&before, &s->params);
        }
        set->params = s->params;
        set->version = s->version;
        last = set;
    }
    s->params = b.params;
    if (s->version != version_before || b.surface) /* point queries: this version from now on */
        query_version(s->cfg.queries, s->version, s->sim_time, b.surface != NULL || (b.prepared && commit_rc == 0),
                      b.surface);
    if (last) {
        pthread_mutex_lock(&s->lock);
        *s->answers_tail = b.sets;
        s->answers_tail = &last->next;
        pthread_mutex_unlock(&s->lock);
    }
}


/* role_lease.c — the active sim's lease and record in JetStream, and the
 * standby that follows it and takes over (role_lease.h). */
#include "role_lease.h"

#include <cjson/cJSON.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "clock.h"
#include "control.h"
#include "log.h"

#define LEASE_POLL_S 0.1       /* the standby reads the record this often */
#define LEASE_KV_TIMEOUT_MS 1000

struct role_lease {
    struct cl_link *link;
    double tick_rate;
    struct sim *sim;               /* start writes; the lease thread reads */
    pthread_t thread;
    bool started;
    pthread_mutex_t lock;          /* stop, cond, kv, params, version */
    pthread_cond_t cond;
    bool stop;
    struct cl_kv *kv;              /* the lease thread opens it; persist reads it */
    struct ocean_params params;    /* the state this sim holds (persisted, or adopted) */
    uint32_t version;
    struct sea_spectrum *sea;      /* its measured sea (malloc'd), or NULL (role_lease_sea.c) */
    pthread_mutex_t wlock;         /* one record write at a time: a renewal never writes an older state
                                      over the builder's newer one */
    _Atomic int state;             /* enum lease_state: the lease thread and persist write, any thread reads */
    _Atomic double written_t;      /* mono time of our last successful claim or write (the lease's start) */
    /* lease thread only */
    uint64_t seen_rev;             /* the record's revision last read... */
    double seen_t;                 /* ...and when it was first seen (mono) */
    double renew_t;
    double warn_t;
    struct lease_bodies *bodies;   /* the record's floating bodies (role_lease_bodies.c) */
};

struct lease_bodies *role_lease_bodies(struct role_lease *ls) { return ls->bodies; }

struct record {
    char holder[CL_NAME_MAX];
    bool released;
    struct ocean_params params;
    uint32_t version;
    double sim_time;
    uint64_t wall_us, seq;
    struct sea_spectrum *sea;      /* malloc'd (record_free), or NULL */
};

static void record_free(struct record *r)
{
    free(r->sea);
    r->sea = NULL;
}

const char *role_lease_state_name(enum lease_state s)
{
    static const char *const names[] = { "starting", "solo", "standby", "active" };
    return (unsigned)s < 4 ? names[s] : "?";
}

enum lease_state role_lease_state(struct role_lease *ls) { return (enum lease_state)atomic_load(&ls->state); }

bool role_lease_acting(struct role_lease *ls)
{
    enum lease_state s = role_lease_state(ls);
    /* Active only while the lease is surely ours: a holder stalled (SIGSTOP,
     * starved) past LEASE_SAFE_S stops answering and publishing at once when
     * it runs again, before its next write finds out whether it lost it. */
    return s == LEASE_SOLO || (s == LEASE_ACTIVE && mono_now() - atomic_load(&ls->written_t) < LEASE_SAFE_S);
}

/* {"holder":..,"name":..,"released":..,"params":{..},"params_version":V,
 *  "sim_time":t,"wall_us":U,"seq":S,"tick_rate":R}: the clock at wall_us. */
static char *record_text(struct role_lease *ls, const struct ocean_params *p, uint32_t version, double sim_time,
                         uint64_t seq, bool released, const struct sea_spectrum *sea)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "holder", cl_link_instance(ls->link));
    cJSON_AddStringToObject(o, "name", cl_link_name(ls->link));
    cJSON_AddBoolToObject(o, "released", released);
    cJSON_AddItemToObject(o, "params", control_params_object(p));
    cJSON_AddNumberToObject(o, "params_version", version);
    cJSON_AddNumberToObject(o, "sim_time", sim_time);
    cJSON_AddNumberToObject(o, "wall_us", (double)unix_us());
    cJSON_AddNumberToObject(o, "seq", (double)seq);
    cJSON_AddNumberToObject(o, "tick_rate", ls->tick_rate);
    lease_bodies_add(ls->bodies, o);
    if (lease_record_add_sea(o, sea) != 0) { /* role_lease_sea.c */
        cJSON_Delete(o);
        return NULL;
    }
    char *t = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return t;
}

/* Checked as a state file is, by the same rules (control.h): parameters as a
 * set's, the version and the clock in what the running sim can reach (a
 * holder's clock at its limit is a valid record), seq and wall_us whole
 * numbers JSON holds exactly. */
static int record_parse(const char *text, size_t len, const struct ocean_params *base, struct record *out)
{
    struct ctl_error pe; /* strict, as the state file: a NUL would cut a string */
    if (control_json_prescan(text, len, &pe) != 0)
        return -1;
    cJSON *root = cJSON_ParseWithLength(text, len);
    const cJSON *h = cJSON_GetObjectItemCaseSensitive(root, "holder");
    const cJSON *p = cJSON_GetObjectItemCaseSensitive(root, "params");
    struct ctl_error e;
    struct record r = { 0 };
    int rc = -1;
    if (cJSON_IsString(h) && cJSON_IsObject(p) &&
        control_json_version(cJSON_GetObjectItemCaseSensitive(root, "params_version"), &r.version) &&
        control_json_sim_time(cJSON_GetObjectItemCaseSensitive(root, "sim_time"), &r.sim_time) &&
        control_json_whole(cJSON_GetObjectItemCaseSensitive(root, "wall_us"), CTL_JSON_EXACT_MAX, &r.wall_us) &&
        control_json_whole(cJSON_GetObjectItemCaseSensitive(root, "seq"), CTL_JSON_EXACT_MAX, &r.seq) &&
        control_apply_params(p, base, NULL, &r.params, NULL, &e) == 0 && lease_record_sea(root, &r.sea) == 0) {
        snprintf(r.holder, sizeof r.holder, "%s", h->valuestring);
        r.released = cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(root, "released"));
        *out = r;
        rc = 0;
    }
    cJSON_Delete(root);
    return rc;
}

static void set_state(struct role_lease *ls, enum lease_state s)
{
    atomic_store(&ls->state, s);
    cl_sim_set_standby(ls->link, s == LEASE_STANDBY || s == LEASE_STARTING);
}

/* wlock held: the record with our state and the clock now. */
static int write_record(struct role_lease *ls, bool released)
{
    pthread_mutex_lock(&ls->lock);
    struct ocean_params p = ls->params;
    uint32_t v = ls->version;
    struct cl_kv *kv = ls->kv;
    char *text = record_text(ls, &p, v, sim_time_now(ls->sim), sim_seq(ls->sim), released, ls->sea);
    pthread_mutex_unlock(&ls->lock);
    int rc = text ? cl_kv_write(kv, text, strlen(text)) : CL_E_NOMEM;
    free(text);
    return rc;
}

static void step_down(struct role_lease *ls, const char *why)
{
    LOGW("cluster: %s: this simulation is a standby now (it answers and publishes nothing)", why);
    set_state(ls, LEASE_STANDBY);
    ls->seen_rev = 0;
}

int role_lease_persist(struct role_lease *ls, const struct ocean_params *p, uint32_t version, double sim_time,
                       const struct sea_spectrum *sea, char *err, size_t errlen)
{
    pthread_mutex_lock(&ls->wlock);
    int rc = CL_OK;
    if (role_lease_state(ls) == LEASE_ACTIVE) {
        pthread_mutex_lock(&ls->lock);
        struct cl_kv *kv = ls->kv;
        pthread_mutex_unlock(&ls->lock);
        char *text = record_text(ls, p, version, sim_time, sim_seq(ls->sim), false, sea);
        double t0 = mono_now();
        rc = text ? cl_kv_write(kv, text, strlen(text)) : CL_E_NOMEM;
        free(text);
        if (rc == CL_OK)
            atomic_store(&ls->written_t, t0);
        else if (rc == CL_E_LOST)
            step_down(ls, "another simulation took the lease");
    }
    if (rc == CL_OK) {
        pthread_mutex_lock(&ls->lock);
        ls->params = *p;
        ls->version = version;
        if (lease_keep_sea(&ls->sea, sea) != 0)
            LOGW("cluster: out of memory keeping the measured sea for the record's renewals");
        pthread_mutex_unlock(&ls->lock);
    } else {
        snprintf(err, errlen, "JetStream: %s", cl_strerror(rc));
    }
    pthread_mutex_unlock(&ls->wlock);
    return rc == CL_OK ? 0 : -1;
}

/* The record's state into our simulation (its clock carried on to now by
 * the tick), and as ours. */
static void adopt(struct role_lease *ls, const struct record *rec)
{
    pthread_mutex_lock(&ls->lock);
    bool new_sea = lease_sea_differs(ls->sea, rec->sea); /* only a new sea is built again */
    pthread_mutex_unlock(&ls->lock);
    if (sim_adopt(ls->sim, &rec->params, rec->version, rec->sim_time, rec->wall_us, rec->seq,
                  new_sea ? rec->sea : NULL) != 0) {
        LOGW("cluster: out of memory adopting the simulation's state");
        return;
    }
    pthread_mutex_lock(&ls->lock);
    ls->params = rec->params;
    ls->version = rec->version;
    if (lease_keep_sea(&ls->sea, rec->sea) != 0)
        LOGW("cluster: out of memory keeping the measured sea for the record");
    pthread_mutex_unlock(&ls->lock);
}

/* Take the lease: the record's state if it is at least as new as ours (an
 * older record means ours is newer, e.g. the bucket was made afresh). */
static void take_over(struct role_lease *ls, const struct record *rec, uint64_t rev, const char *rtext, size_t rlen)
{
    pthread_mutex_lock(&ls->wlock);
    pthread_mutex_lock(&ls->lock);
    bool theirs = rec && rec->version >= ls->version;
    /* The bodies as the holder left them (before our record is written, which carries them on):
     * its record's, or, when that is older than our state, those of the newest one we followed. */
    if (theirs && rtext)
        lease_bodies_from_record(ls->bodies, rtext, rlen);
    bool bodies = rec && lease_bodies_have(ls->bodies);
    struct ocean_params p = theirs ? rec->params : ls->params;
    uint32_t v = theirs ? rec->version : ls->version;
    struct sea_spectrum *sea = NULL; /* the sea that goes with p: a copy, the lock is let go */
    const struct sea_spectrum *from = theirs ? rec->sea : ls->sea;
    if (from && (sea = malloc(sizeof *sea)))
        *sea = *from;
    pthread_mutex_unlock(&ls->lock);
    double t = sim_time_now(ls->sim);
    uint64_t seq = sim_seq(ls->sim);
    struct record now = { .params = p, .version = v, .sim_time = t, .wall_us = unix_us(), .seq = seq, .sea = sea };
    if (theirs) { /* its clock, carried on to now */
        double since = ((double)now.wall_us - (double)rec->wall_us) * 1e-6;
        since = since > 0 ? since : 0;
        now.sim_time = ocean_time_clamp(rec->sim_time + (p.paused ? 0 : p.time_scale * since));
        uint64_t their_seq = rec->seq + (uint64_t)(since * ls->tick_rate);
        now.seq = their_seq > seq ? their_seq : seq;
    }
    char *text = from && !sea ? NULL : record_text(ls, &p, v, now.sim_time, now.seq, false, sea);
    double t0 = mono_now();
    int rc = text ? cl_kv_claim(ls->kv, rev, text, strlen(text)) : CL_E_NOMEM;
    free(text);
    if (rc == CL_OK) {
        atomic_store(&ls->written_t, t0);
        if (rec)
            adopt(ls, &now);
        if (bodies) /* before we act: the lws thread puts them in the world before any request */
            lease_bodies_commit(ls->bodies);
        set_state(ls, LEASE_ACTIVE);
        ls->renew_t = mono_now();
        LOGI("cluster: this simulation holds the lease now (params_version %u%s%s)", (unsigned)v,
             rec ? ", taken over from " : "", rec ? rec->holder : "");
    } else if (rc != CL_E_LOST) {
        LOGD("cluster: taking the lease failed: %s", cl_strerror(rc));
    }
    record_free(&now);
    pthread_mutex_unlock(&ls->wlock);
}

static void standby_round(struct role_lease *ls, double now)
{
    char *text = NULL;
    size_t len = 0;
    uint64_t rev = 0;
    int rc = cl_kv_read(ls->kv, &text, &len, &rev);
    if (rc == 0) {
        take_over(ls, NULL, 0, NULL, 0); /* nobody ever held it */
    } else if (rc == 1) {
        struct record rec;
        pthread_mutex_lock(&ls->lock);
        struct ocean_params base = ls->params;
        uint32_t mine = ls->version;
        pthread_mutex_unlock(&ls->lock);
        bool ok = record_parse(text, len, &base, &rec) == 0;
        if (rev != ls->seen_rev) {
            ls->seen_rev = rev;
            ls->seen_t = now;
            /* Hot: follow the holder's sea, so a take-over builds nothing. A
             * version names one sea (durable before use, never reused), so
             * the renewals (same version, new clock) cost nothing here. Only
             * a newer one: a record older than our state (written by a stale
             * copy, a restored bucket) never takes the version back. */
            bool holders = ok && strcmp(rec.holder, cl_link_instance(ls->link)) != 0;
            if (holders && rec.version > mine)
                adopt(ls, &rec);
            if (holders && rec.version >= mine) /* its bodies, for a take-over (role_lease_bodies.c) */
                lease_bodies_from_record(ls->bodies, text, len);
        }
        if (!ok) {
            if (now - ls->warn_t > 10) {
                ls->warn_t = now;
                LOGW("cluster: the simulation's record in JetStream is not valid; taking it over when it expires");
            }
        }
        if ((ok && rec.released) || now - ls->seen_t >= LEASE_EXPIRE_S)
            take_over(ls, ok ? &rec : NULL, rev, text, len);
        if (ok)
            record_free(&rec);
    }
    free(text);
}

static void *lease_main(void *arg)
{
    struct role_lease *ls = arg;
    pthread_mutex_lock(&ls->lock);
    while (!ls->stop) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        ts.tv_nsec += (long)(LEASE_POLL_S * 1e9);
        if (ts.tv_nsec >= 1000000000L) {
            ts.tv_sec++;
            ts.tv_nsec -= 1000000000L;
        }
        pthread_cond_timedwait(&ls->cond, &ls->lock, &ts);
        if (ls->stop)
            break;
        bool have_kv = ls->kv != NULL;
        pthread_mutex_unlock(&ls->lock);
        double now = mono_now();
        enum lease_state st = role_lease_state(ls);
        if (!have_kv && st == LEASE_STARTING && cl_link_connected(ls->link)) {
            struct cl_kv *kv = NULL;
            char err[300];
            int rc = cl_kv_open(ls->link, LEASE_KV_TIMEOUT_MS, &kv, err, sizeof err);
            if (rc == CL_OK) {
                pthread_mutex_lock(&ls->lock);
                ls->kv = kv;
                pthread_mutex_unlock(&ls->lock);
                set_state(ls, LEASE_STANDBY);
                LOGI("cluster: the simulation's record is in JetStream; waiting for the lease");
            } else if (rc == CL_E_NO_JETSTREAM) {
                set_state(ls, LEASE_SOLO);
                LOGW("cluster: no JetStream on the NATS server: no standby, the state is in the state file only");
            } else if (now - ls->warn_t > 10) {
                ls->warn_t = now;
                LOGW("cluster: JetStream: %s (trying again)", err);
            }
        } else if (st == LEASE_ACTIVE && now - ls->renew_t >= LEASE_RENEW_S) {
            /* Silent while the lease may have run out (role_lease_acting); the
             * renewal below tells whether it is still ours. */
            cl_sim_set_standby(ls->link, now - atomic_load(&ls->written_t) >= LEASE_SAFE_S);
            pthread_mutex_lock(&ls->wlock);
            int rc = role_lease_state(ls) == LEASE_ACTIVE ? write_record(ls, false) : CL_OK;
            pthread_mutex_unlock(&ls->wlock);
            if (rc == CL_OK) {
                ls->renew_t = now;
                atomic_store(&ls->written_t, now);
                cl_sim_set_standby(ls->link, false);
            } else if (rc == CL_E_LOST) {
                step_down(ls, "another simulation took the lease");
            }
        } else if (st == LEASE_STANDBY) {
            standby_round(ls, now);
        }
        pthread_mutex_lock(&ls->lock);
    }
    pthread_mutex_unlock(&ls->lock);
    return NULL;
}

struct role_lease *role_lease_new(struct cl_link *link, double tick_rate)
{
    struct role_lease *ls = calloc(1, sizeof *ls);
    if (!ls)
        return NULL;
    ls->link = link;
    ls->tick_rate = tick_rate;
    if (!(ls->bodies = lease_bodies_new())) {
        free(ls);
        return NULL;
    }
    pthread_mutex_init(&ls->lock, NULL);
    pthread_mutex_init(&ls->wlock, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&ls->cond, &ca);
    pthread_condattr_destroy(&ca);
    set_state(ls, LEASE_STARTING);
    return ls;
}

int role_lease_start(struct role_lease *ls, struct sim *sim, const struct ocean_params *p, uint32_t version,
                     const struct sea_spectrum *sea)
{
    ls->sim = sim;
    ls->params = *p;
    ls->version = version;
    if (lease_keep_sea(&ls->sea, sea) != 0)
        return -1;
    int rc = pthread_create(&ls->thread, NULL, lease_main, ls);
    ls->started = rc == 0;
    return rc;
}

void role_lease_stop(struct role_lease *ls)
{
    if (!ls || !ls->started)
        return;
    pthread_mutex_lock(&ls->lock);
    ls->stop = true;
    pthread_cond_signal(&ls->cond);
    pthread_mutex_unlock(&ls->lock);
    pthread_join(ls->thread, NULL);
    ls->started = false;
    /* Released: a standby takes over at its next read instead of after the expiry. */
    pthread_mutex_lock(&ls->wlock);
    if (role_lease_state(ls) == LEASE_ACTIVE && write_record(ls, true) == CL_OK)
        LOGI("cluster: lease released");
    set_state(ls, LEASE_STANDBY);
    pthread_mutex_unlock(&ls->wlock);
}

void role_lease_free(struct role_lease *ls)
{
    if (!ls)
        return;
    role_lease_stop(ls);
    cl_kv_close(ls->kv);
    lease_bodies_free(ls->bodies);
    pthread_cond_destroy(&ls->cond);
    pthread_mutex_destroy(&ls->wlock);
    pthread_mutex_destroy(&ls->lock);
    free(ls->sea);
    free(ls);
}

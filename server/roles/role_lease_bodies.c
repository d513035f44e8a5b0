/* role_lease_bodies.c — the floating bodies in the active sim's JetStream
 * record (role_lease.h, docs/scaling.md "Standby and durability"): the
 * record's "bodies" member, in the state file's form (state_bodies.c, every
 * double exact), so that a standby that takes over puts every body where it
 * was with its owner. The lws thread hands the newest bodies over
 * (role_lease_set_bodies, every BODY_REPLICA_EVERY_S); each record write
 * carries them; a take-over hands the record's to the lws thread
 * (role_lease_take_bodies). One mutex; any thread. */
#include "role_lease.h"

#include <cjson/cJSON.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "log.h"

struct lease_bodies {
    pthread_mutex_t lock;
    struct state_bodies cur;      /* what the next record carries */
    bool have;                    /* cur was set (a record without bodies says nothing of them) */
    bool fits;                    /* the last record had room for them (warned once when not) */
    struct state_bodies taken;    /* a take-over's, for the lws thread */
    bool taken_due;
    void (*wake)(void *);
    void *wake_user;
};

struct lease_bodies *lease_bodies_new(void)
{
    struct lease_bodies *lb = calloc(1, sizeof *lb);
    if (lb) {
        pthread_mutex_init(&lb->lock, NULL);
        lb->fits = true;
    }
    return lb;
}

void lease_bodies_free(struct lease_bodies *lb)
{
    if (!lb)
        return;
    state_bodies_free(&lb->cur);
    state_bodies_free(&lb->taken);
    pthread_mutex_destroy(&lb->lock);
    free(lb);
}

void role_lease_set_bodies(struct role_lease *ls, const struct state_bodies *sb)
{
    struct lease_bodies *lb = role_lease_bodies(ls);
    pthread_mutex_lock(&lb->lock);
    if (state_bodies_copy(&lb->cur, sb) == 0) /* out of memory: the record keeps the last ones */
        lb->have = true;
    pthread_mutex_unlock(&lb->lock);
}

void role_lease_on_bodies(struct role_lease *ls, void (*wake)(void *), void *user)
{
    struct lease_bodies *lb = role_lease_bodies(ls);
    lb->wake = wake;
    lb->wake_user = user;
}

/* The record's "bodies" (o: the record object). They go in only while the
 * whole record stays within LEASE_BODIES_MAX_BYTES (the bucket's value
 * limit, with room for the parameters): a record without them is still a
 * lease; the standby then takes over without bodies. */
void lease_bodies_add(struct lease_bodies *lb, cJSON *o)
{
    pthread_mutex_lock(&lb->lock);
    cJSON *b = lb->have ? state_bodies_json(&lb->cur) : NULL;
    int n = lb->cur.n;
    pthread_mutex_unlock(&lb->lock);
    if (!b)
        return;
    char *text = cJSON_PrintUnformatted(b);
    bool fits = text && strlen(text) <= LEASE_BODIES_MAX_BYTES;
    free(text);
    if (fits)
        cJSON_AddItemToObject(o, "bodies", b);
    else
        cJSON_Delete(b);
    if (fits != lb->fits) {
        lb->fits = fits;
        if (!fits)
            LOGW("cluster: %d floating bodies do not fit the JetStream record (%u bytes): a standby would take "
                 "over without them", n, (unsigned)LEASE_BODIES_MAX_BYTES);
    }
}

/* A record of the holder's (one the standby follows, or the one it takes
 * over from): its bodies are the ones a take-over restores, and the next
 * record we write carries them; committed, they are the lws thread's. 1 = it
 * had bodies, 0 = none (nothing to restore), -1 = bad ones (the last good
 * ones stay). */
int lease_bodies_from_record(struct lease_bodies *lb, const char *text, size_t len)
{
    cJSON *root = cJSON_ParseWithLength(text, len);
    const cJSON *b = cJSON_GetObjectItemCaseSensitive(root, "bodies");
    struct state_bodies sb;
    char err[256];
    int rc = !b ? 0 : state_bodies_parse(b, &sb, err, sizeof err) == 0 ? 1 : -1;
    cJSON_Delete(root);
    if (rc < 0)
        LOGW("cluster: the bodies in the simulation's record are not valid (%s): not taken", err);
    if (rc == 0) {
        pthread_mutex_lock(&lb->lock);
        state_bodies_free(&lb->taken);
        pthread_mutex_unlock(&lb->lock);
    }
    if (rc <= 0)
        return rc;
    pthread_mutex_lock(&lb->lock);
    state_bodies_free(&lb->taken);
    lb->taken = sb;
    if (state_bodies_copy(&lb->cur, &sb) == 0)
        lb->have = true;
    lb->taken_due = false;
    pthread_mutex_unlock(&lb->lock);
    return 1;
}

bool lease_bodies_have(struct lease_bodies *lb)
{
    pthread_mutex_lock(&lb->lock);
    bool any = lb->taken.next_id != 0;
    pthread_mutex_unlock(&lb->lock);
    return any;
}

/* The claim succeeded: the lws thread takes them at its next wake. */
void lease_bodies_commit(struct lease_bodies *lb)
{
    pthread_mutex_lock(&lb->lock);
    bool any = lb->taken.next_id != 0;
    lb->taken_due = any;
    pthread_mutex_unlock(&lb->lock);
    if (any && lb->wake)
        lb->wake(lb->wake_user);
}

int role_lease_take_bodies(struct role_lease *ls, struct state_bodies *out)
{
    struct lease_bodies *lb = role_lease_bodies(ls);
    pthread_mutex_lock(&lb->lock);
    int rc = lb->taken_due;
    if (rc) {
        *out = lb->taken;
        lb->taken = (struct state_bodies){ 0 };
        lb->taken_due = false;
    }
    pthread_mutex_unlock(&lb->lock);
    return rc;
}

/* link_kv.c — the sim's record in a JetStream KV bucket (cluster.h):
 * compare-and-set writes on the last revision seen, so one sim at a time
 * holds it. Blocking calls, for the sim's builder and lease threads. */
#include "link_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define KV_KEY "sim"

struct cl_kv {
    struct cl_link *l;
    pthread_mutex_t lock;   /* one JetStream call at a time; guards rev */
    jsCtx *js;
    kvStore *store;
    uint64_t rev;           /* revision of our last claim or write (0 = we hold nothing) */
};

static int nats_err(natsStatus s)
{
    switch (s) {
    case NATS_NOT_YET_CONNECTED:
    case NATS_CONNECTION_CLOSED:
    case NATS_CONNECTION_DISCONNECTED:
    case NATS_STALE_CONNECTION:
        return CL_E_NOT_CONNECTED;
    case NATS_TIMEOUT:
        return CL_E_TIMEOUT;
    case NATS_NO_RESPONDERS:
        return CL_E_NO_JETSTREAM;
    default:
        return CL_E_NATS;
    }
}

int cl_kv_open(struct cl_link *l, int timeout_ms, struct cl_kv **out, char *err, size_t errlen)
{
    *out = NULL;
    if (!l || !l->nc || l->cfg.role != CL_ROLE_SIM) {
        snprintf(err, errlen, "not a sim's link");
        return CL_E_ARG;
    }
    if (!cl_link_connected(l)) {
        snprintf(err, errlen, "%s", cl_strerror(CL_E_NOT_CONNECTED));
        return CL_E_NOT_CONNECTED;
    }
    struct cl_kv *kv = calloc(1, sizeof *kv);
    if (!kv) {
        snprintf(err, errlen, "out of memory");
        return CL_E_NOMEM;
    }
    kv->l = l;
    pthread_mutex_init(&kv->lock, NULL);
    char bucket[CL_PREFIX_MAX + 8];
    snprintf(bucket, sizeof bucket, "OCEAND_%s", l->prefix);
    for (char *p = bucket; *p; p++)
        if (*p == '.')
            *p = '_';
    jsOptions jo;
    jsOptions_Init(&jo);
    jo.Wait = timeout_ms;
    natsStatus s = natsConnection_JetStream(&kv->js, l->nc, &jo);
    if (s == NATS_OK) {
        kvConfig kc;
        kvConfig_Init(&kc);
        kc.Bucket = bucket;
        kc.History = 1;
        kc.StorageType = js_FileStorage;
        kc.MaxValueSize = CL_KV_VALUE_MAX;
        kc.Description = "oceand: the active simulation's lease and state";
        s = js_CreateKeyValue(&kv->store, kv->js, &kc);
        if (s != NATS_OK) /* it exists with another configuration: use it as it is */
            s = js_KeyValue(&kv->store, kv->js, bucket);
    }
    if (s != NATS_OK) {
        int rc = nats_err(s);
        snprintf(err, errlen, "bucket %s: %s (%s)", bucket, cl_strerror(rc), nats_GetLastError(NULL));
        cl_kv_close(kv);
        return rc;
    }
    *out = kv;
    return CL_OK;
}

void cl_kv_close(struct cl_kv *kv)
{
    if (!kv)
        return;
    if (kv->store)
        kvStore_Destroy(kv->store);
    if (kv->js)
        jsCtx_Destroy(kv->js);
    pthread_mutex_destroy(&kv->lock);
    free(kv);
}

/* lock held */
static int read_locked(struct cl_kv *kv, char **text, size_t *len, uint64_t *rev)
{
    kvEntry *e = NULL;
    natsStatus s = kvStore_Get(&e, kv->store, KV_KEY);
    if (s == NATS_NOT_FOUND)
        return 0;
    if (s != NATS_OK)
        return nats_err(s);
    int n = kvEntry_ValueLen(e);
    *rev = kvEntry_Revision(e);
    if (text) {
        *text = malloc((size_t)(n > 0 ? n : 0) + 1);
        if (!*text) {
            kvEntry_Destroy(e);
            return CL_E_NOMEM;
        }
        if (n > 0)
            memcpy(*text, kvEntry_Value(e), (size_t)n);
        (*text)[n > 0 ? n : 0] = '\0';
        *len = (size_t)(n > 0 ? n : 0);
    }
    kvEntry_Destroy(e);
    return 1;
}

int cl_kv_read(struct cl_kv *kv, char **text, size_t *len, uint64_t *rev)
{
    pthread_mutex_lock(&kv->lock);
    int rc = read_locked(kv, text, len, rev);
    pthread_mutex_unlock(&kv->lock);
    return rc;
}

/* A failed compare-and-set: lost when the record's revision is not the one
 * we expected (the library reports "wrong last sequence" as a plain error),
 * unless the record is exactly what we wrote: the write went through and
 * only its acknowledgement was lost (a timeout), so it is ours at that
 * revision (*rev). */
static int failed_cas(struct cl_kv *kv, natsStatus s, uint64_t expected, const char *text, size_t len,
                      uint64_t *rev)
{
    uint64_t now = 0;
    char *cur = NULL;
    size_t clen = 0;
    int rc = read_locked(kv, &cur, &clen, &now);
    bool mine = rc == 1 && clen == len && memcmp(cur, text, len) == 0;
    free(cur);
    if (mine) {
        *rev = now;
        return CL_OK;
    }
    if (rc == 1 && now != expected)
        return CL_E_LOST;
    if (rc == 0 && expected != 0)
        return CL_E_LOST; /* deleted under us */
    return nats_err(s);
}

int cl_kv_claim(struct cl_kv *kv, uint64_t seen, const char *text, size_t len)
{
    pthread_mutex_lock(&kv->lock);
    uint64_t rev = 0;
    natsStatus s = seen ? kvStore_Update(&rev, kv->store, KV_KEY, text, (int)len, seen)
                        : kvStore_Create(&rev, kv->store, KV_KEY, text, (int)len);
    int rc = s == NATS_OK ? CL_OK : failed_cas(kv, s, seen, text, len, &rev);
    if (rc == CL_OK)
        kv->rev = rev;
    pthread_mutex_unlock(&kv->lock);
    return rc;
}

int cl_kv_write(struct cl_kv *kv, const char *text, size_t len)
{
    pthread_mutex_lock(&kv->lock);
    int rc = CL_OK;
    if (!kv->rev) {
        rc = CL_E_LOST;
    } else {
        uint64_t rev = 0;
        natsStatus s = kvStore_Update(&rev, kv->store, KV_KEY, text, (int)len, kv->rev);
        rc = s == NATS_OK ? CL_OK : failed_cas(kv, s, kv->rev, text, len, &rev);
        if (rc == CL_OK)
            kv->rev = rev;
        else if (rc == CL_E_LOST)
            kv->rev = 0; /* we hold nothing any more */
    }
    pthread_mutex_unlock(&kv->lock);
    return rc;
}

/* cluster.c — the network side of --role sim|edge (net.h, docs/scaling.md):
 * frames, hello and params events that come from a simulation in another
 * process, the cluster status banner, and the sim's hello for edges. The
 * role logic itself (NATS) is in server/roles/role_sim.c and server/roles/role_edge.c;
 * everything here runs on the lws service thread. */
#include "net_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "sim_thread.h"

void net_set_cluster(struct net *n, const struct net_cluster_hooks *h) { n->cluster = *h; }

uint64_t net_latest_seq(const struct net *n) { return n->latest ? n->latest->hdr.seq : 0; }

static void wake_writers(struct net *n)
{
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next) {
        struct session *s = session_of(d);
        if (s->tq.count || fanout_want_write(n, s))
            lws_callback_on_writable(s->wsi);
    }
}

void net_publish_frame(struct net *n, struct frame *f)
{
    frame_ref(f);
    fanout_set_latest(n, f);
    fanout_police(n);
    wake_writers(n);
}

double net_tick_rate(const struct net *n) { return n->dc.tick_rate; }

void net_send_text(struct net *n, uint64_t serial, const char *text)
{
    struct session *s = session_find(n, serial);
    if (s)
        session_queue_text(s, text, false);
}

void net_send_probe_data(struct net *n, uint64_t serial, const char *text)
{
    struct session *s = session_find(n, serial);
    if (s && s->wsi && !s->closing && s->tq.count < NET_PROBE_QUEUE_MAX)
        session_queue_text(s, text, false);
}

static void send_all(struct net *n, const char *text, const char *skip_client)
{
    for (lws_dll2_t *d = lws_dll2_get_head(&n->sessions); d; d = d->next)
        if (!skip_client || strcmp(session_of(d)->client_id, skip_client) != 0)
            session_queue_text(session_of(d), text, false);
}

/* A message from the sim (text[0..len), checked) to every client of ours but skip_client
 * (NULL: none), as a string of its own: -1 when out of memory. */
int net_relay_sim_text(struct net *n, const char *text, size_t len, const char *skip_client)
{
    char *copy = malloc(len + 1);
    if (!copy)
        return -1;
    memcpy(copy, text, len);
    copy[len] = '\0';
    send_all(n, copy, skip_client);
    free(copy);
    return 0;
}

/* The sim's capacity from its hello or a params event (sent with a new N):
 * kept for this edge's hellos. Only an object passes (net_sim_message
 * bounded the message's size). */
static void adopt_capacity(struct net *n, const cJSON *root)
{
    const cJSON *c = cJSON_GetObjectItemCaseSensitive(root, "capacity");
    cJSON *copy = cJSON_IsObject(c) ? cJSON_Duplicate(c, 1) : NULL;
    if (!copy)
        return;
    cJSON_Delete(n->sim_capacity);
    n->sim_capacity = copy;
}

cJSON *net_hello_capacity(struct net *n, cJSON *hello)
{
    cJSON *c;
    if (hello && !n->sim && n->sim_capacity && !cJSON_HasObjectItem(hello, "capacity") &&
        (c = cJSON_Duplicate(n->sim_capacity, 1)))
        cJSON_AddItemToObject(hello, "capacity", c);
    return hello;
}

/* The measured sea's summary of a hello (always there: null for none) or a
 * params (there when it changed), kept for this edge's hellos. Passed on as
 * the sim made it: an object, or null. */
/* The summary's texts are shown to people: printable ASCII, as the sim's check has them. */
static bool printable_member(const cJSON *o, const char *name)
{
    const char *t = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(o, name));
    for (; t && *t; t++)
        if (*t < 0x20 || *t > 0x7e)
            return false;
    return t != NULL;
}

static void adopt_sea(struct net *n, const cJSON *root)
{
    const cJSON *s = cJSON_GetObjectItemCaseSensitive(root, "sea");
    if (!s || !(cJSON_IsNull(s) || cJSON_IsObject(s)))
        return;
    if (cJSON_IsObject(s) && (!printable_member(s, "source") || !printable_member(s, "time"))) {
        LOGW("cluster: a measured sea's summary from the sim with unprintable text: not passed on");
        return;
    }
    char *text = cJSON_IsObject(s) ? cJSON_PrintUnformatted(s) : NULL;
    if (cJSON_IsObject(s) && !text) {
        LOGW("cluster: out of memory keeping the measured sea's summary");
        return;
    }
    free(n->sea_summary);
    n->sea_summary = text;
}

/* The params (and version) of a hello or params message onto n->applied.
 * -1 if the message has neither a valid params object nor a version. */
static int adopt_params(struct net *n, const cJSON *root, uint64_t *changed)
{
    const cJSON *obj = cJSON_GetObjectItemCaseSensitive(root, "params");
    uint32_t version;
    if (!cJSON_IsObject(obj) ||
        !control_json_version(cJSON_GetObjectItemCaseSensitive(root, "params_version"), &version))
        return -1;
    struct ocean_params out;
    struct ctl_error e;
    /* No limits: the sim checked them; the edge only mirrors its values. */
    if (control_apply_params(obj, &n->applied, NULL, &out, changed, &e) != 0) {
        LOGW("cluster: the sim's parameters do not parse here: %s", e.message);
        return -1;
    }
    n->applied = n->view = out;
    n->applied_version = version;
    adopt_sea(n, root);
    return 0;
}

int net_adopt_hello(struct net *n, const char *text, size_t len)
{
    static const char *const types[] = { "hello", NULL };
    cJSON *root = net_sim_message(text, len, NET_SIM_HELLO_MAX, types);
    uint32_t before = n->applied_version;
    uint64_t changed = 0;
    if (!root || adopt_params(n, root, &changed) != 0) {
        cJSON_Delete(root);
        return -1;
    }
    const cJSON *rate = cJSON_GetObjectItemCaseSensitive(root, "tick_rate");
    const cJSON *ts = cJSON_GetObjectItemCaseSensitive(root, "cluster_tile_size");
    const cJSON *ease = cJSON_GetObjectItemCaseSensitive(root, "ease_ticks");
    if (cJSON_IsNumber(rate) && rate->valuedouble >= 1 && rate->valuedouble <= 240)
        n->dc.tick_rate = n->lim.tick_rate = rate->valuedouble;
    if (cJSON_IsNumber(ts) && ts->valueint >= 1 && ts->valueint <= 4096)
        n->dc.tile_size = ts->valueint;
    if (cJSON_IsNumber(ease) && ease->valueint >= 0 && ease->valueint <= 300) /* the sim's, told to this edge's clients */
        n->dc.ease_ticks = ease->valueint;
    adopt_capacity(n, root);
    if (body_net_adopt_hello(n, root) != 0)
        LOGW("cluster: the bodies in the sim's hello do not parse here (the next `bodies` brings them)");
    cJSON_Delete(root);
    if (n->applied_version != before || changed) {
        /* Clients that got hello from an older cache learn the sim's values now. */
        cJSON *m = control_params_msg(&n->applied, n->applied_version, changed, NULL, NULL);
        if (m)
            cJSON_AddNumberToObject(m, "tile_size", net_tile_size(n));
        char *t = control_print(m);
        if (t)
            send_all(n, t, NULL);
        free(t);
    }
    return 0;
}

cJSON *net_sim_message(const char *text, size_t len, size_t cap, const char *const types[])
{
    if (!text || len > cap || !control_valid_utf8(text, len))
        return NULL;
    struct ctl_error e; /* strict, as a client's message: no NUL to cut a string, nothing after the object */
    cJSON *root = control_parse_object(text, len, &e);
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "type");
    for (int i = 0; cJSON_IsString(t) && types[i]; i++)
        if (strcmp(t->valuestring, types[i]) == 0)
            return root;
    cJSON_Delete(root);
    return NULL;
}

int net_broadcast_params(struct net *n, const char *text, size_t len, const char *skip_client)
{
    static const char *const types[] = { "params", NULL };
    cJSON *root = net_sim_message(text, len, NET_SIM_PARAMS_MAX, types);
    /* by_name is shown to people: it must pass the rules a local name does */
    const cJSON *bn = cJSON_GetObjectItemCaseSensitive(root, "by_name");
    struct ctl_error e;
    if (bn && (!cJSON_IsString(bn) || control_check_name(bn->valuestring, &e) != 0)) {
        cJSON_Delete(root);
        return -1;
    }
    uint64_t changed = 0;
    int rc = root ? adopt_params(n, root, &changed) : -1;
    if (rc == 0)
        adopt_capacity(n, root);
    cJSON_Delete(root);
    if (rc != 0)
        return -1;
    return net_relay_sim_text(n, text, len, skip_client);
}

void net_set_status(struct net *n, const char *text, const char *ok_text)
{
    free(n->status_text);
    n->status_text = text ? strdup(text) : NULL;
    if (text || ok_text)
        send_all(n, text ? text : ok_text, NULL);
}

char *net_hello_text(struct net *n)
{
    struct subscription sub;
    subscription_default(&sub, n->dc.tick_rate);
    struct hello_info h = {
        .client_id = "", .controller = false, .params = &n->applied, .params_version = n->applied_version,
        .tick_rate = n->dc.tick_rate, .tile_size = net_tile_size(n), .sub = &sub, .ease_ticks = n->dc.ease_ticks,
        .sea = n->sea_summary,
    };
    struct capacity_info ci;
    if (n->sim) { /* edges pass it on in their hellos */
        sim_capacity(n->sim, &ci);
        h.capacity = &ci;
    }
    cJSON *m = body_net_hello(n, control_hello_msg(&h)); /* the bodies and their limits too */
    if (m) /* the configured tile side, so that edges follow N changes like the sim */
        cJSON_AddNumberToObject(m, "cluster_tile_size", n->dc.tile_size);
    return control_print(m);
}

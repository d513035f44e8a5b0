/* tap_session.c — ocean-tap's session: its stages (hello -> set -> subscribe/query/
 * probe/render -> run), the control messages it sends and answers, and the
 * libwebsockets client around them. */
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <time.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tap.h"

volatile sig_atomic_t interrupted;
struct lws_context *g_ctx;

double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

double wall_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return ts.tv_sec * 1e6 + ts.tv_nsec * 1e-3;
}

void finish(struct session *s, int code)
{
    if (s->stage == ST_DONE) return;
    s->stage = ST_DONE;
    s->exit_code = code;
}

/* Report the first failure only: later ones are its consequences. */
void fail(struct session *s, int code, const char *fmt, ...)
{
    if (s->stage == ST_DONE) return;
    va_list ap;
    va_start(ap, fmt);
    fputs("ocean-tap: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    finish(s, code);
}

/* Queue a JSON message (takes ownership of j) and ask lws for a write slot. */
void send_json(struct session *s, cJSON *j)
{
    char *text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
    if (!text || s->noutq == (int)(sizeof s->outq / sizeof s->outq[0])) {
        free(text);
        fail(s, EXIT_PROTOCOL, "out of memory");
        return;
    }
    s->outq[s->noutq++] = text;
    lws_callback_on_writable(s->wsi);
}

/* ---- requests ----------------------------------------------------------- */

static const char *schema_type(struct session *s, const char *name)
{
    cJSON *p;
    cJSON_ArrayForEach(p, s->schema) {
        cJSON *n = cJSON_GetObjectItemCaseSensitive(p, "name");
        if (cJSON_IsString(n) && !strcmp(n->valuestring, name)) {
            cJSON *t = cJSON_GetObjectItemCaseSensitive(p, "type");
            return cJSON_IsString(t) ? t->valuestring : NULL;
        }
    }
    return NULL;
}

/* The JSON value of a --set: typed by the server's schema. A value that does
 * not fit its type is sent as a string, so the server (the one authority on
 * parameters) answers with its documented error code. */
static cJSON *set_value(struct session *s, const char *name, const char *text)
{
    const char *type = schema_type(s, name);
    char *end;
    if (type && !strcmp(type, "bool")) {
        if (!strcmp(text, "true")) return cJSON_CreateTrue();
        if (!strcmp(text, "false")) return cJSON_CreateFalse();
        return cJSON_CreateString(text);
    }
    if (type && !strcmp(type, "enum")) return cJSON_CreateString(text);
    double v = strtod(text, &end);
    if (*text && !*end) return cJSON_CreateNumber(v);
    return cJSON_CreateString(text);
}

static void send_set(struct session *s)
{
    cJSON *j = cJSON_CreateObject(), *params = cJSON_CreateObject();
    cJSON_AddStringToObject(j, "type", "set");
    cJSON_AddNumberToObject(j, "id", ID_SET);
    for (int i = 0; i < s->o->nsets; i++) {
        const char *eq = strchr(s->o->sets[i], '=');
        char name[128];
        snprintf(name, sizeof name, "%.*s", (int)(eq - s->o->sets[i]), s->o->sets[i]);
        cJSON_DeleteItemFromObjectCaseSensitive(params, name); /* last --set of a name wins */
        cJSON_AddItemToObject(params, name, set_value(s, name, eq + 1));
    }
    cJSON_AddItemToObject(j, "params", params);
    if (s->o->token) cJSON_AddStringToObject(j, "token", s->o->token);
    send_json(s, j);
}

/* cascade_patch_sizes of a hello or params message into s->patch. */
static void read_patch_sizes(struct session *s, cJSON *msg)
{
    cJSON *ps = cJSON_GetObjectItemCaseSensitive(msg, "cascade_patch_sizes"), *v;
    int c = 0;
    cJSON_ArrayForEach(v, ps) {
        if (c < OC_MAX_CASCADES && cJSON_IsNumber(v)) s->patch[c] = v->valuedouble;
        c++;
    }
}

/* Move on from the stage just completed to the next one that applies. */
void advance(struct session *s)
{
    if (s->stage <= ST_SET && s->o->query) { s->stage = ST_QUERY; send_points(s, "query", ID_QUERY); return; }
    if (s->stage <= ST_SET && s->o->probe) {
        s->stage = ST_PROBE;
        send_quiet_subscribe(s); /* the frames of the default subscription are not wanted */
        send_points(s, "probe", ID_PROBE);
        return;
    }
    if (s->stage == ST_PROBE) { s->stage = ST_RUN; s->st.t0 = s->st.last_report = now_s(); return; }
    if (s->stage == ST_HELLO && s->o->nsets) { s->stage = ST_SET; send_set(s); return; }
    if (s->stage <= ST_SET && body_mode(s->o)) { body_start(s); return; }
    if (s->stage <= ST_SET && s->o->bake) {
        s->stage = ST_RENDER;
        send_quiet_subscribe(s); /* live frames are not wanted while the server renders ours */
        send_subscribe(s);
        return;
    }
    if (s->stage == ST_RENDER) { s->stage = ST_RUN; s->st.t0 = s->st.last_report = s->last_frame = now_s(); return; }
    if (s->stage <= ST_SET && s->want_frames) { s->stage = ST_SUBSCRIBE; send_subscribe(s); return; }
    if (s->stage <= ST_SUBSCRIBE && (s->want_frames || s->o->watch)) {
        s->stage = ST_RUN;
        s->st.t0 = s->st.last_report = s->last_frame = now_s();
        if (!s->want_frames) send_quiet_subscribe(s);
        return;
    }
    finish(s, EXIT_OK);
}

/* ---- incoming messages -------------------------------------------------- */

static int id_is(cJSON *msg, int id)
{
    cJSON *j = cJSON_GetObjectItemCaseSensitive(msg, "id");
    return cJSON_IsNumber(j) && j->valuedouble == id;
}

void print_error(cJSON *msg, const char *what)
{
    cJSON *code = cJSON_GetObjectItemCaseSensitive(msg, "code");
    cJSON *text = cJSON_GetObjectItemCaseSensitive(msg, "message");
    cJSON *param = cJSON_GetObjectItemCaseSensitive(msg, "param");
    fprintf(stderr, "ocean-tap: %s: error %s%s%s: %s\n", what,
            cJSON_IsString(code) ? code->valuestring : "?",
            cJSON_IsString(param) ? " param=" : "", cJSON_IsString(param) ? param->valuestring : "",
            cJSON_IsString(text) ? text->valuestring : "");
}

static void on_text(struct session *s, const char *text, size_t len)
{
    cJSON *msg = cJSON_ParseWithLength(text, len);
    cJSON *type = cJSON_GetObjectItemCaseSensitive(msg, "type");
    if (!cJSON_IsString(type)) {
        fail(s, EXIT_PROTOCOL, "server sent a control message without a type: %.*s", (int)(len > 200 ? 200 : len), text);
        cJSON_Delete(msg);
        return;
    }
    const char *t = type->valuestring;
    if (body_mode(s->o) && s->stage != ST_HELLO && body_on_text(s, msg, t)) {
        cJSON_Delete(msg);
        return;
    }
    if (!strcmp(t, "hello") && s->stage == ST_HELLO) {
        cJSON *proto = cJSON_GetObjectItemCaseSensitive(msg, "protocol");
        if (!cJSON_IsNumber(proto) || proto->valueint != OC_PROTO_VERSION) {
            fail(s, EXIT_PROTOCOL, "server speaks protocol %d, ocean-tap speaks %d",
                 cJSON_IsNumber(proto) ? proto->valueint : -1, OC_PROTO_VERSION);
        } else {
            s->schema = cJSON_DetachItemFromObjectCaseSensitive(msg, "schema");
            read_patch_sizes(s, msg);
            cJSON *np = cJSON_GetObjectItemCaseSensitive(cJSON_GetObjectItemCaseSensitive(msg, "params"), "cascades");
            int have = cJSON_IsNumber(np) && np->valueint >= 1 && np->valueint <= OC_MAX_CASCADES ? np->valueint : 1;
            s->ncasc = s->o->cascades < 0 || s->o->cascades > have ? have : s->o->cascades;
            if (s->o->cascades > have)
                fprintf(stderr, "ocean-tap: the server runs %d cascade%s: receiving %d\n", have, have > 1 ? "s" : "", have);
            for (int c = 1; s->grid && c < s->ncasc; c++)
                oc_grid_want(s->grid, c, fine_fields(s->o), fine_lod(s->o));
            if (body_mode(s->o)) body_hello(s, msg);
            else if (!s->o->nsets && !s->want_frames && !s->o->watch && !s->o->query && !s->o->probe) {
                /* Info mode: the hello without the long schema, one line. */
                char *out = cJSON_PrintUnformatted(msg);
                if (out) puts(out);
                free(out);
            }
            advance(s);
        }
    } else if (!strcmp(t, "params")) {
        read_patch_sizes(s, msg);
        if (s->o->watch) {
            char *out = cJSON_PrintUnformatted(msg);
            if (out) { puts(out); fflush(stdout); }
            free(out);
        }
        if (s->stage == ST_SET && id_is(msg, ID_SET)) {
            cJSON *v = cJSON_GetObjectItemCaseSensitive(msg, "params_version");
            cJSON *changed = cJSON_GetObjectItemCaseSensitive(msg, "changed"), *c;
            if (!s->o->watch) {
                printf("params_version=%.0f changed=", cJSON_IsNumber(v) ? v->valuedouble : -1.0);
                int first = 1;
                cJSON_ArrayForEach(c, changed) if (cJSON_IsString(c)) {
                    printf("%s%s", first ? "" : ",", c->valuestring);
                    first = 0;
                }
                putchar('\n');
                fflush(stdout);
            }
            advance(s);
        }
    } else if (!strcmp(t, "subscribed")) {
        if (s->stage == ST_SUBSCRIBE) {
            cJSON *sub = cJSON_GetObjectItemCaseSensitive(msg, "subscription");
            cJSON *lod = cJSON_GetObjectItemCaseSensitive(sub, "lod");
            if (cJSON_IsNumber(lod) && lod->valueint != s->o->lod)
                fail(s, EXIT_PROTOCOL, "server chose lod %d, asked for %d", lod->valueint, s->o->lod);
            else
                advance(s);
        }
    } else if (!strcmp(t, "degraded") && s->want_frames) {
        /* Say why frames stop being written: at a coarser LOD they do not fill our grids. */
        cJSON *active = cJSON_GetObjectItemCaseSensitive(msg, "active"), *lod = cJSON_GetObjectItemCaseSensitive(msg, "lod");
        cJSON *reason = cJSON_GetObjectItemCaseSensitive(msg, "reason");
        s->degraded_lod = cJSON_IsTrue(active) && cJSON_IsNumber(lod) ? lod->valueint : -1;
        if (cJSON_IsTrue(active))
            fprintf(stderr, "ocean-tap: the server serves this subscription degraded (lod %d%s): %s\n",
                    cJSON_IsNumber(lod) ? lod->valueint : -1,
                    cJSON_IsNumber(lod) && lod->valueint != s->o->lod ? ", frames not written until it is back" : "",
                    cJSON_IsString(reason) ? reason->valuestring : "no reason given");
        else
            fprintf(stderr, "ocean-tap: the server serves this subscription in full again\n");
    } else if (!strcmp(t, "query_result") && s->stage == ST_QUERY && id_is(msg, ID_QUERY)) {
        printf("%.*s\n", (int)len, text);
        fflush(stdout);
        finish(s, EXIT_OK);
    } else if (!strcmp(t, "rendering") && s->stage == ST_RENDER && id_is(msg, ID_RENDER)) {
        advance(s);
    } else if (!strcmp(t, "rendered") && s->o->bake && id_is(msg, ID_RENDER)) {
        if (s->frames_done < s->o->frames)
            fail(s, EXIT_PROTOCOL, "the server ended the render after %ld of %ld frames", s->frames_done, s->o->frames);
    } else if (!strcmp(t, "probing") && s->stage == ST_PROBE && id_is(msg, ID_PROBE)) {
        advance(s);
    } else if (!strcmp(t, "probe_data") && s->stage == ST_RUN && s->o->probe) {
        print_probe(s, msg, text, len);
    } else if (!strcmp(t, "error")) {
        if (s->o->bake && id_is(msg, ID_RENDER)) {
            cJSON *code = cJSON_GetObjectItemCaseSensitive(msg, "code");
            print_error(msg, "render rejected");
            if (cJSON_IsString(code) && !strcmp(code->valuestring, "unknown_type"))
                fprintf(stderr, "ocean-tap: this server has no render request (exact-time frames); "
                                "bake from the stream instead: --format exr without --bake\n");
            finish(s, EXIT_REJECTED);
        } else if ((s->stage == ST_QUERY && id_is(msg, ID_QUERY)) || (s->stage == ST_PROBE && id_is(msg, ID_PROBE))) {
            print_error(msg, s->stage == ST_QUERY ? "query rejected" : "probe rejected");
            finish(s, EXIT_REJECTED);
        } else if (s->stage == ST_SET && (id_is(msg, ID_SET) || !cJSON_GetObjectItem(msg, "id"))) {
            print_error(msg, "set rejected");
            finish(s, EXIT_REJECTED);
        } else if (s->stage == ST_SUBSCRIBE && (id_is(msg, ID_SUBSCRIBE) || !cJSON_GetObjectItem(msg, "id"))) {
            print_error(msg, "subscribe rejected");
            finish(s, EXIT_REJECTED);
        } else if (!id_is(msg, ID_QUIET)) { /* a server that refuses the quiet subscription still works */
            print_error(msg, "server");
        }
    }
    /* pong and unknown types: nothing to do (unknown members are ignored by the spec). */
    cJSON_Delete(msg);
}

int callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    struct session *s = lws_context_user(lws_get_context(wsi));
    switch (reason) {
    case LWS_CALLBACK_CLIENT_CONNECTION_ERROR:
        fail(s, EXIT_CONNECT, "cannot connect to %s: %s", s->o->url, in ? (const char *)in : "unknown error");
        s->wsi = NULL;
        break;
    case LWS_CALLBACK_CLIENT_ESTABLISHED:
        s->last_activity = now_s();
        break;
    case LWS_CALLBACK_CLIENT_RECEIVE:
        s->last_activity = now_s();
        if (lws_is_first_fragment(wsi)) s->msg.len = 0;
        if (oc_buf_reserve(&s->msg, len) != 0) { fail(s, EXIT_PROTOCOL, "out of memory"); break; }
        memcpy(s->msg.data + s->msg.len, in, len);
        s->msg.len += len;
        if (!lws_is_final_fragment(wsi)) break;
        if (lws_frame_is_binary(wsi) && body_mode(s->o)) body_on_frame(s, s->msg.data, s->msg.len);
        else if (lws_frame_is_binary(wsi)) on_binary(s, s->msg.data, s->msg.len);
        else on_text(s, (const char *)s->msg.data, s->msg.len);
        break;
    case LWS_CALLBACK_CLIENT_WRITEABLE:
        if (s->noutq) {
            char *text = s->outq[0];
            size_t n = strlen(text);
            unsigned char *buf = malloc(LWS_PRE + n);
            if (!buf) { fail(s, EXIT_PROTOCOL, "out of memory"); break; }
            memcpy(buf + LWS_PRE, text, n);
            int w = lws_write(wsi, buf + LWS_PRE, n, LWS_WRITE_TEXT);
            free(buf);
            free(text);
            memmove(s->outq, s->outq + 1, (size_t)--s->noutq * sizeof s->outq[0]);
            if (w < (int)n) { fail(s, EXIT_CLOSED, "write to server failed"); return -1; }
            if (s->noutq) lws_callback_on_writable(wsi);
        }
        break;
    case LWS_CALLBACK_WS_PEER_INITIATED_CLOSE:
        if (s->stage != ST_DONE) {
            int code = len >= 2 ? ((const unsigned char *)in)[0] << 8 | ((const unsigned char *)in)[1] : 0;
            fail(s, EXIT_CLOSED, "server closed the connection (code %d%s%.*s)", code,
                 len > 2 ? ": " : "", (int)(len > 2 ? len - 2 : 0), (const char *)in + 2);
        }
        break;
    case LWS_CALLBACK_CLIENT_CLOSED:
        if (s->stage != ST_DONE) fail(s, EXIT_CLOSED, "connection closed by the server");
        s->wsi = NULL;
        break;
    default:
        break;
    }
    return 0;
}

void on_signal(int sig)
{
    (void)sig;
    interrupted = 1;
    if (g_ctx) lws_cancel_service(g_ctx);
}

/* Wakes the service loop ten times a second to check timeouts and signals. */
lws_sorted_usec_list_t tick_sul;
void tick(lws_sorted_usec_list_t *sul)
{
    lws_sul_schedule(g_ctx, 0, sul, tick, 100 * LWS_US_PER_MS);
}

int connect_server(struct session *s, struct lws_context *ctx)
{
    char url[sizeof s->o->url], path[sizeof s->o->url + 1];
    const char *scheme, *host, *p;
    int port;
    snprintf(url, sizeof url, "%s", s->o->url);
    if (lws_parse_uri(url, &scheme, &host, &port, &p) || !*host) {
        fprintf(stderr, "ocean-tap: cannot parse URL %s\n", s->o->url);
        return EXIT_USAGE;
    }
    int tls = !strcmp(scheme, "wss") || !strcmp(scheme, "https");
    if (!tls && strcmp(scheme, "ws") && strcmp(scheme, "http")) {
        fprintf(stderr, "ocean-tap: URL must start with ws:// or wss://\n");
        return EXIT_USAGE;
    }
    snprintf(path, sizeof path, "/%s", p);
    struct lws_client_connect_info ci = {
        .context = ctx, .address = host, .port = port, .path = path, .host = host,
        .origin = host, .protocol = OC_SUBPROTOCOL, .ssl_connection = tls ? LCCSCF_USE_SSL : 0,
        .ietf_version_or_minus_one = -1, .pwsi = &s->wsi,
    };
    if (!lws_client_connect_via_info(&ci) && s->stage != ST_DONE) {
        fprintf(stderr, "ocean-tap: cannot connect to %s\n", s->o->url);
        return EXIT_CONNECT;
    }
    return s->stage == ST_DONE ? s->exit_code : -1;
}

/* tap_sea_send.c — `ocean-tap sea SOURCE URL`: the read documents sent to a
 * daemon as `sea` messages (PROTOCOL.md §7.8), one after the other; a
 * forecast of several times plays as a timeline: each document is sent when
 * its time comes, the file's times scaled by --speed (forecast seconds per
 * wall-clock second). The daemon eases each change in, so the sea evolves.
 * Its own small connection (not the frame session of tap_session.c): hello,
 * then one request and its answer at a time. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <libwebsockets.h>

#include "oc_proto.h"
#include "sea.h"
#include "tap.h"

#define EXIT_SEA 8

struct sender {
    const struct sea_doc *docs;
    int n, next;               /* documents; the next to send */
    int waiting;               /* a request is out: its id is next */
    double speed, t0_wall, t0_doc;
    const char *token, *tail;
    char *out;                 /* the message to write, LWS_PRE bytes before it */
    size_t out_len;
    char rx[1 << 16];          /* one reply (params with the summary is ~12 kB) */
    size_t rx_len;
    int done, code;
    struct lws *wsi;
};

static double wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double doc_seconds(const struct sea_doc *d)
{
    struct tm tm = {0};
    if (!strptime(d->time, "%Y-%m-%dT%H:%M:%SZ", &tm)) return 0;
    return (double)timegm(&tm);
}

static void end(struct sender *s, int code)
{
    s->done = 1;
    s->code = code;
}

/* The next document as a `sea` message, queued for WRITEABLE. */
static int queue_next(struct sender *s)
{
    cJSON *doc = sea_doc_json(&s->docs[s->next]);
    cJSON *m = cJSON_CreateObject();
    if (doc && s->tail) cJSON_AddStringToObject(doc, "tail", s->tail);
    cJSON_AddStringToObject(m, "type", "sea");
    cJSON_AddNumberToObject(m, "id", s->next + 1);
    if (s->token) cJSON_AddStringToObject(m, "token", s->token);
    cJSON_AddItemToObject(m, "sea", doc);
    char *text = cJSON_PrintUnformatted(m);
    cJSON_Delete(m);
    if (!text) return -1;
    size_t len = strlen(text);
    free(s->out);
    s->out = malloc(LWS_PRE + len);
    if (s->out) memcpy(s->out + LWS_PRE, text, len);
    free(text);
    if (!s->out) return -1;
    s->out_len = len;
    s->waiting = 1;
    lws_callback_on_writable(s->wsi);
    return 0;
}

static void on_text(struct sender *s, const char *text, size_t len)
{
    cJSON *m = cJSON_ParseWithLength(text, len);
    const char *type = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(m, "type"));
    const cJSON *id = cJSON_GetObjectItemCaseSensitive(m, "id");
    if (type && !strcmp(type, "hello")) {
        s->t0_wall = wall_s();
        s->t0_doc = doc_seconds(&s->docs[0]);
    } else if (type && s->waiting && cJSON_IsNumber(id) && id->valueint == s->next + 1) {
        const struct sea_doc *d = &s->docs[s->next];
        if (!strcmp(type, "error")) {
            fprintf(stderr, "ocean-tap: sea: the daemon refused %s %s: %s: %s\n", d->source, d->time,
                    cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(m, "code")),
                    cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(m, "message")));
            end(s, EXIT_SEA);
        } else {
            const cJSON *sum = cJSON_GetObjectItemCaseSensitive(m, "sea");
            const cJSON *cap = cJSON_GetObjectItemCaseSensitive(sum, "captured");
            const char *note = cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(sum, "fit_note"));
            fprintf(stderr, "sent %s %s: params_version %.0f, the grid holds %.3g of it%s%s\n", d->source, d->time,
                    cJSON_GetNumberValue(cJSON_GetObjectItemCaseSensitive(m, "params_version")),
                    cJSON_IsNumber(cap) ? cap->valuedouble : -1, note ? ": " : "", note ? note : "");
            s->waiting = 0;
            if (++s->next == s->n) end(s, EXIT_OK);
        }
    } else if (type && !strcmp(type, "error") && !cJSON_IsNumber(id)) { /* rate_limited, too_large: no id */
        fprintf(stderr, "ocean-tap: sea: %s: %s\n", cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(m, "code")),
                cJSON_GetStringValue(cJSON_GetObjectItemCaseSensitive(m, "message")));
        end(s, EXIT_SEA);
    }
    cJSON_Delete(m);
}

static int send_cb(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    struct sender *s = lws_context_user(lws_get_context(wsi));
    switch (reason) {
    case LWS_CALLBACK_CLIENT_CONNECTION_ERROR:
        fprintf(stderr, "ocean-tap: sea: cannot connect: %s\n", in ? (const char *)in : "?");
        end(s, EXIT_CONNECT);
        break;
    case LWS_CALLBACK_CLIENT_RECEIVE:
        if (s->rx_len + len > sizeof s->rx) { /* a message we have no use for (never a reply of ours) */
            s->rx_len = sizeof s->rx + 1;
        } else {
            memcpy(s->rx + s->rx_len, in, len);
            s->rx_len += len;
        }
        if (lws_is_final_fragment(wsi)) {
            if (!lws_frame_is_binary(wsi) && s->rx_len <= sizeof s->rx) on_text(s, s->rx, s->rx_len);
            s->rx_len = 0;
        }
        break;
    case LWS_CALLBACK_CLIENT_WRITEABLE:
        if (s->out && s->waiting && s->out_len) {
            if (lws_write(wsi, (unsigned char *)s->out + LWS_PRE, s->out_len, LWS_WRITE_TEXT) < (int)s->out_len) {
                end(s, EXIT_CLOSED);
                return -1;
            }
            s->out_len = 0;
        }
        break;
    case LWS_CALLBACK_CLIENT_CLOSED:
        if (!s->done) {
            fprintf(stderr, "ocean-tap: sea: the server closed the connection\n");
            end(s, EXIT_CLOSED);
        }
        break;
    default:
        break;
    }
    return 0;
}

int tap_sea_send(const char *url, const struct sea_doc *docs, int n, double speed, const char *token,
                 const char *tail, double timeout)
{
    struct sender s = {.docs = docs, .n = n, .speed = speed, .token = token, .tail = tail};
    char u[1024];
    const char *scheme, *host, *p;
    int port;
    snprintf(u, sizeof u, "%s", url);
    if (lws_parse_uri(u, &scheme, &host, &port, &p) || !*host || (strcmp(scheme, "ws") && strcmp(scheme, "wss")))
        return usage_error("sea: %s is not a ws:// or wss:// URL", url);
    char path[1100];
    snprintf(path, sizeof path, "/%s", p);
    lws_set_log_level(LLL_ERR, NULL);
    static const struct lws_protocols protocols[] = {{OC_SUBPROTOCOL, send_cb, 0, 1 << 16, 0, NULL, 0},
                                                     {NULL, NULL, 0, 0, 0, NULL, 0}};
    int tls = !strcmp(scheme, "wss");
    struct lws_context_creation_info info = {
        .port = CONTEXT_PORT_NO_LISTEN, .protocols = protocols, .gid = (gid_t)-1, .uid = (uid_t)-1,
        .options = tls ? LWS_SERVER_OPTION_DO_SSL_GLOBAL_INIT : 0, .user = &s,
    };
    struct lws_context *ctx = lws_create_context(&info);
    if (!ctx) return EXIT_CONNECT;
    /* ?frames=0: a session for control messages only (PROTOCOL.md §1.2) */
    strncat(path, strchr(path, '?') ? "&frames=0" : "?frames=0", sizeof path - strlen(path) - 1);
    struct lws_client_connect_info ci = {
        .context = ctx, .address = host, .port = port, .path = path, .host = host, .origin = host,
        .protocol = OC_SUBPROTOCOL, .ssl_connection = tls ? LCCSCF_USE_SSL : 0, .ietf_version_or_minus_one = -1,
        .pwsi = &s.wsi,
    };
    if (!lws_client_connect_via_info(&ci) && !s.done) {
        lws_context_destroy(ctx);
        fprintf(stderr, "ocean-tap: sea: cannot connect to %s\n", url);
        return EXIT_CONNECT;
    }
    double last = wall_s();
    while (!s.done && !interrupted) {
        lws_service(ctx, 50);
        double now = wall_s();
        if (s.t0_wall > 0 && !s.waiting && s.next < s.n) {
            double due = s.t0_wall + (doc_seconds(&s.docs[s.next]) - s.t0_doc) / s.speed;
            if (now >= due) {
                if (queue_next(&s) != 0) end(&s, EXIT_SEA);
                last = now;
            }
        }
        if ((s.waiting || s.t0_wall == 0) && now - last > timeout) {
            fprintf(stderr, "ocean-tap: sea: timed out after %.1f s waiting for the daemon\n", timeout);
            end(&s, EXIT_TIMEOUT);
        }
    }
    lws_context_destroy(ctx);
    free(s.out);
    return s.done ? s.code : EXIT_INTERRUPTED;
}

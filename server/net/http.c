/* http.c — plain HTTP on the daemon's port: /healthz, /metrics, and a
 * placeholder page at / when the web client is not built. Static files are
 * served by lws itself (an LWSMPRO_FILE mount, context.c). This protocol
 * also refuses WebSocket upgrades that do not ask for oceand.v1. */
#include "net_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "log.h"
#include "metrics.h"

static const char placeholder_html[] =
    "<!doctype html><meta charset=utf-8><title>oceand</title>"
    "<h1>oceand is running</h1><p>The web client is not built (no index.html in the web root). "
    "Run <code>make</code> to bundle it into <code>build/web</code>.</p>"
    "<p>WebSocket: subprotocol <code>oceand.v1</code> on this port. "
    "<a href=/metrics>/metrics</a> · <a href=/healthz>/healthz</a></p>\n";

/* /healthz, built whole with cJSON: a cluster role adds its members (the
 * layers its viewers or edges want: dozens of names), so no fixed buffer
 * may cut it (a monitor that parses it must always get valid JSON). */
static char *render_health(struct net *n, size_t *len)
{
    cJSON *extra = cJSON_CreateObject(), *o = cJSON_CreateObject();
    char *text = NULL, *body = NULL;
    if (!extra || !o)
        goto out;
    const char *status = n->cluster.health ? n->cluster.health(n->cluster.user, extra) : "ok";
    cJSON_AddStringToObject(o, "status", status);
    cJSON_AddNumberToObject(o, "clients", (double)n->sessions.count);
    cJSON_AddNumberToObject(o, "params_version", (double)n->applied_version);
    cJSON_AddNumberToObject(o, "ticks", (double)atomic_load(&g_metrics.ticks));
    while (extra->child) { /* the role's members after the daemon's own, in its order */
        cJSON *item = cJSON_DetachItemViaPointer(extra, extra->child);
        if (!cJSON_AddItemToObject(o, item->string, item)) /* copies the name, frees the old one */
            cJSON_Delete(item);
    }
    if (!(text = cJSON_PrintUnformatted(o)))
        goto out;
    *len = strlen(text) + 1;
    if ((body = malloc(LWS_PRE + *len + 1)))
        snprintf(body + LWS_PRE, *len + 1, "%s\n", text);
out:
    cJSON_free(text);
    cJSON_Delete(extra);
    cJSON_Delete(o);
    return body;
}

/* The body for uri (LWS_PRE bytes of headroom, then *len bytes), with its
 * type; NULL with *len = 0 for 404, NULL with *len = 1 when out of memory. */
static char *render(struct net *n, const char *uri, size_t *len, const char **type)
{
    char *body = NULL;
    *len = 0;
    if (strcmp(uri, "/healthz") == 0) {
        *type = "application/json";
        body = render_health(n, len);
    } else if (strcmp(uri, "/metrics") == 0) {
        *type = "text/plain; version=0.0.4; charset=utf-8";
        size_t cap = 16384;
        if ((body = malloc(LWS_PRE + cap + 4096))) {
            *len = metrics_render(body + LWS_PRE, cap);
            if (n->cluster.metrics) /* cluster counters (--role sim|edge) after the daemon's own */
                *len += n->cluster.metrics(n->cluster.user, body + LWS_PRE + *len, 4096);
        }
    } else if (n->placeholder && (strcmp(uri, "/") == 0 || strcmp(uri, "/index.html") == 0)) {
        *type = "text/html; charset=utf-8";
        if ((body = malloc(LWS_PRE + sizeof placeholder_html)))
            memcpy(body + LWS_PRE, placeholder_html, *len = sizeof placeholder_html - 1);
    } else {
        return NULL;
    }
    if (!body)
        *len = 1;
    return body;
}

/* Does the static file for uri pass through a symlink below the web root?
 * lws' file mount follows symlinks (open(2)); an operator's stray link must
 * not publish files outside the root. The root itself may be a link. */
static bool static_path_has_symlink(const struct net *n, const char *uri)
{
    char path[1200];
    int len = snprintf(path, sizeof path, "%s%s", n->dc.web_root, uri);
    if (len <= 0 || (size_t)len >= sizeof path - 16)
        return true; /* longer than any file we serve: refuse */
    size_t root = strlen(n->dc.web_root);
    struct stat st = { 0 };
    for (size_t i = root + 1; i <= (size_t)len; i++) {
        if (path[i] != '/' && path[i] != 0)
            continue;
        char c = path[i];
        path[i] = 0;
        int r = lstat(path, &st);
        path[i] = c;
        if (r != 0)
            return false; /* missing: lws answers 404 */
        if (S_ISLNK(st.st_mode))
            return true;
    }
    /* A directory is served as its index.html (the mount's default). */
    if (S_ISDIR(st.st_mode) && (size_t)len + 12 < sizeof path) {
        snprintf(path + len, sizeof path - (size_t)len, "%sindex.html", path[len - 1] == '/' ? "" : "/");
        return lstat(path, &st) == 0 && S_ISLNK(st.st_mode);
    }
    return false;
}

/* At accept: keep a reserve of descriptors below RLIMIT_NOFILE. Linux hands
 * out the lowest free fd, so an accepted fd at or above the ceiling means
 * every fd below it is taken: close it at once (counted) rather than let
 * accept(2) reach EMFILE, which lws 4.1 retries in a busy loop. */
static int filter_accept(struct net *n, int fd)
{
    if (fd < n->fd_ceiling) {
        rx_guard_accept(fd);
        return 0;
    }
    atomic_fetch_add(&g_metrics.refused_fd_limit, 1);
    time_t now = time(NULL);
    if (now != n->fd_warned) {
        n->fd_warned = now;
        LOGW("refusing connections: %d of %d file descriptors in use (RLIMIT_NOFILE; see ulimit -n)", fd, n->fd_limit);
    }
    return 1;
}

/* HEAD is GET without the body (RFC 9110 §9.3.2). lws 4.1 serves HEAD of
 * a static file itself; everything else reaches LWS_CALLBACK_HTTP with the
 * path under WSI_TOKEN_HEAD_URI, not GET_URI. */
static bool is_head(struct lws *wsi) { return lws_hdr_total_length(wsi, WSI_TOKEN_HEAD_URI) > 0; }

/* A status with a one-line text body, and for HEAD the same head without
 * it: lws_return_http_status sends its HTML body whatever the method, so
 * on a kept-alive connection the next response would start inside it.
 * Returns nonzero when the write failed. */
static int http_status(struct lws *wsi, unsigned code, const char *text)
{
    unsigned char buf[LWS_PRE + 512], *start = buf + LWS_PRE, *p = start, *end = buf + sizeof buf - 1;
    size_t tl = strlen(text);
    char clen[24];
    int cl = snprintf(clen, sizeof clen, "%zu", tl);
    if (lws_add_http_header_status(wsi, code, &p, end) ||
        lws_add_http_header_by_token(wsi, WSI_TOKEN_HTTP_CONTENT_TYPE, (const unsigned char *)"text/plain; charset=utf-8",
                                     25, &p, end) ||
        lws_add_http_header_by_token(wsi, WSI_TOKEN_HTTP_CONTENT_LENGTH, (const unsigned char *)clen, cl, &p, end) ||
        lws_finalize_http_header(wsi, &p, end))
        return 1;
    if (!is_head(wsi)) {
        if ((size_t)(end - p) < tl)
            return 1;
        memcpy(p, text, tl);
        p += tl;
    }
    int len = lws_ptr_diff(p, start);
    return lws_write(wsi, start, (size_t)len, LWS_WRITE_HTTP) != len;
}

/* Every plain HTTP request, before lws looks at its mounts. */
static int filter_http(struct net *n, struct lws *wsi, const char *uri)
{
    if (!net_host_allowed(n, wsi)) {
        atomic_fetch_add(&g_metrics.http_refused_host, 1);
        http_status(wsi, 421, "unknown Host (see --server-name)\n");
        return 1;
    }
    if (!n->placeholder && uri && strcmp(uri, "/healthz") != 0 && strcmp(uri, "/metrics") != 0 &&
        static_path_has_symlink(n, uri)) {
        atomic_fetch_add(&g_metrics.http_refused_symlink, 1);
        LOGW("refusing %s: a symlink in the web root", uri);
        http_status(wsi, HTTP_STATUS_NOT_FOUND, "not found\n");
        return 1;
    }
    return 0;
}

int cb_http(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    struct net *n = net_of(wsi);
    struct http_session *hs = user;
    switch (reason) {
    case LWS_CALLBACK_FILTER_NETWORK_CONNECTION:
        return filter_accept(n, (int)(intptr_t)in);
    case LWS_CALLBACK_FILTER_HTTP_CONNECTION: {
        char uri[1024];
        snprintf(uri, sizeof uri, "%.*s", (int)len, in ? (const char *)in : "");
        return filter_http(n, wsi, uri);
    }
    case LWS_CALLBACK_HTTP_CONFIRM_UPGRADE:
        return upgrade_confirm(n, wsi, in);
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION:
        LOGD("refusing a WebSocket without subprotocol %s", OC_SUBPROTOCOL);
        return 1;
    case LWS_CALLBACK_HTTP: {
        char uri[256] = "";
        bool head = is_head(wsi);
        lws_hdr_copy(wsi, uri, sizeof uri, head ? WSI_TOKEN_HEAD_URI : WSI_TOKEN_GET_URI);
        const char *type = "text/plain; charset=utf-8";
        size_t blen;
        char *body = render(n, uri, &blen, &type);
        if (!body && blen == 0)
            return http_status(wsi, HTTP_STATUS_NOT_FOUND, "not found\n") ? -1 : lws_http_transaction_completed(wsi);
        if (!body)
            return -1;
        unsigned char hdr[LWS_PRE + 512], *start = hdr + LWS_PRE, *p = start, *end = hdr + sizeof hdr - 1;
        if (lws_add_http_common_headers(wsi, HTTP_STATUS_OK, type, blen, &p, end) ||
            lws_add_http_header_by_token(wsi, WSI_TOKEN_HTTP_CACHE_CONTROL, (const unsigned char *)"no-store", 8, &p, end) ||
            lws_finalize_write_http_header(wsi, start, &p, end)) {
            free(body);
            return 1;
        }
        if (head) { /* the GET's head, Content-Length included, and no body */
            free(body);
            return lws_http_transaction_completed(wsi) ? -1 : 0;
        }
        hs->body = (unsigned char *)body;
        hs->len = blen;
        lws_callback_on_writable(wsi);
        return 0;
    }
    case LWS_CALLBACK_HTTP_WRITEABLE: {
        if (!hs || !hs->body)
            break;
        int w = lws_write(wsi, hs->body + LWS_PRE, hs->len, LWS_WRITE_HTTP_FINAL);
        free(hs->body);
        hs->body = NULL;
        if (w < (int)hs->len)
            return -1;
        if (lws_http_transaction_completed(wsi))
            return -1;
        return 0;
    }
    case LWS_CALLBACK_CLOSED_HTTP:
        rx_guard_forget(lws_get_socket_fd(wsi));
        if (hs) {
            free(hs->body);
            hs->body = NULL;
        }
        break;
    default:
        break;
    }
    return lws_callback_http_dummy(wsi, reason, user, in, len);
}

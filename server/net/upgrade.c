/* upgrade.c — who may talk to the daemon: the Host check on every request
 * (DNS rebinding), the WebSocket handshake rules (GET, version 13), the
 * client count limit and the Origin check (browsers' users are protected
 * from foreign pages; programs send no Origin). Checks on requests go here. */
#include "net_internal.h"

#include <arpa/inet.h>
#include <ctype.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "metrics.h"

#define HTTP_STATUS_UPGRADE_REQUIRED 426 /* not in lws' enum */

/* Was header h sent at all (even empty)? lws' copy of one fragment tells
 * absent (-1) from empty (0); lws_hdr_total_length is 0 for both. */
static bool hdr_present(struct lws *wsi, enum lws_token_indexes h)
{
    char c[1];
    return lws_hdr_total_length(wsi, h) > 0 || lws_hdr_copy_fragment(wsi, c, sizeof c, h, 0) == 0;
}

/* ---- Host (DNS rebinding) ---- */

static bool is_ipv4(const char *s)
{
    struct in_addr a;
    return inet_pton(AF_INET, s, &a) == 1;
}

static bool is_ipv6(const char *s)
{
    struct in6_addr a;
    return inet_pton(AF_INET6, s, &a) == 1;
}

/* Same address, whatever the spelling (::1 vs 0:0::1). */
static bool same_ip(const char *a, const char *b)
{
    unsigned char x[16], y[16];
    if (inet_pton(AF_INET, a, x) == 1 && inet_pton(AF_INET, b, y) == 1)
        return memcmp(x, y, 4) == 0;
    if (inet_pton(AF_INET6, a, x) == 1 && inet_pton(AF_INET6, b, y) == 1)
        return memcmp(x, y, 16) == 0;
    return false;
}

/* The --bind address listens on every interface (or is an interface name,
 * whose addresses we do not track): any IP literal of ours may be asked for. */
static bool bind_is_wildcard(const char *bind)
{
    return !bind[0] || same_ip(bind, "0.0.0.0") || same_ip(bind, "::") || (!is_ipv4(bind) && !is_ipv6(bind));
}

static bool bind_is_loopback(const char *bind)
{
    struct in_addr a;
    if (inet_pton(AF_INET, bind, &a) == 1)
        return (ntohl(a.s_addr) >> 24) == 127;
    return same_ip(bind, "::1");
}

/* "name", "name:port", "[v6]", "[v6]:port" -> the name, lower case, without
 * a trailing dot. false if malformed. */
static bool host_name_of(const char *host, char *name, size_t cap)
{
    const char *end;
    if (host[0] == '[') {
        const char *close = strchr(host, ']');
        if (!close)
            return false;
        host++;
        end = close;
        if (close[1] && close[1] != ':')
            return false;
    } else {
        end = strchr(host, ':');
        if (!end)
            end = host + strlen(host);
        else if (strchr(end + 1, ':'))
            return false; /* a bare IPv6 address is not a Host */
    }
    if (*end == ':' || (end[0] == ']' && end[1] == ':')) {
        const char *p = strchr(end, ':') + 1;
        if (!*p)
            return false;
        for (; *p; p++)
            if (!isdigit((unsigned char)*p))
                return false;
    }
    size_t len = (size_t)(end - host);
    if (len && host[len - 1] == '.')
        len--;
    if (!len || len >= cap)
        return false;
    for (size_t i = 0; i < len; i++)
        name[i] = (char)tolower((unsigned char)host[i]);
    name[len] = 0;
    return true;
}

static bool in_list(const char *list, const char *name)
{
    char copy[512];
    snprintf(copy, sizeof copy, "%s", list);
    char *save = NULL;
    for (char *tok = strtok_r(copy, ", ", &save); tok; tok = strtok_r(NULL, ", ", &save))
        if (strcasecmp(tok, name) == 0)
            return true;
    return false;
}

/* A Host value the daemon answers to: localhost, the --bind address (with
 * 127.0.0.1 and ::1 on a loopback bind; any IP literal on a wildcard bind,
 * since a literal involves no DNS to rebind), or a --server-name. */
bool net_host_name_allowed(const struct daemon_config *dc, const char *host)
{
    if (strcmp(dc->server_name, "*") == 0)
        return true;
    char name[256];
    if (!host_name_of(host, name, sizeof name))
        return false;
    if (strcmp(name, "localhost") == 0 || in_list(dc->server_name, name))
        return true;
    if (!is_ipv4(name) && !is_ipv6(name))
        return strcasecmp(name, dc->bind) == 0;
    if (bind_is_wildcard(dc->bind))
        return true;
    if (same_ip(name, dc->bind))
        return true;
    return bind_is_loopback(dc->bind) && (same_ip(name, "127.0.0.1") || same_ip(name, "::1"));
}

/* The request's Host header: absent is allowed (HTTP/1.0 tools; no browser
 * omits it), present must name us. */
bool net_host_allowed(struct net *n, struct lws *wsi)
{
    char host[256];
    if (!hdr_present(wsi, WSI_TOKEN_HOST))
        return true;
    int len = lws_hdr_total_length(wsi, WSI_TOKEN_HOST);
    if (len <= 0 || len >= (int)sizeof host || lws_hdr_copy(wsi, host, sizeof host, WSI_TOKEN_HOST) != len)
        return false;
    return net_host_name_allowed(&n->dc, host);
}

/* ---- the WebSocket handshake ---- */

/* A short refusal: status, optional Sec-WebSocket-Version (426), a body.
 * The connection stays in HTTP (keep-alive). */
static int refuse(struct lws *wsi, unsigned int status, const char *why)
{
    rx_guard_upgrade_refused(lws_get_socket_fd(wsi));
    unsigned char buf[LWS_PRE + 512], *start = buf + LWS_PRE, *p = start, *end = buf + sizeof buf - 1;
    size_t blen = strlen(why);
    if (lws_add_http_header_status(wsi, status, &p, end) ||
        (status == HTTP_STATUS_UPGRADE_REQUIRED &&
         lws_add_http_header_by_token(wsi, WSI_TOKEN_VERSION, (const unsigned char *)"13", 2, &p, end)) ||
        lws_add_http_header_by_token(wsi, WSI_TOKEN_HTTP_CONTENT_TYPE, (const unsigned char *)"text/plain", 10, &p, end) ||
        lws_add_http_header_content_length(wsi, blen, &p, end) || lws_finalize_http_header(wsi, &p, end) ||
        (size_t)(end - p) < blen)
        return -1;
    memcpy(p, why, blen);
    p += blen;
    if (lws_write(wsi, start, (size_t)(p - start), LWS_WRITE_HTTP_HEADERS) != (int)(p - start))
        return -1;
    return 1; /* lws: "headers sent", completes the transaction */
}

int upgrade_confirm(struct net *n, struct lws *wsi, const char *upgrade)
{
    if (!net_host_allowed(n, wsi)) {
        atomic_fetch_add(&g_metrics.rejected_host, 1);
        LOGW("refusing an upgrade: Host not ours (--server-name)");
        return refuse(wsi, 421, "421 Misdirected Request: unknown Host (see --server-name)\n");
    }
    if (!upgrade || strcasecmp(upgrade, "websocket") != 0) {
        atomic_fetch_add(&g_metrics.rejected_handshake, 1);
        return refuse(wsi, HTTP_STATUS_BAD_REQUEST, "400 Bad Request: only WebSocket upgrades\n");
    }
    if (lws_hdr_total_length(wsi, WSI_TOKEN_GET_URI) <= 0) {
        atomic_fetch_add(&g_metrics.rejected_handshake, 1);
        return refuse(wsi, HTTP_STATUS_METHOD_NOT_ALLOWED, "405 Method Not Allowed: a WebSocket opens with GET\n");
    }
    char version[16];
    if (!hdr_present(wsi, WSI_TOKEN_VERSION)) {
        atomic_fetch_add(&g_metrics.rejected_handshake, 1);
        return refuse(wsi, HTTP_STATUS_BAD_REQUEST, "400 Bad Request: no Sec-WebSocket-Version\n");
    }
    if (lws_hdr_copy(wsi, version, sizeof version, WSI_TOKEN_VERSION) != 2 || strcmp(version, "13") != 0) {
        atomic_fetch_add(&g_metrics.rejected_handshake, 1);
        return refuse(wsi, HTTP_STATUS_UPGRADE_REQUIRED, "426 Upgrade Required: Sec-WebSocket-Version 13 only\n");
    }
    return 0;
}

/* ---- Origin and the client count ---- */

static bool origin_allowed(struct net *n, struct lws *wsi)
{
    char origin[256], host[256];
    if (strcmp(n->dc.allowed_origins, "*") == 0)
        return true;
    if (!hdr_present(wsi, WSI_TOKEN_ORIGIN))
        return true; /* not a browser: the Origin check protects browsers' users */
    /* Present but empty (or over our buffer) is not "no Origin": refused. */
    if (lws_hdr_copy(wsi, origin, sizeof origin, WSI_TOKEN_ORIGIN) <= 0)
        return false;
    if (n->dc.allowed_origins[0] == 0) {
        if (lws_hdr_copy(wsi, host, sizeof host, WSI_TOKEN_HOST) <= 0)
            return false;
        const char *o = strstr(origin, "://");
        return o && strcmp(o + 3, host) == 0;
    }
    char list[sizeof n->dc.allowed_origins];
    snprintf(list, sizeof list, "%s", n->dc.allowed_origins);
    char *save = NULL;
    for (char *tok = strtok_r(list, ", ", &save); tok; tok = strtok_r(NULL, ", ", &save))
        if (strcmp(tok, origin) == 0)
            return true;
    return false;
}

bool upgrade_allowed(struct net *n, struct lws *wsi)
{
    if (n->cluster.no_viewers)
        return false; /* --role sim: viewers connect to edges */
    if ((int)n->sessions.count >= n->dc.max_clients) {
        atomic_fetch_add(&g_metrics.rejected_full, 1);
        LOGW("refusing a client: already %d (--max-clients)", (int)n->sessions.count);
        return false;
    }
    if (!origin_allowed(n, wsi)) {
        atomic_fetch_add(&g_metrics.rejected_origin, 1);
        LOGW("refusing a client: Origin not allowed");
        return false;
    }
    if (!rx_guard_in_sync(lws_get_socket_fd(wsi))) {
        /* The masking check lost the stream (a chunked body before the
         * upgrade): it could not see this client's frames. */
        atomic_fetch_add(&g_metrics.rejected_handshake, 1);
        LOGW("refusing a client: upgrade after a request body the frame check cannot follow");
        return false;
    }
    return true;
}

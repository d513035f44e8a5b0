/* sea_fetch.c — a sea's source text: a file, or an http(s):// GET through
 * libwebsockets' HTTP client (already ocean-tap's library: TLS, redirects and
 * chunked bodies included, so nothing is written by hand here), gunzipped by
 * zlib when the name ends in .gz. */
#include <errno.h>
#include <libwebsockets.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "sea.h"

#define MAX_BYTES ((size_t)64 << 20)

struct buf {
    char *p;
    size_t n, cap;
    int too_big;
};

static int append(struct buf *b, const void *d, size_t n)
{
    if (b->n + n + 1 > MAX_BYTES) { b->too_big = 1; return -1; }
    if (b->n + n + 1 > b->cap) {
        size_t cap = b->cap ? b->cap : 65536;
        while (cap < b->n + n + 1) cap *= 2;
        char *q = realloc(b->p, cap);
        if (!q) return -1;
        b->p = q;
        b->cap = cap;
    }
    memcpy(b->p + b->n, d, n);
    b->n += n;
    b->p[b->n] = 0;
    return 0;
}

static int ends_with(const char *s, const char *tail)
{
    size_t a = strlen(s), b = strlen(tail);
    return a >= b && !strcmp(s + a - b, tail);
}

static int gunzip(const char *name, struct buf *in, struct buf *out, struct sea_err *e)
{
    z_stream z;
    memset(&z, 0, sizeof z);
    if (inflateInit2(&z, 16 + MAX_WBITS) != Z_OK) return sea_fail(e, "io", name, 0, 0, "zlib: cannot start");
    z.next_in = (Bytef *)in->p;
    z.avail_in = (uInt)in->n;
    unsigned char chunk[65536];
    int r;
    do {
        z.next_out = chunk;
        z.avail_out = sizeof chunk;
        r = inflate(&z, Z_NO_FLUSH);
        if (r != Z_OK && r != Z_STREAM_END) break;
        if (append(out, chunk, sizeof chunk - z.avail_out)) { r = Z_MEM_ERROR; break; }
    } while (r != Z_STREAM_END && (z.avail_in || !z.avail_out));
    inflateEnd(&z);
    if (r != Z_STREAM_END)
        return sea_fail(e, "io", name, 0, 0, out->too_big ? "more than 64 MiB gunzipped" : "not a whole gzip stream");
    return 0;
}

/* ---- http(s) ------------------------------------------------------------ */

struct http {
    struct buf body;
    int status, done, failed;
    char err[256];
};

static int http_cb(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in, size_t len)
{
    struct http *h = lws_context_user(lws_get_context(wsi));
    switch (reason) {
    case LWS_CALLBACK_CLIENT_CONNECTION_ERROR:
        snprintf(h->err, sizeof h->err, "%s", in ? (const char *)in : "connection failed");
        h->failed = h->done = 1;
        lws_cancel_service(lws_get_context(wsi));
        return 0;
    case LWS_CALLBACK_ESTABLISHED_CLIENT_HTTP:
        h->status = (int)lws_http_client_http_response(wsi);
        break;
    case LWS_CALLBACK_RECEIVE_CLIENT_HTTP_READ:
        if (append(&h->body, in, len)) {
            snprintf(h->err, sizeof h->err, "%s", h->body.too_big ? "more than 64 MiB" : "out of memory");
            h->failed = 1;
            return -1;
        }
        return 0;
    case LWS_CALLBACK_RECEIVE_CLIENT_HTTP: {
        char chunk[LWS_PRE + 16384], *p = chunk + LWS_PRE;
        int n = (int)sizeof chunk - LWS_PRE;
        if (lws_http_client_read(wsi, &p, &n) < 0) return -1;
        return 0;
    }
    case LWS_CALLBACK_COMPLETED_CLIENT_HTTP:
    case LWS_CALLBACK_CLOSED_CLIENT_HTTP:
        h->done = 1;
        lws_cancel_service(lws_get_context(wsi));
        break;
    default:
        break;
    }
    return lws_callback_http_dummy(wsi, reason, user, in, len);
}

static int http_get(const char *url, struct buf *out, struct sea_err *e)
{
    char u[2048], path[2048];
    const char *scheme, *host, *p;
    int port;
    snprintf(u, sizeof u, "%s", url);
    if (lws_parse_uri(u, &scheme, &host, &port, &p) || !*host)
        return sea_fail(e, "io", url, 0, 0, "cannot parse the URL");
    int tls = !strcmp(scheme, "https");
    snprintf(path, sizeof path, "/%s", p);
    struct http h = {0};
    static const struct lws_protocols protocols[] = {{"http", http_cb, 0, 0, 0, NULL, 0},
                                                     {NULL, NULL, 0, 0, 0, NULL, 0}};
    struct lws_context_creation_info info = {
        .port = CONTEXT_PORT_NO_LISTEN, .protocols = protocols, .gid = (gid_t)-1, .uid = (uid_t)-1,
        .options = tls ? LWS_SERVER_OPTION_DO_SSL_GLOBAL_INIT : 0, .user = &h,
    };
    struct lws_context *ctx = lws_create_context(&info);
    if (!ctx) return sea_fail(e, "io", url, 0, 0, "cannot create the libwebsockets context");
    struct lws *wsi = NULL;
    struct lws_client_connect_info ci = {
        .context = ctx, .address = host, .port = port, .path = path, .host = host, .origin = host,
        .method = "GET", .protocol = protocols[0].name, .ssl_connection = tls ? LCCSCF_USE_SSL : 0, .pwsi = &wsi,
    };
    if (!lws_client_connect_via_info(&ci) && !h.done) {
        lws_context_destroy(ctx);
        return sea_fail(e, "io", url, 0, 0, "cannot connect");
    }
    for (int i = 0; !h.done && i < 300; i++) lws_service(ctx, 100); /* 30 s at most */
    lws_context_destroy(ctx);
    int rc = 0;
    if (!h.done) rc = sea_fail(e, "io", url, 0, 0, "no answer within 30 s");
    else if (h.failed) rc = sea_fail(e, "io", url, 0, 0, "%s", h.err);
    else if (h.status != 200) rc = sea_fail(e, "io", url, 0, 0, "HTTP status %d", h.status);
    if (rc) { free(h.body.p); return rc; }
    *out = h.body;
    if (!out->p && append(out, "", 0)) return sea_fail(e, "io", url, 0, 0, "out of memory");
    return 0;
}

int sea_load(const char *source, char **out, size_t *len, struct sea_err *e)
{
    struct buf raw = {0};
    if (!strncmp(source, "http://", 7) || !strncmp(source, "https://", 8)) {
        lws_set_log_level(LLL_ERR, NULL);
        if (http_get(source, &raw, e)) return -1;
    } else {
        FILE *fp = fopen(source, "rb");
        if (!fp) return sea_fail(e, "io", source, 0, 0, "cannot open: %s", strerror(errno));
        char chunk[65536];
        size_t n;
        while ((n = fread(chunk, 1, sizeof chunk, fp)) > 0)
            if (append(&raw, chunk, n)) {
                fclose(fp);
                free(raw.p);
                return sea_fail(e, "io", source, 0, 0, raw.too_big ? "larger than 64 MiB" : "out of memory");
            }
        int bad = ferror(fp);
        fclose(fp);
        if (bad) { free(raw.p); return sea_fail(e, "io", source, 0, 0, "read error"); }
        if (!raw.p && append(&raw, "", 0)) return sea_fail(e, "io", source, 0, 0, "out of memory");
    }
    if (ends_with(source, ".gz")) {
        struct buf plain = {0};
        int r = gunzip(source, &raw, &plain, e);
        free(raw.p);
        if (r) { free(plain.p); return -1; }
        if (!plain.p && append(&plain, "", 0)) return sea_fail(e, "io", source, 0, 0, "out of memory");
        raw = plain;
    }
    if (memchr(raw.p, 0, raw.n)) { free(raw.p); return sea_fail(e, "bad_header", source, 0, 0, "a NUL byte: not text"); }
    *out = raw.p;
    *len = raw.n;
    return 0;
}

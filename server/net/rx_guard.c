/* rx_guard.c — RFC 6455 §5.1: "The server MUST close the connection upon
 * receiving a frame that is not masked." libwebsockets 4.1 (the version we
 * build against) parses unmasked client frames as if they were masked; the
 * check arrived upstream later (lib/roles/ws/ops-ws.c, "client unmasked").
 * lws offers no option or callback that sees the mask bit, so we watch the
 * bytes it reads: this file defines recv(2) for the process, which lws'
 * plain-socket read (lws_ssl_capable_read_no_ssl) calls, and follows each
 * client connection's stream: HTTP request heads (and Content-Length
 * bodies) until an "Upgrade: websocket" head, then WebSocket frame headers.
 * At the second byte of an unmasked frame the rest of the read is replaced
 * by an empty masked frame (completing the header lws has begun) and a
 * masked Close frame with status 1002 "unmasked frame": lws then closes the
 * connection as for a client close and echoes 1002 back. Nothing of the
 * unmasked frame reaches lws or the session.
 *
 * Hand-written because lws 4.1 has no hook; it reads two header bytes and a
 * length per frame, nothing else. TLS connections are not watched (lws
 * reads them with SSL_read; masking guards proxies' caches, which cannot see
 * into TLS anyway). Remove this file when lws >= the release with the
 * upstream check is the minimum. Only the lws service thread's reads are
 * looked at; every other recv passes straight through.
 *
 * The end of a client's stream, for the same reason (an lws 4.1 defect,
 * fixed upstream in 4.2 by "adopt: rejection should not loop with listen
 * adoption", lib/plat/unix/unix-service.c): when a read returns 0 (the
 * client's FIN) or fails, lws closes the connection, but while it still
 * holds the unsent tail of a partial write it only marks it "flushing
 * before close" and reports it closed; the service loop then services the
 * same pollfd again without polling, reads 0 again, and spins there for
 * ever (the lws thread never returns to main, SIGTERM's flag is never
 * seen). A viewer whose send buffer is full (the ladder's low-water mark,
 * pacing, --send-buffer-kb) that closes or half-closes its side does it.
 * So the first end is handed on, the socket is shut down both ways, and
 * every later read of it says EAGAIN: lws leaves the loop, and its next
 * poll sees the socket writable (and hung up), where the flush fails and
 * lws closes the connection at once. */
#include "net_internal.h"

#include <errno.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/types.h>

#include "log.h"
#include "metrics.h"

enum { G_NONE, G_HEAD, G_BODY, G_WS, G_OFF, G_DEAD };

struct rx_guard {
    uint8_t phase;
    uint8_t hpos, hlen;         /* WS: header bytes seen, header length once known */
    uint8_t line_len;           /* HEAD: bytes kept of the current line (lower case) */
    uint16_t line_n;            /* HEAD: its true length (saturating), CR not counted */
    bool upgrade, chunked;      /* HEAD: seen in this request's head */
    bool colon, ows;            /* HEAD: the line's first ':' kept; skipping the blanks after it */
    char line[40];              /* HEAD: "name:value", the blanks after the colon left out */
    uint64_t clen;              /* HEAD: Content-Length of this request */
    uint64_t left;              /* BODY: bytes of body left; WS: payload bytes left */
    uint64_t plen;              /* WS: payload length of the frame whose header is being read */
    bool ended;                 /* lws was handed the stream's end (0 or an error): later reads are EAGAIN */
};

/* Empty masked frame completing the header lws has begun, then a masked
 * Close (zero key) with status 1002 and a reason. */
static const unsigned char inject[] = {
    0x80, 0, 0, 0, 0,
    0x88, 0x80 | 16, 0, 0, 0, 0, 0x03, 0xea, 'u', 'n', 'm', 'a', 's', 'k', 'e', 'd', ' ', 'f', 'r', 'a', 'm', 'e',
};

static void head_reset(struct rx_guard *g)
{
    g->phase = G_HEAD;
    g->line_len = 0;
    g->line_n = 0;
    g->colon = g->ows = false;
    g->upgrade = g->chunked = false;
    g->clen = 0;
}

static void head_line_end(struct rx_guard *g)
{
    g->line[g->line_len] = 0;
    if (g->line_n == 0) { /* the empty line: end of the head */
        if (g->upgrade) {
            g->phase = G_WS;
            g->hpos = 0;
            g->left = 0;
        } else if (g->chunked) {
            g->phase = G_OFF; /* not followed further; an upgrade after it is refused (rx_guard_in_sync) */
        } else if (g->clen) {
            uint64_t body = g->clen;
            head_reset(g);
            g->phase = G_BODY;
            g->left = body;
        } else {
            head_reset(g);
        }
        return;
    }
    if (strncmp(g->line, "upgrade:", 8) == 0 && strstr(g->line, "websocket"))
        g->upgrade = true;
    else if (strncmp(g->line, "transfer-encoding:", 18) == 0)
        g->chunked = true;
    else if (strncmp(g->line, "content-length:", 15) == 0)
        g->clen = strtoull(g->line + 15, NULL, 10);
    g->line_len = 0;
    g->line_n = 0;
    g->colon = g->ows = false;
}

/* The bytes lws is about to get: n read into buf (room for cap). Returns
 * how many to hand on (n, or fewer plus the injected close), or -1 to fail
 * the read (no room to inject: lws closes the connection). */
static ssize_t guard_feed(struct rx_guard *g, unsigned char *buf, size_t n, size_t cap)
{
    for (size_t i = 0; i < n; i++) {
        unsigned char c = buf[i];
        switch (g->phase) {
        case G_HEAD:
            if (c == '\n') {
                head_line_end(g);
            } else if (c != '\r') {
                if (g->line_n < UINT16_MAX)
                    g->line_n++;
                /* Any amount of blanks may precede a value (RFC 9110 §5.6.3,
                 * OWS): kept, 40 of them pushed "websocket" or a length out
                 * of the line, and a legal upgrade was refused. */
                if (g->ows && (c == ' ' || c == '\t'))
                    break;
                g->ows = false;
                if (g->line_len < sizeof g->line - 1) {
                    g->line[g->line_len++] = (char)(c >= 'A' && c <= 'Z' ? c + 32 : c);
                    if (c == ':' && !g->colon)
                        g->colon = g->ows = true;
                }
            }
            break;
        case G_BODY: {
            uint64_t take = n - i < g->left ? n - i : g->left;
            g->left -= take;
            i += take - 1;
            if (!g->left)
                head_reset(g);
            break;
        }
        case G_WS:
            if (g->left) { /* payload: skip it whole */
                uint64_t take = n - i < g->left ? n - i : g->left;
                g->left -= take;
                i += take - 1;
                break;
            }
            if (g->hpos == 0) { /* FIN, RSV, opcode: lws checks those */
                g->hpos = 1;
                break;
            }
            if (g->hpos == 1) { /* MASK bit and 7-bit length */
                if (!(c & 0x80)) {
                    atomic_fetch_add(&g_metrics.closed_unmasked, 1);
                    g->phase = G_DEAD;
                    if (cap - i < sizeof inject)
                        return -1;
                    memcpy(buf + i, inject, sizeof inject);
                    return (ssize_t)(i + sizeof inject);
                }
                int l7 = c & 0x7f;
                g->hlen = (uint8_t)(2 + (l7 == 126 ? 2 : l7 == 127 ? 8 : 0) + 4);
                g->plen = l7 < 126 ? (uint64_t)l7 : 0;
                g->hpos = 2;
            } else { /* extended length (big-endian), then the masking key */
                if (g->hpos < g->hlen - 4)
                    g->plen = (g->plen << 8) | c;
                g->hpos++;
            }
            if (g->hpos == g->hlen) {
                g->left = g->plen;
                g->hpos = 0;
            }
            break;
        default: /* G_OFF: not followed; G_DEAD: handled by the caller */
            return (ssize_t)n;
        }
    }
    return (ssize_t)n;
}

/* ---- the table of client connections (lws thread only) ---- */

static struct rx_guard *guards;
static int guards_cap;
static pthread_t guard_thread;
static bool guard_on;

void rx_guard_start(void)
{
    guard_thread = pthread_self();
    guard_on = true;
}

void rx_guard_stop(void)
{
    guard_on = false;
    free(guards);
    guards = NULL;
    guards_cap = 0;
}

static bool mine(void) { return guard_on && pthread_equal(pthread_self(), guard_thread); }

void rx_guard_accept(int fd)
{
    if (!mine() || fd < 0)
        return;
    if (fd >= guards_cap) {
        int cap = guards_cap ? guards_cap : 64;
        while (cap <= fd)
            cap *= 2;
        struct rx_guard *ng = realloc(guards, (size_t)cap * sizeof *ng);
        if (!ng)
            return; /* not followed: its upgrade is refused */
        memset(ng + guards_cap, 0, (size_t)(cap - guards_cap) * sizeof *ng);
        guards = ng;
        guards_cap = cap;
    }
    memset(&guards[fd], 0, sizeof guards[fd]);
    head_reset(&guards[fd]);
}

static struct rx_guard *guard_of(int fd)
{
    return mine() && fd >= 0 && fd < guards_cap && guards[fd].phase != G_NONE ? &guards[fd] : NULL;
}

/* At the upgrade: the guard read the same head lws did (else refuse). */
bool rx_guard_in_sync(int fd)
{
    if (!guard_on)
        return true; /* TLS: not watched */
    struct rx_guard *g = guard_of(fd);
    return g && g->phase == G_WS && g->hpos == 0 && g->left == 0;
}

/* The connection is closing: its fd number may next belong to a socket
 * that is not a client's. */
void rx_guard_forget(int fd)
{
    struct rx_guard *g = guard_of(fd);
    if (g)
        g->phase = G_NONE;
}

/* The upgrade was refused with an HTTP answer and the connection stays in
 * HTTP: what follows is the next request's head, not frames. */
void rx_guard_upgrade_refused(int fd)
{
    struct rx_guard *g = guard_of(fd);
    if (g && g->phase == G_WS)
        head_reset(g);
}

bool rx_guard_tripped(int fd)
{
    struct rx_guard *g = guard_of(fd);
    return g && g->phase == G_DEAD;
}

/* The process' recv(2): lws' reads of client sockets pass through guard_feed. */
ssize_t recv(int fd, void *buf, size_t len, int flags)
{
    struct rx_guard *g = (flags & MSG_PEEK) ? NULL : guard_of(fd);
    if (g && g->ended) { /* lws 4.1 reads an ended stream again without polling, for ever: see the top */
        errno = EAGAIN;
        return -1;
    }
    ssize_t r = recvfrom(fd, buf, len, flags, NULL, NULL);
    if (!g)
        return r;
    if (r == 0 || (r < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
        int e = errno;
        g->ended = true;
        shutdown(fd, SHUT_RDWR); /* its next poll: writable and hung up, so a pending flush fails at once */
        errno = e;
        return r;
    }
    if (r < 0)
        return r;
    if (g->phase == G_DEAD) { /* after the injected close: drop what follows */
        errno = EAGAIN;
        return -1;
    }
    ssize_t out = guard_feed(g, buf, (size_t)r, len);
    if (out < 0)
        errno = ECONNRESET;
    return out;
}

/* load_client — K WebSocket clients against one oceand on loopback.
 *
 * Counts frames per client over a measuring window, tick-to-receipt latency
 * (server_time_us in the frame header vs this host's clock) and, from client
 * 0, the latency of a `set` to the first frame carrying the new
 * params_version, in ticks (frame seq). Prints one JSON object.
 *
 * Why not an lws client: lws parses received payload byte by byte (about
 * 30 ns/byte here), so 200 lws clients measured the client, not the daemon.
 * This one is a plain epoll loop with a minimal RFC 6455 reader (server
 * frames are unmasked) that skips payload with one pass over each recv.
 *
 *   load_client PORT CLIENTS WARMUP_S WINDOW_S [SUBSCRIBE_JSON]
 * SUBSCRIBE_JSON (at most 4096 bytes) is sent by every client after the
 * handshake, e.g. {"type":"subscribe","fields":["height"]}.
 * Environment LOAD_SET_INTERVAL_S: seconds between client 0's wind sets
 * (default 0.3, someone steering; 0 = no sets, the sea left alone).
 * LOAD_HOST: the daemon's IPv4 address (default 127.0.0.1); LOAD_BIND: the
 * clients' source address (default: the kernel's choice). The clients connect
 * in parallel (one thread each for the handshake: over a 300 ms link, one
 * after the other would take 0.6 s apiece).
 * Every client reads the `link` messages (PROTOCOL.md §7.2) for its rung;
 * the JSON has the rungs' spread, and with LOAD_PER_CLIENT=1 also per client
 * arrays: "client_fps", "client_rung" (at the end), "client_rung_max".
 * LOAD_LINK_LOG=FILE: every `link` message received, "seconds client json". */
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <pthread.h>
#include <signal.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "bench_time.h"

struct client {
    int fd, idx;
    bool open;
    /* RFC 6455 reader state */
    uint8_t wh[14];
    int wh_len;
    uint64_t remaining;     /* payload bytes left in the current ws frame */
    int opcode;             /* of the current ws frame */
    bool fin;
    bool in_binary;         /* inside a binary message */
    uint64_t msg_off;
    bool in_text;           /* inside a text message */
    char txt[1024];         /* its first bytes (a `link` message's rung and reason) */
    size_t txt_len;
    int rung, rung_max, rung_changes, downs, ups;
    int port;
    uint8_t hdr[48];
    uint8_t ping[125];
    int ping_len;
    /* stats */
    uint64_t frames, bytes, last_seq;
    uint32_t last_version;
};

static struct client *clients;
static int nclients;
static bool measuring;
static double *lat;
static double *sizes;            /* bytes of each frame received while measuring (as lat) */
static size_t nlat, lat_cap;
static uint64_t seq_max;
static bool set_waiting;
static uint64_t set_seq;
static uint32_t set_version;
static double set_samples[4096];
static int nset, set_value;

static uint64_t unix_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

static uint64_t rd64(const uint8_t *p) { uint64_t v; memcpy(&v, p, 8); return v; }
static uint32_t rd32(const uint8_t *p) { uint32_t v; memcpy(&v, p, 4); return v; }

/* Send one masked client frame (mask key 0: payload goes as is). */
static void send_frame(struct client *c, int opcode, const void *data, size_t len)
{
    uint8_t buf[4096 + 8];
    if (len > 4096)
        return;
    size_t h = 2;
    buf[0] = (uint8_t)(0x80 | opcode);
    if (len <= 125) {
        buf[1] = (uint8_t)(0x80 | len);
    } else { /* 16-bit length */
        buf[1] = 0x80 | 126;
        buf[2] = (uint8_t)(len >> 8);
        buf[3] = (uint8_t)len;
        h = 4;
    }
    memset(buf + h, 0, 4); /* mask key 0 */
    memcpy(buf + h + 4, data, len);
    ssize_t w = send(c->fd, buf, h + 4 + len, MSG_NOSIGNAL);
    (void)w;
}

static void on_frame(struct client *c)
{
    uint64_t seq = rd64(c->hdr + 8), us = rd64(c->hdr + 40);
    uint32_t version = rd32(c->hdr + 24);
    if (seq > seq_max)
        seq_max = seq;
    if (measuring) {
        c->frames++;
        c->bytes += c->msg_off;
        if (nlat < lat_cap) {
            sizes[nlat] = (double)c->msg_off;
            lat[nlat++] = ((double)unix_us() - (double)us) / 1000.0;
        }
    }
    if (c->idx == 0 && set_waiting && version > set_version) {
        if (nset < 4096)
            set_samples[nset++] = (double)(seq - set_seq);
        set_waiting = false;
    }
    c->last_seq = seq;
    c->last_version = version;
}

/* End of a ws frame's payload. */
static FILE *link_log; /* LOAD_LINK_LOG=FILE: every `link` message, "seconds client json" a line */
static double t_origin;

static void text_done(struct client *c)
{
    c->txt[c->txt_len < sizeof c->txt ? c->txt_len : sizeof c->txt - 1] = 0;
    const char *r;
    if (strstr(c->txt, "\"type\":\"link\"") && (r = strstr(c->txt, "\"rung\":"))) {
        c->rung = atoi(r + 7);
        if (c->rung > c->rung_max)
            c->rung_max = c->rung;
        c->rung_changes++;
        if (link_log)
            fprintf(link_log, "%.3f %d %s\n", now_s() - t_origin, c->idx, c->txt);
        if (strstr(c->txt, "\"reason\":\"congestion"))
            c->downs++;
        else if (strstr(c->txt, "\"reason\":\"probe"))
            c->ups++;
    }
}

static void frame_done(struct client *c)
{
    if (c->opcode == 9)
        send_frame(c, 10, c->ping, (size_t)c->ping_len); /* pong */
    if (c->opcode == 8)
        c->open = false;
    if ((c->opcode == 2 || c->opcode == 0) && c->in_binary && c->fin) {
        if (c->msg_off >= 48)
            on_frame(c);
        c->in_binary = false;
    }
    if ((c->opcode == 1 || c->opcode == 0) && c->in_text && c->fin) {
        text_done(c);
        c->in_text = false;
    }
}

static void consume(struct client *c, const uint8_t *p, size_t n)
{
    while (n > 0) {
        if (c->remaining == 0 && c->wh_len >= 0) {
            /* accumulate the ws frame header */
            c->wh[c->wh_len++] = *p++;
            n--;
            if (c->wh_len < 2)
                continue;
            int len7 = c->wh[1] & 0x7f;
            int need = 2 + (len7 == 126 ? 2 : len7 == 127 ? 8 : 0);
            if (c->wh_len < need)
                continue;
            uint64_t len = (uint64_t)len7;
            if (len7 == 126)
                len = (uint64_t)c->wh[2] << 8 | c->wh[3];
            else if (len7 == 127)
                for (int i = 0; i < 8; i++)
                    len = len << 8 | c->wh[2 + i];
            c->opcode = c->wh[0] & 0x0f;
            c->fin = (c->wh[0] & 0x80) != 0;
            c->wh_len = 0;
            c->remaining = len;
            c->ping_len = 0;
            if (c->opcode == 2) {
                c->in_binary = true;
                c->msg_off = 0;
            }
            if (c->opcode == 1) {
                c->in_text = true;
                c->txt_len = 0;
            }
            if (len == 0)
                frame_done(c);
            continue;
        }
        size_t take = c->remaining < n ? (size_t)c->remaining : n;
        if (c->in_binary && (c->opcode == 2 || c->opcode == 0)) {
            if (c->msg_off < 48) {
                size_t h = 48 - c->msg_off < take ? 48 - c->msg_off : take;
                memcpy(c->hdr + c->msg_off, p, h);
            }
            c->msg_off += take;
        } else if (c->in_text && (c->opcode == 1 || c->opcode == 0)) {
            if (c->txt_len < sizeof c->txt - 1) {
                size_t h = sizeof c->txt - 1 - c->txt_len < take ? sizeof c->txt - 1 - c->txt_len : take;
                memcpy(c->txt + c->txt_len, p, h);
            }
            c->txt_len += take;
        } else if (c->opcode == 9 && c->ping_len + take <= sizeof c->ping) {
            memcpy(c->ping + c->ping_len, p, take);
            c->ping_len += (int)take;
        }
        p += take;
        n -= take;
        c->remaining -= take;
        if (c->remaining == 0)
            frame_done(c);
    }
}

static const char *host = "127.0.0.1", *bind_addr;

static int open_client(struct client *c, int port)
{
    c->fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port) };
    if (inet_pton(AF_INET, host, &a.sin_addr) != 1)
        return -1;
    if (c->fd >= 0 && bind_addr) {
        struct sockaddr_in b = { .sin_family = AF_INET };
        if (inet_pton(AF_INET, bind_addr, &b.sin_addr) != 1 || bind(c->fd, (struct sockaddr *)&b, sizeof b) != 0)
            return -1;
    }
    if (c->fd < 0 || connect(c->fd, (struct sockaddr *)&a, sizeof a) != 0)
        return -1;
    int one = 1;
    setsockopt(c->fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    char req[512];
    int n = snprintf(req, sizeof req,
                     "GET / HTTP/1.1\r\nHost: %s:%d\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                     "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
                     "Sec-WebSocket-Protocol: oceand.v1\r\n\r\n", host, port);
    if (send(c->fd, req, (size_t)n, MSG_NOSIGNAL) != n)
        return -1;
    /* Read the response header byte by byte so no WebSocket data is swallowed. */
    char resp[1024];
    size_t got = 0;
    while (got < sizeof resp - 1) {
        if (recv(c->fd, resp + got, 1, 0) != 1)
            return -1;
        got++;
        if (got >= 4 && memcmp(resp + got - 4, "\r\n\r\n", 4) == 0)
            break;
    }
    resp[got] = 0;
    if (!strstr(resp, " 101 "))
        return -1;
    c->open = true;
    return 0;
}

static const char *sub_json;
static int open_rc[65536];

static void *open_thread(void *arg)
{
    struct client *c = arg;
    open_rc[c->idx] = open_client(c, c->port);
    if (open_rc[c->idx] == 0 && sub_json)
        send_frame(c, 1, sub_json, strlen(sub_json));
    return NULL;
}

/* Nearest-rank percentile (p50 included: the rank's value, as the JSON
 * figures always were), not bench_time.h's median. */
static double pct(double *v, size_t n, double p)
{
    if (!n)
        return -1;
    qsort(v, n, sizeof *v, bench_cmp_double);
    return v[(size_t)(p * (double)(n - 1) + 0.5)];
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fprintf(stderr, "usage: load_client PORT CLIENTS WARMUP_S WINDOW_S [SUBSCRIBE_JSON]\n");
        return 2;
    }
    int port = atoi(argv[1]);
    nclients = atoi(argv[2]);
    double warmup = atof(argv[3]), window = atof(argv[4]);
    signal(SIGPIPE, SIG_IGN);
    clients = calloc((size_t)nclients, sizeof *clients);
    lat_cap = (size_t)nclients * 32 * (size_t)(window + 2) + 1024;
    lat = malloc(lat_cap * sizeof *lat);
    sizes = malloc(lat_cap * sizeof *sizes);
    int ep = epoll_create1(0);
    if (!clients || !lat || !sizes || ep < 0)
        return 1;
    int connected = 0, errors = 0;
    if (getenv("LOAD_HOST") && *getenv("LOAD_HOST"))
        host = getenv("LOAD_HOST");
    if (getenv("LOAD_BIND") && *getenv("LOAD_BIND"))
        bind_addr = getenv("LOAD_BIND");
    sub_json = argc > 5 ? argv[5] : NULL;
    t_origin = now_s();
    if (getenv("LOAD_LINK_LOG") && *getenv("LOAD_LINK_LOG"))
        link_log = fopen(getenv("LOAD_LINK_LOG"), "w");
    if (nclients > 65536)
        return 2;
    pthread_t *th = calloc((size_t)nclients, sizeof *th);
    if (!th)
        return 1;
    for (int i = 0; i < nclients; i++) {
        clients[i].idx = i;
        clients[i].port = port;
        if (pthread_create(&th[i], NULL, open_thread, &clients[i]) != 0)
            open_rc[i] = -2;
    }
    for (int i = 0; i < nclients; i++)
        if (open_rc[i] != -2)
            pthread_join(th[i], NULL);
    free(th);
    for (int i = 0; i < nclients; i++) {
        if (open_rc[i] != 0) {
            errors++;
            continue;
        }
        connected++;
        struct epoll_event ev = { .events = EPOLLIN, .data.ptr = &clients[i] };
        epoll_ctl(ep, EPOLL_CTL_ADD, clients[i].fd, &ev);
    }
    static uint8_t buf[1 << 18];
    double t_start = now_s() + warmup, next_set = 0;
    const char *si = getenv("LOAD_SET_INTERVAL_S");
    double set_interval = si && *si ? atof(si) : 0.3;
    uint64_t seq_start = 0;
    struct epoll_event evs[256];
    for (;;) {
        int n = epoll_wait(ep, evs, 256, 10);
        for (int i = 0; i < n; i++) {
            struct client *c = evs[i].data.ptr;
            ssize_t r = recv(c->fd, buf, sizeof buf, MSG_DONTWAIT);
            if (r > 0) {
                consume(c, buf, (size_t)r);
            } else if (r == 0 || (errno != EAGAIN && errno != EINTR)) {
                epoll_ctl(ep, EPOLL_CTL_DEL, c->fd, NULL);
                c->open = false;
            }
        }
        double t = now_s();
        if (!measuring && t >= t_start) {
            measuring = true;
            seq_start = seq_max;
            next_set = t + 0.25;
            fprintf(stderr, "measuring %.6f\n", t); /* the driver samples daemon CPU from here (t: CLOCK_MONOTONIC) */
            fflush(stderr);
        }
        if (set_interval > 0 && measuring && clients[0].open && t >= next_set && !set_waiting) {
            char msg[96];
            int len = snprintf(msg, sizeof msg, "{\"type\":\"set\",\"params\":{\"wind_speed\":%d}}", 11 + (set_value++ % 2));
            set_waiting = true;
            set_seq = clients[0].last_seq;
            set_version = clients[0].last_version;
            send_frame(&clients[0], 1, msg, (size_t)len);
            next_set = t + set_interval;
        }
        if (measuring && t >= t_start + window)
            break;
    }
    uint64_t made = seq_max - seq_start;
    double *fps = malloc(sizeof(double) * (size_t)nclients), *share = malloc(sizeof(double) * (size_t)nclients);
    uint64_t bytes = 0;
    int still_open = 0;
    for (int i = 0; i < nclients; i++) {
        fps[i] = (double)clients[i].frames / window;
        share[i] = made ? (double)clients[i].frames / (double)made : 0;
        bytes += clients[i].bytes;
        still_open += clients[i].open;
    }
    printf("{\"connected\":%d,\"errors\":%d,\"open_at_end\":%d,\"window_s\":%g,\"frames_made\":%llu,\"fps_median\":%.2f,"
           "\"fps_min\":%.2f,\"delivered\":%.4f,\"delivered_median\":%.4f,\"lat_p50_ms\":%.2f,\"lat_p99_ms\":%.2f,"
           "\"set_latency_ticks_p50\":%.1f,\"set_latency_ticks_p99\":%.1f,\"set_samples\":%d,\"mbytes_per_s\":%.3f,"
           "\"frame_kb\":%.1f,\"frame_kb_p50\":%.1f",
           connected, errors, still_open, window, (unsigned long long)made, pct(fps, (size_t)nclients, 0.5),
           pct(fps, (size_t)nclients, 0), pct(share, (size_t)nclients, 0), pct(share, (size_t)nclients, 0.5),
           pct(lat, nlat, 0.5), pct(lat, nlat, 0.99), pct(set_samples, (size_t)nset, 0.5),
           pct(set_samples, (size_t)nset, 0.99), nset, (double)bytes / window / 1e6,
           nlat ? (double)bytes / (double)nlat / 1024 : 0, pct(sizes, nlat, 0.5) / 1024);
    /* The rungs: at the end of the window (median, max), the highest reached. */
    double *rv = malloc(sizeof(double) * (size_t)nclients), *rmax = malloc(sizeof(double) * (size_t)nclients);
    int changes = 0, downs = 0, ups = 0;
    for (int i = 0; i < nclients && rv && rmax; i++) {
        rv[i] = clients[i].rung;
        rmax[i] = clients[i].rung_max;
        changes += clients[i].rung_changes;
        downs += clients[i].downs;
        ups += clients[i].ups;
    }
    bool per = getenv("LOAD_PER_CLIENT") && atoi(getenv("LOAD_PER_CLIENT"));
    if (rv && rmax) {
        printf(",\"rungs\":{\"end_median\":%g,\"end_max\":%g,\"max_reached\":%g,\"link_messages\":%d,\"congestion\":%d,\"probe\":%d}",
               pct(rv, (size_t)nclients, 0.5), pct(rv, (size_t)nclients, 1), pct(rmax, (size_t)nclients, 1), changes,
               downs, ups);
        if (per) {
            printf(",\"client_fps\":[");
            for (int i = 0; i < nclients; i++)
                printf("%s%.2f", i ? "," : "", (double)clients[i].frames / window);
            printf("],\"client_rung\":[");
            for (int i = 0; i < nclients; i++)
                printf("%s%d", i ? "," : "", clients[i].rung);
            printf("],\"client_rung_max\":[");
            for (int i = 0; i < nclients; i++)
                printf("%s%d", i ? "," : "", clients[i].rung_max);
            printf("]");
        }
    }
    printf("}\n");
    free(rv);
    free(rmax);
    if (link_log)
        fclose(link_log);
    for (int i = 0; i < nclients; i++)
        if (clients[i].fd > 0)
            close(clients[i].fd);
    free(fps);
    free(share);
    free(lat);
    free(sizes);
    free(clients);
    return 0;
}

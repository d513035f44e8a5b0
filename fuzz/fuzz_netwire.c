/* fuzz_netwire.c — libFuzzer target: the two parsers of server/net/ that
 * read a stranger's bytes before libwebsockets' own checks: the masking
 * guard (rx_guard.c: HTTP heads, Content-Length bodies, WebSocket frame
 * headers, the close it puts in place of an unmasked frame) and the Host
 * check (upgrade.c: net_host_name_allowed).
 * Input: byte 0 picks the read sizes; the rest is one client's stream, fed
 * to the guard in reads of that size into buffers of exactly that room
 * (ASan catches a write past it). Each NUL-free line of the input is also
 * tried as a Host header against three --bind/--server-name settings. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "../server/net/rx_guard.c" /* the static parser itself, not the recv(2) it defines for the daemon */

static void host_lines(const uint8_t *data, size_t size)
{
    static const struct { const char *bind, *names; } cfg[] = {
        { "127.0.0.1", "" }, { "0.0.0.0", "ocean.example.org,b.example" }, { "::1", "*" } };
    char line[300];
    size_t start = 0;
    for (size_t i = 0; i <= size; i++) {
        if (i < size && data[i] != '\n')
            continue;
        size_t len = i - start;
        if (len < sizeof line && !memchr(data + start, 0, len)) {
            memcpy(line, data + start, len);
            line[len] = 0;
            for (size_t c = 0; c < sizeof cfg / sizeof cfg[0]; c++) {
                struct daemon_config dc;
                memset(&dc, 0, sizeof dc);
                strcpy(dc.bind, cfg[c].bind);
                strcpy(dc.server_name, cfg[c].names);
                bool ok = net_host_name_allowed(&dc, line);
                if (c == 2 && !ok)
                    abort(); /* "*" accepts every Host */
            }
        }
        start = i + 1;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    size_t step = 1 + data[0] % 64 * (data[0] & 0x40 ? 64 : 1);
    struct rx_guard g;
    memset(&g, 0, sizeof g);
    head_reset(&g);
    size_t injected = 0;
    for (size_t off = 1; off < size && g.phase != G_DEAD; off += step) {
        size_t n = size - off < step ? size - off : step;
        unsigned char *buf = malloc(n);
        if (!buf)
            abort();
        memcpy(buf, data + off, n);
        ssize_t out = guard_feed(&g, buf, n, n);
        if (out > (ssize_t)n)
            abort();
        if (g.phase == G_DEAD && out >= 0) {
            /* what lws gets ends with the masked close 1002, intact */
            if ((size_t)out < sizeof inject || memcmp(buf + out - sizeof inject, inject, sizeof inject) != 0)
                abort();
            injected++;
        } else if (out >= 0 && memcmp(buf, data + off, (size_t)out) != 0) {
            abort(); /* bytes pass unchanged until an unmasked frame */
        }
        free(buf);
    }
    if (injected > 1)
        abort();
    host_lines(data + 1, size - 1);
    return 0;
}

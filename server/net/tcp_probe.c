/* tcp_probe.c — what the kernel knows about a client's link: delivery rate,
 * RTT and bytes not sent yet (TCP_INFO), and the bound on the latter
 * (TCP_NOTSENT_LOWAT). glibc's struct tcp_info stops before the delivery
 * rate, so this file takes the kernel's header and nothing that clashes
 * with it. */
#include <netinet/in.h> /* IPPROTO_TCP; netinet/tcp.h would clash with the kernel header */
#include <linux/tcp.h>
#include <stddef.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>
#include <sys/socket.h>

struct tcp_probe { double delivery_bps, rtt_ms; uint32_t notsent; bool app_limited, ok; };
void tcp_probe_read(int fd, struct tcp_probe *p);
void tcp_probe_lowat(int fd, uint32_t bytes);

void tcp_probe_read(int fd, struct tcp_probe *p)
{
    struct tcp_info ti;
    socklen_t len = sizeof ti;
    memset(&ti, 0, sizeof ti);
    memset(p, 0, sizeof *p);
    if (fd < 0 || getsockopt(fd, IPPROTO_TCP, TCP_INFO, &ti, &len) != 0)
        return;
    p->ok = true;
    p->rtt_ms = ti.tcpi_rtt / 1000.0;
    /* Older kernels return a shorter struct: fields past len stay 0 (unknown). */
    if (len >= offsetof(struct tcp_info, tcpi_notsent_bytes) + sizeof ti.tcpi_notsent_bytes)
        p->notsent = ti.tcpi_notsent_bytes;
    if (len >= offsetof(struct tcp_info, tcpi_delivery_rate) + sizeof ti.tcpi_delivery_rate) {
        p->delivery_bps = (double)ti.tcpi_delivery_rate;
        p->app_limited = ti.tcpi_delivery_rate_app_limited;
    }
}

void tcp_probe_lowat(int fd, uint32_t bytes)
{
    unsigned v = bytes;
    setsockopt(fd, IPPROTO_TCP, TCP_NOTSENT_LOWAT, &v, sizeof v);
}

/* tcp_probe.c — what the kernel knows about a client's link: delivery rate,
 * RTT and bytes not sent yet (TCP_INFO), the bound on the latter
 * (TCP_NOTSENT_LOWAT), and a ceiling on TCP's pacing rate (SO_MAX_PACING_RATE). glibc's struct tcp_info stops before the delivery
 * rate, so this file takes the kernel's header and nothing that clashes
 * with it. */
#include <netinet/in.h> /* IPPROTO_TCP; netinet/tcp.h would clash with the kernel header */
#include <linux/tcp.h>
#include <stddef.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>
#include <sys/socket.h>

struct tcp_probe { double delivery_bps, rtt_ms, min_rtt_ms; uint32_t notsent, inflight; bool app_limited, ok; };
void tcp_probe_read(int fd, struct tcp_probe *p);
void tcp_probe_lowat(int fd, uint32_t bytes);
void tcp_probe_pacing(int fd, double bytes_per_s);

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
    /* Packets in flight as the kernel counts them (sent, not acked, not
     * sacked nor lost, plus retransmissions out), in bytes. */
    uint32_t pk = ti.tcpi_unacked - ti.tcpi_sacked - ti.tcpi_lost + ti.tcpi_retrans;
    p->inflight = ti.tcpi_unacked >= ti.tcpi_sacked + ti.tcpi_lost ? pk * ti.tcpi_snd_mss : 0;
    /* Older kernels return a shorter struct: fields past len stay 0 (unknown). */
    if (len >= offsetof(struct tcp_info, tcpi_notsent_bytes) + sizeof ti.tcpi_notsent_bytes)
        p->notsent = ti.tcpi_notsent_bytes;
    if (len >= offsetof(struct tcp_info, tcpi_min_rtt) + sizeof ti.tcpi_min_rtt)
        p->min_rtt_ms = ti.tcpi_min_rtt / 1000.0;
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

void tcp_probe_pacing(int fd, double bytes_per_s)
{
    unsigned v = bytes_per_s <= 0 || bytes_per_s >= 4e9 ? ~0u : (unsigned)bytes_per_s;
    setsockopt(fd, SOL_SOCKET, SO_MAX_PACING_RATE, &v, sizeof v);
}

/* shaper — a userspace link between two network namespaces (the link lab,
 * `make bench-links`, `make test-links`).
 *
 *   shaper NS_A NS_B RATE_KBIT DELAY_MS LOSS_PCT QUEUE_BYTES [SEED]
 *
 * Opens a TUN device "lnk0" in each namespace (they exist while this runs)
 * and moves IP packets between them, per direction: random loss, a
 * drop-tail queue of QUEUE_BYTES, serialisation at RATE_KBIT, then
 * DELAY_MS one way. This kernel has tbf but no netem, and tbf alone has no
 * delay: hence userspace. Prints "ready" once both devices exist; the
 * caller sets their addresses. SIGUSR1 toggles a stall (both directions
 * hold every packet, as a dead radio link would; the queue still drops
 * tail); SIGTERM ends it. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <linux/if.h>
#include <linux/if_tun.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <time.h>
#include <unistd.h>

#define MAX_PKT 65536
#define MAX_QUEUED 65536

struct pkt {
    double due;               /* delivery time (delay line) */
    size_t len;
    unsigned char data[];
};

struct dir {
    int in, out;              /* read from in, write to out */
    struct pkt *q[MAX_QUEUED]; /* drop-tail queue (FIFO ring) */
    int qh, qn;
    size_t qbytes;
    struct pkt *d[MAX_QUEUED]; /* delay line, in due order */
    int dh, dn;
    double tx_free;           /* when the wire is free */
    unsigned long long passed, lost, dropped;
};

static double rate_bps, delay_s, loss, qmax;
static volatile sig_atomic_t stop, stall_flag;

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void on_sig(int sig)
{
    if (sig == SIGUSR1)
        stall_flag = !stall_flag;
    else
        stop = 1;
}

static int tun_in(const char *ns)
{
    char path[256];
    snprintf(path, sizeof path, "/var/run/netns/%s", ns);
    int nfd = open(path, O_RDONLY);
    if (nfd < 0 || setns(nfd, CLONE_NEWNET) != 0) {
        perror(path);
        exit(1);
    }
    close(nfd);
    int fd = open("/dev/net/tun", O_RDWR | O_NONBLOCK);
    if (fd < 0) {
        perror("/dev/net/tun");
        exit(1);
    }
    struct ifreq ifr;
    memset(&ifr, 0, sizeof ifr);
    ifr.ifr_flags = IFF_TUN | IFF_NO_PI;
    snprintf(ifr.ifr_name, sizeof ifr.ifr_name, "lnk0");
    if (ioctl(fd, TUNSETIFF, &ifr) != 0) {
        perror("TUNSETIFF");
        exit(1);
    }
    return fd;
}

static void take(struct dir *x, double now)
{
    for (int i = 0; i < 64; i++) {
        unsigned char buf[MAX_PKT];
        ssize_t r = read(x->in, buf, sizeof buf);
        if (r <= 0)
            return;
        if (loss > 0 && drand48() < loss) {
            x->lost++;
            continue;
        }
        if (x->qbytes + (size_t)r > qmax || x->qn == MAX_QUEUED) {
            x->dropped++;
            continue;
        }
        struct pkt *p = malloc(sizeof *p + (size_t)r);
        if (!p)
            return;
        p->len = (size_t)r;
        memcpy(p->data, buf, (size_t)r);
        x->q[(x->qh + x->qn++) % MAX_QUEUED] = p;
        x->qbytes += (size_t)r;
        (void)now;
    }
}

/* Move what the wire has finished into the delay line, deliver what is due;
 * returns the next time something happens (or a second from now). */
static double pump(struct dir *x, double now)
{
    double next = now + 1;
    if (!stall_flag) {
        if (x->tx_free < now)
            x->tx_free = now;
        while (x->qn && x->tx_free <= now && x->dn < MAX_QUEUED) {
            struct pkt *p = x->q[x->qh];
            x->qh = (x->qh + 1) % MAX_QUEUED;
            x->qn--;
            x->qbytes -= p->len;
            x->tx_free += p->len * 8.0 / rate_bps;
            p->due = x->tx_free + delay_s;
            x->d[(x->dh + x->dn++) % MAX_QUEUED] = p;
        }
        if (x->qn && x->tx_free < next)
            next = x->tx_free;
    }
    while (x->dn && x->d[x->dh]->due <= now && !stall_flag) {
        struct pkt *p = x->d[x->dh];
        x->dh = (x->dh + 1) % MAX_QUEUED;
        x->dn--;
        if (write(x->out, p->data, p->len) == (ssize_t)p->len)
            x->passed++;
        free(p);
    }
    if (x->dn && x->d[x->dh]->due < next && !stall_flag)
        next = x->d[x->dh]->due;
    return next;
}

int main(int argc, char **argv)
{
    if (argc < 7) {
        fprintf(stderr, "usage: %s NS_A NS_B RATE_KBIT DELAY_MS LOSS_PCT QUEUE_BYTES [SEED]\n", argv[0]);
        return 2;
    }
    rate_bps = atof(argv[3]) * 1000;
    delay_s = atof(argv[4]) / 1000;
    loss = atof(argv[5]) / 100;
    qmax = atof(argv[6]);
    srand48(argc > 7 ? atol(argv[7]) : 1);
    int self = open("/proc/self/ns/net", O_RDONLY);
    int a = tun_in(argv[1]), b = tun_in(argv[2]);
    if (self >= 0) {
        setns(self, CLONE_NEWNET);
        close(self);
    }
    static struct dir ab, ba;
    ab.in = a, ab.out = b;
    ba.in = b, ba.out = a;
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_sig;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);
    printf("ready\n");
    fflush(stdout);
    while (!stop) {
        double now = now_s();
        take(&ab, now);
        take(&ba, now);
        double next = pump(&ab, now);
        double n2 = pump(&ba, now);
        if (n2 < next)
            next = n2;
        double wait = next - now_s();
        if (wait < 0)
            wait = 0;
        struct pollfd pf[2] = { { a, POLLIN, 0 }, { b, POLLIN, 0 } };
        struct timespec ts = { (time_t)wait, (long)((wait - (time_t)wait) * 1e9) };
        if (ppoll(pf, 2, &ts, NULL) < 0 && errno != EINTR)
            break;
    }
    fprintf(stderr, "shaper: a->b passed %llu lost %llu dropped %llu; b->a passed %llu lost %llu dropped %llu\n",
            ab.passed, ab.lost, ab.dropped, ba.passed, ba.lost, ba.dropped);
    return 0;
}

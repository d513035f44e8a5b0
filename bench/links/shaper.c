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
 * tail); SIGTERM ends it.
 *
 * Per-flow links (bench/links/many.sh, `make bench-links-load`):
 *   shaper ... QUEUE_BYTES [SEED] --flow IP:RATE_KBIT:DELAY_MS:LOSS_PCT:QUEUE_BYTES ...
 * Each TCP or UDP connection whose NS_B end has address IP gets a link of
 * its own with those figures (its own queue, wire and delay line, per
 * direction), as if each viewer sat behind its own access link; forty
 * viewers of a 2 Mbit/s class have 2 Mbit/s each. Other packets (other
 * addresses, not IPv4 TCP/UDP, or past MAX_FLOWS connections) share the
 * link of the positional figures. */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <linux/if.h>
#include <linux/if_tun.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <time.h>
#include <unistd.h>

#define MAX_PKT 65536
#define RING 8192             /* packets a queue or delay line holds (per direction and link) */
#define MAX_CLASSES 16
#define MAX_FLOWS 2048
#define HASH_SLOTS 8192

struct pkt {
    double due;               /* delivery time (delay line) */
    size_t len;
    struct pkt *next;
    unsigned char data[];
};

struct params {
    double rate_bps, delay_s, loss, qmax;
};

/* The queue and the delay line are FIFOs of packets (head, tail). */
static void fifo_push(struct pkt **head, struct pkt **tail, struct pkt *p)
{
    p->next = NULL;
    if (*tail)
        (*tail)->next = p;
    else
        *head = p;
    *tail = p;
}

static struct pkt *fifo_pop(struct pkt **head, struct pkt **tail)
{
    struct pkt *p = *head;
    *head = p->next;
    if (!*head)
        *tail = NULL;
    return p;
}

/* One direction of one link: a drop-tail queue, the wire, a delay line. */
struct dir {
    const struct params *pa;
    struct pkt *qh, *qt;      /* drop-tail queue (FIFO) */
    int qn;
    size_t qbytes;
    struct pkt *dh, *dt;      /* delay line, in due order */
    int dn;
    double tx_free;           /* when the wire is free */
    double next;              /* when pump has something to do next (cached) */
    unsigned long long passed, lost, dropped;
};

struct link {
    struct dir ab, ba;
};

static struct params shared_pa;
static struct params class_pa[MAX_CLASSES];
static uint32_t class_ip[MAX_CLASSES];  /* network order */
static int nclasses;
static struct link shared;
static struct link *flows[MAX_FLOWS];
static int nflows;
static struct { uint32_t ip; uint16_t bport, aport; int idx; } slots[HASH_SLOTS];
static int fd_a, fd_b;
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

/* The link a packet read from NS_A (to_b) or NS_B travels: its connection's
 * own when its NS_B address is a --flow class, else the shared one. */
static struct link *link_of(const unsigned char *p, size_t len, bool to_b)
{
    if (!nclasses || len < 20 || (p[0] >> 4) != 4)
        return &shared;
    uint32_t bip;
    memcpy(&bip, p + (to_b ? 16 : 12), 4);
    int c = 0;
    while (c < nclasses && class_ip[c] != bip)
        c++;
    size_t ihl = (size_t)(p[0] & 15) * 4;
    if (c == nclasses || (p[9] != 6 && p[9] != 17) || len < ihl + 4)
        return &shared;
    uint16_t sport = (uint16_t)(p[ihl] << 8 | p[ihl + 1]), dport = (uint16_t)(p[ihl + 2] << 8 | p[ihl + 3]);
    uint16_t bport = to_b ? dport : sport, aport = to_b ? sport : dport;
    uint32_t h = (bip * 2654435761u) ^ ((uint32_t)bport * 40503u) ^ ((uint32_t)aport << 7);
    for (int i = 0; i < HASH_SLOTS; i++) {
        int sl = (int)((h + (uint32_t)i) % HASH_SLOTS);
        if (slots[sl].idx && slots[sl].ip == bip && slots[sl].bport == bport && slots[sl].aport == aport)
            return flows[slots[sl].idx - 1];
        if (!slots[sl].idx) {
            if (nflows == MAX_FLOWS)
                return &shared;
            struct link *l = calloc(1, sizeof *l);
            if (!l)
                return &shared;
            l->ab.pa = l->ba.pa = &class_pa[c];
            l->ab.next = l->ba.next = 1e300;
            flows[nflows++] = l;
            slots[sl].ip = bip, slots[sl].bport = bport, slots[sl].aport = aport, slots[sl].idx = nflows;
            return l;
        }
    }
    return &shared;
}

/* Read what is waiting on fd (from NS_A when to_b) into the links' queues. */
static void take(int fd, bool to_b, double now)
{
    for (int i = 0; i < 64; i++) {
        unsigned char buf[MAX_PKT];
        ssize_t r = read(fd, buf, sizeof buf);
        if (r <= 0)
            return;
        struct link *l = link_of(buf, (size_t)r, to_b);
        struct dir *x = to_b ? &l->ab : &l->ba;
        if (x->pa->loss > 0 && drand48() < x->pa->loss) {
            x->lost++;
            continue;
        }
        if (x->qbytes + (size_t)r > x->pa->qmax || x->qn == RING) {
            x->dropped++;
            continue;
        }
        struct pkt *p = malloc(sizeof *p + (size_t)r);
        if (!p)
            return;
        p->len = (size_t)r;
        memcpy(p->data, buf, (size_t)r);
        fifo_push(&x->qh, &x->qt, p);
        x->qn++;
        x->qbytes += (size_t)r;
        x->next = now; /* pump it */
    }
}

/* Move what the wire has finished into the delay line, deliver what is due;
 * returns the next time something happens (or a second from now). */
static double pump(struct dir *x, int out, double now)
{
    double next = now + 1;
    if (!stall_flag) {
        if (x->tx_free < now)
            x->tx_free = now;
        while (x->qn && x->tx_free <= now && x->dn < RING) {
            struct pkt *p = fifo_pop(&x->qh, &x->qt);
            x->qn--;
            x->qbytes -= p->len;
            x->tx_free += p->len * 8.0 / x->pa->rate_bps;
            p->due = x->tx_free + x->pa->delay_s;
            fifo_push(&x->dh, &x->dt, p);
            x->dn++;
        }
        if (x->qn && x->tx_free < next)
            next = x->tx_free;
    }
    while (x->dn && x->dh->due <= now && !stall_flag) {
        struct pkt *p = fifo_pop(&x->dh, &x->dt);
        x->dn--;
        if (write(out, p->data, p->len) == (ssize_t)p->len)
            x->passed++;
        free(p);
    }
    if (x->dn && x->dh->due < next && !stall_flag)
        next = x->dh->due;
    if (!x->qn && !x->dn)
        next = 1e300; /* idle until take() queues something */
    return x->next = next;
}

static void parse_class(const char *spec)
{
    char ip[64];
    double kbit, delay_ms, loss_pct, q;
    if (nclasses == MAX_CLASSES || sscanf(spec, "%63[^:]:%lf:%lf:%lf:%lf", ip, &kbit, &delay_ms, &loss_pct, &q) != 5 ||
        inet_pton(AF_INET, ip, &class_ip[nclasses]) != 1) {
        fprintf(stderr, "shaper: bad --flow %s (IP:RATE_KBIT:DELAY_MS:LOSS_PCT:QUEUE_BYTES)\n", spec);
        exit(2);
    }
    class_pa[nclasses++] = (struct params){ kbit * 1000, delay_ms / 1000, loss_pct / 100, q };
}

static void sum_stats(const struct dir *x, unsigned long long *t)
{
    t[0] += x->passed, t[1] += x->lost, t[2] += x->dropped;
}

int main(int argc, char **argv)
{
    int npos = 1;
    while (npos < argc && strcmp(argv[npos], "--flow") != 0)
        npos++;
    if (npos < 7) {
        fprintf(stderr, "usage: %s NS_A NS_B RATE_KBIT DELAY_MS LOSS_PCT QUEUE_BYTES [SEED] "
                        "[--flow IP:RATE_KBIT:DELAY_MS:LOSS_PCT:QUEUE_BYTES ...]\n", argv[0]);
        return 2;
    }
    for (int i = npos; i < argc; i++) {
        if (strcmp(argv[i], "--flow") != 0 || i + 1 >= argc) {
            fprintf(stderr, "shaper: unexpected %s\n", argv[i]);
            return 2;
        }
        parse_class(argv[++i]);
    }
    shared_pa = (struct params){ atof(argv[3]) * 1000, atof(argv[4]) / 1000, atof(argv[5]) / 100, atof(argv[6]) };
    srand48(npos > 7 ? atol(argv[7]) : 1);
    shared.ab.pa = shared.ba.pa = &shared_pa;
    shared.ab.next = shared.ba.next = 1e300;
    int self = open("/proc/self/ns/net", O_RDONLY);
    fd_a = tun_in(argv[1]), fd_b = tun_in(argv[2]);
    if (self >= 0) {
        setns(self, CLONE_NEWNET);
        close(self);
    }
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_sig;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);
    printf("ready\n");
    fflush(stdout);
    bool was_stalled = false;
    while (!stop) {
        double now = now_s();
        take(fd_a, true, now);
        take(fd_b, false, now);
        bool stalled = stall_flag;
        bool all = stalled != was_stalled; /* a stall's end: every link has work again */
        was_stalled = stalled;
        double next = now + 1;
        for (int i = -1; i < nflows; i++) {
            struct link *l = i < 0 ? &shared : flows[i];
            double n1 = (all || l->ab.next <= now) ? pump(&l->ab, fd_b, now) : l->ab.next;
            double n2 = (all || l->ba.next <= now) ? pump(&l->ba, fd_a, now) : l->ba.next;
            if (n1 < next)
                next = n1;
            if (n2 < next)
                next = n2;
        }
        double wait = next - now_s();
        if (wait < 0)
            wait = 0;
        struct pollfd pf[2] = { { fd_a, POLLIN, 0 }, { fd_b, POLLIN, 0 } };
        struct timespec ts = { (time_t)wait, (long)((wait - (time_t)wait) * 1e9) };
        if (ppoll(pf, 2, &ts, NULL) < 0 && errno != EINTR)
            break;
    }
    unsigned long long ab[3] = { 0 }, ba[3] = { 0 };
    sum_stats(&shared.ab, ab);
    sum_stats(&shared.ba, ba);
    for (int i = 0; i < nflows; i++) {
        sum_stats(&flows[i]->ab, ab);
        sum_stats(&flows[i]->ba, ba);
    }
    fprintf(stderr, "shaper: a->b passed %llu lost %llu dropped %llu; b->a passed %llu lost %llu dropped %llu; %d flows\n",
            ab[0], ab[1], ab[2], ba[0], ba[1], ba[2], nflows);
    return 0;
}

/* test_cluster_nats.c — the cluster link against a real nats-server, which
 * this test starts itself on a free 127.0.0.1 port (and kills if the test
 * dies: PR_SET_PDEATHSIG). One process plays the sim and several edges,
 * each its own NATS connection, exactly as separate daemons would:
 *   layers reach only the edges that demand them, byte for byte, split into
 *   parts above the server's max_payload; request/reply (deferred reply,
 *   hello); params events with origin; demand goodbye and expiry; kill -9 of
 *   nats-server and restart on the same port: every link reconnects, an
 *   edge opened while NATS is down connects later, demand comes back and
 *   layers flow again; sim down: edges see sim_down and requests get
 *   no_responders; a new sim gets the edges' demand within a heartbeat.
 * Waits have deadlines but nothing is timed. Closing line: "N passed, M failed". */
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "cluster/cluster.h"
#include "layer_gen.h"

#include "../common/check.h"

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* ---- nats-server, started and stopped by the test ---- */

static const char *natsd_bin;
static pid_t natsd_pid;
static int natsd_port;
static char tmpdir[] = "/tmp/oceand-cluster-XXXXXX";

static const char *find_nats_server(void)
{
    const char *env = getenv("NATS_SERVER");
    if (env && access(env, X_OK) == 0)
        return env;
    static const char *paths[] = { "/usr/sbin/nats-server", "/usr/bin/nats-server", "/usr/local/bin/nats-server" };
    for (size_t i = 0; i < sizeof paths / sizeof *paths; i++)
        if (access(paths[i], X_OK) == 0)
            return paths[i];
    return NULL;
}

static int free_port(void)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    socklen_t len = sizeof a;
    if (fd < 0 || bind(fd, (struct sockaddr *)&a, sizeof a) != 0 || getsockname(fd, (struct sockaddr *)&a, &len) != 0) {
        if (fd >= 0)
            close(fd);
        return -1;
    }
    close(fd);
    return ntohs(a.sin_port);
}

static bool port_open(int port)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = { .sin_family = AF_INET, .sin_port = htons((uint16_t)port),
                             .sin_addr.s_addr = htonl(INADDR_LOOPBACK) };
    bool ok = fd >= 0 && connect(fd, (struct sockaddr *)&a, sizeof a) == 0;
    if (fd >= 0)
        close(fd);
    return ok;
}

static void natsd_kill(int sig)
{
    if (natsd_pid <= 0)
        return;
    kill(natsd_pid, sig);
    double until = now_s() + 5;
    int st;
    while (waitpid(natsd_pid, &st, WNOHANG) == 0) {
        if (now_s() > until) {
            kill(natsd_pid, SIGKILL);
            waitpid(natsd_pid, &st, 0);
            break;
        }
        usleep(10000);
    }
    natsd_pid = 0;
}

static bool natsd_tls; /* serve TLS only, with tmpdir/cert.pem + key.pem */

static bool natsd_start(void)
{
    char conf[300], log[300];
    snprintf(conf, sizeof conf, "%s/nats.conf", tmpdir);
    snprintf(log, sizeof log, "%s/nats.log", tmpdir);
    FILE *f = fopen(conf, "w");
    if (!f)
        return false;
    /* loopback only; a small max_payload so that layers are split into parts */
    fprintf(f, "listen: 127.0.0.1:%d\nmax_payload: 65536\n", natsd_port);
    if (natsd_tls)
        fprintf(f, "tls { cert_file: \"%s/cert.pem\", key_file: \"%s/key.pem\" }\n", tmpdir, tmpdir);
    fclose(f);
    pid_t pid = fork();
    if (pid < 0)
        return false;
    if (pid == 0) {
        prctl(PR_SET_PDEATHSIG, SIGKILL); /* never outlive the test */
        int devnull = open("/dev/null", O_RDWR);
        if (devnull >= 0) {
            dup2(devnull, 0);
            dup2(devnull, 1);
        }
        execl(natsd_bin, natsd_bin, "-c", conf, "-l", log, (char *)NULL);
        _exit(127);
    }
    natsd_pid = pid;
    for (double until = now_s() + 10; now_s() < until; usleep(20000)) {
        int st;
        if (waitpid(pid, &st, WNOHANG) == pid) {
            natsd_pid = 0;
            return false;
        }
        if (port_open(natsd_port))
            return true;
    }
    return false;
}

static void cleanup(void)
{
    natsd_kill(SIGTERM);
    char cmd[400];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmpdir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", tmpdir);
}

static void on_signal(int sig)
{
    if (natsd_pid > 0)
        kill(natsd_pid, SIGKILL);
    signal(sig, SIG_DFL);
    raise(sig);
}

/* ---- what each link saw (touched on the main thread only: handlers run in dispatch) ---- */

#define MAXQ 64
struct obs {
    const char *who;
    struct cl_link *link;
    int ev[CL_EV_SIM_NEW + 1];
    struct cl_layer *layers[CL_KEYS]; /* latest of each key */
    int nlayers;
    struct cl_request *reqs[MAXQ];
    int nreqs;
    char params_text[256], params_origin[CL_NAME_MAX], params_by[CL_NAME_MAX];
    int nparams;
    char probe_text[256], probe_by[CL_NAME_MAX];
    int nprobe;
};

struct reply_box {
    bool done;
    int status;
    char text[256];
};

static pthread_mutex_t wake_lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t wake_cond = PTHREAD_COND_INITIALIZER;
static int wakes;

static void wake(void *user)
{
    pthread_mutex_lock(&wake_lock);
    wakes++;
    pthread_cond_signal(&wake_cond);
    pthread_mutex_unlock(&wake_lock);
}

static void h_state(void *user, enum cl_event ev)
{
    struct obs *o = user;
    o->ev[ev]++;
}
static void h_request(void *user, struct cl_request *req)
{
    struct obs *o = user;
    if (o->nreqs < MAXQ)
        o->reqs[o->nreqs++] = req;
    else
        cl_request_reply(o->link, req, NULL, 0);
}
static void h_layer(void *user, struct cl_layer *l)
{
    struct obs *o = user;
    int k = cl_info_key(&l->info);
    cl_layer_free(o->layers[k]);
    o->layers[k] = l;
    o->nlayers++;
}
static void h_params(void *user, const char *origin, const char *by, const char *text, size_t len)
{
    struct obs *o = user;
    snprintf(o->params_text, sizeof o->params_text, "%.*s", (int)len, text);
    snprintf(o->params_origin, sizeof o->params_origin, "%s", origin);
    snprintf(o->params_by, sizeof o->params_by, "%s", by);
    o->nparams++;
}
static void h_probe_data(void *user, const char *by, const char *text, size_t len)
{
    struct obs *o = user;
    snprintf(o->probe_text, sizeof o->probe_text, "%.*s", (int)len, text);
    snprintf(o->probe_by, sizeof o->probe_by, "%s", by);
    o->nprobe++;
}
static void h_reply(void *ctx, int status, const char *text, size_t len)
{
    struct reply_box *b = ctx;
    b->done = true;
    b->status = status;
    snprintf(b->text, sizeof b->text, "%.*s", text ? (int)len : 0, text ? text : "");
}

static struct obs *all_obs[8];
static int nobs;

static void dispatch_all(void)
{
    for (int i = 0; i < nobs; i++)
        if (all_obs[i]->link)
            cl_link_dispatch(all_obs[i]->link);
}

/* Dispatch until pred() holds or the deadline passes; returns pred(). */
static bool spin_until(double seconds, bool (*pred)(void *), void *arg)
{
    double until = now_s() + seconds;
    for (;;) {
        dispatch_all();
        if (pred && pred(arg))
            return true;
        if (now_s() >= until)
            return pred ? pred(arg) : true;
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        ts.tv_nsec += 20 * 1000000L;
        if (ts.tv_nsec >= 1000000000L) {
            ts.tv_sec++;
            ts.tv_nsec -= 1000000000L;
        }
        pthread_mutex_lock(&wake_lock);
        if (!wakes)
            pthread_cond_timedwait(&wake_cond, &wake_lock, &ts);
        wakes = 0;
        pthread_mutex_unlock(&wake_lock);
    }
}

static const char *link_tls_ca; /* --nats-tls-ca of the links opened next */

static struct cl_link *open_link_ex(struct obs *o, enum cl_role role, const char *name, const char *prefix,
                                    bool may_fail);
static struct cl_link *open_link(struct obs *o, enum cl_role role, const char *name, const char *prefix)
{
    return open_link_ex(o, role, name, prefix, false);
}

/* may_fail: an open refused at once is an accepted outcome (a plain client
 * against a TLS-only server may be turned away during cl_link_open). */
static struct cl_link *open_link_ex(struct obs *o, enum cl_role role, const char *name, const char *prefix,
                                    bool may_fail)
{
    char url[64], err[300];
    snprintf(url, sizeof url, "nats://127.0.0.1:%d", natsd_port);
    struct cl_config c = {
        .role = role, .url = url, .prefix = prefix, .name = name, .tls_ca = link_tls_ca,
        .heartbeat_s = role == CL_ROLE_SIM ? 0.2 : 0.3,
        .demand_ttl_s = 1.5, .sim_timeout_s = 1.0, .request_timeout_s = 3.0,
        .reconnect_min_s = 0.05, .reconnect_max_s = 0.5,
        .wake = wake, .user = o,
        .h = { .on_state = h_state, .on_request = h_request, .on_layer = h_layer, .on_params = h_params,
               .on_probe_data = h_probe_data },
    };
    o->link = cl_link_open(&c, err, sizeof err);
    if (!o->link && !may_fail)
        CHECK(0, "open %s: %s", name, err);
    return o->link;
}

static void close_link(struct obs *o)
{
    for (int i = 0; i < o->nreqs; i++)
        cl_request_reply(o->link, o->reqs[i], NULL, 0);
    o->nreqs = 0;
    cl_link_close(o->link);
    o->link = NULL;
}

static void obs_free(struct obs *o)
{
    for (int k = 0; k < CL_KEYS; k++)
        cl_layer_free(o->layers[k]);
}

/* ---- predicates ---- */
struct evwant { struct obs *o; enum cl_event ev; int n; };
static bool p_event(void *a)
{
    struct evwant *w = a;
    return w->o->ev[w->ev] >= w->n;
}
struct demwant { struct obs *sim; int key1, key2, edges; int absent; };
static bool p_demand(void *a)
{
    struct demwant *w = a;
    uint8_t u[CL_KEY_BYTES];
    int n = cl_sim_demand(w->sim->link, u);
    return (w->edges < 0 || n == w->edges) && (w->key1 < 0 || cl_bit(u, w->key1)) &&
           (w->key2 < 0 || cl_bit(u, w->key2)) && (w->absent < 0 || !cl_bit(u, w->absent));
}
struct laywant { struct obs *o; int key; uint64_t seq; };
static bool p_layer(void *a)
{
    struct laywant *w = a;
    return w->o->layers[w->key] && w->o->layers[w->key]->info.seq == w->seq;
}
static bool p_reply(void *a) { return ((struct reply_box *)a)->done; }
struct reqwant { struct obs *o; int n; };
static bool p_reqs(void *a) { return ((struct reqwant *)a)->o->nreqs >= ((struct reqwant *)a)->n; }
struct parwant { struct obs *o; int n; };
static bool p_probe(void *a) { return ((struct parwant *)a)->o->nprobe >= ((struct parwant *)a)->n; }
static bool p_params(void *a) { return ((struct parwant *)a)->o->nparams >= ((struct parwant *)a)->n; }
static atomic_int released;
static void release_cb(void *ctx) { atomic_fetch_add(&released, 1); }
static bool p_released(void *a) { return atomic_load(&released) >= *(int *)a; }
struct statwant { struct cl_link *l; };
static bool p_dropped_offline(void *a)
{
    struct cl_stats st;
    cl_link_stats(((struct statwant *)a)->l, &st);
    return st.layers_dropped_offline >= 1;
}

static void demand1(struct obs *o, int k1, int k2)
{
    uint8_t bits[CL_KEY_BYTES] = { 0 };
    if (k1 >= 0)
        cl_bit_set(bits, k1, true);
    if (k2 >= 0)
        cl_bit_set(bits, k2, true);
    CHECK(cl_edge_set_demand(o->link, bits) == 0, "%s: set demand", o->who);
}

static int publish(struct obs *sim, const struct gen_layer *g)
{
    return cl_sim_publish_layer(sim->link, &g->info, g->data, g->len, g->tile_off, release_cb, NULL);
}

int main(void)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    check_section = "setup";
    natsd_bin = find_nats_server();
    if (!natsd_bin) {
        CHECK(0, "nats-server not found: run `make deps` (scripts/apt-packages.txt lists it)");
        return check_done();
    }
    if (!mkdtemp(tmpdir)) {
        CHECK(0, "mkdtemp %s: %s", tmpdir, strerror(errno));
        return check_done();
    }
    atexit(cleanup);
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGABRT, on_signal);
    natsd_port = free_port();
    if (natsd_port <= 0 || !natsd_start()) {
        CHECK(0, "could not start %s on 127.0.0.1:%d (log in %s)", natsd_bin, natsd_port, tmpdir);
        return check_done();
    }
    char prefix[64];
    snprintf(prefix, sizeof prefix, "test.sea%ld", (long)getpid());

    struct obs sim = { .who = "sim" }, ea = { .who = "edge-a" }, eb = { .who = "edge-b" }, ec = { .who = "edge-c" };
    all_obs[nobs++] = &sim;
    all_obs[nobs++] = &ea;
    all_obs[nobs++] = &eb;
    all_obs[nobs++] = &ec;
    const int K1 = cl_key(0, 0, 2), K2 = cl_key(1, 1, 0), K3 = cl_key(5, 0, 0), K4 = cl_key(3, 0, 0);

    check_section = "connect";
    if (!open_link(&sim, CL_ROLE_SIM, "sim-1", prefix) || !open_link(&ea, CL_ROLE_EDGE, "edge-a", prefix) ||
        !open_link(&eb, CL_ROLE_EDGE, "edge-b", prefix))
        goto out;
    {
        char err[200];
        struct cl_config bad = { .role = CL_ROLE_EDGE, .url = "nats://127.0.0.1:1", .prefix = "a.*" };
        CHECK(cl_link_open(&bad, err, sizeof err) == NULL && strstr(err, "prefix"), "a wildcard prefix accepted");
        bad.prefix = NULL;
        bad.name = "edge 1";
        CHECK(cl_link_open(&bad, err, sizeof err) == NULL && strstr(err, "name"), "a name with a space accepted");
        bad.name = NULL;
        bad.tls_cert = "/nonexistent.pem";
        CHECK(cl_link_open(&bad, err, sizeof err) == NULL, "a certificate without key accepted");
    }
    for (int i = 0; i < 3; i++) {
        struct evwant w = { all_obs[i], CL_EV_CONNECTED, 1 };
        CHECK(spin_until(5, p_event, &w), "%s not connected", all_obs[i]->who);
        CHECK(cl_link_connected(all_obs[i]->link), "%s: cl_link_connected false", all_obs[i]->who);
    }

    check_section = "sim heartbeat";
    {
        struct evwant wa = { &ea, CL_EV_SIM_UP, 1 }, wb = { &eb, CL_EV_SIM_UP, 1 };
        CHECK(spin_until(5, p_event, &wa) && cl_link_sim_up(ea.link), "edge-a never saw the sim");
        CHECK(spin_until(5, p_event, &wb), "edge-b never saw the sim");
    }

    check_section = "demand";
    {
        uint8_t u[CL_KEY_BYTES];
        CHECK(cl_sim_demand(sim.link, u) == 0, "demand before any edge asked");
        demand1(&ea, K1, K4);
        demand1(&eb, K1, K2);
        struct demwant w = { &sim, K1, K2, 2, K3 };
        CHECK(spin_until(5, p_demand, &w), "the sim never saw both edges' demand");
        struct demwant w4 = { &sim, K4, -1, 2, -1 };
        CHECK(p_demand(&w4), "edge-a's second key missing");
    }

    check_section = "layers";
    {
        struct gen_layer g1, g2, g3;
        gen_layer_make(&g1, 64, 16, 0, 0, 2, 1, 500, 11);     /* K1, one part */
        gen_layer_make(&g2, 256, 32, 1, 1, 0, 1, 8000, 12);   /* K2, ~260 KB: split at 64 KiB */
        gen_layer_make(&g3, 64, 16, 5, 0, 0, 1, 500, 13);     /* K3: nobody wants it */
        atomic_store(&released, 0);
        CHECK(publish(&sim, &g1) == 0 && publish(&sim, &g2) == 0 && publish(&sim, &g3) == 0, "publish");
        struct laywant a1 = { &ea, K1, 1 }, b1 = { &eb, K1, 1 }, b2 = { &eb, K2, 1 };
        CHECK(spin_until(5, p_layer, &a1) && gen_layer_equal(&g1, ea.layers[K1]), "edge-a: K1 missing or differs");
        CHECK(spin_until(5, p_layer, &b1) && gen_layer_equal(&g1, eb.layers[K1]), "edge-b: K1 missing or differs");
        CHECK(spin_until(5, p_layer, &b2) && gen_layer_equal(&g2, eb.layers[K2]), "edge-b: K2 (split) missing or differs");
        int three = 3;
        CHECK(spin_until(5, p_released, &three), "release called %d times, want 3", atomic_load(&released));
        spin_until(0.3, NULL, NULL); /* anything stray would have arrived by now */
        CHECK(!ea.layers[K2] && !ea.layers[K3] && !eb.layers[K3], "a layer reached an edge that did not ask for it");
        /* K2 goes in as many parts as the server's max_payload (64 KiB here) needs */
        int k2_parts = 0;
        for (int first = 0; first < 64; k2_parts++)
            first += cl_layer_part_tiles(g2.tile_off, first, 64, 65536);
        struct cl_stats st;
        cl_link_stats(sim.link, &st);
        CHECK(k2_parts >= 4 && st.layers_published == 3 && st.parts_published == 2 + (uint64_t)k2_parts,
              "sim published %llu layers in %llu parts: want 3 layers, K2 in %d parts",
              (unsigned long long)st.layers_published, (unsigned long long)st.parts_published, k2_parts);
        cl_link_stats(eb.link, &st);
        CHECK(st.layers_received == 2 && st.bad_messages == 0 && st.layers_dropped_incomplete == 0,
              "edge-b stats: %llu layers, %llu bad, %llu incomplete", (unsigned long long)st.layers_received,
              (unsigned long long)st.bad_messages, (unsigned long long)st.layers_dropped_incomplete);
        gen_layer_free(&g1);
        gen_layer_free(&g2);
        gen_layer_free(&g3);
    }

    check_section = "request/reply";
    {
        const char *set = "{\"type\":\"set\",\"id\":5,\"params\":{\"wind_speed\":14}}";
        struct reply_box ra = { 0 }, rb = { 0 };
        CHECK(cl_edge_request(ea.link, CL_KIND_CTL, "c7", set, strlen(set), h_reply, &ra) == 0, "request");
        struct reqwant w = { &sim, 1 };
        CHECK(spin_until(5, p_reqs, &w), "the sim got no request");
        if (sim.nreqs >= 1) {
            struct cl_request *r = sim.reqs[0];
            CHECK(r->kind == CL_KIND_CTL && strcmp(r->origin, "edge-a") == 0 && strcmp(r->by, "c7") == 0 &&
                  r->len == strlen(set) && strcmp(r->body, set) == 0, "request as received: %s %s %s", r->origin,
                  r->by, r->body);
            /* answered later, as a set is answered when the tick applies it */
            spin_until(0.2, NULL, NULL);
            CHECK(!ra.done, "a reply arrived before the sim answered");
            const char *ans = "{\"type\":\"params\",\"id\":5,\"params_version\":2}";
            cl_request_reply(sim.link, r, ans, strlen(ans));
            sim.nreqs = 0;
            CHECK(spin_until(5, p_reply, &ra) && ra.status == 0 && strcmp(ra.text, ans) == 0,
                  "edge-a reply: status %d text %s", ra.status, ra.text);
        }
        CHECK(cl_edge_request(eb.link, CL_KIND_HELLO, "c1", NULL, 0, h_reply, &rb) == 0, "hello request");
        struct reqwant w2 = { &sim, 1 };
        CHECK(spin_until(5, p_reqs, &w2) && sim.reqs[0]->kind == CL_KIND_HELLO && sim.reqs[0]->len == 0,
              "the sim got no hello");
        if (sim.nreqs >= 1) {
            const char *hello = "{\"type\":\"hello\",\"params_version\":2}";
            cl_request_reply(sim.link, sim.reqs[0], hello, strlen(hello));
            sim.nreqs = 0;
            CHECK(spin_until(5, p_reply, &rb) && rb.status == 0 && strcmp(rb.text, hello) == 0, "hello reply: %s",
                  rb.text);
        }
        CHECK(cl_edge_request(ea.link, CL_KIND_REPLY, "c1", "x", 1, h_reply, &rb) == CL_E_ARG,
              "a request of kind reply accepted");
        /* a query and a probe go to their own subjects; probe_data then streams to the
         * edge that asked (its inbox + ".p"), for the client it names, and to no other edge */
        const char *q = "{\"type\":\"query\",\"id\":3,\"points\":[[1,2]]}";
        const char *pr = "{\"type\":\"probe\",\"id\":4,\"points\":[[0,0]]}";
        struct reply_box rq = { 0 }, rp = { 0 };
        CHECK(cl_edge_request(ea.link, CL_KIND_QUERY, "c8", q, strlen(q), h_reply, &rq) == 0, "query request");
        CHECK(cl_edge_request(ea.link, CL_KIND_PROBE, "c9", pr, strlen(pr), h_reply, &rp) == 0, "probe request");
        struct reqwant w3 = { &sim, 2 };
        CHECK(spin_until(5, p_reqs, &w3), "the sim got %d of the query and the probe", sim.nreqs);
        if (sim.nreqs >= 2) {
            struct cl_request *a = sim.reqs[0], *b = sim.reqs[1];
            CHECK(a->kind == CL_KIND_QUERY && strcmp(a->by, "c8") == 0 && strcmp(a->body, q) == 0, "query as received");
            CHECK(b->kind == CL_KIND_PROBE && strcmp(b->by, "c9") == 0 && strcmp(b->body, pr) == 0, "probe as received");
            char stream[CL_SUBJECT_MAX];
            CHECK(cl_probe_stream_subject(b->reply_to, stream, sizeof stream) == 0, "stream subject of %s", b->reply_to);
            const char *qr = "{\"type\":\"query_result\"}", *pg = "{\"type\":\"probing\"}";
            cl_request_reply(sim.link, a, qr, strlen(qr));
            cl_request_reply(sim.link, b, pg, strlen(pg));
            sim.nreqs = 0;
            CHECK(spin_until(5, p_reply, &rq) && rq.status == 0 && strcmp(rq.text, qr) == 0,
                  "query reply: %s", rq.text);
            CHECK(spin_until(5, p_reply, &rp) && rp.status == 0 && strcmp(rp.text, pg) == 0, "probe reply: %d %s",
                  rp.status, rp.text);
            const char *pd = "{\"type\":\"probe_data\",\"seq\":1}";
            CHECK(cl_sim_publish_probe_data(sim.link, stream, "c9", pd, strlen(pd)) == 0, "publish probe_data");
            CHECK(cl_sim_publish_probe_data(sim.link, stream, "", pd, strlen(pd)) == CL_E_ARG, "probe_data for nobody");
            struct parwant wp = { &ea, 1 };
            CHECK(spin_until(5, p_probe, &wp) && strcmp(ea.probe_text, pd) == 0 && strcmp(ea.probe_by, "c9") == 0,
                  "edge-a probe_data: %s for %s", ea.probe_text, ea.probe_by);
            spin_until(0.2, NULL, NULL);
            CHECK(eb.nprobe == 0, "edge-b got another edge's probe_data");
        }
    }

    check_section = "params events";
    {
        const char *p = "{\"type\":\"params\",\"params_version\":2,\"by\":\"c7\"}";
        CHECK(cl_sim_publish_params(sim.link, "edge-a", "c7", p, strlen(p)) == 0, "publish params");
        struct parwant wa = { &ea, 1 }, wb = { &eb, 1 };
        CHECK(spin_until(5, p_params, &wa) && strcmp(ea.params_text, p) == 0 && strcmp(ea.params_origin, "edge-a") == 0 &&
              strcmp(ea.params_by, "c7") == 0, "edge-a params: %s from %s/%s", ea.params_text, ea.params_origin,
              ea.params_by);
        CHECK(spin_until(5, p_params, &wb) && strcmp(eb.params_text, p) == 0, "edge-b params: %s", eb.params_text);
    }

    check_section = "demand goodbye and expiry";
    {
        demand1(&ea, -1, -1); /* edge-a's viewers left: it says so at once */
        struct demwant w = { &sim, K1, K2, 1, K4 };
        CHECK(spin_until(0.9, p_demand, &w), "edge-a's empty demand did not remove it before its expiry");
        close_link(&eb); /* edge-b dies without a word */
        uint8_t u[CL_KEY_BYTES];
        CHECK(cl_sim_demand(sim.link, u) == 1 && cl_bit(u, K2), "edge-b forgotten before its expiry");
        struct demwant gone = { &sim, -1, -1, 0, K2 };
        CHECK(spin_until(5, p_demand, &gone), "edge-b's demand never expired");
    }

    check_section = "nats-server killed";
    {
        natsd_kill(SIGKILL);
        struct evwant ws = { &sim, CL_EV_DISCONNECTED, 1 }, wa = { &ea, CL_EV_DISCONNECTED, 1 };
        CHECK(spin_until(10, p_event, &ws), "sim did not notice NATS going away");
        CHECK(spin_until(10, p_event, &wa), "edge-a did not notice NATS going away");
        CHECK(!cl_link_connected(ea.link), "edge-a says connected");
        /* the tick goes on: layers are dropped and released, never queued for later */
        struct gen_layer g;
        gen_layer_make(&g, 64, 16, 0, 0, 2, 5, 500, 21);
        atomic_store(&released, 0);
        CHECK(publish(&sim, &g) == 0, "publish while NATS is down");
        struct statwant sw = { sim.link };
        int one = 1;
        CHECK(spin_until(5, p_dropped_offline, &sw) && spin_until(5, p_released, &one),
              "a layer published while NATS was down was not dropped and released");
        gen_layer_free(&g);
        struct reply_box r = { 0 };
        CHECK(cl_edge_request(ea.link, CL_KIND_CTL, "c7", "{}", 2, h_reply, &r) == 0, "request while down");
        CHECK(spin_until(5, p_reply, &r) && r.status == CL_E_NOT_CONNECTED, "request while NATS down: status %d",
              r.status);
        /* an edge started while NATS is down comes up by itself later */
        CHECK(open_link(&ec, CL_ROLE_EDGE, "edge-c", prefix) != NULL, "edge-c open while NATS is down");
        spin_until(0.3, NULL, NULL);
        CHECK(ec.ev[CL_EV_CONNECTED] == 0, "edge-c connected to nothing");
    }

    check_section = "nats-server restarted";
    if (!natsd_start()) {
        CHECK(0, "could not restart nats-server on port %d", natsd_port);
        goto out;
    }
    {
        struct evwant ws = { &sim, CL_EV_RECONNECTED, 1 }, wa = { &ea, CL_EV_RECONNECTED, 1 },
                      wc = { &ec, CL_EV_CONNECTED, 1 };
        CHECK(spin_until(10, p_event, &ws), "sim did not reconnect");
        CHECK(spin_until(10, p_event, &wa), "edge-a did not reconnect");
        CHECK(spin_until(10, p_event, &wc), "edge-c did not connect after NATS came up");
        demand1(&ea, K1, -1);
        demand1(&ec, K2, -1);
        struct demwant w = { &sim, K1, K2, 2, -1 };
        CHECK(spin_until(5, p_demand, &w), "demand not back after the restart");
        struct gen_layer g1, g2;
        gen_layer_make(&g1, 64, 16, 0, 0, 2, 10, 500, 31);
        gen_layer_make(&g2, 256, 32, 1, 1, 0, 10, 8000, 32);
        publish(&sim, &g1);
        publish(&sim, &g2);
        struct laywant a1 = { &ea, K1, 10 }, c2 = { &ec, K2, 10 };
        CHECK(spin_until(5, p_layer, &a1) && gen_layer_equal(&g1, ea.layers[K1]), "edge-a: no layer after restart");
        CHECK(spin_until(5, p_layer, &c2) && gen_layer_equal(&g2, ec.layers[K2]), "edge-c: no layer after restart");
        gen_layer_free(&g1);
        gen_layer_free(&g2);
        struct reply_box r = { 0 };
        cl_edge_request(ec.link, CL_KIND_HELLO, "c2", NULL, 0, h_reply, &r);
        struct reqwant rq = { &sim, 1 };
        if (spin_until(5, p_reqs, &rq)) {
            cl_request_reply(sim.link, sim.reqs[0], "{}", 2);
            sim.nreqs = 0;
        }
        CHECK(spin_until(5, p_reply, &r) && r.status == 0, "request/reply after restart: status %d", r.status);
    }

    check_section = "sim down and back";
    {
        /* counted from here: a slow NATS restart above may have shown edge-a a
         * sim_down and sim_up already */
        int downs = ea.ev[CL_EV_SIM_DOWN], ups = ea.ev[CL_EV_SIM_UP];
        close_link(&sim);
        struct evwant wa = { &ea, CL_EV_SIM_DOWN, downs + 1 };
        CHECK(spin_until(5, p_event, &wa) && !cl_link_sim_up(ea.link), "edge-a never saw the sim go");
        struct reply_box r = { 0 };
        cl_edge_request(ea.link, CL_KIND_CTL, "c7", "{}", 2, h_reply, &r);
        CHECK(spin_until(5, p_reply, &r) && r.status == CL_E_NO_RESPONDERS, "request with no sim: status %d (%s)",
              r.status, cl_strerror(r.status));
        memset(sim.ev, 0, sizeof sim.ev);
        if (open_link(&sim, CL_ROLE_SIM, "sim-2", prefix)) {
            struct evwant up = { &ea, CL_EV_SIM_UP, ups + 1 };
            CHECK(spin_until(5, p_event, &up), "edge-a never saw the new sim");
            /* the edges repeat their demand at once for a new sim */
            struct demwant w = { &sim, K1, K2, 2, -1 };
            CHECK(spin_until(1.0, p_demand, &w), "the new sim did not get the edges' demand within a second");
        }
        /* Another sim process under the same name within the edges' 2 s
         * detection: its heartbeat's instance id differs, so the edges hear
         * of it (sim_new: ask hello again) without a sim_down in between. */
        int news = ea.ev[CL_EV_SIM_NEW], downs2 = ea.ev[CL_EV_SIM_DOWN];
        if (sim.link) {
            close_link(&sim);
            if (open_link(&sim, CL_ROLE_SIM, "sim-2", prefix)) {
                struct evwant nw = { &ea, CL_EV_SIM_NEW, news + 1 };
                CHECK(spin_until(3, p_event, &nw), "edge-a never saw the new sim instance");
                CHECK(ea.ev[CL_EV_SIM_DOWN] == downs2, "edge-a saw a sim_down for a quick restart");
                /* A standby sends no heartbeat: the edges see no sim. */
                cl_sim_set_standby(sim.link, true);
                struct evwant dw = { &ea, CL_EV_SIM_DOWN, downs2 + 1 };
                CHECK(spin_until(5, p_event, &dw), "a standby's heartbeats kept the sim up at edge-a");
                /* ...and takes no request: nobody answers, at once */
                struct reply_box rs = { 0 };
                cl_edge_request(ea.link, CL_KIND_CTL, "c8", "{}", 2, h_reply, &rs);
                CHECK(spin_until(5, p_reply, &rs) && rs.status == CL_E_NO_RESPONDERS,
                      "request to a standby: status %d (%s)", rs.status, cl_strerror(rs.status));
                int ups2 = ea.ev[CL_EV_SIM_UP];
                cl_sim_set_standby(sim.link, false);
                struct evwant uw = { &ea, CL_EV_SIM_UP, ups2 + 1 };
                CHECK(spin_until(3, p_event, &uw), "edge-a did not see the sim acting again");
            }
        }
    }

    check_section = "TLS";
    for (int i = 0; i < nobs; i++)
        if (all_obs[i]->link)
            close_link(all_obs[i]);
    natsd_kill(SIGTERM);
    {
        /* a self-signed certificate for 127.0.0.1; the links trust exactly it */
        char cmd[1200], ca[300];
        snprintf(cmd, sizeof cmd,
                 "openssl req -x509 -newkey rsa:2048 -nodes -days 1 -subj /CN=127.0.0.1 "
                 "-addext subjectAltName=IP:127.0.0.1 -keyout '%s/key.pem' -out '%s/cert.pem' >/dev/null 2>&1",
                 tmpdir, tmpdir);
        snprintf(ca, sizeof ca, "%s/cert.pem", tmpdir);
        natsd_tls = true;
        natsd_port = free_port();
        if (system(cmd) != 0 || !natsd_start()) {
            CHECK(0, "could not start nats-server with TLS");
            goto out;
        }
        struct obs ts = { .who = "tls-sim" }, te = { .who = "tls-edge" }, tp = { .who = "plain-edge" };
        all_obs[nobs++] = &ts;
        all_obs[nobs++] = &te;
        all_obs[nobs++] = &tp;
        link_tls_ca = ca;
        open_link(&ts, CL_ROLE_SIM, "sim-tls", prefix);
        open_link(&te, CL_ROLE_EDGE, "edge-tls", prefix);
        link_tls_ca = NULL;
        open_link_ex(&tp, CL_ROLE_EDGE, "edge-plain", prefix, true); /* refused now or never connects */
        struct evwant ws = { &ts, CL_EV_CONNECTED, 1 }, we = { &te, CL_EV_CONNECTED, 1 };
        CHECK(ts.link && spin_until(10, p_event, &ws), "the sim did not connect over TLS");
        CHECK(te.link && spin_until(10, p_event, &we), "the edge did not connect over TLS");
        if (ts.link && te.link) {
            demand1(&te, K1, -1);
            struct demwant w = { &ts, K1, -1, 1, -1 };
            CHECK(spin_until(5, p_demand, &w), "demand over TLS");
            struct gen_layer g;
            gen_layer_make(&g, 64, 16, 0, 0, 2, 77, 500, 41);
            publish(&ts, &g);
            struct laywant lw = { &te, K1, 77 };
            CHECK(spin_until(5, p_layer, &lw) && gen_layer_equal(&g, te.layers[K1]), "layer over TLS");
            gen_layer_free(&g);
        }
        /* a client that does not speak TLS never gets in */
        CHECK(tp.ev[CL_EV_CONNECTED] == 0 && !(tp.link && cl_link_connected(tp.link)),
              "a plain client connected to a TLS-only server");
        for (int i = 0; i < nobs; i++)
            if (all_obs[i]->link)
                close_link(all_obs[i]);
        for (int i = nobs - 3; i < nobs; i++)
            obs_free(all_obs[i]);
        nobs -= 3;
    }

out:
    check_section = "shutdown";
    for (int i = 0; i < nobs; i++)
        if (all_obs[i]->link)
            close_link(all_obs[i]);
    for (int i = 0; i < nobs; i++)
        obs_free(all_obs[i]);
    natsd_kill(SIGTERM);
    cl_library_shutdown();
    return check_done();
}

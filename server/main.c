/* main.c — oceand: read the configuration, start the simulation (tick and
 * builder threads), serve HTTP + WebSocket on this thread until SIGINT/SIGTERM;
 * the builder saves the parameters before a change is applied. Threads: docs/threads.md. */
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "config.h"
#include "log.h"
#include "net.h"
#include "query_worker.h"
#include "render_worker.h"
#include "roles.h"
#include "sim_thread.h"
#include "state.h"
#include "state_saver.h"

/* Only a flag: the sim thread wakes the service loop every tick anyway
 * (lws_cancel_service), so we see it within one period without calling
 * into lws from a signal handler. */
static volatile sig_atomic_t interrupted;

static void on_signal(int sig)
{
    (void)sig;
    interrupted = 1;
    /* Safety net: if shutdown ever hangs (say, inside lws), SIGALRM's default
     * action ends the process after 3 s instead of leaving it running. */
    alarm(3);
}

/* SIGHUP (and SIGUSR1, SIGUSR2): save the state now (a daemon's usual
 * "hang-up" duty). The configuration is read at start-up only, so it is
 * not reloaded. */
static volatile sig_atomic_t hangup;

static void on_hangup(int sig)
{
    (void)sig;
    hangup = 1;
}

/* mkdir -p of the folder that will hold path. */
static int ensure_parent_dir(const char *path)
{
    char dir[512];
    snprintf(dir, sizeof dir, "%s", path);
    char *slash = strrchr(dir, '/');
    if (!slash || slash == dir)
        return 0;
    *slash = '\0';
    for (char *p = dir + 1; *p; p++) {
        if (*p != '/')
            continue;
        *p = '\0';
        if (mkdir(dir, 0755) != 0 && errno != EEXIST)
            return -1;
        *p = '/';
    }
    return mkdir(dir, 0755) != 0 && errno != EEXIST ? -1 : 0;
}

static void install_signals(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    /* A write past RLIMIT_FSIZE (ulimit -f: the state file, the FFTW wisdom,
     * a log file) fails with EFBIG and is handled like a full disk, instead
     * of SIGXFSZ ending the process (test-hostile state_save_fsize). */
    signal(SIGXFSZ, SIG_IGN);
    /* HUP, USR1 and USR2 would end the process without saving: save instead. */
    sa.sa_handler = on_hangup;
    sigaction(SIGHUP, &sa, NULL);
    sigaction(SIGUSR1, &sa, NULL);
    sigaction(SIGUSR2, &sa, NULL);
}

/* --role edge: no simulation here; frames, hello and answers come from the
 * sim over NATS (server/roles/role_edge.c). Nothing to save: an edge is stateless. */
static int run_edge(const struct daemon_config *dc, struct net *net, struct render_service *renders)
{
    char err[512];
    struct role_edge *edge = role_edge_open(dc, net, err, sizeof err);
    if (!edge) {
        LOGE("%s", err);
        net_attach_renders(net, NULL);
        render_service_free(renders);
        net_destroy(net);
        return 1;
    }
    LOGI("oceand edge listening on %s://%s:%d/ (web root %s)", dc->tls_cert[0] ? "https" : "http", dc->bind,
         net_port(net), dc->web_root);
    while (!interrupted)
        if (net_service(net) < 0)
            break;
    LOGI("stopping");
    net_attach_renders(net, NULL);
    render_service_free(renders);
    role_edge_close(edge);
    net_destroy(net);
    LOGI("bye");
    return 0;
}

int main(int argc, char **argv)
{
    struct daemon_config dc;
    struct ocean_params params;
    struct config_result res;
    char err[512];
    if (config_load(argc, argv, &dc, &params, &res, err, sizeof err) != 0) {
        fprintf(stderr, "oceand: %s\n", err);
        return 2;
    }
    if (res.help) {
        config_usage(stdout, argv[0]);
        return 0;
    }
    log_set_level((enum log_level)dc.log_level);
    log_route_lws();
    if (res.state_loaded)
        LOGI("restored parameters from %s (version %u, t=%.2f s)", dc.state_file, res.params_version, res.sim_time);
    /* The measured sea saved with them, through the `sea` message's own check. */
    struct sea_spectrum *sea = res.state_loaded ? malloc(sizeof *sea) : NULL;
    int sea_rc = sea ? state_load_sea(dc.state_file, sea, err, sizeof err) : 0;
    if (sea_rc < 0)
        LOGW("%s: %s; starting without it", dc.state_file, err);
    if (sea_rc <= 0) {
        free(sea);
        sea = NULL;
    } else {
        LOGI("restored the measured sea %s %s", sea->source, sea->time);
    }
    if (params.spectrum == SPECTRUM_MEASURED && !sea) {
        LOGW("spectrum measured without a measured sea: starting with jonswap");
        params.spectrum = SPECTRUM_JONSWAP;
    }

    if (dc.wisdom_file[0] && ensure_parent_dir(dc.wisdom_file) != 0) {
        LOGW("no FFTW wisdom cache: cannot create the folder of %s: %s", dc.wisdom_file, strerror(errno));
        dc.wisdom_file[0] = '\0';
    }

    struct net *net = net_create(&dc, &params, res.params_version, err, sizeof err);
    if (!net) {
        LOGE("%s", err);
        free(sea);
        return 1;
    }
    install_signals();
    /* Renders need only the parameters in force: an edge serves them too. */
    struct render_config rc = {
        .workers = dc.render_workers, .budget = dc.render_budget, .max_units = dc.render_max_units,
        .nice = dc.render_nice, .tile_size = dc.tile_size, .plan_rigor = dc.plan_rigor,
        .wisdom_path = dc.wisdom_file[0] ? dc.wisdom_file : NULL, .wake = net_wake, .wake_user = net,
    };
    struct render_service *renders = render_service_new(&rc, err, sizeof err);
    if (!renders) {
        LOGE("render workers: %s", err);
        net_destroy(net);
        free(sea);
        return 1;
    }
    net_attach_renders(net, renders);
    if (strcmp(dc.role, "edge") == 0) {
        free(sea);
        return run_edge(&dc, net, renders); /* no simulation here: no point queries either */
    }
    struct query_config qc = {
        .threads = dc.query_threads, .window = dc.query_window, .budget = dc.query_budget,
        .queue = dc.query_queue, .probe_max_points = dc.probe_max_points, .probe_max_total = dc.probe_max_total,
        .wake = net_wake, .wake_user = net,
    };
    struct query_service *queries = query_service_new(&qc, err, sizeof err);
    if (!queries) {
        LOGE("point queries: %s", err);
        net_attach_renders(net, NULL);
        render_service_free(renders);
        net_destroy(net);
        free(sea);
        return 1;
    }
    struct sim_config sc = {
        .tick_rate = dc.tick_rate,
        .tile_size = dc.tile_size,
        .keyframe_interval = dc.keyframe_interval,
        .ease_ticks = dc.ease_ticks,
        .stream_budget = (size_t)dc.max_memory_mb * 1048576 / 2, /* temporal layers: half the simulation's cap */
        .opts = { .threads = dc.fft_threads, .wisdom_path = dc.wisdom_file[0] ? dc.wisdom_file : NULL,
                  .plan_rigor = dc.plan_rigor },
        .start_time = res.sim_time,
        .nice = dc.sim_nice,
        .start_version = res.params_version,
        .encode_threads = dc.encode_threads,
        .encode_budget = dc.encode_budget,
        .temporal_budget = dc.temporal_budget,
        .max_memory_mb = dc.max_memory_mb,
        .cores = (int)sysconf(_SC_NPROCESSORS_ONLN),
        .wake = net_wake,
        .wake_user = net,
        .queries = queries,
    };
    /* Durability: the builder saves each batch of sets before it is applied
     * and acknowledged (sim_config.persist); role_sim_open may add the
     * JetStream copy on top. */
    struct state_saver saver;
    state_saver_init(&saver, dc.state_file, &params, res.params_version, sea);
    sc.sea = sea;
    sc.persist = state_saver_persist;
    sc.persist_user = &saver;
    /* The floating bodies saved with the sea: all of them or none. */
    struct state_bodies saved = { 0 };
    if (res.state_loaded && state_load_bodies(dc.state_file, &saved, err, sizeof err) < 0)
        LOGW("%s: %s; starting without bodies", dc.state_file, err);
    sc.max_bodies = dc.max_bodies;
    sc.restore_next_id = saved.next_id;
    sc.nrestore = saved.n;
    struct body_state *restore = saved.n ? calloc((size_t)saved.n, sizeof *restore) : NULL;
    for (int i = 0; restore && i < saved.n; i++)
        restore[i] = saved.b[i].st;
    sc.restore = restore;
    if (!restore)
        sc.nrestore = 0;
    /* --role sim: the NATS link feeds demand in and takes frames out. */
    struct role_sim *cluster = NULL;
    if (strcmp(dc.role, "sim") == 0 && !(cluster = role_sim_open(&dc, net, &sc, err, sizeof err))) {
        LOGE("%s", err);
        free(restore);
        state_bodies_free(&saved);
        query_service_free(queries);
        net_attach_renders(net, NULL);
        render_service_free(renders);
        net_destroy(net);
        state_saver_destroy(&saver);
        free(sea);
        return 1;
    }
    struct sim *sim = sim_start(&params, &sc, err, sizeof err);
    if (!sim) {
        free(sea);
        free(restore);
        state_bodies_free(&saved);
        LOGE("simulation: %s", err);
        query_service_free(queries);
        role_sim_close(cluster);
        net_attach_renders(net, NULL);
        render_service_free(renders);
        net_destroy(net);
        state_saver_destroy(&saver);
        return 1;
    }
    free(restore); /* sim_start copied them */
    if (saved.n && sim_bodies_restored(sim) == saved.n) {
        net_bodies_restore(net, &saved);
        state_saver_set_bodies(&saver, &saved);
        LOGI("restored %d floating bodies", saved.n);
    }
    state_bodies_free(&saved);
    net_attach_saver(net, &saver);
    net_attach_sim(net, sim);
    net_attach_queries(net, queries);
    int attached = role_sim_attach(cluster, sim, &params, res.params_version, sea);
    free(sea); /* sim_start, the saver and the lease copied it */
    sea = NULL;
    if (attached != 0)
        LOGW("cluster: no lease thread: this simulation stays a standby");

    LOGI("oceand listening on %s://%s:%d/ (N=%d, %g Hz, web root %s)", dc.tls_cert[0] ? "https" : "http", dc.bind, net_port(net),
         params.resolution, dc.tick_rate, dc.web_root);
    while (!interrupted) {
        if (net_service(net) < 0)
            break;
        if (hangup) { /* the builder saves: no fsync on this thread */
            hangup = 0;
            LOGI("SIGHUP/SIGUSR1/SIGUSR2: saving the state; the configuration is not reloaded (restart to apply it)");
            sim_save_now(sim);
        }
    }

    LOGI("stopping");
    role_sim_detach(cluster); /* releases the lease: a standby takes over at once */
    state_saver_final(&saver, sim_time_now(sim));
    sim_stop(sim);
    net_attach_queries(net, NULL);
    query_service_free(queries); /* after the tick: it no longer hands over grids */
    net_attach_sim(net, NULL);
    net_attach_renders(net, NULL);
    render_service_free(renders); /* a render in progress ends where it is */
    role_sim_close(cluster); /* after the tick (it publishes), before net (it holds requests) */
    net_destroy(net);
    state_saver_destroy(&saver);
    LOGI("bye");
    return 0;
}

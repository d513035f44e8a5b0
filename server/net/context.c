/* context.c — the lws context: protocol table, HTTP mounts, listening
 * socket, TLS; and the network side's lifecycle. */
#include "net_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>

#include "frame.h"
#include "sim_thread.h"
#include "log.h"

#define NET_BEAT_MS 200
static void net_beat(lws_sorted_usec_list_t *sul)
{
    struct net *n = lws_container_of(sul, struct net, beat);
    lws_sul_schedule(n->ctx, 0, &n->beat, net_beat, NET_BEAT_MS * LWS_US_PER_MS);
}

struct net *net_create(const struct daemon_config *dc, const struct ocean_params *p, uint32_t version,
                       char *err, size_t errlen)
{
    struct net *n = calloc(1, sizeof *n);
    if (!n) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    n->dc = *dc;
    n->lim.tick_rate = dc->tick_rate;
    n->lim.max_memory_mb = dc->max_memory_mb;
    n->view = n->applied = *p;
    n->applied_version = version;
    net_instance_tag(n->instance_tag, sizeof n->instance_tag);

    /* [0] plain HTTP (and refusal of WebSockets without our subprotocol),
     * [1] oceand.v1. The sim's wake-up is handled in [1] (session.c). */
    n->protocols[0] = (struct lws_protocols){ .name = "http", .callback = cb_http,
                                              .per_session_data_size = sizeof(struct http_session) };
    n->protocols[1] = (struct lws_protocols){ .name = OC_SUBPROTOCOL, .callback = cb_ws,
                                              .per_session_data_size = sizeof(struct session),
                                              .rx_buffer_size = 4096,
                                              /* else lws sends rx_buffer_size bytes per POLLOUT */
                                              .tx_packet_size = CHUNK_SIZE };

    char index[600];
    struct stat st;
    snprintf(index, sizeof index, "%s/index.html", dc->web_root);
    n->placeholder = stat(index, &st) != 0;
    if (n->placeholder)
        LOGW("no %s: serving a placeholder page at /", index);
    n->m_metrics = (struct lws_http_mount){ .mountpoint = "/metrics", .mountpoint_len = 8, .protocol = "http",
                                            .origin_protocol = LWSMPRO_CALLBACK };
    n->m_health = (struct lws_http_mount){ .mount_next = &n->m_metrics, .mountpoint = "/healthz", .mountpoint_len = 8,
                                           .protocol = "http", .origin_protocol = LWSMPRO_CALLBACK };
    if (n->placeholder)
        n->m_files = (struct lws_http_mount){ .mount_next = &n->m_health, .mountpoint = "/", .mountpoint_len = 1,
                                              .protocol = "http", .origin_protocol = LWSMPRO_CALLBACK };
    else
        n->m_files = (struct lws_http_mount){ .mount_next = &n->m_health, .mountpoint = "/", .mountpoint_len = 1,
                                              .origin = n->dc.web_root, .def = "index.html",
                                              .origin_protocol = LWSMPRO_FILE };

    /* A reserve of descriptors for the daemon's own files (state, wisdom,
     * static files being served) and for lws: connections that would take
     * one of the last ones are closed at accept (http.c, filter_accept). */
    struct rlimit rl;
    n->fd_limit = getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur < (1u << 30) ? (int)rl.rlim_cur : 1 << 30;
    n->fd_ceiling = n->fd_limit - (FD_RESERVE_MIN + n->fd_limit / 64);
    if (n->fd_ceiling < 8)
        n->fd_ceiling = 8;

    n->retry.secs_since_valid_ping = (uint16_t)dc->ping_interval;
    n->retry.secs_since_valid_hangup = (uint16_t)dc->idle_timeout;

    struct lws_context_creation_info info;
    memset(&info, 0, sizeof info);
    info.port = dc->port;
    info.iface = dc->bind;
    info.protocols = n->protocols;
    info.mounts = &n->m_files;
    info.user = n;
    info.retry_and_idle_policy = &n->retry;
    info.options = LWS_SERVER_OPTION_DISABLE_IPV6 | LWS_SERVER_OPTION_VALIDATE_UTF8;
    if (dc->tls_cert[0]) {
        /* https/wss on the same port (lws' OpenSSL backend). Plain http/ws
         * connections to it fail the TLS handshake: no
         * LWS_SERVER_OPTION_ALLOW_NON_SSL_ON_SSL_PORT. */
        info.options |= LWS_SERVER_OPTION_DO_SSL_GLOBAL_INIT;
        info.ssl_cert_filepath = n->dc.tls_cert;
        info.ssl_private_key_filepath = n->dc.tls_key;
    }
    info.extensions = NULL; /* no permessage-deflate: frames are compressed already */
    info.timeout_secs = 10;
    info.pt_serv_buf_size = CHUNK_SIZE + LWS_PRE + 64; /* lws' scratch for partial sends and reads */
    n->ctx = lws_create_context(&info);
    if (!n->ctx) {
        if (dc->tls_cert[0])
            snprintf(err, errlen, "cannot listen on %s:%d with TLS (port in use, bad --bind, or unreadable / "
                     "mismatched --tls-cert %s / --tls-key %s?)", dc->bind, dc->port, dc->tls_cert, dc->tls_key);
        else
            snprintf(err, errlen, "cannot listen on %s:%d (in use, or bad --bind?)", dc->bind, dc->port);
        free(n);
        return NULL;
    }
    /* The tick wakes this loop every period (lws_cancel_service), but an edge
     * with no viewer and a sim with no edge may get nothing for seconds, and
     * main's loop sees SIGTERM's flag only when lws_service returns. */
    lws_sul_schedule(n->ctx, 0, &n->beat, net_beat, NET_BEAT_MS * LWS_US_PER_MS);
    if (!dc->tls_cert[0])
        rx_guard_start(); /* this thread is the service thread (net_service) */
    struct lws_vhost *vh = lws_get_vhost_by_name(n->ctx, "default");
    n->port = vh ? lws_get_vhost_listen_port(vh) : dc->port;
    return n;
}

void net_attach_sim(struct net *n, struct sim *s)
{
    n->sim = s;
    if (s) { /* the sea a restart put back */
        free(n->sea_summary);
        n->sea_summary = sim_sea_summary(s);
    }
}
void net_attach_queries(struct net *n, struct query_service *q) { n->queries = q; }
void net_attach_renders(struct net *n, struct render_service *r) { n->renders = r; }

void net_on_params(struct net *n, net_params_fn fn, void *user)
{
    n->on_params = fn;
    n->on_params_user = user;
}

void net_wake(void *net) { lws_cancel_service(((struct net *)net)->ctx); }
int net_service(struct net *n) { return lws_service(n->ctx, 0); }
int net_port(const struct net *n) { return n->port; }

void net_destroy(struct net *n)
{
    if (!n)
        return;
    lws_context_destroy(n->ctx); /* closes every client: CLOSED frees sessions */
    rx_guard_stop();
    fanout_free_ring(n);
    frame_unref(n->latest);
    dispatch_free_requests(n);
    body_net_free(n);
    free(n->status_text);
    free(n->sea_summary);
    cJSON_Delete(n->sim_capacity);
    free(n);
}

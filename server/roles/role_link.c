/* role_link.c — the NATS link's options and counters for both cluster roles. */
#include "role_link.h"

#include <cjson/cJSON.h>
#include <stdio.h>
#include <string.h>

#include "ocean.h"

static const char *opt(const char *s) { return s[0] ? s : NULL; }

void role_link_config(const struct daemon_config *dc, enum cl_role role, struct cl_config *cfg)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->role = role;
    cfg->url = dc->nats_url;
    cfg->prefix = opt(dc->nats_prefix);
    cfg->name = opt(dc->nats_name);
    cfg->creds_file = opt(dc->nats_creds);
    cfg->tls_ca = opt(dc->nats_tls_ca);
    cfg->tls_cert = opt(dc->nats_tls_cert);
    cfg->tls_key = opt(dc->nats_tls_key);
}

size_t role_link_metrics(struct cl_link *l, char *buf, size_t cap)
{
    struct cl_stats st;
    cl_link_stats(l, &st);
    const struct { const char *name, *help; uint64_t v; } c[] = {
        { "layers_published", "layers the sim published on NATS", st.layers_published },
        { "bytes_published", "bytes of layer parts published", st.bytes_published },
        { "layers_dropped_outbox", "layers dropped: outbox full (latest wins)", st.layers_dropped_outbox },
        { "layers_dropped_offline", "layers dropped: NATS not connected", st.layers_dropped_offline },
        { "layers_too_large", "layers with a tile over NATS max_payload", st.layers_too_large },
        { "layers_received", "complete layers received", st.layers_received },
        { "layers_dropped_incomplete", "layers lost while being reassembled", st.layers_dropped_incomplete },
        { "layers_dropped_inbox", "layers superseded before the daemon took them", st.layers_dropped_inbox },
        { "bad_messages", "NATS messages that failed to parse", st.bad_messages },
        { "requests_sent", "control and hello requests sent to the sim", st.requests_sent },
        { "request_timeouts", "requests without a reply in time", st.request_timeouts },
        { "no_responders", "requests nobody served (sim down)", st.no_responders },
        { "requests_received", "requests received from edges", st.requests_received },
        { "disconnects", "NATS connection losses", st.disconnects },
        { "reconnects", "NATS reconnections", st.reconnects },
    };
    size_t off = 0;
    for (size_t i = 0; i < sizeof c / sizeof c[0] && off < cap; i++)
        off += (size_t)snprintf(buf + off, cap - off, "# HELP oceand_cluster_%s_total %s\n# TYPE oceand_cluster_%s_total counter\n"
                                "oceand_cluster_%s_total %llu\n", c[i].name, c[i].help, c[i].name, c[i].name,
                                (unsigned long long)c[i].v);
    if (off < cap)
        off += (size_t)snprintf(buf + off, cap - off, "# TYPE oceand_cluster_connected gauge\noceand_cluster_connected %d\n"
                                "# TYPE oceand_cluster_edges gauge\noceand_cluster_edges %d\n",
                                cl_link_connected(l) ? 1 : 0, st.demand_edges);
    return off < cap ? off : (cap ? cap - 1 : 0);
}

void role_keys_json(const uint8_t bits[CL_KEY_BYTES], cJSON *obj) { role_keys_json_as(bits, obj, "layers"); }

void role_keys_json_as(const uint8_t bits[CL_KEY_BYTES], cJSON *obj, const char *member)
{
    cJSON *a = cJSON_AddArrayToObject(obj, member);
    for (int k = 0; a && k < CL_KEYS; k++)
        if (cl_bit(bits, k)) {
            char name[64];
            snprintf(name, sizeof name, "%s%.0d%s%s.%d.%d", layer_key_which_cascade(k) ? "c" : "",
                     layer_key_which_cascade(k), layer_key_which_cascade(k) ? "." : "",
                     ocean_field_name((enum ocean_field)layer_key_field(k)), layer_key_lod(k), layer_key_bound(k));
            cJSON_AddItemToArray(a, cJSON_CreateString(name));
        }
}

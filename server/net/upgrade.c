/* upgrade.c — who may open an oceand.v1 WebSocket: the client count limit
 * and the Origin check (browsers' users are protected from foreign pages;
 * programs send no Origin). Checks on the upgrade request go here. */
#include "net_internal.h"

#include <stdio.h>
#include <string.h>

#include "log.h"
#include "metrics.h"

static bool origin_allowed(struct net *n, struct lws *wsi)
{
    char origin[256], host[256];
    if (strcmp(n->dc.allowed_origins, "*") == 0)
        return true;
    if (lws_hdr_copy(wsi, origin, sizeof origin, WSI_TOKEN_ORIGIN) <= 0)
        return true; /* not a browser: the Origin check protects browsers' users */
    if (n->dc.allowed_origins[0] == 0) {
        if (lws_hdr_copy(wsi, host, sizeof host, WSI_TOKEN_HOST) <= 0)
            return false;
        const char *o = strstr(origin, "://");
        return o && strcmp(o + 3, host) == 0;
    }
    char list[sizeof n->dc.allowed_origins];
    snprintf(list, sizeof list, "%s", n->dc.allowed_origins);
    char *save = NULL;
    for (char *tok = strtok_r(list, ", ", &save); tok; tok = strtok_r(NULL, ", ", &save))
        if (strcmp(tok, origin) == 0)
            return true;
    return false;
}

bool upgrade_allowed(struct net *n, struct lws *wsi)
{
    if (n->cluster.no_viewers)
        return false; /* --role sim: viewers connect to edges */
    if ((int)n->sessions.count >= n->dc.max_clients) {
        atomic_fetch_add(&g_metrics.rejected_full, 1);
        LOGW("refusing a client: already %d (--max-clients)", (int)n->sessions.count);
        return false;
    }
    if (!origin_allowed(n, wsi)) {
        atomic_fetch_add(&g_metrics.rejected_origin, 1);
        LOGW("refusing a client: Origin not allowed");
        return false;
    }
    return true;
}

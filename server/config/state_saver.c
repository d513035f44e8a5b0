/* state_saver.c — the state file as the sim's persist hook (see state_saver.h). */
#include "state_saver.h"

#include <stdlib.h>
#include <string.h>

#include "log.h"
#include "state.h"

static void keep_sea(struct state_saver *sv, const struct sea_spectrum *sea);

void state_saver_init(struct state_saver *sv, const char *path, const struct ocean_params *p, uint32_t version,
                      const struct sea_spectrum *sea)
{
    sv->path = path;
    pthread_mutex_init(&sv->lock, NULL);
    sv->bodies = (struct state_bodies){ 0 };
    sv->sea = NULL;
    keep_sea(sv, sea);
    sv->params = *p;
    sv->version = version;
}

void state_saver_destroy(struct state_saver *sv)
{
    state_bodies_free(&sv->bodies);
    free(sv->sea);
    pthread_mutex_destroy(&sv->lock);
}

void state_saver_set_bodies(struct state_saver *sv, const struct state_bodies *b)
{
    pthread_mutex_lock(&sv->lock);
    if (state_bodies_copy(&sv->bodies, b) != 0)
        LOGW("bodies: out of memory keeping them for the state file (the last copy is saved)");
    pthread_mutex_unlock(&sv->lock);
}

/* The sea for the final save: a copy of what was saved last (once per new sea). */
static void keep_sea(struct state_saver *sv, const struct sea_spectrum *sea)
{
    if (!sea) {
        free(sv->sea);
        sv->sea = NULL;
        return;
    }
    if (sv->sea && memcmp(sv->sea, sea, sizeof *sea) == 0)
        return;
    struct sea_spectrum *c = sv->sea ? sv->sea : malloc(sizeof *c);
    if (!c) { /* the final save then keeps the sea of the file it overwrites: none */
        LOGW("measured sea: out of memory keeping it for the final save");
        return;
    }
    *c = *sea;
    sv->sea = c;
}

int state_saver_persist(void *saver, const struct ocean_params *p, uint32_t version, double sim_time,
                        const struct sea_spectrum *sea, char *err, size_t errlen)
{
    struct state_saver *sv = saver;
    pthread_mutex_lock(&sv->lock);
    int rc = sv->path[0] ? state_save(sv->path, p, version, sim_time, &sv->bodies, sea, err, errlen) : 0;
    if (rc == 0) {
        keep_sea(sv, sea);
        sv->params = *p;
        sv->version = version;
    }
    pthread_mutex_unlock(&sv->lock);
    return rc;
}

void state_saver_final(struct state_saver *sv, double sim_time)
{
    char err[300];
    pthread_mutex_lock(&sv->lock); /* held throughout: a save the builder makes meanwhile is newer */
    if (sv->path[0] && state_save(sv->path, &sv->params, sv->version, sim_time, &sv->bodies, sv->sea, err,
                                    sizeof err) != 0)
        LOGW("%s", err);
    pthread_mutex_unlock(&sv->lock);
}

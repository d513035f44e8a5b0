/* state_saver.c — the state file as the sim's persist hook (see state_saver.h). */
#include "state_saver.h"

#include "log.h"
#include "state.h"

void state_saver_init(struct state_saver *sv, const char *path, const struct ocean_params *p, uint32_t version)
{
    sv->path = path;
    pthread_mutex_init(&sv->lock, NULL);
    sv->bodies = (struct state_bodies){ 0 };
    sv->params = *p;
    sv->version = version;
}

void state_saver_destroy(struct state_saver *sv)
{
    state_bodies_free(&sv->bodies);
    pthread_mutex_destroy(&sv->lock);
}

void state_saver_set_bodies(struct state_saver *sv, const struct state_bodies *b)
{
    pthread_mutex_lock(&sv->lock);
    if (state_bodies_copy(&sv->bodies, b) != 0)
        LOGW("bodies: out of memory keeping them for the state file (the last copy is saved)");
    pthread_mutex_unlock(&sv->lock);
}

int state_saver_persist(void *saver, const struct ocean_params *p, uint32_t version, double sim_time, char *err,
                        size_t errlen)
{
    struct state_saver *sv = saver;
    pthread_mutex_lock(&sv->lock);
    int rc = sv->path[0] ? state_save(sv->path, p, version, sim_time, &sv->bodies, err, errlen) : 0;
    if (rc == 0) {
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
    if (sv->path[0] && state_save(sv->path, &sv->params, sv->version, sim_time, &sv->bodies, err, sizeof err) != 0)
        LOGW("%s", err);
    pthread_mutex_unlock(&sv->lock);
}

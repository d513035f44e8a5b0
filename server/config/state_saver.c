/* state_saver.c — save the parameters when they change (see state_saver.h). */
#include "state_saver.h"

#include "clock.h"

#include "log.h"
#include "state.h"

void state_saver_init(struct state_saver *sv, const char *path, const struct ocean_params *p, uint32_t version)
{
    sv->path = path;
    sv->params = *p;
    sv->version = version;
    sv->dirty = false;
    sv->saved_t = mono_now();
}

void state_saver_on_params(void *saver, const struct ocean_params *p, uint32_t version)
{
    struct state_saver *sv = saver;
    sv->params = *p;
    sv->version = version;
    sv->dirty = true;
}

void state_saver_flush(struct state_saver *sv, double sim_time, bool force)
{
    if (!sv->path[0] || !(force || (sv->dirty && mono_now() - sv->saved_t >= 1.0)))
        return;
    char err[300];
    if (state_save(sv->path, &sv->params, sv->version, sim_time, err, sizeof err) != 0)
        LOGW("%s", err);
    sv->dirty = false;
    sv->saved_t = mono_now();
}

/* ocean_fftw.c — process-wide FFTW setup.
 *
 * FFTW's planner and wisdom are global to the process. fftwf_init_threads
 * runs once (pthread_once); fftwf_make_planner_thread_safe lets a daemon
 * plan a new N on one thread while another executes; our own lock also
 * covers fftwf_plan_with_nthreads (a planner-wide setting) and the wisdom
 * import/export, so two oceans planning at once cannot mix them up. */
#include <pthread.h>

#include "ocean_internal.h"

static pthread_once_t init_once = PTHREAD_ONCE_INIT;
static pthread_mutex_t planner_lock = PTHREAD_MUTEX_INITIALIZER;

static void init(void)
{
    fftwf_init_threads();
    fftwf_make_planner_thread_safe();
}

void ocean_fftw_init(void)
{
    pthread_once(&init_once, init);
}

void ocean_fftw_lock(void)
{
    pthread_mutex_lock(&planner_lock);
}

void ocean_fftw_unlock(void)
{
    pthread_mutex_unlock(&planner_lock);
}

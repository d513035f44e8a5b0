/* render_worker.h — exact-time frames for bakes (PROTOCOL.md §7.5), off the
 * tick and lws threads.
 *
 * A `render` asks for K frames at sim times start + k/fps. The sea is a
 * function of (parameters, time), so a render worker thread renders them on
 * a simulation of its own (struct ocean, made from the parameters in force
 * when the request arrived, with one FFT thread), steps it at each time,
 * encodes the asked layers intra (codec 0 or 1) into whole frames and hands
 * them to the lws thread through a locked list and a wake-up, like the query
 * workers. The live tick never waits for a render and shares nothing with
 * it: the workers run at a lower priority (nice), all renders together are
 * paced to --render-budget units per second, and a render that would take
 * the work accepted and not yet rendered past --render-max-units is refused
 * with `busy`. Flow control: a render has at most RENDER_WINDOW frames
 * (and RENDER_WINDOW_BYTES, one frame always) handed over and not yet
 * written to its client's socket, so a bake is never buffered whole. docs/threads.md has the contract. */
#ifndef OCEAND_RENDER_WORKER_H
#define OCEAND_RENDER_WORKER_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "control.h"
#include "ocean.h"
#include "render_msg.h"

#define RENDER_WINDOW 4   /* frames of one render handed over and not yet sent, at most */
#define RENDER_WINDOW_BYTES ((size_t)16 << 20) /* ...and their bytes, at most (one frame always) */

struct render_config {
    int workers;                /* render threads (>= 1): renders that run at once */
    double budget;              /* units per second, all renders together (render_frame_units) */
    double max_units;           /* units accepted and not yet rendered, all renders together; more: busy */
    int nice;                   /* nice value of the render threads (above the tick's: the tick goes first) */
    int tile_size;              /* the configured tile side (frames use min(tile_size, N)) */
    int plan_rigor;             /* as the live simulation's (ocean_options) */
    const char *wisdom_path;    /* FFTW wisdom cache, NULL = none (copied) */
    void (*wake)(void *user);   /* wake the lws thread (net_wake) */
    void *wake_user;
};

struct render_service;
struct render_service *render_service_new(const struct render_config *c, char *err, size_t errlen);
/* Stops the workers (a render in progress ends where it is); results not taken are freed. */
void render_service_free(struct render_service *r);

/* ---- lws thread ---- */

/* Queue a render for client `serial` of the sea `p` (params_version
 * `version`). *units = what it costs. Returns 0, or -1 with e: bad_render
 * (alone over --render-max-units), busy (the client has a render in
 * progress, or the work accepted would pass --render-max-units). */
int render_submit(struct render_service *r, uint64_t serial, const cJSON *id, const struct render_req *req,
                  const struct ocean_params *p, uint32_t version, double *units, struct ctl_error *e);
/* End client `serial`'s render (render_cancel, or the client went away):
 * no frame is rendered for it after this returns; the worker posts its
 * `rendered` (reason "cancelled"). false when it had none. */
bool render_cancel(struct render_service *r, uint64_t serial);
/* The last byte of frame o (from render_take_results) was written: room for the next. */
struct render_out;
void render_frame_sent(struct render_service *r, const struct render_out *o);

/* What the workers produced, in order per client: frames (binary) and
 * the closing JSON (`rendered`, or an error). */
struct render_out {
    struct render_out *next;
    uint64_t serial;            /* the client's */
    uint64_t render;            /* which of its renders */
    bool frame;                 /* a binary frame; else a JSON text message */
    size_t len;                 /* bytes of data (text: without the NUL) */
    uint8_t *data;
    cJSON *rendered;            /* the closing `rendered`, not printed yet (data NULL): only the lws
                                 * thread knows how many frames reached the socket (render_out_print) */
};
struct render_out *render_take_results(struct render_service *r);
void render_out_free(struct render_out *o);
/* Print a `rendered` o into its data, with "frames" = `written`, the frames of its
 * render written whole to the client (not those posted: a cancel drops the ones
 * not started). 0, or -1 out of memory. Other messages are left as they are. */
int render_out_print(struct render_out *o, long written);
/* Renders queued or running (for /metrics and tests). */
int render_active(struct render_service *r);

#endif

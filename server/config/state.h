/* state.h — save the sea parameters so that a restart continues the same sea.
 * File: {"params":{...},"params_version":N,"sim_time":t}. Saved atomically
 * (write a temporary file, fsync, rename over the old one). */
#ifndef OCEAND_STATE_H
#define OCEAND_STATE_H

#include <stddef.h>
#include <stdint.h>

#include "bodies.h"
#include "control.h"
#include "params.h"
#include "sea_spectrum.h"

/* The floating bodies saved with the sea (state_bodies.c): every body's
 * full state and who may claim it, so that a restart continues the same
 * scene; ids below next_id are never issued again. */
struct state_body {
    struct body_state st;       /* exactly (doubles as %.17g, the kind by name) */
    char owner[32];             /* the owner's client id when it was saved */
    char name[CTL_NAME_BYTES];  /* its display name, "" = none */
    char resume[33];            /* the resume key (32 hex digits): claim takes the body back */
    char origin[64];            /* a cluster's sim: the owner's edge ("" = none, a local client) */
};
#define STATE_IDS_EXHAUSTED ((uint64_t)UINT32_MAX + 1) /* next_id once the last id (2^32 - 1) was issued */
struct state_bodies {
    int n, cap;
    uint64_t next_id;           /* 1 .. STATE_IDS_EXHAUSTED; 0 = not known (nothing saved) */
    struct state_body *b;       /* malloc'd, cap entries */
};
void state_bodies_free(struct state_bodies *b);
/* Copy src into *dst (growing it); -1 out of memory (dst unchanged). */
int state_bodies_copy(struct state_bodies *dst, const struct state_bodies *src);
/* The saved bodies of a state file: 1 = loaded (*out filled, maybe 0
 * bodies; free with state_bodies_free), 0 = no file or no "bodies", -1 = a
 * bad entry (code "bad_body" in err; *out empty: nothing half-applied). */
int state_load_bodies(const char *path, struct state_bodies *out, char *err, size_t errlen);
/* The same from the "bodies" object itself (the cluster's record): 0, or -1 with err (*out empty). */
int state_bodies_parse(const struct cJSON *bodies, struct state_bodies *out, char *err, size_t errlen);

/* The "bodies" member of the state file (state_bodies.c). */
struct cJSON *state_bodies_json(const struct state_bodies *b);
/* The measured sea saved with the parameters (state_sea.c): the "sea"
 * member, the document as the `sea` message carries it. 1 = loaded (*out
 * filled), 0 = no file or no "sea", -1 = a bad one (err says why, with the
 * library's code; *out untouched). */
int state_load_sea(const char *path, struct sea_spectrum *out, char *err, size_t errlen);
struct cJSON *state_sea_json(const struct sea_spectrum *sea);
/* bodies: NULL or none = the file has no "bodies"; sea: NULL = no "sea". */
int state_save(const char *path, const struct ocean_params *p, uint32_t version, double sim_time,
               const struct state_bodies *bodies, const struct sea_spectrum *sea, char *err, size_t errlen);
/* Returns 1 if loaded, 0 if the file does not exist (p untouched), -1 on a
 * bad file (p untouched, err says why), -2 if path is not a regular file (a
 * FIFO, a directory: refused without reading, err says why). A params_version
 * or sim_time out of range (control_json_version, control_json_sim_time: the
 * running daemon's own limits) and data after the object are logged as
 * warnings; the bad value falls back to 0. */
int state_load(const char *path, struct ocean_params *p, uint32_t *version, double *sim_time,
               char *err, size_t errlen);

#endif

/* sea_msg.h — the JSON of measured seas (proto/PROTOCOL.md §7.8): the sea
 * document into the library's struct sea_spectrum and back (the `sea`
 * message, the state file, the cluster record), and the compact summary
 * `hello` and `params` carry. Pure like control.c (no threads, no globals):
 * unit-tested and fuzzed on its own. The check itself is the library's
 * (sea_spectrum_check): its codes are the wire codes. */
#ifndef OCEAND_SEA_MSG_H
#define OCEAND_SEA_MSG_H

#include <cjson/cJSON.h>
#include <stdint.h>

#include "control.h"
#include "sea_spectrum.h"

/* The summary's polar grid, at most (PROTOCOL.md §7.8): bands x directions. */
#define SEA_POLAR_BANDS 32
#define SEA_POLAR_DIRECTIONS 36

/* A sea document (a JSON object) into *out, then sea_spectrum_check.
 * Codes: bad_message (a member missing, or "sea" not an object), bad_type
 * (a member of the wrong JSON type), sea_size (arrays longer than the
 * limits, or of different lengths), sea_form (an unknown form, tail or
 * directional), then the library's (sea_error_name). e->param names the
 * member ("energy[3][5]" where the library names a place). Returns 0, or -1
 * with e filled (*out is then scratch). */
int sea_doc_parse(const cJSON *doc, struct sea_spectrum *out, struct ctl_error *e);

/* The document back as JSON (tail and directional included): what
 * sea_doc_parse reads gives the same struct bit for bit (%.17g). NULL on no
 * memory. */
cJSON *sea_doc_json(const struct sea_spectrum *s);

/* The summary: version (the params_version that brought the sea), source,
 * time, Hs, Tp, direction and spread at the peak, the share the grid
 * captures and its note, depth, convention, tail, and the polar plot (E in
 * m^2/Hz/deg, bands x directions, downsampled to at most
 * SEA_POLAR_BANDS x SEA_POLAR_DIRECTIONS). cap may be NULL (captured and
 * fit_note null). NULL on no memory. */
cJSON *sea_summary_json(const struct sea_spectrum *s, const struct sea_capture *cap, uint32_t version);

/* "f-4", "f-5", "none", "wind"; "mem", "lh", "lh_weighted". */
const char *sea_tail_name(enum sea_tail t);
const char *sea_directional_name(enum sea_directional d);

#endif

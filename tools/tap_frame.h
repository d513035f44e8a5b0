/* tap_frame.h — assemble the tiles of binary frames into whole fields.
 *
 * Each requested field is kept as a (n >> lod)^2 float grid. Tiles are
 * decoded with the project decoder (oc_proto.h) and copied into place; a
 * field is complete once every tile of the grid has arrived at least once
 * (later tiles overwrite), so a server that sends only changed tiles is
 * handled too. Tiles of other fields or another LOD are ignored (frames
 * encoded before a subscribe took effect). */
#ifndef OCEAND_TAP_FRAME_H
#define OCEAND_TAP_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "oc_proto.h"

#define TAP_E_GEOMETRY (-100) /* a tile lies outside the grid its frame header describes */

struct tap_frame;

/* fields: bit mask of enum oc_field; lod: the subscribed LOD (cascade 0). */
struct tap_frame *tap_frame_new(unsigned fields, int lod);
/* Also assemble cascade `cascade` (1..3, PROTOCOL.md §4.1): its own fields and
 * LOD; fields 0 = not wanted. Tiles of a cascade not wanted are skipped; a
 * frame is complete when every wanted cascade is. Returns 0 or -1. */
int tap_frame_want_cascade(struct tap_frame *a, int cascade, unsigned fields, int lod);
void tap_frame_free(struct tap_frame *a);
/* Decode one binary message into the grids. Returns 0, a negative
 * enum oc_error, or TAP_E_GEOMETRY. fh receives the frame header. */
int tap_frame_add(struct tap_frame *a, const uint8_t *data, size_t len, struct oc_frame_header *fh);
/* 1 when the last message carried every tile of every requested field at the
 * subscribed LOD. A frame the server sends at a coarser LOD while it is
 * degraded (PROTOCOL.md §7.2) does not: the grids would still hold the
 * previous frame's samples, which must not be written under this frame's seq. */
int tap_frame_complete(const struct tap_frame *a);
/* Grid of one field (side*side floats, row-major, row = z), NULL if not
 * requested; *bound = the error bound of its latest tile (0 = lossless).
 * tap_frame_field is cascade 0's. */
const float *tap_frame_field(const struct tap_frame *a, enum oc_field f, int *side, float *bound);
const float *tap_frame_cascade_field(const struct tap_frame *a, int cascade, enum oc_field f, int *side, float *bound);
/* Message for tap_frame_add's error codes. */
const char *tap_frame_strerror(int err);

#endif

/* tap_exr.h — ocean-tap's OpenEXR bakes, in the layout Blender's ocean
 * modifier bakes and reads back (see docs/operations.md, "Baking for Blender").
 *
 * Per frame, four files in the output directory, numbered 1, 2, 3, ... in
 * the order written (Blender wants consecutive frame numbers):
 *   disp_NNNN.exr    R = Dx, G = height, B = Dz (m, y up), A = 1
 *   normal_NNNN.exr  R G B = unit normal (-slope_x, 1, -slope_z)/|.|, A = 1
 *   foam_NNNN.exr    R = G = B = foam = clamp(1 - jacobian, 0, 1), A = 1
 *   vdisp_NNNN.exr   R = Dx, G = Dz, B = height: Blender's X, Y, Z, A = 1
 * RGBA half float, ZIP compression, scanline image; image column = x, and
 * the first scanline is the last grid row (z = N-1), as Blender writes its
 * bottom-up images. Every file carries string attributes oceand_seq,
 * oceand_sim_time, oceand_params_version, oceand_patch_size, oceand_field,
 * oceand_origin_x, oceand_origin_z (the world position of sample [0][0]),
 * oceand_cascades (how many cascades the image sums);
 * frame_NNNN.json beside them says the same for scripts. */
#ifndef OCEAND_TAP_EXR_H
#define OCEAND_TAP_EXR_H

#include <stddef.h>

#include "tap_write.h"

/* Fields of one frame, side*side floats each, row-major (row = z). */
struct tap_exr_fields {
    const float *height, *dx, *dz, *slope_x, *slope_z, *jacobian;
};

/* Write the four files and the JSON of Blender frame `frame` into dir (two
 * threads, two files each).
 * Returns 0, or -1 with a message in err. */
int tap_exr_bake(const char *dir, int frame, int side, const struct tap_exr_fields *f, const struct tap_meta *m,
                 int cascades, char *err, size_t errlen);

#endif

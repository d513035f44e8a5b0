/* tap_exr.c — see tap_exr.h. OpenEXR 3.1's C API (OpenEXRCore, Debian
 * libopenexr-dev); half floats converted with Imath's C functions. */
#include "tap_exr.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <half.h>
#include <openexr.h>

/* zlib level of the ZIP blocks: readers do not care, and half floats of a sea
 * compress no better at the default level (30 bake frames at N = 256: the same
 * 31 MB, 107 ms of CPU a frame at the default, 73 ms at level 1). */
#ifndef TAP_EXR_ZIP_LEVEL
#define TAP_EXR_ZIP_LEVEL 1
#endif

static int exr_fail(exr_result_t rv, const char *what, const char *path, char *err, size_t errlen)
{
    snprintf(err, errlen, "%s: %s: %s", path, what, exr_get_default_error_message(rv));
    return -1;
}

int tap_exr_write(const char *path, int side, const float *const rgba[4], const char *const *attrs, char *err,
                  size_t errlen)
{
    static const char *const names[4] = {"R", "G", "B", "A"};
    size_t count = (size_t)side * side;
    uint16_t *hbuf = malloc(4 * count * sizeof *hbuf);
    if (!hbuf) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    /* Channel c, EXR scanline y = grid row side-1-y (Blender's bottom-up rows). */
    for (int c = 0; c < 4; c++) {
        uint16_t *dst = hbuf + (size_t)c * count;
        for (int y = 0; y < side; y++) {
            const float *src = rgba[c] ? rgba[c] + (size_t)(side - 1 - y) * side : NULL;
            for (int x = 0; x < side; x++)
                dst[(size_t)y * side + x] = imath_float_to_half(src ? src[x] : 1.0f);
        }
    }
    exr_context_t f = NULL;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    int part = 0, r = -1;
    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    int enc_ready = 0;
    exr_result_t rv = exr_start_write(&f, path, EXR_INTERMEDIATE_TEMP_FILE, &init);
    if (rv != EXR_ERR_SUCCESS) {
        exr_fail(rv, "cannot create", path, err, errlen);
        free(hbuf);
        return -1;
    }
    if ((rv = exr_add_part(f, "", EXR_STORAGE_SCANLINE, &part)) ||
        (rv = exr_initialize_required_attr_simple(f, part, side, side, EXR_COMPRESSION_ZIP)) ||
        (rv = exr_set_zip_compression_level(f, part, TAP_EXR_ZIP_LEVEL))) {
        exr_fail(rv, "header", path, err, errlen);
        goto out;
    }
    for (int c = 0; c < 4; c++)
        if ((rv = exr_add_channel(f, part, names[c], EXR_PIXEL_HALF, EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1))) {
            exr_fail(rv, "channel", path, err, errlen);
            goto out;
        }
    for (int i = 0; attrs && attrs[i]; i += 2)
        if ((rv = exr_attr_set_string(f, part, attrs[i], attrs[i + 1]))) {
            exr_fail(rv, "attribute", path, err, errlen);
            goto out;
        }
    if ((rv = exr_write_header(f))) {
        exr_fail(rv, "write header", path, err, errlen);
        goto out;
    }
    int32_t lines = 1;
    exr_get_scanlines_per_chunk(f, part, &lines);
    for (int y = 0; y < side; y += lines) {
        exr_chunk_info_t ci;
        if ((rv = exr_write_scanline_chunk_info(f, part, y, &ci)) ||
            (rv = enc_ready ? exr_encoding_update(f, part, &ci, &enc) : exr_encoding_initialize(f, part, &ci, &enc))) {
            exr_fail(rv, "chunk", path, err, errlen);
            goto out;
        }
        enc_ready = 1;
        for (int k = 0; k < enc.channel_count; k++) { /* the header sorts channels: A B G R */
            exr_coding_channel_info_t *ch = &enc.channels[k];
            int c = 0;
            while (c < 3 && strcmp(ch->channel_name, names[c]))
                c++;
            ch->encode_from_ptr = (const uint8_t *)(hbuf + (size_t)c * count + (size_t)y * side);
            ch->user_pixel_stride = 2;
            ch->user_line_stride = 2 * side;
            ch->user_data_type = EXR_PIXEL_HALF;
            ch->user_bytes_per_element = 2;
        }
        if ((rv = exr_encoding_choose_default_routines(f, part, &enc)) || (rv = exr_encoding_run(f, part, &enc))) {
            exr_fail(rv, "encode", path, err, errlen);
            goto out;
        }
    }
    r = 0;
out:
    if (enc_ready)
        exr_encoding_destroy(f, &enc);
    rv = exr_finish(&f); /* with a temp file: renamed into place only on success */
    if (r == 0 && rv != EXR_ERR_SUCCESS)
        r = exr_fail(rv, "finish", path, err, errlen);
    free(hbuf);
    return r;
}

struct exr_job {
    char path[4096];
    int side;
    const float *chans[4];
    const char *attrs[17];
    int rc;
    char err[512];
};

/* Writes jobs[0] and jobs[1]. */
static void *write_pair(void *arg)
{
    struct exr_job *j = arg;
    for (int k = 0; k < 2; k++)
        j[k].rc = tap_exr_write(j[k].path, j[k].side, j[k].chans, j[k].attrs, j[k].err, sizeof j[k].err);
    return NULL;
}

int tap_exr_bake(const char *dir, int frame, int side, const struct tap_exr_fields *fl, const struct tap_meta *m,
                 int cascades, char *err, size_t errlen)
{
    size_t count = (size_t)side * side;
    float *buf = malloc(4 * count * sizeof *buf);
    if (!buf) {
        snprintf(err, errlen, "out of memory");
        return -1;
    }
    float *nx = buf, *ny = nx + count, *nz = ny + count, *foam = nz + count;
    for (size_t i = 0; i < count; i++) {
        /* Blender's baked normal: the undisplaced surface's, y up. */
        double sx = fl->slope_x[i], sz = fl->slope_z[i], l = sqrt(sx * sx + 1 + sz * sz);
        nx[i] = (float)(-sx / l);
        ny[i] = (float)(1 / l);
        nz[i] = (float)(-sz / l);
        float j = 1.0f - fl->jacobian[i];
        foam[i] = j < 0 ? 0 : j > 1 ? 1 : j;
    }
    char seq[32], t[40], pv[16], L[32];
    snprintf(seq, sizeof seq, "%llu", (unsigned long long)m->seq);
    snprintf(t, sizeof t, "%.17g", m->sim_time);
    snprintf(pv, sizeof pv, "%u", (unsigned)m->params_version);
    snprintf(L, sizeof L, "%.9g", (double)m->patch_size);
    /* vdisp: the displacement in Blender's axes (X = x, Y = z, Z = height) for
     * a Displace modifier in RGB to XYZ mode (tools/blender/oceand_bake.py). */
    static const char *const kinds[4] = {"disp", "normal", "foam", "vdisp"};
    const float *const chans[4][4] = {{fl->dx, fl->height, fl->dz, NULL},
                                      {nx, ny, nz, NULL},
                                      {foam, foam, foam, NULL},
                                      {fl->dx, fl->dz, fl->height, NULL}};
    char ox[40], oz[40], nc[8];
    snprintf(ox, sizeof ox, "%.17g", m->origin_x);
    snprintf(oz, sizeof oz, "%.17g", m->origin_z);
    snprintf(nc, sizeof nc, "%d", cascades);
    /* The four files are independent: two threads write two each (ZIP and the
     * half conversion are most of a bake frame's time). */
    struct exr_job jobs[4];
    for (int k = 0; k < 4; k++) {
        const char *attrs[] = {"oceand_field", kinds[k], "oceand_seq", seq, "oceand_sim_time", t,
                               "oceand_params_version", pv, "oceand_patch_size", L, "oceand_origin_x", ox,
                               "oceand_origin_z", oz, "oceand_cascades", nc, NULL};
        jobs[k] = (struct exr_job){.side = side, .rc = 0};
        memcpy(jobs[k].attrs, attrs, sizeof attrs);
        memcpy(jobs[k].chans, chans[k], sizeof jobs[k].chans);
        if (snprintf(jobs[k].path, sizeof jobs[k].path, "%s/%s_%04d.exr", dir, kinds[k], frame) >=
            (int)sizeof jobs[k].path) {
            snprintf(err, errlen, "path too long");
            free(buf);
            return -1;
        }
    }
    pthread_t th;
    int threaded = pthread_create(&th, NULL, write_pair, &jobs[2]) == 0;
    write_pair(&jobs[0]);
    if (!threaded) write_pair(&jobs[2]);
    else pthread_join(th, NULL);
    free(buf);
    int r = 0;
    for (int k = 0; k < 4 && r == 0; k++)
        if (jobs[k].rc) {
            snprintf(err, errlen, "%s", jobs[k].err);
            r = -1;
        }
    if (r)
        return r;
    char path[4096];
    snprintf(path, sizeof path, "%s/frame_%04d.json", dir, frame);
    FILE *f = fopen(path, "w");
    if (!f) {
        snprintf(err, errlen, "%s: %s", path, strerror(errno));
        return -1;
    }
    int ok = fprintf(f,
                     "{\n  \"frame\": %d,\n  \"files\": [\"disp_%04d.exr\", \"normal_%04d.exr\", \"foam_%04d.exr\", "
                     "\"vdisp_%04d.exr\"],\n"
                     "  \"seq\": %s,\n  \"sim_time\": %s,\n  \"params_version\": %s,\n  \"n\": %d,\n  \"lod\": %d,\n"
                     "  \"side\": %d,\n  \"patch_size\": %s,\n  \"origin\": [%s, %s],\n  \"cascades\": %d,\n"
                     "  \"bound\": %.9g,\n  \"server_time_us\": %llu,\n"
                     "  \"layout\": \"blender ocean bake: half RGBA, ZIP, first scanline = last row (z = side-1)\"\n}\n",
                     frame, frame, frame, frame, frame, seq, t, pv, m->n, m->lod, side, L, ox, oz, cascades,
                     (double)m->bound,
                     (unsigned long long)m->server_time_us) > 0;
    if (fclose(f) != 0 || !ok) {
        snprintf(err, errlen, "%s: write failed", path);
        return -1;
    }
    return 0;
}

/* exr_read.c — test helper: read an OpenEXR file back with the OpenEXR
 * library (3.1 C API) and hand it to Python as .npy.
 *
 *   exr-read FILE.exr OUT.npy
 * OUT.npy: float32, shape (height, width, 4), channels R G B A in the
 * file's scanline order (no flip). Prints one JSON line: width, height,
 * compression, channels [[name, type], ...] and the oceand_* string
 * attributes. Exit 1 on any error. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <half.h>
#include <openexr.h>

static int die(const char *what, exr_result_t rv)
{
    fprintf(stderr, "exr-read: %s: %s\n", what, rv ? exr_get_default_error_message(rv) : "failed");
    return 1;
}

int main(int argc, char **argv)
{
    if (argc != 3) {
        fprintf(stderr, "usage: exr-read FILE.exr OUT.npy\n");
        return 1;
    }
    exr_context_t f;
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    exr_result_t rv = exr_start_read(&f, argv[1], &init);
    if (rv)
        return die("open", rv);
    exr_attr_box2i_t dw;
    const exr_attr_chlist_t *chl;
    exr_compression_t comp;
    int32_t lines;
    if ((rv = exr_get_data_window(f, 0, &dw)) || (rv = exr_get_channels(f, 0, &chl)) ||
        (rv = exr_get_compression(f, 0, &comp)) || (rv = exr_get_scanlines_per_chunk(f, 0, &lines)))
        return die("header", rv);
    int w = dw.max.x - dw.min.x + 1, h = dw.max.y - dw.min.y + 1;
    static const char *const comp_names[] = {"none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab"};
    printf("{\"width\": %d, \"height\": %d, \"compression\": \"%s\", \"channels\": [", w, h,
           (unsigned)comp < sizeof comp_names / sizeof comp_names[0] ? comp_names[comp] : "?");
    for (int c = 0; c < chl->num_channels; c++)
        printf("%s[\"%s\", \"%s\"]", c ? ", " : "", chl->entries[c].name.str,
               chl->entries[c].pixel_type == EXR_PIXEL_HALF ? "half" : chl->entries[c].pixel_type == EXR_PIXEL_FLOAT ? "float" : "uint");
    printf("]");
    static const char *const attrs[] = {"oceand_field", "oceand_seq", "oceand_sim_time", "oceand_params_version",
                                        "oceand_patch_size"};
    for (size_t i = 0; i < sizeof attrs / sizeof attrs[0]; i++) {
        const char *v = NULL;
        int32_t len = 0;
        if (exr_attr_get_string(f, 0, attrs[i], &len, &v) == EXR_ERR_SUCCESS && v)
            printf(", \"%s\": \"%.*s\"", attrs[i], (int)len, v);
    }
    printf("}\n");

    size_t count = (size_t)w * h;
    uint16_t *hbuf = calloc(4 * count, sizeof *hbuf);
    float *out = malloc(4 * count * sizeof *out);
    if (!hbuf || !out)
        return die("out of memory", 0);
    exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
    int ready = 0;
    for (int y = dw.min.y; y <= dw.max.y; y += lines) {
        exr_chunk_info_t ci;
        if ((rv = exr_read_scanline_chunk_info(f, 0, y, &ci)) ||
            (rv = ready ? exr_decoding_update(f, 0, &ci, &dec) : exr_decoding_initialize(f, 0, &ci, &dec)))
            return die("chunk", rv);
        ready = 1;
        for (int k = 0; k < dec.channel_count; k++) {
            exr_coding_channel_info_t *ch = &dec.channels[k];
            static const char *const names[4] = {"R", "G", "B", "A"};
            int c = 0;
            while (c < 4 && strcmp(ch->channel_name, names[c]))
                c++;
            if (c == 4 || ch->data_type != EXR_PIXEL_HALF) {
                ch->decode_to_ptr = NULL; /* skip channels we do not know */
                continue;
            }
            ch->decode_to_ptr = (uint8_t *)(hbuf + (size_t)c * count + (size_t)(y - dw.min.y) * w);
            ch->user_pixel_stride = 2;
            ch->user_line_stride = 2 * w;
            ch->user_data_type = EXR_PIXEL_HALF;
            ch->user_bytes_per_element = 2;
        }
        if ((rv = exr_decoding_choose_default_routines(f, 0, &dec)) || (rv = exr_decoding_run(f, 0, &dec)))
            return die("decode", rv);
    }
    if (ready)
        exr_decoding_destroy(f, &dec);
    exr_finish(&f);
    for (size_t i = 0; i < count; i++)
        for (int c = 0; c < 4; c++)
            out[4 * i + c] = imath_half_to_float(hbuf[(size_t)c * count + i]);

    char dict[128];
    int len = snprintf(dict, sizeof dict, "{'descr': '<f4', 'fortran_order': False, 'shape': (%d, %d, 4), }", h, w);
    int pad = (64 - (10 + len + 1) % 64) % 64, hlen = len + pad + 1;
    FILE *o = fopen(argv[2], "wb");
    if (!o)
        return die("cannot write the .npy", 0);
    unsigned char magic[10] = {0x93, 'N', 'U', 'M', 'P', 'Y', 1, 0, (unsigned char)(hlen & 0xff), (unsigned char)(hlen >> 8)};
    fwrite(magic, 1, 10, o);
    fwrite(dict, 1, (size_t)len, o);
    for (int i = 0; i < pad; i++)
        fputc(' ', o);
    fputc('\n', o);
    int ok = fwrite(out, sizeof *out, 4 * count, o) == 4 * count;
    if (fclose(o) != 0 || !ok)
        return die("cannot write the .npy", 0);
    free(hbuf);
    free(out);
    return 0;
}

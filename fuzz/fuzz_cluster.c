/* fuzz_cluster.c — libFuzzer target: the cluster's message parsers (layer
 * parts "OCNL", envelopes "OCNE", demand bodies, layer subjects), the layer
 * assembler and the demand table must reject or accept any bytes a NATS
 * peer could publish, without reading outside them.
 * Input: records [u32 little-endian length][bytes], each tried as a layer
 * part (fed to one assembler) and as an envelope; the whole input is also
 * tried as a subject. Whatever parses must write back byte for byte;
 * complete layers go on into a frame collector. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "cluster/cluster.h"

static void check_part(const uint8_t *msg, size_t len, struct cl_assembler *a, struct cl_collector *col,
                       const uint8_t want[CL_KEY_BYTES])
{
    struct cl_layer_part p;
    if (cl_layer_part_parse(msg, len, &p) != CL_OK)
        return;
    int total = cl_layer_tiles(&p.info), sec = p.info.tiles_per_side * p.info.tiles_per_side;
    if (p.tile_first + p.tile_count > total || p.tile_first / sec != (p.tile_first + p.tile_count - 1) / sec ||
        p.info.need > CL_LAYER_MAX_NEED || !p.info.epoch)
        abort();
    /* round trip: absolute offsets of its section as the sim would hold them, rewritten */
    if (msg[6] == CL_LAYER_HEADER_SIZE && msg[7] == 0) {
        uint32_t *off = calloc((size_t)sec + 1, sizeof *off);
        uint8_t *out = malloc(len);
        if (!off || !out)
            abort();
        for (int i = 0; i <= p.tile_count; i++)
            off[p.tile_first % sec + i] = cl_part_off(&p, i);
        long w = cl_layer_part_write(out, len, &p.info, p.tile_first, p.tile_count, p.data, off);
        if (w != (long)len || memcmp(out, msg, len) != 0)
            abort();
        free(off);
        free(out);
    }
    struct cl_layer *l = NULL;
    if (cl_assembler_add(a, &p, &l) == 1) {
        if (!l || l->tile_off[0] != 0 || l->tile_off[total] != l->len || cl_layer_tiles(&l->info) != total)
            abort();
        for (int i = 0; i < total; i++)
            if (l->tile_off[i + 1] < l->tile_off[i] + 40)
                abort();
        struct cl_frame_set *out[2];
        int n = cl_collector_add(col, l, want, out);
        for (int i = 0; i < n; i++) {
            if (out[i]->nlayers < 1 || out[i]->nlayers > CL_KEYS)
                abort();
            for (int j = 1; j < out[i]->nlayers; j++)
                if (out[i]->layers[j]->info.seq != out[i]->hdr.seq)
                    abort();
            cl_frame_set_free(out[i]);
        }
    }
}

static void check_envelope(const uint8_t *msg, size_t len, struct cl_demand *d, double t)
{
    struct cl_envelope e;
    if (cl_envelope_parse(msg, len, &e) != CL_OK)
        return;
    uint8_t *out = malloc(len);
    if (!out)
        abort();
    long w = cl_envelope_write(out, len, e.kind, e.origin, e.by, e.body, e.body_len);
    if (w != (long)len || memcmp(out, msg, len) != 0)
        abort();
    free(out);
    uint32_t ttl;
    uint8_t bits[CL_KEY_BYTES], u[CL_KEY_BYTES];
    if (e.kind == CL_KIND_DEMAND && cl_demand_body_parse(e.body, e.body_len, &ttl, bits) == CL_OK) {
        cl_demand_update(d, e.origin, bits, ttl / 1000.0, t);
        int live = cl_demand_union(d, t, u);
        if (live < 0 || live > 4)
            abort();
    }
    struct cl_demand_bits b, ub;
    if (e.kind == CL_KIND_DEMAND && cl_demand_body_parse_ex(e.body, e.body_len, &ttl, &b) == CL_OK) {
        for (int i = 0; i < CL_KEY_BYTES; i++) /* stream and wish are subsets of keys */
            if ((b.stream[i] & ~b.keys[i]) || (b.wish[i] & ~b.keys[i]))
                abort();
        uint8_t back[CL_DEMAND_BODY_EX];
        if (e.body_len == CL_DEMAND_BODY_EX) {
            cl_demand_body_write_ex(back, ttl, &b);
            if (memcmp(back, e.body, CL_DEMAND_BODY_EX) != 0)
                abort();
        }
        cl_demand_update_ex(d, e.origin, &b, ttl / 1000.0, t);
        int live = cl_demand_union_ex(d, t, &ub);
        if (live < 0 || live > 4)
            abort();
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    struct cl_assembler *a = cl_assembler_new();
    struct cl_demand *d = cl_demand_new(4);
    struct cl_collector *col = cl_collector_new();
    if (!a || !d || !col)
        abort();
    /* the edge wants the layers whose key bits the input's first bytes set */
    uint8_t want[CL_KEY_BYTES] = { 0 };
    for (int k = 0; k < 150 && (size_t)(k >> 3) < size; k++) /* keys 0..149 of every cascade */
        if ((data[k >> 3] >> (k & 7)) & 1)
            for (int c = 0; c < CL_CASCADES; c++)
                cl_bit_set(want, c * CL_CASCADE_KEYS + k, true);
    double t = 0;
    for (size_t pos = 0; pos + 4 <= size;) {
        uint32_t len = (uint32_t)data[pos] | (uint32_t)data[pos + 1] << 8 | (uint32_t)data[pos + 2] << 16 |
                       (uint32_t)data[pos + 3] << 24;
        pos += 4;
        if (len > size - pos)
            len = (uint32_t)(size - pos);
        /* a copy of exactly len bytes, so ASan sees any read past the record */
        uint8_t *rec = malloc(len ? len : 1);
        if (!rec)
            abort();
        memcpy(rec, data + pos, len);
        check_part(rec, len, a, col, want);
        check_envelope(rec, len, d, t);
        free(rec);
        pos += len;
        t += 0.5;
    }
    char *subj = malloc(size + 1);
    if (!subj)
        abort();
    memcpy(subj, data, size);
    subj[size] = 0;
    int k = cl_subject_layer_parse(subj, "oceand");
    if (k >= CL_KEYS)
        abort();
    char stream[CL_SUBJECT_MAX];
    if (cl_probe_stream_subject(subj, stream, sizeof stream) == CL_OK &&
        (strlen(stream) < 2 || strcmp(stream + strlen(stream) - 2, ".p") != 0 || strlen(stream) > size + 1))
        abort();
    free(subj);
    cl_assembler_free(a);
    cl_demand_free(d);
    cl_collector_free(col);
    return 0;
}

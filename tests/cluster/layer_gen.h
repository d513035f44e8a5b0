/* layer_gen.h — synthetic layers for the cluster tests: tiles framed as the
 * encoder frames them (40-byte OC tile header with field, lod and
 * payload_len; then payload_len pseudo-random bytes), sizes varying per
 * tile. The cluster code treats tile payloads as opaque bytes, so real
 * encoded data would test nothing more here. */
#ifndef OCEAND_TEST_LAYER_GEN_H
#define OCEAND_TEST_LAYER_GEN_H

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "cluster/cluster.h"

struct gen_layer {
    struct cl_layer_info info;
    uint8_t *data;
    size_t len;
    uint32_t *tile_off;
};

static uint32_t gen_rand(uint64_t *s)
{
    *s = *s * 6364136223846793005ull + 1442695040888963407ull;
    return (uint32_t)(*s >> 33);
}

/* n samples per side, tiles of tile_size; payloads of 1..max_payload bytes. */
static inline int gen_layer_make(struct gen_layer *g, int n, int tile_size, int field, int lod, int bound,
                                 uint64_t seq, uint32_t max_payload, uint64_t seed)
{
    memset(g, 0, sizeof *g);
    struct cl_layer_info *h = &g->info;
    h->seq = seq;
    h->sim_time = (double)seq / 30.0;
    h->params_version = 3;
    h->n = (uint16_t)n;
    h->tile_size = (uint16_t)tile_size;
    h->patch_size = 256.0f;
    h->server_time_us = 1700000000000000ull + seq;
    h->field = (uint8_t)field;
    h->lod = (uint8_t)lod;
    h->bound_index = (uint8_t)bound;
    h->tiles_per_side = (uint16_t)(n / tile_size);
    h->ncascades = 1;
    h->encoded_lod = (uint8_t)lod;
    h->epoch = 0x5eed0000feedull; /* a sim process (cluster.h: never 0) */
    cl_bit_set(h->encoded, cl_key(field, lod, bound), true);
    int total = h->tiles_per_side * h->tiles_per_side;
    g->tile_off = malloc(sizeof(uint32_t) * ((size_t)total + 1));
    size_t cap = (size_t)total * (40 + max_payload);
    g->data = malloc(cap ? cap : 1);
    if (!g->tile_off || !g->data)
        return -1;
    uint64_t s = seed;
    for (int t = 0; t < total; t++) {
        g->tile_off[t] = (uint32_t)g->len;
        uint32_t pl = 1 + gen_rand(&s) % max_payload;
        uint8_t *p = g->data + g->len;
        memset(p, 0, 40);
        p[0] = (uint8_t)field;
        p[1] = (uint8_t)lod;
        p[2] = 1;
        p[4] = (uint8_t)(t % h->tiles_per_side);
        p[6] = (uint8_t)(t / h->tiles_per_side);
        p[32] = (uint8_t)pl;
        p[33] = (uint8_t)(pl >> 8);
        p[34] = (uint8_t)(pl >> 16);
        p[35] = (uint8_t)(pl >> 24);
        for (uint32_t i = 0; i < pl; i++)
            p[40 + i] = (uint8_t)gen_rand(&s);
        g->len += 40 + pl;
    }
    g->tile_off[total] = (uint32_t)g->len;
    return 0;
}

/* Makes it a layer of cascade `cascade` of `ncascades`: header, encoded bit
 * and every tile header's flags byte (PROTOCOL.md §3.2). */
static inline void gen_layer_cascade(struct gen_layer *g, int cascade, int ncascades)
{
    struct cl_layer_info *h = &g->info;
    cl_bit_set(h->encoded, cl_info_key(h), false);
    h->cascade = (uint8_t)cascade;
    h->ncascades = (uint8_t)ncascades;
    cl_bit_set(h->encoded, cl_info_key(h), true);
    int total = h->tiles_per_side * h->tiles_per_side;
    for (int t = 0; t < total; t++)
        g->data[g->tile_off[t] + 3] = (uint8_t)cascade;
}

static inline void gen_layer_free(struct gen_layer *g)
{
    free(g->data);
    free(g->tile_off);
    memset(g, 0, sizeof *g);
}

/* The assembled layer equals the generated one: header fields, bytes, offsets. */
static inline int gen_layer_equal(const struct gen_layer *g, const struct cl_layer *l)
{
    const struct cl_layer_info *a = &g->info, *b = &l->info;
    if (a->seq != b->seq || a->sim_time != b->sim_time || a->params_version != b->params_version ||
        a->n != b->n || a->tile_size != b->tile_size || a->patch_size != b->patch_size ||
        a->frame_flags != b->frame_flags || a->server_time_us != b->server_time_us || a->field != b->field ||
        a->lod != b->lod || a->bound_index != b->bound_index || a->layer_flags != b->layer_flags ||
        a->cascade != b->cascade || a->ncascades != b->ncascades || a->encoded_lod != b->encoded_lod ||
        a->tiles_per_side != b->tiles_per_side || memcmp(a->encoded, b->encoded, CL_KEY_BYTES) != 0 ||
        a->need != b->need || a->epoch != b->epoch)
        return 0;
    int total = a->tiles_per_side * a->tiles_per_side;
    return g->len == l->len && memcmp(g->data, l->data, g->len) == 0 &&
           memcmp(g->tile_off, l->tile_off, sizeof(uint32_t) * ((size_t)total + 1)) == 0;
}

#endif

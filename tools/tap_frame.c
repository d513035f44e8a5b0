/* tap_frame.c — see tap_frame.h. */
#include "tap_frame.h"

#include <stdlib.h>
#include <string.h>

struct field_grid {
    float *data;          /* side*side */
    unsigned char *seen;  /* tiles_per_side^2 flags: tile arrived at least once */
    int missing;          /* tiles not seen yet */
    int fresh;            /* tiles the current message carried */
    float bound;          /* of the latest tile */
};

struct tap_frame {
    unsigned fields;
    int lod;
    int n, tile_size;     /* geometry the grids were made for; 0 = none yet */
    int side, tiles;      /* samples per side at lod, tiles per side */
    struct field_grid grid[OC_FIELD_COUNT];
    struct oc_decoder *dec;
    int err;              /* first geometry error in the current message */
};

struct tap_frame *tap_frame_new(unsigned fields, int lod)
{
    struct tap_frame *a = calloc(1, sizeof *a);
    if (!a) return NULL;
    a->fields = fields;
    a->lod = lod;
    a->dec = oc_decoder_new();
    if (!a->dec) { free(a); return NULL; }
    return a;
}

static void drop_grids(struct tap_frame *a)
{
    for (int f = 0; f < OC_FIELD_COUNT; f++) {
        free(a->grid[f].data);
        free(a->grid[f].seen);
        memset(&a->grid[f], 0, sizeof a->grid[f]);
    }
    a->n = a->tile_size = 0;
}

void tap_frame_free(struct tap_frame *a)
{
    if (!a) return;
    drop_grids(a);
    oc_decoder_free(a->dec);
    free(a);
}

/* (Re)build the grids when the resolution or tile size changes (a resolution
 * change on the server starts a new, empty picture). */
static int shape_grids(struct tap_frame *a, int n, int tile_size)
{
    if (n == a->n && tile_size == a->tile_size) return 0;
    drop_grids(a);
    if (n <= 0 || tile_size <= 0 || (n >> a->lod) <= 0) return OC_E_CORRUPT;
    a->n = n;
    a->tile_size = tile_size;
    a->side = n >> a->lod;
    a->tiles = (n + tile_size - 1) / tile_size;
    for (int f = 0; f < OC_FIELD_COUNT; f++) {
        if (!(a->fields & (1u << f))) continue;
        struct field_grid *g = &a->grid[f];
        g->data = calloc((size_t)a->side * (size_t)a->side, sizeof(float));
        g->seen = calloc((size_t)a->tiles * (size_t)a->tiles, 1);
        if (!g->data || !g->seen) { drop_grids(a); return OC_E_NOMEM; }
        g->missing = a->tiles * a->tiles;
    }
    return 0;
}

static int on_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th,
                   const float *samples)
{
    struct tap_frame *a = user;
    if (th->field >= OC_FIELD_COUNT || !(a->fields & (1u << th->field)) || th->lod != a->lod)
        return 0;
    int r = shape_grids(a, fh->n, fh->tile_size);
    if (r) return r;
    struct field_grid *g = &a->grid[th->field];
    /* Tile (tx, tz) starts at sample tx*tile_size of the full grid, i.e. at
     * tx*(tile_size >> lod) of the LOD grid. */
    int step = a->tile_size >> a->lod;
    long x0 = (long)th->tile_x * step, z0 = (long)th->tile_z * step;
    if (th->tile_x >= a->tiles || th->tile_z >= a->tiles ||
        x0 + th->width > a->side || z0 + th->height > a->side) {
        a->err = TAP_E_GEOMETRY;
        return TAP_E_GEOMETRY;
    }
    for (int j = 0; j < th->height; j++)
        memcpy(g->data + (size_t)(z0 + j) * a->side + x0, samples + (size_t)j * th->width,
               th->width * sizeof(float));
    g->bound = th->bound;
    unsigned char *seen = &g->seen[th->tile_z * a->tiles + th->tile_x];
    if (!*seen) { *seen = 1; g->missing--; }
    g->fresh++;
    return 0;
}

int tap_frame_add(struct tap_frame *a, const uint8_t *data, size_t len, struct oc_frame_header *fh)
{
    a->err = 0;
    for (int f = 0; f < OC_FIELD_COUNT; f++)
        a->grid[f].fresh = 0;
    int r = oc_decode_frame(a->dec, data, len, fh, on_tile, a);
    if (a->err) return a->err;
    return r < 0 ? r : 0;
}

int tap_frame_complete(const struct tap_frame *a)
{
    if (!a->n) return 0;
    for (int f = 0; f < OC_FIELD_COUNT; f++)
        if ((a->fields & (1u << f)) && (a->grid[f].missing > 0 || a->grid[f].fresh < a->tiles * a->tiles)) return 0;
    return 1;
}

const float *tap_frame_field(const struct tap_frame *a, enum oc_field f, int *side, float *bound)
{
    if ((unsigned)f >= OC_FIELD_COUNT || !a->grid[f].data) return NULL;
    *side = a->side;
    *bound = a->grid[f].bound;
    return a->grid[f].data;
}

const char *tap_frame_strerror(int err)
{
    if (err == TAP_E_GEOMETRY) return "tile outside the frame's grid";
    return oc_strerror(err);
}

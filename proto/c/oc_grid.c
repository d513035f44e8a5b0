/* oc_grid.c — whole fields from the tiles of frames, per cascade (oc_proto.h, "Grids"). */
#include "oc_proto.h"

#include <stdlib.h>
#include <string.h>

struct field_grid {
    float *data;          /* side*side */
    unsigned char *seen;  /* tiles_per_side^2 flags: tile arrived at least once */
    int missing;          /* tiles not seen yet */
    int fresh;            /* tiles the current message carried */
    float bound;          /* of the latest tile */
};

/* One cascade's grids (PROTOCOL.md §4.1): its own fields and LOD. */
struct cascade_grids {
    unsigned fields;      /* 0 = cascade not wanted */
    int lod;
    int side;             /* samples per side at lod */
    struct field_grid grid[OC_FIELD_COUNT];
};

struct oc_grid {
    int n, tile_size;     /* geometry the grids were made for; 0 = none yet */
    int tiles;            /* tiles per side */
    struct cascade_grids cg[OC_MAX_CASCADES];
    struct oc_decoder *dec;
    int err;              /* first geometry error in the current message */
};

static void drop_grids(struct oc_grid *a);

struct oc_grid *oc_grid_new(unsigned fields, int lod)
{
    struct oc_grid *a = calloc(1, sizeof *a);
    if (!a) return NULL;
    a->cg[0].fields = fields;
    a->cg[0].lod = lod;
    a->dec = oc_decoder_new();
    if (!a->dec) { free(a); return NULL; }
    return a;
}

int oc_grid_want(struct oc_grid *a, int cascade, unsigned fields, int lod)
{
    if (cascade < 0 || cascade >= OC_MAX_CASCADES || lod < 0 || lod > OC_MAX_LOD) return -1;
    drop_grids(a);
    a->cg[cascade].fields = fields;
    a->cg[cascade].lod = lod;
    return 0;
}

static void drop_grids(struct oc_grid *a)
{
    for (int c = 0; c < OC_MAX_CASCADES; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            free(a->cg[c].grid[f].data);
            free(a->cg[c].grid[f].seen);
            memset(&a->cg[c].grid[f], 0, sizeof a->cg[c].grid[f]);
        }
    a->n = a->tile_size = 0;
}

void oc_grid_free(struct oc_grid *a)
{
    if (!a) return;
    drop_grids(a);
    oc_decoder_free(a->dec);
    free(a);
}

/* (Re)build the grids when the resolution or tile size changes (a resolution
 * change on the server starts a new, empty picture). */
static int shape_grids(struct oc_grid *a, int n, int tile_size)
{
    if (n == a->n && tile_size == a->tile_size) return 0;
    drop_grids(a);
    if (n <= 0 || tile_size <= 0) return OC_E_CORRUPT;
    for (int c = 0; c < OC_MAX_CASCADES; c++)
        if (a->cg[c].fields && (n >> a->cg[c].lod) <= 0) return OC_E_CORRUPT;
    a->n = n;
    a->tile_size = tile_size;
    a->tiles = (n + tile_size - 1) / tile_size;
    for (int c = 0; c < OC_MAX_CASCADES; c++) {
        struct cascade_grids *cg = &a->cg[c];
        cg->side = n >> cg->lod;
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            if (!(cg->fields & (1u << f))) continue;
            struct field_grid *g = &cg->grid[f];
            g->data = calloc((size_t)cg->side * (size_t)cg->side, sizeof(float));
            g->seen = calloc((size_t)a->tiles * (size_t)a->tiles, 1);
            if (!g->data || !g->seen) { drop_grids(a); return OC_E_NOMEM; }
            g->missing = a->tiles * a->tiles;
        }
    }
    return 0;
}

static int on_tile(void *user, const struct oc_frame_header *fh, const struct oc_tile_header *th,
                   const float *samples)
{
    struct oc_grid *a = user;
    struct cascade_grids *cg = &a->cg[oc_tile_cascade(th)];
    if (th->field >= OC_FIELD_COUNT || !(cg->fields & (1u << th->field)) || th->lod != cg->lod)
        return 0;
    int r = shape_grids(a, fh->n, fh->tile_size);
    if (r) return r;
    struct field_grid *g = &cg->grid[th->field];
    /* Tile (tx, tz) starts at sample tx*tile_size of the full grid, i.e. at
     * tx*(tile_size >> lod) of the LOD grid. */
    int step = a->tile_size >> cg->lod;
    long x0 = (long)th->tile_x * step, z0 = (long)th->tile_z * step;
    if (th->tile_x >= a->tiles || th->tile_z >= a->tiles ||
        x0 + th->width > cg->side || z0 + th->height > cg->side) {
        a->err = OC_E_CORRUPT;
        return OC_E_CORRUPT;
    }
    for (int j = 0; j < th->height; j++)
        memcpy(g->data + (size_t)(z0 + j) * cg->side + x0, samples + (size_t)j * th->width,
               th->width * sizeof(float));
    g->bound = th->bound;
    unsigned char *seen = &g->seen[th->tile_z * a->tiles + th->tile_x];
    if (!*seen) { *seen = 1; g->missing--; }
    g->fresh++;
    return 0;
}

int oc_grid_add(struct oc_grid *a, const uint8_t *data, size_t len, struct oc_frame_header *fh)
{
    a->err = 0;
    for (int c = 0; c < OC_MAX_CASCADES; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++)
            a->cg[c].grid[f].fresh = 0;
    int r = oc_decode_frame(a->dec, data, len, fh, on_tile, a);
    if (a->err) return a->err;
    return r < 0 ? r : 0;
}

int oc_grid_complete(const struct oc_grid *a)
{
    if (!a->n) return 0;
    for (int c = 0; c < OC_MAX_CASCADES; c++)
        for (int f = 0; f < OC_FIELD_COUNT; f++) {
            const struct field_grid *g = &a->cg[c].grid[f];
            if ((a->cg[c].fields & (1u << f)) && (g->missing > 0 || g->fresh < a->tiles * a->tiles)) return 0;
        }
    return 1;
}

const float *oc_grid_field(const struct oc_grid *a, int cascade, enum oc_field f, int *side, float *bound)
{
    if (cascade < 0 || cascade >= OC_MAX_CASCADES || (unsigned)f >= OC_FIELD_COUNT) return NULL;
    const struct cascade_grids *cg = &a->cg[cascade];
    if (!cg->grid[f].data) return NULL;
    *side = cg->side;
    *bound = cg->grid[f].bound;
    return cg->grid[f].data;
}

/* bodies_kinds.c — the table of kinds of bodies (one place: validation,
 * the schema in `hello`, the web panel) and the error names.
 *
 * Sizes and masses are those of real craft of the kind (docs/simulation.md,
 * "Bodies", table of kinds). `draft` is what the hull model gives at rest
 * for that mass (tests/test_bodies.c launches each kind and measures it);
 * change a size or a mass and `make test-bodies` names the new draft. */
#include <string.h>

#include "bodies.h"

static const struct body_kind kinds[BODY_KIND_COUNT] = {
    {
        .name = "spar",
        .label = "Spar buoy",
        .description = "A slender ballasted pole, 8 m long and 0.6 m across, floating upright with 6 m under water.",
        .hull = BODY_HULL_CYLINDER,
        .length = 0.6, .beam = 0.6, .height = 8.0,
        .mass = 1739.0,
        .draft = 6.0004,
        .kg = 2.0,
    },
    {
        .name = "ball",
        .label = "Ball buoy",
        .description = "A 1 m mooring ball with a ballast weight, riding every wave.",
        .hull = BODY_HULL_SPHERE,
        .length = 1.0, .beam = 1.0, .height = 1.0,
        .mass = 150.0,
        .draft = 0.3412,
        .kg = 0.3,
    },
    {
        .name = "dinghy",
        .label = "Dinghy",
        .description = "A 3 m outboard dinghy with one person aboard.",
        .hull = BODY_HULL_SHIP,
        .length = 3.0, .beam = 1.4, .height = 0.6,
        .mass = 220.0,
        .draft = 0.1511,
        .powered = true, .top_speed = 3.0, .turning_diameter = 8.0,
        .kg = 0.25,
    },
    {
        .name = "boat",
        .label = "Motor boat",
        .description = "A 12 m motor boat (about 9 t), 10 m/s flat out.",
        .hull = BODY_HULL_SHIP,
        .length = 12.0, .beam = 4.0, .height = 2.2,
        .mass = 9000.0,
        .draft = 0.5474,
        .powered = true, .top_speed = 10.0, .turning_diameter = 40.0,
        .kg = 0.95,
    },
    {
        .name = "ship",
        .label = "Coaster",
        .description = "A 60 m coastal cargo ship (about 1200 t), 8 m/s (15.5 kn) at full ahead.",
        .hull = BODY_HULL_SHIP,
        .length = 60.0, .beam = 10.0, .height = 6.0,
        .mass = 1.2e6,
        .draft = 3.5350,
        .powered = true, .top_speed = 8.0, .turning_diameter = 240.0,
        .kg = 2.7,
    },
};

const struct body_kind *body_kinds(void) { return kinds; }

const struct body_kind *body_kind_find(const char *name)
{
    if (!name)
        return NULL;
    for (int i = 0; i < BODY_KIND_COUNT; i++)
        if (strcmp(kinds[i].name, name) == 0)
            return &kinds[i];
    return NULL;
}

const char *body_error_name(enum body_error e)
{
    switch (e) {
    case BODY_OK: return "ok";
    case BODY_ERR_KIND: return "kind";
    case BODY_ERR_NOT_FINITE: return "not_finite";
    case BODY_ERR_RANGE: return "range";
    case BODY_ERR_FULL: return "full";
    case BODY_ERR_NOT_FOUND: return "not_found";
    case BODY_ERR_NO_MEMORY: return "no_memory";
    }
    return "unknown";
}

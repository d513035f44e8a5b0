/* bodies_internal.h — inside the bodies module (not a contract): the hull
 * as volume elements and the coefficients derived from a kind, shared by
 * bodies_hull.c (which builds them), bodies.c (which steps them) and the
 * module's tests. Model and sources: docs/simulation.md, "Bodies".
 *
 * Body axes are indexed 0 = x (to port), 1 = y (up), 2 = z (to the bow);
 * a rotation "about axis i" is pitch (0), yaw (1), roll (2). */
#ifndef OCEAND_BODIES_INTERNAL_H
#define OCEAND_BODIES_INTERNAL_H

#include "bodies.h"

/* Most volume elements one hull has (the box's grid uses up to 48, a ship
 * 32, a buoy 12): each is one sea sample per substep. */
#define BODY_ELEMS_MAX 64

/* One volume element: a prism whose axis is the body's y axis, through
 * (bx, bz) in the body frame, from y0 (bottom) to y1 (top) in the body
 * frame (origin at the centre of mass). area is its plan area, already
 * weighted so that the elements' volumes sum to the exact hull volume. */
struct body_elem {
    double bx, bz;
    double y0, y1;
    double area;
};

/* Everything the step needs of one kind, derived once at launch (or
 * restore) from the kind's row alone, with + - * / and sqrt only, so that
 * every IEEE machine derives the same numbers. */
struct body_model {
    int n;                          /* elements */
    struct body_elem e[BODY_ELEMS_MAX];
    double volume;                  /* m^3, the hull's exact volume (= sum of the elements') */
    double mass;                    /* kg */
    double kg;                      /* m, centre of mass above the keel */
    double wl_y;                    /* body y of the still waterline at rest (sample points lie on it) */
    double rest_y;                  /* world y of the centre of mass at rest in still water */
    double draft;                   /* m, keel below still water at rest */
    double v_rest;                  /* m^3, displacement at rest (mass / density; volume when it cannot float) */
    double waterplane;              /* m^2, waterplane area at rest */
    double inertia[3];              /* kg m^2, dry moments of inertia about the body axes through the centre of mass */
    double added[3];                /* kg, added mass along body x (sway), y (heave), z (surge) */
    double added_rot[3];            /* kg m^2, added moment of inertia about body x (pitch), y (yaw), z (roll) */
    double heave_lin;               /* N s/m, linear vertical damping of the whole hull (spread by element area) */
    double vert_quad;               /* kg/m^3, 1/2 rho C_d: quadratic vertical drag per m^2 of element area */
    double wet_ref;                 /* m, submerged length over which an element's drag grows to full */
    double surge_lin, surge_quad;   /* N s/m, N s^2/m^2: resistance along the bow */
    double sway_lin, sway_quad;     /* N s^2/m^2 (times |u|), N s^2/m^2: resistance across */
    double yaw_lin, yaw_quad;       /* N m s (times |u|), N m s^2: yaw damping */
    double rock_quad[3];            /* N m s^2: cross-flow drag of the hull's sides in pitch ([0]) and roll ([2]) */
    double thrust;                  /* N, full ahead (astern: half) */
    double rudder;                  /* N s^2/m^2: side force at the rudder per (rudder * u|u|) */
    double rudder_arm;              /* m, rudder aft of the centre of mass */
    bool can_float;                 /* volume * density > mass */
    double sink_margin;             /* m: a body that cannot float is gone once wholly this far under */
};

/* The model of kind k; 0, or -1 when k is not a usable kind (NULL, a
 * non-finite or non-positive size or mass, an unknown hull, kg outside
 * (0, height), a powered kind without top speed or turning diameter). */
int body_model_build(const struct body_kind *k, struct body_model *m);

#endif

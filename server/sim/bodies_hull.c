/* bodies_hull.c — a kind's row turned into what the step integrates: the
 * hull as vertical prism columns, its rest draft, inertia, added mass,
 * damping, thrust and rudder (docs/simulation.md, "Bodies").
 *
 * Only + - * / and sqrt here (no pow, no libm transcendental), so that
 * every IEEE machine derives bit-identical models: a standby restoring a
 * body rebuilds the same numbers the active sim had. */
#include <math.h>
#include <string.h>

#include "bodies_internal.h"

/* No fused multiply-add: a*b + c rounded twice, on every compiler and
 * -march, so a standby built elsewhere continues the same bits. GCC in ISO
 * C mode does not contract (and does not know the pragma); clang does by
 * default where the target has FMA. */
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#endif

#define RHO BODY_WATER_DENSITY
#define G   BODY_GRAVITY
#define PI  3.14159265358979323846

/* Heave damping as a fraction of critical: radiation and viscous losses in
 * one figure, picked so a released buoy rings a few times (docs). */
#define HEAVE_DAMPING_RATIO 0.08

static double clampd(double v, double lo, double hi) { return v < lo ? lo : v > hi ? hi : v; }

static bool finite_pos(double v) { return isfinite(v) && v > 0; }

static void add_elem(struct body_model *m, double bx, double bz, double y0, double y1, double area)
{
    m->e[m->n++] = (struct body_elem){bx, bz, y0, y1, area};
}

/* A 4 x 4 grid of square cells over the disc of radius r; the 12 cells
 * whose centre lies inside make the columns (the corners fall outside).
 * Buoys are small beside the waves that move them: 12 points see the
 * surface's height and slope under them, and cost the sampler little. */
enum { DISC_CELLS = 4 };
static void disc_columns(struct body_model *m, double r, bool sphere, double centre_y, double y0, double y1)
{
    double cell = 2 * r / DISC_CELLS;
    for (int i = 0; i < DISC_CELLS; i++)
        for (int j = 0; j < DISC_CELLS; j++) {
            double x = -r + (i + 0.5) * cell, z = -r + (j + 0.5) * cell;
            double rr = x * x + z * z;
            if (rr >= r * r)
                continue;
            if (sphere) {
                double h = sqrt(r * r - rr);
                add_elem(m, x, z, centre_y - h, centre_y + h, cell * cell);
            } else {
                add_elem(m, x, z, y0, y1, cell * cell);
            }
        }
}

/* The ship hull, in fractions of length L, beam B and height H, with
 * zeta = z / (L/2) from -1 (stern) to 1 (bow), fore-aft symmetric:
 *   half-beam  b(zeta) = B/2 (1 - |zeta|^2.5)        (waterplane coefficient 5/7)
 *   bottom     keel + H (0.3 (x/b)^2 + 0.25 |zeta|^3) (rising to the bilges and the ends)
 *   deck       flat at keel + H.
 * Its exact volume: L B H * int_0^1 (1 - s^2.5)(0.9 - 0.25 s^3) ds
 *   = L B H (0.9 - 0.0625 - 0.9/3.5 + 0.25/6.5). */
static double ship_half_beam(double beam, double zeta)
{
    double a = fabs(zeta);
    return 0.5 * beam * (1 - a * a * sqrt(a));
}
static double ship_rise(double height, double xb, double zeta)
{
    double a = fabs(zeta);
    return height * (0.3 * xb * xb + 0.25 * a * a * a);
}
#define SHIP_VOLUME_FRACTION (0.9 - 0.0625 - 0.9 / 3.5 + 0.25 / 6.5)
/* Stations along the length: 16 for a ship (3.75 m apart at 60 m, ten
 * to a 40 m wave), 12 for small craft (waves much shorter than them carry
 * little energy). Across, each station is two strips at the Gauss points
 * x = +-b/sqrt(3), each of half the station's width: two-point Gauss
 * quadrature integrates polynomials up to x^3 exactly, so the strips carry
 * the section's area, its quadratic bottom and the waterplane's second
 * moment (b^2/3 per unit area: the roll stiffness) exactly, at half the
 * columns and sea samples of four strips. */
static int ship_stations(double len) { return len >= 20 ? 16 : 12; }

static void ship_columns(struct body_model *m, double len, double beam, double height, double keel)
{
    int stations = ship_stations(len);
    double dz = len / stations, gauss = 1 / sqrt(3.0);
    for (int i = 0; i < stations; i++) {
        double z = -0.5 * len + (i + 0.5) * dz, zeta = z / (0.5 * len);
        double b = ship_half_beam(beam, zeta);
        for (int j = 0; j < 2; j++) {
            double xb = j ? gauss : -gauss; /* x / b */
            add_elem(m, xb * b, z, keel + ship_rise(height, xb, zeta), keel + height, b * dz);
        }
    }
}

/* Box: cells as square as 48 of them allow. */
static void box_columns(struct body_model *m, double len, double beam, double y0, double y1)
{
    int nz = (int)(sqrt(48.0 * len / beam) + 0.5);
    nz = nz < 2 ? 2 : nz > 24 ? 24 : nz;
    int nx = (int)(48.0 / nz + 0.5);
    nx = nx < 2 ? 2 : nx > 24 ? 24 : nx;
    if (nx * nz > BODY_ELEMS_MAX)
        nx = BODY_ELEMS_MAX / nz;
    double dx = beam / nx, dz = len / nz;
    for (int i = 0; i < nx; i++)
        for (int j = 0; j < nz; j++)
            add_elem(m, -0.5 * beam + (i + 0.5) * dx, -0.5 * len + (j + 0.5) * dz, y0, y1, dx * dz);
}

/* Volume below still water (y = 0) with the centre of mass at world y,
 * level. */
static double displaced_level(const struct body_model *m, double y)
{
    double v = 0;
    for (int i = 0; i < m->n; i++) {
        const struct body_elem *e = &m->e[i];
        v += e->area * clampd(-(y + e->y0), 0, e->y1 - e->y0);
    }
    return v;
}

/* The centre of mass's height at which the level hull displaces v_want,
 * by bisection (displacement falls as the body rises). */
static double rest_height(const struct body_model *m, double v_want)
{
    double ylo = 0, yhi = 0;
    for (int i = 0; i < m->n; i++) {
        ylo = fmin(ylo, -m->e[i].y1);
        yhi = fmax(yhi, -m->e[i].y0);
    }
    for (int it = 0; it < 200; it++) {
        double mid = 0.5 * (ylo + yhi);
        if (mid <= ylo || mid >= yhi)
            break;
        if (displaced_level(m, mid) > v_want)
            ylo = mid;
        else
            yhi = mid;
    }
    return 0.5 * (ylo + yhi);
}

/* Strip theory over the length for the box and the ship (a flat plate of
 * half-width a moving normal to itself has rho pi a^2 per unit length:
 * Newman 1977 ch. 4, DNV-RP-H103 Table A-1; at the free surface only the
 * water side counts, half of it):
 *   heave  per length rho pi b^2 / 2   (a plate of half-width b, the half-beam)
 *   sway   per length rho pi T^2 / 2   (a plate of half-width T, the local draft)
 * and their moments about the centre of mass for pitch and yaw. */
enum { STRIP_STATIONS = 64 };
static void strip_added_mass(struct body_model *m, const struct body_kind *k, bool ship)
{
    double len = k->length, dz = len / STRIP_STATIONS;
    for (int i = 0; i < STRIP_STATIONS; i++) {
        double z = -0.5 * len + (i + 0.5) * dz, zeta = z / (0.5 * len);
        double b = ship ? ship_half_beam(k->beam, zeta) : 0.5 * k->beam;
        double bottom = -m->kg + (ship ? ship_rise(k->height, 0, zeta) : 0);
        double t = clampd(m->wl_y - bottom, 0, k->height);
        double heave = RHO * PI * b * b / 2 * dz, sway = RHO * PI * t * t / 2 * dz;
        m->added[1] += heave;
        m->added[0] += sway;
        m->added_rot[0] += heave * z * z;
        m->added_rot[1] += sway * z * z;
    }
}

double body_kind_kg(const struct body_kind *k)
{
    static const double default_kg[] = {
        [BODY_HULL_CYLINDER] = 0.25, [BODY_HULL_SPHERE] = 0.4, [BODY_HULL_BOX] = 0.5, [BODY_HULL_SHIP] = 0.45,
    };
    if ((unsigned)k->hull > BODY_HULL_SHIP)
        return 0.5 * k->height;
    return k->kg > 0 ? k->kg : default_kg[k->hull] * k->height;
}

int body_model_build(const struct body_kind *k, struct body_model *m)
{
    if (!k || !finite_pos(k->length) || !finite_pos(k->beam) || !finite_pos(k->height) || !finite_pos(k->mass))
        return -1;
    if (!isfinite(k->kg) || k->kg < 0 || k->kg >= k->height)
        return -1;
    if (k->hull != BODY_HULL_CYLINDER && k->hull != BODY_HULL_SPHERE && k->hull != BODY_HULL_BOX &&
        k->hull != BODY_HULL_SHIP)
        return -1;
    if (k->powered && (!finite_pos(k->top_speed) || !finite_pos(k->turning_diameter)))
        return -1;
    memset(m, 0, sizeof *m);
    double len = k->length, beam = k->beam, height = k->height, mass = k->mass;
    m->kg = body_kind_kg(k);
    m->mass = mass;
    double keel = -m->kg, deck = height - m->kg, r = 0.5 * beam;

    /* Columns, then their areas scaled so their volume is the hull's exact
     * volume (the grid's cells miss or overshoot the curved outline). */
    double exact;
    switch (k->hull) {
    case BODY_HULL_CYLINDER:
        disc_columns(m, r, false, 0, keel, deck);
        exact = PI * r * r * height;
        break;
    case BODY_HULL_SPHERE:
        r = 0.5 * height; /* diameter = beam = length = height */
        disc_columns(m, r, true, keel + r, 0, 0);
        exact = 4.0 / 3.0 * PI * r * r * r;
        break;
    case BODY_HULL_BOX:
        box_columns(m, len, beam, keel, deck);
        exact = len * beam * height;
        break;
    default:
        ship_columns(m, len, beam, height, keel);
        exact = SHIP_VOLUME_FRACTION * len * beam * height;
        break;
    }
    double grid = 0;
    for (int i = 0; i < m->n; i++)
        grid += m->e[i].area * (m->e[i].y1 - m->e[i].y0);
    for (int i = 0; i < m->n; i++)
        m->e[i].area *= exact / grid;
    m->volume = exact;

    /* Rest in still water: level, displacing its mass; a body that cannot
     * float starts with its deck awash (and sinks). */
    m->can_float = RHO * exact > mass;
    m->v_rest = m->can_float ? mass / RHO : exact;
    if (m->can_float) {
        m->rest_y = rest_height(m, mass / RHO);
    } else {
        double top = keel;
        for (int i = 0; i < m->n; i++)
            top = fmax(top, m->e[i].y1);
        m->rest_y = -top;
    }
    m->wl_y = -m->rest_y;
    m->draft = m->kg - m->rest_y;
    for (int i = 0; i < m->n; i++)
        if (m->e[i].y0 < m->wl_y && m->wl_y < m->e[i].y1)
            m->waterplane += m->e[i].area;
    if (m->waterplane <= 0) /* none crosses the waterline (a sinker, deck awash): its plan */
        for (int i = 0; i < m->n; i++)
            m->waterplane += m->e[i].area;
    double draft = clampd(m->draft, 0, height);

    /* Dry inertia: the uniform solid of the outline, but for the ship the
     * radii of gyration naval architects use (0.25 L in pitch and yaw,
     * 0.35 B in roll). Added mass and inertia: docs, with sources. */
    double drag_cd = 1.0, front = beam * draft, side = len * draft;
    switch (k->hull) {
    case BODY_HULL_SPHERE:
        m->inertia[0] = m->inertia[1] = m->inertia[2] = 0.4 * mass * r * r;
        /* A sphere's 1/2 rho V (Newman 1977 ch. 4), of what is wet at rest; no added
         * inertia in rotation (a turning sphere moves no water in potential flow). */
        m->added[0] = m->added[1] = m->added[2] = 0.5 * RHO * m->v_rest;
        drag_cd = 0.5; /* Hoerner 1965: a sphere, subcritical */
        front = side = PI / 4 * beam * draft;
        break;
    case BODY_HULL_CYLINDER:
        m->inertia[0] = m->inertia[2] = mass * (3 * r * r + height * height) / 12;
        m->inertia[1] = 0.5 * mass * r * r;
        /* Sideways: a circle's rho pi r^2 per unit length over the draft (DNV-RP-H103 Table A-1);
         * heave: the keel, half of a disc's 8/3 rho r^3 (Table A-2; Newman 1977 ch. 4). */
        m->added[0] = m->added[2] = RHO * PI * r * r * draft;
        m->added[1] = 4.0 / 3.0 * RHO * r * r * r;
        m->added_rot[0] = m->added_rot[2] = RHO * PI * r * r * (m->wl_y * m->wl_y * m->wl_y + m->kg * m->kg * m->kg) / 3;
        side = beam * draft;
        break;
    case BODY_HULL_BOX:
        m->inertia[0] = mass * (height * height + len * len) / 12;
        m->inertia[1] = mass * (beam * beam + len * len) / 12;
        m->inertia[2] = mass * (beam * beam + height * height) / 12;
        strip_added_mass(m, k, false);
        m->added[2] = 0.05 * mass;
        m->added_rot[2] = 0.2 * m->inertia[2];
        break;
    default:
        m->inertia[0] = m->inertia[1] = mass * (0.25 * len) * (0.25 * len);
        m->inertia[2] = mass * (0.35 * beam) * (0.35 * beam);
        strip_added_mass(m, k, true);
        m->added[2] = 0.05 * mass;
        m->added_rot[2] = 0.2 * m->inertia[2];
        side = (1.0 - 1.0 / 3.5) * len * draft; /* the lateral profile tapers like the waterplane */
        break;
    }

    /* Damping. Vertical: linear, HEAVE_DAMPING_RATIO of critical for the
     * whole hull, spread over the elements by area (so it damps roll and
     * pitch too), plus quadratic drag 1/2 rho C_d A |w| w per element. */
    m->heave_lin = 2 * HEAVE_DAMPING_RATIO * sqrt((mass + m->added[1]) * RHO * G * m->waterplane);
    m->vert_quad = 0.5 * RHO * drag_cd;
    m->wet_ref = fmax(0.02, 0.25 * draft);
    /* Horizontal, lumped at the centre of mass: cross-flow drag of the
     * submerged profile, and yaw drag of the same profile turning
     * (int over the length of 1/2 rho C_d T |r z| r z z dz = rho C_d T L^4 / 64). */
    m->surge_quad = 0.5 * RHO * drag_cd * front;
    m->sway_quad = 0.5 * RHO * drag_cd * side;
    m->yaw_quad = RHO * drag_cd * draft * len * len * len * len / 64;
    /* Pitching and rolling, the wet sides move sideways through the water
     * at omega y: cross-flow drag int 1/2 rho C_d width |omega y| omega y y dy
     * from the keel to the waterline (the beam meets it in pitch, the
     * lateral profile in roll). */
    double lo = -m->kg, hi = m->wl_y < height - m->kg ? m->wl_y : height - m->kg;
    double cube = (hi * fabs(hi) * hi * hi - lo * fabs(lo) * lo * lo) / 4; /* int |y|^3 dy */
    m->rock_quad[0] = 0.5 * RHO * drag_cd * (front / fmax(draft, 1e-9)) * cube;
    m->rock_quad[2] = 0.5 * RHO * drag_cd * (side / fmax(draft, 1e-9)) * cube;
    m->sink_margin = fmax(1.0, height);

    if (k->powered) {
        double u = k->top_speed, radius = 0.5 * k->turning_diameter;
        /* Thrust gives (m + a_surge) u / tau at rest, tau = 16 sqrt(L/g)
         * (9 s for the dinghy, 40 s for the ship); resistance 1.1 k u^2 at
         * top speed, a tenth of it linear, so full ahead settles at u. */
        double tau = 16 * sqrt(len / G);
        m->thrust = (mass + m->added[2]) * u / tau;
        m->surge_quad = m->thrust / (1.1 * u * u);
        m->surge_lin = 0.1 * m->surge_quad * u;
        /* Lateral resistance (keel and hull lift, proportional to the speed)
         * that stops a sideways drift within 0.3 of a length travelled. */
        m->sway_lin = (mass + m->added[0]) / (0.3 * len);
        /* Yaw damping from the hull moving ahead: a Nomoto time constant of
         * 2 lengths travelled (T' = 2). */
        m->yaw_lin = (m->inertia[1] + m->added_rot[1]) / (2 * len);
        /* The rudder, at the stern, sized so that the steady turn at full
         * rudder has the kind's diameter: its moment arm * F = damping at
         * r = u / R. Both sides go as u^2, so the diameter does not depend
         * on the speed. */
        m->rudder_arm = 0.5 * len;
        m->rudder = (m->yaw_lin / radius + m->yaw_quad / (radius * radius)) / m->rudder_arm;
    }
    return 0;
}

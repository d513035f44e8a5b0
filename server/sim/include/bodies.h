/* bodies.h — rigid bodies that float on the sea (no networking).
 *
 * A struct body_world holds every body on one sea: buoys, boats and ships,
 * each a rigid body with six degrees of freedom, integrated at fixed
 * substeps (BODY_SUBSTEP_S) by body_world_step. The sea enters only
 * through a struct body_sea the caller supplies (the daemon samples the
 * tick's grids of cascade 0; tests supply still water or an analytic
 * swell), so the library needs no simulation of its own and no threads.
 *
 * Deterministic: the same launches, steering and steps (the same dt
 * sequence and the same sea) give the same states bit for bit, whatever
 * the machine's thread count, so a standby given body_world_get's states
 * continues the same motion.
 *
 * Frames (stated once, docs/simulation.md "Bodies"): world axes as the sea's,
 * y up, north = +z, east = -x (the web client's sky uses the same). A
 * heading is a compass bearing, degrees clockwise from north. A body's own
 * frame: +z toward the bow, +y up through the deck, +x to port; the
 * identity orientation is bow north, deck level. */
#ifndef OCEAND_BODIES_H
#define OCEAND_BODIES_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define BODY_SUBSTEP_S      (1.0 / 120.0) /* s of sim time per integration substep */
#define BODY_WORLD_HALF_M   2500.0        /* |x|, |z| <= this: the world's bounds (5 km across) */
#define BODY_MAX_WORLD      4096          /* most bodies one world can hold */
#define BODY_WATER_DENSITY  1025.0        /* kg/m^3, sea water */
#define BODY_GRAVITY        9.81          /* m/s^2, as the sea's */
#define BODY_STEP_MAX_S     60.0          /* longest dt one body_world_step takes */

enum body_hull {
    BODY_HULL_CYLINDER, /* vertical cylinder: diameter = beam = length, height */
    BODY_HULL_SPHERE,   /* diameter = beam = length = height */
    BODY_HULL_BOX,      /* length x beam x height */
    BODY_HULL_SHIP,     /* a ship-shaped hull: waterplane tapering to bow and stern */
};

/* One row of the table of kinds (body_kinds): it drives validation, the
 * schema in `hello` and the web panel, like the parameter table. */
struct body_kind {
    const char *name;         /* stable lowercase id: "spar", "ball", "dinghy", "boat", "ship" */
    const char *label;        /* for people: "Spar buoy" */
    const char *description;  /* one sentence */
    enum body_hull hull;
    double length;            /* m, along the bow (body +z) */
    double beam;              /* m, across (body x) */
    double height;            /* m, keel to deck (body y) */
    double mass;              /* kg */
    double draft;             /* m, keel below the still water at rest (documented, checked by the tests) */
    bool   powered;           /* has thrust and a rudder */
    double top_speed;         /* m/s at full throttle in still water (0 when not powered) */
    double turning_diameter;  /* m, steady turning circle at full rudder and top speed (0 when not powered) */
    /* Added after the first version (fields at the end, so existing
     * initialisers stay valid; 0 means the hull's default): */
    double kg;                /* m, centre of mass above the keel; 0 = the hull's default
                               * (box 1/2, sphere 0.4, cylinder 1/4, ship 0.45 of height) */
};

/* The table: BODY_KIND_COUNT rows, in a stable order. */
enum { BODY_KIND_COUNT = 5 };
const struct body_kind *body_kinds(void);
/* The row named name, or NULL. */
const struct body_kind *body_kind_find(const char *name);
/* The centre of mass above the keel (m) a body of kind k has: k->kg, or the
 * hull's default when k->kg is 0. A client draws the hull from it (hello's kg). */
double body_kind_kg(const struct body_kind *k);

/* Steering. Powered kinds only; an unpowered body ignores it. */
struct body_control {
    double throttle; /* -1 (full astern) .. 1 (full ahead); astern thrust is half */
    double rudder;   /* -1 (full to port) .. 1 (full to starboard) */
};

/* Everything a body is: what body_world_get hands out and body_world_restore
 * takes back (restoring it continues the same motion bit for bit). */
struct body_state {
    uint32_t id;                 /* >= 1, unique in its world, never reused */
    const struct body_kind *kind;
    double pos[3];               /* m, world position of the centre of mass */
    double quat[4];              /* unit quaternion (w, x, y, z): body frame -> world */
    double vel[3];               /* m/s, world velocity of the centre of mass */
    double omega[3];             /* rad/s, world angular velocity */
    struct body_control control;
};

/* The water a body meets. sample fills height[i] (m, y of the displaced
 * surface above world point xz[i]) and dhdt[i] (m/s, its vertical velocity
 * there) for n points at sim time t; returns 0, or -1 (the step is then
 * done in still water at y = 0). NULL sample = still water at y = 0.
 * It must honour t: the water's vertical acceleration (the Froude-Krylov
 * and added-mass forces of accelerating water) is taken from how dhdt
 * changes between samples, and a step also samples once at t - dt - dt/n.
 * A sampler that gives one tick's grid for every t gives no acceleration:
 * large hulls then heave too much near their heave resonance (docs). It is
 * called body by body in ascending id order, for each body once per sample
 * in ascending t, with that body's column points (at most 64); under
 * body_world_step_part on the threads that call it, at once. */
struct body_sea {
    int (*sample)(void *ctx, double t, int n, const double (*xz)[2], double *height, double *dhdt);
    void *ctx;
};

/* Why a request was refused (the daemon maps these to wire error codes). */
enum body_error {
    BODY_OK = 0,
    BODY_ERR_KIND,       /* no such kind */
    BODY_ERR_NOT_FINITE, /* NaN or infinity */
    BODY_ERR_RANGE,      /* outside the world's bounds, or steering outside -1..1 */
    BODY_ERR_FULL,       /* the world holds as many bodies as it may */
    BODY_ERR_NOT_FOUND,  /* no body with that id */
    BODY_ERR_NO_MEMORY,
};
const char *body_error_name(enum body_error e); /* "kind", "not_finite", ... */

/* Why a body left the world on its own (body_world_step). */
enum body_gone { BODY_GONE_SUNK = 1 };

struct body_world;

/* A world that holds at most capacity (1..BODY_MAX_WORLD) bodies; NULL on
 * no memory or a bad capacity. */
struct body_world *body_world_new(int capacity);
void body_world_free(struct body_world *w);

/* Launch a body of kind at world (x, z), heading in degrees, resting at its
 * still-water draft, at rest. *id gets its id. Refused launches change
 * nothing. kind need not be a row of the table (tests use their own), but
 * it must outlive the body. */
enum body_error body_launch(struct body_world *w, const struct body_kind *kind, double x, double z,
                            double heading_deg, uint32_t *id);
/* Added: body_launch on a known sea. The body rests level at its draft
 * below the mean surface over its hull at sim time t (the sea sampled at
 * its columns as a step would), rising or falling with that surface's mean
 * dhdt; in waves a still-water launch starts it under a crest or above a
 * trough and it jumps. Same refusals as body_launch; a failing sea is
 * still water (then it is body_launch). */
enum body_error body_launch_on(struct body_world *w, const struct body_kind *kind, double x, double z,
                               double heading_deg, const struct body_sea *sea, double t, uint32_t *id);
enum body_error body_steer(struct body_world *w, uint32_t id, const struct body_control *c);
enum body_error body_remove(struct body_world *w, uint32_t id);

/* Advance every body by dt >= 0 s of sim time ending at sim time t, in
 * ceil(dt / BODY_SUBSTEP_S) equal substeps (a dt within 1e-9 of a whole
 * number of substeps counts as that number: 1/30 s is 4 substeps). Substep
 * k samples the sea at t - dt + k dt/n. A dt that is not finite, negative
 * or above BODY_STEP_MAX_S, or a t that is not finite, does nothing
 * (returns 0). A body that sank is removed:
 * its id and why are appended to gone (ascending id; up to max_gone, more
 * are still removed) and the count written is returned. */
int body_world_step(struct body_world *w, const struct body_sea *sea, double t, double dt, uint32_t *gone_ids,
                    enum body_gone *gone_why, int max_gone);
/* The same step in parts, for a caller that spreads the bodies over its
 * threads (bodies do not touch each other, so each moves bit for bit as
 * under body_world_step): body_world_step_part steps bodies i0 .. i1 - 1
 * (body_world_get's indices), and disjoint ranges may run on several threads
 * at once (the sampler must then be safe to call from them); once every
 * body is stepped, body_world_step_end on one thread removes those that sank
 * and reports them as body_world_step does. No other call on w in between. */
void body_world_step_part(struct body_world *w, const struct body_sea *sea, double t, double dt, int i0, int i1);
int body_world_step_end(struct body_world *w, uint32_t *gone_ids, enum body_gone *gone_why, int max_gone);

/* Bodies in the world, and each one's state, in ascending id order
 * (i = 0 .. count-1). body_world_get returns -1 when i is out of range. */
int body_world_count(const struct body_world *w);
int body_world_get(const struct body_world *w, int i, struct body_state *out);
/* Put a saved body back (a standby, a restart): its id, kind, state and
 * control exactly. Refused (BODY_ERR_RANGE) when the id is 0 or already in
 * use, or the state is not finite, not a unit quaternion or out of bounds
 * (also: its control outside -1..1); BODY_ERR_KIND when its kind is NULL
 * or unusable, BODY_ERR_FULL when the world is full. Ids issued later are
 * above every id restored. */
enum body_error body_world_restore(struct body_world *w, const struct body_state *s);
/* The next id body_launch would give (ids only grow); 0 once ids are
 * exhausted (the last id, UINT32_MAX, was issued or restored: launches are
 * then refused with BODY_ERR_FULL). */
uint32_t body_world_next_id(const struct body_world *w);

/* Heading (degrees clockwise from north, 0..360), pitch (degrees, bow up
 * positive) and roll (degrees, starboard down positive) of a state. */
void body_attitude(const struct body_state *s, double *heading_deg, double *pitch_deg, double *roll_deg);

#endif

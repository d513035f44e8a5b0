/* bodies.c — the world of floating bodies: launch, steer, remove, restore,
 * and the fixed-substep integration (docs/simulation.md, "Bodies").
 *
 * Per substep and body, in ascending id order: sample the sea at every
 * column's waterline point; per column, the hydrostatic pressure on its
 * submerged part (buoyancy, and the push down the surface's slope) at that
 * part's centroid, the pressure of the accelerating water and vertical drag
 * against the water's vertical velocity; the added mass moved by the water;
 * gravity; the lumped horizontal forces (resistance, lateral resistance,
 * yaw and rocking damping, thrust, rudder) in the body frame; then
 * semi-implicit Euler (velocities first, positions from the new ones) with
 * the mass and inertia plus added mass along the body axes, and the
 * quaternion renormalised. Plain sequential double arithmetic, + - * / and
 * sqrt only: the same inputs give the same bits. */
#include <math.h>
#include <stdlib.h>
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

struct body {
    struct body_state s;
    struct body_model m;
    /* Scratch of one body_world_step (not state): the water's vertical
     * velocity at each column at the previous sample, for its acceleration. */
    double prev_dhdt[BODY_ELEMS_MAX];
    bool prev_ok;
    bool sunk; /* sank in the step's part, removed by its end */
};

struct body_world {
    int capacity, count;
    uint64_t next_id; /* above UINT32_MAX: ids are exhausted */
    struct body *b;   /* count bodies, ascending id */
};

/* ---- small vector helpers --------------------------------------------- */

static void quat_matrix(const double q[4], double r[3][3])
{
    double w = q[0], x = q[1], y = q[2], z = q[3];
    r[0][0] = 1 - 2 * (y * y + z * z); r[0][1] = 2 * (x * y - w * z);     r[0][2] = 2 * (x * z + w * y);
    r[1][0] = 2 * (x * y + w * z);     r[1][1] = 1 - 2 * (x * x + z * z); r[1][2] = 2 * (y * z - w * x);
    r[2][0] = 2 * (x * z - w * y);     r[2][1] = 2 * (y * z + w * x);     r[2][2] = 1 - 2 * (x * x + y * y);
}

static void mat_vec(const double r[3][3], const double v[3], double out[3])
{
    for (int i = 0; i < 3; i++)
        out[i] = r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2];
}

static void mat_t_vec(const double r[3][3], const double v[3], double out[3])
{
    for (int i = 0; i < 3; i++)
        out[i] = r[0][i] * v[0] + r[1][i] * v[1] + r[2][i] * v[2];
}

static void cross(const double a[3], const double b[3], double out[3])
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static double clampd(double v, double lo, double hi) { return v < lo ? lo : v > hi ? hi : v; }

/* ---- the world --------------------------------------------------------- */

struct body_world *body_world_new(int capacity)
{
    if (capacity < 1 || capacity > BODY_MAX_WORLD)
        return NULL;
    struct body_world *w = calloc(1, sizeof *w);
    if (!w)
        return NULL;
    w->b = calloc((size_t)capacity, sizeof *w->b);
    if (!w->b) {
        free(w);
        return NULL;
    }
    w->capacity = capacity;
    w->next_id = 1;
    return w;
}

void body_world_free(struct body_world *w)
{
    if (!w)
        return;
    free(w->b);
    free(w);
}

int body_world_count(const struct body_world *w) { return w ? w->count : 0; }

uint32_t body_world_next_id(const struct body_world *w)
{
    return w && w->next_id <= UINT32_MAX ? (uint32_t)w->next_id : 0;
}

int body_world_get(const struct body_world *w, int i, struct body_state *out)
{
    if (!w || !out || i < 0 || i >= w->count)
        return -1;
    *out = w->b[i].s;
    return 0;
}

/* Index of id, or where it would go (ascending order). */
static int find_slot(const struct body_world *w, uint32_t id, bool *found)
{
    int lo = 0, hi = w->count;
    while (lo < hi) {
        int mid = (lo + hi) / 2;
        if (w->b[mid].s.id < id)
            lo = mid + 1;
        else
            hi = mid;
    }
    *found = lo < w->count && w->b[lo].s.id == id;
    return lo;
}

static bool in_bounds(double x, double z) { return fabs(x) <= BODY_WORLD_HALF_M && fabs(z) <= BODY_WORLD_HALF_M; }

enum body_error body_launch(struct body_world *w, const struct body_kind *kind, double x, double z,
                            double heading_deg, uint32_t *id)
{
    if (!w)
        return BODY_ERR_NOT_FOUND;
    struct body_model m;
    if (body_model_build(kind, &m) != 0)
        return BODY_ERR_KIND;
    if (!isfinite(x) || !isfinite(z) || !isfinite(heading_deg))
        return BODY_ERR_NOT_FINITE;
    if (!in_bounds(x, z))
        return BODY_ERR_RANGE;
    if (w->count >= w->capacity || w->next_id > UINT32_MAX)
        return BODY_ERR_FULL;
    struct body *b = &w->b[w->count];
    memset(b, 0, sizeof *b);
    b->m = m;
    b->s.id = (uint32_t)w->next_id;
    b->s.kind = kind;
    b->s.pos[0] = x;
    b->s.pos[1] = m.rest_y;
    b->s.pos[2] = z;
    /* Bow north is the identity; heading psi clockwise from north (toward
     * east = -x) is a rotation by -psi about +y. */
    double half = -0.5 * heading_deg * (3.14159265358979323846 / 180);
    b->s.quat[0] = cos(half);
    b->s.quat[2] = sin(half);
    w->count++;
    w->next_id++;
    if (id)
        *id = b->s.id;
    return BODY_OK;
}

static enum body_error check_control(const struct body_control *c)
{
    if (!c)
        return BODY_ERR_RANGE;
    if (!isfinite(c->throttle) || !isfinite(c->rudder))
        return BODY_ERR_NOT_FINITE;
    if (fabs(c->throttle) > 1 || fabs(c->rudder) > 1)
        return BODY_ERR_RANGE;
    return BODY_OK;
}

enum body_error body_steer(struct body_world *w, uint32_t id, const struct body_control *c)
{
    bool found = false;
    int i = w ? find_slot(w, id, &found) : 0;
    if (!found)
        return BODY_ERR_NOT_FOUND;
    enum body_error e = check_control(c);
    if (e != BODY_OK)
        return e;
    w->b[i].s.control = *c;
    return BODY_OK;
}

static void remove_at(struct body_world *w, int i)
{
    memmove(&w->b[i], &w->b[i + 1], (size_t)(w->count - i - 1) * sizeof *w->b);
    w->count--;
}

enum body_error body_remove(struct body_world *w, uint32_t id)
{
    bool found = false;
    int i = w ? find_slot(w, id, &found) : 0;
    if (!found)
        return BODY_ERR_NOT_FOUND;
    remove_at(w, i);
    return BODY_OK;
}

enum body_error body_world_restore(struct body_world *w, const struct body_state *s)
{
    if (!w || !s)
        return BODY_ERR_RANGE;
    struct body_model m;
    if (body_model_build(s->kind, &m) != 0)
        return BODY_ERR_KIND;
    const double *v[4] = {s->pos, s->vel, s->omega, s->quat};
    for (int k = 0; k < 4; k++)
        for (int j = 0; j < (k == 3 ? 4 : 3); j++)
            if (!isfinite(v[k][j]))
                return BODY_ERR_RANGE;
    double qn = sqrt(s->quat[0] * s->quat[0] + s->quat[1] * s->quat[1] + s->quat[2] * s->quat[2] +
                     s->quat[3] * s->quat[3]);
    if (fabs(qn - 1) > 1e-6 || !in_bounds(s->pos[0], s->pos[2]) || check_control(&s->control) != BODY_OK)
        return BODY_ERR_RANGE;
    bool found;
    int i = find_slot(w, s->id, &found);
    if (s->id == 0 || found)
        return BODY_ERR_RANGE;
    if (w->count >= w->capacity)
        return BODY_ERR_FULL;
    memmove(&w->b[i + 1], &w->b[i], (size_t)(w->count - i) * sizeof *w->b);
    w->b[i].s = *s;
    w->b[i].m = m;
    w->count++;
    if ((uint64_t)s->id + 1 > w->next_id)
        w->next_id = (uint64_t)s->id + 1;
    return BODY_OK;
}

/* ---- the step ------------------------------------------------------------ */

/* The slope of the sea under a body: the least-squares plane
 * eta = c + gx (x - px) + gz (z - pz) through its sample points (a small
 * ridge keeps it defined for a single point). */
static void surface_slope(int n, const double (*xz)[2], const double *eta, const double pos[3], double *gx,
                          double *gz)
{
    double sx = 0, sz = 0, se = 0;
    for (int i = 0; i < n; i++) {
        sx += xz[i][0] - pos[0];
        sz += xz[i][1] - pos[2];
        se += eta[i];
    }
    double mx = sx / n, mz = sz / n, me = se / n, cxx = 1e-9, czz = 1e-9, cxz = 0, cxe = 0, cze = 0;
    for (int i = 0; i < n; i++) {
        double dx = xz[i][0] - pos[0] - mx, dz = xz[i][1] - pos[2] - mz, de = eta[i] - me;
        cxx += dx * dx, czz += dz * dz, cxz += dx * dz, cxe += dx * de, cze += dz * de;
    }
    double det = cxx * czz - cxz * cxz;
    *gx = (cxe * czz - cze * cxz) / det;
    *gz = (cze * cxx - cxe * cxz) / det;
}

/* Where each column meets the water at rest (its sample point), and the
 * sea there at time t; still water when there is no sea or it fails, and
 * in place of values that are not finite. Returns whether the sea gave
 * its values (a still-water stand-in has no acceleration to tell). */
static bool sample_sea(const struct body *b, const double r[3][3], const struct body_sea *sea, double t,
                       double (*xz)[2], double *eta, double *dhdt)
{
    const struct body_model *m = &b->m;
    for (int i = 0; i < m->n; i++) {
        const struct body_elem *e = &m->e[i];
        double p[3] = {e->bx, clampd(m->wl_y, e->y0, e->y1), e->bz}, pw[3];
        mat_vec(r, p, pw);
        xz[i][0] = b->s.pos[0] + pw[0];
        xz[i][1] = b->s.pos[2] + pw[2];
    }
    bool ok = sea && sea->sample && sea->sample(sea->ctx, t, m->n, (const double (*)[2])xz, eta, dhdt) == 0;
    for (int i = 0; i < m->n; i++) {
        if (!ok || !isfinite(eta[i]))
            eta[i] = 0;
        if (!ok || !isfinite(dhdt[i]))
            dhdt[i] = 0;
    }
    return ok;
}

/* The forces of one substep on body b at sim time t: world force f and
 * torque tq about the centre of mass, and *am_out the share of its added
 * mass in force; returns whether it is gone (sunk). */
static bool body_forces(struct body *b, const struct body_sea *sea, double t, double h_step, double f[3],
                        double tq[3], double *am_out)
{
    const struct body_model *m = &b->m;
    const struct body_state *s = &b->s;
    double r[3][3];
    quat_matrix(s->quat, r);

    double xz[BODY_ELEMS_MAX][2], eta[BODY_ELEMS_MAX], dhdt[BODY_ELEMS_MAX];
    bool sea_ok = sample_sea(b, r, sea, t, xz, eta, dhdt), acc_ok = sea_ok && b->prev_ok;
    b->prev_ok = sea_ok;
    double gx, gz;
    surface_slope(m->n, xz, eta, s->pos, &gx, &gz);

    /* First the submerged part of each column: its fraction from the
     * lower end up (a capsized body's columns are upside down) and its
     * centroid on the axis, relative to the centre of mass. */
    double frac[BODY_ELEMS_MAX], cen[BODY_ELEMS_MAX][3];
    double vsub = 0, highest_top = -INFINITY, area_sum = 0; /* highest_top: above the surface at its column */
    bool all_under = true;
    for (int i = 0; i < m->n; i++) {
        const struct body_elem *e = &m->e[i];
        double pb[3] = {e->bx, e->y0, e->bz}, pt[3] = {e->bx, e->y1, e->bz}, rb[3], rt[3];
        mat_vec(r, pb, rb);
        mat_vec(r, pt, rt);
        double yb = s->pos[1] + rb[1], yt = s->pos[1] + rt[1];
        const double *rlo = yb <= yt ? rb : rt, *rhi = yb <= yt ? rt : rb;
        double lo = fmin(yb, yt), hi = fmax(yb, yt);
        frac[i] = hi - lo > 1e-12 ? clampd((eta[i] - lo) / (hi - lo), 0, 1) : (eta[i] > lo ? 1 : 0);
        for (int k = 0; k < 3; k++)
            cen[i][k] = rlo[k] + 0.5 * frac[i] * (rhi[k] - rlo[k]);
        all_under = all_under && frac[i] >= 1;
        highest_top = fmax(highest_top, hi - eta[i]);
        vsub += e->area * (e->y1 - e->y0) * frac[i];
        area_sum += e->area;
    }
    /* The share of the added mass in force: full from half the rest
     * displacement wet, none in the air. */
    double am = clampd(2 * vsub / m->v_rest, 0, 1);

    f[0] = 0, f[1] = -m->mass * G, f[2] = 0;
    tq[0] = tq[1] = tq[2] = 0;
    double axis_y = r[1][1]; /* the vertical component of the body's +y */
    double acc_mean = 0;     /* the water's vertical acceleration under the hull, by plan area */
    for (int i = 0; i < m->n; i++) {
        const struct body_elem *e = &m->e[i];
        /* The water's vertical acceleration here, from its velocity at the
         * previous sample; none across a sample the sea did not give, and at
         * most g (real waves break first: a glitch must not throw a body). */
        double acc = acc_ok ? clampd((dhdt[i] - b->prev_dhdt[i]) / h_step, -G, G) : 0;
        b->prev_dhdt[i] = dhdt[i];
        acc_mean += e->area / area_sum * acc;
        if (frac[i] <= 0)
            continue;
        const double *c = cen[i];
        double len = e->y1 - e->y0, vol = e->area * len * frac[i];
        /* Buoyancy: the hydrostatic pressure rho g (eta - y) on the wet
         * part; its gradient is rho g (-d eta/dx, 1, -d eta/dz), so a
         * sloping surface also pushes the part down the slope. */
        double fy = RHO * G * vol, fx = -RHO * G * vol * gx, fz = -RHO * G * vol * gz;
        /* The pressure that accelerates the displaced water with the
         * wave (Froude-Krylov, rho V a). */
        fy += RHO * vol * acc;
        /* Vertical drag against the water's vertical velocity at the
         * centroid; it grows to full over wet_ref of wetted length. */
        double vc[3];
        cross(s->omega, c, vc);
        double wrel = s->vel[1] + vc[1] - dhdt[i];
        double wet = fmin(1, frac[i] * len / m->wet_ref);
        double area_h = e->area * fabs(axis_y); /* the plan area the vertical flow sees */
        fy -= wet * (m->heave_lin * e->area / area_sum + m->vert_quad * area_h * fabs(wrel)) * wrel;
        f[0] += fx;
        f[1] += fy;
        f[2] += fz;
        double fe[3] = {fx, fy, fz}, te[3];
        cross(c, fe, te);
        for (int k = 0; k < 3; k++)
            tq[k] += te[k];
    }
    /* The added mass the water drags along moves with it (a33 a, at the
     * centre of mass: the heave added mass belongs to the whole hull). With
     * the Froude-Krylov part, a body in a wave much longer than itself
     * moves with the water: the heave resonance is not excited by it. */
    f[1] += am * m->added[1] * acc_mean;
    *am_out = am;

    /* Horizontal forces and yaw in the body frame, lumped at the centre of
     * mass, in proportion to how much of the body is in the water. */
    double vb[3], wb[3];
    mat_t_vec(r, s->vel, vb);
    mat_t_vec(r, s->omega, wb);
    double u = vb[2], v = vb[0], yaw = wb[1];
    double fb[3] = {0, 0, 0}, tb[3] = {0, 0, 0};
    fb[2] = -(m->surge_lin + m->surge_quad * fabs(u)) * u;
    fb[0] = -(m->sway_lin * fabs(u) + m->sway_quad * fabs(v)) * v;
    tb[1] = -(m->yaw_lin * fabs(u) + m->yaw_quad * fabs(yaw)) * yaw;
    tb[0] = -m->rock_quad[0] * fabs(wb[0]) * wb[0];
    tb[2] = -m->rock_quad[2] * fabs(wb[2]) * wb[2];
    if (b->s.kind->powered) {
        double th = s->control.throttle;
        fb[2] += m->thrust * (th >= 0 ? th : 0.5 * th);
        /* The rudder at the stern pushes it to port when turning to
         * starboard: bow to starboard (negative yaw about +y). */
        double side = m->rudder * s->control.rudder * u * fabs(u);
        fb[0] += side;
        tb[1] -= m->rudder_arm * side;
    }
    for (int k = 0; k < 3; k++) {
        fb[k] *= am;
        tb[k] *= am;
    }
    double fw[3], tw[3];
    mat_vec(r, fb, fw);
    mat_vec(r, tb, tw);
    for (int k = 0; k < 3; k++) {
        f[k] += fw[k];
        tq[k] += tw[k];
    }
    return !m->can_float && all_under && highest_top < -m->sink_margin;
}

/* v = R diag(d)^-1 R^T p: a world vector through a body-diagonal inverse. */
static void body_diag_solve(const double r[3][3], const double d[3], const double p[3], double out[3])
{
    double pb[3];
    mat_t_vec(r, p, pb);
    for (int k = 0; k < 3; k++)
        pb[k] /= d[k];
    mat_vec(r, pb, out);
}

/* p = R diag(d) R^T v. */
static void body_diag_mul(const double r[3][3], const double d[3], const double v[3], double out[3])
{
    double vb[3];
    mat_t_vec(r, v, vb);
    for (int k = 0; k < 3; k++)
        vb[k] *= d[k];
    mat_vec(r, vb, out);
}

/* q += h/2 (0, omega) q, then back onto the unit sphere. */
static void quat_advance(double q[4], const double o[3], double h)
{
    double dq[4] = {
        -(o[0] * q[1] + o[1] * q[2] + o[2] * q[3]),
        o[0] * q[0] + o[1] * q[3] - o[2] * q[2],
        o[1] * q[0] + o[2] * q[1] - o[0] * q[3],
        o[2] * q[0] + o[0] * q[2] - o[1] * q[1],
    };
    double n2 = 0;
    for (int k = 0; k < 4; k++) {
        q[k] += 0.5 * h * dq[k];
        n2 += q[k] * q[k];
    }
    double inv = 1 / sqrt(n2);
    for (int k = 0; k < 4; k++)
        q[k] *= inv;
}

/* One semi-implicit Euler substep of length h at sim time t. The mass
 * (with added mass) is diagonal in the body frame, so what is integrated is
 * the world momentum P = R M R^T v: P += h F, then the velocity from it
 * through the new orientation. That carries the term a rotating
 * anisotropic mass brings (omega x (M v)); stepping the accelerations
 * F / M instead makes a rolling ship drift sideways. */
static bool body_substep(struct body *b, const struct body_sea *sea, double t, double h)
{
    double f[3], tq[3], am;
    bool sunk = body_forces(b, sea, t, h, f, tq, &am);
    struct body_state *s = &b->s;
    const struct body_model *m = &b->m;
    /* Added mass and inertia along the body axes, full from half the rest
     * displacement wet down to none in the air. */
    double mb[3], ib[3];
    for (int k = 0; k < 3; k++) {
        mb[k] = m->mass + am * m->added[k];
        ib[k] = m->inertia[k] + am * m->added_rot[k];
    }
    double r[3][3], p[3], wb[3], tb[3], iw[3], gyro[3];
    quat_matrix(s->quat, r);
    body_diag_mul(r, mb, s->vel, p);
    for (int k = 0; k < 3; k++)
        p[k] += h * f[k];
    /* Rotation: Euler's equations in the body frame with the dry inertia's
     * gyroscopic term; the added inertia only resists angular acceleration.
     * (Carried in the gyroscopic term, strip theory's large added inertia
     * in pitch turned pitch and yaw into roll: a boat at speed in a rough
     * sea rolled past 50 degrees.) */
    mat_t_vec(r, s->omega, wb);
    mat_t_vec(r, tq, tb);
    for (int k = 0; k < 3; k++)
        iw[k] = m->inertia[k] * wb[k];
    cross(wb, iw, gyro);
    for (int k = 0; k < 3; k++)
        wb[k] += h * (tb[k] - gyro[k]) / ib[k];
    mat_vec(r, wb, s->omega);
    quat_advance(s->quat, s->omega, h);
    quat_matrix(s->quat, r);
    body_diag_solve(r, mb, p, s->vel);
    for (int k = 0; k < 3; k++)
        s->pos[k] += h * s->vel[k];
    /* The world's edge holds a body: clamped onto it, its outward velocity
     * zeroed (it can still move along the edge or back in). */
    for (int k = 0; k < 3; k += 2) {
        if (s->pos[k] > BODY_WORLD_HALF_M) {
            s->pos[k] = BODY_WORLD_HALF_M;
            s->vel[k] = fmin(s->vel[k], 0);
        } else if (s->pos[k] < -BODY_WORLD_HALF_M) {
            s->pos[k] = -BODY_WORLD_HALF_M;
            s->vel[k] = fmax(s->vel[k], 0);
        }
    }
    return sunk;
}

/* body_launch, then placed on the sea (the samples a step would take). */
enum body_error body_launch_on(struct body_world *w, const struct body_kind *kind, double x, double z,
                               double heading_deg, const struct body_sea *sea, double t, uint32_t *id)
{
    uint32_t got;
    enum body_error e = !isfinite(t) ? BODY_ERR_NOT_FINITE : body_launch(w, kind, x, z, heading_deg, &got);
    if (e != BODY_OK)
        return e;
    struct body *b = &w->b[w->count - 1]; /* the newest is last: ids ascend */
    double r[3][3], xz[BODY_ELEMS_MAX][2], eta[BODY_ELEMS_MAX], dhdt[BODY_ELEMS_MAX], se = 0, sd = 0;
    quat_matrix(b->s.quat, r);
    sample_sea(b, r, sea, t, xz, eta, dhdt);
    for (int i = 0; i < b->m.n; i++)
        se += eta[i], sd += dhdt[i];
    b->s.pos[1] += se / b->m.n;
    b->s.vel[1] = sd / b->m.n;
    if (id)
        *id = got;
    return BODY_OK;
}

/* Whether a step of dt is taken, and its substeps. */
static bool step_plan(double t, double dt, int *n, double *h)
{
    if (!isfinite(t) || !isfinite(dt) || dt <= 0 || dt > BODY_STEP_MAX_S)
        return false;
    *n = (int)ceil(dt / BODY_SUBSTEP_S - 1e-9);
    if (*n < 1)
        *n = 1;
    *h = dt / *n;
    return true;
}

/* One body through the n substeps of a step: it depends on nothing but its
 * own state and the sea, so bodies may be stepped in any order, on any
 * thread. A body that sinks stops there, marked. */
static void step_body(struct body *b, const struct body_sea *sea, double t0, double h, int n)
{
    /* The water's vertical velocity one substep before the first, for its
     * acceleration in the first substep (so a step depends on nothing but
     * the states and the sea: a restored world continues the same). */
    double r[3][3], xz[BODY_ELEMS_MAX][2], eta[BODY_ELEMS_MAX];
    quat_matrix(b->s.quat, r);
    b->prev_ok = sample_sea(b, r, sea, t0 - h, xz, eta, b->prev_dhdt);
    b->sunk = false;
    for (int k = 0; k < n && !b->sunk; k++)
        b->sunk = body_substep(b, sea, t0 + k * h, h);
}

void body_world_step_part(struct body_world *w, const struct body_sea *sea, double t, double dt, int i0, int i1)
{
    int n;
    double h;
    if (!w || !step_plan(t, dt, &n, &h))
        return;
    for (int i = i0 < 0 ? 0 : i0; i < i1 && i < w->count; i++)
        step_body(&w->b[i], sea, t - dt, h, n);
}

int body_world_step_end(struct body_world *w, uint32_t *gone_ids, enum body_gone *gone_why, int max_gone)
{
    int gone = 0;
    for (int i = 0; w && i < w->count;) {
        if (!w->b[i].sunk) {
            i++;
            continue;
        }
        if (gone < max_gone) {
            if (gone_ids)
                gone_ids[gone] = w->b[i].s.id;
            if (gone_why)
                gone_why[gone] = BODY_GONE_SUNK;
            gone++;
        }
        remove_at(w, i);
    }
    return gone;
}

int body_world_step(struct body_world *w, const struct body_sea *sea, double t, double dt, uint32_t *gone_ids,
                    enum body_gone *gone_why, int max_gone)
{
    if (!w)
        return 0;
    body_world_step_part(w, sea, t, dt, 0, w->count);
    return body_world_step_end(w, gone_ids, gone_why, max_gone);
}

void body_attitude(const struct body_state *s, double *heading_deg, double *pitch_deg, double *roll_deg)
{
    const double deg = 180 / 3.14159265358979323846;
    double r[3][3];
    quat_matrix(s->quat, r);
    /* Columns of r: the body's port (x), up (y) and bow (z) axes in the world. */
    double hd = atan2(-r[0][2], r[2][2]) * deg;
    if (hd < 0)
        hd += 360;
    if (hd >= 360)
        hd -= 360;
    if (heading_deg)
        *heading_deg = hd;
    if (pitch_deg)
        *pitch_deg = asin(clampd(r[1][2], -1, 1)) * deg;
    if (roll_deg)
        *roll_deg = atan2(r[1][0], r[1][1]) * deg;
}
